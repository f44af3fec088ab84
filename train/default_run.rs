//! `train` with no `--config`: a short default run that shows the whole training loop on data
//! bundled with the source tree, then says what it trained, where the outputs are and how to
//! run the real recipes.
//!
//! The run is [`CONFIG`] as it is: SDFCNN on the three NYUv2 fixture images
//! (`datasets/fixtures/nyuv2`) at 96x128, 60 epochs on the ndarray backend, into [`OUT`]; from
//! the repository root the same as
//! `train --config configs/train/sdfcnn_tiny.toml --backend ndarray --out runs/train/default`.
//! `--epochs`, `--out`, `--backend`, `--resume`, `--quiet` and `--dry-run` apply to it as to a
//! config. The config and the fixtures are looked up in the working directory, then in the
//! crate's source folder ([`sdf_slam::bundled::locate`]), so the run works from anywhere on the
//! machine that built `train`. An earlier default run in [`OUT`] is replaced.

use anyhow::{Context, Result, bail};
use sdf_slam::bundled::locate;
use sdf_slam::nn::BackendKind;
use sdf_slam::sdfcnn::SdfcnnTrainConfig;
use sdf_slam::training::{RunDir, RunOptions};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The training config of the default run.
pub const CONFIG: &str = "configs/train/sdfcnn_tiny.toml";
/// The images it trains on (what [`CONFIG`] names).
const FIXTURE: &str = "datasets/fixtures/nyuv2";
/// The default run's output folder (under the working directory).
pub const OUT: &str = "runs/train/default";
/// A default run ready to train.
#[derive(Debug)]
pub struct DefaultRun {
    /// The config file it is made from.
    pub config: PathBuf,
    /// The config's text, its data paths pointing at the fixtures from the working directory.
    pub text: String,
    /// ndarray and [`OUT`] unless the command line says otherwise (epochs: the config's).
    pub opts: RunOptions,
}

impl DefaultRun {
    /// The default run with the command line's overrides (`None`: the default's).
    pub fn new(opts: &RunOptions) -> Result<Self> {
        let config = locate(CONFIG).with_context(|| {
            format!(
                "the default run trains on {CONFIG} and the fixtures of datasets/fixtures/, which \
                 are in neither the working directory nor the crate's folder {}: give a config \
                 with --config FILE",
                env!("CARGO_MANIFEST_DIR")
            )
        })?;
        let text = sdf_slam::io::read_text(&config)?;
        let text = with_fixture_paths(&text, &config, locate)?;
        let opts = RunOptions {
            out: Some(opts.out.clone().unwrap_or_else(|| PathBuf::from(OUT))),
            resume: opts.resume,
            backend: Some(opts.backend.unwrap_or(BackendKind::Ndarray)),
            devices: opts.devices.clone(),
            epochs: opts.epochs,
            quiet: opts.quiet,
        };
        Ok(DefaultRun { config, text, opts })
    }

    /// The epochs it trains: `--epochs`, else the config's.
    pub fn epochs(&self) -> Result<usize> {
        match self.opts.epochs {
            Some(n) => Ok(n),
            None => Ok(SdfcnnTrainConfig::parse(&self.text, &self.config)?.epochs),
        }
    }

    /// The output folder.
    pub fn out(&self) -> &Path {
        self.opts.out.as_deref().unwrap_or(Path::new(OUT))
    }
}

/// `text` with every relative `[data]` source path that does not exist from the working
/// directory replaced by where `find` finds it (unchanged text when none needs it).
pub fn with_fixture_paths(
    text: &str,
    config: &Path,
    find: impl Fn(&str) -> Option<PathBuf>,
) -> Result<String> {
    let mut table: toml::Table =
        toml::from_str(text).with_context(|| format!("reading {}", config.display()))?;
    let mut changed = false;
    if let Some(data) = table.get_mut("data").and_then(toml::Value::as_table_mut) {
        for list in ["train", "val"] {
            let Some(sources) = data.get_mut(list).and_then(toml::Value::as_array_mut) else {
                continue;
            };
            for source in sources.iter_mut().filter_map(toml::Value::as_table_mut) {
                let Some(path) = source.get("path").and_then(toml::Value::as_str) else {
                    continue;
                };
                if Path::new(path).is_absolute() || Path::new(path).exists() {
                    continue;
                }
                if let Some(found) = find(path) {
                    source.insert("path".into(), found.display().to_string().into());
                    changed = true;
                }
            }
        }
    }
    Ok(if changed {
        toml::to_string(&table)?
    } else {
        text.to_string()
    })
}

/// Whether `dir` holds a run that `train` with no config made: its saved config trains SDFCNN
/// into [`OUT`].
pub fn is_default_run(dir: &Path) -> bool {
    let Ok(text) = sdf_slam::io::read_text(dir.join("config.toml")) else {
        return false;
    };
    let Ok(table) = toml::from_str::<toml::Table>(&text) else {
        return false;
    };
    table.get("model").and_then(toml::Value::as_str) == Some("sdfcnn")
        && table.get("out").and_then(toml::Value::as_str) == Some(OUT)
}

/// Trains the default run and prints what it did and what to run next.
pub fn run(opts: &RunOptions, dry_run: bool) -> Result<()> {
    let run = DefaultRun::new(opts)?;
    let out = run.out().to_path_buf();
    let epochs = run.epochs()?;
    if dry_run {
        crate::trainers::check_training_config("sdfcnn", &run.config, &run.text)?;
        println!(
            "the default run: a valid sdfcnn config ({}), {} into {}",
            run.config.display(),
            epochs_text(epochs),
            out.display()
        );
        return Ok(());
    }
    // Only the default folder is replaced, and only when an earlier default run made it.
    if opts.out.is_none() && !opts.resume && out.join("config.toml").exists() {
        if !is_default_run(&out) {
            bail!(
                "{} holds a run that is not a default run of `train`: move it away, or give \
                 another folder with --out DIR",
                out.display()
            );
        }
        println!("replacing the earlier default run in {}", out.display());
        sdf_slam::training::clear_run(&out)?;
    }
    println!(
        "no --config: the default run, a short SDFCNN training on the bundled NYUv2 fixture \
         images ({}), {} on {} into {} (train --help: every option)",
        run.config.display(),
        epochs_text(epochs),
        run.opts.backend.unwrap_or(BackendKind::Ndarray),
        out.display()
    );
    let started = Instant::now();
    sdf_slam::sdfcnn::training::run(&run.config, &run.text, &run.opts)?;
    let seconds = started.elapsed().as_secs_f64();
    report(&run, seconds)
}

/// What the run trained, where its outputs are, and the real recipes.
fn report(run: &DefaultRun, seconds: f64) -> Result<()> {
    let out = run.out();
    let last = RunDir {
        root: out.to_path_buf(),
        keep: 0,
    }
    .latest()?
    .with_context(|| format!("{}: the run saved no checkpoint", out.display()))?;
    println!();
    println!(
        "Trained SDFCNN (40-class segmentation + metric depth) for {} in {seconds:.0} s.",
        epochs_text(last.state.epoch)
    );
    if let Some(e) = last.state.history.epochs.last() {
        let value = |k: &str| e.values.get(k).map_or("-".into(), |v| format!("{v:.3}"));
        println!(
            "Last epoch: train loss {}, validation loss {}, mIoU {}, depth RMS {} m \
             (validated on the training images: this shows the loop works, not a model to use).",
            value("train_loss"),
            value("val_loss"),
            value("val_miou"),
            value("val_rms")
        );
    }
    println!("Outputs in {}:", out.display());
    let newest = last.dir.strip_prefix(out).unwrap_or(&last.dir);
    println!(
        "  {}/  the newest checkpoint (model.bpk, optimizer.bpk, state.json, config.toml)",
        newest.display()
    );
    println!("  metrics.csv  one row per epoch");
    let plots = pictures(out);
    if !plots.is_empty() {
        println!("  {}  the curves", plots.join(", "));
    }
    println!("Next:");
    let fixture = locate(FIXTURE).unwrap_or_else(|| PathBuf::from(FIXTURE));
    let mut next = vec![(
        format!(
            "eval seg --checkpoint {} --data {} --out {}",
            out.display(),
            fixture.display(),
            out.join("pred").display()
        ),
        "this run's labels and depth on the fixture images, with the paper's Tables 8-9".into(),
    )];
    next.push((
        "train --config configs/train/sdfcnn_real.toml".into(),
        "SDFCNN as bundled in weights/sdfcnn (the config's header lists the data it needs)".into(),
    ));
    next.extend(fpfdcnn_recipe());
    next.push((
        "train --config configs/train/sweep_lambda_lr.toml".into(),
        "a sweep: 8 SDFCNN runs over the loss weight and the learning rate, ranked (the \
         config's header says which data to generate first)"
            .into(),
    ));
    for (command, what) in next {
        println!("  {command}\n      {what}");
    }
    Ok(())
}

/// The FPFDCNN recipe as a command and what it does: the stage configs of the folder
/// `configs/train/fpfdcnn/`, trained in the order of their names (its README says how).
fn fpfdcnn_recipe() -> Option<(String, String)> {
    const DIR: &str = "configs/train/fpfdcnn";
    let dir = locate(DIR).filter(|d| d.is_dir())?;
    let mut configs: Vec<String> = std::fs::read_dir(&dir)
        .ok()?
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".toml"))
        .collect();
    configs.sort();
    let readme = if dir.join("README.md").is_file() {
        format!(" ({DIR}/README.md)")
    } else {
        String::new()
    };
    let (first, last) = (configs.first()?, configs.last()?);
    Some(if configs.len() == 1 {
        (
            format!("train --config {DIR}/{first}"),
            format!("FPFDCNN as bundled in weights/fpfdcnn{readme}"),
        )
    } else {
        (
            format!("train --config {DIR}/{first}, then each file up to {last}"),
            format!(
                "FPFDCNN as bundled in weights/fpfdcnn, {} stages in order{readme}",
                configs.len()
            ),
        )
    })
}

/// "1 epoch", "60 epochs".
fn epochs_text(n: usize) -> String {
    format!("{n} epoch{}", if n == 1 { "" } else { "s" })
}

/// The names of the run folder's pictures.
fn pictures(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .filter(|n| n.ends_with(".png"))
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixture_paths_are_redirected_only_where_missing() {
        let text = "model = \"sdfcnn\"\n[data]\ntrain = [{ path = \"no/such/fixture\" }]\n\
                    val = [{ path = \"Cargo.toml\" }, { path = \"/abs/olute\" }]\n";
        let found = |p: &str| Some(Path::new("/crate").join(p));
        let out = with_fixture_paths(text, Path::new("c.toml"), found).unwrap();
        let t: toml::Table = toml::from_str(&out).unwrap();
        let path = |list: &str, i: usize| t["data"][list][i]["path"].as_str().unwrap().to_string();
        assert_eq!(path("train", 0), "/crate/no/such/fixture");
        // Found from the working directory (tests run in the crate root), or absolute: kept.
        assert_eq!(path("val", 0), "Cargo.toml");
        assert_eq!(path("val", 1), "/abs/olute");
        // Nothing to redirect: the text as it was, comments and all.
        let kept = "# c\nmodel = \"sdfcnn\"\n[data]\ntrain = [{ path = \"Cargo.toml\" }]\n";
        assert_eq!(
            with_fixture_paths(kept, Path::new("c.toml"), found).unwrap(),
            kept
        );
        assert!(with_fixture_paths("data = [", Path::new("c.toml"), found).is_err());
    }

    #[test]
    fn the_default_run_is_the_tiny_config_with_overrides() {
        let run = DefaultRun::new(&RunOptions::default()).unwrap();
        assert!(run.config.ends_with(CONFIG));
        assert_eq!(run.opts.epochs, None);
        // The config's epochs, as the long help says.
        assert_eq!(run.epochs().unwrap(), 60);
        assert_eq!(run.opts.backend, Some(BackendKind::Ndarray));
        assert_eq!(run.out(), Path::new(OUT));
        crate::trainers::check_training_config("sdfcnn", &run.config, &run.text).unwrap();
        let given = RunOptions {
            out: Some("elsewhere".into()),
            epochs: Some(2),
            ..Default::default()
        };
        let run = DefaultRun::new(&given).unwrap();
        assert_eq!(
            (run.out(), run.epochs().unwrap()),
            (Path::new("elsewhere"), 2)
        );
    }

    #[test]
    fn only_a_default_runs_folder_counts_as_one() {
        let dir = sdf_slam::io::ScratchDir::new("train_default_run_marker").unwrap();
        assert!(!is_default_run(&dir));
        std::fs::write(
            dir.join("config.toml"),
            format!("model = \"sdfcnn\"\nout = \"{OUT}\"\n"),
        )
        .unwrap();
        assert!(is_default_run(&dir));
        std::fs::write(
            dir.join("config.toml"),
            "model = \"sdfcnn\"\nout = \"runs/mine\"\n",
        )
        .unwrap();
        assert!(!is_default_run(&dir));
    }
}
