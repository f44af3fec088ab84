//! The FPFDCNN config (TOML): the network's shape, the data and the training schedule.
//! Saved beside every checkpoint, so inference reads it from here without the trainer.

use super::data::FpDataConfig;
use super::loss::FpfdcnnLossConfig;
use super::model::FpfdcnnConfig;
use crate::error::{Error, Result};
use crate::nn::BackendKind;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// A FPFDCNN training config (TOML).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FpfdcnnTrainConfig {
    /// Always `"fpfdcnn"`.
    pub model: String,
    /// Run folder.
    #[serde(default = "default_out")]
    pub out: PathBuf,
    #[serde(default)]
    pub backend: BackendKind,
    #[serde(default = "default_seed")]
    pub seed: u64,
    pub epochs: usize,
    #[serde(default = "default_batch")]
    pub batch_size: usize,
    /// Training image size (divisible by 16).
    #[serde(default = "default_height")]
    pub height: usize,
    #[serde(default = "default_width")]
    pub width: usize,
    /// Adam learning rate.
    #[serde(default = "default_lr")]
    pub lr: f64,
    /// Learning-rate changes `[[epoch, lr], ...]`: from that (0-based) epoch on.
    #[serde(default)]
    pub lr_steps: Vec<(usize, f64)>,
    /// Gradient clipping by norm (per parameter tensor); 0 disables it.
    #[serde(default = "default_clip")]
    pub grad_clip_norm: f64,
    /// At most this many pairs per epoch (0: all), drawn in the seeded order.
    #[serde(default)]
    pub pairs_per_epoch: usize,
    /// Validate on at most this many pairs, spread evenly over the validation split (0: all).
    #[serde(default)]
    pub val_pairs: usize,
    #[serde(default)]
    pub data: FpDataConfig,
    #[serde(default)]
    pub loss: FpfdcnnLossConfig,
    /// Descriptor length (Table 12: 256).
    #[serde(default = "default_dim")]
    pub descriptor_dim: usize,
    /// Start from these weights (a `model.bpk`, a checkpoint folder or a run folder) instead
    /// of a random initialisation; the optimizer starts afresh. Ignored by `--resume`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init: Option<PathBuf>,
    /// How many epoch checkpoints to keep, the newest ones (0: all, e.g. to average the
    /// last epochs' weights with `train average`).
    #[serde(default = "default_keep")]
    pub keep_checkpoints: usize,
}

fn default_out() -> PathBuf {
    PathBuf::from("runs/fpfdcnn")
}
fn default_seed() -> u64 {
    42
}
fn default_batch() -> usize {
    4
}
fn default_height() -> usize {
    240
}
fn default_width() -> usize {
    320
}
fn default_lr() -> f64 {
    1e-3
}
fn default_clip() -> f64 {
    1.0
}
fn default_dim() -> usize {
    256
}
fn default_keep() -> usize {
    3
}

/// Largest training image side, pixels.
const MAX_SIDE: usize = 4096;

impl FpfdcnnTrainConfig {
    /// Parses and checks a config; errors name the file and line.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let cfg: Self =
            toml::from_str(text).map_err(|e| crate::camera::toml_error(path, text, e))?;
        let bad = |m: String| Err(Error::invalid(path, m));
        if cfg.model != "fpfdcnn" {
            return bad(format!("model = \"{}\" is not \"fpfdcnn\"", cfg.model));
        }
        if !cfg.height.is_multiple_of(16)
            || !cfg.width.is_multiple_of(16)
            || cfg.height == 0
            || cfg.width == 0
        {
            return bad(format!(
                "height x width {}x{} must be non-zero multiples of 16",
                cfg.height, cfg.width
            ));
        }
        if cfg.batch_size == 0 || cfg.epochs == 0 {
            return bad("batch_size and epochs must be at least 1".into());
        }
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(cfg.lr) || cfg.lr_steps.iter().any(|s| !positive(s.1)) {
            return bad("learning rates must be positive".into());
        }
        if cfg.height > MAX_SIDE || cfg.width > MAX_SIDE {
            return bad(format!(
                "height x width {}x{} must be at most {MAX_SIDE} pixels a side",
                cfg.height, cfg.width
            ));
        }
        if cfg.batch_size > 1024 || cfg.epochs > 100_000 || cfg.descriptor_dim == 0 {
            return bad(format!(
                "batch_size ({}) must be at most 1024, epochs ({}) at most 100000 and \
                 descriptor_dim at least 1",
                cfg.batch_size, cfg.epochs
            ));
        }
        if cfg.descriptor_dim > 4096 {
            return bad(format!(
                "descriptor_dim must be at most 4096, got {}",
                cfg.descriptor_dim
            ));
        }
        if !(cfg.grad_clip_norm.is_finite() && cfg.grad_clip_norm >= 0.0) {
            return bad(format!(
                "grad_clip_norm must be a non-negative number (0: off), got {}",
                cfg.grad_clip_norm
            ));
        }
        cfg.loss.validate().map_err(|m| Error::invalid(path, m))?;
        cfg.data.validate().map_err(|m| Error::invalid(path, m))?;
        Ok(cfg)
    }

    /// The network this config trains.
    pub fn network(&self) -> FpfdcnnConfig {
        FpfdcnnConfig::new().with_descriptor_dim(self.descriptor_dim)
    }

    /// Learning rate of a (0-based) epoch.
    pub fn lr_at(&self, epoch: usize) -> f64 {
        self.lr_steps
            .iter()
            .filter(|(e, _)| *e <= epoch)
            .max_by_key(|(e, _)| *e)
            .map(|s| s.1)
            .unwrap_or(self.lr)
    }
}
