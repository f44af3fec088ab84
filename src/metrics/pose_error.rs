//! The paper's pose errors errT (%) and errR (deg/m), eqs 11-14, after the
//! KITTI odometry metric the paper cites (\[37\]; its Table 1 uses the same units).
//!
//! Our reading, for a segment from frame `i` to frame `j` with ground-truth
//! relative motion `T = T_i⁻¹ T_j` (rotation `R`) and estimated relative motion
//! `PT = P_i⁻¹ P_j` (rotation `PR`):
//!
//! * eq 11/13: `T = ΔT · PT`, i.e. `ΔT = T · PT⁻¹` and `ΔR = R · PR⁻¹`;
//! * eq 12: `errT = ‖ΔT − E‖` is read as the length of the translation of `ΔT`
//!   (the part of `ΔT − E` that is a displacement) relative to the segment
//!   length `L`, in percent: `100 · ‖t(ΔT)‖ / L`;
//! * eq 14: `errR = ‖ΔR − E‖` is read as the rotation angle of `ΔR` per metre of
//!   segment: `∠(ΔR) / L` in deg/m.
//!
//! `L` is the ground-truth path length of the segment (the displacement `‖t(T)‖`
//! when only the two end poses are known, as for a frame pair). Over many
//! segments the errors are pooled as ratios of sums, `Σ‖t(ΔT_k)‖ / Σ L_k` and
//! `Σ∠(ΔR_k) / Σ L_k`, which equals KITTI's mean for equal-length segments and
//! stays finite when a segment barely moves (rotation-only motion).

use crate::error::{Error, Result};
use crate::geometry::{Pose, rotation_angle};
use crate::trajectory::Trajectory;
use serde::{Deserialize, Serialize};

/// The error of one segment.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseErrorSegment {
    /// `‖t(ΔT)‖`, metres.
    pub trans_error: f64,
    /// `∠(ΔR)`, degrees.
    pub rot_error_deg: f64,
    /// Segment length `L`, metres.
    pub length: f64,
}

impl PoseErrorSegment {
    /// Error of an estimated relative motion against the ground-truth one,
    /// with segment length `length` (defaults to the ground-truth displacement).
    pub fn new(gt_relative: &Pose, est_relative: &Pose, length: Option<f64>) -> Self {
        let delta = gt_relative * est_relative.inverse();
        PoseErrorSegment {
            trans_error: delta.translation.vector.norm(),
            rot_error_deg: rotation_angle(&delta.rotation).to_degrees(),
            length: length.unwrap_or_else(|| gt_relative.translation.vector.norm()),
        }
    }
}

/// errT and errR pooled over segments.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PoseError {
    /// errT, percent of distance travelled.
    pub err_t_percent: f64,
    /// errR, degrees per metre travelled.
    pub err_r_deg_per_m: f64,
    /// Mean `‖t(ΔT)‖` per segment, metres.
    pub mean_trans_error: f64,
    /// Mean `∠(ΔR)` per segment, degrees.
    pub mean_rot_error_deg: f64,
    /// Number of segments pooled.
    pub segments: usize,
    /// Σ L, metres.
    pub total_length: f64,
}

impl PoseError {
    /// Pools segment errors; an error when there are none or they did not move.
    pub fn pool(segments: &[PoseErrorSegment]) -> Result<Self> {
        let n = segments.len();
        let total_length: f64 = segments.iter().map(|s| s.length).sum();
        if n == 0 || total_length.is_nan() || total_length <= 0.0 {
            return Err(Error::msg(
                "errT/errR need at least one segment with non-zero ground-truth motion",
            ));
        }
        let t: f64 = segments.iter().map(|s| s.trans_error).sum();
        let r: f64 = segments.iter().map(|s| s.rot_error_deg).sum();
        Ok(PoseError {
            err_t_percent: 100.0 * t / total_length,
            err_r_deg_per_m: r / total_length,
            mean_trans_error: t / n as f64,
            mean_rot_error_deg: r / n as f64,
            segments: n,
            total_length,
        })
    }

    /// errT/errR of a trajectory over segments `delta` frames apart (every
    /// frame starts one), `L` being the ground-truth path length along the
    /// segment. Both trajectories must be associated (same length).
    pub fn over_frames(
        reference: &Trajectory,
        estimate: &Trajectory,
        delta: usize,
    ) -> Result<Self> {
        if reference.len() != estimate.len() {
            return Err(Error::msg(
                "errT/errR need associated trajectories of equal length",
            ));
        }
        if delta == 0 {
            return Err(Error::msg("segment delta must be at least one frame"));
        }
        let pos = reference.positions();
        let mut acc = vec![0.0; pos.len()];
        for i in 1..pos.len() {
            acc[i] = acc[i - 1] + (pos[i] - pos[i - 1]).norm();
        }
        let segments: Vec<_> = (0..reference.len().saturating_sub(delta))
            .map(|i| {
                let j = i + delta;
                let gt = reference.poses[i].inverse() * reference.poses[j];
                let est = estimate.poses[i].inverse() * estimate.poses[j];
                PoseErrorSegment::new(&gt, &est, Some(acc[j] - acc[i]))
            })
            .collect();
        Self::pool(&segments)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    #[test]
    fn known_perturbation_gives_its_error() {
        // Ground truth moves 1 m along x; the estimate moves 1.02 m and yaws 0.5 deg.
        let gt = Pose::from_parts(Translation3::new(1.0, 0.0, 0.0), UnitQuaternion::identity());
        let yaw = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.5f64.to_radians());
        let est = Pose::from_parts(Translation3::new(1.02, 0.0, 0.0), yaw);
        let seg = PoseErrorSegment::new(&gt, &est, None);
        // ΔT = T · PT⁻¹ has translation t_T − R_T R_PT⁻¹ t_PT = (1,0,0) − R_z(−0.5°)(1.02,0,0).
        let (c, s) = (0.5f64.to_radians().cos(), 0.5f64.to_radians().sin());
        let expected = ((1.0 - 1.02 * c).powi(2) + (1.02 * s).powi(2)).sqrt();
        assert!((seg.trans_error - expected).abs() < 1e-12);
        assert!((seg.rot_error_deg - 0.5).abs() < 1e-12);
        let e = PoseError::pool(&[seg, seg]).unwrap();
        assert!((e.err_t_percent - 100.0 * expected).abs() < 1e-9);
        assert!((e.err_r_deg_per_m - 0.5).abs() < 1e-9);
        assert!(PoseError::pool(&[]).is_err());
    }

    #[test]
    fn perfect_estimate_gives_zero() {
        let poses: Vec<Pose> = (0..10)
            .map(|i| {
                let r = UnitQuaternion::from_euler_angles(0.1 * i as f64, 0.0, 0.05 * i as f64);
                Pose::from_parts(Translation3::new(0.1 * i as f64, 0.02 * i as f64, 0.0), r)
            })
            .collect();
        let t = Trajectory::from_parts((0..10).map(|i| i as f64).collect(), poses).unwrap();
        let e = PoseError::over_frames(&t, &t, 3).unwrap();
        assert!(e.err_t_percent < 1e-9 && e.err_r_deg_per_m < 1e-9);
        assert_eq!(e.segments, 7);
    }
}
