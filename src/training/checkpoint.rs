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
    pub history: History,
}

/// A complete checkpoint on disk.
#[derive(Debug, Clone)]
pub struct Checkpoint {
    pub dir: PathBuf,
    pub state: TrainState,
}

impl Checkpoint {
    pub fn model_path(&self) -> PathBuf {
        self.dir.join("model.bpk")
    }
    pub fn optimizer_path(&self) -> PathBuf {
        self.dir.join("optimizer.bpk")
    }
}

/// A training run's folder.
#[derive(Debug, Clone)]
pub struct RunDir {
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
    /// Opens `root` for a new run (it must not hold checkpoints unless `resume`)
    /// and writes the config there. When resuming, the saved config must mean the
    /// same as the given one except for the settings that change no computed number
    /// ([`FREE_SETTINGS`]).
    pub fn prepare(root: impl AsRef<Path>, config_toml: &str, resume: bool) -> Result<Self> {
        Self::prepare_normalized(root, config_toml, resume, |_, _| Ok(None))
    }

    /// [`RunDir::prepare`] for a trainer that saves its config normalised (every default
    /// written out): on `--resume` the saved config (its text and path) is compared after
    /// `normalize` (the trainer's parse and re-serialisation; `Ok(None)` compares it as
    /// written), so a run saved by an older version, or with the defaults left out, resumes
    /// when it means the same. A saved config that no longer parses is an error naming it.
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
        let existing = run.latest()?;
        match (&existing, resume) {
            (Some(c), false) => {
                return Err(Error::invalid(
                    &run.root,
                    format!(
                        "run folder already has checkpoints (epoch {}): pass --resume to continue it, or choose another output folder",
                        c.state.epoch
                    ),
                ));
            }
            (None, true) => {
                return Err(Error::invalid(
                    &run.root,
                    "--resume: no checkpoint to resume from in this folder",
                ));
            }
            _ => {}
        }
        let cfg_path = run.root.join("config.toml");
        if resume && cfg_path.is_file() {
            let saved = crate::io::read_text(&cfg_path)?;
            let saved = normalize(&saved, &cfg_path)?.unwrap_or(saved);
            if let Some(diff) = config_difference(&saved, config_toml) {
                return Err(Error::invalid(
                    &cfg_path,
                    format!(
                        "--resume with a config that differs from the one this run was started \
                         with: {diff} (only `epochs`, `keep_checkpoints`, `out` and `backend` may \
                         change)"
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
        let dir = self.checkpoints().join(&l.checkpoint);
        Ok(Some(Self::read(&dir)?))
    }

    /// Reads a checkpoint folder.
    pub fn read(dir: &Path) -> Result<Checkpoint> {
        let p = dir.join("state.json");
        let text = crate::io::read_text(&p)?;
        let state: TrainState =
            serde_json::from_str(&text).map_err(|e| Error::invalid(&p, e.to_string()))?;
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
        let name = format!("epoch-{:04}", state.epoch);
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

/// Settings a resumed run may change: the number of epochs, how many checkpoints are kept,
/// where the run folder is (it may have moved, or be named by another spelling), and the
/// backend (`--backend`: the same computation on another device, equal up to float
/// rounding); none changes what the epochs already run computed.
const FREE_SETTINGS: [&str; 4] = ["epochs", "keep_checkpoints", "out", "backend"];

/// The first difference in meaning between two training configs, as `key: saved -> given`,
/// or `None` when they agree: keys compared as parsed TOML (order, spacing and comments do
/// not matter), [`FREE_SETTINGS`] ignored, and strings naming an existing file or folder
/// compared as canonical paths (`runs/x` and `/home/me/runs/x` agree).
pub fn config_difference(saved: &str, given: &str) -> Option<String> {
    let parse = |t: &str| t.parse::<toml::Table>().ok();
    let (Some(mut a), Some(mut b)) = (parse(saved), parse(given)) else {
        return (saved != given).then(|| "the file (it does not parse as TOML)".to_string());
    };
    for key in FREE_SETTINGS {
        a.remove(key);
        b.remove(key);
    }
    first_difference("", &toml::Value::Table(a), &toml::Value::Table(b))
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
}
