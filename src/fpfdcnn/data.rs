//! FPFDCNN training data, built as the paper builds its FP dataset (section IV-B,
//! V-B): frame pairs `(i, i + k)` of TUM-layout RGB-D sequences with ground truth,
//! Harris corners as detector targets, and their ground-truth matches (eqs 5-7,
//! [`crate::dataset::fp_pairs`](mod@crate::dataset::fp_pairs)) for the descriptors.
//!
//! A training image of `height x width` pixels is either a window cropped from the
//! full-resolution frame ([`Sampling::Crop`], the default: keypoints are learnt at the
//! pixel scale the network runs at, and at every position relative to its 16x16
//! cells) or the whole frame resized ([`Sampling::Resize`]). Frames are kept in
//! memory as grayscale. The last `val_fraction` of every sequence (by frame index)
//! is held out for validation.
//!
//! Beside the posed pairs, a sequence may add `homographies` pairs per training frame
//! (`super::homography`): a crop of the frame and the same crop through a random
//! homography, with exact matches (SuperPoint's recipe) on real texture.

use super::homography::{Homography, HomographyConfig};
use super::sequence::{add_sequence, open_source};
use crate::dataset::fp_pairs::{FpConfig, FpMatch};
use crate::dataset::photometric::PhotometricAugment;
use crate::error::{Error, Result};
use crate::features::harris::{HarrisConfig, harris_corners};
use crate::features::orb::{OrbConfig, detect_and_compute};
use crate::raster::{GrayF32, gray_from_f32};
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
    /// Camera preset (`fr1`, `fr2`, `fr3`) or camera TOML file; when absent, the
    /// sequence's own `camera.toml` if it has one (7-Scenes conversions do), else `fr1`
    /// (TUM's freiburg1 sequences), as `slam` chooses.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<String>,
    /// How many times this sequence's pairs enter the training and validation pools
    /// (weights a small real sequence against larger synthetic ones; frames load once).
    #[serde(default = "default_repeat")]
    pub repeat: usize,
    /// Homography pairs per training frame (0 = none), made afresh in every batch
    /// (`super::homography`); `repeat` multiplies them like the posed pairs; needs
    /// `sampling = "crop"`.
    #[serde(default)]
    pub homographies: usize,
    /// Only the frames `[first, end)` of the sequence (all when absent): frames outside are
    /// never read, so a final held-back split stays out of training and validation alike.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frames: Option<[usize; 2]>,
    /// This sequence's validation share (`[data] val_fraction` when absent).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub val_fraction: Option<f64>,
    /// The posed pairs read the ground truth this many milliseconds after each colour stamp
    /// (negative: before; at most 100 either way). fr1_rpy's colour images fit the ground
    /// truth best about 8 ms before their stamps (lab/notes/slam-results.md, *Depth taken after the colour*).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub gt_time_offset_ms: f64,
}

impl SequenceSource {
    /// The camera this sequence trains with, as a `camera` value: the given one, else the
    /// folder's `camera.toml` (its path; `fr1` when it holds freiburg1's intrinsics, as
    /// `synth`'s sequences do), else `fr1` ([`crate::camera::Camera::for_sequence`]).
    /// Training writes it into the config it saves beside the run, so the saved config says
    /// which camera the run used, and `--resume` of a run saved before sequences read their
    /// folder's camera (`camera = "fr1"` written for every sequence) still matches.
    pub fn resolved_camera(&self) -> String {
        use crate::camera::Camera;
        if let Some(c) = &self.camera {
            return c.clone();
        }
        let fr1 = Camera::tum_fr1();
        match Camera::for_sequence(None, &self.path) {
            Ok(c)
                if (Camera {
                    name: fr1.name.clone(),
                    ..c
                }) == fr1 =>
            {
                "fr1".into()
            }
            // Another camera, or a file that does not read (opening the sequence says why).
            _ => self.path.join("camera.toml").display().to_string(),
        }
    }
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn default_repeat() -> usize {
    1
}

/// The `[data]` table of a FPFDCNN training config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FpDataConfig {
    /// The training sequences.
    pub sequences: Vec<SequenceSource>,
    /// Training image size `[height, width]` (multiples of 16).
    pub size: [usize; 2],
    /// At most this many training pairs an epoch, drawn in the seeded order (0: all).
    pub pairs_per_epoch: usize,
    /// Validate on at most this many pairs, spread evenly over the validation split (0: all).
    pub val_pairs: usize,
    /// Frame pairs and ground-truth matching (gaps, Harris corners of A, occlusion test).
    pub pairs: FpConfig,
    /// Harris corners of the resized training image: the detector targets (with
    /// `target_detector = "orb"`, `max_corners` is the number of ORB keypoints and the
    /// other fields are unused).
    pub targets: HarrisConfig,
    /// What marks the detector targets: the paper's single-scale Harris corners, or ORB's
    /// detector (FAST corners ranked by their Harris response on each level of an
    /// eight-level pyramid, OpenCV's defaults) in full-resolution pixels, whose keypoints
    /// are found again far more often (lab/notes/fpfdcnn-results.md, *Where the deficit lies*). Descriptors are
    /// trained on the FP pairs' Harris corners either way.
    pub target_detector: TargetDetector,
    /// Share of each sequence's frames (the last ones) kept for validation; a sequence's own
    /// `val_fraction` overrides it.
    pub val_fraction: f64,
    /// Photometric augmentation of both images of a pair.
    pub augment: PhotometricAugment,
    /// How a frame becomes a training image.
    pub sampling: Sampling,
    /// The range of the homographies of homography pairs.
    pub homography: HomographyConfig,
    /// Each training posed pair's image B rolled about its window's centre by a uniform
    /// angle within ± this many degrees (its targets and matches with it; 0: as recorded).
    /// Posed pairs otherwise turn about the optical axis only as much as their camera did,
    /// and descriptors trained on them lose most matches at a roll of 15 degrees (lab/notes/fpfdcnn-results.md, *Roll:
    /// stages 15 and 18*).
    pub posed_roll_deg: f64,
}

/// The detector that marks FPFDCNN's detector targets ([`FpDataConfig::target_detector`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TargetDetector {
    /// Harris corners with `[data.targets]` (the paper).
    #[default]
    Harris,
    /// ORB's keypoints over its pyramid, `[data.targets] max_corners` of them.
    Orb,
}

/// How a frame becomes a `height x width` training image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Sampling {
    /// A window of the full-resolution frame, drawn anew for every batch around a
    /// ground-truth match; frame B's window follows A's by the matches' median
    /// displacement. Detector targets are the full-resolution Harris corners.
    #[default]
    Crop,
    /// The whole frame resized to the training size (targets: Harris corners of the
    /// resized image; match positions scaled). A network trained this way sees
    /// keypoints at another scale than a full-resolution frame shows them.
    Resize,
}

/// The bound on [`FpDataConfig::posed_roll_deg`], checked by the config and by
/// [`FpDataset::build`] (which may be called without the config's check).
fn check_posed_roll(deg: f64) -> std::result::Result<(), String> {
    if (0.0..=180.0).contains(&deg) {
        Ok(())
    } else {
        Err(format!(
            "posed_roll_deg must be in [0, 180] degrees, got {deg}"
        ))
    }
}

impl FpDataConfig {
    /// Checks what the config alone decides (the data is checked when it is read); the
    /// message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        let [h, w] = self.size;
        if h == 0 || w == 0 || !h.is_multiple_of(16) || !w.is_multiple_of(16) {
            return Err(format!(
                "data.size {h}x{w} must be non-zero multiples of 16 (height, width)"
            ));
        }
        if h > MAX_SIDE || w > MAX_SIDE {
            return Err(format!(
                "data.size {h}x{w} must be at most {MAX_SIDE} pixels a side"
            ));
        }
        if !(0.0..1.0).contains(&self.val_fraction) {
            return Err(format!(
                "data.val_fraction must be in [0, 1), got {}",
                self.val_fraction
            ));
        }
        self.pairs.validate().map_err(|m| format!("data.{m}"))?;
        self.targets
            .validate()
            .map_err(|m| format!("data.targets: {m}"))?;
        if self.target_detector == TargetDetector::Orb
            && !(1..=MAX_ORB_TARGETS).contains(&self.targets.max_corners)
        {
            return Err(format!(
                "data.targets.max_corners must be in [1, {MAX_ORB_TARGETS}] with target_detector = \"orb\", got {}",
                self.targets.max_corners
            ));
        }
        self.augment.validate().map_err(|m| format!("data.{m}"))?;
        self.homography
            .validate()
            .map_err(|m| format!("data.{m}"))?;
        check_posed_roll(self.posed_roll_deg).map_err(|m| format!("data.{m}"))?;
        for s in &self.sequences {
            if s.repeat == 0 || s.repeat > 1000 || s.homographies > 1000 {
                return Err(format!(
                    "data.sequences {}: repeat must be in 1..=1000 and homographies in 0..=1000",
                    s.path.display()
                ));
            }
            if let Some(v) = s.val_fraction
                && !(0.0..1.0).contains(&v)
            {
                return Err(format!(
                    "data.sequences {}: val_fraction must be in [0, 1), got {v}",
                    s.path.display()
                ));
            }
            if !(s.gt_time_offset_ms.is_finite() && s.gt_time_offset_ms.abs() <= 100.0) {
                return Err(format!(
                    "data.sequences {}: gt_time_offset_ms must be within [-100, 100], got {}",
                    s.path.display(),
                    s.gt_time_offset_ms
                ));
            }
            if let Some([first, end]) = s.frames
                && first >= end
            {
                return Err(format!(
                    "data.sequences {}: frames = [{first}, {end}] must be a non-empty range [first, end)",
                    s.path.display()
                ));
            }
        }
        Ok(())
    }
}

/// The default training image size `[height, width]`.
pub(crate) fn default_size() -> [usize; 2] {
    [240, 320]
}

/// Most ORB keypoints a frame may give as targets.
const MAX_ORB_TARGETS: usize = 100_000;

/// Largest training image side, pixels.
const MAX_SIDE: usize = 4096;

impl Default for FpDataConfig {
    fn default() -> Self {
        FpDataConfig {
            sequences: Vec::new(),
            size: default_size(),
            pairs_per_epoch: 0,
            val_pairs: 0,
            pairs: FpConfig::default(),
            targets: HarrisConfig {
                max_corners: 400,
                nms_radius: 3,
                border: 4,
                ..HarrisConfig::default()
            },
            target_detector: TargetDetector::default(),
            val_fraction: 0.15,
            augment: PhotometricAugment::default(),
            sampling: Sampling::default(),
            homography: HomographyConfig::default(),
            posed_roll_deg: 0.0,
        }
    }
}

impl FpDataConfig {
    /// The detector target pixels `(x, y)` of a training image.
    pub fn target_pixels(&self, gray: &GrayF32) -> Result<Vec<(usize, usize)>> {
        let pixel = |x: f32, y: f32| {
            let clamp = |v: f32, n: usize| (v.round().max(0.0) as usize).min(n - 1);
            (clamp(x, gray.width), clamp(y, gray.height))
        };
        Ok(match self.target_detector {
            TargetDetector::Harris => harris_corners(gray, &self.targets)
                .iter()
                .map(|k| pixel(k.x, k.y))
                .collect(),
            TargetDetector::Orb => {
                let cfg = OrbConfig {
                    n_features: self.targets.max_corners,
                    ..OrbConfig::default()
                };
                let mut p: Vec<_> = detect_and_compute(&gray_from_f32(gray), &cfg)?
                    .keypoints
                    .iter()
                    .map(|k| pixel(k.x, k.y))
                    .collect();
                // Levels may put two keypoints on one pixel: one target.
                p.sort_unstable_by_key(|&(x, y)| (y, x));
                p.dedup();
                p
            }
        })
    }
}

/// A frame at the training resolution (full resolution when cropping).
#[derive(Debug, Clone)]
pub(crate) struct FrameEntry {
    /// The frame in grayscale, values in [0, 1].
    pub gray: GrayF32,
    /// Detector target pixels `(x, y)`.
    pub targets: Vec<(usize, usize)>,
}

/// A frame pair with its matches in its frames' pixels.
#[derive(Debug, Clone)]
pub(crate) struct PairEntry {
    /// Index of frame A in [`FpDataset::frames`].
    pub a: usize,
    /// Index of frame B in [`FpDataset::frames`].
    pub b: usize,
    /// Ground-truth matches (eqs 5-7); empty for a homography pair.
    pub matches: Vec<FpMatch>,
    /// Frame `a` paired with itself through a random homography (`a == b`).
    pub homography: bool,
}

/// Frames and pairs of one split.
#[derive(Debug, Clone, Default)]
pub(crate) struct FpDataset {
    /// Training image size.
    pub height: usize,
    /// Training image width, pixels.
    pub width: usize,
    /// How frames become training images (crop or resize).
    pub sampling: Sampling,
    /// The split's frames, indexed by [`PairEntry::a`] and [`PairEntry::b`].
    pub frames: Vec<FrameEntry>,
    /// The split's frame pairs.
    pub pairs: Vec<PairEntry>,
    /// The homographies of homography pairs.
    pub homography: HomographyConfig,
    /// Posed pairs' roll of image B ([`FpDataConfig::posed_roll_deg`]; the training split
    /// only).
    pub posed_roll_deg: f64,
}

/// A batch in host memory, as [`FpDataset::load`] makes it (on the training loader's
/// thread); [`FpHostBatch::to_device`] makes it an [`FpBatch`].
pub(crate) struct FpHostBatch {
    /// `[N, 1, H, W]` images A and B.
    images: [Vec<f32>; 2],
    /// `[N, 1, H, W]` detector targets of A and B (1 at a target pixel).
    targets: [Vec<f32>; 2],
    shape: [usize; 4],
    matches: Vec<Vec<FpMatch>>,
}

impl FpHostBatch {
    /// The batch as tensors on `device`.
    pub fn into_device(self, device: &Device) -> FpBatch {
        let shape = self.shape;
        let t = |v: Vec<f32>| Tensor::<4>::from_data(TensorData::new(v, shape), device);
        let [ia, ib] = self.images;
        let [ta, tb] = self.targets;
        FpBatch {
            image_a: t(ia),
            image_b: t(ib),
            target_a: t(ta),
            target_b: t(tb),
            matches: self.matches,
        }
    }
}

/// A batch ready for the network.
pub(crate) struct FpBatch {
    /// `[N, 1, H, W]` images A.
    pub image_a: Tensor<4>,
    /// `[N, 1, H, W]` images B.
    pub image_b: Tensor<4>,
    /// `[N, 1, H, W]` detector targets of A (1 at a target pixel).
    pub target_a: Tensor<4>,
    /// `[N, 1, H, W]` detector targets of B (1 at a target pixel).
    pub target_b: Tensor<4>,
    /// Matches of each pair (training-image pixels), at most `max_matches`.
    pub matches: Vec<Vec<FpMatch>>,
}

/// Resizes a float image with bilinear sampling (pixel centres aligned).
pub(crate) fn resize_gray(img: &GrayF32, width: usize, height: usize) -> GrayF32 {
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
        let crop = cfg.sampling == Sampling::Crop;
        cfg.homography.validate().map_err(Error::msg)?;
        check_posed_roll(cfg.posed_roll_deg).map_err(Error::msg)?;
        let mut train = FpDataset {
            height,
            width,
            sampling: cfg.sampling,
            homography: cfg.homography.clone(),
            ..Default::default()
        };
        let mut val = train.clone();
        train.posed_roll_deg = cfg.posed_roll_deg;
        for src in &cfg.sequences {
            let (seq, camera) = open_source(src, crop, [height, width])?;
            progress(&format!("{}: {} frames", seq.name(), seq.len()));
            add_sequence(&mut train, &mut val, src, &seq, &camera, cfg)?;
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
        Ok(self
            .load(ids, augment, max_matches, rng)?
            .into_device(device))
    }

    /// [`FpDataset::batch`] in host memory (no device work).
    pub fn load(
        &self,
        ids: &[usize],
        augment: Option<&PhotometricAugment>,
        max_matches: usize,
        rng: &mut impl rand::Rng,
    ) -> Result<FpHostBatch> {
        let (h, w) = (self.height, self.width);
        let n = ids.len();
        let mut img = [vec![0.0f32; n * h * w], vec![0.0f32; n * h * w]];
        let mut tgt = [vec![0.0f32; n * h * w], vec![0.0f32; n * h * w]];
        let mut matches = Vec::with_capacity(n);
        for (k, &id) in ids.iter().enumerate() {
            let pair = &self.pairs[id];
            let (windows, targets, mut m) = if pair.homography {
                self.homography_sample(pair.a, rng)
            } else {
                self.posed_sample(pair, rng)
            };
            for (side, (window, targets)) in windows.into_iter().zip(targets).enumerate() {
                let g = match augment {
                    Some(a) => a.apply(&window, rng)?,
                    None => window,
                };
                img[side][k * h * w..(k + 1) * h * w].copy_from_slice(&g.data);
                for (x, y) in targets {
                    tgt[side][k * h * w + y * w + x] = 1.0;
                }
            }
            m.shuffle(rng);
            m.truncate(max_matches);
            matches.push(m);
        }
        Ok(FpHostBatch {
            images: img,
            targets: tgt,
            shape: [n, 1, h, w],
            matches,
        })
    }
}

/// The two training images of a pair, their detector targets (window pixels) and matches.
type PairSample = ([GrayF32; 2], [Vec<(usize, usize)>; 2], Vec<FpMatch>);

impl FpDataset {
    /// A posed pair's two windows (whole frames when resizing), targets and matches.
    fn posed_sample(&self, pair: &PairEntry, rng: &mut impl rand::Rng) -> PairSample {
        let (w, h) = (self.width, self.height);
        let (windows, m) = match self.sampling {
            Sampling::Resize => ([[0, 0]; 2], pair.matches.clone()),
            Sampling::Crop => self.crop_windows(pair, rng),
        };
        let side = |frame: usize, [x0, y0]: [usize; 2]| {
            let f = &self.frames[frame];
            let targets = f
                .targets
                .iter()
                .map(|&(x, y)| (x.wrapping_sub(x0), y.wrapping_sub(y0)))
                .filter(|&(x, y)| x < w && y < h)
                .collect();
            (crop(&f.gray, x0, y0, w, h), targets)
        };
        let (a, ta) = side(pair.a, windows[0]);
        if self.posed_roll_deg <= 0.0 {
            let (b, tb) = side(pair.b, windows[1]);
            return ([a, b], [ta, tb], m);
        }
        use rand::RngExt;
        let r = self.posed_roll_deg;
        let roll = Homography::rotation(rng.random_range(-r..r), w, h);
        let f = &self.frames[pair.b];
        let [x0, y0] = windows[1];
        // Every target of B's frame, in window pixels, where the roll takes it (content
        // beyond the window turns into it).
        let tb = f
            .targets
            .iter()
            .filter_map(|&(x, y)| roll.map([x as f32 - x0 as f32, y as f32 - y0 as f32]))
            .filter(|&p| inside(p, w, h))
            .map(|p| (p[0].round() as usize, p[1].round() as usize))
            .collect();
        let m = m
            .into_iter()
            .filter_map(|FpMatch { a, b }| roll.map(b).map(|b| FpMatch { a, b }))
            .filter(|m| inside(m.b, w, h))
            .collect();
        let b = roll.warp(&f.gray, [x0, y0], w, h);
        ([a, b], [ta, tb], m)
    }

    /// A homography pair of `frame`: a random window A, B = A through a random homography;
    /// the frame's Harris corners inside A are A's targets, those the homography takes into
    /// B are B's targets, and those in both are the matches. A few windows are tried for one
    /// with at least 8 matches.
    fn homography_sample(&self, frame: usize, rng: &mut impl rand::Rng) -> PairSample {
        use rand::RngExt;
        let (w, h) = (self.width, self.height);
        let f = &self.frames[frame];
        let mut best: Option<PairSample> = None;
        for _ in 0..4 {
            let x0 = rng.random_range(0..=f.gray.width - w);
            let y0 = rng.random_range(0..=f.gray.height - h);
            let hm = Homography::random(&self.homography, w, h, rng);
            // Every corner of the frame in window-A coordinates (negative outside it), and
            // where the homography takes it in B (which shows content beyond A's window).
            let mut ta = Vec::new();
            let mut tb = Vec::new();
            let mut matches = Vec::new();
            for &(x, y) in &f.targets {
                let a = [x as f32 - x0 as f32, y as f32 - y0 as f32];
                let in_a = inside(a, w, h);
                if in_a {
                    ta.push((a[0] as usize, a[1] as usize));
                }
                let Some(b) = hm.map(a).filter(|&b| inside(b, w, h)) else {
                    continue;
                };
                tb.push((b[0].round() as usize, b[1].round() as usize));
                if in_a {
                    matches.push(FpMatch { a, b });
                }
            }
            let enough = matches.len() >= 8;
            if enough || best.as_ref().is_none_or(|b| b.2.len() < matches.len()) {
                let b = hm.warp(&f.gray, [x0, y0], w, h);
                best = Some(([crop(&f.gray, x0, y0, w, h), b], [ta, tb], matches));
            }
            if enough {
                break;
            }
        }
        best.expect("four tries")
    }

    /// Crop windows `[x0, y0]` of A and B for one pair, and the pair's matches inside
    /// both, in window pixels. A's window holds a randomly chosen match at a random
    /// place; B's is moved by the median displacement of the matches in A's window
    /// (both clamped to the frames).
    fn crop_windows(
        &self,
        pair: &PairEntry,
        rng: &mut impl rand::Rng,
    ) -> ([[usize; 2]; 2], Vec<FpMatch>) {
        use rand::RngExt;
        let (w, h) = (self.width, self.height);
        let fa = &self.frames[pair.a].gray;
        let fb = &self.frames[pair.b].gray;
        let origin = |centre: f32, size: usize, full: usize| -> usize {
            (centre.round().max(0.0) as usize).min(full - size)
        };
        let anchor = pair.matches[rng.random_range(0..pair.matches.len())].a;
        let ax = origin(anchor[0] - rng.random_range(0.0..w as f32), w, fa.width);
        let ay = origin(anchor[1] - rng.random_range(0.0..h as f32), h, fa.height);
        let in_a: Vec<&FpMatch> = pair
            .matches
            .iter()
            .filter(|m| inside([m.a[0] - ax as f32, m.a[1] - ay as f32], w, h))
            .collect();
        let median = |mut v: Vec<f32>| {
            v.sort_by(f32::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(0.0)
        };
        let dx = median(in_a.iter().map(|m| m.b[0] - m.a[0]).collect());
        let dy = median(in_a.iter().map(|m| m.b[1] - m.a[1]).collect());
        let bx = origin(ax as f32 + dx, w, fb.width);
        let by = origin(ay as f32 + dy, h, fb.height);
        let shift = |p: [f32; 2], x0: usize, y0: usize| [p[0] - x0 as f32, p[1] - y0 as f32];
        let matches = in_a
            .into_iter()
            .map(|m| FpMatch {
                a: shift(m.a, ax, ay),
                b: shift(m.b, bx, by),
            })
            .filter(|m| inside(m.b, w, h))
            .collect();
        ([[ax, ay], [bx, by]], matches)
    }
}

/// The `w x h` window of `img` at `(x0, y0)` (which must fit).
fn crop(img: &GrayF32, x0: usize, y0: usize, w: usize, h: usize) -> GrayF32 {
    if (x0, y0, w, h) == (0, 0, img.width, img.height) {
        return img.clone();
    }
    let mut out = GrayF32::new(w, h);
    for (y, row) in out.data.chunks_exact_mut(w).enumerate() {
        let start = (y0 + y) * img.width + x0;
        row.copy_from_slice(&img.data[start..start + w]);
    }
    out
}

pub(super) fn inside(p: [f32; 2], w: usize, h: usize) -> bool {
    p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= (w - 1) as f32 && p[1] <= (h - 1) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The ten-frame fr1_rpy fixture.
    fn fixture() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("datasets/fixtures/tum_fr1_rpy_head10")
    }

    /// Training and validation splits of one sequence entry, whole frames resized to
    /// 120x160, half of each sequence for validation.
    fn build_one(source: SequenceSource) -> Result<(FpDataset, FpDataset)> {
        let cfg = FpDataConfig {
            sequences: vec![source],
            sampling: Sampling::Resize,
            val_fraction: 0.5,
            ..Default::default()
        };
        FpDataset::build(&cfg, [120, 160], |_| {})
    }

    /// A training sequence entry with every option at its default (fr1 camera).
    fn source(path: impl Into<PathBuf>) -> SequenceSource {
        SequenceSource {
            path: path.into(),
            camera: Some("fr1".into()),
            repeat: 1,
            homographies: 0,
            frames: None,
            val_fraction: None,
            gt_time_offset_ms: 0.0,
        }
    }

    /// Frame B is frame A moved by `(dx, dy)`; matches follow the motion exactly.
    fn shifted_pair(dx: usize, dy: usize) -> FpDataset {
        let (w, h) = (160, 96);
        let mut a = GrayF32::new(w, h);
        for (i, v) in a.data.iter_mut().enumerate() {
            *v = ((i * 7919) % 251) as f32 / 251.0;
        }
        let mut b = GrayF32::new(w, h);
        for y in dy..h {
            for x in dx..w {
                b.data[y * w + x] = a.data[(y - dy) * w + (x - dx)];
            }
        }
        let targets: Vec<(usize, usize)> = (0..20).map(|k| (5 + 7 * k, 3 + 4 * k)).collect();
        let matches: Vec<FpMatch> = (0..60)
            .map(|k| {
                let a = [(3 + (k * 37) % 100) as f32, (2 + (k * 13) % 60) as f32];
                FpMatch {
                    a,
                    b: [a[0] + dx as f32, a[1] + dy as f32],
                }
            })
            .collect();
        FpDataset {
            height: 32,
            width: 48,
            sampling: Sampling::Crop,
            frames: vec![
                FrameEntry {
                    gray: a,
                    targets: targets.clone(),
                },
                FrameEntry { gray: b, targets },
            ],
            pairs: vec![PairEntry {
                a: 0,
                b: 1,
                matches,
                homography: false,
            }],
            homography: HomographyConfig::default(),
            posed_roll_deg: 0.0,
        }
    }

    #[test]
    fn rolled_posed_pairs_keep_their_matches_on_the_same_content() {
        use rand::SeedableRng;
        let (dx, dy) = (21usize, 9usize);
        let mut data = shifted_pair(dx, dy);
        // A smooth texture, so that bilinear samples of the rolled B can be compared.
        let texture =
            |x: f32, y: f32| 0.5 + 0.25 * (x * 0.21).sin() + 0.25 * (y * 0.17 + x * 0.05).cos();
        let fw = data.frames[0].gray.width;
        for (f, (ox, oy)) in data
            .frames
            .iter_mut()
            .zip([(0.0, 0.0), (dx as f32, dy as f32)])
        {
            for (i, v) in f.gray.data.iter_mut().enumerate() {
                *v = texture((i % fw) as f32 - ox, (i / fw) as f32 - oy);
            }
        }
        data.posed_roll_deg = 40.0;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
        let (mut seen, mut turned) = (0, 0);
        for _ in 0..20 {
            let ([a, b], [_, tb], m) = data.posed_sample(&data.pairs[0].clone(), &mut rng);
            for m in &m {
                assert!(inside(m.b, 48, 32));
                let (va, vb) = (
                    a.sample(f64::from(m.a[0]), f64::from(m.a[1])),
                    b.sample(f64::from(m.b[0]), f64::from(m.b[1])),
                );
                assert!((va - vb).abs() < 0.03, "match {m:?}: {va} vs {vb}");
                // Unrolled, B's point would sit at A's (the crops follow the motion).
                turned +=
                    usize::from(((m.b[0] - m.a[0]).powi(2) + (m.b[1] - m.a[1]).powi(2)) > 1.0);
            }
            seen += m.len();
            // Every target of the rolled B shows the content of one of the frame's targets
            // (to within the half pixel of its rounding).
            let frame_b = &data.frames[1];
            for &(x, y) in &tb {
                assert!(x < 48 && y < 32);
                let here = b.sample(x as f64, y as f64);
                let nearest = frame_b
                    .targets
                    .iter()
                    .map(|&(tx, ty)| (frame_b.gray.sample(tx as f64, ty as f64) - here).abs())
                    .fold(f32::INFINITY, f32::min);
                assert!(nearest < 0.04, "target ({x}, {y}): {nearest}");
            }
        }
        assert!(seen > 20 * 4, "{seen}");
        assert!(
            turned * 2 > seen,
            "{turned} of {seen} matches moved by the roll"
        );
        // Read from a config, bounded.
        let parsed: FpDataConfig = toml::from_str("posed_roll_deg = 30.0").unwrap();
        assert_eq!(parsed.posed_roll_deg, 30.0);
        assert!(parsed.validate().is_ok());
        for bad in [-1.0, 181.0, f64::NAN] {
            let cfg = FpDataConfig {
                posed_roll_deg: bad,
                ..parsed.clone()
            };
            assert!(cfg.validate().unwrap_err().contains("data.posed_roll_deg"));
            // `build`, which may be called without the config's check, refuses it before
            // reading any sequence.
            let cfg = FpDataConfig {
                sequences: vec![source("no/such/sequence")],
                ..cfg
            };
            let err = FpDataset::build(&cfg, [96, 128], |_| {}).err().unwrap();
            assert!(err.to_string().contains("posed_roll_deg"), "{err}");
        }
    }

    #[test]
    fn crops_follow_the_ground_truth_motion() {
        use rand::SeedableRng;
        let data = shifted_pair(21, 9);
        #[allow(deprecated)]
        let device = Device::ndarray();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut seen = 0;
        for _ in 0..20 {
            let batch = data.batch(&[0], None, 1000, &mut rng, &device).unwrap();
            let img = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
            let (ia, ib) = (img(batch.image_a), img(batch.image_b));
            assert_eq!(ia.len(), 32 * 48);
            // A matched pixel shows the same image content in both crops.
            for m in &batch.matches[0] {
                let at = |v: &[f32], p: [f32; 2]| v[p[1] as usize * 48 + p[0] as usize];
                assert!(m.a[0] >= 0.0 && m.a[0] <= 47.0 && m.b[1] >= 0.0 && m.b[1] <= 31.0);
                assert_eq!(at(&ia, m.a), at(&ib, m.b), "match {m:?}");
            }
            seen += batch.matches[0].len();
            // Every crop keeps targets inside it only, as 0/1 values.
            let ta = img(batch.target_a);
            assert!(ta.iter().all(|v| *v == 0.0 || *v == 1.0));
        }
        assert!(seen > 20 * 4, "crops are drawn around matches ({seen})");
    }

    #[test]
    fn repeat_weights_a_sequence_without_loading_it_twice() {
        let path = fixture();
        let build = |repeat: usize| {
            build_one(SequenceSource {
                repeat,
                ..source(&path)
            })
        };
        let (once, val_once) = build(1).unwrap();
        let (thrice, val_thrice) = build(3).unwrap();
        assert!(
            !once.pairs.is_empty() && !val_once.pairs.is_empty(),
            "{} training, {} validation pairs",
            once.pairs.len(),
            val_once.pairs.len()
        );
        assert_eq!(thrice.frames.len(), once.frames.len());
        assert_eq!(thrice.pairs.len(), 3 * once.pairs.len());
        assert_eq!(val_thrice.pairs.len(), 3 * val_once.pairs.len());
        let n = once.pairs.len();
        assert_eq!(
            (thrice.pairs[2 * n].a, thrice.pairs[2 * n].b),
            (once.pairs[0].a, once.pairs[0].b)
        );
        let err = build(0).err().unwrap().to_string();
        assert!(
            err.contains("repeat must be at least 1") && err.contains("tum_fr1_rpy_head10"),
            "{err}"
        );
        // A camera that does not describe the frames: an error naming a frame.
        let dir = std::env::temp_dir().join(format!("sdf_fp_cam_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cam = dir.join("small.toml");
        crate::camera::Camera::tum_fr1()
            .resized(320, 240)
            .save(&cam)
            .unwrap();
        let cfg = FpDataConfig {
            sequences: vec![SequenceSource {
                camera: Some(cam.display().to_string()),
                ..source(&path)
            }],
            sampling: Sampling::Resize,
            ..Default::default()
        };
        let err = FpDataset::build(&cfg, [120, 160], |_| {})
            .err()
            .unwrap()
            .to_string();
        assert!(err.contains("640x480") && err.contains("320x240"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_ground_truth_time_offset_moves_the_posed_matches_and_is_bounded() {
        let path = fixture();
        let build = |gt_time_offset_ms: f64| {
            build_one(SequenceSource {
                gt_time_offset_ms,
                ..source(&path)
            })
        };
        let (at_stamps, _) = build(0.0).unwrap();
        let (earlier, _) = build(-8.0).unwrap();
        // The same corners of A, sent elsewhere in B: the camera turns fast in these frames.
        let (mut same_a, mut moved) = (0, 0);
        for (p, q) in at_stamps.pairs.iter().zip(&earlier.pairs) {
            for m in &p.matches {
                if let Some(n) = q.matches.iter().find(|n| n.a == m.a) {
                    same_a += 1;
                    let d = ((m.b[0] - n.b[0]).powi(2) + (m.b[1] - n.b[1]).powi(2)).sqrt();
                    moved += (d > 0.5) as usize;
                }
            }
        }
        assert!(
            same_a > 100 && 2 * moved > same_a,
            "{moved} of {same_a} moved"
        );
        for bad in [150.0, f64::NAN] {
            let err = build(bad).err().unwrap().to_string();
            assert!(
                err.contains("gt_time_offset_ms") && err.contains("tum_fr1_rpy_head10"),
                "{err}"
            );
        }
    }

    #[test]
    fn a_sequence_without_posed_pairs_is_named_unless_it_trains_on_homographies() {
        let path = fixture();
        // Frames [0, 1): no pair at the smallest gap (1).
        let build = |homographies: usize| {
            let cfg = FpDataConfig {
                sequences: vec![SequenceSource {
                    frames: Some([0, 1]),
                    val_fraction: Some(0.0),
                    homographies,
                    ..source(&path)
                }],
                sampling: Sampling::Crop,
                ..Default::default()
            };
            FpDataset::build(&cfg, [96, 128], |_| {})
        };
        let err = build(0).err().unwrap().to_string();
        assert!(
            err.contains("tum_fr1_rpy_head10") && err.contains("too few for a pair"),
            "{err}"
        );
        let (train, _) = build(2).unwrap();
        assert_eq!(train.pairs.len(), 2);
        assert!(train.pairs.iter().all(|p| p.homography));
    }

    #[test]
    fn the_saved_camera_is_the_one_used() {
        let dir = std::env::temp_dir().join(format!("sdf_fp_resolved_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let entry = |camera: Option<&str>| SequenceSource {
            camera: camera.map(String::from),
            ..source(&dir)
        };
        // No camera.toml: fr1, as configs saved before sequences read their folder's camera.
        assert_eq!(entry(None).resolved_camera(), "fr1");
        assert_eq!(entry(Some("fr2")).resolved_camera(), "fr2");
        // freiburg1's intrinsics under another name (synth's sequences): still fr1.
        let file = dir.join("camera.toml");
        crate::camera::Camera {
            name: "synthetic".into(),
            ..crate::camera::Camera::tum_fr1()
        }
        .save(&file)
        .unwrap();
        assert_eq!(entry(None).resolved_camera(), "fr1");
        // Another camera: its file.
        crate::camera::Camera::pinhole(640, 480, 527.0, 527.0, 323.0, 236.0)
            .save(&file)
            .unwrap();
        assert_eq!(entry(None).resolved_camera(), file.display().to_string());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn a_frame_range_keeps_the_other_frames_out_of_both_splits() {
        let path = fixture();
        let build = |frames: Option<[usize; 2]>, val_fraction: Option<f64>| {
            build_one(SequenceSource {
                frames,
                val_fraction,
                ..source(&path)
            })
        };
        let (train, val) = build(None, None).unwrap();
        assert_eq!((train.frames.len(), val.frames.len()), (5, 5));
        // Frames 0-7 only, the last quarter of those for validation: 6 + 2.
        let (train, val) = build(Some([0, 8]), Some(0.25)).unwrap();
        assert_eq!((train.frames.len(), val.frames.len()), (6, 2));
        assert!(train.pairs.iter().all(|p| p.a < 6 && p.b < 6));
        assert!(val.pairs.iter().all(|p| p.a < 2 && p.b < 2));
        for (frames, fraction, needle) in [
            (Some([4, 11]), None, "frames = [4, 11]"),
            (Some([5, 5]), None, "frames = [5, 5]"),
            (None, Some(1.0), "val_fraction must be in [0, 1)"),
        ] {
            let err = build(frames, fraction).err().unwrap().to_string();
            assert!(
                err.contains(needle) && err.contains("tum_fr1_rpy_head10"),
                "{err}"
            );
        }
    }

    #[test]
    fn homography_pairs_match_exactly_on_the_frame() {
        use rand::SeedableRng;
        let (fw, fh) = (160, 120);
        let mut gray = GrayF32::new(fw, fh);
        for (i, v) in gray.data.iter_mut().enumerate() {
            let (x, y) = ((i % fw) as f32, (i / fw) as f32);
            *v = 0.5 + 0.25 * (x * 0.21).sin() + 0.25 * (y * 0.17 + x * 0.05).cos();
        }
        let targets: Vec<(usize, usize)> = (0..200)
            .map(|k| (3 + (k * 37) % 150, 2 + (k * 13) % 110))
            .collect();
        let data = FpDataset {
            height: 48,
            width: 64,
            sampling: Sampling::Crop,
            frames: vec![FrameEntry { gray, targets }],
            pairs: vec![PairEntry {
                a: 0,
                b: 0,
                matches: Vec::new(),
                homography: true,
            }],
            homography: HomographyConfig::default(),
            posed_roll_deg: 0.0,
        };
        #[allow(deprecated)]
        let device = Device::ndarray();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        for _ in 0..10 {
            let batch = data.batch(&[0], None, 1000, &mut rng, &device).unwrap();
            let img = |t: Tensor<4>| t.into_data().try_to_vec::<f32>().unwrap();
            let (ia, ib, tb) = (img(batch.image_a), img(batch.image_b), img(batch.target_b));
            assert!(batch.matches[0].len() >= 8, "{}", batch.matches[0].len());
            for m in &batch.matches[0] {
                let a = ia[m.a[1] as usize * 64 + m.a[0] as usize];
                let (bx, by) = (m.b[0].round() as usize, m.b[1].round() as usize);
                // B's target map marks every match; the image agrees up to rounding.
                assert_eq!(tb[by * 64 + bx], 1.0);
                assert!((a - ib[by * 64 + bx]).abs() < 0.2, "{m:?}");
            }
        }
    }

    #[test]
    fn resize_sampling_keeps_whole_frames() {
        let mut data = shifted_pair(0, 0);
        data.sampling = Sampling::Resize;
        data.width = 160;
        data.height = 96;
        #[allow(deprecated)]
        let device = Device::ndarray();
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(1);
        let batch = data.batch(&[0], None, 1000, &mut rng, &device).unwrap();
        assert_eq!(batch.matches[0].len(), 60);
        let ta = batch.target_a.into_data().try_to_vec::<f32>().unwrap();
        assert_eq!(ta.iter().filter(|v| **v == 1.0).count(), 20);
    }

    #[test]
    fn orb_targets_are_orb_keypoints_over_the_pyramid() {
        let path =
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("datasets/fixtures/tum_fr1_rpy_head10");
        let seq = crate::dataset::TumSequence::open(&path).unwrap();
        let gray = GrayF32::from_gray(&seq.load_gray(0).unwrap());
        let harris = FpDataConfig::default();
        let orb = FpDataConfig {
            target_detector: TargetDetector::Orb,
            targets: HarrisConfig {
                max_corners: 300,
                ..harris.targets.clone()
            },
            ..Default::default()
        };
        let h = harris.target_pixels(&gray).unwrap();
        let corners = harris_corners(&gray, &harris.targets);
        assert_eq!(h.len(), corners.len());
        assert!(
            h.iter()
                .zip(&corners)
                .all(|(p, k)| p.0 as f32 == k.x && p.1 as f32 == k.y)
        );
        let o = orb.target_pixels(&gray).unwrap();
        let cfg = OrbConfig {
            n_features: 300,
            ..Default::default()
        };
        let keypoints = detect_and_compute(&gray_from_f32(&gray), &cfg)
            .unwrap()
            .keypoints;
        // Every keypoint, on whatever level, is a target at its full-resolution pixel.
        assert!(o.len() > 200 && o.len() <= keypoints.len(), "{}", o.len());
        for k in &keypoints {
            let p = (k.x.round() as usize, k.y.round() as usize);
            assert!(
                o.binary_search_by_key(&(p.1, p.0), |&(x, y)| (y, x))
                    .is_ok(),
                "{p:?}"
            );
        }
        // Keypoints from coarse levels: many targets are no Harris corner.
        let far = o
            .iter()
            .filter(|p| {
                !h.iter()
                    .any(|q| p.0.abs_diff(q.0) <= 2 && p.1.abs_diff(q.1) <= 2)
            })
            .count();
        assert!(far > o.len() / 4, "{far} of {}", o.len());
        let none = FpDataConfig {
            targets: HarrisConfig {
                max_corners: 0,
                ..harris.targets.clone()
            },
            ..orb.clone()
        };
        assert!(none.validate().unwrap_err().contains("max_corners"));
        let parsed: FpDataConfig = toml::from_str("target_detector = \"orb\"").unwrap();
        assert_eq!(parsed.target_detector, TargetDetector::Orb);
        assert!(toml::from_str::<FpDataConfig>("target_detector = \"sift\"").is_err());
    }
}
