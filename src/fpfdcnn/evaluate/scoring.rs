//! Scoring of one method's matches on one pair against ground truth, and the pooled results.

use super::matching::PixelMatches;
use super::{ConditionResult, PairResult};
use crate::camera::Camera;
use crate::dataset::tum::Frame;
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::metrics::matching::{
    CORRECT_MATCH_PX, MatchingAccuracy, REPEATED_PX, Repeatability, common_offset,
    match_error_vectors, repeatability, within_offset,
};
use crate::metrics::{PoseError, PoseErrorSegment};
use crate::pnp::{PnpConfig, solve_pnp_ransac};
use nalgebra::Point2;

/// One method's figures on one condition, gathered pair by pair.
#[derive(Default)]
pub(super) struct Acc {
    segs: Vec<PoseErrorSegment>,
    rot: Vec<f64>,
    trans: Vec<f64>,
    failures: usize,
    keypoints: usize,
    images: usize,
    errors: Vec<f64>,
    pairs: Vec<PairResult>,
    repeat: Vec<Repeatability>,
    pub(super) derotated: usize,
    pub(super) refined: usize,
}

impl Acc {
    /// The pooled results.
    pub(super) fn finish(self) -> ConditionResult {
        let pooled = MatchingAccuracy::new(
            self.pairs.iter().map(|p| p.correct).sum(),
            self.pairs.iter().map(|p| p.matches).sum(),
        );
        let pose = PoseError::pool(&self.segs).ok();
        let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        let repeat = Repeatability::pool(&self.repeat);
        ConditionResult {
            repeatability: repeat.rate(),
            // Visible keypoints counted in both directions: per image, half of them.
            matching_score: pooled.correct as f64 / (repeat.visible as f64 / 2.0).max(1.0),
            correct: pooled.correct,
            matches: pooled.matches,
            accuracy: pooled.accuracy,
            err_t_percent: pose.map(|p| p.err_t_percent),
            err_r_deg_per_m: pose.map(|p| p.err_r_deg_per_m),
            mean_rot_error_deg: mean(&self.rot),
            mean_trans_error_m: mean(&self.trans),
            pnp_failures: self.failures,
            derotated_pairs: self.derotated,
            refined_matches: self.refined,
            keypoints: self.keypoints as f64 / self.images.max(1) as f64,
            offset_removed_accuracy: self.pairs.iter().map(|p| p.within_offset).sum::<usize>()
                as f64
                / pooled.matches.max(1) as f64,
            within_px: [2.0, 5.0, 10.0, 20.0]
                .iter()
                .map(|&t| {
                    let n = self.errors.iter().filter(|e| **e <= t).count();
                    (t, n as f64 / self.errors.len().max(1) as f64)
                })
                .collect(),
            pairs: self.pairs,
        }
    }
}

/// A frame pair with its ground truth, for scoring matches.
pub(super) struct PairGt<'a> {
    pub(super) a: &'a Frame,
    pub(super) b: &'a Frame,
    pub(super) pose_a: Pose,
    pub(super) pose_b: Pose,
    pub(super) cam: &'a Camera,
    pub(super) pnp: &'a PnpConfig,
}

/// Scores one method's matches on one pair into `acc`; returns each match's error against
/// the ground-truth projection (`None`: no depth at the frame-A keypoint).
pub(super) fn score(
    acc: &mut Acc,
    matches: &PixelMatches,
    [points_a, points_b]: &[Vec<Point2<f64>>; 2],
    gt: &PairGt<'_>,
) -> Result<Vec<Option<f64>>> {
    let PairGt {
        a,
        b,
        pose_a,
        pose_b,
        cam,
        pnp,
    } = gt;
    let (pose_a, pose_b, cam) = (pose_a, pose_b, *cam);
    let depth = a
        .depth
        .as_ref()
        .ok_or_else(|| Error::msg(format!("frame {} has no depth", a.index)))?;
    let vectors = match_error_vectors(matches, depth, cam, pose_a, pose_b)?;
    let errors: Vec<Option<f64>> = vectors.iter().map(|e| e.map(|v| v.norm())).collect();
    let judged: Vec<f64> = errors.iter().flatten().copied().collect();
    let judged_vectors: Vec<_> = vectors.into_iter().flatten().collect();
    let accuracy = MatchingAccuracy::new(
        judged.iter().filter(|e| **e <= CORRECT_MATCH_PX).count(),
        judged.len(),
    );
    let offset = common_offset(&judged_vectors);
    acc.pairs.push(PairResult {
        a: a.index,
        b: b.index,
        correct: accuracy.correct,
        matches: accuracy.matches,
        within_offset: offset.map_or(0, |o| within_offset(&judged_vectors, o, CORRECT_MATCH_PX)),
        offset_px: offset.map(|o| [o.x, o.y]),
    });
    acc.errors.extend(&judged);
    acc.keypoints += points_a.len() + points_b.len();
    acc.images += 2;
    if b.depth.is_some() {
        acc.repeat
            .push(repeatability(cam, a, b, points_a, points_b, REPEATED_PX)?);
    }
    let (mut pts, mut px) = (Vec::new(), Vec::new());
    for (pa, pb) in matches {
        if let Some(z) = depth.at(pa.x, pa.y) {
            pts.push(cam.back_project(pa, z as f64));
            px.push(*pb);
        }
    }
    // Camera A to camera B.
    let gt = pose_b.inverse() * pose_a;
    match solve_pnp_ransac(&pts, &px, cam, None, pnp) {
        Ok(r) => {
            acc.rot
                .push((r.pose.inverse() * gt).rotation.angle().to_degrees());
            acc.trans
                .push((r.pose.translation.vector - gt.translation.vector).norm());
            acc.segs.push(PoseErrorSegment::new(
                &gt.inverse(),
                &r.pose.inverse(),
                None,
            ));
        }
        Err(_) => acc.failures += 1,
    }
    Ok(errors)
}
