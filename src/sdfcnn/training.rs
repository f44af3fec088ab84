//! SDFCNN trainer (Section V-C): eq. 21 on NYUv2 data, SGD with momentum at
//! 0.1 then 0.01, per-epoch validation with the paper's metrics (eqs 16-20), atomic
//! checkpoints and exact `--resume`.
//!
//! ```toml
//! model = "sdfcnn"
//! out = "runs/sdfcnn"
//! epochs = 500
//! batch_size = 20
//! [data]
//! train = [{ path = "datasets/nyuv2", split = "datasets/meta/nyuv2/splits_train_1based.txt" }]
//! val = [{ path = "datasets/nyuv2", split = "datasets/meta/nyuv2/splits_test_1based.txt" }]
//! [optimizer]
//! lr = 0.1
//! lr_steps = [[20, 0.01]]
//! ```
//!
//! Every section but `[data]` is optional; see [`SdfcnnTrainConfig`] for all fields. Unknown
//! fields are errors naming the file and line.
//!
//! Run folder: `config.toml`, `metrics.csv`, `loss.png`, `val_seg.png`, `val_depth.png`, and
//! `checkpoints/epoch-NNNN/{model.bpk, optimizer.bpk, state.json, config.toml}`
//! ([`crate::training::RunDir`]). A resumed run reloads the model (with batch-norm running
//! statistics), the optimizer state (momentum buffers, keyed by parameter id), the epoch and the
//! step, and draws the same data order ([`epoch_order`]) and augmentations
//! ([`batch_rng`]) as an uninterrupted run, so its loss curve continues the same numbers.
//!
//! Validation runs the network at `data.val_size` (default: the training size) on unaugmented
//! images; seg/depth metrics compare the outputs upsampled to that size with the targets
//! resized there by nearest neighbour. `eval seg` evaluates at the original resolution.

use burn::optim::decay::WeightDecayConfig;
use burn::optim::momentum::MomentumConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer, SgdConfig};
use burn::prelude::*;
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::data::{DataSource, SdfcnnBatch, SegDepthData, resolve};
use super::inference::load_weights;
use super::loss::{LossResolution, SdfcnnLossConfig};
use super::{Sdfcnn, SdfcnnConfig, SdfcnnOutput};
use crate::camera::toml_error;
use crate::dataset::augment::AugmentConfig;
use crate::error::{Error, Result};
use crate::metrics::{ConfusionMatrix, DepthAccumulator};
use crate::nn::{resize_bilinear, seeded_init};
use crate::training::{
    BackendKind, EpochRecord, RunDir, RunOptions, TrainState, batch_rng, check_finite,
    check_finite_epoch, epoch_order,
};

/// A complete SDFCNN training config (TOML).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SdfcnnTrainConfig {
    /// Must be `"sdfcnn"`.
    pub model: String,
    /// Run folder.
    pub out: PathBuf,
    /// Backend (`ndarray` or `flex`); `--backend` overrides it.
    #[serde(default)]
    pub backend: BackendKind,
    /// Seed of the initial weights, data order and augmentation.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Number of epochs; `--epochs` overrides it.
    pub epochs: usize,
    /// Images per step (the paper: 20).
    pub batch_size: usize,
    /// How many epoch checkpoints to keep (0 = all).
    #[serde(default = "default_keep")]
    pub keep_checkpoints: usize,
    /// Start from these weights instead of a random initialisation (ignored by `--resume`):
    /// a checkpoint of ours (`model.bpk`, its folder or a run folder; the whole network), or a
    /// `.safetensors` file of torchvision-named ImageNet MobileNetV2 weights (the encoder;
    /// see [`super::imagenet`]). The optimizer starts afresh.
    #[serde(default)]
    pub init: Option<PathBuf>,
    /// Training and validation data.
    pub data: DataConfig,
    /// Optimizer and learning-rate schedule.
    #[serde(default)]
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

fn default_keep() -> usize {
    3
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

/// Optimizer family.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OptimizerKind {
    /// SGD with momentum (the paper's recipe).
    #[default]
    Sgd,
    /// Adam.
    Adam,
}

/// `[optimizer]`: SGD with momentum 0.9 (PyTorch semantics: dampening 0), learning rate 0.1
/// for the first 20 epochs, then 0.01 (Section V-C), by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OptimizerConfig {
    /// `sgd` or `adam`.
    pub kind: OptimizerKind,
    /// Initial learning rate.
    pub lr: f64,
    /// `[epoch, lr]` pairs: from that many completed epochs on, use `lr`.
    pub lr_steps: Vec<(usize, f64)>,
    /// SGD momentum (0 = plain SGD).
    pub momentum: f64,
    /// SGD momentum dampening.
    pub dampening: f64,
    /// Nesterov momentum.
    pub nesterov: bool,
    /// L2 weight decay added to the gradient (0 = none; the paper gives no value).
    pub weight_decay: f64,
    /// Adam β1.
    pub beta1: f64,
    /// Adam β2.
    pub beta2: f64,
    /// Adam ε.
    pub epsilon: f64,
    /// Clip the gradient norm of each parameter to this value.
    pub grad_clip_norm: Option<f64>,
}

impl Default for OptimizerConfig {
    fn default() -> Self {
        OptimizerConfig {
            kind: OptimizerKind::Sgd,
            lr: 0.1,
            lr_steps: vec![(20, 0.01)],
            momentum: 0.9,
            dampening: 0.0,
            nesterov: false,
            weight_decay: 1e-4,
            beta1: 0.9,
            beta2: 0.999,
            epsilon: 1e-8,
            grad_clip_norm: None,
        }
    }
}

impl OptimizerConfig {
    /// Learning rate of epoch `epoch` (0-based).
    pub fn lr_at(&self, epoch: usize) -> f64 {
        self.lr_steps
            .iter()
            .filter(|(e, _)| *e <= epoch)
            .max_by_key(|(e, _)| *e)
            .map_or(self.lr, |(_, lr)| *lr)
    }

    /// The Burn optimizer.
    pub fn init(&self) -> ModuleOptimizer {
        let decay =
            (self.weight_decay > 0.0).then(|| WeightDecayConfig::new(self.weight_decay as f32));
        let clip = self
            .grad_clip_norm
            .map(|n| burn::grad_clipping::GradientClippingConfig::Norm(n as f32));
        match self.kind {
            OptimizerKind::Sgd => {
                let momentum = (self.momentum > 0.0).then(|| {
                    MomentumConfig::new()
                        .with_momentum(self.momentum)
                        .with_dampening(self.dampening)
                        .with_nesterov(self.nesterov)
                });
                SgdConfig::new()
                    .with_momentum(momentum)
                    .with_weight_decay(decay)
                    .with_gradient_clipping(clip)
                    .init()
            }
            OptimizerKind::Adam => AdamConfig::new()
                .with_beta_1(self.beta1 as f32)
                .with_beta_2(self.beta2 as f32)
                .with_epsilon(self.epsilon as f32)
                .with_weight_decay(decay)
                .with_grad_clipping(clip)
                .init(),
        }
    }

    fn validate(&self) -> std::result::Result<(), String> {
        let lrs = std::iter::once(self.lr).chain(self.lr_steps.iter().map(|s| s.1));
        if lrs.clone().any(|lr| !(lr > 0.0 && lr.is_finite())) {
            return Err("optimizer learning rates must be positive".into());
        }
        if !(0.0..1.0).contains(&self.momentum) || !(0.0..=1.0).contains(&self.dampening) {
            return Err("optimizer.momentum must be in [0, 1), dampening in [0, 1]".into());
        }
        if !(self.weight_decay >= 0.0 && self.weight_decay.is_finite())
            || self
                .grad_clip_norm
                .is_some_and(|c| !(c > 0.0 && c.is_finite()))
        {
            return Err("optimizer.weight_decay must be >= 0, grad_clip_norm > 0".into());
        }
        Ok(())
    }
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
    /// Parses and checks a config; errors name `path` (and the line).
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let cfg: SdfcnnTrainConfig = toml::from_str(text).map_err(|e| toml_error(path, text, e))?;
        cfg.validate().map_err(|m| Error::invalid(path, m))?;
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
        if self.data.train.is_empty() {
            return Err("[data] train lists no dataset folder".into());
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
        let sizes_ok = [
            Some(self.data.size),
            self.data.val_size,
            Some(self.network.inner_size),
        ]
        .iter()
        .flatten()
        .all(|s| s.iter().all(|&v| v <= MAX_SIDE));
        if !sizes_ok || self.batch_size > 4096 {
            return Err(format!(
                "image sizes must be at most {MAX_SIDE} pixels a side and batch_size at most 4096"
            ));
        }
        self.optimizer.validate()?;
        self.loss.validate()?;
        self.network
            .to_config()
            .init(&Device::flex())
            .map(|_| ())
            .map_err(|e| e.to_string())
    }
}

/// Loss sums over an epoch, weighted by batch size.
#[derive(Default)]
struct LossMeter {
    total: f64,
    seg: f64,
    depth: f64,
    samples: usize,
}

impl LossMeter {
    fn add(&mut self, [total, seg, depth]: [f64; 3], n: usize) {
        self.total += total * n as f64;
        self.seg += seg * n as f64;
        self.depth += depth * n as f64;
        self.samples += n;
    }

    fn mean(&self) -> [f64; 3] {
        let n = self.samples.max(1) as f64;
        [self.total / n, self.seg / n, self.depth / n]
    }

    fn record(&self, prefix: &str, values: &mut BTreeMap<String, f64>) {
        let [t, s, d] = self.mean();
        values.insert(format!("{prefix}_loss"), t);
        values.insert(format!("{prefix}_seg_loss"), s);
        values.insert(format!("{prefix}_depth_loss"), d);
    }
}

/// Trains SDFCNN as `config_text` (read from `config_path`) says, with the command-line
/// overrides `opts`.
pub fn run(config_path: &Path, config_text: &str, opts: &RunOptions) -> Result<()> {
    let cfg = SdfcnnTrainConfig::parse(config_text, config_path)?;
    let epochs = opts.epochs.unwrap_or(cfg.epochs);
    let backend = opts.backend.unwrap_or(cfg.backend);
    let out = opts.out.clone().unwrap_or_else(|| cfg.out.clone());
    let sources = |list: &[DataSource]| -> Vec<DataSource> {
        list.iter().map(|s| s.resolved(config_path)).collect()
    };
    let focal = cfg.network.depth_focal;
    let train = SegDepthData::open(&sources(&cfg.data.train))?.with_canonical(focal);
    let val = if cfg.data.val.is_empty() {
        None
    } else {
        Some(SegDepthData::open(&sources(&cfg.data.val))?.with_canonical(focal))
    };
    let init = cfg.init.as_ref().map(|p| resolve(p, config_path));
    if let Some(p) = &init
        && !p.exists()
    {
        return Err(Error::invalid(
            config_path,
            format!("init {} does not exist", p.display()),
        ));
    }

    let mut run = RunDir::prepare(&out, config_text, opts.resume)?;
    run.keep = cfg.keep_checkpoints;
    let device = backend.autodiff_device();
    let net = cfg.network.to_config();
    let model = net
        .init(&device)
        .map_err(|e| Error::invalid(config_path, e.to_string()))?;
    let mut model = seeded_init(model, cfg.seed);
    let mut optim = cfg.optimizer.init();
    let mut state = TrainState::default();
    if let (Some(init), false) = (&init, opts.resume) {
        model = initialise(model, init, &train, &cfg)?;
    }
    if opts.resume {
        let ck = run
            .latest()?
            .ok_or_else(|| Error::invalid(&run.root, "--resume: no checkpoint to resume from"))?;
        model = load_weights(model, &ck.model_path(), &ck.dir.join("config.toml"))?;
        let opt_path = ck.optimizer_path();
        optim = optim
            .load(&opt_path)
            .map_err(|e| Error::invalid(&opt_path, format!("cannot load optimizer state: {e}")))?;
        println!(
            "resuming {} from epoch {} (step {})",
            run.root.display(),
            ck.state.epoch,
            ck.state.step
        );
        state = ck.state;
        // metrics.csv as the checkpoint knows it (whatever a kill left there).
        write_history(&run, &state)?;
    }
    println!(
        "SDFCNN: {} training samples, {} validation samples, {} on {backend}, batch {}, epochs {}..{}",
        train.len(),
        val.as_ref().map_or(0, |v| v.len()),
        fmt_size(cfg.data.size),
        cfg.batch_size,
        state.epoch + 1,
        epochs
    );

    for epoch in state.epoch..epochs {
        let started = Instant::now();
        let lr = cfg.optimizer.lr_at(epoch);
        let order = epoch_order(train.len(), cfg.seed, epoch);
        let batches: Vec<&[usize]> = order.chunks(cfg.batch_size).collect();
        let bar = progress_bar(batches.len(), epoch, epochs, opts.quiet);
        let mut meter = LossMeter::default();
        for (b, chunk) in batches.iter().enumerate() {
            let mut rng = batch_rng(cfg.seed, epoch, b);
            let samples = train.load_batch(chunk, cfg.data.size, &cfg.data.augment, &mut rng)?;
            let batch = SdfcnnBatch::from_samples(&samples, &device)?;
            let out = forward(&model, batch.images, cfg.loss.resolution)?;
            let loss = cfg.loss.forward(out, batch.labels, batch.depth);
            let values = [&loss.total, &loss.seg, &loss.depth].map(scalar);
            check_finite(values[0], epoch, b, &run)?;
            let grads = GradientsParams::from_grads(loss.total.backward(), &model);
            model = optim.step(lr, model, grads);
            state.step += 1;
            meter.add(values, chunk.len());
            bar.inc(1);
            bar.set_message(format!("loss {:.4}", meter.mean()[0]));
        }
        bar.finish_and_clear();

        let mut values = BTreeMap::new();
        meter.record("train", &mut values);
        // `valid()` also folds the last batch-norm running-statistics update into the shared
        // state, so the checkpoint below holds it (a resumed run then continues exactly).
        let snapshot = model.valid();
        if let Some(val) = &val {
            let size = cfg.data.val_size.unwrap_or(cfg.data.size);
            validate(&snapshot, val, size, &cfg, &mut values)?;
        }
        check_finite_epoch(&snapshot, &values, epoch, &run)?;
        let record = EpochRecord {
            epoch: epoch + 1,
            lr,
            seconds: started.elapsed().as_secs_f64(),
            values,
        };
        println!("{}", epoch_line(&record, epochs));
        state.epoch = epoch + 1;
        state.history.push(record);
        write_history(&run, &state)?;
        run.save(&state, config_text, |dir| {
            let p = dir.join("model.bpk");
            model
                .clone()
                .save_file(&p)
                .map_err(|e| Error::invalid(&p, format!("cannot save model: {e}")))?;
            let p = dir.join("optimizer.bpk");
            optim
                .save(&p)
                .map_err(|e| Error::invalid(&p, format!("cannot save optimizer: {e}")))
        })?;
    }
    Ok(())
}

/// Loads `init` into `model`: ImageNet encoder weights from a `.safetensors` file (checked on
/// the first training images, see [`super::imagenet::bn_agreement`]) or a whole checkpoint.
fn initialise(
    model: Sdfcnn,
    init: &Path,
    train: &SegDepthData,
    cfg: &SdfcnnTrainConfig,
) -> Result<Sdfcnn> {
    let is_safetensors = init
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("safetensors"));
    if !is_safetensors {
        let (weights, config) = crate::nn::weights::resolve_checkpoint(init)?;
        println!("initialised from {}", weights.display());
        return load_weights(model, &weights, &config);
    }
    let (model, report) = super::imagenet::load_imagenet(model, init)?;
    // The mapping check: batch-norm input means against the stored running means.
    let n = train.len().min(cfg.batch_size.max(8));
    let indices: Vec<usize> = (0..n).map(|k| k * train.len() / n.max(1)).collect();
    let none = AugmentConfig::none();
    let samples = train.load_batch(&indices, cfg.data.size, &none, &mut batch_rng(0, 0, 0))?;
    let snapshot = model.clone().valid();
    let batch = SdfcnnBatch::from_samples(&samples, &model_device(&snapshot))?;
    let probe = snapshot
        .encoder_bn_probe(batch.images)
        .map_err(|e| Error::msg(e.to_string()))?;
    let r = super::imagenet::bn_agreement(&probe);
    let values: Vec<f64> = r.iter().map(|(_, v)| *v).collect();
    let stats = crate::metrics::Stats::of(&values);
    println!(
        "initialised the encoder from ImageNet weights {} ({} tensors; {} ignored): batch-norm \
         input means vs running means on {n} training images: median r = {:.3}, lowest {:.3} \
         ({} layers)",
        init.display(),
        report.loaded,
        report.ignored.len(),
        stats.map_or(f64::NAN, |s| s.median),
        stats.map_or(f64::NAN, |s| s.min),
        values.len()
    );
    Ok(model)
}

/// Network outputs at the loss resolution.
fn forward(model: &Sdfcnn, images: Tensor<4>, res: LossResolution) -> Result<SdfcnnOutput> {
    let out = match res {
        LossResolution::Quarter => model.forward_quarter(images),
        LossResolution::Full => model.forward(images),
    };
    out.map_err(|e| Error::msg(e.to_string()))
}

fn scalar(t: &Tensor<1>) -> f64 {
    t.clone().into_scalar::<f32>() as f64
}

/// Validation loss and the eqs 16-20 metrics of `model` on `data` at `size`, overall and for
/// each named source (`val_<name>_delta1`, ...). Depth metrics are in metres: predictions and
/// targets are taken back from the canonical camera ([`super::focal`]).
fn validate(
    model: &Sdfcnn,
    data: &SegDepthData,
    size: [usize; 2],
    cfg: &SdfcnnTrainConfig,
    values: &mut BTreeMap<String, f64>,
) -> Result<()> {
    let device = model_device(model);
    let indices = data.first_of_each(cfg.data.val_limit);
    let mut meter = LossMeter::default();
    let classes = cfg.network.num_classes;
    let mut confusion = ConfusionMatrix::new(classes);
    let mut depth_acc = DepthAccumulator::default();
    let mut per_source: Vec<(ConfusionMatrix, DepthAccumulator)> = (0..data.num_sources())
        .map(|_| (ConfusionMatrix::new(classes), DepthAccumulator::default()))
        .collect();
    let none = AugmentConfig::none();
    for chunk in indices.chunks(cfg.batch_size) {
        let samples = data.load_batch(chunk, size, &none, &mut batch_rng(0, 0, 0))?;
        let batch = SdfcnnBatch::from_samples(&samples, &device)?;
        let quarter = forward(model, batch.images, LossResolution::Quarter)?;
        let full = SdfcnnOutput {
            seg: resize_bilinear(quarter.seg.clone(), size),
            depth: resize_bilinear(quarter.depth.clone(), size),
        };
        let at_loss = match cfg.loss.resolution {
            LossResolution::Quarter => quarter,
            LossResolution::Full => full.clone(),
        };
        let loss = cfg.loss.forward(at_loss, batch.labels, batch.depth);
        meter.add(
            [&loss.total, &loss.seg, &loss.depth].map(scalar),
            chunk.len(),
        );
        let (labels, depth) = predictions(full)?;
        let mut offset = 0;
        for (s, &i) in samples.iter().zip(chunk) {
            let n = s.width * s.height;
            let pred_labels = &labels[offset..offset + n];
            let metres = |d: &[f32]| -> Vec<f32> { d.iter().map(|v| v / s.depth_factor).collect() };
            let (gt_depth, pred_depth) = (metres(&s.depth), metres(&depth[offset..offset + n]));
            confusion.add(&s.labels, pred_labels);
            depth_acc.add(&gt_depth, &pred_depth);
            if let Some(k) = data.source_of(i) {
                per_source[k].0.add(&s.labels, pred_labels);
                per_source[k].1.add(&gt_depth, &pred_depth);
            }
            offset += n;
        }
    }
    meter.record("val", values);
    record_metrics("val", &confusion, &depth_acc, values);
    for (k, (c, d)) in per_source.iter().enumerate() {
        if let Some(name) = data.source_name(k) {
            record_metrics(&format!("val_{name}"), c, d, values);
        }
    }
    Ok(())
}

/// `{prefix}_mpa`, `_miou`, `_pixel_acc` (when any pixel is labelled) and `{prefix}_rms`,
/// `_rel`, `_delta1..3` (when any has depth).
fn record_metrics(
    prefix: &str,
    confusion: &ConfusionMatrix,
    depth: &DepthAccumulator,
    values: &mut BTreeMap<String, f64>,
) {
    if confusion.per_class().iter().any(|c| c.gt_pixels > 0) {
        values.insert(format!("{prefix}_mpa"), confusion.mpa());
        values.insert(format!("{prefix}_miou"), confusion.miou());
        values.insert(format!("{prefix}_pixel_acc"), confusion.pixel_accuracy());
    }
    if let Some(m) = depth.finish() {
        values.insert(format!("{prefix}_rms"), m.rms);
        values.insert(format!("{prefix}_rel"), m.rel);
        values.insert(format!("{prefix}_delta1"), m.delta1);
        values.insert(format!("{prefix}_delta2"), m.delta2);
        values.insert(format!("{prefix}_delta3"), m.delta3);
    }
}

/// The device a model's parameters live on.
fn model_device(model: &Sdfcnn) -> Device {
    model
        .devices()
        .into_iter()
        .next()
        .unwrap_or_else(Device::flex)
}

/// Argmax labels (`u8`) and depth (metres) of full-resolution outputs, row-major per image.
pub(crate) fn predictions(out: SdfcnnOutput) -> Result<(Vec<u8>, Vec<f32>)> {
    let labels = out.seg.argmax(1).into_data().convert::<i64>();
    let labels = labels
        .as_slice::<i64>()
        .map_err(|e| Error::msg(format!("reading labels: {e:?}")))?
        .iter()
        .map(|&l| l.clamp(0, 254) as u8)
        .collect();
    let depth = out
        .depth
        .into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| Error::msg(format!("reading depth: {e:?}")))?;
    Ok((labels, depth))
}

fn progress_bar(len: usize, epoch: usize, epochs: usize, quiet: bool) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len as u64).with_prefix(format!("epoch {}/{epochs}", epoch + 1));
    if let Ok(style) =
        ProgressStyle::with_template("{prefix} [{bar:30}] {pos}/{len} {msg} ({elapsed}<{eta})")
    {
        bar.set_style(style.progress_chars("=> "));
    }
    bar
}

fn epoch_line(r: &EpochRecord, epochs: usize) -> String {
    let mut s = format!(
        "epoch {}/{epochs} lr {} ({:.1} s)",
        r.epoch, r.lr, r.seconds
    );
    for key in [
        "train_loss",
        "val_loss",
        "val_mpa",
        "val_miou",
        "val_rms",
        "val_rel",
        "val_delta1",
    ] {
        if let Some(v) = r.values.get(key) {
            s.push_str(&format!(" {key} {v:.4}"));
        }
    }
    // Named validation sources: their δ1 and REL (and MPA where labelled).
    for (key, v) in &r.values {
        let named = key.starts_with("val_") && key.matches('_').count() >= 2;
        let shown = ["_delta1", "_rel", "_mpa"].iter().any(|m| key.ends_with(m));
        if named && shown && !key.ends_with("_pixel_acc") {
            s.push_str(&format!(" {key} {v:.4}"));
        }
    }
    s
}

fn fmt_size([h, w]: [usize; 2]) -> String {
    format!("{w}x{h}")
}

fn write_history(run: &RunDir, state: &TrainState) -> Result<()> {
    let h = &state.history;
    h.write_csv(run.root.join("metrics.csv"))?;
    h.plot(
        run.root.join("loss.png"),
        "SDFCNN loss (eq. 21)",
        "loss",
        &["loss"],
        false,
    )?;
    h.plot(
        run.root.join("val_seg.png"),
        "Validation segmentation (eqs 16-17)",
        "score",
        &["val_mpa", "val_miou", "val_pixel_acc"],
        false,
    )?;
    h.plot(
        run.root.join("val_depth.png"),
        "Validation depth (eqs 18-20)",
        "value",
        &["val_rms", "val_rel", "val_delta"],
        false,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::training::RunDir;

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("sdf_sdfcnn_{name}_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("temp dir");
        d
    }

    /// A tiny network and data size: 2 fixture images at 32×48, batch 2.
    fn tiny_config(out: &Path, extra_optimizer: &str) -> String {
        format!(
            r#"model = "sdfcnn"
out = "{}"
epochs = 2
batch_size = 2
seed = 3
[data]
train = [{{ path = "datasets/fixtures/nyuv2" }}]
val = [{{ path = "datasets/fixtures/nyuv2" }}]
size = [32, 48]
val_limit = 2
[optimizer]
lr = 0.01
lr_steps = [[1, 0.005]]
{extra_optimizer}
[loss]
depth = "l1"
[network]
inner_size = [32, 48]
decoder_dim = 16
crp_stages = 2
"#,
            out.display()
        )
    }

    fn losses(run: &Path) -> Vec<f64> {
        let run = RunDir {
            root: run.to_path_buf(),
            keep: 0,
        };
        let state = run.latest().expect("readable").expect("a checkpoint").state;
        state
            .history
            .epochs
            .iter()
            .flat_map(|e| {
                [
                    e.values["train_loss"],
                    e.values["val_loss"],
                    e.values["val_rms"],
                ]
            })
            .collect()
    }

    fn quiet() -> RunOptions {
        RunOptions {
            quiet: true,
            ..Default::default()
        }
    }

    #[test]
    fn lr_schedule_and_optimizer_defaults_follow_the_paper() {
        let o = OptimizerConfig::default();
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
            "configs/sdfcnn.toml",
            "configs/sdfcnn_tiny.toml",
            "configs/sdfcnn_real.toml",
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

    #[test]
    fn resume_continues_exactly_and_checkpoints_load() {
        let root = tmp("resume");
        let (a, b) = (root.join("a"), root.join("b"));
        let cfg_path = root.join("tiny.toml");
        // Uninterrupted: 2 epochs.
        let text_a = tiny_config(&a, "");
        run(&cfg_path, &text_a, &quiet()).expect("run a");
        for f in [
            "metrics.csv",
            "loss.png",
            "val_seg.png",
            "val_depth.png",
            "config.toml",
        ] {
            assert!(a.join(f).is_file(), "{f}");
        }
        let csv = std::fs::read_to_string(a.join("metrics.csv")).expect("csv");
        assert!(
            csv.lines().count() == 3 && csv.contains("val_miou"),
            "{csv}"
        );
        // Interrupted after epoch 1, then resumed to 2.
        let text_b = tiny_config(&b, "");
        let one = RunOptions {
            epochs: Some(1),
            ..quiet()
        };
        run(&cfg_path, &text_b, &one).expect("run b, epoch 1");
        assert_eq!(losses(&b).len(), 3);
        let again = run(&cfg_path, &text_b, &quiet()).expect_err("needs --resume");
        assert!(again.to_string().contains("--resume"), "{again}");
        let resume = RunOptions {
            resume: true,
            ..quiet()
        };
        run(&cfg_path, &text_b, &resume).expect("resume b");
        let (la, lb) = (losses(&a), losses(&b));
        assert_eq!(la.len(), 6);
        for (x, y) in la.iter().zip(&lb) {
            assert!((x - y).abs() <= 1e-6 * x.abs().max(1.0), "{la:?} vs {lb:?}");
        }
        // The checkpoint's weights with another network config: a clear error naming both.
        let ck = RunDir {
            root: a.clone(),
            keep: 0,
        }
        .latest()
        .expect("readable")
        .expect("checkpoint");
        let other = SdfcnnConfig::new()
            .with_inner_size([32, 48])
            .with_decoder_dim(8)
            .init(&Device::flex())
            .expect("valid");
        let e = load_weights(other, &ck.model_path(), &ck.dir.join("config.toml"))
            .expect_err("shape mismatch");
        let msg = e.to_string();
        assert!(
            msg.contains("model.bpk") && msg.contains("config.toml"),
            "{msg}"
        );
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn imagenet_init_with_real_depth_sources() {
        let root = tmp("imagenet");
        let weights = root.join("mnv2.safetensors");
        crate::sdfcnn::imagenet::tests::write_fake_imagenet(&weights);
        let out = root.join("run");
        let text = tiny_config(&out, "")
            .replace("epochs = 2", &format!("epochs = 1\ninit = \"{}\"", weights.display()))
            .replace(
                "train = [{ path = \"datasets/fixtures/nyuv2\" }]",
                "train = [{ path = \"datasets/fixtures/nyuv2\" }, \
                 { path = \"datasets/fixtures/tum_fr1_rpy_head10\", camera = \"fr1\", frames = [0, 6], repeat = 2 }]",
            )
            .replace(
                "val = [{ path = \"datasets/fixtures/nyuv2\" }]",
                "val = [{ path = \"datasets/fixtures/tum_fr1_rpy_head10\", camera = \"fr1\", frames = [6, 10], name = \"tum\" }]",
            )
            .replace("[network]\n", "[network]\ndepth_focal = 0.8107\n");
        run(&root.join("init.toml"), &text, &quiet()).expect("trains");
        let state = RunDir {
            root: out.clone(),
            keep: 0,
        }
        .latest()
        .expect("readable")
        .expect("a checkpoint")
        .state;
        let values = &state.history.epochs[0].values;
        assert!(values["val_tum_delta1"] >= 0.0 && values["val_tum_rel"] > 0.0);
        // Depth-only validation data: no segmentation metrics.
        assert!(!values.contains_key("val_tum_mpa") && !values.contains_key("val_mpa"));
        let e = run(
            &root.join("init.toml"),
            &text.replace("mnv2.safetensors", "missing.safetensors"),
            &RunOptions {
                out: Some(root.join("run2")),
                ..quiet()
            },
        )
        .expect_err("missing init");
        assert!(e.to_string().contains("missing.safetensors"), "{e}");
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn nan_loss_stops_and_keeps_last_checkpoint() {
        let root = tmp("nan");
        let out = root.join("run");
        // Epoch 1 trains normally, epoch 2 at a learning rate that overflows.
        let text = tiny_config(&out, "").replace("[[1, 0.005]]", "[[1, 1e30]]");
        let e = run(&root.join("nan.toml"), &text, &quiet()).expect_err("diverges");
        let msg = e.to_string();
        assert!(
            msg.contains("at epoch 2") && msg.contains("epoch 1, is kept"),
            "{msg}"
        );
        assert_eq!(losses(&out).len(), 3, "epoch 1's checkpoint is the latest");
        std::fs::remove_dir_all(&root).ok();
    }
}
