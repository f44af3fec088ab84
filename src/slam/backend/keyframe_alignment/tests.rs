use super::*;
use crate::dataset::LabelImage;
use crate::geometry::Pose;
use crate::slam::frontend::depth_alignment::tests::render;
use crate::slam::map::{KeyFrame, KeyframeFeatures, KeyframeView};
use nalgebra::{Translation3, UnitQuaternion};

pub(crate) fn keyframe(id: usize, depth: &DepthImage, odom_pose: Pose) -> KeyFrame {
    let (w, h) = (depth.width, depth.height);
    KeyFrame {
        id,
        frame_index: id,
        stamp: id as f64,
        odom_pose,
        pose: odom_pose,
        gt_pose: None,
        track: Arc::new(KeyframeFeatures::default()),
        view: KeyframeView::new(
            2,
            &image::RgbImage::new(w, h),
            depth,
            &LabelImage::new(w, h, 0),
        ),
        depth_scale: 1.0,
    }
}

fn config(keyframe_edges: usize) -> SlamConfig {
    let mut cfg = SlamConfig::default();
    cfg.dense.keyframe_edges = keyframe_edges;
    cfg.dense.min_pairs = 100;
    cfg.tracking.min_depth = 0.1;
    cfg.tracking.max_depth = 6.0;
    cfg
}

/// About 1 cm and 0.3 degrees: how far tracking is off in the test scenes.
fn slip() -> Pose {
    Pose::from_parts(
        Translation3::new(0.008, -0.006, 0.004),
        UnitQuaternion::from_euler_angles(0.004, 0.0, -0.003),
    )
}

/// Three keyframes of the box room 2-4 cm apart; tracking's poses are off by about
/// 1 cm, the third one's by 5 cm (tracking slipped; the ICP finds the truth).
fn scene(camera: &Camera) -> (Map, Vec<Pose>) {
    let truth: Vec<Pose> = (0..3)
        .map(|k| {
            let k = k as f64;
            Pose::from_parts(
                Translation3::new(0.02 * k, -0.01 * k, 0.03 * k),
                UnitQuaternion::from_euler_angles(0.01 * k, -0.015 * k, 0.005 * k),
            )
        })
        .collect();
    let noise = [
        Pose::identity(),
        slip(),
        Pose::from_parts(
            Translation3::new(0.05, 0.0, 0.0),
            UnitQuaternion::identity(),
        ),
    ];
    let keyframes = truth
        .iter()
        .zip(noise)
        .enumerate()
        .map(|(k, (t, n))| keyframe(k, &render(camera, t), t * n))
        .collect();
    let map = Map {
        keyframes,
        ..Map::default()
    };
    (map, truth)
}

#[test]
fn a_pair_alignment_finds_the_relative_pose_and_refuses_an_image_of_another_size() {
    let camera = Camera::tum_fr1().resized(320, 240);
    let (_, truth) = scene(&camera);
    let mut cfg = config(1);
    cfg.map.pixel_stride = 2;
    let pair = PairAlignment::new(&camera, &cfg);
    let (a, b) = (render(&camera, &truth[0]), render(&camera, &truth[1]));
    let expected = truth[0].inverse() * truth[1];
    let start = expected * slip();
    let found = pair.refine(&a, &b, &start).unwrap().expect("aligned");
    let err = expected.inverse() * found;
    assert!(
        err.translation.vector.norm() < 3e-3 && err.rotation.angle() < 2e-3,
        "{err:?}"
    );
    let small = DepthImage::new(160, 120);
    let e = pair.refine(&a, &small, &start).unwrap_err().to_string();
    assert!(e.contains("160x120") && e.contains("320x240"), "{e}");
}

#[test]
fn edges_measure_the_true_relative_poses_and_drop_disagreeing_pairs() {
    let camera = Camera::tum_fr1().resized(320, 240);
    let (map, truth) = scene(&camera);
    let mut cfg = config(2);
    cfg.dense.edge_agree_translation = 0.03;
    let (edges, summary) = keyframe_edges(&map, &camera, &cfg);
    // Pairs (0,1), (0,2), (1,2); the two with keyframe 2 move 5 cm, beyond the 3 cm
    // gate, and are dropped.
    assert_eq!(summary.pairs, 3);
    assert_eq!(edges.len(), 1, "{edges:?}");
    assert_eq!(summary.edges, 1);
    let e = &edges[0];
    assert_eq!((e.i, e.j), (0, 1));
    let expected = truth[0].inverse() * truth[1];
    let err = expected.inverse() * e.measurement;
    assert!(
        err.translation.vector.norm() < 3e-3 && err.rotation.angle() < 2e-3,
        "{err:?}"
    );
    // About the 1 cm tracking was off by.
    assert!(summary.median_correction > 0.005, "{summary:?}");
    let sigma = config(2).dense.sigma_translation;
    assert!((e.information[(0, 0)] - 1.0 / (sigma * sigma)).abs() < 1e-6);
}

#[test]
fn the_sensors_depth_is_read_when_the_view_keeps_it() {
    let camera = Camera::tum_fr1().resized(320, 240);
    let (mut map, _) = scene(&camera);
    // Views whose filtered depth holds nothing: no edges, unless the sensor's depth is
    // kept beside it (`dense.edges_on_filtered_depth` off).
    for k in &mut map.keyframes {
        let sensor = k.view.depth.clone();
        k.view.depth.data.fill(0.0);
        k.view.unfiltered_depth = Some(sensor);
    }
    let (_, with) = keyframe_edges(&map, &camera, &config(2));
    assert_eq!(with.edges, 3, "{with:?}");
    for k in &mut map.keyframes {
        k.view.unfiltered_depth = None;
    }
    let (_, without) = keyframe_edges(&map, &camera, &config(2));
    assert_eq!(without.edges, 0, "{without:?}");
}

#[test]
fn the_default_gate_keeps_the_alignment_of_a_keyframe_tracking_slipped_on() {
    let camera = Camera::tum_fr1().resized(320, 240);
    let (map, truth) = scene(&camera);
    let cfg = config(2);
    assert!(cfg.dense.edge_agree_translation > 0.05);
    let (edges, summary) = keyframe_edges(&map, &camera, &cfg);
    assert_eq!(summary.edges, 3, "{summary:?}");
    for e in &edges {
        let expected = truth[e.i].inverse() * truth[e.j];
        let err = expected.inverse() * e.measurement;
        assert!(
            err.translation.vector.norm() < 3e-3 && err.rotation.angle() < 2e-3,
            "{e:?}: {err:?}"
        );
    }
    // Keyframe 2's edges corrected tracking's 5 cm.
    let to_2 = edges.iter().find(|e| (e.i, e.j) == (1, 2)).expect("(1,2)");
    let start = map.keyframes[1].odom_pose.inverse() * map.keyframes[2].odom_pose;
    let moved = (start.inverse() * to_2.measurement)
        .translation
        .vector
        .norm();
    assert!((0.04..0.06).contains(&moved), "{moved}");
}

#[test]
fn loop_pairs_start_from_their_constraint() {
    let camera = Camera::tum_fr1().resized(320, 240);
    let (mut map, truth) = scene(&camera);
    // A verified loop constraint between keyframes 0 and 2, its PnP pose 8 mm off: the
    // alignment starts there, not from tracking's pose of keyframe 2 (5 cm off).
    let noise = Pose::from_parts(
        Translation3::new(0.0, 0.006, -0.005),
        UnitQuaternion::from_euler_angles(0.0, 0.003, 0.0),
    );
    map.constraints.push(crate::slam::map::Constraint {
        a: 0,
        b: 2,
        relative: truth[0].inverse() * truth[2] * noise,
        kind: ConstraintKind::Proximity,
        inliers: 50,
        matches: Vec::new(),
    });
    let (edges, summary) = keyframe_edges(&map, &camera, &config(1));
    // (0,1) and (1,2) consecutive, (0,2) the loop pair; (1,2) starts 5 cm off.
    assert_eq!(summary.pairs, 3);
    assert_eq!(summary.loop_edges, 1, "{summary:?}");
    let e = edges
        .iter()
        .find(|e| (e.i, e.j) == (0, 2))
        .expect("the loop edge");
    let err = (truth[0].inverse() * truth[2]).inverse() * e.measurement;
    assert!(
        err.translation.vector.norm() < 3e-3 && err.rotation.angle() < 2e-3,
        "{err:?}"
    );
    // Off: the consecutive pairs only.
    let mut cfg = config(1);
    cfg.dense.loop_edges = false;
    let (edges, summary) = keyframe_edges(&map, &camera, &cfg);
    assert_eq!(summary.pairs, 2);
    assert!(edges.iter().all(|e| e.j == e.i + 1));
}

#[test]
fn no_edges_when_off_or_with_one_keyframe() {
    let camera = Camera::tum_fr1().resized(320, 240);
    let (mut map, _) = scene(&camera);
    let (edges, summary) = keyframe_edges(&map, &camera, &config(0));
    assert!(edges.is_empty());
    assert_eq!(summary.pairs, 0);
    map.keyframes.truncate(1);
    assert!(keyframe_edges(&map, &camera, &config(2)).0.is_empty());
    // One predecessor only: (0,1) and (1,2).
    let (map, _) = scene(&camera);
    let (_, summary) = keyframe_edges(&map, &camera, &config(1));
    assert_eq!(summary.pairs, 2);
}
