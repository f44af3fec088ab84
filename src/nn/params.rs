//! Trainable-parameter counting.

use burn::module::{ModuleVisitor, Param};
use burn::prelude::*;

/// Number of trainable scalars of `module`: every float parameter except batch-norm running
/// statistics (`running_mean`, `running_var`), which [`Module::num_params`] also counts.
pub fn trainable_params<M: Module>(module: &M) -> usize {
    let mut counter = Counter::default();
    module.visit(&mut counter);
    counter.count
}

#[derive(Default)]
struct Counter {
    path: Vec<String>,
    count: usize,
}

impl ModuleVisitor for Counter {
    fn enter_module(&mut self, name: &str, _container_type: &str) {
        self.path.push(name.to_owned());
    }

    fn exit_module(&mut self, _name: &str, _container_type: &str) {
        self.path.pop();
    }

    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let running = matches!(
            self.path.last().map(String::as_str),
            Some("running_mean" | "running_var")
        );
        if !running {
            self.count += param.lazy_shape().num_elements();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::nn::{BatchNormConfig, conv::Conv2dConfig};

    #[derive(Module, Debug)]
    struct Tiny {
        conv: burn::nn::conv::Conv2d,
        bn: burn::nn::BatchNorm,
    }

    #[test]
    fn batch_norm_running_stats_are_not_trainable() {
        let d = Device::flex();
        let m = Tiny {
            conv: Conv2dConfig::new([3, 8], [3, 3]).init(&d),
            bn: BatchNormConfig::new(8).init(&d),
        };
        let conv = 3 * 8 * 9 + 8;
        assert_eq!(trainable_params(&m), conv + 2 * 8);
        assert_eq!(m.num_params(), conv + 4 * 8);
    }
}
