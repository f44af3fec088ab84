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

use burn::optim::GradientsParams;
use burn::prelude::*;
use indicatif::{ProgressBar, ProgressStyle};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

pub use super::config::{
    DataConfig, NetworkConfig, OptimizerConfig, OptimizerKind, SdfcnnTrainConfig,
};
use super::data::{DataSource, SdfcnnBatch, SegDepthData, resolve};
use super::inference::load_weights;
use super::loss::LossResolution;
use super::validation::{LossMeter, validate};
use super::{Sdfcnn, SdfcnnOutput};
use crate::dataset::augment::AugmentConfig;
use crate::error::{Error, Result};
use crate::nn::seeded_init;
use crate::training::{
    EpochRecord, RunDir, RunOptions, TrainState, batch_rng, check_finite, check_finite_epoch,
    epoch_order,
};

/// Trains SDFCNN as `config_text` (read from `config_path`) says, with the command-line
/// overrides `opts`.
pub fn run(config_path: &Path, config_text: &str, opts: &RunOptions) -> Result<()> {
    let cfg = SdfcnnTrainConfig::parse(config_text, config_path)?;
    let epochs = opts.epochs.unwrap_or(cfg.epochs);
    let backend = opts.backend.unwrap_or(cfg.backend);
    // A backend not compiled in, without a device, or not trusted to train fails before any
    // data is read.
    backend
        .check_training("SDFCNN")
        .map_err(|e| Error::invalid(config_path, e.to_string()))?;
    let device = backend.autodiff_device()?;
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
        let (weights, config) = crate::training::resolve_checkpoint(init)?;
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

pub(super) fn scalar(t: &Tensor<1>) -> f64 {
    t.clone().into_scalar::<f32>() as f64
}

/// The device a model's parameters live on.
pub(super) fn model_device(model: &Sdfcnn) -> Device {
    model
        .devices()
        .into_iter()
        .next()
        .unwrap_or_else(Device::flex)
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
pub(crate) mod tests {
    use super::*;
    use crate::sdfcnn::SdfcnnConfig;
    use crate::training::RunDir;
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
