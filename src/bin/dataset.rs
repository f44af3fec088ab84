//! `dataset`: public datasets from their own layouts into the TUM RGB-D layout the other
//! commands read.
//!
//! ```text
//! dataset seven-scenes SEQ_FOLDER --out DIR [--first N] [--count M] [--registration FILE]
//! ```

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use sdf_slam::dataset::seven_scenes::{self, ConvertOptions, Registration};
use std::path::PathBuf;
use std::time::Instant;

#[derive(Parser)]
#[command(
    name = "dataset",
    version,
    about = "Convert public RGB-D datasets into the TUM RGB-D layout"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// A Microsoft 7-Scenes sequence folder (e.g. redkitchen/seq-01: frame-NNNNNN.color.png,
    /// .depth.png, .pose.txt): depth registered to the colour camera, poses moved to it,
    /// written with the colour camera's camera.toml
    SevenScenes {
        /// The sequence folder, as 7-Scenes' zip files unpack it.
        src: PathBuf,
        /// Output folder (must not already hold a sequence).
        #[arg(long)]
        out: PathBuf,
        /// First frame number to convert.
        #[arg(long, default_value_t = 0)]
        first: usize,
        /// Number of frames to convert [default: all from --first on].
        #[arg(long)]
        count: Option<usize>,
        /// Registration TOML (depth camera, colour camera, depth-to-colour offset)
        /// [default: the one of the converted redkitchen frames in the README's Data formats].
        #[arg(long)]
        registration: Option<PathBuf>,
    },
}

fn main() -> Result<()> {
    match Cli::parse().command {
        Command::SevenScenes {
            src,
            out,
            first,
            count,
            registration,
        } => {
            let registration = match registration {
                Some(p) => Registration::from_file(&p)?,
                None => Registration::default(),
            };
            let options = ConvertOptions {
                first,
                count,
                registration,
            };
            // One writer per output folder.
            let _lock = sdf_slam::output_lock::OutputLock::acquire(
                &out,
                &sdf_slam::output_lock::command_line(),
            )?;
            let started = Instant::now();
            let bar = ProgressBar::new(0).with_style(
                ProgressStyle::with_template("{bar:40} {pos}/{len} frames {elapsed} (eta {eta})")
                    .context("progress bar template")?,
            );
            let summary = seven_scenes::convert(&src, &out, &options, |done, total| {
                bar.set_length(total as u64);
                bar.set_position(done as u64);
            })
            .with_context(|| format!("converting {}", src.display()))?;
            bar.finish_and_clear();
            println!(
                "{} frames ({}..{}) of {} -> {} in {:.1} s; {:.1} % of colour pixels have a \
                 registered depth reading on average",
                summary.frames,
                summary.first,
                summary.last,
                src.display(),
                out.display(),
                started.elapsed().as_secs_f64(),
                100.0 * summary.depth_coverage
            );
        }
    }
    Ok(())
}
