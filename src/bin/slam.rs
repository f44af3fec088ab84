//! `slam`: runs SDF-SLAM on a TUM RGB-D layout sequence and writes the
//! trajectory, the semantic map (PLY + picture) and a report.
//!
//! With no arguments: the synthetic default sequence (generated on first use),
//! RGB-D mode, FPFDCNN keypoints and SDFCNN labels from the bundled weights
//! (see [`sdf_slam::bundled`]).
//!
//! ```text
//! slam [--sequence DIR] [--camera fr1|fr2|fr3|FILE] [--depth sensor|predicted]
//!      [--features fpfdcnn|orb] [--fpfdcnn CKPT] [--labels gt|sdfcnn|none] [--sdfcnn CKPT]
//!      [--config configs/slam/default.toml] [--out DIR] [--backend ndarray|flex|wgpu|cuda]
//!      [--single-thread] [--max-frames N] [--first N] [--camera-height METRES] [--overwrite]
//! ```

use anyhow::{Context, Result, bail};
use clap::{Parser, ValueEnum};
use indicatif::{ProgressBar, ProgressStyle};
use sdf_slam::bundled::{
    BUNDLED_FPFDCNN, BUNDLED_SDFCNN, DEFAULT_SEQUENCE, bundled_weights, default_sequence,
    default_sequence_config, generate_sequence,
};
use sdf_slam::camera::Camera;
use sdf_slam::dataset::TumSequence;
use sdf_slam::fpfdcnn::inference::FpfdcnnDetector;
use sdf_slam::nn::BackendKind;
use sdf_slam::output_lock::{OutputLock, command_line};
use sdf_slam::signals::StopSignals;
use sdf_slam::slam::frontend::tracking::FrameRecord;
use sdf_slam::slam::mapping::scale_anchor::check_camera_height;
use sdf_slam::slam::output::{write_outputs, write_trajectory};
use sdf_slam::slam::system::{Log, Progress};
use sdf_slam::slam::{
    Control, DepthMode, FpfdcnnSource, GroundTruthSource, KeypointSource, NoLabels, OrbSource,
    SdfcnnSource, SemanticSource, Slam, SlamConfig,
};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum DepthArg {
    /// RGB-D: the sequence's depth images.
    Sensor,
    /// Monocular: metric depth predicted by SDFCNN (--labels sdfcnn).
    Predicted,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum FeaturesArg {
    /// The paper's FPFDCNN (--fpfdcnn CKPT, or the bundled weights/fpfdcnn).
    Fpfdcnn,
    /// ORB baseline (cv::ORB_create(500)).
    Orb,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum LabelsArg {
    /// Ground-truth labels of a synthetic sequence (labels.txt + labels/).
    Gt,
    /// SDFCNN predictions (--sdfcnn CKPT, or the bundled weights/sdfcnn).
    Sdfcnn,
    /// No semantics: the map is coloured by RGB only.
    None,
}

#[derive(Parser, Debug)]
#[command(
    name = "slam",
    version,
    about = "SDF-SLAM: semantic RGB-D / monocular SLAM on a TUM RGB-D layout sequence",
    long_about = "SDF-SLAM: semantic RGB-D / monocular SLAM on a TUM RGB-D layout sequence.\n\n\
        With no arguments it runs the bundled default: the synthetic sequence \
        datasets/generated/default_sequence (generated on first use), RGB-D mode, FPFDCNN \
        keypoints and SDFCNN labels from the bundled weights/fpfdcnn and weights/sdfcnn. \
        Crate-relative defaults are looked up in the current directory, then in the crate's \
        source folder."
)]
struct Cli {
    /// Sequence folder in the TUM RGB-D layout [default: datasets/generated/default_sequence,
    /// generated when absent].
    #[arg(long)]
    sequence: Option<PathBuf>,
    /// Camera: fr1, fr2, fr3 or a camera TOML file [default: the sequence's
    /// camera.toml if it has one, else fr1].
    #[arg(long)]
    camera: Option<String>,
    /// Depth source: sensor (RGB-D) or predicted (monocular, SDFCNN depth).
    #[arg(long, value_enum, default_value_t = DepthArg::Sensor)]
    depth: DepthArg,
    /// Keypoints [default: fpfdcnn when --fpfdcnn is given or weights/fpfdcnn exists, else orb].
    #[arg(long, value_enum)]
    features: Option<FeaturesArg>,
    /// FPFDCNN checkpoint (model.bpk, its folder, or a training run folder)
    /// [default: weights/fpfdcnn when it exists].
    #[arg(long)]
    fpfdcnn: Option<PathBuf>,
    /// SDFCNN checkpoint (model.bpk, its folder, or a training run folder)
    /// [default: weights/sdfcnn when it exists].
    #[arg(long)]
    sdfcnn: Option<PathBuf>,
    /// Semantic labels [default: sdfcnn when --sdfcnn is given or weights/sdfcnn exists,
    /// else none].
    #[arg(long, value_enum)]
    labels: Option<LabelsArg>,
    /// SLAM configuration (TOML, see configs/slam/default.toml; configs/slam/orb_baseline.toml is
    /// the frame-to-frame ORB + PnP baseline).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Output folder [default: runs/slam/NAME, NAME the sequence's name].
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
    /// Replace the earlier run an explicit --out holds (without it, such a folder is an error;
    /// the default folder is replaced with a note).
    #[arg(long)]
    overwrite: bool,
    /// Start at this frame (0-based, in association order): a segment of a sequence with
    /// --max-frames, e.g. frames held back from training.
    #[arg(long, default_value_t = 0)]
    first: usize,
    /// Height of the camera above the floor, metres (scale.camera_height). Monocular mode: the
    /// map's floor fixes its scale; every run reports the height its map implies.
    #[arg(long, value_name = "METRES", allow_negative_numbers = true)]
    camera_height: Option<f64>,
}

/// What an output folder holds of an earlier run, in words (`None`: nothing `slam` writes).
fn earlier_run(dir: &Path) -> Option<String> {
    let report = dir.join("report.json");
    if report.is_file() {
        let frames = sdf_slam::io::read_text(&report)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| v["frames_processed"].as_u64());
        return Some(match frames {
            Some(n) => format!("an earlier run's outputs ({n} frames, report.json)"),
            None => "an earlier run's outputs (report.json)".to_string(),
        });
    }
    ["trajectory.txt", "keyframes.txt", "map.ply"]
        .iter()
        .find(|f| dir.join(f).is_file())
        .map(|f| format!("an unfinished earlier run ({f} without report.json)"))
}

/// A checkpoint given on the command line, else the bundled one (if present).
fn checkpoint(given: &Option<PathBuf>, bundled: &str) -> Option<PathBuf> {
    given.clone().or_else(|| bundled_weights(bundled))
}

/// ` (PATH)` of the checkpoint a network was loaded from.
fn weights_note(used: bool, ckpt: &Option<PathBuf>) -> String {
    match ckpt {
        Some(p) if used => format!(" ({})", p.display()),
        _ => String::new(),
    }
}

/// Generates the default sequence into `dest`, with a progress bar.
fn generate_default_sequence(dest: &Path) -> Result<()> {
    let cfg = default_sequence_config();
    let camera = cfg.camera()?;
    eprintln!(
        "the default sequence {} does not exist yet, generating it (later runs reuse it): one \
         synthetic room (seed {}), {} frames of a {} trajectory at {}x{} with the TUM fr1 \
         camera, sensor and exact depth, NYU40 labels and ground-truth poses; about 1 MB per \
         frame and 20-30 s on two cores",
        dest.display(),
        cfg.seed,
        cfg.frames,
        format!("{:?}", cfg.trajectory).to_lowercase(),
        camera.width,
        camera.height
    );
    let bar = ProgressBar::new(cfg.frames as u64);
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} frames generated")
            .map_err(|e| anyhow::anyhow!("{e}"))?
            .progress_chars("=> "),
    );
    let started = Instant::now();
    let summary = generate_sequence(&cfg, dest, &|n| bar.inc(n));
    bar.finish_and_clear();
    let summary = summary.with_context(|| format!("generating {}", dest.display()))?;
    eprintln!(
        "wrote {} frames to {} in {:.1} s",
        summary.frames,
        dest.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// FPFDCNN (given or bundled weights) or ORB keypoints, with the checkpoint used.
fn keypoint_source(
    cli: &Cli,
    config: &SlamConfig,
) -> Result<(FeaturesArg, Option<PathBuf>, Box<dyn KeypointSource>)> {
    let fpfdcnn_ckpt = checkpoint(&cli.fpfdcnn, BUNDLED_FPFDCNN);
    let features = match cli.features {
        Some(f) => f,
        None if fpfdcnn_ckpt.is_some() => FeaturesArg::Fpfdcnn,
        None => {
            eprintln!(
                "note: using ORB keypoints: no --fpfdcnn checkpoint and no bundled FPFDCNN \
                 weights ({BUNDLED_FPFDCNN}/model.bpk + config.toml, looked for in the current \
                 directory and in {})",
                env!("CARGO_MANIFEST_DIR")
            );
            FeaturesArg::Orb
        }
    };
    let keypoints: Box<dyn KeypointSource> = match features {
        FeaturesArg::Orb => Box::new(OrbSource::from_config(&config.features)),
        FeaturesArg::Fpfdcnn => {
            let Some(ckpt) = &fpfdcnn_ckpt else {
                bail!(
                    "--features fpfdcnn needs a checkpoint: --fpfdcnn CKPT (no bundled weights \
                     found at {BUNDLED_FPFDCNN})"
                );
            };
            let detector = FpfdcnnDetector::load(ckpt, cli.backend, config.features.detector())
                .with_context(|| format!("loading FPFDCNN from {}", ckpt.display()))?;
            Box::new(FpfdcnnSource { detector })
        }
    };
    Ok((features, fpfdcnn_ckpt, keypoints))
}

/// The labels asked for (SDFCNN by default when weights exist) and SDFCNN loaded for them.
fn sdfcnn_source(cli: &Cli) -> Result<(LabelsArg, Option<PathBuf>, Option<SdfcnnSource>)> {
    let sdfcnn_ckpt = checkpoint(&cli.sdfcnn, BUNDLED_SDFCNN);
    let labels = match cli.labels {
        Some(l) => l,
        None if sdfcnn_ckpt.is_some() => LabelsArg::Sdfcnn,
        None => {
            eprintln!(
                "note: no semantic labels: no --sdfcnn checkpoint and no bundled SDFCNN weights \
                 ({BUNDLED_SDFCNN}/model.bpk + config.toml, looked for in the current directory \
                 and in {}); --labels gt uses a synthetic sequence's ground-truth labels",
                env!("CARGO_MANIFEST_DIR")
            );
            LabelsArg::None
        }
    };
    let sdfcnn = match labels {
        LabelsArg::Sdfcnn => {
            let Some(ckpt) = &sdfcnn_ckpt else {
                bail!(
                    "--labels sdfcnn needs a checkpoint: --sdfcnn CKPT (no bundled weights found \
                     at {BUNDLED_SDFCNN})"
                );
            };
            Some(
                SdfcnnSource::load(ckpt, cli.backend)
                    .with_context(|| format!("loading SDFCNN from {}", ckpt.display()))?,
            )
        }
        _ => None,
    };
    if cli.depth == DepthArg::Predicted && labels == LabelsArg::None {
        bail!(
            "monocular mode (--depth predicted) takes its depth from SDFCNN: use --labels sdfcnn \
             with --sdfcnn CKPT{} (or --labels gt on a synthetic sequence with depth_gt/)",
            if sdfcnn_ckpt.is_some() {
                ""
            } else {
                " (no bundled weights found at weights/sdfcnn)"
            }
        );
    }
    Ok((labels, sdfcnn_ckpt, sdfcnn))
}

/// The sequence (the default one, generated on first use, unless `--sequence`), from
/// `--first` on.
fn open_sequence(cli: &Cli) -> Result<(PathBuf, TumSequence)> {
    let sequence_path = match &cli.sequence {
        Some(p) if p != Path::new(DEFAULT_SEQUENCE) => {
            if !p.is_dir() {
                bail!("sequence folder {} does not exist", p.display());
            }
            p.clone()
        }
        _ => match default_sequence() {
            Ok(p) => p,
            Err(dest) => {
                generate_default_sequence(&dest)?;
                dest
            }
        },
    };
    if cli.max_frames == Some(0) {
        bail!("--max-frames 0: at least one frame must be processed");
    }
    let mut sequence = TumSequence::open(&sequence_path)?;
    if cli.first > 0 {
        if cli.first >= sequence.len() {
            bail!(
                "--first {}: {} has {} frames",
                cli.first,
                sequence_path.display(),
                sequence.len()
            );
        }
        sequence.frames.drain(..cli.first);
    }
    Ok((sequence_path, sequence))
}

/// The progress bar, and the run's control: its log prints above the bar.
fn progress(n: usize, stop: Arc<AtomicBool>) -> Result<(ProgressBar, Control)> {
    let told = AtomicBool::new(false);
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
    let stop_seen = stop.clone();
    let control = Control {
        stop,
        log,
        on_frame: Some(Box::new(move |_r: &FrameRecord, p: &Progress| {
            if stop_seen.load(Ordering::SeqCst) && !told.swap(true, Ordering::SeqCst) {
                frame_bar.suspend(|| {
                    eprintln!("\nstopping after the current frame (a second signal quits at once)")
                });
            }
            frame_bar.set_position(p.done as u64);
            frame_bar.set_message(format!("keyframes {} lost {}", p.keyframes, p.lost));
        })),
    };
    Ok((bar, control))
}

fn main() -> Result<()> {
    sdf_slam::malloc::tune_for_tensors();
    let cli = Cli::parse();
    let mut config = match &cli.config {
        Some(p) => SlamConfig::load(p)?,
        None => SlamConfig::default(),
    };
    if cli.single_thread {
        config.system.threads = false;
    }
    if let Some(h) = cli.camera_height {
        check_camera_height(h).map_err(|e| anyhow::anyhow!("--camera-height: {e}"))?;
        config.scale.camera_height = h;
    }
    // The backend first, even when no network runs (never another backend than asked);
    // then the networks: weights that do not fit fail before anything else happens.
    cli.backend.check()?;
    let (features, fpfdcnn_ckpt, keypoints) = keypoint_source(&cli, &config)?;
    let (labels, sdfcnn_ckpt, sdfcnn) = sdfcnn_source(&cli)?;
    let (sequence_path, sequence) = open_sequence(&cli)?;
    let camera = Camera::for_sequence(cli.camera.as_deref(), &sequence_path)?;
    // Every frame is checked against the camera where it is read: one of another size is
    // skipped, with its reason in the report.
    let sequence = sequence.with_camera(&camera);
    let semantics: Box<dyn SemanticSource> = match (labels, sdfcnn) {
        (LabelsArg::Sdfcnn, Some(s)) => Box::new(s.with_camera(&camera)),
        (LabelsArg::Gt, _) => Box::new(GroundTruthSource::open(
            &sequence_path,
            sequence.config.depth_scale,
        )?),
        _ => Box::new(NoLabels),
    };
    let depth = match cli.depth {
        DepthArg::Sensor => DepthMode::Sensor,
        DepthArg::Predicted => DepthMode::Predicted,
    };
    let out_dir = cli
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs/slam").join(sequence.name()));
    if out_dir.exists() && !out_dir.is_dir() {
        bail!(
            "--out {} is a file, not a folder: the run's outputs could not be written there",
            out_dir.display()
        );
    }
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
    // One writer per output folder, locked before any frame is read; an earlier run there is
    // replaced only when asked (or in the default folder, with a note).
    let lock = OutputLock::acquire(&out_dir, &command_line())?;
    if let Some(earlier) = earlier_run(&out_dir) {
        if cli.out.is_some() && !cli.overwrite {
            bail!(
                "--out {} holds {earlier}: give another --out, or --overwrite to replace it",
                out_dir.display()
            );
        }
        eprintln!(
            "replacing {earlier} in {}{}",
            out_dir.display(),
            if cli.out.is_none() {
                " (give --out DIR to keep runs apart)"
            } else {
                ""
            }
        );
    }
    // The handler first: the header below tells a caller the run has started.
    let signals = StopSignals::install().context("installing the signal handlers")?;
    let stop = signals.flag();
    eprintln!(
        "sequence {} ({n} frames), camera {}, {} mode, {} keypoints{}, {} labels{}, {}",
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
        weights_note(features == FeaturesArg::Fpfdcnn, &fpfdcnn_ckpt),
        slam.semantics.name(),
        weights_note(labels == LabelsArg::Sdfcnn, &sdfcnn_ckpt),
        if config.system.threads {
            "3 threads"
        } else {
            "single thread"
        }
    );
    let (bar, control) = progress(n, stop)?;
    let output = slam.run(control)?;
    bar.finish_and_clear();
    // The trajectory first: it is what an interrupted run must not lose.
    write_trajectory(&output, &out_dir)?;
    let report = write_outputs(&output, &sequence, &camera, &config, &out_dir)?;
    println!("{}", report.summary());
    if output.interrupted {
        // The outputs cover the frames processed so far; the exit status says they stop early
        // and why (128 + the signal).
        drop(lock);
        std::process::exit(signals.exit_code());
    }
    if output.frames.is_empty() {
        anyhow::bail!(
            "no frame of {} could be processed ({} skipped, reasons in {}): no trajectory",
            sequence.root.display(),
            output.skipped.len(),
            out_dir.join("report.md").display()
        );
    }
    Ok(())
}
