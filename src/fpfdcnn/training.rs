//! FPFDCNN trainer: `train --config configs/train/fpfdcnn/NN_*.toml` (or `fpfdcnn_tiny.toml`).
//!
//! Pairs of frames with their eqs 5-7 targets and the detector, localization and
//! descriptor losses; Adam by default (`[optimizer]`). The run itself (resume, progress
//! bar, metrics, plots `loss.png` and `accuracy.png`, checkpoints, the non-finite policy)
//! is [`crate::training::fit`]'s, shared with SDFCNN.

pub use super::config::FpfdcnnTrainConfig;
use super::data::{FpBatch, FpDataset, FpHostBatch};
use super::loss::{
    NearNegatives, descriptor_infonce, descriptor_shift_consistency, detector_bce,
    detector_cell_ce, ring_points, sample_descriptors, shift_consistency,
};
use super::model::Fpfdcnn;
use crate::error::{Error, Result};
use crate::nn::sum_all;
use crate::training::fit::{Fit, Learner, Meter, Plot, Step, fit};
use crate::training::{RunDir, RunOptions, batch_rng};
use burn::prelude::*;
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;
use std::path::Path;

/// Loss terms of one batch.
struct BatchLoss {
    total: Tensor<1>,
    detector: f64,
    localization: f64,
    /// The shift-consistency term, when its weight is not 0.
    shift: Option<f64>,
    /// The descriptors' shift-consistency term, when its weight is not 0.
    dshift: Option<f64>,
    descriptor: f64,
    accuracy: f64,
}

fn batch_loss(model: &Fpfdcnn, batch: FpBatch, cfg: &FpfdcnnTrainConfig) -> Result<BatchLoss> {
    let size = cfg.data.size;
    let err = Error::from;
    let image_a = batch.image_a;
    let out_a = model.forward(image_a.clone()).map_err(err)?;
    let out_b = model.forward(batch.image_b).map_err(err)?;
    let l = &cfg.loss;
    let cell = model.cell();
    // Image A again, half a cell in from every side: its FP map and descriptors against A's.
    let s = cell / 2;
    let shifted_a = if l.shift_consistency > 0.0 || l.descriptor_shift_consistency > 0.0 {
        let [n, c, h, w] = image_a.dims();
        let cropped = image_a.slice([0..n, 0..c, s..h - s, s..w - s]);
        Some(model.forward(cropped).map_err(err)?)
    } else {
        None
    };
    let shift = match &shifted_a {
        Some(out) if l.shift_consistency > 0.0 => Some(shift_consistency(
            out_a.prob.clone(),
            out.prob.clone(),
            s,
            l.pos_weight,
        )),
        _ => None,
    };
    let mut dshift_terms = Vec::new();
    let loc = (detector_cell_ce(out_a.logits, batch.target_a.clone(), cell)
        + detector_cell_ce(out_b.logits, batch.target_b.clone(), cell))
    .div_scalar(2.0);
    let det = (detector_bce(out_a.prob, batch.target_a, l.pos_weight)
        + detector_bce(out_b.prob, batch.target_b, l.pos_weight))
    .div_scalar(2.0);
    let mut desc_terms = Vec::new();
    let mut acc = 0.0;
    // A crop can hold fewer than two matches: nothing to contrast there.
    for (i, m) in batch
        .matches
        .iter()
        .enumerate()
        .filter(|(_, m)| m.len() >= 2)
    {
        let pa: Vec<[f32; 2]> = m.iter().map(|x| x.a).collect();
        let pb: Vec<[f32; 2]> = m.iter().map(|x| x.b).collect();
        let da = sample_descriptors(&out_a.descriptors, i, &pa, size);
        if let Some(out) = shifted_a
            .as_ref()
            .filter(|_| l.descriptor_shift_consistency > 0.0)
        {
            dshift_terms.extend(placement_consistency(
                &out.descriptors,
                i,
                &pa,
                &da,
                s,
                size,
            ));
        }
        let db = sample_descriptors(&out_b.descriptors, i, &pb, size);
        let near = (l.near_negatives > 0).then(|| {
            let k = l.near_negatives;
            let around = |points: &[[f32; 2]], map: &Tensor<4>| {
                let (ring, mask) = ring_points(points, k, l.near_radius_px, l.exclusion_px, size);
                let device = map.device();
                (
                    sample_descriptors(map, i, &ring, size),
                    Tensor::<2>::from_data(TensorData::new(mask, [points.len(), k]), &device),
                )
            };
            let (around_a, mask_a) = around(&pa, &out_a.descriptors);
            let (around_b, mask_b) = around(&pb, &out_b.descriptors);
            NearNegatives {
                around_a,
                mask_a,
                around_b,
                mask_b,
                per_point: k,
            }
        });
        let (t, a) = descriptor_infonce(da, db, &pb, l.tau, l.exclusion_px, near);
        desc_terms.push(t);
        acc += a as f64;
    }
    let n = desc_terms.len().max(1) as f64;
    let desc = if desc_terms.is_empty() {
        Tensor::<1>::zeros([1], &det.device())
    } else {
        sum_all(Tensor::cat(desc_terms, 0)).div_scalar(n)
    };
    let detector = det.clone().into_scalar::<f32>() as f64;
    let localization = loc.clone().into_scalar::<f32>() as f64;
    let descriptor = desc.clone().into_scalar::<f32>() as f64;
    let mut total = det.mul_scalar(l.detector_weight)
        + loc.mul_scalar(l.localization_weight)
        + desc.mul_scalar(l.descriptor_weight);
    let mut shift_value = None;
    if let Some(t) = shift {
        shift_value = Some(t.clone().into_scalar::<f32>() as f64);
        total = total + t.mul_scalar(l.shift_consistency);
    }
    // A batch without matched points inside the crop (rare) records 0.
    let mut dshift_value = (l.descriptor_shift_consistency > 0.0).then_some(0.0);
    if !dshift_terms.is_empty() {
        let k = dshift_terms.len() as f64;
        let t = sum_all(Tensor::cat(dshift_terms, 0)).div_scalar(k);
        dshift_value = Some(t.clone().into_scalar::<f32>() as f64);
        total = total + t.mul_scalar(l.descriptor_shift_consistency);
    }
    Ok(BatchLoss {
        total,
        detector,
        localization,
        shift: shift_value,
        dshift: dshift_value,
        descriptor,
        accuracy: acc / n,
    })
}

/// [`descriptor_shift_consistency`] of image `batch`'s descriptors `da` at `points` against
/// those of the same image cropped by `s` pixels on every side (`shifted`, its coarse map), at
/// the points inside that crop; `None` when none is.
fn placement_consistency(
    shifted: &Tensor<4>,
    batch: usize,
    points: &[[f32; 2]],
    da: &Tensor<2>,
    s: usize,
    [h, w]: [usize; 2],
) -> Option<Tensor<1>> {
    let lo = s as f32;
    let (x_max, y_max) = ((w - s - 1) as f32, (h - s - 1) as f32);
    let inside: Vec<usize> = (0..points.len())
        .filter(|&k| {
            let [x, y] = points[k];
            x >= lo && y >= lo && x <= x_max && y <= y_max
        })
        .collect();
    if inside.is_empty() {
        return None;
    }
    let at: Vec<[f32; 2]> = inside
        .iter()
        .map(|&k| [points[k][0] - lo, points[k][1] - lo])
        .collect();
    let other = sample_descriptors(shifted, batch, &at, [h - 2 * s, w - 2 * s]);
    let rows: Vec<i64> = inside.iter().map(|&k| k as i64).collect();
    let rows = Tensor::<1, Int>::from_data(TensorData::new(rows, [inside.len()]), &da.device());
    Some(descriptor_shift_consistency(
        da.clone().select(0, rows),
        other,
    ))
}

impl BatchLoss {
    /// The terms as the epoch means record them (`train_detector`, ...).
    fn terms(&self) -> Vec<(&'static str, f64)> {
        let mut terms = vec![
            ("detector", self.detector),
            ("localization", self.localization),
            ("descriptor", self.descriptor),
            ("desc_top1", self.accuracy),
        ];
        terms.extend(self.shift.map(|s| ("shift", s)));
        terms.extend(self.dshift.map(|s| ("dshift", s)));
        terms
    }
}

/// Trains FPFDCNN as the config says (see the module docs).
pub fn run(config_path: &Path, config_text: &str, opts: &RunOptions) -> Result<()> {
    let mut cfg = FpfdcnnTrainConfig::parse(config_text, config_path)?;
    opts.apply(
        &mut cfg.epochs,
        &mut cfg.backend,
        &mut cfg.devices,
        &mut cfg.out,
    );
    // A backend not compiled in, without a device, or not trusted to train fails before
    // anything is read or written.
    cfg.backend
        .check_training("FPFDCNN")
        .map_err(|e| Error::invalid(config_path, e.to_string()))?;
    let devices = crate::nn::devices::training_devices(cfg.backend, &cfg.devices)
        .map_err(|e| Error::invalid(config_path, e.to_string()))?;
    let device = devices[0].clone();
    for src in &mut cfg.data.sequences {
        src.camera = Some(src.resolved_camera());
    }
    let saved = toml::to_string_pretty(&cfg)?;
    let mut run = RunDir::prepare_normalized(&cfg.out, &saved, opts.resume, |text, path| {
        let c = FpfdcnnTrainConfig::parse_saved(text, path)?;
        Ok(Some(toml::to_string_pretty(&c)?))
    })?;
    run.keep = cfg.keep_checkpoints;
    println!(
        "FPFDCNN training on {} -> {}",
        cfg.backend,
        cfg.out.display()
    );
    let (train, val) = FpDataset::build(&cfg.data, cfg.data.size, |m| println!("  data: {m}"))?;
    let [h, w] = cfg.data.size;
    println!(
        "  {} training pairs ({} frames), {} validation pairs, {w}x{h}",
        train.pairs.len(),
        train.frames.len(),
        val.pairs.len(),
    );
    // A CPU backend's generator draws the initial weights (as since the first FPFDCNN runs,
    // so seeds keep their meaning), on a GPU run too: a GPU's generator draws other numbers
    // from the same seed, and its run would start from other weights than the CPU's.
    let draw = if crate::nn::backend::is_cpu(&device) {
        device.clone()
    } else {
        crate::nn::BackendKind::Ndarray
            .autodiff_device()
            .map_err(|e| Error::msg(e.to_string()))?
    };
    draw.seed(cfg.seed);
    let model = crate::nn::init::drawn(cfg.network().init(&draw)?).fork(&device);
    let model = match (&cfg.init, opts.resume) {
        (Some(init), false) => {
            let (weights, config) = crate::training::resolve_checkpoint(init)?;
            println!("  initialised from {}", weights.display());
            crate::nn::weights::load_into(model, &weights, "FPFDCNN", &config)?
        }
        _ => model,
    };
    let learner = FpLearner {
        cfg: &cfg,
        train: &train,
        val: &val,
    };
    let setup = Fit {
        run: &run,
        config: &saved,
        seed: cfg.seed,
        epochs: cfg.epochs,
        batch_size: cfg.batch_size,
        accumulate: cfg.accumulate,
        devices: &devices,
        optimizer: &cfg.optimizer,
        resume: opts.resume,
        validate_start: cfg.init.is_some() && !val.pairs.is_empty(),
        quiet: opts.quiet,
    };
    fit(&learner, &setup, model)?;
    Ok(())
}

/// FPFDCNN's part in [`fit`]: pairs of frames, eqs 5-7 targets, the three loss terms.
struct FpLearner<'a> {
    cfg: &'a FpfdcnnTrainConfig,
    train: &'a FpDataset,
    val: &'a FpDataset,
}

impl Learner for FpLearner<'_> {
    type Model = Fpfdcnn;

    fn name(&self) -> &'static str {
        "FPFDCNN"
    }

    fn train_len(&self) -> usize {
        self.train.pairs.len()
    }

    fn samples_per_epoch(&self) -> usize {
        self.cfg.data.pairs_per_epoch
    }

    type Batch = FpHostBatch;

    fn load(&self, ids: &[usize], rng: &mut ChaCha8Rng) -> Result<FpHostBatch> {
        let cfg = self.cfg;
        let augment = Some(&cfg.data.augment);
        self.train.load(ids, augment, cfg.loss.max_matches, rng)
    }

    fn train_step(&self, model: &Fpfdcnn, batch: FpHostBatch) -> Result<Step> {
        let cfg = self.cfg;
        // The model's device: the run's, or one of its data-parallel devices.
        let batch = batch.into_device(&crate::training::module_device(model));
        let l = batch_loss(model, batch, cfg)?;
        Ok(Step {
            terms: l.terms(),
            loss: l.total,
            // Each term is already a mean over the batch's pairs (the descriptor term over
            // those with matches), so every batch counts once in the epoch means.
            samples: 1,
        })
    }

    /// Validation loss terms and descriptor top-1 accuracy, without augmentation, on at
    /// most `data.val_pairs` pairs spread over the validation split.
    fn validate(&self, model: &Fpfdcnn, values: &mut BTreeMap<String, f64>) -> Result<()> {
        let cfg = self.cfg;
        let n = self.val.pairs.len();
        if n == 0 {
            return Ok(());
        }
        let device = cfg.backend.device()?;
        let model = model.clone().to_device(&device);
        let keep = match cfg.data.val_pairs {
            0 => n,
            k => k.min(n),
        };
        let ids: Vec<usize> = (0..keep).map(|k| k * n / keep).collect();
        let mut meter = Meter::default();
        let part = cfg.batch_size.div_ceil(cfg.accumulate.max(1));
        for (bi, c) in ids.chunks(part).enumerate() {
            let mut rng = batch_rng(cfg.seed, usize::MAX, bi);
            let batch = self
                .val
                .batch(c, None, cfg.loss.max_matches, &mut rng, &device)?;
            let l = batch_loss(&model, batch, cfg)?;
            let mut terms = vec![("loss", l.total.clone().into_scalar::<f32>() as f64)];
            terms.extend(l.terms());
            meter.add(&terms, 1);
        }
        meter.record("val", values);
        Ok(())
    }

    fn plots(&self) -> &'static [Plot] {
        &[
            Plot {
                file: "loss.png",
                title: "FPFDCNN loss",
                y_label: "loss",
                keys: &["loss", "detector", "localization", "descriptor"],
                log_y: true,
            },
            Plot {
                file: "accuracy.png",
                title: "descriptor top-1 match (within pair)",
                y_label: "share",
                keys: &["top1"],
                log_y: false,
            },
        ]
    }
}

/// FPFDCNN's training step on wgpu against the CPU's (built with the `wgpu` feature; lavapipe is
/// enough): `cargo test --release --features wgpu --lib fpfdcnn::training::gpu_tests`.
#[cfg(all(test, feature = "wgpu"))]
mod gpu_tests {
    use super::*;
    use crate::dataset::FpMatch;
    use crate::nn::{BackendKind, seeded_init};

    fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data()
            .convert::<f32>()
            .try_to_vec::<f32>()
            .expect("f32")
    }

    /// A deterministic batch of `n` pairs at `[h, w]` with `m` matches each.
    fn batch(device: &Device, n: usize, [h, w]: [usize; 2], m: usize) -> FpBatch {
        let image = |salt: usize| -> Vec<f32> {
            (0..n * h * w)
                .map(|i| (((i * 7919 + salt * 104729) % 1009) as f32) / 1009.0)
                .collect()
        };
        let target = |salt: usize| -> Vec<f32> {
            (0..n * h * w)
                .map(|i| f32::from((i * 31 + salt * 17).is_multiple_of(97)))
                .collect()
        };
        let t = |v: Vec<f32>| Tensor::<4>::from_data(TensorData::new(v, [n, 1, h, w]), device);
        let matches = (0..n)
            .map(|b| {
                (0..m)
                    .map(|k| {
                        let x = 5.0 + ((k * 37 + b * 11) % (w - 12)) as f32 + 0.25;
                        let y = 5.0 + ((k * 53 + b * 7) % (h - 12)) as f32 + 0.5;
                        FpMatch {
                            a: [x, y],
                            b: [x + 1.5, y - 0.75],
                        }
                    })
                    .collect()
            })
            .collect();
        FpBatch {
            image_a: t(image(1)),
            image_b: t(image(2)),
            target_a: t(target(1)),
            target_b: t(target(2)),
            matches,
        }
    }

    /// Every parameter's gradient, in the module's order.
    struct ParamGrads<'a> {
        grads: &'a burn::tensor::Gradients,
        out: Vec<Vec<f32>>,
    }

    impl burn::module::ModuleVisitor for ParamGrads<'_> {
        fn visit_float<const D: usize>(&mut self, param: &burn::module::Param<Tensor<D>>) {
            if let Some(g) = param.val().grad(self.grads) {
                self.out.push(values(g));
            }
        }
    }

    /// The loss terms (detector, localisation, descriptor) and the parameter gradients of one
    /// step of the tiny config's network from seeded weights.
    fn step(device: &Device, cfg: &FpfdcnnTrainConfig) -> (Vec<f64>, Vec<Vec<f32>>) {
        let model = seeded_init(cfg.network().init(device).expect("init"), 3);
        let l = batch_loss(&model, batch(device, 2, cfg.data.size, 24), cfg).expect("loss");
        let terms = vec![l.detector, l.localization, l.descriptor];
        let grads = l.total.backward();
        let mut v = ParamGrads {
            grads: &grads,
            out: Vec::new(),
        };
        model.visit(&mut v);
        (terms, v.out)
    }

    /// Each loss term alone and all three together: the terms within 1e-4 of the CPU's and
    /// every parameter's gradient within 1e-4 of the model's largest (FPFDCNN has no batch
    /// norm, so float32 sums in another order stay near 1e-5 here: lavapipe, 2026-12-07).
    /// Skipped without a wgpu adapter unless `SDF_SLAM_REQUIRE_GPU=1`.
    #[test]
    fn the_training_step_on_wgpu_matches_the_cpu_term_by_term() {
        let Ok(gpu) = BackendKind::Wgpu.autodiff_device() else {
            assert!(
                std::env::var("SDF_SLAM_REQUIRE_GPU").is_err(),
                "no wgpu adapter"
            );
            eprintln!("no wgpu adapter: skipped");
            return;
        };
        let root = env!("CARGO_MANIFEST_DIR");
        let path = Path::new(root).join("configs/train/fpfdcnn_tiny.toml");
        let text = std::fs::read_to_string(&path).expect("config");
        let base = FpfdcnnTrainConfig::parse(&text, &path).expect("parse");
        let cpu = BackendKind::Flex.autodiff_device().expect("flex");
        let mut failures = Vec::new();
        for which in ["all", "detector", "localization", "descriptor"] {
            let mut cfg = base.clone();
            if which != "all" {
                let only = |term: &str| f64::from(u8::from(which == term));
                cfg.loss.detector_weight = only("detector");
                cfg.loss.localization_weight = only("localization");
                cfg.loss.descriptor_weight = only("descriptor");
            }
            let (tc, gc) = step(&cpu, &cfg);
            let (tg, gg) = step(&gpu, &cfg);
            let terms = tg
                .iter()
                .zip(&tc)
                .map(|(g, c)| (g - c).abs() / c.abs().max(1e-6))
                .fold(0.0f64, f64::max);
            let scale = gc.iter().flatten().fold(1e-12f32, |m, v| m.max(v.abs()));
            let grads = gg
                .iter()
                .zip(&gc)
                .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
                .fold(0.0f32, f32::max)
                / scale;
            eprintln!("{which}: terms {terms:.2e}, gradients {grads:.2e} of the largest");
            if gg.len() != gc.len() || terms > 1e-4 || grads > 1e-4 {
                failures.push(format!("{which}: terms {terms:.2e}, gradients {grads:.2e}"));
            }
        }
        assert!(failures.is_empty(), "{}", failures.join("\n"));
    }
}
