//! The evaluation loop: the frame pairs, each condition's images, and both methods scored.

use super::draw::draw_matches;
use super::matching::{
    PixelMatches, corner_pixels, fpfdcnn_pair, orb_matches, pixels, refine, unroll, unroll_points,
};
use super::report::{describe_detector, describe_matcher};
use super::scoring::{Acc, PairGt, score};
use super::{MatchingEvalConfig, MatchingReport, MethodResult};
use crate::camera::Camera;
use crate::dataset::photometric::Degradation;
use crate::dataset::tum::{Frame, TumSequence};
use crate::error::{Error, Result};
use crate::features::harris::{HarrisConfig, harris_corners};
use crate::fpfdcnn::adaptation::{AdaptationConfig, adapted_corners};
use crate::fpfdcnn::homography::Homography;
use crate::fpfdcnn::inference::FpfdcnnDetector;
use crate::metrics::matching::{REPEATED_PX, Repeatability, repeatability};
use crate::raster::GrayF32;
use crate::raster::gray_from_f32;
use image::{GrayImage, RgbImage};
use rand::SeedableRng;

/// The frame pairs the evaluation uses.
pub fn select_pairs(n_frames: usize, cfg: &MatchingEvalConfig) -> Vec<(usize, usize)> {
    let last = cfg.last.unwrap_or(n_frames).min(n_frames);
    if last <= cfg.first + cfg.gap {
        return Vec::new();
    }
    let candidates: Vec<usize> = (cfg.first..last - cfg.gap).collect();
    let n = cfg.pairs.min(candidates.len()).max(1);
    (0..n)
        .map(|k| candidates[k * candidates.len() / n])
        .map(|i| (i, i + cfg.gap))
        .collect()
}

/// Runs the evaluation; `detector` is `None` for ORB only. `picture` receives
/// the matches of the middle pair for drawing (like the paper's Figs. 7-8).
pub fn evaluate(
    seq: &TumSequence,
    cam: &Camera,
    detector: Option<&FpfdcnnDetector>,
    cfg: &MatchingEvalConfig,
    mut progress: impl FnMut(usize, usize),
) -> Result<(MatchingReport, Option<RgbImage>)> {
    let pairs = checked_pairs(seq, cfg)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
    let conditions = if cfg.blur.is_some() { 2 } else { 1 };
    let mut orb: Vec<Acc> = (0..conditions).map(|_| Acc::default()).collect();
    let mut net: Vec<Acc> = (0..conditions).map(|_| Acc::default()).collect();
    let mut harris: Vec<Vec<Repeatability>> = vec![Vec::new(); conditions];
    let mut adapted: Vec<Vec<Repeatability>> = vec![Vec::new(); conditions];
    let harris_cfg = HarrisConfig {
        max_corners: cfg.orb.n_features,
        ..cfg.harris.clone()
    };
    let mut picture = None;
    let mut used = Vec::new();
    for (k, &(i, j)) in pairs.iter().enumerate() {
        progress(k, pairs.len());
        let (a, b) = (seq.load_frame(i)?, seq.load_frame(j)?);
        check_image_sizes(seq, cam, [(&a, i), (&b, j)])?;
        let (Some(pose_a), Some(pose_b)) = (a.gt_pose, b.gt_pose) else {
            continue;
        };
        if a.depth.as_ref().is_none_or(|d| d.valid_fraction() == 0.0) {
            continue;
        }
        used.push((i, j));
        let clean = (GrayF32::from_rgb(&a.rgb), GrayF32::from_rgb(&b.rgb));
        let pgt = PairGt {
            a: &a,
            b: &b,
            pose_a,
            pose_b,
            cam,
            pnp: &cfg.pnp,
        };
        // Images and matches are kept for the picture of the middle pair only.
        let picture_pair = k == pairs.len() / 2;
        let mut rows = Vec::new();
        for c in 0..conditions {
            let (ga, gb) = condition_images(c, cfg.blur.as_ref(), &clean, &mut rng);
            // The methods see B rolled (when asked); the targets' repeatability is B's as
            // recorded.
            let (w, h) = (gb.width() as usize, gb.height() as usize);
            let roll = (cfg.roll_deg != 0.0).then(|| Homography::rotation(cfg.roll_deg, w, h));
            let rolled = roll
                .as_ref()
                .map(|r| gray_from_f32(&r.warp(&GrayF32::from_gray(&gb), [0, 0], w, h)));
            let seen_b = rolled.as_ref().unwrap_or(&gb);
            if b.depth.is_some() {
                target_repeatability(
                    &ga,
                    &gb,
                    &pgt,
                    &harris_cfg,
                    cfg.adaptation.as_ref(),
                    &mut harris[c],
                    &mut adapted[c],
                )?;
            }
            let (m, errs) = orb_scored(&ga, seen_b, roll.as_ref(), cfg, &pgt, &mut orb[c])?;
            let blurred = if c == 0 { "" } else { ", blurred" };
            if picture_pair {
                rows.push((
                    ga.clone(),
                    seen_b.clone(),
                    m,
                    errs,
                    format!("ORB + BF{blurred}"),
                ));
            }
            if let Some(det) = detector {
                let (m, errs) =
                    fpfdcnn_scored(det, &ga, seen_b, roll.as_ref(), cfg, &pgt, &mut net[c])?;
                if picture_pair {
                    rows.push((
                        ga,
                        seen_b.clone(),
                        m,
                        errs,
                        format!("FPFDCNN + range{blurred}"),
                    ));
                }
            }
        }
        if picture_pair {
            picture = Some(draw_matches(&rows));
        }
    }
    progress(pairs.len(), pairs.len());
    if used.is_empty() {
        return Err(unscorable(seq, pairs.len()));
    }
    Ok((
        MatchingReport {
            sequence: seq.name(),
            pairs: used,
            gap: cfg.gap,
            blur: cfg.blur.map(|d| format!("{d:?}")),
            roll_deg: cfg.roll_deg,
            range_matcher: describe_matcher(cfg),
            fpfdcnn_detector: detector
                .map(|d| describe_detector(&d.config))
                .unwrap_or_default(),
            orb_bf: finish(orb),
            fpfdcnn_range: detector.map(|_| finish(net)),
            harris_repeatability: harris
                .iter()
                .map(|r| Repeatability::pool(r).rate())
                .collect(),
            adapted_repeatability: match cfg.adaptation {
                Some(_) => adapted
                    .iter()
                    .map(|r| Repeatability::pool(r).rate())
                    .collect(),
                None => Vec::new(),
            },
        },
        picture,
    ))
}

/// The error when none of the `n` selected pairs can be scored.
fn unscorable(seq: &TumSequence, n: usize) -> Error {
    Error::invalid(
        &seq.root,
        format!(
            "none of the {n} selected pairs can be scored: each needs a ground-truth pose \
             for both frames (groundtruth.txt within the association window of their \
             stamps) and a valid depth pixel in its first frame"
        ),
    )
}

/// One method's results from its accumulators (clear, then blurred when there are two).
fn finish(mut v: Vec<Acc>) -> MethodResult {
    let blurred = (v.len() > 1).then(|| v.pop().map(Acc::finish).unwrap_or_default());
    MethodResult {
        clean: v.pop().map(Acc::finish).unwrap_or_default(),
        blurred,
    }
}

/// The settings checked and the frame pairs selected, an error when there are none.
fn checked_pairs(seq: &TumSequence, cfg: &MatchingEvalConfig) -> Result<Vec<(usize, usize)>> {
    if !(-180.0..=180.0).contains(&cfg.roll_deg) {
        return Err(Error::msg(format!(
            "roll_deg must be in [-180, 180] degrees, got {}",
            cfg.roll_deg
        )));
    }
    cfg.derotation.validate()?;
    // Gap 0 would match each frame with itself (100 %, meaning nothing).
    if cfg.gap == 0 || cfg.pairs == 0 {
        return Err(Error::msg(format!(
            "gap ({}) and pairs ({}) must be at least 1",
            cfg.gap, cfg.pairs
        )));
    }
    let pairs = select_pairs(seq.len(), cfg);
    if pairs.is_empty() {
        let last = match cfg.last {
            Some(l) => format!("frame {} (--last)", l.min(seq.len())),
            None => "the end".into(),
        };
        return Err(Error::invalid(
            &seq.root,
            format!(
                "not enough frames for pairs {} apart between frame {} (--first) and {last}; \
                 the sequence has {} frames",
                cfg.gap,
                cfg.first,
                seq.len()
            ),
        ));
    }
    Ok(pairs)
}

/// An error when a frame's image is not the camera's size.
fn check_image_sizes(seq: &TumSequence, cam: &Camera, frames: [(&Frame, usize); 2]) -> Result<()> {
    for (f, index) in frames {
        if (f.rgb.width(), f.rgb.height()) != (cam.width, cam.height) {
            return Err(Error::invalid(
                &seq.frames[index].rgb_path,
                format!(
                    "image is {}x{} but the camera `{}` is {}x{}",
                    f.rgb.width(),
                    f.rgb.height(),
                    cam.name,
                    cam.width,
                    cam.height
                ),
            ));
        }
    }
    Ok(())
}

/// Images A and B of condition `c`: clear, or degraded by `blur` for condition 1.
fn condition_images(
    c: usize,
    blur: Option<&Degradation>,
    clean: &(GrayF32, GrayF32),
    rng: &mut rand_chacha::ChaCha8Rng,
) -> (GrayImage, GrayImage) {
    match (c, blur) {
        (1, Some(d)) => (
            gray_from_f32(&d.apply(&clean.0, rng)),
            gray_from_f32(&d.apply(&clean.1, rng)),
        ),
        _ => (gray_from_f32(&clean.0), gray_from_f32(&clean.1)),
    }
}

/// Repeatability of the targets' Harris corners on images A and B as recorded, into
/// `harris`, and of Harris corners after homographic adaptation into `adapted` when
/// `adaptation` is given.
fn target_repeatability(
    ga: &GrayImage,
    gb: &GrayImage,
    pgt: &PairGt<'_>,
    harris_cfg: &HarrisConfig,
    adaptation: Option<&AdaptationConfig>,
    harris: &mut Vec<Repeatability>,
    adapted: &mut Vec<Repeatability>,
) -> Result<()> {
    let (cam, a, b) = (pgt.cam, pgt.a, pgt.b);
    let (fa, fb) = (GrayF32::from_gray(ga), GrayF32::from_gray(gb));
    let (ca, cb) = (
        harris_corners(&fa, harris_cfg),
        harris_corners(&fb, harris_cfg),
    );
    let (ca, cb) = (corner_pixels(&ca), corner_pixels(&cb));
    harris.push(repeatability(cam, a, b, &ca, &cb, REPEATED_PX)?);
    if let Some(ad) = adaptation {
        let (ca, cb) = (
            adapted_corners(&fa, harris_cfg, ad),
            adapted_corners(&fb, harris_cfg, ad),
        );
        let (ca, cb) = (corner_pixels(&ca), corner_pixels(&cb));
        adapted.push(repeatability(cam, a, b, &ca, &cb, REPEATED_PX)?);
    }
    Ok(())
}

/// ORB's matches between A and the B it sees (`roll`: B rolled), refined when asked for
/// and scored into `acc`: the matches in the seen images' pixels and each one's error.
fn orb_scored(
    ga: &GrayImage,
    seen_b: &GrayImage,
    roll: Option<&Homography>,
    cfg: &MatchingEvalConfig,
    pgt: &PairGt<'_>,
    acc: &mut Acc,
) -> Result<(PixelMatches, Vec<Option<f64>>)> {
    let (mut m, [ka, kb]) = orb_matches(ga, seen_b, &cfg.orb)?;
    let orb_refine = cfg.refine.as_ref().filter(|_| cfg.refine_orb);
    acc.refined += refine(ga, seen_b, &mut m, 0.0, orb_refine)?;
    let errs = score(acc, &unroll(roll, &m), &[ka, unroll_points(roll, kb)], pgt)?;
    Ok((m, errs))
}

/// FPFDCNN's matches between A and the B it sees (`roll`: B rolled), roll-compensated and
/// refined when asked for and scored into `acc`: the matches in the seen images' pixels and
/// each one's error.
fn fpfdcnn_scored(
    det: &FpfdcnnDetector,
    ga: &GrayImage,
    seen_b: &GrayImage,
    roll: Option<&Homography>,
    cfg: &MatchingEvalConfig,
    pgt: &PairGt<'_>,
    acc: &mut Acc,
) -> Result<(PixelMatches, Vec<Option<f64>>)> {
    let (mut m, [fa, fb], turned) = fpfdcnn_pair(det, ga, seen_b, cfg)?;
    acc.derotated += usize::from(turned.is_some());
    let motion_roll = turned.unwrap_or(0.0);
    acc.refined += refine(ga, seen_b, &mut m, motion_roll, cfg.refine.as_ref())?;
    let errs = score(
        acc,
        &unroll(roll, &m),
        &[pixels(&fa), unroll_points(roll, pixels(&fb))],
        pgt,
    )?;
    Ok((m, errs))
}
