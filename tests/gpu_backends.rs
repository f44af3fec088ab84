//! The GPU backends against the CPU backend on small inputs: the full FPFDCNN and SDFCNN
//! forward passes and one gradient, from the same seeded weights. Compiled only with
//! `--features wgpu` (or `cuda`); each backend that finds no device here is reported and
//! skipped, unless `SDF_SLAM_REQUIRE_GPU=1` makes that a failure (the device checks in the
//! README set it). On a machine without a GPU, `scripts/install_lavapipe.sh` installs Mesa's
//! software Vulkan driver, which the wgpu backend then uses.
#![cfg(any(feature = "wgpu", feature = "cuda"))]

use burn::prelude::*;
use sdf_slam::fpfdcnn::FpfdcnnConfig;
use sdf_slam::nn::{BackendKind, seeded_init};
use sdf_slam::sdfcnn::{SdfcnnConfig, SdfcnnLossConfig};

/// The GPU backends this build has, with a device here.
fn gpu_devices() -> Vec<(BackendKind, Device)> {
    let require = std::env::var("SDF_SLAM_REQUIRE_GPU").is_ok_and(|v| v == "1");
    let mut found = Vec::new();
    for b in BackendKind::ALL
        .into_iter()
        .filter(|b| b.is_gpu() && b.is_compiled())
    {
        match b.device() {
            Ok(d) => found.push((b, d)),
            Err(e) if require => panic!("SDF_SLAM_REQUIRE_GPU=1: {e}"),
            Err(e) => eprintln!("skipped: {e}"),
        }
    }
    found
}

fn ramp(shape: [usize; 4], device: &Device) -> Tensor<4> {
    let n: usize = shape.iter().product();
    let v: Vec<f32> = (0..n)
        .map(|i| ((i * 7919 % 1000) as f32 / 1000.0) - 0.3)
        .collect();
    Tensor::from_data(TensorData::new(v, shape), device)
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("f32")
}

/// Largest difference relative to the reference's largest magnitude.
fn assert_close(what: &str, gpu: &[f32], cpu: &[f32], tol: f32) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: sizes");
    let scale = cpu.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
    let worst = gpu
        .iter()
        .zip(cpu)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(
        worst <= tol * scale,
        "{what}: max |gpu - cpu| = {worst} > {tol} x {scale}"
    );
    eprintln!(
        "{what}: max |gpu - cpu| / max |cpu| = {:.2e}",
        worst / scale
    );
}

#[test]
fn fpfdcnn_forward_and_gradient_match_the_cpu() {
    let cpu = BackendKind::Ndarray.autodiff_device().expect("ndarray");
    let run = |device: &Device| {
        let model = seeded_init(FpfdcnnConfig::new().init(device).expect("init"), 3);
        let x = ramp([2, 1, 64, 96], device).require_grad();
        let out = model.forward(x.clone()).expect("forward");
        let (prob, desc) = (values(out.prob.clone()), values(out.descriptors.clone()));
        // The outputs are consumed by element-wise ops, as a loss does (in place on a GPU).
        let loss = out.prob.sub_scalar(0.5).abs().mean() + out.descriptors.powi_scalar(2).mean();
        let value = values(loss.clone());
        let grads = loss.backward();
        // The input's gradient runs back through every layer.
        let g = x.grad(&grads).expect("gradient");
        (prob, desc, value, values(g))
    };
    let want = run(&cpu);
    for (b, device) in gpu_devices() {
        let got = run(&device.autodiff());
        assert_close(&format!("{b} FPFDCNN prob"), &got.0, &want.0, 1e-4);
        assert_close(&format!("{b} FPFDCNN descriptors"), &got.1, &want.1, 1e-4);
        assert_close(&format!("{b} FPFDCNN loss"), &got.2, &want.2, 1e-4);
        assert_close(
            &format!("{b} FPFDCNN input gradient"),
            &got.3,
            &want.3,
            1e-3,
        );
    }
}

#[test]
fn sdfcnn_forward_matches_the_cpu() {
    let cpu = BackendKind::Ndarray.device().expect("ndarray");
    let run = |device: &Device| {
        let cfg = SdfcnnConfig::new()
            .with_inner_size([64, 96])
            .with_decoder_dim(32);
        let model = seeded_init(cfg.init(device).expect("init"), 5);
        let out = model
            .forward(ramp([1, 3, 64, 96], device))
            .expect("forward");
        (values(out.seg), values(out.depth))
    };
    let want = run(&cpu);
    for (b, device) in gpu_devices() {
        let got = run(&device);
        assert_close(&format!("{b} SDFCNN segmentation"), &got.0, &want.0, 1e-4);
        assert_close(&format!("{b} SDFCNN depth"), &got.1, &want.1, 1e-4);
    }
}

/// Fails with Burn 0.22.1's wgpu (lavapipe, 2026-11-26): the depth term comes out 1.09 where
/// the CPU gives 3.50 (right again while a second handle on the outputs is alive: in-place
/// reuse), and even then the input gradient differs by up to 62 % of its largest value
/// (composite or Burn convolutions alike), so `train` refuses the GPU backends; run with
/// `--ignored` after a Burn upgrade.
#[test]
#[ignore = "Burn 0.22.1 wgpu: SDFCNN gradients differ from the CPU's (README, GPU backends)"]
fn sdfcnn_training_loss_and_gradient_match_the_cpu() {
    let cpu = BackendKind::Flex.autodiff_device().expect("flex");
    let [h, w] = [32, 48];
    let run = |device: &Device| {
        let cfg = SdfcnnConfig::new()
            .with_inner_size([h, w])
            .with_decoder_dim(32);
        let model = seeded_init(cfg.init(device).expect("init"), 5);
        let x = ramp([2, 3, h, w], device).require_grad();
        // Labels cycling through the classes with void pixels; depth 0.5-3 m with holes.
        let labels: Vec<i64> = (0..2 * h * w)
            .map(|i| if i % 7 == 0 { 255 } else { (i % 40) as i64 })
            .collect();
        let labels = Tensor::<3, Int>::from_data(TensorData::new(labels, [2, h, w]), device);
        let depth: Vec<f32> = (0..2 * h * w)
            .map(|i| {
                if i % 11 == 0 {
                    0.0
                } else {
                    0.5 + (i % 50) as f32 / 20.0
                }
            })
            .collect();
        let depth = Tensor::<4>::from_data(TensorData::new(depth, [2, 1, h, w]), device);
        // Batch norms in training mode; the loss consumes the outputs (eq. 21, berHu).
        let out = model.forward_quarter(x.clone()).expect("forward");
        let loss = SdfcnnLossConfig::default().forward(out, labels, depth);
        let parts = [
            values(loss.seg),
            values(loss.depth),
            values(loss.total.clone()),
        ]
        .concat();
        let grads = loss.total.backward();
        (parts, values(x.grad(&grads).expect("gradient")))
    };
    let want = run(&cpu);
    for (b, device) in gpu_devices() {
        let got = run(&device.autodiff());
        assert_close(
            &format!("{b} SDFCNN eq. 21 (seg, depth, total)"),
            &got.0,
            &want.0,
            1e-4,
        );
        assert_close(&format!("{b} SDFCNN input gradient"), &got.1, &want.1, 1e-3);
    }
}

#[test]
fn sdfcnn_training_on_a_gpu_backend_is_refused_before_reading_data() {
    let root = env!("CARGO_MANIFEST_DIR");
    let out = std::env::temp_dir().join(format!("sdf_gpu_refused_{}", std::process::id()));
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_train"))
        .args([
            "--config",
            &format!("{root}/configs/train/sdfcnn_tiny.toml"),
        ])
        .args(["--backend", "wgpu", "--out"])
        .arg(&out)
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("train runs");
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success(), "{err}");
    assert!(
        err.contains("SDFCNN training on `wgpu` is refused"),
        "{err}"
    );
    assert!(!out.exists(), "no run folder before the refusal");
}
