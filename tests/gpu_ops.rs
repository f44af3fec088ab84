//! Every op SDFCNN's training step uses, one at a time, on wgpu against the CPU: forward value
//! and the gradient of every input, from inputs made on the CPU, each op run both on a fresh
//! tensor (which the GPU may overwrite in place) and with a second handle on it alive. A
//! mismatch names the op, the shapes and the condition; the test lists every one. Compiled
//! only with `--features wgpu`. It takes wgpu's adapter directly, without the project's
//! device check, so that the ops are compared even on an adapter the check refuses; Mesa's
//! software Vulkan (`scripts/install_lavapipe.sh`) is enough.
#![cfg(feature = "wgpu")]

use burn::nn::conv::Conv2dConfig;
use burn::nn::pool::MaxPool2dConfig;
use burn::nn::{BatchNormConfig, PaddingConfig2d};
use burn::prelude::*;
use sdf_slam::nn::{
    BackendKind, batch_norm, conv2d, max_pool2d, relu6, resize_bilinear, seeded_init, sum_all,
};
use sdf_slam::sdfcnn::loss::{DepthLoss, cross_entropy_void, depth_loss};

mod common;

/// wgpu's first adapter, started once for the tests of this file (the runtime cannot be
/// started twice), or `None` (reported) when there is none, unless `SDF_SLAM_REQUIRE_GPU=1`.
fn wgpu_device() -> Option<Device> {
    static DEVICE: std::sync::OnceLock<Result<Device, String>> = std::sync::OnceLock::new();
    match DEVICE.get_or_init(|| Device::wgpu_options().init().map_err(|e| e.to_string())) {
        Ok(d) => Some(d.clone()),
        Err(e) if std::env::var("SDF_SLAM_REQUIRE_GPU").is_ok_and(|v| v == "1") => {
            panic!("SDF_SLAM_REQUIRE_GPU=1: no wgpu adapter: {e}")
        }
        Err(e) => {
            eprintln!("skipped: no wgpu adapter: {e}");
            None
        }
    }
}

/// Deterministic values in about [-0.3, 0.7), distinct enough that a wrong index shows.
fn ramp(n: usize, salt: usize) -> Vec<f32> {
    (0..n)
        .map(|i| (((i + salt) * 7919 % 1000) as f32 / 1000.0) - 0.3)
        .collect()
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("f32")
}

/// Largest difference relative to the reference's largest magnitude.
fn relative_error(gpu: &[f32], cpu: &[f32]) -> f32 {
    if gpu.len() != cpu.len() {
        return f32::INFINITY;
    }
    let scale = cpu.iter().fold(1e-6f32, |m, v| m.max(v.abs()));
    let worst = gpu
        .iter()
        .zip(cpu)
        .map(|(a, b)| (a - b).abs())
        .fold(
            0.0f32,
            |m, d| if d.is_nan() { f32::INFINITY } else { m.max(d) },
        );
    worst / scale
}

/// An op of float inputs returning a scalar loss; `device` for constants it makes.
type Op = Box<dyn Fn(&[Tensor<4>], &Device) -> Tensor<1>>;

struct Case {
    name: String,
    shapes: Vec<[usize; 4]>,
    op: Op,
}

fn case(
    name: &str,
    shapes: &[[usize; 4]],
    op: impl Fn(&[Tensor<4>], &Device) -> Tensor<1> + 'static,
) -> Case {
    Case {
        name: name.to_string(),
        shapes: shapes.to_vec(),
        op: Box::new(op),
    }
}

/// The loss value and every input's gradient of `case` on `device` (autodiff); `alias` keeps a
/// second handle on each input alive while the op runs.
fn run(case: &Case, device: &Device, alias: bool) -> Vec<Vec<f32>> {
    let inputs: Vec<Tensor<4>> = case
        .shapes
        .iter()
        .enumerate()
        .map(|(k, &s)| {
            let n = s.iter().product();
            Tensor::<4>::from_data(TensorData::new(ramp(n, 31 * k), s), device).require_grad()
        })
        .collect();
    let kept: Vec<Tensor<4>> = if alias { inputs.clone() } else { Vec::new() };
    let loss = (case.op)(&inputs, device);
    let mut out = vec![values(loss.clone())];
    let grads = loss.backward();
    for x in &inputs {
        out.push(x.grad(&grads).map(values).unwrap_or_default());
    }
    drop(kept);
    out
}

/// A weighted sum, so that every output element's gradient differs.
fn weighted(y: Tensor<4>, device: &Device) -> Tensor<1> {
    let dims = y.dims();
    let n: usize = dims.iter().product();
    let w = Tensor::<4>::from_data(TensorData::new(ramp(n, 7), dims), device);
    sum_all(y * w)
}

fn cases() -> Vec<Case> {
    let conv = |name: &str, [ci, co]: [usize; 2], k: usize, s: usize, g: usize, x: [usize; 4]| {
        case(name, &[x], move |i, d| {
            let layer = seeded_init(
                Conv2dConfig::new([ci, co], [k, k])
                    .with_stride([s, s])
                    .with_groups(g)
                    .with_padding(PaddingConfig2d::Explicit(k / 2, k / 2, k / 2, k / 2))
                    .with_bias(false)
                    .init(d),
                3,
            );
            weighted(conv2d(&layer, i[0].clone()), d)
        })
    };
    let labels = |n: usize, h: usize, w: usize, d: &Device| common::sdfcnn_targets(n, h, w, d).0;
    let depth_target =
        |n: usize, h: usize, w: usize, d: &Device| common::sdfcnn_targets(n, h, w, d).1;
    let depth = |name: &str, kind: DepthLoss| {
        case(name, &[[2, 1, 8, 12]], move |i, d| {
            depth_loss(i[0].clone() * 4.0, depth_target(2, 8, 12, d), kind, 0.2)
        })
    };
    vec![
        // The layers, at the shapes of SDFCNN at 32x48 inside the network.
        conv("conv 3x3 s2 3->32", [3, 32], 3, 2, 1, [2, 3, 32, 48]),
        conv("conv 1x1 32->96", [32, 96], 1, 1, 1, [2, 32, 16, 24]),
        conv("depthwise 3x3 s1", [96, 96], 3, 1, 96, [2, 96, 16, 24]),
        conv("depthwise 3x3 s2", [96, 96], 3, 2, 96, [2, 96, 16, 24]),
        conv("conv 3x3 s1 32->32", [32, 32], 3, 1, 1, [2, 32, 8, 12]),
        case("batch norm (training)", &[[2, 16, 8, 12]], |i, d| {
            let bn = BatchNormConfig::new(16).init(d);
            weighted(batch_norm(&bn, i[0].clone()), d)
        }),
        case("relu6", &[[2, 16, 8, 12]], |i, d| {
            weighted(relu6(i[0].clone() * 8.0), d)
        }),
        case("max pool 5x5 s1 p2", &[[2, 16, 8, 12]], |i, d| {
            let pool = MaxPool2dConfig::new([5, 5])
                .with_strides([1, 1])
                .with_padding(PaddingConfig2d::Explicit(2, 2, 2, 2))
                .init();
            weighted(max_pool2d(&pool, i[0].clone()), d)
        }),
        case(
            "bilinear resize 8x12 -> 16x24",
            &[[2, 16, 8, 12]],
            |i, d| weighted(resize_bilinear(i[0].clone(), [16, 24]), d),
        ),
        case(
            "add (residual)",
            &[[2, 16, 8, 12], [2, 16, 8, 12]],
            |i, d| weighted(i[0].clone() + i[1].clone(), d),
        ),
        // The loss, at the judge layer's shapes.
        case("cross entropy with void", &[[2, 40, 8, 12]], move |i, d| {
            cross_entropy_void(i[0].clone(), labels(2, 8, 12, d))
        }),
        depth("depth loss l1", DepthLoss::L1),
        depth("depth loss berHu", DepthLoss::Berhu),
        case("sub + mask_fill", &[[2, 1, 8, 12]], move |i, d| {
            let gt = depth_target(2, 8, 12, d);
            let invalid = gt.clone().lower_equal_elem(0.0);
            weighted((i[0].clone() - gt).mask_fill(invalid, 0.0), d)
        }),
        case("abs", &[[2, 1, 8, 12]], |i, d| {
            weighted(i[0].clone().abs(), d)
        }),
        case("powi 2", &[[2, 1, 8, 12]], |i, d| {
            weighted(i[0].clone().powi_scalar(2), d)
        }),
        case(
            "max (detached) as threshold, greater, mask_where",
            &[[2, 1, 8, 12]],
            |i, d| {
                let abs = i[0].clone().abs();
                let c = abs
                    .clone()
                    .detach()
                    .max()
                    .mul_scalar(0.2)
                    .reshape([1, 1, 1, 1]);
                let above = abs.clone().greater(c.clone().expand(abs.dims()));
                let quad = (i[0].clone().powi_scalar(2) + c.clone().powi_scalar(2)) / (c * 2.0);
                weighted(abs.mask_where(above, quad), d)
            },
        ),
        case("log_softmax + gather", &[[2, 40, 8, 12]], move |i, d| {
            let l = labels(2, 8, 12, d);
            let void = l.clone().equal_elem(255).unsqueeze_dim::<4>(1);
            let index = l.unsqueeze_dim::<4>(1).mask_fill(void, 0);
            weighted(
                burn::tensor::activation::log_softmax(i[0].clone(), 1).gather(1, index),
                d,
            )
        }),
    ]
}

/// Relative tolerance of a value or gradient (float32 sums in another order).
const TOLERANCE: f32 = 1e-4;

#[test]
fn every_training_op_matches_the_cpu_forward_and_backward() {
    let cpu = BackendKind::Flex.autodiff_device().expect("flex");
    let mut failures = Vec::new();
    let b = BackendKind::Wgpu;
    if let Some(device) = wgpu_device() {
        let gpu = device.autodiff();
        for case in cases() {
            for alias in [false, true] {
                let want = run(&case, &cpu, alias);
                let got = run(&case, &gpu, alias);
                let condition = if alias {
                    "a second handle alive"
                } else {
                    "in place allowed"
                };
                for (k, (g, w)) in got.iter().zip(&want).enumerate() {
                    let what = if k == 0 {
                        "value".to_string()
                    } else {
                        format!("gradient of input {}", k - 1)
                    };
                    let err = relative_error(g, w);
                    eprintln!(
                        "{b} {} ({:?}, {condition}): {what} {err:.1e}",
                        case.name, case.shapes
                    );
                    if err > TOLERANCE {
                        failures.push(format!(
                            "{b} {} {:?} ({condition}): {what} differs by {err:.2e} of its largest value",
                            case.name, case.shapes
                        ));
                    }
                }
            }
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// The whole-tensor sum. Mesa's lavapipe ends a shader's loops after 65,535 iterations, and
/// Burn 0.22.1 reduces each row in one invocation's loop there, so Burn's own `sum()` of 2^18
/// or more ones comes back short (262132, printed below). The losses and the device check sum
/// with `nn::sum_all` (rows of at most 2^15), checked here up to a million elements and
/// against the CPU.
#[test]
fn the_losses_whole_tensor_sum_is_right_where_burns_long_rows_are_not() {
    let Some(device) = wgpu_device() else { return };
    for k in [16usize, 18, 20] {
        let n = 1usize << k;
        let ones = Tensor::<1>::ones([n], &device);
        let burn = ones.clone().sum().into_scalar::<f32>();
        let ours = sum_all(ones).into_scalar::<f32>();
        eprintln!("2^{k} ones: Burn's sum() {burn}, nn::sum_all {ours}");
        assert_eq!(ours, n as f32, "nn::sum_all of 2^{k} ones");
    }
    // A ramp of SDFCNN's segmentation size at 144x192, batch 8 (40 x 8 x 36 x 48).
    let shape = [8, 40, 36, 48];
    let n = shape.iter().product();
    let data = || TensorData::new(ramp(n, 3), shape);
    let cpu = BackendKind::Flex.device().expect("flex");
    let want = sum_all(Tensor::<4>::from_data(data(), &cpu)).into_scalar::<f32>();
    let got = sum_all(Tensor::<4>::from_data(data(), &device)).into_scalar::<f32>();
    assert!(
        (got - want).abs() <= 1e-4 * want.abs().max(1.0),
        "sum of {n} values: {got} on wgpu, {want} on the CPU"
    );
}

/// Burn 0.22.1's GPU convolution returns a channels-last view; with one output channel (SDFCNN's
/// depth head) the size-1 channel dimension has stride 1. A fused chain of two element-wise
/// ops on such a view and a tensor already computed (the flush below) then reads the other
/// tensor at the wrong places: SDFCNN's depth loss came out 1.12 where the CPU gives 3.50.
/// A single op, a view with more channels, or the chain without the flush is right. The raw
/// view's error is printed (it is Burn's to fix); `nn::conv2d`'s output, flattened and
/// restored on a GPU, must match the CPU.
#[test]
fn a_fused_chain_on_a_one_channel_convolution_output_matches_the_cpu() {
    let Some(gpu) = wgpu_device() else { return };
    let cpu = BackendKind::Flex.device().expect("flex");
    let chain = |d: &Device, raw: bool| {
        let gt = common::sdfcnn_targets(2, 8, 12, d).1;
        let pred = if raw {
            Tensor::<4>::from_data(TensorData::new(ramp(2 * 96, 2), [2, 8, 12, 1]), d)
                .permute([0, 3, 1, 2])
        } else {
            let layer = seeded_init(
                Conv2dConfig::new([32, 1], [3, 3])
                    .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                    .init(d),
                4,
            );
            let x =
                Tensor::<4>::from_data(TensorData::new(ramp(2 * 32 * 96, 2), [2, 32, 8, 12]), d);
            conv2d(&layer, x)
        };
        let invalid = gt.clone().lower_equal_elem(0.0);
        // The flush: a value read (the loss's pixel count does this).
        let _ = values(sum_all(invalid.clone().bool_not().float()));
        values((pred - gt).mask_fill(invalid, 0.0))
    };
    let raw = relative_error(&chain(&gpu, true), &chain(&cpu, true));
    eprintln!("Burn's channels-last one-channel view, fused sub + mask_fill: error {raw:.2e}");
    let ours = relative_error(&chain(&gpu, false), &chain(&cpu, false));
    assert!(
        ours <= TOLERANCE,
        "nn::conv2d output, fused sub + mask_fill: error {ours:.2e}"
    );
}

/// Gradient clipping by norm (FPFDCNN's Adam clips each parameter's gradient to norm 1) of a
/// 1024x1024 weight, the size of FPFDCNN's largest layer. Burn's `GradientClipping::Norm` takes
/// the norm with a whole-tensor sum, which lavapipe cuts short on its own (above); the square
/// and the sum fused are right, and must stay so: on wgpu the clipped gradient matches the
/// CPU's.
#[test]
fn gradient_clipping_of_a_million_weights_matches_the_cpu() {
    use burn::grad_clipping::GradientClippingConfig;
    use burn::nn::LinearConfig;
    use burn::optim::GradientsParams;
    let Some(gpu) = wgpu_device() else { return };
    // The weight's gradient and its clipped version.
    let run = |device: &Device| {
        let device = device.clone().autodiff();
        let layer = seeded_init(LinearConfig::new(1024, 1024).init(&device), 9);
        let x = Tensor::<2>::from_data(TensorData::new(ramp(1024, 1), [1, 1024]), &device);
        let w = Tensor::<2>::from_data(TensorData::new(ramp(1024, 2), [1, 1024]), &device);
        let loss = sum_all(layer.forward(x) * w);
        let grads = GradientsParams::from_grads(loss.backward(), &layer);
        let raw = grads.get::<2>(layer.weight.id).expect("weight gradient");
        let clipped = GradientClippingConfig::Norm(1.0)
            .init()
            .clip_gradient(raw.clone());
        (values(raw), values(clipped))
    };
    let cpu = BackendKind::Flex.device().expect("flex");
    let want = run(&cpu);
    let got = run(&gpu);
    let norm = |v: &[f32]| v.iter().map(|&x| f64::from(x).powi(2)).sum::<f64>().sqrt();
    eprintln!(
        "gradient norm {:.4} (CPU), clipped to {:.6}",
        norm(&want.0),
        norm(&want.1)
    );
    assert!(norm(&want.0) > 2.0, "the gradient is clipped");
    assert!((norm(&want.1) - 1.0).abs() < 1e-4, "clipped to norm 1");
    let e = relative_error(&got.1, &want.1);
    assert!(e <= TOLERANCE, "clipped gradient on wgpu: {e:.2e}");
}
