//! Depth accuracy, eqs 18-20: RMS, REL and the threshold accuracies
//! δ < 1.25, 1.25², 1.25³, over pixels with a valid ground-truth depth.
//!
//! Eqs 18-19 are read in their standard form with `D*` the ground truth:
//! RMS = sqrt(mean (D − D*)²) in metres, REL = mean |D − D*| / D*.
//! Predictions are clamped to at least 1 mm for the ratio of eq 20.

use serde::{Deserialize, Serialize};

/// Running sums over valid pixels.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct DepthAccumulator {
    /// Valid pixels added.
    pub pixels: u64,
    /// Sum of squared errors `(D − D*)²`, square metres.
    pub sum_sq: f64,
    /// Sum of relative errors `|D − D*| / D*`.
    pub sum_rel: f64,
    /// Pixels with `max(D/D*, D*/D)` below 1.25, 1.25² and 1.25³.
    pub within: [u64; 3],
}

/// Final depth metrics.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DepthMetrics {
    /// RMS error (eq 18), metres.
    pub rms: f64,
    /// Mean relative error (eq 19).
    pub rel: f64,
    /// Share of pixels with δ < 1.25 (eq 20).
    pub delta1: f64,
    /// Share of pixels with δ < 1.25² (eq 20).
    pub delta2: f64,
    /// Share of pixels with δ < 1.25³ (eq 20).
    pub delta3: f64,
    /// Number of valid pixels the metrics cover.
    pub pixels: u64,
}

impl DepthAccumulator {
    /// Adds a ground-truth / prediction pair (metres; ground truth 0 = invalid).
    pub fn add(&mut self, gt: &[f32], pred: &[f32]) {
        for (&g, &p) in gt.iter().zip(pred) {
            if g <= 0.0 || !g.is_finite() || !p.is_finite() {
                continue;
            }
            let (g, p) = (g as f64, (p as f64).max(1e-3));
            self.pixels += 1;
            self.sum_sq += (p - g) * (p - g);
            self.sum_rel += (p - g).abs() / g;
            let ratio = (p / g).max(g / p);
            for (k, t) in [1.25f64, 1.25 * 1.25, 1.25 * 1.25 * 1.25]
                .iter()
                .enumerate()
            {
                if ratio < *t {
                    self.within[k] += 1;
                }
            }
        }
    }

    /// Adds another accumulator's sums to this one.
    pub fn merge(&mut self, o: &DepthAccumulator) {
        self.pixels += o.pixels;
        self.sum_sq += o.sum_sq;
        self.sum_rel += o.sum_rel;
        for k in 0..3 {
            self.within[k] += o.within[k];
        }
    }

    /// Metrics over every pixel added (`None` when there was none).
    pub fn finish(&self) -> Option<DepthMetrics> {
        if self.pixels == 0 {
            return None;
        }
        let n = self.pixels as f64;
        Some(DepthMetrics {
            rms: (self.sum_sq / n).sqrt(),
            rel: self.sum_rel / n,
            delta1: self.within[0] as f64 / n,
            delta2: self.within[1] as f64 / n,
            delta3: self.within[2] as f64 / n,
            pixels: self.pixels,
        })
    }
}

/// The scale of one prediction: the median over valid pixels of ground truth / prediction
/// (monocular depth papers' "median scaling"). 1 means metric on average; the spread of this
/// ratio over the frames of a sequence is what a monocular map built from the predictions
/// inherits as scale drift. `None` without a valid pixel.
pub fn median_scale(gt: &[f32], pred: &[f32]) -> Option<f64> {
    let mut r: Vec<f64> = gt
        .iter()
        .zip(pred)
        .filter(|(g, p)| **g > 0.0 && g.is_finite() && p.is_finite() && **p > 0.0)
        .map(|(&g, &p)| g as f64 / (p as f64).max(1e-3))
        .collect();
    if r.is_empty() {
        return None;
    }
    let mid = r.len() / 2;
    let (_, m, _) = r.select_nth_unstable_by(mid, f64::total_cmp);
    Some(*m)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_example() {
        let gt = [1.0f32, 2.0, 4.0, 0.0];
        let pred = [1.1f32, 3.0, 4.0, 9.0];
        let mut a = DepthAccumulator::default();
        a.add(&gt, &pred);
        let m = a.finish().unwrap();
        assert_eq!(m.pixels, 3);
        let rms = ((0.1f64 * 0.1 + 1.0) / 3.0).sqrt();
        assert!((m.rms - rms).abs() < 1e-6);
        assert!((m.rel - (0.1 + 0.5) / 3.0).abs() < 1e-6);
        // ratios 1.1, 1.5, 1.0 -> delta1 2/3, delta2 (1.5625) 3/3
        assert!((m.delta1 - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(m.delta2, 1.0);
        assert!(DepthAccumulator::default().finish().is_none());
    }

    #[test]
    fn median_scale_ignores_invalid_pixels() {
        // ratios 2, 2, 0.5 (0 and NaN pixels skipped): median 2.
        let gt = [2.0f32, 4.0, 1.0, 0.0, 3.0];
        let pred = [1.0f32, 2.0, 2.0, 5.0, f32::NAN];
        assert_eq!(median_scale(&gt, &pred), Some(2.0));
        assert_eq!(median_scale(&[0.0], &[1.0]), None);
    }
}
