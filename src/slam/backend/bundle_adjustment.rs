//! Bundle adjustment (ORB-SLAM's local / global BA, Mur-Artal & Tardós 2017): keyframe
//! poses and the world points their matched keypoints observe, optimised together.
//!
//! A *track* is one world point seen by several keyframes: the keypoints that data
//! correction's verified pairs matched ([`crate::slam::map::Constraint::matches`]), joined
//! transitively ([`tracks`]); a track in which one keyframe appears twice is dropped.
//! Each observation contributes, in pixels, the reprojection error of the undistorted
//! keypoint and, where the keypoint has a depth, ORB-SLAM's RGB-D term
//! `bf (1/z − 1/d)`: the disparity error of a virtual stereo pair of baseline-focal
//! product `bf`, so that depth counts less the farther it is, as a Kinect's noise grows.
//! The cost is Huber-robust on the whitened residual; after the first half of the
//! iterations, observations beyond the χ² gate are dropped (ORB-SLAM's two rounds).
//!
//! Poses are camera-to-world and perturbed on the right, `T ← T exp(δ)` as in
//! `super::pose_graph`; the normal equations are reduced to the poses by the Schur
//! complement over the points (3x3 blocks) and solved densely by Cholesky
//! (`super::cholesky`) with Levenberg-Marquardt damping. No crate in reach fitted: the sparse solver crates
//! (`factrs`, `tiny-solver`, `apex-solver`) are not available offline here, and the problem
//! is small (tens of poses, thousands of points).

use super::pose_graph::{
    Edge, EdgeTerms, edge_terms, robust, se3_exp, se3_log, skew, sqrt_information,
};
use crate::camera::Camera;
use crate::geometry::{Pose, renormalized};
use crate::slam::config::{BundleAdjustmentConfig, RobustKernel, SlamConfig};
use crate::slam::frontend::tracking::FrameRecord;
use crate::slam::map::Map;
use nalgebra::{
    DMatrix, DVector, Matrix3, Matrix3x6, Matrix6, Point2, Point3, Vector2, Vector3, Vector6,
};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Solver settings (see `[bundle_adjustment]` in `configs/slam/default.toml`).
#[derive(Debug, Clone, PartialEq)]
pub struct BaSettings {
    /// Levenberg-Marquardt iterations (both rounds together).
    pub iterations: usize,
    /// Standard deviation of a keypoint's position, pixels.
    pub sigma_px: f64,
    /// Huber scale on the whitened residual norm.
    pub huber: f64,
    /// Observations whose squared whitened residual exceeds this after the first round
    /// are dropped (ORB-SLAM: 5.991 for two dof, 7.815 for three).
    pub outlier_chi2: f64,
    /// Baseline times focal length of the depth term, pixel metres (0: no depth term).
    pub depth_bf: f64,
    /// Robust kernel of the relative-pose edges ...
    pub edge_kernel: RobustKernel,
    /// ... and its scale on the whitened edge error.
    pub edge_delta: f64,
}

impl BaSettings {
    /// The `[bundle_adjustment]` settings with `iterations`, the depth term of sensor or
    /// (monocular) predicted depth, and the pose graph's robust kernel for the edges.
    pub fn new(cfg: &SlamConfig, monocular: bool, iterations: usize) -> Self {
        let (correction, ba) = (&cfg.correction, &cfg.bundle_adjustment);
        BaSettings {
            iterations,
            sigma_px: ba.sigma_px,
            huber: ba.huber,
            outlier_chi2: ba.outlier_chi2,
            depth_bf: if monocular {
                ba.predicted_depth_bf
            } else {
                ba.depth_bf
            },
            edge_kernel: correction.robust_kernel,
            edge_delta: correction.robust_delta,
        }
    }
}

/// The pose graph's edges with their information times `weight` (none when it is 0).
pub(crate) fn weighted_edges(edges: &[Edge], weight: f64) -> Vec<Edge> {
    edges
        .iter()
        .filter(|_| weight > 0.0)
        .map(|e| Edge {
            information: e.information * weight,
            ..e.clone()
        })
        .collect()
}

/// One keyframe's view of a track.
#[derive(Debug, Clone, PartialEq)]
pub struct Observation {
    /// Index of the observing keyframe (of the poses adjusted).
    pub keyframe: usize,
    /// The keyframe's keypoint.
    pub keypoint: usize,
    /// Undistorted normalised image coordinates of the keypoint.
    pub normalized: Vector2<f64>,
    /// Measured depth (z) of the keypoint, metres.
    pub depth: Option<f64>,
    /// Cleared when the observation fails the χ² gate.
    pub inlier: bool,
}

/// A world point and the keyframes that observe it.
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    /// World coordinates, metres.
    pub point: Point3<f64>,
    /// At most one per keyframe.
    pub observations: Vec<Observation>,
}

/// What an adjustment did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct BaSummary {
    /// Poses in the problem, and how many of them were free.
    pub keyframes: usize,
    /// Poses the adjustment was free to move (the others held fixed).
    pub free_keyframes: usize,
    /// Tracks and their observations.
    pub tracks: usize,
    /// Observations of the tracks, over all of them.
    pub observations: usize,
    /// Observations dropped by the χ² gate.
    pub outliers: usize,
    /// Robust cost before and after (the latter over the gated observations).
    pub initial_cost: f64,
    /// Robust cost after the adjustment, over the gated observations.
    pub final_cost: f64,
    /// Levenberg-Marquardt iterations run.
    pub iterations: usize,
    /// Wall time of the whole adjustment (tracks included), seconds.
    #[serde(default)]
    pub seconds: f64,
    /// Tracked frames whose pose was refined afterwards against the adjusted points.
    #[serde(default)]
    pub frames_refined: usize,
}

/// The tracks of a map: keypoints joined by the matches of its constraints, each with a
/// 3D point (sensor or predicted depth), at least two keyframes, no keyframe twice; the
/// point starts at the mean of the observations' back-projections from the current poses.
pub fn tracks(map: &Map, camera: &Camera) -> Vec<Track> {
    let mut groups = match_groups(map);
    // Groups are sorted by (keyframe, keypoint): a repeated keyframe is adjacent.
    debug_assert!(groups.iter().all(|g| g.is_sorted()));
    groups.retain(|g| g.len() >= 2 && g.windows(2).all(|w| w[0].0 != w[1].0));
    groups
        .iter()
        .map(|g| track_of_group(map, camera, g, |k| k))
        .collect()
}

/// The track of a group of `(keyframe, keypoint)` with 3D points: its point at the mean of
/// their back-projections from the current poses, each observation's keyframe numbered by
/// `slot` (the index of its pose in the adjustment).
pub(crate) fn track_of_group(
    map: &Map,
    camera: &Camera,
    group: &[(usize, usize)],
    slot: impl Fn(usize) -> usize,
) -> Track {
    let mut sum = Vector3::zeros();
    let observations = group
        .iter()
        .map(|&(k, i)| {
            let kf = &map.keyframes[k];
            let p = kf.track.points_cam[i].expect("groups hold keypoints with 3D points");
            sum += (kf.pose * p).coords;
            let px = kf.track.features.points[i];
            Observation {
                keyframe: slot(k),
                keypoint: i,
                normalized: camera.normalized(&Point2::new(px[0] as f64, px[1] as f64)),
                depth: (p.z > 1e-6).then_some(p.z),
                inlier: true,
            }
        })
        .collect();
    Track {
        point: Point3::from(sum / group.len() as f64),
        observations,
    }
}

/// Groups of `(keyframe, keypoint)` joined by the constraints' matches (union-find), each
/// sorted, keypoints with a 3D point only, in order of their first member.
pub(crate) fn match_groups(map: &Map) -> Vec<Vec<(usize, usize)>> {
    let offsets: Vec<usize> = map
        .keyframes
        .iter()
        .scan(0, |acc, k| {
            let o = *acc;
            *acc += k.track.features.len();
            Some(o)
        })
        .collect();
    let total = map.keyframes.iter().map(|k| k.track.features.len()).sum();
    let mut parent: Vec<usize> = (0..total).collect();
    let n_kf = map.keyframes.len();
    for c in &map.constraints {
        if c.a >= n_kf || c.b >= n_kf {
            continue;
        }
        let (na, nb) = (
            map.keyframes[c.a].track.features.len(),
            map.keyframes[c.b].track.features.len(),
        );
        for &(ia, ib) in &c.matches {
            let (x, y) = (offsets[c.a] + ia as usize, offsets[c.b] + ib as usize);
            if (ia as usize) < na && (ib as usize) < nb {
                let (rx, ry) = (find(&mut parent, x), find(&mut parent, y));
                if rx != ry {
                    parent[rx.max(ry)] = rx.min(ry);
                }
            }
        }
    }
    let mut groups: BTreeMap<usize, Vec<(usize, usize)>> = BTreeMap::new();
    for (k, kf) in map.keyframes.iter().enumerate() {
        let n = kf.track.features.len();
        for (i, p) in kf.track.points_cam.iter().take(n).enumerate() {
            if p.is_some() {
                let root = find(&mut parent, offsets[k] + i);
                groups.entry(root).or_default().push((k, i));
            }
        }
    }
    groups.into_values().collect()
}

/// The root of `x` in a union-find forest, halving the path on the way.
pub(crate) fn find(parent: &mut [usize], mut x: usize) -> usize {
    while parent[x] != x {
        parent[x] = parent[parent[x]];
        x = parent[x];
    }
    x
}

/// The geometry of one observation at the current estimate.
struct Residual {
    /// Whitened residual (u, v, depth; the third 0 without a depth term).
    r: Vector3<f64>,
    /// ∂r/∂δ of the pose and ∂r/∂X of the world point.
    j_pose: Matrix3x6<f64>,
    j_point: Matrix3<f64>,
}

/// Camera intrinsics the residuals need.
#[derive(Debug, Clone, Copy)]
struct Scales {
    fx: f64,
    fy: f64,
    /// `1 / sigma_px`.
    whiten: f64,
    bf: f64,
}

fn residual(pose: &Pose, point: &Point3<f64>, obs: &Observation, s: Scales) -> Option<Residual> {
    let rt = pose.rotation.inverse();
    let pc = rt * (point - pose.translation.vector);
    if pc.z <= 1e-3 {
        return None;
    }
    let iz = 1.0 / pc.z;
    let (x, y) = (pc.x * iz, pc.y * iz);
    let depth = obs.depth.filter(|_| s.bf > 0.0);
    let r = Vector3::new(
        s.fx * (x - obs.normalized.x),
        s.fy * (y - obs.normalized.y),
        depth.map_or(0.0, |d| s.bf * (iz - 1.0 / d)),
    ) * s.whiten;
    // ∂r/∂p_c, whitened.
    let a = Matrix3::new(
        s.fx * iz,
        0.0,
        -s.fx * x * iz,
        0.0,
        s.fy * iz,
        -s.fy * y * iz,
        0.0,
        0.0,
        if depth.is_some() {
            -s.bf * iz * iz
        } else {
            0.0
        },
    ) * s.whiten;
    // p_c = exp(−δ) T⁻¹ X: ∂p_c/∂ρ = −I, ∂p_c/∂φ = [p_c]×; ∂p_c/∂X = Rᵀ.
    let mut dp = Matrix3x6::zeros();
    dp.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&-Matrix3::identity());
    dp.fixed_view_mut::<3, 3>(0, 3).copy_from(&skew(&pc.coords));
    Some(Residual {
        r,
        j_pose: a * dp,
        j_point: a * rt.to_rotation_matrix().into_inner(),
    })
}

/// What stays the same during one adjustment: which poses are free, the edges and the
/// scales.
struct Problem<'a> {
    /// Index of each pose in the reduced system (`usize::MAX`: fixed).
    slot: Vec<usize>,
    free: usize,
    edges: &'a [Edge],
    scales: Scales,
    settings: &'a BaSettings,
}

/// A Levenberg-Marquardt step: increments of the free poses (by slot) and of the points.
struct Step {
    poses: Vec<Vector6<f64>>,
    points: Vec<Vector3<f64>>,
}

/// A track's share of the reduced system, kept for the back-substitution: its damped
/// inverse point block `V⁻¹`, gradient, and `Wᵀ` block per free observing pose.
struct PointBlock {
    inverse: Matrix3<f64>,
    gradient: Vector3<f64>,
    poses: Vec<(usize, Matrix3x6<f64>)>,
}

impl Problem<'_> {
    /// Robust cost of every inlier observation (one in front of no camera costs the
    /// gate) and of every edge.
    fn cost(&self, poses: &[Pose], tracks: &[Track]) -> f64 {
        let set = self.settings;
        let mut cost: f64 = self
            .edges
            .iter()
            .map(|e| edge_terms(poses, e, set.edge_kernel, set.edge_delta).cost)
            .sum();
        for t in tracks {
            for o in t.observations.iter().filter(|o| o.inlier) {
                cost += match residual(&poses[o.keyframe], &t.point, o, self.scales) {
                    Some(res) => robust(RobustKernel::Huber, set.huber, res.r.norm_squared()).0,
                    None => set.outlier_chi2,
                };
            }
        }
        cost
    }

    /// Marks observations beyond the χ² gate (or behind their camera) as outliers;
    /// returns how many are outliers now.
    fn gate(&self, poses: &[Pose], tracks: &mut [Track]) -> usize {
        let mut n = 0;
        for t in tracks.iter_mut() {
            let point = t.point;
            for o in t.observations.iter_mut() {
                let ok = o.inlier
                    && residual(&poses[o.keyframe], &point, o, self.scales)
                        .is_some_and(|r| r.r.norm_squared() <= self.settings.outlier_chi2);
                o.inlier = ok;
                n += usize::from(!ok);
            }
        }
        n
    }

    /// The poses and tracks after a step.
    fn apply(&self, poses: &[Pose], tracks: &[Track], step: &Step) -> (Vec<Pose>, Vec<Track>) {
        let poses = poses
            .iter()
            .zip(&self.slot)
            .map(|(p, &i)| match step.poses.get(i) {
                Some(d) => p * se3_exp(d),
                None => *p,
            })
            .collect();
        let mut tracks = tracks.to_vec();
        for (t, d) in tracks.iter_mut().zip(&step.points) {
            t.point += d;
        }
        (poses, tracks)
    }

    /// One damped Gauss-Newton step, reduced to the poses by the Schur complement.
    fn step(&self, poses: &[Pose], tracks: &[Track], lambda: f64) -> Option<Step> {
        let (slot, set) = (&self.slot, self.settings);
        let dim = 6 * self.free;
        let mut h = DMatrix::<f64>::zeros(dim, dim);
        let mut g = DVector::<f64>::zeros(dim);
        for e in self.edges {
            let EdgeTerms {
                omega, err, ji, jj, ..
            } = edge_terms(poses, e, set.edge_kernel, set.edge_delta);
            let vars = [(slot[e.i], ji), (slot[e.j], jj)];
            for &(a, ja) in &vars {
                if a == usize::MAX {
                    continue;
                }
                let mut ga = g.fixed_view_mut::<6, 1>(6 * a, 0);
                ga -= ja.transpose() * omega * err;
                for &(b, jb) in &vars {
                    if b != usize::MAX {
                        let mut hab = h.fixed_view_mut::<6, 6>(6 * a, 6 * b);
                        hab += ja.transpose() * omega * jb;
                    }
                }
            }
        }
        let mut blocks: Vec<Option<PointBlock>> = Vec::with_capacity(tracks.len());
        for t in tracks {
            let mut hpp = Matrix3::zeros();
            let mut gp = Vector3::zeros();
            let mut observers = Vec::new();
            for o in t.observations.iter().filter(|o| o.inlier) {
                let Some(res) = residual(&poses[o.keyframe], &t.point, o, self.scales) else {
                    continue;
                };
                let (_, w) = robust(RobustKernel::Huber, set.huber, res.r.norm_squared());
                hpp += res.j_point.transpose() * res.j_point * w;
                gp -= res.j_point.transpose() * res.r * w;
                let i = slot[o.keyframe];
                if i != usize::MAX {
                    let jc = res.j_pose;
                    let mut hcc = h.fixed_view_mut::<6, 6>(6 * i, 6 * i);
                    hcc += jc.transpose() * jc * w;
                    let mut gc = g.fixed_view_mut::<6, 1>(6 * i, 0);
                    gc -= jc.transpose() * res.r * w;
                    observers.push((i, res.j_point.transpose() * jc * w));
                }
            }
            let mut damped = hpp;
            for r in 0..3 {
                damped[(r, r)] += lambda * hpp[(r, r)].max(1e-9);
            }
            // A point seen along one ray only (no depth) has a singular block: it stays
            // put, its observations acting on the poses alone.
            let inverse = if hpp.determinant().abs() > 1e-12 {
                damped.try_inverse()
            } else {
                None
            };
            blocks.push(inverse.map(|inverse| PointBlock {
                inverse,
                gradient: gp,
                poses: observers,
            }));
        }
        for r in 0..dim {
            h[(r, r)] += lambda * h[(r, r)].max(1e-9);
        }
        // S = U − Σ W V⁻¹ Wᵀ, rhs = g_c − Σ W V⁻¹ g_p.
        for b in blocks.iter().flatten() {
            let vg = b.inverse * b.gradient;
            for (i, wi) in &b.poses {
                let w_vinv = wi.transpose() * b.inverse;
                let mut gc = g.fixed_view_mut::<6, 1>(6 * i, 0);
                gc -= wi.transpose() * vg;
                for (j, wj) in &b.poses {
                    let mut sij = h.fixed_view_mut::<6, 6>(6 * i, 6 * j);
                    sij -= w_vinv * wj;
                }
            }
        }
        let dx = if dim > 0 {
            super::cholesky::solve_spd(h, &g)?
        } else {
            DVector::zeros(0)
        };
        let pose_steps: Vec<Vector6<f64>> = (0..self.free)
            .map(|i| Vector6::from_fn(|r, _| dx[6 * i + r]))
            .collect();
        let points = blocks
            .iter()
            .map(|b| match b {
                Some(b) => {
                    let mut rhs = b.gradient;
                    for (i, w) in &b.poses {
                        rhs -= w * pose_steps[*i];
                    }
                    b.inverse * rhs
                }
                None => Vector3::zeros(),
            })
            .collect();
        dx.iter().all(|c| c.is_finite()).then_some(Step {
            poses: pose_steps,
            points,
        })
    }
}

/// Jointly optimises the poses not marked `fixed` and every track's point, with the
/// relative-pose `edges` (those of [`super::pose_graph`]) as further terms. At least one
/// pose must be fixed (the gauge); with none, the first is. Returns what it did; poses
/// and points are only changed by steps that lower the cost.
pub(crate) fn adjust(
    poses: &mut [Pose],
    fixed: &[bool],
    tracks: &mut [Track],
    edges: &[Edge],
    camera: &Camera,
    settings: &BaSettings,
) -> BaSummary {
    // Observations and edges naming a pose that is not there take no part.
    let n = poses.len();
    for o in tracks.iter_mut().flat_map(|t| t.observations.iter_mut()) {
        o.inlier &= o.keyframe < n;
    }
    let edges: Vec<Edge> = edges
        .iter()
        .filter(|e| e.i < n && e.j < n)
        .cloned()
        .collect();
    let edges = edges.as_slice();
    let mut fixed = fixed.to_vec();
    fixed.resize(n, true);
    if !fixed.iter().any(|&f| f) && !fixed.is_empty() {
        fixed[0] = true;
    }
    let mut slot = vec![usize::MAX; n];
    let mut free = 0;
    for (k, f) in fixed.iter().enumerate() {
        if !f {
            slot[k] = free;
            free += 1;
        }
    }
    let problem = Problem {
        slot,
        free,
        edges,
        scales: Scales {
            fx: camera.fx,
            fy: camera.fy,
            whiten: 1.0 / settings.sigma_px,
            bf: settings.depth_bf,
        },
        settings,
    };
    let mut summary = BaSummary {
        keyframes: n,
        free_keyframes: free,
        tracks: tracks.len(),
        observations: tracks.iter().map(|t| t.observations.len()).sum(),
        ..Default::default()
    };
    let mut cost = problem.cost(poses, tracks);
    summary.initial_cost = cost;
    let mut lambda = 1e-4;
    let first_round = settings.iterations.div_ceil(2);
    let mut gated = false;
    for it in 0..settings.iterations {
        if it == first_round {
            summary.outliers = problem.gate(poses, tracks);
            cost = problem.cost(poses, tracks);
            gated = true;
        }
        summary.iterations = it + 1;
        let Some(step) = problem.step(poses, tracks, lambda) else {
            lambda *= 10.0;
            continue;
        };
        let (trial, trial_tracks) = problem.apply(poses, tracks, &step);
        let new_cost = problem.cost(&trial, &trial_tracks);
        if new_cost < cost {
            let converged = (cost - new_cost) < 1e-9 * cost.max(1e-12);
            poses.copy_from_slice(&trial);
            tracks.clone_from_slice(&trial_tracks);
            cost = new_cost;
            lambda = (lambda / 3.0).max(1e-9);
            if converged && gated {
                break;
            }
        } else {
            lambda *= 4.0;
            if lambda > 1e8 && gated {
                break;
            }
            lambda = lambda.min(1e8);
        }
    }
    if !gated && settings.iterations > 0 {
        summary.outliers = problem.gate(poses, tracks);
        cost = problem.cost(poses, tracks);
    }
    summary.final_cost = cost;
    summary
}

/// Adjusts a whole map after the final pose-graph solve: every keyframe's pose (the newest
/// `max_keyframes` free, the first always fixed, and any keyframe no track sees) and the
/// tracks' points, with the pose graph's `edges` weighted by `edge_weight`. `None` when
/// off or when there is nothing to adjust; else what it did and the adjusted tracks.
pub(crate) fn adjust_map(
    map: &mut Map,
    edges: &[Edge],
    camera: &Camera,
    cfg: &SlamConfig,
    monocular: bool,
) -> Option<(BaSummary, Vec<Track>)> {
    let ba = &cfg.bundle_adjustment;
    let n = map.keyframes.len();
    if !ba.enabled || n < 2 {
        return None;
    }
    let started = std::time::Instant::now();
    let mut tracks = tracks(map, camera);
    if tracks.is_empty() {
        return None;
    }
    let mut seen = vec![false; n];
    for o in tracks.iter().flat_map(|t| &t.observations) {
        seen[o.keyframe] = true;
    }
    let first_free = n.saturating_sub(ba.max_keyframes).max(1);
    let fixed: Vec<bool> = (0..n).map(|k| k < first_free || !seen[k]).collect();
    let settings = BaSettings::new(cfg, monocular, ba.iterations);
    let mut poses: Vec<Pose> = map.keyframes.iter().map(|k| k.pose).collect();
    let edges = weighted_edges(edges, ba.edge_weight);
    let mut summary = adjust(&mut poses, &fixed, &mut tracks, &edges, camera, &settings);
    for (kf, p) in map.keyframes.iter_mut().zip(&poses) {
        kf.pose = renormalized(p);
    }
    map.epoch += 1;
    summary.seconds = started.elapsed().as_secs_f64();
    Some((summary, tracks))
}

/// Refines each tracked frame's pose after the adjustment (ORB-SLAM's motion-only BA):
/// its PnP inliers against the reference keyframe, now seen at the adjusted track points
/// (or, for keypoints in no track, at the keyframe's own 3D point from its adjusted pose),
/// with the same reprojection and depth terms; a frame with fewer than
/// `pnp.min_inliers` such points keeps its pose. Returns how many frames were refined.
pub(crate) fn refine_frames(
    map: &Map,
    tracks: &[Track],
    frames: &mut [FrameRecord],
    camera: &Camera,
    cfg: &SlamConfig,
    monocular: bool,
) -> usize {
    let b = &cfg.bundle_adjustment;
    if !b.refine_frames {
        return 0;
    }
    let mut adjusted: BTreeMap<(usize, usize), Point3<f64>> = BTreeMap::new();
    for t in tracks {
        for o in t.observations.iter().filter(|o| o.inlier) {
            adjusted.insert((o.keyframe, o.keypoint), t.point);
        }
    }
    let scales = Scales {
        fx: camera.fx,
        fy: camera.fy,
        whiten: 1.0 / b.sigma_px,
        bf: if monocular { 0.0 } else { b.depth_bf },
    };
    let (min_depth, max_depth) = (cfg.tracking.min_depth, cfg.tracking.max_depth);
    let d = &cfg.dense;
    let dense_sqrt_info = sqrt_information(d.prior_sigma_translation, d.prior_sigma_rotation_deg);
    let mut refined = 0;
    for f in frames.iter_mut() {
        let Some((k, kf)) = f
            .reference
            .and_then(|k| map.keyframes.get(k).map(|kf| (k, kf)))
        else {
            continue;
        };
        let points: Vec<(Point3<f64>, Observation)> = f
            .observations
            .iter()
            .filter_map(|o| {
                let i = o.keypoint as usize;
                let world = match adjusted.get(&(k, i)) {
                    Some(p) => *p,
                    None => kf.pose * (*kf.track.points_cam.get(i)?)?,
                };
                let px = Point2::new(o.pixel[0] as f64, o.pixel[1] as f64);
                let depth = o
                    .depth
                    .map(f64::from)
                    .filter(|d| *d >= min_depth.max(1e-6) && *d <= max_depth);
                Some((
                    world,
                    Observation {
                        keyframe: 0,
                        keypoint: i,
                        normalized: camera.normalized(&px),
                        depth,
                        inlier: true,
                    },
                ))
            })
            .collect();
        if points.len() < cfg.pnp.min_inliers.max(6) {
            continue;
        }
        let start = kf.pose * f.relative;
        let prior = (f.dense && !monocular).then_some((start, dense_sqrt_info));
        if let Some(pose) = refine_pose(start, points, prior, scales, b) {
            f.relative = renormalized(&(kf.pose.inverse() * pose));
            refined += 1;
        }
    }
    refined
}

/// Gauss-Newton on one pose against fixed points, Huber-weighted; the observations beyond
/// the χ² gate at the halfway pose are dropped. `prior`: a pose measured otherwise (the
/// dense refinement's) with the square root of its diagonal information, a further term
/// `‖W log(T_prior⁻¹ T)‖²`. `None` if no step lowered the cost.
fn refine_pose(
    start: Pose,
    mut points: Vec<(Point3<f64>, Observation)>,
    prior: Option<(Pose, Vector6<f64>)>,
    s: Scales,
    b: &BundleAdjustmentConfig,
) -> Option<Pose> {
    let prior_residual = |pose: &Pose| {
        prior.map(|(target, w)| se3_log(&(target.inverse() * pose)).component_mul(&w))
    };
    let cost = |pose: &Pose, points: &[(Point3<f64>, Observation)]| -> f64 {
        points
            .iter()
            .map(|(p, o)| match residual(pose, p, o, s) {
                Some(r) => robust(RobustKernel::Huber, b.huber, r.r.norm_squared()).0,
                None => b.outlier_chi2,
            })
            .sum::<f64>()
            + prior_residual(pose).map_or(0.0, |r| r.norm_squared())
    };
    let mut pose = start;
    let mut current = cost(&pose, &points);
    let mut improved = false;
    for round in 0..2 {
        if round == 1 {
            points.retain(|(p, o)| {
                residual(&pose, p, o, s).is_some_and(|r| r.r.norm_squared() <= b.outlier_chi2)
            });
            current = cost(&pose, &points);
        }
        for _ in 0..5 {
            let mut h = Matrix6::zeros();
            let mut g = Vector6::zeros();
            for (p, o) in &points {
                if let Some(r) = residual(&pose, p, o, s) {
                    let (_, w) = robust(RobustKernel::Huber, b.huber, r.r.norm_squared());
                    h += r.j_pose.transpose() * r.j_pose * w;
                    g -= r.j_pose.transpose() * r.r * w;
                }
            }
            // Right perturbation: log(T_p⁻¹ T exp(δ)) ≈ log(T_p⁻¹ T) + δ near the prior.
            if let (Some(r), Some((_, w))) = (prior_residual(&pose), prior) {
                let j = Matrix6::from_diagonal(&w);
                h += j.transpose() * j;
                g -= j.transpose() * r;
            }
            let Some(dx) = h.cholesky().map(|c| c.solve(&g)) else {
                break;
            };
            let trial = pose * se3_exp(&dx);
            let c = cost(&trial, &points);
            // A NaN cost is no improvement either.
            if c.partial_cmp(&current) != Some(std::cmp::Ordering::Less) {
                break;
            }
            pose = trial;
            current = c;
            improved = true;
        }
    }
    improved.then_some(pose)
}

#[cfg(test)]
mod tests;
