//! FPFDCNN trainer: `train --config configs/train/fpfdcnn*.toml`.
//!
//! Adam on the ndarray backend by default (flex selectable), seeded data order
//! and augmentation, a progress bar, per-epoch metrics (`metrics.csv`,
//! `loss.png`, `accuracy.png`), an atomic checkpoint per epoch with the config
//! beside it, `--resume` from the last checkpoint (model, optimizer state,
//! epoch, data order), and a stop with a clear message if the loss is NaN.

pub use super::config::FpfdcnnTrainConfig;
use super::data::{FpBatch, FpDataset};
use super::loss::{descriptor_infonce, detector_bce, detector_cell_ce, sample_descriptors};
use super::model::Fpfdcnn;
use crate::error::{Error, Result};
use crate::training::{
    EpochRecord, RunDir, RunOptions, TrainState, batch_rng, check_finite, check_finite_epoch,
    epoch_order, non_finite_grads,
};
use burn::module::Module;
use burn::optim::grad_clipping::GradientClippingConfig;
use burn::optim::{AdamConfig, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use indicatif::{ProgressBar, ProgressStyle};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Instant;

/// Loss terms of one batch.
struct BatchLoss {
    total: Tensor<1>,
    detector: f64,
    localization: f64,
    descriptor: f64,
    accuracy: f64,
}

fn batch_loss(model: &Fpfdcnn, batch: FpBatch, cfg: &FpfdcnnTrainConfig) -> Result<BatchLoss> {
    let size = [cfg.height, cfg.width];
    let err = Error::from;
    let out_a = model.forward(batch.image_a).map_err(err)?;
    let out_b = model.forward(batch.image_b).map_err(err)?;
    let l = &cfg.loss;
    let cell = model.cell();
    let loc = (detector_cell_ce(out_a.logits, batch.target_a.clone(), cell)
        + detector_cell_ce(out_b.logits, batch.target_b.clone(), cell))
    .div_scalar(2.0);
    let det = (detector_bce(out_a.prob, batch.target_a, l.pos_weight)
        + detector_bce(out_b.prob, batch.target_b, l.pos_weight))
    .div_scalar(2.0);
    let mut desc_terms = Vec::new();
    let mut acc = 0.0;
    // A crop can hold fewer than two matches: nothing to contrast there.
    for (i, m) in batch
        .matches
        .iter()
        .enumerate()
        .filter(|(_, m)| m.len() >= 2)
    {
        let pa: Vec<[f32; 2]> = m.iter().map(|x| x.a).collect();
        let pb: Vec<[f32; 2]> = m.iter().map(|x| x.b).collect();
        let da = sample_descriptors(&out_a.descriptors, i, &pa, size);
        let db = sample_descriptors(&out_b.descriptors, i, &pb, size);
        let (t, a) = descriptor_infonce(da, db, &pb, l.tau, l.exclusion_px);
        desc_terms.push(t);
        acc += a as f64;
    }
    let n = desc_terms.len().max(1) as f64;
    let desc = if desc_terms.is_empty() {
        Tensor::<1>::zeros([1], &det.device())
    } else {
        Tensor::cat(desc_terms, 0).sum().div_scalar(n)
    };
    let detector = det.clone().into_scalar::<f32>() as f64;
    let localization = loc.clone().into_scalar::<f32>() as f64;
    let descriptor = desc.clone().into_scalar::<f32>() as f64;
    let total = det.mul_scalar(l.detector_weight)
        + loc.mul_scalar(l.localization_weight)
        + desc.mul_scalar(l.descriptor_weight);
    Ok(BatchLoss {
        total,
        detector,
        localization,
        descriptor,
        accuracy: acc / n,
    })
}

/// Trains FPFDCNN as the config says (see the module docs).
pub fn run(config_path: &Path, config_text: &str, opts: &RunOptions) -> Result<()> {
    let mut cfg = FpfdcnnTrainConfig::parse(config_text, config_path)?;
    if let Some(e) = opts.epochs {
        cfg.epochs = e;
    }
    if let Some(b) = opts.backend {
        cfg.backend = b;
    }
    if let Some(o) = &opts.out {
        cfg.out = o.clone();
    }
    // A backend not compiled in, without a device, or not trusted to train fails before
    // anything is read or written.
    cfg.backend
        .check_training("FPFDCNN")
        .map_err(|e| Error::invalid(config_path, e.to_string()))?;
    let device = cfg.backend.autodiff_device()?;
    let saved_text = toml::to_string_pretty(&cfg)?;
    let mut run = RunDir::prepare(&cfg.out, &saved_text, opts.resume)?;
    run.keep = cfg.keep_checkpoints;
    let log = |m: &str| {
        if !opts.quiet {
            eprintln!("{m}")
        }
    };
    log(&format!(
        "FPFDCNN training on {} -> {}",
        cfg.backend,
        cfg.out.display()
    ));
    let (train, val) = FpDataset::build(&cfg.data, [cfg.height, cfg.width], |m| {
        log(&format!("  data: {m}"))
    })?;
    log(&format!(
        "  {} training pairs ({} frames), {} validation pairs, {}x{}",
        train.pairs.len(),
        train.frames.len(),
        val.pairs.len(),
        cfg.width,
        cfg.height
    ));

    device.seed(cfg.seed);
    let (mut model, mut optim) = new_model(&cfg, &device, opts.resume, &log)?;
    let mut state = TrainState::default();
    if opts.resume {
        (model, optim, state) = resume(model, optim, &run, config_path, &log)?;
    }

    let trainer = Trainer {
        cfg: &cfg,
        run: &run,
        train: &train,
        device: &device,
        quiet: opts.quiet,
    };
    for epoch in state.epoch..cfg.epochs {
        let started = Instant::now();
        let lr = cfg.lr_at(epoch);
        let sums;
        (model, sums) = trainer.epoch(model, &mut optim, epoch, lr, &mut state)?;
        let mut values = BTreeMap::new();
        sums.insert("train", &mut values);
        if !val.pairs.is_empty() {
            validate(&model.valid(), &val, &cfg)?.insert("val", &mut values);
        }
        check_finite_epoch(&model, &values, epoch, &run)?;
        state.epoch = epoch + 1;
        state.history.push(EpochRecord {
            epoch: epoch + 1,
            lr,
            seconds: started.elapsed().as_secs_f64(),
            values: values.clone(),
        });
        let ckpt = run.save(&state, &saved_text, |dir| {
            model
                .clone()
                .save_file(dir.join("model.bpk"))
                .map_err(|e| Error::invalid(dir.join("model.bpk"), e.to_string()))?;
            optim
                .save(dir.join("optimizer.bpk"))
                .map_err(|e| Error::invalid(dir.join("optimizer.bpk"), e.to_string()))
        })?;
        write_history(&run, &state)?;
        let summary: Vec<String> = values.iter().map(|(k, v)| format!("{k} {v:.4}")).collect();
        log(&format!(
            "epoch {}/{} ({:.0} s, lr {lr}): {} -> {}",
            epoch + 1,
            cfg.epochs,
            started.elapsed().as_secs_f64(),
            summary.join(", "),
            ckpt.dir.display()
        ));
    }
    Ok(())
}

/// The network of `cfg` on `device` (from `cfg.init`'s weights unless resuming) and a fresh
/// Adam optimizer, clipping gradients by norm when `grad_clip_norm` is set.
fn new_model(
    cfg: &FpfdcnnTrainConfig,
    device: &Device,
    resuming: bool,
    log: &dyn Fn(&str),
) -> Result<(Fpfdcnn, ModuleOptimizer)> {
    let mut model = cfg.network().init(device)?;
    let mut adam = AdamConfig::new();
    if cfg.grad_clip_norm > 0.0 {
        adam = adam.with_grad_clipping(Some(GradientClippingConfig::Norm(
            cfg.grad_clip_norm as f32,
        )));
    }
    let optim = adam.init();
    if let (Some(init), false) = (&cfg.init, resuming) {
        let (weights, config) = crate::training::resolve_checkpoint(init)?;
        model = crate::nn::weights::load_into(model, &weights, "FPFDCNN", &config)?;
        log(&format!("  initialised from {}", weights.display()));
    }
    Ok((model, optim))
}

/// `--resume`: the model, optimizer state and training state of the run's last checkpoint;
/// `metrics.csv` is rewritten from that state.
fn resume(
    model: Fpfdcnn,
    optim: ModuleOptimizer,
    run: &RunDir,
    config_path: &Path,
    log: &dyn Fn(&str),
) -> Result<(Fpfdcnn, ModuleOptimizer, TrainState)> {
    let ckpt = run
        .latest()?
        .ok_or_else(|| Error::invalid(&run.root, "no checkpoint to resume"))?;
    let model = model.try_load_file(ckpt.model_path()).map_err(|e| {
        Error::invalid(
            ckpt.model_path(),
            format!("does not fit the FPFDCNN of {}: {e}", config_path.display()),
        )
    })?;
    let optim = optim
        .load(ckpt.optimizer_path())
        .map_err(|e| Error::invalid(ckpt.optimizer_path(), e.to_string()))?;
    let state = ckpt.state;
    // A kill between the checkpoint and its metrics line lost nothing: the state has it.
    state.history.write_csv(run.root.join("metrics.csv"))?;
    log(&format!(
        "  resumed after epoch {} ({})",
        state.epoch,
        ckpt.dir.display()
    ));
    Ok((model, optim, state))
}

/// What every training epoch of a run reads.
struct Trainer<'a> {
    cfg: &'a FpfdcnnTrainConfig,
    run: &'a RunDir,
    train: &'a FpDataset,
    device: &'a Device,
    quiet: bool,
}

impl Trainer<'_> {
    /// One epoch over the training pairs in the seeded order (at most `pairs_per_epoch`):
    /// the updated model and the epoch's loss sums. A batch with non-finite gradients is
    /// skipped; ten in a row stop the run, as a non-finite loss does.
    fn epoch(
        &self,
        mut model: Fpfdcnn,
        optim: &mut ModuleOptimizer,
        epoch: usize,
        lr: f64,
        state: &mut TrainState,
    ) -> Result<(Fpfdcnn, LossSums)> {
        let (cfg, run) = (self.cfg, self.run);
        let mut order = epoch_order(self.train.pairs.len(), cfg.seed, epoch);
        if cfg.pairs_per_epoch > 0 {
            order.truncate(cfg.pairs_per_epoch);
        }
        let batches: Vec<&[usize]> = order.chunks(cfg.batch_size).collect();
        let bar = epoch_bar(batches.len(), epoch, cfg.epochs, self.quiet)?;
        let mut sums = LossSums::default();
        let mut skipped = 0usize;
        for (bi, ids) in batches.iter().enumerate() {
            let mut rng = batch_rng(cfg.seed, epoch, bi);
            let batch = self.train.batch(
                ids,
                Some(&cfg.data.augment),
                cfg.loss.max_matches,
                &mut rng,
                self.device,
            )?;
            let l = batch_loss(&model, batch, cfg)?;
            let value = l.total.clone().into_scalar::<f32>() as f64;
            check_finite(value, epoch, bi, run)?;
            let grads = GradientsParams::from_grads(l.total.backward(), &model);
            let bad = non_finite_grads(&model, &grads);
            if !bad.is_empty() {
                // A rare batch can give infinite gradients (a saturated sigmoid, a
                // degenerate descriptor); skipping it keeps the weights finite.
                skipped += 1;
                bar.suspend(|| {
                    eprintln!(
                        "epoch {} batch {bi}: non-finite gradients in {} parameter tensors (shapes {:?}), step skipped",
                        epoch + 1,
                        bad.len(),
                        &bad[..bad.len().min(3)]
                    )
                });
                if skipped >= 10 {
                    check_finite(f64::NAN, epoch, bi, run)?;
                }
                bar.inc(1);
                continue;
            }
            skipped = 0;
            model = optim.step(lr, model, grads);
            state.step += 1;
            sums.add(value, &l);
            bar.inc(1);
            bar.set_message(format!(
                "loss {:.4} (det {:.4} loc {:.4} desc {:.4})",
                sums.mean(sums.total),
                sums.mean(sums.detector),
                sums.mean(sums.localization),
                sums.mean(sums.descriptor)
            ));
        }
        bar.finish_and_clear();
        Ok((model, sums))
    }
}

/// The progress bar of an epoch of `len` batches (hidden when `quiet`).
fn epoch_bar(len: usize, epoch: usize, epochs: usize, quiet: bool) -> Result<ProgressBar> {
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(len as u64)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "epoch {prefix} [{bar:30}] {pos}/{len} {msg} ({elapsed}<{eta})",
        )
        .map_err(Error::wrap)?
        .progress_chars("=> "),
    );
    bar.set_prefix(format!("{}/{epochs}", epoch + 1));
    Ok(bar)
}

/// `metrics.csv`, `loss.png` and `accuracy.png` of the run so far.
fn write_history(run: &RunDir, state: &TrainState) -> Result<()> {
    state.history.write_csv(run.root.join("metrics.csv"))?;
    state.history.plot(
        run.root.join("loss.png"),
        "FPFDCNN loss",
        "loss",
        &["loss", "detector", "localization", "descriptor"],
        true,
    )?;
    state.history.plot(
        run.root.join("accuracy.png"),
        "descriptor top-1 match (within pair)",
        "share",
        &["top1"],
        false,
    )
}

/// Validation loss terms and descriptor top-1 accuracy, without augmentation.
fn validate(model: &Fpfdcnn, val: &FpDataset, cfg: &FpfdcnnTrainConfig) -> Result<LossSums> {
    let device = cfg.backend.device()?;
    let model = model.clone().to_device(&device);
    let n = val.pairs.len();
    let keep = if cfg.val_pairs == 0 {
        n
    } else {
        cfg.val_pairs.min(n)
    };
    let ids: Vec<usize> = (0..keep).map(|k| k * n / keep.max(1)).collect();
    let mut sums = LossSums::default();
    for (bi, c) in ids.chunks(cfg.batch_size).enumerate() {
        let mut rng = batch_rng(cfg.seed, usize::MAX, bi);
        let batch = val.batch(c, None, cfg.loss.max_matches, &mut rng, &device)?;
        let r = batch_loss(&model, batch, cfg)?;
        sums.add(r.total.clone().into_scalar::<f32>() as f64, &r);
    }
    Ok(sums)
}

/// Sums of the loss terms over the batches of an epoch.
#[derive(Default)]
struct LossSums {
    batches: usize,
    total: f64,
    detector: f64,
    localization: f64,
    descriptor: f64,
    top1: f64,
}

impl LossSums {
    fn add(&mut self, total: f64, l: &BatchLoss) {
        self.batches += 1;
        self.total += total;
        self.detector += l.detector;
        self.localization += l.localization;
        self.descriptor += l.descriptor;
        self.top1 += l.accuracy;
    }

    fn mean(&self, sum: f64) -> f64 {
        sum / self.batches.max(1) as f64
    }

    /// The means as `{prefix}_loss`, `{prefix}_detector`, ... metrics.
    fn insert(&self, prefix: &str, values: &mut BTreeMap<String, f64>) {
        for (name, sum) in [
            ("loss", self.total),
            ("detector", self.detector),
            ("localization", self.localization),
            ("descriptor", self.descriptor),
            ("desc_top1", self.top1),
        ] {
            values.insert(format!("{prefix}_{name}"), self.mean(sum));
        }
    }
}
