//! ELU (Table 12, footnote 1: `x` for `x > 0`, `a(eˣ − 1)` otherwise; FPFDCNN's L1-L7 and
//! L9) in one pass forward and one pass backward on the CPU backends: a Burn backend
//! extension beside [`super::relu6_kernel`].
//!
//! [`super::activation::elu_composite`] is six tensor ops (two clamps, each a comparison and a
//! masked fill, an exponential, two scalar ops and a sum), each a pass over the activation
//! with its own allocation, and as many again backward. Here the forward pass writes the
//! output over the input's buffer (over a copy when something else holds it) and the backward
//! pass reads that output back: the derivative is 1 where it is positive and `y + a = a·eˣ`
//! elsewhere, so nothing but the output is kept (the next convolution keeps it anyway). Only
//! positive `a` takes this path. Values are the composite's (`f32` exponential); gradients
//! agree within `a·2⁻²⁴` absolute (`y + a` cancels: below about `x = −17` the slope comes out
//! 0 where the composite's is `a·eˣ`), except at exactly `x = 0`, where this kernel takes the
//! left derivative `a` (the composite's two clamps both pass it, `1 + a`), and at NaN inputs,
//! where the gradient passes unchanged (the composite's is NaN).

// burn-ndarray is deprecated upstream but is this crate's default backend.
#![allow(deprecated)]

use super::backend::is_cpu;
use super::conv::{OpImpl, op_impl};
use super::pool_kernel::{read, tensor, values};
use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::{base::Checkpointer, strategy::CheckpointStrategy};
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind, unary};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, Flex, NdArray, TensorMetadata, backend_extension};
use burn::prelude::*;
use rayon::prelude::*;

/// Elements per parallel task.
const CHUNK: usize = 1 << 16;

/// The extension: ELU of `x` with slope `alpha > 0` of the negative part.
#[backend_extension(Flex, NdArray, Autodiff)]
pub(crate) trait EluOps: Backend {
    /// ELU of `x`, element-wise: `x` where positive, `alpha·(eˣ − 1)` elsewhere.
    fn elu_fused(x: FloatTensor<Self>, alpha: f32) -> FloatTensor<Self>;
}

impl EluOps for Flex {
    fn elu_fused(x: FloatTensor<Self>, alpha: f32) -> FloatTensor<Self> {
        forward::<Flex>(x, alpha)
    }
}

impl EluOps for NdArray {
    fn elu_fused(x: FloatTensor<Self>, alpha: f32) -> FloatTensor<Self> {
        forward::<NdArray>(x, alpha)
    }
}

impl<B: Backend, C: CheckpointStrategy> EluOps for Autodiff<B, C> {
    fn elu_fused(x: FloatTensor<Self>, alpha: f32) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct Elu;

        impl<B: Backend> Backward<B, 1> for Elu {
            /// The output and `alpha`.
            type State = (FloatTensor<B>, f32);

            fn backward(
                self,
                ops: Ops<Self::State, 1>,
                grads: &mut Gradients,
                _checkpointer: &mut Checkpointer,
            ) {
                let (out, alpha) = ops.state;
                unary::<B, _>(ops.parents, ops.node, grads, |grad| {
                    backward::<B>(grad, out, alpha)
                });
            }
        }

        let guard = x.node();
        match Elu.prepare::<C>([guard]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let out = forward::<B>(x.into_primitive(), alpha);
                prep.finish((out.clone(), alpha), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(forward::<B>(x.into_primitive(), alpha)),
        }
    }
}

/// ELU of `x`: the fused kernel on the CPU backends for `alpha > 0` (unless
/// [`OpImpl::Burn`] is chosen), [`super::activation::elu_composite`] elsewhere.
pub(crate) fn elu_fused<const D: usize>(x: Tensor<D>, alpha: f64) -> Tensor<D> {
    if op_impl() == OpImpl::Burn || !is_cpu(&x.device()) || alpha.is_nan() || alpha <= 0.0 {
        return super::activation::elu_composite(x, alpha);
    }
    Tensor::from_dispatch(Dispatch::elu_fused(x.into_dispatch(), alpha as f32))
}

/// `x` for `x > 0`, `alpha (eˣ − 1)` otherwise, in place.
fn forward<B: Backend>(x: FloatTensor<B>, alpha: f32) -> FloatTensor<B> {
    let device = x.device();
    let (mut v, shape, dtype) = values::<B>(x);
    v.par_chunks_mut(CHUNK).for_each(|v| {
        v.iter_mut().for_each(|x| {
            if *x <= 0.0 {
                *x = (x.exp() - 1.0) * alpha;
            }
        })
    });
    tensor::<B>(v, shape, dtype, &device)
}

/// The input gradient from the output `out`: `grad` where `out > 0`, `grad · (out + alpha)`
/// (`= grad · alpha eˣ`) elsewhere.
fn backward<B: Backend>(grad: FloatTensor<B>, out: FloatTensor<B>, alpha: f32) -> FloatTensor<B> {
    let device = grad.device();
    let (mut g, shape, dtype) = values::<B>(grad);
    let (y, _, _) = read::<B>(out);
    let y = y.as_slice();
    g.par_chunks_mut(CHUNK)
        .zip(y.par_chunks(CHUNK))
        .for_each(|(g, y)| {
            g.iter_mut().zip(y).for_each(|(g, &y)| {
                if y <= 0.0 {
                    *g *= y + alpha;
                }
            })
        });
    tensor::<B>(g, shape, dtype, &device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::activation::elu_composite;
    use crate::nn::pool::tests::run;
    use burn::tensor::{Distribution, TensorData};

    #[test]
    fn matches_the_composite_elu_values_and_gradients() {
        let reference = Device::ndarray();
        let shape = [2, 3, 17, 19];
        let mut x = Tensor::<4>::random(shape, Distribution::Uniform(-6.0, 4.0), &reference)
            .into_data()
            .to_vec::<f32>()
            .unwrap();
        x[..5].copy_from_slice(&[-1e30, -90.0, -1e-6, 1e-6, 1e30]);
        let x = Tensor::<4>::from_data(TensorData::new(x, shape), &reference);
        let up = Tensor::<4>::random(shape, Distribution::Uniform(0.5, 1.5), &reference);
        for alpha in [1.0, 0.3] {
            let want = run(&reference, &x, &up, |x| elu_composite(x, alpha));
            for device in [Device::ndarray(), Device::flex()] {
                let got = run(&device, &x, &up, |x| elu_fused(x, alpha));
                for (what, (got, want)) in ["values", "gradients"].iter().zip(got.iter().zip(&want))
                {
                    assert_eq!(got.len(), want.len());
                    for (i, (a, b)) in got.iter().zip(want).enumerate() {
                        assert!(
                            a.is_finite() && (a - b).abs() <= 1e-6 * b.abs().max(1.0),
                            "{what}[{i}] on {device:?}, alpha {alpha}: {a} vs {b}"
                        );
                    }
                }
                let plain = elu_fused(Tensor::<4>::from_data(x.to_data(), &device), alpha);
                let plain = plain.into_data().to_vec::<f32>().unwrap();
                for (a, b) in plain.iter().zip(&want[0]) {
                    assert!((a - b).abs() <= 1e-6 * b.abs().max(1.0), "{a} vs {b}");
                }
            }
        }
    }

    #[test]
    fn takes_the_left_derivative_at_zero_and_falls_back_for_other_slopes() {
        let device = Device::flex();
        let x = Tensor::<4>::from_data(TensorData::new(vec![0.0f32, -2.0], [1, 1, 1, 2]), &device);
        let up = Tensor::<4>::ones([1, 1, 1, 2], &device);
        let [y, g] = run(&device, &x, &up, |x| elu_fused(x, 0.5));
        assert_eq!(y[0], 0.0);
        assert_eq!(g[0], 0.5);
        assert!((g[1] - 0.5 * (-2.0f32).exp()).abs() < 1e-7);
        // alpha ≤ 0 is the composite's: no exponential is inverted.
        let [y, _] = run(&device, &x, &up, |x| elu_fused(x, 0.0));
        assert_eq!(y, vec![0.0, 0.0]);
    }
}
