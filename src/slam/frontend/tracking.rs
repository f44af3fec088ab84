//! Tracking: the camera pose of every frame (section IV-B, Fig. 2). Keypoints of
//! the frame are range-matched (Fig. 4, eq 8) against the reference keyframe and
//! the previous frame, whose keypoints carry 3D points from depth (eqs 9-10);
//! PnP + RANSAC, scoring the constant-velocity prediction first, then
//! Levenberg-Marquardt on the inliers (eq 4) gives the pose. Frames become
//! keyframes by inlier count and motion since the reference keyframe.
//!
//! A failed frame is *lost*: relocalisation tries the reference and the
//! keyframes with the most similar descriptors with a wide window; if none
//! agrees the frame keeps the constant-velocity pose and the run goes on. After
//! `reinitialise_after` lost frames in a row a keyframe is started at the
//! predicted pose so that tracking can resume.
//!
//! Poses here are in the odometry frame (as tracked, never corrected): the final
//! trajectory composes each frame's pose relative to its reference keyframe with
//! that keyframe's corrected pose, as ORB-SLAM3 writes its trajectories.

use super::depth_alignment::{DepthModel, align};
use super::keypoints::{KeyFeatures, similarity};
use super::matching::{Correspondences, Source, correspond};
use crate::camera::{Camera, RayTable};
use crate::dataset::DepthImage;
use crate::features::optical_flow::{self, FlowParams, Pyramid};
use crate::geometry::{Pose, renormalized};
use crate::pnp::{PnpResult, solve_pnp_ransac};
use crate::range_matcher::RangeMatcherConfig;
use crate::slam::config::{DenseConfig, SlamConfig};
use crate::slam::map::{KeyframeFeatures, KeypointDepth, Map, points_from_depth};
use nalgebra::{Point2, Point3};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// How a frame was tracked.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FrameStatus {
    /// First keyframe (or restart after being lost).
    Initialised,
    /// Tracked against the reference keyframe (and previous frame).
    Tracked,
    /// Lost, then found again against an earlier keyframe.
    Relocalised,
    /// Lost: the constant-velocity pose was kept.
    Lost,
}

/// The outcome of one frame.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameRecord {
    /// The frame's index in the sequence.
    pub index: usize,
    /// The frame's timestamp, seconds.
    pub stamp: f64,
    /// How the frame was tracked.
    pub status: FrameStatus,
    /// The keyframe this frame became, if any.
    pub keyframe: Option<usize>,
    /// The keyframe the pose is expressed against.
    pub reference: Option<usize>,
    /// `T_ref⁻¹ T_frame` in the odometry frame.
    pub relative: Pose,
    /// Camera-to-world pose in the odometry frame.
    pub odom_pose: Pose,
    /// PnP inliers and correspondences.
    pub inliers: usize,
    /// Number of 2D-3D correspondences given to PnP.
    pub correspondences: usize,
    /// The PnP inliers against the reference keyframe (empty for keyframes and lost
    /// frames), for the frame's refinement after bundle adjustment.
    pub observations: Vec<FrameObservation>,
    /// `relative` came from the dense refinement against the reference keyframe's depth
    /// (RGB-D, `dense.enabled`): the refinement after bundle adjustment keeps it as a prior.
    pub dense: bool,
    /// `dense.frame_graph` (RGB-D): the previous frame's index and this frame's pose in its
    /// camera frame (`T_prev⁻¹ T_this`) from aligning this frame's depth to the previous
    /// frame's, when the alignment was kept.
    pub step: Option<(usize, Pose)>,
}

impl FrameRecord {
    /// A frame tracked against keyframe `reference` without keypoints of its own (by its
    /// depth or by optical flow): no keyframe, no observations, no frame-to-frame step yet.
    fn tracked_without_keypoints(
        index: usize,
        stamp: f64,
        reference: usize,
        relative: Pose,
        odom_pose: Pose,
    ) -> Self {
        FrameRecord {
            index,
            stamp,
            status: FrameStatus::Tracked,
            keyframe: None,
            reference: Some(reference),
            relative,
            odom_pose,
            inliers: 0,
            correspondences: 0,
            observations: Vec::new(),
            dense: false,
            step: None,
        }
    }
}

impl FrameRecord {
    /// The frame's final pose: its reference keyframe's pose in `map` composed with the
    /// tracked relative pose (the odometry pose without a reference in `map`).
    pub fn pose_in(&self, map: &Map) -> Pose {
        match self.reference.and_then(|k| map.keyframes.get(k)) {
            Some(kf) => kf.pose * self.relative,
            None => self.odom_pose,
        }
    }
}

/// A tracked frame's PnP inlier against its reference keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameObservation {
    /// The reference keyframe's keypoint.
    pub keypoint: u32,
    /// The frame's matching keypoint, pixels.
    pub pixel: [f32; 2],
    /// Sensor depth at that keypoint (RGB-D mode), metres.
    pub depth: Option<f32>,
}

/// A keyframe just created by tracking, for the mapping stage.
#[derive(Debug, Clone)]
pub(crate) struct NewKeyframe {
    /// The keyframe's id (its index in the map's keyframes).
    pub id: usize,
    /// Index of the frame it was made from.
    pub frame_index: usize,
    /// The frame's timestamp, seconds.
    pub stamp: f64,
    /// Camera-to-world pose in the odometry frame.
    pub pose: Pose,
    /// Ground-truth camera-to-world pose, when the sequence has one.
    pub gt_pose: Option<Pose>,
    /// Keypoints with 3D points from sensor depth (RGB-D), or without 3D
    /// points until mapping predicts the depth (monocular).
    pub track: Arc<KeyframeFeatures>,
}

/// One frame for the tracker.
#[derive(Debug, Clone)]
pub(crate) struct TrackInput<'a> {
    /// The frame's index in the sequence.
    pub index: usize,
    /// The frame's timestamp, seconds.
    pub stamp: f64,
    /// The frame's keypoints and descriptors.
    pub features: KeyFeatures,
    /// Sensor depth (RGB-D mode only).
    pub depth: Option<&'a DepthImage>,
    /// Ground-truth camera-to-world pose, when the sequence has one.
    pub gt_pose: Option<Pose>,
}

/// Result of [`Tracker::track`].
#[derive(Debug, Clone)]
pub(crate) struct TrackOutput {
    /// The frame's outcome.
    pub record: FrameRecord,
    /// The keyframe the frame became, if any, for the mapping stage.
    pub keyframe: Option<NewKeyframe>,
    /// What happened, for the log (lost, relocalised, restarted).
    pub events: Vec<String>,
}

struct TrackedKeyframe {
    frame_index: usize,
    pose: Pose,
    data: Arc<KeyframeFeatures>,
}

struct LastFrame {
    index: usize,
    pose: Pose,
    /// The frame whose keypoints `features` are: `index`, or an earlier frame when the
    /// frames since were lost or tracked without keypoints.
    detected: usize,
    /// The frame whose image `features.points` are in: `detected`, or a later frame the
    /// keypoints were followed to by optical flow (monocular).
    seen: usize,
    features: KeyFeatures,
    world: Vec<Option<Point3<f64>>>,
}

/// Counters of tracking trouble, with frame indices.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct TrackingCounters {
    /// Frames whose guided tracking failed.
    pub failures: Vec<usize>,
    /// ... of which relocalised against a keyframe.
    pub relocalised: Vec<usize>,
    /// ... of which kept the constant-velocity pose.
    pub lost: Vec<usize>,
    /// Frames where a keyframe was started after a lost streak.
    pub reinitialised: Vec<usize>,
    /// RGB-D mode: frames whose pose the dense refinement against the reference keyframe's
    /// depth replaced ([`super::depth_alignment`]) ...
    #[serde(default)]
    pub dense_kept: usize,
    /// ... and frames where it ran but did not agree with the keypoints or failed.
    #[serde(default)]
    pub dense_rejected: usize,
    /// `dense.frame_graph`: frames whose alignment to the previous frame was kept.
    #[serde(default)]
    pub frame_steps: usize,
    /// `tracking.keypoints_every_frame = false`: frames tracked by the dense alignment alone,
    /// with no keypoints detected.
    #[serde(default)]
    pub without_keypoints: usize,
    /// Frames due to be keyframes by the frame count (`keyframes.max_frames_depth_tracked` or
    /// `max_frames_flow_tracked` after the reference keyframe) whose keypoints a feature
    /// worker detected ahead of tracking ...
    #[serde(default)]
    pub detected_ahead: usize,
    /// ... of which tracking did not use (an earlier keyframe had moved the due frame on).
    #[serde(default)]
    pub detected_ahead_unused: usize,
}

/// Scales of the image pyramid of monocular tracking by optical flow (640x480 down to 160x120).
const FLOW_LEVELS: usize = 3;

/// `dense.frame_graph`: a frame's depth is kept every this many pixels as the next frame's
/// model, and the next frame is aligned to it by the first (coarsest) of `dense.levels` with
/// this many Gauss-Newton iterations: it starts from both frames' refined poses, close
/// already. On fr1_rpy 0-79 with ORB keypoints, 1.3 ms a frame against 12 ms with the model
/// every second pixel, both levels and 10 iterations, for the same per-frame RPE (0.0055 m);
/// the model every second pixel with this alignment is closer on exact synthetic depth but
/// slowed ORB's tracking below its target (lab/notes/slam-results.md, "Frames placed by frame-to-frame depth").
const FRAME_MODEL_STEP: usize = 4;
const FRAME_ITERATIONS: usize = 3;

/// The tracking stage.
pub(crate) struct Tracker {
    cfg: SlamConfig,
    camera: Camera,
    monocular: bool,
    keyframes: Vec<TrackedKeyframe>,
    reference: Option<usize>,
    last: Option<LastFrame>,
    /// `T_{k-1}⁻¹ T_k` of the last tracked frame.
    velocity: Pose,
    lost_streak: usize,
    /// The reference keyframe's depth for the dense refinement, with its keyframe id.
    dense_model: Option<(usize, DepthModel)>,
    /// `dense.frame_graph`: the last frame's depth with its index and odometry pose.
    frame_model: Option<(usize, Pose, DepthModel)>,
    /// `dense.frame_graph`: the alignment settings of a frame-to-frame step (`dense` at its
    /// first level, [`FRAME_ITERATIONS`]).
    step_alignment: DenseConfig,
    /// The camera's pixel rays for the dense refinement, made at the first RGB-D keyframe.
    rays: Option<Arc<RayTable>>,
    /// Monocular tracking by optical flow: the image pyramid of the last frame's keypoints
    /// (`LastFrame::seen`), with its index.
    flow_image: Option<(usize, Pyramid)>,
    /// Tracking trouble so far.
    pub counters: TrackingCounters,
}

impl Tracker {
    /// A tracker with no keyframe yet; `monocular`: no sensor depth (depth from mapping).
    pub fn new(cfg: SlamConfig, camera: Camera, monocular: bool) -> Self {
        let step_alignment = DenseConfig {
            levels: cfg.dense.levels.iter().take(1).cloned().collect(),
            iterations: FRAME_ITERATIONS,
            ..cfg.dense.clone()
        };
        Tracker {
            step_alignment,
            cfg,
            camera,
            monocular,
            keyframes: Vec::new(),
            reference: None,
            last: None,
            velocity: Pose::identity(),
            lost_streak: 0,
            dense_model: None,
            frame_model: None,
            rays: None,
            flow_image: None,
            counters: TrackingCounters::default(),
        }
    }

    /// Number of keyframes created.
    pub fn n_keyframes(&self) -> usize {
        self.keyframes.len()
    }

    fn depth_range(&self) -> (f64, f64) {
        (self.cfg.tracking.min_depth, self.cfg.tracking.max_depth)
    }

    /// Which readings give a keypoint its 3D point.
    fn keypoint_depth(&self) -> KeypointDepth {
        KeypointDepth::from_config(&self.cfg.tracking)
    }

    /// Monocular mode: the keyframe's 3D points from predicted depth, sent back by
    /// the mapping stage (Fig. 1: "passes depth information to the camera pose
    /// module").
    pub fn update_keyframe(&mut self, id: usize, data: Arc<KeyframeFeatures>) {
        let Some(kf) = self.keyframes.get_mut(id) else {
            return;
        };
        kf.data = data;
        if let Some(last) = &mut self.last
            && last.detected == kf.frame_index
        {
            last.world = kf
                .data
                .points_cam
                .iter()
                .map(|p| p.map(|p| kf.pose * p))
                .collect();
        }
    }

    /// The constant-velocity pose of frame `index` from frame `from` at `pose`, the velocity
    /// applied once per frame of the gap (skipped frames).
    fn predict(&self, pose: Pose, from: usize, index: usize) -> Pose {
        let gap = index.saturating_sub(from).max(1);
        (0..gap).fold(pose, |p, _| renormalized(&(p * self.velocity)))
    }

    /// Whether `keyframes.max_frames` frames (`max_frames_depth_tracked` where frames are
    /// tracked by their depth alone, `max_frames_flow_tracked` by optical flow) have passed
    /// since the reference keyframe.
    fn keyframe_due_by_count(&self, reference: usize, index: usize) -> bool {
        let rules = &self.cfg.keyframes;
        let max = if self.needs_keypoints_every_frame() {
            rules.max_frames
        } else if self.monocular {
            rules.max_frames_flow_tracked
        } else {
            rules.max_frames_depth_tracked
        };
        index.saturating_sub(self.keyframes[reference].frame_index) >= max
    }

    /// The frame at which the next keyframe is due by the frame count
    /// (`keyframes.max_frames_depth_tracked` or `max_frames_flow_tracked` after the reference
    /// keyframe's frame) when frames between keyframes are tracked without keypoints; `None`
    /// when every frame needs its keypoints or there is no reference keyframe yet. Such a
    /// frame is declined by [`Self::track_without_keypoints`] whatever its motion, so its
    /// keypoints can be detected before it is tracked.
    pub fn frame_due_by_count(&self) -> Option<usize> {
        if self.needs_keypoints_every_frame() {
            return None;
        }
        let rules = &self.cfg.keyframes;
        let max = if self.monocular {
            rules.max_frames_flow_tracked
        } else {
            rules.max_frames_depth_tracked
        };
        Some(self.keyframes[self.reference?].frame_index + max)
    }

    /// Whether the motion rules (`keyframes.max_*`) make frame `index` a keyframe, `since`
    /// being its pose in the reference keyframe's frame.
    fn motion_wants_keyframe(&self, since: &Pose, reference: usize, index: usize) -> bool {
        let rules = &self.cfg.keyframes;
        since.translation.vector.norm() > rules.max_translation
            || since.rotation.angle().to_degrees() > rules.max_rotation_deg
            || self.keyframe_due_by_count(reference, index)
    }

    /// Whether every frame needs its keypoints before it is tracked (else they are detected
    /// only when [`Self::track_without_keypoints`] declines the frame).
    pub fn needs_keypoints_every_frame(&self) -> bool {
        let tracking = &self.cfg.tracking;
        tracking.keypoints_every_frame
            || if self.monocular {
                !tracking.monocular_flow
            } else {
                !self.cfg.dense.enabled
            }
    }

    /// Whether frames between keyframes are followed by optical flow (monocular,
    /// `tracking.monocular_flow`): [`Self::track_without_keypoints`] then wants
    /// each frame's image pyramid, and [`Self::keep_image`] after each frame.
    pub fn tracks_by_flow(&self) -> bool {
        self.monocular && !self.needs_keypoints_every_frame()
    }

    /// The image pyramid [`Self::track_without_keypoints`] and [`Self::keep_image`] want of a
    /// frame's grey image when [`Self::tracks_by_flow`].
    pub fn flow_pyramid(gray: &image::GrayImage) -> Pyramid {
        Pyramid::new(gray, FLOW_LEVELS)
    }

    /// Keeps frame `index`'s image pyramid when the last frame's keypoints are in it (a frame
    /// tracked by its keypoints or followed by flow; not a lost one), for the next frame's
    /// optical flow.
    pub fn keep_image(&mut self, index: usize, pyramid: Pyramid) {
        if self.last.as_ref().is_some_and(|l| l.seen == index) {
            self.flow_image = Some((index, pyramid));
        }
    }

    /// `tracking.keypoints_every_frame = false` (RGB-D): tracks a frame by the dense alignment
    /// alone against its reference keyframe's depth, from the constant-velocity pose, when that
    /// is enough: the alignment passes the refinement's gates against the prediction
    /// (`dense.min_inlier_fraction`, `dense.agree_*`) and the frame is not due to become a
    /// keyframe (`keyframes.max_*`). Monocular runs with `tracking.monocular_flow` follow the
    /// last keypoints by optical flow instead ([`Self::track_by_flow`], from `image`, the
    /// frame's [`Self::flow_pyramid`]). `None`: the frame needs its keypoints ([`Self::track`]).
    pub fn track_without_keypoints(
        &mut self,
        index: usize,
        stamp: f64,
        depth: Option<&DepthImage>,
        image: Option<&Pyramid>,
    ) -> Option<TrackOutput> {
        if self.needs_keypoints_every_frame() {
            return None;
        }
        if self.monocular {
            return self.track_by_flow(index, stamp, image?);
        }
        let cfg = &self.cfg;
        let depth = depth?;
        let reference = self.reference?;
        let last = self.last.as_ref()?;
        let (id, model) = self.dense_model.as_ref()?;
        // A keyframe due by the frame count needs its keypoints whatever the alignment says.
        if *id != reference || self.lost_streak > 0 || self.keyframe_due_by_count(reference, index)
        {
            return None;
        }
        let predicted = self.predict(last.pose, last.index, index);
        let kf_pose = self.keyframes[reference].pose;
        let initial = kf_pose.inverse() * predicted;
        let since = align(model, depth, &initial, self.depth_range(), &cfg.dense)
            .filter(|a| a.passes_frame_gates(&initial, &cfg.dense))
            .map(|a| renormalized(&a.pose))?;
        if self.motion_wants_keyframe(&since, reference, index) {
            return None;
        }
        let pose = renormalized(&(kf_pose * since));
        self.velocity = renormalized(&(last.pose.inverse() * pose));
        self.counters.dense_kept += 1;
        self.counters.without_keypoints += 1;
        // The last frame with keypoints stays the previous frame to match against (its
        // points are in the world frame); only the pose and index move on.
        if let Some(last) = &mut self.last {
            last.pose = pose;
            last.index = index;
        }
        let mut record =
            FrameRecord::tracked_without_keypoints(index, stamp, reference, since, pose);
        record.dense = true;
        if self.cfg.dense.frame_graph {
            self.frame_step(&mut record, Some(depth));
        }
        Some(TrackOutput {
            record,
            keyframe: None,
            events: Vec::new(),
        })
    }

    /// Monocular, `tracking.monocular_flow`: follows the last frame's keypoints
    /// that have map points into this frame by pyramidal Lucas-Kanade optical flow
    /// ([`optical_flow::track`], each started where the constant-velocity pose projects its map
    /// point) and places the frame by PnP on them, when that is enough: at least
    /// `keyframes.min_inliers` inliers and no `keyframes.max_*` rule due. The inliers become
    /// the last frame's keypoints, at their new places. `None`: the frame needs its keypoints
    /// ([`Self::track`]).
    fn track_by_flow(&mut self, index: usize, stamp: f64, image: &Pyramid) -> Option<TrackOutput> {
        let reference = self.reference?;
        let last = self.last.as_ref()?;
        let (seen, from) = self.flow_image.as_ref()?;
        if *seen != last.seen
            || self.lost_streak > 0
            || self.keyframe_due_by_count(reference, index)
        {
            return None;
        }
        let min = self.cfg.keyframes.min_inliers.max(4);
        let predicted = self.predict(last.pose, last.index, index);
        let to_camera = predicted.inverse();
        let followed: Vec<(usize, Point3<f64>)> = last
            .world
            .iter()
            .enumerate()
            .filter_map(|(k, w)| w.map(|w| (k, w)))
            .collect();
        if followed.len() < min {
            return None;
        }
        let points: Vec<[f32; 2]> = followed
            .iter()
            .map(|&(k, _)| last.features.points[k])
            .collect();
        let guesses: Vec<[f32; 2]> = followed
            .iter()
            .zip(&points)
            .map(|((_, w), p)| {
                self.camera
                    .project(&(to_camera * w))
                    .map_or([0.0; 2], |q| [q.x as f32 - p[0], q.y as f32 - p[1]])
            })
            .collect();
        let moved =
            optical_flow::track(from, image, &points, Some(&guesses), &FlowParams::default());
        let kept: Vec<(usize, Point3<f64>, [f32; 2])> = followed
            .iter()
            .zip(&moved)
            .filter_map(|(&(k, w), q)| q.map(|q| (k, w, q)))
            .collect();
        if kept.len() < min {
            return None;
        }
        let world: Vec<Point3<f64>> = kept.iter().map(|k| k.1).collect();
        let pixels: Vec<Point2<f64>> = kept
            .iter()
            .map(|k| Point2::new(f64::from(k.2[0]), f64::from(k.2[1])))
            .collect();
        let pnp = self.cfg.pnp.pnp();
        let result =
            solve_pnp_ransac(&world, &pixels, &self.camera, Some(&to_camera), &pnp).ok()?;
        if result.n_inliers < min {
            return None;
        }
        let pose = renormalized(&result.pose.inverse());
        let since = self.keyframes[reference].pose.inverse() * pose;
        if self.motion_wants_keyframe(&since, reference, index) {
            return None;
        }
        self.velocity = renormalized(&(last.pose.inverse() * pose));
        self.counters.without_keypoints += 1;
        let last = self.last.as_mut()?;
        let mut world = vec![None; last.world.len()];
        for ((k, w, q), _) in kept
            .iter()
            .zip(&result.inliers)
            .filter(|(_, inlier)| **inlier)
        {
            last.features.points[*k] = *q;
            world[*k] = Some(*w);
        }
        last.world = world;
        last.pose = pose;
        last.index = index;
        last.seen = index;
        let mut record =
            FrameRecord::tracked_without_keypoints(index, stamp, reference, since, pose);
        (record.inliers, record.correspondences) = (result.n_inliers, kept.len());
        Some(TrackOutput {
            record,
            keyframe: None,
            events: Vec::new(),
        })
    }

    /// Tracks one frame.
    pub fn track(&mut self, input: TrackInput<'_>) -> TrackOutput {
        let depth = input.depth;
        let mut out = self.track_frame(input);
        if self.cfg.dense.frame_graph && !self.monocular {
            self.frame_step(&mut out.record, depth);
        }
        out
    }

    /// `dense.frame_graph`: the frame's depth aligned to the previous frame's
    /// ([`FRAME_MODEL_STEP`]), from the tracked step between the two, kept in the record when
    /// it passes the refinement's gates (`dense.min_inlier_fraction`, `dense.agree_*`); then
    /// the frame's depth becomes the next frame's model. Lost frames break the chain.
    fn frame_step(&mut self, record: &mut FrameRecord, depth: Option<&DepthImage>) {
        let previous = self.frame_model.take();
        let Some(depth) = depth.filter(|_| record.status != FrameStatus::Lost) else {
            return;
        };
        let range = self.depth_range();
        if let Some((index, pose, model)) = previous {
            let initial = pose.inverse() * record.odom_pose;
            let kept = align(&model, depth, &initial, range, &self.step_alignment)
                .filter(|a| a.passes_frame_gates(&initial, &self.cfg.dense))
                .map(|a| renormalized(&a.pose));
            self.counters.frame_steps += kept.is_some() as usize;
            record.step = kept.map(|step| (index, step));
        }
        let camera = &self.camera;
        let rays = self
            .rays
            .get_or_insert_with(|| Arc::new(RayTable::new(camera, 1)));
        self.frame_model = DepthModel::new(depth, camera, rays.clone(), FRAME_MODEL_STEP, range)
            .map(|model| (record.index, record.odom_pose, model));
    }

    fn track_frame(&mut self, input: TrackInput<'_>) -> TrackOutput {
        let mut events = Vec::new();
        let Some(reference) = self.reference else {
            return self.start(input, None, FrameStatus::Initialised, events);
        };
        let (last_pose, last_index) = match &self.last {
            Some(l) => (l.pose, l.index),
            None => (self.keyframes[reference].pose, input.index),
        };
        let predicted = self.predict(last_pose, last_index, input.index);
        let mut status = FrameStatus::Tracked;
        let mut reference_now = reference;
        let guided = self.guided(&input.features, reference, &predicted);
        let mut tracked = guided.filter(|(r, _)| r.n_inliers >= self.cfg.pnp.min_inliers);
        if tracked.is_none() {
            self.counters.failures.push(input.index);
            match self.relocalise(&input.features, reference, &predicted) {
                Some((kf, r, c)) => {
                    status = FrameStatus::Relocalised;
                    self.counters.relocalised.push(input.index);
                    events.push(format!(
                        "frame {}: tracking lost, relocalised against keyframe {kf} ({} inliers)",
                        input.index, r.n_inliers
                    ));
                    reference_now = kf;
                    tracked = Some((r, c));
                }
                None => {
                    self.counters.lost.push(input.index);
                    events.push(format!(
                        "frame {}: tracking lost, keeping the constant-velocity pose",
                        input.index
                    ));
                }
            }
        }
        let Some((result, corr)) = tracked else {
            return self.lost(input, predicted, reference, events);
        };
        self.lost_streak = 0;
        self.reference = Some(reference_now);
        let mut pose = result.pose.inverse();
        let mut dense = false;
        if let Some(refined) = self.refine_dense(&input, reference_now, &pose) {
            pose = refined;
            dense = true;
        }
        // The PnP inliers against the reference keyframe: they decide on a new keyframe
        // and, kept in the frame's record, refine it after bundle adjustment.
        let gate = self.keypoint_depth();
        let observations: Vec<FrameObservation> = (0..corr.world.len())
            .filter(|&k| result.inliers[k] && corr.from_reference[k])
            .map(|k| {
                let pixel = input.features.points[corr.current[k]];
                FrameObservation {
                    keypoint: corr.source[k] as u32,
                    pixel,
                    depth: input
                        .depth
                        .filter(|_| !self.monocular)
                        .and_then(|d| gate.at(d, pixel[0] as f64, pixel[1] as f64)),
                }
            })
            .collect();
        let ref_inliers = observations.len();
        let inliers = result.n_inliers;
        // The frame's own 3D points: sensor depth, or the inliers' map points.
        let world: Vec<Option<Point3<f64>>> = if self.monocular {
            let mut w = vec![None; input.features.len()];
            for k in 0..corr.world.len() {
                if result.inliers[k] {
                    w[corr.current[k]] = Some(corr.world[k]);
                }
            }
            w
        } else {
            points_from_depth(&input.features, input.depth, &self.camera, gate)
                .into_iter()
                .map(|p| p.map(|p| pose * p))
                .collect()
        };
        self.velocity = renormalized(&(last_pose.inverse() * pose));
        let kf_pose = self.keyframes[reference_now].pose;
        let since = kf_pose.inverse() * pose;
        let wants_keyframe = ref_inliers < self.cfg.keyframes.min_inliers
            || self.motion_wants_keyframe(&since, reference_now, input.index);
        let can = self.monocular || input.depth.is_some();
        if wants_keyframe && can {
            let mut out = self.start(input, Some(pose), status, events);
            out.record.inliers = inliers;
            out.record.correspondences = corr.world.len();
            return out;
        }
        let record = FrameRecord {
            index: input.index,
            stamp: input.stamp,
            status,
            keyframe: None,
            reference: Some(reference_now),
            relative: since,
            odom_pose: pose,
            inliers,
            correspondences: corr.world.len(),
            observations,
            dense,
            step: None,
        };
        self.last = Some(LastFrame {
            index: input.index,
            pose,
            detected: input.index,
            seen: input.index,
            features: input.features,
            world,
        });
        TrackOutput {
            record,
            keyframe: None,
            events,
        }
    }

    /// Makes the frame a keyframe at `pose` (or at the start pose: ground truth
    /// of the first frame when configured, else the identity).
    fn start(
        &mut self,
        input: TrackInput<'_>,
        pose: Option<Pose>,
        status: FrameStatus,
        mut events: Vec<String>,
    ) -> TrackOutput {
        let first = self.keyframes.is_empty();
        let pose = pose.unwrap_or_else(|| {
            if first && self.cfg.tracking.start_at_ground_truth {
                input.gt_pose.unwrap_or_else(Pose::identity)
            } else {
                Pose::identity()
            }
        });
        if !self.monocular && input.depth.is_none() {
            events.push(format!(
                "frame {}: no depth image, cannot start a keyframe",
                input.index
            ));
            self.counters.lost.push(input.index);
            return TrackOutput {
                record: FrameRecord {
                    index: input.index,
                    stamp: input.stamp,
                    status: FrameStatus::Lost,
                    keyframe: None,
                    reference: None,
                    relative: pose,
                    odom_pose: pose,
                    inliers: 0,
                    correspondences: 0,
                    observations: Vec::new(),
                    dense: false,
                    step: None,
                },
                keyframe: None,
                events,
            };
        }
        let depth = if self.monocular { None } else { input.depth };
        let id = self.keyframes.len();
        self.dense_model = None;
        if let Some(d) = depth.filter(|_| self.cfg.dense.enabled) {
            let camera = &self.camera;
            let rays = self
                .rays
                .get_or_insert_with(|| Arc::new(RayTable::new(camera, 1)));
            let step = self.cfg.dense.model_step;
            self.dense_model = DepthModel::new(d, camera, rays.clone(), step, self.depth_range())
                .map(|model| (id, model));
        }
        let data = Arc::new(KeyframeFeatures::new(
            input.features.clone(),
            depth,
            &self.camera,
            self.keypoint_depth(),
        ));
        let world = data
            .points_cam
            .iter()
            .map(|p| p.map(|p| pose * p))
            .collect();
        self.keyframes.push(TrackedKeyframe {
            frame_index: input.index,
            pose,
            data: data.clone(),
        });
        self.reference = Some(id);
        self.lost_streak = 0;
        if let Some(last) = &self.last {
            self.velocity = renormalized(&(last.pose.inverse() * pose));
        }
        if status == FrameStatus::Lost {
            self.counters.reinitialised.push(input.index);
            events.push(format!(
                "frame {}: lost for {} frames, restarting from keyframe {id} at the predicted pose",
                input.index, self.cfg.tracking.reinitialise_after
            ));
        }
        let record = FrameRecord {
            index: input.index,
            stamp: input.stamp,
            status,
            keyframe: Some(id),
            reference: Some(id),
            relative: Pose::identity(),
            odom_pose: pose,
            inliers: 0,
            correspondences: 0,
            observations: Vec::new(),
            dense: false,
            step: None,
        };
        self.last = Some(LastFrame {
            index: input.index,
            pose,
            detected: input.index,
            seen: input.index,
            features: input.features,
            world,
        });
        TrackOutput {
            record,
            keyframe: Some(NewKeyframe {
                id,
                frame_index: input.index,
                stamp: input.stamp,
                pose,
                gt_pose: input.gt_pose,
                track: data,
            }),
            events,
        }
    }

    /// RGB-D mode: `pose` (world from frame, from the keypoints) refined against the reference
    /// keyframe's depth, when the refinement runs, pairs enough of the frame's points and
    /// stays within `dense.agree_*` of `pose`; `None` otherwise. Frames tracked against an
    /// older keyframe after relocalisation are not refined (nor counted) until the next
    /// keyframe: only the newest keyframe's depth is kept.
    fn refine_dense(
        &mut self,
        input: &TrackInput<'_>,
        reference: usize,
        pose: &Pose,
    ) -> Option<Pose> {
        let cfg = &self.cfg.dense;
        let depth = input.depth.filter(|_| cfg.enabled && !self.monocular)?;
        let (id, model) = self.dense_model.as_ref()?;
        if *id != reference {
            return None;
        }
        let kf_pose = self.keyframes[reference].pose;
        let initial = kf_pose.inverse() * pose;
        let kept = align(model, depth, &initial, self.depth_range(), cfg)
            .filter(|a| a.passes_frame_gates(&initial, cfg))
            .map(|a| a.pose);
        match kept {
            Some(refined) => {
                self.counters.dense_kept += 1;
                Some(renormalized(&(kf_pose * refined)))
            }
            None => {
                self.counters.dense_rejected += 1;
                None
            }
        }
    }

    fn lost(
        &mut self,
        input: TrackInput<'_>,
        predicted: Pose,
        reference: usize,
        events: Vec<String>,
    ) -> TrackOutput {
        self.lost_streak += 1;
        let after = self.cfg.tracking.reinitialise_after;
        if after > 0 && self.lost_streak >= after {
            return self.start(input, Some(predicted), FrameStatus::Lost, events);
        }
        let record = FrameRecord {
            index: input.index,
            stamp: input.stamp,
            status: FrameStatus::Lost,
            keyframe: None,
            reference: Some(reference),
            relative: self.keyframes[reference].pose.inverse() * predicted,
            odom_pose: predicted,
            inliers: 0,
            correspondences: 0,
            observations: Vec::new(),
            dense: false,
            step: None,
        };
        // Keep the last good frame for matching; only its pose moves on.
        if let Some(last) = &mut self.last {
            last.pose = predicted;
            last.index = input.index;
        }
        TrackOutput {
            record,
            keyframe: None,
            events,
        }
    }

    /// Range matching against the reference keyframe (and the previous frame)
    /// with windows centred on the predicted positions, then PnP + RANSAC with
    /// the prediction scored first.
    fn guided(
        &self,
        current: &KeyFeatures,
        reference: usize,
        predicted: &Pose,
    ) -> Option<(PnpResult, Correspondences)> {
        let kf = &self.keyframes[reference];
        let kf_world: Vec<Option<Point3<f64>>> = kf
            .data
            .points_cam
            .iter()
            .map(|p| p.map(|p| kf.pose * p))
            .collect();
        let mut sources = vec![Source {
            features: &kf.data.features,
            world: &kf_world,
            reference: true,
        }];
        let prev = self
            .last
            .as_ref()
            .filter(|l| self.cfg.tracking.match_previous_frame && l.detected != kf.frame_index);
        if let Some(l) = prev {
            sources.push(Source {
                features: &l.features,
                world: &l.world,
                reference: false,
            });
        }
        let guide = self.cfg.matcher.predict_window.then_some(predicted);
        let corr = self.correspond(&sources, current, guide, &self.cfg.matcher.range());
        let result = self.pnp(&corr, Some(predicted))?;
        Some((result, corr))
    }

    /// Relocalisation: the reference keyframe, then those with the most similar
    /// signatures, matched with the wide window; the best PnP wins.
    fn relocalise(
        &self,
        current: &KeyFeatures,
        reference: usize,
        predicted: &Pose,
    ) -> Option<(usize, PnpResult, Correspondences)> {
        let signature = current.mean_descriptor();
        let mut ranked: Vec<(f32, usize)> = (0..self.keyframes.len())
            .filter(|&k| k != reference)
            .map(|k| (similarity(&signature, &self.keyframes[k].data.signature), k))
            .collect();
        ranked.sort_by(|a, b| b.0.total_cmp(&a.0).then(b.1.cmp(&a.1)));
        let candidates = std::iter::once(reference).chain(
            ranked
                .into_iter()
                .take(self.cfg.tracking.relocalisation_candidates)
                .map(|r| r.1),
        );
        let mut best: Option<(usize, PnpResult, Correspondences)> = None;
        for k in candidates {
            let kf = &self.keyframes[k];
            let world: Vec<Option<Point3<f64>>> = kf
                .data
                .points_cam
                .iter()
                .map(|p| p.map(|p| kf.pose * p))
                .collect();
            let corr = self.correspond(
                &[Source {
                    features: &kf.data.features,
                    world: &world,
                    reference: true,
                }],
                current,
                None,
                &self.cfg.matcher.wide(),
            );
            let prior = (k == reference).then_some(predicted);
            if let Some(r) = self.pnp(&corr, prior)
                && r.n_inliers >= self.cfg.pnp.min_inliers
                && best.as_ref().is_none_or(|b| r.n_inliers > b.1.n_inliers)
            {
                best = Some((k, r, corr));
            }
        }
        best
    }

    fn pnp(&self, corr: &Correspondences, predicted: Option<&Pose>) -> Option<PnpResult> {
        if corr.world.len() < self.cfg.pnp.min_inliers.max(4) {
            return None;
        }
        let prior = predicted.map(|p| p.inverse());
        solve_pnp_ransac(
            &corr.world,
            &corr.pixels,
            &self.camera,
            prior.as_ref(),
            &self.cfg.pnp.pnp(),
        )
        .ok()
    }

    /// Matches each source's keypoints that have world points to the current
    /// keypoints; a current keypoint keeps its nearest-descriptor match.
    fn correspond(
        &self,
        sources: &[Source<'_>],
        current: &KeyFeatures,
        guide: Option<&Pose>,
        cfg: &RangeMatcherConfig,
    ) -> Correspondences {
        correspond(&self.camera, sources, current, guide, cfg)
    }
}
