//! Faster equivalents of the layers SDFCNN uses everywhere, built from operations whose
//! backward pass every backend runs quickly. They use the layers' own parameters, so
//! checkpoints do not change.
//!
//! * [`conv2d`] runs a 1×1, stride-1 convolution as a matrix product over the channels (or,
//!   when depthwise, a per-channel scale). burn-ndarray computes the weight gradient of a 1×1
//!   convolution ~90× slower than the matrix product (2.7 s vs 30 ms for 96 channels at
//!   3×48×64); burn-flex gains ~2×.
//! * During training (autodiff device) [`conv2d`] runs a 3×3 depthwise convolution as nine
//!   shifted, per-channel-scaled slices on every backend (backward 2.5-5× faster on
//!   burn-ndarray, about the same on burn-flex), and on burn-ndarray any other dense
//!   convolution as `k²` shifted matrix products: burn-ndarray's convolution backward takes
//!   17-50 s for a 32→64 4×4/2 or 64→128 3×3 layer at batch 4, 120×160 / 60×80, and 2-2.5 s for
//!   SDFCNN's Layer1 (3→32 3×3/2 at 300×400) or depth1 (256→1 3×3 at 75×100), against
//!   0.3-0.9 s this way. Inference keeps Burn's convolution, whose forward is faster.
//! * [`max_pool_same`]: a k×k, stride-1 max pooling with `k/2` padding as two separable
//!   running maxima over shifted slices (exact, with `-∞` padding as PyTorch pads); 1.5× faster
//!   than burn's `max_pool2d` with its backward on burn-ndarray, 1.2× on burn-flex. Where
//!   several pixels of a window share the maximum the gradient goes to one of them, not
//!   necessarily the one PyTorch picks.

use burn::nn::PaddingConfig2d;
use burn::nn::conv::Conv2d;
use burn::prelude::*;
use burn::tensor::ops::PadMode;

/// Whether `device` is burn-ndarray (with or without autodiff).
fn is_ndarray(device: &Device) -> bool {
    #[allow(deprecated)] // ndarray is deprecated upstream but the project's default backend.
    let ndarray = Device::ndarray();
    device.clone().without_autodiff() == ndarray
}

/// `conv.forward(x)`, computed as described in the module docs.
pub fn conv2d(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let [out, per_group, kh, kw] = conv.weight.dims();
    let [n, cin, h, w] = x.dims();
    let padding = match conv.padding {
        PaddingConfig2d::Valid => Some([0, 0]),
        PaddingConfig2d::Explicit(top, left, bottom, right) if top == bottom && left == right => {
            Some([top, left])
        }
        _ => None,
    };
    let (Some(padding), [1, 1]) = (padding, conv.dilation) else {
        return conv.forward(x);
    };
    let dense = conv.groups == 1 && per_group == cin;
    let depthwise = conv.groups == cin && per_group == 1 && out == cin;
    if [kh, kw] == [1, 1] && conv.stride == [1, 1] && padding == [0, 0] {
        let y = if dense {
            let weight = conv.weight.val().reshape([1, out, cin]);
            weight
                .matmul(x.reshape([n, cin, h * w]))
                .reshape([n, out, h, w])
        } else if depthwise {
            x * conv.weight.val().reshape([1, out, 1, 1])
        } else {
            return conv.forward(x);
        };
        return with_bias(y, conv);
    }
    let device = x.device();
    let training = device.is_autodiff();
    let shifted = training
        && ((depthwise && [kh, kw] == [3, 3] && conv.stride == [1, 1] && padding == [1, 1])
            || (dense && is_ndarray(&device)));
    if shifted {
        with_bias(
            shifted_conv(conv.weight.val(), x, conv.stride, padding, depthwise),
            conv,
        )
    } else {
        conv.forward(x)
    }
}

fn with_bias(y: Tensor<4>, conv: &Conv2d) -> Tensor<4> {
    match &conv.bias {
        Some(b) => {
            let [out] = b.dims();
            y + b.val().reshape([1, out, 1, 1])
        }
        None => y,
    }
}

/// Every `stride`-th element of the last axis of `x`, starting with the first, for `len`
/// outputs (`x` holds at least `stride · len` elements on that axis).
fn every_nth_col(x: Tensor<4>, stride: usize, len: usize) -> Tensor<4> {
    let [n, c, h, _] = x.dims();
    let x = x.slice(s![.., .., .., 0..stride * len]);
    if stride == 1 {
        return x;
    }
    x.reshape([n, c * h * len, stride])
        .slice(s![.., .., 0..1])
        .reshape([n, c, h, len])
}

/// Every `stride`-th row of `x` (axis 2), for `len` outputs.
fn every_nth_row(x: Tensor<4>, stride: usize, len: usize) -> Tensor<4> {
    let [n, c, _, w] = x.dims();
    let x = x.slice(s![.., .., 0..stride * len, ..]);
    if stride == 1 {
        return x;
    }
    x.reshape([n, c * len, stride, w])
        .slice(s![.., .., 0..1, ..])
        .reshape([n, c, len, w])
}

/// Convolution as a sum over the kernel offsets `(dy, dx)` of the input shifted by that offset
/// (and subsampled by the stride) times the weights at that offset: a matrix product for a
/// dense convolution, a per-channel scale for a depthwise one. Zero padding `[top/bottom,
/// left/right]`.
fn shifted_conv(
    weight: Tensor<4>,
    x: Tensor<4>,
    [sy, sx]: [usize; 2],
    [py, px]: [usize; 2],
    depthwise: bool,
) -> Tensor<4> {
    let [out, cin, kh, kw] = weight.dims();
    let [n, c, h, w] = x.dims();
    let oh = (h + 2 * py - kh) / sy + 1;
    let ow = (w + 2 * px - kw) / sx + 1;
    // Pad so that every shifted window of `stride · out` samples fits.
    let hp = (kh - 1 + sy * oh).max(h + 2 * py);
    let wp = (kw - 1 + sx * ow).max(w + 2 * px);
    let xp = x.pad(
        [(py, hp - h - py), (px, wp - w - px)],
        PadMode::Constant(0.0),
    );
    let mut y: Option<Tensor<4>> = None;
    for dy in 0..kh {
        let rows = every_nth_row(xp.clone().slice(s![.., .., dy.., ..]), sy, oh);
        for dx in 0..kw {
            let t = every_nth_col(rows.clone().slice(s![.., .., .., dx..]), sx, ow);
            let k = weight.clone().slice(s![.., .., dy..dy + 1, dx..dx + 1]);
            let t = if depthwise {
                t * k.reshape([1, out, 1, 1])
            } else {
                k.reshape([1, out, cin])
                    .matmul(t.reshape([n, c, oh * ow]))
                    .reshape([n, out, oh, ow])
            };
            y = Some(match y {
                Some(y) => y + t,
                None => t,
            });
        }
    }
    y.unwrap_or_else(|| Tensor::zeros([n, out, oh, ow], &weight.device()))
}

/// `k`×`k` max pooling, stride 1, padding `k / 2` (odd `k`): the output has the input's size.
pub fn max_pool_same(x: Tensor<4>, k: usize) -> Tensor<4> {
    let p = k / 2;
    let [_, _, h, w] = x.dims();
    let xp = x.pad([(0, 0), (p, p)], PadMode::Constant(f32::NEG_INFINITY));
    let mut m = xp.clone().slice(s![.., .., .., 0..w]);
    for i in 1..k {
        m = m.max_pair(xp.clone().slice(s![.., .., .., i..i + w]));
    }
    let xp = m.pad([(p, p), (0, 0)], PadMode::Constant(f32::NEG_INFINITY));
    let mut m = xp.clone().slice(s![.., .., 0..h, ..]);
    for i in 1..k {
        m = m.max_pair(xp.clone().slice(s![.., .., i..i + h, ..]));
    }
    m
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::conv::Conv2dConfig;
    use burn::nn::pool::MaxPool2dConfig;
    use burn::tensor::Distribution;

    #[allow(deprecated)]
    fn devices() -> [Device; 2] {
        [Device::ndarray().autodiff(), Device::flex().autodiff()]
    }

    fn max_abs_diff(a: Tensor<4>, b: Tensor<4>) -> f32 {
        (a - b).abs().max().into_scalar::<f32>()
    }

    /// (in, out, kernel, stride, padding, groups, bias) of every kind of layer in both networks.
    const CASES: [(usize, usize, usize, usize, usize, usize, bool); 9] = [
        (6, 6, 1, 1, 0, 1, true),
        (6, 5, 1, 1, 0, 1, false),
        (6, 6, 1, 1, 0, 6, false),
        (4, 4, 3, 1, 1, 4, true),
        (4, 4, 3, 2, 1, 4, false),
        (3, 5, 3, 2, 1, 1, false),
        (2, 3, 4, 2, 1, 1, true),
        (4, 1, 3, 1, 1, 1, true),
        (3, 4, 3, 1, 0, 1, true),
    ];

    #[test]
    #[allow(deprecated)]
    fn backend_detection() {
        assert!(is_ndarray(&Device::ndarray().autodiff()) && is_ndarray(&Device::ndarray()));
        assert!(!is_ndarray(&Device::flex().autodiff()) && !is_ndarray(&Device::flex()));
    }

    #[test]
    fn convs_match_burn_with_gradients() {
        for d in devices().into_iter().chain([Device::flex()]) {
            for (cin, cout, k, s, p, groups, bias) in CASES {
                let conv = Conv2dConfig::new([cin, cout], [k, k])
                    .with_stride([s, s])
                    .with_padding(PaddingConfig2d::Explicit(p, p, p, p))
                    .with_groups(groups)
                    .with_bias(bias)
                    .init(&d);
                // Odd sizes check the stride bookkeeping.
                let x = Tensor::<4>::random([2, cin, 7, 9], Distribution::Default, &d);
                let (a, b) = (conv.forward(x.clone()), conv2d(&conv, x));
                assert_eq!(a.dims(), b.dims(), "{cin}->{cout} k{k} s{s} p{p} g{groups}");
                assert!(max_abs_diff(a.clone(), b.clone()) < 1e-5);
                if !d.is_autodiff() {
                    continue;
                }
                let (ga, gb) = (
                    a.powi_scalar(2).sum().backward(),
                    b.powi_scalar(2).sum().backward(),
                );
                let g = |g| conv.weight.grad(g).expect("weight gradient");
                let diff = max_abs_diff(g(&ga), g(&gb));
                assert!(
                    diff < 1e-4,
                    "{cin}->{cout} k{k} s{s} p{p} g{groups}: {diff}"
                );
            }
        }
    }

    #[test]
    fn separable_max_pool_equals_burn_max_pool() {
        for d in devices() {
            let pool = MaxPool2dConfig::new([5, 5])
                .with_strides([1, 1])
                .with_padding(PaddingConfig2d::Explicit(2, 2, 2, 2))
                .init();
            let x = Tensor::<4>::random([2, 3, 6, 9], Distribution::Default, &d).require_grad();
            let (a, b) = (pool.forward(x.clone()), max_pool_same(x.clone(), 5));
            assert_eq!(max_abs_diff(a.clone(), b.clone()), 0.0);
            // With distinct values both route each output's gradient to the same input.
            let (ga, gb) = (a.sum().backward(), b.sum().backward());
            let (ga, gb) = (x.grad(&ga).expect("grad"), x.grad(&gb).expect("grad"));
            assert_eq!(max_abs_diff(ga, gb), 0.0);
        }
    }
}
