//! How reproducible one SDFCNN training step is in float32, from random weights on a synthetic
//! ramp (the GPU test's setting) and from the bundled weights on eight TUM fixture frames, at
//! the recipe's 144x192, batch 8: the parameter gradients of the eq. 21 loss, each difference
//! relative to the model's largest gradient (issue 74, item 2's yardstick).
//!
//! ```sh
//! cargo run --release --example step_conditioning           # float32 against float32
//! cargo run --release --example step_conditioning -- --f64  # against the step in float64
//! cargo run --release --example step_conditioning -- --stats
//! ```
//!
//! Without flags: this crate's kernels (`OpImpl::Auto`) against Burn's own ops on flex, and
//! ndarray against flex with each. `--f64`: ndarray in float64 with Burn's own ops (this
//! crate's CPU kernels compute in float32) as the exact step, and flex with either set of ops
//! against it (`SDF_SLAM_PER_PARAM=1` lists the worst parameters). `--stats`: the layer-1
//! channels that are zero on every pixel of the TUM batch, whose batch norms after the
//! identity expansion of `layer2.blocks.0` divide by √ε.

use anyhow::Result;
use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use sdf_slam::nn::{BackendKind, OpImpl, seeded_init, set_op_impl};
use sdf_slam::sdfcnn::{Sdfcnn, SdfcnnConfig, SdfcnnLossConfig, SdfcnnPredictor};

struct Grads<'a>(&'a burn::tensor::Gradients, Vec<Vec<f32>>, Vec<String>);

static NAMES: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

impl ModuleVisitor for Grads<'_> {
    fn enter_module(&mut self, name: &str, _: &str) {
        self.2.push(name.to_string());
    }
    fn exit_module(&mut self, _: &str, _: &str) {
        self.2.pop();
    }
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if let Some(g) = param.val().grad(self.0) {
            let mut names = NAMES.lock().unwrap();
            if names.len() == self.1.len() {
                names.push(self.2.join("."));
            }
            self.1
                .push(g.into_data().convert::<f32>().try_to_vec::<f32>().unwrap());
        }
    }
}

struct Batch {
    images: Vec<f32>,
    depth: Vec<f32>,
    labels: Vec<i64>,
    dims: [usize; 3],
}

/// Casts every float parameter to the device's default float type (float64 for the reference).
struct ToDefault(burn::tensor::FloatDType);

impl burn::module::ModuleMapper for ToDefault {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let dtype = self.0;
        param.map(|t| t.cast(dtype).detach())
    }
}

fn step(model: &Sdfcnn, b: &Batch, d: &Device) -> Result<(f32, Vec<Vec<f32>>)> {
    let [n, h, w] = b.dims;
    let dtype = d.settings().float_dtype;
    let model = model.clone().fork(d).map(&mut ToDefault(dtype)).train();
    let x = Tensor::<4>::from_data(TensorData::new(b.images.clone(), [n, 3, h, w]), d).cast(dtype);
    let depth =
        Tensor::<4>::from_data(TensorData::new(b.depth.clone(), [n, 1, h, w]), d).cast(dtype);
    let labels = Tensor::<3, Int>::from_data(TensorData::new(b.labels.clone(), [n, h, w]), d);
    let out = model.forward_quarter(x)?;
    let total = SdfcnnLossConfig::default()
        .forward(out, labels, depth)
        .total;
    let loss = total
        .clone()
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .unwrap()[0];
    let grads = total.backward();
    let mut v = Grads(&grads, Vec::new(), Vec::new());
    model.visit(&mut v);
    Ok((loss, v.1))
}

/// Largest gradient difference relative to the reference model's largest gradient, and the
/// same per parameter against the parameter's own largest, worst case.
fn parting(a: &[Vec<f32>], b: &[Vec<f32>]) -> (f32, f32) {
    let scale = b.iter().flatten().fold(1e-12f32, |m, v| m.max(v.abs()));
    let mut worst = 0.0f32;
    for (x, y) in a.iter().zip(b) {
        for (p, q) in x.iter().zip(y) {
            worst = worst.max((p - q).abs());
        }
    }
    (worst / scale, scale)
}

fn ramp_batch([n, h, w]: [usize; 3]) -> Batch {
    let images = (0..n * 3 * h * w)
        .map(|i| ((i * 7919 % 1000) as f32 / 1000.0) - 0.3)
        .collect();
    let labels = (0..n * h * w)
        .map(|i| if i % 7 == 0 { 255 } else { (i % 40) as i64 })
        .collect();
    let depth = (0..n * h * w)
        .map(|i| {
            if i % 11 == 0 {
                0.0
            } else {
                0.5 + (i % 50) as f32 / 20.0
            }
        })
        .collect();
    Batch {
        images,
        depth,
        labels,
        dims: [n, h, w],
    }
}

/// TUM fixture frames with their sensor depth (labels: a pattern; they only set the term).
fn tum_batch([n, h, w]: [usize; 3]) -> Result<Batch> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("datasets/fixtures/tum_fr1_rpy_head10");
    let assoc = std::fs::read_to_string(root.join("associations.txt"))?;
    let (mut images, mut depth) = (Vec::new(), Vec::new());
    for line in assoc.lines().filter(|l| !l.starts_with('#')).take(n) {
        let f: Vec<&str> = line.split_whitespace().collect();
        let rgb = image::open(root.join(f[1]))?
            .resize_exact(w as u32, h as u32, image::imageops::FilterType::Triangle)
            .to_rgb8();
        for c in 0..3 {
            for p in rgb.pixels() {
                images.push(p.0[c] as f32 / 255.0);
            }
        }
        let d = image::open(root.join(f[3]))?
            .resize_exact(w as u32, h as u32, image::imageops::FilterType::Nearest)
            .to_luma16();
        depth.extend(d.pixels().map(|p| p.0[0] as f32 / 5000.0));
    }
    let labels = (0..n * h * w).map(|i| ((i / w / 12) % 40) as i64).collect();
    Ok(Batch {
        images,
        depth,
        labels,
        dims: [n, h, w],
    })
}

/// The weights of the parameter at `path`.
struct Weights(&'static str, Vec<String>, Vec<f32>);

impl ModuleVisitor for Weights {
    fn enter_module(&mut self, name: &str, _: &str) {
        self.1.push(name.to_string());
    }
    fn exit_module(&mut self, _: &str, _: &str) {
        self.1.pop();
    }
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        if self.1.join(".") == self.0 {
            self.2 = param
                .val()
                .into_data()
                .convert::<f32>()
                .try_to_vec::<f32>()
                .unwrap();
        }
    }
}

/// Layer 1's channels that are zero on every pixel of the batch (ReLU6 of a batch-normed
/// convolution), and `layer2.blocks.0.expand`'s rows (an identity where the ImageNet network
/// has no expansion): a channel it copies is constant, so its batch norm divides by √ε, which
/// makes that channel's weights' gradients the model's largest (`--stats`).
fn stats(model: &Sdfcnn, b: &Batch, d: &Device) -> Result<()> {
    let [n, h, w] = b.dims;
    let x = Tensor::<4>::from_data(TensorData::new(b.images.clone(), [n, 3, h, w]), d);
    let mut trace = sdf_slam::nn::ShapeTrace::with_values();
    model
        .clone()
        .fork(d)
        .train()
        .forward_quarter_traced(x, &mut trace)?;
    let layer1 = trace
        .layers()
        .iter()
        .find(|l| l.name == "Layer1")
        .and_then(|l| l.values.clone())
        .ok_or_else(|| anyhow::anyhow!("no Layer1 in the trace"))?;
    let channels = 32;
    let plane = layer1.len() / n / channels;
    let zero: Vec<usize> = (0..channels)
        .filter(|&c| {
            (0..n).all(|i| {
                layer1[(i * channels + c) * plane..(i * channels + c + 1) * plane]
                    .iter()
                    .all(|&v| v == 0.0)
            })
        })
        .collect();
    let mut wv = Weights("layer2.blocks.0.expand.conv.weight", Vec::new(), Vec::new());
    model.visit(&mut wv);
    let identity = wv.2.chunks(channels).enumerate().all(|(o, row)| {
        row.iter()
            .enumerate()
            .all(|(k, &v)| v == if k == o { 1.0 } else { 0.0 })
    });
    println!(
        "Layer1 channels zero on every pixel: {zero:?}; layer2.blocks.0.expand is the identity: {identity}"
    );
    Ok(())
}

fn main() -> Result<()> {
    let dims = [8, 144, 192];
    let flex = BackendKind::Flex.autodiff_device()?;
    let ndarray = BackendKind::Ndarray.autodiff_device()?;
    let f64_reference = std::env::args().any(|a| a == "--f64");
    if f64_reference {
        let mut d = BackendKind::Ndarray.device()?;
        d.configure(burn::tensor::FloatDType::F64)
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    }
    let cfg = SdfcnnConfig::new()
        .with_inner_size([dims[1], dims[2]])
        .with_decoder_dim(256);
    let random = seeded_init(cfg.init(&flex)?, 5);
    let bundled = SdfcnnPredictor::load(
        std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/weights/sdfcnn")),
        BackendKind::Flex,
    )?
    .model()
    .clone();
    let ramp = ramp_batch(dims);
    let tum = tum_batch(dims)?;
    if std::env::args().any(|a| a == "--stats") {
        return stats(&bundled, &tum, &flex);
    }
    for (what, model, batch) in [
        ("random weights, ramp", &random, &ramp),
        ("random weights, TUM frames", &random, &tum),
        ("bundled weights, ramp", &bundled, &ramp),
        ("bundled weights, TUM frames", &bundled, &tum),
    ] {
        if f64_reference {
            set_op_impl(OpImpl::Burn);
            let (lr, gr) = step(model, batch, &ndarray)?;
            set_op_impl(OpImpl::Composite);
            let (lc, gc) = step(model, batch, &ndarray)?;
            let (comp, _) = parting(&gc, &gr);
            set_op_impl(OpImpl::Auto);
            let (la, ga) = step(model, batch, &flex)?;
            set_op_impl(OpImpl::Burn);
            let (lb, gb) = step(model, batch, &flex)?;
            let (auto, scale) = parting(&ga, &gr);
            if std::env::var("SDF_SLAM_PER_PARAM").is_ok() {
                let scale = gr.iter().flatten().fold(0f32, |m, v| m.max(v.abs()));
                let mut rows: Vec<(f32, usize, usize, f32)> = ga
                    .iter()
                    .zip(&gr)
                    .enumerate()
                    .map(|(k, (a, b))| {
                        let (i, e) =
                            a.iter()
                                .zip(b)
                                .enumerate()
                                .fold((0, 0f32), |m, (i, (p, q))| {
                                    if (p - q).abs() > m.1 {
                                        (i, (p - q).abs())
                                    } else {
                                        m
                                    }
                                });
                        (
                            e / scale,
                            k,
                            i,
                            b.iter().fold(0f32, |m, v| m.max(v.abs())) / scale,
                        )
                    })
                    .collect();
                rows.sort_by(|a, b| b.0.total_cmp(&a.0));
                for (e, k, i, own) in rows.iter().take(8) {
                    println!(
                        "  param {k} {} (len {}) element {i}: {e:.2e} of the model's largest; its own largest {own:.2e}",
                        NAMES.lock().unwrap()[*k],
                        gr[*k].len()
                    );
                }
            }
            let (burn, _) = parting(&gb, &gr);
            println!(
                "{what}: float64 loss {lr:.7} (composite {lc:.7}), largest gradient {scale:.3e}; \
                 against it: float64 composite {comp:.2e}, flex this crate's ops {auto:.2e} (loss {la:.7}), \
                 flex Burn's ops {burn:.2e} (loss {lb:.7})"
            );
            continue;
        }
        set_op_impl(OpImpl::Auto);
        let (l0, g0) = step(model, batch, &flex)?;
        set_op_impl(OpImpl::Burn);
        let (l1, g1) = step(model, batch, &flex)?;
        let (_, g3) = step(model, batch, &ndarray)?;
        set_op_impl(OpImpl::Auto);
        let (l2, g2) = step(model, batch, &ndarray)?;
        let (burn, scale) = parting(&g1, &g0);
        let (nd, _) = parting(&g2, &g0);
        let (nd_burn, _) = parting(&g3, &g1);
        println!(
            "{what}: loss {l0:.6} (Burn's ops {l1:.6}, ndarray {l2:.6}); largest gradient {scale:.3e}; \
             Burn's ops vs this crate's {burn:.2e}; ndarray vs flex: this crate's ops {nd:.2e}, Burn's {nd_burn:.2e}"
        );
    }
    Ok(())
}
