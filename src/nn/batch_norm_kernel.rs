//! Batch normalisation in training mode (SDFCNN's encoder: one after each of its 52
//! convolutions) in two passes forward and two backward on the CPU backends: a Burn backend
//! extension beside [`super::pool_kernel`].
//!
//! Burn 0.22.1's default `batch_norm_train` and its backward are a dozen composite ops each:
//! channel-first transposes that the next reshape copies element by element, a mean, a
//! centred square, a second mean, the normalisation, and for the gradient four more
//! reductions and five element-wise passes (a fifth of SDFCNN's train step on ndarray,
//! `perf`). Here the per-channel sums are taken in place (parallel over channels, sixteen
//! running `f32` sums per plane added up in `f64`, the variance from the centred values as
//! Burn computes it), then one pass over the planes applies them. The statistics and the
//! semantics are Burn's: biased variance, `ε` inside the square root; the running statistics
//! are updated by [`batch_norm`] exactly as `BatchNorm::forward` updates them.

// burn-ndarray is deprecated upstream but is this crate's default backend.
#![allow(deprecated)]

use super::backend::is_cpu;
use super::conv::{OpImpl, op_impl};
use super::nhwc::{simd_fn, sum_lanes};
use super::pool_kernel::{read, tensor, values};
use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{
    AutodiffBackend, Backend, Dispatch, Flex, NdArray, TensorMetadata, backend_extension,
};
use burn::nn::BatchNorm;
use burn::prelude::*;
use rayon::prelude::*;

/// The extension: `x` (`[N, C, ...]`) normalised with its batch statistics, scaled by `gamma`
/// and shifted by `beta`; with the per-channel mean and (biased) variance.
#[backend_extension(Flex, NdArray, Autodiff)]
pub(crate) trait BatchNormTrainOps: Backend {
    /// Returns `(output, mean, variance)`, the statistics per channel (`[C]`), `epsilon` inside
    /// the square root.
    fn batch_norm_train_fused(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>);
}

impl BatchNormTrainOps for Flex {
    fn batch_norm_train_fused(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        forward::<Flex>(x, gamma, beta, epsilon)
    }
}

impl BatchNormTrainOps for NdArray {
    fn batch_norm_train_fused(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        forward::<NdArray>(x, gamma, beta, epsilon)
    }
}

impl<B: Backend, C: CheckpointStrategy> BatchNormTrainOps for Autodiff<B, C> {
    fn batch_norm_train_fused(
        x: FloatTensor<Self>,
        gamma: FloatTensor<Self>,
        beta: FloatTensor<Self>,
        epsilon: f64,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        #[derive(Debug)]
        struct BatchNormTrain;

        impl<B: Backend> Backward<B, 3> for BatchNormTrain {
            /// The input, γ, the batch mean and variance, ε.
            type State = (
                FloatTensor<B>,
                FloatTensor<B>,
                FloatTensor<B>,
                FloatTensor<B>,
                f64,
            );

            fn backward(
                self,
                ops: Ops<Self::State, 3>,
                grads: &mut Gradients,
                _checkpointer: &mut Checkpointer,
            ) {
                let [x_node, gamma_node, beta_node] = ops.parents;
                let grad = grads.consume::<B>(&ops.node);
                let (x, gamma, mean, var, epsilon) = ops.state;
                let [gx, ggamma, gbeta] = backward::<B>(x, gamma, mean, var, epsilon, grad);
                for (node, g) in [(x_node, gx), (gamma_node, ggamma), (beta_node, gbeta)] {
                    if let Some(node) = node {
                        grads.register::<B>(node.id, g);
                    }
                }
            }
        }

        let guards = [x.node(), gamma.node(), beta.node()];
        let (x, gamma, beta) = (
            x.into_primitive(),
            gamma.into_primitive(),
            beta.into_primitive(),
        );
        match BatchNormTrain
            .prepare::<C>(guards)
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => {
                let (out, mean, var) = forward::<B>(x.clone(), gamma.clone(), beta, epsilon);
                let state = (x, gamma, mean.clone(), var.clone(), epsilon);
                (
                    prep.finish(state, out),
                    Self::from_inner(mean),
                    Self::from_inner(var),
                )
            }
            OpsKind::UnTracked(prep) => {
                let (out, mean, var) = forward::<B>(x, gamma, beta, epsilon);
                (
                    prep.finish(out),
                    Self::from_inner(mean),
                    Self::from_inner(var),
                )
            }
        }
    }
}

/// `bn.forward(x)`: in training (autodiff device, `bn` not frozen) under [`OpImpl::Auto`],
/// on the CPU backends through the fused kernel and on the GPU backends through tensor ops
/// that reduce one axis at a time (width, height, batch; forward and backward), updating the
/// running statistics as Burn does; otherwise Burn's own.
pub fn batch_norm<const D: usize>(bn: &BatchNorm, x: Tensor<D>) -> Tensor<D> {
    let device = x.device();
    let training = op_impl() == OpImpl::Auto
        && device.is_autodiff()
        && bn.training.is_enabled()
        && D >= 2
        && x.dims()[1] == bn.gamma.dims()[0];
    if !training {
        return bn.forward(x);
    }
    if !is_cpu(&device) {
        if D != 4 {
            return bn.forward(x);
        }
        let dims = x.dims();
        let (out, mean, var) =
            batch_norm_staged(bn, x.reshape([dims[0], dims[1], dims[2], dims[3]]));
        update_running(bn, mean, var);
        return out.reshape(dims);
    }
    let (out, mean, var) = Dispatch::batch_norm_train_fused(
        x.into_dispatch(),
        bn.gamma.val().into_dispatch(),
        bn.beta.val().into_dispatch(),
        bn.epsilon,
    );
    let (mean, var) = (
        Tensor::<1>::from_dispatch(mean).detach(),
        Tensor::<1>::from_dispatch(var).detach(),
    );
    update_running(bn, mean, var);
    Tensor::from_dispatch(out)
}

/// Moves `bn`'s running statistics toward a batch's, as Burn's `BatchNorm` does.
fn update_running(bn: &BatchNorm, mean: Tensor<1>, var: Tensor<1>) {
    let device = mean.device();
    let momentum = bn.momentum;
    let update = |running: &burn::module::RunningState<Tensor<1>>, batch: Tensor<1>| {
        let value = running
            .value_sync()
            .to_device(&device)
            .mul_scalar(1.0 - momentum)
            .add(batch.mul_scalar(momentum));
        running.update(value.detach());
    };
    update(&bn.running_mean, mean.detach());
    update(&bn.running_var, var.detach());
}

/// Batch norm in training mode (biased variance, as Burn's) from tensor ops whose every
/// reduction runs over one axis at a time, forward (the statistics: width, then height, then
/// batch) and backward (each staged broadcast's gradient sums one axis). On Mesa's software
/// Vulkan, Burn's own batch norm takes its statistics in one pass over batch × height × width,
/// and a variance at the shape of SDFCNN's first layer (8 x 32 x 72 x 96, synthetic values;
/// a one-op check, not kept) came out 2.0e-6 from float64 where three stages give 1.3e-7
/// (flex: 9.6e-8); the whole training step's gradients were 6.5e-3 of the largest from float64
/// (flex: 1.6e-3; `tests/float64_step.rs`, 2026-12-07). One axis at a time also
/// keeps each reduction far below lavapipe's 65,535 iterations a loop.
/// Returns the output, the batch's mean and its variance.
pub(crate) fn batch_norm_staged(bn: &BatchNorm, x: Tensor<4>) -> (Tensor<4>, Tensor<1>, Tensor<1>) {
    let [n, c, h, w] = x.dims();
    let staged_mean = |t: Tensor<4>| t.mean_dim(3).mean_dim(2).mean_dim(0);
    // `[1, c, 1, 1]` to `[n, c, h, w]`, one axis at a time, so that its gradient is summed so.
    let broadcast = |t: Tensor<4>| {
        t.expand([1, c, 1, w])
            .expand([1, c, h, w])
            .expand([n, c, h, w])
    };
    let mean = staged_mean(x.clone());
    let centred = x - broadcast(mean.clone());
    let var = staged_mean(centred.clone().powi_scalar(2));
    let scale = bn.gamma.val().reshape([1, c, 1, 1]) / var.clone().add_scalar(bn.epsilon).sqrt();
    let out = centred * broadcast(scale) + broadcast(bn.beta.val().reshape([1, c, 1, 1]));
    (out, mean.reshape([c]), var.reshape([c]))
}

simd_fn! {
    /// `Σ v` of one plane.
    fn plane_sum(v: &[f32], out: &mut f64) {
        *out = f64::from(sum_lanes(v));
    }
}

simd_fn! {
    /// `Σ (v − mean)²` of one plane in sixteen running sums.
    fn centred_squares(v: &[f32], mean: f32, out: &mut f64) {
        const LANES: usize = 16;
        let mut q = [0.0f32; LANES];
        let chunks = v.chunks_exact(LANES);
        let tail: f32 = chunks.remainder().iter().map(|&x| (x - mean) * (x - mean)).sum();
        for c in chunks {
            for i in 0..LANES {
                q[i] += (c[i] - mean) * (c[i] - mean);
            }
        }
        *out = f64::from(q.iter().sum::<f32>() + tail);
    }
}

simd_fn! {
    /// `(Σ g, Σ g·(x − mean))` of one plane in sixteen running sums.
    fn grad_sums(g: &[f32], x: &[f32], mean: f32, out: &mut [f64; 2]) {
        const LANES: usize = 16;
        let (mut s, mut q) = ([0.0f32; LANES], [0.0f32; LANES]);
        let (cg, cx) = (g.chunks_exact(LANES), x.chunks_exact(LANES));
        let (mut ts, mut tq) = (0.0f32, 0.0f32);
        for (&g, &x) in cg.remainder().iter().zip(cx.remainder()) {
            ts += g;
            tq += g * (x - mean);
        }
        for (g, x) in cg.zip(cx) {
            for i in 0..LANES {
                s[i] += g[i];
                q[i] += g[i] * (x[i] - mean);
            }
        }
        out[0] = f64::from(s.iter().sum::<f32>() + ts);
        out[1] = f64::from(q.iter().sum::<f32>() + tq);
    }
}

simd_fn! {
    /// `out[i] = a·v[i] + b`.
    fn affine(v: &mut [f32], a: f32, b: f32) {
        for x in v.iter_mut() {
            *x = a * *x + b;
        }
    }
}

simd_fn! {
    /// `g[i] = a·g[i] + b·x[i] + c` (the input gradient, affine in `g` and `x`).
    fn input_grad(g: &mut [f32], x: &[f32], a: f32, b: f32, c: f32) {
        for (g, &x) in g.iter_mut().zip(x) {
            *g = a * *g + b * x + c;
        }
    }
}

/// `[N, C, plane]` sizes of `shape`.
fn layout(shape: &[usize]) -> (usize, usize, usize) {
    let (n, c) = (shape[0], shape[1]);
    (n, c, shape[2..].iter().product())
}

/// Per channel, the sum over the `n` planes of `f(plane index)` (two sums).
fn per_channel(n: usize, c: usize, f: impl Fn(usize) -> [f64; 2] + Sync) -> Vec<[f64; 2]> {
    (0..c)
        .into_par_iter()
        .map(|ch| {
            (0..n).fold([0.0, 0.0], |acc, b| {
                let s = f(b * c + ch);
                [acc[0] + s[0], acc[1] + s[1]]
            })
        })
        .collect()
}

/// Normalised `x`, the batch mean and the biased batch variance.
fn forward<B: Backend>(
    x: FloatTensor<B>,
    gamma: FloatTensor<B>,
    beta: FloatTensor<B>,
    epsilon: f64,
) -> (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>) {
    let device = x.device();
    let (mut v, shape, dtype) = values::<B>(x);
    let (gamma, _, _) = values::<B>(gamma);
    let (beta, _, _) = values::<B>(beta);
    let (n, c, plane) = layout(&shape);
    let count = (n * plane).max(1) as f64;
    // The mean first, then the centred squares around it (as Burn's two means).
    let plane_of = |p: usize| &v[p * plane..(p + 1) * plane];
    let sums = per_channel(n, c, |p| {
        let mut s = [0.0; 2];
        plane_sum(plane_of(p), &mut s[0]);
        s
    });
    let mean: Vec<f32> = sums.iter().map(|s| (s[0] / count) as f32).collect();
    let sums = per_channel(n, c, |p| {
        let mut s = [0.0; 2];
        centred_squares(plane_of(p), mean[p % c], &mut s[0]);
        s
    });
    let var: Vec<f32> = sums.iter().map(|s| (s[0] / count) as f32).collect();
    if plane > 0 {
        v.par_chunks_mut(plane).enumerate().for_each(|(p, v)| {
            let ch = p % c;
            let a = gamma[ch] / (f64::from(var[ch]) + epsilon).sqrt() as f32;
            affine(v, a, beta[ch] - a * mean[ch]);
        });
    }
    (
        tensor::<B>(v, shape, dtype, &device),
        tensor::<B>(mean, vec![c], dtype, &device),
        tensor::<B>(var, vec![c], dtype, &device),
    )
}

/// Gradients of the input, γ and β:
/// `dβ = Σ g`, `dγ = Σ g·x̂`, `dx = γ/σ · (g − dβ/M − x̂·dγ/M)` with `x̂ = (x − μ)/σ`.
fn backward<B: Backend>(
    x: FloatTensor<B>,
    gamma: FloatTensor<B>,
    mean: FloatTensor<B>,
    var: FloatTensor<B>,
    epsilon: f64,
    grad: FloatTensor<B>,
) -> [FloatTensor<B>; 3] {
    let device = x.device();
    let (x, shape, dtype) = read::<B>(x);
    let (gamma, _, p_dtype) = read::<B>(gamma);
    let (mean, _, _) = read::<B>(mean);
    let (var, _, _) = read::<B>(var);
    let (x, gamma, mean, var) = (
        x.as_slice(),
        gamma.as_slice(),
        mean.as_slice(),
        var.as_slice(),
    );
    let (mut g, _, _) = values::<B>(grad);
    let (n, c, plane) = layout(&shape);
    let count = (n * plane).max(1) as f64;
    let sums = per_channel(n, c, |p| {
        let r = p * plane..(p + 1) * plane;
        let mut s = [0.0; 2];
        grad_sums(&g[r.clone()], &x[r], mean[p % c], &mut s);
        s
    });
    let inv_std: Vec<f64> = var
        .iter()
        .map(|&v| 1.0 / (f64::from(v) + epsilon).sqrt())
        .collect();
    let gbeta: Vec<f32> = sums.iter().map(|s| s[0] as f32).collect();
    // Σ g·x̂ = Σ g·(x − μ) / σ.
    let ggamma: Vec<f32> = sums
        .iter()
        .zip(&inv_std)
        .map(|(s, i)| (s[1] * i) as f32)
        .collect();
    if plane > 0 {
        g.par_chunks_mut(plane)
            .zip(x.par_chunks(plane))
            .enumerate()
            .for_each(|(p, (g, x))| {
                let ch = p % c;
                let (s, i) = (sums[ch], inv_std[ch]);
                let scale = f64::from(gamma[ch]) * i;
                // x̂·dγ/M = (x − μ)·i²·Σ g(x − μ)/M.
                let b = -scale * i * i * s[1] / count;
                let c0 = -scale * s[0] / count - b * f64::from(mean[ch]);
                input_grad(g, x, scale as f32, b as f32, c0 as f32);
            });
    }
    [
        tensor::<B>(g, shape, dtype, &device),
        tensor::<B>(ggamma, vec![c], p_dtype, &device),
        tensor::<B>(gbeta, vec![c], p_dtype, &device),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::BatchNormConfig;
    use burn::tensor::Distribution;

    fn vals<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap()
    }

    fn assert_close(what: &str, got: &[f32], want: &[f32]) {
        assert_eq!(got.len(), want.len(), "{what}");
        let scale = want.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            assert!((g - w).abs() <= 1e-4 * scale, "{what}[{i}]: {g} vs {w}");
        }
    }

    /// Which batch norm [`run`] takes.
    #[derive(Debug, Clone, Copy)]
    enum Path {
        Burn,
        /// [`batch_norm`]: the fused kernel on the CPU backends.
        Fused,
        /// [`batch_norm_staged`], the GPU backends' path, here on a CPU backend.
        Staged,
    }

    /// Output, gradients of x, γ, β and the updated running statistics, with Burn's batch
    /// norm, [`batch_norm`] or [`batch_norm_staged`], on `device`.
    fn run(device: &Device, path: Path, x: &Tensor<4>, up: &Tensor<4>) -> Vec<Vec<f32>> {
        let device = device.clone().autodiff();
        let mut bn = BatchNormConfig::new(x.dims()[1])
            .with_momentum(0.3)
            .init(&device);
        let [c] = bn.gamma.dims();
        let param = |seed: f32| {
            let v: Vec<f32> = (0..c).map(|i| seed + 0.37 * i as f32).collect();
            Tensor::<1>::from_data(TensorData::new(v, [c]), &device)
        };
        bn.gamma = burn::module::Param::from_tensor(param(0.5));
        bn.beta = burn::module::Param::from_tensor(param(-0.2));
        let x = Tensor::<4>::from_data(x.to_data(), &device).require_grad();
        let up = Tensor::<4>::from_data(up.to_data(), &device);
        let y = match path {
            Path::Burn => bn.forward(x.clone()),
            Path::Fused => batch_norm(&bn, x.clone()),
            Path::Staged => {
                let (y, mean, var) = batch_norm_staged(&bn, x.clone());
                update_running(&bn, mean, var);
                y
            }
        };
        let grads = (y.clone() * up).sum().backward();
        vec![
            vals(y),
            vals(x.grad(&grads).unwrap()),
            vals(bn.gamma.grad(&grads).unwrap()),
            vals(bn.beta.grad(&grads).unwrap()),
            vals(bn.running_mean.value()),
            vals(bn.running_var.value()),
        ]
    }

    #[test]
    fn matches_burns_batch_norm_values_gradients_and_running_statistics() {
        let reference = Device::ndarray();
        for shape in [[2, 3, 5, 7], [4, 5, 1, 1], [1, 2, 17, 19], [3, 4, 4, 20]] {
            // An offset mean, so that the centring matters.
            let x = Tensor::<4>::random(shape, Distribution::Uniform(2.0, 5.0), &reference);
            let up = Tensor::<4>::random(shape, Distribution::Uniform(-1.0, 1.0), &reference);
            let want = run(&reference, Path::Burn, &x, &up);
            for (device, path) in [
                (Device::ndarray(), Path::Fused),
                (Device::flex(), Path::Fused),
                (Device::ndarray(), Path::Staged),
                (Device::flex(), Path::Staged),
            ] {
                let got = run(&device, path, &x, &up);
                let names = [
                    "output",
                    "d x",
                    "d gamma",
                    "d beta",
                    "running mean",
                    "running var",
                ];
                for ((name, g), w) in names.iter().zip(&got).zip(&want) {
                    assert_close(&format!("{shape:?} {name}, {path:?} on {device:?}"), g, w);
                }
            }
        }
    }

    #[test]
    fn frozen_or_inference_takes_burns_path() {
        let d = Device::flex();
        let bn = BatchNormConfig::new(3).init(&d);
        let x = Tensor::<4>::random([2, 3, 4, 5], Distribution::Default, &d);
        // No autodiff: running statistics used, left alone.
        assert_eq!(vals(batch_norm(&bn, x.clone())), vals(bn.forward(x)));
        assert_eq!(vals(bn.running_mean.value()), vec![0.0; 3]);
    }
}
