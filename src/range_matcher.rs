//! The paper's range matcher (section IV-B, Fig. 4, eq 8): every keypoint of
//! image 1 is paired with the keypoint of image 2 whose descriptor is nearest in
//! Euclidean distance (eq 8) among the keypoints of image 2 inside a square window
//! of side 140 px centred at its position. Optional mutual-nearest and Lowe ratio
//! checks prune ambiguous pairs.
//!
//! Descriptors are `f32` rows of any dimension, stored row-major. Image-2 keypoints
//! are bucketed in a grid of half-window cells, so a query visits at most 9 cells.
//!
//! The window is centred where the keypoint is expected in image 2. The paper centres
//! it at the keypoint's own position, which assumes image motion below half the
//! window (70 px); fast rotations move points farther (fr1_rpy: ~120 px in 5 frames).
//! `guided_range_match` first estimates the image motion as an affine map from
//! confident global matches (mutual nearest neighbours passing a ratio test, RANSAC)
//! and centres each window at the mapped position; tracking centres it at the
//! position predicted by the motion model instead.

use crate::error::{Error, Result};
use crate::nn::nhwc::simd_fn;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Range matcher settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RangeMatcherConfig {
    /// Side of the square search window in pixels (the paper: 140). A keypoint of
    /// image 2 is a candidate when `|dx| ≤ window / 2` and `|dy| ≤ window / 2`.
    pub window: f32,
    /// Keep a pair only when the keypoint of image 1 is also the nearest, among the
    /// image-1 keypoints in the window around the image-2 keypoint.
    pub mutual: bool,
    /// Lowe's ratio test: keep a pair when its distance is below `ratio` times the
    /// second-nearest candidate's (a lone candidate passes).
    pub ratio: Option<f32>,
    /// The ratio test's second-nearest candidate is looked for only among keypoints
    /// farther than this many pixels from the nearest one (0: every candidate, Lowe's
    /// test). FPFDCNN's descriptors come from a 16-px cell grid (Table 12) and the
    /// training loss does not push apart descriptors closer than its `exclusion_px`, so
    /// two keypoints a few pixels apart carry nearly the same descriptor and the classic
    /// test rejects both although either is the right place.
    pub ratio_exclusion_px: f32,
}

impl Default for RangeMatcherConfig {
    fn default() -> Self {
        RangeMatcherConfig {
            window: 140.0,
            mutual: false,
            ratio: None,
            ratio_exclusion_px: 0.0,
        }
    }
}

/// A pair: keypoint `i` of image 1, keypoint `j` of image 2, Euclidean descriptor
/// distance (eq 8).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RangeMatch {
    /// Index of the keypoint in image 1.
    pub i: usize,
    /// Index of the keypoint in image 2.
    pub j: usize,
    /// Euclidean distance between their descriptors (eq 8).
    pub distance: f32,
}

/// Keypoints bucketed in square cells.
struct Grid {
    origin: [f32; 2],
    cell: f32,
    cols: usize,
    rows: usize,
    cells: Vec<Vec<usize>>,
}

impl Grid {
    fn new(points: &[[f32; 2]], cell: f32) -> Self {
        let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
        for p in points {
            for a in 0..2 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if points.is_empty() {
            lo = [0.0; 2];
            hi = [0.0; 2];
        }
        // Cap the grid size so that an enormous spread cannot exhaust memory.
        let cell = cell.max((hi[0] - lo[0]).max(hi[1] - lo[1]) / 1024.0);
        let cols = ((hi[0] - lo[0]) / cell) as usize + 1;
        let rows = ((hi[1] - lo[1]) / cell) as usize + 1;
        let mut cells = vec![Vec::new(); cols * rows];
        for (k, p) in points.iter().enumerate() {
            let c = (((p[0] - lo[0]) / cell) as usize).min(cols - 1);
            let r = (((p[1] - lo[1]) / cell) as usize).min(rows - 1);
            cells[r * cols + c].push(k);
        }
        Grid {
            origin: lo,
            cell,
            cols,
            rows,
            cells,
        }
    }

    /// Indices of the points whose cells overlap `[c - half, c + half]²`.
    fn candidates(&self, c: [f32; 2], half: f32) -> impl Iterator<Item = usize> + '_ {
        let range = |v: f32, o: f32, n: usize| {
            let lo = ((v - half - o) / self.cell).floor();
            let hi = ((v + half - o) / self.cell).floor();
            if hi < 0.0 || lo > (n - 1) as f32 {
                (1, 0) // empty
            } else {
                (lo.max(0.0) as usize, (hi as usize).min(n - 1))
            }
        };
        let (c0, c1) = range(c[0], self.origin[0], self.cols);
        let (r0, r1) = range(c[1], self.origin[1], self.rows);
        (r0..=r1).flat_map(move |r| {
            (c0..=c1).flat_map(move |col| self.cells[r * self.cols + col].iter().copied())
        })
    }
}

/// Partial sums of [`squared_l2`]: four AVX2 registers (two AVX-512 ones), so that the sums
/// do not wait on one another.
const L2_LANES: usize = 32;

/// Squared Euclidean distance, in [`L2_LANES`] partial sums so that it vectorises.
#[inline(always)]
fn squared_l2(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; L2_LANES];
    let (ca, cb) = (a.chunks_exact(L2_LANES), b.chunks_exact(L2_LANES));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| (x - y) * (x - y))
        .sum();
    for (xa, xb) in ca.zip(cb) {
        for k in 0..L2_LANES {
            let d = xa[k] - xb[k];
            acc[k] += d * d;
        }
    }
    acc.iter().sum::<f32>() + tail
}

simd_fn! {
    /// `out[c] = squared_l2(query, row candidates[c] of desc)`, compiled for the CPU's widest
    /// vectors (the same sums in the same order on every CPU).
    fn squared_l2_rows(query: &[f32], desc: &[f32], dim: usize, candidates: &[usize], out: &mut [f32]) {
        for (o, &k) in out.iter_mut().zip(candidates) {
            *o = squared_l2(query, &desc[k * dim..(k + 1) * dim]);
        }
    }
}

/// Nearest and second-nearest squared distances of `query` among the window's
/// candidates (ties to the lower index). The second-nearest is taken among the
/// candidates farther than `exclusion` pixels from the nearest one.
#[allow(clippy::too_many_arguments)]
fn nearest(
    query: &[f32],
    centre: [f32; 2],
    half: f32,
    grid: &Grid,
    points: &[[f32; 2]],
    desc: &[f32],
    dim: usize,
    exclusion: f32,
) -> Option<(usize, f32, f32)> {
    // The window's candidates first, then their distances in one tight loop: the distance
    // loop with the window test and the running minimum inside it took 6.9-7.0 % of a
    // `slam` profile (80 TUM frames) where this takes 4.9-5.2 %, the two buffers included.
    let inside: Vec<usize> = grid
        .candidates(centre, half)
        .filter(|&k| {
            let p = points[k];
            (p[0] - centre[0]).abs() <= half && (p[1] - centre[1]).abs() <= half
        })
        .collect();
    let mut dist = vec![0f32; inside.len()];
    squared_l2_rows(query, desc, dim, &inside, &mut dist);
    let mut best: Option<(usize, f32)> = None;
    let mut second = f32::INFINITY;
    for (&k, &d) in inside.iter().zip(&dist) {
        match best {
            Some((bk, bd)) if d > bd || (d == bd && k > bk) => second = second.min(d),
            Some((_, bd)) => {
                second = second.min(bd);
                best = Some((k, d));
            }
            None => best = Some((k, d)),
        }
    }
    let (bk, bd) = best?;
    if exclusion > 0.0 {
        // The runner-up depends on where the nearest is, known only now.
        let (b, r2) = (points[bk], exclusion * exclusion);
        second = inside
            .iter()
            .zip(&dist)
            .filter(|&(&k, _)| {
                let (dx, dy) = (points[k][0] - b[0], points[k][1] - b[1]);
                dx * dx + dy * dy > r2
            })
            .map(|(_, &d)| d)
            .fold(f32::INFINITY, f32::min);
    }
    Some((bk, bd, second))
}

fn check_inputs(name: &str, points: &[[f32; 2]], desc: &[f32], dim: usize) -> Result<()> {
    if desc.len() != points.len() * dim {
        return Err(Error::msg(format!(
            "range matcher: image {name} has {} keypoints but {} descriptor values (expected {} x {dim})",
            points.len(),
            desc.len(),
            points.len()
        )));
    }
    if let Some(k) = points
        .iter()
        .position(|p| !(p[0].is_finite() && p[1].is_finite()))
    {
        return Err(Error::msg(format!(
            "range matcher: keypoint {k} of image {name} has a non-finite position"
        )));
    }
    if desc.iter().any(|v| !v.is_finite()) {
        return Err(Error::msg(format!(
            "range matcher: image {name} has non-finite descriptor values"
        )));
    }
    Ok(())
}

/// An affine image-motion estimate `p₂ ≈ A·p₁ + t` (row-major `[a, b, tx, c, d, ty]`).
pub(crate) type Affine = [f64; 6];

/// Applies an [`Affine`] to a point.
pub(crate) fn apply_affine(a: &Affine, p: [f32; 2]) -> [f32; 2] {
    let (x, y) = (p[0] as f64, p[1] as f64);
    [
        (a[0] * x + a[1] * y + a[2]) as f32,
        (a[3] * x + a[4] * y + a[5]) as f32,
    ]
}

/// Settings of the global motion estimate of `guided_range_match`.
#[derive(Debug, Clone, PartialEq)]
pub struct GuideConfig {
    /// Ratio test of the global (whole-image) matches the motion is estimated from.
    pub ratio: f32,
    /// RANSAC inlier threshold, pixels.
    pub inlier_px: f64,
    /// RANSAC iterations (seeded, deterministic).
    pub iterations: usize,
    /// Fewer inliers than this: no estimate, windows stay at the keypoint positions.
    pub min_inliers: usize,
}

impl Default for GuideConfig {
    fn default() -> Self {
        GuideConfig {
            ratio: 0.85,
            inlier_px: 12.0,
            iterations: 300,
            min_inliers: 12,
        }
    }
}

/// Least-squares affine map from point pairs (`None` when degenerate).
fn fit_affine(pairs: &[([f32; 2], [f32; 2])]) -> Option<Affine> {
    use nalgebra::{Matrix3, Vector3};
    let mut ata = Matrix3::<f64>::zeros();
    let (mut atx, mut aty) = (Vector3::<f64>::zeros(), Vector3::<f64>::zeros());
    for (p, q) in pairs {
        let r = Vector3::new(p[0] as f64, p[1] as f64, 1.0);
        ata += r * r.transpose();
        atx += r * q[0] as f64;
        aty += r * q[1] as f64;
    }
    let chol = ata.cholesky()?;
    let (u, v) = (chol.solve(&atx), chol.solve(&aty));
    let a = [u[0], u[1], u[2], v[0], v[1], v[2]];
    a.iter().all(|x| x.is_finite()).then_some(a)
}

/// RANSAC estimate of the affine image motion from putative pairs; returns the
/// model refitted on its inliers and the inlier count.
pub(crate) fn estimate_affine(
    pairs: &[([f32; 2], [f32; 2])],
    cfg: &GuideConfig,
) -> Option<(Affine, usize)> {
    use rand::{RngExt, SeedableRng};
    if pairs.len() < cfg.min_inliers.max(3) {
        return None;
    }
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x5eed);
    let thr2 = (cfg.inlier_px * cfg.inlier_px) as f32;
    let inliers_of = |a: &Affine| -> Vec<usize> {
        (0..pairs.len())
            .filter(|&k| {
                let (p, q) = pairs[k];
                let m = apply_affine(a, p);
                (m[0] - q[0]).powi(2) + (m[1] - q[1]).powi(2) <= thr2
            })
            .collect()
    };
    let mut best: Vec<usize> = Vec::new();
    for _ in 0..cfg.iterations {
        let idx: [usize; 3] = std::array::from_fn(|_| rng.random_range(0..pairs.len()));
        if idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2] {
            continue;
        }
        let sample: Vec<_> = idx.iter().map(|&k| pairs[k]).collect();
        let Some(a) = fit_affine(&sample) else {
            continue;
        };
        let inl = inliers_of(&a);
        if inl.len() > best.len() {
            best = inl;
        }
    }
    if best.len() < cfg.min_inliers {
        return None;
    }
    // Least squares on the inliers, twice (the refit may gain or lose a few).
    let mut inliers = best;
    let mut a = [0.0; 6];
    for _ in 0..2 {
        if inliers.len() < cfg.min_inliers {
            return None;
        }
        a = fit_affine(&inliers.iter().map(|&k| pairs[k]).collect::<Vec<_>>())?;
        inliers = inliers_of(&a);
    }
    (inliers.len() >= cfg.min_inliers).then_some((a, inliers.len()))
}

/// The range matcher with each window centred at the keypoint's position moved by the
/// image motion estimated from the descriptors themselves (see the module docs).
/// Returns the matches and the motion estimate (`None`: too few confident global
/// matches, the windows were centred at the keypoint positions as in the paper).
pub(crate) fn guided_range_match(
    points1: &[[f32; 2]],
    desc1: &[f32],
    points2: &[[f32; 2]],
    desc2: &[f32],
    dim: usize,
    cfg: &RangeMatcherConfig,
    guide: &GuideConfig,
) -> Result<(Vec<RangeMatch>, Option<Affine>)> {
    let global = RangeMatcherConfig {
        window: f32::MAX,
        mutual: true,
        ratio: Some(guide.ratio),
        ratio_exclusion_px: cfg.ratio_exclusion_px,
    };
    let putative = range_match(points1, desc1, points2, desc2, dim, &global)?;
    let pairs: Vec<_> = putative
        .iter()
        .map(|m| (points1[m.i], points2[m.j]))
        .collect();
    let affine = estimate_affine(&pairs, guide).map(|(a, _)| a);
    let m = match affine {
        Some(a) => {
            let centres: Vec<[f32; 2]> = points1.iter().map(|&p| apply_affine(&a, p)).collect();
            range_match(&centres, desc1, points2, desc2, dim, cfg)?
        }
        None => range_match(points1, desc1, points2, desc2, dim, cfg)?,
    };
    Ok((m, affine))
}

/// Matches keypoints `points1` (descriptors `desc1`, `dim` values per keypoint) to
/// `points2` (`desc2`) with the range matcher. Returns pairs in order of `i`.
/// `points1` are the window centres: the keypoints' own positions (the paper) or where
/// they are expected in image 2 (a motion estimate or prediction).
pub(crate) fn range_match(
    points1: &[[f32; 2]],
    desc1: &[f32],
    points2: &[[f32; 2]],
    desc2: &[f32],
    dim: usize,
    cfg: &RangeMatcherConfig,
) -> Result<Vec<RangeMatch>> {
    if dim == 0 {
        return Err(Error::msg(
            "range matcher: descriptor dimension must be positive",
        ));
    }
    if cfg.window.is_nan() || cfg.window <= 0.0 {
        return Err(Error::msg(format!(
            "range matcher: window side must be a positive number of pixels, got {}",
            cfg.window
        )));
    }
    if let Some(r) = cfg.ratio
        && !(r > 0.0 && r <= 1.0)
    {
        return Err(Error::msg(format!(
            "range matcher: ratio must be in (0, 1], got {r}"
        )));
    }
    if !(cfg.ratio_exclusion_px.is_finite() && cfg.ratio_exclusion_px >= 0.0) {
        return Err(Error::msg(format!(
            "range matcher: ratio exclusion radius must be a non-negative number of pixels, got {}",
            cfg.ratio_exclusion_px
        )));
    }
    check_inputs("1", points1, desc1, dim)?;
    check_inputs("2", points2, desc2, dim)?;
    if points1.is_empty() || points2.is_empty() {
        return Ok(Vec::new());
    }
    // An unbounded window (global matching) gives a single grid cell.
    let half = (cfg.window / 2.0).min(f32::MAX);
    let grid2 = Grid::new(points2, half);
    let grid1 = cfg.mutual.then(|| Grid::new(points1, half));
    let matches = (0..points1.len())
        .into_par_iter()
        .filter_map(|i| {
            let q = &desc1[i * dim..(i + 1) * dim];
            let (j, d, second) = nearest(
                q,
                points1[i],
                half,
                &grid2,
                points2,
                desc2,
                dim,
                cfg.ratio_exclusion_px,
            )?;
            if let Some(r) = cfg.ratio
                && d.sqrt() >= r * second.sqrt()
            {
                return None;
            }
            if let Some(g1) = &grid1 {
                let back = &desc2[j * dim..(j + 1) * dim];
                let (i_back, _, _) = nearest(back, points2[j], half, g1, points1, desc1, dim, 0.0)?;
                if i_back != i {
                    return None;
                }
            }
            Some(RangeMatch {
                i,
                j,
                distance: d.sqrt(),
            })
        })
        .collect();
    Ok(matches)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn brute_force(
        p1: &[[f32; 2]],
        d1: &[f32],
        p2: &[[f32; 2]],
        d2: &[f32],
        dim: usize,
        half: f32,
    ) -> Vec<RangeMatch> {
        let mut out = Vec::new();
        for i in 0..p1.len() {
            let mut best: Option<(usize, f32)> = None;
            for j in 0..p2.len() {
                if (p1[i][0] - p2[j][0]).abs() > half || (p1[i][1] - p2[j][1]).abs() > half {
                    continue;
                }
                let d = squared_l2(&d1[i * dim..(i + 1) * dim], &d2[j * dim..(j + 1) * dim]);
                if best.is_none_or(|(_, bd)| d < bd) {
                    best = Some((j, d));
                }
            }
            if let Some((j, d)) = best {
                out.push(RangeMatch {
                    i,
                    j,
                    distance: d.sqrt(),
                });
            }
        }
        out
    }

    fn random_set(rng: &mut ChaCha8Rng, n: usize, dim: usize) -> (Vec<[f32; 2]>, Vec<f32>) {
        let pts = (0..n)
            .map(|_| [rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)])
            .collect();
        let desc = (0..n * dim).map(|_| rng.random_range(-1.0..1.0)).collect();
        (pts, desc)
    }

    #[test]
    fn finds_the_exact_nearest_in_the_window() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let dim = 24;
        let (p1, d1) = random_set(&mut rng, 700, dim);
        let (p2, d2) = random_set(&mut rng, 1500, dim);
        let got = range_match(&p1, &d1, &p2, &d2, dim, &RangeMatcherConfig::default()).unwrap();
        let want = brute_force(&p1, &d1, &p2, &d2, dim, 70.0);
        assert_eq!(got.len(), want.len());
        for (g, w) in got.iter().zip(&want) {
            assert_eq!((g.i, g.j), (w.i, w.j));
            assert!((g.distance - w.distance).abs() < 1e-5);
        }
        // Mutual matches are a subset, each the nearest both ways.
        let cfg = RangeMatcherConfig {
            mutual: true,
            ..RangeMatcherConfig::default()
        };
        let mutual = range_match(&p1, &d1, &p2, &d2, dim, &cfg).unwrap();
        assert!(!mutual.is_empty() && mutual.len() < got.len());
        let back = brute_force(&p2, &d2, &p1, &d1, dim, 70.0);
        for m in &mutual {
            assert!(back.iter().any(|b| b.i == m.j && b.j == m.i));
        }
    }

    #[test]
    fn window_excludes_far_keypoints() {
        let p1 = [[100.0, 100.0]];
        let d1 = [1.0, 0.0];
        // An identical descriptor 71 px to the right, a poor one 70 px below.
        let p2 = [[171.0, 100.0], [100.0, 170.0]];
        let d2 = [1.0, 0.0, -1.0, 0.0];
        let cfg = RangeMatcherConfig::default();
        let m = range_match(&p1, &d1, &p2, &d2, 2, &cfg).unwrap();
        assert_eq!((m[0].j, m[0].distance), (1, 2.0));
        let wide = RangeMatcherConfig {
            window: 150.0,
            ..cfg.clone()
        };
        assert_eq!(range_match(&p1, &d1, &p2, &d2, 2, &wide).unwrap()[0].j, 0);
        let narrow = RangeMatcherConfig {
            window: 100.0,
            ..cfg
        };
        assert!(
            range_match(&p1, &d1, &p2, &d2, 2, &narrow)
                .unwrap()
                .is_empty()
        );
    }

    #[test]
    fn mutual_and_ratio_checks() {
        // Image-1 keypoints 0 and 1 both prefer image-2 keypoint 0, which prefers 1.
        let p1 = [[50.0, 50.0], [60.0, 50.0]];
        let d1 = [0.0, 0.0, 0.9, 0.0];
        let p2 = [[55.0, 55.0], [58.0, 52.0]];
        let d2 = [1.0, 0.0, 0.0, 5.0];
        let plain = range_match(&p1, &d1, &p2, &d2, 2, &RangeMatcherConfig::default()).unwrap();
        assert_eq!(
            plain.iter().map(|m| (m.i, m.j)).collect::<Vec<_>>(),
            vec![(0, 0), (1, 0)]
        );
        let mutual = RangeMatcherConfig {
            mutual: true,
            ..RangeMatcherConfig::default()
        };
        let m = range_match(&p1, &d1, &p2, &d2, 2, &mutual).unwrap();
        assert_eq!(
            m.iter().map(|m| (m.i, m.j)).collect::<Vec<_>>(),
            vec![(1, 0)]
        );
        // Keypoint 0: nearest 1.0, second 5.0 (ratio 0.2); keypoint 1: 0.1 vs 5.08.
        let strict = RangeMatcherConfig {
            ratio: Some(0.1),
            ..RangeMatcherConfig::default()
        };
        let r = range_match(&p1, &d1, &p2, &d2, 2, &strict).unwrap();
        assert_eq!(r.iter().map(|m| m.i).collect::<Vec<_>>(), vec![1]);
        // A lone candidate passes the ratio test.
        let lone = range_match(&p1[..1], &d1[..2], &p2[..1], &d2[..2], 2, &strict).unwrap();
        assert_eq!(lone.len(), 1);
    }

    #[test]
    fn ratio_exclusion_ignores_near_twins_but_not_far_lookalikes() {
        // Image-2 keypoints 0 and 1 are 3 px apart with nearly the same descriptor (one
        // place); keypoint 2 is 60 px away and looks alike too (another place).
        let p1 = [[100.0, 100.0]];
        let d1 = [1.0, 0.0];
        let p2 = [[101.0, 100.0], [104.0, 100.0], [160.0, 100.0]];
        let d2 = [0.9, 0.0, 0.89, 0.0, -1.0, 0.0];
        let classic = RangeMatcherConfig {
            ratio: Some(0.8),
            ..RangeMatcherConfig::default()
        };
        assert!(
            range_match(&p1, &d1, &p2[..2], &d2[..4], 2, &classic)
                .unwrap()
                .is_empty()
        );
        let spatial = RangeMatcherConfig {
            ratio_exclusion_px: 8.0,
            ..classic.clone()
        };
        let m = range_match(&p1, &d1, &p2[..2], &d2[..4], 2, &spatial).unwrap();
        assert_eq!(m.iter().map(|m| m.j).collect::<Vec<_>>(), vec![0]);
        // A far look-alike still fails the test.
        let far = [0.9, 0.0, 0.88, 0.0, 0.89, 0.0];
        let p2_far = [[101.0, 100.0], [104.0, 100.0], [150.0, 100.0]];
        assert!(
            range_match(&p1, &d1, &p2_far, &far, 2, &spatial)
                .unwrap()
                .is_empty()
        );
        // With the far keypoint distinct, the near twins do not matter.
        let m = range_match(&p1, &d1, &p2, &d2, 2, &spatial).unwrap();
        assert_eq!(m.len(), 1);
        let bad = RangeMatcherConfig {
            ratio_exclusion_px: f32::NAN,
            ..spatial
        };
        assert!(range_match(&p1, &d1, &p2, &d2, 2, &bad).is_err());
    }

    #[test]
    fn guide_recovers_a_large_motion_the_plain_window_misses() {
        // Image 2 is image 1 rotated by 3 degrees and shifted by (110, -40) px: most true
        // partners lie outside a window centred at the keypoint's own position.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let dim = 32;
        let (p1, d1) = random_set(&mut rng, 300, dim);
        let (c, s) = (3f32.to_radians().cos(), 3f32.to_radians().sin());
        let p2: Vec<[f32; 2]> = p1
            .iter()
            .map(|p| [c * p[0] - s * p[1] + 110.0, s * p[0] + c * p[1] - 40.0])
            .collect();
        let d2: Vec<f32> = d1
            .iter()
            .map(|v| v + rng.random_range(-0.05..0.05))
            .collect();
        let cfg = RangeMatcherConfig::default();
        let correct = |m: &[RangeMatch]| m.iter().filter(|m| m.i == m.j).count();
        let plain = range_match(&p1, &d1, &p2, &d2, dim, &cfg).unwrap();
        assert!(
            correct(&plain) < 60,
            "plain window: {} correct",
            correct(&plain)
        );
        let (guided, affine) =
            guided_range_match(&p1, &d1, &p2, &d2, dim, &cfg, &GuideConfig::default()).unwrap();
        let a = affine.expect("motion estimate");
        let q = apply_affine(&a, [320.0, 240.0]);
        let want = [c * 320.0 - s * 240.0 + 110.0, s * 320.0 + c * 240.0 - 40.0];
        assert!((q[0] - want[0]).abs() < 0.5 && (q[1] - want[1]).abs() < 0.5);
        assert!(
            correct(&guided) >= 295,
            "guided: {} correct",
            correct(&guided)
        );
        // Random descriptors give no confident global matches: no estimate, the
        // plain window is used.
        let (_, d_other) = random_set(&mut rng, 300, dim);
        let (m, none) =
            guided_range_match(&p1, &d1, &p2, &d_other, dim, &cfg, &GuideConfig::default())
                .unwrap();
        assert!(none.is_none());
        assert_eq!(m, range_match(&p1, &d1, &p2, &d_other, dim, &cfg).unwrap());
    }

    #[test]
    fn affine_ransac_ignores_outliers() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let truth: Affine = [1.02, -0.05, 30.0, 0.04, 0.98, -12.0];
        let pairs: Vec<_> = (0..100)
            .map(|k| {
                let p = [rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)];
                let q = if k % 3 == 0 {
                    [rng.random_range(0.0..640.0), rng.random_range(0.0..480.0)]
                } else {
                    apply_affine(&truth, p)
                };
                (p, q)
            })
            .collect();
        let (a, n) = estimate_affine(&pairs, &GuideConfig::default()).unwrap();
        assert!(n >= 66);
        for (x, y) in a.iter().zip(&truth) {
            assert!((x - y).abs() < 1e-3, "{a:?} vs {truth:?}");
        }
        assert!(estimate_affine(&pairs[..5], &GuideConfig::default()).is_none());
    }

    #[test]
    fn bad_inputs_are_errors() {
        let cfg = RangeMatcherConfig::default();
        let p = [[0.0, 0.0]];
        assert!(range_match(&p, &[1.0, 2.0], &p, &[1.0], 2, &cfg).is_err());
        assert!(range_match(&p, &[1.0], &p, &[1.0], 0, &cfg).is_err());
        assert!(range_match(&[[f32::NAN, 0.0]], &[1.0], &p, &[1.0], 1, &cfg).is_err());
        let bad = RangeMatcherConfig {
            ratio: Some(1.5),
            ..cfg.clone()
        };
        assert!(range_match(&p, &[1.0], &p, &[1.0], 1, &bad).is_err());
        assert!(
            range_match(&[], &[], &p, &[1.0], 1, &cfg)
                .unwrap()
                .is_empty()
        );
    }
}
