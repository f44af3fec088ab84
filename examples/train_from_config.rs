//! Train a network from code on a training config, as `train --config` does: the config names
//! the network (`model = "sdfcnn"` or `"fpfdcnn"`), its data and its schedule; the run's output
//! folder, epochs and backend are overridden here, then the last epoch's losses are read back
//! from the run's newest checkpoint.
//!
//! ```text
//! cargo run --release --example train_from_config -- [CONFIG] [--out DIR] [--epochs N]
//! ```
//!
//! Defaults: `configs/train/sdfcnn_tiny.toml` (three NYUv2 fixture images at 96x128) for 3
//! epochs on the ndarray backend into `runs/examples/train_from_config`, which is replaced.

use anyhow::{Context, Result, bail};
use sdf_slam::bundled::locate;
use sdf_slam::nn::BackendKind;
use sdf_slam::training::{RunDir, RunOptions, config_model};
use std::path::PathBuf;

const DEFAULT_CONFIG: &str = "configs/train/sdfcnn_tiny.toml";
const DEFAULT_OUT: &str = "runs/examples/train_from_config";
const USAGE: &str = "usage: train_from_config [CONFIG] [--out DIR] [--epochs N]";

fn main() -> Result<()> {
    let (mut config, mut out, mut epochs) = (None, None, 3);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--out" => out = Some(PathBuf::from(args.next().context("--out needs a folder")?)),
            "--epochs" => {
                let v = args.next().context("--epochs needs a number")?;
                epochs = v
                    .parse()
                    .ok()
                    .filter(|n| *n > 0)
                    .with_context(|| format!("--epochs {v}: a positive number of epochs"))?;
            }
            s if s.starts_with('-') => bail!("unknown option {s}: {USAGE}"),
            _ if config.is_none() => config = Some(PathBuf::from(a)),
            _ => bail!("one config at a time (got {a} as well): {USAGE}"),
        }
    }
    let config = match config {
        Some(p) => p,
        None => locate(DEFAULT_CONFIG)
            .with_context(|| format!("the default config {DEFAULT_CONFIG} is not here"))?,
    };
    let out = match out {
        Some(o) => o,
        None => {
            // The example's own folder: an earlier run of it is replaced (a run folder that
            // holds checkpoints is otherwise only continued, with `resume`).
            let o = PathBuf::from(DEFAULT_OUT);
            if o.exists() {
                std::fs::remove_dir_all(&o).with_context(|| format!("removing {}", o.display()))?;
            }
            o
        }
    };

    let text = sdf_slam::io::read_text(&config)?;
    let options = RunOptions {
        out: Some(out.clone()),
        resume: false,
        backend: Some(BackendKind::Ndarray),
        devices: None,
        epochs: Some(epochs),
        quiet: true,
    };
    // Data paths in the config are relative to the working directory or the config's folder.
    match config_model(&text, &config)?.as_str() {
        "sdfcnn" => sdf_slam::sdfcnn::training::run(&config, &text, &options)?,
        "fpfdcnn" => sdf_slam::fpfdcnn::training::run(&config, &text, &options)?,
        other => bail!(
            "{}: model = \"{other}\" is not a network (sweeps run with `train --config`)",
            config.display()
        ),
    }

    // Every checkpoint holds the run's history, `metrics.csv`'s rows.
    let run = RunDir {
        root: out.clone(),
        keep: 0,
    };
    let last = run.latest()?.context("the run saved no checkpoint")?;
    let epoch = last
        .state
        .history
        .epochs
        .last()
        .context("the run recorded no epoch")?;
    println!(
        "{} trained into {}, epochs done: {}",
        config.display(),
        out.display(),
        last.state.epoch
    );
    println!("checkpoint: {}", last.dir.display());
    println!("epoch {} (lr {}):", epoch.epoch, epoch.lr);
    for (name, value) in epoch.values.iter().filter(|(k, _)| k.contains("loss")) {
        println!("  {name:<20} {value:.5}");
    }
    Ok(())
}
