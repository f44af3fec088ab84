//! Per-epoch training metrics: kept in the checkpoint state, written as
//! `metrics.csv` and plotted as curves after every epoch.

use crate::error::Result;
use crate::plot::{Series, line_chart};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// Metrics of one epoch (`epoch` counts from 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochRecord {
    /// The epoch, counted from 1.
    pub epoch: usize,
    /// Learning rate of the epoch (the schedule's).
    pub lr: f64,
    /// Wall time of the epoch, seconds.
    pub seconds: f64,
    /// Named values, e.g. `train_loss`, `val_miou`.
    pub values: BTreeMap<String, f64>,
}

/// All epochs so far.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct History {
    /// One record per epoch run.
    pub epochs: Vec<EpochRecord>,
    /// The validation of the starting weights, before the first epoch (a run that fine-tunes
    /// a trained checkpoint): epoch 0 in `metrics.csv` and the plots, so that a user sees
    /// whether training improved on them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub start: Option<BTreeMap<String, f64>>,
}

impl History {
    /// Adds a record, replacing any earlier one of the same epoch.
    pub fn push(&mut self, r: EpochRecord) {
        self.epochs.retain(|e| e.epoch != r.epoch);
        self.epochs.push(r);
    }

    /// The validation of the starting weights as epoch 0's values, then each epoch's.
    fn rows(&self) -> impl Iterator<Item = (usize, &BTreeMap<String, f64>)> {
        let start = self.start.iter().map(|v| (0, v));
        start.chain(self.epochs.iter().map(|e| (e.epoch, &e.values)))
    }

    /// Every metric name that appears.
    pub fn keys(&self) -> Vec<String> {
        let mut k: Vec<String> = self.rows().flat_map(|(_, v)| v.keys().cloned()).collect();
        k.sort();
        k.dedup();
        k
    }

    /// The epoch with the best value of `key` (`maximize` or minimise); 0 is the starting
    /// weights (when validated).
    pub fn best(&self, key: &str, maximize: bool) -> Option<(usize, f64)> {
        self.rows()
            .filter_map(|(epoch, values)| values.get(key).map(|v| (epoch, *v)))
            .filter(|(_, v)| v.is_finite())
            .max_by(|a, b| {
                if maximize {
                    a.1.total_cmp(&b.1)
                } else {
                    b.1.total_cmp(&a.1)
                }
            })
    }

    /// `epoch,lr,seconds,<metrics...>` with empty cells for missing values; the starting
    /// weights' validation is epoch 0, without a learning rate or time.
    pub fn to_csv(&self) -> String {
        let keys = self.keys();
        let mut s = String::from("epoch,lr,seconds");
        for k in &keys {
            let _ = write!(s, ",{k}");
        }
        s.push('\n');
        let row = |s: &mut String, head: String, values: &BTreeMap<String, f64>| {
            s.push_str(&head);
            for k in &keys {
                match values.get(k) {
                    Some(v) => {
                        let _ = write!(s, ",{v}");
                    }
                    None => s.push(','),
                }
            }
            s.push('\n');
        };
        if let Some(values) = &self.start {
            row(&mut s, "0,,".into(), values);
        }
        for e in &self.epochs {
            let head = format!("{},{},{:.3}", e.epoch, e.lr, e.seconds);
            row(&mut s, head, &e.values);
        }
        s
    }

    /// Writes `metrics.csv` atomically.
    pub fn write_csv(&self, path: impl AsRef<Path>) -> Result<()> {
        crate::io::write_atomic(path, self.to_csv().as_bytes())
    }

    /// Plots the metrics whose names contain any of `patterns` against the epoch.
    pub fn plot(
        &self,
        path: impl AsRef<Path>,
        title: &str,
        y_label: &str,
        patterns: &[&str],
        log_y: bool,
    ) -> Result<()> {
        let keys: Vec<String> = self
            .keys()
            .into_iter()
            .filter(|k| patterns.iter().any(|p| k.contains(p)))
            .collect();
        let series: Vec<Series<'_>> = keys
            .iter()
            .map(|k| Series {
                name: k,
                points: self
                    .rows()
                    .filter_map(|(epoch, values)| values.get(k).map(|v| (epoch as f64, *v)))
                    .collect(),
            })
            .filter(|s| !s.points.is_empty())
            .collect();
        if series.is_empty() {
            return Ok(());
        }
        line_chart(path, title, "epoch", y_label, &series, log_y)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_and_best() {
        let mut h = History::default();
        for (e, l) in [(1, 2.0), (2, 1.0), (3, 1.5)] {
            let mut values = BTreeMap::new();
            values.insert("train_loss".to_string(), l);
            if e > 1 {
                values.insert("val_miou".to_string(), 0.1 * e as f64);
            }
            h.push(EpochRecord {
                epoch: e,
                lr: 0.1,
                seconds: 1.0,
                values,
            });
        }
        assert_eq!(h.best("train_loss", false), Some((2, 1.0)));
        assert_eq!(h.best("val_miou", true).map(|b| b.0), Some(3));
        let csv = h.to_csv();
        assert!(
            csv.starts_with("epoch,lr,seconds,train_loss,val_miou\n1,0.1,1.000,2,\n"),
            "{csv}"
        );
        // The starting weights' validation: epoch 0, the best when no epoch beats it.
        let mut start = BTreeMap::new();
        start.insert("val_miou".to_string(), 0.35);
        h.start = Some(start);
        assert_eq!(h.best("val_miou", true), Some((0, 0.35)));
        assert_eq!(h.best("train_loss", false), Some((2, 1.0)));
        let csv = h.to_csv();
        assert!(
            csv.starts_with("epoch,lr,seconds,train_loss,val_miou\n0,,,,0.35\n1,0.1,1.000,2,\n"),
            "{csv}"
        );
    }
}
