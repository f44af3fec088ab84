use super::*;

#[test]
fn defaults_round_trip_and_errors_name_fields() {
    let cfg = SlamConfig::default();
    let text = cfg.to_toml().unwrap();
    assert_eq!(SlamConfig::parse(&text, Path::new("x.toml")).unwrap(), cfg);
    let e = SlamConfig::parse("[map]\nvoxel = 1.0\n", Path::new("c.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("c.toml:2") && e.contains("voxel"), "{e}");
    let e = SlamConfig::parse("[map]\nvoxel_size = -1.0\n", Path::new("c.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("map.voxel_size"), "{e}");
    // Too small for the voxel keys (i32 cells): far points would collapse into one.
    let e = SlamConfig::parse("[map]\nvoxel_size = 1e-9\n", Path::new("c.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("map.voxel_size") && e.contains("0.001"), "{e}");
    // A picture side that would overflow or exhaust memory after the whole run.
    let e = SlamConfig::parse("[map]\ntopdown_size = 200000\n", Path::new("c.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("map.topdown_size") && e.contains("8192"), "{e}");
    // Settings that size work per frame or keyframe are bounded.
    for (section, field, value, said) in [
        (
            "map",
            "refuse_per_keyframe",
            "1001",
            "map.refuse_per_keyframe",
        ),
        ("map", "min_views", "5000", "map.min_views"),
        ("labels", "min_votes", "100000", "labels.min_votes"),
        ("pnp", "min_inliers", "501", "pnp.min_inliers"),
        ("matcher", "window", "1e9", "matcher.window"),
        ("matcher", "wide_window", "5000.0", "matcher.wide_window"),
    ] {
        let text = format!("[{section}]\n{field} = {value}\n");
        let e = SlamConfig::parse(&text, Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains(said), "{field} = {value}: {e}");
    }
    for (field, value) in [
        ("fpfdcnn_smoothing", "-1.0"),
        ("fpfdcnn_smoothing", "1e5"),
        ("fpfdcnn_input_scale", "0.0"),
    ] {
        let text = format!("[features]\n{field} = {value}\n");
        let e = SlamConfig::parse(&text, Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains(&format!("features.{field} must be")), "{e}");
    }
    // Values that were accepted and made the run silently useless.
    for (section, field, value) in [
        ("features", "orb_levels", "0"),
        ("features", "orb_scale_factor", "1.0"),
        ("features", "orb_scale_factor", "0.5"),
        ("features", "orb_scale_factor", "nan"),
        ("features", "top_k", "100000000"),
        ("pnp", "max_iterations", "0"),
        ("system", "queue", "0"),
        ("system", "feature_workers", "17"),
        ("map", "min_views", "0"),
        ("multiview", "steps", "100000000"),
        ("multiview", "range", "nan"),
        ("multiview", "min_ncc", "2"),
        ("correction", "min_similarity", "nan"),
        ("dense", "model_step", "0"),
        ("dense", "iterations", "1000"),
        ("dense", "huber", "nan"),
        ("dense", "min_inlier_fraction", "2"),
        ("dense", "agree_rotation_deg", "-1"),
        ("dense", "edge_agree_translation", "0"),
        ("dense", "edge_agree_rotation_deg", "nan"),
        ("bundle_adjustment", "iterations", "100000"),
        ("bundle_adjustment", "max_keyframes", "100000"),
        ("bundle_adjustment", "local_keyframes", "301"),
        ("bundle_adjustment", "local_iterations", "0"),
        ("bundle_adjustment", "sigma_px", "0"),
        ("bundle_adjustment", "huber", "nan"),
        ("bundle_adjustment", "outlier_chi2", "-1"),
        ("bundle_adjustment", "depth_bf", "-1"),
        ("bundle_adjustment", "predicted_depth_bf", "inf"),
        ("bundle_adjustment", "edge_weight", "-1"),
        ("dense", "frame_graph_reference_weight", "0"),
        ("dense", "frame_graph_reference_weight", "1e9"),
    ] {
        let text = format!("[{section}]\n{field} = {value}\n");
        let e = SlamConfig::parse(&text, Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("c.toml") && e.contains(&format!("{section}.{field} must be")),
            "{text}: {e}"
        );
    }
    for (levels, needle) in [
        ("[]", "dense.levels (count) must be"),
        (
            "[{ step = 0, max_distance = 0.1 }]",
            "dense.levels[0].step must be",
        ),
        (
            "[{ step = 4, max_distance = 0.1 }, { step = 2, max_distance = 0.0 }]",
            "dense.levels[1].max_distance must be",
        ),
    ] {
        let text = format!("[dense]\nlevels = {levels}\n");
        let e = SlamConfig::parse(&text, Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("c.toml") && e.contains(needle), "{text}: {e}");
    }
    // Switches that were removed: a file that still sets one is refused, the key named.
    for (section, field) in [
        ("tracking", "sync_depth"),
        ("tracking", "local_keyframes"),
        ("tracking", "keypoint_edge_ratio"),
        ("tracking", "epipolar_rotation"),
        ("dense", "fused_model"),
        ("dense", "photometric_sigma"),
        ("dense", "robust_edges"),
        ("dense", "edge_information"),
        ("keyframes", "skip_mismatched"),
        ("correction", "blend_frames"),
        ("features", "fpfdcnn_subpixel_radius"),
    ] {
        let text = format!("[{section}]\n{field} = 0\n");
        let e = SlamConfig::parse(&text, Path::new("old.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("old.toml:2") && e.contains(&format!("unknown field `{field}`")),
            "{text}: {e}"
        );
    }
    let shipped = include_str!("../../../configs/slam/default.toml");
    assert_eq!(
        SlamConfig::parse(shipped, Path::new("configs/slam/default.toml")).unwrap(),
        cfg,
        "configs/slam/default.toml must list the defaults"
    );
    // ... every one of them: the same sections and keys as the defaults written out.
    let keys = |text: &str| -> Vec<String> {
        let table: toml::Table = toml::from_str(text).unwrap();
        let mut keys: Vec<String> = table
            .iter()
            .flat_map(|(section, fields)| {
                let fields = fields.as_table().expect("a section").keys();
                fields.map(move |field| format!("{section}.{field}"))
            })
            .collect();
        keys.sort();
        keys
    };
    assert_eq!(keys(shipped), keys(&text), "configs/slam/default.toml");
}

#[test]
fn frames_tracked_by_depth_have_their_own_keyframe_count() {
    let d = SlamConfig::default();
    assert!(!d.tracking.keypoints_every_frame && !d.tracking.monocular_flow);
    let k = &d.keyframes;
    assert_eq!(
        (
            k.max_frames,
            k.max_frames_depth_tracked,
            k.max_frames_flow_tracked
        ),
        (20, 4, 5)
    );
    for (text, names) in [
        (
            "[keyframes]\nmax_frames_depth_tracked = 0\n",
            &["keyframes.max_frames_depth_tracked"][..],
        ),
        (
            "[keyframes]\nmax_frames_flow_tracked = 0\n",
            &["keyframes.max_frames_flow_tracked"],
        ),
        (
            "[tracking]\nmonocular_flow = true\nkeypoints_every_frame = true\n",
            &["tracking.monocular_flow", "tracking.keypoints_every_frame"],
        ),
    ] {
        let e = SlamConfig::parse(text, Path::new("c.toml"))
            .unwrap_err()
            .to_string();
        assert!(names.iter().all(|n| e.contains(n)), "{text}: {e}");
    }
    // Without the dense alignment nothing tracks a frame by its depth: not an error, the
    // frames are detected (the tracker's side is tested in tests/slam_system.rs).
    let text = "[tracking]\nkeypoints_every_frame = false\n[dense]\nenabled = false\n";
    assert!(SlamConfig::parse(text, Path::new("c.toml")).is_ok());
}
