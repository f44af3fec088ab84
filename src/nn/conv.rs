//! 2-D convolution built from matrix products and slices.
//!
//! # Why this exists
//!
//! burn-ndarray 0.22.1 convolves with naive loops: its `conv2d` is a direct convolution (one
//! multiply-add pass over the input per kernel tap and input channel), the input gradient goes
//! through `conv_transpose2d`, a seven-deep indexed loop, and the weight gradient of a grouped
//! (depthwise) convolution runs one convolution per group. Training FPFDCNN on ndarray was ~30×
//! slower than on flex, with 90 % of the time inside those loops.
//!
//! [`conv2d_matmul`] computes the same convolution from ordinary differentiable tensor ops that
//! ndarray executes well:
//!
//! * 1×1 stride-1 unpadded convolutions are a (batched) matrix product, or an elementwise product
//!   when depthwise.
//! * Otherwise the input is zero-padded and, for every kernel tap `(kh, kw)`, a strided slice
//!   gives the `[N, C, OH, OW]` input values that tap sees (im2col). Stacked along the channels,
//!   they form `[N, KH·KW·C, OH·OW]`, which one matrix product with the `[OC, KH·KW·C]` weight
//!   turns into the output (a GEMM through `matrixmultiply` on ndarray).
//! * Depthwise convolutions (`groups == C == OC`) sum `slice · w[c, kh, kw]` over the taps:
//!   elementwise, no matrix product.
//! * Other grouped convolutions run the dense path per group.
//!
//! Stride-2 convolutions with an even kernel (FPFDCNN's 4×4 s2) are first turned into stride-1
//! convolutions by space-to-depth (a reshape and a permutation), which cuts the number of
//! slices, and so of the slice gradients, by the stride².
//!
//! The autodiff backward of these ops is again matrix products, slice assignments and sums,
//! all fast on ndarray. [`conv2d`] picks this path or Burn's own convolution per device and
//! kind of convolution (see [`OpImpl`]).

use std::sync::atomic::{AtomicU8, Ordering};

use burn::nn::PaddingConfig2d;
use burn::nn::conv::Conv2d;
use burn::prelude::*;
use burn::tensor::ops::{ConvOptions, PadMode};

use super::backend::is_cpu;
use super::{dense_conv_kernel, depthwise_kernel};

/// Which implementation [`conv2d`] and [`crate::nn::max_pool2d`] run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum OpImpl {
    /// Per op and device, whichever measured faster (`lab/examples/conv_speed.rs`, 2-core VM):
    ///
    /// * ndarray with autodiff (training): the composite ops — Burn's convolution backward
    ///   there is 10–600× slower — except depthwise and dense convolutions (below).
    /// * ndarray without autodiff (inference): the composite ops except 3×3 depthwise
    ///   convolutions, whose direct loop forward is ~4× faster than nine slices.
    /// * flex: only 1×1 stride-1 convolutions (a plain matrix product, 3–5× faster forward +
    ///   backward on flex too) and, without autodiff, the max pool (2×).
    /// * stride-1 max pools with autodiff on either CPU backend: `crate::nn::pool_kernel`
    ///   (`pool_path`); depthwise convolutions with autodiff on either CPU backend:
    ///   `crate::nn::depthwise_kernel`, and dense ones (groups 1, dilation 1) with at least
    ///   as many output as input channels: `crate::nn::dense_conv_kernel`
    ///   (`conv_uses_kernel`; FPFDCNN's train step 0.5× on ndarray, 0.8-0.95× on flex).
    /// * the GPU backends (wgpu, cuda): 1×1 convolutions as matrix products too, Burn's own
    ///   kernels otherwise. Burn 0.22.1's wgpu 1×1 convolution returns a tensor that later
    ///   in-place element-wise ops read wrongly (SDFCNN's one-channel depth head gave an L1
    ///   loss of 1.06 where the CPU gives 2.00; `tests/gpu_backends.rs` checks the losses).
    #[default]
    Auto,
    /// Always Burn's own kernels (`Conv2d::forward`, `MaxPool2d::forward`).
    Burn,
    /// Always the composite ops ([`conv2d_matmul`], `crate::nn::pool::max_pool2d_shifted`).
    Composite,
}

static OP_IMPL: AtomicU8 = AtomicU8::new(0);

/// Sets the process-wide implementation used by [`conv2d`] and [`crate::nn::max_pool2d`] (for
/// benchmarks and comparisons; [`OpImpl::Auto`] is the default).
pub fn set_op_impl(choice: OpImpl) {
    let v = match choice {
        OpImpl::Auto => 0,
        OpImpl::Burn => 1,
        OpImpl::Composite => 2,
    };
    OP_IMPL.store(v, Ordering::Relaxed);
}

/// The process-wide implementation choice (see [`set_op_impl`]).
pub(crate) fn op_impl() -> OpImpl {
    match OP_IMPL.load(Ordering::Relaxed) {
        1 => OpImpl::Burn,
        2 => OpImpl::Composite,
        _ => OpImpl::Auto,
    }
}

/// Whether `device` is the ndarray backend (possibly wrapped in autodiff), whose convolution
/// and pooling kernels are the naive loops this module works around.
pub(crate) fn is_ndarray(device: &Device) -> bool {
    #[allow(deprecated)] // ndarray is deprecated upstream but the project's default backend.
    let ndarray = Device::ndarray();
    device.clone().without_autodiff() == ndarray
}

/// The kinds of convolution [`OpImpl::Auto`] distinguishes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ConvKind {
    /// 1×1, stride 1, no padding: a matrix product (elementwise when depthwise).
    Pointwise,
    /// `groups == C_in == C_out`, larger kernel.
    Depthwise,
    /// Anything else.
    Dense,
}

impl ConvKind {
    /// The kind of `layer`.
    pub fn of(layer: &Conv2d) -> Self {
        let [oc, c_per_group, kh, kw] = layer.weight.dims();
        let pointwise = [kh, kw] == [1, 1]
            && layer.stride == [1, 1]
            && matches!(
                layer.padding,
                PaddingConfig2d::Valid | PaddingConfig2d::Explicit(0, 0, 0, 0)
            );
        if pointwise {
            Self::Pointwise
        } else if c_per_group == 1 && layer.groups == oc {
            Self::Depthwise
        } else {
            Self::Dense
        }
    }
}

/// Whether [`conv2d`] takes the composite path for a convolution of `kind` on `device` under
/// the current [`OpImpl`].
pub(crate) fn conv_uses_composite(device: &Device, kind: ConvKind) -> bool {
    match op_impl() {
        OpImpl::Auto if is_ndarray(device) => device.is_autodiff() || kind != ConvKind::Depthwise,
        OpImpl::Auto => kind == ConvKind::Pointwise,
        OpImpl::Burn => false,
        OpImpl::Composite => true,
    }
}

/// How [`crate::nn::max_pool2d`] computes a stride-1 max pool.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PoolPath {
    /// The backend's own kernel.
    Burn,
    /// [`crate::nn::pool::max_pool2d_shifted`]: running maxima over shifted slices.
    Shifted,
    /// [`crate::nn::pool_kernel::max_pool2d_same`]: row then column maxima, one byte per
    /// output for a backward pass of its own (odd square windows with `k/2` padding).
    Kernel,
}

/// Which [`PoolPath`] [`crate::nn::max_pool2d`] takes on `device` under the current
/// [`OpImpl`]: on the CPU backends with autodiff (training) this crate's kernel, without
/// autodiff the shifted slices, on the GPU Burn's kernel.
pub(crate) fn pool_path(device: &Device) -> PoolPath {
    match op_impl() {
        OpImpl::Auto if is_cpu(device) && device.is_autodiff() => PoolPath::Kernel,
        OpImpl::Auto if is_cpu(device) => PoolPath::Shifted,
        OpImpl::Auto | OpImpl::Burn => PoolPath::Burn,
        OpImpl::Composite => PoolPath::Shifted,
    }
}

/// `layer.forward(x)`, computed by [`conv2d_matmul`] where that is faster than the backend's
/// kernel (see [`OpImpl`]), by Burn otherwise. Same parameters, same result, same gradients.
pub fn conv2d(layer: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let device = x.device();
    let y = conv2d_any(layer, x);
    let [n, c, h, w] = y.dims();
    if c == 1 && !is_cpu(&device) {
        // Burn 0.22.1's GPU convolution returns a channels-last view; with one channel that
        // view's size-1 channel dimension has stride 1, and a fused element-wise chain that
        // reads it beside an already computed tensor then indexes the other wrong (SDFCNN's
        // depth loss came out 1.12 for 3.50: `tests/gpu_ops.rs`). Flattening and restoring
        // the shape gives it ordinary strides.
        return y.reshape([n, h * w]).reshape([n, 1, h, w]);
    }
    y
}

/// [`conv2d`] before the GPU layout fix.
fn conv2d_any(layer: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let device = x.device();
    let kind = ConvKind::of(layer);
    let kernel = match kind {
        ConvKind::Depthwise | ConvKind::Dense => conv_uses_kernel(&device),
        ConvKind::Pointwise => false,
    };
    let composite = conv_uses_composite(&device, kind);
    if !kernel && !composite {
        return layer.forward(x);
    }
    let [_, c, h, w] = x.dims();
    let padding = padding_pairs(&layer.padding, [h, w], layer.kernel_size, layer.stride);
    let options =
        ConvOptions::new_with_padding(layer.stride, padding, layer.dilation, layer.groups);
    let (weight, bias) = (layer.weight.val(), layer.bias.as_ref().map(|b| b.val()));
    if kernel && depthwise_kernel::supports(c, [h, w], weight.dims(), &options) {
        return depthwise_kernel::depthwise_conv2d(x, weight, bias, options);
    }
    // Fewer output than input channels (SDFCNN's depth head, 256 -> 1): unfolding the input
    // costs more than the product saves; `dense_output_taps` (ndarray) or Burn's kernel.
    let [oc, ..] = weight.dims();
    if kernel && oc >= c && dense_conv_kernel::supports(c, [h, w], weight.dims(), &options) {
        return dense_conv_kernel::dense_conv2d(x, weight, bias, options);
    }
    if !composite {
        return layer.forward(x);
    }
    conv2d_matmul(x, weight, bias, options)
}

/// Whether [`conv2d`] runs depthwise and dense convolutions (dilation 1) through
/// [`crate::nn::depthwise_kernel`] and [`crate::nn::dense_conv_kernel`]: on the CPU backends
/// with autodiff (training) under [`OpImpl::Auto`].
pub(crate) fn conv_uses_kernel(device: &Device) -> bool {
    op_impl() == OpImpl::Auto && is_cpu(device) && device.is_autodiff()
}

/// `((top, bottom), (left, right))` padding of `config` for an `[h, w]` input, as
/// `Conv2d::forward` computes it.
pub(crate) fn padding_pairs(
    config: &PaddingConfig2d,
    [h, w]: [usize; 2],
    kernel: [usize; 2],
    stride: [usize; 2],
) -> [(usize, usize); 2] {
    match *config {
        PaddingConfig2d::Valid => [(0, 0), (0, 0)],
        PaddingConfig2d::Explicit(top, left, bottom, right) => [(top, bottom), (left, right)],
        PaddingConfig2d::Same => [
            same_padding(kernel[0], stride[0], h),
            same_padding(kernel[1], stride[1], w),
        ],
    }
}

/// Burn's `Same` padding of one axis: `(before, after)`.
fn same_padding(kernel: usize, stride: usize, size: usize) -> (usize, usize) {
    let out = size.div_ceil(stride);
    let total = if out > 0 {
        ((out - 1) * stride + kernel).saturating_sub(size)
    } else {
        0
    };
    (total / 2, total - total / 2)
}

/// Output size of one axis.
pub(super) fn out_size(
    size: usize,
    (before, after): (usize, usize),
    kernel: usize,
    stride: usize,
    dilation: usize,
) -> usize {
    let span = dilation * (kernel - 1) + 1;
    let padded = size + before + after;
    assert!(
        padded >= span,
        "convolution kernel span {span} exceeds padded input size {padded}"
    );
    (padded - span) / stride + 1
}

/// 2-D convolution of `x` (`[N, C, H, W]`) with `weight` (`[OC, C / groups, KH, KW]`) and an
/// optional `bias` (`[OC]`), equal to `burn::tensor::module::conv2d` with the same options but
/// built from slices, matrix products and elementwise ops (see the module documentation).
///
/// # Panics
/// If the shapes do not match the options (as Burn's `conv2d` does).
pub fn conv2d_matmul(
    x: Tensor<4>,
    weight: Tensor<4>,
    bias: Option<Tensor<1>>,
    options: ConvOptions<2>,
) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    let [oc, c_per_group, kh, kw] = weight.dims();
    let groups = options.groups;
    assert!(
        c == c_per_group * groups && oc.is_multiple_of(groups),
        "conv2d: input channels {c}, weight {:?}, groups {groups}",
        weight.dims()
    );
    let [sh, sw] = options.stride;
    let [dh, dw] = options.dilation;
    let [pad_h, pad_w] = options.padding;
    let oh = out_size(h, pad_h, kh, sh, dh);
    let ow = out_size(w, pad_w, kw, sw, dw);

    let pointwise = kh == 1 && kw == 1 && sh == 1 && sw == 1 && options.padding == [(0, 0); 2];
    let out = if pointwise {
        conv1x1(x, weight, groups)
    } else {
        let x = if options.padding == [(0, 0); 2] {
            x
        } else {
            x.pad([pad_h, pad_w], PadMode::Constant(0.0))
        };
        if groups == c && oc == c {
            depthwise(x, weight, [oh, ow], options.stride, options.dilation)
        } else if groups == 1 {
            dense(x, weight, [oh, ow], options.stride, options.dilation)
        } else {
            let oc_per_group = oc / groups;
            let outs = (0..groups)
                .map(|g| {
                    let xg = x
                        .clone()
                        .slice(s![.., g * c_per_group..(g + 1) * c_per_group]);
                    let wg = weight
                        .clone()
                        .slice(s![g * oc_per_group..(g + 1) * oc_per_group]);
                    dense(xg, wg, [oh, ow], options.stride, options.dilation)
                })
                .collect();
            Tensor::cat(outs, 1)
        }
    };
    debug_assert_eq!(out.dims(), [n, oc, oh, ow]);
    add_bias(out, bias)
}

/// `out` (`[N, OC, OH, OW]`) plus the per-channel `bias` (`[OC]`), if any.
pub(super) fn add_bias(out: Tensor<4>, bias: Option<Tensor<1>>) -> Tensor<4> {
    match bias {
        Some(b) => {
            let [oc] = b.dims();
            out + b.reshape([1, oc, 1, 1])
        }
        None => out,
    }
}

/// Unpadded stride-1 1×1 convolution: a matrix product per group (elementwise when depthwise).
fn conv1x1(x: Tensor<4>, weight: Tensor<4>, groups: usize) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    let [oc, cg, _, _] = weight.dims();
    if groups == c && oc == c {
        return x * weight.reshape([1, c, 1, 1]);
    }
    let ocg = oc / groups;
    let x = x.reshape([n, groups, cg, h * w]);
    let weight = weight.reshape([1, groups, ocg, cg]);
    weight.matmul(x).reshape([n, oc, h, w])
}

/// The `[N, C, OH, OW]` values of the padded input `x` seen by kernel tap `(i, j)`.
fn tap(
    x: &Tensor<4>,
    [i, j]: [usize; 2],
    [oh, ow]: [usize; 2],
    [sh, sw]: [usize; 2],
    [dh, dw]: [usize; 2],
) -> Tensor<4> {
    let (h0, w0) = (i * dh, j * dw);
    let (h1, w1) = (h0 + (oh - 1) * sh + 1, w0 + (ow - 1) * sw + 1);
    x.clone().slice(s![.., .., h0..h1;sh, w0..w1;sw])
}

/// Depthwise convolution of the padded `x`: `Σ_taps tap · w[c, i, j]`.
fn depthwise(
    x: Tensor<4>,
    weight: Tensor<4>,
    out: [usize; 2],
    stride: [usize; 2],
    dilation: [usize; 2],
) -> Tensor<4> {
    let [c, _, kh, kw] = weight.dims();
    let weight = weight.reshape([c, kh * kw]);
    let mut acc: Option<Tensor<4>> = None;
    for i in 0..kh {
        for j in 0..kw {
            let k = i * kw + j;
            let wk = weight.clone().slice(s![.., k..k + 1]).reshape([1, c, 1, 1]);
            let term = tap(&x, [i, j], out, stride, dilation) * wk;
            acc = Some(match acc {
                Some(a) => a + term,
                None => term,
            });
        }
    }
    acc.expect("kernel has at least one tap")
}

/// Dense (`groups == 1`) convolution of the padded `x` by im2col and one matrix product.
///
/// A stride-`s` kernel whose size is a multiple of `s` is first rewritten as a stride-1 kernel
/// on the space-to-depth input (fewer, contiguous slices).
fn dense(
    x: Tensor<4>,
    weight: Tensor<4>,
    [oh, ow]: [usize; 2],
    stride: [usize; 2],
    dilation: [usize; 2],
) -> Tensor<4> {
    let [oc, _, kh, kw] = weight.dims();
    let [sh, sw] = stride;
    if (sh > 1 || sw > 1) && dilation == [1, 1] && kh % sh == 0 && kw % sw == 0 {
        let (x, weight) = space_to_depth(x, weight, [oh, ow], stride);
        return dense(x, weight, [oh, ow], [1, 1], [1, 1]);
    }
    let [n, c, _, _] = x.dims();
    if stride == [1, 1] && oc < c {
        return dense_output_taps(x, weight, [oh, ow], dilation);
    }
    let taps: Vec<Tensor<4>> = (0..kh)
        .flat_map(|i| (0..kw).map(move |j| [i, j]))
        .map(|ij| tap(&x, ij, [oh, ow], stride, dilation))
        .collect();
    let cols = if taps.len() == 1 {
        taps.into_iter().next().expect("one tap")
    } else {
        Tensor::cat(taps, 1)
    };
    let cols = cols.reshape([n, kh * kw * c, oh * ow]);
    // Column order (i, j, c) to match the taps' concatenation.
    let weight = weight.permute([0, 2, 3, 1]).reshape([1, oc, kh * kw * c]);
    weight.matmul(cols).reshape([n, oc, oh, ow])
}

/// Dense stride-1 convolution of the padded `x` with fewer output than input channels
/// (SDFCNN's depth head, 3×3 256→1): one matrix product gives every tap's contribution at every
/// padded pixel, `[N, KH·KW·OC, H, W]`, and the output sums those maps shifted by their tap.
/// im2col would build `[N, KH·KW·C, OH·OW]` (177 MB for the depth head at batch 4, 240×320).
fn dense_output_taps(
    x: Tensor<4>,
    weight: Tensor<4>,
    [oh, ow]: [usize; 2],
    dilation: [usize; 2],
) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    let [oc, _, kh, kw] = weight.dims();
    // Rows in (i, j, o) order.
    let weight = weight.permute([2, 3, 0, 1]).reshape([1, kh * kw * oc, c]);
    let z = weight
        .matmul(x.reshape([n, c, h * w]))
        .reshape([n, kh * kw * oc, h, w]);
    let mut acc: Option<Tensor<4>> = None;
    for i in 0..kh {
        for j in 0..kw {
            let t = i * kw + j;
            let zt = z.clone().slice(s![.., t * oc..(t + 1) * oc]);
            let term = tap(&zt, [i, j], [oh, ow], [1, 1], dilation);
            acc = Some(match acc {
                Some(a) => a + term,
                None => term,
            });
        }
    }
    acc.expect("kernel has at least one tap")
}

/// Rewrites a stride-`s` convolution as a stride-1 one: the padded input `[N, C, H, W]`
/// becomes `[N, C·sh·sw, H/sh, W/sw]` (cropped to the whole blocks the output reads), the weight `[OC, C, KH, KW]` becomes `[OC, C·sh·sw, KH/sh, KW/sw]` with
/// matching channel order.
fn space_to_depth(
    x: Tensor<4>,
    weight: Tensor<4>,
    [oh, ow]: [usize; 2],
    [sh, sw]: [usize; 2],
) -> (Tensor<4>, Tensor<4>) {
    let [n, c, h, w] = x.dims();
    let [oc, _, kh, kw] = weight.dims();
    let (bh, bw) = (kh / sh, kw / sw);
    // Blocks read by the output: oh + bh − 1 rows of blocks.
    let (hb, wb) = (oh + bh - 1, ow + bw - 1);
    let (need_h, need_w) = (hb * sh, wb * sw);
    // (oh − 1)·sh + kh ≤ h by the output size, and that is need_h.
    debug_assert!(need_h <= h && need_w <= w);
    let x = x.slice(s![.., .., 0..need_h, 0..need_w]);
    let x = x
        .reshape([n, c, hb, sh, wb, sw])
        .permute([0, 1, 3, 5, 2, 4])
        .reshape([n, c * sh * sw, hb, wb]);
    let weight = weight
        .reshape([oc, c, bh, sh, bw, sw])
        .permute([0, 1, 3, 5, 2, 4])
        .reshape([oc, c * sh * sw, bh, bw]);
    (x, weight)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;
    use burn::tensor::module::conv2d as burn_conv2d;

    #[allow(deprecated)]
    fn ndarray() -> Device {
        Device::ndarray()
    }

    fn random<const D: usize>(shape: [usize; D], device: &Device) -> Tensor<D> {
        Tensor::random(shape, Distribution::Uniform(-1.0, 1.0), device)
    }

    fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().expect("f32 tensor")
    }

    /// Within 1e-4 of the largest expected value, or of `floor` when that is larger.
    fn assert_close(what: &str, got: &[f32], want: &[f32], floor: f32) {
        assert_eq!(got.len(), want.len(), "{what}: length");
        let scale = want.iter().fold(floor, |m, v| m.max(v.abs())).max(1e-6);
        for (i, (g, e)) in got.iter().zip(want).enumerate() {
            assert!(
                (g - e).abs() <= 1e-4 * scale,
                "{what}[{i}]: {g} vs {e} (scale {scale})"
            );
        }
    }

    /// A convolution case: input shape, weight shape, stride, padding, groups.
    struct Case {
        x: [usize; 4],
        w: [usize; 4],
        stride: usize,
        padding: [(usize, usize); 2],
        dilation: usize,
        groups: usize,
        bias: bool,
    }

    const fn case(
        x: [usize; 4],
        w: [usize; 4],
        stride: usize,
        p: usize,
        groups: usize,
        bias: bool,
    ) -> Case {
        Case {
            x,
            w,
            stride,
            padding: [(p, p), (p, p)],
            dilation: 1,
            groups,
            bias,
        }
    }

    const CASES: [Case; 14] = [
        case([2, 3, 9, 11], [5, 3, 4, 4], 2, 1, 1, true), // FPFDCNN 4×4 s2 p1, odd sizes
        case([2, 3, 8, 12], [4, 3, 4, 4], 2, 1, 1, true), // 4×4 s2 p1, even sizes
        case([2, 4, 7, 9], [6, 4, 3, 3], 1, 1, 1, true),  // 3×3 s1 p1
        case([2, 3, 7, 9], [2, 3, 3, 3], 2, 1, 1, false), // SDFCNN Layer1: 3×3 s2 p1
        case([2, 5, 6, 7], [3, 5, 1, 1], 1, 0, 1, true),  // 1×1
        case([2, 6, 7, 9], [6, 1, 3, 3], 1, 1, 6, false), // depthwise 3×3 s1
        case([2, 6, 7, 9], [6, 1, 3, 3], 2, 1, 6, false), // depthwise 3×3 s2
        case([2, 4, 5, 6], [4, 1, 1, 1], 1, 0, 4, false), // depthwise 1×1
        case([2, 4, 7, 8], [6, 2, 3, 3], 1, 1, 2, true),  // grouped 3×3
        case([2, 4, 7, 8], [6, 4, 1, 1], 2, 1, 1, true),  // 1×1 s2 p1 (general path)
        case([2, 6, 7, 9], [1, 6, 3, 3], 1, 1, 1, true),  // SDFCNN depth1: fewer outputs
        Case {
            x: [2, 5, 8, 9],
            w: [2, 5, 3, 3],
            stride: 1,
            padding: [(1, 2), (2, 1)],
            dilation: 2,
            groups: 1,
            bias: false,
        },
        // Asymmetric padding (what `Same` gives an even kernel), dilation 2.
        Case {
            x: [2, 3, 8, 9],
            w: [4, 3, 3, 3],
            stride: 1,
            padding: [(1, 2), (2, 1)],
            dilation: 2,
            groups: 1,
            bias: true,
        },
        Case {
            x: [2, 3, 9, 8],
            w: [5, 3, 4, 4],
            stride: 2,
            padding: [(1, 2), (2, 1)],
            dilation: 1,
            groups: 1,
            bias: true,
        },
    ];

    /// Output and gradients w.r.t. input, weight and bias of `conv` on `device` (autodiff).
    fn run(
        c: &Case,
        device: &Device,
        data: &(Tensor<4>, Tensor<4>, Tensor<1>, Tensor<4>),
        conv: fn(Tensor<4>, Tensor<4>, Option<Tensor<1>>, ConvOptions<2>) -> Tensor<4>,
    ) -> [Vec<f32>; 4] {
        let device = device.clone().autodiff();
        let to = |t: &Tensor<4>| Tensor::<4>::from_data(t.to_data(), &device).require_grad();
        let (x, w) = (to(&data.0), to(&data.1));
        let b = Tensor::<1>::from_data(data.2.to_data(), &device).require_grad();
        let upstream = Tensor::<4>::from_data(data.3.to_data(), &device);
        let options =
            ConvOptions::new_with_padding([c.stride; 2], c.padding, [c.dilation; 2], c.groups);
        let y = conv(x.clone(), w.clone(), c.bias.then(|| b.clone()), options);
        let grads = (y.clone() * upstream).sum().backward();
        let gb = if c.bias {
            values(b.grad(&grads).expect("bias grad"))
        } else {
            Vec::new()
        };
        [
            values(y),
            values(x.grad(&grads).expect("input grad")),
            values(w.grad(&grads).expect("weight grad")),
            gb,
        ]
    }

    fn check_backend(device: &Device) {
        check_cases(device, &CASES, conv2d_matmul);
    }

    /// `conv` against Burn's `conv2d` on `device`: output and gradients of every case.
    fn check_cases(
        device: &Device,
        cases: &[Case],
        conv: fn(Tensor<4>, Tensor<4>, Option<Tensor<1>>, ConvOptions<2>) -> Tensor<4>,
    ) {
        for (k, c) in cases.iter().enumerate() {
            let reference = Device::flex();
            let [n, _, h, w] = c.x;
            let [(t, b), (l, r)] = c.padding;
            let span = |k: usize| c.dilation * (k - 1) + 1;
            let oh = (h + t + b - span(c.w[2])) / c.stride + 1;
            let ow = (w + l + r - span(c.w[3])) / c.stride + 1;
            let data = (
                random(c.x, &reference),
                random(c.w, &reference),
                random([c.w[0]], &reference),
                random([n, c.w[0], oh, ow], &reference),
            );
            let want = run(c, &reference, &data, burn_conv2d);
            let got = run(c, device, &data, conv);
            // The bias gradient is a sum over the batch and the output pixels: its rounding
            // error scales with the sum of its terms' magnitudes, which a sum that cancels
            // (one output channel, random upstream gradients) can leave far below.
            let dy = values(data.3.clone());
            let per_channel = oh * ow;
            let terms = (0..c.w[0])
                .map(|o| {
                    (0..n)
                        .flat_map(|b| {
                            let at = (b * c.w[0] + o) * per_channel;
                            dy[at..at + per_channel].iter().map(|v| v.abs())
                        })
                        .sum::<f32>()
                })
                .fold(0.0f32, f32::max);
            for (what, (g, e), floor) in [
                ("output", (&got[0], &want[0]), 0.0),
                ("d input", (&got[1], &want[1]), 0.0),
                ("d weight", (&got[2], &want[2]), 0.0),
                ("d bias", (&got[3], &want[3]), terms),
            ] {
                assert_close(&format!("case {k} {what}"), g, e, floor);
            }
        }
    }

    #[test]
    fn matches_burn_conv_on_ndarray() {
        check_backend(&ndarray());
    }

    #[test]
    fn matches_burn_conv_on_flex() {
        check_backend(&Device::flex());
    }

    #[test]
    fn depthwise_kernel_matches_burn_conv_on_both_backends() {
        let cases = [
            case([2, 6, 7, 9], [6, 1, 3, 3], 1, 1, 6, false), // MobileNetV2 3×3 s1
            case([2, 6, 7, 9], [6, 1, 3, 3], 2, 1, 6, true),  // 3×3 s2, odd sizes
            case([2, 5, 8, 10], [5, 1, 3, 3], 2, 1, 5, false), // 3×3 s2, even sizes
            case([1, 3, 2, 2], [3, 1, 3, 3], 1, 1, 3, false), // smaller than the kernel's reach
            case([2, 4, 6, 5], [4, 1, 5, 5], 1, 2, 4, false), // 5×5
            case([2, 4, 6, 7], [4, 1, 3, 3], 1, 0, 4, true),  // no padding
            Case {
                x: [1, 4, 6, 7],
                w: [4, 1, 4, 4],
                stride: 2,
                padding: [(1, 2), (2, 1)],
                dilation: 1,
                groups: 4,
                bias: true,
            },
        ];
        for device in [ndarray(), Device::flex()] {
            check_cases(&device, &cases, depthwise_kernel::depthwise_conv2d);
            // Without autodiff too.
            let c = &cases[1];
            let x = random(c.x, &device);
            let w = random(c.w, &device);
            let options = ConvOptions::new_with_padding([2, 2], c.padding, [1, 1], c.groups);
            let want = values(burn_conv2d(x.clone(), w.clone(), None, options.clone()));
            let got = values(depthwise_kernel::depthwise_conv2d(x, w, None, options));
            assert_close("plain", &got, &want, 0.0);
        }
    }

    #[test]
    fn layer_wrapper_matches_forward_with_same_padding() {
        let d = ndarray();
        for (kernel, stride) in [(3, 1), (4, 2), (3, 2)] {
            let layer = burn::nn::conv::Conv2dConfig::new([3, 4], [kernel, kernel])
                .with_stride([stride, stride])
                .with_padding(PaddingConfig2d::Same)
                .init(&d);
            let x = random([2, 3, 7, 10], &d);
            let want = values(layer.forward(x.clone()));
            set_op_impl(OpImpl::Auto);
            assert!(conv_uses_composite(&d, ConvKind::of(&layer)));
            assert_close("same padding", &values(conv2d(&layer, x)), &want, 0.0);
        }
    }

    #[test]
    fn auto_policy_per_kind_and_device() {
        let d = ndarray();
        let layer = |c: [usize; 2], k: usize, groups: usize| {
            burn::nn::conv::Conv2dConfig::new(c, [k, k])
                .with_groups(groups)
                .with_padding(PaddingConfig2d::Explicit(k / 2, k / 2, k / 2, k / 2))
                .init(&d)
        };
        let (pw, dw, dense) = (
            layer([8, 4], 1, 1),
            layer([8, 8], 3, 8),
            layer([4, 8], 3, 1),
        );
        assert_eq!(ConvKind::of(&pw), ConvKind::Pointwise);
        assert_eq!(ConvKind::of(&layer([8, 8], 1, 8)), ConvKind::Pointwise);
        assert_eq!(ConvKind::of(&dw), ConvKind::Depthwise);
        assert_eq!(ConvKind::of(&dense), ConvKind::Dense);
        set_op_impl(OpImpl::Auto);
        let kinds = [ConvKind::Pointwise, ConvKind::Depthwise, ConvKind::Dense];
        let on = |device: &Device| kinds.map(|k| conv_uses_composite(device, k));
        assert_eq!(on(&d.clone().autodiff()), [true, true, true]);
        assert_eq!(on(&d), [true, false, true]);
        assert_eq!(on(&Device::flex()), [true, false, false]);
        assert_eq!(on(&Device::flex().autodiff()), [true, false, false]);
        assert_eq!(pool_path(&d), PoolPath::Shifted);
        assert_eq!(pool_path(&d.clone().autodiff()), PoolPath::Kernel);
        assert_eq!(pool_path(&Device::flex()), PoolPath::Shifted);
        assert_eq!(pool_path(&Device::flex().autodiff()), PoolPath::Kernel);
        let kernel = [d.clone(), Device::flex()].map(|d| conv_uses_kernel(&d));
        assert_eq!(kernel, [false, false]);
        let kernel = [d.autodiff(), Device::flex().autodiff()].map(|d| conv_uses_kernel(&d));
        assert_eq!(kernel, [true, true]);
    }
}
