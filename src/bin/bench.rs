//! `bench`: timings of the two networks at their real sizes on Burn's backends, and with
//! `--torch` beside PyTorch's CPU times for the same networks, measured in the same run.
//!
//! ```text
//! bench [--backend ndarray --backend flex] [--runs 5] [--warmup 2] [--case sdfcnn-infer ...]
//!       [--torch PYTHON [--torch-threads N] [--torch-script scripts/bench_torch.py]]
//! ```
//!
//! Cases (median of `--runs` after `--warmup` untimed runs; each waits for its results):
//! * `sdfcnn-infer`: SDFCNN on one 640×480 RGB image to full-resolution labels (the argmax of
//!   the upsampled logits, Table 13 out_seg) and depth (out_depth) the way the predictor runs it:
//!   on CPU backends the packed NHWC network (`PackedSdfcnn`), on GPUs Burn's;
//! * `sdfcnn-infer-burn`: the same with Burn's kernels (`Sdfcnn::forward` and an argmax);
//! * `sdfcnn-train`: one SGD step at batch 4, 240×320: forward to the judge layer, eq. 21 loss
//!   (λ 0.4, berHu), backward, optimizer update;
//! * `fpfdcnn-infer`: FPFDCNN forward of one 480×640 grey image and descriptors at 500 keypoints
//!   (Table 12 FD_FP) the way the detector runs it: on CPU backends the packed NHWC network
//!   (`PackedFpfdcnn`), on GPUs Burn's;
//! * `fpfdcnn-infer-burn`: the same with Burn's kernels (`Fpfdcnn::forward` + `descriptors_at`);
//! * `fpfdcnn-detect`: the whole default detector on one 480×640 grey image (`FpfdcnnDetector::
//!   detect` with `DetectorConfig::default()`: the FP map and descriptors averaged over four
//!   cell-grid placements, so four network passes, smoothing, NMS, top 500); no reference;
//! * `fpfdcnn-train`: one SGD step at batch 4, 240×320 with a stand-in loss (mean of the
//!   probability map + mean of the descriptors: the FPFDCNN loss is written elsewhere);
//! * `slam`: the whole RGB-D SLAM with the defaults (bundled FPFDCNN keypoints and SDFCNN labels
//!   on the backend, three threads) over the 10 real 640×480 TUM fr1_rpy frames of
//!   `datasets/fixtures/tum_fr1_rpy_head10`, timed by the run itself (weights loaded outside
//!   the time); frames/s = 10 / the time. Needs the bundled weights (`weights/`).
//!
//! Peak memory is the process's VmHWM from /proc/self/status, reset before each case by
//! writing 5 to /proc/self/clear_refs (so it includes the memory already held then, shown as
//! "base").
//!
//! `--torch PYTHON` runs `scripts/bench_torch.py` (PyTorch definitions of both networks, shape
//! for shape as ours) with that interpreter before each case's own runs, with as many threads,
//! and prints each backend's time as a ratio of PyTorch's measured in the same run: absolute
//! times move with the machine's load from one day (or hour) to the next, ratios much less.

use anyhow::{Context, Result};
use burn::optim::momentum::MomentumConfig;
use burn::optim::{GradientsParams, SgdConfig};
use burn::prelude::*;
use clap::{Parser, ValueEnum};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sdf_slam::fpfdcnn::{FpfdcnnConfig, PackedFpfdcnn};
use sdf_slam::nn::{BackendKind, sample_bilinear_at, trainable_params};
use sdf_slam::sdfcnn::{PackedSdfcnn, SdfcnnConfig, SdfcnnLossConfig};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
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
    /// A Python interpreter with PyTorch: run scripts/bench_torch.py's version of each case
    /// (all but fpfdcnn-detect) just before ours and print the ratios.
    #[arg(long, value_name = "PYTHON")]
    torch: Option<PathBuf>,
    /// The PyTorch script [default: scripts/bench_torch.py here, else in the source tree].
    #[arg(long, value_name = "PATH", requires = "torch")]
    torch_script: Option<PathBuf>,
    /// PyTorch's intra-op threads [default: the hardware threads Burn's CPU backends use].
    #[arg(long, value_name = "N", requires = "torch",
          value_parser = clap::value_parser!(u16).range(1..=1024))]
    torch_threads: Option<u16>,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq)]
enum Case {
    FpfdcnnInfer,
    FpfdcnnInferBurn,
    FpfdcnnDetect,
    SdfcnnInfer,
    SdfcnnInferBurn,
    FpfdcnnTrain,
    SdfcnnTrain,
    Slam,
}

impl Case {
    const ALL: [Case; 8] = [
        Case::FpfdcnnInfer,
        Case::FpfdcnnInferBurn,
        Case::FpfdcnnDetect,
        Case::SdfcnnInfer,
        Case::SdfcnnInferBurn,
        Case::FpfdcnnTrain,
        Case::SdfcnnTrain,
        Case::Slam,
    ];

    fn label(self) -> &'static str {
        match self {
            Case::FpfdcnnInfer => "FPFDCNN inference 480x640 + 500 descriptors",
            Case::FpfdcnnInferBurn => "FPFDCNN inference as above, Burn's kernels",
            Case::FpfdcnnDetect => "FPFDCNN detector 480x640, 4 grid placements, top 500",
            Case::SdfcnnInfer => "SDFCNN inference 640x480 to labels + depth",
            Case::SdfcnnInferBurn => "SDFCNN inference as above, Burn's kernels",
            Case::FpfdcnnTrain => "FPFDCNN train step, batch 4, 240x320 (stand-in loss)",
            Case::SdfcnnTrain => "SDFCNN train step, batch 4, 240x320 (eq. 21)",
            Case::Slam => "RGB-D SLAM, 10 real TUM frames, FPFDCNN + SDFCNN labels",
        }
    }

    /// The case's name in scripts/bench_torch.py (`None`: no PyTorch version).
    fn torch_name(self) -> Option<&'static str> {
        match self {
            Case::FpfdcnnInfer | Case::FpfdcnnInferBurn => Some("fpfdcnn-infer"),
            Case::FpfdcnnDetect | Case::Slam => None,
            Case::SdfcnnInfer | Case::SdfcnnInferBurn => Some("sdfcnn-infer"),
            Case::FpfdcnnTrain => Some("fpfdcnn-train"),
            Case::SdfcnnTrain => Some("sdfcnn-train"),
        }
    }

    /// Trainable parameters of the case's network (the PyTorch definition must agree; BN
    /// running statistics are not counted on either side).
    fn parameters(self) -> Result<usize> {
        let d = BackendKind::Flex.device()?;
        Ok(match self {
            Case::SdfcnnInfer | Case::SdfcnnInferBurn | Case::SdfcnnTrain => {
                trainable_params(&SdfcnnConfig::new().init(&d)?)
            }
            _ => trainable_params(&FpfdcnnConfig::new().init(&d)?),
        })
    }
}

/// One measurement.
struct Measured {
    median_ms: f64,
    min_ms: f64,
    peak_mb: f64,
    base_mb: f64,
}

/// scripts/bench_torch.py run with a given interpreter.
struct Torch {
    python: PathBuf,
    script: PathBuf,
    threads: usize,
}

/// One PyTorch measurement (the script's JSON line).
struct TorchMeasured {
    median_ms: f64,
    min_ms: f64,
    version: String,
    capability: String,
}

impl Torch {
    fn new(cli: &Cli, python: &Path, threads: usize) -> Result<Self> {
        let script = match &cli.torch_script {
            Some(p) => p.clone(),
            None => {
                let here = PathBuf::from("scripts/bench_torch.py");
                if here.is_file() {
                    here
                } else {
                    Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/bench_torch.py")
                }
            }
        };
        anyhow::ensure!(
            script.is_file(),
            "the PyTorch script {} does not exist (--torch-script)",
            script.display()
        );
        let torch = Self {
            python: python.to_path_buf(),
            script,
            threads: cli.torch_threads.map_or(threads, usize::from),
        };
        // Fails here, before any case, when the interpreter or PyTorch is missing.
        torch
            .command()
            .arg("--help")
            .stdout(Stdio::null())
            .status()
            .map_or_else(
                |e| {
                    Err(anyhow::anyhow!(
                        "cannot run {}: {e}",
                        torch.python.display()
                    ))
                },
                |s| {
                    anyhow::ensure!(
                        s.success(),
                        "{} {} does not start ({s}); its message is above",
                        torch.python.display(),
                        torch.script.display()
                    );
                    Ok(())
                },
            )?;
        Ok(torch)
    }

    fn command(&self) -> Command {
        let mut c = Command::new(&self.python);
        c.arg(&self.script).stderr(Stdio::inherit());
        c
    }

    fn run(&self, case: &str, runs: u16, warmup: u16, parameters: usize) -> Result<TorchMeasured> {
        let out = self
            .command()
            .args(["--case", case, "--runs", &runs.to_string()])
            .args(["--warmup", &warmup.to_string()])
            .args(["--threads", &self.threads.to_string()])
            .output()
            .with_context(|| format!("running {}", self.python.display()))?;
        anyhow::ensure!(
            out.status.success(),
            "{} --case {case} failed ({}); its message is above",
            self.script.display(),
            out.status
        );
        let stdout = String::from_utf8_lossy(&out.stdout);
        let line = stdout.lines().last().unwrap_or_default();
        let v: serde_json::Value = serde_json::from_str(line).with_context(|| {
            format!(
                "{} --case {case} printed {line:?}, not JSON",
                self.script.display()
            )
        })?;
        let number = |key: &str| {
            v[key].as_f64().filter(|x| x.is_finite()).with_context(|| {
                format!(
                    "{} --case {case}: no number `{key}` in {line}",
                    self.script.display()
                )
            })
        };
        let theirs = number("parameters")? as usize;
        anyhow::ensure!(
            theirs == parameters,
            "{}'s {case} network has {theirs} parameters, ours {parameters}: the definitions differ",
            self.script.display()
        );
        Ok(TorchMeasured {
            median_ms: number("median_ms")?,
            min_ms: number("min_ms")?,
            version: v["torch"].as_str().unwrap_or("?").to_string(),
            capability: v["cpu_capability"].as_str().unwrap_or("?").to_string(),
        })
    }
}

/// The CPU's model name and vector extensions (from /proc/cpuinfo).
fn cpu_summary() -> String {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let field = |key: &str| {
        info.lines()
            .find(|l| l.starts_with(key))
            .and_then(|l| l.split_once(':'))
            .map(|(_, v)| v.trim().to_string())
    };
    let model = field("model name").unwrap_or_else(|| "unknown CPU".into());
    let flags = field("flags").unwrap_or_default();
    let vector: Vec<&str> = flags
        .split_whitespace()
        .filter(|f| {
            [
                "sse4_2",
                "avx",
                "avx2",
                "fma",
                "f16c",
                "avx512f",
                "avx512bw",
                "avx512_vnni",
            ]
            .contains(f)
                || f.starts_with("amx")
        })
        .collect();
    format!("{model}; vector extensions: {}", vector.join(" "))
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

fn median(v: Vec<f64>) -> f64 {
    sdf_slam::metrics::stats::median(&v)
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

/// The `slam` case: one whole run per repetition, timed by the run (`wall_seconds`).
fn run_slam(backend: BackendKind, runs: usize, warmup: usize) -> Result<Measured> {
    use sdf_slam::bundled::{BUNDLED_FPFDCNN, BUNDLED_SDFCNN, bundled_weights, locate};
    use sdf_slam::camera::Camera;
    use sdf_slam::dataset::TumSequence;
    use sdf_slam::fpfdcnn::FpfdcnnDetector;
    use sdf_slam::slam::{Control, DepthMode, FpfdcnnSource, SdfcnnSource, Slam, SlamConfig};
    const FIXTURE: &str = "datasets/fixtures/tum_fr1_rpy_head10";
    let path = locate(FIXTURE).with_context(|| format!("the fixture {FIXTURE} is not here"))?;
    let weights = |name: &str| {
        bundled_weights(name).with_context(|| format!("the slam case needs the bundled {name}"))
    };
    let (fp, sd) = (weights(BUNDLED_FPFDCNN)?, weights(BUNDLED_SDFCNN)?);
    let sequence = TumSequence::open(&path)?;
    let camera = Camera::for_sequence(None, &path)?;
    let config = SlamConfig::default();
    let quiet = || Control {
        log: std::sync::Arc::new(|_: &str| {}),
        ..Control::default()
    };
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let base_mb = status_mb("VmRSS:");
    let mut ms = Vec::with_capacity(runs);
    for k in 0..warmup + runs.max(1) {
        let detector = FpfdcnnDetector::load(&fp, backend, config.features.detector())?;
        let slam = Slam {
            sequence: sequence.clone(),
            camera: camera.clone(),
            config: config.clone(),
            depth: DepthMode::Sensor,
            keypoints: Box::new(FpfdcnnSource { detector }),
            semantics: Box::new(SdfcnnSource::load(&sd, backend)?.with_camera(&camera)),
            max_frames: None,
        };
        let out = slam.run(quiet())?;
        anyhow::ensure!(out.frames.len() == sequence.len(), "frames lost");
        if k >= warmup {
            ms.push(out.wall_seconds * 1e3);
        }
    }
    Ok(Measured {
        min_ms: ms.iter().copied().fold(f64::INFINITY, f64::min),
        median_ms: median(ms),
        peak_mb: status_mb("VmHWM:"),
        base_mb,
    })
}

fn run_case(case: Case, backend: BackendKind, runs: usize, warmup: usize) -> Result<Measured> {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let sgd = || {
        SgdConfig::new()
            .with_momentum(Some(MomentumConfig::new().with_dampening(0.0)))
            .init()
    };
    match case {
        Case::Slam => run_slam(backend, runs, warmup),
        Case::SdfcnnInfer if !backend.is_gpu() => {
            let d = backend.device()?;
            let model = SdfcnnConfig::new().init(&d)?;
            let packed = PackedSdfcnn::new(&model)?;
            let x: Vec<f32> = (0..480 * 640 * 3)
                .map(|_| rng.random_range(0.0..1.0))
                .collect();
            time(runs, warmup, || {
                let (labels, depth) = packed.predict(&x, [480, 640])?;
                anyhow::ensure!(labels.len() == 480 * 640 && depth.len() == 480 * 640);
                Ok(())
            })
        }
        Case::SdfcnnInfer | Case::SdfcnnInferBurn => {
            let d = backend.device()?;
            let model = SdfcnnConfig::new().init(&d)?;
            let x = random([1, 3, 480, 640], &mut rng, &d);
            time(runs, warmup, || {
                let out = model.forward(x.clone())?;
                let labels = out.seg.argmax(1).into_data();
                anyhow::ensure!(labels.num_elements() == 480 * 640);
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
        Case::FpfdcnnInfer if !backend.is_gpu() => {
            let d = backend.device()?;
            let model = FpfdcnnConfig::new().init(&d)?;
            let packed = PackedFpfdcnn::new(&model)?;
            let x: Vec<f32> = (0..480 * 640).map(|_| rng.random_range(0.0..1.0)).collect();
            let points: Vec<(usize, usize)> = (0..500)
                .map(|_| (rng.random_range(0..640), rng.random_range(0..480)))
                .collect();
            time(runs, warmup, || {
                let out = packed.forward(&x, [480, 640])?;
                let desc =
                    sample_bilinear_at(&out.descriptors, out.descriptor_dims, [480, 640], &points)?;
                anyhow::ensure!(desc.len() == 500 * 256 && out.prob.len() == 480 * 640);
                Ok(())
            })
        }
        Case::FpfdcnnInfer | Case::FpfdcnnInferBurn => {
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
    sdf_slam::malloc::tune_for_tensors();
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
    let torch = cli
        .torch
        .as_deref()
        .map(|python| Torch::new(&cli, python, threads))
        .transpose()?;
    println!(
        "bench: median of {} runs after {} warm-up, {threads} hardware threads",
        cli.runs, cli.warmup
    );
    println!("CPU: {}", cpu_summary());
    for var in [
        "MALLOC_ARENA_MAX",
        "MALLOC_MMAP_THRESHOLD_",
        "MALLOC_TRIM_THRESHOLD_",
    ] {
        if let Ok(v) = std::env::var(var) {
            println!("  {var}={v}");
        }
    }
    let mut rows = Vec::new();
    let mut torch_info = None;
    for &case in &cases {
        // PyTorch first, then ours, case by case: each ratio compares runs minutes apart.
        let reference = match (&torch, case.torch_name()) {
            (Some(t), Some(name)) => {
                // Timed again for each case (the `-burn` ones too): a ratio compares runs
                // minutes apart. A failure is a row, as for our backends.
                eprintln!("{} on PyTorch ({} threads) ...", case.label(), t.threads);
                match t.run(name, cli.runs, cli.warmup, case.parameters()?) {
                    Ok(m) => {
                        eprintln!("  median {:.0} ms (min {:.0})", m.median_ms, m.min_ms);
                        torch_info = Some((m.version.clone(), m.capability.clone(), t.threads));
                        rows.push(Row::torch(case, &m));
                        Some(m.median_ms)
                    }
                    Err(e) => {
                        eprintln!("  {e:#}");
                        rows.push(Row {
                            case,
                            backend: "PyTorch".into(),
                            cells: format!("error: {e} | | | "),
                        });
                        None
                    }
                }
            }
            _ => None,
        };
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
            rows.push(Row::ours(case, backend, r, reference));
        }
    }
    println!();
    if let Some((version, capability, t)) = &torch_info {
        println!("PyTorch {version}, {t} threads, CPU kernels for {capability}.\n");
    }
    println!("| case | backend | median ms | min ms | / PyTorch | peak RSS MB (base) |");
    println!("|---|---|---|---|---|---|");
    for r in &rows {
        println!("{r}");
    }
    if torch.is_none() {
        println!(
            "\n(`--torch PYTHON` adds PyTorch's times and the ratios: scripts/bench_torch.py)"
        );
    }
    println!(
        "\nglibc malloc can be tuned without rebuilding, e.g. MALLOC_ARENA_MAX=2 or \
         MALLOC_MMAP_THRESHOLD_=<bytes>; the variables in effect are listed above."
    );
    Ok(())
}

/// One line of the table.
struct Row {
    case: Case,
    backend: String,
    cells: String,
}

impl Row {
    fn torch(case: Case, m: &TorchMeasured) -> Self {
        Self {
            case,
            backend: "PyTorch".into(),
            cells: format!("{:.0} | {:.0} | 1.00 | –", m.median_ms, m.min_ms),
        }
    }

    fn ours(
        case: Case,
        backend: BackendKind,
        r: Result<Measured, String>,
        reference: Option<f64>,
    ) -> Self {
        let cells = match r {
            Ok(m) => format!(
                "{:.0} | {:.0} | {} | {:.0} ({:.0})",
                m.median_ms,
                m.min_ms,
                reference.map_or("–".into(), |t| format!("{:.2}", m.median_ms / t)),
                m.peak_mb,
                m.base_mb
            ),
            Err(e) => format!("{e} | | | "),
        };
        Self {
            case,
            backend: backend.to_string(),
            cells,
        }
    }
}

impl std::fmt::Display for Row {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "| {} | {} | {} |",
            self.case.label(),
            self.backend,
            self.cells
        )
    }
}
