//! Homographic adaptation of detector targets (SuperPoint, DeTone et al., CVPRW 2018,
//! section 5): a frame's corner response averaged over random homographies of the frame,
//! each warp's response carried back to the frame, keeps the corners that survive changes
//! of rotation, scale and perspective. FPFDCNN's detector is trained on single-scale Harris
//! corners (eqs 5-7), which `eval matching` measures as no more repeatable than the
//! network itself; adapted corners are the candidate targets of a more repeatable one.

use super::homography::{Homography, HomographyConfig};
use crate::features::harris::{HarrisConfig, Keypoint, corners_of_response, harris_response};
use crate::raster::GrayF32;
use rand::SeedableRng;
use serde::{Deserialize, Serialize};

/// Largest number of warps (each costs one Harris response of the whole frame).
pub(crate) const MAX_WARPS: usize = 256;

/// How many warps, and their range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AdaptationConfig {
    /// Random homographies besides the identity (0: the frame's own response).
    pub warps: usize,
    /// Range of the random homographies.
    pub homography: HomographyConfig,
    /// Seed of the random generator drawing the homographies (same seed, same corners).
    pub seed: u64,
}

impl Default for AdaptationConfig {
    fn default() -> Self {
        AdaptationConfig {
            warps: 32,
            homography: HomographyConfig {
                max_rotation_deg: 25.0,
                scale: [0.7, 1.4],
                max_translation: 0.1,
                max_perspective: 0.3,
            },
            seed: 0,
        }
    }
}

impl AdaptationConfig {
    /// Checks the settings; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        if self.warps > MAX_WARPS {
            return Err(format!(
                "adaptation warps must be at most {MAX_WARPS}, got {}",
                self.warps
            ));
        }
        self.homography
            .validate()
            .map_err(|m| format!("adaptation.homography: {m}"))
    }
}

/// Each pixel's Harris response, normalised by the largest response of its view, averaged
/// over the identity and `cfg.warps` random homographies of the frame (over the views in
/// which the pixel is inside the warped image).
pub(crate) fn adapted_response(
    img: &GrayF32,
    harris: &HarrisConfig,
    cfg: &AdaptationConfig,
) -> GrayF32 {
    let (w, h) = (img.width, img.height);
    let normalised = |view: &GrayF32| {
        let mut r = harris_response(view, harris);
        let top = r.data.iter().copied().fold(0.0f32, f32::max);
        if top > 0.0 {
            r.data.iter_mut().for_each(|v| *v /= top);
        }
        r
    };
    let mut sum = normalised(img);
    let mut count = vec![1.0f32; w * h];
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(cfg.seed);
    for _ in 0..cfg.warps {
        let hm = Homography::random(&cfg.homography, w, h, &mut rng);
        let r = normalised(&hm.warp(img, [0, 0], w, h));
        for y in 0..h {
            for x in 0..w {
                let Some([u, v]) = hm.map([x as f32, y as f32]) else {
                    continue;
                };
                if u >= 0.0 && v >= 0.0 && u <= (w - 1) as f32 && v <= (h - 1) as f32 {
                    let i = y * w + x;
                    sum.data[i] += r.sample(u as f64, v as f64);
                    count[i] += 1.0;
                }
            }
        }
    }
    for (s, c) in sum.data.iter_mut().zip(&count) {
        *s /= c;
    }
    sum
}

/// The corners of [`adapted_response`], selected as Harris corners are.
pub(crate) fn adapted_corners(
    img: &GrayF32,
    harris: &HarrisConfig,
    cfg: &AdaptationConfig,
) -> Vec<Keypoint> {
    corners_of_response(&adapted_response(img, harris, cfg), harris)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::harris::harris_corners;

    /// A bright square on a dark frame with a faint ripple.
    fn square() -> GrayF32 {
        let mut img = GrayF32::new(96, 80);
        for y in 0..80 {
            for x in 0..96 {
                let inside = (30..62).contains(&x) && (24..56).contains(&y);
                img.data[y * 96 + x] =
                    if inside { 0.8 } else { 0.2 } + 0.01 * ((x as f32) * 0.7).sin();
            }
        }
        img
    }

    #[test]
    fn without_warps_it_is_harris() {
        let img = square();
        let harris = HarrisConfig {
            max_corners: 8,
            ..HarrisConfig::default()
        };
        let cfg = AdaptationConfig {
            warps: 0,
            ..AdaptationConfig::default()
        };
        let plain: Vec<(f32, f32)> = harris_corners(&img, &harris)
            .iter()
            .map(|k| (k.x, k.y))
            .collect();
        let adapted: Vec<(f32, f32)> = adapted_corners(&img, &harris, &cfg)
            .iter()
            .map(|k| (k.x, k.y))
            .collect();
        assert_eq!(plain, adapted);
    }

    #[test]
    fn warped_views_keep_the_square_corners() {
        let img = square();
        let harris = HarrisConfig {
            max_corners: 4,
            ..HarrisConfig::default()
        };
        let cfg = AdaptationConfig {
            warps: 12,
            ..AdaptationConfig::default()
        };
        let corners = adapted_corners(&img, &harris, &cfg);
        assert_eq!(corners.len(), 4);
        for k in &corners {
            // Every one within 3 px of a corner of the square.
            let near = [(30.0, 24.0), (61.0, 24.0), (30.0, 55.0), (61.0, 55.0)]
                .iter()
                .any(|&(x, y): &(f32, f32)| (k.x - x).abs() <= 3.0 && (k.y - y).abs() <= 3.0);
            assert!(near, "{k:?}");
        }
        // Same seed, same corners.
        assert_eq!(corners, adapted_corners(&img, &harris, &cfg));
        let mut bad = cfg.clone();
        bad.warps = MAX_WARPS + 1;
        assert!(bad.validate().is_err());
        assert!(cfg.validate().is_ok());
    }
}
