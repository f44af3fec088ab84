//! Is every ImageNet tensor in the right layer of SDFCNN's encoder? (`src/sdfcnn/imagenet.rs`)
//!
//! Each batch norm stores the running mean of its input over ImageNet. On natural images the
//! mean of that input over a batch correlates with it channel by channel, but only when the
//! convolution before it holds the weights it was trained with and receives the input it was
//! trained on, i.e. when every tensor up to that layer sits where it belongs. This prints
//! Pearson's r per batch norm on real frames of a TUM-layout sequence, for the ImageNet
//! initialisation and, as the control, for a random one.
//!
//! cargo run --release --example imagenet_check -- \
//!     --weights ../shared/pretrained/mobilenetv2_imagenet_features.safetensors \
//!     --sequence ../shared/data/7scenes_redkitchen_0_799 --images 16

use anyhow::Result;
use burn::prelude::*;
use clap::Parser;
use sdf_slam::dataset::TumSequence;
use sdf_slam::nn::seeded_init;
use sdf_slam::sdfcnn::SdfcnnConfig;
use sdf_slam::sdfcnn::imagenet::{bn_agreement, load_imagenet};
use sdf_slam::sdfcnn::inference::image_tensor;
use std::path::PathBuf;

#[derive(Parser)]
struct Args {
    /// torchvision-named MobileNetV2 safetensors.
    #[arg(long)]
    weights: PathBuf,
    /// TUM-layout sequence of real images.
    #[arg(long)]
    sequence: PathBuf,
    /// Frames, evenly spaced over the sequence.
    #[arg(long, default_value_t = 16)]
    images: usize,
    /// Layer0 size [height width] (the network's input size).
    #[arg(long, num_args = 2, default_values_t = [224, 288])]
    size: Vec<usize>,
}

fn main() -> Result<()> {
    let a = Args::parse();
    let device = Device::flex();
    let seq = TumSequence::open(&a.sequence)?;
    let n = a.images.clamp(1, seq.len());
    let images: Vec<Tensor<4>> = (0..n)
        .map(|k| Ok(image_tensor(&seq.load_rgb(k * seq.len() / n)?, &device)))
        .collect::<Result<_>>()?;
    let batch = Tensor::cat(images, 0);
    let config = SdfcnnConfig::new().with_inner_size([a.size[0], a.size[1]]);
    let random = seeded_init(config.init(&device)?, 1);
    let (imagenet, report) = load_imagenet(random.clone(), &a.weights)?;
    println!(
        "{} tensors loaded, {} ignored; {n} frames of {}\n",
        report.loaded,
        report.ignored.len(),
        a.sequence.display()
    );
    let r_imagenet = bn_agreement(&imagenet.encoder_bn_probe(batch.clone())?);
    let r_random = bn_agreement(&random.encoder_bn_probe(batch)?);
    println!("| batch norm | r (ImageNet) | r (random init) |");
    println!("|---|---|---|");
    for ((name, r), (_, r0)) in r_imagenet.iter().zip(&r_random) {
        println!("| {name} | {r:.3} | {r0:.3} |");
    }
    let summary = |r: &[(String, f64)]| {
        let mut v: Vec<f64> = r.iter().map(|x| x.1).collect();
        v.sort_by(f64::total_cmp);
        (
            v[v.len() / 2],
            v[0],
            v.iter().filter(|&&x| x > 0.5).count(),
            v.len(),
        )
    };
    for (what, r) in [("ImageNet", &r_imagenet), ("random", &r_random)] {
        let (median, min, above, total) = summary(r);
        println!(
            "\n{what}: median r {median:.3}, lowest {min:.3}, {above} of {total} layers above 0.5"
        );
    }
    Ok(())
}
