//! FPFDCNN training loss: the detector learns the Harris corners of each image
//! (a per-pixel binary decision, the paper's "dichotomic problem" of Appendix A),
//! the descriptors learn the ground-truth matches of eqs 5-7.
//!
//! * Detector: binary cross-entropy between the FP probability map and the
//!   Harris target map, positives weighted by `pos_weight` because corners are
//!   about 0.1 % of the pixels.
//! * Localisation: on every 16x16 cell holding a Harris corner, cross-entropy of the
//!   softmax over the cell's 256 L8 logits against its corner(s). The per-pixel BCE alone
//!   learns which cells hold corners but hardly where inside them (trained that way, the
//!   bundled network of 2026-11-21 put 3.5 % of its keypoints within 1.5 px of a Harris
//!   corner); this term makes the sub-pixels of a cell compete, as SuperPoint's
//!   65-way softmax does, while the network keeps Table 12's sigmoid output.
//! * Descriptor: InfoNCE (contrastive, van den Oord et al. 2018) over the matched
//!   points of each image pair, symmetric in A and B: the descriptor of a corner
//!   in A must be nearer (cosine, temperature `tau`) to its partner in B than to
//!   the partners of the other corners, which are the negatives the range matcher
//!   has to reject. Partners closer than `exclusion_px` to the true one in B are
//!   not used as negatives (their descriptors are bilinear blends of the same
//!   16x16 cells, so the network cannot tell them apart).
//!
//! * Shift consistency (optional, `shift_consistency`, 0 by default): the detector
//!   predicts each 16x16 cell's sub-pixel probabilities from that cell's features, so a
//!   single pass carries the cell grid, which `eval matching` averages out over four
//!   placements. This term runs image A again shifted by half a cell and pulls both
//!   probability maps, on their overlap, towards their mean (`shift_consistency`), so
//!   that one pass (what `slam` runs) looks more like the average of placements.
//! * Descriptor shift consistency (optional, `descriptor_shift_consistency`, 0 by
//!   default): the same for the descriptors, which are sampled from a map 16 times
//!   coarser than the image, so one placement's descriptor of a point depends on where
//!   the grid falls (averaging four placements' descriptors gives 28-39 % more correct
//!   matches, lab/notes/fpfdcnn-results.md *Descriptors averaged over the grid placements*). At A's matched
//!   points inside the shifted crop, both descriptors are pulled towards their normalised
//!   mean (detached) by cosine distance (`descriptor_shift_consistency`).
//!
//! Descriptors are sampled from the coarse L10 map at the (sub-pixel) match
//! positions with the bilinear weights of the FD layer, as a sparse matrix
//! product, so the loss is differentiable on every backend.

use crate::nn::{sum_all, taps_at};
use burn::prelude::*;
use burn::tensor::activation::log_softmax;
use serde::{Deserialize, Serialize};

/// Loss weights and settings (the `[loss]` table of a training config).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FpfdcnnLossConfig {
    /// Weight of the detector BCE.
    pub detector_weight: f64,
    /// Weight of the per-cell localisation cross-entropy.
    pub localization_weight: f64,
    /// Weight of the descriptor InfoNCE.
    pub descriptor_weight: f64,
    /// Weight of positive (corner) pixels in the BCE.
    pub pos_weight: f64,
    /// InfoNCE temperature.
    pub tau: f64,
    /// Negatives closer than this to the positive (pixels, training resolution) are ignored.
    pub exclusion_px: f32,
    /// At most this many matches per pair enter the descriptor loss.
    pub max_matches: usize,
    /// Near negatives per matched point (0: none, the default): descriptors sampled on a
    /// ring of `near_radius_px` around the point's partner, which the softmax must rank
    /// below the partner. The other matches' partners are seldom that close, and Lowe's
    /// ratio test fails when a keypoint there matches almost as well (`ring_points`).
    pub near_negatives: usize,
    /// Radius of that ring, pixels (training resolution).
    pub near_radius_px: f32,
    /// Weight of the shift-consistency term (0: off, the default; `shift_consistency`).
    pub shift_consistency: f64,
    /// Weight of the descriptors' shift-consistency term (0: off, the default;
    /// `descriptor_shift_consistency`).
    pub descriptor_shift_consistency: f64,
}

impl Default for FpfdcnnLossConfig {
    fn default() -> Self {
        FpfdcnnLossConfig {
            detector_weight: 1.0,
            localization_weight: 1.0,
            descriptor_weight: 1.0,
            pos_weight: 100.0,
            tau: 0.1,
            exclusion_px: 8.0,
            max_matches: 192,
            near_negatives: 0,
            near_radius_px: 12.0,
            shift_consistency: 0.0,
            descriptor_shift_consistency: 0.0,
        }
    }
}

impl FpfdcnnLossConfig {
    /// Checks the weights and the temperature; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        for (v, what) in [
            (self.detector_weight, "detector_weight"),
            (self.localization_weight, "localization_weight"),
            (self.descriptor_weight, "descriptor_weight"),
            (self.shift_consistency, "shift_consistency"),
            (
                self.descriptor_shift_consistency,
                "descriptor_shift_consistency",
            ),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!(
                    "loss.{what} must be a non-negative number, got {v}"
                ));
            }
        }
        if !(self.pos_weight.is_finite() && self.pos_weight > 0.0) {
            return Err(format!(
                "loss.pos_weight must be a positive number, got {}",
                self.pos_weight
            ));
        }
        if !(self.tau.is_finite() && self.tau > 0.0) {
            return Err(format!(
                "loss.tau (the InfoNCE temperature) must be a positive number, got {}",
                self.tau
            ));
        }
        if !(self.exclusion_px.is_finite() && self.exclusion_px >= 0.0) {
            return Err(format!(
                "loss.exclusion_px must be a non-negative number of pixels, got {}",
                self.exclusion_px
            ));
        }
        if !(1..=100_000).contains(&self.max_matches) {
            return Err(format!(
                "loss.max_matches must be in 1..=100000, got {}",
                self.max_matches
            ));
        }
        if self.near_negatives > 64 {
            return Err(format!(
                "loss.near_negatives must be in 0..=64, got {}",
                self.near_negatives
            ));
        }
        if !(self.near_radius_px.is_finite()
            && self.near_radius_px > 0.0
            && self.near_radius_px <= 256.0)
        {
            return Err(format!(
                "loss.near_radius_px must be in (0, 256] pixels, got {}",
                self.near_radius_px
            ));
        }
        Ok(())
    }
}

/// `count` points evenly spaced on a circle of `radius` pixels around each of `points`,
/// clamped into an image of `[height, width]`, point by point (`points.len() · count`), and
/// the additive mask of [`descriptor_infonce`]'s near negatives: 0, or a large negative value
/// where clamping brought a point within `exclusion_px` of its centre (it would be the
/// positive itself); a ring at the exclusion radius itself is kept whole.
pub(crate) fn ring_points(
    points: &[[f32; 2]],
    count: usize,
    radius: f32,
    exclusion_px: f32,
    [height, width]: [usize; 2],
) -> (Vec<[f32; 2]>, Vec<f32>) {
    let (mut ring, mut mask) = (Vec::new(), Vec::new());
    let (xmax, ymax) = ((width.max(1) - 1) as f32, (height.max(1) - 1) as f32);
    for p in points {
        for k in 0..count {
            let a = std::f32::consts::TAU * k as f32 / count as f32;
            let free = [p[0] + radius * a.cos(), p[1] + radius * a.sin()];
            let q = [free[0].clamp(0.0, xmax), free[1].clamp(0.0, ymax)];
            // Only a clamped point can come closer than the radius (a ring at exactly the
            // exclusion radius must not be masked by rounding).
            let d2 = (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2);
            mask.push(if q != free && d2 < exclusion_px * exclusion_px {
                -1e4
            } else {
                0.0
            });
            ring.push(q);
        }
    }
    (ring, mask)
}

/// Each matched point's own negatives for [`descriptor_infonce`]: `per_point` descriptors
/// (`[M · per_point, D]`, normalised, point by point) around A's points (for the B -> A
/// softmax) and around B's (for A -> B), with their additive masks (`[M, per_point]`).
pub(crate) struct NearNegatives {
    /// `[M · per_point, D]` descriptors of image A on rings around A's points (B -> A softmax).
    pub around_a: Tensor<2>,
    /// `[M, per_point]` additive mask of `around_a` (0, or large negative near the positive).
    pub mask_a: Tensor<2>,
    /// `[M · per_point, D]` descriptors of image B on rings around B's points (A -> B softmax).
    pub around_b: Tensor<2>,
    /// `[M, per_point]` additive mask of `around_b` (0, or large negative near the positive).
    pub mask_b: Tensor<2>,
    /// Near negatives per matched point.
    pub per_point: usize,
}

/// `[M, k]` similarities of each row of `x` (`[M, D]`) to its own `k` rows of `near`
/// (`[M · k, D]`).
fn own_similarities(x: Tensor<2>, near: Tensor<2>, k: usize) -> Tensor<2> {
    let [m, d] = x.dims();
    x.reshape([m, 1, d])
        .mul(near.reshape([m, k, d]))
        .sum_dim(2)
        .reshape([m, k])
}

/// Weighted binary cross-entropy of a probability map `[N, 1, H, W]` against a
/// 0/1 target of the same shape, averaged with the weights.
pub(crate) fn detector_bce(prob: Tensor<4>, target: Tensor<4>, pos_weight: f64) -> Tensor<1> {
    let eps = 1e-6;
    let p = prob.clamp(eps, 1.0 - eps);
    let weights = target.clone().mul_scalar(pos_weight - 1.0).add_scalar(1.0);
    let ll = target.clone().mul(p.clone().log())
        + target
            .neg()
            .add_scalar(1.0)
            .mul(p.neg().add_scalar(1.0).log());
    let total = sum_all(weights.clone());
    sum_all(ll.mul(weights)).neg().div(total)
}

/// Shift consistency of the FP probability maps `prob` (`[N, 1, H, W]`, of an image) and
/// `shifted` (`[N, 1, H − 2s, W − 2s]`, of the same image cropped by `s` pixels on every
/// side, `s` half a cell): on their overlap each map is pulled towards the pair's mean
/// (detached) by [`detector_bce`] with soft targets, averaged over the two.
pub(crate) fn shift_consistency(
    prob: Tensor<4>,
    shifted: Tensor<4>,
    s: usize,
    pos_weight: f64,
) -> Tensor<1> {
    let [n, c, h, w] = prob.dims();
    let centre = prob.slice([0..n, 0..c, s..h - s, s..w - s]);
    let mean = (centre.clone() + shifted.clone()).div_scalar(2.0).detach();
    (detector_bce(centre, mean.clone(), pos_weight) + detector_bce(shifted, mean, pos_weight))
        .div_scalar(2.0)
}

/// Shift consistency of descriptors: `a` and `shifted` (`[M, D]`, unit rows) describe the same
/// image points from two placements of the cell grid; each is pulled towards their normalised
/// mean (detached) by the mean cosine distance `1 − cos`, averaged over the two.
pub(crate) fn descriptor_shift_consistency(a: Tensor<2>, shifted: Tensor<2>) -> Tensor<1> {
    let mean = l2_normalize(a.clone() + shifted.clone()).detach();
    let cos = |x: Tensor<2>| x.mul(mean.clone()).sum_dim(1).mean();
    (cos(a) + cos(shifted))
        .div_scalar(2.0)
        .neg()
        .add_scalar(1.0)
}

/// Localisation term: cross-entropy of the softmax over each cell's `cell²` logits
/// (`[N, cell², Hc, Wc]`, L8 before its sigmoid) against the cell's target pixels (the
/// 0/1 map `[N, 1, H, W]`, several targets sharing the probability), averaged over the
/// cells that hold a target; 0 when none does.
pub(crate) fn detector_cell_ce(logits: Tensor<4>, target: Tensor<4>, cell: usize) -> Tensor<1> {
    let t = crate::nn::pixel_unshuffle(target, cell);
    let count = t.clone().sum_dim(1);
    let has = count.clone().greater_elem(0.0).float();
    let dist = t.div(count.clamp_min(1.0));
    let ce = dist.mul(log_softmax(logits, 1)).sum_dim(1).neg();
    let cells = sum_all(has.clone()).clamp_min(1.0);
    sum_all(ce.mul(has)).div(cells)
}

/// The `[M, Hc·Wc]` matrix that samples a coarse map (of an image of
/// `[height, width]` pixels) bilinearly at sub-pixel points `(x, y)`, as the FD
/// layer followed by reading those pixels would.
pub(crate) fn sampling_matrix(
    points: &[[f32; 2]],
    [hc, wc]: [usize; 2],
    [height, width]: [usize; 2],
) -> Vec<f32> {
    let mut m = vec![0.0f32; points.len() * hc * wc];
    for (k, p) in points.iter().enumerate() {
        let tx = taps_at(p[0], wc, width);
        let ty = taps_at(p[1], hc, height);
        let row = &mut m[k * hc * wc..(k + 1) * hc * wc];
        for (iy, wy) in [(ty.i0, ty.w0), (ty.i1, ty.w1)] {
            for (ix, wx) in [(tx.i0, tx.w0), (tx.i1, tx.w1)] {
                row[iy * wc + ix] += wy * wx;
            }
        }
    }
    m
}

/// L2-normalised descriptors of image `batch` of a coarse map `[N, D, Hc, Wc]`
/// at the given points: `[M, D]`.
pub(crate) fn sample_descriptors(
    map: &Tensor<4>,
    batch: usize,
    points: &[[f32; 2]],
    image: [usize; 2],
) -> Tensor<2> {
    let [_, d, hc, wc] = map.dims();
    let device = map.device();
    let s = Tensor::<2>::from_data(
        TensorData::new(
            sampling_matrix(points, [hc, wc], image),
            [points.len(), hc * wc],
        ),
        &device,
    );
    let flat = map
        .clone()
        .slice(s![batch..batch + 1])
        .reshape([d, hc * wc]);
    let desc = s.matmul(flat.transpose());
    l2_normalize(desc)
}

/// Row-wise L2 normalisation that cannot overflow: rows are first divided by
/// their largest magnitude (InfoNCE leaves the raw descriptor length free, and
/// squaring long vectors in f32 would give infinities).
pub(crate) fn l2_normalize(x: Tensor<2>) -> Tensor<2> {
    let peak = x.clone().abs().max_dim(1).add_scalar(1e-12);
    let x = x.div(peak);
    let norm = x
        .clone()
        .powf_scalar(2.0)
        .sum_dim(1)
        .sqrt()
        .add_scalar(1e-12);
    x.div(norm)
}

/// Symmetric InfoNCE between matched descriptors `a[i] <-> b[i]` (`[M, D]`,
/// normalised), ignoring negatives whose B points lie within `exclusion_px` of
/// the positive's; with `near`, each row of the softmax also holds its point's own near
/// negatives. Returns the loss and the share of points whose nearest descriptor among the
/// partners (A to B) is their own.
pub(crate) fn descriptor_infonce(
    a: Tensor<2>,
    b: Tensor<2>,
    points_b: &[[f32; 2]],
    tau: f64,
    exclusion_px: f32,
    near: Option<NearNegatives>,
) -> (Tensor<1>, f32) {
    let m = points_b.len();
    let device = a.device();
    let (a_rows, b_rows) = (a.clone(), b.clone());
    let sim = a.matmul(b.transpose()).div_scalar(tau);
    // Additive mask: 0 where allowed, a large negative value for excluded negatives.
    let mut mask = vec![0.0f32; m * m];
    let r2 = exclusion_px * exclusion_px;
    for i in 0..m {
        for j in 0..m {
            let (dx, dy) = (
                points_b[i][0] - points_b[j][0],
                points_b[i][1] - points_b[j][1],
            );
            if i != j && dx * dx + dy * dy < r2 {
                mask[i * m + j] = -1e4;
            }
        }
    }
    let mask = Tensor::<2>::from_data(TensorData::new(mask, [m, m]), &device);
    let logits = sim + mask;
    let eye = Tensor::<2>::eye(m, &device);
    let (ab, ba) = match near {
        None => (
            sum_all(log_softmax(logits.clone(), 1).mul(eye.clone())),
            sum_all(log_softmax(logits.clone(), 0).mul(eye)),
        ),
        Some(n) => {
            // Rows A -> B, then B -> A (the transpose), each with its own near negatives.
            let k = n.per_point;
            let near_ab =
                own_similarities(a_rows.clone(), n.around_b, k).div_scalar(tau) + n.mask_b;
            let near_ba = own_similarities(b_rows, n.around_a, k).div_scalar(tau) + n.mask_a;
            let rows_ab = Tensor::cat(vec![logits.clone(), near_ab], 1);
            let rows_ba = Tensor::cat(vec![logits.clone().transpose(), near_ba], 1);
            let pad = Tensor::<2>::zeros([m, k], &device);
            let pick = Tensor::cat(vec![eye, pad], 1);
            (
                sum_all(log_softmax(rows_ab, 1).mul(pick.clone())),
                sum_all(log_softmax(rows_ba, 1).mul(pick)),
            )
        }
    };
    let loss = (ab + ba).div_scalar(-2.0 * m as f64);
    // Top-1 accuracy A -> B, on the host.
    let acc = match logits
        .argmax(1)
        .into_data()
        .convert::<i64>()
        .try_to_vec::<i64>()
    {
        Ok(idx) => {
            idx.iter()
                .enumerate()
                .filter(|(i, j)| **j == *i as i64)
                .count() as f32
                / m.max(1) as f32
        }
        Err(_) => 0.0,
    };
    (loss, acc)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[allow(deprecated)]
    fn device() -> Device {
        Device::ndarray()
    }

    fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    #[test]
    fn shift_consistency_is_least_when_the_shifted_map_agrees() {
        let d = device();
        // A 6x6 map and the 2x2 map of the same image cropped by 2 px on every side.
        let prob: Vec<f32> = (0..36).map(|k| 0.01 + 0.02 * (k % 7) as f32).collect();
        let map = Tensor::<4>::from_data(TensorData::new(prob.clone(), [1, 1, 6, 6]), &d);
        let centre: Vec<f32> = [14, 15, 20, 21].iter().map(|&k| prob[k]).collect();
        let agree = Tensor::<4>::from_data(TensorData::new(centre.clone(), [1, 1, 2, 2]), &d);
        let other: Vec<f32> = centre.iter().rev().map(|p| p + 0.3).collect();
        let differ = Tensor::<4>::from_data(TensorData::new(other, [1, 1, 2, 2]), &d);
        let a = values(shift_consistency(map.clone(), agree, 2, 50.0))[0];
        let b = values(shift_consistency(map.clone(), differ, 2, 50.0))[0];
        // Agreeing maps cost what each map's BCE against itself costs (its entropy).
        let c = Tensor::<4>::from_data(TensorData::new(centre, [1, 1, 2, 2]), &d);
        let own = values(detector_bce(c.clone(), c, 50.0))[0];
        assert!((a - own).abs() < 1e-5, "{a} vs {own}");
        assert!(b > a + 0.05, "{b} vs {a}");
        let bad = FpfdcnnLossConfig {
            shift_consistency: -1.0,
            ..Default::default()
        };
        assert!(bad.validate().unwrap_err().contains("shift_consistency"));
    }

    #[test]
    fn descriptor_shift_consistency_is_zero_when_placements_agree() {
        let d = device();
        let rows =
            |v: Vec<f32>| l2_normalize(Tensor::<2>::from_data(TensorData::new(v, [2, 3]), &d));
        let a = rows(vec![1.0, 0.0, 0.0, 0.0, 1.0, 1.0]);
        assert!(values(descriptor_shift_consistency(a.clone(), a.clone()))[0].abs() < 1e-6);
        // Orthogonal rows: each is 45 degrees from the mean, 1 - cos 45° = 0.2929.
        let b = rows(vec![0.0, 1.0, 0.0, 0.0, 1.0, -1.0]);
        let v = values(descriptor_shift_consistency(a, b))[0];
        assert!((v - (1.0 - 0.5f32.sqrt())).abs() < 1e-5, "{v}");
        let bad = FpfdcnnLossConfig {
            descriptor_shift_consistency: f64::NAN,
            ..Default::default()
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .contains("descriptor_shift_consistency")
        );
    }

    #[test]
    fn cell_ce_is_the_softmax_cross_entropy_of_cells_with_targets() {
        let d = device();
        // Cell 2 (4 sub-pixels), a 1x2 grid of cells: logits [0, ln 3, 0, 0] in both.
        let l = 3f32.ln();
        let logits = Tensor::<4>::from_data(
            TensorData::new(vec![0.0, 0.0, l, l, 0.0, 0.0, 0.0, 0.0], [1, 4, 1, 2]),
            &d,
        );
        // Target at sub-pixel (row 0, col 1) of the left cell; the right cell has none.
        let mut t = vec![0.0f32; 8];
        t[1] = 1.0;
        let target = Tensor::<4>::from_data(TensorData::new(t.clone(), [1, 1, 2, 4]), &d);
        let ce = values(detector_cell_ce(logits.clone(), target, 2))[0];
        assert!((ce - 2f32.ln()).abs() < 1e-5, "{ce}"); // -ln(3/6)
        // A second target in the same cell shares the probability: (ln 2 + ln 6) / 2.
        t[4] = 1.0; // row 1, col 0 of the left cell
        let target = Tensor::<4>::from_data(TensorData::new(t, [1, 1, 2, 4]), &d);
        let ce = values(detector_cell_ce(logits.clone(), target, 2))[0];
        assert!((ce - (2f32.ln() + 6f32.ln()) / 2.0).abs() < 1e-5, "{ce}");
        // No targets: 0.
        let none = Tensor::<4>::zeros([1, 1, 2, 4], &d);
        assert_eq!(values(detector_cell_ce(logits, none, 2))[0], 0.0);
    }

    #[test]
    fn bce_matches_hand_computation() {
        let d = device();
        let prob = Tensor::<4>::from_data(
            TensorData::new(vec![0.9f32, 0.2, 0.1, 0.5], [1, 1, 2, 2]),
            &d,
        );
        let target = Tensor::<4>::from_data(
            TensorData::new(vec![1.0f32, 0.0, 0.0, 0.0], [1, 1, 2, 2]),
            &d,
        );
        let l = values(detector_bce(prob, target, 3.0))[0];
        let expected = -(3.0 * 0.9f32.ln() + 0.8f32.ln() + 0.9f32.ln() + 0.5f32.ln()) / 6.0;
        assert!((l - expected).abs() < 1e-5, "{l} vs {expected}");
    }

    #[test]
    fn sampling_matrix_reproduces_bilinear_upsampling() {
        // A 2x3 coarse map of an 8x12 image (cell 4): compare with sample_bilinear_at.
        let map: Vec<f32> = (0..6).map(|v| v as f32 * 1.5 - 2.0).collect();
        let pts = [(0usize, 0usize), (5, 3), (11, 7), (6, 4)];
        let reference = crate::nn::sample_bilinear_at(&map, [1, 2, 3], [8, 12], &pts).unwrap();
        let fpts: Vec<[f32; 2]> = pts.iter().map(|&(x, y)| [x as f32, y as f32]).collect();
        let m = sampling_matrix(&fpts, [2, 3], [8, 12]);
        for (k, r) in reference.iter().enumerate() {
            let v: f32 = m[k * 6..(k + 1) * 6]
                .iter()
                .zip(&map)
                .map(|(a, b)| a * b)
                .sum();
            assert!((v - r).abs() < 1e-6, "point {k}: {v} vs {r}");
        }
    }

    #[test]
    fn infonce_is_low_for_matching_and_high_for_shuffled_descriptors() {
        let d = device();
        let m = 6;
        let raw: Vec<f32> = (0..m * 4).map(|i| ((i * 7919) % 13) as f32 - 6.0).collect();
        let a = Tensor::<2>::from_data(TensorData::new(raw.clone(), [m, 4]), &d);
        let norm = a.clone().powf_scalar(2.0).sum_dim(1).sqrt();
        let a = a.div(norm);
        let pts: Vec<[f32; 2]> = (0..m).map(|i| [i as f32 * 50.0, 0.0]).collect();
        let (same, acc) = descriptor_infonce(a.clone(), a.clone(), &pts, 0.1, 8.0, None);
        let shuffled = Tensor::cat(
            vec![a.clone().slice(s![1..m]), a.clone().slice(s![0..1])],
            0,
        );
        let (other, _) = descriptor_infonce(a, shuffled, &pts, 0.1, 8.0, None);
        let (same, other) = (values(same)[0], values(other)[0]);
        assert!(same < other, "{same} vs {other}");
        assert!(acc > 0.99);
    }

    #[test]
    fn ring_points_circle_each_point_and_mask_the_ones_clamped_onto_it() {
        let (ring, mask) = ring_points(&[[50.0, 40.0], [0.0, 0.0]], 4, 10.0, 8.0, [100, 200]);
        assert_eq!(ring.len(), 8);
        let near = |a: [f32; 2], b: [f32; 2]| (a[0] - b[0]).abs() + (a[1] - b[1]).abs() < 1e-4;
        for (q, e) in ring[..4]
            .iter()
            .zip([[60.0, 40.0], [50.0, 50.0], [40.0, 40.0], [50.0, 30.0]])
        {
            assert!(near(*q, e), "{q:?} vs {e:?}");
        }
        assert_eq!(&mask[..4], &[0.0; 4]);
        // At the corner two of the four are clamped onto the point itself: masked.
        assert_eq!(mask[4..].iter().filter(|m| **m < 0.0).count(), 2);
        // A ring of 8 at exactly the exclusion radius, diagonals included, stays whole.
        let (_, mask) = ring_points(&[[50.0, 40.0]], 8, 8.0, 8.0, [100, 200]);
        assert_eq!(mask, vec![0.0; 8]);
    }

    #[test]
    fn near_negatives_that_copy_the_partner_raise_the_loss_unless_masked() {
        let d = device();
        let m = 4;
        let eye: Vec<f32> = (0..m * m)
            .map(|i| if i % (m + 1) == 0 { 1.0 } else { 0.0 })
            .collect();
        let a = Tensor::<2>::from_data(TensorData::new(eye, [m, m]), &d);
        let pts: Vec<[f32; 2]> = (0..m).map(|i| [i as f32 * 50.0, 0.0]).collect();
        let loss = |near: Option<NearNegatives>| {
            values(descriptor_infonce(a.clone(), a.clone(), &pts, 0.1, 8.0, near).0)[0]
        };
        let base = loss(None);
        // Two near negatives per point: the zero vector (similarity 0), and a copy of the partner.
        let mut copies = Vec::new();
        for i in 0..m {
            copies.extend((0..m).map(|_| 0.0));
            copies.extend((0..m).map(|j| if i == j { 1.0 } else { 0.0 }));
        }
        let around = Tensor::<2>::from_data(TensorData::new(copies, [m * 2, m]), &d);
        let zero = Tensor::<2>::zeros([m, 2], &d);
        let with = |mask: Tensor<2>| NearNegatives {
            around_a: around.clone(),
            mask_a: mask.clone(),
            around_b: around.clone(),
            mask_b: mask,
            per_point: 2,
        };
        let copied = loss(Some(with(zero)));
        // A copy ties with the partner: the loss rises by about ln 2.
        assert!(copied - base > 0.6, "{base} -> {copied}");
        let masked = Tensor::<2>::from_data(TensorData::new([0.0f32, -1e4].repeat(m), [m, 2]), &d);
        let kept = loss(Some(with(masked)));
        // Masked copies leave only the zero vector: a small rise.
        assert!(kept >= base && kept - base < 0.01, "{base} -> {kept}");
    }

    #[test]
    fn losses_backpropagate_on_ndarray() {
        let d = device().autodiff();
        let map = Tensor::<4>::from_data(
            TensorData::new(
                (0..2 * 8 * 2 * 3)
                    .map(|v| (v as f32 * 0.37).sin())
                    .collect::<Vec<_>>(),
                [2, 8, 2, 3],
            ),
            &d,
        )
        .require_grad();
        let pa = [[3.0f32, 2.0], [40.0, 20.0], [20.5, 10.25]];
        let pb = [[4.0f32, 2.5], [38.0, 21.0], [25.0, 9.0]];
        let a = sample_descriptors(&map, 0, &pa, [32, 48]);
        let b = sample_descriptors(&map, 1, &pb, [32, 48]);
        let (loss, _) = descriptor_infonce(a, b, &pb, 0.1, 2.0, None);
        let grads = loss.backward();
        let g = map
            .grad(&grads)
            .expect("gradient reaches the descriptor map");
        assert!(values(g).iter().any(|v| v.abs() > 0.0));
    }
}
