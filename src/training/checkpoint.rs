//! Run folders and checkpoints.
//!
//! ```text
//! RUN/config.toml              the full training config (written at start)
//! RUN/metrics.csv, *.png       per-epoch metrics and curves
//! RUN/checkpoints/epoch-0007/  model.bpk, optimizer.bpk, state.json, config.toml
//! RUN/checkpoints/last.json    which checkpoint is the newest
//! ```
//!
//! A checkpoint is written into a hidden temporary folder and renamed into place
//! when complete, and `last.json` is replaced atomically afterwards, so an
//! interrupted run never leaves a half-written checkpoint behind: `--resume`
//! always finds the last complete one.

use super::history::History;
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// What is saved beside the weights.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TrainState {
    /// Completed epochs.
    pub epoch: usize,
    /// Optimizer steps so far.
    pub step: u64,
    /// Per-epoch metrics so far.
    pub history: History,
}

/// The most epochs a run may have (the `epochs` bound of every training config).
pub(crate) const MAX_EPOCHS: usize = 100_000;

impl TrainState {
    /// Whether the state can be one a run wrote: at most `MAX_EPOCHS` epochs, and a history
    /// (when it has one) of distinct epochs up to `epoch`, ending there.
    pub fn check(&self) -> std::result::Result<(), String> {
        if self.epoch > MAX_EPOCHS {
            return Err(format!(
                "epoch {} is more than any run has ({MAX_EPOCHS} at most): the file is damaged \
                 or was edited",
                self.epoch
            ));
        }
        let epochs = &self.history.epochs;
        if let Some(last) = epochs.last() {
            let increasing = epochs.windows(2).all(|w| w[0].epoch < w[1].epoch);
            if last.epoch != self.epoch || !increasing || epochs.len() > self.epoch {
                return Err(format!(
                    "epoch {} does not agree with its history ({} records, the last of epoch \
                     {}): the file is damaged or was edited",
                    self.epoch,
                    epochs.len(),
                    last.epoch
                ));
            }
        }
        Ok(())
    }
}

/// The folder name of epoch `epoch`'s checkpoint, `epoch-0007`.
pub(crate) fn checkpoint_name(epoch: usize) -> String {
    format!("epoch-{epoch:04}")
}

/// A complete checkpoint on disk.
#[derive(Debug, Clone)]
pub struct Checkpoint {
    /// The checkpoint's folder (`RUN/checkpoints/epoch-NNNN`).
    pub dir: PathBuf,
    /// Its `state.json`.
    pub state: TrainState,
}

impl Checkpoint {
    /// The model weights, `model.bpk`.
    pub fn model_path(&self) -> PathBuf {
        self.dir.join("model.bpk")
    }
    /// The optimizer state, `optimizer.bpk`.
    pub fn optimizer_path(&self) -> PathBuf {
        self.dir.join("optimizer.bpk")
    }
}

/// A training run's folder.
#[derive(Debug, Clone)]
pub struct RunDir {
    /// The run folder.
    pub root: PathBuf,
    /// How many epoch checkpoints to keep (the newest ones); 0 keeps all.
    pub keep: usize,
}

#[derive(Serialize, Deserialize)]
struct Last {
    checkpoint: String,
    epoch: usize,
}

impl RunDir {
    /// Opens `root` for a new run, or for `resume`, and writes the config there (see
    /// [`RunDir::prepare_normalized`]).
    pub fn prepare(root: impl AsRef<Path>, config_toml: &str, resume: bool) -> Result<Self> {
        Self::prepare_normalized(root, config_toml, resume, |_, _| Ok(None))
    }

    /// Opens `root` for a run and writes the config there. The folder is locked for this
    /// process first (`crate::output_lock::ensure_held`: a second writer is an error naming
    /// the first). A new run needs a folder that holds no run ([`RunContents`]: no
    /// checkpoint, `metrics.csv`, `config.toml`...): otherwise the error says what is there
    /// and the ways out (`--resume`, another `--out`, `--overwrite`). `resume` needs a
    /// checkpoint, and a config that means the same as the saved one except for the settings
    /// that change no computed number (`FREE_SETTINGS`) and a learning-rate schedule that
    /// changes no epoch already trained ([`resume_difference`]).
    ///
    /// A trainer that saves its config normalised (every default written out) gives
    /// `normalize`: on `--resume` the saved config (its text and path) is compared after it
    /// (the trainer's parse and re-serialisation; `Ok(None)` compares it as written), so a run
    /// saved by an older version, or with the defaults left out, resumes when it means the
    /// same. A saved config that no longer parses is an error naming it.
    pub fn prepare_normalized(
        root: impl AsRef<Path>,
        config_toml: &str,
        resume: bool,
        normalize: impl Fn(&str, &Path) -> Result<Option<String>>,
    ) -> Result<Self> {
        let run = RunDir {
            root: root.as_ref().to_path_buf(),
            keep: 3,
        };
        crate::output_lock::ensure_held(&run.root, &crate::output_lock::command_line())?;
        let contents = RunContents::of(&run.root)?;
        if !resume && !contents.is_empty() {
            return Err(Error::invalid(
                &run.root,
                format!(
                    "this folder already holds {}; a new run would mix its files with that \
                     one's. {}",
                    contents.describe(),
                    contents.ways_out()
                ),
            ));
        }
        let existing = run.latest()?;
        let completed = match (&existing, resume) {
            (None, true) => {
                let what = if contents.is_empty() {
                    "it holds no run".to_string()
                } else {
                    format!("it holds {}", contents.describe())
                };
                return Err(Error::invalid(
                    &run.root,
                    format!(
                        "--resume: no checkpoint to resume from ({what}): start a new run without \
                         --resume{}",
                        if contents.is_empty() {
                            String::new()
                        } else {
                            " and with --overwrite (which removes those files first), or choose \
                             another --out"
                                .to_string()
                        }
                    ),
                ));
            }
            (Some(c), _) => c.state.epoch,
            (None, false) => 0,
        };
        let cfg_path = run.root.join("config.toml");
        if resume && cfg_path.is_file() {
            let saved = crate::io::read_text(&cfg_path)?;
            let saved = normalize(&saved, &cfg_path)?.unwrap_or(saved);
            if let Some(diff) = resume_difference(&saved, config_toml, completed) {
                return Err(Error::invalid(
                    &cfg_path,
                    format!(
                        "--resume with a config that differs from the one this run was started \
                         with: {diff} (only `epochs`, `keep_checkpoints`, `out`, `backend`, \
                         `devices` and the learning rates of epochs not trained yet may \
                         change): resume with the run's own config ({}), or start the changed \
                         run in another --out",
                        cfg_path.display()
                    ),
                ));
            }
        }
        crate::io::write_atomic(&cfg_path, config_toml.as_bytes())?;
        Ok(run)
    }

    fn checkpoints(&self) -> PathBuf {
        self.root.join("checkpoints")
    }

    /// The newest complete checkpoint, if any.
    pub fn latest(&self) -> Result<Option<Checkpoint>> {
        let last = self.checkpoints().join("last.json");
        if !last.is_file() {
            return Ok(None);
        }
        let text = crate::io::read_text(&last)?;
        let l: Last =
            serde_json::from_str(&text).map_err(|e| Error::invalid(&last, e.to_string()))?;
        if l.checkpoint != checkpoint_name(l.epoch) {
            return Err(Error::invalid(
                &last,
                format!(
                    "names checkpoint \"{}\" for epoch {}, not {}: the file is damaged or was \
                     edited; point it at the newest complete checkpoint folder",
                    l.checkpoint,
                    l.epoch,
                    checkpoint_name(l.epoch)
                ),
            ));
        }
        let dir = self.checkpoints().join(&l.checkpoint);
        let ckpt = Self::read(&dir)?;
        if ckpt.state.epoch != l.epoch {
            return Err(Error::invalid(
                dir.join("state.json"),
                format!(
                    "says epoch {} but checkpoints/last.json and the folder's name say epoch {}: \
                     the checkpoint mixes files of two runs or was edited",
                    ckpt.state.epoch, l.epoch
                ),
            ));
        }
        Ok(Some(ckpt))
    }

    /// Reads a checkpoint folder.
    pub fn read(dir: &Path) -> Result<Checkpoint> {
        let p = dir.join("state.json");
        let text = crate::io::read_text(&p)?;
        let state: TrainState =
            serde_json::from_str(&text).map_err(|e| Error::invalid(&p, e.to_string()))?;
        state.check().map_err(|m| Error::invalid(&p, m))?;
        Ok(Checkpoint {
            dir: dir.to_path_buf(),
            state,
        })
    }

    /// Writes the checkpoint of `state.epoch`: `write_weights` saves the model
    /// (and optimizer) into the folder it is given; then `state.json` and a copy
    /// of the config are added, the folder is renamed into place and `last.json`
    /// updated.
    pub fn save(
        &self,
        state: &TrainState,
        config_toml: &str,
        write_weights: impl FnOnce(&Path) -> Result<()>,
    ) -> Result<Checkpoint> {
        let name = checkpoint_name(state.epoch);
        let dir = self.checkpoints().join(&name);
        let tmp = self.checkpoints().join(format!(".{name}.tmp"));
        if tmp.exists() {
            std::fs::remove_dir_all(&tmp).map_err(|e| Error::io(&tmp, e))?;
        }
        std::fs::create_dir_all(&tmp).map_err(|e| Error::io(&tmp, e))?;
        write_weights(&tmp)?;
        let json = serde_json::to_string_pretty(state)?;
        crate::io::write_atomic(tmp.join("state.json"), json.as_bytes())?;
        crate::io::write_atomic(tmp.join("config.toml"), config_toml.as_bytes())?;
        if dir.exists() {
            std::fs::remove_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        }
        std::fs::rename(&tmp, &dir).map_err(|e| Error::io(&dir, e))?;
        crate::io::sync_parent(&dir).map_err(|e| Error::io(&dir, e))?;
        let last = serde_json::to_string(&Last {
            checkpoint: name,
            epoch: state.epoch,
        })?;
        crate::io::write_atomic(self.checkpoints().join("last.json"), last.as_bytes())?;
        self.prune(state.epoch)?;
        Ok(Checkpoint {
            dir,
            state: state.clone(),
        })
    }

    /// Removes old epoch checkpoints beyond `keep`, never the newest.
    fn prune(&self, newest: usize) -> Result<()> {
        if self.keep == 0 {
            return Ok(());
        }
        let dir = self.checkpoints();
        let mut epochs: Vec<usize> = std::fs::read_dir(&dir)
            .map_err(|e| Error::io(&dir, e))?
            .filter_map(|e| e.ok())
            .filter_map(|e| e.file_name().to_str()?.strip_prefix("epoch-")?.parse().ok())
            .filter(|&e| e <= newest)
            .collect();
        epochs.sort_unstable();
        let n = epochs.len();
        for e in epochs.into_iter().take(n.saturating_sub(self.keep)) {
            let p = dir.join(format!("epoch-{e:04}"));
            std::fs::remove_dir_all(&p).map_err(|err| Error::io(&p, err))?;
        }
        Ok(())
    }
}

/// What a folder holds of a training run (or of another output that a run must not be mixed
/// with): [`RunContents::of`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunContents {
    /// The epoch of `checkpoints/last.json` (None: no such file, or one that does not read).
    pub last_epoch: Option<usize>,
    /// `checkpoints/epoch-*` folders.
    pub checkpoints: Vec<String>,
    /// Other entries of `checkpoints/` (unfinished `.epoch-*.tmp` folders...).
    pub other_checkpoint_files: Vec<String>,
    /// `config.toml`'s `model` ("" when it has none or does not parse), when there is one.
    pub config: Option<String>,
    /// Epoch rows of `metrics.csv`, when there is one.
    pub metrics_rows: Option<usize>,
    /// Pictures (`*.png`) at the top of the folder.
    pub plots: Vec<String>,
    /// `sweep.toml`: a sweep's folder.
    pub sweep: bool,
    /// `model.bpk` at the top: exported or averaged weights.
    pub weights: bool,
}

impl RunContents {
    /// Looks at `root` (a folder that does not exist holds nothing).
    pub fn of(root: &Path) -> Result<RunContents> {
        let mut c = RunContents::default();
        if !root.is_dir() {
            return Ok(c);
        }
        let ckpts = root.join("checkpoints");
        if ckpts.is_dir() {
            for e in std::fs::read_dir(&ckpts).map_err(|e| Error::io(&ckpts, e))? {
                let name = e.map_err(|e| Error::io(&ckpts, e))?.file_name();
                let name = name.to_string_lossy().into_owned();
                if name == "last.json" {
                    let last = crate::io::read_text(ckpts.join(&name))
                        .ok()
                        .and_then(|t| serde_json::from_str::<Last>(&t).ok());
                    c.last_epoch = last.map(|l| l.epoch);
                    if c.last_epoch.is_none() {
                        c.other_checkpoint_files.push(name);
                    }
                } else if name.starts_with("epoch-") {
                    c.checkpoints.push(name);
                } else {
                    c.other_checkpoint_files.push(name);
                }
            }
            c.checkpoints.sort();
            c.other_checkpoint_files.sort();
        }
        let config = root.join("config.toml");
        if config.is_file() {
            let model = crate::io::read_text(&config)
                .ok()
                .and_then(|t| t.parse::<toml::Table>().ok())
                .and_then(|t| t.get("model")?.as_str().map(str::to_string));
            c.config = Some(model.unwrap_or_default());
        }
        let metrics = root.join("metrics.csv");
        if metrics.is_file() {
            let rows = crate::io::read_text(&metrics)
                .map(|t| t.lines().skip(1).filter(|l| !l.trim().is_empty()).count())
                .unwrap_or(0);
            c.metrics_rows = Some(rows);
        }
        for e in std::fs::read_dir(root).map_err(|e| Error::io(root, e))? {
            let e = e.map_err(|e| Error::io(root, e))?;
            let name = e.file_name().to_string_lossy().into_owned();
            if name.ends_with(".png") && e.path().is_file() {
                c.plots.push(name);
            }
        }
        c.plots.sort();
        c.sweep = root.join("sweep.toml").is_file();
        c.weights = root.join("model.bpk").is_file();
        Ok(c)
    }

    /// Whether it holds nothing of a run.
    pub fn is_empty(&self) -> bool {
        *self == RunContents::default()
    }

    /// What it holds, e.g. "a training run (config.toml of model = \"sdfcnn\", checkpoints up to
    /// epoch 3 (epoch-0002, epoch-0003), metrics.csv with 3 epochs, 2 plots)".
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        if let Some(model) = &self.config {
            parts.push(if model.is_empty() {
                "config.toml".to_string()
            } else {
                format!("config.toml of model = \"{model}\"")
            });
        }
        let list = |v: &[String]| {
            if v.len() > 4 {
                format!("{}, ... {}", v[..2].join(", "), v[v.len() - 1])
            } else {
                v.join(", ")
            }
        };
        match (self.last_epoch, self.checkpoints.is_empty()) {
            (Some(e), false) => parts.push(format!(
                "checkpoints up to epoch {e} ({})",
                list(&self.checkpoints)
            )),
            (Some(e), true) => parts.push(format!(
                "checkpoints/last.json naming epoch {e} but no checkpoint folder"
            )),
            (None, false) => parts.push(format!(
                "checkpoint folders {} but no checkpoints/last.json saying which is the newest",
                list(&self.checkpoints)
            )),
            (None, true) => {}
        }
        if !self.other_checkpoint_files.is_empty() {
            parts.push(format!(
                "{} in checkpoints/",
                list(&self.other_checkpoint_files)
            ));
        }
        if let Some(rows) = self.metrics_rows {
            parts.push(format!("metrics.csv with {rows} epochs"));
        }
        if !self.plots.is_empty() {
            parts.push(list(&self.plots));
        }
        if self.weights {
            parts.push("model.bpk (exported or averaged weights)".to_string());
        }
        if self.sweep {
            parts.push("sweep.toml (a sweep's folder)".to_string());
        }
        let what = if self.sweep && self.config.is_none() {
            "a sweep"
        } else if self.weights && self.checkpoints.is_empty() {
            "weights"
        } else {
            "a training run"
        };
        format!("{what} ({})", parts.join(", "))
    }

    /// The ways out of a new run into this folder.
    pub fn ways_out(&self) -> String {
        let resume = if self.last_epoch.is_some() && !self.weights && !self.sweep {
            "To continue that run, pass --resume; to "
        } else {
            "To "
        };
        format!(
            "{resume}keep it, choose another --out; to replace it, pass --overwrite (which \
             removes its checkpoints, metrics.csv, config.toml and pictures first)"
        )
    }
}

/// `--overwrite`: removes what a training run writes in `root` (`checkpoints/`,
/// `config.toml`, `metrics.csv`, the pictures `*.png`, and `model.bpk`), so that a new run
/// starts in a folder that holds no other run's files; every other file stays. Returns what
/// was removed ([`RunContents::describe`]), `None` when there was nothing.
pub fn clear_run(root: &Path) -> Result<Option<String>> {
    let contents = RunContents::of(root)?;
    if contents.is_empty() {
        return Ok(None);
    }
    let ckpts = root.join("checkpoints");
    if ckpts.is_dir() {
        std::fs::remove_dir_all(&ckpts).map_err(|e| Error::io(&ckpts, e))?;
    }
    let files = ["config.toml", "metrics.csv", "model.bpk", "sweep.toml"];
    for f in files
        .iter()
        .map(|f| f.to_string())
        .chain(contents.plots.clone())
    {
        let p = root.join(f);
        if p.is_file() {
            std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
        }
    }
    Ok(Some(contents.describe()))
}

/// Settings a resumed run may change: the number of epochs, how many checkpoints are kept,
/// where the run folder is (it may have moved, or be named by another spelling), and the
/// backend (`--backend`: the same computation on another device, equal up to float
/// rounding) and the data-parallel devices (`--devices`: a checkpoint continues on any
/// number of them); none changes what the epochs already run computed.
const FREE_SETTINGS: [&str; 5] = ["epochs", "keep_checkpoints", "out", "backend", "devices"];

/// The differences in meaning between two training configs, as `key: saved -> given` joined
/// by "; " (at most six named), or `None` when they agree: keys compared as parsed TOML
/// (order, spacing and comments do not matter), `FREE_SETTINGS` ignored, and strings
/// naming an existing file or folder compared as canonical paths (`runs/x` and
/// `/home/me/runs/x` agree).
pub fn config_difference(saved: &str, given: &str) -> Option<String> {
    resume_difference(saved, given, usize::MAX)
}

/// [`config_difference`] for resuming a run that has trained `completed` epochs: the
/// learning-rate schedule (`optimizer.lr`, `optimizer.lr_steps`) may also change, as long as
/// it gives every epoch already trained the rate it was trained with.
pub fn resume_difference(saved: &str, given: &str, completed: usize) -> Option<String> {
    let parse = |t: &str| t.parse::<toml::Table>().ok();
    let (Some(mut a), Some(mut b)) = (parse(saved), parse(given)) else {
        return (saved != given).then(|| "the file (it does not parse as TOML)".to_string());
    };
    for key in FREE_SETTINGS {
        a.remove(key);
        b.remove(key);
    }
    let mut found = Vec::new();
    if completed < usize::MAX
        && let (Some(x), Some(y)) = (lr_schedule(&a), lr_schedule(&b))
    {
        if let Some(e) = (0..completed.min(MAX_EPOCHS)).find(|&e| x.at(e) != y.at(e)) {
            found.push(format!(
                "the learning-rate schedule (`optimizer.lr`, `optimizer.lr_steps`) gives epoch \
                 {}, already trained, the rate {} instead of {}",
                e + 1,
                y.at(e),
                x.at(e)
            ));
        }
        for t in [&mut a, &mut b] {
            if let Some(toml::Value::Table(o)) = t.get_mut("optimizer") {
                o.remove("lr");
                o.remove("lr_steps");
            }
        }
    }
    differences(
        "",
        &toml::Value::Table(a),
        &toml::Value::Table(b),
        &mut found,
    );
    if found.is_empty() {
        return None;
    }
    let n = found.len();
    let mut text = found.into_iter().take(6).collect::<Vec<_>>().join("; ");
    if n > 6 {
        text.push_str(&format!("; and {} more", n - 6));
    }
    Some(text)
}

/// `[optimizer]`'s `lr` and `lr_steps` of a config table, when it has both in their shape.
struct LrSchedule {
    lr: f64,
    steps: Vec<(i64, f64)>,
}

impl LrSchedule {
    /// As [`super::OptimizerConfig::lr_at`].
    fn at(&self, epoch: usize) -> f64 {
        self.steps
            .iter()
            .filter(|(e, _)| *e >= 0 && *e as u64 <= epoch as u64)
            .max_by_key(|(e, _)| *e)
            .map_or(self.lr, |(_, lr)| *lr)
    }
}

fn lr_schedule(config: &toml::Table) -> Option<LrSchedule> {
    let number = |v: &toml::Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
    let o = config.get("optimizer")?.as_table()?;
    let lr = number(o.get("lr")?)?;
    let steps = match o.get("lr_steps") {
        None => Vec::new(),
        Some(v) => v
            .as_array()?
            .iter()
            .map(|s| {
                let s = s.as_array()?;
                match &s[..] {
                    [e, lr] => Some((e.as_integer()?, number(lr)?)),
                    _ => None,
                }
            })
            .collect::<Option<Vec<_>>>()?,
    };
    Some(LrSchedule { lr, steps })
}

fn differences(key: &str, a: &toml::Value, b: &toml::Value, found: &mut Vec<String>) {
    use toml::Value;
    let named = |k: &str| {
        if key.is_empty() {
            k.to_string()
        } else {
            format!("{key}.{k}")
        }
    };
    match (a, b) {
        (Value::Table(x), Value::Table(y)) => {
            let keys: std::collections::BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            for k in keys {
                match (x.get(k), y.get(k)) {
                    (Some(u), Some(v)) => differences(&named(k), u, v, found),
                    (Some(u), None) => found.push(format!("`{}` = {u} was removed", named(k))),
                    (None, Some(v)) => found.push(format!("`{}` = {v} was added", named(k))),
                    (None, None) => {}
                }
            }
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => {
            for (i, (u, v)) in x.iter().zip(y).enumerate() {
                differences(&format!("{key}[{i}]"), u, v, found);
            }
        }
        _ => {
            if let Some(d) = first_difference(key, a, b) {
                found.push(d);
            }
        }
    }
}

fn first_difference(key: &str, a: &toml::Value, b: &toml::Value) -> Option<String> {
    use toml::Value;
    let named = |k: &str| {
        if key.is_empty() {
            k.to_string()
        } else {
            format!("{key}.{k}")
        }
    };
    match (a, b) {
        (Value::Table(x), Value::Table(y)) => {
            let keys: std::collections::BTreeSet<&String> = x.keys().chain(y.keys()).collect();
            keys.into_iter().find_map(|k| match (x.get(k), y.get(k)) {
                (Some(u), Some(v)) => first_difference(&named(k), u, v),
                (Some(u), None) => Some(format!("`{}` = {u} was removed", named(k))),
                (None, Some(v)) => Some(format!("`{}` = {v} was added", named(k))),
                (None, None) => None,
            })
        }
        (Value::Array(x), Value::Array(y)) if x.len() == y.len() => x
            .iter()
            .zip(y)
            .enumerate()
            .find_map(|(i, (u, v))| first_difference(&format!("{key}[{i}]"), u, v)),
        (Value::String(x), Value::String(y)) if same_path(x, y) => None,
        _ if a == b => None,
        _ => Some(format!("`{key}` was {a}, now {b}")),
    }
}

/// Whether two strings name the same existing file or folder.
fn same_path(a: &str, b: &str) -> bool {
    a == b
        || matches!(
            (std::fs::canonicalize(a), std::fs::canonicalize(b)),
            (Ok(x), Ok(y)) if x == y
        )
}

/// The weights file and training config of a checkpoint given as a `model.bpk`
/// file, a checkpoint folder, or a run folder (its newest checkpoint).
pub fn resolve_checkpoint(path: &Path) -> Result<(PathBuf, PathBuf)> {
    let dir = if path.is_file() {
        path.parent().map(Path::to_path_buf).unwrap_or_default()
    } else if path.join("model.bpk").is_file() {
        path.to_path_buf()
    } else if path.join("checkpoints/last.json").is_file() {
        let run = RunDir {
            root: path.to_path_buf(),
            keep: 0,
        };
        match run.latest()? {
            Some(c) => c.dir,
            None => return Err(Error::invalid(path, "run folder has no checkpoint")),
        }
    } else {
        return Err(Error::invalid(
            path,
            "not a checkpoint: expected a model.bpk file, a folder holding one, or a training run folder",
        ));
    };
    let model = if path.is_file() {
        path.to_path_buf()
    } else {
        dir.join("model.bpk")
    };
    let config = dir.join("config.toml");
    if !config.is_file() {
        return Err(Error::invalid(
            &dir,
            "checkpoint has no config.toml beside its weights",
        ));
    }
    Ok((model, config))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resume_compares_configs_by_meaning_and_names_the_key() {
        let dir = std::env::temp_dir().join(format!("sdf_cfgdiff_{}", std::process::id()));
        std::fs::create_dir_all(dir.join("data")).unwrap();
        let abs = dir.join("data").display().to_string();
        let rel_spelling = dir.join("data/../data").display().to_string();
        let saved =
            format!("out = \"runs/a\"\nepochs = 3\n[data]\npath = \"{abs}\"\nsize = [32, 48]\n");
        // More epochs, a moved run folder, another spelling of the same data folder,
        // comments and key order.
        let given = format!(
            "# resumed\nepochs = 9\nout = \"/elsewhere/a\"\n\
             [data]\nsize = [32, 48]\npath = \"{rel_spelling}\"\n"
        );
        assert_eq!(config_difference(&saved, &given), None, "{given}");
        let changed = saved.replace("[32, 48]", "[32, 64]");
        let d = config_difference(&saved, &changed).unwrap();
        assert!(
            d.contains("data.size[1]") && d.contains("48") && d.contains("64"),
            "{d}"
        );
        let added = saved.clone() + "lr = 0.5\n";
        let d = config_difference(&saved, &added).unwrap();
        assert!(d.contains("data.lr") && d.contains("added"), "{d}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn save_resume_prune_and_refuse_overwrite() {
        let root = std::env::temp_dir().join(format!("sdf_run_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        let cfg = "lr = 0.1\nepochs = 5\n";
        let run = RunDir::prepare(&root, cfg, false).unwrap();
        assert!(
            RunDir::prepare(&root, cfg, true).is_err(),
            "nothing to resume yet"
        );
        for epoch in 1..=5 {
            let state = TrainState {
                epoch,
                step: 10 * epoch as u64,
                history: History::default(),
            };
            run.save(&state, cfg, |dir| {
                crate::io::write_atomic(dir.join("model.bpk"), b"w")
            })
            .unwrap();
        }
        let last = run.latest().unwrap().unwrap();
        assert_eq!(last.state.epoch, 5);
        assert!(last.model_path().is_file());
        let kept: Vec<_> = std::fs::read_dir(root.join("checkpoints"))
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(kept.len(), 4, "{kept:?}"); // 3 epochs + last.json
        // A new run in the same folder is refused; a resume with more epochs is fine;
        // a resume with another learning rate is refused.
        assert!(
            RunDir::prepare(&root, cfg, false)
                .unwrap_err()
                .to_string()
                .contains("--resume")
        );
        assert!(RunDir::prepare(&root, "lr = 0.1\nepochs = 9\n", true).is_ok());
        assert!(
            RunDir::prepare(&root, "lr = 0.1\nepochs = 9\nkeep_checkpoints = 0\n", true).is_ok()
        );
        assert!(RunDir::prepare(&root, "lr = 0.2\nepochs = 9\n", true).is_err());
        // A failed weight write leaves the previous checkpoint as the latest.
        let state = TrainState {
            epoch: 6,
            ..Default::default()
        };
        assert!(
            run.save(&state, cfg, |_| Err(Error::msg("disk full")))
                .is_err()
        );
        assert_eq!(run.latest().unwrap().unwrap().state.epoch, 5);
        std::fs::remove_dir_all(&root).unwrap();
    }
    #[test]
    fn resume_may_change_the_rates_of_epochs_not_trained_yet_only() {
        let saved = "epochs = 10\n[optimizer]\nlr = 0.1\nlr_steps = [[5, 0.01]]\nmomentum = 0.9\n";
        let later = "epochs = 20\n[optimizer]\nlr = 0.1\nlr_steps = [[5, 0.01], [15, 0.001]]\n\
                     momentum = 0.9\n";
        assert_eq!(resume_difference(saved, later, 10), None);
        // The step moved to the fourth epoch: fine before it is trained, refused after.
        let moved = "epochs = 10\n[optimizer]\nlr = 0.1\nlr_steps = [[3, 0.01]]\nmomentum = 0.9\n";
        assert_eq!(resume_difference(saved, moved, 3), None);
        let d = resume_difference(saved, moved, 4).unwrap();
        assert!(
            d.contains("epoch 4, already trained, the rate 0.01 instead of 0.1"),
            "{d}"
        );
        // Every difference is named; outside a resume the schedule is compared as it is.
        let other = "epochs = 10\n[optimizer]\nlr = 0.1\nlr_steps = [[5, 0.01]]\nmomentum = 0.5\n\
                     nesterov = true\n";
        let d = resume_difference(saved, other, 3).unwrap();
        assert!(
            d.contains("optimizer.momentum") && d.contains("optimizer.nesterov"),
            "{d}"
        );
        assert!(config_difference(saved, later).is_some());
    }

    #[test]
    fn a_folder_holding_a_run_is_described_refused_and_cleared() {
        let root = crate::io::ScratchDir::new("run_contents").unwrap();
        let cfg = "model = \"toy\"\nepochs = 5\n";
        assert!(RunContents::of(&root).unwrap().is_empty());
        let run = RunDir::prepare(&*root, cfg, false).unwrap();
        // A run that saved no checkpoint: its config is there.
        let e = RunDir::prepare(&*root, cfg, false).unwrap_err().to_string();
        assert!(
            e.contains("config.toml of model = \"toy\"") && e.contains("--overwrite"),
            "{e}"
        );
        assert!(!e.contains("--resume"), "nothing to resume: {e}");
        for epoch in 1..=2 {
            let state = TrainState {
                epoch,
                ..Default::default()
            };
            run.save(&state, cfg, |dir| {
                crate::io::write_atomic(dir.join("model.bpk"), b"w")
            })
            .unwrap();
        }
        std::fs::write(root.join("metrics.csv"), "epoch,lr\n1,0.1\n2,0.1\n").unwrap();
        std::fs::write(root.join("loss.png"), "png").unwrap();
        std::fs::write(root.join("notes.txt"), "mine").unwrap();
        let e = RunDir::prepare(&*root, cfg, false).unwrap_err().to_string();
        for part in [
            "checkpoints up to epoch 2 (epoch-0001, epoch-0002)",
            "metrics.csv with 2 epochs",
            "loss.png",
            "--resume",
            "another --out",
            "--overwrite",
        ] {
            assert!(e.contains(part), "{part}: {e}");
        }
        // Checkpoints without last.json: neither trained over nor resumed.
        std::fs::remove_file(root.join("checkpoints/last.json")).unwrap();
        let e = RunDir::prepare(&*root, cfg, false).unwrap_err().to_string();
        assert!(
            e.contains("epoch-0001, epoch-0002 but no checkpoints/last.json"),
            "{e}"
        );
        let e = RunDir::prepare(&*root, cfg, true).unwrap_err().to_string();
        assert!(e.contains("no checkpoint to resume from"), "{e}");
        // --overwrite: the run's files go, others stay.
        let removed = clear_run(&root).unwrap().unwrap();
        assert!(removed.contains("epoch-0002"), "{removed}");
        assert!(RunContents::of(&root).unwrap().is_empty());
        assert!(root.join("notes.txt").is_file());
        assert_eq!(clear_run(&root).unwrap(), None);
        RunDir::prepare(&*root, cfg, false).unwrap();
    }

    #[test]
    fn impossible_states_and_a_last_json_of_another_checkpoint_are_refused() {
        let record = |epoch| super::super::EpochRecord {
            epoch,
            lr: 0.1,
            seconds: 1.0,
            values: Default::default(),
        };
        let mut state = TrainState {
            epoch: 2,
            step: 4,
            history: History {
                epochs: vec![record(1), record(2)],
                start: None,
            },
        };
        assert_eq!(state.check(), Ok(()));
        state.epoch = 1_000_000_000_000_000;
        assert!(state.check().unwrap_err().contains("1000000000000000"));
        state.epoch = 3;
        assert!(state.check().unwrap_err().contains("history"));
        let root = crate::io::ScratchDir::new("last_json").unwrap();
        let run = RunDir::prepare(&*root, "lr = 0.1\n", false).unwrap();
        state.epoch = 2;
        run.save(&state, "lr = 0.1\n", |_| Ok(())).unwrap();
        std::fs::write(
            root.join("checkpoints/last.json"),
            r#"{"checkpoint":"../../elsewhere","epoch":2}"#,
        )
        .unwrap();
        let e = run.latest().unwrap_err().to_string();
        assert!(e.contains("not epoch-0002"), "{e}");
        std::fs::write(
            root.join("checkpoints/last.json"),
            r#"{"checkpoint":"epoch-0003","epoch":3}"#,
        )
        .unwrap();
        std::fs::rename(
            root.join("checkpoints/epoch-0002"),
            root.join("checkpoints/epoch-0003"),
        )
        .unwrap();
        let e = run.latest().unwrap_err().to_string();
        assert!(e.contains("says epoch 2"), "{e}");
    }
}
