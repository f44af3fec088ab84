//! Camera pose from 3D-2D correspondences, the paper's eqs 9-10 (section IV-B):
//! 3D points of a reference frame (back-projected with its depth) and their
//! matched pixels in the current image give the rigid motion from the reference
//! camera to the current one.
//!
//! * minimal solver: Lambda Twist P3P (Persson & Nordberg, "Lambda Twist: An
//!   Accurate Fast Robust Perspective Three Point (P3P) Solver", ECCV 2018),
//!   written from the paper, following the corrections to it noted in PoseLib's
//!   implementation (Viktor Larsson, BSD-3-Clause): the sign of the eigenvalue
//!   polynomial, the order of the cubic's coefficients, and solving for whichever
//!   of lambda 1 or 2 is better conditioned;
//! * RANSAC on the reprojection error in pixels, adaptive iteration count, seeded;
//! * Levenberg-Marquardt refinement of all inliers (eq 4), twice, re-selecting
//!   inliers in between.
//!
//! Pixels are undistorted once to normalised coordinates (`Camera::normalized`);
//! reprojection errors are measured there and scaled by `fx, fy`, i.e. in pixels of
//! the ideal pinhole camera.
//!
//! With camera-to-world poses `T_ref`, `T_cur`, the result is `T_cur⁻¹ T_ref`; the
//! paper's eq 10, `pose = −R⁻¹ t`, is the current camera's centre in reference
//! coordinates, `result.pose.inverse().translation`.

mod p3p;
mod ransac;
mod refine;

pub use p3p::p3p;
pub use ransac::solve_pnp_ransac;
pub use refine::refine_pose;

use nalgebra::{Isometry3, Point3, Vector2};
use serde::{Deserialize, Serialize};

/// PnP-RANSAC settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PnpConfig {
    /// Inlier threshold on the reprojection error, pixels.
    pub threshold_px: f64,
    /// Stop when the probability of having drawn an all-inlier sample reaches this.
    pub confidence: f64,
    /// Upper bound on RANSAC iterations (0: only the prior is tried).
    pub max_iterations: usize,
    /// Fewer inliers than this is a failure.
    pub min_inliers: usize,
    /// Levenberg-Marquardt iterations per refinement.
    pub refine_iterations: usize,
    /// Seed of the sampling RNG (results are deterministic for a seed).
    pub seed: u64,
}

impl Default for PnpConfig {
    fn default() -> Self {
        PnpConfig {
            threshold_px: 3.0,
            confidence: 0.99,
            max_iterations: 1000,
            min_inliers: 6,
            refine_iterations: 20,
            seed: 0,
        }
    }
}

/// The estimated motion and its support.
#[derive(Debug, Clone, PartialEq)]
pub struct PnpResult {
    /// Reference camera → current camera: `x_cur = pose * x_ref`.
    pub pose: Isometry3<f64>,
    /// Which correspondences agree with `pose` within the threshold.
    pub inliers: Vec<bool>,
    /// Number of inliers (`true` entries of `inliers`).
    pub n_inliers: usize,
    /// RMS reprojection error over the inliers, pixels.
    pub rms_px: f64,
    /// RANSAC iterations run.
    pub iterations: usize,
}

/// Squared reprojection error in pixels of point `p` against normalised observation
/// `n` (infinite behind the camera).
#[inline]
fn squared_error(pose: &Isometry3<f64>, p: &Point3<f64>, n: &Vector2<f64>, f: (f64, f64)) -> f64 {
    let q = pose * p;
    if q.z <= 1e-9 {
        return f64::INFINITY;
    }
    let ex = f.0 * (q.x / q.z - n.x);
    let ey = f.1 * (q.y / q.z - n.y);
    ex * ex + ey * ey
}

/// Helpers shared by the unit tests of the submodules.
#[cfg(test)]
mod test_util {
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
    use rand::RngExt;
    use rand_chacha::ChaCha8Rng;

    pub(super) fn random_pose(rng: &mut ChaCha8Rng, angle: f64, shift: f64) -> Isometry3<f64> {
        let axis = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        )
        .normalize();
        let t = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        ) * shift;
        Isometry3::from_parts(
            Translation3::from(t),
            UnitQuaternion::from_scaled_axis(axis * angle),
        )
    }

    pub(super) fn errors(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
        let d = a.inverse() * b;
        (
            d.rotation.angle().to_degrees(),
            (a.translation.vector - b.translation.vector).norm(),
        )
    }
}
