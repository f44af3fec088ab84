//! `eval`: trajectory evaluation that agrees with evo, FPFDCNN matching (Tables 6-7) and
//! SDFCNN accuracy (Tables 8-9).
//!
//! ```text
//! eval ate GT EST [--align se3|sim3|scale|none] [--t-max-diff S] [--interpolate] [--json FILE]
//!          [--plot FILE.png]
//! eval rpe GT EST [--delta N --delta-unit frames|metres] [--keyframes KF] [same options]
//! eval matching --sequence DIR [--gap 5] [--pairs 100] [--blur motion:9] [--fpfdcnn CKPT | --orb-only]
//!          [--window-at-keypoint] [--no-mutual] [--ratio R] [--ratio-exclusion PX] [--roll DEG]
//!          [--derotate DEG] [--json FILE]
//! eval seg --checkpoint DIR_OR_FILE --data DIR [--split FILE] [--backend ndarray|flex]
//!          [--json FILE] [--out DIR] [--limit N]
//! ```

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use sdf_slam::fpfdcnn::{DetectorConfig, FpfdcnnDetector};
use sdf_slam::metrics::{self, Alignment, DeltaUnit, PoseError, Stats};
use sdf_slam::nn::BackendKind;
use sdf_slam::plot;
use sdf_slam::trajectory::Trajectory;
use serde_json::json;
use std::path::PathBuf;

#[path = "eval/seg.rs"]
mod seg;

#[derive(Parser)]
#[command(
    name = "eval",
    version,
    about = "Evaluate trajectories (ATE / RPE as evo computes them), FPFDCNN matching (Tables 6-7) and SDFCNN (Tables 8-9)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Absolute trajectory error (evo_ape, translation part).
    Ate(TrajArgs),
    /// Relative pose error (evo_rpe), translation (m) and rotation (deg), plus
    /// the paper's errT (%) / errR (deg/m) over the same frame delta.
    Rpe {
        #[command(flatten)]
        traj: TrajArgs,
        /// Distance between the two poses of a pair.
        #[arg(long, default_value_t = 1.0)]
        delta: f64,
        /// Unit of --delta.
        #[arg(long, default_value = "frames")]
        delta_unit: DeltaUnit,
        /// The run's keyframes (`slam`'s keyframes.txt): also report the pairs within one
        /// keyframe's span and those across a keyframe switch apart.
        #[arg(long)]
        keyframes: Option<PathBuf>,
    },
    /// The paper's Tables 6 and 7: matching accuracy and relative-pose error of
    /// ORB + BF and FPFDCNN + range matcher on clear and blurred frame pairs.
    Matching(MatchingArgs),
    /// SDFCNN segmentation and depth accuracy on a NYUv2-layout folder or the official .mat
    /// file: the paper's Table 8
    /// (MPA, mIoU, time, parameters) and Table 9 (RMS, REL, δ, time, parameters), per class.
    Seg(seg::SegArgs),
}

#[derive(Args)]
struct MatchingArgs {
    /// TUM-layout sequence with depth and ground truth.
    #[arg(long)]
    sequence: PathBuf,
    /// Camera: fr1, fr2, fr3 or a camera TOML file [default: the sequence's camera.toml if
    /// it has one, else fr1].
    #[arg(long)]
    camera: Option<String>,
    /// Frame gap of the pairs (i, i + gap).
    #[arg(long, default_value_t = 5)]
    gap: usize,
    /// Number of pairs, spread evenly over the sequence.
    #[arg(long, default_value_t = 100)]
    pairs: usize,
    /// Use frames from this index on.
    #[arg(long, default_value_t = 0)]
    first: usize,
    /// Use frames before this index only.
    #[arg(long)]
    last: Option<usize>,
    /// Degradation of both images for the blurred half, e.g. motion:9 (a 9-pixel horizontal motion blur).
    #[arg(long)]
    blur: Option<String>,
    /// Rotate the second image of each pair by this many degrees about its centre (-180 to
    /// 180): a roll about the optical axis on top of the pair's motion; matches are scored
    /// in the recorded image's pixels.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
    roll: f64,
    /// Roll-compensated FPFDCNN matching: when the global motion estimate rotates by at
    /// least this many degrees, the second image is turned back by it and described again
    /// (one more network pass), and those matches are kept if there are as many (0: off,
    /// FPFDCNN + range matcher as the paper has it) [default: 5; off with
    /// --window-at-keypoint, which has no motion estimate].
    #[arg(long)]
    derotate: Option<f64>,
    /// FPFDCNN checkpoint (model.bpk, its folder, or a training run folder); default: the
    /// bundled weights/fpfdcnn.
    #[arg(long)]
    fpfdcnn: Option<PathBuf>,
    /// Evaluate ORB + BF only.
    #[arg(long, conflicts_with = "fpfdcnn")]
    orb_only: bool,
    /// Backend for FPFDCNN.
    #[arg(long, value_enum, default_value_t = BackendKind::Ndarray)]
    backend: BackendKind,
    /// Resize images by this factor before FPFDCNN (0.5 for a network trained at 240x320).
    #[arg(long, default_value_t = 1.0)]
    fpfdcnn_scale: f32,
    /// Range matcher window side, pixels (the paper: 140).
    #[arg(long, default_value_t = 140.0)]
    window: f32,
    /// Centre each window at the keypoint's own position, as the paper's Fig. 4 draws it,
    /// instead of where a global affine motion estimate (from confident descriptor
    /// matches, RANSAC) moves the keypoint.
    #[arg(long)]
    window_at_keypoint: bool,
    /// Keep one-way nearest neighbours too (default: mutual nearest neighbours only).
    #[arg(long)]
    no_mutual: bool,
    /// Lowe's ratio test in the range matcher (1: off).
    #[arg(long, default_value_t = 0.7)]
    ratio: f32,
    /// The ratio test's second-nearest descriptor is looked for only among keypoints
    /// farther than this many pixels from the nearest one (0: Lowe's test as it is; 8: the
    /// training loss's exclusion radius, within which FPFDCNN's descriptors are not pushed
    /// apart).
    #[arg(long, default_value_t = 8.0)]
    ratio_exclusion: f32,
    /// Refine FPFDCNN keypoints to the image corner within this radius (0: off).
    #[arg(long, default_value_t = 0)]
    subpixel: usize,
    /// Gaussian smoothing of FPFDCNN's probability map before suppression, pixels (0: off).
    #[arg(long, default_value_t = sdf_slam::fpfdcnn::inference::DEFAULT_SMOOTHING)]
    smoothing: f32,
    /// FPFDCNN non-maximum suppression radius, pixels.
    #[arg(long, default_value_t = 4)]
    nms: usize,
    /// Average FPFDCNN's probability map over 1, 2 or 4 placements of its 16x16 cell grid
    /// (half-cell shifts; each placement is one more network pass).
    #[arg(long, default_value_t = sdf_slam::fpfdcnn::inference::DEFAULT_GRID_SHIFTS)]
    grid_shifts: usize,
    /// Take FPFDCNN's descriptors from the first grid placement only, as before 2026-12-01
    /// (by default they are averaged over the `--grid-shifts` placements). One pass is
    /// unaffected: `--descriptor-spread 0` gives its earlier descriptors.
    #[arg(long)]
    no_descriptor_averaging: bool,
    /// FPFDCNN's matches as matched: no refinement of the second image's point by patch
    /// correlation (on by default since 2026-12-01).
    #[arg(long)]
    no_match_refinement: bool,
    /// Refine ORB's matches by patch correlation too (to see what it gives the baseline).
    #[arg(long)]
    refine_orb: bool,
    /// Match refinement: patch radius, pixels.
    #[arg(long, default_value_t = sdf_slam::features::match_refine::MatchRefineConfig::default().patch_radius)]
    refine_patch_radius: usize,
    /// Match refinement: largest move along each axis, pixels.
    #[arg(long, default_value_t = sdf_slam::features::match_refine::MatchRefineConfig::default().search_px)]
    refine_search: usize,
    /// Match refinement: least correlation (NCC) for a match to move.
    #[arg(long, default_value_t = sdf_slam::features::match_refine::MatchRefineConfig::default().min_ncc)]
    refine_min_ncc: f32,
    /// With one placement (`--grid-shifts 1`), average each FPFDCNN descriptor over five
    /// samples of the coarse map: at the keypoint and this many pixels away along both
    /// diagonals (0: the keypoint's sample alone, as before 2026-12-01).
    #[arg(long, default_value_t = sdf_slam::fpfdcnn::inference::DEFAULT_DESCRIPTOR_SPREAD)]
    descriptor_spread: usize,
    /// No FPFDCNN keypoint closer than this to the image border, pixels (ORB's edge
    /// threshold keeps its keypoints 31 px in).
    #[arg(long, default_value_t = sdf_slam::fpfdcnn::DetectorConfig::default().border)]
    border: usize,
    /// FPFDCNN pyramid levels (1: the image as it is; ORB's 8 share `--keypoints` out over
    /// levels by their side).
    #[arg(long, default_value_t = 1)]
    levels: usize,
    /// Ratio of the sides of consecutive FPFDCNN pyramid levels.
    #[arg(long, default_value_t = 1.2)]
    level_factor: f32,
    /// Keypoints per image, for both methods (the paper: 500; FPFDCNN keeps the most
    /// probable, ORB the strongest FAST corners over its pyramid).
    #[arg(long, default_value_t = 500)]
    keypoints: usize,
    /// Also measure the repeatability of Harris corners after homographic adaptation over
    /// this many random warps of each image (SuperPoint's recipe; candidate FPFDCNN detector
    /// targets; 0: not measured).
    #[arg(long, default_value_t = 0)]
    adapted_harris: usize,
    /// Gaussian window of the Harris corners whose repeatability is measured, pixels (the
    /// FP pairs' 1.5).
    #[arg(long, default_value_t = 1.5)]
    harris_sigma: f32,
    /// ORB pyramid levels (OpenCV's 8; 1: FAST corners at full resolution only).
    #[arg(long, default_value_t = 8)]
    orb_levels: usize,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write the tables as markdown.
    #[arg(long)]
    markdown: Option<PathBuf>,
    /// Also print each pair's figures: accuracy, the pair's common offset (the median of
    /// its match errors: where the ground truth itself is off) and the share within 5 px of
    /// it, per method (the JSON always has them).
    #[arg(long)]
    per_pair: bool,
    /// Write a picture of the matches on the middle pair (green correct, red wrong); JPEG
    /// when the name ends in .jpg, else PNG.
    #[arg(long)]
    picture: Option<PathBuf>,
}

#[derive(Args)]
struct TrajArgs {
    /// Reference (ground-truth) trajectory, TUM format.
    reference: PathBuf,
    /// Estimated trajectory, TUM format.
    estimate: PathBuf,
    /// Alignment of the estimate: se3 (evo -a), sim3 (evo -as), scale (evo -s), none.
    #[arg(long, default_value = "none")]
    align: Alignment,
    /// Maximum timestamp difference for associating poses, seconds (evo --t_max_diff).
    #[arg(long, default_value_t = 0.01)]
    t_max_diff: f64,
    /// Read the reference at each of the estimate's stamps, interpolated between its two
    /// samples around it (translation linearly, rotation by SLERP; none farther than
    /// --t-max-diff from a sample), instead of evo's nearest sample: a 100 Hz ground truth's
    /// nearest sample is up to 5 ms off, on a fast turn a floor under the per-frame RPE (0.23
    /// degrees on fr1_rpy 0-79; lab/notes/slam-results.md, "Poses at the colour instant"). Not evo's figures.
    #[arg(long)]
    interpolate: bool,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write a plot: both trajectories seen from above after alignment, and the error over time.
    #[arg(long)]
    plot: Option<PathBuf>,
}

fn align_name(a: Alignment) -> &'static str {
    match a {
        Alignment::None => "not aligned",
        Alignment::Se3 => "SE(3) Umeyama alignment",
        Alignment::Sim3 => "Sim(3) Umeyama alignment",
        Alignment::Scale => "scale corrected",
    }
}

fn stats_json(s: &Stats) -> serde_json::Value {
    json!({"rmse": s.rmse, "mean": s.mean, "median": s.median, "std": s.std,
           "min": s.min, "max": s.max, "pairs": s.pairs})
}

fn print_stats(title: &str, unit: &str, s: &Stats) {
    println!("{title}");
    for (k, v) in [
        ("rmse", s.rmse),
        ("mean", s.mean),
        ("median", s.median),
        ("std", s.std),
        ("min", s.min),
        ("max", s.max),
    ] {
        println!("  {k:>8}  {v:.6} {unit}");
    }
    println!();
}

fn read(path: &PathBuf) -> Result<Trajectory> {
    Ok(Trajectory::read_tum(path)?)
}

/// The reference and the estimate of `a`; with `--interpolate` the reference read at the
/// estimate's stamps.
fn read_pair(a: &TrajArgs) -> Result<(Trajectory, Trajectory)> {
    if !(a.t_max_diff.is_finite() && a.t_max_diff >= 0.0 && a.t_max_diff <= 3600.0) {
        anyhow::bail!(
            "--t-max-diff must be in [0, 3600] seconds, got {}",
            a.t_max_diff
        );
    }
    let (gt, est) = (read(&a.reference)?, read(&a.estimate)?);
    let gt = if a.interpolate {
        gt.resampled_at(&est.stamps, a.t_max_diff)
    } else {
        gt
    };
    Ok((gt, est))
}

fn write_json(path: &PathBuf, value: &serde_json::Value) -> Result<()> {
    let text = serde_json::to_string_pretty(value)?;
    sdf_slam::io::write_atomic(path, text.as_bytes())?;
    println!("wrote {}", path.display());
    Ok(())
}

fn relative_stamps(t: &Trajectory) -> Vec<f64> {
    let t0 = t.stamps.first().copied().unwrap_or(0.0);
    t.stamps.iter().map(|s| s - t0).collect()
}

/// The `--derotate` threshold, degrees: the flag's value, else off with
/// `--window-at-keypoint` (no motion estimate) and the library's default otherwise.
fn derotation_deg(a: &MatchingArgs) -> Result<f64> {
    let derotate = match (a.derotate, a.window_at_keypoint) {
        (Some(d), true) if d != 0.0 => anyhow::bail!(
            "--derotate needs the global motion estimate: leave out --window-at-keypoint"
        ),
        (Some(d), _) => d,
        (None, true) => 0.0,
        (None, false) => sdf_slam::fpfdcnn::derotation::DEFAULT_DEROTATE_DEG,
    };
    anyhow::ensure!(
        (0.0..=180.0).contains(&derotate),
        "--derotate must be in [0, 180] degrees (0: off), got {derotate}"
    );
    Ok(derotate)
}

/// Match refinement as the `--refine-*` flags set it; `None` with `--no-match-refinement`.
fn match_refinement(
    a: &MatchingArgs,
) -> Result<Option<sdf_slam::features::match_refine::MatchRefineConfig>> {
    let refine = sdf_slam::features::match_refine::MatchRefineConfig {
        patch_radius: a.refine_patch_radius,
        search_px: a.refine_search,
        min_ncc: a.refine_min_ncc,
    };
    let refine = if a.no_match_refinement {
        anyhow::ensure!(!a.refine_orb, "--refine-orb needs match refinement on");
        None
    } else {
        refine.validate().map_err(|m| {
            // The message names the field; say which flag set it.
            let flag = [
                ("patch_radius", "--refine-patch-radius"),
                ("search_px", "--refine-search"),
                ("min_ncc", "--refine-min-ncc"),
            ]
            .into_iter()
            .find(|(field, _)| m.starts_with(field))
            .map_or("--refine-*", |(_, flag)| flag);
            anyhow::anyhow!("{flag}: {m}")
        })?;
        Some(refine)
    };
    Ok(refine)
}

/// The FPFDCNN weights to evaluate (`None` with `--orb-only`, or when none are given and
/// none are bundled) and the detector loaded from them.
fn fpfdcnn_detector(a: &MatchingArgs) -> Result<(Option<PathBuf>, Option<FpfdcnnDetector>)> {
    let weights = match (&a.fpfdcnn, a.orb_only) {
        (_, true) => None,
        (Some(p), _) => Some(p.clone()),
        (None, false) => {
            let found = sdf_slam::bundled::bundled_weights(sdf_slam::bundled::BUNDLED_FPFDCNN);
            if found.is_none() {
                eprintln!("note: no bundled weights/fpfdcnn found: ORB + BF only (--fpfdcnn CKPT)");
            }
            found
        }
    };
    let detector = weights
        .as_ref()
        .map(|p| {
            let cfg = DetectorConfig {
                input_scale: a.fpfdcnn_scale,
                subpixel_radius: a.subpixel,
                grid_shifts: a.grid_shifts,
                average_descriptors: !a.no_descriptor_averaging,
                descriptor_spread: a.descriptor_spread,
                levels: a.levels,
                border: a.border,
                level_factor: a.level_factor,
                nms_radius: a.nms,
                smoothing: a.smoothing,
                top_k: a.keypoints,
                ..Default::default()
            };
            FpfdcnnDetector::load(p, a.backend, cfg)
        })
        .transpose()?;
    Ok((weights, detector))
}

fn matching(a: MatchingArgs) -> Result<()> {
    use sdf_slam::fpfdcnn::evaluate::{MatchingEvalConfig, evaluate, markdown, per_pair_markdown};
    // A backend not compiled in, or without a device, fails before any data is read.
    a.backend.check()?;
    anyhow::ensure!(
        a.ratio > 0.0 && a.ratio.is_finite(),
        "--ratio must be a positive number (1 turns the test off), got {}",
        a.ratio
    );
    anyhow::ensure!(
        (1..=sdf_slam::fpfdcnn::inference::MAX_KEYPOINTS).contains(&a.keypoints),
        "--keypoints must be in [1, {}], got {}",
        sdf_slam::fpfdcnn::inference::MAX_KEYPOINTS,
        a.keypoints
    );
    anyhow::ensure!(
        (0.0..=256.0).contains(&a.ratio_exclusion),
        "--ratio-exclusion must be in [0, 256] pixels (0: Lowe's test as it is), got {}",
        a.ratio_exclusion
    );
    anyhow::ensure!(
        (-180.0..=180.0).contains(&a.roll),
        "--roll must be in [-180, 180] degrees, got {}",
        a.roll
    );
    let derotate = derotation_deg(&a)?;
    let adaptation =
        (a.adapted_harris > 0).then(|| sdf_slam::fpfdcnn::adaptation::AdaptationConfig {
            warps: a.adapted_harris,
            ..Default::default()
        });
    if let Some(ad) = &adaptation {
        ad.validate()
            .map_err(|m| anyhow::anyhow!("--adapted-harris: {m}"))?;
    }
    let refine = match_refinement(&a)?;
    let cam = sdf_slam::camera::Camera::for_sequence(a.camera.as_deref(), &a.sequence)?;
    // Every frame checked against the camera where it is read (size, channels, bit depth).
    let seq = sdf_slam::dataset::TumSequence::open(&a.sequence)?.with_camera(&cam);
    let (weights, detector) = fpfdcnn_detector(&a)?;
    let mut cfg = MatchingEvalConfig {
        gap: a.gap,
        pairs: a.pairs,
        first: a.first,
        last: a.last,
        blur: a
            .blur
            .as_deref()
            .map(sdf_slam::dataset::photometric::Degradation::parse)
            .transpose()?,
        roll_deg: a.roll,
        derotation: sdf_slam::fpfdcnn::derotation::DerotationConfig { min_deg: derotate },
        adaptation,
        refine_orb: a.refine_orb,
        refine,
        ..Default::default()
    };
    cfg.orb.n_features = a.keypoints;
    cfg.orb.n_levels = a.orb_levels;
    cfg.orb.validate()?;
    cfg.harris.sigma = a.harris_sigma;
    cfg.harris
        .validate()
        .map_err(|m| anyhow::anyhow!("--harris-sigma: {m}"))?;
    cfg.range.window = a.window;
    cfg.range.mutual = !a.no_mutual;
    cfg.range.ratio = (a.ratio < 1.0).then_some(a.ratio);
    cfg.range.ratio_exclusion_px = a.ratio_exclusion;
    cfg.guide = (!a.window_at_keypoint).then(sdf_slam::range_matcher::GuideConfig::default);
    if let Some(w) = &weights {
        eprintln!("FPFDCNN weights: {}", w.display());
    }
    let bar = indicatif::ProgressBar::new(0);
    let (report, picture) = evaluate(&seq, &cam, detector.as_ref(), &cfg, |k, n| {
        bar.set_length(n as u64);
        bar.set_position(k as u64);
    })?;
    bar.finish_and_clear();
    let mut md = markdown(&report);
    if a.per_pair {
        md.push_str(&per_pair_markdown(&report));
    }
    println!("{md}");
    if let Some(p) = &a.markdown {
        sdf_slam::io::write_atomic(p, md.as_bytes())?;
        println!("wrote {}", p.display());
    }
    if let Some(p) = &a.json {
        write_json(p, &serde_json::to_value(&report)?)?;
    }
    if let (Some(p), Some(img)) = (&a.picture, picture) {
        sdf_slam::imageio::write_picture_atomic(p, &image::DynamicImage::ImageRgb8(img))?;
        println!("wrote {}", p.display());
    }
    Ok(())
}

fn main() -> Result<()> {
    sdf_slam::malloc::tune_for_tensors();
    let cli = Cli::parse();
    match cli.command {
        Command::Matching(a) => matching(a)?,
        Command::Seg(a) => seg::run(&a)?,
        Command::Ate(a) => {
            let (gt, est) = read_pair(&a)?;
            let r = metrics::ape(&gt, &est, a.align, a.t_max_diff).context("ATE failed")?;
            println!(
                "ATE w.r.t. translation part (m), {} — {} pose pairs of max. {} (t_max_diff {} s)",
                align_name(a.align),
                r.stats.pairs,
                gt.len().min(est.len()),
                a.t_max_diff
            );
            if a.align == Alignment::Sim3 || a.align == Alignment::Scale {
                println!("  scale correction: {:.6}", r.alignment.scale);
            }
            print_stats("", "m", &r.stats);
            if let Some(p) = &a.json {
                let mut v = json!({"ate": stats_json(&r.stats)});
                v["alignment"] = json!({"method": a.align, "scale": r.alignment.scale});
                write_json(p, &v)?;
            }
            if let Some(p) = &a.plot {
                let (rp, ep) = (r.reference.positions(), r.estimate.positions());
                let t = relative_stamps(&r.reference);
                let title = format!("ATE rmse {:.4} m ({})", r.stats.rmse, align_name(a.align));
                plot::trajectory_figure(
                    p,
                    &title,
                    &[("reference", &rp), ("estimate", &ep)],
                    Some(("ATE (m)", &t, &r.errors)),
                )?;
                println!("wrote {}", p.display());
            }
        }
        Command::Rpe {
            traj: a,
            delta,
            delta_unit,
            keyframes,
        } => {
            let (gt, est) = read_pair(&a)?;
            // Read before any result is printed: a bad file fails the command up front.
            let keyframe_stamps = keyframes.as_ref().map(read).transpose()?;
            let r = metrics::rpe(&gt, &est, a.align, a.t_max_diff, delta, delta_unit)
                .context("RPE failed")?;
            let unit = match delta_unit {
                DeltaUnit::Frames => "frames",
                DeltaUnit::Metres => "m",
            };
            println!(
                "RPE for delta = {delta} ({unit}) using consecutive pairs, {} — {} pairs",
                align_name(a.align),
                r.trans.pairs
            );
            print_stats("translation part (m)", "m", &r.trans);
            print_stats("rotation angle (deg)", "deg", &r.rot_deg);
            let split = keyframe_stamps.map(|k| r.at_keyframes(&k.stamps));
            if let Some(split) = &split {
                for (name, part) in [
                    ("within one keyframe's span", &split.within),
                    ("across a keyframe switch", &split.across),
                ] {
                    match part {
                        Some(x) => println!(
                            "pairs {name}: {} pairs, translation rmse {:.6} m, rotation rmse {:.4} deg",
                            x.trans.pairs, x.trans.rmse, x.rot_deg.rmse
                        ),
                        None => println!("pairs {name}: none"),
                    }
                }
            }
            let paper = match delta_unit {
                DeltaUnit::Frames => {
                    PoseError::over_frames(&r.reference, &r.estimate, delta as usize).ok()
                }
                DeltaUnit::Metres => None,
            };
            if let Some(e) = &paper {
                println!(
                    "paper eqs 11-14 over {}-frame segments: errT {:.3} %  errR {:.4} deg/m  ({} segments, {:.3} m)",
                    delta, e.err_t_percent, e.err_r_deg_per_m, e.segments, e.total_length
                );
            }
            if let Some(p) = &a.json {
                let mut v = json!({"rpe_trans": stats_json(&r.trans), "rpe_rot_deg": stats_json(&r.rot_deg)});
                v["delta"] = json!({"value": delta, "unit": delta_unit});
                v["alignment"] = json!({"method": a.align, "scale": r.alignment.scale});
                if let Some(e) = &paper {
                    v["paper"] = serde_json::to_value(e)?;
                }
                if let Some(split) = &split {
                    v["keyframes"] = json!({"within": split.within, "across": split.across});
                }
                write_json(p, &v)?;
            }
            if let Some(p) = &a.plot {
                let (rp, ep) = (r.reference.positions(), r.estimate.positions());
                let t0 = r.reference.stamps[0];
                let t: Vec<f64> = r
                    .pairs
                    .iter()
                    .map(|&(_, j)| r.reference.stamps[j] - t0)
                    .collect();
                let title = format!("RPE rmse {:.4} m / {:.3} deg", r.trans.rmse, r.rot_deg.rmse);
                plot::trajectory_figure(
                    p,
                    &title,
                    &[("reference", &rp), ("estimate", &ep)],
                    Some(("RPE translation (m)", &t, &r.trans_errors)),
                )?;
                println!("wrote {}", p.display());
            }
        }
    }
    Ok(())
}
