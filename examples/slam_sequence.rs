//! Run the SLAM from code on a TUM RGB-D layout sequence (RGB-D mode, no semantic labels) and
//! measure its trajectory against the sequence's ground truth: what `slam` does, through the
//! library, without its files and progress bar.
//!
//! ```text
//! cargo run --release --example slam_sequence -- [SEQUENCE] [--features fpfdcnn|orb] [--max-frames N]
//! ```
//!
//! Default: the bundled 10-frame fixture `datasets/fixtures/tum_fr1_rpy_head10` (TUM fr1_rpy),
//! FPFDCNN keypoints from the bundled `weights/fpfdcnn`; the camera is the sequence's
//! `camera.toml`, else TUM fr1.

use anyhow::{Context, Result, bail};
use sdf_slam::bundled::{BUNDLED_FPFDCNN, bundled_weights, locate};
use sdf_slam::camera::Camera;
use sdf_slam::dataset::TumSequence;
use sdf_slam::fpfdcnn::FpfdcnnDetector;
use sdf_slam::nn::BackendKind;
use sdf_slam::slam::output::evaluation::evaluate_trajectory;
use sdf_slam::slam::{
    Control, DepthMode, FpfdcnnSource, KeypointSource, NoLabels, OrbSource, Slam, SlamConfig,
};
use std::path::PathBuf;

const FIXTURE: &str = "datasets/fixtures/tum_fr1_rpy_head10";
const USAGE: &str = "usage: slam_sequence [SEQUENCE] [--features fpfdcnn|orb] [--max-frames N]";

fn main() -> Result<()> {
    let (mut sequence, mut orb, mut max_frames) = (None, false, None);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--features" => match args.next().as_deref() {
                Some("fpfdcnn") => orb = false,
                Some("orb") => orb = true,
                other => bail!("--features {}: fpfdcnn or orb", other.unwrap_or("")),
            },
            "--max-frames" => {
                let v = args.next().context("--max-frames needs a number")?;
                let n: usize =
                    v.parse().ok().filter(|n| *n > 0).with_context(|| {
                        format!("--max-frames {v}: a positive number of frames")
                    })?;
                max_frames = Some(n);
            }
            s if s.starts_with('-') => bail!("unknown option {s}: {USAGE}"),
            _ if sequence.is_none() => sequence = Some(PathBuf::from(a)),
            _ => bail!("one sequence at a time (got {a} as well): {USAGE}"),
        }
    }
    let path = match sequence {
        Some(p) => p,
        None => locate(FIXTURE)
            .with_context(|| format!("the default sequence {FIXTURE} is not here"))?,
    };
    let sequence = TumSequence::open(&path)
        .with_context(|| format!("opening the sequence {}", path.display()))?;
    let camera = Camera::for_sequence(None, &path)?;

    // The system's configuration (configs/slam/default.toml holds the same defaults).
    let config = SlamConfig::default();
    let keypoints: Box<dyn KeypointSource> = if orb {
        Box::new(OrbSource::from_config(&config.features))
    } else {
        let weights = bundled_weights(BUNDLED_FPFDCNN).with_context(|| {
            format!("no bundled FPFDCNN weights ({BUNDLED_FPFDCNN}); --features orb needs none")
        })?;
        let detector =
            FpfdcnnDetector::load(&weights, BackendKind::Ndarray, config.features.detector())
                .with_context(|| format!("loading FPFDCNN from {}", weights.display()))?;
        Box::new(FpfdcnnSource { detector })
    };
    let slam = Slam {
        sequence: sequence.clone(),
        camera,
        config,
        depth: DepthMode::Sensor,
        keypoints,
        semantics: Box::new(NoLabels),
        max_frames,
    };
    // Checks the sequence against the mode (RGB-D needs depth images) before any work.
    slam.validate()?;
    println!(
        "{} ({} frames), {} keypoints, RGB-D, no labels",
        sequence.root.display(),
        max_frames.map_or(sequence.len(), |m| m.min(sequence.len())),
        slam.keypoints.name()
    );
    // Control::default(): the run's log goes to stderr, nothing stops it early.
    let output = slam.run(Control::default())?;
    let trajectory = output.trajectory();
    if trajectory.is_empty() {
        bail!("no frame of {} could be tracked", path.display());
    }
    println!(
        "tracked {} frames ({} lost) in {:.1} s ({:.1} fps), {} keyframes, {} map points",
        trajectory.len(),
        output.tracking.lost.len(),
        output.wall_seconds,
        output.fps(),
        output.map.keyframes.len(),
        output.semantic_map.len()
    );
    println!("trajectory length: {:.3} m", trajectory.path_length());
    let eval = evaluate_trajectory(
        sequence.groundtruth.as_ref(),
        &trajectory,
        DepthMode::Sensor,
    );
    match (&eval.ate, &eval.ate_note) {
        (Some(ate), _) => println!(
            "ATE ({:?} alignment): RMSE {:.4} m over {} poses (max {:.4} m)",
            ate.alignment, ate.stats.rmse, ate.stats.pairs, ate.stats.max
        ),
        (None, Some(note)) => println!("no ATE: {note}"),
        (None, None) => println!("no ATE: the sequence has no ground truth, or fewer than 3 poses"),
    }
    Ok(())
}
