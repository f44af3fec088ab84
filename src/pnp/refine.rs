//! Levenberg-Marquardt refinement of a pose on its reprojection errors.

use super::squared_error;
use nalgebra::{
    Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector2, Vector3, Vector6,
};

/// Levenberg-Marquardt on the reprojection errors of the given correspondences
/// (eq 4), starting from `pose`. Updates are left-multiplied: `T ← exp(ξ) T`.
pub fn refine_pose(
    points: &[Point3<f64>],
    normalized: &[Vector2<f64>],
    focal: (f64, f64),
    pose: &Isometry3<f64>,
    iterations: usize,
) -> Isometry3<f64> {
    let cost = |t: &Isometry3<f64>| -> f64 {
        points
            .iter()
            .zip(normalized)
            .map(|(p, n)| squared_error(t, p, n, focal))
            .sum()
    };
    let mut pose = *pose;
    let mut current = cost(&pose);
    let mut mu = 1e-4;
    for _ in 0..iterations {
        let mut h = Matrix6::<f64>::zeros();
        let mut g = Vector6::<f64>::zeros();
        for (p, n) in points.iter().zip(normalized) {
            let q = pose * p;
            if q.z <= 1e-9 {
                continue;
            }
            let iz = 1.0 / q.z;
            let r = Vector2::new(focal.0 * (q.x * iz - n.x), focal.1 * (q.y * iz - n.y));
            // d r / d q
            let (ax, az_x) = (focal.0 * iz, -focal.0 * q.x * iz * iz);
            let (by, bz_y) = (focal.1 * iz, -focal.1 * q.y * iz * iz);
            // d q / d(omega, v) = [-[q]x | I]
            let jx = Vector6::new(az_x * q.y, ax * q.z - az_x * q.x, -ax * q.y, ax, 0.0, az_x);
            let jy = Vector6::new(-by * q.z + bz_y * q.y, -bz_y * q.x, by * q.x, 0.0, by, bz_y);
            h += jx * jx.transpose() + jy * jy.transpose();
            g += jx * r.x + jy * r.y;
        }
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = h;
            for k in 0..6 {
                damped[(k, k)] += mu * h[(k, k)].max(1e-12);
            }
            let Some(chol) = damped.cholesky() else {
                mu *= 10.0;
                continue;
            };
            let step = -chol.solve(&g);
            let w = Vector3::new(step[0], step[1], step[2]);
            let v = Vector3::new(step[3], step[4], step[5]);
            let update =
                Isometry3::from_parts(Translation3::from(v), UnitQuaternion::from_scaled_axis(w));
            let candidate = update * pose;
            let c = cost(&candidate);
            if c < current {
                let converged = (current - c) <= 1e-12 * current.max(1e-300);
                pose = candidate;
                current = c;
                mu = (mu / 3.0).max(1e-12);
                improved = !converged;
                break;
            }
            mu *= 5.0;
        }
        if !improved {
            break;
        }
    }
    pose
}
