//! [`super::pool_kernel`]'s plane pass for NaN-free planes on x86-64 CPUs with AVX2, written
//! with intrinsics: eight columns at a time, each window's maximum and winning tap kept in
//! registers and stored once. The compiled portable loop kept its running maxima in memory
//! and stored them through masked stores (`vmaskmovps`), slow on AMD's cores: 12 % of
//! `perf` samples of `bench --case sdfcnn-train --backend ndarray` (2026-12-07).
//!
//! Same results bit for bit: taps in the same order, a tap replaces the running maximum only
//! when strictly greater (the first maximum wins ties), columns and rows whose window leaves
//! the plane go through the same scalar rule.

use std::arch::x86_64::*;

/// Lanes of one AVX2 register of `f32`.
const LANES: usize = 8;

/// One `h × w` plane without NaNs: `out` the window maxima, `offsets` the winning taps
/// (`dy · k + dx`), as [`super::pool_kernel`]'s portable pass computes them.
///
/// # Safety
/// The CPU must have AVX2. `x`, `out` and `offsets` hold `h · w` values, `k` is odd and at
/// most 15.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn pool_plane(
    x: &[f32],
    [h, w]: [usize; 2],
    k: usize,
    out: &mut [f32],
    offsets: &mut [u8],
) {
    let n = h * w;
    assert!(x.len() >= n && out.len() >= n && offsets.len() >= n && k % 2 == 1 && k <= 15);
    let p = k / 2;
    let mut row_max = vec![0.0f32; n];
    let mut row_arg = vec![0u32; n];
    // Row pass: columns whose window lies inside the row, eight at a time.
    let inner = p..w.saturating_sub(p).max(p);
    for y in 0..h {
        let row = &x[y * w..(y + 1) * w];
        let (m_row, a_row) = (
            &mut row_max[y * w..(y + 1) * w],
            &mut row_arg[y * w..(y + 1) * w],
        );
        let mut c = inner.start;
        while c + LANES <= inner.end {
            // SAFETY: columns c − p … c + LANES − 1 + p are inside the row (c ≥ p and
            // c + LANES ≤ w − p); the stores write columns c … c + LANES − 1.
            unsafe {
                let base = row.as_ptr().add(c - p);
                let mut m = _mm256_loadu_ps(base);
                let mut a = _mm256_setzero_si256();
                for d in 1..k {
                    let v = _mm256_loadu_ps(base.add(d));
                    let gt = _mm256_cmp_ps::<_CMP_GT_OQ>(v, m);
                    m = _mm256_blendv_ps(m, v, gt);
                    a = _mm256_castps_si256(_mm256_blendv_ps(
                        _mm256_castsi256_ps(a),
                        _mm256_castsi256_ps(_mm256_set1_epi32(d as i32)),
                        gt,
                    ));
                }
                _mm256_storeu_ps(m_row.as_mut_ptr().add(c), m);
                _mm256_storeu_si256(a_row.as_mut_ptr().add(c).cast(), a);
            }
            c += LANES;
        }
        for col in (0..w).filter(|&col| col < inner.start || col >= c) {
            // The first tap inside the row, then the later ones that are.
            let first = p.saturating_sub(col);
            let (mut m, mut a) = (f32::NEG_INFINITY, first as u32);
            for d in first..k {
                let Some(&v) = row.get(col + d - p) else {
                    break;
                };
                if v > m {
                    (m, a) = (v, d as u32);
                }
            }
            (m_row[col], a_row[col]) = (m, a);
        }
    }
    // Column pass: every row's window rows lo..=hi, eight columns at a time.
    let mut arg = vec![0u32; w];
    for y in 0..h {
        let (lo, hi) = (y.saturating_sub(p), (y + p).min(h - 1));
        let o_row = &mut out[y * w..(y + 1) * w];
        let tap = |yy: usize| ((yy + p - y) * k) as u32;
        let mut c = 0;
        while c + LANES <= w {
            // SAFETY: rows lo..=hi and columns c … c + LANES − 1 are inside the plane.
            unsafe {
                let at = |yy: usize| yy * w + c;
                let mut m = _mm256_loadu_ps(row_max.as_ptr().add(at(lo)));
                let mut a = _mm256_add_epi32(
                    _mm256_loadu_si256(row_arg.as_ptr().add(at(lo)).cast()),
                    _mm256_set1_epi32(tap(lo) as i32),
                );
                for yy in lo + 1..=hi {
                    let v = _mm256_loadu_ps(row_max.as_ptr().add(at(yy)));
                    let va = _mm256_add_epi32(
                        _mm256_loadu_si256(row_arg.as_ptr().add(at(yy)).cast()),
                        _mm256_set1_epi32(tap(yy) as i32),
                    );
                    let gt = _mm256_cmp_ps::<_CMP_GT_OQ>(v, m);
                    m = _mm256_blendv_ps(m, v, gt);
                    a = _mm256_castps_si256(_mm256_blendv_ps(
                        _mm256_castsi256_ps(a),
                        _mm256_castsi256_ps(va),
                        gt,
                    ));
                }
                _mm256_storeu_ps(o_row.as_mut_ptr().add(c), m);
                _mm256_storeu_si256(arg.as_mut_ptr().add(c).cast(), a);
            }
            c += LANES;
        }
        for col in c..w {
            let (mut m, mut a) = (row_max[lo * w + col], tap(lo) + row_arg[lo * w + col]);
            for yy in lo + 1..=hi {
                let v = row_max[yy * w + col];
                if v > m {
                    (m, a) = (v, tap(yy) + row_arg[yy * w + col]);
                }
            }
            (o_row[col], arg[col]) = (m, a);
        }
        // Every tap index is below k² ≤ 225: it fits a byte.
        for (o, &a) in offsets[y * w..(y + 1) * w].iter_mut().zip(&arg) {
            *o = a as u8;
        }
    }
}
