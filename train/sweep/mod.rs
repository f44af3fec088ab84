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

use crate::trainers::{Trainer, trainer};
use serde::Deserialize;
use std::path::PathBuf;
use toml::Value;
pub(crate) use values::lookup;
use values::short_labels;

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

#[cfg(test)]
mod tests;
