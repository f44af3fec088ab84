use super::*;
use crate::dataset::{DepthImage, LabelImage};
use crate::slam::backend::pose_graph::{se3_exp, se3_log};
use crate::slam::config::SlamConfig;
use crate::slam::frontend::keypoints::KeyFeatures;
use crate::slam::map::{Constraint, ConstraintKind, KeyFrame, KeyframeFeatures, KeyframeView};
use nalgebra::{Matrix6, Point2, Point3, Translation3, UnitQuaternion, Vector6};
use std::sync::Arc;

/// Nine keyframes along a sideways arc looking at 200 points 2-4 m away; keypoint `i` of
/// every keyframe is point `i` (with its exact depth where the keyframe sees it);
/// consecutive keyframes are linked by constraints matching the points both see.
/// Keyframes 0-3 sit at the truth, 4-8 are off by up to a few centimetres.
fn scene(camera: &Camera) -> (Map, Vec<Pose>) {
    let truth: Vec<Pose> = (0..9)
        .map(|k| {
            let k = k as f64;
            Pose::from_parts(
                Translation3::new(0.08 * k, 0.01 * k, 0.0),
                UnitQuaternion::from_euler_angles(0.005 * k, -0.02 * k, 0.0),
            )
        })
        .collect();
    let points: Vec<Point3<f64>> = (0..200)
        .map(|i| {
            let f = i as f64;
            Point3::new(
                (f * 0.37).sin() * 1.4 + 0.3,
                (f * 0.73).cos() * 0.9,
                2.0 + (f * 0.19).sin().abs() * 2.0,
            )
        })
        .collect();
    let mut map = Map::default();
    for (k, t) in truth.iter().enumerate() {
        let mut features = KeyFeatures::default();
        let mut points_cam = Vec::new();
        for p in &points {
            let pc = t.inverse() * p;
            let seen = camera.project(&pc).filter(|px| camera.contains(px, 0.0));
            let px = seen.unwrap_or(Point2::new(0.0, 0.0));
            features.points.push([px.x as f32, px.y as f32]);
            points_cam.push(seen.map(|_| pc));
        }
        let xi = Vector6::new(0.01, -0.02, 0.015, 0.004, -0.003, 0.002) * (k as f64 - 3.0);
        let pose = if k <= 3 { *t } else { t * se3_exp(&xi) };
        let (w, h) = (4, 4);
        map.keyframes.push(KeyFrame {
            id: k,
            frame_index: k,
            stamp: k as f64,
            odom_pose: pose,
            pose,
            gt_pose: Some(*t),
            track: Arc::new(KeyframeFeatures {
                features,
                points_cam,
                signature: Vec::new(),
            }),
            view: KeyframeView::new(
                1,
                &image::RgbImage::new(w, h),
                &DepthImage::new(w, h),
                &LabelImage::new(w, h, 0),
            ),
            depth_scale: 1.0,
        });
    }
    for b in 1..truth.len() {
        link(&mut map, b - 1, b);
    }
    (map, truth)
}

/// A constraint between `a` and `b` matching every point both see.
fn link(map: &mut Map, a: usize, b: usize) {
    let (ta, tb) = (&map.keyframes[a].track, &map.keyframes[b].track);
    let matches: Vec<(u32, u32)> = (0..ta.points_cam.len())
        .filter(|&i| ta.points_cam[i].is_some() && tb.points_cam[i].is_some())
        .map(|i| (i as u32, i as u32))
        .collect();
    assert!(matches.len() > 50, "{a}-{b}: {} matches", matches.len());
    map.constraints.push(Constraint {
        a,
        b,
        relative: map.keyframes[a].pose.inverse() * map.keyframes[b].pose,
        kind: ConstraintKind::Odometry,
        inliers: matches.len(),
        matches,
    });
}

fn error(a: &Pose, b: &Pose) -> f64 {
    se3_log(&(a.inverse() * b)).norm()
}

#[test]
fn the_window_is_the_keyframe_its_best_linked_ones_then_its_predecessors() {
    let (mut map, _) = scene(&Camera::tum_fr1());
    assert_eq!(window(&map, 7, 4), vec![4, 5, 6, 7]);
    assert_eq!(window(&map, 2, 10), vec![0, 1, 2]);
    link(&mut map, 1, 7);
    assert_eq!(window(&map, 7, 4), vec![1, 5, 6, 7]);
    assert!(window(&map, 7, 0).is_empty());
    assert!(window(&map, 9, 4).is_empty());
}

#[test]
fn adjusts_the_window_against_fixed_neighbours_and_reads_no_later_keyframe() {
    let camera = Camera::tum_fr1();
    let (mut map, truth) = scene(&camera);
    // Keyframe 8 is already in the map, not yet corrected: it takes no part.
    let w = window(&map, 7, 4);
    let mut p = problem(&map, &w, &camera).unwrap();
    assert_eq!(p.ids, vec![3, 4, 5, 6, 7]);
    assert_eq!(p.fixed, vec![true, false, false, false, false]);
    assert!(p.tracks.iter().all(|t| t.observations.len() >= 2));
    let before: Vec<Pose> = map.keyframes.iter().map(|k| k.pose).collect();
    assert!(error(&before[7], &truth[7]) > 0.05);
    let settings = BaSettings::new(&SlamConfig::default(), false, 20);
    let s = solve(&mut p, &[], &camera, &settings).unwrap();
    assert_eq!((s.keyframes, s.free_keyframes), (5, 4));
    write_back(&mut map, &p);
    for (k, t) in truth.iter().enumerate().take(8).skip(4) {
        let e = error(&map.keyframes[k].pose, t);
        assert!(e < 1e-5, "keyframe {k} off by {e}: {s:?}");
    }
    for k in [0, 1, 2, 3, 8] {
        assert_eq!(map.keyframes[k].pose, before[k], "keyframe {k} moved");
    }
}

#[test]
fn a_window_keyframe_no_track_sees_is_fixed() {
    let camera = Camera::tum_fr1();
    let (mut map, _) = scene(&camera);
    map.constraints
        .iter_mut()
        .filter(|c| c.b == 7)
        .for_each(|c| c.matches.clear());
    let p = problem(&map, &window(&map, 7, 4), &camera).unwrap();
    assert_eq!(p.ids, vec![3, 4, 5, 6, 7]);
    assert_eq!(p.fixed, vec![true, false, false, false, true]);
}

#[test]
fn only_edges_between_keyframes_taking_part_are_kept_and_renumbered() {
    let edge = |i: usize, j: usize| Edge {
        i,
        j,
        measurement: Pose::from_parts(
            Translation3::new(i as f64, j as f64, 0.5),
            UnitQuaternion::identity(),
        ),
        information: Matrix6::from_diagonal_element((i + j) as f64),
        robust: i == 3,
    };
    let ids = [3, 4, 5, 6, 7];
    let edges = [edge(3, 4), edge(4, 8), edge(1, 5), edge(6, 7)];
    let local = local_edges(&ids, &edges);
    assert_eq!(local.len(), 2);
    for (l, (e, (i, j))) in local.iter().zip([(&edges[0], (0, 1)), (&edges[3], (3, 4))]) {
        assert_eq!((l.i, l.j), (i, j));
        assert_eq!(l.measurement, e.measurement);
        assert_eq!(l.information, e.information);
        assert_eq!(l.robust, e.robust);
    }
}

#[test]
fn keyframe_zero_stays_fixed_and_a_window_without_tracks_is_skipped() {
    let camera = Camera::tum_fr1();
    let (mut map, _) = scene(&camera);
    let w = window(&map, 2, 10);
    let p = problem(&map, &w, &camera).unwrap();
    assert_eq!(p.fixed, vec![true, false, false]);
    map.constraints.iter_mut().for_each(|c| c.matches.clear());
    assert!(problem(&map, &w, &camera).is_none());
    // Keyframe 0 alone: nothing free.
    let mut alone = LocalProblem {
        ids: vec![0],
        fixed: vec![true],
        poses: vec![map.keyframes[0].pose],
        tracks: Vec::new(),
    };
    let settings = BaSettings::new(&SlamConfig::default(), false, 5);
    assert!(solve(&mut alone, &[], &camera, &settings).is_none());
}
