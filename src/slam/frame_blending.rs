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
/// A frame is left as it is when no keyframe follows it, or when anything between it and the
/// next keyframe `B` breaks the odometry from its reference `A` to `B`: `B` is not `A + 1` or
/// was not made from a tracked frame (a restart after loss), or a frame between was lost,
/// relocalised or tracked against another keyframe. Frames refined after bundle adjustment
/// (`bundle_adjustment.refine_frames`) are blended from their refined pose against `A`.
pub fn blend_frames(map: &Map, frames: &mut [FrameRecord]) -> usize {
    let mut next: Option<usize> = None;
    let mut blended = 0;
    for f in frames.iter_mut().rev() {
        if let Some(k) = f.keyframe {
            next = (f.status == FrameStatus::Tracked).then_some(k);
            continue;
        }
        // Walking back from `B`, every frame down to `A` must be tracked against `A = B - 1`;
        // a lost or relocalised frame, or one against another keyframe, means `B` was not
        // made from `A`'s odometry, so no frame before it is blended towards `B`.
        let (Some(a), Some(b)) = (f.reference, next) else {
            continue;
        };
        if f.status != FrameStatus::Tracked || b != a + 1 {
            next = None;
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
        let from_b = kb.carry(&(ka.odom_pose * f.relative));
        let pose = interpolate(&from_a, &from_b, s);
        f.relative = renormalized(&(ka.pose.inverse() * pose));
        blended += 1;
    }
    blended
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::dataset::DepthImage;
    use crate::geometry::Pose;
    use crate::slam::map::KeyFrame;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    pub(crate) fn at(x: f64, yaw_deg: f64) -> Pose {
        Pose::from_parts(
            Translation3::new(x, 0.01 * x, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw_deg.to_radians()),
        )
    }

    pub(crate) fn keyframe(id: usize, stamp: f64, odom_pose: Pose, pose: Pose) -> KeyFrame {
        KeyFrame {
            stamp,
            pose,
            ..crate::slam::keyframe_alignment::tests::keyframe(
                id,
                &DepthImage::new(1, 1),
                odom_pose,
            )
        }
    }

    pub(crate) fn record(
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
            step: None,
        }
    }

    /// Keyframe 0 (frame 0) and keyframe 1 (frame 4): tracking moved 10 cm and turned 4
    /// degrees between them; the back end moved keyframe 0 by 5 cm and 3 degrees and keyframe
    /// 1 by 7 cm and 5 degrees. Frames 1-3 are tracked against keyframe 0, frame 5 against 1.
    fn scene() -> (Map, Vec<FrameRecord>) {
        let map = Map {
            keyframes: vec![
                keyframe(0, 0.0, at(0.0, 0.0), at(0.05, 3.0)),
                keyframe(1, 4.0, at(0.1, 4.0), at(0.17, 9.0)),
            ],
            constraints: Vec::new(),
            epoch: 0,
        };
        let mut frames = vec![record(0, Some(0), 0, Pose::identity())];
        frames.extend((1..4).map(|i| record(i, None, 0, at(0.025 * i as f64, i as f64))));
        frames.push(record(4, Some(1), 1, Pose::identity()));
        frames.push(record(5, None, 1, at(0.01, 0.0)));
        (map, frames)
    }

    #[test]
    fn frames_between_keyframes_share_both_corrections_by_time() {
        let (map, before) = scene();
        let mut after = before.clone();
        assert_eq!(blend_frames(&map, &mut after), 3);
        let (a, b) = (&map.keyframes[0], &map.keyframes[1]);
        // Each keyframe's correction, applied to the frame's odometry pose.
        let correction_a = a.pose * a.odom_pose.inverse();
        let correction_b = b.pose * b.odom_pose.inverse();
        for i in 1..4 {
            let s = i as f64 / 4.0;
            let odometry = a.odom_pose * before[i].relative;
            let (from_a, from_b) = (correction_a * odometry, correction_b * odometry);
            let pose = a.pose * after[i].relative;
            let t = from_a.translation.vector * (1.0 - s) + from_b.translation.vector * s;
            assert!((pose.translation.vector - t).norm() < 1e-12, "frame {i}");
            let turn = from_a.rotation.angle_to(&from_b.rotation);
            assert!((from_a.rotation.angle_to(&pose.rotation) - s * turn).abs() < 1e-9);
            assert!((pose.rotation.angle_to(&from_b.rotation) - (1.0 - s) * turn).abs() < 1e-9);
        }
        // Keyframes keep their poses; the frame after the last keyframe has no successor.
        for i in [0, 4, 5] {
            assert_eq!(after[i].relative, before[i].relative, "frame {i}");
        }
    }

    #[test]
    fn frames_are_left_alone_where_the_odometry_breaks() {
        let (map, before) = scene();
        // Keyframe 1 was a restart after loss (the tracker marks it lost).
        let mut frames = before.clone();
        frames[4].status = FrameStatus::Lost;
        assert_eq!(blend_frames(&map, &mut frames), 0);
        let relatives = |f: &[FrameRecord]| f.iter().map(|r| r.relative).collect::<Vec<_>>();
        assert_eq!(relatives(&frames), relatives(&before));
        // Frame 2 was lost and frame 3 relocalised against keyframe 0 before keyframe 1 was
        // made: frames 1-3 keep their poses.
        let mut frames = before.clone();
        frames[2].status = FrameStatus::Lost;
        frames[3].status = FrameStatus::Relocalised;
        assert_eq!(blend_frames(&map, &mut frames), 0);
        // Frame 3 was tracked against an older keyframe than frame 4's predecessor: frame 3
        // and the frames before it keep their poses.
        let mut frames = before.clone();
        frames[3].reference = Some(1);
        assert_eq!(blend_frames(&map, &mut frames), 0);
        // The same break after frame 2 leaves frame 3 to be blended alone.
        let mut frames = before.clone();
        frames[2].status = FrameStatus::Relocalised;
        assert_eq!(blend_frames(&map, &mut frames), 1);
        assert_ne!(frames[3].relative, before[3].relative);
        assert_eq!(frames[1].relative, before[1].relative);
    }
}
