//! Brute-force Hamming matching of binary descriptors, OpenCV's
//! `BFMatcher(NORM_HAMMING, crossCheck)`: the "BF matcher" of the paper's Table 6.

use super::orb::{Descriptor, OrbFeatures};
use nalgebra::Point2;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// A match of query descriptor `query` to train descriptor `train`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct HammingMatch {
    /// Index of the descriptor in the query set.
    pub query: usize,
    /// Index of the descriptor in the train set.
    pub train: usize,
    /// Number of differing bits.
    pub distance: u32,
}

/// Number of differing bits of two descriptors.
#[inline]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    let mut d = 0;
    for (ca, cb) in a.chunks_exact(8).zip(b.chunks_exact(8)) {
        let mut wa = [0u8; 8];
        let mut wb = [0u8; 8];
        wa.copy_from_slice(ca);
        wb.copy_from_slice(cb);
        d += (u64::from_le_bytes(wa) ^ u64::from_le_bytes(wb)).count_ones();
    }
    d
}

/// For every query descriptor, its nearest train descriptor (ties go to the lower
/// index). With `cross_check`, a pair is kept only when the query is also the
/// nearest of the train descriptor among all queries (OpenCV's `crossCheck=True`).
/// Matches come in query order.
pub fn bf_match(
    query: &[Descriptor],
    train: &[Descriptor],
    cross_check: bool,
) -> Vec<HammingMatch> {
    if query.is_empty() || train.is_empty() {
        return Vec::new();
    }
    let m = train.len();
    let mut dist = vec![0u32; query.len() * m];
    dist.par_chunks_mut(m).enumerate().for_each(|(i, row)| {
        for (d, t) in row.iter_mut().zip(train) {
            *d = hamming(&query[i], t);
        }
    });
    let argmin = |it: &mut dyn Iterator<Item = u32>| {
        let mut best = (0usize, u32::MAX);
        for (k, d) in it.enumerate() {
            if d < best.1 {
                best = (k, d);
            }
        }
        best
    };
    let best_train: Vec<(usize, u32)> = (0..query.len())
        .map(|i| argmin(&mut dist[i * m..(i + 1) * m].iter().copied()))
        .collect();
    let best_query: Vec<usize> = if cross_check {
        (0..m)
            .map(|j| argmin(&mut (0..query.len()).map(|i| dist[i * m + j])).0)
            .collect()
    } else {
        Vec::new()
    };
    best_train
        .into_iter()
        .enumerate()
        .filter(|&(i, (j, _))| !cross_check || best_query[j] == i)
        .map(|(i, (j, d))| HammingMatch {
            query: i,
            train: j,
            distance: d,
        })
        .collect()
}

/// ORB keypoints of two images matched by cross-checked brute force ([`bf_match`]), as
/// `(pixel in A, pixel in B)` in A's keypoint order.
pub fn matched_pixels(a: &OrbFeatures, b: &OrbFeatures) -> Vec<(Point2<f64>, Point2<f64>)> {
    bf_match(&a.descriptors, &b.descriptors, true)
        .iter()
        .map(|m| {
            let (ka, kb) = (a.keypoints[m.query], b.keypoints[m.train]);
            (
                Point2::new(ka.x as f64, ka.y as f64),
                Point2::new(kb.x as f64, kb.y as f64),
            )
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn desc(bits: &[usize]) -> Descriptor {
        let mut d = [0u8; 32];
        for &b in bits {
            d[b / 8] |= 1 << (b % 8);
        }
        d
    }

    #[test]
    fn hamming_counts_bits() {
        assert_eq!(hamming(&desc(&[]), &desc(&[])), 0);
        assert_eq!(hamming(&desc(&[0, 63, 64, 255]), &desc(&[0])), 3);
        assert_eq!(hamming(&[0xff; 32], &[0; 32]), 256);
    }

    #[test]
    fn cross_check_keeps_mutual_nearest_only() {
        let q = [desc(&[1, 2, 3]), desc(&[1, 2, 3, 4]), desc(&[100, 101])];
        // Train 0 is nearest to both q0 (distance 0) and q1 (1): q1 loses the cross-check.
        let t = [desc(&[1, 2, 3]), desc(&[200, 201, 202, 203, 204, 205])];
        let all = bf_match(&q, &t, false);
        assert_eq!(all.len(), 3);
        assert_eq!((all[1].train, all[1].distance), (0, 1));
        let cc = bf_match(&q, &t, true);
        let pairs: Vec<_> = cc.iter().map(|m| (m.query, m.train)).collect();
        // q2 {100,101} is at 2 from t0 and 8 from t1, and t0 prefers q0.
        assert_eq!(pairs, vec![(0, 0)]);
        assert!(bf_match(&[], &t, true).is_empty());
    }
}
