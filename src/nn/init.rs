//! Seeded weight initialisation that does not depend on Burn's global random generator.
//!
//! Burn draws initial weights from one process-wide generator per backend, so two models built
//! from the same seed differ when another thread draws in between (parallel tests, a second
//! network). [`seeded_init`] redraws every convolution / linear weight and bias from a ChaCha
//! generator keyed by the seed and the parameter's position, with Burn's (and PyTorch's)
//! default distribution: uniform in `±1/√fan_in`, `fan_in` = input channels per group × kernel
//! area. Other parameters (batch-norm γ = 1, β = 0, running statistics) keep their constant
//! initial values.

use burn::module::{ModuleMapper, ModuleVisitor, Param};
use burn::prelude::*;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Re-initialises the weights and biases of `module` from `seed` (see the module docs).
pub fn seeded_init<M: Module>(module: M, seed: u64) -> M {
    let mut mapper = SeededInit {
        seed,
        index: 0,
        fan_in: 1,
        path: Vec::new(),
    };
    module.map(&mut mapper)
}

/// `module` with every parameter's initial value drawn now. Burn draws it lazily, at the
/// parameter's first use and on the device it is on by then: a module built on the CPU and
/// moved to a GPU before its first use draws from the GPU's generator.
pub fn drawn<M: Module>(module: M) -> M {
    module.visit(&mut Draw);
    module
}

struct Draw;

impl ModuleVisitor for Draw {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let _ = param.val();
    }
}

struct SeededInit {
    seed: u64,
    index: u64,
    /// Fan-in of the last weight seen (a bias follows its weight).
    fan_in: usize,
    path: Vec<String>,
}

impl ModuleMapper for SeededInit {
    fn enter_module(&mut self, name: &str, _container_type: &str) {
        self.path.push(name.to_owned());
    }

    fn exit_module(&mut self, _name: &str, _container_type: &str) {
        self.path.pop();
    }

    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let name = self.path.last().map(String::as_str).unwrap_or("");
        let dims = param.lazy_shape().dims::<D>();
        let fan_in = match (name, D) {
            ("weight", 4) => dims[1] * dims[2] * dims[3],
            ("weight", 2) => dims[0], // burn Linear weights are [in, out]
            ("bias", 1) => self.fan_in,
            _ => return param,
        };
        if name == "weight" {
            self.fan_in = fan_in;
        }
        self.index += 1;
        let mut rng = ChaCha8Rng::seed_from_u64(
            self.seed
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .wrapping_add(self.index),
        );
        let bound = 1.0 / (fan_in.max(1) as f32).sqrt();
        let n: usize = dims.iter().product();
        let values: Vec<f32> = (0..n).map(|_| rng.random_range(-bound..bound)).collect();
        let (id, device) = (param.id, param.lazy_device());
        // Loading keeps the parameter trainable (a plain `map` would drop `require_grad`).
        param.transform_for_load(
            Tensor::from_data(TensorData::new(values, dims), &device),
            id,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::conv::Conv2dConfig;

    #[test]
    fn same_seed_same_weights_within_default_bounds() {
        let d = Device::flex();
        let conv = |seed| {
            let c = Conv2dConfig::new([4, 6], [3, 3]).init(&d);
            seeded_init(c, seed)
        };
        let (a, b, c) = (conv(1), conv(1), conv(2));
        let w = |m: &burn::nn::conv::Conv2d| {
            m.weight.val().into_data().try_to_vec::<f32>().expect("f32")
        };
        assert_eq!(w(&a), w(&b));
        assert_ne!(w(&a), w(&c));
        let bound = 1.0 / 36f32.sqrt();
        assert!(w(&a).iter().all(|v| v.abs() <= bound));
        let bias = a.bias.as_ref().expect("bias").val().into_data();
        let bias = bias.try_to_vec::<f32>().expect("f32");
        assert!(bias.iter().all(|v| v.abs() <= bound) && bias.iter().any(|v| *v != 0.0));
    }

    #[test]
    fn reinitialised_weights_stay_trainable() {
        let d = Device::flex().autodiff();
        let c = seeded_init(Conv2dConfig::new([2, 3], [3, 3]).init(&d), 1);
        let x = Tensor::<4>::ones([1, 2, 5, 5], &d);
        let grads = c.forward(x).sum().backward();
        assert!(c.weight.grad(&grads).is_some());
        assert!(c.bias.as_ref().and_then(|b| b.grad(&grads)).is_some());
    }
}
