//! Stride-1 max pooling as a running maximum over shifted slices.
//!
//! # Why this exists
//!
//! SDFCNN's chained residual pooling applies a 5×5 stride-1 max pool sixteen times, on up to
//! 256×75×100 maps. burn-ndarray 0.22.1 pools with scalar loops: with autodiff it takes
//! `max_pool2d_with_indices`, which visits all 25 taps of every output through bounds-checked
//! 4-D indexing, and inference takes a window loop that is not much faster. That made pooling
//! about a third of an SDFCNN training step on ndarray.
//!
//! `max_pool2d_shifted` computes the same pooling from `max_pair` of slices: the padded input
//! is flattened to `[N, C, Hp·Wp]`, a window of `k` along a row is a maximum over shifts by
//! `0..k`, and along a column over shifts by multiples of `Wp`, so every slice is a long
//! contiguous run. Each 1-D window maximum is built by doubling (`k = 5`: `max(x, x≫1)`, then
//! `≫2`, then an overlapping `≫1`), three `max_pair`s per axis instead of four. Its autodiff
//! backward is masks and slice assignments.
//!
//! Training (autodiff on a CPU backend) takes `super::pool_kernel` instead, whose backward
//! allocates nothing per slice; the slices serve the CPU backends without autodiff (Burn's
//! SDFCNN path; the packed network pools in NHWC) and, on ndarray, windows the kernel does not
//! take.
//!
//! Ties: `max_pair` keeps its first operand when equal, every step pairs an earlier window with
//! a later one, and rows are reduced before columns, so the gradient goes to the first maximum
//! in row-major order — the tap burn-ndarray's pooling picks.

use burn::nn::pool::MaxPool2d;
use burn::prelude::*;
use burn::tensor::ops::PadMode;

use super::conv::{PoolPath, is_ndarray, padding_pairs, pool_path};
use super::pool_kernel::{MAX_KERNEL, max_pool2d_same};

/// `pool.forward(x)`, computed as `pool_path` says for `x`'s device when the pool has
/// stride 1, dilation 1 and no ceil mode (and, for `PoolPath::Kernel`, an odd square window
/// of at most `MAX_KERNEL` with `k/2` padding on every side); by Burn otherwise.
pub fn max_pool2d(pool: &MaxPool2d, x: Tensor<4>) -> Tensor<4> {
    let simple = pool.stride == [1, 1] && pool.dilation == [1, 1] && !pool.ceil_mode;
    let path = pool_path(&x.device());
    if !simple || path == PoolPath::Burn {
        return pool.forward(x);
    }
    let [_, _, h, w] = x.dims();
    let padding = padding_pairs(&pool.padding, [h, w], pool.kernel_size, pool.stride);
    let [kh, kw] = pool.kernel_size;
    let same = kh == kw && kh % 2 == 1 && kh <= MAX_KERNEL && padding == [(kh / 2, kh / 2); 2];
    match path {
        PoolPath::Kernel if same => max_pool2d_same(x, kh),
        // Other windows in training: flex's own pool, ndarray's slices, as before the kernel.
        PoolPath::Kernel if !is_ndarray(&x.device()) => pool.forward(x),
        _ => max_pool2d_shifted(x, pool.kernel_size, padding),
    }
}

/// Stride-1, dilation-1 max pooling of `x` (`[N, C, H, W]`) with window `[kh, kw]` and
/// `((top, bottom), (left, right))` padding (padded positions never win), equal to
/// `burn::tensor::module::max_pool2d` with those options.
///
/// # Panics
/// If the window is empty or larger than the padded input, or a padding is not smaller than
/// the window (an all-padding window).
pub(crate) fn max_pool2d_shifted(
    x: Tensor<4>,
    [kh, kw]: [usize; 2],
    [(top, bottom), (left, right)]: [(usize, usize); 2],
) -> Tensor<4> {
    let [n, c, h, w] = x.dims();
    assert!(
        kh > 0 && kw > 0 && top.max(bottom) < kh && left.max(right) < kw,
        "max pool {kh}x{kw} with padding ({top}, {bottom}), ({left}, {right})"
    );
    let (hp, wp) = (h + top + bottom, w + left + right);
    assert!(
        hp >= kh && wp >= kw,
        "max pool {kh}x{kw} larger than {hp}x{wp}"
    );
    let (oh, ow) = (hp - kh + 1, wp - kw + 1);
    // One extra row of padding keeps `oh · wp` values after both window maxima, so the result
    // reshapes to `[oh, wp]` rows.
    let x = x.pad(
        [(top, bottom + 1), (left, right)],
        PadMode::Constant(f32::NEG_INFINITY),
    );
    let flat = x.reshape([n, c, (hp + 1) * wp]);
    let rows = window_max(flat, kw, 1);
    let both = window_max(rows, kh, wp);
    both.slice(s![.., .., 0..oh * wp])
        .reshape([n, c, oh, wp])
        .slice(s![.., .., .., 0..ow])
}

/// `out[i] = max_{a < k} t[i + a·step]` along the last axis (length `L − (k − 1)·step`), with
/// ties resolved to the smallest `a`.
fn window_max(t: Tensor<3>, k: usize, step: usize) -> Tensor<3> {
    let shifted = |t: &Tensor<3>, by: usize| {
        let len = t.dims()[2];
        let a = t.clone().slice(s![.., .., 0..len - by]);
        let b = t.clone().slice(s![.., .., by..len]);
        a.max_pair(b)
    };
    // `m[i]` is the maximum over `span` consecutive taps starting at `i`.
    let mut m = t;
    let mut span = 1;
    while span * 2 <= k {
        m = shifted(&m, span * step);
        span *= 2;
    }
    if span < k {
        // Overlapping windows [i, i + span) and [i + k − span, i + k) cover [i, i + k).
        m = shifted(&m, (k - span) * step);
    }
    m
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use burn::tensor::Distribution;
    use burn::tensor::module::max_pool2d as burn_max_pool2d;
    use burn::tensor::ops::MaxPoolOptions;

    #[allow(deprecated)]
    fn ndarray() -> Device {
        Device::ndarray()
    }

    pub(in crate::nn) fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().expect("f32 tensor")
    }

    /// Output and input gradient of `pool` (any op on a 4-D tensor) on the autodiff version of
    /// `device`.
    pub(in crate::nn) fn run(
        device: &Device,
        x: &Tensor<4>,
        upstream: &Tensor<4>,
        pool: impl Fn(Tensor<4>) -> Tensor<4>,
    ) -> [Vec<f32>; 2] {
        let device = device.clone().autodiff();
        let x = Tensor::<4>::from_data(x.to_data(), &device).require_grad();
        let up = Tensor::<4>::from_data(upstream.to_data(), &device);
        let y = pool(x.clone());
        let grads = (y.clone() * up).sum().backward();
        [values(y), values(x.grad(&grads).expect("input grad"))]
    }

    fn check(x: Tensor<4>, kernel: [usize; 2], padding: [(usize, usize); 2], device: &Device) {
        let [n, c, h, w] = x.dims();
        let oh = h + padding[0].0 + padding[0].1 + 1 - kernel[0];
        let ow = w + padding[1].0 + padding[1].1 + 1 - kernel[1];
        let up = Tensor::<4>::random([n, c, oh, ow], Distribution::Uniform(0.5, 1.5), &x.device());
        let options = MaxPoolOptions::new(kernel)
            .with_stride([1, 1])
            .with_padding_pairs(padding);
        let want = run(&ndarray(), &x, &up, |x| burn_max_pool2d(x, options.clone()));
        let got = run(device, &x, &up, |x| max_pool2d_shifted(x, kernel, padding));
        for (what, (g, e)) in ["output", "d input"].iter().zip(got.iter().zip(&want)) {
            assert_eq!(g.len(), e.len(), "{what} length");
            for (i, (a, b)) in g.iter().zip(e).enumerate() {
                assert!(
                    (a - b).abs() <= 1e-5 * b.abs().max(1.0),
                    "{what}[{i}]: {a} vs {b}"
                );
            }
        }
    }

    #[test]
    fn matches_burn_max_pool() {
        let d = Device::flex();
        for device in [ndarray(), Device::flex()] {
            for (shape, kernel, p) in [
                ([2, 3, 7, 9], [5, 5], 2), // SDFCNN's CRP pool, odd sizes
                ([2, 2, 6, 8], [3, 3], 1),
                ([1, 2, 5, 6], [2, 3], 0),
                ([2, 1, 4, 3], [5, 5], 2), // window larger than the map
            ] {
                let x = Tensor::<4>::random(shape, Distribution::Default, &d);
                check(x, kernel, [(p, p), (p, p)], &device);
            }
        }
    }

    #[test]
    fn ties_go_to_the_first_maximum_like_burn_ndarray() {
        // After a ReLU most values are 0: whole windows tie.
        let d = ndarray();
        let x = Tensor::<4>::random([2, 2, 6, 7], Distribution::Uniform(-1.0, 1.0), &d);
        let x = burn::tensor::activation::relu(x);
        check(x, [5, 5], [(2, 2), (2, 2)], &d);
        check(
            Tensor::zeros([1, 1, 4, 5], &d),
            [3, 3],
            [(1, 1), (1, 1)],
            &d,
        );
    }

    #[test]
    fn layer_wrapper_matches_forward() {
        let d = ndarray();
        let pool = burn::nn::pool::MaxPool2dConfig::new([5, 5])
            .with_strides([1, 1])
            .with_padding(burn::nn::PaddingConfig2d::Explicit(2, 2, 2, 2))
            .init();
        let x = Tensor::<4>::random([2, 3, 8, 9], Distribution::Default, &d);
        assert_eq!(
            values(max_pool2d(&pool, x.clone())),
            values(pool.forward(x))
        );
    }
}
