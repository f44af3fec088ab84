//! FPFDCNN inference: an image in, the paper's `Out` matrix out (Table 12):
//! `N` keypoints chosen from the FP probability map (threshold, non-maximum
//! suppression, the top `K` = 500 as in the paper's experiments) and their
//! L2-normalised 256-d descriptors, sampled from the coarse L10 map exactly as
//! the bilinear FD layer would give them (FD_FP) without upsampling the whole
//! 256-channel map. By default the probability map is averaged over four placements of
//! the network's 16x16 cell grid ([`DetectorConfig::grid_shifts`]).

use super::config::FpfdcnnTrainConfig;
use super::model::Fpfdcnn;
use super::packed::PackedFpfdcnn;
use crate::error::{Error, Result};
use crate::nn::weights::load_into;
use crate::nn::{BackendKind, sample_bilinear_at_nhwc};
use crate::raster::MAX_BLUR_SIGMA;
use crate::training::resolve_checkpoint;
use burn::prelude::*;
use image::GrayImage;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Keypoint selection.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectorConfig {
    /// Minimum keypoint probability (of the map after grid averaging and smoothing).
    pub threshold: f32,
    /// Standard deviation in pixels of a Gaussian applied to the FP probability map
    /// before non-maximum suppression (0: off). The per-pixel probabilities inside a
    /// 16x16 cell are noisy; smoothing keeps the structure that follows the image, so
    /// the same scene point wins in both images of a pair.
    pub smoothing: f32,
    /// Non-maximum suppression radius, pixels.
    pub nms_radius: usize,
    /// Keep the `top_k` most probable keypoints (0: all).
    pub top_k: usize,
    /// No keypoint closer than this to the image border, pixels (`DEFAULT_BORDER`).
    pub border: usize,
    /// The image is resized by this factor before the network (e.g. 0.5 for a
    /// network trained at 240x320 on 480x640 frames); keypoints are reported
    /// in the original image's pixels.
    pub input_scale: f32,
    /// Refine keypoints to the corner in a window of this radius on the full-resolution
    /// image (`crate::features::subpix`); 0: the probability map's pixel.
    pub subpixel_radius: usize,
    /// Average the FP map over this many placements of the network's 16x16 cell grid
    /// (1: the image as it is; 2: also shifted by half a cell diagonally; 4: by half a
    /// cell along x, y and both), each network pass costing as much as the first. The
    /// detector predicts a cell's 256 sub-pixel probabilities from that cell's features,
    /// so its map carries the grid; other placements average that out.
    pub grid_shifts: usize,
    /// With several [`Self::grid_shifts`], average each keypoint's descriptor over the
    /// placements too (each placement's unit-normalised, then the mean normalised), at no
    /// extra network pass. The descriptor map is 16 times coarser than the image, so one
    /// placement's bilinear samples carry its grid as the FP map does (`DEFAULT_AVERAGE_DESCRIPTORS`).
    pub average_descriptors: bool,
    /// With one placement ([`Self::grid_shifts`] = 1), each keypoint's descriptor is the
    /// normalised mean of five unit-normalised bilinear samples of the coarse map: at the
    /// keypoint and this many pixels away along both diagonals (0: the keypoint's sample
    /// alone). The map is 16 times coarser than the image, and one placement's samples
    /// follow its grid; spreading them is what averaging over placements does at no extra
    /// network pass ([`DEFAULT_DESCRIPTOR_SPREAD`]). Several placements ignore it (their
    /// average spreads the descriptors when [`Self::average_descriptors`] is on; without it
    /// they are the first placement's samples); `average_descriptors` does not affect it.
    pub descriptor_spread: usize,
    /// Detect on this many levels of an image pyramid (1: the image as it is), each level
    /// [`Self::level_factor`] smaller than the one before, keypoints reported in the
    /// original image's pixels. As ORB does, `top_k` is shared out over the levels in
    /// proportion to each level's side (ORB-SLAM's and OpenCV's rule), and a scene corner
    /// found on several levels is kept once per level with that level's descriptor.
    pub levels: usize,
    /// Ratio of the sides of consecutive pyramid levels (> 1).
    pub level_factor: f32,
}

impl DetectorConfig {
    /// Checks ranges; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if self.top_k > MAX_KEYPOINTS {
            return Err(format!(
                "top_k must be at most {MAX_KEYPOINTS} keypoints (0: all), got {}",
                self.top_k
            ));
        }
        if !self.threshold.is_finite() {
            return Err(format!(
                "threshold must be a number, got {}",
                self.threshold
            ));
        }
        if !(self.smoothing.is_finite() && (0.0..=MAX_BLUR_SIGMA).contains(&self.smoothing)) {
            return Err(format!(
                "smoothing must be in [0, {MAX_BLUR_SIGMA}] pixels (0: off), got {}",
                self.smoothing
            ));
        }
        if ![1, 2, 4].contains(&self.grid_shifts) {
            return Err(format!(
                "grid_shifts must be 1, 2 or 4, got {}",
                self.grid_shifts
            ));
        }
        if self.descriptor_spread > MAX_DESCRIPTOR_SPREAD {
            return Err(format!(
                "descriptor_spread must be at most {MAX_DESCRIPTOR_SPREAD} pixels (0: off), got {}",
                self.descriptor_spread
            ));
        }
        if !(1..=MAX_LEVELS).contains(&self.levels) {
            return Err(format!(
                "levels must be in [1, {MAX_LEVELS}], got {}",
                self.levels
            ));
        }
        if !(self.level_factor.is_finite() && self.level_factor > 1.0 && self.level_factor <= 4.0) {
            return Err(format!(
                "level_factor must be in (1, 4], got {}",
                self.level_factor
            ));
        }
        if !(self.input_scale > 0.0 && self.input_scale <= 4.0) {
            return Err(format!(
                "input_scale must be in (0, 4], got {}",
                self.input_scale
            ));
        }
        Ok(())
    }
}

/// Upper bound of [`DetectorConfig::top_k`].
pub const MAX_KEYPOINTS: usize = 100_000;

/// Upper bound of [`DetectorConfig::levels`].
pub(crate) const MAX_LEVELS: usize = 8;

/// Default [`DetectorConfig::smoothing`].
pub const DEFAULT_SMOOTHING: f32 = 2.0;

/// Default [`DetectorConfig::border`]: 16 px. Keypoints near the border are the least often
/// seen again in the other image of a pair; chosen on the validation pairs (2026-11-28,
/// stage-10 weights, four placements): 6-12 % more correct matches than with 4 px at the
/// same accuracy (lab/notes/fpfdcnn-results.md, *Stage 10*). `slam` sets its own (`fpfdcnn_border`).
pub(crate) const DEFAULT_BORDER: usize = 16;

/// Default [`DetectorConfig::average_descriptors`]: on, adopted 2026-12-01 (lab/notes/fpfdcnn-results.md,
/// *Descriptors averaged over the grid placements*): on the validation pairs with four
/// placements 28-39 % more correct matches at 0.9-3.0 points more accuracy; on the final
/// split 116 % / 146 % of ORB + BF's correct matches at 76.4 % / 78.7 % (clear / blurred).
pub(crate) const DEFAULT_AVERAGE_DESCRIPTORS: bool = true;

/// Upper bound of [`DetectorConfig::descriptor_spread`], pixels (four cells).
pub(crate) const MAX_DESCRIPTOR_SPREAD: usize = 64;

/// Default [`DetectorConfig::descriptor_spread`]: 6 px, adopted 2026-12-01 for one pass
/// (lab/notes/fpfdcnn-results.md, *Descriptors spread in one pass*): chosen among 2, 4, 6 and 8 px on the
/// validation pairs, where it gave one pass 19 % more correct matches at 1.7 points more
/// mean accuracy (stage-18 export); on the final split 73.3 % / 74.6 % (clear / blurred)
/// against 71.7 % / 73.1 % without, with 16-17 % more correct matches.
pub const DEFAULT_DESCRIPTOR_SPREAD: usize = 6;

/// Default [`DetectorConfig::grid_shifts`]: four placements, the setting of the README's
/// Table 6/7 figures (`slam` sets one pass for speed).
pub const DEFAULT_GRID_SHIFTS: usize = 4;

impl Default for DetectorConfig {
    fn default() -> Self {
        DetectorConfig {
            threshold: 0.015,
            smoothing: DEFAULT_SMOOTHING,
            nms_radius: 4,
            top_k: 500,
            border: DEFAULT_BORDER,
            input_scale: 1.0,
            subpixel_radius: 0,
            grid_shifts: DEFAULT_GRID_SHIFTS,
            average_descriptors: DEFAULT_AVERAGE_DESCRIPTORS,
            descriptor_spread: DEFAULT_DESCRIPTOR_SPREAD,
            levels: 1,
            level_factor: 1.2,
        }
    }
}

impl DetectorConfig {
    /// Keypoints each pyramid level keeps: ORB's split of `top_k`
    /// ([`crate::features::orb::OrbConfig::features_per_level`]); all on every level when
    /// `top_k` is 0.
    pub fn level_quotas(&self) -> Vec<usize> {
        let n = self.levels.max(1);
        if self.top_k == 0 {
            return vec![0; n];
        }
        crate::features::orb::OrbConfig {
            n_features: self.top_k,
            scale_factor: self.level_factor,
            n_levels: n,
            ..Default::default()
        }
        .features_per_level()
    }
}

/// Keypoints and descriptors of one image.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Features {
    /// `(x, y)` pixel positions.
    pub points: Vec<[f32; 2]>,
    /// FP probabilities at the keypoints (after grid averaging and smoothing).
    pub scores: Vec<f32>,
    /// `N x dim` row-major, L2-normalised.
    pub descriptors: Vec<f32>,
    /// Descriptor length (values per keypoint).
    pub dim: usize,
}

impl Features {
    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether there are no keypoints.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Descriptor of keypoint `i`.
    pub fn descriptor(&self, i: usize) -> &[f32] {
        &self.descriptors[i * self.dim..(i + 1) * self.dim]
    }

    /// The paper's `Out`: `N x (2 + dim)`, each row `x, y, descriptor`.
    pub fn out_matrix(&self) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.len() * (2 + self.dim));
        for (i, p) in self.points.iter().enumerate() {
            out.extend_from_slice(p);
            out.extend_from_slice(self.descriptor(i));
        }
        out
    }
}

/// Greedy non-maximum suppression on a probability map: candidates above
/// `threshold` (away from the border) in decreasing order, each suppressing a
/// `(2r+1)²` square around it; at most `top_k`.
pub(crate) fn select_keypoints(
    prob: &[f32],
    width: usize,
    height: usize,
    cfg: &DetectorConfig,
) -> Vec<(usize, usize, f32)> {
    let b = cfg.border;
    let mut cand: Vec<(f32, usize)> = Vec::new();
    for y in b..height.saturating_sub(b) {
        for x in b..width.saturating_sub(b) {
            let p = prob[y * width + x];
            if p >= cfg.threshold {
                cand.push((p, y * width + x));
            }
        }
    }
    // A total order (the indices differ): the unstable sort gives the stable one's order.
    cand.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut suppressed = vec![false; width * height];
    let r = cfg.nms_radius as isize;
    let mut out = Vec::new();
    for (p, i) in cand {
        if suppressed[i] {
            continue;
        }
        let (x, y) = (i % width, i / width);
        out.push((x, y, p));
        if cfg.top_k > 0 && out.len() == cfg.top_k {
            break;
        }
        for dy in -r..=r {
            for dx in -r..=r {
                let (xx, yy) = (x as isize + dx, y as isize + dy);
                if xx >= 0 && yy >= 0 && (xx as usize) < width && (yy as usize) < height {
                    suppressed[yy as usize * width + xx as usize] = true;
                }
            }
        }
    }
    out
}

/// The coarse descriptor map of one pass: row-major values, channels last
/// (`[h / cell, w / cell, dim]`), and `[dim, h / cell, w / cell]`.
type NetworkDescriptors = (Vec<f32>, [usize; 3]);

/// A loaded FPFDCNN ready to detect and describe keypoints.
#[derive(Debug)]
pub struct FpfdcnnDetector {
    /// The network. On a CPU backend detection runs a packed copy of its weights made by
    /// [`Self::new`] ([`PackedFpfdcnn`]), so changing it afterwards does not change detection.
    pub model: Fpfdcnn,
    /// The device the network runs on.
    pub device: Device,
    /// Keypoint selection settings.
    pub config: DetectorConfig,
    packed: Option<PackedFpfdcnn>,
}

impl FpfdcnnDetector {
    /// A detector around a model; `config` must pass [`DetectorConfig::validate`]
    /// ([`Self::load`] checks it).
    pub fn new(model: Fpfdcnn, device: Device, config: DetectorConfig) -> Self {
        debug_assert!(config.validate().is_ok(), "{config:?}");
        // CPU: packed NHWC convolutions (2-3x Burn's on 2 cores, bench); GPUs keep Burn's.
        let packed = crate::nn::backend::is_cpu(&device)
            .then(|| PackedFpfdcnn::new(&model).ok())
            .flatten();
        FpfdcnnDetector {
            model,
            device,
            config,
            packed,
        }
    }

    /// Loads a checkpoint (a `model.bpk`, its folder, or a run folder) with the
    /// training config beside it.
    pub fn load(checkpoint: &Path, backend: BackendKind, config: DetectorConfig) -> Result<Self> {
        config
            .validate()
            .map_err(|m| Error::msg(format!("FPFDCNN detector: {m}")))?;
        let (weights, cfg_path) = resolve_checkpoint(checkpoint)?;
        let text = crate::io::read_text(&cfg_path)?;
        let train = FpfdcnnTrainConfig::parse_saved(&text, &cfg_path)?;
        let device = backend.device()?;
        let model = train
            .network()
            .init(&device)
            .map_err(|e| Error::invalid(&cfg_path, e.to_string()))?;
        let model = load_into(model, &weights, "FPFDCNN", &cfg_path)?;
        Ok(Self::new(model, device, config))
    }

    /// Detects and describes keypoints of a grayscale image. Images whose sides
    /// are not multiples of 16 are zero-padded on the right and bottom (the shifted
    /// grid placements also pad left and top); no keypoint is taken from the padding.
    pub fn detect(&self, gray: &GrayImage) -> Result<Features> {
        let s = self.config.input_scale;
        let mut f = Features::default();
        for (level, top_k) in self.config.level_quotas().into_iter().enumerate() {
            let scale = s / self.config.level_factor.powi(level as i32);
            let too_small = (gray.width().min(gray.height()) as f32 * scale) < 32.0;
            if level > 0 && ((top_k == 0 && self.config.top_k > 0) || too_small) {
                continue;
            }
            let found = if scale == 1.0 {
                self.detect_at_native(gray, top_k)?
            } else {
                self.detect_scaled(gray, scale, top_k)?
            };
            f.dim = found.dim;
            f.points.extend(found.points);
            f.scores.extend(found.scores);
            f.descriptors.extend(found.descriptors);
        }
        if self.config.subpixel_radius > 0 {
            use crate::features::subpix::{SubPixConfig, gradients, refine_corner};
            let cfg = SubPixConfig {
                radius: self.config.subpixel_radius,
                ..SubPixConfig::default()
            };
            let (gx, gy) = gradients(&crate::raster::GrayF32::from_gray(gray), &cfg);
            for p in f.points.iter_mut() {
                *p = refine_corner(&gx, &gy, *p, &cfg);
            }
        }
        Ok(f)
    }

    fn detect_scaled(&self, gray: &GrayImage, s: f32, top_k: usize) -> Result<Features> {
        let (w0, h0) = (gray.width(), gray.height());
        let (w, h) = (
            ((w0 as f32) * s).round().max(1.0) as u32,
            ((h0 as f32) * s).round().max(1.0) as u32,
        );
        let small = image::imageops::resize(gray, w, h, image::imageops::FilterType::Triangle);
        let mut f = self.detect_at_native(&small, top_k)?;
        let (sx, sy) = (w0 as f32 / w as f32, h0 as f32 / h as f32);
        for p in f.points.iter_mut() {
            *p = [
                ((p[0] + 0.5) * sx - 0.5).clamp(0.0, (w0 - 1) as f32),
                ((p[1] + 0.5) * sy - 0.5).clamp(0.0, (h0 - 1) as f32),
            ];
        }
        Ok(f)
    }

    /// The network on `gray` placed at `(ox, oy)` in a zero image whose sides are multiples
    /// of the cell: the FP map cropped back to `gray`'s pixels, the coarse descriptor map
    /// ([`NetworkDescriptors`], channels last) and the padded size `[hp, wp]`.
    fn run_network(
        &self,
        gray: &GrayImage,
        [ox, oy]: [usize; 2],
    ) -> Result<(crate::raster::GrayF32, NetworkDescriptors, [usize; 2])> {
        let (w, h) = (gray.width() as usize, gray.height() as usize);
        let cell = self.model.cell();
        let (wp, hp) = (
            (w + ox).div_ceil(cell) * cell,
            (h + oy).div_ceil(cell) * cell,
        );
        let mut data = vec![0.0f32; wp * hp];
        for (y, row) in gray.as_raw().chunks_exact(w).enumerate() {
            let start = (y + oy) * wp + ox;
            for (d, &v) in data[start..start + w].iter_mut().zip(row) {
                *d = v as f32 / 255.0;
            }
        }
        let (prob, descriptors) = match &self.packed {
            Some(packed) => {
                let out = packed.forward(&data, [hp, wp])?;
                (out.prob, (out.descriptors, out.descriptor_dims))
            }
            None => {
                let input =
                    Tensor::<4>::from_data(TensorData::new(data, [1, 1, hp, wp]), &self.device);
                let out = self.model.forward(input)?;
                let read = |t: Tensor<4>, what: &str| {
                    t.into_data()
                        .try_to_vec::<f32>()
                        .map_err(|e| Error::msg(format!("reading {what}: {e:?}")))
                };
                let [_, d, hc, wc] = out.descriptors.dims();
                // Channels last, as the packed network gives them.
                let planar = read(out.descriptors, "descriptors")?;
                let plane = hc * wc;
                let mut last = vec![0.0f32; planar.len()];
                for (ch, values) in planar.chunks_exact(plane.max(1)).enumerate() {
                    for (i, &v) in values.iter().enumerate() {
                        last[i * d + ch] = v;
                    }
                }
                (read(out.prob, "FP map")?, (last, [d, hc, wc]))
            }
        };
        // Keypoints inside the original image only.
        let mut cropped = crate::raster::GrayF32::new(w, h);
        for y in 0..h {
            let start = (y + oy) * wp + ox;
            cropped.data[y * w..(y + 1) * w].copy_from_slice(&prob[start..start + w]);
        }
        Ok((cropped, descriptors, [hp, wp]))
    }

    /// One pyramid level: the `top_k` most probable keypoints of `gray` at its own size.
    fn detect_at_native(&self, gray: &GrayImage, top_k: usize) -> Result<Features> {
        let (w, h) = (gray.width() as usize, gray.height() as usize);
        if w < 16 || h < 16 {
            return Err(Error::msg(format!(
                "image {w}x{h} is too small for FPFDCNN (at least 16x16)"
            )));
        }
        let (mut cropped, (map, [dim, hc, wc]), [hp, wp]) = self.run_network(gray, [0, 0])?;
        let half = self.model.cell() / 2;
        let shifts: &[[usize; 2]] = match self.config.grid_shifts {
            2 => &[[half, half]],
            4 => &[[half, 0], [0, half], [half, half]],
            _ => &[],
        };
        // The other placements' descriptor maps, when their descriptors are averaged in.
        let mut other_placements = Vec::new();
        for &shift in shifts {
            let (other, descriptors, size) = self.run_network(gray, shift)?;
            for (a, b) in cropped.data.iter_mut().zip(&other.data) {
                *a += b;
            }
            if self.config.average_descriptors {
                other_placements.push((shift, descriptors, size));
            }
        }
        let passes = (shifts.len() + 1) as f32;
        cropped.data.iter_mut().for_each(|p| *p /= passes);
        let sigma = self.config.smoothing;
        if sigma > 0.0 {
            cropped = cropped.gaussian_blur(sigma);
        }
        let level = DetectorConfig {
            top_k,
            ..self.config.clone()
        };
        let picks = select_keypoints(&cropped.data, w, h, &level);
        let points: Vec<(usize, usize)> = picks.iter().map(|p| (p.0, p.1)).collect();
        let mut descriptors = Vec::new();
        if !points.is_empty() && shifts.is_empty() && self.config.descriptor_spread > 0 {
            descriptors = sample_spread(
                &map,
                [dim, hc, wc],
                [hp, wp],
                &points,
                [w, h],
                self.config.descriptor_spread,
            )?;
            normalise_rows(&mut descriptors, dim);
        } else if !points.is_empty() {
            descriptors = sample_bilinear_at_nhwc(&map, [dim, hc, wc], [hp, wp], &points)
                .map_err(super::FpfdcnnError::from)?;
            if !other_placements.is_empty() {
                normalise_rows(&mut descriptors, dim);
                for ([ox, oy], (m, dims), size) in &other_placements {
                    let at: Vec<(usize, usize)> =
                        points.iter().map(|&(x, y)| (x + ox, y + oy)).collect();
                    let mut d = sample_bilinear_at_nhwc(m, *dims, *size, &at)
                        .map_err(super::FpfdcnnError::from)?;
                    normalise_rows(&mut d, dim);
                    descriptors.iter_mut().zip(&d).for_each(|(a, b)| *a += b);
                }
            }
            normalise_rows(&mut descriptors, dim);
        }
        Ok(Features {
            points: points.iter().map(|&(x, y)| [x as f32, y as f32]).collect(),
            scores: picks.iter().map(|p| p.2).collect(),
            descriptors,
            dim,
        })
    }
}

/// The sum of five unit-normalised bilinear samples of the coarse map `map` (`dims`, padded
/// image `size`) for each point of the `[w, h]` image: at the point and `spread` pixels away
/// along both diagonals, clamped to the image ([`DetectorConfig::descriptor_spread`]).
fn sample_spread(
    map: &[f32],
    dims: [usize; 3],
    size: [usize; 2],
    points: &[(usize, usize)],
    [w, h]: [usize; 2],
    spread: usize,
) -> Result<Vec<f32>> {
    let dim = dims[0];
    let mut sum = vec![0.0f32; points.len() * dim];
    let (r, w, h) = (spread as i64, w as i64, h as i64);
    for (dx, dy) in [(0, 0), (-r, -r), (r, -r), (-r, r), (r, r)] {
        let at: Vec<(usize, usize)> = points
            .iter()
            .map(|&(x, y)| {
                (
                    (x as i64 + dx).clamp(0, w - 1) as usize,
                    (y as i64 + dy).clamp(0, h - 1) as usize,
                )
            })
            .collect();
        let mut d =
            sample_bilinear_at_nhwc(map, dims, size, &at).map_err(super::FpfdcnnError::from)?;
        normalise_rows(&mut d, dim);
        sum.iter_mut().zip(&d).for_each(|(a, b)| *a += b);
    }
    Ok(sum)
}

/// Scales each `dim`-long row of `d` to unit length (L2).
fn normalise_rows(d: &mut [f32], dim: usize) {
    for v in d.chunks_exact_mut(dim) {
        // Scale first so that squaring cannot overflow.
        let peak = v.iter().fold(0.0f32, |m, x| m.max(x.abs())).max(1e-30);
        let n = v
            .iter()
            .map(|x| (x / peak).powi(2))
            .sum::<f32>()
            .sqrt()
            .max(1e-12)
            * peak;
        v.iter_mut().for_each(|x| *x /= n);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nms_keeps_the_strongest_and_respects_radius_border_and_top_k() {
        let (w, h) = (20, 10);
        let mut p = vec![0.0f32; w * h];
        p[5 * w + 5] = 0.9;
        p[5 * w + 6] = 0.8; // suppressed by its neighbour
        p[5 * w + 12] = 0.7;
        p[w + 1] = 0.95; // in the border
        p[8 * w + 16] = 0.01; // under the threshold
        let cfg = DetectorConfig {
            threshold: 0.015,
            nms_radius: 2,
            top_k: 0,
            border: 2,
            input_scale: 1.0,
            subpixel_radius: 0,
            grid_shifts: 1,
            average_descriptors: false,
            descriptor_spread: 0,
            smoothing: 0.0,
            levels: 1,
            level_factor: 1.2,
        };
        let k = select_keypoints(&p, w, h, &cfg);
        assert_eq!(k, vec![(5, 5, 0.9), (12, 5, 0.7)]);
        let k = select_keypoints(&p, w, h, &DetectorConfig { top_k: 1, ..cfg });
        assert_eq!(k.len(), 1);
    }

    #[test]
    fn smoothing_finds_the_centre_of_a_noisy_blob() {
        use rand::{RngExt, SeedableRng};
        let (w, h) = (64, 48);
        let cfg = DetectorConfig {
            top_k: 1,
            border: 4,
            ..Default::default()
        };
        let dist = |p: (usize, usize, f32)| (p.0 as f32 - 37.0).hypot(p.1 as f32 - 21.0);
        let (mut raw_total, mut smooth_total) = (0.0, 0.0);
        for seed in 0..10 {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            // A broad blob of probability at (37, 21) under strong per-pixel noise.
            let mut img = crate::raster::GrayF32::new(w, h);
            for (i, v) in img.data.iter_mut().enumerate() {
                let (x, y) = ((i % w) as f32 - 37.0, (i / w) as f32 - 21.0);
                *v = 0.3 * (-(x * x + y * y) / 200.0).exp() + rng.random_range(0.0..0.4);
            }
            raw_total += dist(select_keypoints(&img.data, w, h, &cfg)[0]);
            smooth_total += dist(select_keypoints(&img.gaussian_blur(4.0).data, w, h, &cfg)[0]);
        }
        let (raw, smooth) = (raw_total / 10.0, smooth_total / 10.0);
        assert!(
            smooth < 2.0 && raw > 2.0 * smooth,
            "raw {raw} px, smoothed {smooth} px"
        );
    }

    /// A randomly initialised FPFDCNN with `dim`-d descriptors on ndarray.
    fn random_detector(dim: usize, config: DetectorConfig) -> FpfdcnnDetector {
        #[allow(deprecated)]
        let device = Device::ndarray();
        let model = super::super::FpfdcnnConfig::new()
            .with_descriptor_dim(dim)
            .init(&device)
            .unwrap();
        FpfdcnnDetector::new(model, device, config)
    }

    #[test]
    fn detect_pads_odd_sizes_and_normalises_descriptors() {
        let det = random_detector(
            16,
            DetectorConfig {
                threshold: 0.0,
                top_k: 20,
                border: 4,
                ..Default::default()
            },
        );
        let img = GrayImage::from_fn(50, 37, |x, y| {
            image::Luma([((x * 37 + y * 11) % 255) as u8])
        });
        let f = det.detect(&img).unwrap();
        assert_eq!(f.len(), 20);
        assert_eq!(f.out_matrix().len(), 20 * 18);
        for i in 0..f.len() {
            let [x, y] = f.points[i];
            assert!(x < 50.0 && y < 37.0);
            let n: f32 = f.descriptor(i).iter().map(|v| v * v).sum();
            assert!((n - 1.0).abs() < 1e-4);
        }
        assert!(det.detect(&GrayImage::new(8, 8)).is_err());
    }

    #[test]
    fn a_shifted_cell_grid_sees_the_image_as_a_padded_copy_would() {
        let single = DetectorConfig {
            grid_shifts: 1,
            border: 4,
            ..DetectorConfig::default()
        };
        let det = random_detector(8, single);
        let (w, h) = (40u32, 30u32);
        let img = GrayImage::from_fn(w, h, |x, y| {
            image::Luma([((x * 53 + y * 29 + x * y) % 251) as u8])
        });
        // The image placed 8 px right and 8 px down in a zero image, run unshifted.
        let padded = GrayImage::from_fn(w + 8, h + 8, |x, y| {
            if x >= 8 && y >= 8 {
                *img.get_pixel(x - 8, y - 8)
            } else {
                image::Luma([0])
            }
        });
        let (shifted, _, [hp, wp]) = det.run_network(&img, [8, 8]).unwrap();
        assert_eq!([hp, wp], [48, 48]);
        let (reference, _, _) = det.run_network(&padded, [0, 0]).unwrap();
        for y in 0..h as usize {
            for x in 0..w as usize {
                let a = shifted.data[y * w as usize + x];
                let b = reference.data[(y + 8) * (w as usize + 8) + x + 8];
                assert!((a - b).abs() < 1e-6, "({x}, {y}): {a} vs {b}");
            }
        }
        // Averaging placements changes the map but keeps every keypoint in the image.
        let one = det.detect(&img).unwrap();
        let four = FpfdcnnDetector::new(
            det.model.clone(),
            det.device.clone(),
            DetectorConfig {
                grid_shifts: 4,
                border: 4,
                ..DetectorConfig::default()
            },
        )
        .detect(&img)
        .unwrap();
        assert_ne!(one.scores, four.scores);
        assert!(
            four.points
                .iter()
                .all(|p| p[0] < w as f32 && p[1] < h as f32)
        );
        let bad = DetectorConfig {
            grid_shifts: 3,
            ..DetectorConfig::default()
        };
        assert!(bad.validate().unwrap_err().contains("grid_shifts"));
    }

    #[test]
    fn descriptors_are_the_normalised_mean_over_the_placements() {
        let config = |grid_shifts, average_descriptors| DetectorConfig {
            grid_shifts,
            average_descriptors,
            threshold: 0.0,
            top_k: 12,
            border: 4,
            ..DetectorConfig::default()
        };
        let det = random_detector(8, config(4, true));
        let with = |c| FpfdcnnDetector::new(det.model.clone(), det.device.clone(), c);
        let img = GrayImage::from_fn(48, 40, |x, y| {
            image::Luma([((x * 31 + y * 17 + x * y) % 253) as u8])
        });
        let averaged = det.detect(&img).unwrap();
        let first = with(config(4, false)).detect(&img).unwrap();
        assert_eq!(averaged.points, first.points);
        assert_eq!(averaged.scores, first.scores);
        assert_ne!(averaged.descriptors, first.descriptors);
        // The same from each placement's own map, sampled where the point lies in it.
        let points: Vec<(usize, usize)> = averaged
            .points
            .iter()
            .map(|p| (p[0] as usize, p[1] as usize))
            .collect();
        let mut expected = vec![0.0f32; points.len() * 8];
        for shift in [[0, 0], [8, 0], [0, 8], [8, 8]] {
            let (_, (map, dims), size) = det.run_network(&img, shift).unwrap();
            let at: Vec<(usize, usize)> = points
                .iter()
                .map(|&(x, y)| (x + shift[0], y + shift[1]))
                .collect();
            let mut d = sample_bilinear_at_nhwc(&map, dims, size, &at).unwrap();
            normalise_rows(&mut d, 8);
            expected.iter_mut().zip(&d).for_each(|(a, b)| *a += b);
        }
        normalise_rows(&mut expected, 8);
        for (a, b) in averaged.descriptors.iter().zip(&expected) {
            assert!((a - b).abs() < 1e-5, "{a} vs {b}");
        }
        // One placement: nothing to average.
        assert_eq!(
            with(config(1, true)).detect(&img).unwrap().descriptors,
            with(config(1, false)).detect(&img).unwrap().descriptors
        );
    }

    #[test]
    fn one_pass_descriptors_are_the_normalised_mean_of_the_spread_samples() {
        let config = |grid_shifts, descriptor_spread| DetectorConfig {
            grid_shifts,
            descriptor_spread,
            threshold: 0.0,
            // Every local maximum (the weights are random): points reach the border band.
            top_k: 200,
            border: 2,
            ..DetectorConfig::default()
        };
        let det = random_detector(8, config(1, 6));
        let with = |c| FpfdcnnDetector::new(det.model.clone(), det.device.clone(), c);
        let img = GrayImage::from_fn(48, 40, |x, y| {
            image::Luma([((x * 29 + y * 13 + x * y) % 251) as u8])
        });
        let spread = det.detect(&img).unwrap();
        let plain = with(config(1, 0)).detect(&img).unwrap();
        assert_eq!(spread.points, plain.points);
        assert_eq!(spread.scores, plain.scores);
        assert_ne!(spread.descriptors, plain.descriptors);
        let points: Vec<(usize, usize)> = spread
            .points
            .iter()
            .map(|p| (p[0] as usize, p[1] as usize))
            .collect();
        // Border 2 < spread 6: some samples are clamped to the image.
        assert!(
            points
                .iter()
                .any(|&(x, y)| x < 6 || y < 6 || x > 41 || y > 33)
        );
        let (_, (map, dims), size) = det.run_network(&img, [0, 0]).unwrap();
        let plain_expected = sample_bilinear_at_nhwc(&map, dims, size, &points).unwrap();
        let mut plain_expected = plain_expected;
        normalise_rows(&mut plain_expected, 8);
        assert_eq!(plain.descriptors, plain_expected);
        let mut expected = vec![0.0f32; points.len() * 8];
        for (dx, dy) in [(0i64, 0i64), (-6, -6), (6, -6), (-6, 6), (6, 6)] {
            let at: Vec<(usize, usize)> = points
                .iter()
                .map(|&(x, y)| {
                    (
                        (x as i64 + dx).clamp(0, 47) as usize,
                        (y as i64 + dy).clamp(0, 39) as usize,
                    )
                })
                .collect();
            let mut d = sample_bilinear_at_nhwc(&map, dims, size, &at).unwrap();
            normalise_rows(&mut d, 8);
            expected.iter_mut().zip(&d).for_each(|(a, b)| *a += b);
        }
        normalise_rows(&mut expected, 8);
        for (a, b) in spread.descriptors.iter().zip(&expected) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
        for row in spread.descriptors.chunks_exact(8) {
            let n = row.iter().map(|x| x * x).sum::<f32>().sqrt();
            assert!((n - 1.0).abs() < 1e-5, "norm {n}");
        }
        // Several placements ignore the spread (their average spreads the descriptors).
        assert_eq!(
            with(config(4, 6)).detect(&img).unwrap().descriptors,
            with(config(4, 0)).detect(&img).unwrap().descriptors
        );
        // Bounded.
        assert!(config(1, MAX_DESCRIPTOR_SPREAD).validate().is_ok());
        let err = config(1, MAX_DESCRIPTOR_SPREAD + 1).validate().unwrap_err();
        assert!(err.contains("descriptor_spread"), "{err}");
    }

    #[test]
    fn pyramid_levels_share_top_k_as_orb_does() {
        let orb = DetectorConfig {
            levels: 8,
            level_factor: 1.2,
            top_k: 500,
            ..Default::default()
        };
        // OpenCV's ORB_create(500).
        assert_eq!(orb.level_quotas(), vec![109, 90, 75, 63, 52, 44, 36, 31]);
        let all = DetectorConfig { top_k: 0, ..orb };
        assert_eq!(all.level_quotas(), vec![0; 8]);
        assert_eq!(DetectorConfig::default().level_quotas(), vec![500]);
        for (levels, factor) in [(0, 1.2), (MAX_LEVELS + 1, 1.2), (2, 1.0), (2, f32::NAN)] {
            let bad = DetectorConfig {
                levels,
                level_factor: factor,
                ..Default::default()
            };
            assert!(
                bad.validate().unwrap_err().contains("level"),
                "{levels} {factor}"
            );
        }
    }

    #[test]
    fn pyramid_detection_keeps_the_first_level_and_adds_coarser_keypoints() {
        let cfg = DetectorConfig {
            threshold: 0.0,
            top_k: 40,
            grid_shifts: 1,
            levels: 3,
            level_factor: 1.5,
            border: 4,
            ..Default::default()
        };
        let det = random_detector(8, cfg.clone());
        let (w, h) = (96u32, 80u32);
        let img = GrayImage::from_fn(w, h, |x, y| {
            image::Luma([((x * 53 + y * 29 + x * y) % 251) as u8])
        });
        let quotas = cfg.level_quotas();
        assert_eq!(quotas.iter().sum::<usize>(), 40);
        let pyramid = det.detect(&img).unwrap();
        assert_eq!(pyramid.len(), 40);
        let first = FpfdcnnDetector::new(
            det.model.clone(),
            det.device.clone(),
            DetectorConfig {
                levels: 1,
                top_k: quotas[0],
                ..cfg
            },
        )
        .detect(&img)
        .unwrap();
        assert_eq!(pyramid.points[..quotas[0]], first.points[..]);
        assert_eq!(pyramid.descriptors[..quotas[0] * 8], first.descriptors[..]);
        for i in 0..pyramid.len() {
            let [x, y] = pyramid.points[i];
            assert!(x < w as f32 && y < h as f32);
            let n: f32 = pyramid.descriptor(i).iter().map(|v| v * v).sum();
            assert!((n - 1.0).abs() < 1e-4);
        }
    }
}
