//! `eval seg`: SDFCNN segmentation and depth accuracy at the images' own resolution, printed as
//! the paper's Table 8 (MPA, mIoU, time, parameters) and Table 9 (RMS, REL, δ1-3, time,
//! parameters), plus a per-class table. `--data` is a NYUv2 layout (labels and depth) or a
//! TUM RGB-D sequence (depth only, `--frames` / `--every` select frames); the depth is made
//! metric for the data's camera (`--camera`, the folder's `camera.toml`, or NYUv2's camera for
//! NYU layouts), see `sdf_slam::sdfcnn::focal`.

use anyhow::Result;
use clap::Args;
use sdf_slam::classes::NYU40;
use sdf_slam::metrics::{ConfusionMatrix, DepthAccumulator, DepthMetrics, median_scale};
use sdf_slam::nn::BackendKind;
use sdf_slam::sdfcnn::SdfcnnPredictor;
use sdf_slam::sdfcnn::data::{DataSource, Set};
use sdf_slam::sdfcnn::inference::{colorize_depth, colorize_labels, save_figure};
use serde_json::json;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct SegArgs {
    /// Checkpoint: model.bpk (with config.toml beside it), its folder, or a run folder.
    #[arg(long)]
    checkpoint: PathBuf,
    /// NYUv2-layout dataset folder, the official nyu_depth_v2_labeled.mat, or a TUM RGB-D
    /// sequence folder (depth only).
    #[arg(long)]
    data: PathBuf,
    /// Split list (ids or 1-based indices; NYU layouts).
    #[arg(long)]
    split: Option<PathBuf>,
    /// The camera: fr1, fr2, fr3 or a camera TOML file [default: the folder's camera.toml;
    /// NYUv2's camera for NYU layouts without one].
    #[arg(long)]
    camera: Option<String>,
    /// TUM sequences: frames FIRST END (0-based, END excluded) [default: all].
    #[arg(long, num_args = 2, value_names = ["FIRST", "END"])]
    frames: Option<Vec<usize>>,
    /// TUM sequences: every N-th frame.
    #[arg(long, default_value_t = 1)]
    every: usize,
    /// Backend.
    #[arg(long, value_enum, default_value_t = BackendKind::Ndarray)]
    backend: BackendKind,
    /// Depth PNG scale (metres = value / scale).
    #[arg(long, default_value_t = 5000.0)]
    depth_scale: f64,
    /// Evaluate the first N images only.
    #[arg(long)]
    limit: Option<usize>,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write colourised predictions and RGB | labels | depth figures here.
    #[arg(long)]
    out: Option<PathBuf>,
}

/// One image's depth range, true against predicted, over the pixels with a valid sensor depth:
/// the medians, and the least-squares slope of log true on log predicted depth (1: the
/// prediction's range fits; above 1: the prediction compresses the true range, and
/// stretching it by that factor in log depth about its mean would fit better).
struct ImageDepth {
    true_median: f64,
    predicted_median: f64,
    log_slope: Option<f64>,
}

impl ImageDepth {
    fn of(truth: &[f32], pred: &[f32]) -> Option<Self> {
        let (t, p): (Vec<f64>, Vec<f64>) = truth
            .iter()
            .zip(pred)
            .filter(|(g, q)| **g > 0.0 && g.is_finite() && **q > 0.0 && q.is_finite())
            .map(|(&g, &q)| (g as f64, q as f64))
            .unzip();
        if t.is_empty() {
            return None;
        }
        let n = t.len() as f64;
        let (lt, lp): (Vec<f64>, Vec<f64>) =
            t.iter().zip(&p).map(|(a, b)| (a.ln(), b.ln())).unzip();
        let (mt, mp) = (lt.iter().sum::<f64>() / n, lp.iter().sum::<f64>() / n);
        let var: f64 = lp.iter().map(|b| (b - mp).powi(2)).sum();
        let cov: f64 = lt.iter().zip(&lp).map(|(a, b)| (a - mt) * (b - mp)).sum();
        Some(ImageDepth {
            true_median: median(t),
            predicted_median: median(p),
            log_slope: (var > 1e-12 * n).then(|| cov / var),
        })
    }
}

/// The median of `v` (NaN when empty): of the times per image (the first, warm-up run not
/// counted) and of an image's depths.
fn median(v: Vec<f64>) -> f64 {
    sdf_slam::metrics::stats::median(&v)
}

/// The images of `--data` with their camera, checked as a training source is
/// (`sdf_slam::sdfcnn::data::Set`).
fn open_data(a: &SegArgs) -> Result<Set> {
    let source = DataSource {
        split: a.split.clone(),
        depth_scale: Some(a.depth_scale),
        camera: a.camera.clone(),
        frames: a.frames.as_deref().map(|f| [f[0], f[1]]),
        every: (a.every != 1).then_some(a.every),
        ..DataSource::folder(&a.data)
    };
    Ok(Set::open(&source)?)
}

pub fn run(a: &SegArgs) -> Result<()> {
    if a.limit == Some(0) {
        anyhow::bail!("--limit 0: at least one image must be evaluated");
    }
    a.backend.check()?;
    let data = open_data(a)?;
    let fx = data.fx();
    let predictor = SdfcnnPredictor::load(&a.checkpoint, a.backend)?;
    let params = predictor.num_params();
    let classes = predictor.config.num_classes;
    let n = a.limit.map_or(data.len(), |l| l.min(data.len()));
    // One writer per output folder.
    let _lock = match &a.out {
        Some(out) => Some(sdf_slam::output_lock::OutputLock::acquire(
            out,
            &sdf_slam::output_lock::command_line(),
        )?),
        None => None,
    };
    let mut confusion = ConfusionMatrix::new(classes);
    let mut depth = DepthAccumulator::default();
    // Per image: its median scale and the metrics after dividing it out (scale-invariant).
    let mut scales = Vec::new();
    let mut rescaled = DepthAccumulator::default();
    let mut per_image = Vec::new();
    let mut times = Vec::with_capacity(n);
    for i in 0..n {
        let (rgb, gt_depth, gt_labels) = data.load(i)?;
        if i == 0 {
            predictor.predict(&rgb)?; // warm-up
        }
        let (pred, seconds) = predictor.predict_timed_for_camera(&rgb, Some(fx))?;
        times.push(seconds);
        confusion.add(&gt_labels.data, &pred.labels.data);
        if let Some(d) = &gt_depth {
            depth.add(&d.data, &pred.depth.data);
            if let Some(r) = ImageDepth::of(&d.data, &pred.depth.data) {
                per_image.push(json!({"id": data.id(i), "true_median_m": r.true_median,
                    "predicted_median_m": r.predicted_median, "log_slope": r.log_slope}));
            }
            if let Some(s) = median_scale(&d.data, &pred.depth.data) {
                scales.push(s);
                let scaled: Vec<f32> = pred.depth.data.iter().map(|&p| p * s as f32).collect();
                rescaled.add(&d.data, &scaled);
            }
        }
        if let Some(out) = &a.out {
            let id = data.id(i);
            let png = |img: image::RgbImage, suffix: &str| {
                sdf_slam::imageio::write_png_atomic(
                    out.join(format!("{id}_{suffix}.png")),
                    &image::DynamicImage::ImageRgb8(img),
                )
            };
            png(colorize_labels(&pred.labels), "labels")?;
            png(colorize_depth(&pred.depth, None), "depth")?;
            save_figure(
                out.join(format!("{id}_figure.png")),
                &rgb,
                &pred,
                Some((&gt_labels, gt_depth.as_ref())),
            )?;
        }
        eprint!("\r{}/{n} images", i + 1);
    }
    eprintln!();
    let time = median(times.clone());
    let m = depth.finish();
    let labelled = confusion.per_class().iter().any(|c| c.gt_pixels > 0);
    let seg = labelled.then(|| (confusion.mpa(), confusion.miou()));
    print_tables(a, &predictor, n, seg, m, time, params);
    let scale = ScaleSummary::of(scales, rescaled.finish());
    if let Some(s) = &scale {
        s.print();
    }
    if let Some(canonical) = predictor.depth_focal {
        println!(
            "Depth made metric for a camera of fx {fx:.1} px (the network predicts it for a focal \
             length of {canonical:.4} image widths; see src/sdfcnn/focal.rs)."
        );
    }
    if labelled {
        print_classes(&confusion);
    }
    if let Some(p) = &a.json {
        let per_class: Vec<_> = confusion
            .per_class()
            .iter()
            .enumerate()
            .map(|(i, c)| {
                json!({"id": i, "name": NYU40.get(i), "accuracy": c.accuracy, "iou": c.iou,
                       "gt_pixels": c.gt_pixels})
            })
            .collect();
        let v = json!({
            "checkpoint": predictor.checkpoint, "data": a.data, "images": n,
            "camera_fx": fx, "depth_focal": predictor.depth_focal,
            "backend": a.backend.to_string(),
            "mpa": seg.map(|s| s.0), "miou": seg.map(|s| s.1),
            "pixel_accuracy": labelled.then(|| confusion.pixel_accuracy()),
            "depth": m, "scale": scale, "time_per_image_s": time, "time_mean_s": times.iter().sum::<f64>() / n.max(1) as f64,
            "parameters": params, "per_class": per_class, "per_image": per_image,
        });
        sdf_slam::io::write_atomic(p, serde_json::to_string_pretty(&v)?.as_bytes())?;
        println!("wrote {}", p.display());
    }
    Ok(())
}

fn print_tables(
    a: &SegArgs,
    predictor: &SdfcnnPredictor,
    n: usize,
    seg: Option<(f64, f64)>,
    depth: Option<DepthMetrics>,
    time: f64,
    params: usize,
) {
    let p = format!("{:.2} M", params as f64 / 1e6);
    println!(
        "SDFCNN {} on {} ({n} images at their own resolution, {} backend)\n",
        predictor.checkpoint.display(),
        a.data.display(),
        a.backend
    );
    println!("Table 8. Semantic segmentation (eqs 16-17; void pixels ignored)\n");
    println!("| Network | MPA | MIoU | Time | Parameter |");
    println!("|---|---|---|---|---|");
    println!("| DeepLab [6] (paper) | 0.614 | 0.354 | 1.44 s | 452.9 M |");
    println!("| SDFCNN (paper) | 0.561 | 0.319 | 0.66 s | 11.8 M |");
    match seg {
        Some((mpa, miou)) => {
            println!("| SDFCNN (this run) | {mpa:.3} | {miou:.3} | {time:.3} s | {p} |\n")
        }
        None => println!(
            "| SDFCNN (this run) | - | - | {time:.3} s | {p} |\n\n(no ground-truth labels)\n"
        ),
    }
    println!("Table 9. Depth (eqs 18-20; pixels with ground-truth depth)\n");
    println!("| Network | RMS | REL | Accuracy (1.25/1.25²/1.25³) | Time | Parameter |");
    println!("|---|---|---|---|---|---|");
    println!("| FCRN [7] (paper) | 0.590 | 0.131 | 0.715/0.864/0.916 | 1.38 s | 242 M |");
    println!("| SDFCNN (paper) | 0.692 | 0.149 | 0.761/0.950/0.989 | 0.66 s | 11.8 M |");
    match depth {
        Some(d) => println!(
            "| SDFCNN (this run) | {:.3} | {:.3} | {:.3}/{:.3}/{:.3} | {time:.3} s | {p} |\n",
            d.rms, d.rel, d.delta1, d.delta2, d.delta3
        ),
        None => {
            println!("| SDFCNN (this run) | - | - | no ground-truth depth | {time:.3} s | {p} |\n")
        }
    }
    println!(
        "Time: median seconds per image of the network and the argmax (decoding excluded, one \
         warm-up run first). Parameter: trainable parameters ({params}); the paper's 11.8 M \
         is close to the size in MB of 3 M f32 weights."
    );
}

/// How far the predictions are from metric, image by image: what a monocular map built
/// from them inherits as scale error (its median) and scale drift (its spread).
#[derive(serde::Serialize)]
struct ScaleSummary {
    images: usize,
    /// Median over images of each image's median ground truth / prediction.
    median: f64,
    p10: f64,
    p90: f64,
    /// Metrics after each prediction is multiplied by its own scale.
    rescaled: Option<DepthMetrics>,
}

impl ScaleSummary {
    fn of(mut scales: Vec<f64>, rescaled: Option<DepthMetrics>) -> Option<Self> {
        if scales.is_empty() {
            return None;
        }
        scales.sort_by(f64::total_cmp);
        let at = |q: f64| scales[((scales.len() - 1) as f64 * q).round() as usize];
        Some(Self {
            images: scales.len(),
            median: at(0.5),
            p10: at(0.1),
            p90: at(0.9),
            rescaled,
        })
    }

    fn print(&self) {
        println!(
            "Scale (per image, median of ground truth / prediction; 1 = metric): median {:.3}, \
             10-90 % {:.3}-{:.3} over {} images.",
            self.median, self.p10, self.p90, self.images
        );
        if let Some(d) = &self.rescaled {
            println!(
                "Each image rescaled by its own scale (scale-invariant): RMS {:.3}, REL {:.3}, \
                 δ < 1.25 {:.3}.",
                d.rms, d.rel, d.delta1
            );
        }
    }
}

fn print_classes(c: &ConfusionMatrix) {
    println!("\nPer class (0-based NYU40 ids)\n");
    println!("| id | class | gt pixels | accuracy | IoU |");
    println!("|---|---|---|---|---|");
    let f = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.3}"));
    for (i, s) in c.per_class().iter().enumerate() {
        let name = NYU40.get(i).copied().unwrap_or("?");
        println!(
            "| {i} | {name} | {} | {} | {} |",
            s.gt_pixels,
            f(s.accuracy),
            f(s.iou)
        );
    }
    println!("\npixel accuracy {:.3}", c.pixel_accuracy());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_depth_medians_and_log_slope() {
        // True depth the square of the prediction: twice the range in log depth.
        let pred = [1.0f32, 2.0, 4.0, 3.0, 0.0];
        let truth = [1.0f32, 4.0, 16.0, 0.0, 5.0];
        let r = ImageDepth::of(&truth, &pred).expect("three valid pixels");
        assert_eq!((r.true_median, r.predicted_median), (4.0, 2.0));
        assert!((r.log_slope.unwrap() - 2.0).abs() < 1e-9);
        // One depth everywhere predicted: no slope; no valid pixel: nothing.
        let flat = ImageDepth::of(&truth[..3], &[2.0; 3]).unwrap();
        assert!(flat.log_slope.is_none());
        assert!(ImageDepth::of(&[0.0; 3], &pred[..3]).is_none());
    }
}
