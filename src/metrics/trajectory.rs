//! Absolute and relative trajectory errors, computed the way evo 1.38.1 computes
//! them (`evo_ape tum GT EST [-a|-as]`, `evo_rpe tum GT EST --delta D --delta_unit
//! f|m [-r angle_deg]`), so figures from this crate and from evo agree.

use super::stats::Stats;
use crate::error::{Error, Result};
use crate::geometry::{Pose, Sim3, rotation_angle};
use crate::trajectory::Trajectory;
use nalgebra::{Matrix3, Point3, Vector3};
use serde::{Deserialize, Serialize};

/// Alignment of the estimate to the reference before measuring.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Alignment {
    /// No alignment (evo without `-a`).
    None,
    /// Rigid Umeyama alignment (evo `-a`).
    Se3,
    /// Similarity Umeyama alignment, for monocular scale (evo `-as`).
    Sim3,
    /// Scale only (evo `-s`).
    Scale,
}

impl std::str::FromStr for Alignment {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "none" => Ok(Alignment::None),
            "se3" => Ok(Alignment::Se3),
            "sim3" => Ok(Alignment::Sim3),
            "scale" => Ok(Alignment::Scale),
            _ => Err(format!("unknown alignment '{s}' (se3, sim3, scale, none)")),
        }
    }
}

/// Unit of the RPE delta.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DeltaUnit {
    /// Delta counted in frames (evo `--delta_unit f`).
    Frames,
    /// Delta as travelled path length in metres (evo `--delta_unit m`).
    Metres,
}

impl std::str::FromStr for DeltaUnit {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        match s.to_ascii_lowercase().as_str() {
            "frames" | "f" => Ok(DeltaUnit::Frames),
            "metres" | "meters" | "m" => Ok(DeltaUnit::Metres),
            _ => Err(format!("unknown delta unit '{s}' (frames, metres)")),
        }
    }
}

/// Nearest-stamp indices of `short` into the sorted `long`, evo's
/// `matching_time_indices` (binary search, ties to the earlier stamp).
fn matching_time_indices(short: &[f64], long: &[f64], max_diff: f64) -> (Vec<usize>, Vec<usize>) {
    let (mut ids_s, mut ids_l) = (Vec::new(), Vec::new());
    let Some((&first, &last)) = long.first().zip(long.last()) else {
        return (ids_s, ids_l);
    };
    for (i, &t) in short.iter().enumerate() {
        if t < first - max_diff || t > last + max_diff {
            continue;
        }
        let k = long.partition_point(|&s| s <= t).min(long.len() - 1);
        let diff_ub = long[k] - t;
        let diff_lb = if k > 0 {
            t - long[k - 1]
        } else {
            f64::INFINITY
        };
        let best = if diff_ub <= max_diff && diff_ub < diff_lb {
            k
        } else if diff_lb <= max_diff && diff_lb <= diff_ub {
            k - 1
        } else {
            continue;
        };
        ids_s.push(i);
        ids_l.push(best);
    }
    (ids_s, ids_l)
}

/// Associates two trajectories by timestamp as evo does: each stamp of the
/// shorter one is paired with the nearest stamp of the longer one, kept when
/// within `t_max_diff` seconds. Returns `(reference, estimate)` with equal length.
pub fn associate(
    reference: &Trajectory,
    estimate: &Trajectory,
    t_max_diff: f64,
) -> Result<(Trajectory, Trajectory)> {
    let est_longer = estimate.len() > reference.len();
    let (short, long) = if est_longer {
        (reference, estimate)
    } else {
        (estimate, reference)
    };
    let (ids_s, ids_l) = matching_time_indices(&short.stamps, &long.stamps, t_max_diff);
    if ids_s.is_empty() {
        return Err(Error::msg(format!(
            "found no matching timestamps between reference ({} poses) and estimate ({} poses) with max. time diff {t_max_diff} s",
            reference.len(),
            estimate.len()
        )));
    }
    let (s, l) = (short.select(&ids_s), long.select(&ids_l));
    Ok(if est_longer { (s, l) } else { (l, s) })
}

/// Umeyama's least-squares similarity `y ≈ s R x + t` (Umeyama, PAMI 1991), as
/// `evo.core.geometry.umeyama_alignment`; `with_scale = false` fixes `s = 1`.
pub fn umeyama(x: &[Point3<f64>], y: &[Point3<f64>], with_scale: bool) -> Result<Sim3> {
    if x.len() != y.len() || x.is_empty() {
        return Err(Error::msg(
            "Umeyama alignment needs two non-empty point sets of equal size",
        ));
    }
    let n = x.len() as f64;
    let mean_x = x.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let mean_y = y.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let sigma_x = x
        .iter()
        .map(|p| (p.coords - mean_x).norm_squared())
        .sum::<f64>()
        / n;
    let mut cov = Matrix3::zeros();
    for (px, py) in x.iter().zip(y) {
        cov += (py.coords - mean_y) * (px.coords - mean_x).transpose();
    }
    cov /= n;
    // `svd` iterates without a bound; with one (1000 sweeps) the result is the same.
    let Some(svd) = cov.try_svd(true, true, 5.0 * f64::EPSILON, 1000) else {
        return Err(Error::msg("Umeyama alignment: SVD did not converge"));
    };
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Err(Error::msg("Umeyama alignment: SVD failed"));
    };
    // Sort singular values in descending order, as numpy returns them.
    let mut order = [0usize, 1, 2];
    let d = svd.singular_values;
    order.sort_by(|&a, &b| d[b].total_cmp(&d[a]));
    let u = Matrix3::from_columns(&[u.column(order[0]), u.column(order[1]), u.column(order[2])]);
    let v_t = Matrix3::from_rows(&[v_t.row(order[0]), v_t.row(order[1]), v_t.row(order[2])]);
    let d = Vector3::new(d[order[0]], d[order[1]], d[order[2]]);
    if d.iter().filter(|&&s| s > f64::EPSILON).count() < 2 {
        return Err(Error::msg(format!(
            "cannot align: the {} matched position(s) do not span a plane (one pose, one point or \
             one straight line), so the rotation is undetermined; use --align none, or longer \
             trajectories (evo: degenerate covariance rank)",
            x.len()
        )));
    }
    let mut s = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        s[2] = -1.0;
    }
    let rotation = u * Matrix3::from_diagonal(&s) * v_t;
    let scale = if with_scale {
        d.component_mul(&s).sum() / sigma_x
    } else {
        1.0
    };
    let translation = mean_y - scale * (rotation * mean_x);
    Ok(Sim3 {
        rotation,
        translation,
        scale,
    })
}

/// Aligns `estimate` to `reference` (already associated, same length).
pub fn align(
    reference: &Trajectory,
    estimate: &Trajectory,
    how: Alignment,
) -> Result<(Trajectory, Sim3)> {
    let sim = match how {
        Alignment::None => return Ok((estimate.clone(), Sim3::identity())),
        Alignment::Se3 => umeyama(&estimate.positions(), &reference.positions(), false)?,
        Alignment::Sim3 => umeyama(&estimate.positions(), &reference.positions(), true)?,
        Alignment::Scale => {
            let s = umeyama(&estimate.positions(), &reference.positions(), true)?.scale;
            Sim3 {
                scale: s,
                ..Sim3::identity()
            }
        }
    };
    let poses = estimate
        .poses
        .iter()
        .map(|p| sim.transform_pose(p))
        .collect();
    Ok((
        Trajectory {
            stamps: estimate.stamps.clone(),
            poses,
        },
        sim,
    ))
}

/// Absolute trajectory error (evo APE, translation part).
#[derive(Debug, Clone)]
pub struct Ape {
    /// Statistics of the translation errors, metres.
    pub stats: Stats,
    /// Per associated pose, metres.
    pub errors: Vec<f64>,
    /// The transform applied to the estimate to align it with the reference.
    pub alignment: Sim3,
    /// Associated reference poses.
    pub reference: Trajectory,
    /// Associated estimate poses after alignment.
    pub estimate: Trajectory,
}

/// ATE: associates, aligns and measures `|t_est - t_ref|` per pose.
pub fn ape(
    reference: &Trajectory,
    estimate: &Trajectory,
    how: Alignment,
    t_max_diff: f64,
) -> Result<Ape> {
    let (reference, estimate) = associate(reference, estimate, t_max_diff)?;
    let (estimate, alignment) = align(&reference, &estimate, how)?;
    let errors: Vec<f64> = reference
        .poses
        .iter()
        .zip(&estimate.poses)
        .map(|(r, e)| (e.translation.vector - r.translation.vector).norm())
        .collect();
    let stats = Stats::of(&errors).ok_or_else(|| Error::msg("no poses to compare"))?;
    Ok(Ape {
        stats,
        errors,
        alignment,
        reference,
        estimate,
    })
}

/// Relative pose error (evo RPE): translation in metres and rotation angle in
/// degrees of `E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)` for consecutive pairs `(i, j)` at
/// the given delta.
#[derive(Debug, Clone)]
pub struct Rpe {
    /// Statistics of the translation errors, metres.
    pub trans: Stats,
    /// Statistics of the rotation errors, degrees.
    pub rot_deg: Stats,
    /// Translation error of each pair, metres.
    pub trans_errors: Vec<f64>,
    /// Rotation error of each pair, degrees.
    pub rot_errors_deg: Vec<f64>,
    /// Index pairs into the associated trajectories.
    pub pairs: Vec<(usize, usize)>,
    /// The transform applied to the estimate to align it with the reference.
    pub alignment: Sim3,
    /// Associated reference poses.
    pub reference: Trajectory,
    /// Associated estimate poses after alignment.
    pub estimate: Trajectory,
}

/// An [`Rpe`]'s pairs split by whether a keyframe begins between the two poses: a
/// keyframe-based tracker expresses the frames of one keyframe's span against that keyframe,
/// so the pairs across a switch show the jumps where the reference changes (issue 18's
/// "fewer jumps at keyframe switches").
#[derive(Debug, Clone)]
pub struct RpeAtKeyframes {
    /// Pairs within one keyframe's span (no keyframe stamp in `(t_i, t_j]`).
    pub within: Option<RpeSplit>,
    /// Pairs across a switch (a keyframe stamp in `(t_i, t_j]`).
    pub across: Option<RpeSplit>,
}

/// Translation (m) and rotation (deg) statistics of a subset of an [`Rpe`]'s pairs.
#[derive(Debug, Clone, Serialize)]
pub struct RpeSplit {
    /// Translation error statistics of the subset, metres.
    pub trans: Stats,
    /// Rotation error statistics of the subset, degrees.
    pub rot_deg: Stats,
}

impl Rpe {
    /// Splits the pairs at the keyframes' stamps (the estimate's clock; a stamp within 1 µs
    /// of a pose's counts as that pose's).
    pub fn at_keyframes(&self, keyframe_stamps: &[f64]) -> RpeAtKeyframes {
        let mut stamps: Vec<f64> = keyframe_stamps
            .iter()
            .copied()
            .filter(|t| t.is_finite())
            .collect();
        stamps.sort_by(f64::total_cmp);
        let eps = 1e-6;
        let (mut within, mut across) = ((Vec::new(), Vec::new()), (Vec::new(), Vec::new()));
        for (k, &(i, j)) in self.pairs.iter().enumerate() {
            let (ti, tj) = (self.estimate.stamps[i], self.estimate.stamps[j]);
            // The first keyframe stamp after t_i; a switch if it is not after t_j.
            let next = stamps.partition_point(|&s| s <= ti + eps);
            let side = if stamps.get(next).is_some_and(|&s| s <= tj + eps) {
                &mut across
            } else {
                &mut within
            };
            side.0.push(self.trans_errors[k]);
            side.1.push(self.rot_errors_deg[k]);
        }
        let split = |(t, r): (Vec<f64>, Vec<f64>)| {
            Some(RpeSplit {
                trans: Stats::of(&t)?,
                rot_deg: Stats::of(&r)?,
            })
        };
        RpeAtKeyframes {
            within: split(within),
            across: split(across),
        }
    }
}

/// Consecutive pairs `delta` frames apart (evo `filter_pairs_by_index`).
fn pairs_by_index(n: usize, delta: usize) -> Vec<(usize, usize)> {
    let ids: Vec<usize> = (0..n).step_by(delta).collect();
    ids.windows(2).map(|w| (w[0], w[1])).collect()
}

/// Consecutive pairs whose travelled path reaches `delta` metres (evo
/// `filter_pairs_by_path`, measured on the poses given).
fn pairs_by_path(poses: &[Pose], delta: f64) -> Vec<(usize, usize)> {
    let mut ids = vec![0];
    let mut path = 0.0;
    for i in 1..poses.len() {
        path += (poses[i].translation.vector - poses[i - 1].translation.vector).norm();
        if path >= delta {
            ids.push(i);
            path = 0.0;
        }
    }
    ids.windows(2).map(|w| (w[0], w[1])).collect()
}

/// RPE over consecutive pairs `delta` frames or metres apart (pairs chosen on
/// the aligned estimate, as evo does by default).
pub fn rpe(
    reference: &Trajectory,
    estimate: &Trajectory,
    how: Alignment,
    t_max_diff: f64,
    delta: f64,
    unit: DeltaUnit,
) -> Result<Rpe> {
    if delta.is_nan() || delta <= 0.0 {
        return Err(Error::msg(format!(
            "RPE delta must be positive, got {delta}"
        )));
    }
    let (reference, estimate) = associate(reference, estimate, t_max_diff)?;
    let (estimate, alignment) = align(&reference, &estimate, how)?;
    let pairs = match unit {
        DeltaUnit::Frames => {
            if delta.fract() != 0.0 {
                return Err(Error::msg(format!(
                    "delta in frames must be an integer, got {delta}"
                )));
            }
            pairs_by_index(estimate.len(), delta as usize)
        }
        DeltaUnit::Metres => pairs_by_path(&estimate.poses, delta),
    };
    if pairs.is_empty() {
        return Err(Error::msg(format!(
            "no pose pairs {delta} {} apart among {} associated poses",
            match unit {
                DeltaUnit::Frames => "frames",
                DeltaUnit::Metres => "metres",
            },
            estimate.len()
        )));
    }
    let (mut trans_errors, mut rot_errors_deg) = (Vec::new(), Vec::new());
    for &(i, j) in &pairs {
        let q_rel = reference.poses[i].inverse() * reference.poses[j];
        let p_rel = estimate.poses[i].inverse() * estimate.poses[j];
        let e = q_rel.inverse() * p_rel;
        trans_errors.push(e.translation.vector.norm());
        rot_errors_deg.push(rotation_angle(&e.rotation).to_degrees());
    }
    let trans = Stats::of(&trans_errors).ok_or_else(|| Error::msg("no pairs"))?;
    let rot_deg = Stats::of(&rot_errors_deg).ok_or_else(|| Error::msg("no pairs"))?;
    Ok(Rpe {
        trans,
        rot_deg,
        trans_errors,
        rot_errors_deg,
        pairs,
        alignment,
        reference,
        estimate,
    })
}
