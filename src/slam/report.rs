//! Outputs of a run (all written atomically): `trajectory.txt` (every frame,
//! TUM), `keyframes.txt`, `map.ply`, `map_topdown.png`, `trajectory.png`, and
//! `report.md` / `report.json` with ATE / RPE against ground truth (Table 10),
//! timing per stage, tracking failures, and the map accuracy of Table 11 when
//! ground truth allows: per-class accuracy of the map labels and the share of
//! map points within a tolerance of the true surface.

use super::config::SlamConfig;
use super::map::ViewBounds;
use super::semantic_map::{MapPoint, label_histogram, render_topdown, write_ply};
use super::semantic_source::GroundTruthSource;
use super::system::{DepthMode, SlamOutput};
use crate::camera::Camera;
use crate::classes;
use crate::dataset::{DepthImage, LabelImage, TumSequence};
use crate::error::{Error, Result};
use crate::geometry::Sim3;
use crate::metrics::Stats;
use crate::metrics::trajectory::{Alignment, DeltaUnit, ape, rpe};
use nalgebra::Point3;
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Trajectory error against ground truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AteReport {
    pub alignment: Alignment,
    pub stats: Stats,
    /// Scale of the Sim(3) alignment (1 for SE(3) and none).
    pub scale: f64,
}

/// Relative pose error between consecutive frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RpeReport {
    pub delta_frames: usize,
    pub translation: Stats,
    pub rotation_deg: Stats,
}

/// Accuracy of one class of the map labels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassAccuracy {
    pub label: u8,
    pub name: String,
    /// Map points whose ground-truth label is this class.
    pub points: usize,
    /// Share of them labelled correctly (the paper's CA).
    pub accuracy: f64,
}

/// Table 11: label and position accuracy of the map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MapAccuracy {
    /// Distance to the true surface counted as correct, metres.
    pub tolerance: f64,
    /// "exact depth (depth_gt/)" or "sensor depth".
    pub surface_source: String,
    /// Map points evaluated (projected into a keyframe with a depth reading).
    pub evaluated_points: usize,
    /// Share within `tolerance` of the true surface.
    pub position_accuracy: f64,
    pub median_error: f64,
    pub mean_error: f64,
    /// Per-class accuracy (ground-truth labels only).
    pub classes: Vec<ClassAccuracy>,
    /// Mean of the per-class accuracies (MPA), over classes with points.
    pub mpa: Option<f64>,
    /// Share of all labelled evaluated points with the right label.
    pub overall_label_accuracy: Option<f64>,
}

/// A row of the label histogram.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LabelCount {
    pub label: u8,
    pub name: String,
    pub points: usize,
}

/// A stage's timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageReport {
    pub stage: String,
    pub seconds: f64,
    pub calls: usize,
    pub per_second: f64,
}

/// Tracking trouble.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrackingReport {
    pub failures: usize,
    pub relocalised: usize,
    pub lost: usize,
    pub reinitialised: usize,
    pub failure_frames: Vec<usize>,
    pub relocalised_frames: Vec<usize>,
    pub lost_frames: Vec<usize>,
    pub reinitialised_frames: Vec<usize>,
}

/// Everything `report.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub sequence: String,
    pub mode: String,
    pub features: String,
    pub labels: String,
    pub threads: bool,
    pub frames_requested: usize,
    pub frames_processed: usize,
    pub frames_skipped: Vec<(usize, String)>,
    pub interrupted: bool,
    pub keyframes: usize,
    pub odometry_constraints: usize,
    pub loop_constraints: usize,
    pub landmarks: usize,
    pub map_points: usize,
    pub tracking: TrackingReport,
    pub wall_seconds: f64,
    pub fps: f64,
    pub timing: Vec<StageReport>,
    pub ate: Option<AteReport>,
    pub ate_unaligned: Option<AteReport>,
    /// Why `ate` is missing although there is ground truth.
    pub ate_note: Option<String>,
    pub rpe: Option<RpeReport>,
    pub label_histogram: Vec<LabelCount>,
    pub map_accuracy: Option<MapAccuracy>,
    pub semantic_failures: Vec<(usize, String)>,
    pub correction: super::correction::CorrectionStats,
    pub local_correction: super::correction::LocalSummary,
    /// Multi-view depth of monocular keyframes (zero in RGB-D mode).
    #[serde(default)]
    pub multiview: super::multiview_depth::SweepSummary,
    pub outputs: Vec<PathBuf>,
}

const T_MAX_DIFF: f64 = 0.02;

/// Writes only `trajectory.txt` (e.g. as soon as a run is interrupted).
pub fn write_trajectory(out: &SlamOutput, dir: &Path) -> Result<PathBuf> {
    retire_manifest(dir)?;
    let p = dir.join("trajectory.txt");
    out.trajectory().write_tum(&p)?;
    Ok(p)
}

/// `report.json` is written last and lists the run's files: a folder holds a finished run
/// exactly when it has one. Before a run writes over an earlier one, the earlier report
/// goes first, so that a run killed half-way never leaves old and new files looking like
/// one run.
fn retire_manifest(dir: &Path) -> Result<()> {
    for name in ["report.json", "report.md"] {
        let p = dir.join(name);
        match std::fs::remove_file(&p) {
            Ok(()) => crate::io::sync_parent(&p).map_err(|e| Error::io(&p, e))?,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(Error::io(&p, e)),
        }
    }
    Ok(())
}

/// Writes every output into `dir` (the report last, see [`retire_manifest`]) and returns
/// the report.
pub fn write_outputs(
    out: &SlamOutput,
    seq: &TumSequence,
    camera: &Camera,
    cfg: &SlamConfig,
    dir: &Path,
) -> Result<Report> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let mut outputs = vec![write_trajectory(out, dir)?];
    let kf_path = dir.join("keyframes.txt");
    out.keyframe_trajectory().write_tum(&kf_path)?;
    outputs.push(kf_path);
    let points = out.semantic_map.points(&cfg.labels, cfg.map.min_views);
    let ply = dir.join("map.ply");
    write_ply(&ply, &points, cfg.map.ply_ascii)?;
    outputs.push(ply);
    let top = dir.join("map_topdown.png");
    let kf_poses: Vec<_> = out.map.keyframes.iter().map(|k| k.pose).collect();
    render_topdown(
        &top,
        &format!(
            "{}: semantic map from above ({} points)",
            seq.name(),
            points.len()
        ),
        &points,
        &kf_poses,
        cfg.map.voxel_size,
        cfg.map.topdown_size,
    )?;
    outputs.push(top);
    let estimate = out.trajectory();
    let alignment = match out.depth {
        DepthMode::Sensor => Alignment::Se3,
        DepthMode::Predicted => Alignment::Sim3,
    };
    let (mut ate, mut ate_unaligned, mut rpe_report) = (None, None, None);
    let mut ate_note: Option<String> = None;
    let traj_png = dir.join("trajectory.png");
    match (&seq.groundtruth, estimate.len() >= 3) {
        (Some(gt), true) => {
            // A degenerate alignment (a camera that only rotates in place) falls
            // back to unaligned errors, with a note.
            let aligned = match ape(gt, &estimate, alignment, T_MAX_DIFF) {
                Ok(a) => Some((a, alignment)),
                Err(e) => {
                    ate_note = Some(format!(
                        "{alignment:?} alignment failed ({e}): errors are unaligned"
                    ));
                    ape(gt, &estimate, Alignment::None, T_MAX_DIFF)
                        .ok()
                        .map(|a| (a, Alignment::None))
                }
            };
            if let Some((a, how)) = aligned {
                let times: Vec<f64> = a
                    .estimate
                    .stamps
                    .iter()
                    .map(|t| t - a.estimate.stamps[0])
                    .collect();
                crate::plot::trajectory_figure(
                    &traj_png,
                    &format!(
                        "{}: SLAM ({how:?}-aligned) vs ground truth, ATE RMSE {:.4} m",
                        seq.name(),
                        a.stats.rmse
                    ),
                    &[
                        ("ground truth", &a.reference.positions()),
                        ("SLAM", &a.estimate.positions()),
                    ],
                    Some(("ATE (m)", &times, &a.errors)),
                )?;
                outputs.push(traj_png.clone());
                if how == alignment {
                    ate = Some(AteReport {
                        alignment,
                        stats: a.stats,
                        scale: a.alignment.scale,
                    });
                }
            }
            if let Ok(a) = ape(gt, &estimate, Alignment::None, T_MAX_DIFF) {
                ate_unaligned = Some(AteReport {
                    alignment: Alignment::None,
                    stats: a.stats,
                    scale: 1.0,
                });
            }
            let how = if ate.is_some() {
                alignment
            } else {
                Alignment::None
            };
            if let Ok(r) = rpe(gt, &estimate, how, T_MAX_DIFF, 1.0, DeltaUnit::Frames) {
                rpe_report = Some(RpeReport {
                    delta_frames: 1,
                    translation: r.trans,
                    rotation_deg: r.rot_deg,
                });
            }
        }
        _ => {
            crate::plot::trajectory_figure(
                &traj_png,
                &format!("{}: SLAM trajectory (no ground truth)", seq.name()),
                &[("SLAM", &estimate.positions())],
                None,
            )?;
            outputs.push(traj_png);
        }
    }
    let map_accuracy = match keyframe_alignment(out) {
        Some(s) => evaluate_map(out, seq, camera, cfg, &points, &s)?,
        None => None,
    };
    let hist = label_histogram(&points);
    let label_histogram = hist
        .iter()
        .enumerate()
        .filter(|(_, n)| **n > 0)
        .map(|(l, &n)| {
            let label = if l == classes::NUM_CLASSES {
                classes::VOID
            } else {
                l as u8
            };
            LabelCount {
                label,
                name: classes::display_name(label),
                points: n,
            }
        })
        .collect();
    let t = &out.tracking;
    let mut report = Report {
        sequence: seq.root.display().to_string(),
        mode: match out.depth {
            DepthMode::Sensor => "rgbd".into(),
            DepthMode::Predicted => "monocular".into(),
        },
        features: out.keypoint_source.into(),
        labels: out.semantic_source.into(),
        threads: out.threads,
        frames_requested: out.total_frames,
        frames_processed: out.frames.len(),
        frames_skipped: out.skipped.clone(),
        interrupted: out.interrupted,
        keyframes: out.map.keyframes.len(),
        odometry_constraints: out.map.constraints.len() - out.map.loop_constraints(),
        loop_constraints: out.map.loop_constraints(),
        landmarks: out.landmarks.len(),
        map_points: points.len(),
        tracking: TrackingReport {
            failures: t.failures.len(),
            relocalised: t.relocalised.len(),
            lost: t.lost.len(),
            reinitialised: t.reinitialised.len(),
            failure_frames: t.failures.clone(),
            relocalised_frames: t.relocalised.clone(),
            lost_frames: t.lost.clone(),
            reinitialised_frames: t.reinitialised.clone(),
        },
        wall_seconds: out.wall_seconds,
        fps: out.fps(),
        timing: out
            .timings
            .stages()
            .iter()
            .map(|(name, s)| StageReport {
                stage: name.to_string(),
                seconds: s.seconds,
                calls: s.calls,
                per_second: s.rate(),
            })
            .collect(),
        ate,
        ate_unaligned,
        ate_note,
        rpe: rpe_report,
        label_histogram,
        map_accuracy,
        semantic_failures: out.semantic_failures.clone(),
        correction: out.correction.clone(),
        local_correction: out.local.clone(),
        multiview: out.multiview,
        outputs: Vec::new(),
    };
    let json_path = dir.join("report.json");
    let md_path = dir.join("report.md");
    outputs.push(json_path.clone());
    outputs.push(md_path.clone());
    report.outputs = outputs;
    let mut json = serde_json::to_vec_pretty(&report).map_err(|e| Error::msg(e.to_string()))?;
    json.push(b'\n');
    crate::io::write_atomic(&json_path, &json)?;
    crate::io::write_atomic(&md_path, report.markdown().as_bytes())?;
    Ok(report)
}

/// The rigid motion moving the estimated world onto the ground-truth world,
/// from the keyframes' full poses: rotation the chordal mean of `R_gt R_est⁻¹`,
/// translation the mean residual. The map is metric in both modes (sensor or
/// predicted metric depth), so no scale is fitted. The position-only ATE
/// alignment is ill-conditioned in rotation (and scale) when the camera mostly
/// rotates (fr1_rpy) or barely moves, which would misplace a map metres away
/// from the cameras.
fn keyframe_alignment(out: &SlamOutput) -> Option<Sim3> {
    let scale = 1.0;
    let pairs: Vec<_> = out
        .map
        .keyframes
        .iter()
        .filter_map(|k| k.gt_pose.map(|g| (g, k.pose)))
        .collect();
    if pairs.is_empty() {
        return None;
    }
    let m: nalgebra::Matrix3<f64> = pairs
        .iter()
        .map(|(g, e)| {
            (g.rotation * e.rotation.inverse())
                .to_rotation_matrix()
                .into_inner()
        })
        .sum();
    let rotation = nalgebra::Rotation3::from_matrix(&m).into_inner();
    let translation = pairs
        .iter()
        .map(|(g, e)| g.translation.vector - scale * (rotation * e.translation.vector))
        .sum::<nalgebra::Vector3<f64>>()
        / pairs.len() as f64;
    Some(Sim3 {
        rotation,
        translation,
        scale,
    })
}

/// Per keyframe: ground-truth labels (if any) and the true surface depth.
struct KeyframeTruth {
    centre: Point3<f64>,
    world_to_cam: crate::geometry::Pose,
    depth: DepthImage,
    labels: Option<LabelImage>,
}

/// Table 11 figures: map points (moved into the ground-truth frame by
/// [`keyframe_alignment`]) are projected into the nearest keyframes by ground-truth pose;
/// the keyframe where the point is closest to the true surface (exact depth
/// when the sequence has it, else sensor depth) gives the position error and
/// the ground-truth label.
fn evaluate_map(
    out: &SlamOutput,
    seq: &TumSequence,
    camera: &Camera,
    cfg: &SlamConfig,
    points: &[MapPoint],
    alignment: &Sim3,
) -> Result<Option<MapAccuracy>> {
    let gt = GroundTruthSource::open(&seq.root, seq.config.depth_scale).ok();
    let exact = gt.as_ref().is_some_and(|g| g.depth.is_some());
    let mut truths = Vec::new();
    for kf in &out.map.keyframes {
        let Some(pose) = kf.gt_pose else { continue };
        let depth = match gt.as_ref().filter(|_| exact) {
            Some(g) => g.depth_at(kf.stamp).ok().flatten(),
            None => seq.load_depth(kf.frame_index).ok().flatten(),
        };
        let Some(depth) = depth else { continue };
        let labels = gt.as_ref().and_then(|g| g.labels_at(kf.stamp).ok());
        truths.push(KeyframeTruth {
            centre: Point3::from(pose.translation.vector),
            world_to_cam: pose.inverse(),
            depth,
            labels,
        });
    }
    if truths.is_empty() || points.is_empty() {
        return Ok(None);
    }
    let has_labels = truths.iter().any(|t| t.labels.is_some());
    let bounds = ViewBounds::new(camera);
    let step = points.len().div_ceil(cfg.system.max_eval_points.max(1));
    let mut errors = Vec::new();
    let mut per_class = vec![(0usize, 0usize); classes::NUM_CLASSES];
    for p in points.iter().step_by(step.max(1)) {
        let world = alignment.transform_point(&p.position.cast::<f64>());
        // The three nearest keyframes (by camera centre) that see the point.
        let mut near: Vec<(f64, usize, Point3<f64>)> = truths
            .iter()
            .enumerate()
            .filter_map(|(i, t)| {
                let q = t.world_to_cam * world;
                bounds
                    .contains(&q)
                    .then(|| ((t.centre - world).norm_squared(), i, q))
            })
            .collect();
        near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        let mut best: Option<(f64, usize, (u32, u32))> = None;
        for &(_, i, q) in near.iter().take(3) {
            let t = &truths[i];
            let Some(px) = camera.project(&q) else {
                continue;
            };
            let Some(d) = t.depth.at(px.x, px.y) else {
                continue;
            };
            let e = (q.z - d as f64).abs();
            if best.is_none_or(|b| e < b.0) {
                best = Some((e, i, (px.x.round() as u32, px.y.round() as u32)));
            }
        }
        let Some((e, i, (x, y))) = best else { continue };
        errors.push(e);
        if let Some(l) = &truths[i].labels
            && p.label != classes::VOID
            && x < l.width
            && y < l.height
        {
            let g = l.get(x, y) as usize;
            if g < classes::NUM_CLASSES {
                per_class[g].0 += 1;
                if g == p.label as usize {
                    per_class[g].1 += 1;
                }
            }
        }
    }
    if errors.is_empty() {
        return Ok(None);
    }
    let tol = cfg.system.position_tolerance;
    let within = errors.iter().filter(|&&e| e <= tol).count();
    let stats = Stats::of(&errors).ok_or_else(|| Error::msg("no map errors"))?;
    let classes_acc: Vec<ClassAccuracy> = per_class
        .iter()
        .enumerate()
        .filter(|(_, c)| c.0 > 0)
        .map(|(l, c)| ClassAccuracy {
            label: l as u8,
            name: classes::display_name(l as u8),
            points: c.0,
            accuracy: c.1 as f64 / c.0 as f64,
        })
        .collect();
    let labelled: usize = per_class.iter().map(|c| c.0).sum();
    let correct: usize = per_class.iter().map(|c| c.1).sum();
    Ok(Some(MapAccuracy {
        tolerance: tol,
        surface_source: if exact {
            "exact depth (depth_gt/)".into()
        } else {
            "sensor depth".into()
        },
        evaluated_points: errors.len(),
        position_accuracy: within as f64 / errors.len() as f64,
        median_error: stats.median,
        mean_error: stats.mean,
        mpa: (has_labels && !classes_acc.is_empty()).then(|| {
            classes_acc.iter().map(|c| c.accuracy).sum::<f64>() / classes_acc.len() as f64
        }),
        overall_label_accuracy: (has_labels && labelled > 0)
            .then(|| correct as f64 / labelled as f64),
        classes: classes_acc,
    }))
}

impl Report {
    /// The report as Markdown.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "# SDF-SLAM run\n");
        let _ = writeln!(s, "| | |\n|---|---|");
        let _ = writeln!(s, "| sequence | `{}` |", self.sequence);
        let _ = writeln!(
            s,
            "| mode | {} ({} keypoints, {} labels, {}) |",
            self.mode,
            self.features,
            self.labels,
            if self.threads {
                "threads"
            } else {
                "single thread"
            }
        );
        let _ = writeln!(
            s,
            "| frames | {} of {} processed{}, {} skipped |",
            self.frames_processed,
            self.frames_requested,
            if self.interrupted {
                " (interrupted)"
            } else {
                ""
            },
            self.frames_skipped.len()
        );
        let _ = writeln!(
            s,
            "| keyframes | {} ({} odometry + {} loop constraints, {} unified points) |",
            self.keyframes, self.odometry_constraints, self.loop_constraints, self.landmarks
        );
        let _ = writeln!(s, "| map points | {} |", self.map_points);
        let _ = writeln!(
            s,
            "| tracking | {} failures: {} relocalised, {} lost (constant velocity), {} restarts |",
            self.tracking.failures,
            self.tracking.relocalised,
            self.tracking.lost,
            self.tracking.reinitialised
        );
        let _ = writeln!(
            s,
            "| speed | {:.2} frames/s over {:.1} s |",
            self.fps, self.wall_seconds
        );
        if !self.tracking.lost_frames.is_empty() {
            let _ = writeln!(s, "\nLost frames: {:?}", self.tracking.lost_frames);
        }
        if !self.frames_skipped.is_empty() {
            let _ = writeln!(s, "\nSkipped frames:");
            for (i, why) in &self.frames_skipped {
                let _ = writeln!(s, "- {i}: {why}");
            }
        }
        let _ = writeln!(s, "\n## Trajectory (Table 10)\n");
        match &self.ate {
            Some(a) => {
                let _ = writeln!(
                    s,
                    "| error | rmse | mean | median | max | poses |\n|---|---|---|---|---|---|"
                );
                let row = |s: &mut String, name: &str, st: &Stats| {
                    let _ = writeln!(
                        s,
                        "| {name} | {:.4} | {:.4} | {:.4} | {:.4} | {} |",
                        st.rmse, st.mean, st.median, st.max, st.pairs
                    );
                };
                row(
                    &mut s,
                    &format!("ATE {:?}-aligned (m)", a.alignment),
                    &a.stats,
                );
                if let Some(u) = &self.ate_unaligned {
                    row(&mut s, "ATE unaligned (m)", &u.stats);
                }
                if let Some(r) = &self.rpe {
                    row(&mut s, "RPE translation, 1 frame (m)", &r.translation);
                    row(&mut s, "RPE rotation, 1 frame (deg)", &r.rotation_deg);
                }
                if a.alignment == Alignment::Sim3 {
                    let _ = writeln!(s, "\nSim(3) alignment scale: {:.4}", a.scale);
                }
            }
            None => match (&self.ate_unaligned, &self.ate_note) {
                (Some(u), note) => {
                    let _ = writeln!(
                        s,
                        "ATE unaligned: RMSE {:.4} m over {} poses. {}",
                        u.stats.rmse,
                        u.stats.pairs,
                        note.clone().unwrap_or_default()
                    );
                }
                _ => {
                    let _ = writeln!(s, "No ground truth: no trajectory error.");
                }
            },
        }
        let _ = writeln!(s, "\n## Map accuracy (Table 11)\n");
        match &self.map_accuracy {
            Some(m) => {
                let _ = writeln!(
                    s,
                    "Position accuracy: {:.3} of {} map points within {:.3} m of the true surface ({}); median error {:.4} m.\n",
                    m.position_accuracy,
                    m.evaluated_points,
                    m.tolerance,
                    m.surface_source,
                    m.median_error
                );
                if let Some(mpa) = m.mpa {
                    let _ = writeln!(
                        s,
                        "Label accuracy: MPA {:.3}, overall {:.3}.\n",
                        mpa,
                        m.overall_label_accuracy.unwrap_or(0.0)
                    );
                    let _ = writeln!(s, "| class | points | accuracy |\n|---|---|---|");
                    for c in &m.classes {
                        let _ = writeln!(s, "| {} | {} | {:.3} |", c.name, c.points, c.accuracy);
                    }
                } else {
                    let _ = writeln!(s, "No ground-truth labels: no label accuracy.");
                }
            }
            None => {
                let _ = writeln!(s, "Not available (needs ground-truth poses and depth).");
            }
        }
        let _ = writeln!(
            s,
            "\n## Timing\n\n| stage | seconds | calls | per second |\n|---|---|---|---|"
        );
        for t in &self.timing {
            let _ = writeln!(
                s,
                "| {} | {:.2} | {} | {:.2} |",
                t.stage, t.seconds, t.calls, t.per_second
            );
        }
        let _ = writeln!(s, "\n## Map labels\n\n| class | points |\n|---|---|");
        for l in &self.label_histogram {
            let _ = writeln!(s, "| {} | {} |", l.name, l.points);
        }
        let c = &self.correction;
        let _ = writeln!(
            s,
            "\n## Data correction\n\n{} keyframe pairs verified; constraints: {} proximity, {} similarity, {} random; {} of {} odometry edges verified; {} optimisations. Local: {} unified points from {} observations, {} keyframes rescaled ({:.3}-{:.3}).",
            c.pairs_tried,
            c.proximity_constraints,
            c.similarity_constraints,
            c.random_constraints,
            c.odometry_verified,
            c.odometry_edges,
            c.optimisations,
            self.local_correction.landmarks,
            self.local_correction.observations,
            self.local_correction.rescaled_keyframes,
            self.local_correction.min_scale,
            self.local_correction.max_scale
        );
        if self.multiview.candidates > 0 {
            let m = &self.multiview;
            let _ = writeln!(
                s,
                "\nMulti-view depth: {} of {} keyframe pixels with texture and parallax measured ({:.1} %), the rest keep SDFCNN's prediction or are dropped (`multiview.keep_unconfirmed`).",
                m.confirmed,
                m.candidates,
                100.0 * m.confirmed as f64 / m.candidates as f64
            );
        }
        let _ = writeln!(s, "\n## Files\n");
        for p in &self.outputs {
            let _ = writeln!(s, "- `{}`", p.display());
        }
        s
    }

    /// The end-of-run summary for the terminal.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "frames {} / {}{} ({} skipped), keyframes {}, loop constraints {}, map points {}",
            self.frames_processed,
            self.frames_requested,
            if self.interrupted {
                " (interrupted)"
            } else {
                ""
            },
            self.frames_skipped.len(),
            self.keyframes,
            self.loop_constraints,
            self.map_points
        );
        let _ = writeln!(
            s,
            "tracking failures {} (relocalised {}, lost {}, restarts {})",
            self.tracking.failures,
            self.tracking.relocalised,
            self.tracking.lost,
            self.tracking.reinitialised
        );
        let _ = writeln!(s, "speed {:.2} frames/s overall; per stage:", self.fps);
        for t in self.timing.iter().filter(|t| t.calls > 0) {
            let _ = writeln!(
                s,
                "  {:<13} {:>8.2} s  {:>5} calls  {:>8.2} /s",
                t.stage, t.seconds, t.calls, t.per_second
            );
        }
        if let Some(a) = &self.ate {
            let _ = write!(
                s,
                "ATE ({:?}-aligned) RMSE {:.4} m",
                a.alignment, a.stats.rmse
            );
            if let Some(u) = &self.ate_unaligned {
                let _ = write!(s, ", unaligned {:.4} m", u.stats.rmse);
            }
            if let Some(r) = &self.rpe {
                let _ = write!(
                    s,
                    "; RPE {:.4} m / {:.3} deg per frame",
                    r.translation.rmse, r.rotation_deg.rmse
                );
            }
            let _ = writeln!(s);
        }
        if let (None, Some(u)) = (&self.ate, &self.ate_unaligned) {
            let _ = writeln!(
                s,
                "ATE unaligned RMSE {:.4} m ({})",
                u.stats.rmse,
                self.ate_note.clone().unwrap_or_default()
            );
        }
        if let Some(m) = &self.map_accuracy {
            let _ = write!(
                s,
                "map position accuracy {:.3} (within {} m, {})",
                m.position_accuracy, m.tolerance, m.surface_source
            );
            if let Some(mpa) = m.mpa {
                let _ = write!(s, ", label MPA {mpa:.3}");
            }
            let _ = writeln!(s);
        }
        let labels: Vec<String> = self
            .label_histogram
            .iter()
            .map(|l| format!("{} {}", l.name, l.points))
            .collect();
        let _ = writeln!(s, "labels: {}", labels.join(", "));
        let _ = writeln!(s, "wrote:");
        for p in &self.outputs {
            let _ = writeln!(s, "  {}", p.display());
        }
        s
    }
}
