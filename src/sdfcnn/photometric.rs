//! Self-supervised depth from a moving camera: Monodepth2's photometric loss (Godard et al.,
//! "Digging Into Self-Supervised Monocular Depth Estimation", ICCV 2019), with the poses given
//! rather than learnt (they come from `slam`'s trajectory of the same recording).
//!
//! For a target image `I_t`, its predicted metric depth `D` and a source image `I_s` with the
//! relative pose `T_st` (target camera to source camera), every target pixel `p` is lifted to
//! `D(p) K⁻¹ p`, moved by `T_st`, projected with `K` and `I_s` is sampled there ([`warp`]):
//! `I_s→t`. The loss per pixel is
//!
//! * `pe(a, b) = α (1 − SSIM(a, b)) / 2 + (1 − α) |a − b|`, α = 0.85, SSIM over 3x3 windows
//!   (`photometric_error`);
//! * the **minimum** over the sources of `pe(I_s→t, I_t)` (a pixel occluded in one source is
//!   judged by the other);
//! * **auto-masking**: the unwarped sources' `pe(I_s, I_t)` join that minimum, so a pixel that
//!   matches better without any motion (a static camera, an object moving with it, a
//!   textureless wall) is judged by that identity error, which has no gradient to the depth;
//!
//! averaged over the pixels, plus `smoothness` times the edge-aware smoothness of the
//! mean-normalised inverse depth (`smoothness_loss`). Unlike Monodepth2 it is taken at the
//! input resolution only, and the windows at the border average the pixels inside rather than
//! reflect them. Because the poses are metric (a sensor's, or a monocular run scaled by
//! `--camera-height`), the depth this teaches is metric too.

use burn::prelude::*;
use burn::tensor::module::avg_pool2d;
use burn::tensor::ops::{
    AvgPoolOptions, GridSampleOptions, GridSamplePaddingMode, InterpolateMode,
};

/// SSIM's weight in the photometric error (Monodepth2's α).
pub(crate) const SSIM_WEIGHT: f64 = 0.85;

/// Added to the identity errors so that a tie goes to the warped source.
const IDENTITY_OFFSET: f64 = 1e-5;

/// Nearest depth a warp divides by, metres.
const MIN_DEPTH: f64 = 1e-3;

/// `I_s` sampled where each target pixel lands in the source camera: `src` `[N, C, H, W]`,
/// the target's metric `depth` `[N, 1, H, W]`, `pose` `[N, 12]` the target-to-source
/// transform (rotation row-major, then translation) and `k` `[N, 4]` the intrinsics
/// `fx, fy, cx, cy` at `W x H` (pixel centres at integer coordinates). Pixels that land
/// outside the source take its border.
pub fn warp(src: Tensor<4>, depth: Tensor<4>, pose: Tensor<2>, k: Tensor<2>) -> Tensor<4> {
    let [n, _, h, w] = depth.dims();
    let device = depth.device();
    let depth = depth.clamp_min(MIN_DEPTH);
    let col = |t: &Tensor<2>, i: usize| t.clone().slice([0..n, i..i + 1]).reshape([n, 1, 1, 1]);
    let (fx, fy, cx, cy) = (col(&k, 0), col(&k, 1), col(&k, 2), col(&k, 3));
    let u = Tensor::<1, Int>::arange(0..w as i64, &device)
        .float()
        .reshape([1, 1, 1, w]);
    let v = Tensor::<1, Int>::arange(0..h as i64, &device)
        .float()
        .reshape([1, 1, h, 1]);
    let x = (u - cx.clone()) / fx.clone() * depth.clone();
    let y = (v - cy.clone()) / fy.clone() * depth.clone();
    let z = depth;
    let row = |r: usize| {
        col(&pose, 3 * r) * x.clone()
            + col(&pose, 3 * r + 1) * y.clone()
            + col(&pose, 3 * r + 2) * z.clone()
            + col(&pose, 9 + r)
    };
    let (xs, ys, zs) = (row(0), row(1), row(2).clamp_min(MIN_DEPTH));
    let us = fx * xs / zs.clone() + cx;
    let vs = fy * ys / zs + cy;
    // align_corners = false: -1 and 1 are the outer edges of the border pixels.
    let gx = (us * 2.0 + 1.0) / w as f64 - 1.0;
    let gy = (vs * 2.0 + 1.0) / h as f64 - 1.0;
    let grid = Tensor::cat(vec![gx, gy], 1).permute([0, 2, 3, 1]);
    let options = GridSampleOptions::new(InterpolateMode::Bilinear)
        .with_padding_mode(GridSamplePaddingMode::Border)
        .with_align_corners(false);
    src.grid_sample_2d(grid, options)
}

/// Mean over 3x3 windows (the pixels inside the image at the border).
fn window_mean(x: Tensor<4>) -> Tensor<4> {
    let options = AvgPoolOptions::new([3, 3])
        .with_stride([1, 1])
        .with_padding([1, 1])
        .with_count_include_pad(false);
    avg_pool2d(x, options)
}

/// Monodepth2's photometric error of two images `[N, C, H, W]` in `[0, 1]`, per pixel
/// `[N, 1, H, W]`: `α (1 − SSIM) / 2 + (1 − α) |a − b|`, averaged over the channels.
pub(crate) fn photometric_error(a: Tensor<4>, b: Tensor<4>) -> Tensor<4> {
    const C1: f64 = 0.01 * 0.01;
    const C2: f64 = 0.03 * 0.03;
    let l1 = (a.clone() - b.clone()).abs().mean_dim(1);
    let (mu_a, mu_b) = (window_mean(a.clone()), window_mean(b.clone()));
    let var_a = window_mean(a.clone() * a.clone()) - mu_a.clone() * mu_a.clone();
    let var_b = window_mean(b.clone() * b.clone()) - mu_b.clone() * mu_b.clone();
    let cov = window_mean(a * b) - mu_a.clone() * mu_b.clone();
    let num = (mu_a.clone() * mu_b.clone() * 2.0 + C1) * (cov * 2.0 + C2);
    let den = (mu_a.clone() * mu_a + mu_b.clone() * mu_b + C1) * (var_a + var_b + C2);
    let dissimilarity = ((-(num / den) + 1.0) / 2.0).clamp(0.0, 1.0).mean_dim(1);
    dissimilarity * SSIM_WEIGHT + l1 * (1.0 - SSIM_WEIGHT)
}

/// The per-pixel minimum reprojection error with auto-masking, averaged over the pixels: the
/// target `[N, 3, H, W]`, its metric depth `[N, 1, H, W]`, and each source image with its
/// target-to-source pose `[N, 12]`; `k` as in [`warp`].
pub(crate) fn reprojection_loss(
    target: Tensor<4>,
    depth: Tensor<4>,
    sources: &[(Tensor<4>, Tensor<2>)],
    k: Tensor<2>,
) -> Tensor<1> {
    let mut errors = Vec::with_capacity(2 * sources.len());
    for (src, pose) in sources {
        errors.push(photometric_error(src.clone(), target.clone()) + IDENTITY_OFFSET);
        let warped = warp(src.clone(), depth.clone(), pose.clone(), k.clone());
        errors.push(photometric_error(warped, target.clone()));
    }
    Tensor::cat(errors, 1).min_dim(1).mean()
}

/// Edge-aware smoothness of the mean-normalised inverse depth (Monodepth2's): its horizontal
/// and vertical differences, each weighted by `exp(−|∂I|)` of the image `[N, 3, H, W]`.
pub(crate) fn smoothness_loss(depth: Tensor<4>, image: Tensor<4>) -> Tensor<1> {
    let [n, _, h, w] = depth.dims();
    let disp = depth.clamp_min(MIN_DEPTH).recip();
    let disp = disp.clone() / disp.mean_dim(2).mean_dim(3);
    let dx = |t: Tensor<4>| {
        let c = t.dims()[1];
        t.clone().slice([0..n, 0..c, 0..h, 1..w]) - t.slice([0..n, 0..c, 0..h, 0..w - 1])
    };
    let dy = |t: Tensor<4>| {
        let c = t.dims()[1];
        t.clone().slice([0..n, 0..c, 1..h, 0..w]) - t.slice([0..n, 0..c, 0..h - 1, 0..w])
    };
    let weight = |g: Tensor<4>| (-g.abs().mean_dim(1)).exp();
    let x = dx(disp.clone()).abs() * weight(dx(image.clone()));
    let y = dy(disp).abs() * weight(dy(image));
    x.mean() + y.mean()
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::TensorData;

    const H: usize = 24;
    const W: usize = 32;

    /// A smooth random texture `[1, 3, H, W]` in [0, 1].
    fn texture(device: &Device) -> Tensor<4> {
        let mut values = Vec::with_capacity(3 * H * W);
        for c in 0..3 {
            for v in 0..H {
                for u in 0..W {
                    let (x, y) = (u as f32, v as f32);
                    let s = (0.7 * x + 0.3 * c as f32).sin() * (0.5 * y).cos()
                        + 0.5 * (0.23 * x * y / 10.0 + c as f32).sin();
                    values.push(0.5 + 0.3 * s);
                }
            }
        }
        Tensor::from_data(TensorData::new(values, [1, 3, H, W]), device)
    }

    fn pose(t: [f32; 3]) -> [f32; 12] {
        [
            1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, t[0], t[1], t[2],
        ]
    }

    fn tensors(device: &Device, pose: [f32; 12]) -> (Tensor<2>, Tensor<2>) {
        let k = [30.0, 30.0, (W as f32 - 1.0) / 2.0, (H as f32 - 1.0) / 2.0];
        (
            Tensor::from_data(TensorData::new(pose.to_vec(), [1, 12]), device),
            Tensor::from_data(TensorData::new(k.to_vec(), [1, 4]), device),
        )
    }

    fn max_abs(t: Tensor<4>) -> f32 {
        t.abs().max().into_scalar::<f32>()
    }

    #[test]
    fn no_motion_warps_the_source_onto_itself() {
        let device = Device::flex();
        let src = texture(&device);
        let depth = Tensor::<4>::ones([1, 1, H, W], &device) * 2.0;
        let (pose, k) = tensors(&device, pose([0.0; 3]));
        let warped = warp(src.clone(), depth, pose, k);
        assert!(max_abs(warped - src.clone()) < 1e-5);
        let same = photometric_error(src.clone(), src);
        assert!(max_abs(same) < 1e-6);
    }

    #[test]
    fn a_sideways_move_shifts_the_image_by_the_disparity() {
        // fx 30 px, depth 2 m, 0.2 m to the side: the scene moves 3 px in the source.
        let device = Device::flex();
        let src = texture(&device);
        let depth = Tensor::<4>::ones([1, 1, H, W], &device) * 2.0;
        let (pose, k) = tensors(&device, pose([0.2, 0.0, 0.0]));
        let warped = warp(src.clone(), depth, pose, k);
        let inner = |t: Tensor<4>, from: usize| t.slice([0..1, 0..3, 0..H, from..from + W - 4]);
        assert!(max_abs(inner(warped, 0) - inner(src, 3)) < 1e-5);
    }

    /// The target a source looks like from a camera `t` away, when the scene lies at `depth`.
    fn scene(
        device: &Device,
        t: [f32; 3],
        depth: f32,
    ) -> (Tensor<4>, Tensor<4>, Tensor<2>, Tensor<2>) {
        let src = texture(device);
        let d = Tensor::<4>::ones([1, 1, H, W], device) * depth;
        let (pose, k) = tensors(device, pose(t));
        let target = warp(src.clone(), d, pose.clone(), k.clone());
        (target, src, pose, k)
    }

    #[test]
    fn the_loss_is_lowest_at_the_true_depth_and_its_gradient_points_there() {
        let device = Device::flex().autodiff();
        let (target, src, pose, k) = scene(&device, [0.15, 0.05, 0.1], 2.0);
        let loss_at = |depth: f32| {
            let d = Tensor::<4>::ones([1, 1, H, W], &device) * depth;
            let sources = [(src.clone(), pose.clone())];
            reprojection_loss(target.clone(), d, &sources, k.clone()).into_scalar::<f32>()
        };
        let (short, right, long) = (loss_at(1.4), loss_at(2.0), loss_at(2.8));
        assert!(
            right < 0.6 * short && right < 0.6 * long,
            "{short} {right} {long}"
        );
        // Too near: the gradient says farther, and too far: nearer.
        for (depth, sign) in [(1.6f32, -1.0f32), (2.5, 1.0)] {
            let d = (Tensor::<4>::ones([1, 1, H, W], &device) * depth).require_grad();
            let sources = [(src.clone(), pose.clone())];
            let loss = reprojection_loss(target.clone(), d.clone(), &sources, k.clone());
            let grads = loss.backward();
            let g = d
                .grad(&grads)
                .expect("depth gradient")
                .sum()
                .into_scalar::<f32>();
            assert!(g * sign > 0.0, "depth {depth}: gradient {g}");
        }
    }

    #[test]
    fn auto_masking_ignores_a_camera_that_did_not_move() {
        // A source identical to the target: the identity error (0) wins at every pixel, and
        // the depth, however wrong, is not penalised.
        let device = Device::flex();
        let (target, _, _, k) = scene(&device, [0.0; 3], 2.0);
        let (pose, _) = tensors(&device, pose([0.2, 0.0, 0.0]));
        let wrong = Tensor::<4>::ones([1, 1, H, W], &device) * 0.5;
        let sources = [(target.clone(), pose)];
        let loss = reprojection_loss(target, wrong, &sources, k).into_scalar::<f32>();
        assert!(loss <= 2.0 * IDENTITY_OFFSET as f32, "{loss}");
    }

    #[test]
    fn smoothness_is_zero_for_a_plane_of_constant_depth_and_grows_with_edges() {
        let device = Device::flex();
        let image = texture(&device);
        let flat = Tensor::<4>::ones([1, 1, H, W], &device) * 3.0;
        assert!(smoothness_loss(flat, image.clone()).into_scalar::<f32>() < 1e-7);
        let steps: Vec<f32> = (0..H * W)
            .map(|i| if i % W < W / 2 { 1.0 } else { 4.0 })
            .collect();
        let step = Tensor::from_data(TensorData::new(steps, [1, 1, H, W]), &device);
        assert!(smoothness_loss(step, image).into_scalar::<f32>() > 1e-3);
    }
}
