//! Blocked dense Cholesky solve of the symmetric positive-definite systems of the pose graph
//! and of bundle adjustment's reduced camera system.
//!
//! nalgebra's `cholesky` works column by column on scalars. The pose graph is optimised
//! again at every closed loop, on the thread beside tracking, each time with up to 30
//! factorisations of 6 variables per keyframe: over 500 real frames (210 keyframes) that was
//! 67 s of a 113 s run. Here the factorisation is right-looking in panels of `BLOCK`
//! columns: each panel is factored with small loops, and the trailing update
//! `A22 −= L21·L21ᵀ` (its lower triangle), nearly all of the work, is a few matrix products
//! through the `gemm` crate (AVX-512 / AVX2 kernels chosen at run time) on the calling thread.

use nalgebra::{DMatrix, DVector};

/// Panel width.
const BLOCK: usize = 48;

/// `x` with `h·x = g`, for symmetric positive-definite `h` (only its lower triangle is read);
/// `None` when `h` is not positive definite (a non-positive or non-finite pivot) or the sizes
/// differ.
pub(crate) fn solve_spd(mut h: DMatrix<f64>, g: &DVector<f64>) -> Option<DVector<f64>> {
    let n = h.nrows();
    if h.ncols() != n || g.len() != n {
        return None;
    }
    factor(&mut h)?;
    // L y = g, then Lᵀ x = y; the factor is in the lower triangle, column-major.
    let l = h.as_slice();
    let mut x = g.clone();
    for j in 0..n {
        let v = x[j] / l[j + j * n];
        x[j] = v;
        for i in j + 1..n {
            x[i] -= l[i + j * n] * v;
        }
    }
    for j in (0..n).rev() {
        let col = &l[j * n..(j + 1) * n];
        let s: f64 = (j + 1..n).map(|i| col[i] * x[i]).sum();
        x[j] = (x[j] - s) / col[j];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

/// Overwrites the lower triangle of `a` with its Cholesky factor `L` (`a = L·Lᵀ`).
fn factor(a: &mut DMatrix<f64>) -> Option<()> {
    let n = a.nrows();
    let data = a.as_mut_slice();
    let mut k = 0;
    while k < n {
        let b = BLOCK.min(n - k);
        // The diagonal block, unblocked (column j: scale, then update the block's later
        // columns).
        for j in k..k + b {
            let d = data[j + j * n];
            if !(d > 0.0 && d.is_finite()) {
                return None;
            }
            let d = d.sqrt();
            data[j + j * n] = d;
            // The whole column below the diagonal: the panel's rows (L11) and the rows
            // below (L21 = A21·L11⁻ᵀ, column by column).
            for i in j + 1..n {
                data[i + j * n] /= d;
            }
            for c in j + 1..k + b {
                let f = data[c + j * n];
                if f != 0.0 {
                    for i in c..n {
                        data[i + c * n] -= data[i + j * n] * f;
                    }
                }
            }
        }
        // Trailing update of A22's lower triangle, −= L21·L21ᵀ, one column block at a time
        // (each from its diagonal block down: half the products of the whole square).
        let base = data.as_mut_ptr();
        let mut c = k + b;
        while c < n {
            let w = BLOCK.min(n - c);
            let rows = n - c;
            // SAFETY: `dst` is columns c..c+w, rows c..n; `lhs` is L21's rows c..n and `rhs`
            // L21's rows c..c+w read transposed, both in columns k..k+b < c: disjoint column
            // ranges of one live column-major n×n buffer, every index below n².
            unsafe {
                let dst = base.add(c + c * n);
                let lhs = base.add(c + k * n) as *const f64;
                gemm::gemm(
                    rows,
                    w,
                    b,
                    dst,
                    n as isize,
                    1,
                    true,
                    lhs,
                    n as isize,
                    1,
                    lhs,
                    1,
                    n as isize,
                    1.0,
                    -1.0,
                    false,
                    false,
                    false,
                    gemm::Parallelism::None,
                );
            }
            c += w;
        }
        k += b;
    }
    Some(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A symmetric positive-definite matrix with a block-sparse pattern like a pose graph's.
    fn spd(n: usize, seed: u64) -> DMatrix<f64> {
        let mut s = seed;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        let m = DMatrix::from_fn(n, n, |i, j| if (i + 2 * j) % 5 == 0 { next() } else { 0.0 });
        &m * m.transpose() + DMatrix::identity(n, n) * 0.1
    }

    #[test]
    fn agrees_with_nalgebra_across_block_edges() {
        for n in [1, 5, BLOCK - 1, BLOCK, BLOCK + 1, 3 * BLOCK + 7, 300] {
            let h = spd(n, n as u64);
            let g = DVector::from_fn(n, |i, _| (i as f64 * 0.37 + 1.0).sin());
            let want = h.clone().cholesky().unwrap().solve(&g);
            let got = solve_spd(h.clone(), &g).unwrap();
            let err = (&got - &want).norm() / want.norm();
            assert!(err < 1e-9, "n {n}: relative error {err}");
            assert!((&h * &got - &g).norm() < 1e-8 * g.norm(), "n {n}: residual");
        }
    }

    #[test]
    fn refuses_indefinite_and_mismatched_systems() {
        let mut h = spd(60, 3);
        h[(50, 50)] = -1.0;
        assert!(solve_spd(h, &DVector::zeros(60)).is_none());
        let nan = DMatrix::from_element(3, 3, f64::NAN);
        assert!(solve_spd(nan, &DVector::zeros(3)).is_none());
        assert!(solve_spd(spd(4, 1), &DVector::zeros(5)).is_none());
        assert!(solve_spd(DMatrix::zeros(0, 0), &DVector::zeros(0)).is_some());
    }
}
