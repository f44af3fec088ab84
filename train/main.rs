//! `train`: command-line entry point for the SDF-SLAM networks.
//!
//! With no `--config` (and no subcommand) it trains the short default run of
//! [`default_run`]: SDFCNN on the bundled NYUv2 fixture images into `runs/train/default`, then
//! says what it trained, where the outputs are and how to run the real recipes.
//!
//! `train --config FILE [--resume] [--out DIR] [--backend ndarray|flex] [--epochs N]` trains
//! the network the config names (`model = "fpfdcnn"` or `"sdfcnn"`), or runs a sweep of
//! training runs (`model = "sweep"`, see [`sweep`]). `--dry-run` only
//! checks the config (and lists a sweep's runs). The networks it knows are listed in one
//! place, [`trainers`].
//!
//! `train export CKPT --out DIR` writes half-precision weights (the bundled layout);
//! `train average CKPT... --out DIR` averages FPFDCNN checkpoints' weights (SWA).
//!
//! `train summary fpfdcnn|sdfcnn` runs one forward pass on a zero image and prints each layer's
//! output shape under the names of the paper's Table 12 (FPFDCNN) and Table 13 (SDFCNN), then
//! the trainable-parameter count.

mod default_run;
mod outputs;
mod sweep;
mod trainers;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use sdf_slam::nn::BackendKind;
use sdf_slam::nn::ShapeTrace;
use sdf_slam::training::{RunOptions, config_model};
use std::path::PathBuf;
use sweep::Sweep;
use trainers::Network;

#[derive(Parser, Debug)]
#[command(
    about = "Train and inspect the SDF-SLAM networks (FPFDCNN, SDFCNN)",
    long_about = "Train and inspect the SDF-SLAM networks (FPFDCNN, SDFCNN).\n\n\
        With no --config it trains the default run, configs/train/sdfcnn_tiny.toml on ndarray \
        into runs/train/default: SDFCNN on the three bundled NYUv2 fixture images at 96x128 for \
        60 epochs, a minute or two on 2 cores (an earlier default run there is replaced). Then \
        it prints where the checkpoints, metrics.csv and plots are and the commands of the real \
        recipes. --epochs, --out, --backend, --resume and --dry-run apply to it as to a config."
)]
#[command(args_conflicts_with_subcommands = true)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    run: RunArgs,
}

/// Training from a config file.
#[derive(clap::Args, Debug)]
struct RunArgs {
    /// Training config (TOML), e.g. configs/train/fpfdcnn_tiny.toml [default: the default run,
    /// configs/train/sdfcnn_tiny.toml into runs/train/default].
    #[arg(long)]
    config: Option<PathBuf>,
    /// Continue from the last checkpoint of the output folder (sweeps always resume).
    #[arg(long)]
    resume: bool,
    /// Start a new run in an output folder that holds an earlier run: its checkpoints,
    /// metrics.csv, config.toml and pictures are removed first (without it, such a folder is
    /// an error).
    #[arg(long, conflicts_with = "resume")]
    overwrite: bool,
    /// Output folder (overrides the config's `out`).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Backend (overrides the config's `backend`).
    #[arg(long, value_enum)]
    backend: Option<BackendKind>,
    /// Data-parallel training on these GPUs of the backend, e.g. `wgpu:0,wgpu:1` (overrides
    /// the config's `devices`; docs/training.md, *Several GPUs*).
    #[arg(long, value_delimiter = ',', num_args = 1..)]
    devices: Option<Vec<sdf_slam::nn::DeviceSpec>>,
    /// Number of epochs (overrides the config's `epochs`), 1-100000.
    #[arg(long, value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(1..=100_000))]
    epochs: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Check the config (a sweep: every point) and list a sweep's runs; train nothing.
    #[arg(long)]
    dry_run: bool,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Print every layer's output shape for one input, and the parameter count.
    Summary(SummaryArgs),
    /// Write a checkpoint's weights in half precision with its config beside them
    /// (`OUT/model.bpk`, `OUT/config.toml`): the layout of the bundled weights.
    Export(ExportArgs),
    /// Average the weights of several checkpoints of one FPFDCNN run (SWA, Izmailov et al.
    /// 2018) into a checkpoint folder (`OUT/model.bpk`, `OUT/config.toml`) that `export`,
    /// `eval --fpfdcnn` and a config's `init` accept.
    Average(AverageArgs),
}

#[derive(clap::Args, Debug)]
struct AverageArgs {
    /// Checkpoints (folders holding model.bpk and config.toml), e.g.
    /// runs/fpfdcnn_stage7/checkpoints/epoch-00{11..30} (a run at a constant learning rate
    /// with `keep_checkpoints = 0`).
    #[arg(required = true, num_args = 2..)]
    checkpoints: Vec<PathBuf>,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
}

#[derive(clap::Args, Debug)]
struct ExportArgs {
    /// Checkpoint: a `model.bpk`, its folder, or a run folder (its newest checkpoint).
    checkpoint: PathBuf,
    /// Output folder.
    #[arg(long)]
    out: PathBuf,
}

#[derive(clap::Args, Debug)]
struct SummaryArgs {
    /// Network to summarise.
    network: Network,
    /// Input height.
    #[arg(long, default_value_t = 480)]
    height: usize,
    /// Input width.
    #[arg(long, default_value_t = 640)]
    width: usize,
    /// Burn backend to run the forward pass on.
    #[arg(long, value_enum, default_value_t = BackendKind::Ndarray)]
    backend: BackendKind,
}

fn main() -> Result<()> {
    sdf_slam::malloc::tune_for_tensors();
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Summary(args)) => summary(&args),
        Some(Command::Export(args)) => export(&args),
        Some(Command::Average(args)) => average(&args),
        None => train(cli.run),
    }
}

fn train(args: RunArgs) -> Result<()> {
    let opts = RunOptions {
        out: args.out,
        resume: args.resume,
        backend: args.backend,
        devices: args.devices,
        epochs: args.epochs,
        quiet: args.quiet,
    };
    // One writer per folder, and no new run over an earlier one's files (`--overwrite`).
    let _lock = outputs::lock_run_folder(
        args.config.as_deref(),
        &opts,
        args.overwrite,
        args.dry_run,
        default_run::OUT,
    )?;
    let Some(config) = args.config else {
        return default_run::run(&opts, args.dry_run);
    };
    let text = sdf_slam::io::read_text(&config)?;
    let model = config_model(&text, &config)?;
    if args.dry_run {
        if model == "sweep" {
            print!("{}", Sweep::load(&config, &text, &opts)?.describe()?);
        } else {
            trainers::check_training_config(&model, &config, &text)?;
            println!("{}: a valid {model} config", config.display());
        }
        return Ok(());
    }
    if model == "sweep" {
        sweep::run(&config, &text, &opts)?;
    } else {
        let Some(trainer) = trainers::trainer(&model) else {
            return Err(trainers::no_trainer(&config, &model));
        };
        (trainer.run)(&config, &text, &opts)?;
    }
    Ok(())
}

/// `train export`: half-precision weights and the training config, written atomically.
fn export(args: &ExportArgs) -> Result<()> {
    use sdf_slam::training::resolve_checkpoint;
    let (weights, config) = resolve_checkpoint(&args.checkpoint)?;
    let _lock = outputs::export_folder(&weights, &args.out)?;
    let text = sdf_slam::io::read_text(&config)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let target = args.out.join("model.bpk");
    let model = config_model(&text, &config)?;
    let Some(trainer) = trainers::trainer(&model) else {
        anyhow::bail!("{}: no network called \"{model}\"", config.display());
    };
    (trainer.export)(&weights, &target)?;
    sdf_slam::io::write_atomic(args.out.join("config.toml"), text.as_bytes())?;
    let size = std::fs::metadata(&target)?.len();
    println!(
        "{} -> {} ({:.1} MB, half precision) and config.toml",
        weights.display(),
        target.display(),
        size as f64 / 1e6
    );
    Ok(())
}

/// `train average`: the mean of several FPFDCNN checkpoints' weights, in full precision,
/// with the first checkpoint's config (a comment lists the checkpoints averaged).
fn average(args: &AverageArgs) -> Result<()> {
    use sdf_slam::fpfdcnn::inference::FpfdcnnDetector;
    use sdf_slam::nn::weights::{average_modules, save_atomic};
    use sdf_slam::training::resolve_checkpoint;
    let mut models = Vec::new();
    let mut names = Vec::new();
    let mut first_config = None;
    let mut inputs = Vec::new();
    for checkpoint in &args.checkpoints {
        let (weights, config) = resolve_checkpoint(checkpoint)?;
        inputs.push(outputs::average_input(&weights, &config)?);
        if names.contains(&weights.display().to_string()) {
            anyhow::bail!(
                "{} is given twice: each checkpoint is averaged once",
                weights.display()
            );
        }
        let text = sdf_slam::io::read_text(&config)?;
        if config_model(&text, &config)? != "fpfdcnn" {
            anyhow::bail!(
                "{}: only FPFDCNN checkpoints can be averaged (SDFCNN's batch-norm statistics would need recomputing)",
                config.display()
            );
        }
        let det = FpfdcnnDetector::load(&weights, BackendKind::Flex, Default::default())?;
        models.push(det.model);
        names.push(weights.display().to_string());
        first_config.get_or_insert(text);
    }
    let _lock = outputs::average_inputs(&inputs, &args.out)?;
    let mean = average_modules(models, &names)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let target = args.out.join("model.bpk");
    save_atomic(mean, &target)?;
    let mut text = format!(
        "# Weights averaged (train average) over {} checkpoints:\n",
        names.len()
    );
    for n in &names {
        text.push_str(&format!("#   {n}\n"));
    }
    text.push_str(&first_config.unwrap_or_default());
    sdf_slam::io::write_atomic(args.out.join("config.toml"), text.as_bytes())?;
    println!(
        "mean of {} checkpoints -> {} and config.toml",
        names.len(),
        target.display()
    );
    Ok(())
}

fn summary(args: &SummaryArgs) -> Result<()> {
    let [h, w] = [args.height, args.width];
    let mut trace = ShapeTrace::enabled();
    let (parameters, all) = (args.network.trainer().summary)(&mut trace, [h, w], args.backend)?;
    println!(
        "{:?} on {:?}, input {h}x{w} (HxW)",
        args.network, args.backend
    );
    println!(
        "{:<14} {:<36} {:<22} H×W×C",
        "layer", "method", "output [N, C, H, W]"
    );
    for layer in trace.layers() {
        let hwc = match layer.shape[..] {
            [_, c, h, w] => format!("{h}×{w}×{c}"),
            _ => String::new(),
        };
        println!(
            "{:<14} {:<36} {:<22} {hwc}",
            layer.name,
            layer.method,
            format!("{:?}", layer.shape)
        );
    }
    println!("parameters: {parameters}");
    if all > parameters {
        println!(
            "batch-norm running statistics (not trainable): {}",
            all - parameters
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn help_names_the_default_runs_config_and_epochs() {
        let help = Cli::command().render_long_help().to_string();
        let run = default_run::DefaultRun::new(&RunOptions::default()).unwrap();
        let epochs = format!("for {} epochs", run.epochs().unwrap());
        assert!(help.contains(&epochs), "{help}");
        assert!(help.contains(default_run::CONFIG) && help.contains(default_run::OUT));
    }
}
