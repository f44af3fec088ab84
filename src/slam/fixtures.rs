//! Small map pieces the unit tests of several modules build on.

use super::frontend::tracking::{FrameRecord, FrameStatus};
use super::map::KeyFrame;
use crate::dataset::DepthImage;
use crate::geometry::Pose;
use nalgebra::{Translation3, UnitQuaternion, Vector3};

/// A pose `x` metres along x (and a hundredth of that along y), turned `yaw_deg` about y.
pub fn at(x: f64, yaw_deg: f64) -> Pose {
    Pose::from_parts(
        Translation3::new(x, 0.01 * x, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw_deg.to_radians()),
    )
}

/// Keyframe `id` at `stamp`: tracked at `odom_pose`, corrected to `pose`.
pub fn keyframe(id: usize, stamp: f64, odom_pose: Pose, pose: Pose) -> KeyFrame {
    KeyFrame {
        stamp,
        pose,
        ..super::backend::keyframe_alignment::tests::keyframe(id, &DepthImage::new(1, 1), odom_pose)
    }
}

/// A tracked frame `index` (stamped `index` seconds) against keyframe `reference`.
pub fn record(
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
