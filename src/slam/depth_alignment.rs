//! Depth beyond the keypoints (RGB-D mode): a tracked frame's pose refined against its
//! reference keyframe's whole depth image by projective point-to-plane ICP, KinectFusion's
//! association (a frame point is paired with the keyframe point its projection lands on),
//! coarse to fine, with Huber weights. Pixels go through the camera's distortion model both
//! ways, as everywhere else in the system. Tracking keeps the refined pose only when it agrees
//! with the pose from the keypoints (`[dense]` in `configs/slam/default.toml`).

use super::config::DenseConfig;
use super::map::ViewBounds;
use super::pose_graph::se3_exp;
use crate::camera::{Camera, RayTable};
use crate::dataset::DepthImage;
use crate::geometry::{Pose, renormalized};
use nalgebra::{Matrix6, Point3, Vector3, Vector6};
use rayon::prelude::*;
use std::sync::Arc;

/// Whether `depth` has the size of `rays`' images (sampled at stride 1).
fn fits(rays: &RayTable, depth: &DepthImage) -> bool {
    rays.stride == 1 && (depth.width, depth.height) == (rays.width, rays.height)
}

/// A keyframe's depth as points and normals on a grid of every `step`-th pixel, in the
/// keyframe's camera frame.
pub struct DepthModel {
    step: usize,
    width: usize,
    height: usize,
    /// `None` where the depth is missing, out of range, or has no normal.
    points: Vec<Option<(Vector3<f64>, Vector3<f64>)>>,
    camera: Camera,
    /// Where projecting is reliable (the distortion polynomial folds back beyond).
    bounds: ViewBounds,
    rays: Arc<RayTable>,
}

impl DepthModel {
    /// The points of `depth` every `step` pixels within `range` metres, with normals from
    /// the neighbouring grid points (none across a depth jump of more than 5 % of the depth);
    /// `None` when `depth` is not the size of `rays`' images (a table of `camera` at stride 1).
    pub fn new(
        depth: &DepthImage,
        camera: &Camera,
        rays: Arc<RayTable>,
        step: usize,
        range: (f64, f64),
    ) -> Option<Self> {
        if !fits(&rays, depth) {
            return None;
        }
        let step = step.max(1);
        let (width, height) = (depth.width as usize / step, depth.height as usize / step);
        let vertex = |gx: usize, gy: usize| {
            let (u, v) = (gx * step, gy * step);
            let z = f64::from(depth.data[v * depth.width as usize + u]);
            (z > range.0 && z < range.1).then(|| rays.point(u, v, z).coords)
        };
        let vertices: Vec<Option<Vector3<f64>>> = (0..height)
            .flat_map(|gy| (0..width).map(move |gx| (gx, gy)))
            .map(|(gx, gy)| vertex(gx, gy))
            .collect();
        let at = |gx: usize, gy: usize| vertices[gy * width + gx];
        let mut points = vec![None; width * height];
        for gy in 1..height.saturating_sub(1) {
            for gx in 1..width.saturating_sub(1) {
                let (Some(p), Some(l), Some(r), Some(u), Some(d)) = (
                    at(gx, gy),
                    at(gx - 1, gy),
                    at(gx + 1, gy),
                    at(gx, gy - 1),
                    at(gx, gy + 1),
                ) else {
                    continue;
                };
                let jump = 0.05 * p.z;
                if [l, r, u, d].iter().any(|q| (q.z - p.z).abs() > jump) {
                    continue;
                }
                let n = (r - l).cross(&(d - u));
                let Some(mut n) = n.try_normalize(1e-12) else {
                    continue;
                };
                if n.dot(&p) > 0.0 {
                    n = -n;
                }
                points[gy * width + gx] = Some((p, n));
            }
        }
        Some(DepthModel {
            step,
            width,
            height,
            points,
            camera: camera.clone(),
            bounds: ViewBounds::new(camera),
            rays,
        })
    }

    /// The model point and normal where `p` (keyframe camera frame) projects.
    fn lookup(&self, p: &Vector3<f64>) -> Option<&(Vector3<f64>, Vector3<f64>)> {
        let p = Point3::from(*p);
        if !self.bounds.contains(&p) {
            return None;
        }
        let px = self.camera.project(&p)?;
        let (gx, gy) = (
            (px.x / self.step as f64).round(),
            (px.y / self.step as f64).round(),
        );
        if gx < 0.0 || gy < 0.0 || gx >= self.width as f64 || gy >= self.height as f64 {
            return None;
        }
        self.points[gy as usize * self.width + gx as usize].as_ref()
    }
}

/// The outcome of [`align`].
#[derive(Debug, Clone, PartialEq)]
pub struct Alignment {
    /// The refined pose of the frame in the keyframe's camera frame (`T_kf_frame`).
    pub pose: Pose,
    /// Frame points paired within the last level's distance gate, at the pose of the last
    /// Gauss-Newton step (the returned pose is that step's result).
    pub inliers: usize,
    /// Frame points with a valid depth at the last level.
    pub points: usize,
    /// Root mean square of those pairs' point-to-plane distances, metres.
    pub rms: f64,
}

/// Refines `initial` (`T_kf_frame`) by point-to-plane ICP of the frame's depth against
/// `model`, one level per entry of `cfg.levels` (frame pixels sampled every `step`, pairs
/// farther apart than `max_distance` dropped). `None` when `depth` is not the camera's size,
/// too few pairs remain, or the system is degenerate (a single plane leaves directions
/// unconstrained; a near-degenerate one, a wall with a little clutter, is not caught here,
/// and the caller's agreement with the keypoint pose bounds what it can do).
pub fn align(
    model: &DepthModel,
    depth: &DepthImage,
    initial: &Pose,
    range: (f64, f64),
    cfg: &DenseConfig,
) -> Option<Alignment> {
    let rays = &model.rays;
    if !fits(rays, depth) {
        return None;
    }
    let mut pose = *initial;
    let mut last = None;
    for level in &cfg.levels {
        let step = level.step.max(1);
        let source: Vec<Vector3<f64>> = (0..depth.height as usize)
            .step_by(step)
            .flat_map(|v| (0..depth.width as usize).step_by(step).map(move |u| (u, v)))
            .filter_map(|(u, v)| {
                let z = f64::from(depth.data[v * depth.width as usize + u]);
                (z > range.0 && z < range.1).then(|| rays.point(u, v, z).coords)
            })
            .collect();
        for _ in 0..cfg.iterations {
            let (h, g, inliers, sq) =
                normal_equations(model, &source, &pose, level.max_distance, cfg.huber);
            if inliers < cfg.min_pairs {
                return None;
            }
            // A plane or a corridor leaves a direction unconstrained: refuse rather than drift.
            let eig = h.symmetric_eigenvalues();
            if eig.min() < 1e-6 * eig.max().max(1e-12) {
                return None;
            }
            let delta = h.cholesky()?.solve(&(-g));
            pose = renormalized(&(se3_exp(&delta) * pose));
            last = Some((inliers, source.len(), sq));
            if delta.norm() < 1e-5 {
                break;
            }
        }
    }
    let (inliers, points, sq) = last?;
    Some(Alignment {
        pose,
        inliers,
        points,
        rms: (sq / inliers.max(1) as f64).sqrt(),
    })
}

/// `JᵀWJ`, `JᵀWr`, the pair count and the sum of squared distances of one Gauss-Newton step
/// for a left perturbation `δ = (v, ω)` of `pose`: `r = n·(p − q)`, `∂r/∂δ = (n, p × n)`.
/// Chunks of points are summed in parallel and their sums added in order, so the result does
/// not depend on the thread count.
fn normal_equations(
    model: &DepthModel,
    source: &[Vector3<f64>],
    pose: &Pose,
    max_distance: f64,
    huber: f64,
) -> (Matrix6<f64>, Vector6<f64>, usize, f64) {
    let chunk = |points: &[Vector3<f64>]| {
        let mut h = Matrix6::zeros();
        let mut g = Vector6::zeros();
        let (mut n_pairs, mut sq) = (0usize, 0.0);
        for s in points {
            let p = (pose * Point3::from(*s)).coords;
            let Some((q, n)) = model.lookup(&p) else {
                continue;
            };
            if (p - q).norm() > max_distance {
                continue;
            }
            let r = n.dot(&(p - q));
            let w = if r.abs() <= huber {
                1.0
            } else {
                huber / r.abs()
            };
            let pn = p.cross(n);
            let j = Vector6::new(n.x, n.y, n.z, pn.x, pn.y, pn.z);
            h += w * j * j.transpose();
            g += w * r * j;
            n_pairs += 1;
            sq += r * r;
        }
        (h, g, n_pairs, sq)
    };
    let parts: Vec<_> = source.par_chunks(4096).map(chunk).collect();
    parts.into_iter().fold(
        (Matrix6::zeros(), Vector6::zeros(), 0, 0.0),
        |(h, g, n, sq), (h2, g2, n2, sq2)| (h + h2, g + g2, n + n2, sq + sq2),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::slam::config::DenseConfig;
    use nalgebra::{Point2, Translation3, UnitQuaternion};

    /// Depth of a box room seen from `pose` (world from camera): floor, walls, and a block,
    /// so that every direction is constrained.
    fn render(camera: &Camera, pose: &Pose) -> DepthImage {
        let (w, h) = (camera.width, camera.height);
        let mut depth = DepthImage::new(w, h);
        // Planes n·x = d in the world frame.
        let planes = [
            (Vector3::new(0.0, 0.0, -1.0), -3.0), // back wall z = 3
            (Vector3::new(0.0, -1.0, 0.0), -1.0), // floor y = 1
            (Vector3::new(1.0, 0.0, 0.0), -1.5),  // left wall x = -1.5
            (Vector3::new(-1.0, 0.0, 0.0), -1.2), // right wall x = 1.2
        ];
        let origin = pose.translation.vector;
        for v in 0..h {
            for u in 0..w {
                let n = camera.normalized(&Point2::new(u as f64, v as f64));
                let ray_cam = Vector3::new(n.x, n.y, 1.0);
                let ray = pose.rotation * ray_cam;
                let mut best = f64::INFINITY;
                for (n, d) in &planes {
                    let den = n.dot(&ray);
                    if den.abs() > 1e-9 {
                        let t = (d - n.dot(&origin)) / den;
                        if t > 0.0 && t < best {
                            best = t;
                        }
                    }
                }
                // A block in front of the back wall: z = 2.2 for |x| < 0.4, y in [0.2, 1].
                let t = (2.2 - origin.z) / ray.z;
                let hit = origin + t * ray;
                if t > 0.0 && t < best && hit.x.abs() < 0.4 && hit.y > 0.2 && hit.y < 1.0 {
                    best = t;
                }
                if best.is_finite() {
                    // Depth is the z of the hit in the camera frame: t · ray_cam.z = t.
                    depth.data[(v * w + u) as usize] = best as f32;
                }
            }
        }
        depth
    }

    #[test]
    fn recovers_a_small_motion_from_a_perturbed_start() {
        let camera = Camera::tum_fr1().resized(160, 120);
        let kf_pose = Pose::identity();
        let frame_pose = Pose::from_parts(
            Translation3::new(0.03, -0.02, 0.05),
            UnitQuaternion::from_euler_angles(0.02, -0.03, 0.01),
        );
        let kf_depth = render(&camera, &kf_pose);
        let frame_depth = render(&camera, &frame_pose);
        let range = (0.1, 6.0);
        // A 160x120 image has 300 points at the coarsest level.
        let cfg = DenseConfig {
            min_pairs: 100,
            ..DenseConfig::default()
        };
        let rays = Arc::new(RayTable::new(&camera, 1));
        let model = DepthModel::new(&kf_depth, &camera, rays, 1, range).unwrap();
        let truth = kf_pose.inverse() * frame_pose;
        let start = Pose::from_parts(
            Translation3::new(0.01, -0.01, 0.03),
            UnitQuaternion::from_euler_angles(0.01, -0.015, 0.0),
        );
        let a = align(&model, &frame_depth, &start, range, &cfg).expect("aligned");
        let err = truth.inverse() * a.pose;
        assert!(
            err.translation.vector.norm() < 2e-3 && err.rotation.angle() < 1e-3,
            "error {:?} after {} pairs",
            err,
            a.inliers
        );
        assert!(a.inliers > a.points / 2, "{} of {}", a.inliers, a.points);
    }

    #[test]
    fn a_single_plane_is_refused() {
        let camera = Camera::tum_fr1().resized(160, 120);
        let mut depth = DepthImage::new(camera.width, camera.height);
        depth.data.fill(2.0);
        let range = (0.1, 6.0);
        let model = DepthModel::new(
            &depth,
            &camera,
            Arc::new(RayTable::new(&camera, 1)),
            1,
            range,
        )
        .expect("the camera's size");
        let cfg = DenseConfig {
            min_pairs: 100,
            ..DenseConfig::default()
        };
        // Enough pairs (every frame point lands on the plane), but sliding along the plane
        // and turning about its normal are unconstrained.
        let a = align(&model, &depth, &Pose::identity(), range, &cfg);
        assert!(a.is_none(), "{a:?}");
        // A depth image of another size than the camera's: no model, no alignment.
        let small = DepthImage::new(80, 60);
        let rays = Arc::new(RayTable::new(&camera, 1));
        assert!(DepthModel::new(&small, &camera, rays, 1, range).is_none());
        assert!(align(&model, &small, &Pose::identity(), range, &cfg).is_none());
    }
}
