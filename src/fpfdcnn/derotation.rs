//! Roll-compensated matching of an image pair.
//!
//! FPFDCNN's descriptors are learned at the orientation the images were taken in, not steered
//! by a keypoint orientation as ORB's are (rotated BRIEF), so a camera that rolls about its
//! optical axis between two images costs it matches (lab/notes/fpfdcnn-results.md, *Roll: stages 15 and 18*). A roll
//! turns the whole image about the principal point, so it shows in the global image motion the
//! guided range matcher already estimates (`guided_range_match`): when that affine motion
//! rotates by at least [`DerotationConfig::min_deg`], image B is turned back by that angle
//! about its centre (the affine guide absorbs the shift between centre and principal point),
//! described again (one more network pass), and its keypoints, mapped back into B's pixels,
//! are matched in place of the first ones if they give at least as many matches. Keypoints
//! whose back-mapped position lies within the detector's border of B's edge are dropped: the
//! turned image's corners hold B's edge pixels smeared outwards, not recorded content. The
//! turned image keeps the detector's `top_k`, so a few keypoints fewer remain.

use super::homography::Homography;
use super::inference::{Features, FpfdcnnDetector};
use crate::error::{Error, Result};
use crate::range_matcher::{
    Affine, GuideConfig, RangeMatch, RangeMatcherConfig, guided_range_match,
};
use crate::raster::{GrayF32, gray_from_f32};
use image::GrayImage;

/// Default [`DerotationConfig::min_deg`] of `eval matching`: 5 degrees, adopted 2026-11-30 by
/// a rule fixed before the validation runs (lab/notes/fpfdcnn-results.md, *Roll-compensated matching*): on the
/// validation pairs rolled by 15 / 30 degrees it gave 34 % / 194 % more correct matches on
/// 7-Scenes and 39 % / 231 % more on fr1_rpy, and upright pairs were never turned.
pub const DEFAULT_DEROTATE_DEG: f64 = 5.0;

/// Settings of roll-compensated matching.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DerotationConfig {
    /// Turn image B back when the estimated image motion rotates by at least this many
    /// degrees (0: never).
    pub min_deg: f64,
}

impl DerotationConfig {
    /// Checks the angle (0 to 180 degrees).
    pub fn validate(&self) -> Result<()> {
        if !(0.0..=180.0).contains(&self.min_deg) {
            return Err(Error::msg(format!(
                "derotation: the least rotation must be in [0, 180] degrees, got {}",
                self.min_deg
            )));
        }
        Ok(())
    }
}

/// The rotation of an affine image motion's linear part, degrees (positive: clockwise on
/// screen, image y pointing down, as [`Homography::rotation`]); for `[a, b; c, d]` the angle
/// of its closest rotation, `atan2(c − b, a + d)`.
pub(crate) fn affine_rotation_deg(m: &Affine) -> f64 {
    (m[3] - m[1]).atan2(m[0] + m[4]).to_degrees()
}

/// One pair's FPFDCNN matches, with roll compensation.
#[derive(Debug, Clone)]
pub(crate) struct PairMatches {
    /// Range-matcher matches between A's keypoints and `features_b`.
    pub matches: Vec<RangeMatch>,
    /// B's keypoints the matches index, in B's pixels.
    pub features_b: Features,
    /// The angle image B was turned back by, when its matches were kept.
    pub derotated_deg: Option<f64>,
}

/// Matches `fa` (image A's features) to image `b` (`fb`: its features) with the guided range
/// matcher, turning B back by the estimated roll when it reaches `cfg.min_deg` (see the
/// module documentation).
pub(crate) fn match_with_derotation(
    detector: &FpfdcnnDetector,
    fa: &Features,
    b: &GrayImage,
    fb: Features,
    range: &RangeMatcherConfig,
    guide: &GuideConfig,
    cfg: &DerotationConfig,
) -> Result<PairMatches> {
    cfg.validate()?;
    let (matches, motion) = guided(fa, &fb, range, guide)?;
    let first = PairMatches {
        matches,
        features_b: fb,
        derotated_deg: None,
    };
    let Some(angle) = motion.map(|m| affine_rotation_deg(&m)) else {
        return Ok(first);
    };
    if cfg.min_deg <= 0.0 || angle.abs() < cfg.min_deg {
        return Ok(first);
    }
    let (w, h) = (b.width() as usize, b.height() as usize);
    // B's pixel p appears at back * p in the turned image, near where A saw it.
    let back = Homography::rotation(-angle, w, h);
    let turned = gray_from_f32(&back.warp(&GrayF32::from_gray(b), [0, 0], w, h));
    let found = detector.detect(&turned)?;
    // The detector's border is in pixels of the network's input.
    let border = detector.config.border as f32 / detector.config.input_scale.max(1e-3);
    let features_b = in_original(&found, &back, w, h, border);
    let (matches, _) = guided(fa, &features_b, range, guide)?;
    Ok(if matches.len() >= first.matches.len() {
        PairMatches {
            matches,
            features_b,
            derotated_deg: Some(angle),
        }
    } else {
        first
    })
}

fn guided(
    fa: &Features,
    fb: &Features,
    range: &RangeMatcherConfig,
    guide: &GuideConfig,
) -> Result<(Vec<RangeMatch>, Option<Affine>)> {
    guided_range_match(
        &fa.points,
        &fa.descriptors,
        &fb.points,
        &fb.descriptors,
        fa.dim,
        range,
        guide,
    )
}

/// The turned image's keypoints in the original image's pixels, those within `border` of its
/// edge (or outside it) dropped.
fn in_original(found: &Features, back: &Homography, w: usize, h: usize, border: f32) -> Features {
    let (w, h) = (w as f32, h as f32);
    let mut out = Features {
        dim: found.dim,
        ..Default::default()
    };
    for (k, p) in found.points.iter().enumerate() {
        let Some(q) = back.map_back(*p) else {
            continue;
        };
        let inside = q[0] >= border && q[1] >= border && q[0] < w - border && q[1] < h - border;
        if !inside {
            continue;
        }
        out.points.push(q);
        out.scores.push(found.scores[k]);
        out.descriptors
            .extend_from_slice(&found.descriptors[k * found.dim..(k + 1) * found.dim]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_of_an_affine_motion() {
        for deg in [-150.0f64, -30.0, 0.0, 12.5, 90.0, 170.0] {
            let (s, c) = deg.to_radians().sin_cos();
            // A rotation scaled by 1.1 with a shear-free linear part and a shift.
            let m = [1.1 * c, -1.1 * s, 5.0, 1.1 * s, 1.1 * c, -3.0];
            assert!((affine_rotation_deg(&m) - deg).abs() < 1e-9, "{deg}");
        }
        // The angle agrees with Homography::rotation's sense.
        let r = Homography::rotation(20.0, 64, 48).h;
        let m = [
            r[(0, 0)],
            r[(0, 1)],
            r[(0, 2)],
            r[(1, 0)],
            r[(1, 1)],
            r[(1, 2)],
        ];
        assert!((affine_rotation_deg(&m) - 20.0).abs() < 1e-9);
    }

    #[test]
    fn turned_keypoints_map_back_and_the_border_drops_the_corners() {
        let (w, h) = (64usize, 48usize);
        let back = Homography::rotation(-30.0, w, h);
        let orig = [[32.0f32, 24.0], [20.0, 30.0], [2.0, 2.0]];
        let found = Features {
            points: orig.iter().map(|p| back.map(*p).unwrap()).collect(),
            scores: vec![0.9, 0.8, 0.7],
            descriptors: vec![1.0, 0.0, 0.0, 1.0, 0.6, 0.8],
            dim: 2,
        };
        let f = in_original(&found, &back, w, h, 4.0);
        assert_eq!(
            f.points.len(),
            2,
            "the keypoint 2 px from the corner is dropped"
        );
        for (p, q) in f.points.iter().zip(&orig[..2]) {
            assert!((p[0] - q[0]).abs() < 1e-3 && (p[1] - q[1]).abs() < 1e-3);
        }
        assert_eq!(f.descriptors, vec![1.0, 0.0, 0.0, 1.0]);
        assert_eq!(f.scores, vec![0.9, 0.8]);
    }

    #[test]
    fn angles_outside_the_range_are_errors() {
        assert!(DerotationConfig { min_deg: -1.0 }.validate().is_err());
        assert!(DerotationConfig { min_deg: 181.0 }.validate().is_err());
        assert!(DerotationConfig { min_deg: f64::NAN }.validate().is_err());
        assert!(DerotationConfig { min_deg: 10.0 }.validate().is_ok());
    }
}
