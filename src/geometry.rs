//! SE(3) / Sim(3) helpers on top of nalgebra. Poses are camera-to-world
//! (`x_world = T * x_cam`), the TUM RGB-D convention.

use nalgebra::{
    Isometry3, Matrix3, Point3, Quaternion, Rotation3, Translation3, UnitQuaternion, Vector3,
};

/// A rigid camera pose, camera-to-world.
pub type Pose = Isometry3<f64>;

/// Builds a pose from TUM fields (`tx ty tz`, `qx qy qz qw`). The quaternion is
/// normalised; `None` when any value is not finite or the quaternion is zero.
pub(crate) fn pose_from_tum(t: [f64; 3], q_xyzw: [f64; 4]) -> Option<Pose> {
    if t.iter().chain(q_xyzw.iter()).any(|v| !v.is_finite()) {
        return None;
    }
    let q = Quaternion::new(q_xyzw[3], q_xyzw[0], q_xyzw[1], q_xyzw[2]);
    let norm = q.norm();
    if norm < 1e-12 {
        return None;
    }
    Some(Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::new_unchecked(q / norm),
    ))
}

/// The rotation nearest to `m` in the Frobenius norm (the chordal mean when `m` is a sum of
/// rotations, P3P's rotation from a cross-covariance): `U diag(1, 1, det(U Vᵀ)) Vᵀ` of its
/// SVD. `None` when `m` is not finite, the SVD does not converge, or the smallest singular
/// value is below `min_ratio` times the largest (0: any). Not nalgebra's
/// `Rotation3::from_matrix`, which iterates until an update falls below machine epsilon,
/// which rounding can prevent: it never returned on one sum of 25 keyframe rotations
/// (7-Scenes, 2026-11-29).
pub(crate) fn nearest_rotation(m: &Matrix3<f64>, min_ratio: f64) -> Option<Rotation3<f64>> {
    if !m.iter().all(|v| v.is_finite()) {
        return None;
    }
    // nalgebra's `svd` iterates without a bound; 1000 sweeps are far more than a 3x3 needs.
    let svd = m.try_svd(true, true, 5.0 * f64::EPSILON, 1000)?;
    let (u, v_t) = (svd.u?, svd.v_t?);
    let s = svd.singular_values;
    if s.min() < min_ratio * s.max() {
        return None;
    }
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    Some(Rotation3::from_matrix_unchecked(u * d * v_t))
}

/// TUM fields of a pose: (`[tx, ty, tz]`, `[qx, qy, qz, qw]`).
pub fn pose_to_tum(pose: &Pose) -> ([f64; 3], [f64; 4]) {
    let t = pose.translation.vector;
    let q = pose.rotation.quaternion();
    ([t.x, t.y, t.z], [q.i, q.j, q.k, q.w])
}

/// The pose with its rotation quaternion rescaled to unit norm. nalgebra
/// composes and inverts unit quaternions without renormalising, so rounding
/// errors add up along chains of products; where a pose feeds back into the
/// next one (the constant-velocity prediction `T_k T_{k-1}⁻¹ T_k` seeding PnP),
/// the norm error grows by about 2.4x per frame and a non-unit quaternion
/// rotates *and scales* points.
pub(crate) fn renormalized(pose: &Pose) -> Pose {
    Pose::from_parts(
        pose.translation,
        UnitQuaternion::new_normalize(pose.rotation.into_inner()),
    )
}

/// Interpolates between two poses at `s` in [0, 1]: translation linearly,
/// rotation by SLERP along the shorter arc (a quaternion sign flip between the
/// two samples, common in motion-capture files, is handled).
pub fn interpolate(a: &Pose, b: &Pose, s: f64) -> Pose {
    let t = a.translation.vector.lerp(&b.translation.vector, s);
    let qa = a.rotation;
    let mut qb = b.rotation;
    if qa.coords.dot(&qb.coords) < 0.0 {
        qb = UnitQuaternion::new_unchecked(-qb.into_inner());
    }
    // Nearly equal rotations: normalised lerp is exact to machine precision.
    let r = qa.try_slerp(&qb, s, 1e-12).unwrap_or_else(|| {
        UnitQuaternion::new_normalize(qa.into_inner().lerp(&qb.into_inner(), s))
    });
    Isometry3::from_parts(Translation3::from(t), r)
}

/// Rotation angle of a rotation in radians, in [0, pi] (atan2 form, accurate
/// for small angles).
pub fn rotation_angle(r: &UnitQuaternion<f64>) -> f64 {
    r.angle()
}

/// Two unit vectors spanning the plane orthogonal to unit vector `n`, so that `(e1, e2, n)`
/// is right-handed up to the order (`e1 = n × helper`, `e2 = n × e1`).
pub(crate) fn orthonormal_basis(n: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let helper = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = n.cross(&helper).normalize();
    let e2 = n.cross(&e1);
    (e1, e2)
}

/// A similarity transform `x -> s R x + t` (Umeyama alignment result).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3 {
    /// Rotation `R` (orthonormal, determinant +1).
    pub rotation: Matrix3<f64>,
    /// Translation `t`, in the target frame's units.
    pub translation: Vector3<f64>,
    /// Scale factor `s`.
    pub scale: f64,
}

impl Sim3 {
    /// The identity transform (`s = 1`, `R = I`, `t = 0`).
    pub fn identity() -> Self {
        Sim3 {
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }

    /// Applies the transform to a point.
    pub fn transform_point(&self, p: &Point3<f64>) -> Point3<f64> {
        Point3::from(self.scale * (self.rotation * p.coords) + self.translation)
    }

    /// Applies the transform to a camera pose as evo does: positions are scaled
    /// first, then the rigid part is left-multiplied.
    pub fn transform_pose(&self, pose: &Pose) -> Pose {
        // Closed form and renormalised, not `from_matrix`, which may never return (see
        // [`nearest_rotation`]): a Sim(3)'s rotation (Umeyama, a chordal mean) is already
        // orthonormal, so no projection per pose. A non-finite one stays non-finite.
        let q =
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(self.rotation));
        let r = UnitQuaternion::new_normalize(q.into_inner());
        let t = self.scale * (self.rotation * pose.translation.vector) + self.translation;
        Isometry3::from_parts(Translation3::from(t), r * pose.rotation)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tum_round_trip() {
        let p = pose_from_tum([1.0, 2.0, 3.0], [0.1, -0.2, 0.3, 0.9]).unwrap();
        let (t, q) = pose_to_tum(&p);
        assert_eq!(t, [1.0, 2.0, 3.0]);
        let n = (0.01f64 + 0.04 + 0.09 + 0.81).sqrt();
        assert!((q[0] - 0.1 / n).abs() < 1e-12 && (q[3] - 0.9 / n).abs() < 1e-12);
        assert!(pose_from_tum([0.0; 3], [0.0; 4]).is_none());
        assert!(pose_from_tum([f64::NAN, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]).is_none());
    }

    #[test]
    fn nearest_rotation_is_the_chordal_mean_a_proper_rotation_and_none_for_nan() {
        let r = UnitQuaternion::from_euler_angles(0.3, -1.2, 2.0);
        // Rotations symmetric about r (±0.1 rad about each axis) average to r.
        let mut m = Matrix3::zeros();
        for axis in [Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis()] {
            for s in [-0.1, 0.1] {
                m += (r * UnitQuaternion::from_axis_angle(&axis, s))
                    .to_rotation_matrix()
                    .into_inner();
            }
        }
        let mean = nearest_rotation(&m, 0.0).unwrap();
        assert!((mean.matrix() - r.to_rotation_matrix().matrix()).norm() < 1e-12);
        // A reflection's nearest rotation has determinant +1, not -1.
        let flip = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
        let proper = nearest_rotation(&(flip * 2.0), 0.0).unwrap();
        assert!((proper.matrix().determinant() - 1.0).abs() < 1e-12);
        // The sum of 25 keyframe rotations (column-major) on which nalgebra 0.35's
        // `Rotation3::from_matrix` never returns; `from_matrix_eps` with 10⁶ iterations
        // stops at the same rotation.
        let stuck = Matrix3::from_column_slice(&[
            24.991946584899647,
            -0.08261529126020908,
            0.35781867317833954,
            0.08362863582814242,
            24.996237781304544,
            -0.04727500894623919,
            -0.3564123464447029,
            0.04605766740676204,
            24.9935649850973,
        ]);
        let mean = nearest_rotation(&stuck, 0.0).unwrap();
        let reference =
            Rotation3::from_matrix_eps(&stuck, f64::EPSILON, 1_000_000, Rotation3::identity());
        let gap = (mean.matrix() - reference.matrix()).norm();
        assert!(gap < 1e-12, "{gap}");
        let mut bad = m;
        bad[(1, 2)] = f64::NAN;
        assert!(nearest_rotation(&bad, 0.0).is_none());
        // A rank-deficient matrix is refused when a condition is asked for.
        let flat = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0));
        assert!(nearest_rotation(&flat, 0.0).is_some());
        assert!(nearest_rotation(&flat, 1e-9).is_none());
        assert!(nearest_rotation(&Matrix3::from_element(f64::INFINITY), 0.0).is_none());
    }

    #[test]
    fn renormalized_restores_unit_quaternions_and_keeps_the_pose() {
        let p = pose_from_tum([1.0, 2.0, 3.0], [0.1, -0.2, 0.3, 0.9]).unwrap();
        // A quaternion 1e-3 off unit norm rotates and scales points.
        let off = Pose::from_parts(
            p.translation,
            UnitQuaternion::new_unchecked(p.rotation.into_inner() * 1.001),
        );
        let x = Point3::new(0.5, -1.0, 2.0);
        let d = (off * x - p * x).norm();
        assert!(d > 1e-4, "{d}");
        let r = renormalized(&off);
        assert!((r.rotation.quaternion().norm() - 1.0).abs() < 1e-15);
        assert!((r * x - p * x).norm() < 1e-12);
    }

    #[test]
    fn interpolation_handles_sign_flip() {
        let a = pose_from_tum([0.0; 3], [0.0, 0.0, 0.0, 1.0]).unwrap();
        let half = (std::f64::consts::FRAC_PI_4).sin();
        let (c, s) = ((std::f64::consts::FRAC_PI_4).cos(), half);
        // 90 degrees about z, written with the opposite sign.
        let b = pose_from_tum([2.0, 0.0, 0.0], [0.0, 0.0, -s, -c]).unwrap();
        let m = interpolate(&a, &b, 0.5);
        assert!((m.translation.vector.x - 1.0).abs() < 1e-12);
        assert!((rotation_angle(&m.rotation) - std::f64::consts::FRAC_PI_4).abs() < 1e-12);
        let end = interpolate(&a, &b, 1.0);
        assert!(rotation_angle(&(end.rotation.inverse() * b.rotation)) < 1e-12);
    }
}
