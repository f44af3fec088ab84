//! What `train` writes, and where it may write it: one writer per output folder
//! ([`sdf_slam::output_lock`]), never a new run over another run's files (`--overwrite`
//! clears them first), and `export` / `average` outputs that never replace a training
//! checkpoint's full-precision weights, from inputs of one run.

use anyhow::{Result, bail};
use sdf_slam::output_lock::{OutputLock, command_line};
use sdf_slam::training::{RunContents, RunDir, RunOptions, clear_run, config_model};
use std::path::{Path, PathBuf};

use crate::sweep::lookup;
use crate::trainers;

/// Locks the folder `train` is about to write (a training run's; a sweep locks its own
/// folders as it goes) before any data is read, and with `overwrite` removes the earlier
/// run's files there ([`clear_run`]). Nothing for `--dry-run`, which writes nothing.
/// `config`: `--config` (None: the default run, into `opts.out` or `default_out`).
pub fn lock_run_folder(
    config: Option<&Path>,
    opts: &RunOptions,
    overwrite: bool,
    dry_run: bool,
    default_out: &str,
) -> Result<Option<OutputLock>> {
    if dry_run {
        return Ok(None);
    }
    let out = match config {
        None => opts
            .out
            .clone()
            .unwrap_or_else(|| PathBuf::from(default_out)),
        Some(path) => {
            let text = sdf_slam::io::read_text(path)?;
            let model = config_model(&text, path)?;
            if model == "sweep" {
                if overwrite {
                    bail!(
                        "--overwrite does not apply to a sweep ({}): its runs resume where they \
                         stopped; remove the sweep's folder to start it again",
                        path.display()
                    );
                }
                return Ok(None);
            }
            let Some(trainer) = trainers::trainer(&model) else {
                return Err(trainers::no_trainer(path, &model));
            };
            match &opts.out {
                Some(o) => o.clone(),
                None => {
                    let cfg = (trainer.parse)(&text, path)?;
                    match lookup(&cfg, "out").and_then(toml::Value::as_str) {
                        Some(o) => PathBuf::from(o),
                        None => bail!("{}: no `out` folder (give --out DIR)", path.display()),
                    }
                }
            }
        }
    };
    let lock = OutputLock::acquire(&out, &command_line())?;
    if overwrite && let Some(removed) = clear_run(&out)? {
        println!("--overwrite: removed {removed} from {}", out.display());
    }
    Ok(Some(lock))
}

/// The weights in a folder's `model.bpk`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Weights {
    /// Half precision: a `train export`.
    Half,
    /// Full precision, with a config that says `train average` wrote them.
    Averaged,
    /// Full precision: a training checkpoint's (or weights of unknown origin).
    Full,
}

fn weights_in(dir: &Path) -> Result<Option<Weights>> {
    use burn::store::burn_pack::{DType, Reader};
    let path = dir.join("model.bpk");
    if !path.is_file() {
        return Ok(None);
    }
    let tensors = Reader::from_file(&path)
        .and_then(|r| r.into_tensors())
        .map_err(|e| anyhow::anyhow!("{}: cannot read the weights: {e}", path.display()))?;
    let floats: Vec<DType> = tensors
        .iter()
        .map(|t| t.dtype)
        .filter(|d| {
            matches!(
                d,
                DType::F64 | DType::F32 | DType::Flex32 | DType::F16 | DType::BF16
            )
        })
        .collect();
    if !floats.is_empty() && floats.iter().all(|d| matches!(d, DType::F16 | DType::BF16)) {
        return Ok(Some(Weights::Half));
    }
    let averaged = sdf_slam::io::read_text(dir.join("config.toml"))
        .is_ok_and(|t| t.starts_with(AVERAGED_HEADER));
    Ok(Some(if averaged {
        Weights::Averaged
    } else {
        Weights::Full
    }))
}

/// The first line of an averaged checkpoint's `config.toml`.
pub const AVERAGED_HEADER: &str = "# Weights averaged (train average)";

/// Whether two paths name the same existing folder.
fn same_folder(a: &Path, b: &Path) -> bool {
    matches!(
        (std::fs::canonicalize(a), std::fs::canonicalize(b)),
        (Ok(x), Ok(y)) if x == y
    )
}

/// Checks that `out` may receive the output of `command` (`export` writes `allowed`
/// weights, `average` full precision ones): not one of the `sources` folders, not a
/// training run's or checkpoint's folder, and holding no weights but a previous output of the
/// same command; then locks it.
fn output_folder(
    command: &str,
    out: &Path,
    sources: &[PathBuf],
    allowed: Weights,
) -> Result<OutputLock> {
    let refuse = |what: String| {
        anyhow::anyhow!(
            "train {command} --out {}: {what}; choose another --out (an empty or new folder)",
            out.display()
        )
    };
    if let Some(src) = sources.iter().find(|s| same_folder(s, out)) {
        return Err(refuse(format!(
            "this is the folder of the checkpoint {} it reads: its weights would be replaced",
            src.display()
        )));
    }
    let lock = OutputLock::acquire(out, &command_line())?;
    let contents = RunContents::of(out)?;
    let checkpoint_files: Vec<&str> = ["state.json", "optimizer.bpk"]
        .into_iter()
        .filter(|f| out.join(f).is_file())
        .collect();
    if !checkpoint_files.is_empty() {
        return Err(refuse(format!(
            "it is a training checkpoint ({} beside full-precision weights), which {command} \
             would overwrite",
            checkpoint_files.join(", ")
        )));
    }
    let is_run = contents.last_epoch.is_some()
        || !contents.checkpoints.is_empty()
        || !contents.other_checkpoint_files.is_empty()
        || contents.metrics_rows.is_some()
        || contents.sweep;
    if is_run {
        return Err(refuse(format!(
            "it holds {}: a run's folder is not an output of {command}",
            contents.describe()
        )));
    }
    match weights_in(out)? {
        None if contents.config.is_some() => Err(refuse(format!(
            "it holds a config.toml of another output ({})",
            contents.describe()
        ))),
        None => Ok(lock),
        Some(w) if w == allowed => Ok(lock),
        Some(Weights::Half) => Err(refuse(
            "it holds half-precision weights of `train export`, not an earlier output of this \
             command"
                .to_string(),
        )),
        Some(Weights::Averaged) => Err(refuse(
            "it holds the full-precision weights of `train average`, which an export would \
             replace by half-precision ones"
                .to_string(),
        )),
        Some(Weights::Full) => Err(refuse(
            "it holds full-precision weights (model.bpk) that this would replace".to_string(),
        )),
    }
}

/// `train export CKPT --out DIR`: refuses an `out` that is the checkpoint's own folder, a run
/// or checkpoint folder, or one holding full-precision weights; then locks it.
pub fn export_folder(weights: &Path, out: &Path) -> Result<OutputLock> {
    let source = weights.parent().unwrap_or(Path::new(".")).to_path_buf();
    output_folder("export", out, &[source], Weights::Half)
}

/// A checkpoint given to `train average`, as read for the one-run check.
pub struct AverageInput {
    /// The folder holding the weights.
    pub dir: PathBuf,
    /// Its `config.toml`'s path and text.
    pub config: (PathBuf, String),
}

/// `train average`: every checkpoint must come from one run: configs that agree on all but
/// the settings a run may change when resumed (the epochs, and the learning rates of epochs
/// one of them has not trained yet), and histories (`state.json`) that agree on the epochs
/// both have. Then the `out` checks of [`output_folder`], and its lock.
pub fn average_inputs(inputs: &[AverageInput], out: &Path) -> Result<OutputLock> {
    let state = |dir: &Path| {
        dir.join("state.json")
            .is_file()
            .then(|| RunDir::read(dir))
            .transpose()
    };
    let Some(first) = inputs.first() else {
        bail!("train average: no checkpoint given");
    };
    let first_state = state(&first.dir)?;
    for other in &inputs[1..] {
        let other_state = state(&other.dir)?;
        let done = match (&first_state, &other_state) {
            (Some(a), Some(b)) => a.state.epoch.min(b.state.epoch),
            _ => usize::MAX,
        };
        let diff = if done == usize::MAX {
            sdf_slam::training::checkpoint::config_difference(&first.config.1, &other.config.1)
        } else {
            sdf_slam::training::checkpoint::resume_difference(
                &first.config.1,
                &other.config.1,
                done,
            )
        };
        if let Some(diff) = diff {
            bail!(
                "train average takes checkpoints of one run, and {} and {} come from runs of \
                 different configs: {diff}",
                first.config.0.display(),
                other.config.0.display()
            );
        }
        if let (Some(a), Some(b)) = (&first_state, &other_state) {
            for ra in &a.state.history.epochs {
                let Some(rb) = b.state.history.epochs.iter().find(|r| r.epoch == ra.epoch) else {
                    continue;
                };
                if ra != rb {
                    bail!(
                        "train average takes checkpoints of one run, and {} and {} disagree on \
                         epoch {}'s record in their state.json (its metrics or its time): they \
                         come from two runs of the same config",
                        first.dir.display(),
                        other.dir.display(),
                        ra.epoch
                    );
                }
            }
        }
    }
    let sources: Vec<PathBuf> = inputs.iter().map(|i| i.dir.clone()).collect();
    output_folder("average", out, &sources, Weights::Averaged)
}

/// Reads a checkpoint's config for [`average_inputs`].
pub fn average_input(weights: &Path, config: &Path) -> Result<AverageInput> {
    let text = sdf_slam::io::read_text(config)?;
    Ok(AverageInput {
        dir: weights.parent().unwrap_or(Path::new(".")).to_path_buf(),
        config: (config.to_path_buf(), text),
    })
}
