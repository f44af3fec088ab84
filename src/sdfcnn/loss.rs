//! SDFCNN training loss, eq. 21: `Loss = λ·H(p, q) + (1 − λ)·L(y − f(x))`.
//!
//! * `H` is the pixel-wise cross entropy over the 40 classes, averaged over labelled pixels
//!   (void = 255 is ignored).
//! * `L` is a regression loss on the depth residual, averaged over pixels with a ground-truth
//!   depth (`gt > 0`): L1, L2, or berHu (reverse Huber, Laina et al. 2016: `|r|` for
//!   `|r| ≤ c`, `(r² + c²) / 2c` above, with `c = 0.2 · max |r|` over the batch's valid pixels,
//!   detached), which is the depth loss of Nekrasov et al.'s multi-task SDFCNN design.
//! * λ = 0.4 (Section V-C: training leans towards depth).
//! * Optional, not in the paper: `gradient_weight` `w` adds a shape term `G` to the depth loss,
//!   `Loss = λ·H + (1 − λ)·(L + w·G)`, the multi-scale scale-invariant gradient matching of
//!   Li & Snavely (MegaDepth, CVPR 2018): with `R = log d̂ − log d` on valid pixels, `G` is
//!   the mean `|R(p + s) − R(p)|` over horizontal and vertical neighbours at strides
//!   1, 2, 4, 8, averaged over the strides. It is blind to a global scale and penalises wrong
//!   relative depth (edges, slopes), which per-pixel `L` weighs little on real Kinect depth.
//!   The default `w = 0` is eq. 21 as printed.
//!
//! Eq. 21 is printed with `−λ·H`; a minus sign would reward a worse segmentation, so it is read
//! as a typo and the two terms are added.
//!
//! Both terms return 0 (not NaN) for a batch without a labelled pixel or without a valid depth.
//!
//! Resolution ([`LossResolution`]): by default the loss is taken at the judge layer's output
//! (seg1/depth1, 1/4 of the Layer0 size, [`super::Sdfcnn::forward_quarter`]) against targets
//! resized there with nearest neighbour, as Nekrasov et al. train; this skips the two output
//! upsamplings (40 channels at full size) in the forward and backward pass. `full` compares
//! the bilinearly upsampled outputs ([`super::Sdfcnn::forward`]) with the full-size targets.

use burn::prelude::*;
use burn::tensor::activation::log_softmax;
use serde::{Deserialize, Serialize};

use super::SdfcnnOutput;
use crate::dataset::labels::VOID;
use crate::nn::sum_all;

/// Depth regression loss `L` of eq. 21.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DepthLoss {
    /// Mean absolute residual.
    L1,
    /// Mean squared residual.
    L2,
    /// Reverse Huber with a per-batch threshold.
    #[default]
    Berhu,
}

/// Where the loss is evaluated.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LossResolution {
    /// Judge-layer output (1/4 of the Layer0 size), targets resized with nearest neighbour.
    #[default]
    Quarter,
    /// Network output upsampled to the input size.
    Full,
}

/// `[loss]` section of a training config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SdfcnnLossConfig {
    /// λ of eq. 21: weight of the cross entropy, `1 − λ` that of the depth loss.
    pub lambda: f64,
    /// Depth loss `L`.
    pub depth: DepthLoss,
    /// berHu threshold as a fraction of the largest absolute residual.
    pub berhu_ratio: f64,
    /// Resolution the loss is computed at.
    pub resolution: LossResolution,
    /// Weight `w` of the gradient-matching shape term `G` (0: eq. 21 as printed).
    pub gradient_weight: f64,
    /// Weight of the photometric loss on `[data] video` samples ([`super::photometric`])
    /// against eq. 21 on the other samples.
    pub photometric: f64,
    /// Weight of the edge-aware smoothness within the photometric loss (Monodepth2: 0.001).
    pub smoothness: f64,
}

impl Default for SdfcnnLossConfig {
    fn default() -> Self {
        SdfcnnLossConfig {
            lambda: 0.4,
            depth: DepthLoss::Berhu,
            berhu_ratio: 0.2,
            resolution: LossResolution::Quarter,
            gradient_weight: 0.0,
            photometric: 1.0,
            smoothness: 0.001,
        }
    }
}

/// The loss and its two terms (each a 1-element tensor).
#[derive(Debug, Clone)]
pub struct LossParts {
    /// `λ·H + (1 − λ)·L`.
    pub total: Tensor<1>,
    /// Cross entropy `H`.
    pub seg: Tensor<1>,
    /// Depth loss `L`.
    pub depth: Tensor<1>,
    /// Gradient-matching term `G` (computed only when its weight is not 0).
    pub shape: Option<Tensor<1>>,
}

impl SdfcnnLossConfig {
    /// Checks the ranges (λ in [0, 1], a positive berHu ratio, a gradient weight in [0, 100]).
    pub fn validate(&self) -> Result<(), String> {
        if !(0.0..=1.0).contains(&self.lambda) {
            return Err(format!("loss.lambda = {} must be in [0, 1]", self.lambda));
        }
        if !(self.berhu_ratio > 0.0 && self.berhu_ratio.is_finite()) {
            return Err(format!(
                "loss.berhu_ratio = {} must be positive",
                self.berhu_ratio
            ));
        }
        if !(0.0..=100.0).contains(&self.gradient_weight) {
            return Err(format!(
                "loss.gradient_weight = {} must be in [0, 100]",
                self.gradient_weight
            ));
        }
        for (name, w) in [
            ("photometric", self.photometric),
            ("smoothness", self.smoothness),
        ] {
            if !(0.0..=100.0).contains(&w) {
                return Err(format!("loss.{name} = {w} must be in [0, 100]"));
            }
        }
        Ok(())
    }

    /// Eq. 21 for network outputs `out` (logits `[N, C, h, w]`, depth `[N, 1, h, w]`) and
    /// targets `labels` (`[N, H, W]`, 255 = void) and `depth` (`[N, 1, H, W]` metres, 0 =
    /// missing). Targets of another size than the outputs are resized with nearest neighbour.
    pub fn forward(
        &self,
        out: SdfcnnOutput,
        labels: Tensor<3, Int>,
        depth: Tensor<4>,
    ) -> LossParts {
        let [_, _, h, w] = out.seg.dims();
        let labels = resize_nearest_labels(labels, [h, w]);
        let [_, _, dh, dw] = out.depth.dims();
        let depth = resize_nearest(depth, [dh, dw]);
        let seg = cross_entropy_void(out.seg, labels);
        let shape = (self.gradient_weight > 0.0)
            .then(|| gradient_matching_loss(out.depth.clone(), depth.clone(), &GRADIENT_STRIDES));
        let depth = depth_loss(out.depth, depth, self.depth, self.berhu_ratio);
        let mut depth_total = depth.clone();
        if let Some(g) = &shape {
            depth_total = depth_total + g.clone().mul_scalar(self.gradient_weight);
        }
        let total = seg.clone().mul_scalar(self.lambda) + depth_total.mul_scalar(1.0 - self.lambda);
        LossParts {
            total,
            seg,
            depth,
            shape,
        }
    }
}

/// Mean cross entropy of `logits` (`[N, C, H, W]`) against `labels` (`[N, H, W]`) over the
/// pixels whose label is not [`VOID`]; 0 when there is none.
pub fn cross_entropy_void(logits: Tensor<4>, labels: Tensor<3, Int>) -> Tensor<1> {
    let void = labels.clone().equal_elem(VOID as i64).unsqueeze_dim::<4>(1);
    let index = labels.unsqueeze_dim::<4>(1).mask_fill(void.clone(), 0);
    let nll = log_softmax(logits, 1)
        .gather(1, index)
        .neg()
        .mask_fill(void.clone(), 0.0);
    let count = sum_all(void.bool_not().float()).clamp_min(1.0).detach();
    sum_all(nll) / count
}

/// Mean depth loss of `pred` against `gt` (both `[N, 1, H, W]`) over pixels with `gt > 0`;
/// 0 when there is none. `berhu_ratio` sets the berHu threshold `c = ratio · max |r|`.
pub fn depth_loss(pred: Tensor<4>, gt: Tensor<4>, kind: DepthLoss, berhu_ratio: f64) -> Tensor<1> {
    let invalid = gt.clone().lower_equal_elem(0.0);
    let count = sum_all(invalid.clone().bool_not().float())
        .clamp_min(1.0)
        .detach();
    let r = (pred - gt).mask_fill(invalid.clone(), 0.0);
    let per_pixel = match kind {
        DepthLoss::L1 => r.abs(),
        DepthLoss::L2 => r.powi_scalar(2),
        DepthLoss::Berhu => {
            let abs = r.clone().abs();
            // The threshold is a constant of the step; the floor keeps 1/c finite when every
            // residual is zero (no pixel is then above it).
            let c = abs
                .clone()
                .detach()
                .max()
                .mul_scalar(berhu_ratio)
                .clamp_min(1e-6)
                .reshape([1, 1, 1, 1]);
            let above = abs.clone().greater(c.clone().expand(abs.dims()));
            let quad = (r.powi_scalar(2) + c.clone().powi_scalar(2)) / (c * 2.0);
            abs.mask_where(above, quad)
        }
    };
    sum_all(per_pixel.mask_fill(invalid, 0.0)) / count
}

/// Neighbour strides of the gradient-matching term (MegaDepth uses four scales).
pub(crate) const GRADIENT_STRIDES: [usize; 4] = [1, 2, 4, 8];

/// Depth below which a prediction is clamped before its logarithm (metres; the depth head is
/// linear and may go negative early in training).
const MIN_LOG_DEPTH: f64 = 0.01;

/// Multi-scale scale-invariant gradient matching (Li & Snavely 2018) of `pred` against `gt`
/// (both `[N, 1, H, W]`, `gt = 0` missing): with `R = log pred − log gt`, the mean of
/// `|R(p + s) − R(p)|` over the horizontal and vertical pixel pairs at stride `s` whose two
/// ends both have a depth, averaged over the `strides` that fit the image. 0 when no pair has
/// two valid ends.
pub(crate) fn gradient_matching_loss(
    pred: Tensor<4>,
    gt: Tensor<4>,
    strides: &[usize],
) -> Tensor<1> {
    let valid = gt.clone().greater_elem(0.0);
    let r = (pred.clamp_min(MIN_LOG_DEPTH).log() - gt.clamp_min(MIN_LOG_DEPTH).log())
        .mask_fill(valid.clone().bool_not(), 0.0);
    let valid = valid.float();
    let [n, c, h, w] = r.dims();
    let mut total = Tensor::<1>::zeros([1], &r.device());
    let mut scales = 0usize;
    for &s in strides.iter().filter(|&&s| s > 0 && (s < w || s < h)) {
        let mut sum = Tensor::<1>::zeros([1], &r.device());
        let mut count = Tensor::<1>::zeros([1], &r.device());
        // Pairs along x (dimension 3) then along y (dimension 2).
        let pairs = [
            (s < w).then(|| ([0..n, 0..c, 0..h, s..w], [0..n, 0..c, 0..h, 0..w - s])),
            (s < h).then(|| ([0..n, 0..c, s..h, 0..w], [0..n, 0..c, 0..h - s, 0..w])),
        ];
        for (a, b) in pairs.into_iter().flatten() {
            let both = valid.clone().slice(a.clone()) * valid.clone().slice(b.clone());
            let diff = (r.clone().slice(a) - r.clone().slice(b)).abs();
            sum = sum + sum_all(diff * both.clone());
            count = count + sum_all(both).detach();
        }
        total = total + sum / count.clamp_min(1.0);
        scales += 1;
    }
    total.div_scalar(scales.max(1) as f64)
}

/// Source index of each of `dst` output samples when resizing an axis of `src` samples with
/// nearest neighbour at pixel centres (`floor((i + ½)·src / dst)`).
pub(crate) fn nearest_indices(src: usize, dst: usize) -> Vec<i64> {
    (0..dst)
        .map(|i| (((2 * i + 1) * src) / (2 * dst)).min(src.saturating_sub(1)) as i64)
        .collect()
}

fn index_tensor(src: usize, dst: usize, device: &Device) -> Tensor<1, Int> {
    Tensor::from_data(TensorData::new(nearest_indices(src, dst), [dst]), device)
}

/// Nearest-neighbour resize of a label batch `[N, H, W]` to `[h, w]`.
pub(crate) fn resize_nearest_labels(labels: Tensor<3, Int>, [h, w]: [usize; 2]) -> Tensor<3, Int> {
    let [_, sh, sw] = labels.dims();
    let device = labels.device();
    let labels = if sh == h {
        labels
    } else {
        labels.select(1, index_tensor(sh, h, &device))
    };
    if sw == w {
        labels
    } else {
        labels.select(2, index_tensor(sw, w, &device))
    }
}

/// Nearest-neighbour resize of `[N, C, H, W]` to `[h, w]` (depth targets: no blending of
/// missing and valid pixels).
pub(crate) fn resize_nearest(x: Tensor<4>, [h, w]: [usize; 2]) -> Tensor<4> {
    let [_, _, sh, sw] = x.dims();
    let device = x.device();
    let x = if sh == h {
        x
    } else {
        x.select(2, index_tensor(sh, h, &device))
    };
    if sw == w {
        x
    } else {
        x.select(3, index_tensor(sw, w, &device))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[allow(deprecated)]
    fn devices() -> [Device; 2] {
        [Device::ndarray(), Device::flex()]
    }

    fn scalar(t: Tensor<1>) -> f64 {
        t.into_scalar::<f32>() as f64
    }

    fn labels(v: &[i64], shape: [usize; 3], d: &Device) -> Tensor<3, Int> {
        Tensor::from_data(TensorData::new(v.to_vec(), shape), d)
    }

    fn float4(v: &[f32], shape: [usize; 4], d: &Device) -> Tensor<4> {
        Tensor::from_data(TensorData::new(v.to_vec(), shape), d)
    }

    #[test]
    fn cross_entropy_by_hand_ignores_void() {
        for d in devices() {
            // 2 classes, 1×3 pixels: logits (0, 0), (ln 3, 0), (5, 7); labels 0, 1, void.
            let l3 = 3f32.ln();
            let logits = float4(&[0.0, l3, 5.0, 0.0, 0.0, 7.0], [1, 2, 1, 3], &d);
            let y = labels(&[0, 1, 255], [1, 1, 3], &d);
            // -ln(1/2) and -ln(1/4) averaged over 2 labelled pixels.
            let want = (2f64.ln() + 4f64.ln()) / 2.0;
            let got = scalar(cross_entropy_void(logits, y));
            assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        }
    }

    #[test]
    fn depth_losses_by_hand_on_valid_pixels() {
        for d in devices() {
            let pred = float4(&[1.5, 2.0, 3.0, 9.0], [1, 1, 2, 2], &d);
            let gt = float4(&[1.0, 3.0, 3.0, 0.0], [1, 1, 2, 2], &d);
            // Residuals on the 3 valid pixels: 0.5, -1, 0.
            let l1 = scalar(depth_loss(pred.clone(), gt.clone(), DepthLoss::L1, 0.2));
            assert!((l1 - 1.5 / 3.0).abs() < 1e-6);
            let l2 = scalar(depth_loss(pred.clone(), gt.clone(), DepthLoss::L2, 0.2));
            assert!((l2 - 1.25 / 3.0).abs() < 1e-6);
            // c = 0.2 · 1 = 0.2: both non-zero residuals are above c.
            let c = 0.2;
            let b = |r: f64| {
                if r.abs() <= c {
                    r.abs()
                } else {
                    (r * r + c * c) / (2.0 * c)
                }
            };
            let want = (b(0.5) + b(-1.0) + b(0.0)) / 3.0;
            let got = scalar(depth_loss(pred.clone(), gt.clone(), DepthLoss::Berhu, 0.2));
            assert!((got - want).abs() < 1e-5, "{got} vs {want}");
            // With c = 0.6 (ratio 0.6), 0.5 is below the threshold.
            let got = scalar(depth_loss(pred, gt, DepthLoss::Berhu, 0.6));
            let want = (0.5 + (1.0 + 0.36) / 1.2) / 3.0;
            assert!((got - want).abs() < 1e-5, "{got} vs {want}");
        }
    }

    #[test]
    fn total_is_weighted_sum_and_targets_are_resized() {
        let d = Device::flex();
        // Outputs 1×1, targets 2×2: the nearest sample of a 2→1 axis is index 1.
        let out = SdfcnnOutput {
            seg: float4(&[0.0, 0.0], [1, 2, 1, 1], &d),
            depth: float4(&[2.0], [1, 1, 1, 1], &d),
        };
        let y = labels(&[255, 255, 255, 1], [1, 2, 2], &d);
        let gt = float4(&[0.0, 0.0, 0.0, 3.0], [1, 1, 2, 2], &d);
        let cfg = SdfcnnLossConfig {
            depth: DepthLoss::L1,
            ..Default::default()
        };
        let p = cfg.forward(out, y, gt);
        let (seg, depth, total) = (scalar(p.seg), scalar(p.depth), scalar(p.total));
        assert!((seg - 2f64.ln()).abs() < 1e-6);
        assert!((depth - 1.0).abs() < 1e-6);
        assert!((total - (0.4 * 2f64.ln() + 0.6)).abs() < 1e-6);
        assert_eq!(nearest_indices(4, 2), vec![1, 3]);
        assert_eq!(nearest_indices(3, 6), vec![0, 0, 1, 1, 2, 2]);
        assert_eq!(nearest_indices(240, 75)[0], 1);
    }

    #[test]
    fn empty_targets_give_zero_and_finite_gradients() {
        for d in devices() {
            let d = d.autodiff();
            let seg = Tensor::<4>::random([2, 3, 2, 2], burn::tensor::Distribution::Default, &d)
                .require_grad();
            let depth = Tensor::<4>::random([2, 1, 2, 2], burn::tensor::Distribution::Default, &d)
                .require_grad();
            let out = SdfcnnOutput {
                seg: seg.clone(),
                depth: depth.clone(),
            };
            let y = labels(&[255; 8], [2, 2, 2], &d);
            let gt = Tensor::<4>::zeros([2, 1, 2, 2], &d);
            let p = SdfcnnLossConfig::default().forward(out, y, gt);
            assert_eq!(scalar(p.total.clone()), 0.0);
            let grads = p.total.backward();
            for g in [seg.grad(&grads), depth.grad(&grads)] {
                let g = g
                    .expect("gradient")
                    .into_data()
                    .try_to_vec::<f32>()
                    .expect("f32");
                assert!(g.iter().all(|v| *v == 0.0), "{g:?}");
            }
        }
    }

    #[test]
    fn gradient_matching_by_hand_skips_pairs_with_a_missing_end() {
        for d in devices() {
            // R = log pred − log gt = [0, ln 2; ln 2, missing]: one valid pair along x (row 0)
            // and one along y (column 0), each |ln 2|; stride 2 does not fit a 2×2 image.
            let pred = float4(&[1.0, 2.0, 4.0, 4.0], [1, 1, 2, 2], &d);
            let gt = float4(&[1.0, 1.0, 2.0, 0.0], [1, 1, 2, 2], &d);
            let got = scalar(gradient_matching_loss(pred, gt, &GRADIENT_STRIDES));
            assert!((got - 2f64.ln()).abs() < 1e-5, "{got}");
        }
    }

    #[test]
    fn gradient_matching_ignores_a_global_scale_but_not_a_wrong_shape() {
        let d = Device::flex();
        let gt: Vec<f32> = (0..2 * 16 * 20)
            .map(|i| 1.0 + (i % 37) as f32 * 0.1)
            .collect();
        let gt = float4(&gt, [2, 1, 16, 20], &d);
        let scaled = gt.clone().mul_scalar(2.5);
        let g = scalar(gradient_matching_loss(
            scaled,
            gt.clone(),
            &GRADIENT_STRIDES,
        ));
        assert!(g.abs() < 1e-5, "{g}");
        // A flat prediction misses every relative step of the target.
        let flat = Tensor::<4>::ones([2, 1, 16, 20], &d).mul_scalar(2.0);
        let g = scalar(gradient_matching_loss(flat, gt, &GRADIENT_STRIDES));
        assert!(g > 0.05, "{g}");
    }

    #[test]
    fn gradient_weight_adds_the_shape_term_to_the_depth_part() {
        let d = Device::flex();
        let out = SdfcnnOutput {
            seg: float4(&[0.0; 8], [1, 2, 2, 2], &d),
            depth: float4(&[1.0, 2.0, 4.0, 4.0], [1, 1, 2, 2], &d),
        };
        let y = labels(&[0, 1, 255, 255], [1, 2, 2], &d);
        let gt = float4(&[1.0, 1.0, 2.0, 0.0], [1, 1, 2, 2], &d);
        let cfg = SdfcnnLossConfig {
            depth: DepthLoss::L1,
            gradient_weight: 0.5,
            ..Default::default()
        };
        let p = cfg.forward(out, y, gt);
        let shape = scalar(p.shape.expect("shape term"));
        let (seg, depth, total) = (scalar(p.seg), scalar(p.depth), scalar(p.total));
        assert!((shape - 2f64.ln()).abs() < 1e-5);
        // L1 on the valid residuals 0, 1, 2.
        assert!((depth - 1.0).abs() < 1e-6);
        let want = 0.4 * seg + 0.6 * (depth + 0.5 * shape);
        assert!((total - want).abs() < 1e-5, "{total} vs {want}");
        assert!(SdfcnnLossConfig::default().validate().is_ok());
        for bad in [-0.1, 101.0, f64::NAN] {
            let cfg = SdfcnnLossConfig {
                gradient_weight: bad,
                ..Default::default()
            };
            assert!(cfg.validate().is_err(), "{bad}");
        }
    }

    #[test]
    fn gradient_matching_without_depth_is_zero_with_finite_gradients() {
        let d = Device::flex().autodiff();
        let pred = Tensor::<4>::random([1, 1, 4, 4], burn::tensor::Distribution::Default, &d)
            .sub_scalar(0.5)
            .require_grad();
        let zero = Tensor::<4>::zeros([1, 1, 4, 4], &d);
        let l = gradient_matching_loss(pred.clone(), zero, &GRADIENT_STRIDES);
        assert_eq!(scalar(l.clone()), 0.0);
        let g = pred.grad(&l.backward()).expect("gradient");
        let g = g.into_data().try_to_vec::<f32>().expect("f32");
        assert!(g.iter().all(|v| v.is_finite()), "{g:?}");
    }

    #[test]
    fn berhu_gradient_is_finite_when_residuals_vanish() {
        let d = Device::flex().autodiff();
        let pred = float4(&[1.0, 2.0], [1, 1, 1, 2], &d).require_grad();
        let gt = float4(&[1.0, 2.0], [1, 1, 1, 2], &d);
        let l = depth_loss(pred.clone(), gt, DepthLoss::Berhu, 0.2);
        let g = pred.grad(&l.backward()).expect("gradient");
        let g = g.into_data().try_to_vec::<f32>().expect("f32");
        assert!(g.iter().all(|v| v.is_finite()), "{g:?}");
    }
}
