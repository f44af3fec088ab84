//! Monocular tracking's rotation from the matches' bearings alone (two-view epipolar
//! geometry), then its translation fitted to the keyframe's points with that rotation held.
//!
//! PnP against the reference keyframe's 3D points takes its rotation from points whose depths
//! SDFCNN predicted. Where the prediction is pressed towards its middle (near points too far),
//! PnP explains part of a turn as a shift, so monocular tracking turns too little and moves too
//! far; with the ground truth's rotation (an oracle) tracking alone is metric on held-back
//! frames (lab/notes/slam-results.md, *Where the monocular trajectory's scale comes from*). The
//! epipolar constraint `b₂ · (t × R b₁) = 0` between a keypoint's bearing in the keyframe and
//! in the frame does not read depth, so it gives the rotation without that bias; the depth
//! then sets only the translation's length.

use crate::camera::Camera;
use crate::geometry::{Pose, orthonormal_basis};
use nalgebra::{
    Matrix3, Matrix5, Point2, Point3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3,
    Vector5,
};

/// Settings of the epipolar refinement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpipolarParams {
    /// Scale of the Cauchy weight on a bearing's angle to its epipolar plane, radians.
    pub scale: f64,
    /// Gauss-Newton iterations at most.
    pub iterations: usize,
    /// Fewest bearing pairs to refine on.
    pub min_pairs: usize,
}

impl Default for EpipolarParams {
    fn default() -> Self {
        EpipolarParams {
            scale: 0.003,
            iterations: 15,
            min_pairs: 20,
        }
    }
}

/// Unit bearing of a (distorted) pixel in the camera's frame.
pub fn bearing(camera: &Camera, px: &Point2<f64>) -> Vector3<f64> {
    let n = camera.normalized(px);
    Vector3::new(n.x, n.y, 1.0).normalize()
}

/// Sine of the angle between bearing `b2` and the epipolar plane of `b1` under the relative
/// motion `x₂ = R x₁ + t` (`t` a unit direction); `None` when `b1` looks along `t`.
fn plane_error(
    rotation: &Rotation3<f64>,
    t: &Vector3<f64>,
    b1: &Vector3<f64>,
    b2: &Vector3<f64>,
) -> Option<f64> {
    let n = t.cross(&(rotation * b1));
    let norm = n.norm();
    (norm > 1e-9).then(|| b2.dot(&n) / norm)
}

/// The rotation and translation direction after a step `d` (rotation vector, then two
/// tangent components of the direction).
fn stepped(
    rotation: &Rotation3<f64>,
    t: &Vector3<f64>,
    d: &Vector5<f64>,
) -> (Rotation3<f64>, Vector3<f64>) {
    let (u, v) = orthonormal_basis(t);
    let r = Rotation3::new(Vector3::new(d[0], d[1], d[2])) * rotation;
    let t = (t + u * d[3] + v * d[4]).normalize();
    (r, t)
}

/// Refines the relative rotation `R` and translation direction of `x₂ = R x₁ + t` from
/// bearing pairs `(b₁, b₂)` by Cauchy-weighted Gauss-Newton on each pair's angle to its
/// epipolar plane, starting from `rotation` and `translation` (whose length is ignored).
/// `None` with fewer than `min_pairs` usable pairs, a translation too short to give a
/// direction, or a system that does not solve.
pub fn refine_relative_rotation(
    pairs: &[(Vector3<f64>, Vector3<f64>)],
    rotation: &Rotation3<f64>,
    translation: &Vector3<f64>,
    params: &EpipolarParams,
) -> Option<(Rotation3<f64>, Unit<Vector3<f64>>)> {
    let len = translation.norm();
    if pairs.len() < params.min_pairs.max(5) || !len.is_finite() || len <= 1e-9 {
        return None;
    }
    let mut r = *rotation;
    let mut t = translation / len;
    let h = 1e-6;
    for _ in 0..params.iterations.max(1) {
        let mut jtj = Matrix5::<f64>::zeros();
        let mut jtr = Vector5::<f64>::zeros();
        let mut used = 0;
        for (b1, b2) in pairs {
            let Some(e) = plane_error(&r, &t, b1, b2).filter(|e| e.is_finite()) else {
                continue;
            };
            let mut j = Vector5::zeros();
            let mut ok = true;
            for k in 0..5 {
                let mut d = Vector5::zeros();
                d[k] = h;
                let (rk, tk) = stepped(&r, &t, &d);
                match plane_error(&rk, &tk, b1, b2).filter(|e| e.is_finite()) {
                    Some(ek) => j[k] = (ek - e) / h,
                    None => ok = false,
                }
            }
            if !ok {
                continue;
            }
            // Cauchy's weight: a match several thresholds off its plane barely counts.
            let w = 1.0 / (1.0 + (e / params.scale).powi(2));
            jtj += w * j * j.transpose();
            jtr += w * j * e;
            used += 1;
        }
        if used < params.min_pairs.max(5) {
            return None;
        }
        // A little damping: the direction is weakly determined when the baseline is short.
        let damping = 1e-9 * jtj.trace().max(1e-12);
        let step = (jtj + Matrix5::identity() * damping)
            .cholesky()?
            .solve(&(-jtr));
        if !step.iter().all(|s| s.is_finite()) {
            return None;
        }
        let (nr, nt) = stepped(&r, &t, &step);
        r = nr;
        t = nt;
        if step.norm() < 1e-10 {
            break;
        }
    }
    Some((r, Unit::new_normalize(t)))
}

/// The world-to-camera translation that best reprojects `world` points onto the undistorted
/// normalised observations `observed` with the world-to-camera `rotation` held:
/// Huber-weighted Gauss-Newton (threshold `huber_norm` in normalised units) from `start`.
/// `None` when fewer than four points stay in front of the camera or the system does not
/// solve.
pub fn refit_translation(
    world: &[Point3<f64>],
    observed: &[nalgebra::Vector2<f64>],
    rotation: &Rotation3<f64>,
    start: &Vector3<f64>,
    huber_norm: f64,
    iterations: usize,
) -> Option<Vector3<f64>> {
    let mut t = *start;
    for _ in 0..iterations {
        let mut jtj = Matrix3::<f64>::zeros();
        let mut jtr = Vector3::<f64>::zeros();
        let mut used = 0;
        for (x, o) in world.iter().zip(observed) {
            let p = rotation * x.coords + t;
            if p.z.is_nan() || p.z <= 1e-6 || !o.iter().all(|v| v.is_finite()) {
                continue;
            }
            let iz = 1.0 / p.z;
            let r = [p.x * iz - o.x, p.y * iz - o.y];
            let rows = [
                Vector3::new(iz, 0.0, -p.x * iz * iz),
                Vector3::new(0.0, iz, -p.y * iz * iz),
            ];
            let e = (r[0] * r[0] + r[1] * r[1]).sqrt();
            if !e.is_finite() {
                continue;
            }
            let w = if e <= huber_norm { 1.0 } else { huber_norm / e };
            for (row, ri) in rows.iter().zip(r) {
                jtj += w * row * row.transpose();
                jtr += w * row * ri;
            }
            used += 1;
        }
        if used < 4 {
            return None;
        }
        let step = jtj.cholesky()?.solve(&(-jtr));
        if !step.iter().all(|s| s.is_finite()) {
            return None;
        }
        t += step;
        if step.norm() < 1e-12 {
            break;
        }
    }
    Some(t)
}

/// A camera-to-world pose from a world-to-camera rotation and translation.
pub fn camera_to_world(rotation: &Rotation3<f64>, translation: &Vector3<f64>) -> Pose {
    Pose::from_parts(
        Translation3::from(*translation),
        UnitQuaternion::from_rotation_matrix(rotation),
    )
    .inverse()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Points spread over depths 1-3 m in front of camera 1, and camera 2 moved by `(R, t)`.
    fn scene() -> (Vec<Point3<f64>>, Rotation3<f64>, Vector3<f64>) {
        let mut pts = Vec::new();
        let mut s = 12345u64;
        let mut rnd = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..150 {
            let z = 1.0 + 2.0 * rnd();
            pts.push(Point3::new((rnd() - 0.5) * z, (rnd() - 0.5) * 0.75 * z, z));
        }
        let r = Rotation3::from_euler_angles(0.01, 0.06, -0.02);
        let t = Vector3::new(0.05, -0.01, 0.02);
        (pts, r, t)
    }

    /// Each point's bearing from camera 1 and from camera 2 (`x₂ = R x₁ + t`).
    fn bearing_pairs(
        pts: &[Point3<f64>],
        r: &Rotation3<f64>,
        t: &Vector3<f64>,
    ) -> Vec<(Vector3<f64>, Vector3<f64>)> {
        pts.iter()
            .map(|p| (p.coords.normalize(), (r * p.coords + t).normalize()))
            .collect()
    }

    #[test]
    fn the_rotation_comes_back_from_bearings_alone() {
        let (pts, r, t) = scene();
        let pairs = bearing_pairs(&pts, &r, &t);
        // Start 2 degrees and a skewed direction away.
        let r0 = Rotation3::from_euler_angles(0.0, 0.035, 0.0) * r;
        let t0 = t + Vector3::new(0.0, 0.02, -0.01);
        let (rr, tt) =
            refine_relative_rotation(&pairs, &r0, &t0, &EpipolarParams::default()).unwrap();
        assert!(
            (rr.inverse() * r).angle() < 1e-6,
            "{}",
            (rr.inverse() * r).angle()
        );
        assert!((tt.into_inner() - t.normalize()).norm() < 1e-5);
    }

    #[test]
    fn outliers_are_held_by_the_robust_weight() {
        let (pts, r, t) = scene();
        let mut pairs = bearing_pairs(&pts, &r, &t);
        // A tenth of the matches wrong by several degrees.
        for (i, pair) in pairs.iter_mut().enumerate().filter(|(i, _)| i % 10 == 0) {
            let wrong = Rotation3::from_euler_angles(0.05 + 0.001 * i as f64, -0.04, 0.0);
            pair.1 = wrong * pair.1;
        }
        let (rr, _) = refine_relative_rotation(&pairs, &r, &t, &EpipolarParams::default()).unwrap();
        let err = (rr.inverse() * r).angle().to_degrees();
        assert!(err < 0.05, "{err}");
    }

    #[test]
    fn too_few_pairs_or_no_baseline_give_none() {
        let (pts, r, t) = scene();
        let pairs = bearing_pairs(&pts, &r, &t);
        let p = EpipolarParams::default();
        assert!(refine_relative_rotation(&pairs[..10], &r, &t, &p).is_none());
        assert!(refine_relative_rotation(&pairs, &r, &Vector3::zeros(), &p).is_none());
        assert!(
            refine_relative_rotation(&pairs, &r, &Vector3::from_element(f64::NAN), &p).is_none()
        );
        // A few unreadable bearings are skipped, not fatal.
        let mut some_nan = pairs.clone();
        some_nan[3].1 = Vector3::from_element(f64::NAN);
        let (rr, _) = refine_relative_rotation(&some_nan, &r, &t, &p).unwrap();
        assert!((rr.inverse() * r).angle() < 1e-6);
    }

    /// Each point's undistorted normalised coordinates in camera 2.
    fn normalised_views(
        pts: &[Point3<f64>],
        r: &Rotation3<f64>,
        t: &Vector3<f64>,
    ) -> Vec<nalgebra::Vector2<f64>> {
        pts.iter()
            .map(|p| {
                let q = r * p.coords + t;
                nalgebra::Vector2::new(q.x / q.z, q.y / q.z)
            })
            .collect()
    }

    #[test]
    fn the_translation_is_refitted_with_the_rotation_held() {
        let (pts, r, t) = scene();
        let observed = normalised_views(&pts, &r, &t);
        let got = refit_translation(&pts, &observed, &r, &Vector3::zeros(), 0.01, 20).unwrap();
        assert!((got - t).norm() < 1e-9, "{got:?}");
        let pose = camera_to_world(&r, &got);
        let c = pose.inverse() * pts[0];
        assert!((c.coords - (r * pts[0].coords + t)).norm() < 1e-9);
    }

    /// Depths pressed towards their middle (as SDFCNN's are on unseen frames) do not enter the
    /// bearings: from a start two degrees off, the rotation comes back exactly, and the
    /// translation refitted against the compressed points with it keeps the true direction.
    #[test]
    fn compressed_depths_do_not_bend_the_epipolar_rotation() {
        let (pts, r, t) = scene();
        let squashed: Vec<_> = pts
            .iter()
            .map(|p| p * (2.0 * (p.z / 2.0).powf(1.0 / 1.2) / p.z))
            .collect();
        // Bearings are the same whatever the depths along their rays.
        let pairs: Vec<_> = squashed
            .iter()
            .zip(&pts)
            .map(|(q, p)| (q.coords.normalize(), (r * p.coords + t).normalize()))
            .collect();
        let r0 = Rotation3::from_euler_angles(0.02, -0.025, 0.0) * r;
        let (rr, _) =
            refine_relative_rotation(&pairs, &r0, &(t * 2.0), &EpipolarParams::default()).unwrap();
        assert!((rr.inverse() * r).angle() < 1e-6);
        let observed = normalised_views(&pts, &r, &t);
        let got =
            refit_translation(&squashed, &observed, &rr, &Vector3::zeros(), 0.01, 30).unwrap();
        let cos = got.normalize().dot(&t.normalize());
        assert!(cos > 0.99, "{cos}");
    }
}
