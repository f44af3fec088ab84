//! Frames between two keyframes placed by both keyframes' corrections.
//!
//! Tracking expresses each frame against its reference keyframe, and the output takes the
//! frame's final pose as that keyframe's corrected pose times the tracked relative pose
//! ([`SlamOutput::frame_pose`](super::system::SlamOutput::frame_pose)). Where the back end
//! (pose graph, bundle adjustment) moves the next keyframe differently from the tracked
//! motion between the two, every frame before it follows the first keyframe and the frame
//! after it jumps to the second: the discrepancy lands in one frame-to-frame step.
//!
//! With `correction.blend_frames` a frame between keyframes `A` and `B = A + 1` (`B` made
//! from a frame tracked against `A`) takes its pose both ways, from `A`'s corrected pose
//! (`T_A T̂_rel`) and from `B`'s (`T_B T̂_B⁻¹ T̂_A T̂_rel`, hats: odometry poses), and
//! interpolates between them by its time between the two keyframes, so the discrepancy is
//! spread over the frames in between. Keyframes keep their poses; the result is written back
//! into each frame's relative pose, so the output reads it unchanged.

use super::map::Map;
use super::tracking::{FrameRecord, FrameStatus};
use crate::geometry::{interpolate, renormalized};

/// Blends the frames between consecutive keyframes in place; returns how many moved.
///
/// A frame is left as it is when it has no reference, when it was lost, when no keyframe
/// follows it, or when the keyframe after it is not its reference's successor made from a
/// tracked frame (a relocalisation or a restart after loss breaks the odometry between them).
pub fn blend_frames(map: &Map, frames: &mut [FrameRecord]) -> usize {
    let mut next: Option<usize> = None;
    let mut blended = 0;
    for f in frames.iter_mut().rev() {
        if let Some(k) = f.keyframe {
            next = (f.status == FrameStatus::Tracked).then_some(k);
            continue;
        }
        if f.status == FrameStatus::Lost {
            continue;
        }
        let (Some(a), Some(b)) = (f.reference, next) else {
            continue;
        };
        if b != a + 1 {
            continue;
        }
        let (Some(ka), Some(kb)) = (map.keyframes.get(a), map.keyframes.get(b)) else {
            continue;
        };
        let span = kb.stamp - ka.stamp;
        if span <= 0.0 || !span.is_finite() {
            continue;
        }
        let s = ((f.stamp - ka.stamp) / span).clamp(0.0, 1.0);
        let from_a = ka.pose * f.relative;
        let from_b = kb.pose * kb.odom_pose.inverse() * ka.odom_pose * f.relative;
        let pose = interpolate(&from_a, &from_b, s);
        f.relative = renormalized(&(ka.pose.inverse() * pose));
        blended += 1;
    }
    blended
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::{DepthImage, LabelImage};
    use crate::geometry::Pose;
    use crate::slam::map::{KeyFrame, KeyframeFeatures, KeyframeView};
    use nalgebra::{Translation3, UnitQuaternion, Vector3};
    use std::sync::Arc;

    fn at(x: f64, yaw_deg: f64) -> Pose {
        Pose::from_parts(
            Translation3::new(x, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw_deg.to_radians()),
        )
    }

    fn keyframe(id: usize, stamp: f64, odom_pose: Pose, pose: Pose) -> KeyFrame {
        KeyFrame {
            id,
            frame_index: id,
            stamp,
            odom_pose,
            pose,
            gt_pose: None,
            track: Arc::new(KeyframeFeatures::default()),
            view: KeyframeView::new(
                1,
                &image::RgbImage::new(1, 1),
                &DepthImage::new(1, 1),
                &LabelImage::new(1, 1, 0),
            ),
            depth_scale: 1.0,
        }
    }

    fn record(
        index: usize,
        keyframe: Option<usize>,
        reference: usize,
        relative: Pose,
    ) -> FrameRecord {
        FrameRecord {
            index,
            stamp: index as f64,
            status: FrameStatus::Tracked,
            keyframe,
            reference: Some(reference),
            relative,
            odom_pose: Pose::identity(),
            inliers: 0,
            correspondences: 0,
            observations: Vec::new(),
            dense: false,
        }
    }

    /// Tracking moved 10 cm and turned 4 degrees from keyframe 0 (frame 0) to keyframe 1
    /// (frame 4); the back end put keyframe 1 2 cm further and 2 degrees more turned. The
    /// frames between take a growing share of that, keyframes and frames before the first
    /// keyframe's successor keep theirs.
    fn run() -> (Map, Vec<FrameRecord>, Vec<FrameRecord>) {
        let map = Map {
            keyframes: vec![
                keyframe(0, 0.0, at(0.0, 0.0), at(0.0, 0.0)),
                keyframe(1, 4.0, at(0.1, 4.0), at(0.12, 6.0)),
            ],
            constraints: Vec::new(),
            epoch: 0,
        };
        let mut frames = vec![record(0, Some(0), 0, Pose::identity())];
        frames.extend((1..4).map(|i| record(i, None, 0, at(0.025 * i as f64, i as f64))));
        frames.push(record(4, Some(1), 1, Pose::identity()));
        frames.push(record(5, None, 1, at(0.01, 0.0)));
        let before = frames.clone();
        blend_frames(&map, &mut frames);
        (map, before, frames)
    }

    #[test]
    fn frames_between_keyframes_share_both_corrections_by_time() {
        let (map, before, after) = run();
        for i in 1..4 {
            let s = i as f64 / 4.0;
            let from_a = map.keyframes[0].pose * before[i].relative;
            let pose = map.keyframes[0].pose * after[i].relative;
            // Keyframe 1's correction, applied to the frame's odometry pose, in full.
            let correction = map.keyframes[1].pose * map.keyframes[1].odom_pose.inverse();
            let from_b = correction * from_a;
            let expected = interpolate(&from_a, &from_b, s);
            assert!((pose.translation.vector - expected.translation.vector).norm() < 1e-12);
            assert!(pose.rotation.angle_to(&expected.rotation) < 1e-12);
            // Strictly between the two: the jump is spread, not moved.
            let gap = (from_b.translation.vector - from_a.translation.vector).norm();
            let moved = (pose.translation.vector - from_a.translation.vector).norm();
            assert!(
                (moved - s * gap).abs() < 1e-9,
                "frame {i}: {moved} vs {}",
                s * gap
            );
        }
        // Keyframes keep their poses; the frame after the last keyframe has no successor.
        assert_eq!(after[0].relative, before[0].relative);
        assert_eq!(after[4].relative, before[4].relative);
        assert_eq!(after[5].relative, before[5].relative);
    }

    #[test]
    fn frames_are_left_alone_where_the_odometry_breaks() {
        let (map, mut frames, _) = run();
        // The next keyframe was a restart after loss: its odometry does not follow keyframe 0's.
        frames[4].status = FrameStatus::Initialised;
        let before = frames.clone();
        assert_eq!(blend_frames(&map, &mut frames), 0);
        assert_eq!(frames, before);
        // A frame relocalised against another keyframe than the next one's predecessor.
        frames[4].status = FrameStatus::Tracked;
        frames[2].reference = Some(1);
        frames[2].status = FrameStatus::Relocalised;
        let moved = blend_frames(&map, &mut frames);
        assert_eq!(moved, 2);
        assert_eq!(frames[2].relative, before[2].relative);
    }
}
