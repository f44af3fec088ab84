//! ORB features (Rublee et al., ICCV 2011) computed as OpenCV's `cv::ORB_create(500)`
//! computes them: the "ORB + BF matcher" baseline of the paper's Table 6 and the ORB
//! rows of Tables 1 and 7.
//!
//! The pipeline of OpenCV 4's `orb.cpp`:
//! 1. an image pyramid of 8 levels, each resized bilinearly from the previous one by
//!    1/1.2;
//! 2. the 500 features shared among levels as a geometric series of ratio 1/1.2
//!    (109, 90, 75, 63, 52, 44, 36, 31);
//! 3. FAST-9 (threshold 20, 3x3 non-maximum suppression) on every level, keypoints
//!    closer than `edge_threshold` (31) level pixels to the border dropped, the best
//!    `2n` by FAST score kept;
//! 4. re-ranking by the Harris response of a 7x7 block (k = 0.04), the best `n` kept;
//! 5. orientation by the intensity centroid of a disc of radius 15;
//! 6. steered BRIEF: the 256 comparisons of OpenCV's learned pattern, rotated by the
//!    keypoint's angle, on the level image smoothed by a 7x7 Gaussian (sigma 2).
//!
//! Deliberate differences: pyramid resizing and blurring are computed in floating
//! point where OpenCV uses fixed point (grey levels may differ by one), angles use an
//! exact `atan2`, and level positions map to full resolution with pixel centres
//! aligned, `(x + 0.5) s - 0.5`, where OpenCV reports `x s` (up to 1.3 px apart at
//! level 7). There is no FAST threshold fallback: that belongs to ORB-SLAM's
//! extractor, not to OpenCV's ORB.

use super::harris::Keypoint;
use crate::error::{Error, Result};
use crate::raster::GrayF32;
use image::{GrayImage, RgbImage};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// A 256-bit binary descriptor (bit `k` of byte `i` is comparison `8 i + k`).
pub type Descriptor = [u8; 32];

/// ORB settings; the defaults are `cv::ORB_create(500)`'s.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OrbConfig {
    /// Number of features to retain over all levels.
    pub n_features: usize,
    /// Ratio between the resolutions of consecutive pyramid levels (> 1).
    pub scale_factor: f32,
    /// Number of pyramid levels.
    pub n_levels: usize,
    /// Keypoints closer than this to a level's border are dropped, level pixels.
    /// At least 19: the rotated pattern reaches 18.4 px from the centre.
    pub edge_threshold: usize,
    /// FAST intensity threshold, grey levels.
    pub fast_threshold: u8,
}

impl Default for OrbConfig {
    fn default() -> Self {
        OrbConfig {
            n_features: 500,
            scale_factor: 1.2,
            n_levels: 8,
            edge_threshold: 31,
            fast_threshold: 20,
        }
    }
}

/// Side of the square patch the pattern was learned on.
const PATCH_SIZE: usize = 31;
const HALF_PATCH: i32 = 15;
/// Harris block size and constant of OpenCV's `HARRIS_SCORE`.
const HARRIS_BLOCK: i32 = 7;
const HARRIS_K: f32 = 0.04;

impl OrbConfig {
    fn validate(&self) -> Result<()> {
        if !(self.scale_factor.is_finite() && self.scale_factor > 1.0) {
            return Err(Error::msg(format!(
                "ORB scale factor must be a number above 1, got {}",
                self.scale_factor
            )));
        }
        if self.n_levels == 0 || self.n_levels > 32 {
            return Err(Error::msg(format!(
                "ORB needs 1 to 32 pyramid levels, got {}",
                self.n_levels
            )));
        }
        if self.edge_threshold < 19 {
            return Err(Error::msg(format!(
                "ORB edge threshold must be at least 19 px (the steered pattern's reach), got {}",
                self.edge_threshold
            )));
        }
        Ok(())
    }

    /// Features wanted on each level: a geometric series of ratio
    /// `1 / scale_factor` (OpenCV's distribution: in proportion to the levels' side
    /// lengths, not their areas), the last level taking the remainder.
    pub fn features_per_level(&self) -> Vec<usize> {
        let factor = 1.0 / self.scale_factor;
        let mut per_scale =
            self.n_features as f32 * (1.0 - factor) / (1.0 - factor.powi(self.n_levels as i32));
        let mut out = Vec::with_capacity(self.n_levels);
        let mut sum = 0usize;
        for _ in 0..self.n_levels.saturating_sub(1) {
            let n = per_scale.round_ties_even().max(0.0) as usize;
            out.push(n);
            sum += n;
            per_scale *= factor;
        }
        out.push(self.n_features.saturating_sub(sum));
        out
    }
}

/// An ORB keypoint.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OrbKeypoint {
    /// Position in full-resolution (level-0) pixels.
    pub x: f32,
    pub y: f32,
    /// Pyramid level (OpenCV's octave).
    pub level: usize,
    /// Orientation in degrees in [0, 360), measured from the x axis towards y (image
    /// axes, y down), as OpenCV's `KeyPoint::angle`.
    pub angle: f32,
    /// Harris response (OpenCV's scaling).
    pub response: f32,
    /// Diameter of the described patch in level-0 pixels (`31 · 1.2^level`).
    pub size: f32,
}

impl OrbKeypoint {
    /// As a plain keypoint (position and response).
    pub fn to_keypoint(&self) -> Keypoint {
        Keypoint {
            x: self.x,
            y: self.y,
            score: self.response,
        }
    }
}

/// Keypoints and their descriptors (same order).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OrbFeatures {
    pub keypoints: Vec<OrbKeypoint>,
    pub descriptors: Vec<Descriptor>,
}

impl OrbFeatures {
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }
}

/// Grey conversion of OpenCV's `cvtColor(RGB2GRAY)` for 8-bit images (fixed point,
/// 0.299 R + 0.587 G + 0.114 B, rounded).
pub fn rgb_to_gray(img: &RgbImage) -> GrayImage {
    let data = img
        .pixels()
        .map(|p| {
            let v = p[0] as u32 * 4899 + p[1] as u32 * 9617 + p[2] as u32 * 1868;
            ((v + (1 << 13)) >> 14) as u8
        })
        .collect();
    GrayImage::from_raw(img.width(), img.height(), data).unwrap_or_default()
}

/// An intensity image in [0, 1] as 8-bit grey levels (rounded, clamped), e.g. after
/// photometric augmentation, for ORB.
pub fn gray_from_f32(img: &GrayF32) -> GrayImage {
    let data = img
        .data
        .iter()
        .map(|&v| (v * 255.0).round().clamp(0.0, 255.0) as u8)
        .collect();
    GrayImage::from_raw(img.width as u32, img.height as u32, data).unwrap_or_default()
}

/// A FAST corner at integer level coordinates with its score: the largest
/// threshold for which it is still a corner.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FastCorner {
    pub x: u32,
    pub y: u32,
    pub score: u8,
}

/// Bresenham circle of radius 3, clockwise from the top (x, y offsets).
const CIRCLE: [(i32, i32); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// FAST-9 score of pixel `(x, y)` (at least 3 px from the border): 0 when it is not a
/// corner (no arc of 9 contiguous circle pixels all brighter than `centre + t` or all
/// darker than `centre - t`), else the largest such `t`.
fn fast_score(data: &[u8], w: usize, x: usize, y: usize, t: i16) -> u8 {
    let c = data[y * w + x] as i16;
    let px = |k: usize| {
        let (dx, dy) = CIRCLE[k];
        data[(y as i32 + dy) as usize * w + (x as i32 + dx) as usize] as i16 - c
    };
    // Any arc of 9 contains at least two of the four compass pixels.
    let compass = [px(0), px(4), px(8), px(12)];
    let bright = compass.iter().filter(|&&d| d > t).count();
    let dark = compass.iter().filter(|&&d| d < -t).count();
    if bright < 2 && dark < 2 {
        return 0;
    }
    let mut d = [0i16; 16];
    for (k, v) in d.iter_mut().enumerate() {
        *v = px(k);
    }
    let (mut best_bright, mut best_dark) = (i16::MIN, i16::MIN);
    for start in 0..16 {
        let (mut lo, mut hi) = (i16::MAX, i16::MIN);
        for k in start..start + 9 {
            let v = d[k % 16];
            lo = lo.min(v);
            hi = hi.max(v);
        }
        best_bright = best_bright.max(lo);
        best_dark = best_dark.max(-hi);
    }
    let best = best_bright.max(best_dark);
    if best > t { (best - 1) as u8 } else { 0 }
}

/// FAST-9 corners with 3x3 non-maximum suppression (a corner survives when its score
/// is strictly above its eight neighbours'), in raster order.
pub fn fast_corners(img: &GrayImage, threshold: u8) -> Vec<FastCorner> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w < 7 || h < 7 {
        return Vec::new();
    }
    let data = img.as_raw();
    let t = threshold as i16;
    let mut scores = vec![0u8; w * h];
    scores[3 * w..(h - 3) * w]
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(r, row)| {
            let y = r + 3;
            for (x, s) in row.iter_mut().enumerate().take(w - 3).skip(3) {
                *s = fast_score(data, w, x, y, t);
            }
        });
    let mut out = Vec::new();
    for y in 3..h - 3 {
        for x in 3..w - 3 {
            let s = scores[y * w + x];
            if s == 0 {
                continue;
            }
            let is_max = (-1i32..=1).all(|dy| {
                (-1i32..=1).all(|dx| {
                    (dx == 0 && dy == 0)
                        || s > scores[(y as i32 + dy) as usize * w + (x as i32 + dx) as usize]
                })
            });
            if is_max {
                out.push(FastCorner {
                    x: x as u32,
                    y: y as u32,
                    score: s,
                });
            }
        }
    }
    out
}

/// Keeps the `n` best items by `key` and every item tied with the n-th
/// (OpenCV's `KeyPointsFilter::retainBest`), sorted best first.
fn retain_best<T>(items: &mut Vec<T>, n: usize, key: impl Fn(&T) -> f32) {
    items.sort_by(|a, b| key(b).total_cmp(&key(a)));
    if items.len() > n {
        if n == 0 {
            items.clear();
            return;
        }
        let boundary = key(&items[n - 1]);
        let end = items.partition_point(|it| key(it) >= boundary);
        items.truncate(end);
    }
}

/// Harris response of the 7x7 block centred at `(x, y)` with 3x3 Sobel gradients,
/// scaled as OpenCV's ORB does.
fn harris_response(img: &GrayImage, x: i32, y: i32) -> f32 {
    let w = img.width() as i32;
    let d = img.as_raw();
    let p = |xx: i32, yy: i32| d[(yy * w + xx) as usize] as i32;
    let r = HARRIS_BLOCK / 2;
    let (mut a, mut b, mut c) = (0i64, 0i64, 0i64);
    for yy in y - r..=y + r {
        for xx in x - r..=x + r {
            let ix = (p(xx + 1, yy) - p(xx - 1, yy)) * 2
                + (p(xx + 1, yy - 1) - p(xx - 1, yy - 1))
                + (p(xx + 1, yy + 1) - p(xx - 1, yy + 1));
            let iy = (p(xx, yy + 1) - p(xx, yy - 1)) * 2
                + (p(xx - 1, yy + 1) - p(xx - 1, yy - 1))
                + (p(xx + 1, yy + 1) - p(xx + 1, yy - 1));
            a += (ix * ix) as i64;
            b += (iy * iy) as i64;
            c += (ix * iy) as i64;
        }
    }
    let scale = 1.0 / (4.0 * HARRIS_BLOCK as f64 * 255.0);
    let (a, b, c) = (a as f64, b as f64, c as f64);
    ((a * b - c * c - HARRIS_K as f64 * (a + b) * (a + b)) * scale.powi(4)) as f32
}

/// Half-widths of the rows of the radius-15 disc (OpenCV's `umax`, made symmetric).
fn disc_half_widths() -> [i32; HALF_PATCH as usize + 2] {
    let mut umax = [0i32; HALF_PATCH as usize + 2];
    let hp = HALF_PATCH as f64;
    let vmax = (hp * std::f64::consts::SQRT_2 / 2.0 + 1.0).floor() as usize;
    let vmin = (hp * std::f64::consts::SQRT_2 / 2.0).ceil() as usize;
    for (v, u) in umax.iter_mut().enumerate().take(vmax + 1) {
        *u = (hp * hp - (v * v) as f64).sqrt().round() as i32;
    }
    let mut v0 = 0usize;
    let mut v = HALF_PATCH as usize;
    while v >= vmin {
        while umax[v0] == umax[v0 + 1] {
            v0 += 1;
        }
        umax[v] = v0 as i32;
        v0 += 1;
        v -= 1;
    }
    umax
}

/// Orientation of the intensity centroid of the disc around `(x, y)`, degrees in [0, 360).
fn ic_angle(img: &GrayImage, x: i32, y: i32, umax: &[i32]) -> f32 {
    let w = img.width() as i32;
    let d = img.as_raw();
    let p = |xx: i32, yy: i32| d[(yy * w + xx) as usize] as i64;
    let (mut m01, mut m10) = (0i64, 0i64);
    for u in -HALF_PATCH..=HALF_PATCH {
        m10 += u as i64 * p(x + u, y);
    }
    for v in 1..=HALF_PATCH {
        let dmax = umax[v as usize];
        let mut v_sum = 0i64;
        for u in -dmax..=dmax {
            let (plus, minus) = (p(x + u, y + v), p(x + u, y - v));
            v_sum += plus - minus;
            m10 += u as i64 * (plus + minus);
        }
        m01 += v as i64 * v_sum;
    }
    let a = (m01 as f64).atan2(m10 as f64).to_degrees();
    (if a < 0.0 { a + 360.0 } else { a }) as f32
}

/// Bilinear resize with pixel centres aligned (OpenCV's `INTER_LINEAR`).
fn resize_bilinear(src: &GrayImage, w: usize, h: usize) -> GrayImage {
    let (sw, sh) = (src.width() as usize, src.height() as usize);
    let taps = |n_dst: usize, n_src: usize| -> Vec<(usize, f32)> {
        let r = n_src as f64 / n_dst as f64;
        (0..n_dst)
            .map(|i| {
                let f = (i as f64 + 0.5) * r - 0.5;
                let i0 = f.floor();
                if i0 < 0.0 {
                    (0, 0.0)
                } else if i0 as usize >= n_src - 1 {
                    (n_src - 1, 0.0)
                } else {
                    (i0 as usize, (f - i0) as f32)
                }
            })
            .collect()
    };
    let (xs, ys) = (taps(w, sw), taps(h, sh));
    let d = src.as_raw();
    let mut out = vec![0u8; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let (y0, fy) = ys[y];
        let y1 = (y0 + 1).min(sh - 1);
        for (x, o) in row.iter_mut().enumerate() {
            let (x0, fx) = xs[x];
            let x1 = (x0 + 1).min(sw - 1);
            let g = |xx: usize, yy: usize| d[yy * sw + xx] as f32;
            let top = g(x0, y0) * (1.0 - fx) + g(x1, y0) * fx;
            let bottom = g(x0, y1) * (1.0 - fx) + g(x1, y1) * fx;
            *o = (top * (1.0 - fy) + bottom * fy).round().clamp(0.0, 255.0) as u8;
        }
    });
    GrayImage::from_raw(w as u32, h as u32, out).unwrap_or_default()
}

/// Index reflected into `[0, n)` without repeating the edge (OpenCV's BORDER_REFLECT_101).
fn reflect101(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let mut i = i;
    while i < 0 || i >= n {
        i = if i < 0 { -i } else { 2 * n - 2 - i };
    }
    i as usize
}

/// 7x7 Gaussian blur with sigma 2 and reflected borders.
fn gaussian_blur_7x7(img: &GrayImage) -> GrayImage {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let mut k = [0f32; 7];
    for (i, v) in k.iter_mut().enumerate() {
        let d = i as f32 - 3.0;
        *v = (-d * d / 8.0).exp();
    }
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    let d = img.as_raw();
    let mut tmp = vec![0f32; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            *o = (0..7)
                .map(|j| k[j] * d[y * w + reflect101(x as isize + j as isize - 3, w)] as f32)
                .sum();
        }
    });
    let mut out = vec![0u8; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let v: f32 = (0..7)
                .map(|j| k[j] * tmp[reflect101(y as isize + j as isize - 3, h) * w + x])
                .sum();
            *o = v.round().clamp(0.0, 255.0) as u8;
        }
    });
    GrayImage::from_raw(w as u32, h as u32, out).unwrap_or_default()
}

/// Steered BRIEF descriptor at integer level position `(x, y)` with orientation
/// `angle` (degrees) on the smoothed level image.
fn steered_brief(smoothed: &GrayImage, x: i32, y: i32, angle: f32) -> Descriptor {
    let w = smoothed.width() as i32;
    let d = smoothed.as_raw();
    let (b, a) = angle.to_radians().sin_cos();
    let value = |px: i8, py: i8| {
        let (px, py) = (px as f32, py as f32);
        let rx = (px * a - py * b).round_ties_even() as i32;
        let ry = (px * b + py * a).round_ties_even() as i32;
        d[((y + ry) * w + x + rx) as usize]
    };
    let mut desc = [0u8; 32];
    for (i, pair) in BIT_PATTERN_31.iter().enumerate() {
        if value(pair[0], pair[1]) < value(pair[2], pair[3]) {
            desc[i / 8] |= 1 << (i % 8);
        }
    }
    desc
}

/// Keypoints of one pyramid level, in level coordinates, with their descriptors.
fn level_features(
    img: &GrayImage,
    wanted: usize,
    cfg: &OrbConfig,
    umax: &[i32],
) -> Vec<(i32, i32, f32, f32, Descriptor)> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let border = cfg.edge_threshold;
    if wanted == 0 || w <= 2 * border || h <= 2 * border {
        return Vec::new();
    }
    let mut corners: Vec<FastCorner> = fast_corners(img, cfg.fast_threshold)
        .into_iter()
        .filter(|c| {
            let (x, y) = (c.x as usize, c.y as usize);
            x >= border && y >= border && x < w - border && y < h - border
        })
        .collect();
    retain_best(&mut corners, 2 * wanted, |c| c.score as f32);
    let mut scored: Vec<(i32, i32, f32)> = corners
        .iter()
        .map(|c| {
            let (x, y) = (c.x as i32, c.y as i32);
            (x, y, harris_response(img, x, y))
        })
        .collect();
    retain_best(&mut scored, wanted, |s| s.2);
    let smoothed = gaussian_blur_7x7(img);
    scored
        .into_iter()
        .map(|(x, y, response)| {
            let angle = ic_angle(img, x, y, umax);
            (x, y, response, angle, steered_brief(&smoothed, x, y, angle))
        })
        .collect()
}

/// Detects ORB keypoints and computes their descriptors on an 8-bit grey image
/// (see [`rgb_to_gray`] for colour images). Keypoints are grouped by level, strongest
/// first within a level; an image too small for any level yields no features.
pub fn detect_and_compute(img: &GrayImage, cfg: &OrbConfig) -> Result<OrbFeatures> {
    cfg.validate()?;
    let (w0, h0) = (img.width() as usize, img.height() as usize);
    let wanted = cfg.features_per_level();
    let umax = disc_half_widths();
    // The pyramid: each level resized from the previous one.
    let mut levels: Vec<GrayImage> = vec![img.clone()];
    for l in 1..cfg.n_levels {
        let scale = (cfg.scale_factor as f64).powi(l as i32) as f32;
        let w = (w0 as f32 / scale).round_ties_even() as usize;
        let h = (h0 as f32 / scale).round_ties_even() as usize;
        if w == 0 || h == 0 {
            break;
        }
        let prev = &levels[l - 1];
        levels.push(resize_bilinear(prev, w, h));
    }
    let per_level: Vec<_> = levels
        .par_iter()
        .enumerate()
        .map(|(l, lev)| level_features(lev, wanted[l], cfg, &umax))
        .collect();
    let mut out = OrbFeatures::default();
    for (l, feats) in per_level.into_iter().enumerate() {
        let lev = &levels[l];
        let sx = w0 as f32 / lev.width() as f32;
        let sy = h0 as f32 / lev.height() as f32;
        let scale = (cfg.scale_factor as f64).powi(l as i32) as f32;
        for (x, y, response, angle, desc) in feats {
            out.keypoints.push(OrbKeypoint {
                x: (x as f32 + 0.5) * sx - 0.5,
                y: (y as f32 + 0.5) * sy - 0.5,
                level: l,
                angle,
                response,
                size: PATCH_SIZE as f32 * scale,
            });
            out.descriptors.push(desc);
        }
    }
    Ok(out)
}

// The test pairs below are `bit_pattern_31_` of OpenCV's
// `modules/features2d/src/orb.cpp` (authors Ethan Rublee, Vincent Rabaud, Gary
// Bradski), distributed under this licence:
//
// Copyright (c) 2009, Willow Garage, Inc.
// All rights reserved.
//
// Redistribution and use in source and binary forms, with or without
// modification, are permitted provided that the following conditions are met:
//  * Redistributions of source code must retain the above copyright notice, this
//    list of conditions and the following disclaimer.
//  * Redistributions in binary form must reproduce the above copyright notice,
//    this list of conditions and the following disclaimer in the documentation
//    and/or other materials provided with the distribution.
//  * Neither the name of the Willow Garage nor the names of its contributors may
//    be used to endorse or promote products derived from this software without
//    specific prior written permission.
//
// THIS SOFTWARE IS PROVIDED BY THE COPYRIGHT HOLDERS AND CONTRIBUTORS "AS IS" AND
// ANY EXPRESS OR IMPLIED WARRANTIES, INCLUDING, BUT NOT LIMITED TO, THE IMPLIED
// WARRANTIES OF MERCHANTABILITY AND FITNESS FOR A PARTICULAR PURPOSE ARE
// DISCLAIMED. IN NO EVENT SHALL THE COPYRIGHT OWNER OR CONTRIBUTORS BE LIABLE FOR
// ANY DIRECT, INDIRECT, INCIDENTAL, SPECIAL, EXEMPLARY, OR CONSEQUENTIAL DAMAGES
// (INCLUDING, BUT NOT LIMITED TO, PROCUREMENT OF SUBSTITUTE GOODS OR SERVICES;
// LOSS OF USE, DATA, OR PROFITS; OR BUSINESS INTERRUPTION) HOWEVER CAUSED AND ON
// ANY THEORY OF LIABILITY, WHETHER IN CONTRACT, STRICT LIABILITY, OR TORT
// (INCLUDING NEGLIGENCE OR OTHERWISE) ARISING IN ANY WAY OUT OF THE USE OF THIS
// SOFTWARE, EVEN IF ADVISED OF THE POSSIBILITY OF SUCH DAMAGE.

/// OpenCV's learned rBRIEF test pairs `(x1, y1, x2, y2)` for a 31x31 patch (bit `i`
/// is set when the smoothed intensity at the first point is below the second's).
#[rustfmt::skip]
const BIT_PATTERN_31: [[i8; 4]; 256] = [
    [8, -3, 9, 5], [4, 2, 7, -12], [-11, 9, -8, 2], [7, -12, 12, -13],
    [2, -13, 2, 12], [1, -7, 1, 6], [-2, -10, -2, -4], [-13, -13, -11, -8],
    [-13, -3, -12, -9], [10, 4, 11, 9], [-13, -8, -8, -9], [-11, 7, -9, 12],
    [7, 7, 12, 6], [-4, -5, -3, 0], [-13, 2, -12, -3], [-9, 0, -7, 5],
    [12, -6, 12, -1], [-3, 6, -2, 12], [-6, -13, -4, -8], [11, -13, 12, -8],
    [4, 7, 5, 1], [5, -3, 10, -3], [3, -7, 6, 12], [-8, -7, -6, -2],
    [-2, 11, -1, -10], [-13, 12, -8, 10], [-7, 3, -5, -3], [-4, 2, -3, 7],
    [-10, -12, -6, 11], [5, -12, 6, -7], [5, -6, 7, -1], [1, 0, 4, -5],
    [9, 11, 11, -13], [4, 7, 4, 12], [2, -1, 4, 4], [-4, -12, -2, 7],
    [-8, -5, -7, -10], [4, 11, 9, 12], [0, -8, 1, -13], [-13, -2, -8, 2],
    [-3, -2, -2, 3], [-6, 9, -4, -9], [8, 12, 10, 7], [0, 9, 1, 3],
    [7, -5, 11, -10], [-13, -6, -11, 0], [10, 7, 12, 1], [-6, -3, -6, 12],
    [10, -9, 12, -4], [-13, 8, -8, -12], [-13, 0, -8, -4], [3, 3, 7, 8],
    [5, 7, 10, -7], [-1, 7, 1, -12], [3, -10, 5, 6], [2, -4, 3, -10],
    [-13, 0, -13, 5], [-13, -7, -12, 12], [-13, 3, -11, 8], [-7, 12, -4, 7],
    [6, -10, 12, 8], [-9, -1, -7, -6], [-2, -5, 0, 12], [-12, 5, -7, 5],
    [3, -10, 8, -13], [-7, -7, -4, 5], [-3, -2, -1, -7], [2, 9, 5, -11],
    [-11, -13, -5, -13], [-1, 6, 0, -1], [5, -3, 5, 2], [-4, -13, -4, 12],
    [-9, -6, -9, 6], [-12, -10, -8, -4], [10, 2, 12, -3], [7, 12, 12, 12],
    [-7, -13, -6, 5], [-4, 9, -3, 4], [7, -1, 12, 2], [-7, 6, -5, 1],
    [-13, 11, -12, 5], [-3, 7, -2, -6], [7, -8, 12, -7], [-13, -7, -11, -12],
    [1, -3, 12, 12], [2, -6, 3, 0], [-4, 3, -2, -13], [-1, -13, 1, 9],
    [7, 1, 8, -6], [1, -1, 3, 12], [9, 1, 12, 6], [-1, -9, -1, 3],
    [-13, -13, -10, 5], [7, 7, 10, 12], [12, -5, 12, 9], [6, 3, 7, 11],
    [5, -13, 6, 10], [2, -12, 2, 3], [3, 8, 4, -6], [2, 6, 12, -13],
    [9, -12, 10, 3], [-8, 4, -7, 9], [-11, 12, -4, -6], [1, 12, 2, -8],
    [6, -9, 7, -4], [2, 3, 3, -2], [6, 3, 11, 0], [3, -3, 8, -8],
    [7, 8, 9, 3], [-11, -5, -6, -4], [-10, 11, -5, 10], [-5, -8, -3, 12],
    [-10, 5, -9, 0], [8, -1, 12, -6], [4, -6, 6, -11], [-10, 12, -8, 7],
    [4, -2, 6, 7], [-2, 0, -2, 12], [-5, -8, -5, 2], [7, -6, 10, 12],
    [-9, -13, -8, -8], [-5, -13, -5, -2], [8, -8, 9, -13], [-9, -11, -9, 0],
    [1, -8, 1, -2], [7, -4, 9, 1], [-2, 1, -1, -4], [11, -6, 12, -11],
    [-12, -9, -6, 4], [3, 7, 7, 12], [5, 5, 10, 8], [0, -4, 2, 8],
    [-9, 12, -5, -13], [0, 7, 2, 12], [-1, 2, 1, 7], [5, 11, 7, -9],
    [3, 5, 6, -8], [-13, -4, -8, 9], [-5, 9, -3, -3], [-4, -7, -3, -12],
    [6, 5, 8, 0], [-7, 6, -6, 12], [-13, 6, -5, -2], [1, -10, 3, 10],
    [4, 1, 8, -4], [-2, -2, 2, -13], [2, -12, 12, 12], [-2, -13, 0, -6],
    [4, 1, 9, 3], [-6, -10, -3, -5], [-3, -13, -1, 1], [7, 5, 12, -11],
    [4, -2, 5, -7], [-13, 9, -9, -5], [7, 1, 8, 6], [7, -8, 7, 6],
    [-7, -4, -7, 1], [-8, 11, -7, -8], [-13, 6, -12, -8], [2, 4, 3, 9],
    [10, -5, 12, 3], [-6, -5, -6, 7], [8, -3, 9, -8], [2, -12, 2, 8],
    [-11, -2, -10, 3], [-12, -13, -7, -9], [-11, 0, -10, -5], [5, -3, 11, 8],
    [-2, -13, -1, 12], [-1, -8, 0, 9], [-13, -11, -12, -5], [-10, -2, -10, 11],
    [-3, 9, -2, -13], [2, -3, 3, 2], [-9, -13, -4, 0], [-4, 6, -3, -10],
    [-4, 12, -2, -7], [-6, -11, -4, 9], [6, -3, 6, 11], [-13, 11, -5, 5],
    [11, 11, 12, 6], [7, -5, 12, -2], [-1, 12, 0, 7], [-4, -8, -3, -2],
    [-7, 1, -6, 7], [-13, -12, -8, -13], [-7, -2, -6, -8], [-8, 5, -6, -9],
    [-5, -1, -4, 5], [-13, 7, -8, 10], [1, 5, 5, -13], [1, 0, 10, -13],
    [9, 12, 10, -1], [5, -8, 10, -9], [-1, 11, 1, -13], [-9, -3, -6, 2],
    [-1, -10, 1, 12], [-13, 1, -8, -10], [8, -11, 10, -6], [2, -13, 3, -6],
    [7, -13, 12, -9], [-10, -10, -5, -7], [-10, -8, -8, -13], [4, -6, 8, 5],
    [3, 12, 8, -13], [-4, 2, -3, -3], [5, -13, 10, -12], [4, -13, 5, -1],
    [-9, 9, -4, 3], [0, 3, 3, -9], [-12, 1, -6, 1], [3, 2, 4, -8],
    [-10, -10, -10, 9], [8, -13, 12, 12], [-8, -12, -6, -5], [2, 2, 3, 7],
    [10, 6, 11, -8], [6, 8, 8, -12], [-7, 10, -6, 5], [-3, -9, -3, 9],
    [-1, -13, -1, 5], [-3, -7, -3, 4], [-8, -2, -8, 3], [4, 2, 12, 12],
    [2, -5, 3, 11], [6, -9, 11, -13], [3, -1, 7, 12], [11, -1, 12, 4],
    [-3, 0, -3, 6], [4, -11, 4, 12], [2, -4, 2, 1], [-10, -6, -8, 1],
    [-13, 7, -11, 1], [-13, 12, -11, -13], [6, 0, 11, -13], [0, -1, 1, 4],
    [-13, 3, -9, -2], [-9, 8, -6, -3], [-13, -6, -8, -2], [5, -9, 8, 10],
    [2, 7, 3, -9], [-1, -6, -1, -1], [9, 5, 11, -2], [11, -3, 12, -8],
    [3, 0, 3, 5], [-1, 4, 0, 10], [3, -6, 4, 5], [-13, 0, -10, 5],
    [5, 8, 12, 11], [8, 9, 9, -6], [7, -4, 8, -12], [-10, 4, -10, 9],
    [7, 3, 12, 4], [9, -7, 10, -2], [7, 0, 12, -2], [-1, -6, 0, -11],
];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::dataset::TumSequence;
    use crate::features::bf_matcher::bf_match;
    use crate::metrics::matching::{CORRECT_MATCH_PX, frame_pair_accuracy, matching_accuracy};
    use nalgebra::Point2;

    const FIXTURE: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/datasets/fixtures/tum_fr1_rpy_head10"
    );

    fn fixture_gray(seq: &TumSequence, i: usize) -> GrayImage {
        rgb_to_gray(&seq.load_rgb(i).unwrap())
    }

    #[test]
    fn level_budget_and_disc_match_opencv() {
        let per = OrbConfig::default().features_per_level();
        assert_eq!(per.len(), 8);
        assert_eq!(per.iter().sum::<usize>(), 500);
        assert_eq!(per[0], 109);
        assert_eq!(
            disc_half_widths()[..16],
            [15, 15, 15, 15, 14, 14, 14, 13, 13, 12, 11, 10, 9, 8, 6, 3]
        );
        let bad = OrbConfig {
            scale_factor: 1.0,
            ..OrbConfig::default()
        };
        assert!(detect_and_compute(&GrayImage::new(64, 64), &bad).is_err());
        let bad = OrbConfig {
            edge_threshold: 10,
            ..OrbConfig::default()
        };
        assert!(detect_and_compute(&GrayImage::new(64, 64), &bad).is_err());
        // Too small for any level: no features, no panic.
        let f = detect_and_compute(&GrayImage::new(40, 30), &OrbConfig::default()).unwrap();
        assert!(f.is_empty());
    }

    #[test]
    fn fast_finds_the_corners_of_a_bright_square() {
        // A 200-grey square on black with its four corner pixels at 255: on a binary
        // square the corner and its neighbours tie and suppress each other, as in OpenCV.
        let mut img = GrayImage::new(40, 40);
        for y in 10..30 {
            for x in 10..30 {
                let corner = (x == 10 || x == 29) && (y == 10 || y == 29);
                img.put_pixel(x, y, image::Luma([if corner { 255 } else { 200 }]));
            }
        }
        let c = fast_corners(&img, 20);
        let xy: Vec<_> = c.iter().map(|k| (k.x, k.y)).collect();
        assert_eq!(xy, vec![(10, 10), (29, 10), (10, 29), (29, 29)], "{c:?}");
        assert!(c.iter().all(|k| k.score == 254));
        assert!(fast_corners(&img, 255).is_empty());
    }

    #[test]
    fn real_frames_give_about_500_well_spread_keypoints() {
        let seq = TumSequence::open(FIXTURE).unwrap();
        for i in [0, 5, 9] {
            let f = detect_and_compute(&fixture_gray(&seq, i), &OrbConfig::default()).unwrap();
            assert_eq!(f.keypoints.len(), f.descriptors.len());
            let n = f.len();
            // Spread: occupied cells of a 4x4 grid over the image.
            let mut cells = [false; 16];
            for k in &f.keypoints {
                assert!(k.x >= 0.0 && k.y >= 0.0 && k.x < 640.0 && k.y < 480.0);
                cells[(k.y / 120.0) as usize * 4 + (k.x / 160.0) as usize] = true;
            }
            let occupied = cells.iter().filter(|&&c| c).count();
            let levels = f.keypoints.iter().map(|k| k.level).max().unwrap_or(0);
            eprintln!("frame {i}: {n} keypoints, {occupied}/16 cells, levels 0..={levels}");
            assert!((450..=510).contains(&n), "frame {i}: {n} keypoints");
            // OpenCV 4.14 covers 10, 9 and 10 cells on these frames (the rest is wall).
            assert!(occupied >= 9, "frame {i}: {occupied}/16 cells");
            assert!(levels >= 5);
        }
    }

    #[test]
    fn reproduces_opencv_keypoints_and_descriptors() {
        // scripts/opencv_orb_reference.py: cv2.ORB_create(500) on fixture frame 0.
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/datasets/fixtures/opencv_orb/tum_fr1_rpy_head10_frame0.txt"
        );
        let text = std::fs::read_to_string(path).unwrap();
        let seq = TumSequence::open(FIXTURE).unwrap();
        let ours = detect_and_compute(&fixture_gray(&seq, 0), &OrbConfig::default()).unwrap();
        let (mut found, mut bits, mut identical, mut total) = (0, 0, 0, 0);
        for line in text.lines().filter(|l| !l.starts_with('#')) {
            let f: Vec<&str> = line.split_whitespace().collect();
            let (x, y, level): (f32, f32, usize) = (
                f[0].parse().unwrap(),
                f[1].parse().unwrap(),
                f[2].parse().unwrap(),
            );
            let desc: Vec<u8> = (0..32)
                .map(|i| u8::from_str_radix(&f[5][2 * i..2 * i + 2], 16).unwrap())
                .collect();
            total += 1;
            // OpenCV reports level positions times 1.2^level.
            let s = 1.2f32.powi(level as i32);
            let (lx, ly) = ((x / s).round(), (y / s).round());
            let hit = ours.keypoints.iter().position(|k| {
                let (sx, sy) = (640.0 / (640.0 / s).round(), 480.0 / (480.0 / s).round());
                k.level == level
                    && (((k.x + 0.5) / sx - 0.5) - lx).abs() < 0.01
                    && (((k.y + 0.5) / sy - 0.5) - ly).abs() < 0.01
            });
            if let Some(i) = hit {
                found += 1;
                let d = super::super::bf_matcher::hamming(
                    &ours.descriptors[i],
                    desc.as_slice().try_into().unwrap(),
                );
                bits += d;
                identical += (d == 0) as usize;
            }
        }
        eprintln!(
            "OpenCV reference: {found}/{total} keypoints reproduced, {identical} identical descriptors, mean {:.2} differing bits",
            bits as f64 / found as f64
        );
        assert_eq!(total, 500);
        assert!(found >= 475, "{found}");
        assert!(identical as f64 >= 0.8 * found as f64);
        assert!((bits as f64) / (found as f64) < 0.5);
    }

    #[test]
    fn matches_between_real_frames_are_mostly_correct() {
        let seq = TumSequence::open(FIXTURE).unwrap();
        let cam = Camera::tum_fr1();
        let (a, b) = (seq.load_frame(0).unwrap(), seq.load_frame(3).unwrap());
        let cfg = OrbConfig::default();
        let fa = detect_and_compute(&rgb_to_gray(&a.rgb), &cfg).unwrap();
        let fb = detect_and_compute(&rgb_to_gray(&b.rgb), &cfg).unwrap();
        let pairs: Vec<_> = bf_match(&fa.descriptors, &fb.descriptors, true)
            .iter()
            .map(|m| {
                let (ka, kb) = (fa.keypoints[m.query], fb.keypoints[m.train]);
                (
                    Point2::new(ka.x as f64, ka.y as f64),
                    Point2::new(kb.x as f64, kb.y as f64),
                )
            })
            .collect();
        let acc = frame_pair_accuracy(&pairs, &a, &b, &cam).unwrap();
        // The same count with poses passed explicitly.
        let explicit = matching_accuracy(
            &pairs,
            a.depth.as_ref().unwrap(),
            &cam,
            &a.gt_pose.unwrap(),
            &b.gt_pose.unwrap(),
            CORRECT_MATCH_PX,
        )
        .unwrap();
        assert_eq!(acc, explicit);
        eprintln!(
            "ORB 0-3: {} cross-checked matches, {}/{} judged correct ({:.1} %)",
            pairs.len(),
            acc.correct,
            acc.matches,
            100.0 * acc.accuracy
        );
        // Measured: 163/232 = 70.3 %; OpenCV 4.14's ORB + BFMatcher on this pair:
        // 168/235 = 71.5 %.
        assert!(acc.matches >= 150, "{acc:?}");
        assert!(acc.accuracy >= 0.6, "{acc:?}");
        let mut b_without_gt = b.clone();
        b_without_gt.gt_pose = None;
        assert!(frame_pair_accuracy(&pairs, &a, &b_without_gt, &cam).is_err());
    }

    #[test]
    fn orientation_makes_descriptors_survive_a_90_degree_rotation() {
        let seq = TumSequence::open(FIXTURE).unwrap();
        let img = fixture_gray(&seq, 0);
        let rot = image::imageops::rotate90(&img); // (x, y) -> (h - 1 - y, x)
        let cfg = OrbConfig::default();
        let f0 = detect_and_compute(&img, &cfg).unwrap();
        let f1 = detect_and_compute(&rot, &cfg).unwrap();
        let h = img.height() as f32;
        let matches = bf_match(&f0.descriptors, &f1.descriptors, true);
        let consistent = matches
            .iter()
            .filter(|m| {
                let (k0, k1) = (f0.keypoints[m.query], f1.keypoints[m.train]);
                let (ex, ey) = (h - 1.0 - k0.y, k0.x);
                (k1.x - ex).hypot(k1.y - ey) <= 2.0
            })
            .count();
        // The angles turn by 90 degrees with the image.
        let turned = matches
            .iter()
            .filter(|m| {
                let d = f1.keypoints[m.train].angle - f0.keypoints[m.query].angle - 90.0;
                d.rem_euclid(360.0).min((-d).rem_euclid(360.0)) < 5.0
            })
            .count();
        eprintln!(
            "rotated 90 deg: {} matches, {consistent} at the rotated position, {turned} with angle +90",
            matches.len()
        );
        assert!(matches.len() >= 350, "{} matches", matches.len());
        assert!(consistent as f64 >= 0.9 * matches.len() as f64);
        assert!(turned as f64 >= 0.9 * matches.len() as f64);
    }
}
