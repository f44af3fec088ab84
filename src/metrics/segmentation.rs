//! Semantic segmentation accuracy, eqs 16-17: MPA (mean per-class pixel
//! accuracy) and mIoU, from a confusion matrix that ignores void pixels.
//!
//! Reading of the equations: eq 16 averages `p_ii / Σ_j p_ij` (correct over
//! ground-truth pixels of class i) over classes; eq 17 as printed counts `p_ii`
//! three times in the denominator, so we use the standard IoU
//! `p_ii / (Σ_j p_ij + Σ_j p_ji − p_ii)`. Classes absent from the ground truth
//! (no `p_ij`) are left out of the MPA mean, classes with an empty union out of
//! the mIoU mean (numpy `nanmean`, as common segmentation benchmarks do).

use crate::dataset::labels::VOID;
use serde::{Deserialize, Serialize};

/// Confusion counts: `counts[gt * k + pred]`, plus per ground-truth class the
/// pixels predicted as something that is not a class (`invalid[gt]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConfusionMatrix {
    /// Number of classes `k`.
    pub num_classes: usize,
    /// `k × k` pixel counts, row = ground-truth class, column = predicted class.
    pub counts: Vec<u64>,
    /// Per ground-truth class, pixels predicted as a value outside the classes.
    pub invalid: Vec<u64>,
}

/// Accuracy and IoU of one class (`None` where undefined).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ClassScore {
    /// Pixel accuracy of the class, TP / its ground-truth pixels (averaged into MPA, eq 16).
    pub accuracy: Option<f64>,
    /// Intersection over union, TP / (TP + FP + FN) (averaged into mIoU, eq 17).
    pub iou: Option<f64>,
    /// Ground-truth pixels of the class (invalid predictions included).
    pub gt_pixels: u64,
}

impl ConfusionMatrix {
    /// An empty matrix for `num_classes` classes.
    pub fn new(num_classes: usize) -> Self {
        ConfusionMatrix {
            num_classes,
            counts: vec![0; num_classes * num_classes],
            invalid: vec![0; num_classes],
        }
    }

    /// Adds a ground-truth / prediction pair of label images (void ground truth
    /// pixels skipped; a predicted value outside the classes counts as wrong).
    pub fn add(&mut self, gt: &[u8], pred: &[u8]) {
        let k = self.num_classes;
        for (&g, &p) in gt.iter().zip(pred) {
            if g == VOID || g as usize >= k {
                continue;
            }
            if (p as usize) < k {
                self.counts[g as usize * k + p as usize] += 1;
            } else {
                self.invalid[g as usize] += 1;
            }
        }
    }

    /// Adds another matrix's counts to this one (same number of classes).
    pub fn merge(&mut self, other: &ConfusionMatrix) {
        for (a, b) in self.counts.iter_mut().zip(&other.counts) {
            *a += b;
        }
        for (a, b) in self.invalid.iter_mut().zip(&other.invalid) {
            *a += b;
        }
    }

    /// Per-class scores.
    pub fn per_class(&self) -> Vec<ClassScore> {
        let k = self.num_classes;
        (0..k)
            .map(|i| {
                let row: u64 =
                    (0..k).map(|j| self.counts[i * k + j]).sum::<u64>() + self.invalid[i];
                let col: u64 = (0..k).map(|j| self.counts[j * k + i]).sum();
                let tp = self.counts[i * k + i];
                let union = row + col - tp;
                ClassScore {
                    accuracy: (row > 0).then(|| tp as f64 / row as f64),
                    iou: (union > 0).then(|| tp as f64 / union as f64),
                    gt_pixels: row,
                }
            })
            .collect()
    }

    /// Overall pixel accuracy.
    pub fn pixel_accuracy(&self) -> f64 {
        let k = self.num_classes;
        let total: u64 = self.counts.iter().sum::<u64>() + self.invalid.iter().sum::<u64>();
        let tp: u64 = (0..k).map(|i| self.counts[i * k + i]).sum();
        if total == 0 {
            0.0
        } else {
            tp as f64 / total as f64
        }
    }

    /// MPA, eq 16.
    pub fn mpa(&self) -> f64 {
        mean(self.per_class().iter().filter_map(|c| c.accuracy))
    }

    /// mIoU, eq 17.
    pub fn miou(&self) -> f64 {
        mean(self.per_class().iter().filter_map(|c| c.iou))
    }
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    if n == 0 { 0.0 } else { s / n as f64 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_example() {
        // 3 classes. gt: 0 0 0 1 1 2 void; pred: 0 0 1 1 2 2 0
        let gt = [0, 0, 0, 1, 1, 2, VOID];
        let pred = [0, 0, 1, 1, 2, 2, 0];
        let mut m = ConfusionMatrix::new(3);
        m.add(&gt, &pred);
        let c = m.per_class();
        assert_eq!(c[0].accuracy, Some(2.0 / 3.0));
        assert_eq!(c[1].accuracy, Some(0.5));
        assert_eq!(c[2].accuracy, Some(1.0));
        // IoU: class 0: 2 / (3 + 2 - 2) ; class 1: 1 / (2 + 2 - 1); class 2: 1 / (1 + 2 - 1)
        assert_eq!(c[0].iou, Some(2.0 / 3.0));
        assert_eq!(c[1].iou, Some(1.0 / 3.0));
        assert_eq!(c[2].iou, Some(0.5));
        assert!((m.mpa() - (2.0 / 3.0 + 0.5 + 1.0) / 3.0).abs() < 1e-12);
        assert!((m.miou() - (2.0 / 3.0 + 1.0 / 3.0 + 0.5) / 3.0).abs() < 1e-12);
        assert!((m.pixel_accuracy() - 4.0 / 6.0).abs() < 1e-12);
    }

    #[test]
    fn absent_classes_are_left_out_and_bad_predictions_are_misses() {
        let mut m = ConfusionMatrix::new(40);
        m.add(&[5, 5, 5, 5], &[5, 5, 200, 7]);
        let c = m.per_class();
        assert_eq!(c[5].accuracy, Some(0.5));
        assert_eq!(c[0].accuracy, None);
        assert!((m.mpa() - 0.5).abs() < 1e-12);
    }
}
