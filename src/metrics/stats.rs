//! Summary statistics of an error vector, with evo's definitions
//! (`std` is the population standard deviation, as `numpy.std`).

use serde::{Deserialize, Serialize};

/// RMSE, mean, median, std, min, max and count of a set of errors.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Stats {
    /// Root mean square of the errors.
    pub rmse: f64,
    /// Mean of the errors.
    pub mean: f64,
    /// Median of the errors (the mean of the middle two for an even count).
    pub median: f64,
    /// Standard deviation of the errors (population: divided by the count, as numpy's).
    pub std: f64,
    /// Smallest error.
    pub min: f64,
    /// Largest error.
    pub max: f64,
    /// Number of errors (pose pairs) the statistics are over.
    pub pairs: usize,
}

/// The median of `values` (the mean of the two middle ones for an even count); NaN without
/// any.
pub fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => v[n / 2],
        _ => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

impl Stats {
    /// Statistics of `errors`; `None` when there are none.
    pub fn of(errors: &[f64]) -> Option<Stats> {
        let n = errors.len();
        if n == 0 {
            return None;
        }
        let nf = n as f64;
        let mean = errors.iter().sum::<f64>() / nf;
        let rmse = (errors.iter().map(|e| e * e).sum::<f64>() / nf).sqrt();
        let var = errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / nf;
        let median = median(errors);
        Some(Stats {
            rmse,
            mean,
            median,
            std: var.sqrt(),
            min: errors.iter().copied().min_by(f64::total_cmp)?,
            max: errors.iter().copied().max_by(f64::total_cmp)?,
            pairs: n,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stats_match_numpy() {
        // numpy: rmse 2.7386127875, mean 2.5, median 2.5, std 1.1180339887
        let s = Stats::of(&[1.0, 2.0, 3.0, 4.0]).unwrap();
        assert!((s.rmse - 2.7386127875258306).abs() < 1e-12);
        assert_eq!(
            (s.mean, s.median, s.min, s.max, s.pairs),
            (2.5, 2.5, 1.0, 4.0, 4)
        );
        assert!((s.std - 1.118033988749895).abs() < 1e-12);
        assert_eq!(Stats::of(&[3.0, 1.0, 2.0]).unwrap().median, 2.0);
        assert!(Stats::of(&[]).is_none());
    }
}
