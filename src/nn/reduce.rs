//! The sum of every element of a tensor, as the training losses take it.
//!
//! Burn 0.22.1's GPU reductions give each reduced row to one invocation that loops over it
//! (the only routine whose timing Mesa's software Vulkan, lavapipe, reports, so autotune picks
//! it there). Mesa's lavapipe ends a shader's loops after 65,535 iterations in all (gallivm's
//! `LP_MAX_TGSI_LOOP_ITERATIONS`), so a row longer than that comes back short: a million ones
//! sum to 262,132 (four per iteration), a strided column of 65,536 to 65,532
//! (`tests/gpu_ops.rs`, Mesa 22.3.6). [`sum_all`] sums in rows of at most [`ROW`] elements,
//! then sums the rows' sums the same way: right on every backend.

use burn::prelude::*;

/// The longest row [`sum_all`] reduces in one go: well under lavapipe's 65,535 loop
/// iterations even when a row is read one element at a time.
pub const ROW: usize = 1 << 15;

/// The sum of every element of `t`, shape `[1]` (what `t.sum()` gives), differentiable.
pub fn sum_all<const D: usize>(t: Tensor<D>) -> Tensor<1> {
    let n = t.shape().num_elements();
    let flat = t.reshape([n]);
    if n <= ROW {
        return flat.sum_dim(0);
    }
    let rows = n.div_ceil(ROW);
    let pad = rows * ROW - n;
    let flat = if pad == 0 {
        flat
    } else {
        let zeros = Tensor::<1>::zeros([pad], &flat.device());
        Tensor::cat(vec![flat, zeros], 0)
    };
    sum_all(flat.reshape([rows, ROW]).sum_dim(1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::BackendKind;

    #[test]
    fn sums_every_element_and_passes_the_gradient_back() {
        let device = BackendKind::Flex.autodiff_device().expect("flex");
        let x = Tensor::<3>::from_data(
            TensorData::new((0..24).map(|i| i as f32).collect::<Vec<_>>(), [2, 3, 4]),
            &device,
        )
        .require_grad();
        let s = sum_all(x.clone().powi_scalar(2));
        assert_eq!(s.dims(), [1]);
        let want: f32 = (0..24).map(|i| (i * i) as f32).sum();
        assert_eq!(s.clone().into_scalar::<f32>(), want);
        let g = x.grad(&s.backward()).expect("gradient");
        let g: Vec<f32> = g.into_data().convert::<f32>().try_to_vec().expect("f32");
        assert_eq!(g, (0..24).map(|i| 2.0 * i as f32).collect::<Vec<_>>());
    }

    #[test]
    fn sums_tensors_longer_than_a_row_padded_or_not() {
        let device = BackendKind::Flex.device().expect("flex");
        for n in [ROW + 1, 3 * ROW, 5 * ROW + 7] {
            let ones = Tensor::<2>::ones([n, 1], &device);
            assert_eq!(sum_all(ones).into_scalar::<f32>(), n as f32, "{n} ones");
        }
    }
}
