//! Timing of the two networks on a CPU backend: inference at 480×640 and one training step
//! (forward, mean loss, backward, Adam step) with a batch of 4 at 240×320.
//!
//! ```text
//! cargo run --release --example conv_speed -- [ndarray|flex] [REPS] [fi,ft,si,st] \
//!     [auto|burn|composite] [malloc=default]
//! ```
//!
//! `fi`/`si`: FPFDCNN / SDFCNN inference (`forward`, batch 1, 480×640); `ft`: FPFDCNN train
//! step (both images of a pair through the network, mean loss, backward, Adam); `st`: SDFCNN
//! train step (`forward`, mean loss, backward, Adam). Prints the median and the spread of
//! `REPS` timed runs (default 5) after one warm-up run, and the median process CPU time (all
//! threads), which says more than wall time on a loaded machine.
//!
//! The fourth argument picks the convolution and max-pool implementation
//! (`sdf_slam::nn::OpImpl`): `burn` is Burn's own kernels (the behaviour before
//! `sdf_slam::nn::conv` existed), `composite` the im2col + matrix-product convolution and
//! shifted-slice pooling, `auto` (default) per op whichever is faster. The binary tunes glibc
//! malloc (`sdf_slam::malloc`) like the `train` binary unless `malloc=default` is given.

use std::time::Instant;

use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use burn::tensor::Distribution;
use sdf_slam::fpfdcnn::{Fpfdcnn, FpfdcnnConfig};
use sdf_slam::nn::BackendKind;
use sdf_slam::nn::{OpImpl, set_op_impl};
use sdf_slam::sdfcnn::{Sdfcnn, SdfcnnConfig};

/// Process CPU time (user + system, all threads) in milliseconds, from `/proc/self/stat`
/// (Linux; clock ticks of 10 ms). `None` elsewhere.
fn cpu_ms() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks: f64 = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks * 10.0)
}

/// Wall-clock and CPU milliseconds of `reps` runs of `f` after one warm-up run, each sorted.
fn time(reps: usize, mut f: impl FnMut()) -> (Vec<f64>, Vec<f64>) {
    f();
    let (mut wall, mut cpu) = (Vec::new(), Vec::new());
    for _ in 0..reps {
        let (t, c) = (Instant::now(), cpu_ms());
        f();
        wall.push(t.elapsed().as_secs_f64() * 1e3);
        if let (Some(c0), Some(c1)) = (c, cpu_ms()) {
            cpu.push(c1 - c0);
        }
    }
    wall.sort_by(f64::total_cmp);
    cpu.sort_by(f64::total_cmp);
    (wall, cpu)
}

fn report(name: &str, (wall, cpu): &(Vec<f64>, Vec<f64>)) {
    let median = |v: &[f64]| v[v.len() / 2];
    let cpu = if cpu.is_empty() {
        String::new()
    } else {
        format!(", cpu median {:.0} ms", median(cpu))
    };
    println!(
        "{name:<28} median {:8.1} ms  (min {:.1}, max {:.1}, n {}{cpu})",
        median(wall),
        wall[0],
        wall[wall.len() - 1],
        wall.len()
    );
}

/// Forces the computation of `x` (some backends are lazy).
fn sync(x: Tensor<4>) -> f32 {
    x.sum().into_scalar::<f32>()
}

fn fpfdcnn_infer(device: &Device, reps: usize) -> (Vec<f64>, Vec<f64>) {
    let model = FpfdcnnConfig::new().init(device).expect("valid config");
    let x = Tensor::<4>::random([1, 1, 480, 640], Distribution::Default, device);
    time(reps, || {
        let out = model.forward(x.clone()).expect("valid input");
        sync(out.prob);
        sync(out.descriptors);
    })
}

fn fpfdcnn_train(device: &Device, reps: usize) -> (Vec<f64>, Vec<f64>) {
    let device = device.clone().autodiff();
    let mut model: Option<Fpfdcnn> = Some(FpfdcnnConfig::new().init(&device).expect("valid"));
    let mut optim = AdamConfig::new().init();
    let a = Tensor::<4>::random([4, 1, 240, 320], Distribution::Default, &device);
    let b = Tensor::<4>::random([4, 1, 240, 320], Distribution::Default, &device);
    time(reps, || {
        let m = model.take().expect("model");
        let oa = m.forward(a.clone()).expect("valid input");
        let ob = m.forward(b.clone()).expect("valid input");
        let loss = oa.prob.mean() + ob.prob.mean() + (oa.descriptors * ob.descriptors).mean();
        let grads = GradientsParams::from_grads(loss.backward(), &m);
        model = Some(optim.step(1e-4, m, grads));
    })
}

fn sdfcnn_infer(device: &Device, reps: usize) -> (Vec<f64>, Vec<f64>) {
    let model = SdfcnnConfig::new().init(device).expect("valid config");
    let x = Tensor::<4>::random([1, 3, 480, 640], Distribution::Default, device);
    time(reps, || {
        let out = model.forward(x.clone()).expect("valid input");
        sync(out.seg);
        sync(out.depth);
    })
}

fn sdfcnn_train(device: &Device, reps: usize) -> (Vec<f64>, Vec<f64>) {
    let device = device.clone().autodiff();
    let mut model: Option<Sdfcnn> = Some(SdfcnnConfig::new().init(&device).expect("valid"));
    let mut optim = AdamConfig::new().init();
    let x = Tensor::<4>::random([4, 3, 240, 320], Distribution::Default, &device);
    time(reps, || {
        let m = model.take().expect("model");
        let out = m.forward(x.clone()).expect("valid input");
        let loss = out.seg.powi_scalar(2).mean() + out.depth.mean();
        let grads = GradientsParams::from_grads(loss.backward(), &m);
        model = Some(optim.step(1e-4, m, grads));
    })
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let backend = match args.get(1).map_or("ndarray", String::as_str) {
        "ndarray" => BackendKind::Ndarray,
        "flex" => BackendKind::Flex,
        other => anyhow::bail!("unknown backend {other} (ndarray|flex)"),
    };
    let reps: usize = args.get(2).map_or(Ok(5), |s| s.parse())?;
    let which = args.get(3).map_or("fi,ft,si,st", String::as_str);
    let conv = match args.get(4).map_or("auto", String::as_str) {
        "auto" => OpImpl::Auto,
        "burn" => OpImpl::Burn,
        "composite" => OpImpl::Composite,
        other => anyhow::bail!("unknown implementation {other} (auto|burn|composite)"),
    };
    set_op_impl(conv);
    // `malloc=default` keeps glibc's defaults, to measure what `sdf_slam::malloc` gains.
    let tuned = args.get(5).map(String::as_str) != Some("malloc=default")
        && sdf_slam::malloc::tune_for_tensors();
    let device = backend.device()?;
    println!("backend {backend}, ops {conv:?}, malloc tuned {tuned}, {reps} timed runs each");
    for job in which.split(',') {
        let (name, ms) = match job {
            "fi" => ("FPFDCNN infer 1x480x640", fpfdcnn_infer(&device, reps)),
            "ft" => ("FPFDCNN train 4x240x320", fpfdcnn_train(&device, reps)),
            "si" => ("SDFCNN infer 1x480x640", sdfcnn_infer(&device, reps)),
            "st" => ("SDFCNN train 4x240x320", sdfcnn_train(&device, reps)),
            other => anyhow::bail!("unknown job {other} (fi,ft,si,st)"),
        };
        report(name, &ms);
    }
    Ok(())
}
