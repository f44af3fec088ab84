//! Depth beyond the keypoints (RGB-D mode): a tracked frame's pose refined against its
//! reference keyframe's whole depth image by projective point-to-plane ICP, KinectFusion's
//! association (a frame point is paired with the keyframe point its projection lands on),
//! coarse to fine, with Huber weights (and, by default, the sensor's depth noise:
//! `axial_noise`). Pixels go through the camera's distortion model both
//! ways, as everywhere else in the system. Tracking keeps the refined pose only when it agrees
//! with the pose from the keypoints (`[dense]` in `configs/slam/default.toml`).

use crate::camera::{Camera, RayTable};
use crate::dataset::DepthImage;
use crate::geometry::{Pose, renormalized};
use crate::slam::backend::pose_graph::se3_exp;
use crate::slam::config::DenseConfig;
use crate::slam::map::ViewBounds;
use nalgebra::{Matrix6, Vector2, Vector3, Vector6};
use std::sync::Arc;

/// Whether `depth` is sampled as `rays` is (the camera's image every `rays.stride` pixels:
/// full resolution in tracking, a keyframe's fusion resolution between keyframes).
fn fits(rays: &RayTable, depth: &DepthImage) -> bool {
    (depth.width, depth.height) == (rays.width, rays.height)
}

/// A keyframe's depth as points and normals on a grid of every `step`-th sample of its depth
/// image, in the keyframe's camera frame.
pub struct DepthModel {
    width: usize,
    height: usize,
    /// Point, normal and [`noise_weight`] at the point's depth, single precision (32 bytes a
    /// sample: the grid stays in cache); `None` where the depth is missing, out of range, or
    /// has no normal.
    points: Vec<Option<[f32; 7]>>,
    camera: Camera,
    /// Where projecting is reliable (the distortion polynomial folds back beyond).
    bounds: ViewBounds,
    /// No distortion: pixels from normalised coordinates directly.
    pinhole: bool,
    /// One over the grid's spacing in image pixels.
    inv_cell: f64,
    rays: Arc<RayTable>,
}

impl DepthModel {
    /// The points of `depth` every `step` samples within `range` metres, with normals from
    /// the neighbouring grid points (none across a depth jump of more than 5 % of the depth);
    /// `None` when `depth` is not sampled as `rays` is (a table of `camera`).
    pub fn new(
        depth: &DepthImage,
        camera: &Camera,
        rays: Arc<RayTable>,
        step: usize,
        range: (f64, f64),
    ) -> Option<Self> {
        if !fits(&rays, depth) {
            return None;
        }
        let step = step.max(1);
        let (width, height) = (depth.width as usize / step, depth.height as usize / step);
        let vertex = |gx: usize, gy: usize| {
            let (u, v) = (gx * step, gy * step);
            let z = f64::from(depth.data[v * depth.width as usize + u]);
            (z > range.0 && z < range.1).then(|| rays.point(u, v, z).coords)
        };
        // Three rows of vertices at a time (the row above, this one, the row below), so that
        // they stay in cache.
        let mut rows: [Vec<Option<Vector3<f64>>>; 3] = std::array::from_fn(|_| Vec::new());
        let fill = |row: &mut Vec<Option<Vector3<f64>>>, gy: usize| {
            row.clear();
            row.extend((0..width).map(|gx| vertex(gx, gy)));
        };
        let mut points = vec![None; width * height];
        if height >= 2 {
            fill(&mut rows[1], 0);
            fill(&mut rows[2], 1);
        }
        for gy in 1..height.saturating_sub(1) {
            rows.rotate_left(1);
            fill(&mut rows[2], gy + 1);
            let [above, here, below] = &rows;
            for gx in 1..width.saturating_sub(1) {
                let (Some(p), Some(l), Some(r), Some(u), Some(d)) =
                    (here[gx], here[gx - 1], here[gx + 1], above[gx], below[gx])
                else {
                    continue;
                };
                let jump = 0.05 * p.z;
                if [l, r, u, d].iter().any(|q| (q.z - p.z).abs() > jump) {
                    continue;
                }
                let n = (r - l).cross(&(d - u));
                let Some(mut n) = n.try_normalize(1e-12) else {
                    continue;
                };
                if n.dot(&p) > 0.0 {
                    n = -n;
                }
                points[gy * width + gx] = Some([
                    p.x as f32,
                    p.y as f32,
                    p.z as f32,
                    n.x as f32,
                    n.y as f32,
                    n.z as f32,
                    noise_weight(p.z) as f32,
                ]);
            }
        }
        Some(DepthModel {
            width,
            height,
            points,
            camera: camera.clone(),
            bounds: ViewBounds::new(camera),
            pinhole: camera.distortion.is_zero(),
            inv_cell: 1.0 / (step * rays.stride as usize) as f64,
            rays,
        })
    }

    /// The pixel where `p` (keyframe camera frame) projects in the keyframe's image (after
    /// the camera's distortion); `None` behind the camera or where projecting is unreliable.
    #[inline]
    fn project(&self, p: [f64; 3]) -> Option<(f64, f64)> {
        if p[2] <= 1e-6 {
            return None;
        }
        let (x, y) = (p[0] / p[2], p[1] / p[2]);
        if !self.bounds.contains_normalized(x, y) {
            return None;
        }
        let c = &self.camera;
        let (u, v) = if self.pinhole {
            (x, y)
        } else {
            let d = c.distortion.distort(Vector2::new(x, y));
            (d.x, d.y)
        };
        Some((c.fx * u + c.cx, c.fy * v + c.cy))
    }

    /// The grid sample nearest a projected pixel, as an index of `points`.
    #[inline]
    fn cell(&self, pixel: (f64, f64)) -> Option<usize> {
        // Rounded to the nearest sample (the `+ 0.5` and truncation of a non-negative value).
        let gx = pixel.0 * self.inv_cell + 0.5;
        let gy = pixel.1 * self.inv_cell + 0.5;
        if gx < 0.0 || gy < 0.0 || gx >= self.width as f64 || gy >= self.height as f64 {
            return None;
        }
        Some(gy as usize * self.width + gx as usize)
    }

    /// Asks the CPU to bring `points[cell]` into cache (it is read a few points later).
    #[inline(always)]
    fn prefetch(&self, cell: usize) {
        #[cfg(target_arch = "x86_64")]
        if let Some(p) = self.points.get(cell) {
            // SAFETY: a prefetch only hints; the address is that of an element.
            unsafe {
                use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
                _mm_prefetch::<_MM_HINT_T0>((p as *const Option<[f32; 7]>).cast());
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = cell;
    }
}

/// The outcome of [`align`].
#[derive(Debug, Clone, PartialEq)]
pub struct Alignment {
    /// The refined pose of the frame in the keyframe's camera frame (`T_kf_frame`).
    pub pose: Pose,
    /// Frame points paired within the last level's distance gate, at the pose of the last
    /// Gauss-Newton step (the returned pose is that step's result).
    pub inliers: usize,
    /// Frame points with a valid depth at the last level.
    pub points: usize,
    /// Root mean square of those pairs' point-to-plane distances, metres.
    pub rms: f64,
}

impl Alignment {
    /// Whether an alignment started from `initial` passes a frame refinement's gates: it
    /// pairs `dense.min_inlier_fraction` of the frame's points and moves `initial` by at most
    /// `dense.agree_translation` and `dense.agree_rotation_deg`.
    pub fn passes_frame_gates(&self, initial: &Pose, cfg: &DenseConfig) -> bool {
        let change = initial.inverse() * self.pose;
        self.inliers as f64 >= cfg.min_inlier_fraction * self.points as f64
            && change.translation.vector.norm() <= cfg.agree_translation
            && change.rotation.angle().to_degrees() <= cfg.agree_rotation_deg
    }

    /// Whether an alignment started from `initial` passes the keyframe edges' gates
    /// (`dense.edge_*`): it pairs `edge_min_inlier_fraction` of the frame's points and moves
    /// `initial` by at most `edge_agree_translation` and `edge_agree_rotation_deg`.
    pub fn passes_edge_gates(&self, initial: &Pose, cfg: &DenseConfig) -> bool {
        let change = initial.inverse() * self.pose;
        self.inliers as f64 >= cfg.edge_min_inlier_fraction * self.points as f64
            && change.translation.vector.norm() <= cfg.edge_agree_translation
            && change.rotation.angle().to_degrees() <= cfg.edge_agree_rotation_deg
    }
}

/// Refines `initial` (`T_kf_frame`) by point-to-plane ICP of the frame's depth against
/// `model`, one level per entry of `cfg.levels` (frame pixels sampled every `step` pixels of
/// the camera's image, pairs farther apart than `max_distance` dropped). `depth` is sampled
/// as the model's depth is. `None` when it is not,
/// too few pairs remain, or the system is degenerate (a single plane leaves directions
/// unconstrained; a near-degenerate one, a wall with a little clutter, is not caught here,
/// and the caller's agreement with the keypoint pose bounds what it can do).
pub fn align(
    model: &DepthModel,
    depth: &DepthImage,
    initial: &Pose,
    range: (f64, f64),
    cfg: &DenseConfig,
) -> Option<Alignment> {
    let rays = &model.rays;
    if !fits(rays, depth) {
        return None;
    }
    let mut weights = Weights {
        max_sq: 0.0,
        huber: cfg.huber,
        noise_weighting: cfg.noise_weighting,
    };
    let mut pose = *initial;
    let mut last = None;
    for level in &cfg.levels {
        let step = (level.step / rays.stride as usize).max(1);
        let source: Vec<Vector3<f64>> = (0..depth.height as usize)
            .step_by(step)
            .flat_map(|v| (0..depth.width as usize).step_by(step).map(move |u| (u, v)))
            .filter_map(|(u, v)| {
                let z = f64::from(depth.data[v * depth.width as usize + u]);
                (z > range.0 && z < range.1).then(|| rays.point(u, v, z).coords)
            })
            .collect();
        weights.max_sq = level.max_distance * level.max_distance;
        for _ in 0..cfg.iterations {
            let NormalEquations {
                h,
                g,
                pairs: inliers,
                sq,
            } = normal_equations(model, &source, &pose, &weights);
            if inliers < cfg.min_pairs {
                return None;
            }
            // A plane or a corridor leaves a direction unconstrained: refuse rather than drift.
            // (`try_symmetric_eigen`: `symmetric_eigenvalues` iterates without a bound, and
            // nalgebra issue #1025 is a rank-deficient matrix on which it never returns; and
            // non-finite input panics inside the eigen-solver.)
            if !h.iter().chain(g.iter()).all(|v| v.is_finite()) {
                return None;
            }
            let eig = h.try_symmetric_eigen(f64::EPSILON, 1000)?.eigenvalues;
            if eig.min() < 1e-6 * eig.max().max(1e-12) {
                return None;
            }
            let delta = h.cholesky()?.solve(&(-g));
            pose = renormalized(&(se3_exp(&delta) * pose));
            last = Some((inliers, source.len(), sq));
            if delta.norm() < 1e-5 {
                break;
            }
        }
    }
    let (inliers, points, sq) = last?;
    Some(Alignment {
        pose,
        inliers,
        points,
        rms: (sq / inliers.max(1) as f64).sqrt(),
    })
}

/// The Kinect's axial depth noise at depth `z` (metres), after Nguyen, Izadi and Lovell
/// (2012), "Modeling Kinect sensor noise for improved 3D reconstruction and tracking":
/// `σ(z) = 1.2 mm + 1.9 mm/m² · (z − 0.4 m)²`.
pub(crate) fn axial_noise(z: f64) -> f64 {
    0.0012 + 0.0019 * (z - 0.4) * (z - 0.4)
}

/// A pair's weight when the model point lies at depth `z`: the inverse variance of the
/// axial noise there, relative to its value at 1 m (1 at 1 m, 0.10 at 2 m, 0.018 at 3 m).
#[inline]
fn noise_weight(z: f64) -> f64 {
    let r = axial_noise(1.0) / axial_noise(z);
    r * r
}

/// Points summed apart in [`normal_equations`] (their sums are added in order).
const CHUNK: usize = 4096;

/// Points [`normal_equations`] places before it reads their model samples: enough to cover
/// a sample's trip from memory.
const PREFETCH_BLOCK: usize = 32;

/// One Gauss-Newton step's system from [`normal_equations`].
struct NormalEquations {
    h: Matrix6<f64>,
    g: Vector6<f64>,
    /// Pairs within the distance gate.
    pairs: usize,
    /// Their squared point-to-plane distances, summed.
    sq: f64,
}

/// How [`normal_equations`] weighs pairs.
#[derive(Debug, Clone, Copy)]
struct Weights {
    /// Pairs farther apart than this squared distance are dropped.
    max_sq: f64,
    huber: f64,
    noise_weighting: bool,
}

/// The derivative of a residual with gradient `d` along the point `p` under a left
/// perturbation `δ = (v, ω)` (`p' ≈ p + v + ω × p`): `(d, p × d)`.
#[inline]
fn jacobian(p: &[f64; 3], d: [f64; 3]) -> [f64; 6] {
    [
        d[0],
        d[1],
        d[2],
        p[1] * d[2] - p[2] * d[1],
        p[2] * d[0] - p[0] * d[2],
        p[0] * d[1] - p[1] * d[0],
    ]
}

/// Row and column of the upper triangle's entries of a 6x6 matrix, row by row.
const UPPER_ROW: [usize; 21] = [
    0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 4, 4, 5,
];
/// (See [`UPPER_ROW`].)
const UPPER_COL: [usize; 21] = [
    0, 1, 2, 3, 4, 5, 1, 2, 3, 4, 5, 2, 3, 4, 5, 3, 4, 5, 4, 5, 5,
];

/// Adds `w·jᵀj` (upper triangle, row by row) and `w·jᵀr` to the sums: each sum gets
/// `(w·j[a])·j[b]`, written as one operation over all entries so that it vectorises.
#[inline]
fn accumulate(upper: &mut [f64; 21], g: &mut [f64; 6], j: &[f64; 6], w: f64, r: f64) {
    let wa: [f64; 6] = std::array::from_fn(|a| w * j[a]);
    for k in 0..21 {
        upper[k] += wa[UPPER_ROW[k]] * j[UPPER_COL[k]];
    }
    for a in 0..6 {
        g[a] += wa[a] * r;
    }
}

/// Huber's weight for residual `r` whitened by `√wn`: `wn` within `huber`, `wn·huber/|r√wn|`
/// beyond it.
#[inline]
fn huber_weight(r: f64, wn: f64, huber: f64) -> f64 {
    if r * r * wn <= huber * huber {
        wn
    } else {
        huber * wn.sqrt() / r.abs()
    }
}

/// `JᵀWJ`, `JᵀWr`, the pair count and the sum of squared distances of one Gauss-Newton step
/// for a left perturbation `δ = (v, ω)` of `pose`: `r = n·(p − q)`, `∂r/∂δ = (n, p × n)`;
/// with `noise_weighting` each pair is weighted by [`noise_weight`] at the model point's
/// depth, and Huber's threshold applies to the residual so whitened. Chunks of [`CHUNK`]
/// points are summed apart and their sums added in order: the sums the earlier parallel
/// version gave, bit for bit.
///
/// On the calling thread: in `slam` the global pool's threads are the other stages', and
/// tracking's stage time went down when the split over them went (`lab/notes/cpu-speed.md`,
/// 2026-12-07 evening).
fn normal_equations(
    model: &DepthModel,
    source: &[Vector3<f64>],
    pose: &Pose,
    weights: &Weights,
) -> NormalEquations {
    let Weights {
        max_sq,
        huber,
        noise_weighting,
    } = *weights;
    let m = pose.rotation.to_rotation_matrix().into_inner();
    let t = pose.translation.vector;
    let chunk = |samples: &[Vector3<f64>]| {
        // The upper triangle of JᵀWJ, row by row, summed as numbers (no 6x6 temporaries).
        let mut upper = [0.0f64; 21];
        let mut g = [0.0f64; 6];
        let (mut n_pairs, mut sq) = (0usize, 0.0);
        // Points placed a block at a time, their model samples fetched while the block's
        // other points are placed; then summed in order.
        let mut placed = [([0.0f64; 3], 0usize); PREFETCH_BLOCK];
        for block in samples.chunks(PREFETCH_BLOCK) {
            let mut count = 0;
            for s in block {
                let p = [
                    m[(0, 0)] * s.x + m[(0, 1)] * s.y + m[(0, 2)] * s.z + t.x,
                    m[(1, 0)] * s.x + m[(1, 1)] * s.y + m[(1, 2)] * s.z + t.y,
                    m[(2, 0)] * s.x + m[(2, 1)] * s.y + m[(2, 2)] * s.z + t.z,
                ];
                let Some(cell) = model.project(p).and_then(|px| model.cell(px)) else {
                    continue;
                };
                model.prefetch(cell);
                placed[count] = (p, cell);
                count += 1;
            }
            for &(p, cell) in &placed[..count] {
                let Some([qx, qy, qz, nx, ny, nz, noise]) = model.points[cell] else {
                    continue;
                };
                let n = [f64::from(nx), f64::from(ny), f64::from(nz)];
                let d = [
                    p[0] - f64::from(qx),
                    p[1] - f64::from(qy),
                    p[2] - f64::from(qz),
                ];
                if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] > max_sq {
                    continue;
                }
                let r = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
                let wn = if noise_weighting {
                    f64::from(noise)
                } else {
                    1.0
                };
                let w = huber_weight(r, wn, huber);
                accumulate(&mut upper, &mut g, &jacobian(&p, n), w, r);
                n_pairs += 1;
                sq += r * r;
            }
        }
        let mut h = Matrix6::zeros();
        let mut k = 0;
        for a in 0..6 {
            for b in a..6 {
                h[(a, b)] = upper[k];
                h[(b, a)] = upper[k];
                k += 1;
            }
        }
        NormalEquations {
            h,
            g: Vector6::from(g),
            pairs: n_pairs,
            sq,
        }
    };
    let empty = NormalEquations {
        h: Matrix6::zeros(),
        g: Vector6::zeros(),
        pairs: 0,
        sq: 0.0,
    };
    source
        .chunks(CHUNK)
        .map(chunk)
        .fold(empty, |a, b| NormalEquations {
            h: a.h + b.h,
            g: a.g + b.g,
            pairs: a.pairs + b.pairs,
            sq: a.sq + b.sq,
        })
}

#[cfg(test)]
pub(crate) mod tests;
