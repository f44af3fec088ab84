//! The trainers the `train` command knows, by their config's `model`: how to parse, check,
//! train, export and summarise each network. `train` (training, `--dry-run`, `export`,
//! `summary`) and the sweeps ([`crate::sweep`]) dispatch through [`trainer`] only, so adding
//! a network means editing this file.

use anyhow::Context as _;
use burn::prelude::*;
use clap::ValueEnum;
use sdf_slam::error::{Error, Result};
use sdf_slam::fpfdcnn::FpfdcnnConfig;
use sdf_slam::nn::{BackendKind, ShapeTrace, trainable_params};
use sdf_slam::sdfcnn::SdfcnnConfig;
use sdf_slam::training::RunOptions;
use std::path::Path;
use toml::Value;

use crate::sweep::lookup;

/// The networks `train summary` can summarise.
#[derive(ValueEnum, Clone, Copy, Debug)]
pub enum Network {
    /// Keypoint detector/descriptor (Table 12).
    Fpfdcnn,
    /// Semantic segmentation + depth (Table 13).
    Sdfcnn,
}

impl Network {
    /// The network's trainer.
    pub fn trainer(self) -> Trainer {
        let model = match self {
            Network::Fpfdcnn => "fpfdcnn",
            Network::Sdfcnn => "sdfcnn",
        };
        trainer(model).expect("every network has a trainer")
    }
}

/// `train summary` of one network: (trace, `[height, width]`, backend) -> (trainable
/// parameters, all parameters).
pub type SummaryFn = fn(&mut ShapeTrace, [usize; 2], BackendKind) -> anyhow::Result<(usize, usize)>;

/// What `train` and the sweeps need to know about a trainer.
#[derive(Clone, Copy)]
pub struct Trainer {
    /// The config's `model`.
    pub model: &'static str,
    /// Parses a config as the trainer does and returns it with every default filled in.
    pub parse: fn(&str, &Path) -> Result<Value>,
    /// [`Trainer::parse`] for the copy of a config saved in a run folder, which may have the
    /// shape of an older version.
    pub parse_saved: fn(&str, &Path) -> Result<Value>,
    /// Trains (config path, config text, options).
    pub run: fn(&Path, &str, &RunOptions) -> Result<()>,
    /// Checks that the data a config names can be opened (config text, config path).
    pub check_data: fn(&str, &Path) -> Result<()>,
    /// Whether a config (normalised by `parse`) has validation data, which every `val_*`
    /// metric needs.
    pub has_validation: fn(&Value) -> bool,
    /// What to add to a config that has none.
    pub validation_hint: &'static str,
    /// Every column the trainer writes to `metrics.csv` (besides epoch, lr, seconds).
    pub metrics: &'static [&'static str],
    /// Metrics reported in the results (final and best value).
    pub main: &'static [&'static str],
    /// Metrics plotted against the first numeric field by default.
    pub plots: &'static [&'static str],
    /// `train export`: writes a checkpoint's weights (a `model.bpk`) in half precision to
    /// the given file.
    pub export: fn(&Path, &Path) -> Result<()>,
    /// `train summary`: one forward pass of a freshly initialised network on a zero image
    /// of the given height and width, traced layer by layer; returns the trainable and the
    /// total parameter counts.
    pub summary: SummaryFn,
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
    use sdf_slam::sdfcnn::data::{DataSource, SegDepthData};
    let cfg = sdf_slam::sdfcnn::SdfcnnTrainConfig::parse(text, path)?;
    if let Some(init) = &cfg.init {
        let p = sdf_slam::sdfcnn::data::resolve(init, path);
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
    let cfg = sdf_slam::fpfdcnn::training::FpfdcnnTrainConfig::parse(text, path)?;
    if let Some(init) = &cfg.init {
        sdf_slam::training::resolve_checkpoint(init)
            .map_err(|e| Error::invalid(path, format!("init: {e}")))?;
    }
    for s in &cfg.data.sequences {
        sdf_slam::dataset::TumSequence::open(&s.path)?;
    }
    Ok(())
}

/// The trainers `train` and the sweeps can run, by their config's `model`.
pub fn trainer(model: &str) -> Option<Trainer> {
    match model {
        "sdfcnn" => Some(Trainer {
            model: "sdfcnn",
            parse: |t, p| normalized(&sdf_slam::sdfcnn::SdfcnnTrainConfig::parse(t, p)?, p),
            parse_saved: |t, p| normalized(&sdf_slam::sdfcnn::SdfcnnTrainConfig::parse(t, p)?, p),
            run: sdf_slam::sdfcnn::training::run,
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
            export: sdfcnn_export,
            summary: sdfcnn_summary,
        }),
        "fpfdcnn" => Some(Trainer {
            model: "fpfdcnn",
            parse: |t, p| {
                normalized(
                    &sdf_slam::fpfdcnn::training::FpfdcnnTrainConfig::parse(t, p)?,
                    p,
                )
            },
            parse_saved: |t, p| {
                normalized(
                    &sdf_slam::fpfdcnn::training::FpfdcnnTrainConfig::parse_saved(t, p)?,
                    p,
                )
            },
            run: sdf_slam::fpfdcnn::training::run,
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
            export: fpfdcnn_export,
            summary: fpfdcnn_summary,
        }),
        _ => None,
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

/// What `train` says when a config's `model` has no trainer.
pub fn no_trainer(path: &Path, model: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "{}: no trainer for model = \"{model}\" (expected \"fpfdcnn\", \"sdfcnn\" or \"sweep\")",
        path.display()
    )
}

fn fpfdcnn_export(weights: &Path, target: &Path) -> Result<()> {
    let det = sdf_slam::fpfdcnn::inference::FpfdcnnDetector::load(
        weights,
        BackendKind::Flex,
        Default::default(),
    )?;
    sdf_slam::nn::weights::save_f16(det.model, target)
}

fn sdfcnn_export(weights: &Path, target: &Path) -> Result<()> {
    let p = sdf_slam::sdfcnn::inference::SdfcnnPredictor::load(weights, BackendKind::Flex)?;
    p.save_f16(target)
}

fn fpfdcnn_summary(
    trace: &mut ShapeTrace,
    [h, w]: [usize; 2],
    backend: BackendKind,
) -> anyhow::Result<(usize, usize)> {
    let device = backend.device()?;
    let model = FpfdcnnConfig::new()
        .init(&device)
        .context("building FPFDCNN")?;
    let out = model
        .forward_traced(Tensor::zeros([1, 1, h, w], &device), trace)
        .context("FPFDCNN forward")?;
    let fd = model.full_descriptors(out.descriptors, [h, w]);
    trace.record("FD", "bilinear", &fd);
    Ok((trainable_params(&model), model.num_params()))
}

fn sdfcnn_summary(
    trace: &mut ShapeTrace,
    [h, w]: [usize; 2],
    backend: BackendKind,
) -> anyhow::Result<(usize, usize)> {
    let device = backend.device()?;
    let model = SdfcnnConfig::new()
        .init(&device)
        .context("building SDFCNN")?;
    if h == 0 || w == 0 {
        anyhow::bail!("empty input size {h}x{w}");
    }
    model
        .forward_traced(Tensor::zeros([1, 3, h, w], &device), trace)
        .context("SDFCNN forward")?;
    Ok((trainable_params(&model), model.num_params()))
}
