//! The paper's Tables 6 and 7 on a TUM-layout sequence: matching accuracy of
//! ORB + brute-force matching and of FPFDCNN + the range matcher on clear and on
//! motion-blurred frame pairs, and errT / errR (eqs 11-14) of the relative pose
//! that PnP + RANSAC (eqs 9-10) recovers from each method's matches.
//!
//! A match is correct when the matched keypoint in B lies within 5 px of the
//! ground-truth projection of its A keypoint (A's depth, the camera with its
//! distortion, ground-truth poses interpolated at the image timestamps); matches
//! whose A keypoint has no depth are not counted.

mod draw;
mod matching;
mod report;
mod run;
mod scoring;

pub use matching::{PixelMatches, fpfdcnn_matches, orb_matches};
pub use report::{describe_detector, describe_matcher, markdown, per_pair_markdown};
pub use run::{evaluate, select_pairs};

use super::derotation::DerotationConfig;
use crate::dataset::fp_pairs::FpConfig;
use crate::dataset::photometric::Degradation;
use crate::features::harris::HarrisConfig;
use crate::features::match_refine::MatchRefineConfig;
use crate::features::orb::OrbConfig;
use crate::pnp::PnpConfig;
use crate::range_matcher::{GuideConfig, RangeMatcherConfig};
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
    /// (`crate::range_matcher::guided_range_match`); `None`: at the keypoint (the paper).
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

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

fn is_zero_count(v: &usize) -> bool {
    *v == 0
}
