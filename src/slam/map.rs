//! The shared map (Fig. 1): keyframes with their features, depth, labels and
//! colours, and the constraints between keyframe pairs found by data
//! correction. Tracking creates keyframes, mapping fills in their semantics and
//! inserts them, correction adds constraints and corrects their poses; the
//! threads share it as [`SharedMap`].

use super::config::TrackingConfig;
use super::frontend::keypoints::KeyFeatures;
use crate::camera::Camera;
use crate::dataset::{DepthImage, LabelImage};
use crate::geometry::{Pose, renormalized};
use image::RgbImage;
use nalgebra::{Point2, Point3};
use serde::{Deserialize, Serialize};
use std::sync::{Arc, RwLock, RwLockReadGuard, RwLockWriteGuard};

/// What tracking, relocalisation and correction need of a keyframe: its
/// keypoints, their 3D points in the keyframe's camera (eqs 9-10, from sensor
/// or predicted depth) and its global descriptor signature.
#[derive(Debug, Clone, Default)]
pub struct KeyframeFeatures {
    /// The keyframe's keypoints and descriptors.
    pub features: KeyFeatures,
    /// Camera coordinates of each keypoint, `None` without a usable depth.
    pub points_cam: Vec<Option<Point3<f64>>>,
    /// Normalised mean descriptor.
    pub signature: Vec<f32>,
}

impl KeyframeFeatures {
    /// Features with 3D points from a depth image, where `gate` takes the reading.
    pub fn new(
        features: KeyFeatures,
        depth: Option<&DepthImage>,
        camera: &Camera,
        gate: KeypointDepth,
    ) -> Self {
        let points_cam = points_from_depth(&features, depth, camera, gate);
        let signature = features.mean_descriptor();
        KeyframeFeatures {
            features,
            points_cam,
            signature,
        }
    }

    /// Number of keypoints with a 3D point.
    pub fn n_points(&self) -> usize {
        self.points_cam.iter().filter(|p| p.is_some()).count()
    }
}

/// Which depth readings give a keypoint its 3D point (eqs 9-10).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KeypointDepth {
    /// Readings outside `[min, max]` metres give none.
    pub range: (f64, f64),
}

impl KeypointDepth {
    /// `tracking.min_depth` and `max_depth`.
    pub fn from_config(t: &TrackingConfig) -> Self {
        KeypointDepth {
            range: (t.min_depth, t.max_depth),
        }
    }

    /// The reading at the pixel nearest to `(x, y)`, when the gate takes it.
    pub fn at(&self, depth: &DepthImage, x: f64, y: f64) -> Option<f32> {
        let d = depth.at(x, y)?;
        let (min, max) = self.range;
        ((d as f64) >= min && (d as f64) <= max).then_some(d)
    }
}

/// Back-projects each keypoint with the reading at its nearest pixel where `gate` takes it
/// (eq 9 inverted).
pub fn points_from_depth(
    features: &KeyFeatures,
    depth: Option<&DepthImage>,
    camera: &Camera,
    gate: KeypointDepth,
) -> Vec<Option<Point3<f64>>> {
    features
        .points
        .iter()
        .map(|p| {
            let (x, y) = (p[0] as f64, p[1] as f64);
            let d = gate.at(depth?, x, y)? as f64;
            Some(camera.back_project(&Point2::new(x, y), d))
        })
        .collect()
}

/// The normalised image coordinates `(X/Z, Y/Z)` that project inside the image:
/// an inner box of the undistorted border. Projecting a point outside it is
/// unreliable with strong radial distortion (the polynomial folds back).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ViewBounds {
    /// Open range `(min, max)` of `X/Z`.
    pub x: (f64, f64),
    /// Open range `(min, max)` of `Y/Z`.
    pub y: (f64, f64),
}

impl ViewBounds {
    /// The bounds of `camera`, sampled along the image border.
    pub fn new(camera: &Camera) -> Self {
        let (w, h) = (camera.width as f64 - 1.0, camera.height as f64 - 1.0);
        let n = |x: f64, y: f64| camera.normalized(&Point2::new(x, y));
        let (mut b, steps) = (
            ViewBounds {
                x: (f64::NEG_INFINITY, f64::INFINITY),
                y: (f64::NEG_INFINITY, f64::INFINITY),
            },
            32,
        );
        for k in 0..=steps {
            let f = k as f64 / steps as f64;
            b.x.0 = b.x.0.max(n(0.0, f * h).x);
            b.x.1 = b.x.1.min(n(w, f * h).x);
            b.y.0 = b.y.0.max(n(f * w, 0.0).y);
            b.y.1 = b.y.1.min(n(f * w, h).y);
        }
        b
    }

    /// Whether a camera-frame point is in front of the camera and inside the bounds.
    pub fn contains(&self, p: &Point3<f64>) -> bool {
        if p.z <= 1e-6 {
            return false;
        }
        self.contains_normalized(p.x / p.z, p.y / p.z)
    }

    /// Whether normalised image coordinates `(x/z, y/z)` are inside the bounds.
    #[inline]
    pub fn contains_normalized(&self, x: f64, y: f64) -> bool {
        x > self.x.0 && x < self.x.1 && y > self.y.0 && y < self.y.1
    }
}

/// A keyframe's images at the fusion resolution (every `stride`-th pixel).
#[derive(Debug, Clone)]
pub struct KeyframeView {
    /// Subsampling step, full-resolution pixels per view pixel.
    pub stride: u32,
    /// Colour image at the view resolution.
    pub rgb: RgbImage,
    /// Depth (sensor or predicted) at the view resolution, metres; 0 = no reading.
    pub depth: DepthImage,
    /// Semantic labels at the view resolution.
    pub labels: LabelImage,
    /// The depth as the sensor gave it, sampled as `depth`, before the map's depth-edge
    /// filter: what the keyframe alignments read when `dense.edges_on_filtered_depth` is
    /// off (`None` otherwise).
    pub unfiltered_depth: Option<DepthImage>,
}

impl KeyframeView {
    /// Subsamples full-resolution images (nearest pixel: labels are not blended).
    pub fn new(stride: u32, rgb: &RgbImage, depth: &DepthImage, labels: &LabelImage) -> Self {
        let (w, h) = rgb.dimensions();
        let (sw, sh) = (w.div_ceil(stride), h.div_ceil(stride));
        let small_rgb = RgbImage::from_fn(sw, sh, |x, y| *rgb.get_pixel(x * stride, y * stride));
        let mut small_depth = DepthImage::new(sw, sh);
        let mut small_labels = LabelImage::new(sw, sh, crate::dataset::labels::VOID);
        for y in 0..sh {
            for x in 0..sw {
                let (fx, fy) = (x * stride, y * stride);
                let i = (y * sw + x) as usize;
                if fx < depth.width && fy < depth.height {
                    small_depth.data[i] = depth.data[(fy * depth.width + fx) as usize];
                }
                if fx < labels.width && fy < labels.height {
                    small_labels.data[i] = labels.get(fx, fy);
                }
            }
        }
        KeyframeView {
            stride,
            rgb: small_rgb,
            depth: small_depth,
            labels: small_labels,
            unfiltered_depth: None,
        }
    }
}

/// A keyframe of the map.
#[derive(Debug, Clone)]
pub struct KeyFrame {
    /// Index of this keyframe in [`Map::keyframes`] (creation order).
    pub id: usize,
    /// Index of its frame in the sequence.
    pub frame_index: usize,
    /// Time stamp of its frame, seconds.
    pub stamp: f64,
    /// The pose tracking gave it (camera-to-world), never changed.
    pub odom_pose: Pose,
    /// The current estimate, corrected by the pose graph.
    pub pose: Pose,
    /// Ground-truth pose (camera-to-world) at its stamp, when known.
    pub gt_pose: Option<Pose>,
    /// Keypoints, their 3D points and signature.
    pub track: Arc<KeyframeFeatures>,
    /// RGB, depth (sensor or predicted) and labels at the fusion resolution.
    pub view: KeyframeView,
    /// Depth rescaling found by local correction, times any scale the anchor applied to the
    /// run (1: none).
    pub depth_scale: f64,
}

impl KeyFrame {
    /// A tracked (odometry) pose moved by this keyframe's correction:
    /// `T T̂⁻¹ T̂_other` (hat: tracked), the pose a later keyframe takes until it is
    /// corrected itself.
    pub fn carry(&self, odom_pose: &Pose) -> Pose {
        renormalized(&(self.pose * self.odom_pose.inverse() * odom_pose))
    }
}

/// Why two keyframes are linked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ConstraintKind {
    /// Consecutive keyframes, relative pose from tracking.
    Odometry,
    /// A random earlier keyframe (the paper's global optimisation).
    Random,
    /// An earlier keyframe whose camera was close by.
    Proximity,
    /// An earlier keyframe whose descriptors look alike.
    Similarity,
}

/// A relative-pose constraint `T_a⁻¹ T_b` between keyframes `a < b`.
#[derive(Debug, Clone)]
pub struct Constraint {
    /// Id of the earlier keyframe.
    pub a: usize,
    /// Id of the later keyframe.
    pub b: usize,
    /// Relative pose `T_a⁻¹ T_b`.
    pub relative: Pose,
    /// How the constraint was found.
    pub kind: ConstraintKind,
    /// PnP inliers that verified it (0 for an unverified odometry edge).
    pub inliers: usize,
    /// Inlier keypoint pairs `(keypoint of a, keypoint of b)` (local correction).
    pub matches: Vec<(u32, u32)>,
}

/// Keyframes and constraints.
#[derive(Debug, Clone, Default)]
pub struct Map {
    /// Keyframes in creation order (index = id).
    pub keyframes: Vec<KeyFrame>,
    /// Relative-pose constraints between keyframe pairs.
    pub constraints: Vec<Constraint>,
    /// Incremented every time the poses are corrected.
    pub epoch: u64,
}

impl Map {
    /// Camera centres of the keyframes (current estimates).
    pub fn centres(&self) -> Vec<Point3<f64>> {
        self.keyframes
            .iter()
            .map(|k| Point3::from(k.pose.translation.vector))
            .collect()
    }

    /// Number of constraints that are not odometry.
    pub fn loop_constraints(&self) -> usize {
        self.constraints
            .iter()
            .filter(|c| c.kind != ConstraintKind::Odometry)
            .count()
    }
}

/// The map shared by the threads.
pub type SharedMap = Arc<RwLock<Map>>;

/// Reads the shared map (a panic in another thread does not make it unreadable).
pub fn read(map: &SharedMap) -> RwLockReadGuard<'_, Map> {
    map.read().unwrap_or_else(|e| e.into_inner())
}

/// Writes the shared map.
pub fn write(map: &SharedMap) -> RwLockWriteGuard<'_, Map> {
    map.write().unwrap_or_else(|e| e.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keypoints_take_the_readings_within_the_depth_range() {
        let camera = Camera::pinhole(640, 480, 525.0, 525.0, 319.5, 239.5);
        let (w, h) = (camera.width, camera.height);
        // A box side at 1.2 m left of column 320, the wall at 2.4 m right of it.
        let mut depth = DepthImage::new(w, h);
        for (i, d) in depth.data.iter_mut().enumerate() {
            *d = if (i as u32 % w) < 320 { 1.2 } else { 2.4 };
        }
        let features = KeyFeatures {
            points: vec![[100.0, 200.0], [500.0, 100.0]],
            descriptors: vec![0.0; 2],
            dim: 1,
        };
        let mut gate = KeypointDepth::from_config(&TrackingConfig::default());
        let all = points_from_depth(&features, Some(&depth), &camera, gate);
        assert!(all.iter().all(|p| p.is_some()));
        let p = all[0].unwrap();
        assert!((p.z - 1.2).abs() < 1e-6, "{p:?}");
        gate.range = (0.1, 2.0);
        let near = points_from_depth(&features, Some(&depth), &camera, gate);
        assert!(near[0].is_some() && near[1].is_none());
        assert!(
            points_from_depth(&features, None, &camera, gate)
                .iter()
                .all(|p| p.is_none())
        );
    }
}
