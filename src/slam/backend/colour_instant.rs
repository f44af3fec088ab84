//! Each frame's pose moved to its colour image's instant (RGB-D, `tracking.colour_instant`).
//!
//! A Kinect's colour and depth streams are not synchronised, and TUM RGB-D pairs each colour
//! image with the nearest depth image in time: on fr1_rpy the depth comes 3-11 ms after the
//! colour on about a third of the frames, while the camera turns at 1-3.5 rad/s. The
//! trajectory is stamped with the colour images' stamps, but most of what places a frame is
//! its depth: the dense refinement against the keyframe, the frame-to-frame steps
//! ([`super::frame_graph`]), the keyframes' depth edges. Measured on fr1_rpy 0-79 against the
//! ground truth interpolated at each instant, the frames' rotation from one to the next
//! agrees with the ground truth's between the depth stamps 14 % better than with that between
//! the colour stamps (lab/notes/slam-results.md, *Poses at the colour instant*).
//!
//! `move_to_colour_instants` therefore takes each frame's final pose as the depth's and
//! moves it along the trajectory to the colour's instant: between the frame and its previous
//! frame when the depth came after the colour (the usual case), towards the next frame when
//! it came before, at that step's velocity (`motion_over`: interpolation, never more than
//! the step). The neighbours' poses are read before any frame moves. Frames
//! without an offset (7-Scenes, registered offline with equal stamps; monocular runs), frames
//! without a tracked neighbour of the next or previous index, and frames whose offset is
//! longer than the step to that neighbour or whose neighbour's depth is not on the colour
//! instant's side keep their poses, to the bit. The map's keyframes do not move: only the
//! trajectory written for the frames does, keyframes' own frames included (each record's
//! relative pose, or its odometry pose without a reference keyframe).

use crate::geometry::{Pose, renormalized};
use crate::slam::frontend::tracking::{FrameRecord, FrameStatus};
use crate::slam::map::Map;
use nalgebra::{Translation3, UnitQuaternion};

/// Offsets shorter than this (seconds) are treated as none.
pub(crate) const MIN_OFFSET_S: f64 = 0.5e-3;

/// The camera's motion over `offset_s` seconds after an instant, at the velocity of `step`
/// (`T_prev⁻¹ T_now`, camera frame, taken over `step_s` seconds), to first order: the
/// step's rotation vector and translation scaled by `offset_s / step_s`. That is
/// `T_now⁻¹ T(now + offset)`, the depth camera's pose in the colour camera's frame when the
/// depth comes `offset_s` after the colour. `None` when the offset is shorter than
/// [`MIN_OFFSET_S`], longer than the step, or any input is not finite.
pub(crate) fn motion_over(step: &Pose, step_s: f64, offset_s: f64) -> Option<Pose> {
    if !(step_s.is_finite() && step_s > 1e-6 && offset_s.is_finite())
        || offset_s.abs() < MIN_OFFSET_S
        || offset_s.abs() > step_s
    {
        return None;
    }
    let s = offset_s / step_s;
    let rotation = step.rotation.scaled_axis() * s;
    let translation = step.translation.vector * s;
    (rotation
        .iter()
        .chain(translation.iter())
        .all(|v| v.is_finite()))
    .then(|| {
        Pose::from_parts(
            Translation3::from(translation),
            UnitQuaternion::from_scaled_axis(rotation),
        )
    })
}

/// Moves each frame's pose from its depth image's instant (`stamp + depth_offset(index)`) to
/// its colour image's (`stamp`) in place. Returns how many frames moved.
pub(crate) fn move_to_colour_instants(
    map: &Map,
    frames: &mut [FrameRecord],
    depth_offset: impl Fn(usize) -> f64,
) -> usize {
    let tracked = |r: &FrameRecord| r.status != FrameStatus::Lost;
    let offsets: Vec<f64> = frames.iter().map(|r| depth_offset(r.index)).collect();
    let poses: Vec<Pose> = frames.iter().map(|r| r.pose_in(map)).collect();
    let mut moved = 0;
    for i in 0..frames.len() {
        let offset = offsets[i];
        if !offset.is_finite() || offset.abs() < MIN_OFFSET_S || !tracked(&frames[i]) {
            continue;
        }
        // The neighbour on the colour instant's side: the previous frame when the depth came
        // after the colour, the next one when before.
        let j = if offset > 0.0 {
            i.checked_sub(1)
        } else {
            Some(i + 1).filter(|&j| j < frames.len())
        };
        let Some(j) =
            j.filter(|&j| tracked(&frames[j]) && frames[i].index.abs_diff(frames[j].index) == 1)
        else {
            continue;
        };
        let depth_stamp = |k: usize| frames[k].stamp + offsets[k];
        // `T_i⁻¹ T_j` over the time from i's depth to j's, followed for the offset's time
        // towards j. A neighbour whose depth is not on the colour instant's side (stamps out
        // of order) gives no positive duration, and the frame is left alone.
        let duration = (depth_stamp(j) - depth_stamp(i)) * -offset.signum();
        let step = poses[i].inverse() * poses[j];
        let Some(motion) = motion_over(&step, duration, offset.abs()) else {
            continue;
        };
        let r = &mut frames[i];
        match r.reference.filter(|&k| k < map.keyframes.len()) {
            Some(_) => r.relative = renormalized(&(r.relative * motion)),
            None => r.odom_pose = renormalized(&(r.odom_pose * motion)),
        }
        moved += 1;
    }
    moved
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::slam::fixtures::{keyframe, record};
    use nalgebra::Vector3;

    /// The camera at time `t`: it turns about y at 2 rad/s and moves along x at 0.3 m/s.
    fn truth_at(t: f64) -> Pose {
        Pose::from_parts(
            Translation3::new(0.3 * t, 0.0, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::y() * 2.0 * t),
        )
    }

    /// Frames every 1/30 s, keyframe 0 at the start, each record's pose where the camera was
    /// at `stamp + offset`.
    fn turning(offsets: &[f64]) -> (Map, Vec<FrameRecord>) {
        let map = Map {
            keyframes: vec![keyframe(0, 0.0, Pose::identity(), Pose::identity())],
            ..Map::default()
        };
        let frames = offsets
            .iter()
            .enumerate()
            .map(|(k, &o)| {
                let t = k as f64 / 30.0;
                let mut r = record(k, (k == 0).then_some(0), 0, truth_at(t + o));
                r.stamp = t;
                r
            })
            .collect();
        (map, frames)
    }

    #[test]
    fn late_depth_poses_move_back_to_the_colour_instant() {
        let offsets = [0.0, 0.010, 0.0, 0.011, 0.004, 0.0];
        let (map, mut frames) = turning(&offsets);
        let before = frames.clone();
        let moved = move_to_colour_instants(&map, &mut frames, |i| offsets[i]);
        assert_eq!(moved, 3);
        for (k, r) in frames.iter().enumerate() {
            let truth = truth_at(r.stamp);
            let error = (truth.inverse() * r.relative).rotation.angle().to_degrees();
            // Constant velocity: interpolation is exact to rounding.
            assert!(error < 1e-9, "frame {k}: {error} degrees");
            if offsets[k] == 0.0 {
                assert_eq!(r.relative, before[k].relative, "frame {k} moved");
            } else {
                let was = (truth.inverse() * before[k].relative)
                    .rotation
                    .angle()
                    .to_degrees();
                assert!(was > 0.2, "frame {k}: {was}");
            }
        }
    }

    #[test]
    fn early_depth_moves_towards_the_next_frame() {
        let offsets = [0.0, -0.008, 0.0];
        let (map, mut frames) = turning(&offsets);
        assert_eq!(
            move_to_colour_instants(&map, &mut frames, |i| offsets[i]),
            1
        );
        let error = (truth_at(frames[1].stamp).inverse() * frames[1].relative)
            .translation
            .vector
            .norm();
        assert!(error < 1e-9, "{error}");
    }

    #[test]
    fn frames_without_a_tracked_neighbour_or_offset_keep_their_poses() {
        // The first frame has no previous one; frame 2's previous frame was lost; frame 4's
        // previous record is frame 2 (frame 3 skipped).
        let offsets = [0.010, 0.0, 0.010, 0.0, 0.010];
        let (map, mut frames) = turning(&offsets);
        frames[1].status = FrameStatus::Lost;
        frames.remove(3);
        frames[3].index = 4;
        let before = frames.clone();
        assert_eq!(
            move_to_colour_instants(&map, &mut frames, |i| offsets[i]),
            0
        );
        assert_eq!(frames, before);
        // An offset longer than the step from the previous frame's depth (its depth came after
        // this frame's colour), a NaN offset, and a previous frame whose depth came after this
        // frame's (stamps out of order): nothing moves.
        for (o1, o0) in [(0.040, 0.035), (f64::NAN, 0.0), (0.010, 0.070)] {
            let offsets = [o0, o1];
            let (map, mut frames) = turning(&offsets.map(|o| if o.is_nan() { 0.0 } else { o }));
            let before = frames.clone();
            let moved = move_to_colour_instants(&map, &mut frames, |i| offsets[i]);
            assert_eq!(moved, 0, "offsets {offsets:?}");
            assert_eq!(frames, before, "offsets {offsets:?}");
        }
        // No offsets at all (7-Scenes): nothing moves.
        let (map, mut frames) = turning(&[0.0; 4]);
        let before = frames.clone();
        assert_eq!(move_to_colour_instants(&map, &mut frames, |_| 0.0), 0);
        assert_eq!(frames, before);
    }

    #[test]
    fn motion_over_scales_the_step_and_refuses_what_it_cannot_extrapolate() {
        let step = Pose::from_parts(
            Translation3::new(0.03, 0.0, 0.0),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.06, 0.0)),
        );
        let m = motion_over(&step, 1.0 / 30.0, 0.01).unwrap();
        assert!((m.translation.vector.x - 0.009).abs() < 1e-12);
        assert!((m.rotation.scaled_axis().y - 0.018).abs() < 1e-12);
        let back = motion_over(&step, 1.0 / 30.0, -0.01).unwrap();
        assert!((back * m).rotation.angle() < 1e-12);
        assert!((back.translation.vector + m.translation.vector).norm() < 1e-12);
        assert!(motion_over(&step, 1.0 / 30.0, 0.0001).is_none());
        assert!(motion_over(&step, 1.0 / 30.0, 0.05).is_none());
        assert!(motion_over(&step, 0.0, 0.01).is_none());
        assert!(motion_over(&step, f64::NAN, 0.01).is_none());
        assert!(motion_over(&step, 1.0 / 30.0, f64::INFINITY).is_none());
    }
}
