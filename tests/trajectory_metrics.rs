//! Analytic checks of alignment, ATE and RPE (no evo needed).

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use sdf_slam::geometry::{Pose, Sim3};
use sdf_slam::metrics::{self, Alignment, DeltaUnit};
use sdf_slam::trajectory::Trajectory;

/// A wavy handheld-like trajectory, 100 poses at 30 Hz.
fn wavy() -> Trajectory {
    let poses = (0..100)
        .map(|i| {
            let t = i as f64 / 30.0;
            let r = UnitQuaternion::from_euler_angles(
                0.3 * (t * 1.3).sin(),
                0.2 * t,
                0.1 * (t * 2.1).cos(),
            );
            Isometry3::from_parts(
                Translation3::new(t.sin(), 0.5 * t, 0.2 * (2.0 * t).cos()),
                r,
            )
        })
        .collect();
    Trajectory::from_parts((0..100).map(|i| 100.0 + i as f64 / 30.0).collect(), poses).unwrap()
}

fn transformed(t: &Trajectory, sim: &Sim3) -> Trajectory {
    Trajectory::from_parts(
        t.stamps.clone(),
        t.poses.iter().map(|p| sim.transform_pose(p)).collect(),
    )
    .unwrap()
}

fn known_sim(scale: f64) -> Sim3 {
    Sim3 {
        rotation: *UnitQuaternion::from_euler_angles(0.4, -0.7, 1.9)
            .to_rotation_matrix()
            .matrix(),
        translation: Vector3::new(3.0, -1.0, 0.5),
        scale,
    }
}

#[test]
fn rigid_and_similarity_copies_give_zero_after_alignment() {
    let gt = wavy();
    let rigid = transformed(&gt, &known_sim(1.0));
    let r = metrics::ape(&gt, &rigid, Alignment::Se3, 0.01).unwrap();
    assert!(r.stats.max < 1e-9, "{:?}", r.stats);
    let sim = transformed(&gt, &known_sim(0.37));
    let r = metrics::ape(&gt, &sim, Alignment::Sim3, 0.01).unwrap();
    assert!(r.stats.max < 1e-9 && (r.alignment.scale - 1.0 / 0.37).abs() < 1e-9);
    // Without scale the similarity copy cannot be explained.
    assert!(
        metrics::ape(&gt, &sim, Alignment::Se3, 0.01)
            .unwrap()
            .stats
            .rmse
            > 0.05
    );
    // RPE is invariant to a rigid change of world frame.
    let r = metrics::rpe(&gt, &rigid, Alignment::None, 0.01, 1.0, DeltaUnit::Frames).unwrap();
    assert!(r.trans.max < 1e-9 && r.rot_deg.max < 1e-7);
    assert_eq!(r.trans.pairs, 99);
}

#[test]
fn constant_offset_gives_its_ate_and_zero_rpe() {
    let gt = wavy();
    let offset = Vector3::new(0.03, -0.04, 0.0); // 5 cm
    let est = Trajectory::from_parts(
        gt.stamps.clone(),
        gt.poses
            .iter()
            .map(|p| {
                Pose::from_parts(
                    Translation3::from(p.translation.vector + offset),
                    p.rotation,
                )
            })
            .collect(),
    )
    .unwrap();
    let r = metrics::ape(&gt, &est, Alignment::None, 0.01).unwrap();
    assert!((r.stats.rmse - 0.05).abs() < 1e-12 && r.stats.std < 1e-12);
    let r = metrics::rpe(&gt, &est, Alignment::None, 0.01, 5.0, DeltaUnit::Frames).unwrap();
    assert!(r.trans.max < 1e-12);
}

#[test]
fn known_rotation_drift_gives_its_rpe() {
    // Estimate yaws an extra 0.1 degree per frame about the camera z axis.
    let gt = wavy();
    let mut poses = vec![gt.poses[0]];
    for i in 1..gt.len() {
        let step = gt.poses[i - 1].inverse() * gt.poses[i];
        let extra = Pose::rotation(Vector3::z() * 0.1f64.to_radians());
        poses.push(poses[i - 1] * step * extra);
    }
    let est = Trajectory::from_parts(gt.stamps.clone(), poses).unwrap();
    let r = metrics::rpe(&gt, &est, Alignment::None, 0.01, 1.0, DeltaUnit::Frames).unwrap();
    assert!(
        (r.rot_deg.mean - 0.1).abs() < 1e-9 && r.rot_deg.std < 1e-9,
        "{:?}",
        r.rot_deg
    );
    assert!(r.trans.max < 1e-12);
}

#[test]
fn association_with_missing_and_jittered_stamps() {
    let gt = wavy();
    // Keep every other pose but one, jitter by up to +-4 ms.
    let ids: Vec<usize> = (0..gt.len()).filter(|i| i % 2 == 0 && *i != 40).collect();
    let mut est = gt.select(&ids);
    for (k, s) in est.stamps.iter_mut().enumerate() {
        *s += 0.004 * ((k as f64) * 1.7).sin();
    }
    let (r, e) = metrics::associate(&gt, &est, 0.01).unwrap();
    assert_eq!(r.len(), ids.len());
    for (k, &i) in ids.iter().enumerate() {
        assert_eq!(r.stamps[k], gt.stamps[i]);
        assert_eq!(e.stamps[k], est.stamps[k]);
    }
    // A tighter window drops the most jittered ones.
    let (r2, _) = metrics::associate(&gt, &est, 0.002).unwrap();
    assert!(r2.len() < ids.len() && !r2.is_empty());
    // Nothing in common: a clear error.
    let far = Trajectory::from_parts(vec![1.0], vec![Pose::identity()]).unwrap();
    assert!(
        metrics::associate(&gt, &far, 0.01)
            .unwrap_err()
            .to_string()
            .contains("no matching")
    );
}

#[test]
fn umeyama_recovers_a_similarity() {
    let pts: Vec<Point3<f64>> = wavy().positions();
    let sim = known_sim(2.5);
    let moved: Vec<_> = pts.iter().map(|p| sim.transform_point(p)).collect();
    let est = metrics::umeyama(&pts, &moved, true).unwrap();
    assert!((est.rotation - sim.rotation).norm() < 1e-9);
    assert!((est.translation - sim.translation).norm() < 1e-9);
    assert!((est.scale - 2.5).abs() < 1e-9);
    let line: Vec<_> = (0..5).map(|i| Point3::new(i as f64, 0.0, 0.0)).collect();
    assert!(metrics::umeyama(&line, &line, false).is_err());
}

/// A keyframe-based estimate: every frame follows its keyframe exactly, and each new
/// keyframe (every 10th frame) is 1 cm off along x from where the ground truth puts it, so
/// the error lands in the one step into each keyframe. Split at the keyframes' stamps, the
/// pairs across a switch carry all of it and the pairs within a span none.
#[test]
fn rpe_at_keyframes_puts_the_jumps_at_the_switches() {
    let gt = wavy();
    let poses = gt
        .poses
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let slip = Translation3::new(0.01 * (i / 10) as f64, 0.0, 0.0);
            Isometry3::from_parts(slip, UnitQuaternion::identity()) * p
        })
        .collect();
    let est = Trajectory::from_parts(gt.stamps.clone(), poses).unwrap();
    let r = metrics::rpe(&gt, &est, Alignment::None, 0.01, 1.0, DeltaUnit::Frames).unwrap();
    let keyframes: Vec<f64> = gt.stamps.iter().step_by(10).copied().collect();
    let split = r.at_keyframes(&keyframes);
    let (within, across) = (split.within.unwrap(), split.across.unwrap());
    assert_eq!(within.trans.pairs + across.trans.pairs, 99);
    // Frames 10, 20, ..., 90 begin a keyframe: nine pairs across a switch.
    assert_eq!(across.trans.pairs, 9);
    assert!(within.trans.max < 1e-9, "{}", within.trans.max);
    assert!((across.trans.min - 0.01).abs() < 1e-6 && (across.trans.max - 0.01).abs() < 1e-6);
    // Without keyframes every pair is within one span.
    let none = r.at_keyframes(&[]);
    assert!(none.across.is_none());
    assert_eq!(none.within.unwrap().trans.pairs, 99);
}
