//! Config-file sweeps: one training run per point of a grid (or list) of config values and
//! per seed, each in its own run folder, with result tables and plots.
//!
//! ```toml
//! model = "sweep"
//! base = "sdfcnn_sweep_base.toml"     # a training config; as given, else next to this file
//! out = "runs/sweep_lambda_lr"
//! seeds = [1, 2]                      # each point is trained once per seed (sets `seed`)
//! select = { metric = "val_miou", mode = "max", at = "final" }
//! plot = ["val_miou", "val_rms"]      # optional: metrics plotted against the first numeric field
//!
//! [set]                               # optional: overrides for every run
//! epochs = 4
//!
//! [grid]                              # every combination of these values
//! "loss.lambda" = [0.2, 0.4, 0.6, 0.8]
//! "optimizer.lr" = [0.01, 0.1]
//!
//! [[points]]                          # optional: further points, listed one by one
//! "loss.lambda" = 0.4
//! "loss.depth" = "l1"
//! ```
//!
//! Field paths are dotted paths into the base config (`optimizer.lr`, `data.augment.flip`);
//! nested tables (`[grid.loss]`) work too. A field may be one the base file does not list, as
//! long as the trainer's config has it: every point is checked by parsing the merged config with
//! the trainer's own parser before any run starts, so an unknown field, a wrong type or an
//! out-of-range value is an error naming the sweep file, its line and the key.
//!
//! Runs go to `out/<field>=<value>_..._seed=<n>/` (a normal run folder: `config.toml`,
//! `metrics.csv`, plots, checkpoints). A run whose last checkpoint reached its epochs is
//! skipped; one with fewer epochs is resumed from its last checkpoint, so a killed sweep
//! restarts where it stopped. After every run `out/results.csv`, `out/results.md` and the plots
//! are rewritten (see [`report`]); `out/sweep.log` records what was run.

pub mod report;

mod load;
mod run;
mod values;

pub use run::run;
pub use values::value_label;

use crate::error::{Error, Result};
use crate::training::RunOptions;
use serde::Deserialize;
use std::path::{Path, PathBuf};
use toml::Value;
use values::{lookup, short_labels};

/// What a sweep needs to know about a trainer.
#[derive(Clone, Copy)]
pub struct Trainer {
    /// The config's `model`.
    pub model: &'static str,
    /// Parses a config as the trainer does and returns it with every default filled in.
    parse: fn(&str, &Path) -> Result<Value>,
    /// Trains (config path, config text, options).
    run: fn(&Path, &str, &RunOptions) -> Result<()>,
    /// Checks that the data a config names can be opened (config text, config path).
    check_data: fn(&str, &Path) -> Result<()>,
    /// Whether a config (normalised by `parse`) has validation data, which every `val_*`
    /// metric needs.
    has_validation: fn(&Value) -> bool,
    /// What to add to a config that has none.
    validation_hint: &'static str,
    /// Every column the trainer writes to `metrics.csv` (besides epoch, lr, seconds).
    pub metrics: &'static [&'static str],
    /// Metrics reported in the results (final and best value).
    pub main: &'static [&'static str],
    /// Metrics plotted against the first numeric field by default.
    pub plots: &'static [&'static str],
}

const SDFCNN_METRICS: &[&str] = &[
    "train_loss",
    "train_seg_loss",
    "train_depth_loss",
    "val_loss",
    "val_seg_loss",
    "val_depth_loss",
    "val_mpa",
    "val_miou",
    "val_pixel_acc",
    "val_rms",
    "val_rel",
    "val_delta1",
    "val_delta2",
    "val_delta3",
];

const FPFDCNN_METRICS: &[&str] = &[
    "train_loss",
    "train_detector",
    "train_descriptor",
    "train_localization",
    "train_desc_top1",
    "val_loss",
    "val_detector",
    "val_descriptor",
    "val_localization",
    "val_desc_top1",
];

fn normalized<T: serde::Serialize>(cfg: &T, path: &Path) -> Result<Value> {
    Value::try_from(cfg).map_err(|e| Error::invalid(path, format!("cannot re-serialise: {e}")))
}

fn sdfcnn_check_data(text: &str, path: &Path) -> Result<()> {
    use crate::sdfcnn::data::{DataSource, SegDepthData};
    let cfg = crate::sdfcnn::SdfcnnTrainConfig::parse(text, path)?;
    if let Some(init) = &cfg.init {
        let p = crate::sdfcnn::data::resolve(init, path);
        if !p.exists() {
            return Err(Error::invalid(
                path,
                format!("init {} does not exist", p.display()),
            ));
        }
    }
    for list in [&cfg.data.train, &cfg.data.val] {
        let sources: Vec<DataSource> = list.iter().map(|s| s.resolved(path)).collect();
        SegDepthData::open(&sources)?;
    }
    Ok(())
}

fn fpfdcnn_check_data(text: &str, path: &Path) -> Result<()> {
    let cfg = crate::fpfdcnn::training::FpfdcnnTrainConfig::parse(text, path)?;
    if let Some(init) = &cfg.init {
        crate::nn::weights::resolve_checkpoint(init)
            .map_err(|e| Error::invalid(path, format!("init: {e}")))?;
    }
    for s in &cfg.data.sequences {
        crate::dataset::TumSequence::open(&s.path)?;
    }
    Ok(())
}

/// The trainers a sweep can run, by their config's `model`.
pub fn trainer(model: &str) -> Option<Trainer> {
    match model {
        "sdfcnn" => Some(Trainer {
            model: "sdfcnn",
            parse: |t, p| normalized(&crate::sdfcnn::SdfcnnTrainConfig::parse(t, p)?, p),
            run: crate::sdfcnn::training::run,
            check_data: sdfcnn_check_data,
            // `[[data.val]]` sources.
            has_validation: |cfg| {
                lookup(cfg, "data.val")
                    .and_then(Value::as_array)
                    .is_some_and(|v| !v.is_empty())
            },
            validation_hint: "[[data.val]] sources",
            metrics: SDFCNN_METRICS,
            main: &[
                "val_miou",
                "val_mpa",
                "val_rms",
                "val_rel",
                "val_delta1",
                "val_loss",
                "train_loss",
            ],
            plots: &["val_miou", "val_rms"],
        }),
        "fpfdcnn" => Some(Trainer {
            model: "fpfdcnn",
            parse: |t, p| {
                normalized(
                    &crate::fpfdcnn::training::FpfdcnnTrainConfig::parse(t, p)?,
                    p,
                )
            },
            run: crate::fpfdcnn::training::run,
            check_data: fpfdcnn_check_data,
            // The last `data.val_fraction` of every sequence.
            has_validation: |cfg| {
                lookup(cfg, "data.val_fraction")
                    .and_then(Value::as_float)
                    .is_some_and(|f| f > 0.0)
            },
            validation_hint: "data.val_fraction > 0",
            metrics: FPFDCNN_METRICS,
            main: &[
                "val_desc_top1",
                "val_loss",
                "val_descriptor",
                "val_detector",
                "train_loss",
            ],
            plots: &["val_desc_top1", "val_loss"],
        }),
        _ => None,
    }
}

/// Whether larger values of a metric are better (losses and depth errors are minimised).
pub fn larger_is_better(metric: &str) -> bool {
    !(metric.contains("loss")
        || ["rms", "rel", "detector", "descriptor"]
            .iter()
            .any(|s| metric.ends_with(s)))
}

/// Which value of a run's metric curve ranks it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum At {
    /// The last epoch's value.
    #[default]
    Final,
    /// The best value over all epochs.
    Best,
}

/// How runs are ranked.
#[derive(Debug, Clone, PartialEq)]
pub struct Select {
    pub metric: String,
    pub maximize: bool,
    pub at: At,
}

/// One configuration of the sweep (trained once per seed).
#[derive(Debug, Clone)]
pub struct Point {
    /// The value of every varied field (`Sweep::keys`), as the trainer sees it.
    pub values: Vec<Value>,
    /// Folder-name stem, e.g. `lambda=0.4_lr=0.01`.
    pub name: String,
}

/// One training run: a point and a seed.
#[derive(Debug, Clone)]
pub struct Run {
    /// Index into `Sweep::points`.
    pub point: usize,
    pub seed: u64,
    /// Folder name, e.g. `lambda=0.4_lr=0.01_seed=1`.
    pub name: String,
    pub dir: PathBuf,
    /// The merged training config given to the trainer.
    pub config: String,
    /// Epochs to train.
    pub epochs: usize,
    /// The merged config with defaults, for comparing with an existing run folder.
    normalized: Value,
}

/// A validated sweep: every run's config has been parsed by the trainer.
pub struct Sweep {
    /// The sweep file.
    pub path: PathBuf,
    pub trainer: Trainer,
    /// The base training config.
    pub base: PathBuf,
    pub out: PathBuf,
    /// The varied fields (grid keys in file order, then keys only `[[points]]` set).
    pub keys: Vec<String>,
    pub points: Vec<Point>,
    pub seeds: Vec<u64>,
    pub runs: Vec<Run>,
    pub select: Select,
    /// Metrics plotted against the first numeric varied field.
    pub plots: Vec<String>,
}

impl Sweep {
    /// `field = value, ..., seed = n` of a run.
    pub fn describe_point(&self, run: &Run) -> String {
        let mut parts: Vec<String> = self
            .keys
            .iter()
            .zip(&self.points[run.point].values)
            .map(|(k, v)| format!("{k} = {v}"))
            .collect();
        parts.push(format!("seed = {}", run.seed));
        parts.join(", ")
    }

    /// Short names of the varied fields (the last path segment, or the whole path where two
    /// fields end the same way).
    pub fn labels(&self) -> Vec<String> {
        short_labels(&self.keys)
    }
}

/// Parses a training config with its trainer's checks and opens the data and the `init`
/// weights it names (for `train --dry-run`).
pub fn check_training_config(model: &str, path: &Path, text: &str) -> Result<()> {
    let t = trainer(model).ok_or_else(|| {
        Error::invalid(
            path,
            format!("unknown model '{model}' (fpfdcnn, sdfcnn or sweep)"),
        )
    })?;
    (t.parse)(text, path)?;
    (t.check_data)(text, path)
}

#[cfg(test)]
mod tests;
