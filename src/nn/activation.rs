//! Activations whose gradients stay finite.

use burn::prelude::*;

/// ELU, `x` for `x > 0` and `alpha (eˣ − 1)` otherwise (Table 12, footnote 1),
/// written as `max(x, 0) + alpha (e^{min(x, 0)} − 1)`.
///
/// Burn's `elu` selects between `x` and `alpha (eˣ − 1)` with a mask; for large
/// activations the unselected `eˣ` overflows and its zero-weighted gradient
/// becomes `0 · ∞ = NaN`, which poisons every layer below it during training.
/// This form never exponentiates a positive number.
///
/// On the CPU backends with `alpha > 0` it runs as one fused pass forward and one backward
/// (`super::elu_kernel`); `elu_composite` elsewhere and under [`super::OpImpl::Burn`].
pub fn elu<const D: usize>(x: Tensor<D>, alpha: f64) -> Tensor<D> {
    super::elu_kernel::elu_fused(x, alpha)
}

/// [`elu`] from Burn's tensor ops: `max(x, 0) + alpha (e^{min(x, 0)} − 1)` (the GPU path,
/// and the reference of [`super::elu_kernel`]'s tests).
pub(crate) fn elu_composite<const D: usize>(x: Tensor<D>, alpha: f64) -> Tensor<D> {
    let pos = x.clone().clamp_min(0.0);
    let neg = x.clamp_max(0.0).exp().sub_scalar(1.0).mul_scalar(alpha);
    pos + neg
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_elu_and_has_finite_gradients_for_huge_inputs() {
        type Elu = fn(Tensor<1>, f64) -> Tensor<1>;
        #[allow(deprecated)]
        let devices = [Device::ndarray().autodiff(), Device::flex().autodiff()];
        for (d, f) in devices
            .iter()
            .flat_map(|d| [(d, elu as Elu), (d, elu_composite as Elu)])
        {
            let x = Tensor::<1>::from_data(
                TensorData::new(vec![-3.0f32, -0.5, 0.0, 2.0, 500.0], [5]),
                d,
            )
            .require_grad();
            let y = f(x.clone(), 1.0);
            let v = y.clone().into_data().try_to_vec::<f32>().unwrap();
            let expected = [
                (-3.0f32).exp() - 1.0,
                (-0.5f32).exp() - 1.0,
                0.0,
                2.0,
                500.0,
            ];
            for (a, b) in v.iter().zip(expected) {
                assert!((a - b).abs() < 1e-6, "{a} vs {b}");
            }
            let g = x
                .grad(&y.sum().backward())
                .unwrap()
                .into_data()
                .try_to_vec::<f32>()
                .unwrap();
            assert!(g.iter().all(|v| v.is_finite()), "{g:?}");
            assert!((g[0] - (-3.0f32).exp()).abs() < 1e-6 && g[4] == 1.0);
        }
    }
}
