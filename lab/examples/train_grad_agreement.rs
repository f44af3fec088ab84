//! How far one SDFCNN training step's gradients move with the CPU kernels: the input gradient
//! of the eq. 21 loss (batch 4, 96×128, random weights, images, labels and depth) under
//! `OpImpl::Auto` (this crate's kernels) and `OpImpl::Composite` (the composite ops) against
//! `OpImpl::Burn` (Burn's own kernels), on ndarray and flex.
//!
//! ```sh
//! cargo run --release --example train_grad_agreement
//! ```

use anyhow::Result;
use burn::prelude::*;
use rand::{RngExt, SeedableRng};
use sdf_slam::nn::{OpImpl, set_op_impl};
use sdf_slam::sdfcnn::{SdfcnnConfig, SdfcnnLossConfig};

/// The loss and the input gradient of one step under `imp`.
fn step(
    imp: OpImpl,
    model: &sdf_slam::sdfcnn::Sdfcnn,
    data: &(Vec<f32>, Vec<f32>, Vec<i64>),
    [n, h, w]: [usize; 3],
    d: &Device,
) -> Result<(f32, Vec<f32>)> {
    set_op_impl(imp);
    let x = Tensor::<4>::from_data(TensorData::new(data.0.clone(), [n, 3, h, w]), d).require_grad();
    let depth = Tensor::<4>::from_data(TensorData::new(data.1.clone(), [n, 1, h, w]), d);
    let labels = Tensor::<3, Int>::from_data(TensorData::new(data.2.clone(), [n, h, w]), d);
    let out = model.forward_quarter(x.clone())?;
    let total = SdfcnnLossConfig::default()
        .forward(out, labels, depth)
        .total;
    let loss = total
        .clone()
        .into_data()
        .convert::<f32>()
        .try_to_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("{e:?}"))?[0];
    let grads = total.backward();
    let g = x
        .grad(&grads)
        .ok_or_else(|| anyhow::anyhow!("no input gradient"))?
        .into_data()
        .try_to_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    Ok((loss, g))
}

fn main() -> Result<()> {
    let dims = [4, 96, 128];
    let [n, h, w] = dims;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let data = (
        (0..n * 3 * h * w)
            .map(|_| rng.random_range(0.0..1.0))
            .collect(),
        (0..n * h * w).map(|_| rng.random_range(0.5..5.0)).collect(),
        (0..n * h * w).map(|_| rng.random_range(0..40i64)).collect(),
    );
    #[allow(deprecated)] // ndarray is deprecated upstream but the project's default backend.
    let devices = [Device::ndarray(), Device::flex()];
    for d in devices {
        let d = d.autodiff();
        let model = SdfcnnConfig::new().init(&d)?;
        let (burn_loss, reference) = step(OpImpl::Burn, &model, &data, dims, &d)?;
        for imp in [OpImpl::Auto, OpImpl::Composite] {
            let (loss, g) = step(imp, &model, &data, dims, &d)?;
            let scale = reference.iter().fold(0f32, |m, v| m.max(v.abs()));
            let max_diff = reference
                .iter()
                .zip(&g)
                .fold(0f32, |m, (a, b)| m.max((a - b).abs()));
            let dot: f64 = reference
                .iter()
                .zip(&g)
                .map(|(a, b)| f64::from(a * b))
                .sum();
            let norm = |v: &[f32]| v.iter().map(|a| f64::from(a * a)).sum::<f64>().sqrt();
            println!(
                "{d:?} {imp:?} vs Burn: loss {loss} vs {burn_loss}; input gradient cosine {:.6}, \
                 max |difference| {max_diff:.2e} of max {scale:.2e}",
                dot / (norm(&reference) * norm(&g))
            );
        }
    }
    set_op_impl(OpImpl::Auto);
    Ok(())
}
