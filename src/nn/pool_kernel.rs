//! A stride-1 "same" max pool (odd `k×k` window, `k/2` padding) with its own backward pass,
//! as a Burn backend extension on the CPU backends: SDFCNN's chained residual pooling (5×5,
//! sixteen times per forward pass) when training.
//!
//! Burn's pool with autodiff keeps an `i64` index per output and visits all `k²` taps; the
//! shifted slices of [`super::pool::max_pool2d_shifted`] allocate a zero tensor per slice in
//! their backward. Here the window maximum is taken along rows, then along columns (`2k`
//! comparisons), the winning tap is kept as one byte (its offset in the window), and the
//! backward pass scatters the output gradient through those bytes. Ties go to the first
//! maximum in row-major order, as Burn's kernels choose. A NaN wins its window (the first NaN
//! in row-major order gets the gradient; burn-flex's pool picks the last one, burn-ndarray's
//! skips NaNs), and the arithmetic is `f32` whatever the tensor's float type.

// burn-ndarray is deprecated upstream but is this crate's default backend.
#![allow(deprecated)]

use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind, unary};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, Flex, NdArray, TensorMetadata, backend_extension};
use burn::prelude::*;
use burn::tensor::{DType, TensorData};

use super::nhwc::simd_fn;
use rayon::prelude::*;

/// The largest window: offsets in a `k×k` window must fit a byte.
pub(crate) const MAX_KERNEL: usize = 15;

/// The extension: `x` (`[N, C, H, W]`) max-pooled over `kernel × kernel` windows, stride 1,
/// padding `kernel / 2` (padding never wins).
#[backend_extension(Flex, NdArray, Autodiff)]
pub(crate) trait SamePoolOps: Backend {
    /// Max-pools `x` over `kernel × kernel` windows, output the same size as the input.
    fn max_pool_same(x: FloatTensor<Self>, kernel: usize) -> FloatTensor<Self>;
}

impl SamePoolOps for Flex {
    fn max_pool_same(x: FloatTensor<Self>, kernel: usize) -> FloatTensor<Self> {
        forward::<Flex>(x, kernel).0
    }
}

impl SamePoolOps for NdArray {
    fn max_pool_same(x: FloatTensor<Self>, kernel: usize) -> FloatTensor<Self> {
        forward::<NdArray>(x, kernel).0
    }
}

impl<B: Backend, C: CheckpointStrategy> SamePoolOps for Autodiff<B, C> {
    fn max_pool_same(x: FloatTensor<Self>, kernel: usize) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct MaxPoolSame;

        impl<B: Backend> Backward<B, 1> for MaxPoolSame {
            /// The winning tap of every output and the window side.
            type State = (Vec<u8>, usize);

            fn backward(
                self,
                ops: Ops<Self::State, 1>,
                grads: &mut Gradients,
                _checkpointer: &mut Checkpointer,
            ) {
                let (offsets, kernel) = ops.state;
                unary::<B, _>(ops.parents, ops.node, grads, |grad| {
                    backward::<B>(grad, &offsets, kernel)
                });
            }
        }

        let guard = x.node();
        let (out, offsets) = forward::<B>(x.into_primitive(), kernel);
        match MaxPoolSame.prepare::<C>([guard]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => prep.finish((offsets, kernel), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }
}

/// `x` max-pooled over `kernel × kernel` windows (odd, at most [`MAX_KERNEL`]), stride 1,
/// padding `kernel / 2`, with autodiff where `x` has it; on the CPU backends only.
///
/// # Panics
/// On a kernel that is even or larger than [`MAX_KERNEL`], or a GPU tensor.
pub(crate) fn max_pool2d_same(x: Tensor<4>, kernel: usize) -> Tensor<4> {
    assert!(
        kernel % 2 == 1 && kernel <= MAX_KERNEL,
        "max_pool2d_same: kernel {kernel} must be odd and at most {MAX_KERNEL}"
    );
    Tensor::from_dispatch(Dispatch::max_pool_same(x.into_dispatch(), kernel))
}

/// Waits for a future that a CPU backend has already completed.
pub(super) fn ready<T>(future: impl std::future::Future<Output = T>) -> T {
    let mut future = std::pin::pin!(future);
    let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
    loop {
        if let std::task::Poll::Ready(v) = future.as_mut().poll(&mut cx) {
            return v;
        }
        std::thread::yield_now();
    }
}

/// The tensor's values as `f32`, its shape and its dtype.
pub(super) fn values<B: Backend>(t: FloatTensor<B>) -> (Vec<f32>, Vec<usize>, DType) {
    let shape = t.shape().to_vec();
    let dtype = t.dtype();
    if let Some(v) = shared_values(&t) {
        return (v, shape, dtype);
    }
    let data = ready(B::float_into_data(t)).expect("a CPU tensor reads back");
    let v = data
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("converted to f32");
    (v, shape, dtype)
}

/// A tensor's `f32` values for a kernel that only reads them: borrowed from the tensor's own
/// buffer where it is a contiguous `f32` tensor of burn-flex or burn-ndarray (no copy), as
/// [`values`] gives them otherwise.
pub(super) enum Values<B: Backend> {
    /// The tensor itself, whose buffer [`borrowed`] reads.
    Borrowed(FloatTensor<B>),
    /// A copy (or the moved buffer).
    Owned(Vec<f32>),
}

impl<B: Backend> Values<B> {
    /// The values, row-major.
    pub(super) fn as_slice(&self) -> &[f32] {
        match self {
            // `read` made it only where `borrowed` gives the buffer, and tensors do not change.
            Self::Borrowed(t) => borrowed(t).unwrap_or_default(),
            Self::Owned(v) => v,
        }
    }
}

/// [`Values`] of `t`, its shape and its dtype.
pub(super) fn read<B: Backend>(t: FloatTensor<B>) -> (Values<B>, Vec<usize>, DType) {
    if borrowed(&t).is_some() {
        let (shape, dtype) = (t.shape().to_vec(), t.dtype());
        return (Values::Borrowed(t), shape, dtype);
    }
    let (v, shape, dtype) = values::<B>(t);
    (Values::Owned(v), shape, dtype)
}

/// The buffer of a contiguous `f32` burn-flex or burn-ndarray tensor; `None` for anything else.
fn borrowed<T: 'static>(t: &T) -> Option<&[f32]> {
    use burn::backend::flex::FlexTensor;
    use burn::backend::ndarray::NdArrayTensor;
    let any = t as &dyn std::any::Any;
    if let Some(t) = any.downcast_ref::<FlexTensor>() {
        return t.as_slice::<f32>();
    }
    match any.downcast_ref::<NdArrayTensor>()? {
        NdArrayTensor::F32(storage) => storage.view().to_slice(),
        _ => None,
    }
}

/// A copy of a contiguous `f32` burn-flex or burn-ndarray tensor whose buffer is shared (kept
/// for a backward pass or by another op), taken from [`borrowed`]'s slice. burn-ndarray
/// 0.22.1's `into_data` moves a buffer it owns alone but reads a shared one element by element
/// through a dynamic-rank iterator: a fifth of SDFCNN's train step on ndarray (`perf`).
/// `None` for a buffer the tensor owns alone (`into_data` moves it) and for anything else.
fn shared_values<T: 'static>(t: &T) -> Option<Vec<f32>> {
    use burn::backend::flex::FlexTensor;
    use burn::backend::ndarray::NdArrayTensor;
    let any = t as &dyn std::any::Any;
    let unique = match (
        any.downcast_ref::<FlexTensor>(),
        any.downcast_ref::<NdArrayTensor>(),
    ) {
        (Some(t), _) => t.is_unique(),
        (_, Some(NdArrayTensor::F32(storage))) => storage.is_unique(),
        _ => return None,
    };
    if unique {
        return None;
    }
    borrowed(t).map(<[f32]>::to_vec)
}

pub(super) fn tensor<B: Backend>(
    v: Vec<f32>,
    shape: Vec<usize>,
    dtype: DType,
    device: &B::Device,
) -> FloatTensor<B> {
    B::float_from_data(TensorData::new(v, shape).convert_dtype(dtype), device)
}

/// The pooled tensor and the winning tap of every output (`dy · k + dx` in its window).
fn forward<B: Backend>(x: FloatTensor<B>, k: usize) -> (FloatTensor<B>, Vec<u8>) {
    let device = x.device();
    let (x, shape, dtype) = read::<B>(x);
    let x = x.as_slice();
    let [h, w] = [shape[2], shape[3]];
    let plane = h * w;
    let mut out = vec![0.0f32; x.len()];
    let mut offsets = vec![0u8; x.len()];
    if plane > 0 {
        out.par_chunks_mut(plane)
            .zip(offsets.par_chunks_mut(plane))
            .zip(x.par_chunks(plane))
            .for_each(|((out, offsets), x)| pool_plane_fastest(x, [h, w], k, out, offsets));
    }
    (tensor::<B>(out, shape, dtype, &device), offsets)
}

/// The input gradient: each output's gradient added at its winning tap.
fn backward<B: Backend>(grad: FloatTensor<B>, offsets: &[u8], k: usize) -> FloatTensor<B> {
    let device = grad.device();
    let (g, shape, dtype) = values::<B>(grad);
    let [h, w] = [shape[2], shape[3]];
    let (plane, p) = (h * w, k / 2);
    let mut gin = vec![0.0f32; g.len()];
    if plane > 0 {
        gin.par_chunks_mut(plane)
            .zip(g.par_chunks(plane))
            .zip(offsets.par_chunks(plane))
            .for_each(|((gin, g), offsets)| {
                for y in 0..h {
                    for x in 0..w {
                        let i = y * w + x;
                        let o = offsets[i] as usize;
                        let (yy, xx) = (y + o / k - p, x + o % k - p);
                        gin[yy * w + xx] += g[i];
                    }
                }
            });
    }
    tensor::<B>(gin, shape, dtype, &device)
}

/// [`pool_plane`], through the AVX2 kernel (`super::pool_avx2`) on a NaN-free plane where
/// the CPU has AVX2.
fn pool_plane_fastest(x: &[f32], hw: [usize; 2], k: usize, out: &mut [f32], offsets: &mut [u8]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && !x.iter().any(|v| v.is_nan()) {
        // SAFETY: the CPU has AVX2; the planes hold h·w values and k is odd and at most
        // MAX_KERNEL = 15 (`max_pool2d_same`).
        unsafe { super::pool_avx2::pool_plane(x, hw, k, out, offsets) };
        return;
    }
    pool_plane(x, hw, k, out, offsets)
}

/// Whether `v` replaces the running maximum `m` (strictly greater; a NaN wins once).
#[inline(always)]
fn wins(v: f32, m: f32) -> bool {
    v > m || (v.is_nan() && !m.is_nan())
}

simd_fn! {
    /// One `h × w` plane: row maxima with their tap, then column maxima of those. Every pass
    /// runs over contiguous columns with selects instead of branches, so it vectorises; the
    /// taps are carried as `u32`, as wide as the values, and a plane without a NaN compares
    /// with a plain `>` (with `u8` taps and the NaN rule everywhere the column pass stayed
    /// scalar: 17-18 % of `perf` samples of `bench --case sdfcnn-train --backend ndarray`, now
    /// 12-13 %; 2026-12-07).
    fn pool_plane(x: &[f32], hw: [usize; 2], k: usize, out: &mut [f32], offsets: &mut [u8]) {
        if x.iter().any(|v| v.is_nan()) {
            pool_plane_with(x, hw, k, out, offsets, wins)
        } else {
            pool_plane_with(x, hw, k, out, offsets, |v, m| v > m)
        }
    }
}

/// [`pool_plane`] with `wins` deciding whether a value replaces the running maximum.
#[inline(always)]
fn pool_plane_with(
    x: &[f32],
    hw: [usize; 2],
    k: usize,
    out: &mut [f32],
    offsets: &mut [u8],
    wins: impl Fn(f32, f32) -> bool + Copy,
) {
    let [h, w] = hw;
    let p = k / 2;
    let mut row_max = vec![f32::NEG_INFINITY; h * w];
    let mut row_arg = vec![0u32; h * w];
    for y in 0..h {
        let row = &x[y * w..(y + 1) * w];
        let m = &mut row_max[y * w..(y + 1) * w];
        let a = &mut row_arg[y * w..(y + 1) * w];
        // Each column starts at its first tap inside the row (−∞ loses to everything but
        // −∞, which then keeps that first tap).
        for (c, a) in a.iter_mut().enumerate().take(p) {
            *a = (p - c) as u32;
        }
        // Tap d reads column c + d − p for the columns where that is inside the row.
        for d in 0..k {
            let lo = p.saturating_sub(d);
            let hi = (w + p).saturating_sub(d).min(w);
            if lo >= hi {
                continue;
            }
            let src = &row[lo + d - p..hi + d - p];
            for ((m, a), &v) in m[lo..hi].iter_mut().zip(&mut a[lo..hi]).zip(src) {
                let win = wins(v, *m);
                *m = if win { v } else { *m };
                *a = if win { d as u32 } else { *a };
            }
        }
    }
    let mut arg = vec![0u32; w];
    for y in 0..h {
        let (lo, hi) = (y.saturating_sub(p), (y + p).min(h - 1));
        let out = &mut out[y * w..(y + 1) * w];
        out.copy_from_slice(&row_max[lo * w..(lo + 1) * w]);
        let base = ((lo + p - y) * k) as u32;
        for (o, &a) in arg.iter_mut().zip(&row_arg[lo * w..(lo + 1) * w]) {
            *o = base + a;
        }
        for yy in lo + 1..=hi {
            let r = &row_max[yy * w..(yy + 1) * w];
            let ra = &row_arg[yy * w..(yy + 1) * w];
            let base = ((yy + p - y) * k) as u32;
            for (((o, off), &v), &a) in out.iter_mut().zip(arg.iter_mut()).zip(r).zip(ra) {
                let win = wins(v, *o);
                *o = if win { v } else { *o };
                *off = if win { base + a } else { *off };
            }
        }
        // k ≤ MAX_KERNEL (`max_pool2d_same`), so every tap index, below k², fits a byte.
        for (o, &a) in offsets[y * w..(y + 1) * w].iter_mut().zip(&arg) {
            *o = a as u8;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::pool::tests::{run, values as values_of};
    use burn::tensor::Distribution;
    use burn::tensor::module::max_pool2d;
    use burn::tensor::ops::MaxPoolOptions;

    #[test]
    #[allow(deprecated)]
    fn matches_burn_values_and_gradients_ties_included() {
        let reference = Device::ndarray();
        for device in [Device::ndarray(), Device::flex()] {
            for (shape, k) in [
                ([2, 3, 7, 9], 5),
                ([1, 2, 4, 3], 5),
                ([2, 2, 6, 5], 3),
                ([1, 1, 1, 1], 5),
                // Rows and columns wide enough for whole vectors and a remainder.
                ([1, 2, 11, 29], 5),
                ([2, 1, 9, 20], 3),
                ([1, 1, 5, 19], 7),
            ] {
                let x = Tensor::<4>::random(shape, Distribution::Uniform(-1.0, 1.0), &reference);
                // After a ReLU most values are 0: whole windows tie.
                for x in [x.clone(), burn::tensor::activation::relu(x)] {
                    let up =
                        Tensor::<4>::random(shape, Distribution::Uniform(0.5, 1.5), &reference);
                    let options = MaxPoolOptions::new([k, k])
                        .with_stride([1, 1])
                        .with_padding([k / 2, k / 2]);
                    let want = run(&reference, &x, &up, |x| max_pool2d(x, options.clone()));
                    let got = run(&device, &x, &up, |x| max_pool2d_same(x, k));
                    assert_eq!(got, want, "{shape:?} k {k}");
                }
            }
        }
    }

    #[test]
    fn the_avx2_plane_pass_equals_the_portable_one_bit_for_bit() {
        use rand::{RngExt, SeedableRng};
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            let mut rng = rand::rngs::StdRng::seed_from_u64(7);
            // Planes narrower than a vector and than the window, and wide ones with remainders;
            // small integers (ties everywhere) and −∞.
            for (h, w, k) in [
                (1, 1, 5),
                (3, 2, 5),
                (2, 7, 5),
                (5, 8, 5),
                (6, 12, 5),
                (9, 13, 5),
                (7, 21, 3),
                (11, 37, 7),
                (4, 100, 5),
                (3, 30, 15),
            ] {
                for levels in [3, 1000] {
                    let x: Vec<f32> = (0..h * w)
                        .map(|_| match rng.random_range(0..levels + 1) {
                            0 => f32::NEG_INFINITY,
                            v => v as f32,
                        })
                        .collect();
                    let (mut out, mut off) = (vec![0.0; h * w], vec![0u8; h * w]);
                    let (mut want, mut want_off) = (vec![0.0; h * w], vec![0u8; h * w]);
                    // SAFETY: AVX2 checked above; sizes as the kernel asks.
                    unsafe {
                        super::super::pool_avx2::pool_plane(&x, [h, w], k, &mut out, &mut off)
                    };
                    pool_plane(&x, [h, w], k, &mut want, &mut want_off);
                    assert_eq!(off, want_off, "{h}x{w} k {k}: taps");
                    let bits = |v: &[f32]| v.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                    assert_eq!(bits(&out), bits(&want), "{h}x{w} k {k}: values");
                }
            }
        }
    }

    #[test]
    #[allow(deprecated)]
    fn a_nan_wins_its_window_and_takes_the_gradient() {
        // Channel 0 holds a NaN at its centre and a second one at the last corner; channel 1
        // none (the fast path).
        let mut v: Vec<f32> = (0..18).map(|i| (i % 7) as f32).collect();
        v[4] = f32::NAN;
        v[8] = f32::NAN;
        for device in [Device::ndarray(), Device::flex()] {
            let x = Tensor::<4>::from_data(TensorData::new(v.clone(), [1, 2, 3, 3]), &device);
            let up = Tensor::<4>::ones([1, 2, 3, 3], &device);
            let [y, g] = run(&device, &x, &up, |x| max_pool2d_same(x, 3));
            assert!(y[..9].iter().all(|v| v.is_nan()), "{y:?}");
            // The first NaN in row-major order of each window: the centre's, in every one.
            assert_eq!(&g[..9], &[0., 0., 0., 0., 9., 0., 0., 0., 0.]);
            let plain: Vec<f32> = v[9..].to_vec();
            assert_eq!(y[9..], [6., 6., 6., 6., 6., 6., 6., 6., 6.], "{plain:?}");
            assert_eq!(g[9..].iter().sum::<f32>(), 9.0);
        }
    }

    #[test]
    #[allow(deprecated)]
    fn works_without_autodiff() {
        let d = Device::flex();
        let x = Tensor::<4>::random([1, 2, 5, 6], Distribution::Default, &d);
        let options = MaxPoolOptions::new([5, 5])
            .with_stride([1, 1])
            .with_padding([2, 2]);
        assert_eq!(
            values_of(max_pool2d_same(x.clone(), 5)),
            values_of(max_pool2d(x, options))
        );
    }
}
