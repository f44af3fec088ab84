//! Data correction (section IV-A), the loop-closing stage.
//!
//! *Global*: every new keyframe is linked to its predecessor (odometry edge) and
//! paired with earlier keyframes — chosen at random as the paper does, by
//! camera proximity and by descriptor similarity (cosine of mean descriptors) —
//! each pair verified by range matching + PnP + RANSAC; verified pairs become
//! relative-pose constraints, and a pose graph over all keyframes is optimised
//! (`super::pose_graph`). The map is then re-fused from the corrected poses.
//!
//! *Local*: keypoints matched between keyframes are unified into one world point
//! (the average of their back-projections); each keyframe's depth is rescaled by
//! the median ratio of the unified points' depths to its own, so that surfaces
//! seen twice with slightly different depth (predicted depth above all) merge.
//!
//! Optimisation always starts from the tracked (odometry) poses with all
//! constraints known, so its result does not depend on when it runs: threaded
//! and single-thread runs agree.

use super::bundle_adjustment::{
    BaSettings, BaSummary, Track, adjust_map, match_groups, weighted_edges,
};
use super::local_bundle_adjustment;
use super::pose_graph::{Edge, LmSettings, LmSummary, information, optimise};
use crate::camera::Camera;
use crate::geometry::Pose;
use crate::slam::config::SlamConfig;
use crate::slam::frontend::keypoints::similarity;
use crate::slam::frontend::matching::verify_pair;
use crate::slam::map::{Constraint, ConstraintKind, Map, SharedMap, read, write};
use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::time::Instant;

/// Counts of the correction stage.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CorrectionStats {
    /// Keyframe pairs verified by PnP.
    pub pairs_tried: usize,
    /// Odometry edges, one from each new keyframe to its predecessor.
    pub odometry_edges: usize,
    /// Odometry edges whose keyframe pair PnP verified.
    pub odometry_verified: usize,
    /// Constraints to keyframes chosen at random.
    pub random_constraints: usize,
    /// Constraints to keyframes chosen by camera proximity.
    pub proximity_constraints: usize,
    /// Constraints to keyframes chosen by descriptor similarity.
    pub similarity_constraints: usize,
    /// Pose-graph optimisations run.
    pub optimisations: usize,
    /// Robust cost before and after the last optimisation.
    pub last_initial_cost: Option<f64>,
    /// Robust cost after the last optimisation.
    pub last_final_cost: Option<f64>,
    /// Levenberg-Marquardt iterations of the last optimisation.
    pub last_iterations: usize,
}

/// What local correction did.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct LocalSummary {
    /// Unified world points (seen in two or more keyframes).
    pub landmarks: usize,
    /// Keypoint observations merged into them.
    pub observations: usize,
    /// Keyframes whose depth was rescaled, and the extreme factors.
    pub rescaled_keyframes: usize,
    /// Smallest depth rescaling factor applied (1 when none).
    pub min_scale: f64,
    /// Largest depth rescaling factor applied (1 when none).
    pub max_scale: f64,
}

/// The correction stage.
pub(crate) struct Corrector {
    cfg: SlamConfig,
    camera: Camera,
    /// Counts so far.
    pub stats: CorrectionStats,
    /// Edges from outside the keypoints (dense keyframe alignment), joined to the
    /// constraints' edges in every later solve.
    extra_edges: Vec<Edge>,
}

impl Corrector {
    /// A correction stage for `camera` with the settings of `cfg`.
    pub fn new(cfg: SlamConfig, camera: Camera) -> Self {
        Corrector {
            cfg,
            camera,
            stats: CorrectionStats::default(),
            extra_edges: Vec::new(),
        }
    }

    /// Edges that later solves (pose graph and bundle adjustment) add to the constraints'.
    pub fn set_extra_edges(&mut self, edges: Vec<Edge>) {
        self.extra_edges = edges;
    }

    /// Links keyframe `k` (already in the map) to earlier ones. Returns whether
    /// a loop constraint (not odometry) was added.
    pub fn add_keyframe(&mut self, map: &SharedMap, k: usize) -> bool {
        if k == 0 {
            return false;
        }
        let c = &self.cfg.correction;
        // Snapshot what is needed, then verify without holding the lock.
        let (current, odom, others) = {
            let m = read(map);
            let Some(kf) = m.keyframes.get(k) else {
                return false;
            };
            let others: Vec<_> = m.keyframes[..k]
                .iter()
                .map(|o| (o.odom_pose, o.track.clone()))
                .collect();
            (kf.track.clone(), kf.odom_pose, others)
        };
        let mut added = Vec::new();
        // Odometry edge to the predecessor, verified for its matches.
        let (prev_pose, prev_track) = &others[k - 1];
        let relative = prev_pose.inverse() * odom;
        self.stats.odometry_edges += 1;
        // Its matches only serve local correction and the pose graph: with
        // both off (the frame-to-frame baseline) nothing is verified.
        let verified = if c.enabled || c.local {
            verify_pair(
                &self.camera,
                &self.cfg,
                prev_track,
                &current,
                Some(&relative),
            )
        } else {
            None
        };
        if verified.is_some() {
            self.stats.odometry_verified += 1;
        }
        let (inliers, matches) = verified.map(|v| (v.inliers, v.matches)).unwrap_or_default();
        added.push(Constraint {
            a: k - 1,
            b: k,
            relative,
            kind: ConstraintKind::Odometry,
            inliers,
            matches,
        });
        if c.enabled && k >= c.min_id_gap {
            let last = k - c.min_id_gap;
            let mut candidates: Vec<(usize, ConstraintKind)> = Vec::new();
            let push = |j: usize, kind, list: &mut Vec<(usize, ConstraintKind)>| {
                if !list.iter().any(|x| x.0 == j) {
                    list.push((j, kind));
                }
            };
            // By proximity of the camera centres and viewing directions.
            let axis = odom.rotation * Vector3::z();
            let cos_max = c.proximity_angle_deg.to_radians().cos();
            let mut near: Vec<(f64, usize)> = (0..=last)
                .filter_map(|j| {
                    let p = &others[j].0;
                    let d = (p.translation.vector - odom.translation.vector).norm();
                    let cos = (p.rotation * Vector3::z()).dot(&axis);
                    (d <= c.proximity_radius && cos >= cos_max).then_some((d, j))
                })
                .collect();
            near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            for &(_, j) in near.iter().take(c.proximity_pairs) {
                push(j, ConstraintKind::Proximity, &mut candidates);
            }
            // By descriptor similarity.
            let mut similar: Vec<(f32, usize)> = (0..=last)
                .map(|j| (similarity(&current.signature, &others[j].1.signature), j))
                .filter(|s| s.0 >= c.min_similarity)
                .collect();
            similar.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
            for &(_, j) in similar.iter().take(c.similarity_pairs) {
                push(j, ConstraintKind::Similarity, &mut candidates);
            }
            // At random, as the paper does (seeded per keyframe: reproducible).
            let mut rng =
                ChaCha8Rng::seed_from_u64(c.seed ^ (k as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
            for _ in 0..c.random_pairs {
                let j = rng.random_range(0..=last);
                push(j, ConstraintKind::Random, &mut candidates);
            }
            for (j, kind) in candidates {
                self.stats.pairs_tried += 1;
                let guess = others[j].0.inverse() * odom;
                if let Some(v) = verify_pair(
                    &self.camera,
                    &self.cfg,
                    &others[j].1,
                    &current,
                    Some(&guess),
                ) {
                    match kind {
                        ConstraintKind::Random => self.stats.random_constraints += 1,
                        ConstraintKind::Proximity => self.stats.proximity_constraints += 1,
                        ConstraintKind::Similarity => self.stats.similarity_constraints += 1,
                        ConstraintKind::Odometry => {}
                    }
                    added.push(Constraint {
                        a: j,
                        b: k,
                        relative: v.relative,
                        kind,
                        inliers: v.inliers,
                        matches: v.matches,
                    });
                }
            }
        }
        let loops = added.iter().any(|c| c.kind != ConstraintKind::Odometry);
        write(map).constraints.extend(added);
        loops
    }

    /// Optimises every keyframe pose from the tracked poses over all
    /// constraints and writes the result into the map (`None` without loop
    /// constraints, or with global correction off).
    pub fn optimise(&mut self, map: &SharedMap) -> Option<LmSummary> {
        if !self.cfg.correction.enabled {
            return None;
        }
        let (mut poses, edges) = {
            let m = read(map);
            // Keyframes the corrector has processed (later ones have no edges yet).
            let n = m.constraints.iter().map(|c| c.b + 1).max().unwrap_or(0);
            let extra = self.extra_edges.iter().any(|e| e.j < n);
            if (m.loop_constraints() == 0 && !extra) || n < 2 || n > m.keyframes.len() {
                return None;
            }
            let poses: Vec<Pose> = m.keyframes[..n].iter().map(|k| k.odom_pose).collect();
            (poses, self.edges(&m, n))
        };
        let c = &self.cfg.correction;
        let settings = LmSettings {
            iterations: c.lm_iterations,
            kernel: c.robust_kernel,
            delta: c.robust_delta,
            ..Default::default()
        };
        let summary = optimise(&mut poses, &edges, &settings);
        self.stats.optimisations += 1;
        self.stats.last_initial_cost = Some(summary.initial_cost);
        self.stats.last_final_cost = Some(summary.final_cost);
        self.stats.last_iterations = summary.iterations;
        let mut m = write(map);
        let n = poses.len();
        for (kf, p) in m.keyframes.iter_mut().zip(&poses) {
            kf.pose = *p;
        }
        // Keyframes inserted while optimising follow the last optimised one.
        if let Some(anchor) = m
            .keyframes
            .get(n - 1)
            .map(|k| k.pose * k.odom_pose.inverse())
        {
            for kf in m.keyframes.iter_mut().skip(n) {
                kf.pose = anchor * kf.odom_pose;
            }
        }
        m.epoch += 1;
        Some(summary)
    }

    /// The final solve: [`Self::optimise`] over every constraint; with nothing to solve, the
    /// keyframes go back to their tracked poses, where a solve would start, so the final
    /// estimate never depends on the live one (local bundle adjustment, run order).
    pub fn optimise_final(&mut self, map: &SharedMap) -> Option<LmSummary> {
        let summary = self.optimise(map);
        if summary.is_none() {
            for k in write(map).keyframes.iter_mut() {
                k.pose = k.odom_pose;
            }
        }
        summary
    }

    /// Bundle adjustment of the whole map from its current poses, with the pose graph's
    /// edges ([`super::bundle_adjustment::adjust_map`]).
    pub fn bundle_adjust(
        &self,
        map: &SharedMap,
        monocular: bool,
    ) -> Option<(BaSummary, Vec<Track>)> {
        let mut m = write(map);
        let edges = self.edges(&m, m.keyframes.len());
        adjust_map(&mut m, &edges, &self.camera, &self.cfg, monocular)
    }

    /// Places keyframe `k` where the correction of its predecessor puts it,
    /// `T_{k-1} T̂_{k-1}⁻¹ T̂_k` (hat: tracked), whatever pose mapping inserted it with.
    pub fn follow_predecessor(&self, map: &SharedMap, k: usize) {
        let mut m = write(map);
        if k == 0 || k >= m.keyframes.len() {
            return;
        }
        m.keyframes[k].pose = m.keyframes[k - 1].carry(&m.keyframes[k].odom_pose);
    }

    /// Local bundle adjustment of keyframe `k`'s window
    /// ([`super::local_bundle_adjustment`]): the problem is built under the read lock,
    /// solved without the lock, and its free poses written back. `None` when off or when
    /// there is nothing to adjust; else what it did and its wall time in seconds.
    pub fn adjust_local(
        &self,
        map: &SharedMap,
        k: usize,
        monocular: bool,
    ) -> Option<(BaSummary, f64)> {
        let ba = &self.cfg.bundle_adjustment;
        if !ba.enabled || ba.local_keyframes == 0 {
            return None;
        }
        let started = Instant::now();
        let (mut problem, edges) = {
            let m = read(map);
            let window = local_bundle_adjustment::window(&m, k, ba.local_keyframes);
            let problem = local_bundle_adjustment::problem(&m, &window, &self.camera)?;
            (
                problem,
                weighted_edges(&self.edges(&m, k + 1), ba.edge_weight),
            )
        };
        let settings = BaSettings::new(&self.cfg, monocular, ba.local_iterations);
        let summary =
            local_bundle_adjustment::solve(&mut problem, &edges, &self.camera, &settings)?;
        let mut m = write(map);
        local_bundle_adjustment::write_back(&mut m, &problem);
        m.epoch += 1;
        Some((summary, started.elapsed().as_secs_f64()))
    }

    fn edges(&self, m: &Map, n: usize) -> Vec<Edge> {
        let c = &self.cfg.correction;
        let info = information(c.sigma_translation, c.sigma_rotation_deg);
        m.constraints
            .iter()
            .filter(|e| e.b < n)
            .map(|e| Edge {
                i: e.a,
                j: e.b,
                measurement: e.relative,
                // An odometry edge no PnP could confirm (a restart after being
                // lost) is weak: loops may bend it.
                information: if e.kind == ConstraintKind::Odometry && e.inliers == 0 {
                    info * 1e-4
                } else {
                    info
                },
                robust: true,
            })
            .chain(self.extra_edges.iter().filter(|e| e.j < n).cloned())
            .collect()
    }
}

/// Local correction: unifies matched keypoints into world points and rescales
/// keyframe depths (see the module documentation). Sets `depth_scale` of each
/// keyframe and returns what it did and the unified points.
pub(crate) fn local_correction(
    map: &mut Map,
    cfg: &SlamConfig,
    rescale_depth: bool,
) -> (LocalSummary, Vec<Point3<f64>>) {
    let mut summary = LocalSummary {
        min_scale: 1.0,
        max_scale: 1.0,
        ..Default::default()
    };
    let n_kf = map.keyframes.len();
    let groups = match_groups(map);
    let mut landmarks = Vec::new();
    let mut ratios: Vec<Vec<f64>> = vec![Vec::new(); n_kf];
    for obs in groups.iter().filter(|g| g.len() >= 2) {
        let world: Vec<Point3<f64>> = obs
            .iter()
            .filter_map(|&(k, i)| {
                let kf = &map.keyframes[k];
                kf.track.points_cam[i].map(|p| kf.pose * p)
            })
            .collect();
        let mean =
            Point3::from(world.iter().map(|p| p.coords).sum::<Vector3<f64>>() / world.len() as f64);
        landmarks.push(mean);
        summary.observations += obs.len();
        for &(k, i) in obs {
            let kf = &map.keyframes[k];
            if let Some(own) = kf.track.points_cam[i] {
                let z = (kf.pose.inverse() * mean).z;
                if own.z > 0.0 && z > 0.0 {
                    ratios[k].push(z / own.z);
                }
            }
        }
    }
    summary.landmarks = landmarks.len();
    let c = &cfg.correction;
    for (kf, mut r) in map.keyframes.iter_mut().zip(ratios) {
        kf.depth_scale = 1.0;
        if !c.local || !rescale_depth || r.len() < c.local_min_observations.max(1) {
            continue;
        }
        r.sort_by(f64::total_cmp);
        let median = r[r.len() / 2];
        let s = median.clamp(
            1.0 - c.local_max_scale_change,
            1.0 + c.local_max_scale_change,
        );
        kf.depth_scale = s;
        summary.rescaled_keyframes += 1;
        summary.min_scale = summary.min_scale.min(s);
        summary.max_scale = summary.max_scale.max(s);
    }
    (summary, landmarks)
}
