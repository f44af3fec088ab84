//! `bench`: timings of the two networks at their real sizes, next to the reference figures
//! measured before (PyTorch CPU, burn-flex, burn-ndarray).
//!
//! ```text
//! bench [--backend ndarray --backend flex] [--runs 5] [--warmup 2] [--case sdfcnn-infer ...]
//! ```
//!
//! Cases (median of `--runs` after `--warmup` untimed runs; each waits for its results):
//! * `sdfcnn-infer`: SDFCNN forward of one 640×480 RGB image to full-resolution logits and depth
//!   (Table 13 out_seg/out_depth);
//! * `sdfcnn-train`: one SGD step at batch 4, 240×320: forward to the judge layer, eq. 21 loss
//!   (λ 0.4, berHu), backward, optimizer update;
//! * `fpfdcnn-infer`: FPFDCNN forward of one 480×640 grey image and descriptors at 500 keypoints
//!   (`Fpfdcnn::forward` + `descriptors_at`, Table 12 FD_FP);
//! * `fpfdcnn-detect`: the whole default detector on one 480×640 grey image (`FpfdcnnDetector::
//!   detect` with `DetectorConfig::default()`: the FP map averaged over four cell-grid
//!   placements, so four network passes, smoothing, NMS, top 500, descriptors); no reference;
//! * `fpfdcnn-train`: one SGD step at batch 4, 240×320 with a stand-in loss (mean of the
//!   probability map + mean of the descriptors: the FPFDCNN loss is written elsewhere).
//!
//! Peak memory is the process's VmHWM from /proc/self/status, reset before each case by
//! writing 5 to /proc/self/clear_refs (so it includes the memory already held then, shown as
//! "base").

use anyhow::Result;
use burn::optim::momentum::MomentumConfig;
use burn::optim::{GradientsParams, SgdConfig};
use burn::prelude::*;
use clap::{Parser, ValueEnum};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sdf_slam::fpfdcnn::FpfdcnnConfig;
use sdf_slam::nn::BackendKind;
use sdf_slam::sdfcnn::{SdfcnnConfig, SdfcnnLossConfig};
use std::time::Instant;

#[derive(Parser, Debug)]
#[command(
    about = "Time SDFCNN and FPFDCNN inference and training steps on the CPU (and GPU) backends"
)]
struct Cli {
    /// Backends to time (repeat the flag; default both).
    #[arg(long, value_enum)]
    backend: Vec<BackendKind>,
    /// Cases to run (repeat the flag; default all).
    #[arg(long, value_enum)]
    case: Vec<Case>,
    /// Timed runs per case (the median is reported), 1-1000.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u16).range(1..=1000))]
    runs: u16,
    /// Untimed runs first, 0-1000.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u16).range(0..=1000))]
    warmup: u16,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq)]
enum Case {
    FpfdcnnInfer,
    FpfdcnnDetect,
    SdfcnnInfer,
    FpfdcnnTrain,
    SdfcnnTrain,
}

impl Case {
    const ALL: [Case; 5] = [
        Case::FpfdcnnInfer,
        Case::FpfdcnnDetect,
        Case::SdfcnnInfer,
        Case::FpfdcnnTrain,
        Case::SdfcnnTrain,
    ];

    fn label(self) -> &'static str {
        match self {
            Case::FpfdcnnInfer => "FPFDCNN inference 480x640 + 500 descriptors",
            Case::FpfdcnnDetect => "FPFDCNN detector 480x640, 4 grid placements, top 500",
            Case::SdfcnnInfer => "SDFCNN inference 640x480",
            Case::FpfdcnnTrain => "FPFDCNN train step, batch 4, 240x320 (stand-in loss)",
            Case::SdfcnnTrain => "SDFCNN train step, batch 4, 240x320 (eq. 21)",
        }
    }

    /// Reference milliseconds: PyTorch CPU, burn-flex, burn-ndarray (None: panicked); None
    /// for a case without reference figures.
    fn reference(self) -> Option<(f64, f64, Option<f64>)> {
        match self {
            Case::FpfdcnnInfer => Some((46.0, 171.0, Some(303.0))),
            Case::FpfdcnnDetect => None,
            Case::SdfcnnInfer => Some((254.0, 377.0, Some(692.0))),
            Case::FpfdcnnTrain => Some((459.0, 1418.0, None)),
            Case::SdfcnnTrain => Some((1099.0, 3272.0, None)),
        }
    }
}

/// One measurement.
struct Measured {
    median_ms: f64,
    min_ms: f64,
    peak_mb: f64,
    base_mb: f64,
}

fn status_mb(key: &str) -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with(key))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Times `step` (which must wait for its results).
fn time(runs: usize, warmup: usize, mut step: impl FnMut() -> Result<()>) -> Result<Measured> {
    // Reset the peak RSS to the current RSS (Linux ≥ 4.0).
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let base_mb = status_mb("VmRSS:");
    for _ in 0..warmup {
        step()?;
    }
    let mut ms = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let t = Instant::now();
        step()?;
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(Measured {
        min_ms: ms.iter().copied().fold(f64::INFINITY, f64::min),
        median_ms: median(ms),
        peak_mb: status_mb("VmHWM:"),
        base_mb,
    })
}

fn random(shape: [usize; 4], rng: &mut ChaCha8Rng, device: &Device) -> Tensor<4> {
    let n: usize = shape.iter().product();
    let v: Vec<f32> = (0..n).map(|_| rng.random_range(0.0..1.0)).collect();
    Tensor::from_data(TensorData::new(v, shape), device)
}

fn sync(t: Tensor<4>) -> f32 {
    t.sum().into_scalar::<f32>()
}

fn run_case(case: Case, backend: BackendKind, runs: usize, warmup: usize) -> Result<Measured> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let sgd = || {
        SgdConfig::new()
            .with_momentum(Some(MomentumConfig::new().with_dampening(0.0)))
            .init()
    };
    match case {
        Case::SdfcnnInfer => {
            let d = backend.device()?;
            let model = SdfcnnConfig::new().init(&d)?;
            let x = random([1, 3, 480, 640], &mut rng, &d);
            time(runs, warmup, || {
                let out = model.forward(x.clone())?;
                sync(out.seg);
                sync(out.depth);
                Ok(())
            })
        }
        Case::SdfcnnTrain => {
            let d = backend.autodiff_device()?;
            let mut model = Some(SdfcnnConfig::new().init(&d)?);
            let mut optim = sgd();
            let loss = SdfcnnLossConfig::default();
            let x = random([4, 3, 240, 320], &mut rng, &d);
            let depth = random([4, 1, 240, 320], &mut rng, &d).mul_scalar(5.0);
            let labels: Vec<i64> = (0..4 * 240 * 320)
                .map(|_| rng.random_range(0..41i64))
                .map(|l| if l == 40 { 255 } else { l })
                .collect();
            let labels = Tensor::<3, Int>::from_data(TensorData::new(labels, [4, 240, 320]), &d);
            time(runs, warmup, || {
                let m = model.take().ok_or_else(|| anyhow::anyhow!("model lost"))?;
                let out = m.forward_quarter(x.clone())?;
                let l = loss.forward(out, labels.clone(), depth.clone());
                let grads = GradientsParams::from_grads(l.total.backward(), &m);
                let m = optim.step(0.01, m, grads);
                model = Some(m);
                // A GPU runs the step asynchronously: wait for it.
                d.sync().map_err(|e| anyhow::anyhow!("{e:?}"))?;
                Ok(())
            })
        }
        Case::FpfdcnnInfer => {
            let d = backend.device()?;
            let model = FpfdcnnConfig::new().init(&d)?;
            let x = random([1, 1, 480, 640], &mut rng, &d);
            let points: Vec<(usize, usize)> = (0..500)
                .map(|_| (rng.random_range(0..640), rng.random_range(0..480)))
                .collect();
            time(runs, warmup, || {
                let out = model.forward(x.clone())?;
                sync(out.prob);
                let desc = model.descriptors_at(&out.descriptors, 0, [480, 640], &points)?;
                anyhow::ensure!(desc.len() == 500);
                Ok(())
            })
        }
        Case::FpfdcnnDetect => {
            use sdf_slam::fpfdcnn::{DetectorConfig, FpfdcnnDetector};
            let d = backend.device()?;
            let model = FpfdcnnConfig::new().init(&d)?;
            let detector = FpfdcnnDetector::new(model, d, DetectorConfig::default());
            let gray = image::GrayImage::from_fn(640, 480, |_, _| {
                image::Luma([rng.random_range(0..=255u8)])
            });
            time(runs, warmup, || {
                let f = detector.detect(&gray)?;
                anyhow::ensure!(f.len() == 500, "{} keypoints", f.len());
                Ok(())
            })
        }
        Case::FpfdcnnTrain => {
            let d = backend.autodiff_device()?;
            let mut model = Some(FpfdcnnConfig::new().init(&d)?);
            let mut optim = sgd();
            let x = random([4, 1, 240, 320], &mut rng, &d);
            time(runs, warmup, || {
                let m = model.take().ok_or_else(|| anyhow::anyhow!("model lost"))?;
                let out = m.forward(x.clone())?;
                let loss = out.prob.mean() + out.descriptors.mean();
                let grads = GradientsParams::from_grads(loss.backward(), &m);
                model = Some(optim.step(0.01, m, grads));
                d.sync().map_err(|e| anyhow::anyhow!("{e:?}"))?;
                Ok(())
            })
        }
    }
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    let backends = if cli.backend.is_empty() {
        vec![BackendKind::Ndarray, BackendKind::Flex]
    } else {
        cli.backend.clone()
    };
    // A backend not compiled in, or without a device, fails before any case runs.
    for b in &backends {
        b.check()?;
    }
    let cases: Vec<Case> = if cli.case.is_empty() {
        Case::ALL.to_vec()
    } else {
        cli.case.clone()
    };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "bench: median of {} runs after {} warm-up, {threads} hardware threads",
        cli.runs, cli.warmup
    );
    for var in [
        "MALLOC_ARENA_MAX",
        "MALLOC_MMAP_THRESHOLD_",
        "MALLOC_TRIM_THRESHOLD_",
    ] {
        if let Ok(v) = std::env::var(var) {
            println!("  {var}={v}");
        }
    }
    let mut results = Vec::new();
    for &case in &cases {
        for &backend in &backends {
            eprintln!("{} on {backend} ...", case.label());
            let r = std::panic::catch_unwind(|| {
                run_case(case, backend, cli.runs.into(), cli.warmup.into())
            });
            let r = match r {
                Ok(Ok(m)) => Ok(m),
                Ok(Err(e)) => Err(format!("error: {e}")),
                Err(_) => Err("panicked".to_string()),
            };
            if let Ok(m) = &r {
                eprintln!(
                    "  median {:.0} ms (min {:.0}), peak RSS {:.0} MB",
                    m.median_ms, m.min_ms, m.peak_mb
                );
            }
            results.push((case, backend, r));
        }
    }
    println!();
    println!(
        "| case | PyTorch CPU (ref) | burn-flex (ref) | burn-ndarray (ref) | this: backend | median ms | min ms | peak RSS MB (base) |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (case, backend, r) in &results {
        let refs = match case.reference() {
            Some((pt, fx, nd)) => format!(
                "{pt:.0} | {fx:.0} | {}",
                nd.map_or("panics".to_string(), |v| format!("{v:.0}"))
            ),
            None => "– | – | –".to_string(),
        };
        let cells = match r {
            Ok(m) => format!(
                "{:.0} | {:.0} | {:.0} ({:.0})",
                m.median_ms, m.min_ms, m.peak_mb, m.base_mb
            ),
            Err(e) => format!("{e} | | "),
        };
        println!("| {} | {refs} | {backend} | {cells} |", case.label());
    }
    println!(
        "\nglibc malloc can be tuned without rebuilding, e.g. MALLOC_ARENA_MAX=2 or \
         MALLOC_MMAP_THRESHOLD_=<bytes>; the variables in effect are listed above."
    );
    Ok(())
}
