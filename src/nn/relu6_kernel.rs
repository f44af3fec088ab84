//! ReLU6, `min(max(x, 0), 6)` (MobileNetV2's activation, SDFCNN's encoder), in one pass
//! forward and one pass backward on the CPU backends: a Burn backend extension beside
//! [`super::pool_kernel`].
//!
//! Burn 0.22.1's autodiff has no clamp of its own: `relu6` is a `clamp_min` and a
//! `clamp_max`, each a comparison and a masked fill forward and a masked fill backward, with
//! two boolean masks kept (a sixth of the SDFCNN train step on flex, `perf`). Here the
//! forward pass clamps in place and keeps one byte per element saying whether the gradient
//! passes, and the backward pass zeroes the gradient where it does not. The semantics are
//! Burn's exactly: `x < 0` gives 0, `x > 6` gives 6, anything else (0 and 6 included, and
//! NaN) passes through with its gradient, so values and gradients are bit for bit Burn's.

// burn-ndarray is deprecated upstream but is this crate's default backend.
#![allow(deprecated)]

use super::backend::is_cpu;
use super::conv::{OpImpl, op_impl};
use super::pool_kernel::{tensor, values};
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

/// The extension: ReLU6 of `x`.
#[backend_extension(Flex, NdArray, Autodiff)]
pub(crate) trait Relu6Ops: Backend {
    /// `min(max(x, 0), 6)` element by element.
    fn relu6_fused(x: FloatTensor<Self>) -> FloatTensor<Self>;
}

impl Relu6Ops for Flex {
    fn relu6_fused(x: FloatTensor<Self>) -> FloatTensor<Self> {
        forward::<Flex>(x, false).0
    }
}

impl Relu6Ops for NdArray {
    fn relu6_fused(x: FloatTensor<Self>) -> FloatTensor<Self> {
        forward::<NdArray>(x, false).0
    }
}

impl<B: Backend, C: CheckpointStrategy> Relu6Ops for Autodiff<B, C> {
    fn relu6_fused(x: FloatTensor<Self>) -> FloatTensor<Self> {
        #[derive(Debug)]
        struct Relu6;

        impl<B: Backend> Backward<B, 1> for Relu6 {
            /// 1 where the gradient passes.
            type State = Vec<u8>;

            fn backward(
                self,
                ops: Ops<Self::State, 1>,
                grads: &mut Gradients,
                _checkpointer: &mut Checkpointer,
            ) {
                let pass = ops.state;
                unary::<B, _>(ops.parents, ops.node, grads, |grad| {
                    backward::<B>(grad, &pass)
                });
            }
        }

        let guard = x.node();
        match Relu6.prepare::<C>([guard]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (out, pass) = forward::<B>(x.into_primitive(), true);
                prep.finish(pass, out)
            }
            OpsKind::UnTracked(prep) => prep.finish(forward::<B>(x.into_primitive(), false).0),
        }
    }
}

/// ReLU6 of `x`: the fused kernel on the CPU backends (unless [`OpImpl::Burn`] is chosen),
/// Burn's `relu6` elsewhere.
pub fn relu6<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    if op_impl() == OpImpl::Burn || !is_cpu(&x.device()) {
        return burn::tensor::activation::relu6(x);
    }
    Tensor::from_dispatch(Dispatch::relu6_fused(x.into_dispatch()))
}

/// The clamped tensor and, when `mask`, whether each element's gradient passes.
fn forward<B: Backend>(x: FloatTensor<B>, mask: bool) -> (FloatTensor<B>, Vec<u8>) {
    let device = x.device();
    let (mut v, shape, dtype) = values::<B>(x);
    let clamp = |x: &mut f32| {
        let (low, high) = (*x < 0.0, *x > 6.0);
        *x = if low {
            0.0
        } else if high {
            6.0
        } else {
            *x
        };
        u8::from(!low && !high)
    };
    let pass = if mask {
        let mut pass = vec![0u8; v.len()];
        v.par_chunks_mut(CHUNK)
            .zip(pass.par_chunks_mut(CHUNK))
            .for_each(|(v, p)| v.iter_mut().zip(p).for_each(|(x, p)| *p = clamp(x)));
        pass
    } else {
        v.par_chunks_mut(CHUNK).for_each(|v| {
            v.iter_mut().for_each(|x| {
                clamp(x);
            })
        });
        Vec::new()
    };
    (tensor::<B>(v, shape, dtype, &device), pass)
}

/// The input gradient: the output's where it passes, 0 elsewhere.
fn backward<B: Backend>(grad: FloatTensor<B>, pass: &[u8]) -> FloatTensor<B> {
    let device = grad.device();
    let (mut g, shape, dtype) = values::<B>(grad);
    g.par_chunks_mut(CHUNK)
        .zip(pass.par_chunks(CHUNK))
        .for_each(|(g, p)| {
            g.iter_mut()
                .zip(p)
                .for_each(|(g, &p)| *g = if p == 0 { 0.0 } else { *g });
        });
    tensor::<B>(g, shape, dtype, &device)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::pool::tests::run;
    use burn::tensor::{Distribution, TensorData};

    #[test]
    fn equals_burns_relu6_bit_for_bit_edges_and_nan_included() {
        let reference = Device::ndarray();
        let mut x =
            Tensor::<4>::random([2, 3, 17, 19], Distribution::Uniform(-3.0, 9.0), &reference)
                .into_data()
                .to_vec::<f32>()
                .unwrap();
        x[..6].copy_from_slice(&[0.0, 6.0, -0.0, f32::NAN, -1e30, 1e30]);
        let x = Tensor::<4>::from_data(TensorData::new(x, [2, 3, 17, 19]), &reference);
        let up = Tensor::<4>::random([2, 3, 17, 19], Distribution::Uniform(0.5, 1.5), &reference);
        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        let want = run(&reference, &x, &up, burn::tensor::activation::relu6);
        for device in [Device::ndarray(), Device::flex()] {
            let got = run(&device, &x, &up, relu6);
            assert_eq!(bits(&got[0]), bits(&want[0]), "values on {device:?}");
            assert_eq!(bits(&got[1]), bits(&want[1]), "gradients on {device:?}");
            let plain = relu6(Tensor::<4>::from_data(x.to_data(), &device));
            let plain = plain.into_data().to_vec::<f32>().unwrap();
            assert_eq!(
                bits(&plain),
                bits(&want[0]),
                "without autodiff on {device:?}"
            );
        }
    }
}
