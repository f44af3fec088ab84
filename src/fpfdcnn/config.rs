//! The FPFDCNN config (TOML): the network's shape, the data and the training schedule.
//! Saved beside every checkpoint, so inference reads it from here without the trainer.

use super::data::FpDataConfig;
use super::data::default_size;
use super::loss::FpfdcnnLossConfig;
use super::model::FpfdcnnConfig;
use crate::error::{Error, Result};
use crate::nn::{BackendKind, DeviceSpec};
use crate::training::OptimizerConfig;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// A FPFDCNN training config (TOML), the skeleton every training config shares
/// (`model, out, backend, seed, epochs, batch_size, keep_checkpoints, init, [optimizer],
/// [network], [data], [loss]`).
///
/// Configs written before 2026-11-26 had `height`, `width`, `lr`, `lr_steps`,
/// `grad_clip_norm`, `pairs_per_epoch`, `val_pairs` and `descriptor_dim` at the top level:
/// [`FpfdcnnTrainConfig::parse`] refuses them saying where each key lives now;
/// [`FpfdcnnTrainConfig::parse_saved`] (the copies beside checkpoints) reads them there, so
/// old checkpoints still load and old runs still resume.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FpfdcnnTrainConfig {
    /// Always `"fpfdcnn"`.
    pub model: String,
    /// Run folder.
    #[serde(default = "default_out")]
    pub out: PathBuf,
    /// Backend (`ndarray`, `flex`, `wgpu` or `cuda`); `--backend` overrides it.
    #[serde(default)]
    pub backend: BackendKind,
    /// Data-parallel training on several GPUs of `backend`, e.g. `["wgpu:0", "wgpu:1"]`
    /// ([`crate::nn::devices`]): a batch's parts (`accumulate` of them, at least one per
    /// device) spread over them, the gradients summed on the first; `--devices` overrides
    /// it. Empty: the backend's one device.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub devices: Vec<DeviceSpec>,
    /// Seed of the initial weights, data order and augmentation.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Number of epochs; `--epochs` overrides it.
    pub epochs: usize,
    /// Frame pairs per step.
    #[serde(default = "default_batch")]
    pub batch_size: usize,
    /// Train each batch in this many parts with their gradients summed (gradient
    /// accumulation): the same step on a batch this many times smaller in memory.
    #[serde(default = "default_accumulate")]
    pub accumulate: usize,
    /// How many epoch checkpoints to keep, the newest ones (0: all, e.g. to average the
    /// last epochs' weights with `train average`).
    #[serde(default = "default_keep")]
    pub keep_checkpoints: usize,
    /// Start from these weights (a `model.bpk`, a checkpoint folder or a run folder) instead
    /// of a random initialisation; the optimizer starts afresh. Ignored by `--resume`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init: Option<PathBuf>,
    /// Adam at 1e-3 with the gradient norm clipped at 1 unless the config says otherwise.
    #[serde(default = "default_optimizer", deserialize_with = "optimizer_over")]
    pub optimizer: OptimizerConfig,
    /// The network ([`FpfdcnnConfig`] fields).
    #[serde(default)]
    pub network: NetworkConfig,
    /// Training and validation data.
    #[serde(default)]
    pub data: FpDataConfig,
    /// Loss weights and settings.
    #[serde(default)]
    pub loss: FpfdcnnLossConfig,
}

/// `[network]`: the [`FpfdcnnConfig`] fields a config may change.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NetworkConfig {
    /// Descriptor length (Table 12: 256).
    pub descriptor_dim: usize,
}

impl Default for NetworkConfig {
    fn default() -> Self {
        NetworkConfig {
            descriptor_dim: FpfdcnnConfig::new().descriptor_dim,
        }
    }
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
fn default_accumulate() -> usize {
    1
}
fn default_keep() -> usize {
    3
}
fn default_optimizer() -> OptimizerConfig {
    OptimizerConfig::adam(1e-3)
}
fn optimizer_over<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<OptimizerConfig, D::Error> {
    crate::training::optimizer::deserialize_over(d, default_optimizer())
}

/// The top-level keys of configs written before 2026-11-26 and where they live now.
const LEGACY_KEYS: [(&str, &str, &str); 6] = [
    ("lr", "optimizer", "lr"),
    ("lr_steps", "optimizer", "lr_steps"),
    ("grad_clip_norm", "optimizer", "grad_clip_norm"),
    ("pairs_per_epoch", "data", "pairs_per_epoch"),
    ("val_pairs", "data", "val_pairs"),
    ("descriptor_dim", "network", "descriptor_dim"),
];

/// The top-level keys of an old config in `table`, as `` `lr` -> `optimizer.lr` ``.
fn legacy_keys(table: &toml::Table) -> Vec<String> {
    let mut keys: Vec<String> = LEGACY_KEYS
        .iter()
        .filter(|(old, _, _)| table.contains_key(*old))
        .map(|(old, section, key)| format!("`{old}` -> `{section}.{key}`"))
        .collect();
    if table.contains_key("height") || table.contains_key("width") {
        keys.push("`height`, `width` -> `data.size = [height, width]`".to_string());
    }
    keys
}

/// Moves the keys of an old config to their sections (`height`/`width` become
/// `data.size`) and says what moved ([`legacy_keys`]). A key given in both places is an
/// error.
fn upgrade_legacy(table: &mut toml::Table) -> std::result::Result<Vec<String>, String> {
    let moved = legacy_keys(table);
    let put = |table: &mut toml::Table, section: &str, key: &str, value: toml::Value| {
        let entry = table
            .entry(section)
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        let toml::Value::Table(t) = entry else {
            return Err(format!("`{section}` must be a table"));
        };
        if t.contains_key(key) {
            return Err(format!(
                "`{key}` is given both at the top level (the old place) and in [{section}]"
            ));
        }
        t.insert(key.to_string(), value);
        Ok(())
    };
    for (old, section, key) in LEGACY_KEYS {
        if let Some(v) = table.remove(old) {
            put(table, section, key, v)?;
        }
    }
    let (h, w) = (table.remove("height"), table.remove("width"));
    if h.is_some() || w.is_some() {
        let [dh, dw] = default_size();
        let side = |v: Option<toml::Value>, d: usize| v.unwrap_or(toml::Value::Integer(d as i64));
        let size = toml::Value::Array(vec![side(h, dh), side(w, dw)]);
        put(table, "data", "size", size)?;
    }
    Ok(moved)
}

impl FpfdcnnTrainConfig {
    /// Parses and checks a config; errors name the file and line.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        Self::parse_with(text, path, false)
    }

    /// [`FpfdcnnTrainConfig::parse`] for a config saved beside a checkpoint, which may have
    /// the shape of before 2026-11-26 (top-level `lr`, `height`, ...).
    pub fn parse_saved(text: &str, path: &Path) -> Result<Self> {
        Self::parse_with(text, path, true)
    }

    fn parse_with(text: &str, path: &Path, legacy: bool) -> Result<Self> {
        let toml_err = |e| crate::camera::toml_error(path, text, e);
        let mut table: toml::Table = toml::from_str(text).map_err(toml_err)?;
        if !legacy {
            let moved = legacy_keys(&table).join(", ");
            if !moved.is_empty() {
                return Err(Error::invalid(
                    path,
                    format!(
                        "these keys have moved into sections: {moved} (the shape every \
                         training config shares; see configs/train/fpfdcnn/)"
                    ),
                ));
            }
        }
        let moved = upgrade_legacy(&mut table).map_err(|m| Error::invalid(path, m))?;
        let cfg: Self = if moved.is_empty() {
            // Line numbers in the errors: deserialise from the text itself.
            toml::from_str(text).map_err(toml_err)?
        } else {
            table
                .try_into()
                .map_err(|e: toml::de::Error| Error::invalid(path, e.to_string()))?
        };
        let bad = |m: String| Err(crate::io::config_error(path, text, m));
        if cfg.model != "fpfdcnn" {
            return bad(format!("model = \"{}\" is not \"fpfdcnn\"", cfg.model));
        }
        if cfg.batch_size == 0 || cfg.epochs == 0 {
            return bad("batch_size and epochs must be at least 1".into());
        }
        if let Err(e) = crate::nn::devices::check_entries(&cfg.devices) {
            return bad(format!("devices: {e}"));
        }
        if !(1..=cfg.batch_size).contains(&cfg.accumulate) {
            return bad(format!(
                "accumulate must be in 1..=batch_size ({}), got {}",
                cfg.batch_size, cfg.accumulate
            ));
        }
        if cfg.batch_size > 1024 || cfg.epochs > 100_000 {
            return bad(format!(
                "batch_size ({}) must be at most 1024 and epochs ({}) at most 100000",
                cfg.batch_size, cfg.epochs
            ));
        }
        let dim = cfg.network.descriptor_dim;
        if !(1..=4096).contains(&dim) {
            return bad(format!(
                "network.descriptor_dim must be in 1..=4096, got {dim}"
            ));
        }
        cfg.optimizer
            .validate()
            .map_err(|m| crate::io::config_error(path, text, m))?;
        if !legacy && cfg.data.sequences.is_empty() {
            // Checked here, not only when the data are read, so that `--dry-run` says it.
            return bad(
                "[[data.sequences]] lists no training sequence: FPFDCNN trains on TUM-layout \
                 sequences (path = \"...\")"
                    .into(),
            );
        }
        cfg.loss
            .validate()
            .map_err(|m| crate::io::config_error(path, text, m))?;
        cfg.data
            .validate()
            .map_err(|m| crate::io::config_error(path, text, m))?;
        let [h, w] = cfg.data.size;
        for (weight, what) in [
            (cfg.loss.shift_consistency, "shift_consistency"),
            (
                cfg.loss.descriptor_shift_consistency,
                "descriptor_shift_consistency",
            ),
        ] {
            if weight > 0.0 && h.min(w) < 32 {
                // The term crops half a cell off every side, and a cell must remain.
                return bad(format!(
                    "loss.{what} needs data.size of at least 32x32, got {h}x{w}"
                ));
            }
        }
        Ok(cfg)
    }

    /// The network this config trains.
    pub fn network(&self) -> FpfdcnnConfig {
        FpfdcnnConfig::new().with_descriptor_dim(self.network.descriptor_dim)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const NEW: &str = "model = \"fpfdcnn\"\nepochs = 2\n[optimizer]\nlr = 0.0002\n\
        lr_steps = [[14, 0.00007]]\n[network]\ndescriptor_dim = 64\n[data]\nsize = [96, 128]\n\
        pairs_per_epoch = 40\n[[data.sequences]]\npath = \"seq\"\n";
    const OLD: &str = "model = \"fpfdcnn\"\nepochs = 2\nheight = 96\nwidth = 128\n\
        lr = 0.0002\nlr_steps = [[14, 0.00007]]\npairs_per_epoch = 40\ndescriptor_dim = 64\n\
        [[data.sequences]]\npath = \"seq\"\n";

    #[test]
    fn saved_configs_of_the_old_shape_still_read_new_ones_must_use_sections() {
        let p = Path::new("c.toml");
        let new = FpfdcnnTrainConfig::parse(NEW, p).unwrap();
        assert_eq!(new.optimizer.kind, crate::training::OptimizerKind::Adam);
        assert_eq!(new.optimizer.grad_clip_norm, 1.0);
        assert_eq!(FpfdcnnTrainConfig::parse_saved(OLD, p).unwrap(), new);
        let e = FpfdcnnTrainConfig::parse(OLD, p).unwrap_err().to_string();
        assert!(
            e.starts_with("c.toml") && e.contains("`lr` -> `optimizer.lr`"),
            "{e}"
        );
        let both = format!("{OLD}[optimizer]\nlr = 0.1\n");
        let e = FpfdcnnTrainConfig::parse_saved(&both, p)
            .unwrap_err()
            .to_string();
        assert!(e.contains("both"), "{e}");
        let normalized = toml::to_string_pretty(&new).unwrap();
        assert_eq!(FpfdcnnTrainConfig::parse(&normalized, p).unwrap(), new);
    }

    #[test]
    fn configs_without_sequences_or_with_unsorted_lr_steps_are_refused() {
        let p = Path::new("c.toml");
        let none = NEW.replace("[[data.sequences]]\npath = \"seq\"\n", "");
        let e = FpfdcnnTrainConfig::parse(&none, p).unwrap_err().to_string();
        assert!(
            e.starts_with("c.toml") && e.contains("data.sequences"),
            "{e}"
        );
        for steps in ["[[20, 0.001], [10, 0.0001]]", "[[10, 0.001], [10, 0.0001]]"] {
            let text = NEW.replace("[[14, 0.00007]]", steps);
            let e = FpfdcnnTrainConfig::parse(&text, p).unwrap_err().to_string();
            assert!(
                e.starts_with("c.toml") && e.contains("optimizer.lr_steps"),
                "{e}"
            );
        }
        let text = NEW.replace("[[14, 0.00007]]", "[[10, 0.001], [20, 0.0001]]");
        assert!(FpfdcnnTrainConfig::parse(&text, p).is_ok());
    }

    /// The shift-consistency term crops half a cell off every side of the training crop, so
    /// a crop of one cell is refused before training starts.
    #[test]
    fn shift_consistency_needs_crops_of_two_cells() {
        let p = Path::new("c.toml");
        let with = |size: &str| {
            let text = NEW.replace("size = [96, 128]", size);
            FpfdcnnTrainConfig::parse(&format!("{text}[loss]\nshift_consistency = 1.0\n"), p)
        };
        assert!(with("size = [32, 48]").is_ok());
        let e = with("size = [16, 48]").unwrap_err().to_string();
        assert!(
            e.starts_with("c.toml") && e.contains("at least 32x32, got 16x48"),
            "{e}"
        );
    }
}
