//! FPFDCNN training data, built as the paper builds its FP dataset (section IV-B,
//! V-B): frame pairs `(i, i + k)` of TUM-layout RGB-D sequences with ground truth,
//! Harris corners as detector targets, and their ground-truth matches (eqs 5-7,
//! [`crate::dataset::fp_pairs`]) for the descriptors.
//!
//! Images are kept in memory as grayscale at the training resolution; match
//! positions are scaled to it. The last `val_fraction` of every sequence (by
//! frame index) is held out for validation.

use crate::camera::Camera;
use crate::dataset::fp_pairs::{FpConfig, FpMatch, fp_pairs};
use crate::dataset::photometric::PhotometricAugment;
use crate::dataset::tum::TumSequence;
use crate::error::{Error, Result};
use crate::features::harris::{HarrisConfig, harris_corners};
use crate::raster::GrayF32;
use burn::prelude::*;
use rand::seq::SliceRandom;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// One training sequence.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SequenceSource {
    /// TUM-layout folder with depth and ground truth.
    pub path: PathBuf,
    /// Camera preset (`fr1`, `fr2`, `fr3`) or camera TOML file.
    #[serde(default = "default_camera")]
    pub camera: String,
}

fn default_camera() -> String {
    "fr1".into()
}

/// The `[data]` table of a FPFDCNN training config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FpDataConfig {
    pub sequences: Vec<SequenceSource>,
    /// Frame pairs and ground-truth matching (gaps, Harris corners of A, occlusion test).
    pub pairs: FpConfig,
    /// Harris corners of the resized training image: the detector targets.
    pub targets: HarrisConfig,
    /// Share of each sequence's frames (the last ones) kept for validation.
    pub val_fraction: f64,
    /// Photometric augmentation of both images of a pair.
    pub augment: PhotometricAugment,
}

impl Default for FpDataConfig {
    fn default() -> Self {
        FpDataConfig {
            sequences: Vec::new(),
            pairs: FpConfig::default(),
            targets: HarrisConfig {
                max_corners: 400,
                nms_radius: 3,
                border: 4,
                ..HarrisConfig::default()
            },
            val_fraction: 0.15,
            augment: PhotometricAugment::default(),
        }
    }
}

/// A frame at the training resolution.
#[derive(Debug, Clone)]
pub struct FrameEntry {
    pub gray: GrayF32,
    /// Detector target pixels `(x, y)`.
    pub targets: Vec<(usize, usize)>,
}

/// A frame pair with its matches at the training resolution.
#[derive(Debug, Clone)]
pub struct PairEntry {
    pub a: usize,
    pub b: usize,
    pub matches: Vec<FpMatch>,
}

/// Frames and pairs of one split.
#[derive(Debug, Clone, Default)]
pub struct FpDataset {
    pub height: usize,
    pub width: usize,
    pub frames: Vec<FrameEntry>,
    pub pairs: Vec<PairEntry>,
}

/// A batch ready for the network.
pub struct FpBatch {
    pub image_a: Tensor<4>,
    pub image_b: Tensor<4>,
    pub target_a: Tensor<4>,
    pub target_b: Tensor<4>,
    /// Matches of each pair (training resolution), at most `max_matches`.
    pub matches: Vec<Vec<FpMatch>>,
}

/// Resizes a float image with bilinear sampling (pixel centres aligned).
pub fn resize_gray(img: &GrayF32, width: usize, height: usize) -> GrayF32 {
    if (img.width, img.height) == (width, height) {
        return img.clone();
    }
    let (sx, sy) = (
        img.width as f64 / width as f64,
        img.height as f64 / height as f64,
    );
    // Pre-blur when shrinking, so that the small image is not aliased.
    let src = if sx > 1.5 {
        img.gaussian_blur((0.5 * sx) as f32)
    } else {
        img.clone()
    };
    let mut out = GrayF32::new(width, height);
    out.data
        .par_chunks_mut(width)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, v) in row.iter_mut().enumerate() {
                *v = src.sample((x as f64 + 0.5) * sx - 0.5, (y as f64 + 0.5) * sy - 0.5);
            }
        });
    out
}

/// Maps a pixel position to an image resized by `scale` (pixel centres aligned).
fn scale_point(p: [f32; 2], sx: f32, sy: f32) -> [f32; 2] {
    [(p[0] + 0.5) * sx - 0.5, (p[1] + 0.5) * sy - 0.5]
}

impl FpDataset {
    /// Builds the training and validation splits from the configured sequences.
    pub fn build(
        cfg: &FpDataConfig,
        [height, width]: [usize; 2],
        mut progress: impl FnMut(&str),
    ) -> Result<(FpDataset, FpDataset)> {
        if cfg.sequences.is_empty() {
            return Err(Error::msg(
                "[data] lists no sequences: add [[data.sequences]] entries with a path",
            ));
        }
        if !(0.0..1.0).contains(&cfg.val_fraction) {
            return Err(Error::msg(format!(
                "val_fraction must be in [0, 1), got {}",
                cfg.val_fraction
            )));
        }
        let mut train = FpDataset {
            height,
            width,
            ..Default::default()
        };
        let mut val = train.clone();
        for src in &cfg.sequences {
            let seq = TumSequence::open(&src.path)?;
            let camera = Camera::load(&src.camera)?;
            if !seq.has_depth() || seq.groundtruth.is_none() {
                return Err(Error::invalid(
                    &src.path,
                    "FPFDCNN training needs depth and groundtruth.txt",
                ));
            }
            progress(&format!("{}: {} frames", seq.name(), seq.len()));
            let n = seq.len();
            let cut = ((n as f64) * (1.0 - cfg.val_fraction)).round() as usize;
            // Frames at the training resolution, with their Harris targets.
            let offset_train = train.frames.len();
            let offset_val = val.frames.len();
            let loaded: Vec<Result<FrameEntry>> = (0..n)
                .into_par_iter()
                .map(|i| {
                    let gray = GrayF32::from_gray(&seq.load_gray(i)?);
                    let gray = resize_gray(&gray, width, height);
                    let targets = harris_corners(&gray, &cfg.targets)
                        .iter()
                        .map(|k| (k.x as usize, k.y as usize))
                        .collect();
                    Ok(FrameEntry { gray, targets })
                })
                .collect();
            for (i, f) in loaded.into_iter().enumerate() {
                let f = f?;
                if i < cut {
                    train.frames.push(f)
                } else {
                    val.frames.push(f)
                }
            }
            let (sx, sy) = (
                width as f32 / camera.width as f32,
                height as f32 / camera.height as f32,
            );
            for pair in fp_pairs(&seq, &camera, &cfg.pairs) {
                let pair = pair?;
                let (a, b) = (pair.frame_a, pair.frame_b);
                let matches: Vec<FpMatch> = pair
                    .matches
                    .iter()
                    .map(|m| FpMatch {
                        a: scale_point(m.a, sx, sy),
                        b: scale_point(m.b, sx, sy),
                    })
                    .filter(|m| inside(m.a, width, height) && inside(m.b, width, height))
                    .collect();
                if matches.len() < 8 {
                    continue;
                }
                if b < cut {
                    train.pairs.push(PairEntry {
                        a: offset_train + a,
                        b: offset_train + b,
                        matches,
                    });
                } else if a >= cut {
                    val.pairs.push(PairEntry {
                        a: offset_val + a - cut,
                        b: offset_val + b - cut,
                        matches,
                    });
                }
            }
        }
        if train.pairs.is_empty() {
            return Err(Error::msg(
                "no training pairs with at least 8 ground-truth matches",
            ));
        }
        Ok((train, val))
    }

    /// Assembles the pairs `ids` into a batch: photometric augmentation (seeded by
    /// `rng`), target maps, and a random subset of at most `max_matches` matches.
    pub fn batch(
        &self,
        ids: &[usize],
        augment: Option<&PhotometricAugment>,
        max_matches: usize,
        rng: &mut impl rand::Rng,
        device: &Device,
    ) -> Result<FpBatch> {
        let (h, w) = (self.height, self.width);
        let n = ids.len();
        let mut img = [vec![0.0f32; n * h * w], vec![0.0f32; n * h * w]];
        let mut tgt = [vec![0.0f32; n * h * w], vec![0.0f32; n * h * w]];
        let mut matches = Vec::with_capacity(n);
        for (k, &id) in ids.iter().enumerate() {
            let pair = &self.pairs[id];
            for (side, frame) in [pair.a, pair.b].into_iter().enumerate() {
                let f = &self.frames[frame];
                let g = match augment {
                    Some(a) => a.apply(&f.gray, rng)?,
                    None => f.gray.clone(),
                };
                img[side][k * h * w..(k + 1) * h * w].copy_from_slice(&g.data);
                for &(x, y) in &f.targets {
                    tgt[side][k * h * w + y * w + x] = 1.0;
                }
            }
            let mut m = pair.matches.clone();
            m.shuffle(rng);
            m.truncate(max_matches);
            matches.push(m);
        }
        let t = |v: Vec<f32>| Tensor::<4>::from_data(TensorData::new(v, [n, 1, h, w]), device);
        let [ia, ib] = img;
        let [ta, tb] = tgt;
        Ok(FpBatch {
            image_a: t(ia),
            image_b: t(ib),
            target_a: t(ta),
            target_b: t(tb),
            matches,
        })
    }
}

fn inside(p: [f32; 2], w: usize, h: usize) -> bool {
    p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= (w - 1) as f32 && p[1] <= (h - 1) as f32
}
