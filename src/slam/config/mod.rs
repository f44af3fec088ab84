//! Every tunable of the SLAM system ([`SlamConfig`]), read from TOML
//! (`configs/slam/default.toml` documents each field). Unknown keys are errors, missing
//! keys take the defaults below.

use crate::error::Result;
use crate::fpfdcnn::inference::DetectorConfig;
use crate::pnp::PnpConfig;
use crate::range_matcher::RangeMatcherConfig;
use serde::{Deserialize, Serialize};
use std::path::Path;

mod validate;

/// Largest top-down picture side: 8192 px is a 200 MB picture.
const MAX_TOPDOWN: u32 = 8192;
/// Most keypoints a frame may keep (`features.top_k`).
const MAX_KEYPOINTS: usize = 100_000;

/// The whole configuration.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SlamConfig {
    /// Keypoints and descriptors.
    pub features: FeatureConfig,
    /// The range matcher.
    pub matcher: MatcherConfig,
    /// PnP + RANSAC pose estimation.
    pub pnp: PnpSettings,
    /// Frame tracking.
    pub tracking: TrackingConfig,
    /// RGB-D dense pose refinement (ICP) and keyframe alignment edges.
    pub dense: DenseConfig,
    /// Keyframe selection.
    pub keyframes: KeyframeConfig,
    /// The dense semantic map.
    pub map: MapConfig,
    /// Multi-view depth of monocular keyframes.
    pub multiview: MultiviewConfig,
    /// Voxel label voting.
    pub labels: LabelVoteConfig,
    /// Data correction: pose graph and local correction.
    pub correction: CorrectionConfig,
    /// Bundle adjustment after the final pose-graph solve.
    pub bundle_adjustment: BundleAdjustmentConfig,
    /// Monocular scale anchors.
    pub scale: ScaleConfig,
    /// Threads and reporting.
    pub system: SystemConfig,
}

/// Keypoints and descriptors (section IV-B).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FeatureConfig {
    /// Keypoints kept per image (ORB features / FPFDCNN top-k; the paper: 500).
    pub top_k: usize,
    /// FPFDCNN: minimum keypoint probability.
    pub fpfdcnn_threshold: f32,
    /// FPFDCNN: non-maximum suppression radius, pixels.
    pub fpfdcnn_nms_radius: usize,
    /// FPFDCNN: Gaussian smoothing of the probability map before suppression, pixels (0: off).
    pub fpfdcnn_smoothing: f32,
    /// FPFDCNN: no keypoint closer than this to the border, pixels.
    pub fpfdcnn_border: usize,
    /// FPFDCNN: image resize factor before the network (0.5 for weights trained at 240x320).
    pub fpfdcnn_input_scale: f32,
    /// FPFDCNN: average the FP map over 1, 2 or 4 placements of the 16x16 cell grid (each
    /// a full network pass).
    pub fpfdcnn_grid_shifts: usize,
    /// FPFDCNN: with one placement, average each descriptor over the keypoint and four
    /// samples this many pixels away along the diagonals (0: off; `DetectorConfig::descriptor_spread`).
    pub fpfdcnn_descriptor_spread: usize,
    /// ORB: FAST threshold, grey levels.
    pub orb_fast_threshold: u8,
    /// ORB: when fewer than half of `top_k` keypoints are found, detect again
    /// with this lower FAST threshold (ORB-SLAM's fallback; 0: off).
    pub orb_fallback_threshold: u8,
    /// ORB: pyramid levels.
    pub orb_levels: usize,
    /// ORB: pyramid scale factor.
    pub orb_scale_factor: f32,
}

impl Default for FeatureConfig {
    fn default() -> Self {
        FeatureConfig {
            top_k: 500,
            fpfdcnn_threshold: 0.015,
            fpfdcnn_nms_radius: 4,
            fpfdcnn_smoothing: crate::fpfdcnn::inference::DEFAULT_SMOOTHING,
            fpfdcnn_border: 4,
            orb_fast_threshold: 20,
            orb_fallback_threshold: 7,
            orb_levels: 8,
            orb_scale_factor: 1.2,
            fpfdcnn_input_scale: 1.0,
            fpfdcnn_grid_shifts: 1,
            fpfdcnn_descriptor_spread: crate::fpfdcnn::inference::DEFAULT_DESCRIPTOR_SPREAD,
        }
    }
}

impl FeatureConfig {
    /// The FPFDCNN detector settings these fields give.
    pub fn detector(&self) -> DetectorConfig {
        DetectorConfig {
            threshold: self.fpfdcnn_threshold,
            nms_radius: self.fpfdcnn_nms_radius,
            smoothing: self.fpfdcnn_smoothing,
            top_k: self.top_k,
            border: self.fpfdcnn_border,
            input_scale: self.fpfdcnn_input_scale,
            grid_shifts: self.fpfdcnn_grid_shifts,
            descriptor_spread: self.fpfdcnn_descriptor_spread,
            ..DetectorConfig::default()
        }
    }

    /// The ORB extractor settings these fields give.
    pub fn orb(&self) -> crate::features::OrbConfig {
        crate::features::OrbConfig {
            n_features: self.top_k,
            fast_threshold: self.orb_fast_threshold,
            n_levels: self.orb_levels,
            scale_factor: self.orb_scale_factor,
            ..Default::default()
        }
    }
}

/// The range matcher (Fig. 4, eq 8).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatcherConfig {
    /// Side of the square search window, pixels (the paper: 140).
    pub window: f32,
    /// Centre the window on where the constant-velocity motion predicts the
    /// keypoint instead of on its own position.
    pub predict_window: bool,
    /// Mutual-nearest check.
    pub mutual: bool,
    /// Lowe ratio (0: off).
    pub ratio: f32,
    /// The ratio tests' second-nearest candidate is taken among keypoints farther than
    /// this from the nearest one, pixels (0: Lowe's test as it is).
    pub ratio_exclusion_px: f32,
    /// Window for relocalisation and keyframe-pair verification when the
    /// guided match fails, pixels (the whole image at 640x480: 1300).
    pub wide_window: f32,
    /// Lowe ratio of wide-window matching (0: off).
    pub wide_ratio: f32,
}

impl Default for MatcherConfig {
    fn default() -> Self {
        MatcherConfig {
            window: 140.0,
            predict_window: true,
            mutual: true,
            ratio: 0.0,
            ratio_exclusion_px: 0.0,
            wide_window: 1300.0,
            wide_ratio: 0.9,
        }
    }
}

impl MatcherConfig {
    /// The range matcher settings of guided matching (`window`, `ratio`).
    pub fn range(&self) -> RangeMatcherConfig {
        RangeMatcherConfig {
            window: self.window,
            mutual: self.mutual,
            ratio: (self.ratio > 0.0).then_some(self.ratio),
            ratio_exclusion_px: self.ratio_exclusion_px,
        }
    }

    /// The range matcher settings of wide-window matching (`wide_window`, `wide_ratio`).
    pub fn wide(&self) -> RangeMatcherConfig {
        RangeMatcherConfig {
            window: self.wide_window,
            mutual: self.mutual,
            ratio: (self.wide_ratio > 0.0).then_some(self.wide_ratio),
            ratio_exclusion_px: self.ratio_exclusion_px,
        }
    }
}

/// PnP + RANSAC (eqs 9-10).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PnpSettings {
    /// Inlier threshold on the reprojection error, pixels.
    pub threshold_px: f64,
    /// Maximum RANSAC iterations.
    pub max_iterations: usize,
    /// RANSAC confidence for the adaptive iteration count.
    pub confidence: f64,
    /// Fewer inliers than this: the pose is rejected (tracking lost).
    pub min_inliers: usize,
    /// Levenberg-Marquardt iterations of the refinement on the inliers.
    pub refine_iterations: usize,
    /// RANSAC seed.
    pub seed: u64,
}

impl Default for PnpSettings {
    fn default() -> Self {
        PnpSettings {
            threshold_px: 3.0,
            max_iterations: 500,
            confidence: 0.999,
            min_inliers: 20,
            refine_iterations: 20,
            seed: 0,
        }
    }
}

impl PnpSettings {
    /// The PnP + RANSAC settings (at least 4 inliers required).
    pub fn pnp(&self) -> PnpConfig {
        PnpConfig {
            threshold_px: self.threshold_px,
            confidence: self.confidence,
            max_iterations: self.max_iterations,
            min_inliers: self.min_inliers.max(4),
            refine_iterations: self.refine_iterations,
            seed: self.seed,
        }
    }
}

/// Frame tracking (section IV-B).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackingConfig {
    /// Also match against the previous frame (not only the reference keyframe).
    pub match_previous_frame: bool,
    /// Depth readings outside `[min_depth, max_depth]` metres give no 3D point.
    pub min_depth: f64,
    /// Upper end of the usable depth range, metres.
    pub max_depth: f64,
    /// Keyframes tried by relocalisation (most similar mean descriptors first).
    pub relocalisation_candidates: usize,
    /// After this many consecutive lost frames a keyframe is started at the
    /// constant-velocity pose so that tracking can resume (0: never).
    pub reinitialise_after: usize,
    /// Start at the ground-truth pose of the first frame when the sequence has
    /// one (otherwise the identity), so that unaligned errors mean something.
    pub start_at_ground_truth: bool,
    /// RGB-D mode: after the back end, move each frame's pose from its depth image's instant
    /// to its colour image's (the trajectory's stamps), along the trajectory
    /// ([`crate::slam::backend::colour_instant`]); frames whose stamps are equal do not move.
    pub colour_instant: bool,
    /// Detect keypoints on every frame (the paper's tracking). `false` (the default; RGB-D
    /// with `dense.enabled`): a frame is first tracked by the dense alignment alone against its
    /// reference keyframe's depth, from the constant-velocity pose; keypoints are detected, and
    /// the frame tracked by them, only when that alignment fails its gates
    /// (`dense.min_inlier_fraction`, `dense.agree_*` against the prediction) or the frame is
    /// due to become a keyframe (`keyframes.max_translation`, `max_rotation_deg`,
    /// `max_frames_depth_tracked`). Runs without the dense alignment detect on every frame
    /// whatever this says; monocular runs unless `monocular_flow`.
    pub keypoints_every_frame: bool,
    /// Monocular, with `keypoints_every_frame = false`: frames between keyframes are followed
    /// by pyramidal Lucas-Kanade optical flow of the last frame's keypoints and placed by PnP
    /// on their map points; keypoints are detected only when fewer than `keyframes.min_inliers`
    /// remain or a keyframe is due (`keyframes.max_translation`, `max_rotation_deg`,
    /// `max_frames_flow_tracked`). Faster, less accurate on some sequences
    /// (`docs/performance.md`, the ladder).
    pub monocular_flow: bool,
}

impl Default for TrackingConfig {
    fn default() -> Self {
        TrackingConfig {
            match_previous_frame: true,
            min_depth: 0.1,
            max_depth: 6.0,
            relocalisation_candidates: 5,
            reinitialise_after: 10,
            start_at_ground_truth: true,
            colour_instant: true,
            keypoints_every_frame: false,
            monocular_flow: false,
        }
    }
}

/// RGB-D mode: each tracked frame's pose refined against its reference keyframe's depth by
/// point-to-plane ICP ([`crate::slam::frontend::depth_alignment`]), kept when it agrees with the pose
/// from the keypoints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DenseConfig {
    /// Refine at all.
    pub enabled: bool,
    /// The keyframe's depth is kept every `model_step` pixels.
    pub model_step: usize,
    /// Coarse to fine: frame pixels sampled every `step`, pairs farther apart than
    /// `max_distance` metres dropped.
    pub levels: Vec<DenseLevel>,
    /// Gauss-Newton iterations per level.
    pub iterations: usize,
    /// Point-to-plane distances beyond this (metres; at 1 m with `noise_weighting`) are
    /// down-weighted (Huber).
    pub huber: f64,
    /// Weigh each pair by the inverse variance of the sensor's depth noise at its depth,
    /// relative to 1 m (a Kinect's, which grows with the square of the depth:
    /// `crate::slam::frontend::depth_alignment::axial_noise`; the model point's axial noise only,
    /// whatever the angle of the surface); `huber` then applies at 1 m, so at 3 m to
    /// distances 7.5 times larger, where the levels' `max_distance` gates first.
    pub noise_weighting: bool,
    /// Fewer pairs than this: no refinement.
    pub min_pairs: usize,
    /// Fewer than this share of the frame's sampled points paired at the last level: not kept.
    pub min_inlier_fraction: f64,
    /// The refined pose is kept only within this translation (metres) and rotation (degrees)
    /// of the pose from the keypoints.
    pub agree_translation: f64,
    /// Rotation bound of `agree_translation`'s check, degrees.
    pub agree_rotation_deg: f64,
    /// Keyframe-to-keyframe edges: each keyframe's depth (at the fusion resolution) is aligned
    /// to this many preceding keyframes' by the same ICP, and each alignment that agrees with
    /// tracking becomes a relative-pose edge of the pose graph and of bundle adjustment
    /// ([`crate::slam::backend::keyframe_alignment`]; 0: none, and in monocular mode never).
    pub keyframe_edges: usize,
    /// With `keyframe_edges` > 0: also align the two keyframes of each verified loop
    /// constraint (proximity, similarity, random), from its PnP pose.
    pub loop_edges: bool,
    /// An alignment becomes an edge only when at least this share of the later keyframe's
    /// sampled points is paired at the last level (misaligned pairs pair fewer).
    pub edge_min_inlier_fraction: f64,
    /// ... and when it moves less than this translation (metres) and rotation (degrees) from
    /// its starting pose (tracking's, or the loop constraint's PnP pose). Wider than the
    /// frames' `agree_*`: a keyframe pair's start can be centimetres off where tracking
    /// slipped, which is where its alignment matters most.
    pub edge_agree_translation: f64,
    /// Rotation bound of `edge_agree_translation`'s check, degrees.
    pub edge_agree_rotation_deg: f64,
    /// Standard deviations of a keyframe edge (a relative pose from the ICP), metres and
    /// degrees.
    pub sigma_translation: f64,
    /// Rotation standard deviation of a keyframe edge, degrees.
    pub sigma_rotation_deg: f64,
    /// Standard deviations of the prior that keeps a refined frame's dense pose when the
    /// frame is refined again against the adjusted points after bundle adjustment.
    pub prior_sigma_translation: f64,
    /// Rotation standard deviation of that prior, degrees.
    pub prior_sigma_rotation_deg: f64,
    /// Keyframe alignments read each keyframe's depth after the map's depth-edge filter
    /// (`map.depth_edge_*`); off: as the sensor gave it.
    pub edges_on_filtered_depth: bool,
    /// Tracking also aligns each frame's depth to the previous frame's, and after the back
    /// end the frames between two keyframes are placed by a small pose graph of those
    /// frame-to-frame steps and their alignments to the first keyframe, between both
    /// keyframes' corrected poses ([`crate::slam::backend::frame_graph`]).
    pub frame_graph: bool,
    /// In that graph, the weight (information) of a frame's dense pose against its reference
    /// keyframe relative to a frame-to-frame step's, for the first frame after the keyframe;
    /// the `k`-th frame's weighs `1/k` of it (a frame whose dense refinement was not kept: its
    /// keypoint pose, a ninth of that).
    pub frame_graph_reference_weight: f64,
}

/// One level of [`DenseConfig::levels`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DenseLevel {
    /// Frame pixels are sampled every `step` pixels at this level.
    pub step: usize,
    /// Pairs farther apart than this are dropped, metres.
    pub max_distance: f64,
}

impl Default for DenseConfig {
    fn default() -> Self {
        DenseConfig {
            enabled: true,
            model_step: 1,
            levels: vec![
                DenseLevel {
                    step: 8,
                    max_distance: 0.1,
                },
                DenseLevel {
                    step: 4,
                    max_distance: 0.03,
                },
            ],
            iterations: 10,
            huber: 0.01,
            noise_weighting: true,
            min_pairs: 500,
            min_inlier_fraction: 0.3,
            agree_translation: 0.03,
            agree_rotation_deg: 2.0,
            keyframe_edges: 2,
            loop_edges: true,
            edge_min_inlier_fraction: 0.5,
            edge_agree_translation: 0.1,
            edge_agree_rotation_deg: 6.0,
            sigma_translation: 0.002,
            sigma_rotation_deg: 0.5,
            prior_sigma_translation: 0.0005,
            prior_sigma_rotation_deg: 0.1,
            edges_on_filtered_depth: true,
            frame_graph: true,
            frame_graph_reference_weight: 0.25,
        }
    }
}

/// Keyframe selection: a tracked frame becomes a keyframe when any rule fires.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct KeyframeConfig {
    /// Fewer PnP inliers against the reference keyframe than this.
    pub min_inliers: usize,
    /// Translation since the reference keyframe above this, metres.
    pub max_translation: f64,
    /// Rotation since the reference keyframe above this, degrees.
    pub max_rotation_deg: f64,
    /// This many frames since the reference keyframe, where keypoints are detected on every
    /// frame (`tracking.keypoints_every_frame`, monocular without `tracking.monocular_flow`,
    /// or RGB-D without the dense alignment).
    pub max_frames: usize,
    /// This many frames since the reference keyframe, where frames between keyframes are
    /// tracked by their depth alone (RGB-D, `tracking.keypoints_every_frame = false`): those
    /// frames make no keyframe by their keypoints, so keyframes come from the motion rules and
    /// this count only.
    pub max_frames_depth_tracked: usize,
    /// This many frames since the reference keyframe, where frames between keyframes are
    /// followed by optical flow (monocular, `tracking.monocular_flow`).
    pub max_frames_flow_tracked: usize,
}

impl Default for KeyframeConfig {
    fn default() -> Self {
        KeyframeConfig {
            min_inliers: 80,
            max_translation: 0.10,
            max_rotation_deg: 10.0,
            max_frames: 20,
            max_frames_depth_tracked: 4,
            max_frames_flow_tracked: 5,
        }
    }
}

/// Dense semantic map (section IV-C).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MapConfig {
    /// Voxel side, metres.
    pub voxel_size: f64,
    /// Every `pixel_stride`-th pixel of a keyframe (in x and y) is fused; the
    /// keyframe keeps its RGB, depth and labels at this resolution.
    pub pixel_stride: u32,
    /// Depths outside `[min_depth, max_depth]` metres are not fused.
    pub min_depth: f64,
    /// Upper end of the fused depth range, metres.
    pub max_depth: f64,
    /// After a correction, each new keyframe also re-fuses at most this many of the
    /// keyframes that moved most (by more than a voxel) since they were fused, so that
    /// online fusion stays bounded per keyframe; the final map is re-fused from all final
    /// poses whatever this is (0: no online re-fusion).
    pub refuse_per_keyframe: usize,
    /// A voxel becomes a map point when at least this many keyframes put an observation
    /// in it (1: every voxel). Depth that several keyframes agree on, within a voxel, is
    /// kept; what one keyframe alone saw there (flicker of predicted depth, sensor
    /// noise at edges) is not.
    pub min_views: u16,
    /// Depth edges (`crate::slam::mapping::depth_edges`): a pixel where the second difference of inverse
    /// depth over `depth_edge_reach` pixels (full resolution, along x or y), times its
    /// depth, exceeds `depth_edge_ratio` is not fused (0: every pixel). Planes, slanted or
    /// not, score 0.
    pub depth_edge_ratio: f32,
    /// Reach of the depth-edge second difference, full-resolution pixels.
    pub depth_edge_reach: u32,
    /// Write the PLY as ASCII instead of binary little-endian.
    pub ply_ascii: bool,
    /// Side of the top-down picture of the map, pixels.
    pub topdown_size: u32,
}

impl Default for MapConfig {
    fn default() -> Self {
        MapConfig {
            voxel_size: 0.02,
            pixel_stride: 2,
            min_depth: 0.1,
            max_depth: 4.0,
            refuse_per_keyframe: 8,
            min_views: 3,
            depth_edge_ratio: 0.02,
            depth_edge_reach: 8,
            ply_ascii: false,
            topdown_size: 1000,
        }
    }
}

/// Multi-view depth of monocular keyframes ([`crate::slam::mapping::multiview_depth`]): SDFCNN's
/// prediction is measured again by a plane sweep against earlier keyframes where there is
/// texture and parallax. RGB-D mode does not use it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MultiviewConfig {
    /// Earlier keyframes compared against (0: off, the prediction is fused as it is).
    pub references: usize,
    /// Only keyframes among the last `look_back` whose camera centre is at least
    /// `min_baseline` metres away (and whose viewing direction is within
    /// `max_angle_deg`) are references, the widest baselines first.
    pub look_back: usize,
    /// Smallest distance of a reference's camera centre, metres.
    pub min_baseline: f64,
    /// Largest angle between a reference's viewing direction and the keyframe's, degrees.
    pub max_angle_deg: f64,
    /// Depth hypotheses, log-spaced over `predicted · e^(±range)`.
    pub steps: usize,
    /// Half-width of the hypothesis range in log depth (`predicted · e^(±range)`).
    pub range: f64,
    /// Patch of `2 r + 1` x `2 r + 1` samples, `patch_step` full-resolution pixels apart
    /// (bilinear in the earlier keyframes' full-resolution grey images).
    pub patch_radius: usize,
    /// Spacing of the patch samples, full-resolution pixels.
    pub patch_step: usize,
    /// A depth is measured when the best mean NCC is at least `min_ncc`, ...
    pub min_ncc: f32,
    /// ... the patch's standard deviation at least `min_texture` grey levels, ...
    pub min_texture: f32,
    /// ... its cost `1 - NCC` at most `uniqueness` times that of every hypothesis more
    /// than two steps away, ...
    pub uniqueness: f32,
    /// ... and the range moves it by at least this many (full-resolution) pixels in a
    /// reference.
    pub min_parallax_px: f64,
    /// Pixels without a measured depth keep the prediction (false: they are not fused), ...
    pub keep_unconfirmed: bool,
    /// ... multiplied by the median ratio measured / predicted over a grid of this many
    /// columns of cells (rows in proportion; bilinear between cell centres; a cell with
    /// fewer than 100 measured pixels takes the keyframe's median; 0: not corrected).
    pub rescale_cells: usize,
}

impl Default for MultiviewConfig {
    fn default() -> Self {
        MultiviewConfig {
            references: 3,
            look_back: 8,
            min_baseline: 0.03,
            max_angle_deg: 30.0,
            steps: 24,
            range: 0.3,
            patch_radius: 2,
            patch_step: 2,
            min_ncc: 0.8,
            min_texture: 3.0,
            uniqueness: 0.6,
            min_parallax_px: 4.0,
            keep_unconfirmed: true,
            rescale_cells: 8,
        }
    }
}

/// How the votes of a voxel's observations decide its label.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LabelVoteConfig {
    /// The winning class needs at least this many votes.
    pub min_votes: u32,
    /// ... and at least this share of the voxel's votes.
    pub min_share: f64,
    /// Whether void (255) observations count as votes (against every class).
    pub void_votes: bool,
}

impl Default for LabelVoteConfig {
    fn default() -> Self {
        LabelVoteConfig {
            min_votes: 1,
            min_share: 0.0,
            void_votes: false,
        }
    }
}

/// Robust kernel of the pose graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum RobustKernel {
    /// Plain least squares.
    None,
    /// Huber kernel: quadratic up to `robust_delta`, linear beyond.
    Huber,
    /// Cauchy kernel with scale `robust_delta`.
    Cauchy,
}

/// Data correction (section IV-A): global (keyframe-pair constraints + pose
/// graph) and local (matched keypoints unified into one world point).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CorrectionConfig {
    /// Global correction on/off.
    pub enabled: bool,
    /// Randomly chosen earlier keyframes tried per keyframe (the paper's way).
    pub random_pairs: usize,
    /// Earlier keyframes whose camera centre is within `proximity_radius`
    /// metres (and viewing direction within `proximity_angle_deg`) are tried,
    /// nearest first, at most `proximity_pairs`.
    pub proximity_pairs: usize,
    /// Largest camera-centre distance of a proximity pair, metres.
    pub proximity_radius: f64,
    /// Largest viewing-direction angle of a proximity pair, degrees.
    pub proximity_angle_deg: f64,
    /// Earlier keyframes with the most similar mean descriptor (cosine) are
    /// tried, at most `similarity_pairs`, if the cosine is above `min_similarity`.
    pub similarity_pairs: usize,
    /// Smallest mean-descriptor cosine of a similarity pair.
    pub min_similarity: f32,
    /// Keyframes closer in id than this are not paired (the odometry edge links
    /// neighbours already).
    pub min_id_gap: usize,
    /// A pair becomes a constraint with at least this many PnP inliers.
    pub min_inliers: usize,
    /// ... and this share of its matches as inliers.
    pub min_inlier_ratio: f64,
    /// Pose-graph Levenberg-Marquardt iterations.
    pub lm_iterations: usize,
    /// Standard deviations of the edge errors (information = 1 / sigma²).
    pub sigma_translation: f64,
    /// Rotation standard deviation of an edge error, degrees.
    pub sigma_rotation_deg: f64,
    /// Robust kernel on the whitened edge error, and its scale.
    pub robust_kernel: RobustKernel,
    /// Scale of the robust kernel, on the whitened error.
    pub robust_delta: f64,
    /// Optimise while the run goes on when a loop constraint is found (otherwise once at
    /// the end). Every solve starts from the tracked poses, so online solves change the live
    /// map, never the final trajectory.
    pub optimise_online: bool,
    /// Online, at most one solve per this many keyframes (1: at every keyframe that closes
    /// a loop). Over long sequences nearly every keyframe closes one (proximity pairs), and
    /// a solve costs more as the graph grows. RGB-D mode only: monocular mode solves at
    /// every closed loop, because its multi-view depth (and so its map) is measured between
    /// keyframes placed by the corrections made so far.
    pub optimise_every: usize,
    /// Local correction on/off.
    pub local: bool,
    /// Local correction: a keyframe's depth is rescaled by the median ratio of its
    /// unified points' depths to its own, if it has this many ...
    pub local_min_observations: usize,
    /// ... clamped to `1 ± local_max_scale_change`.
    pub local_max_scale_change: f64,
    /// Seed of the random pair selection.
    pub seed: u64,
}

impl Default for CorrectionConfig {
    fn default() -> Self {
        CorrectionConfig {
            enabled: true,
            random_pairs: 2,
            proximity_pairs: 3,
            proximity_radius: 0.5,
            proximity_angle_deg: 45.0,
            similarity_pairs: 2,
            min_similarity: 0.6,
            min_id_gap: 2,
            min_inliers: 30,
            min_inlier_ratio: 0.25,
            lm_iterations: 30,
            sigma_translation: 0.01,
            sigma_rotation_deg: 0.5,
            robust_kernel: RobustKernel::Huber,
            robust_delta: 3.0,
            optimise_online: true,
            optimise_every: 10,
            local: true,
            local_min_observations: 20,
            local_max_scale_change: 0.2,
            seed: 0,
        }
    }
}

/// Bundle adjustment of the keyframe poses and the points their matched keypoints observe
/// ([`crate::slam::backend::bundle_adjustment`]), run after the final pose-graph solve.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BundleAdjustmentConfig {
    /// Adjust at all.
    pub enabled: bool,
    /// Levenberg-Marquardt iterations (two rounds, the χ² gate between them).
    pub iterations: usize,
    /// At most this many keyframes are free (the newest; earlier ones stay fixed).
    pub max_keyframes: usize,
    /// Standard deviation of a keypoint's position, pixels.
    pub sigma_px: f64,
    /// Huber scale on the whitened residual norm.
    pub huber: f64,
    /// Squared whitened residual beyond which an observation is dropped after round one.
    pub outlier_chi2: f64,
    /// Baseline × focal length of the depth term for sensor depth (RGB-D), pixel metres
    /// (ORB-SLAM's `Camera.bf` for TUM is 40; 400 is a depth σ of z²/400, 1 cm at 2 m, near
    /// a Kinect's noise); 0: reprojection only.
    pub depth_bf: f64,
    /// The same for SDFCNN's predicted depth (monocular mode).
    pub predicted_depth_bf: f64,
    /// The pose graph's relative-pose edges (`[correction]` sigmas) join the adjustment
    /// with their information times this (0: points only).
    pub edge_weight: f64,
    /// Afterwards, refine each tracked frame's pose against the adjusted points.
    pub refine_frames: bool,
    /// Local bundle adjustment during the run (`crate::slam::backend::local_bundle_adjustment`):
    /// at most this many keyframes free around each new one (0: off, the default; 10 when
    /// on).
    pub local_keyframes: usize,
    /// Levenberg-Marquardt iterations of each local adjustment.
    pub local_iterations: usize,
}

impl Default for BundleAdjustmentConfig {
    fn default() -> Self {
        BundleAdjustmentConfig {
            enabled: true,
            iterations: 20,
            max_keyframes: 300,
            sigma_px: 1.0,
            huber: 2.796,
            outlier_chi2: 7.815,
            depth_bf: 400.0,
            predicted_depth_bf: 4.0,
            edge_weight: 1.0,
            refine_frames: true,
            local_keyframes: 0,
            local_iterations: 10,
        }
    }
}

/// Threads and reporting.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SystemConfig {
    /// Tracking, mapping and correction in their own threads (Fig. 1); off:
    /// everything in order on one thread (deterministic, for tests).
    pub threads: bool,
    /// Capacity of the channels between threads (back-pressure on tracking).
    pub queue: usize,
    /// With `threads`: threads that load frames ahead of tracking and, where every frame needs
    /// its keypoints (monocular, `tracking.keypoints_every_frame`), detect them, else those of
    /// the frame at which the next keyframe is due by the frame count, each running the
    /// keypoint network on its share of the cores (0: on the tracking thread, the network on
    /// all cores).
    pub feature_workers: usize,
    /// Distance from the true surface within which a map point counts as
    /// correctly placed (Table 11 "position accuracy"), metres.
    pub position_tolerance: f64,
    /// At most this many map points are evaluated against ground truth.
    pub max_eval_points: usize,
    /// A frame that cannot be read (a missing or damaged image, another size than the camera)
    /// ends the run with an error naming it; off, it is skipped and reported.
    pub strict_frames: bool,
}

impl Default for SystemConfig {
    fn default() -> Self {
        SystemConfig {
            threads: true,
            queue: 8,
            feature_workers: 2,
            position_tolerance: 0.05,
            max_eval_points: 200_000,
            strict_frames: false,
        }
    }
}

/// Monocular scale anchors ([`crate::slam::mapping::scale_anchor`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScaleConfig {
    /// Height of the camera above the floor, metres (0: not known). Monocular mode: the floor
    /// plane of the map then fixes its scale; with sensor depth it is only compared.
    pub camera_height: f64,
}

impl Default for ScaleConfig {
    fn default() -> Self {
        ScaleConfig { camera_height: 0.0 }
    }
}

impl SlamConfig {
    /// Parses TOML; errors name the file and line.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let cfg: SlamConfig =
            toml::from_str(text).map_err(|e| crate::camera::toml_error(path, text, e))?;
        cfg.validate()
            .map_err(|m| crate::io::config_error(path, text, m))?;
        Ok(cfg)
    }

    /// Reads a TOML file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::parse(&crate::io::read_text(path)?, path)
    }

    /// The configuration as TOML.
    pub fn to_toml(&self) -> Result<String> {
        Ok(toml::to_string_pretty(self)?)
    }
}

#[cfg(test)]
mod tests;
