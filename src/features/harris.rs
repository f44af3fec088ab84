//! Harris corner detector (Harris & Stephens 1988): the corners the paper uses
//! as FPFDCNN's detector targets (section V-B).

use crate::raster::{GrayF32, MAX_BLUR_SIGMA};
use serde::{Deserialize, Serialize};

/// A detected keypoint at pixel `(x, y)` with its response.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Keypoint {
    /// Column, pixels.
    pub x: f32,
    /// Row, pixels.
    pub y: f32,
    /// Corner response (Harris response; higher is stronger).
    pub score: f32,
}

/// Harris detector settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HarrisConfig {
    /// Harris `k` in `det(M) - k trace(M)²`.
    pub k: f32,
    /// Standard deviation of the Gaussian window, pixels.
    pub sigma: f32,
    /// Keep responses above this fraction of the image's maximum response.
    pub relative_threshold: f32,
    /// Non-maximum suppression radius, pixels.
    pub nms_radius: usize,
    /// No corner closer than this to the border, pixels.
    pub border: usize,
    /// Keep the strongest `max_corners` (0: all).
    pub max_corners: usize,
}

impl HarrisConfig {
    /// Checks the settings; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if !(self.k.is_finite() && self.k > 0.0 && self.k < 0.25) {
            return Err(format!("harris k must be in (0, 0.25), got {}", self.k));
        }
        if !(self.sigma.is_finite() && self.sigma > 0.0 && self.sigma <= MAX_BLUR_SIGMA) {
            return Err(format!(
                "harris sigma must be in (0, {MAX_BLUR_SIGMA}] pixels, got {}",
                self.sigma
            ));
        }
        if !(0.0..1.0).contains(&self.relative_threshold) {
            return Err(format!(
                "harris relative_threshold must be in [0, 1), got {}",
                self.relative_threshold
            ));
        }
        if self.nms_radius > 64 || self.border > 1024 || self.max_corners > 100_000 {
            return Err(format!(
                "harris nms_radius ({}) must be at most 64, border ({}) at most 1024 and \
                 max_corners ({}) at most 100000",
                self.nms_radius, self.border, self.max_corners
            ));
        }
        Ok(())
    }
}

impl Default for HarrisConfig {
    fn default() -> Self {
        HarrisConfig {
            k: 0.04,
            sigma: 1.5,
            relative_threshold: 0.01,
            nms_radius: 4,
            border: 8,
            max_corners: 500,
        }
    }
}

/// Harris response map.
pub(crate) fn harris_response(img: &GrayF32, cfg: &HarrisConfig) -> GrayF32 {
    let (gx, gy) = img.sobel();
    let n = gx.data.len();
    let mut xx = GrayF32::new(img.width, img.height);
    let mut yy = xx.clone();
    let mut xy = xx.clone();
    for i in 0..n {
        let (a, b) = (gx.data[i], gy.data[i]);
        xx.data[i] = a * a;
        yy.data[i] = b * b;
        xy.data[i] = a * b;
    }
    let (xx, yy, xy) = (
        xx.gaussian_blur(cfg.sigma),
        yy.gaussian_blur(cfg.sigma),
        xy.gaussian_blur(cfg.sigma),
    );
    let mut r = GrayF32::new(img.width, img.height);
    for i in 0..n {
        let det = xx.data[i] * yy.data[i] - xy.data[i] * xy.data[i];
        let tr = xx.data[i] + yy.data[i];
        r.data[i] = det - cfg.k * tr * tr;
    }
    r
}

/// Harris corners: thresholded, non-maximum suppressed, strongest first.
pub fn harris_corners(img: &GrayF32, cfg: &HarrisConfig) -> Vec<Keypoint> {
    corners_of_response(&harris_response(img, cfg), cfg)
}

/// The corners of a response map as [`harris_corners`] selects them: above
/// `relative_threshold` of the maximum, local maxima within `nms_radius`, away from the
/// border, the strongest `max_corners`.
pub(crate) fn corners_of_response(r: &GrayF32, cfg: &HarrisConfig) -> Vec<Keypoint> {
    let max = r.data.iter().copied().fold(0.0f32, f32::max);
    if max <= 0.0 {
        return Vec::new();
    }
    let thr = max * cfg.relative_threshold;
    let (w, h, rad, b) = (r.width, r.height, cfg.nms_radius as isize, cfg.border);
    let mut out = Vec::new();
    for y in b..h.saturating_sub(b) {
        for x in b..w.saturating_sub(b) {
            let v = r.get(x, y);
            if v <= thr {
                continue;
            }
            let mut is_max = true;
            'nms: for dy in -rad..=rad {
                for dx in -rad..=rad {
                    if dx == 0 && dy == 0 {
                        continue;
                    }
                    let o = r.get_clamped(x as isize + dx, y as isize + dy);
                    // Ties are broken towards the first pixel in raster order.
                    if o > v || (o == v && (dy < 0 || (dy == 0 && dx < 0))) {
                        is_max = false;
                        break 'nms;
                    }
                }
            }
            if is_max {
                out.push(Keypoint {
                    x: x as f32,
                    y: y as f32,
                    score: v,
                });
            }
        }
    }
    out.sort_by(|a, b| b.score.total_cmp(&a.score));
    if cfg.max_corners > 0 {
        out.truncate(cfg.max_corners);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_the_corners_of_a_square() {
        let mut img = GrayF32::new(64, 64);
        for y in 20..44 {
            for x in 20..44 {
                img.data[y * 64 + x] = 1.0;
            }
        }
        let c = harris_corners(&img, &HarrisConfig::default());
        assert_eq!(c.len(), 4, "{c:?}");
        for k in &c {
            let near = |v: f32| (v - 19.5).abs() <= 1.5 || (v - 43.5).abs() <= 1.5;
            assert!(near(k.x) && near(k.y), "{k:?}");
        }
    }
}
