use super::*;
use crate::slam::backend::pose_graph::se3_log;
use nalgebra::{Translation3, UnitQuaternion};

fn settings(depth_bf: f64) -> BaSettings {
    BaSettings {
        iterations: 30,
        sigma_px: 1.0,
        huber: 2.796,
        outlier_chi2: 7.815,
        depth_bf,
        edge_kernel: RobustKernel::Huber,
        edge_delta: 3.0,
    }
}

/// Five cameras along a sideways arc looking at 120 points 2-4 m away, each point
/// observed exactly (pixel and depth) by every camera that sees it.
fn scene(camera: &Camera) -> (Vec<Pose>, Vec<Track>) {
    let poses: Vec<Pose> = (0..5)
        .map(|k| {
            let a = 0.04 * k as f64;
            Pose::from_parts(
                Translation3::new(0.15 * k as f64, 0.02 * k as f64, 0.0),
                UnitQuaternion::from_euler_angles(0.01 * k as f64, -a, 0.0),
            )
        })
        .collect();
    let mut tracks = Vec::new();
    for i in 0..120 {
        let f = i as f64;
        let point = Point3::new(
            (f * 0.37).sin() * 1.2 + 0.3,
            (f * 0.73).cos() * 0.8,
            2.0 + (f * 0.19).sin().abs() * 2.0,
        );
        let observations: Vec<Observation> = poses
            .iter()
            .enumerate()
            .filter_map(|(k, p)| {
                let pc = p.inverse() * point;
                let px = camera.project(&pc)?;
                camera.contains(&px, 0.0).then(|| Observation {
                    keyframe: k,
                    keypoint: i,
                    normalized: camera.normalized(&px),
                    depth: Some(pc.z),
                    inlier: true,
                })
            })
            .collect();
        if observations.len() >= 2 {
            tracks.push(Track {
                point,
                observations,
            });
        }
    }
    (poses, tracks)
}

fn perturbed(poses: &[Pose], tracks: &[Track]) -> (Vec<Pose>, Vec<Track>) {
    let noisy: Vec<Pose> = poses
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let f = k as f64;
            let xi = Vector6::new(0.02 * f.sin(), -0.015, 0.01 * f, 0.01, -0.008 * f, 0.005);
            if k == 0 { *p } else { p * se3_exp(&xi) }
        })
        .collect();
    let mut moved = tracks.to_vec();
    for (i, t) in moved.iter_mut().enumerate() {
        t.point += Vector3::new(0.03, -0.02, 0.05) * ((i % 7) as f64 / 7.0 - 0.5);
    }
    (noisy, moved)
}

fn max_error(a: &[Pose], b: &[Pose]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| se3_log(&(x.inverse() * y)).norm())
        .fold(0.0, f64::max)
}

#[test]
fn recovers_poses_and_points_from_exact_observations() {
    let camera = Camera::tum_fr1();
    let (truth, tracks) = scene(&camera);
    assert!(tracks.len() > 80, "{} tracks", tracks.len());
    for bf in [0.0, 400.0] {
        let (mut poses, mut moved) = perturbed(&truth, &tracks);
        assert!(max_error(&poses, &truth) > 0.02);
        let fixed = [true, false, false, false, false];
        let s = adjust(&mut poses, &fixed, &mut moved, &[], &camera, &settings(bf));
        assert!(s.final_cost < 1e-6 * s.initial_cost, "bf {bf}: {s:?}");
        assert_eq!(s.outliers, 0);
        // Without depth the scale is free: the arc's shape is still recovered.
        if bf > 0.0 {
            assert!(max_error(&poses, &truth) < 1e-5, "{:?}", s);
            let worst = moved
                .iter()
                .zip(&tracks)
                .map(|(a, b)| (a.point - b.point).norm())
                .fold(0.0, f64::max);
            assert!(worst < 1e-5, "point off by {worst}");
        }
        assert_eq!(poses[0], truth[0], "the fixed pose moved");
    }
}

#[test]
fn gross_mismatches_are_gated_and_do_not_bend_the_result() {
    let camera = Camera::tum_fr1();
    let (truth, mut tracks) = scene(&camera);
    // Every tenth track has one observation 25 px off (a wrong match).
    let mut wrong = 0;
    for t in tracks.iter_mut().step_by(10) {
        let o = t.observations.last_mut().unwrap();
        o.normalized.x += 25.0 / camera.fx;
        wrong += 1;
    }
    let (mut poses, mut moved) = perturbed(&truth, &tracks);
    let fixed = [true, false, false, false, false];
    let s = adjust(
        &mut poses,
        &fixed,
        &mut moved,
        &[],
        &camera,
        &settings(400.0),
    );
    assert_eq!(s.outliers, wrong, "{s:?}");
    assert!(max_error(&poses, &truth) < 1e-5, "{s:?}");
}

#[test]
fn edges_hold_poses_the_points_leave_free() {
    let camera = Camera::tum_fr1();
    let (truth, tracks) = scene(&camera);
    // Pose 4 observes nothing: only its edge to pose 3 places it.
    let tracks: Vec<Track> = tracks
        .into_iter()
        .map(|mut t| {
            t.observations.retain(|o| o.keyframe != 4);
            t
        })
        .filter(|t| t.observations.len() >= 2)
        .collect();
    let edge = Edge {
        i: 3,
        j: 4,
        measurement: truth[3].inverse() * truth[4],
        information: Matrix6::from_diagonal_element(1e4),
        robust: true,
    };
    let (mut poses, mut moved) = perturbed(&truth, &tracks);
    let fixed = [true, false, false, false, false];
    adjust(
        &mut poses,
        &fixed,
        &mut moved,
        &[edge],
        &camera,
        &settings(400.0),
    );
    assert!(max_error(&poses, &truth) < 1e-4);
}

#[test]
fn a_lone_free_pose_without_fixed_ones_keeps_the_gauge() {
    let camera = Camera::tum_fr1();
    let (truth, tracks) = scene(&camera);
    let (mut poses, mut moved) = perturbed(&truth, &tracks);
    // Nothing fixed: the first pose is held.
    let s = adjust(
        &mut poses,
        &[false; 5],
        &mut moved,
        &[],
        &camera,
        &settings(400.0),
    );
    assert_eq!(s.free_keyframes, 4);
    assert_eq!(poses[0], truth[0]);
    assert!(max_error(&poses, &truth) < 1e-5);
}

#[test]
fn motion_only_refinement_recovers_a_frame_pose() {
    let camera = Camera::tum_fr1();
    let (truth, tracks) = scene(&camera);
    let b = BundleAdjustmentConfig::default();
    let s = Scales {
        fx: camera.fx,
        fy: camera.fy,
        whiten: 1.0,
        bf: b.depth_bf,
    };
    // Camera 2's observations of the true points, one of them a 30-px mismatch.
    let mut points: Vec<(Point3<f64>, Observation)> = tracks
        .iter()
        .filter_map(|t| {
            let o = t.observations.iter().find(|o| o.keyframe == 2)?;
            Some((t.point, o.clone()))
        })
        .collect();
    assert!(points.len() > 50);
    points[0].1.normalized.y += 30.0 / camera.fy;
    let start = truth[2] * se3_exp(&Vector6::new(0.03, -0.02, 0.01, 0.01, 0.02, -0.01));
    let pose = refine_pose(start, points.clone(), None, s, &b).expect("a step lowers the cost");
    let err = se3_log(&(pose.inverse() * truth[2])).norm();
    assert!(err < 1e-6, "{err}");
    // From the truth itself no step lowers the cost beyond rounding.
    if let Some(p) = refine_pose(truth[2], points.clone(), None, s, &b) {
        assert!(se3_log(&(p.inverse() * truth[2])).norm() < 1e-9);
    }
    // A prior (the dense refinement's pose) 1 cm off the truth: a weak one moves the
    // result a little, a strong one close to itself, and each lies between the two.
    let offset = truth[2] * se3_exp(&Vector6::new(0.01, 0.0, 0.0, 0.0, 0.0, 0.0));
    let off_by = |p: &Pose| {
        let e = se3_log(&(truth[2].inverse() * p));
        (e[0], e.fixed_rows::<5>(1).norm())
    };
    let with = |sigma: f64| {
        let w = Vector6::repeat(1.0 / sigma);
        refine_pose(start, points.clone(), Some((offset, w)), s, &b).expect("refined")
    };
    let (weak, _) = off_by(&with(0.01));
    let (strong, strong_rest) = off_by(&with(1e-5));
    assert!(weak > 1e-5 && weak < 0.005, "weak prior: {weak}");
    assert!(
        strong > 0.0099 && strong <= 0.01 + 1e-9,
        "strong prior: {strong}"
    );
    assert!(strong_rest < 1e-4, "{strong_rest}");
}
