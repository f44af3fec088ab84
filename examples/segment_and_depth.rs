//! Segment one image into the 40 NYUv2 classes and predict its metric depth with the bundled
//! SDFCNN (`weights/sdfcnn`). Depth from one image is metric for a known camera only: the
//! network predicts it for NYUv2's focal length and scales it to the given one (`--fx`, pixels
//! at the image's width).
//!
//! ```text
//! cargo run --release --example segment_and_depth -- [IMAGE] [--fx PIXELS] [--out DIR]
//! ```
//!
//! Defaults: the bundled NYUv2 image `datasets/fixtures/nyuv2/000433_rgb.png`, NYUv2's focal
//! length (518.86 px), pictures written to `runs/examples/` (`labels.png`, `depth.png`).

use anyhow::{Context, Result, bail};
use sdf_slam::bundled::{BUNDLED_SDFCNN, bundled_weights, locate};
use sdf_slam::classes;
use sdf_slam::imageio::{read_rgb, write_png_atomic};
use sdf_slam::nn::BackendKind;
use sdf_slam::sdfcnn::SdfcnnPredictor;
use sdf_slam::sdfcnn::focal::NYU_FX;
use sdf_slam::sdfcnn::inference::{colorize_depth, colorize_labels};
use std::path::PathBuf;

const DEFAULT_IMAGE: &str = "datasets/fixtures/nyuv2/000433_rgb.png";

fn main() -> Result<()> {
    let (mut image, mut fx, mut out) = (None, NYU_FX, PathBuf::from("runs/examples"));
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--fx" => {
                let v = args.next().context("--fx needs a focal length in pixels")?;
                fx = v
                    .parse()
                    .ok()
                    .filter(|f: &f64| f.is_finite() && *f > 0.0)
                    .with_context(|| format!("--fx {v}: not a positive number of pixels"))?;
            }
            "--out" => out = args.next().context("--out needs a folder")?.into(),
            s if s.starts_with('-') => {
                bail!(
                    "unknown option {s}: usage segment_and_depth [IMAGE] [--fx PIXELS] [--out DIR]"
                )
            }
            _ if image.is_none() => image = Some(PathBuf::from(a)),
            _ => bail!("one image at a time (got {a} as well)"),
        }
    }
    let image = match image {
        Some(p) => p,
        None => locate(DEFAULT_IMAGE)
            .with_context(|| format!("the default image {DEFAULT_IMAGE} is not here"))?,
    };

    let weights = bundled_weights(BUNDLED_SDFCNN).with_context(|| {
        format!("no bundled SDFCNN weights ({BUNDLED_SDFCNN}/model.bpk + config.toml)")
    })?;
    let sdfcnn = SdfcnnPredictor::load(&weights, BackendKind::Ndarray)
        .with_context(|| format!("loading SDFCNN from {}", weights.display()))?;
    let rgb = read_rgb(&image).with_context(|| format!("reading {}", image.display()))?;
    let (pred, seconds) = sdfcnn.predict_timed_for_camera(&rgb, Some(fx))?;
    println!(
        "{} ({}x{}, fx {fx:.1} px): SDFCNN took {seconds:.2} s",
        image.display(),
        rgb.width(),
        rgb.height()
    );

    // Label histogram, largest classes first.
    let mut counts = [0usize; 256];
    pred.labels
        .data
        .iter()
        .for_each(|&l| counts[l as usize] += 1);
    let mut classes_seen: Vec<(usize, u8)> = (0..=255u8)
        .filter(|&l| counts[l as usize] > 0)
        .map(|l| (counts[l as usize], l))
        .collect();
    classes_seen.sort_by(|a, b| b.cmp(a));
    let total = pred.labels.data.len().max(1) as f64;
    println!("labels ({} classes):", classes_seen.len());
    for (n, l) in &classes_seen {
        println!(
            "  {:>5.1} %  {}",
            100.0 * *n as f64 / total,
            classes::display_name(*l)
        );
    }

    let valid: Vec<f32> = pred
        .depth
        .data
        .iter()
        .copied()
        .filter(|d| d.is_finite() && *d > 0.0)
        .collect();
    if valid.is_empty() {
        bail!("SDFCNN predicted no valid depth for {}", image.display());
    }
    let (min, max) = valid
        .iter()
        .fold((f32::MAX, 0.0f32), |(lo, hi), &d| (lo.min(d), hi.max(d)));
    let mean = valid.iter().map(|&d| d as f64).sum::<f64>() / valid.len() as f64;
    println!("depth: {min:.2} to {max:.2} m, mean {mean:.2} m");

    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let (labels_png, depth_png) = (out.join("labels.png"), out.join("depth.png"));
    write_png_atomic(&labels_png, &colorize_labels(&pred.labels).into())?;
    write_png_atomic(&depth_png, &colorize_depth(&pred.depth, None).into())?;
    println!(
        "wrote {} (NYU40 colours) and {} (viridis, 0 to {max:.2} m)",
        labels_png.display(),
        depth_png.display()
    );
    Ok(())
}
