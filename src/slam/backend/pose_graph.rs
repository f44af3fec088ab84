//! Pose-graph optimisation over SE(3) for global data correction (section
//! IV-A): one 6-dof pose per keyframe (the first fixed), relative-pose edges
//! (odometry and loop constraints), robust (Huber / Cauchy) Levenberg-Marquardt
//! on block-sparse normal equations with nalgebra.
//!
//! Poses are camera-to-world and perturbed on the right, `T ← T exp(δ)` with
//! `δ = (ρ, φ)` (translation first). The error of an edge `(i, j, Z)` is
//! `e = log(Z⁻¹ T_i⁻¹ T_j)`, with Jacobians `∂e/∂δ_j = J_r⁻¹(e)` and
//! `∂e/∂δ_i = −J_r⁻¹(e) Ad(T_j⁻¹ T_i)`, `J_r⁻¹(e) ≈ I + ½ ad(e)` (Barfoot,
//! "State Estimation for Robotics", 2017, ch. 7).

use crate::geometry::Pose;
use crate::slam::config::RobustKernel;
use nalgebra::{
    DMatrix, DVector, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6,
};
use std::collections::BTreeMap;

/// The cross-product matrix `[v]×`.
pub(super) fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// `exp` of `ξ = (ρ, φ)`.
pub(crate) fn se3_exp(xi: &Vector6<f64>) -> Pose {
    let rho = Vector3::new(xi[0], xi[1], xi[2]);
    let phi = Vector3::new(xi[3], xi[4], xi[5]);
    let theta = phi.norm();
    let k = skew(&phi);
    let v = if theta < 1e-6 {
        Matrix3::identity() + 0.5 * k + k * k / 6.0
    } else {
        let t2 = theta * theta;
        Matrix3::identity()
            + (1.0 - theta.cos()) / t2 * k
            + (theta - theta.sin()) / (t2 * theta) * k * k
    };
    Pose::from_parts(
        Translation3::from(v * rho),
        UnitQuaternion::from_scaled_axis(phi),
    )
}

/// `log` of a pose as `(ρ, φ)`.
pub(crate) fn se3_log(t: &Pose) -> Vector6<f64> {
    let phi = t.rotation.scaled_axis();
    let theta = phi.norm();
    let k = skew(&phi);
    let c = if theta < 1e-6 {
        1.0 / 12.0
    } else {
        (1.0 - theta * theta.sin() / (2.0 * (1.0 - theta.cos()))) / (theta * theta)
    };
    let v_inv = Matrix3::identity() - 0.5 * k + c * k * k;
    let rho = v_inv * t.translation.vector;
    Vector6::new(rho.x, rho.y, rho.z, phi.x, phi.y, phi.z)
}

/// Adjoint of a pose for `(ρ, φ)` twists.
pub(super) fn adjoint(t: &Pose) -> Matrix6<f64> {
    let r = t.rotation.to_rotation_matrix().into_inner();
    let mut a = Matrix6::zeros();
    a.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    a.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    a.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(skew(&t.translation.vector) * r));
    a
}

/// `J_r⁻¹(e) ≈ I + ½ ad(e)`.
fn jr_inv(e: &Vector6<f64>) -> Matrix6<f64> {
    let rho = Vector3::new(e[0], e[1], e[2]);
    let phi = Vector3::new(e[3], e[4], e[5]);
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&skew(&phi));
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&skew(&phi));
    ad.fixed_view_mut::<3, 3>(0, 3).copy_from(&skew(&rho));
    Matrix6::identity() + 0.5 * ad
}

/// An edge: measured `Z = T_i⁻¹ T_j` with its information matrix.
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    /// Index of the first pose.
    pub i: usize,
    /// Index of the second pose.
    pub j: usize,
    /// Measured relative pose `Z = T_i⁻¹ T_j`.
    pub measurement: Pose,
    /// Information (inverse covariance, symmetric) of the error `(ρ, φ)`.
    pub information: Matrix6<f64>,
    /// Whether the solver's robust kernel applies (keypoint constraints, which may be
    /// wrong); `false` for edges already gated where they were made (depth alignments).
    pub robust: bool,
}

/// An edge's information from the standard deviations of its translation (metres) and
/// rotation (degrees).
pub(crate) fn information(sigma_translation: f64, sigma_rotation_deg: f64) -> Matrix6<f64> {
    Matrix6::from_diagonal(&sqrt_information(sigma_translation, sigma_rotation_deg).map(|w| w * w))
}

/// The square root of [`information`]: one over the standard deviations.
pub(crate) fn sqrt_information(sigma_translation: f64, sigma_rotation_deg: f64) -> Vector6<f64> {
    let (t, r) = (sigma_translation, sigma_rotation_deg.to_radians());
    Vector6::new(1.0 / t, 1.0 / t, 1.0 / t, 1.0 / r, 1.0 / r, 1.0 / r)
}

/// Solver settings.
#[derive(Debug, Clone, PartialEq)]
pub struct LmSettings {
    /// Most Levenberg-Marquardt iterations.
    pub iterations: usize,
    /// Robust kernel of edges with `robust` set.
    pub kernel: RobustKernel,
    /// Kernel scale on the whitened error norm.
    pub delta: f64,
    /// Dense Cholesky ([`super::cholesky`]) up to this many variables, block-Jacobi preconditioned
    /// conjugate gradients above.
    pub dense_limit: usize,
}

impl Default for LmSettings {
    fn default() -> Self {
        LmSettings {
            iterations: 30,
            kernel: RobustKernel::Huber,
            delta: 3.0,
            dense_limit: 1800,
        }
    }
}

/// What the optimisation did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LmSummary {
    /// Robust cost ([`cost`]) before the optimisation.
    pub initial_cost: f64,
    /// Robust cost ([`cost`]) after it.
    pub final_cost: f64,
    /// Iterations run.
    pub iterations: usize,
}

/// Robust cost of a squared whitened error and its IRLS weight.
pub(super) fn robust(kernel: RobustKernel, delta: f64, r2: f64) -> (f64, f64) {
    match kernel {
        RobustKernel::None => (r2, 1.0),
        RobustKernel::Huber => {
            let r = r2.sqrt();
            if r <= delta {
                (r2, 1.0)
            } else {
                (2.0 * delta * r - delta * delta, delta / r)
            }
        }
        RobustKernel::Cauchy => {
            let d2 = delta * delta;
            (d2 * (1.0 + r2 / d2).ln(), 1.0 / (1.0 + r2 / d2))
        }
    }
}

/// The kernel an edge is solved with: `kernel`, or none for an edge that is not robust.
fn kernel_of(e: &Edge, kernel: RobustKernel) -> RobustKernel {
    if e.robust { kernel } else { RobustKernel::None }
}

fn edge_error(poses: &[Pose], e: &Edge) -> Vector6<f64> {
    se3_log(&(e.measurement.inverse() * poses[e.i].inverse() * poses[e.j]))
}

fn whitened2(err: &Vector6<f64>, info: &Matrix6<f64>) -> f64 {
    err.dot(&(info * err))
}

/// An edge linearised at the current poses.
pub(super) struct EdgeTerms {
    /// Robust cost.
    pub cost: f64,
    /// Information times the robust kernel's weight.
    pub omega: Matrix6<f64>,
    pub err: Vector6<f64>,
    /// `∂e/∂δ_i` and `∂e/∂δ_j`.
    pub ji: Matrix6<f64>,
    pub jj: Matrix6<f64>,
}

/// The error of an edge, its robust cost and weight, and its Jacobians.
pub(super) fn edge_terms(poses: &[Pose], e: &Edge, kernel: RobustKernel, delta: f64) -> EdgeTerms {
    let err = edge_error(poses, e);
    let (cost, w) = robust(kernel_of(e, kernel), delta, whitened2(&err, &e.information));
    let jr = jr_inv(&err);
    EdgeTerms {
        cost,
        omega: e.information * w,
        err,
        ji: -jr * adjoint(&(poses[e.j].inverse() * poses[e.i])),
        jj: jr,
    }
}

/// Total robust cost.
pub fn cost(poses: &[Pose], edges: &[Edge], settings: &LmSettings) -> f64 {
    edges
        .iter()
        .map(|e| {
            robust(
                kernel_of(e, settings.kernel),
                settings.delta,
                whitened2(&edge_error(poses, e), &e.information),
            )
            .0
        })
        .sum()
}

/// Block-sparse normal equations over the free poses (index `k - 1` for pose `k`).
struct Normal {
    n: usize,
    diag: Vec<Matrix6<f64>>,
    off: BTreeMap<(usize, usize), Matrix6<f64>>,
    g: Vec<Vector6<f64>>,
}

impl Normal {
    fn build(poses: &[Pose], edges: &[Edge], s: &LmSettings) -> Self {
        let n = poses.len() - 1;
        let mut nq = Normal {
            n,
            diag: vec![Matrix6::zeros(); n],
            off: BTreeMap::new(),
            g: vec![Vector6::zeros(); n],
        };
        for e in edges {
            let EdgeTerms {
                omega, err, ji, jj, ..
            } = edge_terms(poses, e, s.kernel, s.delta);
            let vars = [(e.i, ji), (e.j, jj)];
            for (a, ja) in vars {
                if a == 0 {
                    continue;
                }
                nq.g[a - 1] += ja.transpose() * omega * err;
                for (b, jb) in vars {
                    if b == 0 {
                        continue;
                    }
                    let block = ja.transpose() * omega * jb;
                    if a == b {
                        nq.diag[a - 1] += block;
                    } else if a < b {
                        *nq.off.entry((a - 1, b - 1)).or_insert_with(Matrix6::zeros) += block;
                    }
                }
            }
        }
        nq
    }

    /// `(H + λ diag(H)) x`.
    fn apply(&self, lambda: f64, x: &[Vector6<f64>]) -> Vec<Vector6<f64>> {
        let mut y: Vec<Vector6<f64>> = (0..self.n)
            .map(|k| {
                let d = &self.diag[k];
                let damp = Vector6::from_fn(|r, _| lambda * d[(r, r)].max(1e-9));
                d * x[k] + damp.component_mul(&x[k])
            })
            .collect();
        for (&(a, b), m) in &self.off {
            y[a] += m * x[b];
            y[b] += m.transpose() * x[a];
        }
        y
    }

    fn damped_diag(&self, lambda: f64, k: usize) -> Matrix6<f64> {
        let mut d = self.diag[k];
        for r in 0..6 {
            d[(r, r)] += lambda * d[(r, r)].max(1e-9);
        }
        d
    }

    /// Solves `(H + λ diag H) δ = −g`.
    fn solve(&self, lambda: f64, dense_limit: usize) -> Option<Vec<Vector6<f64>>> {
        let dim = 6 * self.n;
        if dim <= dense_limit {
            let mut h = DMatrix::<f64>::zeros(dim, dim);
            for k in 0..self.n {
                h.view_mut((6 * k, 6 * k), (6, 6))
                    .copy_from(&self.damped_diag(lambda, k));
            }
            for (&(a, b), m) in &self.off {
                h.view_mut((6 * a, 6 * b), (6, 6)).copy_from(m);
                h.view_mut((6 * b, 6 * a), (6, 6)).copy_from(&m.transpose());
            }
            let g = DVector::from_iterator(dim, self.g.iter().flat_map(|v| v.iter().map(|x| -x)));
            let x = super::cholesky::solve_spd(h, &g)?;
            Some(
                (0..self.n)
                    .map(|k| Vector6::from_fn(|r, _| x[6 * k + r]))
                    .collect(),
            )
        } else {
            self.pcg(lambda)
        }
    }

    /// Block-Jacobi preconditioned conjugate gradients.
    fn pcg(&self, lambda: f64) -> Option<Vec<Vector6<f64>>> {
        let pre: Vec<Matrix6<f64>> = (0..self.n)
            .map(|k| self.damped_diag(lambda, k).try_inverse())
            .collect::<Option<_>>()?;
        let dot = |a: &[Vector6<f64>], b: &[Vector6<f64>]| -> f64 {
            a.iter().zip(b).map(|(x, y)| x.dot(y)).sum()
        };
        let b: Vec<Vector6<f64>> = self.g.iter().map(|v| -v).collect();
        let mut x = vec![Vector6::zeros(); self.n];
        let mut r = b.clone();
        let mut z: Vec<Vector6<f64>> = r.iter().zip(&pre).map(|(v, p)| p * v).collect();
        let mut p = z.clone();
        let mut rz = dot(&r, &z);
        let b_norm = dot(&b, &b).sqrt().max(1e-300);
        for _ in 0..(10 * 6 * self.n).max(100) {
            let ap = self.apply(lambda, &p);
            let pap = dot(&p, &ap);
            if pap <= 0.0 || !pap.is_finite() {
                break;
            }
            let alpha = rz / pap;
            for k in 0..self.n {
                x[k] += alpha * p[k];
                r[k] -= alpha * ap[k];
            }
            if dot(&r, &r).sqrt() < 1e-10 * b_norm {
                break;
            }
            z = r.iter().zip(&pre).map(|(v, q)| q * v).collect();
            let rz_new = dot(&r, &z);
            let beta = rz_new / rz;
            rz = rz_new;
            for k in 0..self.n {
                p[k] = z[k] + beta * p[k];
            }
        }
        x.iter()
            .all(|v| v.iter().all(|c| c.is_finite()))
            .then_some(x)
    }
}

/// Optimises `poses` in place (pose 0 fixed) over `edges`.
pub(crate) fn optimise(poses: &mut [Pose], edges: &[Edge], settings: &LmSettings) -> LmSummary {
    let initial_cost = cost(poses, edges, settings);
    let mut summary = LmSummary {
        initial_cost,
        final_cost: initial_cost,
        iterations: 0,
    };
    if poses.len() < 2 || edges.is_empty() {
        return summary;
    }
    let mut current = initial_cost;
    let mut lambda = 1e-4;
    for it in 0..settings.iterations {
        let nq = Normal::build(poses, edges, settings);
        let mut improved = false;
        for _ in 0..10 {
            let Some(step) = nq.solve(lambda, settings.dense_limit) else {
                lambda *= 10.0;
                continue;
            };
            let candidate: Vec<Pose> = poses
                .iter()
                .enumerate()
                .map(|(k, p)| {
                    if k == 0 {
                        *p
                    } else {
                        p * se3_exp(&step[k - 1])
                    }
                })
                .collect();
            let c = cost(&candidate, edges, settings);
            if c < current {
                let small = current - c <= 1e-10 * current.max(1e-300);
                poses.copy_from_slice(&candidate);
                current = c;
                lambda = (lambda / 3.0).max(1e-12);
                improved = !small;
                break;
            }
            lambda *= 5.0;
        }
        summary.iterations = it + 1;
        if !improved {
            break;
        }
    }
    summary.final_cost = current;
    summary
}

#[cfg(test)]
mod tests;
