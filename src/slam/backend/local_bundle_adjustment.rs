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
    /// Map indices of the keyframes taking part, sorted.
    pub ids: Vec<usize>,
    /// Per keyframe of `ids`: whether its pose is held fixed.
    pub fixed: Vec<bool>,
    /// Per keyframe of `ids`: its camera-to-world pose (the starting point).
    pub poses: Vec<Pose>,
    /// World points with their observations, keyframes indexed into `ids`.
    pub tracks: Vec<Track>,
}

/// The problem of `window` (from [`window`]) in a map whose keyframes up to the window's
/// newest have poses: keypoints joined by the matches of the constraints that touch the
/// window (union-find), with a 3D point, in at least two keyframes, no keyframe twice;
/// each point starts at the mean of its back-projections. Keyframe 0, keyframes outside
/// the window and window keyframes no track sees are fixed. `None` without a track.
pub(crate) fn problem(map: &Map, window: &[usize], camera: &Camera) -> Option<LocalProblem> {
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
pub(crate) fn local_edges(ids: &[usize], edges: &[Edge]) -> Vec<Edge> {
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
pub(crate) fn write_back(map: &mut Map, p: &LocalProblem) {
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
    /// Keyframes taking part with fixed poses, summed.
    pub fixed_keyframes: usize,
    /// Tracks, summed.
    pub tracks: usize,
    /// Observations, summed.
    pub observations: usize,
    /// Observations dropped by the χ² gate, summed.
    pub outliers: usize,
    /// Wall time, summed and the largest single adjustment, seconds.
    pub seconds: f64,
    /// Wall time of the longest single adjustment, seconds.
    pub max_seconds: f64,
}

impl LocalBaStats {
    /// Adds one adjustment's summary and its wall time, seconds.
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
mod tests;
