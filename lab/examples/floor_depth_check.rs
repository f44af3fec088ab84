//! Diagnostic (lab note `generalisation.md`): how SDFCNN's depth compares with the sensor's on
//! the pixels it labels floor, against all pixels, on a stretch of a real sequence. The floor
//! anchor of monocular SLAM assumes the floor's depth is wrong by the same factor as the rest.
//!
//! ```text
//! cargo run --release --example floor_depth_check -- SEQ CAMERA CKPT FIRST COUNT EVERY
//! ```
//!
//! Prints, for floor pixels and for all pixels with a sensor reading, the median of
//! sensor / predicted depth and the median sensor depth, and the same for the floor split
//! into the image's lower and upper half.

use anyhow::{Context, Result};
use sdf_slam::camera::Camera;
use sdf_slam::classes::label;
use sdf_slam::dataset::TumSequence;
use sdf_slam::nn::BackendKind;
use sdf_slam::sdfcnn::SdfcnnPredictor;

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() -> Result<()> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let [seq, cam, ckpt, first, count, every] = a.as_slice() else {
        anyhow::bail!("usage: floor_depth_check SEQ CAMERA CKPT FIRST COUNT EVERY");
    };
    let seq = TumSequence::open(seq)?;
    let camera = Camera::load(cam)?;
    let sdfcnn = SdfcnnPredictor::load(ckpt.as_ref(), BackendKind::Flex)?;
    let (first, count, every): (usize, usize, usize) =
        (first.parse()?, count.parse()?, every.parse()?);
    // (ratio, sensor depth) per pixel class: all, floor, floor in the lower half, upper half.
    let mut sets: [Vec<(f64, f64)>; 4] = Default::default();
    for i in (first..(first + count).min(seq.len())).step_by(every.max(1)) {
        let rgb = seq.load_rgb(i)?;
        let depth = seq.load_depth(i)?.context("no depth")?;
        let p = sdfcnn.predict_for_camera(&rgb, Some(camera.fx))?;
        if i == first {
            println!(
                "image {}x{}, prediction {}x{}, sensor depth {}x{}, fx {}",
                rgb.width(),
                rgb.height(),
                p.depth.width,
                p.depth.height,
                depth.width,
                depth.height,
                camera.fx
            );
        }
        let (w, h) = (depth.width, depth.height);
        for y in 0..h {
            for x in 0..w {
                let s = depth.data[(y * w + x) as usize] as f64;
                // Prediction at the sensor pixel (the prediction is at the image's size).
                let px = x * p.depth.width / w;
                let py = y * p.depth.height / h;
                let j = (py * p.depth.width + px) as usize;
                let d = p.depth.data[j] as f64;
                if s <= 0.0 || d <= 0.0 {
                    continue;
                }
                sets[0].push((s / d, s));
                if p.labels.data[j] == label::FLOOR {
                    sets[1].push((s / d, s));
                    sets[if y >= h / 2 { 2 } else { 3 }].push((s / d, s));
                }
            }
        }
    }
    for (name, v) in ["all", "floor", "floor, lower half", "floor, upper half"]
        .iter()
        .zip(sets)
    {
        let n = v.len();
        let ratio = median(v.iter().map(|r| r.0).collect());
        let sensor = median(v.iter().map(|r| r.1).collect());
        println!(
            "{name:<18} pixels {n:>9}  sensor/predicted {ratio:.3}  sensor depth {sensor:.2} m"
        );
    }
    Ok(())
}
