//! What both trainers share: the fit loop ([`fit`]), `[optimizer]` ([`optimizer`]), run
//! folders with atomic per-epoch checkpoints and `--resume`, per-epoch metrics (CSV +
//! plots), seeded data order, and the NaN guard. Config-file sweeps over the trainers live
//! in the `train` application (`train/sweep/`), which knows the concrete models.

pub mod checkpoint;
pub mod fit;
pub mod history;
pub mod optimizer;

/// Backends live with the networks ([`crate::nn::backend`]); re-exported for the trainers.
pub use crate::nn::backend::{self, BackendKind};
pub use checkpoint::{Checkpoint, RunContents, RunDir, TrainState, clear_run, resolve_checkpoint};
pub use history::{EpochRecord, History};
pub use optimizer::{OptimizerConfig, OptimizerKind};

use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;

/// The order in which an epoch visits `n` samples: a permutation that depends
/// only on the seed and the epoch, so a resumed run sees the same data order as
/// an uninterrupted one.
pub(crate) fn epoch_order(n: usize, seed: u64, epoch: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..n).collect();
    let mut rng =
        ChaCha8Rng::seed_from_u64(seed ^ (epoch as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    order.shuffle(&mut rng);
    order
}

/// A seeded RNG for one (epoch, batch): augmentation is reproducible on resume.
pub(crate) fn batch_rng(seed: u64, epoch: usize, batch: usize) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(
        seed.wrapping_add((epoch as u64) << 32)
            .wrapping_add(batch as u64)
            .wrapping_mul(0xD134_2543_DE82_EF95),
    )
}

/// Options of a training run given on the command line (they override the config).
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Output folder (default: the config's `out`).
    pub out: Option<std::path::PathBuf>,
    /// Continue from the last checkpoint in the output folder.
    pub resume: bool,
    /// Backend (default: the config's `backend`).
    pub backend: Option<BackendKind>,
    /// Data-parallel devices (default: the config's `devices`).
    pub devices: Option<Vec<crate::nn::DeviceSpec>>,
    /// Number of epochs (default: the config's `epochs`).
    pub epochs: Option<usize>,
    /// Hide the progress bar (logs still print one line per epoch).
    pub quiet: bool,
}

/// The device a module's parameters live on (the first parameter's; flex for a module
/// without any).
pub(crate) fn module_device<M: burn::module::Module>(module: &M) -> burn::prelude::Device {
    module
        .devices()
        .into_iter()
        .next()
        .unwrap_or_else(burn::prelude::Device::flex)
}

impl RunOptions {
    /// Writes the command-line overrides into a config's skeleton fields.
    pub fn apply(
        &self,
        epochs: &mut usize,
        backend: &mut BackendKind,
        devices: &mut Vec<crate::nn::DeviceSpec>,
        out: &mut std::path::PathBuf,
    ) {
        if let Some(e) = self.epochs {
            *epochs = e;
        }
        if let Some(b) = self.backend {
            *backend = b;
        }
        if let Some(d) = &self.devices {
            *devices = d.clone();
        }
        if let Some(o) = &self.out {
            *out = o.clone();
        }
    }
}

/// The `model = "..."` key that says which network a training config is for.
pub fn config_model(toml_text: &str, path: &std::path::Path) -> crate::Result<String> {
    let value: toml::Table =
        toml::from_str(toml_text).map_err(|e| crate::camera::toml_error(path, toml_text, e))?;
    match value.get("model").and_then(|v| v.as_str()) {
        Some(m) => Ok(m.to_string()),
        None => Err(crate::Error::invalid(
            path,
            "missing top-level `model = \"fpfdcnn\"`, `model = \"sdfcnn\"` or `model = \"sweep\"`",
        )),
    }
}

/// Shapes of the parameters whose gradient holds a NaN or an infinity.
pub(crate) fn non_finite_grads<M: burn::module::Module>(
    module: &M,
    grads: &burn::optim::GradientsParams,
) -> Vec<Vec<usize>> {
    non_finite(module, Some(grads))
}

/// Shapes of the trainable parameters holding a NaN or an infinity.
pub(crate) fn non_finite_params<M: burn::module::Module>(module: &M) -> Vec<Vec<usize>> {
    non_finite(module, None)
}

/// Shapes of the parameters whose gradient (with `grads`) or value (without) is not finite:
/// each tensor's sum (a NaN or an infinity anywhere makes it non-finite), all read back from
/// the device at once.
fn non_finite<M: burn::module::Module>(
    module: &M,
    grads: Option<&burn::optim::GradientsParams>,
) -> Vec<Vec<usize>> {
    use burn::prelude::Tensor;
    struct Sums<'a> {
        grads: Option<&'a burn::optim::GradientsParams>,
        shapes: Vec<Vec<usize>>,
        sums: Vec<Tensor<1>>,
    }
    impl burn::module::ModuleVisitor for Sums<'_> {
        fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<D>>) {
            let tensor = match self.grads {
                Some(grads) => grads.get::<D>(param.id),
                None => Some(param.val()),
            };
            if let Some(t) = tensor {
                self.shapes.push(t.dims().to_vec());
                self.sums.push(crate::nn::sum_all(t));
            }
        }
    }
    let mut sums = Sums {
        grads,
        shapes: Vec::new(),
        sums: Vec::new(),
    };
    module.visit(&mut sums);
    if sums.sums.is_empty() {
        return Vec::new();
    }
    let values = Tensor::cat(sums.sums, 0).into_data().convert::<f32>();
    let values = values.as_slice::<f32>().unwrap_or(&[]);
    sums.shapes
        .into_iter()
        .zip(values)
        .filter(|(_, v)| !v.is_finite())
        .map(|(s, _)| s)
        .collect()
}

/// Stops training on a non-finite loss with a message that says what was kept.
pub(crate) fn check_finite(
    loss: f64,
    epoch: usize,
    batch: usize,
    run: &RunDir,
) -> crate::Result<()> {
    if loss.is_finite() {
        return Ok(());
    }
    Err(crate::Error::msg(format!(
        "loss became {loss} at epoch {} batch {batch}: training stopped; {}. Lower the learning rate or check the data.",
        epoch + 1,
        kept_checkpoint(run)
    )))
}

/// Checks, before an epoch's checkpoint is written, that every weight and every epoch
/// metric (training and validation) is finite: the last step of an epoch can leave NaN
/// weights whose loss no batch has computed yet, and that checkpoint must not replace the
/// last good one.
pub(crate) fn check_finite_epoch<M: burn::module::Module>(
    module: &M,
    values: &std::collections::BTreeMap<String, f64>,
    epoch: usize,
    run: &RunDir,
) -> crate::Result<()> {
    let bad = non_finite_params(module);
    let bad_values: Vec<&str> = values
        .iter()
        .filter(|(_, v)| !v.is_finite())
        .map(|(k, _)| k.as_str())
        .collect();
    if bad.is_empty() && bad_values.is_empty() {
        return Ok(());
    }
    let what = if bad.is_empty() {
        format!("{} became non-finite", bad_values.join(", "))
    } else {
        format!(
            "{} weight tensors became non-finite (shapes {:?})",
            bad.len(),
            &bad[..bad.len().min(3)]
        )
    };
    Err(crate::Error::msg(format!(
        "after epoch {}: {what}: training stopped without saving this epoch; {}. Lower the learning rate or check the data.",
        epoch + 1,
        kept_checkpoint(run)
    )))
}

/// "the last good checkpoint, epoch N, is kept in DIR" (or that there is none yet).
pub(crate) fn kept_checkpoint(run: &RunDir) -> String {
    match run.latest() {
        Ok(Some(c)) => format!(
            "the last good checkpoint, epoch {}, is kept in {}",
            c.state.epoch,
            c.dir.display()
        ),
        _ => "no checkpoint had been written yet".to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn epoch_order_is_a_seeded_permutation() {
        let a = epoch_order(100, 7, 3);
        assert_eq!(a, epoch_order(100, 7, 3));
        assert_ne!(a, epoch_order(100, 7, 4));
        let mut s = a.clone();
        s.sort();
        assert_eq!(s, (0..100).collect::<Vec<_>>());
    }

    #[test]
    fn an_epoch_with_nan_weights_or_validation_loss_is_refused() {
        #[allow(deprecated)]
        let device = burn::prelude::Device::ndarray();
        let root = std::env::temp_dir().join(format!("sdf_nan_run_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let run = RunDir::prepare(&root, "lr = 0.1\n", false).unwrap();
        let linear = burn::nn::LinearConfig::new(3, 2).init(&device);
        let fine = std::collections::BTreeMap::from([("val_loss".to_string(), 1.5)]);
        assert!(check_finite_epoch(&linear, &fine, 0, &run).is_ok());
        let nan_val = std::collections::BTreeMap::from([("val_loss".to_string(), f64::NAN)]);
        let err = check_finite_epoch(&linear, &nan_val, 0, &run)
            .unwrap_err()
            .to_string();
        assert!(err.contains("val_loss became non-finite"), "{err}");
        assert!(err.contains("without saving"), "{err}");
        let broken = burn::nn::Linear {
            weight: burn::module::Param::from_tensor(
                burn::prelude::Tensor::<2>::zeros([3, 2], &device).div_scalar(0.0),
            ),
            bias: linear.bias.clone(),
        };
        let err = check_finite_epoch(&broken, &fine, 4, &run)
            .unwrap_err()
            .to_string();
        assert!(err.contains("after epoch 5: 1 weight tensors"), "{err}");
        assert!(err.contains("[3, 2]"), "{err}");
        assert!(err.contains("no checkpoint had been written yet"), "{err}");
        let _ = std::fs::remove_dir_all(&root);
    }
}
