//! `synth`: synthetic indoor RGB-D sequences (TUM layout) and a segmentation /
//! depth training set (NYU PNG layout) with exact depth, NYU40 labels and poses.
//!
//! ```text
//! synth [--config configs/synth/default.toml] [--seed N] [--frames N]
//!       [--trajectory sweep|rpy|robot|walk] [--scenes N] [--resolution 640x480]
//!       [--camera fr1|fr2|fr3|FILE] [--blur] [--nyu-only|--sequence-only] --out DIR
//! ```

use anyhow::{Context, Result, bail};
use clap::Parser;
use indicatif::{ProgressBar, ProgressStyle};
use sdf_slam::output_lock::{OutputLock, command_line};
use sdf_slam::synth::{self, SynthConfig, TrajectoryKind, config::parse_resolution};
use sdf_slam::training::checkpoint::config_difference;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Parser)]
#[command(
    name = "synth",
    version,
    about = "Generate synthetic indoor RGB-D data with exact depth, NYU40 labels and poses"
)]
struct Cli {
    /// TOML configuration (default: configs/synth/default.toml when it exists,
    /// else the built-in defaults).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Master seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Frames per sequence.
    #[arg(long)]
    frames: Option<usize>,
    /// Camera motion: sweep, rpy, robot or walk.
    #[arg(long)]
    trajectory: Option<String>,
    /// Number of rooms.
    #[arg(long)]
    scenes: Option<usize>,
    /// Image size WIDTHxHEIGHT.
    #[arg(long)]
    resolution: Option<String>,
    /// fr1, fr2, fr3 or a camera TOML file.
    #[arg(long)]
    camera: Option<String>,
    /// Motion blur on.
    #[arg(long)]
    blur: bool,
    /// Only the NYU-layout training set.
    #[arg(long, conflicts_with = "sequence_only")]
    nyu_only: bool,
    /// Only the TUM-layout sequences.
    #[arg(long)]
    sequence_only: bool,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    let mut cfg = match &cli.config {
        Some(p) => SynthConfig::from_file(p)?,
        None => {
            let default = Path::new("configs/synth/default.toml");
            if default.is_file() {
                SynthConfig::from_file(default)?
            } else {
                SynthConfig::default()
            }
        }
    };
    if let Some(v) = cli.seed {
        cfg.seed = v;
    }
    if let Some(v) = cli.frames {
        cfg.frames = v;
    }
    if let Some(v) = &cli.trajectory {
        cfg.trajectory = v.parse::<TrajectoryKind>()?;
    }
    if let Some(v) = cli.scenes {
        cfg.scenes = v;
    }
    if let Some(v) = &cli.resolution {
        parse_resolution(v)?;
        cfg.resolution = v.clone();
    }
    if let Some(v) = &cli.camera {
        cfg.camera = v.clone();
    }
    if cli.blur {
        cfg.blur.enabled = true;
    }
    if cli.nyu_only {
        cfg.output.sequence = false;
        cfg.output.nyu = true;
    }
    if cli.sequence_only {
        cfg.output.sequence = true;
        cfg.output.nyu = false;
    }
    cfg.validate()?;
    let camera = cfg.camera()?;
    let total = synth::work_units(&cfg);
    if total == 0 {
        bail!("nothing to generate");
    }
    eprintln!(
        "synth: seed {}, {} scene(s), {} x {} {}, {:?} trajectory, {} frames{} -> {}",
        cfg.seed,
        cfg.scenes,
        camera.width,
        camera.height,
        if camera.name.is_empty() {
            "camera"
        } else {
            &camera.name
        },
        cfg.trajectory,
        cfg.frames,
        if cfg.blur.enabled {
            " (motion blur)"
        } else {
            ""
        },
        cli.out.display()
    );
    // One writer per output folder, and no synthetic data of two configs in one.
    let _lock = OutputLock::acquire(&cli.out, &command_line())?;
    let saved = cli.out.join("config.toml");
    if saved.is_file() {
        let text = sdf_slam::io::read_text(&saved)?;
        if let Some(diff) = config_difference(&text, &cfg.to_toml()?) {
            bail!(
                "{} holds synthetic data of another config ({diff}): writing this one there \
                 would mix the two; choose another --out, or remove the folder first",
                cli.out.display()
            );
        }
    }
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template("{bar:40} {pos}/{len} images  {per_sec}  eta {eta}")
            .context("progress bar template")?,
    );
    let start = Instant::now();
    let summary = synth::generate(&cfg, &cli.out, &|n| bar.inc(n));
    bar.finish_and_clear();
    let summary = summary?;
    let secs = start.elapsed().as_secs_f64();
    eprintln!(
        "wrote {} sequence frames and {} + {} NYU-layout images in {:.1} s ({:.1} images/s); {} classes in view (all images)",
        summary.frames,
        summary.nyu_train,
        summary.nyu_test,
        secs,
        total as f64 / secs.max(1e-9),
        summary.histogram.classes_present()
    );
    Ok(())
}
