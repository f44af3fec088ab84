//! Dense convolution (groups 1, dilation 1: FPFDCNN's L1-L7 and L9, Table 12) with its own
//! backward pass, as a Burn backend extension on the CPU backends, for training.
//!
//! burn-flex 0.22.1's autodiff computes a convolution's weight gradient as another
//! convolution (the input against the output gradient, dilated by the stride) and its input
//! gradient as a transposed convolution; `perf` of the FPFDCNN train step put a quarter of it
//! outside the matrix products, in their strided copies, fills and direct loops. Here all
//! three are matrix products (`gemm`) over columns unfolded once per band of output rows
//! (im2col, row `(c, i, j)` of the columns holding what kernel tap `(i, j)` of channel `c`
//! sees at each output pixel):
//!
//! * forward: `y = W · cols`, `W` the `[OC, C·KH·KW]` weight as it is stored;
//! * weight gradient: `dW = Σ dy · colsᵀ` over images and bands;
//! * input gradient: `dcols = Wᵀ · dy`, folded back onto the input (col2im), channel by
//!   channel in parallel.
//!
//! The columns of a band hold at most `BAND_VALUES` values (or one output row's, if more),
//! so memory stays bounded whatever the image: FPFDCNN's L3 alone would unfold into 44 MB a
//! batch of four at 240x320, 177 MB at 480x640. Padding is zeros; the arithmetic is `f32`
//! whatever the float type.

// burn-ndarray is deprecated upstream but is this crate's default backend.
#![allow(deprecated)]

use super::conv::add_bias;
use super::depthwise_kernel::{ConvKernel, DepthwiseOptions, Geometry, autodiff_conv, kernel_fits};
use super::pool_kernel::{read, tensor};
use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, Flex, NdArray, TensorMetadata, backend_extension};
use burn::prelude::*;
use burn::tensor::ops::ConvOptions;
use rayon::prelude::*;

/// Most values in one band's columns (16 MB of `f32`).
const BAND_VALUES: usize = 1 << 22;

#[cfg(test)]
thread_local! {
    /// Tests set a smaller band to run several bands on small images.
    static TEST_BAND_VALUES: std::cell::Cell<usize> = const { std::cell::Cell::new(BAND_VALUES) };
}

/// [`BAND_VALUES`] (in tests, this thread's [`TEST_BAND_VALUES`]).
fn band_values() -> usize {
    #[cfg(test)]
    return TEST_BAND_VALUES.with(|v| v.get());
    #[cfg(not(test))]
    BAND_VALUES
}

/// The extension: `x` (`[N, C, H, W]`) convolved with `weight` (`[OC, C, KH, KW]`), no bias;
/// stride and zero padding as the depthwise kernel's options.
#[backend_extension(Flex, NdArray, Autodiff)]
pub(crate) trait DenseConvOps: Backend {
    /// `x` (`[N, C, H, W]`) convolved with `weight` (`[OC, C, KH, KW]`): `[N, OC, OH, OW]`.
    fn dense_conv(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: DepthwiseOptions,
    ) -> FloatTensor<Self>;
}

impl DenseConvOps for Flex {
    fn dense_conv(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: DepthwiseOptions,
    ) -> FloatTensor<Self> {
        forward::<Flex>(x, weight, options)
    }
}

impl DenseConvOps for NdArray {
    fn dense_conv(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: DepthwiseOptions,
    ) -> FloatTensor<Self> {
        forward::<NdArray>(x, weight, options)
    }
}

impl<B: Backend, C: CheckpointStrategy> DenseConvOps for Autodiff<B, C> {
    fn dense_conv(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        options: DepthwiseOptions,
    ) -> FloatTensor<Self> {
        autodiff_conv::<B, C, Dense>(x, weight, options)
    }
}

/// The dense convolution's [`ConvKernel`].
#[derive(Debug)]
struct Dense;

impl ConvKernel for Dense {
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
        want: [bool; 2],
    ) -> (Option<FloatTensor<B>>, Option<FloatTensor<B>>) {
        backward::<B>(x, weight, grad, options, want)
    }
}

/// Whether [`dense_conv2d`] computes a convolution of `weight` (`[OC, C/groups, KH, KW]`) on
/// `c` input channels with `options`: groups 1, and `kernel_fits`.
pub(crate) fn supports(
    c: usize,
    [h, w]: [usize; 2],
    weight: [usize; 4],
    options: &ConvOptions<2>,
) -> bool {
    let [oc, c_in, kh, kw] = weight;
    options.groups == 1 && c_in == c && c > 0 && oc > 0 && kernel_fits([h, w], [kh, kw], options)
}

/// Dense convolution of `x` (`[N, C, H, W]`) with `weight` (`[OC, C, KH, KW]`) and an
/// optional `bias` (`[OC]`), equal to `burn::tensor::module::conv2d` with the same options up
/// to `f32` rounding, on the CPU backends, with autodiff where `x` or `weight` has it.
///
/// # Panics
/// If [`supports`] does not hold (as Burn's `conv2d` panics on mismatched shapes).
pub(crate) fn dense_conv2d(
    x: Tensor<4>,
    weight: Tensor<4>,
    bias: Option<Tensor<1>>,
    options: ConvOptions<2>,
) -> Tensor<4> {
    let [_, c, h, w] = x.dims();
    assert!(
        supports(c, [h, w], weight.dims(), &options),
        "dense_conv2d: input {:?}, weight {:?}, {options:?}",
        x.dims(),
        weight.dims()
    );
    let options = DepthwiseOptions::from(&options);
    let out = Tensor::from_dispatch(Dispatch::dense_conv(
        x.into_dispatch(),
        weight.into_dispatch(),
        options,
    ));
    add_bias(out, bias)
}

/// One convolution's sizes and its bands of output rows.
struct Plan {
    g: Geometry,
    c: usize,
    oc: usize,
    /// Rows of the columns: `C·KH·KW`.
    k: usize,
    /// Output rows per band.
    band: usize,
}

impl Plan {
    fn new(x: &[usize], weight: &[usize], options: &DepthwiseOptions) -> Self {
        let g = Geometry::new(x, weight, options);
        let k = x[1] * g.kh * g.kw;
        let band = (band_values() / (k * g.ow).max(1)).clamp(1, g.oh.max(1));
        Self {
            g,
            c: x[1],
            oc: weight[0],
            k,
            band,
        }
    }

    /// The output rows of each band.
    fn bands(&self) -> impl Iterator<Item = std::ops::Range<usize>> + '_ {
        (0..self.g.oh)
            .step_by(self.band)
            .map(|y0| y0..(y0 + self.band).min(self.g.oh))
    }

    /// The columns of output rows `rows` of one image `x` (`[C, H, W]`): `[K, rows·OW]`.
    fn unfold(&self, x: &[f32], rows: &std::ops::Range<usize>, cols: &mut [f32]) {
        let (g, ow) = (&self.g, self.g.ow);
        let p = rows.len() * ow;
        let s = g.stride[1];
        cols[..self.k * p]
            .par_chunks_mut(p)
            .enumerate()
            .for_each(|(k, col)| {
                let (ci, t) = (k / (g.kh * g.kw), k % (g.kh * g.kw));
                let (i, j) = (t / g.kw, t % g.kw);
                let (lo, hi, x0) = g.columns(j);
                let plane = &x[ci * g.h * g.w..(ci + 1) * g.h * g.w];
                for (r, oy) in rows.clone().enumerate() {
                    let out = &mut col[r * ow..(r + 1) * ow];
                    let Some(y) = g.input_row(oy, i) else {
                        out.fill(0.0);
                        continue;
                    };
                    let xrow = &plane[y * g.w..(y + 1) * g.w];
                    out[..lo].fill(0.0);
                    out[hi..].fill(0.0);
                    if s == 1 {
                        out[lo..hi].copy_from_slice(&xrow[x0..x0 + hi - lo]);
                    } else {
                        for (q, o) in out[lo..hi].iter_mut().enumerate() {
                            *o = xrow[x0 + q * s];
                        }
                    }
                }
            });
    }

    /// Adds the columns' gradients `dcols` (`[K, rows·OW]`) of output rows `rows` onto the
    /// input gradient `gx` (`[C, H, W]`) of one image, channel by channel in parallel.
    fn fold(&self, dcols: &[f32], rows: &std::ops::Range<usize>, gx: &mut [f32]) {
        let g = &self.g;
        let (ow, taps) = (g.ow, g.kh * g.kw);
        let p = rows.len() * ow;
        let s = g.stride[1];
        gx.par_chunks_mut(g.h * g.w)
            .enumerate()
            .for_each(|(ci, plane)| {
                for t in 0..taps {
                    let (i, j) = (t / g.kw, t % g.kw);
                    let (lo, hi, x0) = g.columns(j);
                    let col = &dcols[(ci * taps + t) * p..(ci * taps + t + 1) * p];
                    for (r, oy) in rows.clone().enumerate() {
                        let Some(y) = g.input_row(oy, i) else {
                            continue;
                        };
                        let d = &col[r * ow + lo..r * ow + hi];
                        let xrow = &mut plane[y * g.w..(y + 1) * g.w];
                        if s == 1 {
                            for (o, &v) in xrow[x0..x0 + hi - lo].iter_mut().zip(d) {
                                *o += v;
                            }
                        } else {
                            for (q, &v) in d.iter().enumerate() {
                                xrow[x0 + q * s] += v;
                            }
                        }
                    }
                }
            });
    }
}

/// `dst (m×n, row stride dst_rs) = [dst +] lhs (m×k) · rhs (k×n)`, each operand given by its
/// row and column strides.
///
/// # Safety
/// Every index the strides reach must lie inside its slice; `dst` must not overlap the others.
#[allow(clippy::too_many_arguments)]
unsafe fn matmul(
    [m, n, k]: [usize; 3],
    dst: *mut f32,
    dst_rs: usize,
    accumulate: bool,
    lhs: *const f32,
    [lhs_rs, lhs_cs]: [usize; 2],
    rhs: *const f32,
    [rhs_rs, rhs_cs]: [usize; 2],
) {
    // SAFETY: the caller's guarantees.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst,
            1,
            dst_rs as isize,
            accumulate,
            lhs,
            lhs_cs as isize,
            lhs_rs as isize,
            rhs,
            rhs_cs as isize,
            rhs_rs as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::Rayon(0),
        )
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
    let plan = Plan::new(&shape, &wshape, &options);
    let (n, oc, k) = (shape[0], plan.oc, plan.k);
    let (plane, oplane) = (plan.c * plan.g.h * plan.g.w, plan.g.oh * plan.g.ow);
    let mut out = vec![0.0f32; n * oc * oplane];
    let mut cols = vec![0.0f32; k * plan.band * plan.g.ow];
    for b in 0..n {
        let (xb, ob) = (
            &x[b * plane..(b + 1) * plane],
            &mut out[b * oc * oplane..(b + 1) * oc * oplane],
        );
        for rows in plan.bands() {
            let p = rows.len() * plan.g.ow;
            plan.unfold(xb, &rows, &mut cols);
            let dst = &mut ob[rows.start * plan.g.ow..];
            // dst[o][q] (o < oc, q < p, row stride oplane) lies inside `ob` as the band's
            // rows do; wt is [oc, k], cols [k, p].
            debug_assert!(dst.len() >= (oc - 1) * oplane + p && cols.len() >= k * p);
            // SAFETY: the bounds above; three distinct buffers.
            unsafe {
                matmul(
                    [oc, p, k],
                    dst.as_mut_ptr(),
                    oplane,
                    false,
                    wt.as_ptr(),
                    [k, 1],
                    cols.as_ptr(),
                    [p, 1],
                )
            }
        }
    }
    tensor::<B>(out, vec![n, oc, plan.g.oh, plan.g.ow], dtype, &device)
}

/// The input gradient and the weight gradient, each when wanted.
fn backward<B: Backend>(
    x: FloatTensor<B>,
    weight: FloatTensor<B>,
    grad: FloatTensor<B>,
    options: DepthwiseOptions,
    [want_x, want_w]: [bool; 2],
) -> (Option<FloatTensor<B>>, Option<FloatTensor<B>>) {
    let device = x.device();
    let (x, shape, x_dtype) = read::<B>(x);
    let (wt, wshape, w_dtype) = read::<B>(weight);
    let (grad, _, _) = read::<B>(grad);
    let (x, wt, grad) = (x.as_slice(), wt.as_slice(), grad.as_slice());
    let plan = Plan::new(&shape, &wshape, &options);
    let (n, oc, k, ow) = (shape[0], plan.oc, plan.k, plan.g.ow);
    let (plane, oplane) = (plan.c * plan.g.h * plan.g.w, plan.g.oh * ow);
    let mut gx = if want_x {
        vec![0.0f32; x.len()]
    } else {
        Vec::new()
    };
    let mut gw = vec![0.0f32; if want_w { oc * k } else { 0 }];
    let band_len = k * plan.band * ow;
    let mut cols = vec![0.0f32; if want_w { band_len } else { 0 }];
    let mut dcols = vec![0.0f32; if want_x { band_len } else { 0 }];
    let mut first = true;
    for b in 0..n {
        let (xb, gb) = (
            &x[b * plane..(b + 1) * plane],
            &grad[b * oc * oplane..(b + 1) * oc * oplane],
        );
        for rows in plan.bands() {
            let p = rows.len() * ow;
            let g0 = &gb[rows.start * ow..];
            debug_assert!(g0.len() >= (oc - 1) * oplane + p);
            if want_w {
                plan.unfold(xb, &rows, &mut cols);
                // gw [oc, k] += grad band [oc, p] · colsᵀ [p, k] (cols is [k, p]).
                // SAFETY: the bounds above; gw, grad and cols are distinct buffers.
                unsafe {
                    matmul(
                        [oc, k, p],
                        gw.as_mut_ptr(),
                        k,
                        !first,
                        g0.as_ptr(),
                        [oplane, 1],
                        cols.as_ptr(),
                        [1, p],
                    )
                }
                first = false;
            }
            if want_x {
                // dcols [k, p] = Wᵀ [k, oc] · grad band [oc, p] (wt is [oc, k]).
                // SAFETY: as above; dcols is a fourth buffer.
                unsafe {
                    matmul(
                        [k, p, oc],
                        dcols.as_mut_ptr(),
                        p,
                        false,
                        wt.as_ptr(),
                        [1, k],
                        g0.as_ptr(),
                        [oplane, 1],
                    )
                }
                plan.fold(&dcols, &rows, &mut gx[b * plane..(b + 1) * plane]);
            }
        }
    }
    let gx = want_x.then(|| tensor::<B>(gx, shape, x_dtype, &device));
    let gw = want_w.then(|| tensor::<B>(gw, wshape, w_dtype, &device));
    (gx, gw)
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    fn values(t: Tensor<4>) -> Vec<f32> {
        t.into_data().convert::<f32>().to_vec::<f32>().unwrap()
    }

    /// Output, input gradient, weight gradient and bias gradient of `conv` under
    /// `loss = Σ conv(x) ⊙ up` on the autodiff version of `device`.
    fn run(
        device: &Device,
        [x, w, b, up]: [&Tensor<4>; 4],
        conv: impl Fn(Tensor<4>, Tensor<4>, Tensor<1>) -> Tensor<4>,
    ) -> [Vec<f32>; 4] {
        let device = device.clone().autodiff();
        let x = Tensor::<4>::from_data(x.to_data(), &device).require_grad();
        let w = Tensor::<4>::from_data(w.to_data(), &device).require_grad();
        let b = Tensor::<4>::from_data(b.to_data(), &device);
        let oc = b.dims()[0];
        let b = b.reshape([oc]).require_grad();
        let up = Tensor::<4>::from_data(up.to_data(), &device);
        let y = conv(x.clone(), w.clone(), b.clone());
        let grads = (y.clone() * up).sum().backward();
        let gb = b.grad(&grads).expect("bias grad");
        let gb_len = gb.dims()[0];
        [
            values(y),
            values(x.grad(&grads).expect("input grad")),
            values(w.grad(&grads).expect("weight grad")),
            values(gb.reshape([gb_len, 1, 1, 1])),
        ]
    }

    /// `(n, c, [h, w], oc, [kh, kw], stride, padding)`.
    type Case = (
        usize,
        usize,
        [usize; 2],
        usize,
        [usize; 2],
        [usize; 2],
        [(usize, usize); 2],
    );

    #[test]
    fn matches_burns_conv2d_values_and_gradients() {
        let reference = Device::ndarray();
        let uniform = Distribution::Uniform(-1.0, 1.0);
        // SDFCNN's first layer, FPFDCNN's 4×4 s2 p1 and 3×3 s1 p1, odd sizes, uneven padding,
        // taps that miss a one-column image, a kernel as wide as the padded input, one output
        // channel.
        let cases: [Case; 9] = [
            (2, 3, [24, 32], 8, [3, 3], [2, 2], [(0, 1), (0, 1)]),
            (2, 3, [24, 32], 8, [3, 3], [2, 2], [(1, 1), (1, 1)]),
            (2, 3, [11, 13], 5, [4, 4], [2, 2], [(1, 1), (1, 1)]),
            (2, 4, [9, 10], 6, [3, 3], [1, 1], [(1, 1), (1, 1)]),
            (1, 1, [8, 7], 4, [4, 4], [2, 2], [(1, 1), (1, 1)]),
            (3, 2, [7, 9], 3, [3, 2], [2, 1], [(0, 2), (1, 0)]),
            (1, 5, [5, 4], 1, [3, 3], [1, 1], [(1, 1), (1, 1)]),
            (2, 2, [3, 3], 2, [5, 5], [1, 1], [(1, 1), (1, 1)]),
            (1, 2, [3, 1], 2, [5, 5], [1, 1], [(2, 2), (2, 2)]),
        ];
        for (n, c, [h, w], oc, [kh, kw], stride, padding) in cases {
            let x = Tensor::<4>::random([n, c, h, w], uniform, &reference);
            let wt = Tensor::<4>::random([oc, c, kh, kw], uniform, &reference);
            let b = Tensor::<4>::random([oc, 1, 1, 1], uniform, &reference);
            let options = ConvOptions::new_with_padding(stride, padding, [1, 1], 1);
            let [_, _, oh, ow] =
                burn::tensor::module::conv2d(x.clone(), wt.clone(), None, options.clone()).dims();
            let up = Tensor::<4>::random([n, oc, oh, ow], uniform, &reference);
            assert!(supports(c, [h, w], wt.dims(), &options));
            let want = run(&reference, [&x, &wt, &b, &up], |x, w, b| {
                burn::tensor::module::conv2d(x, w, Some(b), options.clone())
            });
            // One band, and bands of two rows (the last one shorter when the rows are odd).
            let runs = [Device::ndarray(), Device::flex()]
                .into_iter()
                .flat_map(|d| [(d.clone(), BAND_VALUES), (d, 3 * c * kh * kw * ow - 1)]);
            for (device, band_values) in runs {
                TEST_BAND_VALUES.with(|v| v.set(band_values));
                let got = run(&device, [&x, &wt, &b, &up], |x, w, b| {
                    dense_conv2d(x, w, Some(b), options.clone())
                });
                TEST_BAND_VALUES.with(|v| v.set(BAND_VALUES));
                for (what, (got, want)) in ["output", "d input", "d weight", "d bias"]
                    .iter()
                    .zip(got.iter().zip(&want))
                {
                    assert_eq!(got.len(), want.len(), "{what}");
                    let scale = want.iter().fold(1.0f32, |m, v| m.max(v.abs()));
                    for (i, (a, e)) in got.iter().zip(want).enumerate() {
                        assert!(
                            (a - e).abs() <= 1e-5 * scale,
                            "{what}[{i}] on {device:?}, band limit {band_values}, case {:?}: {a} vs {e}",
                            (n, c, h, w, oc, kh, kw, stride, padding)
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn bands_cover_every_output_row_once_and_bound_the_columns() {
        let x = [1, 256, 480, 640];
        let w = [1, 256, 3, 3];
        let plan = Plan::new(
            &x,
            &w,
            &DepthwiseOptions {
                stride: [1, 1],
                padding: [(1, 1), (1, 1)],
            },
        );
        assert!(plan.k * plan.band * plan.g.ow <= BAND_VALUES && plan.band >= 1);
        let rows: Vec<usize> = plan.bands().flatten().collect();
        assert_eq!(rows, (0..480).collect::<Vec<_>>());
        assert!(plan.bands().count() > 1);
    }

    #[test]
    fn weight_gradient_alone_when_the_input_needs_none() {
        // The first layer's case: the image needs no gradient, so only dW is computed.
        let reference = Device::ndarray();
        let uniform = Distribution::Uniform(-1.0, 1.0);
        let x = Tensor::<4>::random([2, 3, 32, 48], uniform, &reference);
        let w = Tensor::<4>::random([8, 3, 3, 3], uniform, &reference);
        let options = ConvOptions::new_with_padding([2, 2], [(0, 1), (0, 1)], [1, 1], 1);
        let weight_grad = |device: &Device, conv: &dyn Fn(Tensor<4>, Tensor<4>) -> Tensor<4>| {
            let device = device.clone().autodiff();
            let x = Tensor::<4>::from_data(x.to_data(), &device);
            let w = Tensor::<4>::from_data(w.to_data(), &device).require_grad();
            let y = conv(x, w.clone());
            values(
                w.grad(&(y.clone() * y).sum().backward())
                    .expect("weight grad"),
            )
        };
        let want = weight_grad(&reference, &|x, w| {
            burn::tensor::module::conv2d(x, w, None, options.clone())
        });
        let scale = want.iter().fold(1.0f32, |m, v| m.max(v.abs()));
        for device in [Device::ndarray(), Device::flex()] {
            let got = weight_grad(&device, &|x, w| dense_conv2d(x, w, None, options.clone()));
            for (a, e) in got.iter().zip(&want) {
                assert!((a - e).abs() <= 1e-5 * scale, "{device:?}: {a} vs {e}");
            }
        }
    }
}
