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

use crate::camera::Camera;
use crate::error::{Error, Result};
use nalgebra::{
    Isometry3, Matrix3, Matrix6, Point2, Point3, Rotation3, Translation3, UnitQuaternion, Vector2,
    Vector3, Vector6,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
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
    pub n_inliers: usize,
    /// RMS reprojection error over the inliers, pixels.
    pub rms_px: f64,
    /// RANSAC iterations run.
    pub iterations: usize,
}

/// Lambda Twist P3P: the poses `T` (up to four) with `λ_i y_i = T x_i`, `λ_i > 0`, for
/// three bearing vectors `y_i` (any length) and three points `x_i`. Degenerate
/// configurations (collinear points, coincident rays) give no solution.
pub fn p3p(bearings: &[Vector3<f64>; 3], points: &[Point3<f64>; 3]) -> Vec<Isometry3<f64>> {
    let mut y = [Vector3::zeros(); 3];
    for k in 0..3 {
        let n = bearings[k].norm();
        if !(n > 0.0 && n.is_finite()) {
            return Vec::new();
        }
        y[k] = bearings[k] / n;
    }
    let x = points;
    let (d12, d13, d23) = (x[0] - x[1], x[0] - x[2], x[1] - x[2]);
    let (a12, a13, a23) = (d12.norm_squared(), d13.norm_squared(), d23.norm_squared());
    let (b12, b13, b23) = (y[0].dot(&y[1]), y[0].dot(&y[2]), y[1].dot(&y[2]));
    // The pencil of the two conics eliminating lambda_1 and lambda_2 (paper eq 11).
    let d1 = Matrix3::new(
        a23,
        -a23 * b12,
        0.0,
        -a23 * b12,
        a23 - a12,
        a12 * b23,
        0.0,
        a12 * b23,
        -a12,
    );
    let d2 = Matrix3::new(
        a23,
        0.0,
        -a23 * b13,
        0.0,
        -a13,
        a13 * b23,
        -a23 * b13,
        a13 * b23,
        a23 - a13,
    );
    // det(D1 + g D2) = c3 g^3 + c2 g^2 + c1 g + c0, through cofactor matrices.
    let cof = |m: &Matrix3<f64>| {
        Matrix3::from_columns(&[
            m.column(1).cross(&m.column(2)),
            m.column(2).cross(&m.column(0)),
            m.column(0).cross(&m.column(1)),
        ])
    };
    let (cof1, cof2) = (cof(&d1), cof(&d2));
    let c3 = d2.column(0).dot(&cof2.column(0));
    let c2 = d1.component_mul(&cof2).sum();
    let c1 = d2.component_mul(&cof1).sum();
    let c0 = d1.column(0).dot(&cof1.column(0));
    if !(c3.abs() > 1e-300 && c3.is_finite()) {
        return Vec::new();
    }
    let Some(gamma) = cubic_real_root(c2 / c3, c1 / c3, c0 / c3) else {
        return Vec::new();
    };
    let d0 = d1 + d2 * gamma;
    let Some((e1, e2, sig1, sig2)) = eig_known_zero(&d0) else {
        return Vec::new();
    };
    let ratio = -sig2 / sig1;
    if ratio.is_nan() || ratio < 0.0 {
        return Vec::new();
    }
    // Points frame and its inverse, shared by every solution.
    let xx = Matrix3::from_columns(&[d12, d13, d12.cross(&d13)]);
    let Some(xx_inv) = xx.try_inverse() else {
        return Vec::new();
    };
    let mut out = Vec::new();
    for s in [ratio.sqrt(), -ratio.sqrt()] {
        // (e1 - s e2) . lambda = 0
        let u = e1 - e2 * s;
        let lambdas = if u.x.abs() >= u.y.abs() {
            if u.x == 0.0 {
                continue;
            }
            // lambda1 = w0 lambda2 + w1 lambda3, tau = lambda3 / lambda2.
            let (w0, w1) = (-u.y / u.x, -u.z / u.x);
            let qa = (a13 - a12) * w1 * w1 + 2.0 * a12 * b13 * w1 - a12;
            let qb = -2.0 * a13 * b12 * w1 + 2.0 * a12 * b13 * w0 - 2.0 * w0 * w1 * (a12 - a13);
            let qc = (a13 - a12) * w0 * w0 - 2.0 * a13 * b12 * w0 + a13;
            positive_quadratic_roots(qa, qb, qc)
                .into_iter()
                .filter_map(|tau| {
                    let den = tau * (tau - 2.0 * b23) + 1.0;
                    (den > 0.0).then(|| {
                        let l2 = (a23 / den).sqrt();
                        let l3 = tau * l2;
                        [w0 * l2 + w1 * l3, l2, l3]
                    })
                })
                .collect::<Vec<_>>()
        } else {
            // lambda2 = w0 lambda1 + w1 lambda3, tau = lambda3 / lambda1.
            let (w0, w1) = (-u.x / u.y, -u.z / u.y);
            let qa = -a13 * w1 * w1 + 2.0 * a13 * b23 * w1 - a13 + a23;
            let qb = 2.0 * a13 * b23 * w0 - 2.0 * a23 * b13 - 2.0 * a13 * w0 * w1;
            let qc = -a13 * w0 * w0 + a23;
            positive_quadratic_roots(qa, qb, qc)
                .into_iter()
                .filter_map(|tau| {
                    let den = tau * (tau - 2.0 * b13) + 1.0;
                    (den > 0.0).then(|| {
                        let l1 = (a13 / den).sqrt();
                        let l3 = tau * l1;
                        [l1, w0 * l1 + w1 * l3, l3]
                    })
                })
                .collect::<Vec<_>>()
        };
        for l in lambdas {
            if !(l[0] > 0.0 && l[1] > 0.0 && l[2] > 0.0) {
                continue;
            }
            let l = refine_lambdas(l, [a12, a13, a23], [b12, b13, b23]);
            let v1 = y[0] * l[0] - y[1] * l[1];
            let v2 = y[0] * l[0] - y[2] * l[2];
            let yy = Matrix3::from_columns(&[v1, v2, v1.cross(&v2)]);
            let Some(r) = nearest_rotation(&(yy * xx_inv)) else {
                continue;
            };
            let t = y[0] * l[0] - r * x[0].coords;
            if t.iter().all(|v| v.is_finite()) {
                out.push(Isometry3::from_parts(
                    Translation3::from(t),
                    UnitQuaternion::from_rotation_matrix(&r),
                ));
            }
        }
    }
    out
}

/// A real root of `g^3 + b g^2 + c g + d`, polished by Newton steps.
fn cubic_real_root(b: f64, c: f64, d: f64) -> Option<f64> {
    let p = c - b * b / 3.0;
    let q = (2.0 * b * b * b - 9.0 * b * c) / 27.0 + d;
    let disc = q * q / 4.0 + p * p * p / 27.0;
    let mut g = if disc > 0.0 {
        let s = disc.sqrt();
        (-q / 2.0 + s).cbrt() + (-q / 2.0 - s).cbrt() - b / 3.0
    } else if p < 0.0 {
        let arg = (3.0 * q / (2.0 * p) * (-3.0 / p).sqrt()).clamp(-1.0, 1.0);
        2.0 * (-p / 3.0).sqrt() * (arg.acos() / 3.0).cos() - b / 3.0
    } else {
        -b / 3.0 // triple root
    };
    for _ in 0..3 {
        let f = ((g + b) * g + c) * g + d;
        let df = (3.0 * g + 2.0 * b) * g + c;
        if df == 0.0 {
            break;
        }
        g -= f / df;
    }
    g.is_finite().then_some(g)
}

/// Eigen-decomposition of a symmetric 3x3 matrix known to have a zero eigenvalue:
/// the two other eigenvectors with `|σ1| ≥ |σ2|`.
fn eig_known_zero(m: &Matrix3<f64>) -> Option<(Vector3<f64>, Vector3<f64>, f64, f64)> {
    let tr = m.trace();
    let minors = m[(0, 0)] * m[(1, 1)] + m[(0, 0)] * m[(2, 2)] + m[(1, 1)] * m[(2, 2)]
        - m[(0, 1)] * m[(0, 1)]
        - m[(0, 2)] * m[(0, 2)]
        - m[(1, 2)] * m[(1, 2)];
    let disc = (tr * tr / 4.0 - minors).max(0.0).sqrt();
    let (mut s1, mut s2) = (tr / 2.0 + disc, tr / 2.0 - disc);
    if s1.abs() < s2.abs() {
        std::mem::swap(&mut s1, &mut s2);
    }
    if s1 == 0.0 {
        return None;
    }
    // The null vector of (M - σI): the largest cross product of two of its rows.
    let eigvec = |s: f64| -> Option<Vector3<f64>> {
        let a = m - Matrix3::identity() * s;
        let rows = [
            a.row(0).transpose(),
            a.row(1).transpose(),
            a.row(2).transpose(),
        ];
        let c = [
            rows[0].cross(&rows[1]),
            rows[0].cross(&rows[2]),
            rows[1].cross(&rows[2]),
        ];
        let best = c
            .iter()
            .max_by(|p, q| p.norm_squared().total_cmp(&q.norm_squared()))?;
        let n = best.norm();
        (n > 0.0 && n.is_finite()).then(|| best / n)
    };
    Some((eigvec(s1)?, eigvec(s2)?, s1, s2))
}

/// Positive real roots of `a t^2 + b t + c` (numerically stable form).
fn positive_quadratic_roots(a: f64, b: f64, c: f64) -> Vec<f64> {
    let mut roots = Vec::with_capacity(2);
    if a.abs() < 1e-14 * (b.abs() + c.abs()).max(1e-300) {
        if b != 0.0 {
            roots.push(-c / b);
        }
    } else {
        let disc = b * b - 4.0 * a * c;
        // Slightly negative discriminants are a double root.
        if disc < -1e-12 * (b * b).max(1e-300) {
            return roots;
        }
        let sq = disc.max(0.0).sqrt();
        let q = -0.5 * (b + b.signum() * sq);
        if q != 0.0 {
            roots.push(c / q);
        }
        roots.push(q / a);
        if disc <= 0.0 {
            roots.truncate(1);
        }
    }
    roots.retain(|t| *t > 0.0 && t.is_finite());
    roots
}

/// Newton steps on the three distance equations
/// `λi² + λj² − 2 b_ij λi λj = a_ij`.
fn refine_lambdas(mut l: [f64; 3], a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    for _ in 0..5 {
        let r = Vector3::new(
            l[0] * l[0] + l[1] * l[1] - 2.0 * b[0] * l[0] * l[1] - a[0],
            l[0] * l[0] + l[2] * l[2] - 2.0 * b[1] * l[0] * l[2] - a[1],
            l[1] * l[1] + l[2] * l[2] - 2.0 * b[2] * l[1] * l[2] - a[2],
        );
        if r.abs().sum() < 1e-13 * (a[0] + a[1] + a[2]) {
            break;
        }
        let j = Matrix3::new(
            2.0 * (l[0] - b[0] * l[1]),
            2.0 * (l[1] - b[0] * l[0]),
            0.0,
            2.0 * (l[0] - b[1] * l[2]),
            0.0,
            2.0 * (l[2] - b[1] * l[0]),
            0.0,
            2.0 * (l[1] - b[2] * l[2]),
            2.0 * (l[2] - b[2] * l[1]),
        );
        let Some(step) = j.lu().solve(&r) else {
            break;
        };
        let next = [l[0] - step.x, l[1] - step.y, l[2] - step.z];
        if next.iter().any(|v| !v.is_finite()) {
            break;
        }
        l = next;
    }
    l
}

/// The rotation nearest to `m` (Frobenius norm), `None` when `m` is degenerate.
fn nearest_rotation(m: &Matrix3<f64>) -> Option<Rotation3<f64>> {
    if m.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let svd = m.svd(true, true);
    let (u, vt) = (svd.u?, svd.v_t?);
    if svd.singular_values.min() < 1e-9 * svd.singular_values.max() {
        return None;
    }
    let mut d = Matrix3::identity();
    if (u * vt).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    Some(Rotation3::from_matrix_unchecked(u * d * vt))
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

fn check_inputs(points: &[Point3<f64>], pixels: &[Point2<f64>], cfg: &PnpConfig) -> Result<()> {
    if points.len() != pixels.len() {
        return Err(Error::msg(format!(
            "PnP: {} 3D points but {} pixels",
            points.len(),
            pixels.len()
        )));
    }
    if points.len() < 4 {
        return Err(Error::msg(format!(
            "PnP needs at least 4 correspondences, got {}",
            points.len()
        )));
    }
    if let Some(k) = points
        .iter()
        .position(|p| !p.coords.iter().all(|v| v.is_finite()))
    {
        return Err(Error::msg(format!("PnP: 3D point {k} is not finite")));
    }
    if let Some(k) = pixels
        .iter()
        .position(|p| !(p.x.is_finite() && p.y.is_finite()))
    {
        return Err(Error::msg(format!("PnP: pixel {k} is not finite")));
    }
    if !(cfg.threshold_px.is_finite() && cfg.threshold_px > 0.0) {
        return Err(Error::msg(format!(
            "PnP: inlier threshold must be a positive number of pixels, got {}",
            cfg.threshold_px
        )));
    }
    if !(cfg.confidence > 0.0 && cfg.confidence < 1.0) {
        return Err(Error::msg(format!(
            "PnP: RANSAC confidence must be in (0, 1), got {}",
            cfg.confidence
        )));
    }
    Ok(())
}

/// Estimates the motion from the reference camera (where `points` are expressed)
/// to the current camera (where `pixels`, distorted, are observed), with RANSAC
/// over Lambda Twist P3P and Levenberg-Marquardt refinement. `prior` (e.g. a
/// constant-velocity guess) is scored first. Errors when there are fewer than 4
/// correspondences, on non-finite input, or when no model reaches
/// `cfg.min_inliers` (at least 4).
pub fn solve_pnp_ransac(
    points: &[Point3<f64>],
    pixels: &[Point2<f64>],
    camera: &Camera,
    prior: Option<&Isometry3<f64>>,
    cfg: &PnpConfig,
) -> Result<PnpResult> {
    check_inputs(points, pixels, cfg)?;
    let n = points.len();
    let normalized: Vec<Vector2<f64>> = pixels.iter().map(|p| camera.normalized(p)).collect();
    let bearings: Vec<Vector3<f64>> = normalized
        .iter()
        .map(|v| Vector3::new(v.x, v.y, 1.0))
        .collect();
    let focal = (camera.fx, camera.fy);
    let thr2 = cfg.threshold_px * cfg.threshold_px;
    let count = |pose: &Isometry3<f64>| -> (usize, f64) {
        let mut inl = 0;
        let mut err = 0.0;
        for (p, nv) in points.iter().zip(&normalized) {
            let e = squared_error(pose, p, nv, focal);
            if e <= thr2 {
                inl += 1;
                err += e;
            }
        }
        (inl, err)
    };
    // Best model so far: (inliers, sum of inlier squared errors, pose).
    let mut best: Option<(usize, f64, Isometry3<f64>)> = None;
    let consider = |pose: Isometry3<f64>, best: &mut Option<(usize, f64, Isometry3<f64>)>| {
        let (inl, err) = count(&pose);
        let better = match best {
            None => inl > 0,
            Some((bi, be, _)) => inl > *bi || (inl == *bi && err < *be),
        };
        if better {
            *best = Some((inl, err, pose));
        }
    };
    if let Some(p) = prior {
        consider(crate::geometry::renormalized(p), &mut best);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut needed = cfg.max_iterations;
    let mut iterations = 0;
    while iterations < needed.min(cfg.max_iterations) {
        iterations += 1;
        let i = rng.random_range(0..n);
        let mut j = rng.random_range(0..n - 1);
        if j >= i {
            j += 1;
        }
        let mut k = rng.random_range(0..n - 2);
        for m in [i.min(j), i.max(j)] {
            if k >= m {
                k += 1;
            }
        }
        let sample = [points[i], points[j], points[k]];
        if (sample[1] - sample[0])
            .cross(&(sample[2] - sample[0]))
            .norm_squared()
            < 1e-18
        {
            continue;
        }
        for pose in p3p(&[bearings[i], bearings[j], bearings[k]], &sample) {
            consider(pose, &mut best);
        }
        if let Some((inl, _, _)) = best {
            let w = inl as f64 / n as f64;
            let p_fail = 1.0 - w * w * w;
            needed = if p_fail <= f64::EPSILON {
                iterations
            } else {
                let k = ((1.0 - cfg.confidence).ln() / p_fail.ln()).ceil();
                if k.is_finite() {
                    k.max(1.0) as usize
                } else {
                    usize::MAX
                }
            };
        }
    }
    let min_inliers = cfg.min_inliers.max(4);
    let Some((inl, _, mut pose)) = best.filter(|b| b.0 >= min_inliers) else {
        return Err(Error::msg(format!(
            "PnP failed: no pose explains at least {min_inliers} of {n} correspondences within {} px (best: {})",
            cfg.threshold_px,
            best.map_or(0, |b| b.0)
        )));
    };
    let inlier_mask = |pose: &Isometry3<f64>| -> Vec<bool> {
        points
            .iter()
            .zip(&normalized)
            .map(|(p, nv)| squared_error(pose, p, nv, focal) <= thr2)
            .collect()
    };
    // Refine on the inliers, re-select them, refine again.
    for _ in 0..2 {
        let (sel_p, sel_n): (Vec<Point3<f64>>, Vec<Vector2<f64>>) = inlier_mask(&pose)
            .iter()
            .enumerate()
            .filter(|&(_, &m)| m)
            .map(|(k, _)| (points[k], normalized[k]))
            .unzip();
        if sel_p.len() < 4 {
            break;
        }
        pose = refine_pose(&sel_p, &sel_n, focal, &pose, cfg.refine_iterations);
    }
    let mask = inlier_mask(&pose);
    let n_inliers = mask.iter().filter(|&&m| m).count();
    if n_inliers < min_inliers {
        return Err(Error::msg(format!(
            "PnP failed: refinement left {n_inliers} inliers (RANSAC had {inl})"
        )));
    }
    let sq: f64 = mask
        .iter()
        .enumerate()
        .filter(|&(_, &m)| m)
        .map(|(k, _)| squared_error(&pose, &points[k], &normalized[k], focal))
        .sum();
    Ok(PnpResult {
        pose: crate::geometry::renormalized(&pose),
        inliers: mask,
        n_inliers,
        rms_px: (sq / n_inliers as f64).sqrt(),
        iterations,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::TumSequence;
    use crate::features::bf_matcher::bf_match;
    use crate::features::orb::{OrbConfig, detect_and_compute, rgb_to_gray};
    use crate::metrics::PoseErrorSegment;
    use rand::RngExt;

    fn random_pose(rng: &mut ChaCha8Rng, angle: f64, shift: f64) -> Isometry3<f64> {
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

    fn errors(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
        let d = a.inverse() * b;
        (
            d.rotation.angle().to_degrees(),
            (a.translation.vector - b.translation.vector).norm(),
        )
    }

    #[test]
    fn p3p_recovers_exact_poses() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut worst: f64 = 0.0;
        for _ in 0..200 {
            let angle = rng.random_range(0.0..3.0);
            let truth = random_pose(&mut rng, angle, 2.0);
            let inv = truth.inverse();
            // Points in front of the camera, expressed in the "world" (reference) frame.
            let pts: Vec<Point3<f64>> = (0..3)
                .map(|_| {
                    let c = Point3::new(
                        rng.random_range(-1.5..1.5),
                        rng.random_range(-1.0..1.0),
                        rng.random_range(1.0..5.0),
                    );
                    inv * c
                })
                .collect();
            let y: Vec<Vector3<f64>> = pts.iter().map(|p| (truth * p).coords * 3.7).collect();
            let sols = p3p(&[y[0], y[1], y[2]], &[pts[0], pts[1], pts[2]]);
            assert!(!sols.is_empty() && sols.len() <= 4);
            let best = sols
                .iter()
                .map(|s| {
                    let (r, t) = errors(s, &truth);
                    r + t
                })
                .fold(f64::MAX, f64::min);
            worst = worst.max(best);
        }
        assert!(worst < 1e-6, "worst {worst}");
        // Collinear points have no solution.
        let line = [
            Point3::new(0.0, 0.0, 1.0),
            Point3::new(0.0, 0.0, 2.0),
            Point3::new(0.0, 0.0, 3.0),
        ];
        let y = [Vector3::z(), Vector3::z(), Vector3::z()];
        assert!(p3p(&y, &line).is_empty());
    }

    struct Synthetic {
        pts: Vec<Point3<f64>>,
        px: Vec<Point2<f64>>,
        good: Vec<bool>,
        truth: Isometry3<f64>,
        cam: Camera,
    }

    /// Points 2-3 m in front of the reference camera, seen by the current one with
    /// the fr1 distortion, 0.5 px noise and 40 % gross outliers.
    fn synthetic(seed: u64) -> Synthetic {
        let cam = Camera::tum_fr1();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let truth = random_pose(&mut rng, 0.15, 0.15);
        let (mut pts, mut px, mut good) = (Vec::new(), Vec::new(), Vec::new());
        while pts.len() < 300 {
            let u = Point2::new(rng.random_range(0.0..640.0), rng.random_range(0.0..480.0));
            let p = cam.back_project(&u, rng.random_range(2.0..3.0));
            let Some(q) = cam.project(&(truth * p)) else {
                continue;
            };
            if !cam.contains(&q, 0.0) {
                continue;
            }
            let outlier = rng.random::<f64>() < 0.4;
            let obs = if outlier {
                Point2::new(rng.random_range(0.0..640.0), rng.random_range(0.0..480.0))
            } else {
                let n = |r: &mut ChaCha8Rng| {
                    let (a, b): (f64, f64) = (1.0 - r.random::<f64>(), r.random());
                    0.5 * (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
                };
                Point2::new(q.x + n(&mut rng), q.y + n(&mut rng))
            };
            pts.push(p);
            px.push(obs);
            good.push(!outlier);
        }
        Synthetic {
            pts,
            px,
            good,
            truth,
            cam,
        }
    }

    #[test]
    fn ransac_recovers_a_pose_through_noise_and_40_percent_outliers() {
        for seed in 0..5 {
            let Synthetic {
                pts,
                px,
                good,
                truth,
                cam,
            } = synthetic(seed);
            let res = solve_pnp_ransac(&pts, &px, &cam, None, &PnpConfig::default()).unwrap();
            let (r, t) = errors(&res.pose, &truth);
            let agree = res
                .inliers
                .iter()
                .zip(&good)
                .filter(|(a, b)| a == b)
                .count();
            eprintln!(
                "seed {seed}: rot {r:.4} deg, trans {:.2} mm, {} inliers ({} true), rms {:.2} px, {} iterations",
                t * 1e3,
                res.n_inliers,
                good.iter().filter(|&&g| g).count(),
                res.rms_px,
                res.iterations
            );
            assert!(r < 0.1 && t < 0.01, "seed {seed}: {r} deg {t} m");
            assert!(agree as f64 >= 0.97 * pts.len() as f64);
            assert!(res.rms_px < 1.0);
            // Deterministic for a seed.
            let again = solve_pnp_ransac(&pts, &px, &cam, None, &PnpConfig::default()).unwrap();
            assert_eq!(again, res);
        }
    }

    #[test]
    fn prior_is_tried_first_and_bad_input_is_an_error() {
        let Synthetic {
            pts,
            px,
            truth,
            cam,
            ..
        } = synthetic(9);
        let prior_only = PnpConfig {
            max_iterations: 0,
            ..PnpConfig::default()
        };
        let res = solve_pnp_ransac(&pts, &px, &cam, Some(&truth), &prior_only).unwrap();
        let (r, t) = errors(&res.pose, &truth);
        assert!(r < 0.1 && t < 0.01 && res.iterations == 0);
        assert!(solve_pnp_ransac(&pts, &px, &cam, None, &prior_only).is_err());
        let cfg = PnpConfig::default();
        assert!(solve_pnp_ransac(&pts[..3], &px[..3], &cam, None, &cfg).is_err());
        assert!(solve_pnp_ransac(&pts[..10], &px[..9], &cam, None, &cfg).is_err());
        let mut nan = px.clone();
        nan[2].x = f64::NAN;
        assert!(solve_pnp_ransac(&pts, &nan, &cam, None, &cfg).is_err());
        // All 3D points identical: degenerate, no model.
        let same = vec![Point3::new(0.1, 0.2, 2.0); 20];
        assert!(solve_pnp_ransac(&same, &px[..20], &cam, None, &cfg).is_err());
        let bad = PnpConfig {
            confidence: 1.0,
            ..cfg
        };
        assert!(solve_pnp_ransac(&pts, &px, &cam, None, &bad).is_err());
    }

    #[test]
    fn a_prior_with_a_non_unit_quaternion_gives_a_unit_result() {
        // Tracking chains priors (constant velocity): a result that kept the
        // prior's norm error would feed it back, growing each frame.
        let Synthetic {
            pts,
            px,
            truth,
            cam,
            ..
        } = synthetic(9);
        let off = Isometry3::from_parts(
            truth.translation,
            UnitQuaternion::new_unchecked(truth.rotation.into_inner() * (1.0 + 1e-6)),
        );
        for iterations in [0, 500] {
            let cfg = PnpConfig {
                max_iterations: iterations,
                ..PnpConfig::default()
            };
            let res = solve_pnp_ransac(&pts, &px, &cam, Some(&off), &cfg).unwrap();
            let norm = res.pose.rotation.quaternion().norm();
            assert!((norm - 1.0).abs() < 1e-12, "{iterations}: {norm}");
            let (r, t) = errors(&res.pose, &truth);
            assert!(r < 0.1 && t < 0.01, "{r} {t}");
        }
    }

    #[test]
    fn orb_pnp_on_real_frames_follows_ground_truth() {
        let seq = TumSequence::open(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/datasets/fixtures/tum_fr1_rpy_head10"
        ))
        .unwrap();
        let cam = Camera::tum_fr1();
        let (a, b) = (seq.load_frame(0).unwrap(), seq.load_frame(3).unwrap());
        let cfg = OrbConfig::default();
        let fa = detect_and_compute(&rgb_to_gray(&a.rgb), &cfg).unwrap();
        let fb = detect_and_compute(&rgb_to_gray(&b.rgb), &cfg).unwrap();
        let depth = a.depth.as_ref().unwrap();
        let (mut pts, mut px) = (Vec::new(), Vec::new());
        for m in bf_match(&fa.descriptors, &fb.descriptors, true) {
            let (ka, kb) = (fa.keypoints[m.query], fb.keypoints[m.train]);
            if let Some(z) = depth.at(ka.x as f64, ka.y as f64) {
                pts.push(cam.back_project(&Point2::new(ka.x as f64, ka.y as f64), z as f64));
                px.push(Point2::new(kb.x as f64, kb.y as f64));
            }
        }
        let res = solve_pnp_ransac(&pts, &px, &cam, None, &PnpConfig::default()).unwrap();
        let (pose_a, pose_b) = (a.gt_pose.unwrap(), b.gt_pose.unwrap());
        let gt = pose_b.inverse() * pose_a;
        let (r, t) = errors(&res.pose, &gt);
        // errT/errR of the frame pair (eqs 11-14) on the camera motion T_a⁻¹ T_b.
        let seg = PoseErrorSegment::new(&gt.inverse(), &res.pose.inverse(), None);
        eprintln!(
            "ORB+PnP 0-3: {} correspondences, {} inliers, rms {:.2} px; rotation error {r:.3} deg, translation error {:.1} mm; GT motion {:.3} deg / {:.1} mm; errT {:.1} %, errR {:.3} deg/m",
            pts.len(),
            res.n_inliers,
            res.rms_px,
            t * 1e3,
            gt.rotation.angle().to_degrees(),
            gt.translation.vector.norm() * 1e3,
            100.0 * seg.trans_error / seg.length,
            seg.rot_error_deg / seg.length
        );
        // Measured: 196 inliers, 0.49 deg and 7.4 mm; OpenCV 4.14's ORB + solvePnPRansac
        // on this pair: 0.42 deg and 5.9 mm. The floor is the ground truth's own
        // accuracy on this fast rotation (8.5 deg in 0.1 s).
        assert!(res.n_inliers >= 150);
        assert!(r < 0.8 && t < 0.015, "{r} deg {t} m");
    }
}
