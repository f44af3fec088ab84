//! Each method's matches on one image pair: ORB + brute force and FPFDCNN + the range matcher.

use super::MatchingEvalConfig;
use crate::error::{Error, Result};
use crate::features::bf_matcher::matched_pixels;
use crate::features::harris::Keypoint;
use crate::features::match_refine::{MatchRefineConfig, refine_matches};
use crate::features::orb::{OrbConfig, detect_and_compute};
use crate::fpfdcnn::derotation::match_with_derotation;
use crate::fpfdcnn::homography::Homography;
use crate::fpfdcnn::inference::{Features, FpfdcnnDetector};
use crate::range_matcher::{
    GuideConfig, RangeMatch, RangeMatcherConfig, guided_range_match, range_match,
};
use crate::raster::GrayF32;
use image::GrayImage;
use nalgebra::Point2;

/// Matches of one method on one image pair: `(pixel in A, pixel in B)`.
pub type PixelMatches = Vec<(Point2<f64>, Point2<f64>)>;

/// ORB keypoints of both images matched by cross-checked brute force (Hamming), and the
/// keypoints of the two.
pub fn orb_matches(
    a: &GrayImage,
    b: &GrayImage,
    cfg: &OrbConfig,
) -> Result<(PixelMatches, [Vec<Point2<f64>>; 2])> {
    let fa = detect_and_compute(a, cfg)?;
    let fb = detect_and_compute(b, cfg)?;
    let m = matched_pixels(&fa, &fb);
    let pixels = |f: &crate::features::orb::OrbFeatures| {
        f.keypoints
            .iter()
            .map(|k| Point2::new(k.x as f64, k.y as f64))
            .collect()
    };
    Ok((m, [pixels(&fa), pixels(&fb)]))
}

/// Pixels of corners.
pub(super) fn corner_pixels(k: &[Keypoint]) -> Vec<Point2<f64>> {
    k.iter()
        .map(|k| Point2::new(k.x as f64, k.y as f64))
        .collect()
}

/// Keypoint pixels of FPFDCNN features.
pub(super) fn pixels(f: &Features) -> Vec<Point2<f64>> {
    f.points
        .iter()
        .map(|p| Point2::new(p[0] as f64, p[1] as f64))
        .collect()
}

/// FPFDCNN keypoints of both images matched by the range matcher (eq 8), its windows
/// centred by a global motion estimate when `guide` is given.
pub fn fpfdcnn_matches(
    fa: &Features,
    fb: &Features,
    cfg: &RangeMatcherConfig,
    guide: Option<&GuideConfig>,
) -> Result<PixelMatches> {
    let (p1, d1, p2, d2) = (&fa.points, &fa.descriptors, &fb.points, &fb.descriptors);
    let m = match guide {
        Some(g) => guided_range_match(p1, d1, p2, d2, fa.dim, cfg, g)?.0,
        None => range_match(p1, d1, p2, d2, fa.dim, cfg)?,
    };
    Ok(pixel_matches(fa, fb, &m))
}

/// Range matches between `fa` and `fb` as pixel pairs.
fn pixel_matches(fa: &Features, fb: &Features, matches: &[RangeMatch]) -> PixelMatches {
    matches
        .iter()
        .map(|m| {
            let (pa, pb) = (fa.points[m.i], fb.points[m.j]);
            (
                Point2::new(pa[0] as f64, pa[1] as f64),
                Point2::new(pb[0] as f64, pb[1] as f64),
            )
        })
        .collect()
}

/// FPFDCNN's matches on one pair, roll-compensated when `cfg` asks for it, with B's
/// keypoints and whether B was turned back.
pub(super) fn fpfdcnn_pair(
    det: &FpfdcnnDetector,
    a: &GrayImage,
    b: &GrayImage,
    cfg: &MatchingEvalConfig,
) -> Result<(PixelMatches, [Features; 2], Option<f64>)> {
    let (fa, fb) = (det.detect(a)?, det.detect(b)?);
    let guide = cfg.guide.as_ref().filter(|_| cfg.derotation.min_deg > 0.0);
    let Some(guide) = guide else {
        let m = fpfdcnn_matches(&fa, &fb, &cfg.range, cfg.guide.as_ref())?;
        return Ok((m, [fa, fb], None));
    };
    let r = match_with_derotation(det, &fa, b, fb, &cfg.range, guide, &cfg.derotation)?;
    let m = pixel_matches(&fa, &r.features_b, &r.matches);
    Ok((m, [fa, r.features_b], r.derotated_deg))
}

/// `matches` refined by patch correlation when `refine` asks for it (`roll_deg`: the image
/// motion's roll); returns how many moved.
pub(super) fn refine(
    a: &GrayImage,
    b: &GrayImage,
    matches: &mut PixelMatches,
    roll_deg: f64,
    refine: Option<&MatchRefineConfig>,
) -> Result<usize> {
    let Some(cfg) = refine else { return Ok(0) };
    let (a, b) = (GrayF32::from_gray(a), GrayF32::from_gray(b));
    refine_matches(&a, &b, matches, roll_deg, cfg).map_err(Error::msg)
}

/// Pixels of a rolled image B (`roll`: B's pixels to the rolled image's) back in B.
pub(super) fn unroll_points(
    roll: Option<&Homography>,
    points: Vec<Point2<f64>>,
) -> Vec<Point2<f64>> {
    let Some(r) = roll else { return points };
    points
        .into_iter()
        .map(|p| {
            let q = r
                .map_back([p.x as f32, p.y as f32])
                .unwrap_or([f32::NAN; 2]);
            Point2::new(f64::from(q[0]), f64::from(q[1]))
        })
        .collect()
}

/// Matches into a rolled image B with their B side back in B's pixels.
pub(super) fn unroll(roll: Option<&Homography>, matches: &PixelMatches) -> PixelMatches {
    let (a, b): (Vec<_>, Vec<_>) = matches.iter().copied().unzip();
    a.into_iter().zip(unroll_points(roll, b)).collect()
}
