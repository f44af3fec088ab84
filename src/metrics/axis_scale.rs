//! Per-axis scale of one set of relative motions against another: the least-squares slope of
//! the reference's step on the estimate's, per axis of the first camera's frame, for the
//! translation and for the rotation vector. An isotropic scale error gives equal slopes; a
//! reference that trades one motion for another (vertical translation for pitch, say) gives
//! slopes that differ by axis (lab/notes/slam-results.md, *Repeated images and jumps in 7-Scenes'
//! ground truth*).

use crate::geometry::Pose;
use nalgebra::Vector3;

/// Sums for the slopes `Σ r·e / Σ e²`, per axis.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct AxisScale {
    translation: [Vector3<f64>; 2],
    rotation: [Vector3<f64>; 2],
    /// Step pairs added.
    pub pairs: usize,
}

impl AxisScale {
    /// Empty sums (no pairs).
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds one pair of relative poses (`T_a⁻¹ T_b`, B in A's camera frame). Pairs with a
    /// non-finite component are skipped.
    pub fn add(&mut self, reference: &Pose, estimate: &Pose) {
        let parts = |p: &Pose| (p.translation.vector, p.rotation.scaled_axis());
        let ((tr, rr), (te, re)) = (parts(reference), parts(estimate));
        if ![tr, rr, te, re]
            .iter()
            .all(|v| v.iter().all(|x| x.is_finite()))
        {
            return;
        }
        self.translation[0] += tr.component_mul(&te);
        self.translation[1] += te.component_mul(&te);
        self.rotation[0] += rr.component_mul(&re);
        self.rotation[1] += re.component_mul(&re);
        self.pairs += 1;
    }

    /// The translation slopes (x, y, z); `None` while the estimate has not moved along
    /// every axis.
    pub fn translation(&self) -> Option<Vector3<f64>> {
        slopes(&self.translation)
    }

    /// The rotation-vector slopes (about x, y, z); `None` while the estimate has not
    /// turned about every axis.
    pub fn rotation(&self) -> Option<Vector3<f64>> {
        slopes(&self.rotation)
    }
}

fn slopes([num, den]: &[Vector3<f64>; 2]) -> Option<Vector3<f64>> {
    (den.min() > 0.0).then(|| num.component_div(den))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn pose(t: [f64; 3], w: [f64; 3]) -> Pose {
        Pose::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_scaled_axis(Vector3::from(w)),
        )
    }

    #[test]
    fn equal_steps_give_unit_slopes_and_stretched_ones_their_stretch() {
        let steps = [
            ([0.03, -0.01, 0.02], [0.01, 0.02, -0.005]),
            ([-0.02, 0.015, 0.04], [-0.004, 0.03, 0.01]),
            ([0.01, 0.02, -0.03], [0.02, -0.01, 0.003]),
        ];
        let (mut same, mut stretched) = (AxisScale::new(), AxisScale::new());
        for (t, w) in steps {
            let e = pose(t, w);
            same.add(&e, &e);
            let r = pose([1.05 * t[0], 0.9 * t[1], t[2]], [1.1 * w[0], w[1], w[2]]);
            stretched.add(&r, &e);
        }
        assert_eq!(same.pairs, 3);
        assert!((same.translation().unwrap() - Vector3::repeat(1.0)).norm() < 1e-12);
        assert!((same.rotation().unwrap() - Vector3::repeat(1.0)).norm() < 1e-9);
        let t = stretched.translation().unwrap();
        assert!((t - Vector3::new(1.05, 0.9, 1.0)).norm() < 1e-12, "{t}");
        let r = stretched.rotation().unwrap();
        assert!((r - Vector3::new(1.1, 1.0, 1.0)).norm() < 1e-9, "{r}");
    }

    #[test]
    fn no_motion_along_an_axis_gives_no_slopes_and_non_finite_pairs_are_skipped() {
        let mut s = AxisScale::new();
        assert_eq!(s.translation(), None);
        let e = pose([0.03, 0.0, 0.02], [0.0, 0.02, 0.0]);
        s.add(&e, &e);
        assert_eq!((s.translation(), s.rotation()), (None, None));
        s.add(&pose([f64::NAN, 0.0, 0.0], [0.0; 3]), &e);
        assert_eq!(s.pairs, 1);
    }
}
