//! Multi-view depth of monocular keyframes. SDFCNN's depth from one image is right to
//! about 13 % on real held-back frames (REL), some 25 cm at 2 m, so a map fused from it
//! alone puts most points farther than 5 cm from the surface. Where a keyframe has
//! texture and earlier keyframes saw the same place from elsewhere, the depth can be
//! measured instead, as CNN-SLAM (Tateno et al. 2017) refines its network's depth by
//! small-baseline stereo: a plane sweep (Collins 1996) over depths around the prediction,
//! each hypothesis scored by the normalised cross-correlation (NCC) of the pixel's patch
//! with the patches it maps to in the earlier keyframes. The prediction bounds the search
//! (±`range` in log depth), which keeps the sweep short and its minimum unambiguous.
//!
//! A pixel is *confirmed* only when its patch has texture, the poses move it by at least
//! `min_parallax_px` across the range in some earlier keyframe, and its best score is
//! high, inside the range (not at its ends) and clearly better than every hypothesis more
//! than two steps away. Its depth is then the parabola's vertex through the best score and
//! its neighbours. The rest keep the prediction (or are dropped, as the caller chooses).

use crate::camera::Camera;
use crate::dataset::DepthImage;
use crate::geometry::Pose;
use crate::nn::nhwc::simd_fn;
use crate::slam::config::MultiviewConfig;
use image::RgbImage;
use nalgebra::{Matrix3, Point2, Point3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// A grey image in `f32` (BT.601 luma, 0-255).
#[derive(Debug, Clone, PartialEq)]
pub struct GrayView {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Luma row-major, `width * height` values.
    pub data: Vec<f32>,
}

impl GrayView {
    /// The BT.601 luma of a colour image.
    pub fn from_rgb(img: &RgbImage) -> Self {
        let data = img
            .pixels()
            .map(|p| 0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32)
            .collect();
        GrayView {
            width: img.width() as usize,
            height: img.height() as usize,
            data,
        }
    }

    fn at(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Bilinear sample; the caller keeps `(x, y)` inside `[0, w - 1) x [0, h - 1)` (the
    /// reference [`ncc_lanes`] is tested against).
    #[cfg(test)]
    fn bilinear(&self, x: f32, y: f32) -> f32 {
        let (x0, y0) = (x as usize, y as usize);
        let (ax, ay) = (x - x0 as f32, y - y0 as f32);
        let i = y0 * self.width + x0;
        let (a, b) = (self.data[i], self.data[i + 1]);
        let (c, d) = (self.data[i + self.width], self.data[i + self.width + 1]);
        blend(a, b, c, d, ax, ay)
    }
}

/// The bilinear blend of a cell's corners `a` `b` (top) and `c` `d` (bottom) at `(ax, ay)`.
#[inline(always)]
fn blend(a: f32, b: f32, c: f32, d: f32, ax: f32, ay: f32) -> f32 {
    let top = a + ax * (b - a);
    top + ay * (c + ax * (d - c) - top)
}

/// An earlier keyframe the sweep compares against: its grey view and its pose
/// (camera to world).
pub struct SweepReference<'a> {
    /// The reference keyframe's grey image.
    pub image: &'a GrayView,
    /// The reference keyframe's pose, camera to world.
    pub pose: Pose,
}

/// What one sweep did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct SweepSummary {
    /// Pixels with a predicted depth, texture and at least one reference with parallax.
    pub candidates: usize,
    /// Of them, pixels whose depth was measured.
    pub confirmed: usize,
}

/// Where one reference sees a target ray: `q(z) = z a + t` in its camera frame.
struct RefRay<'a> {
    image: &'a GrayView,
    rotation: Matrix3<f64>,
    translation: Vector3<f64>,
}

/// Measures the depth of a keyframe's map grid (`predicted`: every `stride`-th pixel of the
/// full-resolution `camera` and images) by a plane sweep around the prediction against
/// `refs`; patches are sampled in the full-resolution images, `patch_step` pixels apart.
/// Returns the measured depth on the same grid (0 where not confirmed) and counts.
pub fn sweep_depth(
    target: &GrayView,
    pose: &Pose,
    predicted: &DepthImage,
    refs: &[SweepReference],
    camera: &Camera,
    stride: u32,
    s: &MultiviewConfig,
) -> (DepthImage, SweepSummary) {
    let (w, h) = (predicted.width as usize, predicted.height as usize);
    let mut out = DepthImage::new(w as u32, h as u32);
    let st = stride.max(1) as usize;
    let reach = s.patch_radius * s.patch_step.max(1);
    if refs.is_empty()
        || s.steps < 5
        || target.width.div_ceil(st) != w
        || target.height.div_ceil(st) != h
        || target.width <= 2 * reach + 2
        || target.height <= 2 * reach + 2
    {
        return (out, SweepSummary::default());
    }
    let rays: Vec<RefRay> = refs
        .iter()
        .map(|rf| {
            let rel = rf.pose.inverse() * pose;
            RefRay {
                image: rf.image,
                rotation: *rel.rotation.to_rotation_matrix().matrix(),
                translation: rel.translation.vector,
            }
        })
        .collect();
    let rows: Vec<(Vec<f32>, SweepSummary)> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut row = vec![0.0f32; w];
            let mut sum = SweepSummary::default();
            let fy = y * st;
            if fy < reach || fy + reach >= target.height {
                return (row, sum);
            }
            let mut scratch = Scratch::new(s.steps, s.range, rays.len());
            let predicted_row = &predicted.data[y * w..(y + 1) * w];
            for (x, (out, &d)) in row.iter_mut().zip(predicted_row).enumerate() {
                let fx = x * st;
                if fx < reach || fx + reach >= target.width || d <= 0.0 || !d.is_finite() {
                    continue;
                }
                if let Some(z) = sweep_pixel(
                    target,
                    (fx, fy),
                    d as f64,
                    &rays,
                    camera,
                    s,
                    &mut scratch,
                    &mut sum,
                ) {
                    *out = z as f32;
                }
            }
            (row, sum)
        })
        .collect();
    let mut summary = SweepSummary::default();
    for (y, (row, sum)) in rows.into_iter().enumerate() {
        out.data[y * w..(y + 1) * w].copy_from_slice(&row);
        summary.candidates += sum.candidates;
        summary.confirmed += sum.confirmed;
    }
    (out, summary)
}

/// Buffers reused from pixel to pixel.
struct Scratch {
    patch: Vec<f32>,
    costs: Vec<f32>,
    counts: Vec<u32>,
    usable: Vec<bool>,
    /// The NCC of hypothesis `i` in reference `k` at `i·refs + k`.
    scores: Vec<f32>,
    /// [`factor`] of each whole hypothesis.
    factors: Vec<f64>,
}

impl Scratch {
    fn new(steps: usize, range: f64, refs: usize) -> Self {
        Scratch {
            patch: Vec::new(),
            costs: vec![0.0; steps],
            counts: vec![0; steps],
            usable: vec![false; refs],
            scores: vec![0.0; steps * refs],
            factors: (0..steps).map(|i| factor(i as f64, steps, range)).collect(),
        }
    }
}

/// Hypothesis `i` (fractional) of `steps` over the predicted depth, log-spaced over
/// `e^(±range)`.
fn factor(i: f64, steps: usize, range: f64) -> f64 {
    (range * (2.0 * i / (steps - 1) as f64 - 1.0)).exp()
}

/// Depth of hypothesis `i` (fractional) of `steps`, log-spaced over `d·e^(±range)`.
fn hypothesis(d: f64, i: f64, steps: usize, range: f64) -> f64 {
    d * factor(i, steps, range)
}

#[allow(clippy::too_many_arguments)]
fn sweep_pixel(
    target: &GrayView,
    (x, y): (usize, usize),
    d: f64,
    rays: &[RefRay],
    camera: &Camera,
    s: &MultiviewConfig,
    sc: &mut Scratch,
    sum: &mut SweepSummary,
) -> Option<f64> {
    let (r, step) = (s.patch_radius as isize, s.patch_step.max(1) as isize);
    // The target patch, zero-mean and unit-norm.
    sc.patch.clear();
    for dy in -r..=r {
        for dx in -r..=r {
            sc.patch.push(target.at(
                (x as isize + dx * step) as usize,
                (y as isize + dy * step) as usize,
            ));
        }
    }
    let n = sc.patch.len() as f32;
    let mean = sc.patch.iter().sum::<f32>() / n;
    let var = sc
        .patch
        .iter()
        .map(|v| (v - mean) * (v - mean))
        .sum::<f32>();
    if (var / n).sqrt() < s.min_texture {
        return None;
    }
    let norm = var.sqrt();
    for v in sc.patch.iter_mut() {
        *v = (*v - mean) / norm;
    }
    let ray = camera.normalized(&Point2::new(x as f64, y as f64));
    let ray = Vector3::new(ray.x, ray.y, 1.0);
    let margin = (r * step) as f64 + 1.0;
    let to_view = |rr: &RefRay, z: f64| -> Option<Point2<f64>> {
        let q = rr.rotation * (ray * z) + rr.translation;
        let v = camera.project(&Point3::from(q))?;
        let (rw, rh) = (rr.image.width as f64, rr.image.height as f64);
        (v.x >= margin && v.y >= margin && v.x < rw - 1.0 - margin && v.y < rh - 1.0 - margin)
            .then_some(v)
    };
    // References that see both ends of the range, with parallax.
    let (near, far) = (d * sc.factors[0], d * sc.factors[s.steps - 1]);
    let mut any = false;
    for (k, rr) in rays.iter().enumerate() {
        sc.usable[k] = match (to_view(rr, near), to_view(rr, far)) {
            (Some(a), Some(b)) => (a - b).norm() >= s.min_parallax_px,
            _ => false,
        };
        any |= sc.usable[k];
    }
    if !any {
        return None;
    }
    sum.candidates += 1;
    // Every hypothesis' score in every usable reference, NCC_LANES hypotheses of one
    // reference at a time (their sums run side by side; each is summed as `ncc` sums it)...
    let refs = rays.len();
    for (k, rr) in rays.iter().enumerate() {
        if !sc.usable[k] {
            continue;
        }
        for first in (0..s.steps).step_by(NCC_LANES) {
            let views: [Option<Point2<f64>>; NCC_LANES] = std::array::from_fn(|l| {
                let i = first + l;
                (i < s.steps)
                    .then(|| to_view(rr, d * sc.factors[i]))
                    .flatten()
            });
            // A lane seen outside the reference scores -1 (it samples a seen lane's place).
            let Some(seen) = views.iter().flatten().next() else {
                for i in first..(first + NCC_LANES).min(s.steps) {
                    sc.scores[i * refs + k] = -1.0;
                }
                continue;
            };
            let at = views.map(|v| v.unwrap_or(*seen));
            let mut out = [0.0f32; NCC_LANES];
            ncc_lanes(
                &sc.patch,
                rr.image,
                &at.map(|v| v.x as f32),
                &at.map(|v| v.y as f32),
                r,
                step,
                &mut out,
            );
            for (l, (v, o)) in views.iter().zip(out).enumerate() {
                if first + l < s.steps {
                    sc.scores[(first + l) * refs + k] = if v.is_some() { o } else { -1.0 };
                }
            }
        }
    }
    // ...summed per hypothesis over the references in order.
    sc.costs.iter_mut().for_each(|c| *c = 0.0);
    sc.counts.iter_mut().for_each(|c| *c = 0);
    for i in 0..s.steps {
        for k in 0..refs {
            if sc.usable[k] {
                sc.costs[i] += 1.0 - sc.scores[i * refs + k];
                sc.counts[i] += 1;
            }
        }
    }
    for (c, &k) in sc.costs.iter_mut().zip(&sc.counts) {
        *c /= k.max(1) as f32;
    }
    let (best, &cb) = sc
        .costs
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    if best == 0 || best + 1 == s.steps || cb > 1.0 - s.min_ncc {
        return None;
    }
    let second = sc
        .costs
        .iter()
        .enumerate()
        .filter(|(i, _)| i.abs_diff(best) > 2)
        .map(|(_, &c)| c)
        .fold(f32::INFINITY, f32::min);
    if cb > s.uniqueness * second {
        return None;
    }
    let (a, c) = (sc.costs[best - 1], sc.costs[best + 1]);
    let curvature = a - 2.0 * cb + c;
    let offset = if curvature > 1e-9 {
        (0.5 * (a - c) / curvature).clamp(-0.5, 0.5)
    } else {
        0.0
    };
    sum.confirmed += 1;
    Some(hypothesis(d, best as f64 + offset as f64, s.steps, s.range))
}

/// Measured pixels (with at least this many) set a correction of the prediction.
const MIN_RATIOS_KEYFRAME: usize = 500;
const MIN_RATIOS_CELL: usize = 100;

/// Puts the measured depth into `depth` (the prediction). Pixels without a measurement
/// are dropped (`keep_unconfirmed` false) or keep the prediction, corrected by the ratio
/// measured / predicted (`cells > 0`): its median over a grid of `cells` columns (rows in
/// the image's proportion), bilinear between cell centres; a cell with too few
/// measurements takes the median of the whole keyframe. SDFCNN's error is mostly smooth
/// (a scale, or a slant, per region), so where a region was measured, its unmeasured
/// pixels move with it. Returns the keyframe's median ratio when a correction was made.
pub(crate) fn merge_measured(
    depth: &mut DepthImage,
    measured: &DepthImage,
    keep_unconfirmed: bool,
    cells: usize,
) -> Option<f32> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let correction = (keep_unconfirmed && cells > 0)
        .then(|| ratio_grid(depth, measured, cells))
        .flatten();
    for (i, (d, &m)) in depth.data.iter_mut().zip(&measured.data).enumerate() {
        if m > 0.0 {
            *d = m;
        } else if !keep_unconfirmed {
            *d = 0.0;
        } else if let Some(g) = &correction {
            *d *= g.at((i % w) as f32, (i / w) as f32, w, h);
        }
    }
    correction.map(|g| g.keyframe)
}

/// Median ratios measured / predicted per cell.
struct RatioGrid {
    cols: usize,
    rows: usize,
    cells: Vec<f32>,
    keyframe: f32,
}

fn median(v: &mut [f32]) -> f32 {
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f32::total_cmp).1
}

fn ratio_grid(depth: &DepthImage, measured: &DepthImage, cols: usize) -> Option<RatioGrid> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let rows = (cols * h).div_ceil(w.max(1)).max(1);
    let mut all = Vec::new();
    let mut per_cell: Vec<Vec<f32>> = vec![Vec::new(); cols * rows];
    for y in 0..h {
        for x in 0..w {
            let (d, m) = (depth.data[y * w + x], measured.data[y * w + x]);
            if d > 0.0 && m > 0.0 {
                all.push(m / d);
                per_cell[(y * rows / h) * cols + x * cols / w].push(m / d);
            }
        }
    }
    if all.len() < MIN_RATIOS_KEYFRAME {
        return None;
    }
    let keyframe = median(&mut all);
    let cells = per_cell
        .iter_mut()
        .map(|c| {
            if c.len() >= MIN_RATIOS_CELL {
                median(c)
            } else {
                keyframe
            }
        })
        .collect();
    Some(RatioGrid {
        cols,
        rows,
        cells,
        keyframe,
    })
}

impl RatioGrid {
    /// The ratio at pixel `(x, y)` of a `w x h` image, bilinear between cell centres.
    fn at(&self, x: f32, y: f32, w: usize, h: usize) -> f32 {
        let (c, r) = (self.cols, self.rows);
        let fx = ((x + 0.5) * c as f32 / w as f32 - 0.5).clamp(0.0, (c - 1) as f32);
        let fy = ((y + 0.5) * r as f32 / h as f32 - 0.5).clamp(0.0, (r - 1) as f32);
        let (x0, y0) = (fx as usize, fy as usize);
        let (x1, y1) = ((x0 + 1).min(c - 1), (y0 + 1).min(r - 1));
        let (ax, ay) = (fx - x0 as f32, fy - y0 as f32);
        let at = |x: usize, y: usize| self.cells[y * c + x];
        let top = at(x0, y0) + ax * (at(x1, y0) - at(x0, y0));
        let bottom = at(x0, y1) + ax * (at(x1, y1) - at(x0, y1));
        top + ay * (bottom - top)
    }
}

/// NCC of a zero-mean unit-norm patch with the reference patch around `v`
/// (fronto-parallel: the same pixel offsets).
#[cfg(test)]
fn ncc(patch: &[f32], img: &GrayView, v: Point2<f64>, r: isize, step: isize) -> f32 {
    let (cx, cy) = (v.x as f32, v.y as f32);
    let (mut dot, mut s1, mut s2) = (0.0f32, 0.0f32, 0.0f32);
    let mut k = 0;
    for dy in -r..=r {
        for dx in -r..=r {
            let g = img.bilinear(cx + (dx * step) as f32, cy + (dy * step) as f32);
            dot += patch[k] * g;
            s1 += g;
            s2 += g * g;
            k += 1;
        }
    }
    ncc_of_sums(dot, s1, s2, patch.len() as f32)
}

/// The NCC from the sums over a patch of `n` samples `g` of `Σ patch·g`, `Σ g` and `Σ g²`.
#[inline(always)]
fn ncc_of_sums(dot: f32, s1: f32, s2: f32, n: f32) -> f32 {
    let var = s2 - s1 * s1 / n;
    if var <= 1e-3 {
        return 0.0;
    }
    // Σ patch = 0, so Σ patch·(g − mean g) = Σ patch·g.
    dot / var.sqrt()
}

/// Patches [`ncc_lanes`] scores at once.
const NCC_LANES: usize = 8;

simd_fn! {
    /// `out[l]` = the NCC of `patch` around `(xs[l], ys[l])` for each lane, summed sample
    /// by sample in `ncc`'s order (the same values bit for bit), the lanes side by side so
    /// that their sums do not wait on one another.
    fn ncc_lanes(
        patch: &[f32],
        img: &GrayView,
        xs: &[f32; NCC_LANES],
        ys: &[f32; NCC_LANES],
        r: isize,
        step: isize,
        out: &mut [f32; NCC_LANES],
    ) {
        let [mut dot, mut s1, mut s2] = [[0.0f32; NCC_LANES]; 3];
        let w = img.width;
        let mut k = 0;
        for dy in -r..=r {
            for dx in -r..=r {
                let (ox, oy) = ((dx * step) as f32, (dy * step) as f32);
                // `GrayView::bilinear` per lane, in three passes so that the arithmetic
                // vectorises: the corners' places and weights (truncation as `as usize`
                // truncates these non-negative places), the corners read, then the blend.
                let x: [f32; NCC_LANES] = std::array::from_fn(|l| xs[l] + ox);
                let y: [f32; NCC_LANES] = std::array::from_fn(|l| ys[l] + oy);
                let x0 = x.map(|v| v as i32);
                let y0 = y.map(|v| v as i32);
                let ax: [f32; NCC_LANES] = std::array::from_fn(|l| x[l] - x0[l] as f32);
                let ay: [f32; NCC_LANES] = std::array::from_fn(|l| y[l] - y0[l] as f32);
                let mut corners = [[0.0f32; NCC_LANES]; 4];
                for l in 0..NCC_LANES {
                    let i = y0[l] as usize * w + x0[l] as usize;
                    let (top, bottom) = (&img.data[i..i + 2], &img.data[i + w..i + w + 2]);
                    corners[0][l] = top[0];
                    corners[1][l] = top[1];
                    corners[2][l] = bottom[0];
                    corners[3][l] = bottom[1];
                }
                let [a, b, c, d] = corners;
                let p = patch[k];
                for l in 0..NCC_LANES {
                    let g = blend(a[l], b[l], c[l], d[l], ax[l], ay[l]);
                    dot[l] += p * g;
                    s1[l] += g;
                    s2[l] += g * g;
                }
                k += 1;
            }
        }
        let n = patch.len() as f32;
        for l in 0..NCC_LANES {
            out[l] = ncc_of_sums(dot[l], s1[l], s2[l], n);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    /// A textured wall at z = `wall` in world coordinates, seen from `pose`.
    fn render(camera: &Camera, stride: u32, pose: &Pose, wall: f64) -> (RgbImage, DepthImage) {
        let (w, h) = (camera.width / stride, camera.height / stride);
        let mut depth = DepthImage::new(w, h);
        let img = RgbImage::from_fn(w, h, |x, y| {
            let ray = camera.normalized(&Point2::new((x * stride) as f64, (y * stride) as f64));
            let dir = pose.rotation * Vector3::new(ray.x, ray.y, 1.0);
            let o = pose.translation.vector;
            let t = (wall - o.z) / dir.z;
            let p = o + dir * t;
            depth.data[(y * w + x) as usize] = (t * 1.0) as f32;
            let v = (128.0
                + 60.0 * (p.x * 23.0).sin() * (p.y * 17.0).cos()
                + 40.0 * (p.x * 7.0 + p.y * 11.0).sin()) as u8;
            image::Rgb([v, v, v])
        });
        (img, depth)
    }

    fn settings() -> MultiviewConfig {
        MultiviewConfig::default()
    }

    #[test]
    fn lanes_score_as_one_patch_at_a_time_bit_for_bit() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let (w, h) = (64usize, 48usize);
        let img = GrayView {
            width: w,
            height: h,
            data: (0..w * h).map(|_| rng.random_range(0.0..255.0)).collect(),
        };
        // A flat patch too (variance below the floor: score 0).
        let flat = GrayView {
            width: w,
            height: h,
            data: vec![17.0; w * h],
        };
        for (r, step) in [(2isize, 2isize), (1, 1), (3, 1)] {
            let n = ((2 * r + 1) * (2 * r + 1)) as usize;
            let patch: Vec<f32> = (0..n).map(|_| rng.random_range(-0.5..0.5)).collect();
            let reach = (r * step) as f32 + 1.0;
            for image in [&img, &flat] {
                let xs: [f32; NCC_LANES] =
                    std::array::from_fn(|_| rng.random_range(reach..w as f32 - 1.0 - reach));
                let ys: [f32; NCC_LANES] =
                    std::array::from_fn(|_| rng.random_range(reach..h as f32 - 1.0 - reach));
                let mut out = [f32::NAN; NCC_LANES];
                ncc_lanes(&patch, image, &xs, &ys, r, step, &mut out);
                for l in 0..NCC_LANES {
                    let v = Point2::new(xs[l] as f64, ys[l] as f64);
                    let one = ncc(&patch, image, v, r, step);
                    assert_eq!(out[l].to_bits(), one.to_bits(), "lane {l}, r {r}");
                }
            }
        }
    }

    #[test]
    fn measures_a_wall_from_a_wrong_prediction() {
        let camera = Camera::tum_fr1().undistorted();
        let stride = 2;
        let target_pose = Pose::identity();
        let ref_pose = Pose::from_parts(
            Translation3::new(0.12, 0.02, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.02, 0.0),
        );
        let (img, truth) = render(&camera, 1, &target_pose, 2.0);
        let truth = truth.subsample(stride);
        let (ref_img, _) = render(&camera, 1, &ref_pose, 2.0);
        let (target, reference) = (GrayView::from_rgb(&img), GrayView::from_rgb(&ref_img));
        // The prediction is 15 % too far.
        let mut predicted = truth.clone();
        predicted.data.iter_mut().for_each(|d| *d *= 1.15);
        let refs = [SweepReference {
            image: &reference,
            pose: ref_pose,
        }];
        let (measured, sum) = sweep_depth(
            &target,
            &target_pose,
            &predicted,
            &refs,
            &camera,
            stride,
            &settings(),
        );
        assert!(sum.confirmed > sum.candidates / 2, "{sum:?}");
        let mut errors: Vec<f32> = measured
            .data
            .iter()
            .zip(&truth.data)
            .filter(|(m, _)| **m > 0.0)
            .map(|(m, t)| (m - t).abs() / t)
            .collect();
        errors.sort_by(f32::total_cmp);
        let median = errors[errors.len() / 2];
        assert!(median < 0.01, "median relative error {median}");
    }

    #[test]
    fn unmeasured_pixels_follow_the_measured_ones_of_their_region() {
        // Prediction 2 m everywhere; the left half measured at 2.2 m where x is even, the
        // right half at 1.8 m where x is even.
        let (w, h) = (64u32, 48u32);
        let mut depth = DepthImage::new(w, h);
        depth.data.iter_mut().for_each(|d| *d = 2.0);
        let mut measured = DepthImage::new(w, h);
        for y in 0..h {
            for x in (0..w).step_by(2) {
                measured.data[(y * w + x) as usize] = if x < w / 2 { 2.2 } else { 1.8 };
            }
        }
        let mut one = depth.clone();
        assert_eq!(merge_measured(&mut one, &measured, true, 0), None);
        assert_eq!(one.data[1], 2.0, "no correction with cells = 0");
        assert_eq!(one.data[0], 2.2);
        let mut grid = depth.clone();
        merge_measured(&mut grid, &measured, true, 4);
        let (left, right) = (grid.data[1], grid.data[(w - 1) as usize]);
        assert!(
            (left - 2.2).abs() < 1e-5 && (right - 1.8).abs() < 1e-5,
            "{left} {right}"
        );
        let mut dropped = depth.clone();
        merge_measured(&mut dropped, &measured, false, 4);
        assert_eq!((dropped.data[0], dropped.data[1]), (2.2, 0.0));
        // Too few measurements: no correction.
        let mut sparse = DepthImage::new(w, h);
        sparse.data[0] = 3.0;
        let mut kept = depth.clone();
        assert_eq!(merge_measured(&mut kept, &sparse, true, 4), None);
        assert_eq!(kept.data[1], 2.0);
    }

    #[test]
    fn confirms_nothing_without_parallax_or_texture() {
        let camera = Camera::tum_fr1().undistorted();
        let stride = 2;
        let pose = Pose::identity();
        let (img, truth) = render(&camera, 1, &pose, 2.0);
        let truth = truth.subsample(stride);
        let target = GrayView::from_rgb(&img);
        // A pure rotation gives no parallax.
        let rotated = Pose::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_euler_angles(0.0, 0.05, 0.0),
        );
        let (ref_img, _) = render(&camera, 1, &rotated, 2.0);
        let reference = GrayView::from_rgb(&ref_img);
        let refs = [SweepReference {
            image: &reference,
            pose: rotated,
        }];
        let (_, sum) = sweep_depth(&target, &pose, &truth, &refs, &camera, stride, &settings());
        assert_eq!(sum.confirmed, 0);
        // A flat image has no texture.
        let flat = GrayView {
            data: vec![100.0; target.data.len()],
            ..target.clone()
        };
        let moved = Pose::from_parts(Translation3::new(0.1, 0.0, 0.0), UnitQuaternion::identity());
        let refs = [SweepReference {
            image: &flat,
            pose: moved,
        }];
        let (measured, sum) =
            sweep_depth(&flat, &pose, &truth, &refs, &camera, stride, &settings());
        assert_eq!((sum.candidates, sum.confirmed), (0, 0));
        assert!(measured.data.iter().all(|&d| d == 0.0));
    }
}
