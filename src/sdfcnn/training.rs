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
//! ([`crate::training::RunDir`]). The run itself is [`crate::training::fit`]'s, shared with
//! FPFDCNN: a resumed run reloads the model (with batch-norm running statistics), the
//! optimizer state (momentum buffers, keyed by parameter id), the epoch and the step, and
//! draws the same data order and augmentations as an uninterrupted run, so its loss curve
//! continues the same numbers.
//!
//! `[data] video` adds recordings with a trajectory, trained by the photometric loss of
//! [`super::photometric`] (weight `loss.photometric`; `train` may then be empty): a batch
//! draws from both, each sample weighing the same.
//!
//! Validation runs the network at `data.val_size` (default: the training size) on unaugmented
//! images; seg/depth metrics compare the outputs upsampled to that size with the targets
//! resized there by nearest neighbour. `eval seg` evaluates at the original resolution.

use burn::optim::GradientsParams;
use burn::prelude::*;
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;
use std::path::Path;

pub use super::config::{DataConfig, NetworkConfig, SdfcnnTrainConfig};
use super::data::{SdfcnnBatch, SegDepthData};
use super::inference::load_weights;
use super::loss::{LossParts, LossResolution};
use super::validation::validate;
use super::video::{VideoData, VideoSample};
use super::{Sdfcnn, SdfcnnOutput};
use crate::dataset::augment::{AugmentConfig, SegDepthSample};
use crate::error::{Error, Result};
use crate::nn::seeded_init;
use crate::training::fit::{Fit, Learner, Plot, Step, fit};
pub use crate::training::{OptimizerConfig, OptimizerKind};
use crate::training::{RunDir, RunOptions, batch_rng};

/// Trains SDFCNN as `config_text` (read from `config_path`) says, with the command-line
/// overrides `opts`.
pub fn run(config_path: &Path, config_text: &str, opts: &RunOptions) -> Result<()> {
    let mut cfg = SdfcnnTrainConfig::parse(config_text, config_path)?.resolved(config_path);
    opts.apply(
        &mut cfg.epochs,
        &mut cfg.backend,
        &mut cfg.devices,
        &mut cfg.out,
    );
    // A backend not compiled in, without a device, or not trusted to train fails before any
    // data is read.
    cfg.backend
        .check_training("SDFCNN")
        .map_err(|e| Error::invalid(config_path, e.to_string()))?;
    let devices = crate::nn::devices::training_devices(cfg.backend, &cfg.devices)
        .map_err(|e| Error::invalid(config_path, e.to_string()))?;
    train_on(cfg, config_path, opts, &devices)
}

/// [`run`] once the config is read and its devices are open (`devices[0]` holds the model).
fn train_on(
    cfg: SdfcnnTrainConfig,
    config_path: &Path,
    opts: &RunOptions,
    devices: &[Device],
) -> Result<()> {
    let device = devices[0].clone();
    let focal = cfg.network.depth_focal;
    let train = SegDepthData::open(&cfg.data.train)?.with_canonical(focal);
    let video = VideoData::open(&cfg.data.video)?.with_canonical(focal);
    let val = if cfg.data.val.is_empty() {
        None
    } else {
        Some(
            SegDepthData::open(&cfg.data.val)?
                .with_canonical(focal)
                .with_fixed_draws(),
        )
    };
    if let Some(p) = &cfg.init
        && !p.exists()
    {
        return Err(Error::invalid(
            config_path,
            format!("init {} does not exist", p.display()),
        ));
    }

    let model = cfg
        .network
        .to_config()
        .init(&device)
        .map_err(|e| Error::invalid(config_path, e.to_string()))?;
    let mut model = seeded_init(model, cfg.seed);
    // The starting weights are read before the run folder is made: a bad `init` file leaves
    // nothing behind.
    if let (Some(init), false) = (&cfg.init, opts.resume) {
        model = initialise(model, init, &train, &cfg)?;
    }
    // Saved with every default and the paths as read from here, so the copy beside a
    // checkpoint means the same wherever it is read from.
    let saved = toml::to_string_pretty(&cfg)?;
    // An older run's copy may hold the paths as written, relative to this config's folder.
    let mut run = RunDir::prepare_normalized(&cfg.out, &saved, opts.resume, |text, path| {
        let c = SdfcnnTrainConfig::parse(text, path)?.resolved(config_path);
        Ok(Some(toml::to_string_pretty(&c)?))
    })?;
    run.keep = cfg.keep_checkpoints;
    let videos = match video.median_baseline() {
        None => String::new(),
        Some(b) => {
            // Below a centimetre, a frame and its sources look at the scene from almost one
            // point: the photometric loss then constrains the depth little.
            if b < 0.01 {
                eprintln!(
                    "warning: the video frames are a median {:.1} mm from their sources: the \
                     photometric loss learns depth from the camera's translation; raise `gap`",
                    b * 1000.0
                );
            }
            format!(
                " and {} video frames ({:.1} cm from their sources)",
                video.len(),
                b * 100.0
            )
        }
    };
    println!(
        "SDFCNN: {} training samples{videos}, {} validation samples, {} on {}, batch {}, {} epochs -> {}",
        train.len(),
        val.as_ref().map_or(0, |v| v.len()),
        fmt_size(cfg.data.size),
        cfg.backend,
        cfg.batch_size,
        cfg.epochs,
        cfg.out.display()
    );
    let learner = SdfLearner {
        cfg: &cfg,
        train: &train,
        video: &video,
        val: val.as_ref(),
    };
    let setup = Fit {
        run: &run,
        config: &saved,
        seed: cfg.seed,
        epochs: cfg.epochs,
        batch_size: cfg.batch_size,
        accumulate: cfg.accumulate,
        devices,
        optimizer: &cfg.optimizer,
        resume: opts.resume,
        // Fine-tuning a trained SDFCNN (not an ImageNet start): is it better than before?
        validate_start: cfg.init.as_deref().is_some_and(|p| !is_safetensors(p)) && val.is_some(),
        quiet: opts.quiet,
    };
    fit(&learner, &setup, model)?;
    Ok(())
}

/// SDFCNN's part in [`fit`]: eq. 21 on labelled and depth-only samples, the paper's
/// metrics (eqs 16-20) on the validation sources.
struct SdfLearner<'a> {
    cfg: &'a SdfcnnTrainConfig,
    train: &'a SegDepthData,
    video: &'a VideoData,
    val: Option<&'a SegDepthData>,
}

/// A batch on the host: samples with targets (eq. 21) and video samples (photometric).
struct SdfBatch {
    supervised: Vec<SegDepthSample>,
    video: Vec<VideoSample>,
}

impl Learner for SdfLearner<'_> {
    type Model = Sdfcnn;

    fn name(&self) -> &'static str {
        "SDFCNN"
    }

    fn train_len(&self) -> usize {
        self.train.len() + self.video.len()
    }

    type Batch = SdfBatch;

    /// Indices from `train.len()` on are video samples.
    fn load(&self, ids: &[usize], rng: &mut ChaCha8Rng) -> Result<SdfBatch> {
        use rayon::prelude::*;
        let data = &self.cfg.data;
        let first_video = self.train.len();
        let (labelled, video): (Vec<usize>, Vec<usize>) =
            ids.iter().partition(|&&i| i < first_video);
        Ok(SdfBatch {
            supervised: self
                .train
                .load_batch(&labelled, data.size, &data.augment, rng)?,
            video: video
                .par_iter()
                .map(|&i| self.video.load(i - first_video, data.size))
                .collect::<Result<_>>()?,
        })
    }

    /// Eq. 21 on the samples with targets and the photometric loss on the video samples,
    /// weighted by their shares of the batch. The logged terms are each part's mean over its
    /// own samples (0 in a batch without any), so in a run mixing the two their epoch figures
    /// (averaged over all samples) are lower than the parts' own means.
    fn train_step(&self, model: &Sdfcnn, batch: SdfBatch) -> Result<Step> {
        let cfg = self.cfg;
        // The model's device: the run's, or one of its data-parallel devices.
        let device = model_device(model);
        let (k, m) = (batch.supervised.len(), batch.video.len());
        let n = (k + m) as f64;
        let mut terms = Vec::new();
        let mut total: Option<Tensor<1>> = None;
        let mut add = |part: Tensor<1>, share: f64| {
            let part = part * share;
            total = Some(match total.take() {
                Some(t) => t + part,
                None => part,
            });
        };
        if k > 0 {
            let b = SdfcnnBatch::from_samples(&batch.supervised, &device)?;
            let out = forward(model, b.images, cfg.loss.resolution)?;
            let loss = cfg.loss.forward(out, b.labels, b.depth);
            terms.extend(loss_terms(&loss));
            add(loss.total, k as f64 / n);
        } else if !self.train.is_empty() {
            terms.extend([("seg_loss", 0.0), ("depth_loss", 0.0)]);
        }
        if m > 0 {
            let (photo, smooth) = video_loss(model, &batch.video, &device)?;
            terms.extend([
                ("photo_loss", scalar(&photo)),
                ("smooth_loss", scalar(&smooth)),
            ]);
            let w = cfg.loss.photometric;
            add((photo + smooth * cfg.loss.smoothness) * w, m as f64 / n);
        } else if !self.video.is_empty() {
            terms.extend([("photo_loss", 0.0), ("smooth_loss", 0.0)]);
        }
        Ok(Step {
            terms,
            loss: total.ok_or_else(|| Error::msg("empty batch"))?,
            samples: k + m,
        })
    }

    fn validate(&self, model: &Sdfcnn, values: &mut BTreeMap<String, f64>) -> Result<()> {
        match self.val {
            Some(val) => {
                let size = self.cfg.data.val_size.unwrap_or(self.cfg.data.size);
                validate(model, val, size, self.cfg, values)
            }
            None => Ok(()),
        }
    }

    fn lr_groups(&self, model: &Sdfcnn, mut grads: GradientsParams) -> Vec<(f64, GradientsParams)> {
        let factor = self.cfg.encoder_lr;
        if factor == 1.0 {
            return vec![(1.0, grads)];
        }
        let encoder = model.take_encoder_grads(&mut grads);
        vec![(factor, encoder), (1.0, grads)]
    }

    fn plots(&self) -> &'static [Plot] {
        &[
            Plot {
                file: "loss.png",
                title: "SDFCNN loss (eq. 21)",
                y_label: "loss",
                keys: &["loss"],
                log_y: false,
            },
            Plot {
                file: "val_seg.png",
                title: "Validation segmentation (eqs 16-17)",
                y_label: "score",
                keys: &["val_mpa", "val_miou", "val_pixel_acc"],
                log_y: false,
            },
            Plot {
                file: "val_depth.png",
                title: "Validation depth (eqs 18-20)",
                y_label: "value",
                keys: &["val_rms", "val_rel", "val_delta"],
                log_y: false,
            },
        ]
    }

    fn summary(&self, values: &BTreeMap<String, f64>) -> String {
        epoch_summary(values)
    }
}

/// Loads `init` into `model`: ImageNet encoder weights from a `.safetensors` file (checked on
/// the first training images, see [`super::imagenet::bn_agreement`]) or a whole checkpoint.
fn initialise(
    model: Sdfcnn,
    init: &Path,
    train: &SegDepthData,
    cfg: &SdfcnnTrainConfig,
) -> Result<Sdfcnn> {
    if !is_safetensors(init) {
        let (weights, config) = crate::training::resolve_checkpoint(init)?;
        let model = load_weights(model, &weights, &config)?;
        println!("initialised from {}", weights.display());
        return Ok(model);
    }
    let (model, report) = super::imagenet::load_imagenet(model, init)?;
    // The mapping check: batch-norm input means against the stored running means.
    let n = train.len().min(cfg.batch_size.max(8));
    let indices: Vec<usize> = (0..n).map(|k| k * train.len() / n.max(1)).collect();
    let none = AugmentConfig::none();
    let samples = train.load_batch(&indices, cfg.data.size, &none, &mut batch_rng(0, 0, 0))?;
    let snapshot = model.clone().valid();
    let batch = SdfcnnBatch::from_samples(&samples, &model_device(&snapshot))?;
    let probe = snapshot.encoder_bn_probe(batch.images)?;
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

/// The photometric reprojection loss and the smoothness of video samples of one size
/// ([`super::photometric`]), the depth predicted at the input size and made metric.
fn video_loss(
    model: &Sdfcnn,
    samples: &[VideoSample],
    device: &Device,
) -> Result<(Tensor<1>, Tensor<1>)> {
    use super::photometric::{reprojection_loss, smoothness_loss};
    let n = samples.len();
    let [h, w] = samples[0].size;
    if samples.iter().any(|s| s.size != [h, w]) {
        return Err(Error::msg("batch samples differ in size"));
    }
    let images = |slot: usize| {
        let data: Vec<f32> = samples
            .iter()
            .flat_map(|s| s.images[slot].iter().copied())
            .collect();
        Tensor::<4>::from_data(TensorData::new(data, [n, 3, h, w]), device)
    };
    let rows = |f: &dyn Fn(&VideoSample) -> Vec<f32>, width: usize| {
        let data: Vec<f32> = samples.iter().flat_map(f).collect();
        Tensor::<2>::from_data(TensorData::new(data, [n, width]), device)
    };
    let target = images(0);
    let k = rows(&|s| s.k.to_vec(), 4);
    let sources = [
        (images(1), rows(&|s| s.poses[0].to_vec(), 12)),
        (images(2), rows(&|s| s.poses[1].to_vec(), 12)),
    ];
    let metric = rows(&|s| vec![s.metric], 1).reshape([n, 1, 1, 1]);
    let depth = model.forward(target.clone())?.depth * metric;
    let photo = reprojection_loss(target.clone(), depth.clone(), &sources, k);
    Ok((photo, smoothness_loss(depth, target)))
}

/// Network outputs at the loss resolution.
pub(super) fn forward(
    model: &Sdfcnn,
    images: Tensor<4>,
    res: LossResolution,
) -> Result<SdfcnnOutput> {
    let out = match res {
        LossResolution::Quarter => model.forward_quarter(images),
        LossResolution::Full => model.forward(images),
    };
    Ok(out?)
}

/// The logged parts of a loss (`seg_loss`, `depth_loss`, and `shape_loss` when computed): the
/// columns training and validation share in `metrics.csv`.
pub(super) fn loss_terms(loss: &LossParts) -> Vec<(&'static str, f64)> {
    let mut terms = vec![
        ("seg_loss", scalar(&loss.seg)),
        ("depth_loss", scalar(&loss.depth)),
    ];
    if let Some(g) = &loss.shape {
        terms.push(("shape_loss", scalar(g)));
    }
    terms
}

pub(super) fn scalar(t: &Tensor<1>) -> f64 {
    t.clone().into_scalar::<f32>() as f64
}

/// The device a model's parameters live on.
pub(super) fn model_device(model: &Sdfcnn) -> Device {
    crate::training::module_device(model)
}

/// The overall losses and metrics, then each named validation source's δ1, REL and MPA.
fn epoch_summary(values: &BTreeMap<String, f64>) -> String {
    let mut s = String::new();
    for key in [
        "train_loss",
        "val_loss",
        "val_mpa",
        "val_miou",
        "val_rms",
        "val_rel",
        "val_delta1",
    ] {
        if let Some(v) = values.get(key) {
            s.push_str(&format!(" {key} {v:.4}"));
        }
    }
    // Named validation sources: their δ1 and REL (and MPA where labelled).
    for (key, v) in values {
        let named = key.starts_with("val_") && key.matches('_').count() >= 2;
        let shown = ["_delta1", "_rel", "_mpa"].iter().any(|m| key.ends_with(m));
        if named && shown && !key.ends_with("_pixel_acc") {
            s.push_str(&format!(" {key} {v:.4}"));
        }
    }
    s.trim_start().to_string()
}

/// Whether `init` names ImageNet weights (a `.safetensors` file) rather than a checkpoint.
fn is_safetensors(init: &Path) -> bool {
    init.extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("safetensors"))
}

fn fmt_size([h, w]: [usize; 2]) -> String {
    format!("{w}x{h}")
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::nn::DeviceSpec;
    use crate::sdfcnn::SdfcnnConfig;
    use crate::training::RunDir;
    use burn::nn::conv::Conv2d;
    use std::path::PathBuf;

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("sdf_sdfcnn_{name}_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("temp dir");
        d
    }

    /// A tiny network and data size: 2 fixture images at 32×48, batch 2.
    pub(crate) fn tiny_config(out: &Path, extra_optimizer: &str) -> String {
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
    fn two_devices_train_as_one_with_twice_the_accumulation_and_their_checkpoints_resume_on_one() {
        // No second GPU here: flex (the model's device) and ndarray are two devices to Burn,
        // so each share of a batch trains on its own fork and its gradients cross devices.
        let root = tmp("devices");
        let cfg_path = root.join("tiny.toml");
        let (one, two, mixed) = (root.join("one"), root.join("two"), root.join("mixed"));
        // 12 samples in batches of 4, parts of 2: a batch norm over one sample at these sizes
        // sees two values a channel in the last layers, and its gradients are float noise.
        let accumulate = |out: &Path, parts: usize| {
            let mut text = tiny_config(out, "");
            for (from, to) in [
                ("batch_size = 2", "batch_size = 4"),
                ("lr = 0.01\n", "lr = 0.001\n"),
                (
                    r#"train = [{ path = "datasets/fixtures/nyuv2" }]"#,
                    r#"train = [{ path = "datasets/fixtures/nyuv2", repeat = 4 }]"#,
                ),
            ] {
                assert!(text.contains(from), "the tiny config no longer sets {from}");
                text = text.replace(from, to);
            }
            format!("accumulate = {parts}\nbackend = \"flex\"\n{text}")
        };
        run(&cfg_path, &accumulate(&one, 2), &quiet()).expect("one device");
        #[allow(deprecated)] // ndarray is deprecated upstream but the project's default.
        let devices = [Device::flex().autodiff(), Device::ndarray().autodiff()];
        let parse = |text: &str| {
            SdfcnnTrainConfig::parse(text, &cfg_path)
                .expect("parses")
                .resolved(&cfg_path)
        };
        train_on(parse(&accumulate(&two, 1)), &cfg_path, &quiet(), &devices).expect("two");
        // Epoch 1 on two devices, epoch 2 resumed from its checkpoint on one (two parts a
        // batch either way).
        let first = RunOptions {
            epochs: Some(1),
            ..quiet()
        };
        let mut cfg = parse(&accumulate(&mixed, 2));
        cfg.epochs = 1;
        train_on(cfg, &cfg_path, &first, &devices).expect("mixed, epoch 1");
        let resumed = RunOptions {
            resume: true,
            ..quiet()
        };
        run(&cfg_path, &accumulate(&mixed, 2), &resumed).expect("mixed, resumed on one");
        // The yardstick: the same run on ndarray alone, against flex alone. Each step's
        // float noise grows through the next ones (batch norms over two samples).
        let control = root.join("control");
        let on_ndarray =
            accumulate(&control, 2).replace("backend = \"flex\"", "backend = \"ndarray\"");
        run(&cfg_path, &on_ndarray, &quiet()).expect("control");
        let train_losses =
            |run: &Path| -> Vec<f64> { losses(run).into_iter().step_by(3).collect() };
        let (l1, l2, lm) = (train_losses(&one), train_losses(&two), train_losses(&mixed));
        let lc = train_losses(&control);
        eprintln!(
            "train losses: one device {l1:?}, two {l2:?}, two then one {lm:?}, ndarray {lc:?}"
        );
        assert_eq!(l1.len(), 2);
        for l in [&l2, &lm] {
            for ((x, y), c) in l1.iter().zip(l).zip(&lc) {
                assert!(
                    (x - y).abs() <= (4.0 * (x - c).abs()).max(1e-4),
                    "{l1:?} vs {l:?}"
                );
            }
        }
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn device_lists_that_cannot_train_are_refused_before_any_data_is_read() {
        let root = tmp("device_lists");
        let cfg_path = root.join("tiny.toml");
        // Data that does not exist: an error about it would mean the list was not checked first.
        let text = tiny_config(&root.join("out"), "").replace("datasets/fixtures/nyuv2", "missing");
        let spec = |s: &str| s.parse::<DeviceSpec>().expect("valid entry");
        for (backend, list, want) in [
            ("flex", vec!["flex"], "backend `flex` has one device"),
            (
                "ndarray",
                vec!["wgpu:0", "wgpu:1"],
                "set `backend = \"wgpu\"`",
            ),
            ("wgpu", vec!["wgpu:0", "cuda:0"], "cannot mix backends"),
        ] {
            let text = format!("backend = \"{backend}\"\n{text}");
            let opts = RunOptions {
                devices: Some(list.iter().map(|s| spec(s)).collect()),
                ..quiet()
            };
            let e = run(&cfg_path, &text, &opts)
                .expect_err("refused")
                .to_string();
            // Without the wgpu feature its own refusal comes first, also before the data.
            assert!(
                e.contains(want) || e.contains("not compiled into this binary"),
                "{e}"
            );
            assert!(!root.join("out").exists(), "{e}");
        }
        // What the list shows by itself is refused when the config is read (`--dry-run`).
        let mixed = format!("devices = [\"wgpu:0\", \"cuda:0\"]\n{text}");
        let e = SdfcnnTrainConfig::parse(&mixed, &cfg_path)
            .expect_err("mixed")
            .to_string();
        assert!(
            e.contains("devices: ") && e.contains("cannot mix backends"),
            "{e}"
        );
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn encoder_lr_slows_the_encoder_alone() {
        let root = tmp("encoder_lr");
        let cfg_path = root.join("tiny.toml");
        // The weights before training: the run's own seeded initialisation.
        let start = |text: &str| {
            let cfg = SdfcnnTrainConfig::parse(text, &cfg_path).expect("parses");
            let model = cfg
                .network
                .to_config()
                .init(&Device::flex())
                .expect("valid");
            seeded_init(model, cfg.seed)
        };
        let trained = |out: &Path, text: &str| {
            let one = RunOptions {
                epochs: Some(1),
                ..quiet()
            };
            run(&cfg_path, text, &one).expect("one epoch");
            let ck = RunDir {
                root: out.to_path_buf(),
                keep: 0,
            }
            .latest()
            .expect("readable")
            .expect("checkpoint");
            load_weights(start(text), &ck.model_path(), &ck.dir.join("config.toml")).expect("loads")
        };
        let moved = |a: &Conv2d, b: &Conv2d| -> f32 {
            let (a, b) = (a.weight.val(), b.weight.val());
            (a - b).abs().max().into_scalar::<f32>()
        };
        // How far one epoch moves the encoder (Layer1, Layer7's last projection) and the
        // decoder (Layer7_13) from the same start, at the schedule's rate and at a millionth.
        // Adam, whose steps do not scale with the gradient: this tiny network's Layer1 (batch
        // norm over a batch of one or two 32x48 images) gets gradients whose size swings by
        // orders of magnitude with float rounding, so SGD's steps there say little.
        let movement = |factor: f64| {
            let out = root.join(format!("run_{factor}"));
            let adam = "kind = \"adam\"";
            let text = format!("encoder_lr = {factor}\n{}", tiny_config(&out, adam));
            let (before, after) = (start(&text), trained(&out, &text));
            let encoder = [
                moved(&before.layer1.conv, &after.layer1.conv),
                moved(
                    &before.layer7_320.blocks[0].project.conv,
                    &after.layer7_320.blocks[0].project.conv,
                ),
            ];
            (encoder, moved(&before.conv8, &after.conv8))
        };
        let (full, full_decoder) = movement(1.0);
        let (slow, slow_decoder) = movement(1e-6);
        for (f, s) in full.iter().zip(&slow) {
            assert!(
                *f > 0.0 && *s < 1e-3 * f,
                "encoder moved {full:?} at 1, {slow:?} at 1e-6"
            );
        }
        assert!(
            full_decoder > 0.0 && slow_decoder > 0.5 * full_decoder,
            "decoder moved {full_decoder} at 1, {slow_decoder} at 1e-6"
        );
        let bad = format!("encoder_lr = 0\n{}", tiny_config(&root.join("bad"), ""));
        let e = run(&cfg_path, &bad, &quiet()).expect_err("zero factor");
        assert!(e.to_string().contains("encoder_lr"), "{e}");
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

    #[test]
    fn video_frames_train_by_the_photometric_loss_beside_labelled_images_or_alone() {
        let seq = "datasets/fixtures/tum_fr1_rpy_head10";
        let video = format!(
            "video = [{{ path = \"{seq}\", camera = \"fr1\", trajectory = \"{seq}/groundtruth.txt\", gap = 2 }}]"
        );
        let mixed = tmp("video_mixed");
        // Video alone fine-tunes a trained network: here the mixed run's.
        let alone_start = format!(
            "epochs = 1\ninit = \"{}\"",
            mixed.join("checkpoints/epoch-0001").display()
        );
        let alone = tmp("video_alone");
        for (name, root, train, start) in [
            (
                "mixed",
                &mixed,
                r#"train = [{ path = "datasets/fixtures/nyuv2" }]"#,
                "epochs = 1".to_string(),
            ),
            ("alone", &alone, "train = []", alone_start),
        ] {
            let text = tiny_config(root, "").replace("epochs = 2", &start).replace(
                r#"train = [{ path = "datasets/fixtures/nyuv2" }]"#,
                &format!("{video}\n{train}"),
            );
            let cfg_path = root.join("c.toml");
            std::fs::write(&cfg_path, &text).unwrap();
            run(&cfg_path, &text, &quiet()).expect(name);
            let csv = std::fs::read_to_string(root.join("metrics.csv")).unwrap();
            let (head, row) = (csv.lines().next().unwrap(), csv.lines().last().unwrap());
            let value = |key: &str| -> f64 {
                let i = head
                    .split(',')
                    .position(|k| k == key)
                    .unwrap_or_else(|| panic!("{key}: {head}"));
                row.split(',').nth(i).unwrap().parse().unwrap()
            };
            // Frames 2..7 have both sources two frames away: a photometric error of real
            // images, positive and below the largest possible (1).
            let photo = value("train_photo_loss");
            assert!(photo > 0.0 && photo < 1.0, "{name}: {photo}");
            assert!(value("train_loss").is_finite());
            assert_eq!(head.contains("train_seg_loss"), name == "mixed", "{head}");
        }
        // Without a trained start, video alone is refused before anything is read.
        let text = tiny_config(&alone, "").replace(
            r#"train = [{ path = "datasets/fixtures/nyuv2" }]"#,
            &format!("{video}\ntrain = []"),
        );
        let err = SdfcnnTrainConfig::parse(&text, &alone.join("c.toml")).unwrap_err();
        assert!(err.to_string().contains("needs init"), "{err}");
        std::fs::remove_dir_all(&mixed).ok();
        std::fs::remove_dir_all(&alone).ok();
    }

    #[test]
    fn a_trajectory_that_misses_the_frames_is_an_error_naming_it() {
        let root = tmp("video_no_poses");
        std::fs::create_dir_all(&root).unwrap();
        let trajectory = root.join("elsewhere.txt");
        std::fs::write(&trajectory, "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n").unwrap();
        let seq = "datasets/fixtures/tum_fr1_rpy_head10";
        let text = tiny_config(&root, "").replace(
            r#"train = [{ path = "datasets/fixtures/nyuv2" }]"#,
            &format!(
                "video = [{{ path = \"{seq}\", camera = \"fr1\", trajectory = \"{}\" }}]\ntrain = []",
                trajectory.display()
            ),
        )
        .replace("epochs = 2", "epochs = 2\ninit = \"weights/sdfcnn\"");
        let cfg_path = root.join("c.toml");
        std::fs::write(&cfg_path, &text).unwrap();
        let err = run(&cfg_path, &text, &quiet()).unwrap_err().to_string();
        assert!(
            err.contains("elsewhere.txt") && err.contains("has a pose"),
            "{err}"
        );
        std::fs::remove_dir_all(&root).ok();
    }

    /// A small `synth` config for streamed views.
    fn synth_config(root: &Path) -> PathBuf {
        let path = root.join("rooms.toml");
        std::fs::write(&path, "seed = 5\nresolution = \"64x48\"\n").unwrap();
        path
    }

    #[test]
    fn synthetic_views_are_drawn_afresh_with_their_own_focal_length() {
        use super::super::data::{DataSource, Set};
        let root = tmp("synth_stream");
        let mut source = DataSource::folder(synth_config(&root));
        source.samples = Some(3);
        source.focal = Some([400.0, 700.0]);
        let set = Set::open(&source).expect("a synth config as a source");
        assert_eq!(set.len(), 3);
        let ((rgb, depth, labels), fx) = set.load_drawn(0, 1).unwrap();
        let ((again, _, _), fx_again) = set.load_drawn(0, 1).unwrap();
        let ((other, _, _), _) = set.load_drawn(0, 2).unwrap();
        assert_eq!((rgb.width(), rgb.height()), (64, 48));
        assert_eq!((labels.width, labels.height), (64, 48));
        assert!(depth.unwrap().valid_fraction() > 0.5);
        // The same draw is the same view; another draw another room.
        assert!(rgb == again && fx == fx_again && rgb != other);
        // 400-700 px at 640 px width is 40-70 px at 64.
        assert!((40.0..=70.0).contains(&fx), "{fx}");
        // A synth config needs `samples`; `samples` and `focal` need a synth config.
        source.samples = None;
        let err = Set::open(&source).unwrap_err().to_string();
        assert!(err.contains("samples"), "{err}");
        let mut folder = DataSource::folder("datasets/fixtures/nyuv2");
        folder.focal = Some([400.0, 700.0]);
        let err = Set::open(&folder).unwrap_err().to_string();
        assert!(err.contains("focal is for synthetic sources"), "{err}");
        std::fs::remove_dir_all(&root).ok();
    }

    #[test]
    fn training_streams_synthetic_rooms() {
        let root = tmp("synth_train");
        let rooms = synth_config(&root);
        let text = tiny_config(&root, "")
            .replace("epochs = 2", "epochs = 1")
            .replace(
                r#"train = [{ path = "datasets/fixtures/nyuv2" }]"#,
                &format!(
                    "train = [{{ path = \"{}\", samples = 4, focal = [400, 700] }}]",
                    rooms.display()
                ),
            );
        let cfg_path = root.join("c.toml");
        std::fs::write(&cfg_path, &text).unwrap();
        run(&cfg_path, &text, &quiet()).expect("streamed training");
        let loss = losses(&root);
        assert!(
            loss.iter().all(|v| v.is_finite()) && loss[0] > 0.0,
            "{loss:?}"
        );
        std::fs::remove_dir_all(&root).ok();
    }
}
