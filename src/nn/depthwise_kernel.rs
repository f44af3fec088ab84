//! Depthwise convolution (one `kh×kw` filter per channel, MobileNetV2's 3×3 layers in
//! SDFCNN's encoder, Table 13) with its own backward pass, as a Burn backend extension on the
//! CPU backends, for training.
//!
//! With autodiff, burn-flex 0.22.1 convolves a grouped convolution group by group and
//! burn-ndarray's weight gradient runs one convolution per group; [`super::conv2d_matmul`]'s
//! nine shifted slices allocate a zero tensor of the whole padded input per slice in their
//! backward. Here each `(n, c)` plane is convolved directly: for every output row and kernel
//! tap a multiply-add along the row (contiguous at stride 1, so it vectorises), compiled for
//! AVX-512 or AVX2 when the CPU has them. The backward pass makes the input gradient (the
//! same loops scattering into the input row) and the weight gradient (a dot product of
//! output-gradient and input rows per tap, summed in `f64` over a plane) in one pass over the
//! planes. Padding is zeros; dilation is 1; the arithmetic is `f32` whatever the float type.

// burn-ndarray is deprecated upstream but is this crate's default backend.
#![allow(deprecated)]

use super::conv::{add_bias, out_size};
use super::nhwc::{dot_lanes, simd_fn};
use super::pool_kernel::{read, tensor};
use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, Flex, NdArray, TensorMetadata, backend_extension};
use burn::prelude::*;
use burn::tensor::ops::ConvOptions;
use rayon::prelude::*;

/// Stride and zero padding `((top, bottom), (left, right))` of a depthwise convolution.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct DepthwiseOptions {
    /// Stride `[vertical, horizontal]`, pixels.
    pub stride: [usize; 2],
    /// Zero padding `((top, bottom), (left, right))`, pixels.
    pub padding: [(usize, usize); 2],
}

impl From<&ConvOptions<2>> for DepthwiseOptions {
    /// The stride and padding of `options` (the callers check groups and dilation).
    fn from(options: &ConvOptions<2>) -> Self {
        Self {
            stride: options.stride,
            padding: options.padding,
        }
    }
}

/// The extension: `x` (`[N, C, H, W]`) convolved channel by channel with `weight`
/// (`[C, 1, KH, KW]`), no bias.
#[backend_extension(Flex, NdArray, Autodiff)]
pub(crate) trait DepthwiseOps: Backend {
    /// `x` (`[N, C, H, W]`) convolved channel by channel with `weight` (`[C, 1, KH, KW]`).
    fn depthwise_conv(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: DepthwiseOptions,
    ) -> FloatTensor<Self>;
}

impl DepthwiseOps for Flex {
    fn depthwise_conv(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: DepthwiseOptions,
    ) -> FloatTensor<Self> {
        forward::<Flex>(x, weight, options)
    }
}

impl DepthwiseOps for NdArray {
    fn depthwise_conv(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: DepthwiseOptions,
    ) -> FloatTensor<Self> {
        forward::<NdArray>(x, weight, options)
    }
}

impl<B: Backend, C: CheckpointStrategy> DepthwiseOps for Autodiff<B, C> {
    fn depthwise_conv(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: DepthwiseOptions,
    ) -> FloatTensor<Self> {
        autodiff_conv::<B, C, Depthwise>(x, weight, options)
    }
}

/// A convolution of an input by a weight that this crate computes on the CPU backends, with
/// its own backward pass: [`Depthwise`] and [`super::dense_conv_kernel`]'s.
pub(super) trait ConvKernel: std::fmt::Debug + Send + 'static {
    /// The output, no bias.
    fn forward<B: Backend>(
        x: FloatTensor<B>,
        weight: FloatTensor<B>,
        options: DepthwiseOptions,
    ) -> FloatTensor<B>;

    /// The input and the weight gradient from the output's, each when `want` asks for it.
    fn backward<B: Backend>(
        x: FloatTensor<B>,
        weight: FloatTensor<B>,
        grad: FloatTensor<B>,
        options: DepthwiseOptions,
        want: [bool; 2],
    ) -> (Option<FloatTensor<B>>, Option<FloatTensor<B>>);
}

/// `K`'s node in the autodiff graph.
#[derive(Debug)]
struct Tracked<K>(std::marker::PhantomData<K>);

impl<B: Backend, K: ConvKernel> Backward<B, 2> for Tracked<K> {
    /// The input, the weight and the options.
    type State = (FloatTensor<B>, FloatTensor<B>, DepthwiseOptions);

    fn backward(
        self,
        ops: Ops<Self::State, 2>,
        grads: &mut Gradients,
        _checkpointer: &mut Checkpointer,
    ) {
        let (x, weight, options) = ops.state;
        let grad = grads.consume::<B>(&ops.node);
        let [x_node, w_node] = ops.parents;
        let want = [x_node.is_some(), w_node.is_some()];
        let (gx, gw) = K::backward::<B>(x, weight, grad, options, want);
        if let (Some(node), Some(gx)) = (x_node, gx) {
            grads.register::<B>(node.id, gx);
        }
        if let (Some(node), Some(gw)) = (w_node, gw) {
            grads.register::<B>(node.id, gw);
        }
    }
}

/// `K`'s convolution on the autodiff backend: its forward pass on the inner backend, its
/// backward pass recorded when `x` or `weight` is tracked.
pub(super) fn autodiff_conv<B: Backend, C: CheckpointStrategy, K: ConvKernel>(
    x: FloatTensor<Autodiff<B, C>>,
    weight: FloatTensor<Autodiff<B, C>>,
    options: DepthwiseOptions,
) -> FloatTensor<Autodiff<B, C>> {
    let (x_guard, w_guard) = (x.node(), weight.node());
    let (x, weight) = (x.into_primitive(), weight.into_primitive());
    match Tracked::<K>(std::marker::PhantomData)
        .prepare::<C>([x_guard, w_guard])
        .compute_bound()
        .stateful()
    {
        OpsKind::Tracked(prep) => {
            let out = K::forward::<B>(x.clone(), weight.clone(), options);
            prep.finish((x, weight, options), out)
        }
        OpsKind::UnTracked(prep) => prep.finish(K::forward::<B>(x, weight, options)),
    }
}

/// The depthwise convolution's [`ConvKernel`].
#[derive(Debug)]
pub(super) struct Depthwise;

impl ConvKernel for Depthwise {
    fn forward<B: Backend>(
        x: FloatTensor<B>,
        weight: FloatTensor<B>,
        options: DepthwiseOptions,
    ) -> FloatTensor<B> {
        forward::<B>(x, weight, options)
    }

    fn backward<B: Backend>(
        x: FloatTensor<B>,
        weight: FloatTensor<B>,
        grad: FloatTensor<B>,
        options: DepthwiseOptions,
        [want_x, want_w]: [bool; 2],
    ) -> (Option<FloatTensor<B>>, Option<FloatTensor<B>>) {
        let (gx, gw) = backward::<B>(x, weight, grad, options, want_x);
        (gx, want_w.then_some(gw))
    }
}

/// Whether [`depthwise_conv2d`] computes a convolution of `weight` (`[OC, C/groups, KH, KW]`)
/// on `c` input channels with `options`: depthwise (`groups == C == OC`), and
/// `kernel_fits`.
pub(crate) fn supports(
    c: usize,
    [h, w]: [usize; 2],
    weight: [usize; 4],
    options: &ConvOptions<2>,
) -> bool {
    let [oc, c_per_group, kh, kw] = weight;
    options.groups == c && oc == c && c_per_group == 1 && kernel_fits([h, w], [kh, kw], options)
}

/// What the kernels here need beyond the channels: dilation 1, non-zero strides, and a
/// non-empty `[kh, kw]` kernel that fits the non-empty `[h, w]` input once padded.
pub(super) fn kernel_fits(
    [h, w]: [usize; 2],
    [kh, kw]: [usize; 2],
    options: &ConvOptions<2>,
) -> bool {
    let [(t, b), (l, r)] = options.padding;
    options.dilation == [1, 1]
        && options.stride.iter().all(|&s| s > 0)
        && h > 0
        && w > 0
        && kh > 0
        && kw > 0
        && h + t + b >= kh
        && w + l + r >= kw
}

/// Depthwise convolution of `x` (`[N, C, H, W]`) with `weight` (`[C, 1, KH, KW]`) and an
/// optional `bias` (`[C]`), equal to `burn::tensor::module::conv2d` with the same options, on
/// the CPU backends, with autodiff where `x` or `weight` has it.
///
/// # Panics
/// If [`supports`] does not hold (as Burn's `conv2d` panics on mismatched shapes).
pub(crate) fn depthwise_conv2d(
    x: Tensor<4>,
    weight: Tensor<4>,
    bias: Option<Tensor<1>>,
    options: ConvOptions<2>,
) -> Tensor<4> {
    let [_, c, h, w] = x.dims();
    assert!(
        supports(c, [h, w], weight.dims(), &options),
        "depthwise_conv2d: input {:?}, weight {:?}, {options:?}",
        x.dims(),
        weight.dims()
    );
    let options = DepthwiseOptions::from(&options);
    let out = Tensor::from_dispatch(Dispatch::depthwise_conv(
        x.into_dispatch(),
        weight.into_dispatch(),
        options,
    ));
    add_bias(out, bias)
}

/// Sizes of one convolution (dilation 1), in elements (also [`super::dense_conv_kernel`]'s).
#[derive(Debug, Clone, Copy)]
pub(super) struct Geometry {
    pub(super) h: usize,
    pub(super) w: usize,
    pub(super) oh: usize,
    pub(super) ow: usize,
    pub(super) kh: usize,
    pub(super) kw: usize,
    pub(super) stride: [usize; 2],
    /// Top and left padding.
    pub(super) pad: [usize; 2],
}

impl Geometry {
    /// Of input `x` (`[N, C, H, W]`) and `weight` (`[OC, C/groups, KH, KW]`) under `o`.
    pub(super) fn new(x: &[usize], weight: &[usize], o: &DepthwiseOptions) -> Self {
        let (h, w, kh, kw) = (x[2], x[3], weight[2], weight[3]);
        let [pad_h, pad_w] = o.padding;
        let [sh, sw] = o.stride;
        Self {
            h,
            w,
            oh: out_size(h, pad_h, kh, sh, 1),
            ow: out_size(w, pad_w, kw, sw, 1),
            kh,
            kw,
            stride: o.stride,
            pad: [pad_h.0, pad_w.0],
        }
    }

    /// The input row kernel row `i` reads for output row `oy`, if inside the image.
    #[inline(always)]
    pub(super) fn input_row(&self, oy: usize, i: usize) -> Option<usize> {
        (oy * self.stride[0] + i)
            .checked_sub(self.pad[0])
            .filter(|&y| y < self.h)
    }

    /// The output columns `lo..hi` (`lo ≤ hi ≤ OW`) whose kernel column `j` lands inside
    /// the input row, and the input column of `lo` (`lo · stride + j − left`; 0 when there
    /// are none).
    #[inline(always)]
    pub(super) fn columns(&self, j: usize) -> (usize, usize, usize) {
        let (s, left) = (self.stride[1], self.pad[1]);
        let lo = left.saturating_sub(j).div_ceil(s).min(self.ow);
        // Last output column with lo·s + j − left ≤ w − 1.
        let hi = match (self.w + left).checked_sub(j + 1) {
            Some(last) => (last / s + 1).min(self.ow),
            None => 0,
        };
        let hi = hi.max(lo);
        let x0 = if hi > lo { lo * s + j - left } else { 0 };
        (lo, hi, x0)
    }
}

simd_fn! {
    /// One `(n, c)` plane: `out = Σ_taps w[i, j] · x[oy·s + i − top, ox·s + j − left]`.
    fn forward_plane(x: &[f32], wk: &[f32], g: &Geometry, out: &mut [f32]) {
        let s = g.stride[1];
        out.fill(0.0);
        for oy in 0..g.oh {
            let row = &mut out[oy * g.ow..(oy + 1) * g.ow];
            for i in 0..g.kh {
                let Some(y) = g.input_row(oy, i) else { continue };
                let xrow = &x[y * g.w..(y + 1) * g.w];
                for j in 0..g.kw {
                    let wv = wk[i * g.kw + j];
                    let (lo, hi, x0) = g.columns(j);
                    if s == 1 {
                        for (o, &v) in row[lo..hi].iter_mut().zip(&xrow[x0..x0 + hi - lo]) {
                            *o += wv * v;
                        }
                    } else {
                        for (k, o) in row[lo..hi].iter_mut().enumerate() {
                            *o += wv * xrow[x0 + k * s];
                        }
                    }
                }
            }
        }
    }
}

simd_fn! {
    /// One plane's gradients: the input's (`gx`, when given, scattered back through the taps)
    /// and the weight's (`gw[i·kw + j] = Σ g · x` over the taps' pairs).
    fn backward_plane(
        x: &[f32],
        wk: &[f32],
        grad: &[f32],
        g: &Geometry,
        gx: Option<&mut [f32]>,
        gw: &mut [f64],
    ) {
        let s = g.stride[1];
        gw.fill(0.0);
        let mut gx = gx;
        if let Some(gx) = gx.as_deref_mut() {
            gx.fill(0.0);
        }
        for oy in 0..g.oh {
            let grow = &grad[oy * g.ow..(oy + 1) * g.ow];
            for i in 0..g.kh {
                let Some(y) = g.input_row(oy, i) else { continue };
                let xrow = &x[y * g.w..(y + 1) * g.w];
                for j in 0..g.kw {
                    let t = i * g.kw + j;
                    let (lo, hi, x0) = g.columns(j);
                    let grow = &grow[lo..hi];
                    let mut dot = 0.0f32;
                    if s == 1 {
                        let xs = &xrow[x0..x0 + hi - lo];
                        dot = dot_lanes(grow, xs);
                        if let Some(gx) = gx.as_deref_mut() {
                            let wv = wk[t];
                            let gxrow = &mut gx[y * g.w + x0..y * g.w + x0 + hi - lo];
                            for (o, &d) in gxrow.iter_mut().zip(grow) {
                                *o += wv * d;
                            }
                        }
                    } else {
                        for (k, &d) in grow.iter().enumerate() {
                            dot += d * xrow[x0 + k * s];
                        }
                        if let Some(gx) = gx.as_deref_mut() {
                            let wv = wk[t];
                            let gxrow = &mut gx[y * g.w..(y + 1) * g.w];
                            for (k, &d) in grow.iter().enumerate() {
                                gxrow[x0 + k * s] += wv * d;
                            }
                        }
                    }
                    gw[t] += f64::from(dot);
                }
            }
        }
    }
}

/// The convolution (no bias).
fn forward<B: Backend>(
    x: FloatTensor<B>,
    weight: FloatTensor<B>,
    options: DepthwiseOptions,
) -> FloatTensor<B> {
    let device = x.device();
    let (x, shape, dtype) = read::<B>(x);
    let (wt, wshape, _) = read::<B>(weight);
    let (x, wt) = (x.as_slice(), wt.as_slice());
    let g = Geometry::new(&shape, &wshape, &options);
    let (n, c) = (shape[0], shape[1]);
    let (plane, oplane, taps) = (g.h * g.w, g.oh * g.ow, g.kh * g.kw);
    let mut out = vec![0.0f32; n * c * oplane];
    if oplane > 0 {
        out.par_chunks_mut(oplane).enumerate().for_each(|(p, out)| {
            let ch = p % c;
            forward_plane(
                &x[p * plane..(p + 1) * plane],
                &wt[ch * taps..(ch + 1) * taps],
                &g,
                out,
            );
        });
    }
    tensor::<B>(out, vec![n, c, g.oh, g.ow], dtype, &device)
}

/// The input gradient (when `want_x`) and the weight gradient.
fn backward<B: Backend>(
    x: FloatTensor<B>,
    weight: FloatTensor<B>,
    grad: FloatTensor<B>,
    options: DepthwiseOptions,
    want_x: bool,
) -> (Option<FloatTensor<B>>, FloatTensor<B>) {
    let device = x.device();
    let (x, shape, x_dtype) = read::<B>(x);
    let (wt, wshape, w_dtype) = read::<B>(weight);
    let (grad, _, _) = read::<B>(grad);
    let (x, wt, grad) = (x.as_slice(), wt.as_slice(), grad.as_slice());
    let g = Geometry::new(&shape, &wshape, &options);
    let (n, c) = (shape[0], shape[1]);
    let (plane, oplane, taps) = (g.h * g.w, g.oh * g.ow, g.kh * g.kw);
    let mut gx = if want_x {
        vec![0.0f32; x.len()]
    } else {
        Vec::new()
    };
    let mut partial = vec![0.0f64; n * c * taps];
    let run = |p: usize, gx: Option<&mut [f32]>, gw: &mut [f64]| {
        let ch = p % c;
        backward_plane(
            &x[p * plane..(p + 1) * plane],
            &wt[ch * taps..(ch + 1) * taps],
            &grad[p * oplane..(p + 1) * oplane],
            &g,
            gx,
            gw,
        );
    };
    if plane > 0 && oplane > 0 {
        if want_x {
            gx.par_chunks_mut(plane)
                .zip(partial.par_chunks_mut(taps))
                .enumerate()
                .for_each(|(p, (gx, gw))| run(p, Some(gx), gw));
        } else {
            partial
                .par_chunks_mut(taps)
                .enumerate()
                .for_each(|(p, gw)| run(p, None, gw));
        }
    }
    let mut gw = vec![0.0f32; c * taps];
    for (ch, out) in gw.chunks_mut(taps).enumerate() {
        for (t, out) in out.iter_mut().enumerate() {
            *out = (0..n)
                .map(|b| partial[(b * c + ch) * taps + t])
                .sum::<f64>() as f32;
        }
    }
    let gx = want_x.then(|| tensor::<B>(gx, shape, x_dtype, &device));
    (gx, tensor::<B>(gw, wshape, w_dtype, &device))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn columns_cover_exactly_the_taps_inside_the_row() {
        for (w, k, s, left, right) in [
            (9, 3, 1, 1, 1),
            (10, 3, 2, 1, 1),
            (5, 4, 2, 2, 1),
            (1, 3, 1, 1, 1),
            (7, 3, 2, 0, 0),
            (1, 5, 1, 2, 2),
            (2, 5, 2, 2, 2),
        ] {
            let o = DepthwiseOptions {
                stride: [1, s],
                padding: [(0, 0), (left, right)],
            };
            let g = Geometry::new(&[1, 1, 1, w], &[1, 1, 1, k], &o);
            for j in 0..k {
                let (lo, hi, x0) = g.columns(j);
                assert!(lo <= hi && hi <= g.ow && x0 <= w, "w {w} k {k} s {s} j {j}");
                let inside: Vec<usize> = (0..g.ow)
                    .filter(|ox| (ox * s + j).checked_sub(left).is_some_and(|x| x < w))
                    .collect();
                assert_eq!(
                    (lo..hi).collect::<Vec<_>>(),
                    inside,
                    "w {w} k {k} s {s} j {j}"
                );
                if hi > lo {
                    assert_eq!(x0, lo * s + j - left);
                }
            }
        }
    }
}
