//! The validation pass of the SDFCNN trainer: eq. 21's loss terms and the paper's metrics
//! (eqs 16-20) of a model on unaugmented validation images, overall and per named source.

use std::collections::BTreeMap;

use super::config::SdfcnnTrainConfig;
use super::data::{SdfcnnBatch, SegDepthData};
use super::loss::LossResolution;
use super::training::{forward, loss_terms, model_device, scalar};
use super::{Sdfcnn, SdfcnnOutput};
use crate::dataset::augment::AugmentConfig;
use crate::error::{Error, Result};
use crate::metrics::{ConfusionMatrix, DepthAccumulator};
use crate::nn::resize_bilinear;
use crate::training::batch_rng;
use crate::training::fit::Meter;

/// Validation loss and the eqs 16-20 metrics of `model` on `data` at `size`, overall and for
/// each named source (`val_<name>_delta1`, ...). Depth metrics are in metres: predictions and
/// targets are taken back from the canonical camera ([`super::focal`]).
pub(super) fn validate(
    model: &Sdfcnn,
    data: &SegDepthData,
    size: [usize; 2],
    cfg: &SdfcnnTrainConfig,
    values: &mut BTreeMap<String, f64>,
) -> Result<()> {
    let device = model_device(model);
    let indices = data.first_of_each(cfg.data.val_limit);
    let mut meter = Meter::default();
    let classes = cfg.network.num_classes;
    let mut confusion = ConfusionMatrix::new(classes);
    let mut depth_acc = DepthAccumulator::default();
    let mut per_source: Vec<(ConfusionMatrix, DepthAccumulator)> = (0..data.num_sources())
        .map(|_| (ConfusionMatrix::new(classes), DepthAccumulator::default()))
        .collect();
    let none = AugmentConfig::none();
    // Batches of a training part: the memory of a training step bounds validation's too.
    for chunk in indices.chunks(cfg.batch_size.div_ceil(cfg.accumulate.max(1))) {
        let samples = data.load_batch(chunk, size, &none, &mut batch_rng(0, 0, 0))?;
        let batch = SdfcnnBatch::from_samples(&samples, &device)?;
        let quarter = forward(model, batch.images, LossResolution::Quarter)?;
        let full = SdfcnnOutput {
            seg: resize_bilinear(quarter.seg.clone(), size),
            depth: resize_bilinear(quarter.depth.clone(), size),
        };
        let at_loss = match cfg.loss.resolution {
            LossResolution::Quarter => quarter,
            LossResolution::Full => full.clone(),
        };
        let loss = cfg.loss.forward(at_loss, batch.labels, batch.depth);
        let mut terms = vec![("loss", scalar(&loss.total))];
        terms.extend(loss_terms(&loss));
        meter.add(&terms, chunk.len());
        let (labels, depth) = predictions(full)?;
        let mut offset = 0;
        for (s, &i) in samples.iter().zip(chunk) {
            let n = s.width * s.height;
            let pred_labels = &labels[offset..offset + n];
            let metres = |d: &[f32]| -> Vec<f32> { d.iter().map(|v| v / s.depth_factor).collect() };
            let (gt_depth, pred_depth) = (metres(&s.depth), metres(&depth[offset..offset + n]));
            confusion.add(&s.labels, pred_labels);
            depth_acc.add(&gt_depth, &pred_depth);
            if let Some(k) = data.source_of(i) {
                per_source[k].0.add(&s.labels, pred_labels);
                per_source[k].1.add(&gt_depth, &pred_depth);
            }
            offset += n;
        }
    }
    meter.record("val", values);
    record_metrics("val", &confusion, &depth_acc, values);
    for (k, (c, d)) in per_source.iter().enumerate() {
        if let Some(name) = data.source_name(k) {
            record_metrics(&format!("val_{name}"), c, d, values);
        }
    }
    Ok(())
}

/// `{prefix}_mpa`, `_miou`, `_pixel_acc` (when any pixel is labelled) and `{prefix}_rms`,
/// `_rel`, `_delta1..3` (when any has depth).
fn record_metrics(
    prefix: &str,
    confusion: &ConfusionMatrix,
    depth: &DepthAccumulator,
    values: &mut BTreeMap<String, f64>,
) {
    if confusion.per_class().iter().any(|c| c.gt_pixels > 0) {
        values.insert(format!("{prefix}_mpa"), confusion.mpa());
        values.insert(format!("{prefix}_miou"), confusion.miou());
        values.insert(format!("{prefix}_pixel_acc"), confusion.pixel_accuracy());
    }
    if let Some(m) = depth.finish() {
        values.insert(format!("{prefix}_rms"), m.rms);
        values.insert(format!("{prefix}_rel"), m.rel);
        values.insert(format!("{prefix}_delta1"), m.delta1);
        values.insert(format!("{prefix}_delta2"), m.delta2);
        values.insert(format!("{prefix}_delta3"), m.delta3);
    }
}

/// Argmax labels (`u8`) and depth (metres) of full-resolution outputs, row-major per image.
pub(crate) fn predictions(out: SdfcnnOutput) -> Result<(Vec<u8>, Vec<f32>)> {
    let labels = out.seg.argmax(1).into_data().convert::<i64>();
    let labels = labels
        .as_slice::<i64>()
        .map_err(|e| Error::msg(format!("reading labels: {e:?}")))?
        .iter()
        .map(|&l| l.clamp(0, 254) as u8)
        .collect();
    let depth = out
        .depth
        .into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .map_err(|e| Error::msg(format!("reading depth: {e:?}")))?;
    Ok((labels, depth))
}
