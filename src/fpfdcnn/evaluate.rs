//! The paper's Tables 6 and 7 on a TUM-layout sequence: matching accuracy of
//! ORB + brute-force matching and of FPFDCNN + the range matcher on clear and on
//! motion-blurred frame pairs, and errT / errR (eqs 11-14) of the relative pose
//! that PnP + RANSAC (eqs 9-10) recovers from each method's matches.
//!
//! A match is correct when the matched keypoint in B lies within 5 px of the
//! ground-truth projection of its A keypoint (A's depth, the camera with its
//! distortion, ground-truth poses interpolated at the image timestamps); matches
//! whose A keypoint has no depth are not counted.

use super::adaptation::adapted_corners;
use super::derotation::{DerotationConfig, match_with_derotation};
use super::homography::Homography;
use super::inference::{Features, FpfdcnnDetector};
use crate::camera::Camera;
use crate::dataset::fp_pairs::FpConfig;
use crate::dataset::photometric::Degradation;
use crate::dataset::tum::{Frame, TumSequence};
use crate::error::{Error, Result};
use crate::features::bf_matcher::matched_pixels;
use crate::features::harris::{HarrisConfig, Keypoint, harris_corners};
use crate::features::match_refine::{MatchRefineConfig, refine_matches};
use crate::features::orb::{OrbConfig, detect_and_compute};
use crate::geometry::Pose;
use crate::metrics::matching::{
    CORRECT_MATCH_PX, MatchingAccuracy, REPEATED_PX, Repeatability, common_offset,
    match_error_vectors, repeatability, within_offset,
};
use crate::metrics::{PoseError, PoseErrorSegment};
use crate::pnp::{PnpConfig, solve_pnp_ransac};
use crate::range_matcher::{
    GuideConfig, RangeMatch, RangeMatcherConfig, guided_range_match, range_match,
};
use crate::raster::GrayF32;
use crate::raster::gray_from_f32;
use image::{GrayImage, Rgb, RgbImage};
use nalgebra::Point2;
use rand::SeedableRng;
use serde::{Deserialize, Serialize};

/// What to evaluate.
#[derive(Debug, Clone)]
pub struct MatchingEvalConfig {
    /// Frame gap of the pairs `(i, i + gap)`.
    pub gap: usize,
    /// Number of pairs, spread evenly over the allowed frames.
    pub pairs: usize,
    /// Only frames `first..last` (exclusive) are used.
    pub first: usize,
    /// End of the frame range, exclusive (`None`: the sequence's end).
    pub last: Option<usize>,
    /// Degradation of both images for the "blurred" half (e.g. `motion:9`).
    pub blur: Option<Degradation>,
    /// Image B rotated by this many degrees about its centre before either method sees it
    /// (a roll about the optical axis on top of the pair's own motion); matches are mapped
    /// back to B's pixels before they are scored. 0: the images as recorded.
    pub roll_deg: f64,
    /// ORB detector and descriptor settings (the baseline).
    pub orb: OrbConfig,
    /// The range matcher's settings (FPFDCNN's matching).
    pub range: RangeMatcherConfig,
    /// Centre the range matcher's windows by a global motion estimate
    /// ([`crate::range_matcher::guided_range_match`]); `None`: at the keypoint (the paper).
    pub guide: Option<GuideConfig>,
    /// Roll-compensated FPFDCNN matching ([`super::derotation`]; needs `guide`): image B
    /// turned back by the estimated roll when it reaches `min_deg`.
    pub derotation: DerotationConfig,
    /// PnP + RANSAC settings of the relative pose (eqs 9-10).
    pub pnp: PnpConfig,
    /// Also measure the repeatability of Harris corners after homographic adaptation
    /// ([`super::adaptation`]: a pixel is averaged over the views it lies in, and a view's
    /// clamped borders reach only pixels near the frame's edge, inside the Harris border).
    pub adaptation: Option<super::adaptation::AdaptationConfig>,
    /// Harris settings of the targets' repeatability (the FP pairs' by default; as many
    /// corners as ORB keypoints are kept).
    pub harris: HarrisConfig,
    /// FPFDCNN's matches refined by patch correlation
    /// ([`crate::features::match_refine`]); `None`: the keypoints as detected.
    pub refine: Option<MatchRefineConfig>,
    /// ORB's matches refined the same way (to see what refinement gives a baseline).
    pub refine_orb: bool,
}

impl Default for MatchingEvalConfig {
    fn default() -> Self {
        MatchingEvalConfig {
            gap: 5,
            pairs: 100,
            first: 0,
            last: None,
            blur: None,
            roll_deg: 0.0,
            orb: OrbConfig::default(),
            range: RangeMatcherConfig::default(),
            guide: None,
            derotation: DerotationConfig {
                min_deg: super::derotation::DEFAULT_DEROTATE_DEG,
            },
            pnp: PnpConfig::default(),
            adaptation: None,
            harris: FpConfig::default().harris,
            refine: Some(MatchRefineConfig::default()),
            refine_orb: false,
        }
    }
}

/// One method's matches on one frame pair.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PairResult {
    /// Frame indices of the pair.
    pub a: usize,
    /// Frame index of B.
    pub b: usize,
    /// Correct (within 5 px) and judged matches.
    pub correct: usize,
    /// Judged matches: those whose A keypoint has depth.
    pub matches: usize,
    /// Matches within 5 px of the pair's common offset.
    pub within_offset: usize,
    /// The common offset, ground-truth projection minus matched point, pixels (`None`:
    /// no judged match).
    pub offset_px: Option<[f64; 2]>,
}

/// Results of one method on one condition (clear or blurred).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct ConditionResult {
    /// Correct matches (within 5 px), over all pairs.
    pub correct: usize,
    /// Judged matches, over all pairs.
    pub matches: usize,
    /// Matching accuracy: `correct / matches`.
    pub accuracy: f64,
    /// errT (%) and errR (deg/m) pooled over the pairs whose PnP succeeded.
    pub err_t_percent: Option<f64>,
    /// errR (deg/m), pooled over the pairs whose PnP succeeded.
    pub err_r_deg_per_m: Option<f64>,
    /// Mean rotation (deg) and translation (m) error of the PnP relative pose.
    pub mean_rot_error_deg: Option<f64>,
    /// Mean translation error of the PnP relative pose, metres.
    pub mean_trans_error_m: Option<f64>,
    /// Pairs whose PnP + RANSAC found no pose.
    pub pnp_failures: usize,
    /// Mean keypoints per image.
    pub keypoints: f64,
    /// Share of judged matches within 2, 5, 10 and 20 px of the ground-truth
    /// projection (5 px is the accuracy above): tells localisation errors from
    /// wrong partners.
    #[serde(default)]
    pub within_px: Vec<(f64, f64)>,
    /// Share of judged matches within 5 px of their pair's common offset
    /// ([`crate::metrics::matching::within_common_offset`]): the accuracy with each pair's
    /// shared ground-truth error taken out (a diagnostic beside `accuracy`).
    #[serde(default)]
    pub offset_removed_accuracy: f64,
    /// Each pair's figures, in the order of [`MatchingReport::pairs`].
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pairs: Vec<PairResult>,
    /// Keypoint repeatability within 3 px, both directions pooled
    /// ([`crate::metrics::matching::Repeatability`]): how many keypoints the other image
    /// detects again, whatever their descriptors.
    #[serde(default)]
    pub repeatability: f64,
    /// Correct matches per keypoint visible in the other image (SuperPoint's matching
    /// score: detector, descriptor and matcher together).
    #[serde(default)]
    pub matching_score: f64,
    /// Pairs whose second image was turned back by its estimated roll
    /// ([`MatchingEvalConfig::derotation`]).
    #[serde(default, skip_serializing_if = "is_zero_count")]
    pub derotated_pairs: usize,
    /// Matches whose second point moved by patch correlation ([`MatchingEvalConfig::refine`]),
    /// judged or not (a match without depth at its first point is not judged).
    #[serde(default, skip_serializing_if = "is_zero_count")]
    pub refined_matches: usize,
}

/// One method's results.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct MethodResult {
    /// Results on the clear frame pairs.
    pub clean: ConditionResult,
    /// Results on the degraded frame pairs (`None` without `blur`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub blurred: Option<ConditionResult>,
}

/// The whole evaluation.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct MatchingReport {
    /// The sequence's name.
    pub sequence: String,
    /// Frame indices `(a, b)` of the pairs scored.
    pub pairs: Vec<(usize, usize)>,
    /// Frame gap of the pairs.
    pub gap: usize,
    /// The degradation of the blurred condition, in words (`None`: clear frames only).
    pub blur: Option<String>,
    /// Degrees image B was rolled by ([`MatchingEvalConfig::roll_deg`]).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub roll_deg: f64,
    /// The range matcher's settings, in words.
    #[serde(default)]
    pub range_matcher: String,
    /// FPFDCNN's keypoint selection, in words (empty without FPFDCNN).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub fpfdcnn_detector: String,
    /// ORB + brute-force matching.
    pub orb_bf: MethodResult,
    /// FPFDCNN + the range matcher (`None` without a FPFDCNN model).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fpfdcnn_range: Option<MethodResult>,
    /// Repeatability (3 px) of the strongest Harris corners, as many as each method's
    /// keypoints, with the FP pairs' Harris settings: the corners FPFDCNN's detector is
    /// trained to reproduce (clear, then blurred when evaluated).
    #[serde(default)]
    pub harris_repeatability: Vec<f64>,
    /// The same for Harris corners after homographic adaptation, when asked for.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub adapted_repeatability: Vec<f64>,
}

#[derive(Default)]
struct Acc {
    segs: Vec<PoseErrorSegment>,
    rot: Vec<f64>,
    trans: Vec<f64>,
    failures: usize,
    keypoints: usize,
    images: usize,
    errors: Vec<f64>,
    pairs: Vec<PairResult>,
    repeat: Vec<Repeatability>,
    derotated: usize,
    refined: usize,
}

impl Acc {
    fn finish(self) -> ConditionResult {
        let pooled = MatchingAccuracy::new(
            self.pairs.iter().map(|p| p.correct).sum(),
            self.pairs.iter().map(|p| p.matches).sum(),
        );
        let pose = PoseError::pool(&self.segs).ok();
        let mean = |v: &[f64]| (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64);
        let repeat = Repeatability::pool(&self.repeat);
        ConditionResult {
            repeatability: repeat.rate(),
            // Visible keypoints counted in both directions: per image, half of them.
            matching_score: pooled.correct as f64 / (repeat.visible as f64 / 2.0).max(1.0),
            correct: pooled.correct,
            matches: pooled.matches,
            accuracy: pooled.accuracy,
            err_t_percent: pose.map(|p| p.err_t_percent),
            err_r_deg_per_m: pose.map(|p| p.err_r_deg_per_m),
            mean_rot_error_deg: mean(&self.rot),
            mean_trans_error_m: mean(&self.trans),
            pnp_failures: self.failures,
            derotated_pairs: self.derotated,
            refined_matches: self.refined,
            keypoints: self.keypoints as f64 / self.images.max(1) as f64,
            offset_removed_accuracy: self.pairs.iter().map(|p| p.within_offset).sum::<usize>()
                as f64
                / pooled.matches.max(1) as f64,
            within_px: [2.0, 5.0, 10.0, 20.0]
                .iter()
                .map(|&t| {
                    let n = self.errors.iter().filter(|e| **e <= t).count();
                    (t, n as f64 / self.errors.len().max(1) as f64)
                })
                .collect(),
            pairs: self.pairs,
        }
    }
}

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
fn corner_pixels(k: &[Keypoint]) -> Vec<Point2<f64>> {
    k.iter()
        .map(|k| Point2::new(k.x as f64, k.y as f64))
        .collect()
}

/// Keypoint pixels of FPFDCNN features.
fn pixels(f: &Features) -> Vec<Point2<f64>> {
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

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn is_zero_count(v: &usize) -> bool {
    *v == 0
}

/// FPFDCNN's matches on one pair, roll-compensated when `cfg` asks for it, with B's
/// keypoints and whether B was turned back.
fn fpfdcnn_pair(
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
fn refine(
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
fn unroll_points(roll: Option<&Homography>, points: Vec<Point2<f64>>) -> Vec<Point2<f64>> {
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
fn unroll(roll: Option<&Homography>, matches: &PixelMatches) -> PixelMatches {
    let (a, b): (Vec<_>, Vec<_>) = matches.iter().copied().unzip();
    a.into_iter().zip(unroll_points(roll, b)).collect()
}

/// A frame pair with its ground truth, for scoring matches.
struct PairGt<'a> {
    a: &'a Frame,
    b: &'a Frame,
    pose_a: Pose,
    pose_b: Pose,
    cam: &'a Camera,
    pnp: &'a PnpConfig,
}

/// Scores one method's matches on one pair into `acc`; returns each match's error against
/// the ground-truth projection (`None`: no depth at the frame-A keypoint).
fn score(
    acc: &mut Acc,
    matches: &PixelMatches,
    [points_a, points_b]: &[Vec<Point2<f64>>; 2],
    gt: &PairGt<'_>,
) -> Result<Vec<Option<f64>>> {
    let PairGt {
        a,
        b,
        pose_a,
        pose_b,
        cam,
        pnp,
    } = gt;
    let (pose_a, pose_b, cam) = (pose_a, pose_b, *cam);
    let depth = a
        .depth
        .as_ref()
        .ok_or_else(|| Error::msg(format!("frame {} has no depth", a.index)))?;
    let vectors = match_error_vectors(matches, depth, cam, pose_a, pose_b)?;
    let errors: Vec<Option<f64>> = vectors.iter().map(|e| e.map(|v| v.norm())).collect();
    let judged: Vec<f64> = errors.iter().flatten().copied().collect();
    let judged_vectors: Vec<_> = vectors.into_iter().flatten().collect();
    let accuracy = MatchingAccuracy::new(
        judged.iter().filter(|e| **e <= CORRECT_MATCH_PX).count(),
        judged.len(),
    );
    let offset = common_offset(&judged_vectors);
    acc.pairs.push(PairResult {
        a: a.index,
        b: b.index,
        correct: accuracy.correct,
        matches: accuracy.matches,
        within_offset: offset.map_or(0, |o| within_offset(&judged_vectors, o, CORRECT_MATCH_PX)),
        offset_px: offset.map(|o| [o.x, o.y]),
    });
    acc.errors.extend(&judged);
    acc.keypoints += points_a.len() + points_b.len();
    acc.images += 2;
    if b.depth.is_some() {
        acc.repeat
            .push(repeatability(cam, a, b, points_a, points_b, REPEATED_PX)?);
    }
    let (mut pts, mut px) = (Vec::new(), Vec::new());
    for (pa, pb) in matches {
        if let Some(z) = depth.at(pa.x, pa.y) {
            pts.push(cam.back_project(pa, z as f64));
            px.push(*pb);
        }
    }
    // Camera A to camera B.
    let gt = pose_b.inverse() * pose_a;
    match solve_pnp_ransac(&pts, &px, cam, None, pnp) {
        Ok(r) => {
            acc.rot
                .push((r.pose.inverse() * gt).rotation.angle().to_degrees());
            acc.trans
                .push((r.pose.translation.vector - gt.translation.vector).norm());
            acc.segs.push(PoseErrorSegment::new(
                &gt.inverse(),
                &r.pose.inverse(),
                None,
            ));
        }
        Err(_) => acc.failures += 1,
    }
    Ok(errors)
}

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
        for (f, index) in [(&a, i), (&b, j)] {
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
            let (ga, gb) = match (c, &cfg.blur) {
                (1, Some(d)) => (
                    gray_from_f32(&d.apply(&clean.0, &mut rng)),
                    gray_from_f32(&d.apply(&clean.1, &mut rng)),
                ),
                _ => (gray_from_f32(&clean.0), gray_from_f32(&clean.1)),
            };
            // The methods see B rolled (when asked); the targets' repeatability is B's as
            // recorded.
            let (w, h) = (gb.width() as usize, gb.height() as usize);
            let roll = (cfg.roll_deg != 0.0).then(|| Homography::rotation(cfg.roll_deg, w, h));
            let rolled = roll
                .as_ref()
                .map(|r| gray_from_f32(&r.warp(&GrayF32::from_gray(&gb), [0, 0], w, h)));
            let seen_b = rolled.as_ref().unwrap_or(&gb);
            if b.depth.is_some() {
                let (fa, fb) = (GrayF32::from_gray(&ga), GrayF32::from_gray(&gb));
                let (ca, cb) = (
                    harris_corners(&fa, &harris_cfg),
                    harris_corners(&fb, &harris_cfg),
                );
                let (ca, cb) = (corner_pixels(&ca), corner_pixels(&cb));
                harris[c].push(repeatability(cam, &a, &b, &ca, &cb, REPEATED_PX)?);
                if let Some(ad) = &cfg.adaptation {
                    let (ca, cb) = (
                        adapted_corners(&fa, &harris_cfg, ad),
                        adapted_corners(&fb, &harris_cfg, ad),
                    );
                    let (ca, cb) = (corner_pixels(&ca), corner_pixels(&cb));
                    adapted[c].push(repeatability(cam, &a, &b, &ca, &cb, REPEATED_PX)?);
                }
            }
            let (mut m, [ka, kb]) = orb_matches(&ga, seen_b, &cfg.orb)?;
            let orb_refine = cfg.refine.as_ref().filter(|_| cfg.refine_orb);
            orb[c].refined += refine(&ga, seen_b, &mut m, 0.0, orb_refine)?;
            let errs = score(
                &mut orb[c],
                &unroll(roll.as_ref(), &m),
                &[ka, unroll_points(roll.as_ref(), kb)],
                &pgt,
            )?;
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
                let (mut m, [fa, fb], turned) = fpfdcnn_pair(det, &ga, seen_b, cfg)?;
                net[c].derotated += usize::from(turned.is_some());
                let motion_roll = turned.unwrap_or(0.0);
                net[c].refined += refine(&ga, seen_b, &mut m, motion_roll, cfg.refine.as_ref())?;
                let errs = score(
                    &mut net[c],
                    &unroll(roll.as_ref(), &m),
                    &[pixels(&fa), unroll_points(roll.as_ref(), pixels(&fb))],
                    &pgt,
                )?;
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
        return Err(Error::invalid(
            &seq.root,
            format!(
                "none of the {} selected pairs can be scored: each needs a ground-truth pose \
                 for both frames (groundtruth.txt within the association window of their \
                 stamps) and a valid depth pixel in its first frame",
                pairs.len()
            ),
        ));
    }
    let finish = |mut v: Vec<Acc>| {
        let blurred = (v.len() > 1).then(|| v.pop().map(Acc::finish).unwrap_or_default());
        MethodResult {
            clean: v.pop().map(Acc::finish).unwrap_or_default(),
            blurred,
        }
    };
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

type Row = (GrayImage, GrayImage, PixelMatches, Vec<Option<f64>>, String);

/// Rows of `A | B` with match lines: green correct, red wrong, grey unjudged.
fn draw_matches(rows: &[Row]) -> RgbImage {
    let (w, h) = rows
        .first()
        .map(|r| (r.0.width(), r.0.height()))
        .unwrap_or((1, 1));
    let mut img = RgbImage::new(2 * w, h * rows.len() as u32);
    for (r, (a, b, m, errs, _)) in rows.iter().enumerate() {
        let y0 = r as u32 * h;
        for (x0, g) in [(0, a), (w, b)] {
            for (x, y, p) in g.enumerate_pixels() {
                let v = (p[0] as f32 * 0.8) as u8;
                img.put_pixel(x0 + x, y0 + y, Rgb([v, v, v]));
            }
        }
        for ((pa, pb), e) in m.iter().zip(errs) {
            let color = match e {
                Some(e) if *e <= CORRECT_MATCH_PX => Rgb([40, 220, 60]),
                Some(_) => Rgb([240, 40, 40]),
                None => Rgb([160, 160, 160]),
            };
            draw_line(
                &mut img,
                (pa.x, pa.y + y0 as f64),
                (pb.x + w as f64, pb.y + y0 as f64),
                color,
            );
        }
    }
    img
}

fn draw_line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), c: Rgb<u8>) {
    let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let (x, y) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
        if x >= 0.0 && y >= 0.0 && (x as u32) < img.width() && (y as u32) < img.height() {
            img.put_pixel(x as u32, y as u32, c);
        }
    }
}

/// The range matcher's settings, e.g. "140 px window centred by a global affine motion
/// estimate, mutual, ratio 0.9".
pub fn describe_matcher(cfg: &MatchingEvalConfig) -> String {
    let mut s = format!(
        "{} px window {}",
        cfg.range.window,
        if cfg.guide.is_some() {
            "centred by a global affine motion estimate"
        } else {
            "centred at the keypoint"
        }
    );
    if cfg.range.mutual {
        s.push_str(", mutual");
    }
    if let Some(r) = cfg.range.ratio {
        s.push_str(&format!(", ratio {r}"));
        if cfg.range.ratio_exclusion_px > 0.0 {
            s.push_str(&format!(
                " against the nearest keypoint beyond {} px",
                cfg.range.ratio_exclusion_px
            ));
        }
    }
    if cfg.guide.is_some() && cfg.derotation.min_deg > 0.0 {
        s.push_str(&format!(
            "; FPFDCNN's image B turned back by a global roll of {} degrees or more",
            cfg.derotation.min_deg
        ));
    }
    if let Some(r) = &cfg.refine {
        s.push_str(&format!(
            "; {} matches refined by patch correlation ({}x{} patch, up to {} px, NCC >= {})",
            if cfg.refine_orb {
                "FPFDCNN's and ORB's"
            } else {
                "FPFDCNN's"
            },
            2 * r.patch_radius + 1,
            2 * r.patch_radius + 1,
            r.search_px,
            r.min_ncc
        ));
    }
    s
}

/// FPFDCNN's keypoint selection, e.g. "top 500, NMS 4 px, FP map and descriptors averaged
/// over 4 cell-grid placements, smoothed 2 px".
pub fn describe_detector(cfg: &super::inference::DetectorConfig) -> String {
    let mut s = format!("top {}, NMS {} px", cfg.top_k, cfg.nms_radius);
    if cfg.input_scale != 1.0 {
        s.push_str(&format!(", image resized x{}", cfg.input_scale));
    }
    if cfg.grid_shifts > 1 {
        let what = if cfg.average_descriptors {
            "FP map and descriptors"
        } else {
            "FP map"
        };
        s.push_str(&format!(
            ", {what} averaged over {} cell-grid placements",
            cfg.grid_shifts
        ));
    }
    if cfg.grid_shifts == 1 && cfg.descriptor_spread > 0 {
        s.push_str(&format!(
            ", descriptors spread over +-{} px diagonals",
            cfg.descriptor_spread
        ));
    }
    if cfg.levels > 1 {
        s.push_str(&format!(
            ", {} pyramid levels x{}",
            cfg.levels, cfg.level_factor
        ));
    }
    if cfg.smoothing > 0.0 {
        s.push_str(&format!(", smoothed {} px", cfg.smoothing));
    }
    if cfg.subpixel_radius > 0 {
        s.push_str(&format!(
            ", refined to corners within {} px",
            cfg.subpixel_radius
        ));
    }
    s
}

/// Each pair's figures as a markdown table per condition: accuracy, the pair's common
/// offset and the share within 5 px of it, for each method (`eval matching --per-pair`).
pub fn per_pair_markdown(r: &MatchingReport) -> String {
    let mut methods = vec![("ORB + BF", &r.orb_bf)];
    if let Some(f) = &r.fpfdcnn_range {
        methods.push(("FPFDCNN + range", f));
    }
    let cell = |p: &PairResult| {
        let share = |n: usize| 100.0 * n as f64 / p.matches.max(1) as f64;
        let offset = p
            .offset_px
            .map_or("–".to_string(), |o| format!("{:+.1}, {:+.1}", o[0], o[1]));
        format!(
            "{:.1} % ({}/{}) | {offset} | {:.1} %",
            share(p.correct),
            p.correct,
            p.matches,
            share(p.within_offset)
        )
    };
    let mut s = String::new();
    for (scenario, blurred) in [("Clear", false), ("Blurred", true)] {
        let rows: Vec<&ConditionResult> = methods
            .iter()
            .filter_map(|(_, m)| {
                if blurred {
                    m.blurred.as_ref()
                } else {
                    Some(&m.clean)
                }
            })
            .collect();
        if rows.len() < methods.len() {
            continue;
        }
        s.push_str(&format!("\n{scenario} pairs\n\n| pair |"));
        for (name, _) in &methods {
            s.push_str(&format!(
                " {name}: accuracy | offset (px) | within 5 px of it |"
            ));
        }
        s.push_str(&format!(
            "\n|---|{}\n",
            "---|---|---|".repeat(methods.len())
        ));
        for (k, &(a, b)) in r.pairs.iter().enumerate() {
            s.push_str(&format!("| {a}-{b} |"));
            for c in &rows {
                match c.pairs.get(k) {
                    Some(p) => s.push_str(&format!(" {} |", cell(p))),
                    None => s.push_str(" – | – | – |"),
                }
            }
            s.push('\n');
        }
    }
    s
}

/// The report as markdown tables shaped like the paper's Tables 6 and 7.
pub fn markdown(r: &MatchingReport) -> String {
    let detector = if r.fpfdcnn_detector.is_empty() {
        String::new()
    } else {
        format!("; FPFDCNN keypoints: {}", r.fpfdcnn_detector)
    };
    let mut s = format!(
        "Sequence `{}`, {} pairs {} frames apart{}{}; range matcher: {}{detector}\n\n| Scenario | Method | Accuracy (correct / matches) | keypoints / image | % within 2 / 5 / 10 / 20 px | % within 5 px of the pair's offset | repeatability (3 px) | matching score |\n|---|---|---|---|---|---|---|---|\n",
        r.sequence,
        r.pairs.len(),
        r.gap,
        r.blur
            .as_ref()
            .map(|b| format!(", blur {b} on both images"))
            .unwrap_or_default(),
        if r.roll_deg != 0.0 {
            format!(", image B rolled by {} degrees", r.roll_deg)
        } else {
            String::new()
        },
        r.range_matcher
    );
    let mut methods = vec![("ORB + BF matcher", &r.orb_bf)];
    if let Some(f) = &r.fpfdcnn_range {
        methods.push(("FPFDCNN + range matcher", f));
    }
    let row = |s: &mut String, scen: &str, name: &str, c: &ConditionResult| {
        s.push_str(&format!(
            "| {scen} | {name} | {:.1} % ({}/{}) | {:.0} | {} | {:.1} % | {:.1} % | {:.1} % |\n",
            100.0 * c.accuracy,
            c.correct,
            c.matches,
            c.keypoints,
            c.within_px
                .iter()
                .map(|(_, f)| format!("{:.0}", 100.0 * f))
                .collect::<Vec<_>>()
                .join(" / "),
            100.0 * c.offset_removed_accuracy,
            100.0 * c.repeatability,
            100.0 * c.matching_score,
        ));
    };
    for (name, m) in &methods {
        row(&mut s, "Clear", name, &m.clean);
    }
    for (name, m) in &methods {
        if let Some(b) = &m.blurred {
            row(&mut s, "Blurred", name, b);
        }
    }
    if let Some(f) = &r.fpfdcnn_range {
        let turned: Vec<String> = std::iter::once(&f.clean)
            .chain(f.blurred.as_ref())
            .map(|c| c.derotated_pairs.to_string())
            .collect();
        if turned.iter().any(|t| t != "0") {
            s.push_str(&format!(
                "\nFPFDCNN's image B turned back by its estimated roll on {} of {} pairs ({}).\n",
                turned.join(" / "),
                r.pairs.len(),
                if turned.len() > 1 {
                    "clear / blurred"
                } else {
                    "clear"
                }
            ));
        }
    }
    for (name, m) in &methods {
        let counts: Vec<String> = std::iter::once(&m.clean)
            .chain(m.blurred.as_ref())
            .map(|c| c.refined_matches.to_string())
            .collect();
        if m.clean.refined_matches + m.blurred.as_ref().map_or(0, |b| b.refined_matches) > 0 {
            s.push_str(&format!(
                "\n{name}: matches moved by patch correlation {} ({}).\n",
                counts.join(" / "),
                if counts.len() > 1 {
                    "clear / blurred"
                } else {
                    "clear"
                }
            ));
        }
    }
    for (rates, what) in [
        (
            &r.harris_repeatability,
            "the strongest Harris corners, FPFDCNN's detector targets",
        ),
        (
            &r.adapted_repeatability,
            "Harris corners after homographic adaptation",
        ),
    ] {
        if rates.is_empty() {
            continue;
        }
        let rates: Vec<String> = rates
            .iter()
            .map(|v| format!("{:.1} %", 100.0 * v))
            .collect();
        s.push_str(&format!(
            "\nRepeatability (3 px) of {what}: {} ({}).\n",
            rates.join(" / "),
            if rates.len() > 1 {
                "clear / blurred"
            } else {
                "clear"
            }
        ));
    }
    s.push_str("\n| Scenario | Method | errT (%) | errR (deg/m) | rotation error (deg) | translation error (mm) | PnP failures |\n|---|---|---|---|---|---|---|\n");
    let f = |v: Option<f64>, k: f64, d: usize| {
        v.map(|x| format!("{:.*}", d, x * k))
            .unwrap_or_else(|| "-".into())
    };
    for (scen, blurred) in [("Clear", false), ("Blurred", true)] {
        for (name, m) in &methods {
            let c = if blurred {
                match &m.blurred {
                    Some(b) => b,
                    None => continue,
                }
            } else {
                &m.clean
            };
            s.push_str(&format!(
                "| {scen} | {name} | {} | {} | {} | {} | {} |\n",
                f(c.err_t_percent, 1.0, 2),
                f(c.err_r_deg_per_m, 1.0, 4),
                f(c.mean_rot_error_deg, 1.0, 3),
                f(c.mean_trans_error_m, 1000.0, 1),
                c.pnp_failures
            ));
        }
    }
    s
}
