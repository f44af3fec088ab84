//! The fit loop both networks train with, as Burn's `Learner` runs `TrainStep` /
//! `ValidStep`: a network plugs in through [`Learner`] (the loss of a batch, its validation
//! metrics, its plots) and [`fit`] does the rest, the same way for every network:
//! - `--resume`: model, optimizer state, epoch, step and history from the run's last
//!   checkpoint; the seeded data order (`epoch_order`) and augmentation (`batch_rng`)
//!   make a resumed run continue the numbers of an uninterrupted one;
//! - a progress bar per epoch (hidden by `--quiet`; one line per epoch is always printed);
//! - the non-finite policy: a non-finite loss stops the run; a batch with non-finite
//!   gradients is skipped, ten in a row stop the run; an epoch whose weights or metrics are
//!   not finite is not saved (`check_finite_epoch`); every stop names the checkpoint kept;
//! - per epoch: `metrics.csv` and the network's plots, then an atomic checkpoint
//!   (`model.bpk`, `optimizer.bpk`, `state.json`, the run's config);
//! - data loading overlapped with the steps: a loader thread reads and augments the next
//!   `PREFETCH` batches ([`Learner::load`]) while the current one trains, as PyTorch's
//!   `DataLoader` workers do; the epoch line says how long loading took and how long the
//!   steps waited for it;
//! - data-parallel training over several devices ([`Fit::devices`]), with burn-train's
//!   gradient exchange (`GradientsParams::to_device`, `GradientsAccumulator`).

use super::{
    EpochRecord, OptimizerConfig, RunDir, TrainState, batch_rng, check_finite, check_finite_epoch,
    epoch_order, non_finite_grads,
};
use crate::error::{Error, Result};
use burn::module::Module;
use burn::optim::{GradientsAccumulator, GradientsParams, ModuleOptimizer};
use burn::prelude::*;
use indicatif::{ProgressBar, ProgressStyle};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// The loss of one training batch.
pub struct Step {
    /// The total loss, to back-propagate.
    pub loss: Tensor<1>,
    /// Its terms (and other per-batch figures) for the epoch means, e.g. `("seg_loss", x)`:
    /// recorded as `train_<name>` beside `train_loss`.
    pub terms: Vec<(&'static str, f64)>,
    /// The weight of its terms in the epoch means (the samples in the batch, or 1 for a
    /// network whose terms are batch means already).
    pub samples: usize,
}

/// A plot of the run's history written beside `metrics.csv` after every epoch.
pub struct Plot {
    /// File name in the run folder.
    pub file: &'static str,
    /// The chart's title.
    pub title: &'static str,
    /// Label of the y axis.
    pub y_label: &'static str,
    /// Every metric whose name contains one of these.
    pub keys: &'static [&'static str],
    /// Whether the y axis is logarithmic.
    pub log_y: bool,
}

/// What a network brings to [`fit`].
pub trait Learner {
    /// The network (on an autodiff device).
    type Model: Module;

    /// The network's name in messages, e.g. `"SDFCNN"`.
    fn name(&self) -> &'static str;

    /// Number of training samples (an epoch visits them in `epoch_order`).
    fn train_len(&self) -> usize;

    /// At most this many samples an epoch, the first of the seeded order (0: all).
    fn samples_per_epoch(&self) -> usize {
        0
    }

    /// One training batch as [`Learner::load`] leaves it: host memory, no device work, so
    /// that a loader thread can make it while the previous batch trains.
    type Batch: Send;

    /// Reads and augments the training samples `ids`, drawing every random choice from
    /// `rng` (seeded per batch, so the batch is the same whichever thread loads it).
    fn load(&self, ids: &[usize], rng: &mut ChaCha8Rng) -> Result<Self::Batch>;

    /// The loss of a loaded batch.
    fn train_step(&self, model: &Self::Model, batch: Self::Batch) -> Result<Step>;

    /// Adds the validation metrics (`val_*`) of `model` (in validation mode) to `values`.
    fn validate(&self, model: &Self::Model, values: &mut BTreeMap<String, f64>) -> Result<()>;

    /// The plots of the run folder.
    fn plots(&self) -> &'static [Plot];

    /// The batch's gradients split into learning-rate groups, each a factor on the
    /// scheduled rate and the gradients it applies to (fine-tuning a pretrained part more
    /// gently than a new one). Default: one group, every parameter at the scheduled rate.
    /// (Burn's `ModuleLearningRate` holds such groups too, but is only built by its own
    /// `ModuleLrScheduler`, not from the trainer's `OptimizerConfig::lr_at` schedule.)
    fn lr_groups(
        &self,
        _model: &Self::Model,
        grads: GradientsParams,
    ) -> Vec<(f64, GradientsParams)> {
        vec![(1.0, grads)]
    }

    /// The end-of-epoch line's metrics (default: all of them).
    fn summary(&self, values: &BTreeMap<String, f64>) -> String {
        let parts: Vec<String> = values.iter().map(|(k, v)| format!("{k} {v:.4}")).collect();
        parts.join(", ")
    }
}

/// The settings of a run every network shares (the training config's skeleton).
pub struct Fit<'a> {
    /// The run folder, where checkpoints and metrics go.
    pub run: &'a RunDir,
    /// The config saved beside every checkpoint.
    pub config: &'a str,
    /// Seed of the data order and of each batch's random choices.
    pub seed: u64,
    /// Number of epochs.
    pub epochs: usize,
    /// Training samples per step.
    pub batch_size: usize,
    /// Each batch in this many parts, trained one after the other with their gradients
    /// summed before the step: peak memory of a batch this many times smaller.
    pub accumulate: usize,
    /// Data-parallel training: the parts of a batch (`accumulate` of them, or one per device
    /// where there are more devices) go to these devices in rounds; each trains its part on a
    /// fork of the model and sends its gradients to the first device (the model's, which
    /// holds the optimizer) to be summed before the step, as burn-train's multi-device
    /// strategy does. Empty or one device: the model's.
    pub devices: &'a [Device],
    /// Optimizer and learning-rate schedule.
    pub optimizer: &'a OptimizerConfig,
    /// Continue from the run's last checkpoint (the model given is then only its shape).
    pub resume: bool,
    /// Validate the model given before the first epoch (a fresh run that fine-tunes trained
    /// weights): epoch 0 of the history, compared with the best epoch at the end.
    pub validate_start: bool,
    /// Hide the progress bar.
    pub quiet: bool,
}

/// Per-batch figures summed over an epoch, weighted by samples.
#[derive(Debug, Default)]
pub(crate) struct Meter {
    sums: Vec<(&'static str, f64)>,
    samples: usize,
}

impl Meter {
    /// Adds one batch's figures.
    pub fn add(&mut self, terms: &[(&'static str, f64)], samples: usize) {
        for &(name, v) in terms {
            match self.sums.iter_mut().find(|s| s.0 == name) {
                Some(s) => s.1 += v * samples as f64,
                None => self.sums.push((name, v * samples as f64)),
            }
        }
        self.samples += samples;
    }

    /// The mean of `name` (0 before any batch).
    pub fn mean(&self, name: &str) -> f64 {
        let sum = self.sums.iter().find(|s| s.0 == name).map_or(0.0, |s| s.1);
        sum / self.samples.max(1) as f64
    }

    /// The means as `{prefix}_{name}`; `{prefix}_loss` always (NaN when no batch added
    /// one, which [`check_finite_epoch`] then refuses to save).
    pub fn record(&self, prefix: &str, values: &mut BTreeMap<String, f64>) {
        if self.samples == 0 {
            values.insert(format!("{prefix}_loss"), f64::NAN);
        }
        for &(name, _) in &self.sums {
            values.insert(format!("{prefix}_{name}"), self.mean(name));
        }
    }

    fn line(&self) -> String {
        let parts: Vec<String> = self
            .sums
            .iter()
            .map(|&(name, _)| format!("{name} {:.4}", self.mean(name)))
            .collect();
        parts.join(" ")
    }
}

/// Trains `model` as `fit` says (see the module docs) and returns it after the last epoch.
pub fn fit<L: Learner + Sync>(learner: &L, fit: &Fit, model: L::Model) -> Result<L::Model> {
    let mut optim = fit.optimizer.init();
    let (mut model, mut state) = (model, TrainState::default());
    if fit.resume {
        (model, optim, state) = resume(learner, fit, model, optim)?;
    } else if fit.validate_start {
        let mut values = BTreeMap::new();
        learner.validate(&model.valid(), &mut values)?;
        println!(
            "epoch 0 (the starting weights): {}",
            learner.summary(&values)
        );
        state.history.start = Some(values);
    }
    for epoch in state.epoch..fit.epochs {
        let started = Instant::now();
        let lr = fit.optimizer.lr_at(epoch);
        let (meter, loading);
        (model, meter, loading) =
            train_epoch(learner, fit, model, &mut optim, epoch, lr, &mut state)?;
        let mut values = BTreeMap::new();
        meter.record("train", &mut values);
        // `valid()` also folds the last batch-norm running-statistics update into the
        // shared state, so the checkpoint below holds it (a resumed run continues exactly).
        let snapshot = model.valid();
        learner.validate(&snapshot, &mut values)?;
        check_finite_epoch(&snapshot, &values, epoch, fit.run)?;
        let summary = learner.summary(&values);
        state.epoch = epoch + 1;
        state.history.push(EpochRecord {
            epoch: epoch + 1,
            lr,
            seconds: started.elapsed().as_secs_f64(),
            values,
        });
        let ckpt = fit.run.save(&state, fit.config, |dir| {
            let path = dir.join("model.bpk");
            model
                .clone()
                .save_file(&path)
                .map_err(|e| Error::invalid(&path, format!("cannot save the model: {e}")))?;
            let path = dir.join("optimizer.bpk");
            optim
                .save(&path)
                .map_err(|e| Error::invalid(&path, format!("cannot save the optimizer: {e}")))
        })?;
        write_history(learner, &fit.run.root, &state)?;
        println!(
            "epoch {}/{} ({:.0} s, lr {lr}; {loading}): {summary} -> {}",
            epoch + 1,
            fit.epochs,
            started.elapsed().as_secs_f64(),
            ckpt.dir.display()
        );
    }
    if let Some(start) = state.history.start.as_ref().and_then(|v| v.get("val_loss"))
        && let Some((0, _)) = state.history.best("val_loss", false)
    {
        println!(
            "the starting weights validate better than every epoch (val_loss {start:.4}): \
             training did not improve them on the validation data; keep them"
        );
    }
    Ok(model)
}

/// Batches the loader thread may have ready ahead of the step (each is one batch of
/// decoded, augmented samples in host memory).
pub(crate) const PREFETCH: usize = 2;

/// How an epoch's data loading went: the loader thread's time, and how long the steps
/// waited for it (the part loading added to the epoch).
#[derive(Debug, Default, Clone, Copy)]
pub struct Loading {
    /// Time the loader thread spent loading batches.
    pub load: Duration,
    /// Time the steps waited for the loader.
    pub wait: Duration,
}

impl std::fmt::Display for Loading {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "data {:.1} s, waited {:.1} s",
            self.load.as_secs_f64(),
            self.wait.as_secs_f64()
        )
    }
}

/// One epoch over the training samples in the seeded order: the updated model, the epoch's
/// sums and its loading times. Batches are loaded on a scoped thread, at most [`PREFETCH`]
/// ahead; an error on either side ends both.
fn train_epoch<L: Learner + Sync>(
    learner: &L,
    fit: &Fit,
    model: L::Model,
    optim: &mut ModuleOptimizer,
    epoch: usize,
    lr: f64,
    state: &mut TrainState,
) -> Result<(L::Model, Meter, Loading)> {
    let mut order = epoch_order(learner.train_len(), fit.seed, epoch);
    if learner.samples_per_epoch() > 0 {
        order.truncate(learner.samples_per_epoch());
    }
    let batches: Vec<&[usize]> = order.chunks(fit.batch_size.max(1)).collect();
    // Each batch in `split` shares of at most `part` samples (the last batch may have
    // fewer): `accumulate` of them, or one per device where there are more devices; the
    // devices take them in rounds. Share `m` of batch `bi` draws from generator
    // `bi * split + m`, so a run computes the same on any number of devices up to
    // `accumulate`, and `n` devices with less the same as one with `accumulate = n`.
    let devices = fit.devices.len().max(1);
    let split = fit.accumulate.max(devices).clamp(1, fit.batch_size.max(1));
    let part = fit.batch_size.max(1).div_ceil(split);
    let parts: Vec<(usize, usize, &[usize])> = batches
        .iter()
        .enumerate()
        .flat_map(|(bi, ids)| {
            ids.chunks(part)
                .enumerate()
                .map(move |(m, p)| (bi, bi * split + m, p))
        })
        .collect();
    let bar = progress_bar(batches.len(), epoch, fit.epochs, fit.quiet);
    let mut meter = Meter::default();
    let mut loading = Loading::default();
    let mut skipped = 0usize;
    let model = std::thread::scope(|scope| -> Result<L::Model> {
        let mut model = model;
        let (tx, rx) = mpsc::sync_channel::<(Result<L::Batch>, Duration)>(PREFETCH);
        let (seed, to_load) = (fit.seed, &parts);
        scope.spawn(move || {
            for &(_, stream, ids) in to_load {
                let started = Instant::now();
                let batch = learner.load(ids, &mut batch_rng(seed, epoch, stream));
                let failed = batch.is_err();
                // A closed channel means the step side stopped (an error): stop too.
                if tx.send((batch, started.elapsed())).is_err() || failed {
                    break;
                }
            }
        });
        let mut next = 0;
        for (bi, ids) in batches.iter().enumerate() {
            // The batch's gradient: its parts' gradients, each weighted by its share of the
            // batch's samples, summed (a batch in one part: its gradient as it is).
            let mut accumulator = GradientsAccumulator::<L::Model>::new();
            let mut part_terms = Vec::new();
            while next < parts.len() && parts[next].0 == bi {
                // One round: a share for each device (fewer at the batch's end).
                let mut round = Vec::with_capacity(devices);
                while round.len() < devices && next < parts.len() && parts[next].0 == bi {
                    let share = parts[next].2.len() as f32 / ids.len() as f32;
                    next += 1;
                    let waiting = Instant::now();
                    let (batch, load) = rx.recv().map_err(|_| {
                        Error::msg(format!(
                            "epoch {} batch {bi}: the data loader thread stopped",
                            epoch + 1
                        ))
                    })?;
                    loading.wait += waiting.elapsed();
                    loading.load += load;
                    round.push((batch?, share));
                }
                for (value, terms, samples, grads) in
                    train_round(learner, &model, fit.devices, round)?
                {
                    check_finite(value, epoch, bi, fit.run)?;
                    part_terms.push((terms, samples));
                    accumulator.accumulate(&model, grads);
                }
            }
            let grads = accumulator.grads();
            let bad = non_finite_grads(&model, &grads);
            bar.inc(1);
            if !bad.is_empty() {
                // A rare batch can give infinite gradients (a saturated sigmoid, a degenerate
                // descriptor); skipping it keeps the weights finite.
                skipped += 1;
                bar.suspend(|| {
                    eprintln!(
                        "epoch {} batch {bi}: non-finite gradients in {} parameter tensors \
                         (shapes {:?}), step skipped",
                        epoch + 1,
                        bad.len(),
                        &bad[..bad.len().min(3)]
                    )
                });
                if skipped >= 10 {
                    return Err(Error::msg(format!(
                        "epoch {} batch {bi}: ten batches in a row had non-finite gradients: \
                         training stopped; {}. Lower the learning rate or check the data.",
                        epoch + 1,
                        super::kept_checkpoint(fit.run)
                    )));
                }
                continue;
            }
            skipped = 0;
            for (factor, group) in learner.lr_groups(&model, grads) {
                model = optim.step(lr * factor, model, group);
            }
            state.step += 1;
            for (terms, samples) in &part_terms {
                meter.add(terms, *samples);
            }
            bar.set_message(meter.line());
        }
        Ok(model)
    })?;
    bar.finish_and_clear();
    Ok((model, meter, loading))
}

/// A share's loss, its terms for the epoch means, its sample weight and its gradients (on
/// the model's device, scaled by the share of the batch).
type ShareOutput = (f64, Vec<(&'static str, f64)>, usize, GradientsParams);

/// The loss and gradients of one share of a batch on `model` as it is.
fn train_share<L: Learner>(
    learner: &L,
    model: &L::Model,
    batch: L::Batch,
    share: f32,
) -> Result<ShareOutput> {
    let step = learner.train_step(model, batch)?;
    let value = step.loss.clone().into_scalar::<f32>() as f64;
    let mut terms = vec![("loss", value)];
    terms.extend(step.terms);
    let loss = if share < 1.0 {
        step.loss.mul_scalar(share)
    } else {
        step.loss
    };
    let grads = GradientsParams::from_grads(loss.backward(), model);
    Ok((value, terms, step.samples, grads))
}

/// One share per device trained at once (share `j` on device `j`, each on a fork of `model`
/// there), their gradients moved to `model`'s device: burn-train's multi-device step
/// (`MultiDevicesTrainStep`, `GradientsParams::to_device`), inside this loop so that the
/// schedule, checkpoints and non-finite policy stay the same. One share on one device: the
/// model itself.
fn train_round<L: Learner + Sync>(
    learner: &L,
    model: &L::Model,
    devices: &[Device],
    round: Vec<(L::Batch, f32)>,
) -> Result<Vec<ShareOutput>> {
    if devices.len() <= 1 {
        return round
            .into_iter()
            .map(|(batch, share)| train_share(learner, model, batch, share))
            .collect();
    }
    let main = &devices[0];
    let outputs = std::thread::scope(|scope| {
        let handles: Vec<_> = round
            .into_iter()
            .zip(devices)
            .map(|((batch, share), device)| {
                let fork = model.clone().fork(device);
                scope.spawn(move || {
                    let (value, terms, samples, grads) = train_share(learner, &fork, batch, share)?;
                    Ok((value, terms, samples, grads.to_device(main, &fork)))
                })
            })
            .collect();
        handles
            .into_iter()
            .zip(devices)
            .map(|(h, device)| {
                h.join().unwrap_or_else(|panic| {
                    let why = crate::error::panic_message(panic.as_ref()).unwrap_or_default();
                    Err(Error::msg(format!(
                        "the training step on device {device:?} failed: {why}"
                    )))
                })
            })
            .collect()
    });
    // Batch norms' running statistics are shared by the forks (Burn's `RunningState`): each
    // thread left its update, and the last fork moved the value to its device. Fold the
    // updates (their mean, as in burn-train's multi-device runs) and bring the value back.
    drop(model.valid());
    drop(model.clone().to_device(main));
    outputs
}

/// `--resume`: the model, optimizer state and training state of the run's last checkpoint;
/// `metrics.csv` and the plots are rewritten from that state (a kill between a checkpoint
/// and its metrics line lost nothing). The checkpoint must be one this run can continue: at
/// most `fit.epochs` epochs done, and an optimizer state of this network
/// ([`check_optimizer_state`]).
fn resume<L: Learner>(
    learner: &L,
    fit: &Fit,
    model: L::Model,
    optim: ModuleOptimizer,
) -> Result<(L::Model, ModuleOptimizer, TrainState)> {
    let run = fit.run;
    let ckpt = run
        .latest()?
        .ok_or_else(|| Error::invalid(&run.root, "--resume: no checkpoint to resume from"))?;
    if ckpt.state.epoch > fit.epochs {
        return Err(Error::invalid(
            ckpt.dir.join("state.json"),
            format!(
                "--resume: this checkpoint has {} epochs done, more than the {} the run is to \
                 train: nothing to continue (give --epochs {} or more to train further)",
                ckpt.state.epoch,
                fit.epochs,
                ckpt.state.epoch + 1
            ),
        ));
    }
    let model = crate::nn::weights::load_into(
        model,
        &ckpt.model_path(),
        learner.name(),
        &ckpt.dir.join("config.toml"),
    )?;
    let path = ckpt.optimizer_path();
    check_optimizer_state(&model, &path, learner.name())?;
    let optim = optim
        .load(&path)
        .map_err(|e| Error::invalid(&path, format!("cannot load the optimizer state: {e}")))?;
    write_history(learner, &run.root, &ckpt.state)?;
    if ckpt.state.epoch == fit.epochs {
        println!(
            "{}: all {} epochs are trained already, nothing to resume (give --epochs {} or more \
             to train further)",
            run.root.display(),
            fit.epochs,
            fit.epochs + 1
        );
    } else {
        println!(
            "resuming {} after epoch {} (step {})",
            run.root.display(),
            ckpt.state.epoch,
            ckpt.state.step
        );
    }
    Ok((model, optim, ckpt.state))
}

/// Refuses an optimizer state (`optimizer.bpk`) that is not one of `model`: each of its state
/// tensors is kept for a parameter, by the parameter's id, and must have that parameter's
/// shape; and every parameter it names must be one of the network's (a state saved for
/// another network, or another run of it, names parameters this one does not have). Burn
/// would otherwise drop the state it cannot place and go on with fresh optimizer moments.
pub(crate) fn check_optimizer_state<M: Module>(
    model: &M,
    path: &Path,
    network: &str,
) -> Result<()> {
    use burn::store::burn_pack::Reader;
    struct Shapes(std::collections::HashMap<u64, Vec<usize>>);
    impl burn::module::ModuleVisitor for Shapes {
        fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<D>>) {
            self.0.insert(param.id.val(), param.val().dims().to_vec());
        }
    }
    let mut shapes = Shapes(Default::default());
    model.visit(&mut shapes);
    let shapes = shapes.0;
    let unreadable = |e: &dyn std::fmt::Display| {
        Error::invalid(path, format!("cannot read the optimizer state: {e}"))
    };
    let reader = Reader::from_file(path).map_err(|e| unreadable(&e))?;
    let foreign = |what: String| {
        Error::invalid(
            path,
            format!(
                "this optimizer state is not one of the {network} in model.bpk beside it \
                 ({what}): the checkpoint mixes files of two networks or runs; resume from an \
                 intact checkpoint, or start again with --overwrite"
            ),
        )
    };
    // `{id}.__rank`: the rank of every parameter with state, tensors or not.
    for (key, value) in reader.scalars() {
        let Some(id) = key.strip_suffix(".__rank") else {
            continue;
        };
        let id: u64 = id
            .parse()
            .map_err(|_| foreign(format!("a state key \"{key}\"")))?;
        let Some(shape) = shapes.get(&id) else {
            return Err(foreign(format!(
                "it holds state for a parameter the network does not have (id {id})"
            )));
        };
        if usize::try_from(*value).ok() != Some(shape.len()) {
            return Err(foreign(format!(
                "parameter {id} has rank {}, the state says {value:?}",
                shape.len()
            )));
        }
    }
    for t in reader.into_tensors().map_err(|e| unreadable(&e))? {
        let Some(id) = t.param_id else {
            return Err(foreign(format!(
                "tensor {} belongs to no parameter",
                t.name
            )));
        };
        let Some(shape) = shapes.get(&id) else {
            return Err(foreign(format!(
                "tensor {} is the state of a parameter the network does not have",
                t.name
            )));
        };
        if t.shape.as_slice() != shape.as_slice() {
            return Err(foreign(format!(
                "tensor {} has shape {:?}, its parameter {:?}",
                t.name,
                t.shape.as_slice(),
                shape
            )));
        }
    }
    Ok(())
}

/// `metrics.csv` and the learner's plots of the run so far.
fn write_history<L: Learner>(learner: &L, root: &Path, state: &TrainState) -> Result<()> {
    state.history.write_csv(root.join("metrics.csv"))?;
    for p in learner.plots() {
        state
            .history
            .plot(root.join(p.file), p.title, p.y_label, p.keys, p.log_y)?;
    }
    Ok(())
}

/// The progress bar of an epoch of `len` batches (hidden when `quiet`).
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::training::OptimizerConfig;

    #[test]
    fn meter_weights_batches_by_samples() {
        let mut m = Meter::default();
        m.add(&[("loss", 1.0), ("seg_loss", 0.5)], 4);
        m.add(&[("loss", 4.0), ("seg_loss", 2.0)], 2);
        let mut values = BTreeMap::new();
        m.record("train", &mut values);
        assert_eq!(values["train_loss"], 2.0);
        assert_eq!(values["train_seg_loss"], 1.0);
        assert_eq!(m.line(), "loss 2.0000 seg_loss 1.0000");
    }

    /// A one-weight network that records the batches it trains on, in order, with the first
    /// draw of each batch's generator; `fail_at` makes loading the batch holding that
    /// sample an error.
    struct Toy {
        len: usize,
        fail_at: Option<usize>,
        seen: std::sync::Mutex<Vec<(Vec<usize>, u64)>>,
        /// The devices the steps ran on.
        on: std::sync::Mutex<Vec<Device>>,
    }

    impl Learner for Toy {
        type Model = burn::nn::Linear;
        type Batch = (Vec<usize>, u64);

        fn name(&self) -> &'static str {
            "toy"
        }

        fn train_len(&self) -> usize {
            self.len
        }

        fn load(&self, ids: &[usize], rng: &mut ChaCha8Rng) -> Result<Self::Batch> {
            if let Some(bad) = self.fail_at.filter(|b| ids.contains(b)) {
                return Err(Error::msg(format!("sample {bad} is unreadable")));
            }
            Ok((ids.to_vec(), rand::Rng::next_u64(rng)))
        }

        fn train_step(&self, model: &Self::Model, batch: Self::Batch) -> Result<Step> {
            let (ids, _) = &batch;
            let device = model.weight.val().device();
            let x: Vec<f32> = ids.iter().map(|&i| i as f32 / 10.0).collect();
            let x = Tensor::<2>::from_data(TensorData::new(x, [ids.len(), 1]), &device);
            let loss = model.forward(x).powi_scalar(2).mean();
            let samples = ids.len();
            self.seen.lock().unwrap().push(batch);
            self.on.lock().unwrap().push(device);
            Ok(Step {
                loss,
                terms: Vec::new(),
                samples,
            })
        }

        /// The loss over every sample.
        fn validate(&self, model: &Self::Model, values: &mut BTreeMap<String, f64>) -> Result<()> {
            let device = model.weight.val().device();
            let x: Vec<f32> = (0..self.len).map(|i| i as f32 / 10.0).collect();
            let x = Tensor::<2>::from_data(TensorData::new(x, [self.len, 1]), &device);
            let loss = model.forward(x).powi_scalar(2).mean().into_scalar::<f32>();
            values.insert("val_loss".into(), loss as f64);
            Ok(())
        }

        fn plots(&self) -> &'static [Plot] {
            &[]
        }
    }

    fn toy_fit(
        name: &str,
        fail_at: Option<usize>,
        accumulate: usize,
    ) -> (Toy, Result<burn::nn::Linear>) {
        toy_fit_history(name, fail_at, accumulate, false, &[]).0
    }

    /// [`toy_fit`], with the run's `metrics.csv` and the starting weights validated or not.
    fn toy_fit_history(
        name: &str,
        fail_at: Option<usize>,
        accumulate: usize,
        validate_start: bool,
        devices: &[Device],
    ) -> ((Toy, Result<burn::nn::Linear>), String) {
        let root = std::env::temp_dir().join(format!("sdf_fit_{name}_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let run = RunDir::prepare(&root, "model = \"toy\"\n", false).unwrap();
        // SGD: its step scales with the gradient (Adam's would not show a wrong weighting).
        let optimizer = OptimizerConfig::sgd_paper();
        let setup = Fit {
            run: &run,
            config: "model = \"toy\"\n",
            seed: 5,
            epochs: 2,
            batch_size: 3,
            accumulate,
            devices,
            optimizer: &optimizer,
            resume: false,
            validate_start,
            quiet: true,
        };
        let device = Device::flex().autodiff();
        // Seeded here, not by the device's generator, which tests running beside this one
        // draw from too.
        let model = crate::nn::seeded_init(burn::nn::LinearConfig::new(1, 1).init(&device), 3);
        let toy = Toy {
            len: 10,
            fail_at,
            seen: Default::default(),
            on: Default::default(),
        };
        let out = fit(&toy, &setup, model);
        let csv = std::fs::read_to_string(root.join("metrics.csv")).unwrap_or_default();
        let _ = std::fs::remove_dir_all(&root);
        ((toy, out), csv)
    }

    #[test]
    fn the_starting_weights_are_validated_as_epoch_0_when_asked() {
        let epoch_0 = |csv: &str| csv.lines().nth(1).map(|l| l.split(',').next() == Some("0"));
        let (_, csv) = toy_fit_history("no_start", None, 1, false, &[]);
        assert_eq!(epoch_0(&csv), Some(false), "{csv}");
        let ((_, out), csv) = toy_fit_history("start", None, 1, true, &[]);
        out.unwrap();
        let val_loss = |line: &str| -> f64 { line.rsplit(',').next().unwrap().parse().unwrap() };
        let lines: Vec<&str> = csv.lines().collect();
        assert!(lines[0].ends_with(",val_loss"), "{csv}");
        assert_eq!(lines.len(), 4, "{csv}");
        assert!(lines[1].starts_with("0,,,"), "{csv}");
        // The toy's validation is its training loss: epoch 0 is the untrained one.
        assert!(val_loss(lines[1]) > val_loss(lines[3]), "{csv}");
    }

    #[test]
    fn prefetched_batches_train_in_the_seeded_order_with_their_own_generators() {
        let (toy, out) = toy_fit("order", None, 1);
        out.unwrap();
        let mut expected = Vec::new();
        for epoch in 0..2 {
            let order = epoch_order(10, 5, epoch);
            for (bi, ids) in order.chunks(3).enumerate() {
                let draw = rand::Rng::next_u64(&mut batch_rng(5, epoch, bi));
                expected.push((ids.to_vec(), draw));
            }
        }
        assert_eq!(*toy.seen.lock().unwrap(), expected);
    }

    #[test]
    fn accumulated_parts_make_the_whole_batch_step() {
        // A linear network has no batch statistics: a batch in three parts of one sample
        // gives the gradient of the whole batch, so the same weights after two epochs.
        let weights = |m: &burn::nn::Linear| -> Vec<f32> {
            let w = m.weight.val().into_data().try_to_vec::<f32>().unwrap();
            let b = m.bias.as_ref().unwrap().val().into_data();
            [w, b.try_to_vec::<f32>().unwrap()].concat()
        };
        let (_, whole) = toy_fit("whole", None, 1);
        let (toy, parts) = toy_fit("parts", None, 3);
        let (whole, parts) = (weights(&whole.unwrap()), weights(&parts.unwrap()));
        for (a, b) in whole.iter().zip(&parts) {
            assert!(
                (a - b).abs() <= 1e-5 * a.abs().max(1.0),
                "{whole:?} vs {parts:?}"
            );
        }
        // Every sample trained once per epoch, one part at a time.
        let seen = toy.seen.lock().unwrap();
        assert!(seen.iter().all(|(ids, _)| ids.len() == 1));
        assert_eq!(seen.len(), 20);
    }

    fn toy_weights(m: &burn::nn::Linear) -> Vec<f32> {
        let w = m.weight.val().into_data().try_to_vec::<f32>().unwrap();
        let b = m.bias.as_ref().unwrap().val().into_data();
        [w, b.try_to_vec::<f32>().unwrap()].concat()
    }

    #[test]
    fn two_devices_make_the_step_of_one_with_twice_the_accumulation() {
        // Two distinct devices with no second GPU: flex (the model's) and ndarray. Each
        // trains its share on a fork of the model; the gradients come back to flex.
        #[allow(deprecated)] // ndarray is deprecated upstream but the project's default.
        let devices = [Device::flex().autodiff(), Device::ndarray().autodiff()];
        let ((two, parallel), _) = toy_fit_history("two_devices", None, 1, false, &devices);
        let (one, serial) = toy_fit("one_device", None, 2);
        let (parallel, serial) = (
            toy_weights(&parallel.unwrap()),
            toy_weights(&serial.unwrap()),
        );
        for (a, b) in parallel.iter().zip(&serial) {
            assert!(
                (a - b).abs() <= 1e-5 * a.abs().max(1.0),
                "{parallel:?} vs {serial:?}"
            );
        }
        // The same shares with the same draws, half of them on each device.
        let sorted = |t: &Toy| {
            let mut v = t.seen.lock().unwrap().clone();
            v.sort();
            v
        };
        assert_eq!(sorted(&two), sorted(&one));
        // Batches of 3, 3, 3 and 1 an epoch: shares of 2 + 1 (one on each device) and 1.
        let on = two.on.lock().unwrap();
        let count = |d: &Device| on.iter().filter(|o| *o == d).count();
        assert_eq!([count(&devices[0]), count(&devices[1])], [8, 6]);
    }

    #[test]
    fn a_loading_error_ends_the_epoch_with_that_error() {
        let (toy, out) = toy_fit("fail", Some(7), 1);
        let Err(e) = out else {
            panic!("the run went on although a batch failed to load")
        };
        let message = e.to_string();
        assert!(message.contains("sample 7 is unreadable"), "{message}");
        // The batches before the bad one trained; none after it.
        let seen = toy.seen.lock().unwrap();
        let order = epoch_order(10, 5, 0);
        let bad_batch = order.iter().position(|&i| i == 7).unwrap() / 3;
        assert_eq!(seen.len(), bad_batch);
    }
}
