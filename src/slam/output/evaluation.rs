//! A run measured against ground truth: the trajectory's ATE / RPE as evo computes them
//! (Table 10) and the map's Table 11 figures (map points within a tolerance of the true
//! surface, per-class label accuracy). Pure computation: [`crate::slam::output`] writes files.

use super::report::{AteReport, ClassAccuracy, MapAccuracy, RpeReport};
use crate::camera::Camera;
use crate::classes;
use crate::dataset::{DepthImage, LabelImage, TumSequence};
use crate::error::{Error, Result};
use crate::geometry::Sim3;
use crate::metrics::Stats;
use crate::metrics::trajectory::{Alignment, Ape, DeltaUnit, ape, rpe};
use crate::slam::config::SlamConfig;
use crate::slam::map::ViewBounds;
use crate::slam::mapping::semantic_map::MapPoint;
use crate::slam::mapping::semantic_source::GroundTruthSource;
use crate::slam::system::{DepthMode, SlamOutput};
use crate::trajectory::Trajectory;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

/// Largest stamp difference (s) of an associated estimate / ground-truth pair.
const T_MAX_DIFF: f64 = 0.02;

/// The trajectory's errors against ground truth.
#[derive(Debug, Default)]
pub struct TrajectoryEvaluation {
    /// ATE after the mode's alignment (SE(3) with sensor depth, Sim(3) with predicted).
    pub ate: Option<AteReport>,
    /// ATE without any alignment (poses compared as they are).
    pub ate_unaligned: Option<AteReport>,
    /// Why `ate` is missing although ground truth is there.
    pub ate_note: Option<String>,
    /// Per-frame RPE (delta of one frame), under the mode's alignment when `ate` has one.
    pub rpe: Option<RpeReport>,
    /// The alignment to draw: the mode's, or none when it failed.
    pub drawn: Option<(Ape, Alignment)>,
}

/// ATE and per-frame RPE of `estimate` against the sequence's ground truth; a degenerate
/// alignment (a camera that only rotates in place) falls back to unaligned errors, with a
/// note. Empty without ground truth or with fewer than three poses.
pub fn evaluate_trajectory(
    groundtruth: Option<&Trajectory>,
    estimate: &Trajectory,
    depth: DepthMode,
) -> TrajectoryEvaluation {
    let mut e = TrajectoryEvaluation::default();
    let Some(gt) = groundtruth.filter(|_| estimate.len() >= 3) else {
        return e;
    };
    let alignment = match depth {
        DepthMode::Sensor => Alignment::Se3,
        DepthMode::Predicted => Alignment::Sim3,
    };
    e.drawn = match ape(gt, estimate, alignment, T_MAX_DIFF) {
        Ok(a) => Some((a, alignment)),
        Err(err) => {
            e.ate_note = Some(format!(
                "{alignment:?} alignment failed ({err}): errors are unaligned"
            ));
            ape(gt, estimate, Alignment::None, T_MAX_DIFF)
                .ok()
                .map(|a| (a, Alignment::None))
        }
    };
    if let Some((a, how)) = &e.drawn
        && *how == alignment
    {
        e.ate = Some(AteReport {
            alignment,
            stats: a.stats,
            scale: a.alignment.scale,
        });
    }
    if let Ok(a) = ape(gt, estimate, Alignment::None, T_MAX_DIFF) {
        e.ate_unaligned = Some(AteReport {
            alignment: Alignment::None,
            stats: a.stats,
            scale: 1.0,
        });
    }
    let how = if e.ate.is_some() {
        alignment
    } else {
        Alignment::None
    };
    if let Ok(r) = rpe(gt, estimate, how, T_MAX_DIFF, 1.0, DeltaUnit::Frames) {
        e.rpe = Some(RpeReport {
            delta_frames: 1,
            translation: r.trans,
            rotation_deg: r.rot_deg,
        });
    }
    e
}

/// The keyframes' ATE (the mode's alignment) at three moments of a run.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct KeyframeAtes {
    /// Each keyframe's pose right after its correction step (the live estimate).
    pub live: Option<AteReport>,
    /// Every keyframe's pose at the end of the run, before the final optimisation.
    pub online: Option<AteReport>,
    /// The final poses.
    pub final_poses: Option<AteReport>,
}

/// The keyframes' ATE against the sequence's ground truth (see [`KeyframeAtes`]); each
/// `None` without ground truth, with fewer than three poses, with not one pose per
/// keyframe, or when the alignment fails.
pub(crate) fn keyframe_ates(groundtruth: Option<&Trajectory>, out: &SlamOutput) -> KeyframeAtes {
    let alignment = match out.depth {
        DepthMode::Sensor => Alignment::Se3,
        DepthMode::Predicted => Alignment::Sim3,
    };
    let stamps: Vec<f64> = out.map.keyframes.iter().map(|k| k.stamp).collect();
    let ate = |poses: Vec<crate::geometry::Pose>| {
        let gt = groundtruth?;
        if poses.len() != stamps.len() || poses.len() < 3 {
            return None;
        }
        let estimate = Trajectory {
            stamps: stamps.clone(),
            poses,
        };
        let a = ape(gt, &estimate, alignment, T_MAX_DIFF).ok()?;
        Some(AteReport {
            alignment,
            stats: a.stats,
            scale: a.alignment.scale,
        })
    };
    KeyframeAtes {
        live: ate(out.live_poses.clone()),
        online: ate(out.online_poses.clone()),
        final_poses: ate(out.map.keyframes.iter().map(|k| k.pose).collect()),
    }
}

/// Table 11 figures of the map, when the keyframes have ground-truth poses.
pub(crate) fn evaluate_map_accuracy(
    out: &SlamOutput,
    seq: &TumSequence,
    camera: &Camera,
    cfg: &SlamConfig,
    points: &[MapPoint],
) -> Result<Option<MapAccuracy>> {
    match keyframe_alignment(out) {
        Some(s) => evaluate_map(out, seq, camera, cfg, points, &s),
        None => Ok(None),
    }
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
    let rotation = crate::geometry::nearest_rotation(&m, 0.0)?.into_inner();
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
