//! Differentiable bilinear resizing with PyTorch `align_corners=False` semantics.
//!
//! Both networks upsample bilinearly (FPFDCNN's FD layer, Table 12; SDFCNN's Layer0, the
//! decoder and the output layer, Table 13). Burn's own `interpolate` has no bilinear backward on
//! the NdArray backend, so this module builds the resize from matrix products, which every
//! backend can differentiate: `out = Wy · X · Wxᵀ`, with `Wy` (`[out_h, in_h]`) and `Wx`
//! (`[out_w, in_w]`) holding at most two non-zero weights per row.
//!
//! The weights follow `F.interpolate(mode="bilinear", align_corners=False)` for an explicit
//! output size: half-pixel centres, `src = (dst + 0.5) · in / out − 0.5`, negative sources
//! clamped to 0, the upper neighbour clamped to the last pixel, no antialiasing when
//! downsampling.

use burn::prelude::*;

/// The two source taps of one output coordinate: `value = w0 · in[i0] + w1 · in[i1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Taps {
    /// Lower source index.
    pub i0: usize,
    /// Upper source index (equal to `i0` at the last input pixel).
    pub i1: usize,
    /// Weight of `i0`.
    pub w0: f32,
    /// Weight of `i1`.
    pub w1: f32,
}

/// Source taps of output coordinate `dst` when resizing an axis from `input` to `output`
/// samples, as PyTorch's `upsample_bilinear2d` computes them (`align_corners=False`).
///
/// # Panics
/// If `input` or `output` is zero (an empty axis cannot be interpolated).
pub(crate) fn taps(dst: usize, input: usize, output: usize) -> Taps {
    assert!(input > 0 && output > 0, "bilinear resize of an empty axis");
    if input == output {
        return Taps {
            i0: dst,
            i1: dst,
            w0: 1.0,
            w1: 0.0,
        };
    }
    let scale = input as f32 / output as f32;
    let src = ((dst as f32 + 0.5) * scale - 0.5).max(0.0);
    let i0 = (src as usize).min(input - 1);
    let i1 = if i0 + 1 < input { i0 + 1 } else { i0 };
    let w1 = (src - i0 as f32).clamp(0.0, 1.0);
    Taps {
        i0,
        i1,
        w0: 1.0 - w1,
        w1,
    }
}

/// Source taps of a continuous (sub-pixel) output coordinate `pos`, extending
/// `taps` between pixel centres: at integer `pos` they agree (except when
/// `input == output`, where `taps` is the identity and this interpolates too).
pub fn taps_at(pos: f32, input: usize, output: usize) -> Taps {
    assert!(input > 0 && output > 0, "bilinear resize of an empty axis");
    let scale = input as f32 / output as f32;
    let src = ((pos + 0.5) * scale - 0.5).clamp(0.0, (input - 1) as f32);
    let i0 = (src as usize).min(input - 1);
    let i1 = if i0 + 1 < input { i0 + 1 } else { i0 };
    let w1 = (src - i0 as f32).clamp(0.0, 1.0);
    Taps {
        i0,
        i1,
        w0: 1.0 - w1,
        w1,
    }
}

/// Row-major `[output, input]` interpolation matrix of one axis.
pub(crate) fn interpolation_matrix(input: usize, output: usize) -> Vec<f32> {
    let mut m = vec![0.0; output * input];
    for (dst, row) in m.chunks_exact_mut(input).enumerate() {
        let t = taps(dst, input, output);
        row[t.i0] += t.w0;
        row[t.i1] += t.w1;
    }
    m
}

/// Transposed (`[input, output]`, row-major) interpolation matrix of one axis.
fn interpolation_matrix_t(input: usize, output: usize) -> Vec<f32> {
    let mut m = vec![0.0; input * output];
    for dst in 0..output {
        let t = taps(dst, input, output);
        m[t.i0 * output + dst] += t.w0;
        m[t.i1 * output + dst] += t.w1;
    }
    m
}

/// Resizes `x` (`[N, C, H, W]`) to `size = [out_h, out_w]` by bilinear interpolation with
/// PyTorch `align_corners=False` semantics, differentiably on every backend.
///
/// An axis whose size does not change is left untouched (PyTorch's identity case). Of the two
/// orders of the separable products the cheaper one is taken.
///
/// # Panics
/// If an input or output spatial size is zero.
pub fn resize_bilinear(x: Tensor<4>, size: [usize; 2]) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    let [oh, ow] = size;
    assert!(
        h > 0 && w > 0 && oh > 0 && ow > 0,
        "bilinear resize with an empty spatial size: {h}x{w} -> {oh}x{ow}"
    );
    let width_first = h * w * ow + oh * h * ow <= oh * h * w + oh * w * ow;
    if width_first {
        resize_rows(resize_cols(x, ow), oh)
    } else {
        resize_cols(resize_rows(x, oh), ow)
    }
    .reshape([n, c, oh, ow])
}

/// `X · Wxᵀ`: resizes the last axis to `ow`.
fn resize_cols(x: Tensor<4>, ow: usize) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    if w == ow {
        return x;
    }
    let wx_t = Tensor::<2>::from_data(
        TensorData::new(interpolation_matrix_t(w, ow), [w, ow]),
        &x.device(),
    );
    x.reshape([n * c * h, w])
        .matmul(wx_t)
        .reshape([n, c, h, ow])
}

/// `Wy · X`: resizes the third axis to `oh`.
fn resize_rows(x: Tensor<4>, oh: usize) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    if h == oh {
        return x;
    }
    let wy = Tensor::<3>::from_data(
        TensorData::new(interpolation_matrix(h, oh), [1, oh, h]),
        &x.device(),
    );
    wy.matmul(x.reshape([n * c, h, w])).reshape([n, c, oh, w])
}

/// Error of [`sample_bilinear_at`].
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum SampleError {
    /// The map slice does not hold `channels · height · width` values.
    #[error("map has {len} values, expected {channels}x{height}x{width}")]
    MapSize {
        /// Length of the given slice.
        len: usize,
        /// Channels.
        channels: usize,
        /// Height.
        height: usize,
        /// Width.
        width: usize,
    },
    /// A zero-sized map or output size.
    #[error("empty map or output size")]
    Empty,
    /// A point outside the full-resolution image.
    #[error("point (x={x}, y={y}) outside the {width}x{height} image")]
    PointOutside {
        /// Column.
        x: usize,
        /// Row.
        y: usize,
        /// Full-resolution width.
        width: usize,
        /// Full-resolution height.
        height: usize,
    },
}

/// Samples a low-resolution map at full-resolution pixels, giving the values that
/// [`resize_bilinear`] of the whole map to `full = [height, width]` would hold at those pixels
/// (FPFDCNN's FD_FP layer, Table 12, without upsampling all 256 channels).
///
/// `map` is one image's `[channels, map_h, map_w]` row-major map, `points` are `(x, y)` pixel
/// coordinates (column, row) of the full-resolution image. Returns `points.len() × channels`
/// values, row-major.
pub fn sample_bilinear_at(
    map: &[f32],
    dims: [usize; 3],
    full: [usize; 2],
    points: &[(usize, usize)],
) -> Result<Vec<f32>, SampleError> {
    let taps = point_taps(map.len(), dims, full, points)?;
    let [channels, map_h, map_w] = dims;
    let plane = map_h * map_w;
    let mut out = Vec::with_capacity(points.len() * channels);
    for (ty, tx) in taps {
        let (r0, r1) = (ty.i0 * map_w, ty.i1 * map_w);
        for ch in map.chunks_exact(plane) {
            // Same order as `resize_bilinear` (columns first, then rows).
            let a = tx.w0 * ch[r0 + tx.i0] + tx.w1 * ch[r0 + tx.i1];
            let b = tx.w0 * ch[r1 + tx.i0] + tx.w1 * ch[r1 + tx.i1];
            out.push(ty.w0 * a + ty.w1 * b);
        }
    }
    Ok(out)
}

/// [`sample_bilinear_at`] of a map stored channels last (`map[(y·map_w + x)·channels + c]`,
/// `dims` still `[channels, map_h, map_w]`): the same values bit for bit, each tap's
/// channels read as one contiguous row.
pub fn sample_bilinear_at_nhwc(
    map: &[f32],
    dims: [usize; 3],
    full: [usize; 2],
    points: &[(usize, usize)],
) -> Result<Vec<f32>, SampleError> {
    let taps = point_taps(map.len(), dims, full, points)?;
    let [channels, _, map_w] = dims;
    let mut out = vec![0.0f32; points.len() * channels];
    if channels == 0 {
        return Ok(out);
    }
    for ((ty, tx), o) in taps.into_iter().zip(out.chunks_exact_mut(channels)) {
        let px = |row: usize, col: usize| &map[(row * map_w + col) * channels..][..channels];
        blend_taps(
            o,
            [
                px(ty.i0, tx.i0),
                px(ty.i0, tx.i1),
                px(ty.i1, tx.i0),
                px(ty.i1, tx.i1),
            ],
            [tx.w0, tx.w1, ty.w0, ty.w1],
        );
    }
    Ok(out)
}

/// The row and column taps of each point for the two samplers above, after checking the map's
/// size and that every point lies in the `[height, width]` image.
fn point_taps(
    len: usize,
    [channels, map_h, map_w]: [usize; 3],
    [height, width]: [usize; 2],
    points: &[(usize, usize)],
) -> Result<Vec<(Taps, Taps)>, SampleError> {
    if len != channels * map_h * map_w {
        return Err(SampleError::MapSize {
            len,
            channels,
            height: map_h,
            width: map_w,
        });
    }
    if map_h == 0 || map_w == 0 || height == 0 || width == 0 {
        return Err(SampleError::Empty);
    }
    points
        .iter()
        .map(|&(x, y)| {
            if x >= width || y >= height {
                return Err(SampleError::PointOutside {
                    x,
                    y,
                    width,
                    height,
                });
            }
            Ok((taps(y, map_h, height), taps(x, map_w, width)))
        })
        .collect()
}

crate::nn::nhwc::simd_fn! {
    /// `out = ty0·(tx0·p00 + tx1·p01) + ty1·(tx0·p10 + tx1·p11)` channel by channel (the
    /// order of [`sample_bilinear_at`]).
    fn blend_taps(out: &mut [f32], taps: [&[f32]; 4], weights: [f32; 4]) {
        let [p00, p01, p10, p11] = taps;
        let [tx0, tx1, ty0, ty1] = weights;
        for ((((o, &a0), &a1), &b0), &b1) in out.iter_mut().zip(p00).zip(p01).zip(p10).zip(p11) {
            let a = tx0 * a0 + tx1 * a1;
            let b = tx0 * b0 + tx1 * b1;
            *o = ty0 * a + ty1 * b;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::module::interpolate;
    use burn::tensor::ops::{InterpolateMode, InterpolateOptions};

    #[allow(deprecated)]
    fn ndarray() -> Device {
        Device::ndarray()
    }

    fn values(t: Tensor<4>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().expect("f32 tensor")
    }

    fn ramp(shape: [usize; 4], device: &Device) -> Tensor<4> {
        let n: usize = shape.iter().product();
        let v: Vec<f32> = (0..n)
            .map(|i| ((i * 37 % 101) as f32) / 7.0 - 3.0)
            .collect();
        Tensor::from_data(TensorData::new(v, shape), device)
    }

    fn assert_close(a: &[f32], b: &[f32], tol: f32) {
        assert_eq!(a.len(), b.len());
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!((x - y).abs() <= tol, "index {i}: {x} vs {y}");
        }
    }

    #[test]
    fn resize_matches_hand_computed_pytorch_values() {
        let d = ndarray();
        // F.interpolate([[1,2],[3,4]], size=(4,4), mode="bilinear", align_corners=False)
        let x = Tensor::<4>::from_data(TensorData::new(vec![1.0f32, 2., 3., 4.], [1, 1, 2, 2]), &d);
        let want = [
            1.0, 1.25, 1.75, 2.0, 1.5, 1.75, 2.25, 2.5, 2.5, 2.75, 3.25, 3.5, 3.0, 3.25, 3.75, 4.0,
        ];
        assert_close(&values(resize_bilinear(x, [4, 4])), &want, 1e-6);
        // Downsampling, no antialiasing: [0..5) -> 2 and [0,10,20,30] -> 3 along the width.
        let x = Tensor::<4>::from_data(
            TensorData::new(vec![0.0f32, 1., 2., 3., 4.], [1, 1, 1, 5]),
            &d,
        );
        assert_close(&values(resize_bilinear(x, [1, 2])), &[0.75, 3.25], 1e-6);
        let x = Tensor::<4>::from_data(
            TensorData::new(vec![0.0f32, 10., 20., 30.], [1, 1, 1, 4]),
            &d,
        );
        assert_close(
            &values(resize_bilinear(x, [1, 3])),
            &[5.0 / 3.0, 15.0, 85.0 / 3.0],
            1e-5,
        );
        // 3x3 ramp 3r+c -> 2x2 samples at (0.25, 0.25), (0.25, 1.75), ...
        let x = Tensor::<4>::from_data(
            TensorData::new((0..9).map(|v| v as f32).collect::<Vec<_>>(), [1, 1, 3, 3]),
            &d,
        );
        assert_close(
            &values(resize_bilinear(x, [2, 2])),
            &[1.0, 2.5, 5.5, 7.0],
            1e-6,
        );
    }

    #[test]
    fn resize_matches_burn_interpolate_forward() {
        for device in [ndarray(), Device::flex()] {
            for (input, output) in [
                ([5, 7], [11, 13]), // odd upsampling
                ([9, 13], [4, 5]),  // odd downsampling
                ([6, 9], [6, 17]),  // one axis unchanged
                ([7, 8], [3, 21]),  // down in y, up in x
                ([4, 5], [16, 20]), // integer factor
            ] {
                let x = ramp([2, 3, input[0], input[1]], &device);
                let reference = interpolate(
                    x.clone(),
                    InterpolateOptions::new(InterpolateMode::Bilinear)
                        .with_align_corners(false)
                        .with_output_size(output),
                );
                let ours = resize_bilinear(x, output);
                assert_eq!(ours.dims(), [2, 3, output[0], output[1]]);
                assert_close(&values(ours), &values(reference), 1e-5);
            }
        }
    }

    #[test]
    fn resize_backward_matches_finite_differences() {
        for device in [ndarray().autodiff(), Device::flex().autodiff()] {
            backward_matches_finite_differences(device);
        }
    }

    fn backward_matches_finite_differences(device: Device) {
        let shape = [1, 2, 3, 4];
        let base: Vec<f32> = (0..24).map(|i| ((i * 7 % 11) as f32) * 0.3 - 1.0).collect();
        // Loss = Σ out ⊙ r with a fixed random-looking r, so dL/dx = Rᵀ-interpolation of r.
        for out in [[5, 7], [2, 3]] {
            let r_len = 2 * out[0] * out[1];
            let r: Vec<f32> = (0..r_len)
                .map(|i| ((i * 13 % 17) as f32) * 0.1 - 0.8)
                .collect();
            let loss_of = |x: &[f32]| -> f64 {
                let xt = Tensor::<4>::from_data(TensorData::new(x.to_vec(), shape), &ndarray());
                let o = values(resize_bilinear(xt, out));
                o.iter()
                    .zip(&r)
                    .map(|(a, b)| (*a as f64) * (*b as f64))
                    .sum()
            };
            let x = Tensor::<4>::from_data(TensorData::new(base.clone(), shape), &device)
                .require_grad();
            let rt =
                Tensor::<4>::from_data(TensorData::new(r.clone(), [1, 2, out[0], out[1]]), &device);
            let loss = (resize_bilinear(x.clone(), out) * rt).sum();
            let grads = loss.backward();
            let g = values(x.grad(&grads).expect("gradient of x"));
            let eps = 1e-2f32;
            for i in 0..base.len() {
                let mut p = base.clone();
                p[i] += eps;
                let mut m = base.clone();
                m[i] -= eps;
                let fd = ((loss_of(&p) - loss_of(&m)) / (2.0 * eps as f64)) as f32;
                assert!(
                    (fd - g[i]).abs() < 1e-3,
                    "x[{i}]: analytic {} vs fd {fd}",
                    g[i]
                );
            }
        }
    }

    #[test]
    fn point_sampling_equals_full_upsampling() {
        let d = ndarray();
        let (c, mh, mw, h, w) = (3, 3, 5, 48, 80);
        let map = ramp([1, c, mh, mw], &d);
        let map_host = values(map.clone());
        let full = values(resize_bilinear(map, [h, w]));
        let points: Vec<(usize, usize)> = (0..h)
            .step_by(5)
            .flat_map(|y| (0..w).step_by(7).map(move |x| (x, y)))
            .chain([(0, 0), (w - 1, h - 1), (w - 1, 0), (0, h - 1)])
            .collect();
        let got = sample_bilinear_at(&map_host, [c, mh, mw], [h, w], &points).expect("valid input");
        for (k, &(x, y)) in points.iter().enumerate() {
            for ch in 0..c {
                let want = full[ch * h * w + y * w + x];
                let v = got[k * c + ch];
                assert!((v - want).abs() <= 1e-6, "({x},{y}) ch {ch}: {v} vs {want}");
            }
        }
        assert_eq!(
            sample_bilinear_at(&map_host, [c, mh, mw], [h, w], &[(w, 0)]),
            Err(SampleError::PointOutside {
                x: w,
                y: 0,
                width: w,
                height: h
            })
        );
        assert!(matches!(
            sample_bilinear_at(&map_host[1..], [c, mh, mw], [h, w], &[]),
            Err(SampleError::MapSize { .. })
        ));
        // Channels last: the same values bit for bit, the same errors.
        let mut last = vec![0.0f32; map_host.len()];
        for (i, &v) in map_host.iter().enumerate() {
            let (ch, px) = (i / (mh * mw), i % (mh * mw));
            last[px * c + ch] = v;
        }
        let nhwc =
            |m: &[f32], p: &[(usize, usize)]| sample_bilinear_at_nhwc(m, [c, mh, mw], [h, w], p);
        assert_eq!(nhwc(&last, &points), Ok(got));
        assert_eq!(
            nhwc(&last, &[(0, h)]),
            Err(SampleError::PointOutside {
                x: 0,
                y: h,
                width: w,
                height: h
            })
        );
        assert!(matches!(
            nhwc(&last[1..], &[]),
            Err(SampleError::MapSize { .. })
        ));
    }
}
