//! Depth beyond the keypoints (RGB-D mode): a tracked frame's pose refined against its
//! reference keyframe's whole depth image by projective point-to-plane ICP, KinectFusion's
//! association (a frame point is paired with the keyframe point its projection lands on),
//! coarse to fine, with Huber weights (and, by default, the sensor's depth noise:
//! [`axial_noise`]). Pixels go through the camera's distortion model both
//! ways, as everywhere else in the system. Tracking keeps the refined pose only when it agrees
//! with the pose from the keypoints (`[dense]` in `configs/slam/default.toml`).
//!
//! With `dense.photometric_sigma` > 0 and images on both sides, each pair also contributes a
//! photometric residual (the model's intensity where the frame point projects minus the
//! frame point's own), as in the hybrid RGB-D odometry of Steinbrücker, Sturm and Cremers
//! (2011) and Kerl, Sturm and Cremers (2013): it holds directions that geometry alone leaves
//! loose (sliding along a wall, a cupboard front). The frame's exposure is fitted to the
//! model's (gain and bias) after each step. Keyframe alignments use it
//! ([`super::keyframe_alignment`]); tracking's refinement does not.

use super::config::DenseConfig;
use super::map::ViewBounds;
use super::pose_graph::se3_exp;
use crate::camera::{Camera, RayTable};
use crate::dataset::DepthImage;
use crate::geometry::{Pose, renormalized};
use crate::raster::GrayF32;
use nalgebra::{Matrix6, Vector2, Vector3, Vector6};
use rayon::prelude::*;
use std::sync::Arc;

/// Whether `depth` is sampled as `rays` is (the camera's image every `rays.stride` pixels:
/// full resolution in tracking, a keyframe's fusion resolution between keyframes).
fn fits(rays: &RayTable, depth: &DepthImage) -> bool {
    (depth.width, depth.height) == (rays.width, rays.height)
}

/// Least intensity gradient (half the sum of the central differences' magnitudes along x and
/// y, per sample) of a frame sample that takes part in the photometric term: flat samples
/// carry little information and cost as much (about 40 % of a 7-Scenes kitchen image's
/// samples at the fusion resolution pass).
pub const MIN_GRADIENT: f32 = 0.02;

/// Whether the sample at `(x, y)` of `image` has [`MIN_GRADIENT`]; not at the border.
fn textured(image: &GrayF32, x: usize, y: usize) -> bool {
    let (w, h) = (image.width, image.height);
    if x == 0 || y == 0 || x + 1 >= w || y + 1 >= h {
        return false;
    }
    let gx = (image.get(x + 1, y) - image.get(x - 1, y)).abs();
    let gy = (image.get(x, y + 1) - image.get(x, y - 1)).abs();
    0.5 * (gx + gy) >= MIN_GRADIENT
}

/// Whether `image` (intensities 0-1, [`GrayF32::from_rgb`]) is sampled as `rays` is.
fn fits_intensity(rays: &RayTable, image: &GrayF32) -> bool {
    (image.width, image.height) == (rays.width as usize, rays.height as usize)
        && image.data.len() == image.width * image.height
}

/// A model's intensity with the central-difference gradients of its 3x3-binomial-smoothed
/// copy, per sample: `[I, ∂I/∂x, ∂I/∂y]` (per sample of the image, not per pixel). The
/// intensity itself is not smoothed: it is compared with a frame's unsmoothed intensity.
struct IntensityModel {
    width: usize,
    height: usize,
    samples: Vec<[f32; 3]>,
}

impl IntensityModel {
    fn new(image: &GrayF32) -> Self {
        let (w, h) = (image.width, image.height);
        let at = |x: usize, y: usize| image.get(x, y);
        // Separable [1 2 1] / 4, edges clamped.
        let blur_x: Vec<f32> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let (l, r) = (x.saturating_sub(1), (x + 1).min(w - 1));
                0.25 * at(l, y) + 0.5 * at(x, y) + 0.25 * at(r, y)
            })
            .collect();
        let smooth: Vec<f32> = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let (u, d) = (y.saturating_sub(1), (y + 1).min(h - 1));
                0.25 * blur_x[u * w + x] + 0.5 * blur_x[y * w + x] + 0.25 * blur_x[d * w + x]
            })
            .collect();
        let s = |x: usize, y: usize| smooth[y * w + x];
        let samples = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let (l, r) = (x.saturating_sub(1), (x + 1).min(w - 1));
                let (u, d) = (y.saturating_sub(1), (y + 1).min(h - 1));
                let gx = (s(r, y) - s(l, y)) / (r - l).max(1) as f32;
                let gy = (s(x, d) - s(x, u)) / (d - u).max(1) as f32;
                [at(x, y), gx, gy]
            })
            .collect();
        IntensityModel {
            width: w,
            height: h,
            samples,
        }
    }

    /// Bilinear intensity and gradient at sample coordinates `(x, y)`; `None` outside.
    #[inline]
    fn sample(&self, x: f64, y: f64) -> Option<[f64; 3]> {
        // Inside the last full cell (NaN fails too), checked before any cast.
        let inside = |v: f64, n: usize| v >= 0.0 && v < n.saturating_sub(1) as f64;
        if !(inside(x, self.width) && inside(y, self.height)) {
            return None;
        }
        let (x0, y0) = (x as usize, y as usize);
        let (ax, ay) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let i = y0 * self.width + x0;
        let [a, b, c, d] = [
            self.samples[i],
            self.samples[i + 1],
            self.samples[i + self.width],
            self.samples[i + self.width + 1],
        ];
        let mut out = [0.0; 3];
        for (k, o) in out.iter_mut().enumerate() {
            let top = a[k] + ax * (b[k] - a[k]);
            let bottom = c[k] + ax * (d[k] - c[k]);
            *o = f64::from(top + ay * (bottom - top));
        }
        Some(out)
    }
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
    /// The keyframe's intensity, for the photometric term ([`DepthModel::with_intensity`]).
    intensity: Option<IntensityModel>,
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
        let vertices: Vec<Option<Vector3<f64>>> = (0..height)
            .flat_map(|gy| (0..width).map(move |gx| (gx, gy)))
            .map(|(gx, gy)| vertex(gx, gy))
            .collect();
        let at = |gx: usize, gy: usize| vertices[gy * width + gx];
        let mut points = vec![None; width * height];
        for gy in 1..height.saturating_sub(1) {
            for gx in 1..width.saturating_sub(1) {
                let (Some(p), Some(l), Some(r), Some(u), Some(d)) = (
                    at(gx, gy),
                    at(gx - 1, gy),
                    at(gx + 1, gy),
                    at(gx, gy - 1),
                    at(gx, gy + 1),
                ) else {
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
            intensity: None,
        })
    }

    /// The model with the keyframe's intensity (sampled as its depth is) for the photometric
    /// term; unchanged when `image` is not sampled as the model's depth.
    pub fn with_intensity(mut self, image: &GrayF32) -> Self {
        if fits_intensity(&self.rays, image) {
            self.intensity = Some(IntensityModel::new(image));
        }
        self
    }

    /// Where `p` (keyframe camera frame) projects in the keyframe's image; `None` behind the
    /// camera or where projecting is unreliable.
    #[inline]
    fn project(&self, p: [f64; 3]) -> Option<Projection> {
        if p[2] <= 1e-6 {
            return None;
        }
        // Divided as before the photometric term existed, so that depth-only alignments are
        // unchanged to the bit.
        let (x, y) = (p[0] / p[2], p[1] / p[2]);
        let iz = 1.0 / p[2];
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
        Some(Projection {
            x,
            y,
            iz,
            pixel: (c.fx * u + c.cx, c.fy * v + c.cy),
        })
    }

    /// The model point, normal and weight at a projection: the nearest grid sample to its
    /// pixel.
    #[inline]
    fn lookup(&self, at: &Projection) -> Option<&[f32; 7]> {
        // Rounded to the nearest sample (the `+ 0.5` and truncation of a non-negative value).
        let gx = at.pixel.0 * self.inv_cell + 0.5;
        let gy = at.pixel.1 * self.inv_cell + 0.5;
        if gx < 0.0 || gy < 0.0 || gx >= self.width as f64 || gy >= self.height as f64 {
            return None;
        }
        self.points[gy as usize * self.width + gx as usize].as_ref()
    }

    /// The keyframe's intensity at a projection and its derivatives along the projected
    /// point: `(I, ∂I/∂p)`; `None` without an intensity image or outside it.
    #[inline]
    fn photometric(&self, at: &Projection) -> Option<(f64, [f64; 3])> {
        let intensity = self.intensity.as_ref()?;
        let per_sample = 1.0 / f64::from(self.rays.stride);
        let [i, gx, gy] = intensity.sample(at.pixel.0 * per_sample, at.pixel.1 * per_sample)?;
        // Per pixel, then through the pinhole projection (the distortion's own derivative is
        // left out: it shapes Gauss-Newton's step only; the residual is exact).
        let c = &self.camera;
        let (du, dv) = (gx * per_sample * c.fx, gy * per_sample * c.fy);
        let Projection { x, y, iz, .. } = *at;
        Some((i, [du * iz, dv * iz, -(du * x + dv * y) * iz]))
    }
}

/// A point projected into a keyframe's image: normalised coordinates, inverse depth and
/// pixel (after the camera's distortion).
#[derive(Debug, Clone, Copy)]
struct Projection {
    x: f64,
    y: f64,
    iz: f64,
    pixel: (f64, f64),
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
    /// The last Gauss-Newton step's `JᵀWJ` for a left perturbation `δ = (v, ω)` of the pose
    /// (`T ← exp(δ) T`), weights relative to the sensor's noise at 1 m: the curvature of the
    /// alignment's cost, the shape of its information.
    pub hessian: Matrix6<f64>,
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
///
/// With `intensity` (the frame's, sampled as `depth`), a model made
/// [`DepthModel::with_intensity`] and `cfg.photometric_sigma` > 0, each pair also adds the
/// photometric residual (module documentation).
pub fn align(
    model: &DepthModel,
    depth: &DepthImage,
    intensity: Option<&GrayF32>,
    initial: &Pose,
    range: (f64, f64),
    cfg: &DenseConfig,
) -> Option<Alignment> {
    let rays = &model.rays;
    if !fits(rays, depth) {
        return None;
    }
    let intensity = intensity.filter(|i| {
        cfg.photometric_sigma > 0.0 && model.intensity.is_some() && fits_intensity(rays, i)
    });
    let mut weights = Weights {
        max_sq: 0.0,
        huber: cfg.huber,
        noise_weighting: cfg.noise_weighting,
        // Intensity residuals in metres at 1 m: one sigma of intensity counts as one sigma of
        // the sensor's depth noise there.
        photometric: if intensity.is_some() {
            axial_noise(1.0) / cfg.photometric_sigma
        } else {
            0.0
        },
        brightness: Brightness::IDENTITY,
    };
    let mut pose = *initial;
    let mut last = None;
    for level in &cfg.levels {
        let step = (level.step / rays.stride as usize).max(1);
        let source: Vec<Sample> = (0..depth.height as usize)
            .step_by(step)
            .flat_map(|v| (0..depth.width as usize).step_by(step).map(move |u| (u, v)))
            .filter_map(|(u, v)| {
                let i = v * depth.width as usize + u;
                let z = f64::from(depth.data[i]);
                (z > range.0 && z < range.1).then(|| Sample {
                    point: rays.point(u, v, z).coords,
                    intensity: intensity
                        .filter(|im| textured(im, u, v))
                        .map_or(f32::NAN, |im| im.data[i]),
                })
            })
            .collect();
        // The exposure fitted so far carries over from level to level.
        weights.max_sq = level.max_distance * level.max_distance;
        for _ in 0..cfg.iterations {
            let NormalEquations {
                h,
                g,
                pairs: inliers,
                sq,
                intensities,
            } = normal_equations(model, &source, &pose, &weights);
            // The frame's exposure against the model's, from this step's pairs, for the next.
            weights.brightness = intensities.fit().unwrap_or(weights.brightness);
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
            last = Some((inliers, source.len(), sq, h));
            if delta.norm() < 1e-5 {
                break;
            }
        }
    }
    let (inliers, points, sq, hessian) = last?;
    Some(Alignment {
        pose,
        inliers,
        points,
        rms: (sq / inliers.max(1) as f64).sqrt(),
        hessian,
    })
}

/// The Kinect's axial depth noise at depth `z` (metres), after Nguyen, Izadi and Lovell
/// (2012), "Modeling Kinect sensor noise for improved 3D reconstruction and tracking":
/// `σ(z) = 1.2 mm + 1.9 mm/m² · (z − 0.4 m)²`.
pub fn axial_noise(z: f64) -> f64 {
    0.0012 + 0.0019 * (z - 0.4) * (z - 0.4)
}

/// A pair's weight when the model point lies at depth `z`: the inverse variance of the
/// axial noise there, relative to its value at 1 m (1 at 1 m, 0.10 at 2 m, 0.018 at 3 m).
#[inline]
fn noise_weight(z: f64) -> f64 {
    let r = axial_noise(1.0) / axial_noise(z);
    r * r
}

/// A frame point in its own camera frame, with its intensity (NaN: none).
#[derive(Debug, Clone, Copy)]
struct Sample {
    point: Vector3<f64>,
    intensity: f32,
}

/// The model's intensity as an affine function of the frame's, `I_model ≈ gain · I_frame +
/// bias`: exposure and white balance change between a camera's frames.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Brightness {
    gain: f64,
    bias: f64,
}

impl Brightness {
    const IDENTITY: Brightness = Brightness {
        gain: 1.0,
        bias: 0.0,
    };
}

/// Sums over the pairs with intensities on both sides (frame `f`, model `m`) for fitting a
/// [`Brightness`]: count, Σf, Σm, Σf², Σfm.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct IntensitySums([f64; 5]);

impl IntensitySums {
    fn add(&mut self, f: f64, m: f64) {
        let s = &mut self.0;
        s[0] += 1.0;
        s[1] += f;
        s[2] += m;
        s[3] += f * f;
        s[4] += f * m;
    }

    fn merge(self, other: Self) -> Self {
        let mut out = self;
        for (a, b) in out.0.iter_mut().zip(other.0) {
            *a += b;
        }
        out
    }

    /// Least squares `m ≈ gain · f + bias`; `None` with under 100 pairs, too little contrast
    /// or a gain outside [0.5, 2].
    fn fit(&self) -> Option<Brightness> {
        let [n, sf, sm, sff, sfm] = self.0;
        if n < 100.0 {
            return None;
        }
        let var = sff / n - (sf / n).powi(2);
        if var < 1e-6 {
            return None;
        }
        let gain = (sfm / n - sf / n * sm / n) / var;
        (0.5..=2.0).contains(&gain).then(|| Brightness {
            gain,
            bias: (sm - gain * sf) / n,
        })
    }
}

/// One Gauss-Newton step's system from [`normal_equations`].
struct NormalEquations {
    h: Matrix6<f64>,
    g: Vector6<f64>,
    /// Pairs within the distance gate.
    pairs: usize,
    /// Their squared point-to-plane distances, summed.
    sq: f64,
    intensities: IntensitySums,
}

/// How [`normal_equations`] weighs pairs.
#[derive(Debug, Clone, Copy)]
struct Weights {
    /// Pairs farther apart than this squared distance are dropped.
    max_sq: f64,
    huber: f64,
    noise_weighting: bool,
    /// Intensity residuals times this are metres at 1 m (0: no photometric term).
    photometric: f64,
    /// Applied to the frame's intensities before they are compared.
    brightness: Brightness,
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

/// Adds `w·jᵀj` (upper triangle, row by row) and `w·jᵀr` to the sums.
#[inline]
fn accumulate(upper: &mut [f64; 21], g: &mut Vector6<f64>, j: &[f64; 6], w: f64, r: f64) {
    let mut k = 0;
    for a in 0..6 {
        let wa = w * j[a];
        for b in j.iter().skip(a) {
            upper[k] += wa * b;
            k += 1;
        }
        g[a] += wa * r;
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
/// depth, and Huber's threshold applies to the residual so whitened. With a photometric
/// weight, each pair with intensities on both sides adds `r = k (I_model(π(p)) − gain ·
/// I_frame − bias)`, `∂r/∂δ = k (∂I/∂p, p × ∂I/∂p)`, under the same Huber threshold, and its
/// intensities go into the sums the next step's brightness is fitted from. Chunks of points are
/// summed in parallel and their sums added in order, so the result does not depend on the
/// thread count.
fn normal_equations(
    model: &DepthModel,
    source: &[Sample],
    pose: &Pose,
    weights: &Weights,
) -> NormalEquations {
    let Weights {
        max_sq,
        huber,
        noise_weighting,
        photometric,
        brightness,
    } = *weights;
    let m = pose.rotation.to_rotation_matrix().into_inner();
    let t = pose.translation.vector;
    let chunk = |samples: &[Sample]| {
        // The upper triangle of JᵀWJ, row by row, summed as numbers (no 6x6 temporaries).
        let mut upper = [0.0f64; 21];
        let mut g = Vector6::zeros();
        let (mut n_pairs, mut sq) = (0usize, 0.0);
        let mut intensities = IntensitySums::default();
        for sample in samples {
            let s = &sample.point;
            let p = [
                m[(0, 0)] * s.x + m[(0, 1)] * s.y + m[(0, 2)] * s.z + t.x,
                m[(1, 0)] * s.x + m[(1, 1)] * s.y + m[(1, 2)] * s.z + t.y,
                m[(2, 0)] * s.x + m[(2, 1)] * s.y + m[(2, 2)] * s.z + t.z,
            ];
            let Some(at) = model.project(p) else {
                continue;
            };
            let Some(&[qx, qy, qz, nx, ny, nz, noise]) = model.lookup(&at) else {
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
            if photometric > 0.0
                && !sample.intensity.is_nan()
                && let Some((i, gp)) = model.photometric(&at)
            {
                let k = photometric;
                let f = f64::from(sample.intensity);
                intensities.add(f, i);
                let r = k * (i - brightness.gain * f - brightness.bias);
                let j = jacobian(&p, [k * gp[0], k * gp[1], k * gp[2]]);
                accumulate(&mut upper, &mut g, &j, huber_weight(r, 1.0, huber), r);
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
            g,
            pairs: n_pairs,
            sq,
            intensities,
        }
    };
    let parts: Vec<_> = source.par_chunks(4096).map(chunk).collect();
    let empty = NormalEquations {
        h: Matrix6::zeros(),
        g: Vector6::zeros(),
        pairs: 0,
        sq: 0.0,
        intensities: IntensitySums::default(),
    };
    parts.into_iter().fold(empty, |a, b| NormalEquations {
        h: a.h + b.h,
        g: a.g + b.g,
        pairs: a.pairs + b.pairs,
        sq: a.sq + b.sq,
        intensities: a.intensities.merge(b.intensities),
    })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::slam::config::DenseConfig;
    use nalgebra::{Point2, Translation3, UnitQuaternion};

    /// Depth of a box room seen from `pose` (world from camera): floor, walls, and a block,
    /// so that every direction is constrained.
    pub(crate) fn render(camera: &Camera, pose: &Pose) -> DepthImage {
        let (w, h) = (camera.width, camera.height);
        let mut depth = DepthImage::new(w, h);
        // Planes n·x = d in the world frame.
        let planes = [
            (Vector3::new(0.0, 0.0, -1.0), -3.0), // back wall z = 3
            (Vector3::new(0.0, -1.0, 0.0), -1.0), // floor y = 1
            (Vector3::new(1.0, 0.0, 0.0), -1.5),  // left wall x = -1.5
            (Vector3::new(-1.0, 0.0, 0.0), -1.2), // right wall x = 1.2
        ];
        let origin = pose.translation.vector;
        for v in 0..h {
            for u in 0..w {
                let n = camera.normalized(&Point2::new(u as f64, v as f64));
                let ray_cam = Vector3::new(n.x, n.y, 1.0);
                let ray = pose.rotation * ray_cam;
                let mut best = f64::INFINITY;
                for (n, d) in &planes {
                    let den = n.dot(&ray);
                    if den.abs() > 1e-9 {
                        let t = (d - n.dot(&origin)) / den;
                        if t > 0.0 && t < best {
                            best = t;
                        }
                    }
                }
                // A block in front of the back wall: z = 2.2 for |x| < 0.4, y in [0.2, 1].
                let t = (2.2 - origin.z) / ray.z;
                let hit = origin + t * ray;
                if t > 0.0 && t < best && hit.x.abs() < 0.4 && hit.y > 0.2 && hit.y < 1.0 {
                    best = t;
                }
                if best.is_finite() {
                    // Depth is the z of the hit in the camera frame: t · ray_cam.z = t.
                    depth.data[(v * w + u) as usize] = best as f32;
                }
            }
        }
        depth
    }

    #[test]
    fn recovers_a_small_motion_from_a_perturbed_start() {
        let camera = Camera::tum_fr1().resized(160, 120);
        let kf_pose = Pose::identity();
        let frame_pose = Pose::from_parts(
            Translation3::new(0.03, -0.02, 0.05),
            UnitQuaternion::from_euler_angles(0.02, -0.03, 0.01),
        );
        let kf_depth = render(&camera, &kf_pose);
        let frame_depth = render(&camera, &frame_pose);
        let range = (0.1, 6.0);
        // A 160x120 image has 300 points at the coarsest level; a third, finer level (every
        // 2nd pixel) for precision.
        let mut levels = DenseConfig::default().levels;
        levels.push(crate::slam::config::DenseLevel {
            step: 2,
            max_distance: 0.02,
        });
        let cfg = DenseConfig {
            min_pairs: 100,
            levels,
            ..DenseConfig::default()
        };
        let rays = Arc::new(RayTable::new(&camera, 1));
        let model = DepthModel::new(&kf_depth, &camera, rays, 1, range).unwrap();
        let truth = kf_pose.inverse() * frame_pose;
        let start = Pose::from_parts(
            Translation3::new(0.01, -0.01, 0.03),
            UnitQuaternion::from_euler_angles(0.01, -0.015, 0.0),
        );
        let a = align(&model, &frame_depth, None, &start, range, &cfg).expect("aligned");
        let err = truth.inverse() * a.pose;
        assert!(
            err.translation.vector.norm() < 2e-3 && err.rotation.angle() < 1e-3,
            "error {:?} after {} pairs",
            err,
            a.inliers
        );
        assert!(a.inliers > a.points / 2, "{} of {}", a.inliers, a.points);
    }

    #[test]
    fn a_non_finite_start_is_refused_without_a_panic() {
        let camera = Camera::tum_fr1().resized(160, 120);
        let depth = render(&camera, &Pose::identity());
        let range = (0.1, 6.0);
        let rays = Arc::new(RayTable::new(&camera, 1));
        let model = DepthModel::new(&depth, &camera, rays, 1, range).unwrap();
        let cfg = DenseConfig {
            min_pairs: 100,
            ..DenseConfig::default()
        };
        let nan = Pose::from_parts(
            Translation3::new(f64::NAN, 0.0, 0.0),
            UnitQuaternion::identity(),
        );
        assert!(align(&model, &depth, None, &nan, range, &cfg).is_none());
    }

    #[test]
    fn noise_weights_follow_the_kinect_model() {
        assert!((noise_weight(1.0) - 1.0).abs() < 1e-12);
        assert!(
            (noise_weight(2.0) - 0.0963).abs() < 1e-3,
            "{}",
            noise_weight(2.0)
        );
        assert!(
            (noise_weight(3.0) - 0.0179).abs() < 1e-3,
            "{}",
            noise_weight(3.0)
        );
        assert!(noise_weight(0.5) > 1.0);
        assert!((axial_noise(3.0) - 0.014044).abs() < 1e-6);
    }

    #[test]
    fn noise_weighting_scales_each_pair_by_its_depth() {
        // A wall facing the camera, the frame nearer by `offset`: every pair has the same
        // residual, so weighting scales the whole system by one factor. 4 mm is within Huber's
        // 1 cm either way: the weight at the wall's depth (1 at 1 m, about a tenth at 2 m). 2 cm
        // is beyond it unweighted (Huber's weight 1/2); whitened at 2 m it is 6 mm, within.
        let camera = Camera::tum_fr1().resized(80, 60);
        let rays = Arc::new(RayTable::new(&camera, 1));
        let wall = |z: f32| {
            let mut d = DepthImage::new(camera.width, camera.height);
            d.data.fill(z);
            d
        };
        let w2 = noise_weight(2.0);
        for (z, offset, factor) in [
            (1.0f32, 0.004, 1.0),
            (2.0, 0.004, w2),
            (1.0, 0.02, 1.0),
            (2.0, 0.02, w2 / 0.5),
        ] {
            let model = DepthModel::new(&wall(z), &camera, rays.clone(), 1, (0.1, 6.0)).unwrap();
            let source: Vec<Sample> = (0..60)
                .flat_map(|v| (0..80).map(move |u| (u, v)))
                .map(|(u, v)| Sample {
                    point: rays.point(u, v, f64::from(z) - offset).coords,
                    intensity: f32::NAN,
                })
                .collect();
            let pose = Pose::identity();
            let weights = |noise_weighting| Weights {
                max_sq: 0.01,
                huber: 0.01,
                noise_weighting,
                photometric: 0.0,
                brightness: Brightness::IDENTITY,
            };
            let e0 = normal_equations(&model, &source, &pose, &weights(false));
            let e1 = normal_equations(&model, &source, &pose, &weights(true));
            let (h0, g0, n0, h1, g1, n1) = (e0.h, e0.g, e0.pairs, e1.h, e1.g, e1.pairs);
            assert_eq!(n0, n1);
            assert!(n0 > 3000, "{n0} pairs");
            let case = format!("wall at {z} m, {offset} m nearer");
            assert!(
                (h1 - h0 * factor).norm() < 1e-6 * h0.norm(),
                "{case}: {h1} vs {factor} x {h0}"
            );
            assert!((g1 - g0 * factor).norm() < 1e-6 * g0.norm(), "{case}");
        }
    }

    #[test]
    fn aligns_depth_sampled_every_second_pixel() {
        // A keyframe's depth at the fusion resolution: the camera's image every 2nd pixel,
        // with a ray table of the same stride; levels keep counting full-image pixels.
        let camera = Camera::tum_fr1().resized(320, 240);
        let frame_pose = Pose::from_parts(
            Translation3::new(-0.02, 0.01, 0.04),
            UnitQuaternion::from_euler_angles(-0.01, 0.02, 0.015),
        );
        let sub = |d: &DepthImage| {
            crate::slam::map::KeyframeView::new(
                2,
                &image::RgbImage::new(d.width, d.height),
                d,
                &crate::dataset::LabelImage::new(d.width, d.height, 0),
            )
            .depth
        };
        let kf_depth = sub(&render(&camera, &Pose::identity()));
        let frame_depth = sub(&render(&camera, &frame_pose));
        let range = (0.1, 6.0);
        let cfg = DenseConfig {
            min_pairs: 100,
            ..DenseConfig::default()
        };
        let rays = Arc::new(RayTable::new(&camera, 2));
        let model = DepthModel::new(&kf_depth, &camera, rays, 1, range).expect("stride 2");
        let a = align(&model, &frame_depth, None, &Pose::identity(), range, &cfg).expect("aligned");
        let err = frame_pose.inverse() * a.pose;
        assert!(
            err.translation.vector.norm() < 3e-3 && err.rotation.angle() < 2e-3,
            "error {err:?}"
        );
        // Full-resolution depth against the stride-2 model is not the same sampling.
        let full = render(&camera, &frame_pose);
        assert!(align(&model, &full, None, &Pose::identity(), range, &cfg).is_none());
    }

    /// A wall at z = 2 m (world frame) painted with a smooth two-way pattern, seen from
    /// `pose`: its depth and intensity.
    fn textured_wall(camera: &Camera, pose: &Pose) -> (DepthImage, GrayF32) {
        let (w, h) = (camera.width, camera.height);
        let mut depth = DepthImage::new(w, h);
        let mut intensity = GrayF32::new(w as usize, h as usize);
        let origin = pose.translation.vector;
        for v in 0..h {
            for u in 0..w {
                let n = camera.normalized(&Point2::new(u as f64, v as f64));
                let ray = pose.rotation * Vector3::new(n.x, n.y, 1.0);
                let t = (2.0 - origin.z) / ray.z;
                let hit = origin + t * ray;
                let i = (v * w + u) as usize;
                // Depth: the hit's z in the camera frame.
                depth.data[i] = (pose.inverse() * nalgebra::Point3::from(hit)).z as f32;
                let (x, y) = (hit.x * std::f64::consts::TAU, hit.y * std::f64::consts::TAU);
                intensity.data[i] = (0.5
                    + 0.2 * (x / 0.23).sin() * (y / 0.17).cos()
                    + 0.1 * (x / 0.41 + y / 0.29).sin()) as f32;
            }
        }
        (depth, intensity)
    }

    #[test]
    fn photometric_gradient_matches_finite_differences() {
        // At full resolution and, as keyframes keep their images, every second pixel (the
        // gradient per sample then spans two pixels).
        let camera = Camera::pinhole(320, 240, 260.0, 260.0, 159.5, 119.5);
        for stride in [1u32, 2] {
            let (full_depth, full_intensity) = textured_wall(&camera, &Pose::identity());
            let (w, h) = (camera.width / stride, camera.height / stride);
            let keep = |x: u32, y: u32| ((y * stride) * camera.width + x * stride) as usize;
            let mut depth = DepthImage::new(w, h);
            let mut intensity = GrayF32::new(w as usize, h as usize);
            for y in 0..h {
                for x in 0..w {
                    let i = (y * w + x) as usize;
                    depth.data[i] = full_depth.data[keep(x, y)];
                    intensity.data[i] = full_intensity.data[keep(x, y)];
                }
            }
            let rays = Arc::new(RayTable::new(&camera, stride));
            let model = DepthModel::new(&depth, &camera, rays, 1, (0.1, 6.0))
                .unwrap()
                .with_intensity(&intensity);
            let photometric = |p| model.project(p).and_then(|at| model.photometric(&at));
            for p in [[0.1, -0.05, 2.0], [-0.3, 0.2, 1.9], [0.25, 0.15, 2.1]] {
                let (_, grad) = photometric(p).expect("inside the image");
                let scale = grad.iter().map(|g| g.abs()).fold(0.0, f64::max);
                assert!(scale > 0.1, "stride {stride}, point {p:?}: no gradient");
                // Central differences over about a sample (bilinear values are linear
                // within one). The gradient is the smoothed image's, the values are not
                // smoothed: they agree to within a fifth, not exactly; a missing stride
                // factor (2) or a sign is far outside that.
                let eps = 0.004 * f64::from(stride);
                for k in 0..3 {
                    let (mut a, mut b) = (p, p);
                    a[k] -= eps;
                    b[k] += eps;
                    let (ia, _) = photometric(a).unwrap();
                    let (ib, _) = photometric(b).unwrap();
                    let numeric = (ib - ia) / (2.0 * eps);
                    assert!(
                        (numeric - grad[k]).abs() < 0.2 * scale,
                        "stride {stride}, point {p:?}, axis {k}: numeric {numeric}, \
                         analytic {}",
                        grad[k]
                    );
                }
            }
        }
        // Without an intensity image there is no photometric term.
        let (depth, _) = textured_wall(&camera, &Pose::identity());
        let rays = Arc::new(RayTable::new(&camera, 1));
        let plain = DepthModel::new(&depth, &camera, rays, 1, (0.1, 6.0)).unwrap();
        let at = plain.project([0.1, -0.05, 2.0]).unwrap();
        assert!(plain.lookup(&at).is_some() && plain.photometric(&at).is_none());
    }

    #[test]
    fn intensity_holds_a_textured_wall_that_depth_alone_cannot() {
        // A single plane leaves sliding along it unconstrained: ICP refuses. Its texture
        // constrains the slide, and with the photometric term the shift is found.
        let camera = Camera::pinhole(160, 120, 130.0, 130.0, 79.5, 59.5);
        let rays = Arc::new(RayTable::new(&camera, 1));
        let frame_pose = Pose::from_parts(
            Translation3::new(0.02, -0.015, 0.01),
            UnitQuaternion::from_euler_angles(0.004, -0.006, 0.003),
        );
        let (kf_depth, kf_intensity) = textured_wall(&camera, &Pose::identity());
        let (frame_depth, frame_intensity) = textured_wall(&camera, &frame_pose);
        let range = (0.1, 6.0);
        let model = DepthModel::new(&kf_depth, &camera, rays, 1, range)
            .unwrap()
            .with_intensity(&kf_intensity);
        let mut cfg = DenseConfig {
            min_pairs: 100,
            ..DenseConfig::default()
        };
        cfg.levels.push(crate::slam::config::DenseLevel {
            step: 2,
            max_distance: 0.02,
        });
        let depth_alone = align(&model, &frame_depth, None, &Pose::identity(), range, &cfg);
        assert!(depth_alone.is_none(), "{depth_alone:?}");
        cfg.photometric_sigma = 0.02;
        // Also after the frame's exposure changed (gain 0.8, bias +0.05): the fitted
        // brightness absorbs it.
        let darker = GrayF32 {
            data: frame_intensity
                .data
                .iter()
                .map(|i| 0.8 * i + 0.05)
                .collect(),
            ..frame_intensity.clone()
        };
        for (image, case) in [
            (&frame_intensity, "same exposure"),
            (&darker, "exposure change"),
        ] {
            let a = align(
                &model,
                &frame_depth,
                Some(image),
                &Pose::identity(),
                range,
                &cfg,
            )
            .expect(case);
            let err = frame_pose.inverse() * a.pose;
            assert!(
                err.translation.vector.norm() < 2e-3 && err.rotation.angle() < 1e-3,
                "{case}: error {err:?}"
            );
        }
        // ... because the fit finds it: at the true pose the model's intensity is the
        // frame's mapped back, 1.25 f - 0.0625 (a little flatter: bilinear interpolation
        // between samples lowers the contrast).
        let rays = Arc::new(RayTable::new(&camera, 1));
        let source: Vec<Sample> = (0..camera.height as usize)
            .flat_map(|v| (0..camera.width as usize).map(move |u| (u, v)))
            .filter(|&(u, v)| textured(&darker, u, v))
            .map(|(u, v)| {
                let i = v * camera.width as usize + u;
                Sample {
                    point: rays.point(u, v, f64::from(frame_depth.data[i])).coords,
                    intensity: darker.data[i],
                }
            })
            .collect();
        let weights = Weights {
            max_sq: 0.01,
            huber: cfg.huber,
            noise_weighting: true,
            photometric: 0.1,
            brightness: Brightness::IDENTITY,
        };
        let fitted = normal_equations(&model, &source, &frame_pose, &weights)
            .intensities
            .fit()
            .expect("a fit");
        assert!(
            (fitted.gain - 1.25).abs() < 0.07 && (fitted.bias + 0.0625).abs() < 0.03,
            "{fitted:?}"
        );
        // The sigma set to 0 turns the term off again, whatever images are given.
        cfg.photometric_sigma = 0.0;
        let off = align(
            &model,
            &frame_depth,
            Some(&frame_intensity),
            &Pose::identity(),
            range,
            &cfg,
        );
        assert!(off.is_none(), "{off:?}");
    }

    #[test]
    fn only_textured_samples_take_part() {
        // A ramp along x of 0.05 per sample between flat parts: its samples pass, flat ones and
        // the border do not.
        let (w, h) = (8, 6);
        let data = (0..h)
            .flat_map(|_| (0..w).map(|x: usize| (x.clamp(2, 5) as f32) * 0.05))
            .collect();
        let image = GrayF32 {
            width: w,
            height: h,
            data,
        };
        let at = |x, y| textured(&image, x, y);
        assert!(at(3, 2) && at(4, 3));
        assert!(!at(1, 2), "flat on both sides");
        assert!(!at(6, 2) && !at(0, 2) && !at(3, 0));
        // An image of another size than the model's, or with too few values, is not used.
        let rays = RayTable::new(&Camera::pinhole(8, 6, 5.0, 5.0, 4.0, 3.0), 1);
        assert!(fits_intensity(&rays, &image));
        let short = GrayF32 {
            data: vec![0.0; 10],
            ..image.clone()
        };
        assert!(!fits_intensity(&rays, &short));
        assert!(!fits_intensity(&rays, &GrayF32::new(4, 3)));
    }

    #[test]
    fn brightness_fit_recovers_gain_and_bias() {
        let mut sums = IntensitySums::default();
        for k in 0..200 {
            let f = 0.2 + 0.003 * k as f64;
            sums.add(f, 1.25 * f - 0.04);
        }
        let b = sums.fit().expect("enough pairs and contrast");
        assert!(
            (b.gain - 1.25).abs() < 1e-9 && (b.bias + 0.04).abs() < 1e-9,
            "{b:?}"
        );
        // Halves merged give the same fit.
        let (mut x, mut y) = (IntensitySums::default(), IntensitySums::default());
        for k in 0..200 {
            let f = 0.2 + 0.003 * k as f64;
            if k % 2 == 0 { &mut x } else { &mut y }.add(f, 1.25 * f - 0.04);
        }
        let merged = x.merge(y).fit().expect("the same pairs");
        assert!((merged.gain - b.gain).abs() < 1e-9 && (merged.bias - b.bias).abs() < 1e-9);
        // Too few pairs, no contrast, or an implausible gain: no fit.
        let mut few = IntensitySums::default();
        (0..50).for_each(|k| few.add(0.01 * k as f64, 0.01 * k as f64));
        assert_eq!(few.fit(), None);
        let mut flat = IntensitySums::default();
        (0..500).for_each(|_| flat.add(0.5, 0.6));
        assert_eq!(flat.fit(), None);
        let mut steep = IntensitySums::default();
        (0..500).for_each(|k| steep.add(0.001 * k as f64, 0.003 * k as f64));
        assert_eq!(steep.fit(), None);
    }

    #[test]
    fn a_single_plane_is_refused() {
        let camera = Camera::tum_fr1().resized(160, 120);
        let mut depth = DepthImage::new(camera.width, camera.height);
        depth.data.fill(2.0);
        let range = (0.1, 6.0);
        let model = DepthModel::new(
            &depth,
            &camera,
            Arc::new(RayTable::new(&camera, 1)),
            1,
            range,
        )
        .expect("the camera's size");
        let cfg = DenseConfig {
            min_pairs: 100,
            ..DenseConfig::default()
        };
        // Enough pairs (every frame point lands on the plane), but sliding along the plane
        // and turning about its normal are unconstrained.
        let a = align(&model, &depth, None, &Pose::identity(), range, &cfg);
        assert!(a.is_none(), "{a:?}");
        // A depth image of another size than the camera's: no model, no alignment.
        let small = DepthImage::new(80, 60);
        let rays = Arc::new(RayTable::new(&camera, 1));
        assert!(DepthModel::new(&small, &camera, rays, 1, range).is_none());
        assert!(align(&model, &small, None, &Pose::identity(), range, &cfg).is_none());
    }

    #[test]
    fn edge_gates_bound_the_inliers_and_the_change() {
        let cfg = DenseConfig {
            edge_min_inlier_fraction: 0.5,
            edge_agree_translation: 0.1,
            edge_agree_rotation_deg: 6.0,
            ..DenseConfig::default()
        };
        let initial = Pose::from_parts(
            Translation3::new(0.3, 0.0, 0.1),
            UnitQuaternion::from_euler_angles(0.0, 0.2, 0.0),
        );
        let found = |dx: f64, turn_deg: f64, inliers: usize| Alignment {
            pose: initial
                * Pose::from_parts(
                    Translation3::new(dx, 0.0, 0.0),
                    UnitQuaternion::from_euler_angles(turn_deg.to_radians(), 0.0, 0.0),
                ),
            inliers,
            points: 1000,
            rms: 0.01,
            hessian: Matrix6::identity(),
        };
        assert!(found(0.09, 5.0, 500).passes_edge_gates(&initial, &cfg));
        assert!(!found(0.09, 5.0, 499).passes_edge_gates(&initial, &cfg));
        assert!(!found(0.11, 0.0, 1000).passes_edge_gates(&initial, &cfg));
        assert!(!found(0.0, 6.5, 1000).passes_edge_gates(&initial, &cfg));
        assert!(!found(f64::NAN, 0.0, 1000).passes_edge_gates(&initial, &cfg));
    }
}
