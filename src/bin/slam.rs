//! `slam`: runs SDF-SLAM on a TUM RGB-D layout sequence and writes the
//! trajectory, the semantic map (PLY + picture) and a report.
//!
//! ```text
//! slam [--sequence DIR] [--camera fr1|fr2|fr3|FILE] [--depth sensor|predicted]
//!      [--features fpfdcnn|orb] [--fpfdcnn CKPT] [--labels gt|sdfcnn|none] [--sdfcnn CKPT]
//!      [--config configs/slam.toml] [--out DIR] [--backend ndarray|flex]
//!      [--single-thread] [--max-frames N]
//! ```

use anyhow::{Context, Result, bail};
use clap::{Parser, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use sdf_slam::camera::Camera;
use sdf_slam::dataset::TumSequence;
use sdf_slam::fpfdcnn::inference::FpfdcnnDetector;
use sdf_slam::slam::report::{write_outputs, write_trajectory};
use sdf_slam::slam::system::{Log, Progress};
use sdf_slam::slam::tracking::FrameRecord;
use sdf_slam::slam::{
    Control, DepthMode, FpfdcnnSource, GroundTruthSource, KeypointSource, NoLabels, OrbSource,
    SemanticSource, Slam, SlamConfig,
};
use sdf_slam::training::BackendKind;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// The sequence run when none is given.
const DEFAULT_SEQUENCE: &str = "datasets/generated/default_sequence";

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum DepthArg {
    /// RGB-D: the sequence's depth images.
    Sensor,
    /// Monocular: depth from the semantic source (SDFCNN).
    Predicted,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum FeaturesArg {
    /// The paper's FPFDCNN (needs --fpfdcnn).
    Fpfdcnn,
    /// ORB baseline (cv::ORB_create(500)).
    Orb,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum LabelsArg {
    /// Ground-truth labels of a synthetic sequence (labels.txt + labels/).
    Gt,
    /// SDFCNN predictions (needs --sdfcnn).
    Sdfcnn,
    /// No semantics: the map is coloured by RGB only.
    None,
}

#[derive(Parser, Debug)]
#[command(
    name = "slam",
    version,
    about = "SDF-SLAM: semantic RGB-D / monocular SLAM on a TUM RGB-D layout sequence"
)]
struct Cli {
    /// Sequence folder in the TUM RGB-D layout.
    #[arg(long, default_value = DEFAULT_SEQUENCE)]
    sequence: PathBuf,
    /// Camera: fr1, fr2, fr3 or a camera TOML file [default: the sequence's
    /// camera.toml if it has one, else fr1].
    #[arg(long)]
    camera: Option<String>,
    /// Depth source: sensor (RGB-D) or predicted (monocular).
    #[arg(long, value_enum, default_value_t = DepthArg::Sensor)]
    depth: DepthArg,
    /// Keypoints [default: fpfdcnn when --fpfdcnn is given, else orb].
    #[arg(long, value_enum)]
    features: Option<FeaturesArg>,
    /// FPFDCNN checkpoint (model.bpk, its folder, or a training run folder).
    #[arg(long)]
    fpfdcnn: Option<PathBuf>,
    /// SDFCNN checkpoint.
    #[arg(long)]
    sdfcnn: Option<PathBuf>,
    /// Semantic labels [default: gt when the sequence has labels.txt, else none].
    #[arg(long, value_enum)]
    labels: Option<LabelsArg>,
    /// SLAM configuration (TOML, see configs/slam.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Output folder [default: runs/slam/<sequence name>].
    #[arg(long)]
    out: Option<PathBuf>,
    /// Burn backend for the networks.
    #[arg(long, value_enum, default_value_t = BackendKind::Ndarray)]
    backend: BackendKind,
    /// Run tracking, mapping and correction in order on one thread (deterministic).
    #[arg(long)]
    single_thread: bool,
    /// Process at most this many frames.
    #[arg(long)]
    max_frames: Option<usize>,
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    if !cli.sequence.is_dir() {
        if cli.sequence == Path::new(DEFAULT_SEQUENCE) {
            bail!(
                "the default sequence {DEFAULT_SEQUENCE} does not exist yet: generate a synthetic \
                 sequence with the synthetic generator into that folder, or run on your own data \
                 with --sequence DIR (a TUM RGB-D layout folder, e.g. rgbd_dataset_freiburg1_desk2)"
            );
        }
        bail!("sequence folder {} does not exist", cli.sequence.display());
    }
    let mut config = match &cli.config {
        Some(p) => SlamConfig::load(p)?,
        None => SlamConfig::default(),
    };
    if cli.single_thread {
        config.system.threads = false;
    }
    let sequence = TumSequence::open(&cli.sequence)?;
    let camera = match &cli.camera {
        Some(spec) => Camera::load(spec)?,
        None if cli.sequence.join("camera.toml").is_file() => {
            Camera::from_file(cli.sequence.join("camera.toml"))?
        }
        None => Camera::tum_fr1(),
    };
    let features = cli.features.unwrap_or(if cli.fpfdcnn.is_some() {
        FeaturesArg::Fpfdcnn
    } else {
        FeaturesArg::Orb
    });
    let keypoints: Box<dyn KeypointSource> = match features {
        FeaturesArg::Orb => Box::new(OrbSource::from_config(&config.features)),
        FeaturesArg::Fpfdcnn => {
            let Some(ckpt) = &cli.fpfdcnn else {
                bail!("--features fpfdcnn needs a checkpoint: --fpfdcnn CKPT");
            };
            let detector = FpfdcnnDetector::load(ckpt, cli.backend, config.features.detector())
                .with_context(|| format!("loading FPFDCNN from {}", ckpt.display()))?;
            Box::new(FpfdcnnSource { detector })
        }
    };
    let has_labels = cli.sequence.join("labels.txt").is_file();
    let labels = cli.labels.unwrap_or(if has_labels {
        LabelsArg::Gt
    } else {
        LabelsArg::None
    });
    let semantics: Box<dyn SemanticSource> = match labels {
        LabelsArg::None => Box::new(NoLabels),
        LabelsArg::Gt => Box::new(GroundTruthSource::open(
            &cli.sequence,
            sequence.config.depth_scale,
        )?),
        LabelsArg::Sdfcnn => bail!(
            "--labels sdfcnn: SDFCNN inference is not part of this build yet{}; use --labels gt \
             (synthetic sequences) or --labels none",
            cli.sdfcnn
                .as_ref()
                .map(|p| format!(" (checkpoint {} not loaded)", p.display()))
                .unwrap_or_default()
        ),
    };
    let depth = match cli.depth {
        DepthArg::Sensor => DepthMode::Sensor,
        DepthArg::Predicted => DepthMode::Predicted,
    };
    let out_dir = cli
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs/slam").join(sequence.name()));
    let n = cli
        .max_frames
        .map_or(sequence.len(), |m| m.min(sequence.len()));
    let slam = Slam {
        sequence: sequence.clone(),
        camera: camera.clone(),
        config: config.clone(),
        depth,
        keypoints,
        semantics,
        max_frames: cli.max_frames,
    };
    slam.validate()?;
    eprintln!(
        "sequence {} ({n} frames), camera {}, {} mode, {} keypoints, {} labels, {}",
        sequence.root.display(),
        if camera.name.is_empty() {
            "from file"
        } else {
            &camera.name
        },
        match depth {
            DepthMode::Sensor => "RGB-D",
            DepthMode::Predicted => "monocular",
        },
        slam.keypoints.name(),
        slam.semantics.name(),
        if config.system.threads {
            "3 threads"
        } else {
            "single thread"
        }
    );
    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || {
            if stop.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
            eprintln!("\nstopping after the current frame (Ctrl-C again to quit at once)");
        })
        .context("installing the Ctrl-C handler")?;
    }
    let bar = ProgressBar::new(n as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} frames {per_sec} {msg}",
        )
        .map_err(|e| anyhow::anyhow!("{e}"))?
        .progress_chars("=> "),
    );
    let log_bar = bar.clone();
    let log: Log = Arc::new(move |m: &str| log_bar.suspend(|| eprintln!("{m}")));
    let frame_bar = bar.clone();
    let control = Control {
        stop,
        log,
        on_frame: Some(Box::new(move |_r: &FrameRecord, p: &Progress| {
            frame_bar.set_position(p.done as u64);
            frame_bar.set_message(format!("keyframes {} lost {}", p.keyframes, p.lost));
        })),
    };
    let output = slam.run(control)?;
    bar.finish_and_clear();
    // The trajectory first: it is what an interrupted run must not lose.
    write_trajectory(&output, &out_dir)?;
    let report = write_outputs(&output, &sequence, &camera, &config, &out_dir)?;
    println!("{}", report.summary());
    Ok(())
}
