//! SDFCNN's training step in float32, on the CPU with this crate's kernels and on each GPU,
//! against the same step in float64: the bundled weights on eight real TUM frames at the
//! recipe's 144x192. A float32 step is not reproducible to 1e-4 of the largest gradient: the
//! first layers' weight gradients are sums over the whole batch whose terms cancel after the
//! batch norms, and the bundled weights' largest gradient is at a channel that is zero on every
//! pixel, whose batch norm divides by √ε. So the yardstick is the exact step. Its own test
//! binary, because the float64 reference needs ndarray's default float type set before any
//! tensor exists in the process; the GPU test is compiled only with `--features wgpu` (or
//! `cuda`), like `gpu_backends.rs`.

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::prelude::*;
use burn::tensor::FloatDType;
use sdf_slam::dataset::tum::TumSequence;
use sdf_slam::nn::{BackendKind, OpImpl, ShapeTrace, set_op_impl};
use sdf_slam::sdfcnn::{Sdfcnn, SdfcnnLossConfig, SdfcnnPredictor};
use std::sync::{Mutex, MutexGuard, OnceLock};

mod common;

/// Every parameter's name and gradient, in the module's order.
struct Grads<'a> {
    grads: &'a burn::tensor::Gradients,
    path: Vec<String>,
    out: Vec<(String, Vec<f32>)>,
}

impl ModuleVisitor for Grads<'_> {
    fn enter_module(&mut self, name: &str, _: &str) {
        self.path.push(name.to_string());
    }

    fn exit_module(&mut self, _: &str, _: &str) {
        self.path.pop();
    }

    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = param.val().grad(self.grads) {
            self.out.push((self.path.join("."), values(g)));
        }
    }
}

/// Casts every float parameter to `dtype` (a new leaf: the cast is not part of the step).
struct Cast(FloatDType);

impl ModuleMapper for Cast {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let dtype = self.0;
        param.map(|t| t.cast(dtype).detach())
    }
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .expect("f32")
}

/// Eight TUM fixture frames at 144x192 (colour resized, depth nearest) and a banded label
/// pattern (the labels only set the segmentation term's value).
struct Batch {
    images: Vec<f32>,
    depth: Vec<f32>,
    labels: Vec<i64>,
}

const DIMS: [usize; 3] = [8, 144, 192];

fn tum_batch() -> Batch {
    let [n, h, w] = DIMS;
    let seq =
        TumSequence::open(common::manifest_dir().join("datasets/fixtures/tum_fr1_rpy_head10"))
            .expect("TUM fixture");
    let (mut images, mut depth) = (Vec::new(), Vec::new());
    for i in 0..n {
        let rgb = image::imageops::resize(
            &seq.load_rgb(i).expect("colour"),
            w as u32,
            h as u32,
            image::imageops::FilterType::Triangle,
        );
        for c in 0..3 {
            images.extend(rgb.pixels().map(|p| p.0[c] as f32 / 255.0));
        }
        let d = seq.load_depth(i).expect("depth").expect("a depth image");
        let (sx, sy) = (d.width as f64 / w as f64, d.height as f64 / h as f64);
        for y in 0..h {
            for x in 0..w {
                depth.push(d.at(x as f64 * sx, y as f64 * sy).unwrap_or(0.0));
            }
        }
    }
    let labels = (0..n * h * w).map(|i| ((i / w / 12) % 40) as i64).collect();
    Batch {
        images,
        depth,
        labels,
    }
}

/// One training step on `device`, in its default float type.
struct Step {
    loss: f32,
    /// Every forward layer's output, in order (the GPU test's bisection).
    #[cfg_attr(not(any(feature = "wgpu", feature = "cuda")), allow(dead_code))]
    layers: Vec<(String, Vec<f32>)>,
    /// Every parameter's gradient.
    grads: Vec<(String, Vec<f32>)>,
}

fn step(model: &Sdfcnn, b: &Batch, device: &Device) -> Step {
    let [n, h, w] = DIMS;
    let dtype = device.settings().float_dtype;
    let model = model.clone().fork(device).map(&mut Cast(dtype)).train();
    let tensor = |v: &[f32], c| {
        Tensor::<4>::from_data(TensorData::new(v.to_vec(), [n, c, h, w]), device).cast(dtype)
    };
    let labels = Tensor::<3, Int>::from_data(TensorData::new(b.labels.clone(), [n, h, w]), device);
    let mut trace = ShapeTrace::with_values();
    let out = model
        .forward_quarter_traced(tensor(&b.images, 3), &mut trace)
        .expect("forward");
    let layers = common::traced_layers(&trace);
    let total = SdfcnnLossConfig::default()
        .forward(out, labels, tensor(&b.depth, 1))
        .total;
    let loss = values(total.clone())[0];
    let grads = total.backward();
    let mut visitor = Grads {
        grads: &grads,
        path: Vec::new(),
        out: Vec::new(),
    };
    model.visit(&mut visitor);
    Step {
        loss,
        layers,
        grads: visitor.out,
    }
}

/// The largest difference relative to the reference's largest magnitude.
#[cfg_attr(not(any(feature = "wgpu", feature = "cuda")), allow(dead_code))]
fn relative(got: &[f32], exact: &[f32]) -> f32 {
    let scale = exact.iter().fold(1e-30f32, |m, v| m.max(v.abs()));
    got.iter()
        .zip(exact)
        .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()))
        / scale
}

/// How many gradient elements have the other sign than the exact step's (Adam's first step is
/// `lr` times the sign of each gradient, so these elements take a full step the other way).
fn other_signs(got: &[(String, Vec<f32>)], exact: &[(String, Vec<f32>)]) -> usize {
    got.iter()
        .zip(exact)
        .flat_map(|((_, a), (_, b))| a.iter().zip(b))
        .filter(|(p, q)| p.signum() != q.signum())
        .count()
}

/// The largest gradient difference relative to the reference's largest gradient, and the
/// parameter where it is.
fn parting(got: &[(String, Vec<f32>)], exact: &[(String, Vec<f32>)]) -> (f32, String) {
    parting_except(got, exact, None)
}

/// The largest gradient magnitude (at least 1e-12) and the parameter holding it.
fn largest(grads: &[(String, Vec<f32>)]) -> (f32, Option<&str>) {
    let mut top = (1e-12f32, None);
    for (name, g) in grads {
        let m = g.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        if m > top.0 {
            top = (m, Some(name.as_str()));
        }
    }
    top
}

/// [`parting`] over every parameter but `skip` (the scale is still the largest of all).
fn parting_except(
    got: &[(String, Vec<f32>)],
    exact: &[(String, Vec<f32>)],
    skip: Option<&str>,
) -> (f32, String) {
    assert_eq!(got.len(), exact.len(), "parameters");
    let scale = largest(exact).0;
    let mut worst = (0.0f32, String::new());
    for ((_, a), (name, b)) in got.iter().zip(exact) {
        if Some(name.as_str()) == skip {
            continue;
        }
        assert_eq!(a.len(), b.len(), "{name}");
        let e = a
            .iter()
            .zip(b)
            .fold(0.0f32, |m, (p, q)| m.max((p - q).abs()));
        if e / scale > worst.0 {
            worst = (e / scale, name.clone());
        }
    }
    worst
}

/// `set_op_impl` is process-wide: a test holds this while it computes steps.
static OPS: Mutex<()> = Mutex::new(());

/// The bundled SDFCNN, the batch, and the step in float64 with Burn's own ops (this crate's CPU
/// kernels compute in float32), computed once; the lock on `set_op_impl`, held.
fn reference() -> (
    Sdfcnn,
    &'static Batch,
    &'static Step,
    MutexGuard<'static, ()>,
) {
    static EXACT: OnceLock<(Batch, Step)> = OnceLock::new();
    let guard = OPS.lock().unwrap_or_else(|e| e.into_inner());
    let model = SdfcnnPredictor::load(
        &common::manifest_dir().join("weights/sdfcnn"),
        BackendKind::Flex,
    )
    .expect("bundled SDFCNN")
    .model()
    .clone();
    let (batch, exact) = EXACT.get_or_init(|| {
        // Before any tensor exists on ndarray in this process: it computes in float64.
        BackendKind::Ndarray
            .device()
            .expect("ndarray")
            .configure(FloatDType::F64)
            .expect("float64 on ndarray");
        let batch = tum_batch();
        set_op_impl(OpImpl::Burn);
        let exact = step(
            &model,
            &batch,
            &BackendKind::Ndarray.autodiff_device().unwrap(),
        );
        set_op_impl(OpImpl::Auto);
        (batch, exact)
    });
    (model, batch, exact, guard)
}

/// flex's step with `ops`, and its gradients' distance from the exact step.
fn flex_step(model: &Sdfcnn, batch: &Batch, exact: &Step, ops: OpImpl) -> (Step, (f32, String)) {
    set_op_impl(ops);
    let got = step(model, batch, &BackendKind::Flex.autodiff_device().unwrap());
    set_op_impl(OpImpl::Auto);
    let part = parting(&got.grads, &exact.grads);
    let total: usize = exact.grads.iter().map(|(_, g)| g.len()).sum();
    eprintln!(
        "float64 loss {}; flex with {ops:?} ops {} ({:.2e} of the largest gradient from float64, \
         at {}; {} of {total} gradient elements of the other sign)",
        exact.loss,
        got.loss,
        part.0,
        part.1,
        other_signs(&got.grads, &exact.grads)
    );
    (got, part)
}

/// This crate's CPU kernels (`OpImpl::Auto`) keep the step within float32's rounding of
/// float64: the loss within 1e-6; the gradients within [`ELSEWHERE`] of the largest gradient
/// everywhere but at the parameter holding it, and within [`ILL_CONDITIONED`] there.
///
/// That parameter is `layer2.blocks.0.expand`'s weight: the layer is the identity, and layer
/// 1's channel 3 is zero on every pixel of these frames, so its batch norm divides by √ε =
/// 0.0032 and the weight's float32 gradient is rounding amplified
/// (`lab/examples/step_conditioning.rs -- --stats`).
///
/// The bounds are absolute because how close a float32 step lands depends on the CPU:
/// Burn's own ops (printed beside, for comparison) were 1.4e-3 from float64 there on a 2-core
/// AMD EPYC VM with AVX2 and 8.4e-4 on an Intel Xeon VM with AVX-512, the kernels 1.6e-3 on
/// both; elsewhere the kernels were within 8e-5 on the first and 3.2e-5 on the second, Burn's
/// ops 8.4e-6 on the second (2026-12-07).
#[test]
fn the_cpu_kernels_keep_the_sdfcnn_step_within_float32_rounding_of_float64() {
    let (model, batch, exact, _ops) = reference();
    let (kernels, k) = flex_step(&model, batch, exact, OpImpl::Auto);
    let (burn_step, burn) = flex_step(&model, batch, exact, OpImpl::Burn);
    let loss = (kernels.loss - exact.loss).abs() / exact.loss.abs();
    assert!(loss <= 1e-6, "loss {loss:.2e} from float64");
    let largest = largest(&exact.grads).1;
    let rest = parting_except(&kernels.grads, &exact.grads, largest);
    let burn_rest = parting_except(&burn_step.grads, &exact.grads, largest);
    eprintln!(
        "largest gradient at {largest:?}; elsewhere: the kernels {rest:?}, Burn's ops {burn_rest:?}"
    );
    assert!(
        rest.0 <= ELSEWHERE,
        "this crate's kernels {rest:?} from float64 at every parameter but {largest:?} (Burn's \
         ops {burn_rest:?})"
    );
    assert!(
        k.0 <= ILL_CONDITIONED,
        "this crate's kernels {k:?} from float64 (Burn's ops {burn:?})"
    );
}

/// How far from float64, relative to the largest gradient, a float32 step may land at every
/// parameter but the one holding the largest gradient (see the test above): 1.5 times the
/// farthest seen.
const ELSEWHERE: f32 = 1.2e-4;

/// The same at the parameter holding the largest gradient.
const ILL_CONDITIONED: f32 = 2.4e-3;

/// Each GPU's float32 step is at least as close to the float64 step as flex's: the loss within
/// 1e-5 of it and the gradients within flex's distance (or 1e-4, if larger). Lavapipe with the
/// staged batch norm (`nn::batch_norm` on GPUs): loss 3.2e-7, gradients 6.5e-4 from float64
/// (flex 1.7e-7, 1.6e-3); with Burn's own batch norm it was 1.1e-5 and 6.5e-3 (2026-12-07).
#[cfg(any(feature = "wgpu", feature = "cuda"))]
#[test]
fn the_sdfcnn_step_on_the_gpu_is_as_close_to_float64_as_the_cpus() {
    let gpus = common::gpu_devices();
    if gpus.is_empty() {
        return;
    }
    let (model, batch, exact, _ops) = reference();
    let (cpu, cpu_part) = flex_step(&model, batch, exact, OpImpl::Auto);
    let mut failures = Vec::new();
    for (b, device) in gpus {
        let got = step(&model, batch, &device.autodiff());
        let part = parting(&got.grads, &exact.grads);
        let loss = (got.loss - exact.loss).abs() / exact.loss.abs();
        eprintln!(
            "{b} loss {} ({loss:.2e} from float64), gradients {:.2e} of the largest from float64, \
             at {}; {} gradient elements of the other sign",
            got.loss,
            part.0,
            part.1,
            other_signs(&got.grads, &exact.grads)
        );
        // The forward layers, each against float64: the GPU's and flex's distances.
        for (((name, g), (_, c)), (_, e)) in got.layers.iter().zip(&cpu.layers).zip(&exact.layers) {
            eprintln!(
                "  {name}: {b} {:.2e}, flex {:.2e}",
                relative(g, e),
                relative(c, e)
            );
        }
        if loss > 1e-5 || part.0 > 1e-4f32.max(cpu_part.0) {
            failures.push(format!("{b}: loss {loss:.2e}, gradients {part:?}"));
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}
