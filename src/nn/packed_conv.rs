//! Inference-only convolutions on channels-last (NHWC) images, with weights packed once.
//!
//! Burn's CPU convolutions convert each input to NHWC, build im2col tiles and transpose the
//! result back on every call. Here activations stay NHWC from layer to layer and every
//! convolution is a few large matrix products (the `gemm` crate, which picks AVX2 or AVX-512
//! microkernels at run time) straight on the zero-padded image, with no im2col buffer except
//! for layers with very few input channels (below):
//!
//! * stride 1, `k×k`: in a padded image of width `Wp`, output pixel `(y, x)` of kernel row `ky`
//!   reads the `k` consecutive pixels starting at row-major index `(y + ky)·Wp + x`, that is
//!   `k·C` consecutive floats. Computing the output over the padded width too (`Wp − W + k − 1`
//!   wasted columns per row) makes kernel row `ky` one product `[H·Wp, k·C] × [k·C, C_out]`
//!   whose left matrix is the image itself read with a row stride of `C` (rows overlap);
//!   `k` products accumulate.
//! * stride 2, even `k` (FPFDCNN's 4×4 convolutions): a 2×2 space-to-depth of the padded image
//!   turns it into a stride-1 `k/2 × k/2` convolution over `4·C` channels.
//! * 1×1: one product.
//!
//! Bias and activation are applied while the wide result is copied out (the epilogue). The
//! results agree with Burn's `conv2d` to float rounding (tests below, and
//! `fpfdcnn::packed`'s against the whole network).

use super::winograd::Winograd;
use burn::nn::conv::Conv2d;
use burn::prelude::*;
use rayon::prelude::*;

#[cfg(test)]
use super::nhwc::from_nchw;
pub use super::nhwc::{Activation, Nhwc, NhwcView, activate};

/// Below this depth (k·c) per kernel row, one product over an im2col of all taps is faster.
const SMALL_K: usize = 32;

/// Buffers one convolution reuses from call to call: the padded (and space-to-depth) source,
/// whose zero border is written once per input size, the wide output and the im2col matrix.
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    /// The input size and convolution (`[h, w, c, k, stride, padding, winograd]`) `src` was
    /// laid out for: a buffer is reused only by the same convolution on the same size.
    layout: Option<[usize; 7]>,
    src: Vec<f32>,
    wide: Vec<f32>,
    col: Vec<f32>,
}

/// Why a convolution cannot be packed (the caller keeps Burn's).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PackError {
    /// The convolution's shape is not one packing supports (the message says which part).
    #[error("packed convolutions need groups = 1, dilation 1 and square kernels: {0}")]
    Unsupported(String),
    /// Weights or batch-norm parameters that could not be read or do not match in size.
    #[error("reading convolution weights: {0}")]
    Data(String),
    /// The input's channel count is not the convolution's.
    #[error("input has {got} channels, the convolution expects {expected}")]
    Channels {
        /// Channels of the input.
        got: usize,
        /// Input channels the convolution was packed for.
        expected: usize,
    },
    /// The input is too small for the kernel or not a multiple of the stride.
    #[error("input {h}x{w} is too small or not a multiple of the stride for this convolution")]
    Size {
        /// Input height, pixels.
        h: usize,
        /// Input width, pixels.
        w: usize,
    },
}

/// A convolution's weights laid out for [`PackedConv::forward`].
#[derive(Debug, Clone)]
pub(crate) struct PackedConv {
    cin: usize,
    cout: usize,
    /// Kernel size after space-to-depth (stride 2: k/2).
    k: usize,
    stride: usize,
    padding: usize,
    /// Channels after space-to-depth (stride 2: 4·cin).
    c: usize,
    /// Per kernel row `ky`: a row-major `[k·c, cout]` matrix, row index `kx·c + channel`
    /// (empty where `winograd` is used).
    weight: Vec<f32>,
    bias: Vec<f32>,
    activation: Activation,
    /// The same kernels for Winograd's algorithm: 3×3 at stride 1 and 2×2 (stride 2 after
    /// space-to-depth), unless the input has too few channels for the transforms to pay.
    winograd: Option<Winograd>,
}

/// The shape of a square convolution.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ConvGeometry {
    /// Output channels.
    pub cout: usize,
    /// Input channels per group.
    pub cin: usize,
    /// Kernel side, pixels (square kernels).
    pub kernel: usize,
    /// Stride, equal in both directions.
    pub stride: usize,
    /// Zero padding on every side, pixels.
    pub padding: usize,
    /// Number of channel groups (1 for a dense convolution).
    pub groups: usize,
}

/// A Burn convolution's weights (row-major `[cout, cin / groups, k, k]`), bias (zeros
/// without one) and shape; square kernels, equal strides and padding, no dilation.
pub(crate) fn read_conv(conv: &Conv2d) -> Result<(Vec<f32>, Vec<f32>, ConvGeometry), PackError> {
    let [cout, cin, kh, kw] = conv.weight.dims();
    let [sh, sw] = conv.stride;
    let [dh, dw] = conv.dilation;
    let padding = match conv.padding {
        burn::nn::PaddingConfig2d::Explicit(t, l, b, r) if t == l && l == b && b == r => t,
        burn::nn::PaddingConfig2d::Valid => 0,
        ref p => return Err(PackError::Unsupported(format!("padding {p:?}"))),
    };
    if kh != kw || sh != sw || dh != 1 || dw != 1 {
        return Err(PackError::Unsupported(format!(
            "{kh}x{kw} kernel, stride {sh}x{sw}, dilation {dh}x{dw}"
        )));
    }
    let read = |t: Tensor<1>| {
        t.into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .map_err(|e| PackError::Data(format!("{e:?}")))
    };
    let weight = read(conv.weight.val().reshape([cout * cin * kh * kw]))?;
    let bias = match &conv.bias {
        Some(b) => read(b.val())?,
        None => vec![0.0; cout],
    };
    let geometry = ConvGeometry {
        cout,
        cin,
        kernel: kh,
        stride: sh,
        padding,
        groups: conv.groups,
    };
    Ok((weight, bias, geometry))
}

/// Folds an inference-mode batch normalisation into the convolution before it:
/// `γ (w·x + b − μ) / √(σ² + ε) + β` is a convolution with weights `w·s` and bias
/// `(b − μ)·s + β`, `s = γ / √(σ² + ε)` per output channel.
pub(crate) fn fold_batch_norm(
    weight: &mut [f32],
    bias: &mut [f32],
    bn: &burn::nn::BatchNorm,
) -> Result<(), PackError> {
    let read = |t: Tensor<1>| {
        t.into_data()
            .convert::<f64>()
            .try_into_vec::<f64>()
            .map_err(|e| PackError::Data(format!("{e:?}")))
    };
    let gamma = read(bn.gamma.val())?;
    let beta = read(bn.beta.val())?;
    let mean = read(bn.running_mean.value())?;
    let var = read(bn.running_var.value())?;
    let cout = bias.len();
    if [gamma.len(), beta.len(), mean.len(), var.len()] != [cout; 4] {
        return Err(PackError::Data(format!(
            "batch norm of {} channels after {cout}",
            gamma.len()
        )));
    }
    let per = weight.len() / cout;
    for o in 0..cout {
        let s = gamma[o] / (var[o] + bn.epsilon).sqrt();
        weight[o * per..(o + 1) * per]
            .iter_mut()
            .for_each(|w| *w = (*w as f64 * s) as f32);
        bias[o] = ((bias[o] as f64 - mean[o]) * s + beta[o]) as f32;
    }
    Ok(())
}

impl PackedConv {
    /// Packs a Burn convolution followed by `activation`.
    pub fn new(conv: &Conv2d, activation: Activation) -> Result<Self, PackError> {
        let (weight, bias, geometry) = read_conv(conv)?;
        if geometry.groups != 1 {
            return Err(PackError::Unsupported(format!(
                "{} groups",
                geometry.groups
            )));
        }
        Self::from_weights(&weight, &bias, geometry, activation)
    }

    /// Packs row-major `[cout, cin, k, k]` weights and a bias (for example a convolution with
    /// a batch normalisation folded in, [`fold_batch_norm`]).
    pub fn from_weights(
        w: &[f32],
        bias: &[f32],
        g: ConvGeometry,
        activation: Activation,
    ) -> Result<Self, PackError> {
        let ConvGeometry {
            cout,
            cin,
            kernel,
            stride,
            padding,
            groups,
        } = g;
        let sizes = w.len() == cout * cin * kernel * kernel && bias.len() == cout;
        if groups != 1 || !(stride == 1 || stride == 2) || !sizes {
            return Err(PackError::Unsupported(format!("{g:?}")));
        }
        // Stride 2 with an odd kernel: the same convolution with one more row and column of
        // zero taps, which the space-to-depth form needs (same output size on even inputs).
        let taps = if stride == 2 {
            kernel + kernel % 2
        } else {
            kernel
        };
        let (k, c) = if stride == 2 {
            (taps / 2, 4 * cin)
        } else {
            (taps, cin)
        };
        let mut weight = vec![0.0; k * k * c * cout];
        for o in 0..cout {
            for i in 0..cin {
                for y in 0..kernel {
                    for x in 0..kernel {
                        let v = w[((o * cin + i) * kernel + y) * kernel + x];
                        // Stride 2: tap (y, x) = (2a + dy, 2b + dx) reads channel
                        // (dy·2 + dx)·cin + i of space-to-depth pixel (a, b).
                        let (ky, kx, ch) = if stride == 2 {
                            (y / 2, x / 2, ((y % 2) * 2 + x % 2) * cin + i)
                        } else {
                            (y, x, i)
                        };
                        weight[((ky * k + kx) * c + ch) * cout + o] = v;
                    }
                }
            }
        }
        let winograd = if k * c >= SMALL_K {
            Winograd::new(&weight, k, c, cout)
        } else {
            None
        };
        // The direct form's weights are kept only where they are used.
        let weight = if winograd.is_some() {
            Vec::new()
        } else {
            weight
        };
        Ok(Self {
            cin,
            cout,
            k,
            stride,
            padding,
            c,
            winograd,
            weight,
            bias: bias.to_vec(),
            activation,
        })
    }

    /// `dst (+)= lhs · rhs` with `dst` `[rows, cout]`, `lhs` `[rows, depth]` of row stride
    /// `lhs_stride` and `rhs` `[depth, cout]`, all row-major.
    ///
    /// # Safety
    /// `lhs` and `rhs` must be valid for those shapes and strides and `dst` hold
    /// `rows · cout` values.
    #[allow(clippy::too_many_arguments)]
    unsafe fn product(
        &self,
        dst: &mut [f32],
        rows: usize,
        depth: usize,
        lhs: *const f32,
        lhs_stride: usize,
        rhs: *const f32,
        accumulate: bool,
    ) {
        debug_assert_eq!(dst.len(), rows * self.cout);
        // SAFETY: the caller's contract.
        unsafe {
            gemm::gemm(
                rows,
                self.cout,
                depth,
                dst.as_mut_ptr(),
                1,
                self.cout as isize,
                accumulate,
                lhs,
                1,
                lhs_stride as isize,
                rhs,
                1,
                self.cout as isize,
                1.0,
                1.0,
                false,
                false,
                false,
                gemm::Parallelism::Rayon(0),
            )
        }
    }

    /// The convolution of `x`, bias and activation included, as a compact image with buffers
    /// of its own: [`Self::forward_view`]'s output, moved out when it is compact (Winograd's,
    /// and every 1x1 convolution's) and copied otherwise. A 1x1 stride-1 convolution of a
    /// compact image multiplies the image itself (no padded copy), the same product.
    pub fn forward(&self, x: &NhwcView) -> Result<Nhwc, PackError> {
        if self.k == 1 && self.stride == 1 && self.padding == 0 && x.stride == x.w {
            return self.pointwise(x);
        }
        let mut scratch = Scratch::default();
        let (h, w, c, stride) = {
            let v = self.forward_view(*x, &mut scratch)?;
            (v.h, v.w, v.c, v.stride)
        };
        if stride != w {
            return Ok(NhwcView {
                h,
                w,
                c,
                stride,
                data: &scratch.wide,
            }
            .to_owned());
        }
        // Both paths that give a compact result write it from the start of `wide`.
        let mut data = std::mem::take(&mut scratch.wide);
        data.truncate(h * w * c);
        Ok(Nhwc { h, w, c, data })
    }

    /// A 1x1 stride-1 unpadded convolution of a compact image: one product over its pixels
    /// (the one [`Self::forward_view`] computes from its copy of the image), then the epilogue.
    fn pointwise(&self, x: &NhwcView) -> Result<Nhwc, PackError> {
        if x.c != self.cin {
            return Err(PackError::Channels {
                got: x.c,
                expected: self.cin,
            });
        }
        let rows = x.h * x.w;
        if rows == 0 {
            return Err(PackError::Size { h: x.h, w: x.w });
        }
        let mut out = Nhwc::zeros(x.h, x.w, self.cout);
        assert!(
            x.data.len() >= rows * self.c,
            "a compact view holds h·w·c values"
        );
        // SAFETY: lhs is x's [rows, c] (checked above), rhs the [c, cout] weight, dst
        // [rows, cout] = out.data.len().
        unsafe {
            self.product(
                &mut out.data,
                rows,
                self.c,
                x.data.as_ptr(),
                self.c,
                self.weight.as_ptr(),
                false,
            )
        };
        self.epilogue(&mut out.data, x.w);
        Ok(out)
    }

    /// Adds the bias and applies the activation to `rows_of` pixels at a time, in place.
    fn epilogue(&self, data: &mut [f32], rows_of: usize) {
        let (bias, act, cout) = (&self.bias, self.activation, self.cout);
        data.par_chunks_mut(rows_of * cout).for_each(|row| {
            for px in row.chunks_exact_mut(cout) {
                for (v, &b) in px.iter_mut().zip(bias) {
                    *v += b;
                }
            }
            activate(row, act);
        });
    }

    /// The convolution of `x`, bias and activation included, computed in `scratch`, which
    /// holds the result (compact from Winograd's algorithm; otherwise rows of the wide grid,
    /// `k − 1` columns wider than the image).
    pub fn forward_view<'s>(
        &self,
        x: NhwcView<'_>,
        scratch: &'s mut Scratch,
    ) -> Result<NhwcView<'s>, PackError> {
        if x.c != self.cin {
            return Err(PackError::Channels {
                got: x.c,
                expected: self.cin,
            });
        }
        let p = self.padding;
        let (hp, wp) = (x.h + 2 * p, x.w + 2 * p);
        let odd = self.stride == 2 && (hp % 2 != 0 || wp % 2 != 0);
        if odd || hp < self.k * self.stride || wp < self.k * self.stride {
            return Err(PackError::Size { h: x.h, w: x.w });
        }
        // The source of the stride-1 k×k "valid" convolution (after space-to-depth at
        // stride 2). Only its interior is written below, so its border stays zero from one
        // call to the next.
        let (sh, sw) = if self.stride == 2 {
            (hp / 2, wp / 2)
        } else {
            (hp, wp)
        };
        let (oh, ow) = (sh - self.k + 1, sw - self.k + 1);
        if let Some(wino) = &self.winograd {
            // Whole tiles: the source grows to a multiple of the tile (zeros beyond the image).
            let [hs, ws] = wino.source_size([oh, ow]);
            let layout = [x.h, x.w, x.c, self.k, self.stride, p, 1];
            if scratch.layout != Some(layout) {
                scratch.src.clear();
                scratch.src.resize(hs * ws * self.c, 0.0);
                scratch.layout = Some(layout);
            }
            if self.stride == 2 {
                space_to_depth_padded(&x, p, ws, &mut scratch.src);
            } else {
                pad_into(&x, p, ws, &mut scratch.src);
            }
            scratch.wide.resize(oh * ow * self.cout, 0.0);
            let (src, out) = (&scratch.src, &mut scratch.wide);
            wino.forward(src, ws, [oh, ow], &self.bias, self.activation, out);
            return Ok(NhwcView {
                h: oh,
                w: ow,
                c: self.cout,
                stride: ow,
                data: &scratch.wide,
            });
        }
        // Directly: k spare pixels at the end (the wide output's last rows read past the
        // image).
        let layout = [x.h, x.w, x.c, self.k, self.stride, p, 0];
        if scratch.layout != Some(layout) {
            scratch.src.clear();
            scratch.src.resize((sh * sw + self.k) * self.c, 0.0);
            scratch.layout = Some(layout);
        }
        let src = &mut scratch.src;
        if self.stride == 2 {
            space_to_depth_padded(&x, p, sw, src);
        } else {
            pad_into(&x, p, sw, src);
        }
        let rows = oh * sw;
        // Every value is written by the first product (it does not read them).
        scratch.wide.resize(rows * self.cout, 0.0);
        let wide = &mut scratch.wide;
        let kc = self.k * self.c;
        if self.k > 1 && kc < SMALL_K {
            // Few channels (FPFDCNN's L1): one product over all k² taps of a k-row im2col,
            // since k products of depth k·c would be dominated by their overhead.
            let kk = self.k * kc;
            scratch.col.resize(rows * kk, 0.0);
            let c = self.c;
            scratch
                .col
                .par_chunks_mut(kk)
                .enumerate()
                .for_each(|(r, dst)| {
                    for (ky, d) in dst.chunks_exact_mut(kc).enumerate() {
                        let at = (ky * sw + r) * c;
                        d.copy_from_slice(&src[at..at + kc]);
                    }
                });
            // SAFETY: col is [rows, k·kc], weight [k·kc, cout], wide [rows, cout].
            unsafe {
                self.product(
                    wide,
                    rows,
                    kk,
                    scratch.col.as_ptr(),
                    kk,
                    self.weight.as_ptr(),
                    false,
                )
            };
        } else {
            // The bound the products below rely on (the layout key guarantees it).
            assert!(src.len() >= (sh * sw + self.k) * self.c && wide.len() == rows * self.cout);
            for ky in 0..self.k {
                // SAFETY: lhs rows r = 0..rows start at (ky·sw + r)·c and read k·c floats, the
                // last ending at ((ky + oh)·sw + k − 1)·c ≤ (sh·sw + k)·c = src.len(); rhs is
                // the [k·c, cout] block ky of `weight`; dst is [rows, cout] = wide.len().
                unsafe {
                    self.product(
                        wide,
                        rows,
                        kc,
                        src.as_ptr().add(ky * sw * self.c),
                        self.c,
                        self.weight.as_ptr().add(ky * kc * self.cout),
                        ky > 0,
                    )
                };
            }
        }
        // Epilogue, in place over whole rows (the extra columns too: cheaper than skipping).
        self.epilogue(wide, sw);
        Ok(NhwcView {
            h: oh,
            w: ow,
            c: self.cout,
            stride: sw,
            data: &scratch.wide,
        })
    }
}

/// Copies `x` into an image of `wp` pixels per row at offset `(p, p)` (the rest is left as
/// it is: zero).
fn pad_into(x: &NhwcView, p: usize, wp: usize, dst: &mut [f32]) {
    let row = x.w * x.c;
    let rows = &mut dst[p * wp * x.c..(p + x.h) * wp * x.c];
    rows.par_chunks_mut(wp * x.c)
        .enumerate()
        .for_each(|(y, d)| {
            let from = y * x.stride * x.c;
            d[p * x.c..p * x.c + row].copy_from_slice(&x.data[from..from + row]);
        });
}

/// Space-to-depth by 2 of `x` padded by `p`: pixel `(Y, X)` of the result (width `sw`) holds
/// padded pixels `(2Y + dy, 2X + dx)` as channels `(dy·2 + dx)·c + ch`. Only pixels of `x` are
/// written.
fn space_to_depth_padded(x: &NhwcView, p: usize, sw: usize, dst: &mut [f32]) {
    let c = x.c;
    // Output row Y holds padded rows 2Y and 2Y + 1.
    dst.par_chunks_mut(sw * 4 * c)
        .enumerate()
        .for_each(|(py, d)| {
            for dy in 0..2 {
                let Some(y) = (2 * py + dy).checked_sub(p).filter(|&y| y < x.h) else {
                    continue;
                };
                for xx in 0..x.w {
                    let (px, dx) = ((xx + p) / 2, (xx + p) % 2);
                    let at = px * 4 * c + (dy * 2 + dx) * c;
                    d[at..at + c].copy_from_slice(x.pixel(y, xx));
                }
            }
        });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::nhwc::to_nchw;
    use burn::nn::PaddingConfig2d;
    use burn::nn::conv::Conv2dConfig;
    use rand::{RngExt, SeedableRng};

    fn check(cin: usize, cout: usize, k: usize, s: usize, p: usize, [h, w]: [usize; 2]) {
        let d = Device::flex();
        let conv = Conv2dConfig::new([cin, cout], [k, k])
            .with_stride([s, s])
            .with_padding(PaddingConfig2d::Explicit(p, p, p, p))
            .init(&d);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let x: Vec<f32> = (0..cin * h * w)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        for act in [
            Activation::Identity,
            Activation::Elu,
            Activation::Sigmoid,
            Activation::Relu,
            Activation::Relu6,
        ] {
            let packed = PackedConv::new(&conv, act).unwrap();
            let got = packed.forward(&from_nchw(&x, [cin, h, w]).view()).unwrap();
            let input = Tensor::<4>::from_data(TensorData::new(x.clone(), [1, cin, h, w]), &d);
            let y = conv.forward(input);
            let y = match act {
                Activation::Identity => y,
                Activation::Elu => crate::nn::elu(y, 1.0),
                Activation::Sigmoid => burn::tensor::activation::sigmoid(y),
                Activation::Relu => burn::tensor::activation::relu(y),
                Activation::Relu6 => burn::tensor::activation::relu6(y),
            };
            let [_, c, oh, ow] = y.dims();
            assert_eq!([got.c, got.h, got.w], [c, oh, ow]);
            let want = y.into_data().try_into_vec::<f32>().unwrap();
            let got = to_nchw(&got.view());
            let peak = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            for (a, b) in got.iter().zip(&want) {
                assert!(
                    (a - b).abs() <= 1e-5 * peak.max(1.0),
                    "{a} vs {b} ({act:?})"
                );
            }
        }
    }

    #[test]
    fn matches_burn_for_fpfdcnn_geometries() {
        check(1, 8, 4, 2, 1, [16, 24]); // L1
        check(3, 8, 3, 2, 1, [16, 24]); // SDFCNN Layer1 (odd kernel, stride 2)
        check(5, 7, 4, 2, 1, [12, 8]); // L2, L4, L6
        check(6, 9, 3, 1, 1, [7, 11]); // L3, L5, L7, L9 with few channels (direct)
        check(16, 9, 3, 1, 1, [7, 11]); // the same through Winograd's F(4x4, 3x3)
        check(8, 5, 4, 2, 1, [12, 10]); // L2, L4, L6 through F(5x5, 2x2)
        check(8, 5, 4, 2, 0, [12, 10]); // no padding, and two columns of it, on each side
        check(8, 5, 4, 2, 2, [12, 10]);
        check(5, 7, 4, 2, 2, [12, 8]);
        check(9, 4, 1, 1, 0, [5, 6]); // L8, L10
        check(3, 3, 5, 1, 2, [6, 6]);
    }

    #[test]
    fn one_scratch_shared_by_different_convolutions() {
        let d = Device::flex();
        let conv = |k: usize, s: usize| {
            let c = Conv2dConfig::new([4, 6], [k, k])
                .with_stride([s, s])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .init(&d);
            PackedConv::new(&c, Activation::Identity).unwrap()
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let x = Nhwc {
            h: 8,
            w: 10,
            c: 4,
            data: (0..320).map(|_| rng.random_range(-1.0..1.0)).collect(),
        };
        let mut scratch = Scratch::default();
        for p in [conv(3, 1), conv(4, 2), conv(5, 1), conv(3, 1)] {
            let shared = p.forward_view(x.view(), &mut scratch).unwrap().to_owned();
            assert_eq!(shared, p.forward(&x.view()).unwrap());
        }
    }

    #[test]
    fn a_pointwise_convolution_multiplies_the_image_itself_with_the_same_result() {
        let d = Device::flex();
        let c = Conv2dConfig::new([5, 7], [1, 1]).init(&d);
        let p = PackedConv::new(&c, Activation::Relu6).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        // Rows of 9 pixels, 6 of them the image's: the strided view goes the padded way.
        let data: Vec<f32> = (0..4 * 9 * 5)
            .map(|_| rng.random_range(-8.0..8.0))
            .collect();
        for (w, stride) in [(9, 9), (6, 9)] {
            let x = NhwcView {
                h: 4,
                w,
                c: 5,
                stride,
                data: &data,
            };
            let mut scratch = Scratch::default();
            let via_scratch = p.forward_view(x, &mut scratch).unwrap().to_owned();
            assert_eq!(
                p.forward(&x).unwrap(),
                via_scratch,
                "width {w}, stride {stride}"
            );
        }
        let empty = NhwcView {
            h: 0,
            w: 3,
            c: 5,
            stride: 3,
            data: &[],
        };
        assert!(matches!(p.forward(&empty), Err(PackError::Size { .. })));
    }

    #[test]
    fn refuses_what_it_cannot_pack_and_wrong_inputs() {
        let d = Device::flex();
        let dw = Conv2dConfig::new([4, 4], [3, 3]).with_groups(4).init(&d);
        assert!(matches!(
            PackedConv::new(&dw, Activation::Identity),
            Err(PackError::Unsupported(_))
        ));
        let s3 = Conv2dConfig::new([4, 4], [3, 3])
            .with_stride([3, 3])
            .init(&d);
        assert!(PackedConv::new(&s3, Activation::Identity).is_err());
        let c = Conv2dConfig::new([2, 4], [4, 4])
            .with_stride([2, 2])
            .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
            .init(&d);
        let p = PackedConv::new(&c, Activation::Identity).unwrap();
        assert!(matches!(
            p.forward(&Nhwc::zeros(8, 8, 3).view()),
            Err(PackError::Channels { .. })
        ));
        assert!(matches!(
            p.forward(&Nhwc::zeros(7, 8, 2).view()),
            Err(PackError::Size { .. })
        ));
    }
}
