//! Local bundle adjustment (ORB-SLAM's LocalMapping, Mur-Artal et al., T-RO 2015,
//! section VI-D): when keyframe `k` has been linked to the map, the poses of its window
//! — `k`, the keyframes its verified pairs matched it with, then its predecessors, at most
//! `local_keyframes` — and the world points those keyframes observe are optimised together;
//! keyframes outside the window that observe the same points take part with fixed poses.
//! The cost is the final adjustment's ([`super::bundle_adjustment::adjust`]: reprojection
//! plus RGB-D depth term, Huber, χ² gate) with the pose graph's edges among the keyframes
//! taking part. Bounded per keyframe: the window, the points its constraints join, and
//! `local_iterations` Levenberg-Marquardt iterations.
//!
//! It refines the *live* estimate: the poses the semantic map is fused with during the run
//! (and, in monocular mode, the baselines of multi-view depth). The final trajectory comes
//! from the global solve over every keyframe at the end, which starts from the tracked poses
//! (also when there is no pose graph to solve) and does not read these. The adjustment reads only keyframes up to `k` and the
//! constraints correction wrote, and runs on the correction thread after `k`'s constraints,
//! so threaded and single-thread runs give the same live poses.

use super::bundle_adjustment::{BaSettings, BaSummary, Track, adjust, find, track_of_group};
use super::pose_graph::Edge;
use crate::camera::Camera;
use crate::geometry::{Pose, renormalized};
use crate::slam::map::Map;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The window of keyframe `k` (at most `size`, sorted): `k`, the keyframes up to `k` whose
/// constraints with `k` carry the most matches (ties: the newer), then `k`'s predecessors.
pub fn window(map: &Map, k: usize, size: usize) -> Vec<usize> {
    if size == 0 || k >= map.keyframes.len() {
        return Vec::new();
    }
    let mut shared: BTreeMap<usize, usize> = BTreeMap::new();
    for c in map.constraints.iter().filter(|c| c.b == k && c.a < k) {
        *shared.entry(c.a).or_default() += c.matches.len();
    }
    let mut linked: Vec<(usize, usize)> = shared.into_iter().filter(|s| s.1 > 0).collect();
    linked.sort_by(|a, b| b.1.cmp(&a.1).then(b.0.cmp(&a.0)));
    let mut ids = vec![k];
    ids.extend(linked.iter().map(|s| s.0));
    ids.extend((0..k).rev());
    let mut window = Vec::with_capacity(size);
    for id in ids {
        if window.len() == size {
            break;
        }
        if !window.contains(&id) {
            window.push(id);
        }
    }
    window.sort_unstable();
    window
}

/// A local adjustment's problem: the keyframes taking part (sorted map indices), which of
/// them are fixed, their poses, and the tracks with observations indexed into `ids`.
#[derive(Debug, Clone)]
pub struct LocalProblem {
    pub ids: Vec<usize>,
    pub fixed: Vec<bool>,
    pub poses: Vec<Pose>,
    pub tracks: Vec<Track>,
}

/// The problem of `window` (from [`window`]) in a map whose keyframes up to the window's
/// newest have poses: keypoints joined by the matches of the constraints that touch the
/// window (union-find), with a 3D point, in at least two keyframes, no keyframe twice;
/// each point starts at the mean of its back-projections. Keyframe 0, keyframes outside
/// the window and window keyframes no track sees are fixed. `None` without a track.
pub fn problem(map: &Map, window: &[usize], camera: &Camera) -> Option<LocalProblem> {
    let newest = *window.last()?;
    let in_window = |k: usize| window.binary_search(&k).is_ok();
    let mut index: BTreeMap<(usize, usize), usize> = BTreeMap::new();
    let mut parent: Vec<usize> = Vec::new();
    let mut node = |key: (usize, usize), parent: &mut Vec<usize>| {
        *index.entry(key).or_insert_with(|| {
            parent.push(parent.len());
            parent.len() - 1
        })
    };
    let has_point = |k: usize, i: usize| {
        let track = &map.keyframes[k].track;
        i < track.features.len() && track.points_cam.get(i).is_some_and(|p| p.is_some())
    };
    for c in &map.constraints {
        if c.a > newest || c.b > newest || !(in_window(c.a) || in_window(c.b)) {
            continue;
        }
        for &(ia, ib) in &c.matches {
            let (ia, ib) = (ia as usize, ib as usize);
            if !(has_point(c.a, ia) && has_point(c.b, ib)) {
                continue;
            }
            let (x, y) = (node((c.a, ia), &mut parent), node((c.b, ib), &mut parent));
            let (rx, ry) = (find(&mut parent, x), find(&mut parent, y));
            if rx != ry {
                parent[rx.max(ry)] = rx.min(ry);
            }
        }
    }
    let mut groups: BTreeMap<usize, Vec<(usize, usize)>> = BTreeMap::new();
    for (&key, &i) in &index {
        let root = find(&mut parent, i);
        groups.entry(root).or_default().push(key);
    }
    // Keys are visited sorted: each group is sorted and a repeated keyframe adjacent.
    let groups: Vec<Vec<(usize, usize)>> = groups
        .into_values()
        .filter(|g| g.len() >= 2 && g.windows(2).all(|w| w[0].0 != w[1].0))
        .collect();
    if groups.is_empty() {
        return None;
    }
    let mut ids: Vec<usize> = groups.iter().flatten().map(|o| o.0).collect();
    ids.extend_from_slice(window);
    ids.sort_unstable();
    ids.dedup();
    let slot = |k: usize| {
        ids.binary_search(&k)
            .expect("every observing keyframe is listed")
    };
    let poses: Vec<Pose> = ids.iter().map(|&k| map.keyframes[k].pose).collect();
    let tracks: Vec<Track> = groups
        .iter()
        .map(|g| track_of_group(map, camera, g, slot))
        .collect();
    // A window keyframe no track sees stays where it is, as in the final adjustment.
    let mut seen = vec![false; ids.len()];
    for o in tracks.iter().flat_map(|t: &Track| &t.observations) {
        seen[o.keyframe] = true;
    }
    let fixed = ids
        .iter()
        .zip(&seen)
        .map(|(&k, &seen)| k == 0 || !in_window(k) || !seen)
        .collect();
    Some(LocalProblem {
        ids,
        fixed,
        poses,
        tracks,
    })
}

/// Solves `p` with the pose graph's `edges` (map indices; those between keyframes taking
/// part are used). `None` when every pose is fixed.
pub fn solve(
    p: &mut LocalProblem,
    edges: &[Edge],
    camera: &Camera,
    settings: &BaSettings,
) -> Option<BaSummary> {
    if p.fixed.iter().all(|&f| f) {
        return None;
    }
    let edges = local_edges(&p.ids, edges);
    Some(adjust(
        &mut p.poses,
        &p.fixed,
        &mut p.tracks,
        &edges,
        camera,
        settings,
    ))
}

/// The edges between keyframes of `ids` (sorted map indices), renumbered into it.
pub fn local_edges(ids: &[usize], edges: &[Edge]) -> Vec<Edge> {
    let slot = |k: usize| ids.binary_search(&k).ok();
    edges
        .iter()
        .filter_map(|e| {
            Some(Edge {
                i: slot(e.i)?,
                j: slot(e.j)?,
                ..e.clone()
            })
        })
        .collect()
}

/// Writes the free poses of a solved problem into the map.
pub fn write_back(map: &mut Map, p: &LocalProblem) {
    for ((&id, pose), &fixed) in p.ids.iter().zip(&p.poses).zip(&p.fixed) {
        if !fixed {
            map.keyframes[id].pose = renormalized(pose);
        }
    }
}

/// What the local adjustments of a run did, summed over keyframes.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct LocalBaStats {
    /// Adjustments run (keyframes whose window had a track and a free pose).
    pub runs: usize,
    /// Free and fixed keyframes, tracks, observations and gated observations, summed.
    pub free_keyframes: usize,
    pub fixed_keyframes: usize,
    pub tracks: usize,
    pub observations: usize,
    pub outliers: usize,
    /// Wall time, summed and the largest single adjustment, seconds.
    pub seconds: f64,
    pub max_seconds: f64,
}

impl LocalBaStats {
    pub fn add(&mut self, s: &BaSummary, seconds: f64) {
        self.runs += 1;
        self.free_keyframes += s.free_keyframes;
        self.fixed_keyframes += s.keyframes - s.free_keyframes;
        self.tracks += s.tracks;
        self.observations += s.observations;
        self.outliers += s.outliers;
        self.seconds += seconds;
        self.max_seconds = self.max_seconds.max(seconds);
    }
}

#[cfg(test)]
mod tests {
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
}
