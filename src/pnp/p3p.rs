//! Lambda Twist P3P, the minimal solver of the RANSAC loop.

use crate::geometry::nearest_rotation;
use nalgebra::{Isometry3, Matrix3, Point3, Translation3, UnitQuaternion, Vector3};

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
            let Some(r) = nearest_rotation(&(yy * xx_inv), 1e-9) else {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pnp::test_util::{errors, random_pose};
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

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
}
