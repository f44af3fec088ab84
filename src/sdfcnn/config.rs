//! The SDFCNN training config (TOML): the run, `[data]`, `[optimizer]` (shared with FPFDCNN:
//! [`crate::training::optimizer`]; the paper's SGD recipe by default), `[network]`, and the
//! checks [`SdfcnnTrainConfig::parse`] makes. [`super::training`] runs it.

use burn::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

use super::SdfcnnConfig;
use super::data::DataSource;
use super::loss::SdfcnnLossConfig;
use crate::camera::toml_error;
use crate::dataset::augment::AugmentConfig;
use crate::error::Result;
use crate::nn::DeviceSpec;
use crate::training::{BackendKind, OptimizerConfig};

/// A complete SDFCNN training config (TOML).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SdfcnnTrainConfig {
    /// Must be `"sdfcnn"`.
    pub model: String,
    /// Run folder.
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
    /// Images per step (the paper: 20).
    pub batch_size: usize,
    /// Train each batch in this many parts with their gradients summed (gradient
    /// accumulation): the same step on a batch this many times smaller in memory. Batch
    /// normalisation then normalises each part by its own statistics.
    #[serde(default = "default_accumulate")]
    pub accumulate: usize,
    /// How many epoch checkpoints to keep (0 = all).
    #[serde(default = "default_keep")]
    pub keep_checkpoints: usize,
    /// Start from these weights instead of a random initialisation (ignored by `--resume`):
    /// a checkpoint of ours (`model.bpk`, its folder or a run folder; the whole network), or a
    /// `.safetensors` file of torchvision-named ImageNet MobileNetV2 weights (the encoder;
    /// see [`super::imagenet`]). The optimizer starts afresh.
    #[serde(default)]
    pub init: Option<PathBuf>,
    /// The encoder's learning rate (Layer1 … Layer7, the part `init` can take from
    /// ImageNet) as a factor of the schedule's; the decoder and the judge layers take the
    /// schedule's own. 1: one rate for all (the paper's); below 1 fine-tunes the pretrained
    /// encoder more gently than the new decoder learns.
    #[serde(default = "default_encoder_lr")]
    pub encoder_lr: f64,
    /// Training and validation data.
    pub data: DataConfig,
    /// Optimizer and learning-rate schedule (SGD with momentum, 0.1 then 0.01 after epoch
    /// 20: the paper's, unless the config says otherwise).
    #[serde(
        default = "OptimizerConfig::sgd_paper",
        deserialize_with = "optimizer_over"
    )]
    pub optimizer: OptimizerConfig,
    /// Eq. 21.
    #[serde(default)]
    pub loss: SdfcnnLossConfig,
    /// The network ([`SdfcnnConfig`] fields).
    #[serde(default)]
    pub network: NetworkConfig,
}

fn default_seed() -> u64 {
    42
}

fn default_encoder_lr() -> f64 {
    1.0
}

fn default_keep() -> usize {
    3
}

fn default_accumulate() -> usize {
    1
}

fn optimizer_over<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<OptimizerConfig, D::Error> {
    crate::training::optimizer::deserialize_over(d, OptimizerConfig::sgd_paper())
}

/// `[data]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    /// Training sources (all samples are used together, each source `repeat` times): NYU
    /// layouts (labels and depth) and TUM RGB-D sequences (depth only).
    pub train: Vec<DataSource>,
    /// Validation sources (none: no validation); named ones get their own metrics.
    #[serde(default)]
    pub val: Vec<DataSource>,
    /// Recordings with a trajectory whose colour frames train the depth by the photometric
    /// loss ([`super::video`], [`super::photometric`]), beside `train` (which may then be
    /// empty).
    #[serde(default)]
    pub video: Vec<super::video::VideoSource>,
    /// Training image size `[height, width]` the samples are cropped and resized to.
    #[serde(default = "default_size")]
    pub size: [usize; 2],
    /// Validation image size (default: `size`).
    #[serde(default)]
    pub val_size: Option<[usize; 2]>,
    /// Validate on at most this many samples of each source (its first ones).
    #[serde(default)]
    pub val_limit: Option<usize>,
    /// Augmentation of the training samples.
    #[serde(default)]
    pub augment: AugmentConfig,
}

fn default_size() -> [usize; 2] {
    [300, 400]
}

/// `[network]`: the [`SdfcnnConfig`] fields (Table 13 defaults).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NetworkConfig {
    /// Semantic classes.
    pub num_classes: usize,
    /// Layer0 output size `[height, width]`.
    pub inner_size: [usize; 2],
    /// Eq. 15 mean.
    pub mean: [f32; 3],
    /// Eq. 15 standard deviation.
    pub std: [f32; 3],
    /// Decoder width.
    pub decoder_dim: usize,
    /// Stages of each chained residual pooling.
    pub crp_stages: usize,
    /// The canonical camera's focal length in image widths: depth targets are scaled to it in
    /// training and predictions scaled back for the camera at inference
    /// ([`super::focal`]). `None`: depth in metres as is, whatever the camera.
    pub depth_focal: Option<f64>,
}

impl Default for NetworkConfig {
    fn default() -> Self {
        let c = SdfcnnConfig::new();
        NetworkConfig {
            num_classes: c.num_classes,
            inner_size: c.inner_size,
            mean: c.mean,
            std: c.std,
            decoder_dim: c.decoder_dim,
            crp_stages: c.crp_stages,
            depth_focal: None,
        }
    }
}

impl NetworkConfig {
    /// The model configuration.
    pub fn to_config(&self) -> SdfcnnConfig {
        SdfcnnConfig::new()
            .with_num_classes(self.num_classes)
            .with_inner_size(self.inner_size)
            .with_mean(self.mean)
            .with_std(self.std)
            .with_decoder_dim(self.decoder_dim)
            .with_crp_stages(self.crp_stages)
    }
}

impl SdfcnnTrainConfig {
    /// The config with its data sources and `init` resolved as read from `config_path`
    /// (relative to the working directory, else to the config's folder).
    pub fn resolved(mut self, config_path: &Path) -> Self {
        for list in [&mut self.data.train, &mut self.data.val] {
            for s in list.iter_mut() {
                *s = s.resolved(config_path);
            }
        }
        for s in self.data.video.iter_mut() {
            *s = s.resolved(config_path);
        }
        self.init = self.init.map(|p| super::data::resolve(&p, config_path));
        self
    }

    /// Parses and checks a config; errors name `path` (and the line).
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let cfg: SdfcnnTrainConfig = toml::from_str(text).map_err(|e| toml_error(path, text, e))?;
        cfg.validate()
            .map_err(|m| crate::io::config_error(path, text, m))?;
        Ok(cfg)
    }

    fn validate(&self) -> std::result::Result<(), String> {
        if self.model != "sdfcnn" {
            return Err(format!(
                "model = \"{}\" is not an SDFCNN config (model = \"sdfcnn\")",
                self.model
            ));
        }
        if self.batch_size == 0 {
            return Err("batch_size must be at least 1".into());
        }
        crate::nn::devices::check_entries(&self.devices).map_err(|e| format!("devices: {e}"))?;
        if !(self.encoder_lr > 0.0 && self.encoder_lr <= 10.0) {
            return Err(format!(
                "encoder_lr must be a factor in (0, 10], got {}",
                self.encoder_lr
            ));
        }
        if !(1..=self.batch_size).contains(&self.accumulate) {
            return Err(format!(
                "accumulate must be in 1..=batch_size ({}), got {}",
                self.batch_size, self.accumulate
            ));
        }
        if !(1..=100_000).contains(&self.epochs) {
            return Err(format!(
                "epochs must be in 1..=100000, got {} (0 would train nothing)",
                self.epochs
            ));
        }
        if self.data.size.iter().any(|&v| v < 16) || self.network.inner_size.iter().any(|&v| v < 32)
        {
            return Err(format!(
                "data.size {:?} must be at least 16 pixels a side and network.inner_size {:?} at \
                 least 32 (the encoder's stride)",
                self.data.size, self.network.inner_size
            ));
        }
        self.data
            .augment
            .validate()
            .map_err(|m| format!("data.{m}"))?;
        if self.data.train.is_empty() && self.data.video.is_empty() {
            return Err("[data] train lists no dataset folder (and video no recording)".into());
        }
        if self.data.train.is_empty() && self.init.is_none() {
            return Err("[data] train = [] (video alone) needs init = a trained SDFCNN: the photometric loss fine-tunes depth, it cannot start a network".into());
        }
        let imagenet = self.init.as_ref().and_then(|p| p.extension());
        if self.data.train.is_empty()
            && imagenet.is_some_and(|e| e.eq_ignore_ascii_case("safetensors"))
        {
            return Err("an ImageNet start (init = *.safetensors) needs [data] train: the photometric loss alone cannot teach the segmentation or a depth scale".into());
        }
        let sizes = [Some(self.data.size), self.data.val_size];
        if sizes.iter().flatten().any(|s| s.contains(&0)) {
            return Err("data sizes must be non-zero".into());
        }
        if self.network.num_classes == 0 || self.network.num_classes > 255 {
            return Err("network.num_classes must be in 1..=255 (255 is void)".into());
        }
        if let Some(f) = self.network.depth_focal
            && !(f > 0.05 && f < 20.0)
        {
            return Err(format!(
                "network.depth_focal {f} must be a focal length in image widths (0.05..20; NYUv2: 0.8107)"
            ));
        }
        const MAX_SIDE: usize = 8192;
        /// Data sources a config may list (each is opened and checked before training).
        const MAX_SOURCES: usize = 1000;
        let sizes: Vec<[usize; 2]> = [
            Some(self.data.size),
            self.data.val_size,
            Some(self.network.inner_size),
        ]
        .into_iter()
        .flatten()
        .collect();
        let sizes_ok = sizes.iter().all(|s| s.iter().all(|&v| v <= MAX_SIDE));
        if !sizes_ok || self.batch_size > 1024 {
            return Err(format!(
                "image sizes must be at most {MAX_SIDE} pixels a side and batch_size at most 1024"
            ));
        }
        // What one step holds in memory grows with the pixels it pushes through the network
        // (the paper's batch: 20 images of 480x640, 6.1 million pixels).
        const MAX_STEP_PIXELS: usize = 1 << 25;
        let step_images = self.batch_size.div_ceil(self.accumulate.max(1));
        let largest = sizes.iter().map(|[h, w]| h * w).max().unwrap_or(0);
        if step_images * largest > MAX_STEP_PIXELS {
            return Err(format!(
                "one step would push {step_images} images of up to {largest} pixels through the \
                 network ({:.1} million pixels; at most {:.1} million: lower batch_size, raise \
                 accumulate or shrink data.size / data.val_size / network.inner_size)",
                (step_images * largest) as f64 / 1e6,
                MAX_STEP_PIXELS as f64 / 1e6
            ));
        }
        self.optimizer.validate()?;
        let sources = self.data.train.len() + self.data.val.len() + self.data.video.len();
        if sources > MAX_SOURCES {
            return Err(format!(
                "[data] lists {sources} train, val and video sources, more than {MAX_SOURCES}"
            ));
        }
        self.loss.validate()?;
        self.network
            .to_config()
            .init(&Device::flex())
            .map(|_| ())
            .map_err(|e| e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sdfcnn::training::tests::tiny_config;

    #[test]
    fn lr_schedule_and_optimizer_defaults_follow_the_paper() {
        let o = SdfcnnTrainConfig::parse(&tiny_config(Path::new("x"), ""), Path::new("t.toml"))
            .unwrap()
            .optimizer;
        assert_eq!(o.weight_decay, OptimizerConfig::sgd_paper().weight_decay);
        let o = OptimizerConfig::sgd_paper();
        assert_eq!(
            (o.lr_at(0), o.lr_at(19), o.lr_at(20), o.lr_at(500)),
            (0.1, 0.1, 0.01, 0.01)
        );
        assert_eq!((o.momentum, o.dampening), (0.9, 0.0));
        let l = SdfcnnLossConfig::default();
        assert_eq!(l.lambda, 0.4);
    }

    #[test]
    fn shipped_configs_parse() {
        for p in [
            "configs/train/sdfcnn.toml",
            "configs/train/sdfcnn_tiny.toml",
            "configs/train/sdfcnn_real.toml",
        ] {
            let text = std::fs::read_to_string(p).expect("shipped config");
            let c = SdfcnnTrainConfig::parse(&text, Path::new(p)).expect("valid");
            assert_eq!(c.model, "sdfcnn");
        }
    }

    #[test]
    fn config_errors_name_file_and_line() {
        let text =
            tiny_config(Path::new("x"), "").replace("lr = 0.01", "lr = 0.01\nmomentun = 0.5");
        let e = SdfcnnTrainConfig::parse(&text, Path::new("bad.toml")).expect_err("typo");
        let msg = e.to_string();
        assert!(
            msg.starts_with("bad.toml:13:") && msg.contains("momentun"),
            "{msg}"
        );
        let text = tiny_config(Path::new("x"), "")
            .replace("lambda", "x")
            .replace("[loss]\n", "[loss]\nlambda = 2.0\n");
        let e = SdfcnnTrainConfig::parse(&text, Path::new("bad.toml")).expect_err("range");
        assert!(e.to_string().contains("lambda"), "{e}");
    }
}
