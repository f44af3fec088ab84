//! Where FPFDCNN puts its keypoints, and why matches miss the 5-px criterion.
//!
//! For the frames `--first..` of a TUM-layout sequence:
//! * the share of the detector's keypoints within 0.5 / 1.5 / 2.5 / 4 / 8 px of a Harris
//!   corner (the corners the detector is trained to reproduce, as the training targets);
//! * for the pairs `(i, i + gap)`, the matching accuracy of ORB + BF and of FPFDCNN + the
//!   range matcher, and the same after removing each pair's median error vector: what is
//!   left when the ground truth's own per-pair offset (motion-capture sync on fr1) is
//!   taken out, i.e. how repeatably the keypoints sit on the same scene points;
//! * with `--picture FILE.png`, the first frame with its Harris corners (green) and
//!   keypoints (red) beside the probability map.
//!
//! cargo run --release --example fpfdcnn_keypoints -- --sequence ../shared/data/tum_fr1_rpy_head80 \
//!     --first 56 --fpfdcnn weights/fpfdcnn [--smoothing 3] [--picture map.png]

use anyhow::{Context, Result};
use burn::prelude::*;
use clap::Parser;
use nalgebra::Vector2;
use sdf_slam::camera::Camera;
use sdf_slam::dataset::TumSequence;
use sdf_slam::dataset::fp_pairs::transfer;
use sdf_slam::features::harris::{HarrisConfig, harris_corners};
use sdf_slam::features::orb::OrbConfig;
use sdf_slam::fpfdcnn::evaluate::{fpfdcnn_matches, orb_matches};
use sdf_slam::fpfdcnn::{DetectorConfig, FpfdcnnDetector};
use sdf_slam::metrics::matching::CORRECT_MATCH_PX;
use sdf_slam::nn::BackendKind;
use sdf_slam::range_matcher::{GuideConfig, RangeMatcherConfig};
use sdf_slam::raster::GrayF32;
use sdf_slam::raster::gray_from_f32;
use std::path::PathBuf;

#[derive(Parser)]
struct Args {
    #[arg(long)]
    sequence: PathBuf,
    #[arg(long)]
    fpfdcnn: PathBuf,
    #[arg(long, default_value = "fr1")]
    camera: String,
    #[arg(long, default_value_t = 0)]
    first: usize,
    #[arg(long, default_value_t = 5)]
    gap: usize,
    #[arg(long, value_enum, default_value_t = BackendKind::Flex)]
    backend: BackendKind,
    /// Detector smoothing (pixels) and NMS radius.
    #[arg(long, default_value_t = sdf_slam::fpfdcnn::inference::DEFAULT_SMOOTHING)]
    smoothing: f32,
    #[arg(long, default_value_t = 4)]
    nms: usize,
    /// Cell-grid placements the FP map is averaged over (1, 2 or 4), as `eval matching`.
    #[arg(long, default_value_t = sdf_slam::fpfdcnn::inference::DEFAULT_GRID_SHIFTS)]
    grid_shifts: usize,
    #[arg(long)]
    picture: Option<PathBuf>,
}

/// The Harris corners the checkpoint was trained on (its config's `[data.targets]`).
fn targets(checkpoint: &std::path::Path) -> Result<HarrisConfig> {
    let (_, cfg_path) = sdf_slam::training::resolve_checkpoint(checkpoint)?;
    let text = sdf_slam::io::read_text(&cfg_path)?;
    let cfg = sdf_slam::fpfdcnn::training::FpfdcnnTrainConfig::parse_saved(&text, &cfg_path)?;
    Ok(cfg.data.targets)
}

fn main() -> Result<()> {
    let a = Args::parse();
    let targets = targets(&a.fpfdcnn)?;
    let seq = TumSequence::open(&a.sequence)?;
    let cam = Camera::load(&a.camera)?;
    let det = FpfdcnnDetector::load(
        &a.fpfdcnn,
        a.backend,
        DetectorConfig {
            smoothing: a.smoothing,
            nms_radius: a.nms,
            grid_shifts: a.grid_shifts,
            ..Default::default()
        },
    )?;
    anyhow::ensure!(
        a.first + a.gap < seq.len(),
        "not enough frames after --first"
    );

    // 1. Keypoints against Harris corners.
    let radii = [0.5f32, 1.5, 2.5, 4.0, 8.0];
    let mut near = [0usize; 5];
    let mut total = 0usize;
    for i in a.first..seq.len() {
        let gray = seq.load_gray(i)?;
        let corners = harris_corners(&GrayF32::from_gray(&gray), &targets);
        let f = det.detect(&gray)?;
        for p in &f.points {
            let d = corners
                .iter()
                .map(|k| (k.x - p[0]).hypot(k.y - p[1]))
                .fold(f32::MAX, f32::min);
            for (n, r) in near.iter_mut().zip(radii) {
                *n += usize::from(d <= r);
            }
        }
        total += f.len();
        if let (Some(path), true) = (&a.picture, i == a.first) {
            picture(&det, &gray, &corners, &f.points, path)?;
        }
    }
    println!("keypoints within r px of a Harris corner ({total} keypoints):");
    for (n, r) in near.iter().zip(radii) {
        println!(
            "  r = {r:3}: {:5.1} %",
            100.0 * *n as f64 / total.max(1) as f64
        );
    }

    // 2. Matching accuracy with and without each pair's median error vector.
    let range = RangeMatcherConfig {
        mutual: true,
        ratio: Some(0.8),
        ..Default::default()
    };
    let guide = GuideConfig::default();
    let orb = OrbConfig::default();
    let mut sums = [[0usize; 3]; 2];
    println!("pair      | method  matches  accuracy  median offset (px)  accuracy without it");
    for i in a.first..seq.len() - a.gap {
        let (fa, fb) = (seq.load_frame(i)?, seq.load_frame(i + a.gap)?);
        let (Some(pa), Some(pb), Some(depth)) = (fa.gt_pose, fb.gt_pose, fa.depth.as_ref()) else {
            continue;
        };
        let ga = gray_from_f32(&GrayF32::from_rgb(&fa.rgb));
        let gb = gray_from_f32(&GrayF32::from_rgb(&fb.rgb));
        let (orb_matches, _) = orb_matches(&ga, &gb, &orb)?;
        let fp_matches =
            fpfdcnn_matches(&det.detect(&ga)?, &det.detect(&gb)?, &range, Some(&guide))?;
        for (k, (name, m)) in [("ORB", orb_matches), ("FPFDCNN", fp_matches)]
            .into_iter()
            .enumerate()
        {
            let errors: Vec<Vector2<f64>> = m
                .iter()
                .filter_map(|(p, q)| {
                    let z = depth.at(p.x, p.y)?;
                    transfer(&cam, p, z as f64, &pa, &pb).map(|(gt, _)| q - gt)
                })
                .collect();
            let median = |f: fn(&Vector2<f64>) -> f64| {
                let mut v: Vec<f64> = errors.iter().map(f).collect();
                v.sort_by(f64::total_cmp);
                v.get(v.len() / 2).copied().unwrap_or(0.0)
            };
            let offset = Vector2::new(median(|e| e.x), median(|e| e.y));
            let within = |shift: Vector2<f64>| {
                errors
                    .iter()
                    .filter(|e| (*e - shift).norm() <= CORRECT_MATCH_PX)
                    .count()
            };
            let (raw, fixed) = (within(Vector2::zeros()), within(offset));
            let n = errors.len().max(1) as f64;
            println!(
                "{i:3} -> {:3} | {name:7} {:7}  {:7.1} %  ({:+5.1}, {:+5.1})        {:5.1} %",
                i + a.gap,
                errors.len(),
                100.0 * raw as f64 / n,
                offset.x,
                offset.y,
                100.0 * fixed as f64 / n
            );
            let s = &mut sums[k];
            s[0] += errors.len();
            s[1] += raw;
            s[2] += fixed;
        }
    }
    for (name, s) in ["ORB", "FPFDCNN"].iter().zip(sums) {
        let n = s[0].max(1) as f64;
        println!(
            "{name}: accuracy {:.1} % of {} matches, {:.1} % without each pair's median offset",
            100.0 * s[1] as f64 / n,
            s[0],
            100.0 * s[2] as f64 / n
        );
    }
    Ok(())
}

/// The frame with Harris corners (green crosses) and keypoints (red) beside the
/// probability map (square-root scaled).
fn picture(
    det: &FpfdcnnDetector,
    gray: &image::GrayImage,
    corners: &[sdf_slam::features::harris::Keypoint],
    points: &[[f32; 2]],
    path: &PathBuf,
) -> Result<()> {
    let (w, h) = (gray.width() as usize, gray.height() as usize);
    anyhow::ensure!(
        w % 16 == 0 && h % 16 == 0,
        "the picture needs sides divisible by 16"
    );
    let data: Vec<f32> = gray.as_raw().iter().map(|v| *v as f32 / 255.0).collect();
    let input = Tensor::<4>::from_data(TensorData::new(data, [1, 1, h, w]), &det.device);
    let out = det.model.forward(input)?;
    let prob = out
        .prob
        .into_data()
        .try_to_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let peak = prob.iter().copied().fold(1e-12f32, f32::max);
    let mut img = image::RgbImage::new(2 * w as u32, h as u32);
    for (i, (g, p)) in gray.as_raw().iter().zip(&prob).enumerate() {
        let (x, y) = ((i % w) as u32, (i / w) as u32);
        img.put_pixel(x, y, image::Rgb([g / 2; 3]));
        let q = (255.0 * (p / peak).sqrt()) as u8;
        img.put_pixel(x + w as u32, y, image::Rgb([q; 3]));
    }
    let mut dot = |x: i64, y: i64, c: [u8; 3]| {
        for x0 in [0, w as i64] {
            if x >= 0 && y >= 0 && x < w as i64 && y < h as i64 {
                img.put_pixel((x + x0) as u32, y as u32, image::Rgb(c));
            }
        }
    };
    for k in corners {
        let (x, y) = (k.x as i64, k.y as i64);
        for d in -2..=2 {
            dot(x + d, y, [0, 255, 0]);
            dot(x, y + d, [0, 255, 0]);
        }
    }
    for p in points {
        dot(p[0] as i64, p[1] as i64, [255, 0, 0]);
    }
    sdf_slam::imageio::write_png_atomic(path, &image::DynamicImage::ImageRgb8(img))
        .with_context(|| format!("writing {}", path.display()))?;
    println!("wrote {}", path.display());
    Ok(())
}
