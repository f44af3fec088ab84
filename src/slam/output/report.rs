//! The report of a run (`report.md` / `report.json`): ATE / RPE against ground truth
//! (Table 10), timing per stage, tracking failures, the map accuracy of Table 11 when
//! ground truth allows (per-class accuracy of the map labels and the share of map points
//! within a tolerance of the true surface), and the files written. Measured by
//! [`super::evaluation`], written by [`crate::slam::output`].

use super::evaluation::TrajectoryEvaluation;
use crate::classes;
use crate::dataset::TumSequence;
use crate::metrics::Stats;
use crate::metrics::trajectory::Alignment;
use crate::slam::frontend::repeated_images::RepeatCounts;
use crate::slam::mapping::semantic_map::{MapPoint, label_histogram};
use crate::slam::system::{DepthMode, SlamOutput};
use serde::{Deserialize, Serialize};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Absolute trajectory error (ATE) of the camera positions against ground truth.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AteReport {
    /// How the estimate was aligned to the ground truth before measuring.
    pub alignment: Alignment,
    /// Statistics of the position errors, metres.
    pub stats: Stats,
    /// Scale of the Sim(3) alignment (1 for SE(3) and none).
    pub scale: f64,
}

/// Relative pose error between consecutive frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RpeReport {
    /// Frame gap of the relative poses compared (1: consecutive frames).
    pub delta_frames: usize,
    /// Statistics of the relative translation errors, metres.
    pub translation: Stats,
    /// Statistics of the relative rotation errors, degrees.
    pub rotation_deg: Stats,
}

/// Accuracy of one class of the map labels.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassAccuracy {
    /// Class label.
    pub label: u8,
    /// Class name.
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
    /// Median distance of the evaluated points to the true surface, metres.
    pub median_error: f64,
    /// Mean distance of the evaluated points to the true surface, metres.
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
    /// Class label (void included).
    pub label: u8,
    /// Class name (`"void"` for void).
    pub name: String,
    /// Map points with this label.
    pub points: usize,
}

/// A stage's timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageReport {
    /// Stage name.
    pub stage: String,
    /// Time spent in the stage, seconds.
    pub seconds: f64,
    /// Times the stage ran.
    pub calls: usize,
    /// Calls per second of stage time: the rate the stage alone could sustain.
    pub per_second: f64,
    /// The stage's share of the CPU time the run had: its seconds over the run's wall time
    /// times the cores (a stage whose calls took one of two cores all run: 0.5). A stage's
    /// seconds are the wall time of its calls, so waiting inside a call counts and the
    /// threads a call spreads its work over do not.
    #[serde(default)]
    pub cpu_share: f64,
}

/// Tracking trouble.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrackingReport {
    /// Frames whose guided tracking failed.
    pub failures: usize,
    /// Of those, frames relocalised against a keyframe.
    pub relocalised: usize,
    /// Of those, frames that kept the constant-velocity pose.
    pub lost: usize,
    /// Frames where a keyframe was started after a lost streak.
    pub reinitialised: usize,
    /// Indices of the frames counted in `failures`.
    pub failure_frames: Vec<usize>,
    /// Indices of the frames counted in `relocalised`.
    pub relocalised_frames: Vec<usize>,
    /// Indices of the frames counted in `lost`.
    pub lost_frames: Vec<usize>,
    /// Indices of the frames counted in `reinitialised`.
    pub reinitialised_frames: Vec<usize>,
    /// RGB-D: frames whose pose the dense refinement replaced, and frames where it was not kept.
    #[serde(default)]
    pub dense_kept: usize,
    /// RGB-D: frames where the dense refinement's pose was not kept.
    #[serde(default)]
    pub dense_rejected: usize,
    /// Frames tracked with no keypoints detected: by the dense alignment alone (RGB-D,
    /// `tracking.keypoints_every_frame = false`; counted in `dense_kept` too) or by optical flow
    /// (monocular, `tracking.monocular_flow`).
    #[serde(default)]
    pub without_keypoints: usize,
    /// `tracking.colour_instant`: frames whose pose was moved from their depth image's
    /// instant to their colour image's.
    #[serde(default)]
    pub colour_instant: usize,
    /// Keyframes due by the frame count whose keypoints a feature worker detected ahead of
    /// tracking, and how many of those tracking did not use.
    #[serde(default)]
    pub detected_ahead: usize,
    /// Of `detected_ahead`, the detections tracking did not use.
    #[serde(default)]
    pub detected_ahead_unused: usize,
}

/// Everything `report.json` holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// The sequence folder.
    pub sequence: String,
    /// `"rgbd"` (sensor depth) or `"monocular"` (predicted depth).
    pub mode: String,
    /// Name of the keypoint source (`"orb"`, `"fpfdcnn"`).
    pub features: String,
    /// Name of the semantic source.
    pub labels: String,
    /// Whether tracking, mapping and correction ran in their own threads.
    pub threads: bool,
    /// Threads that loaded frames and detected keypoints ahead of tracking (0: tracking
    /// did it); the `features` stage time is summed over them.
    #[serde(default)]
    pub feature_workers: usize,
    /// Frames the run was asked to process.
    pub frames_requested: usize,
    /// Frames tracked.
    pub frames_processed: usize,
    /// Frames that could not be read: index and reason.
    pub frames_skipped: Vec<(usize, String)>,
    /// Frames whose colour and/or depth image repeats the previous frame's.
    #[serde(default)]
    pub repeated_frames: RepeatCounts,
    /// Whether the run was stopped before its last frame.
    pub interrupted: bool,
    /// Keyframes in the map.
    pub keyframes: usize,
    /// Odometry constraints (each keyframe to its predecessor).
    pub odometry_constraints: usize,
    /// Constraints other than odometry (random, proximity and similarity pairs).
    pub loop_constraints: usize,
    /// Unified world points of local correction.
    pub landmarks: usize,
    /// Points of the semantic map.
    pub map_points: usize,
    /// Tracking failures and recoveries.
    pub tracking: TrackingReport,
    /// Wall-clock duration of the run, seconds.
    pub wall_seconds: f64,
    /// Frames per second over the whole run.
    pub fps: f64,
    /// Time per stage.
    pub timing: Vec<StageReport>,
    /// ATE after the mode's alignment (SE(3) with sensor depth, Sim(3) with predicted).
    pub ate: Option<AteReport>,
    /// ATE without any alignment (poses compared as they are).
    pub ate_unaligned: Option<AteReport>,
    /// Why `ate` is missing although there is ground truth.
    pub ate_note: Option<String>,
    /// Per-frame RPE, under the mode's alignment when `ate` has one.
    pub rpe: Option<RpeReport>,
    /// Map points per label, void last.
    pub label_histogram: Vec<LabelCount>,
    /// Table 11's accuracy of the map (`None` when ground truth does not allow it).
    pub map_accuracy: Option<MapAccuracy>,
    /// Keyframes whose semantic source failed (void labels used): frame index and error.
    pub semantic_failures: Vec<(usize, String)>,
    /// Counts of the correction stage.
    pub correction: crate::slam::backend::correction::CorrectionStats,
    /// What local correction did.
    pub local_correction: crate::slam::backend::correction::LocalSummary,
    /// The final bundle adjustment (`None`: off).
    #[serde(default)]
    pub bundle_adjustment: Option<crate::slam::backend::bundle_adjustment::BaSummary>,
    /// Dense keyframe-to-keyframe edges (`None`: off).
    #[serde(default)]
    pub keyframe_alignment:
        Option<crate::slam::backend::keyframe_alignment::KeyframeAlignmentSummary>,
    /// Multi-view depth of monocular keyframes (zero in RGB-D mode).
    #[serde(default)]
    pub multiview: crate::slam::mapping::multiview_depth::SweepSummary,
    /// The local bundle adjustments during the run.
    #[serde(default)]
    pub local_adjustment: crate::slam::backend::local_bundle_adjustment::LocalBaStats,
    /// The keyframes' ATE live, before and after the final optimisation.
    #[serde(default)]
    pub keyframe_ate: super::evaluation::KeyframeAtes,
    /// The floor's camera height, the monocular map-level scale and any rescaling.
    #[serde(default)]
    pub scale: crate::slam::system::scale::ScaleReport,
    /// Files written by the run.
    pub outputs: Vec<PathBuf>,
}

/// Points per class present in the map, void last.
fn label_counts(points: &[MapPoint]) -> Vec<LabelCount> {
    label_histogram(points)
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
        .collect()
}

impl Report {
    /// The report of a finished run: its counts and timings, the errors against ground
    /// truth, and the map's label histogram (files are listed by [`crate::slam::output`]).
    pub fn new(
        out: &SlamOutput,
        seq: &TumSequence,
        points: &[MapPoint],
        trajectory: TrajectoryEvaluation,
        map_accuracy: Option<MapAccuracy>,
    ) -> Report {
        let t = &out.tracking;
        Report {
            sequence: seq.root.display().to_string(),
            mode: match out.depth {
                DepthMode::Sensor => "rgbd".into(),
                DepthMode::Predicted => "monocular".into(),
            },
            features: out.keypoint_source.into(),
            labels: out.semantic_source.into(),
            threads: out.threads,
            feature_workers: out.feature_workers,
            frames_requested: out.total_frames,
            frames_processed: out.frames.len(),
            frames_skipped: out.skipped.clone(),
            repeated_frames: out.repeated_frames,
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
                dense_kept: t.dense_kept,
                dense_rejected: t.dense_rejected,
                without_keypoints: t.without_keypoints,
                colour_instant: out.colour_instant,
                detected_ahead: t.detected_ahead,
                detected_ahead_unused: t.detected_ahead_unused,
            },
            wall_seconds: out.wall_seconds,
            fps: out.fps(),
            timing: {
                let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
                let cpu = out.wall_seconds * cores as f64;
                out.timings
                    .stages()
                    .iter()
                    .map(|(name, s)| StageReport {
                        stage: name.to_string(),
                        seconds: s.seconds,
                        calls: s.calls,
                        per_second: s.rate(),
                        cpu_share: if cpu > 0.0 { s.seconds / cpu } else { 0.0 },
                    })
                    .collect()
            },
            ate: trajectory.ate,
            ate_unaligned: trajectory.ate_unaligned,
            ate_note: trajectory.ate_note,
            rpe: trajectory.rpe,
            label_histogram: label_counts(points),
            map_accuracy,
            semantic_failures: out.semantic_failures.clone(),
            correction: out.correction.clone(),
            local_correction: out.local.clone(),
            bundle_adjustment: out.adjustment,
            keyframe_alignment: out.keyframe_alignment.clone(),
            multiview: out.multiview,
            local_adjustment: out.local_adjustment,
            keyframe_ate: Default::default(),
            scale: out.scale.clone(),
            outputs: Vec::new(),
        }
    }

    /// What the scale anchors found ([`crate::slam::mapping::scale_anchor`]), a line each.
    pub fn scale_lines(&self) -> Vec<String> {
        let sc = &self.scale;
        let mut lines = Vec::new();
        match (&sc.floor, &sc.floor_error) {
            (Some(f), _) => {
                let mut l = format!(
                    "floor: {} of {} floor points on one plane; the cameras are {:.3} (± {:.3}) map units above it",
                    f.inliers, f.floor_points, f.camera_height, f.height_spread
                );
                match (sc.camera_height, sc.applied) {
                    (Some(h), Some(k)) => {
                        l += &format!("; the camera height {h:.3} m scaled the map by {k:.3}")
                    }
                    (Some(h), None) => {
                        l += &format!(
                            "; sensor depth is metric, so the map is not rescaled: the camera height given ({h:.3} m) is {:+.1} % from it",
                            100.0 * (h / f.camera_height - 1.0)
                        )
                    }
                    (None, _) => {
                        l += " (give the camera height, `--camera-height`, to check or fix the scale)"
                    }
                }
                lines.push(l);
            }
            (None, Some(e)) => lines.push(format!("floor: {e}; the map keeps its scale")),
            (None, None) => {}
        }
        if let Some(m) = &sc.multiview {
            lines.push(format!(
                "map-level scale: multi-view / SDFCNN depth over {} keyframes {:.3} ± {:.1} % (10-90 %: {:.3}-{:.3}){}",
                m.keyframes,
                m.scale,
                100.0 * m.relative_error,
                m.p10,
                m.p90,
                if m.poorly_determined { ", poorly determined" } else { "" }
            ));
        }
        lines
    }

    /// The report as Markdown.
    pub fn markdown(&self) -> String {
        let mut s = String::new();
        self.markdown_run(&mut s);
        self.markdown_trajectory(&mut s);
        self.markdown_map(&mut s);
        self.markdown_details(&mut s);
        s
    }

    /// The run: sequence, mode, frames, keyframes, tracking, speed.
    fn markdown_run(&self, s: &mut String) {
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
        let r = &self.repeated_frames;
        if r.total() > 0 {
            let _ = writeln!(s, "| repeated images | {} |", r.describe());
        }
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
        if self.tracking.dense_kept + self.tracking.dense_rejected > 0 {
            let _ = writeln!(
                s,
                "| dense refinement | kept for {} frames, not kept for {} |",
                self.tracking.dense_kept, self.tracking.dense_rejected
            );
        }
        if self.tracking.without_keypoints > 0 {
            let _ = writeln!(
                s,
                "| tracked without keypoints ({}) | {} frames |",
                self.tracked_without_keypoints_by(),
                self.tracking.without_keypoints
            );
        }
        if self.tracking.detected_ahead > 0 {
            let _ = writeln!(
                s,
                "| keyframe keypoints detected ahead by the feature workers | {} frames, {} unused |",
                self.tracking.detected_ahead, self.tracking.detected_ahead_unused
            );
        }
        if self.tracking.colour_instant > 0 {
            let _ = writeln!(
                s,
                "| poses moved to the colour instant | {} frames |",
                self.tracking.colour_instant
            );
        }
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
    }

    /// Table 10: ATE and RPE.
    fn markdown_trajectory(&self, s: &mut String) {
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
                row(s, &format!("ATE {:?}-aligned (m)", a.alignment), &a.stats);
                if let Some(u) = &self.ate_unaligned {
                    row(s, "ATE unaligned (m)", &u.stats);
                }
                if let Some(r) = &self.rpe {
                    row(s, "RPE translation, 1 frame (m)", &r.translation);
                    row(s, "RPE rotation, 1 frame (deg)", &r.rotation_deg);
                }
                if a.alignment == Alignment::Sim3 {
                    let _ = writeln!(s, "\nSim(3) alignment scale: {:.4}", a.scale);
                }
                let k = &self.keyframe_ate;
                if let (Some(live), Some(online), Some(last)) = (&k.live, &k.online, &k.final_poses)
                {
                    let _ = writeln!(
                        s,
                        "\nKeyframes' ATE RMSE ({} keyframes with ground truth): live (each pose right after its correction step) {:.4} m, at the end of the run before the final optimisation {:.4} m, final {:.4} m.",
                        last.stats.pairs, live.stats.rmse, online.stats.rmse, last.stats.rmse
                    );
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
    }

    /// Table 11: map position and label accuracy.
    fn markdown_map(&self, s: &mut String) {
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
    }

    /// Timing per stage, map labels, data correction, multi-view depth, files.
    fn markdown_details(&self, s: &mut String) {
        let _ = writeln!(
            s,
            "\n## Timing\n\n| stage | seconds | calls | per second | CPU share |\n|---|---|---|---|---|"
        );
        for t in &self.timing {
            let _ = writeln!(
                s,
                "| {} | {:.2} | {} | {:.2} | {:.1} % |",
                t.stage,
                t.seconds,
                t.calls,
                t.per_second,
                100.0 * t.cpu_share
            );
        }
        let _ = writeln!(
            s,
            "\nPer second: calls per second of the stage's own time, the rate it alone could \
             sustain. CPU share: the wall time of its calls over the run's wall time times the machine's \
             cores (waiting inside a call counts; the threads a call spreads over do not)."
        );
        if self.feature_workers > 1 {
            let _ = writeln!(
                s,
                "\nThe features stage's time is summed over tracking and {} workers that \
                 prepared frames ahead of it.",
                self.feature_workers
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
        if let Some(k) = &self.keyframe_alignment {
            let _ = writeln!(
                s,
                "\nKeyframe alignment (depth ICP between keyframes): {} of {} keyframe pairs became edges of the final pose graph and bundle adjustment ({} of them loop pairs; median change of the starting relative pose {:.1} mm), {:.3} s.",
                k.edges,
                k.pairs,
                k.loop_edges,
                k.median_correction * 1000.0,
                k.seconds
            );
        }
        let l = &self.local_adjustment;
        if l.runs > 0 {
            let per = |v: usize| v as f64 / l.runs as f64;
            let _ = writeln!(
                s,
                "\nLocal bundle adjustment: {} keyframes' windows adjusted during the run, on average {:.1} free and {:.1} fixed keyframes, {:.0} tracks with {:.0} observations ({:.1} dropped by the chi-square gate); {:.1} ms per keyframe on average, {:.1} ms at most.",
                l.runs,
                per(l.free_keyframes),
                per(l.fixed_keyframes),
                per(l.tracks),
                per(l.observations),
                per(l.outliers),
                l.seconds / l.runs as f64 * 1e3,
                l.max_seconds * 1e3
            );
        }
        if let Some(b) = &self.bundle_adjustment {
            let _ = writeln!(
                s,
                "\nBundle adjustment: {} of {} keyframes free, {} tracks with {} observations ({} dropped by the chi-square gate); cost {:.1} -> {:.1} in {} iterations, {:.3} s; {} tracked frames refined against the adjusted points.",
                b.free_keyframes,
                b.keyframes,
                b.tracks,
                b.observations,
                b.outliers,
                b.initial_cost,
                b.final_cost,
                b.iterations,
                b.seconds,
                b.frames_refined
            );
        }
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
        let scale = self.scale_lines();
        if !scale.is_empty() {
            let _ = writeln!(s, "\n## Scale\n");
            for l in scale {
                let _ = writeln!(s, "- {l}");
            }
        }
        let _ = writeln!(s, "\n## Files\n");
        for p in &self.outputs {
            let _ = writeln!(s, "- `{}`", p.display());
        }
    }

    /// What placed the frames tracked without keypoints: the dense alignment of their depth
    /// (RGB-D) or the optical flow of the last keypoints (monocular).
    fn tracked_without_keypoints_by(&self) -> &'static str {
        if self.mode == "monocular" {
            "optical flow"
        } else {
            "dense alignment alone"
        }
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
        let r = &self.repeated_frames;
        if r.total() > 0 {
            let _ = writeln!(s, "repeated images: {}", r.describe());
        }
        if self.tracking.dense_kept + self.tracking.dense_rejected > 0 {
            let _ = writeln!(
                s,
                "dense refinement kept for {} frames, not kept for {}",
                self.tracking.dense_kept, self.tracking.dense_rejected
            );
        }
        if self.tracking.without_keypoints > 0 {
            let _ = writeln!(
                s,
                "tracked without keypoints ({}): {} frames",
                self.tracked_without_keypoints_by(),
                self.tracking.without_keypoints
            );
        }
        if self.tracking.detected_ahead > 0 {
            let _ = writeln!(
                s,
                "keyframe keypoints detected ahead by the feature workers: {} frames ({} unused)",
                self.tracking.detected_ahead, self.tracking.detected_ahead_unused
            );
        }
        if self.tracking.colour_instant > 0 {
            let _ = writeln!(
                s,
                "poses moved from the depth's instant to the colour's on {} frames",
                self.tracking.colour_instant
            );
        }
        for l in self.scale_lines() {
            let _ = writeln!(s, "{l}");
        }
        let _ = writeln!(s, "speed {:.2} frames/s overall; per stage:", self.fps);
        for t in self.timing.iter().filter(|t| t.calls > 0) {
            let _ = writeln!(
                s,
                "  {:<13} {:>8.2} s  {:>5} calls  {:>8.2} /s",
                t.stage, t.seconds, t.calls, t.per_second
            );
        }
        if self.feature_workers > 1 {
            let _ = writeln!(
                s,
                "  (features: time summed over tracking and {} workers preparing frames ahead of it)",
                self.feature_workers
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
