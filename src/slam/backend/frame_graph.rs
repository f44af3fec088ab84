//! Frames between two keyframes placed by their depth (RGB-D, `dense.frame_graph`).
//!
//! Tracking expresses each frame against its reference keyframe `A`, and the output takes the
//! frame's final pose as `A`'s corrected pose times that relative pose. Where the back end
//! (pose graph, bundle adjustment) moves the next keyframe `B = A + 1` differently from the
//! tracked motion between the two, the frames follow `A` and the whole discrepancy lands in
//! the step into `B` (RPE across a keyframe switch).
//!
//! Here the frames `f₁ … fₙ` between `A` and `B` become the free nodes of a small pose graph:
//! - `A → fₖ`: the frame's pose against `A` (its dense refinement against `A`'s depth, or its
//!   keypoint pose at a ninth of the weight), weighing `dense.frame_graph_reference_weight /
//!   k` of a step: the `k`-th frame after `A` sees less of `A`'s depth, and its error, like
//!   odometry's, grows along the span;
//! - `fₖ₋₁ → fₖ` and `fₙ → B`: the frame-to-frame steps, each frame's depth aligned to the
//!   previous frame's in tracking ([`FrameRecord::step`]);
//! - `A` fixed and `B` held at its corrected pose by a stiff edge.
//!
//! The discrepancy is then spread where the consecutive depths say it belongs. Keyframes keep
//! their poses; the result is written back into each frame's relative pose, so the output
//! reads it unchanged. Frames after the last keyframe (no `B`) are solved against `A` alone.

use super::pose_graph::{Edge, LmSettings, information, optimise};
use crate::geometry::{Pose, renormalized};
use crate::slam::config::{DenseConfig, RobustKernel};
use crate::slam::frontend::tracking::{FrameRecord, FrameStatus};
use crate::slam::map::Map;
use std::ops::Range;

/// What placing the frames did.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct FrameGraphSummary {
    /// Spans solved (a keyframe and the tracked frames after it, with a step edge).
    pub spans: usize,
    /// Of those, spans held at both ends.
    pub closed: usize,
    /// Frames placed.
    pub frames: usize,
}

/// A frame-to-frame step's standard deviations, metres and degrees (only their ratio to the
/// other edges' matters: `A` is fixed and `B` held).
const STEP_SIGMA_TRANSLATION: f64 = 0.002;
const STEP_SIGMA_ROTATION_DEG: f64 = 0.1;

/// `B`'s standard deviations against `A`: held, not measured.
const HOLD_SIGMA_TRANSLATION: f64 = 1e-6;
const HOLD_SIGMA_ROTATION_DEG: f64 = 1e-4;

/// A frame whose dense refinement was not kept: its keypoint pose against `A` weighs this
/// share of a dense one.
const KEYPOINT_WEIGHT: f64 = 1.0 / 9.0;

/// Places the frames between consecutive keyframes in place.
///
/// A span is a keyframe `A`'s record and the tracked frames after it whose reference is `A`;
/// it is held at both ends when the record after it is keyframe `A + 1` made from a tracked
/// frame (not a restart after loss, not a relocalised frame). A frame lost, relocalised or
/// tracked against another keyframe ends the span, and frames up to the next keyframe are left
/// as they are. A step edge joins two records only when the step was measured from the record
/// just before it.
pub(crate) fn place_frames(
    map: &Map,
    frames: &mut [FrameRecord],
    cfg: &DenseConfig,
) -> FrameGraphSummary {
    let mut summary = FrameGraphSummary::default();
    let mut i = 0;
    while i < frames.len() {
        let Some(a) = frames[i].keyframe else {
            i += 1;
            continue;
        };
        let mut j = i + 1;
        while j < frames.len()
            && frames[j].keyframe.is_none()
            && frames[j].status == FrameStatus::Tracked
            && frames[j].reference == Some(a)
        {
            j += 1;
        }
        let held = frames
            .get(j)
            .is_some_and(|r| r.keyframe == Some(a + 1) && r.status == FrameStatus::Tracked);
        if let Some(placed) = place_span(map, frames, a, i + 1..j, held, cfg) {
            summary.spans += 1;
            summary.closed += held as usize;
            summary.frames += placed;
        }
        i = j;
    }
    summary
}

/// Solves one span: keyframe `a`, the frames `between`, and (`held`) keyframe `a + 1`'s
/// record right after them. Returns how many frames moved; `None` without a step edge.
fn place_span(
    map: &Map,
    frames: &mut [FrameRecord],
    a: usize,
    between: Range<usize>,
    held: bool,
    cfg: &DenseConfig,
) -> Option<usize> {
    if between.is_empty() {
        return None;
    }
    let ka = map.keyframes.get(a)?;
    let kb = if held {
        Some(map.keyframes.get(a + 1)?)
    } else {
        None
    };
    let step_info = information(STEP_SIGMA_TRANSLATION, STEP_SIGMA_ROTATION_DEG);
    let dense_info = step_info * cfg.frame_graph_reference_weight;
    let keypoint_info = dense_info * KEYPOINT_WEIGHT;
    let n = between.len();
    // Nodes: 0 = A, 1..=n the frames, n + 1 = B.
    let mut poses: Vec<Pose> = std::iter::once(ka.pose)
        .chain(frames[between.clone()].iter().map(|f| ka.pose * f.relative))
        .chain(kb.map(|kb| kb.pose))
        .collect();
    let edge = |i, j, measurement, information| Edge {
        i,
        j,
        measurement,
        information,
        robust: false,
    };
    let mut edges: Vec<Edge> = frames[between.clone()]
        .iter()
        .enumerate()
        .map(|(k, f)| {
            let info = if f.dense { dense_info } else { keypoint_info };
            edge(0, k + 1, f.relative, info / (k + 1) as f64)
        })
        .collect();
    let last = between.end - 1 + held as usize;
    let steps = edges.len();
    for (k, r) in (between.start - 1..=last).enumerate().skip(1) {
        let previous = frames[r - 1].index;
        if let Some((from, step)) = frames[r].step
            && from == previous
        {
            edges.push(edge(k - 1, k, step, step_info));
        }
    }
    if edges.len() == steps {
        return None;
    }
    if let Some(kb) = kb {
        let hold = information(HOLD_SIGMA_TRANSLATION, HOLD_SIGMA_ROTATION_DEG);
        edges.push(edge(0, n + 1, ka.pose.inverse() * kb.pose, hold));
    }
    let settings = LmSettings {
        iterations: 10,
        kernel: RobustKernel::None,
        ..LmSettings::default()
    };
    optimise(&mut poses, &edges, &settings);
    let inverse = ka.pose.inverse();
    for (f, pose) in frames[between].iter_mut().zip(&poses[1..]) {
        f.relative = renormalized(&(inverse * pose));
    }
    Some(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::slam::fixtures::{at, keyframe, record};
    use crate::slam::map::Map;

    /// A straight move along x: keyframe A at 0, frames every 0.1 m, keyframe B at 0.4 m by
    /// odometry; the back end put B 2 cm further.
    fn scene(steps: bool) -> (Map, Vec<FrameRecord>) {
        let map = Map {
            keyframes: vec![
                keyframe(0, 0.0, at(0.0, 0.0), at(0.0, 0.0)),
                keyframe(1, 4.0, at(0.4, 0.0), at(0.42, 0.0)),
            ],
            ..Map::default()
        };
        let mut frames = vec![record(0, Some(0), 0, Pose::identity())];
        for k in 1..4 {
            frames.push(record(k, None, 0, at(0.1 * k as f64, 0.0)));
        }
        frames.push(record(4, Some(1), 1, Pose::identity()));
        for f in &mut frames {
            f.dense = true;
        }
        if steps {
            for (k, f) in frames.iter_mut().enumerate().skip(1) {
                let step = at(0.1 * (k - 1) as f64, 0.0).inverse() * at(0.1 * k as f64, 0.0);
                f.step = Some((k - 1, step));
            }
        }
        (map, frames)
    }

    #[test]
    fn the_jump_into_the_next_keyframe_is_spread_over_the_frames() {
        let (map, mut frames) = scene(true);
        let summary = place_frames(&map, &mut frames, &DenseConfig::default());
        assert_eq!(
            summary,
            FrameGraphSummary {
                spans: 1,
                closed: 1,
                frames: 3
            }
        );
        // The 2 cm are shared by every step, more of them nearer B: no step takes them all.
        let xs: Vec<f64> = std::iter::once(0.0)
            .chain(frames[1..4].iter().map(|f| f.relative.translation.vector.x))
            .chain([0.42])
            .collect();
        let steps: Vec<f64> = xs.windows(2).map(|w| w[1] - w[0]).collect();
        assert!(steps[0] > 0.1005, "{steps:?}");
        assert!(steps.windows(2).all(|w| w[1] > w[0]), "{steps:?}");
        assert!(steps[3] < 0.1 + 0.012, "{steps:?}");
        assert!((steps.iter().sum::<f64>() - 0.42).abs() < 1e-9);
        // Keyframes keep their poses.
        assert_eq!(frames[0].relative, Pose::identity());
        assert_eq!(frames[4].relative, Pose::identity());
    }

    #[test]
    fn without_steps_from_the_record_before_nothing_moves() {
        let (map, mut frames) = scene(false);
        let before = frames.clone();
        assert_eq!(
            place_frames(&map, &mut frames, &DenseConfig::default()),
            FrameGraphSummary::default()
        );
        assert_eq!(frames, before);
        // A step measured from another frame than the record before it is not an edge.
        let (map, mut frames) = scene(true);
        for f in &mut frames[1..] {
            if let Some((from, _)) = &mut f.step {
                *from += 10;
            }
        }
        let before = frames.clone();
        place_frames(&map, &mut frames, &DenseConfig::default());
        assert_eq!(frames, before);
    }

    #[test]
    fn a_relocalised_frame_ends_the_span_and_b_is_not_held() {
        let (map, mut frames) = scene(true);
        frames[3].status = FrameStatus::Relocalised;
        let summary = place_frames(&map, &mut frames, &DenseConfig::default());
        assert_eq!(summary.closed, 0);
        assert_eq!(summary.frames, 2);
        // Consistent steps and poses against A: nothing to move without B's correction.
        for (k, f) in frames[1..3].iter().enumerate() {
            let x = f.relative.translation.vector.x;
            assert!((x - 0.1 * (k + 1) as f64).abs() < 1e-9, "{x}");
        }
    }
}
