//! The SDF-SLAM system (section IV-A, Fig. 1): tracking (camera pose
//! estimation), mapping (SDFCNN semantics + fusion into the 3D semantic map) and
//! data correction run as separate threads passing messages over channels
//! around the shared [`Map`]; or, for tests, the same stages in order on one
//! thread. Both orders give the same trajectory and map: tracking never reads
//! corrected poses, correction candidates depend only on earlier keyframes, and
//! the final pose graph is solved from the tracked poses with all constraints.

use super::config::SlamConfig;
use super::correction::{CorrectionStats, Corrector, LocalSummary, local_correction};
use super::depth_edges::drop_depth_edges;
use super::keypoints::KeypointSource;
use super::map::{KeyFrame, KeyframeFeatures, KeyframeView, Map, SharedMap, read, write};
use super::multiview_depth::{GrayView, SweepReference, SweepSummary, merge_measured, sweep_depth};
use super::semantic_map::SemanticMap;
use super::semantic_source::{SemanticInput, SemanticSource};
use super::tracking::{
    FrameRecord, FrameStatus, NewKeyframe, TrackInput, Tracker, TrackingCounters,
};
use crate::camera::Camera;
use crate::dataset::{DepthImage, LabelImage, TumSequence};
use crate::error::{Error, Result};
use crate::features::orb::rgb_to_gray;
use crate::geometry::{Pose, renormalized};
use crate::trajectory::Trajectory;
use image::RgbImage;
use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, sync_channel};
use std::sync::{Arc, RwLock};
use std::time::Instant;

/// Where depth comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DepthMode {
    /// RGB-D: the sequence's depth images.
    Sensor,
    /// Monocular: depth predicted by the semantic source (SDFCNN).
    Predicted,
}

/// A message sink for warnings and events (the progress bar prints them
/// without breaking its line).
pub type Log = Arc<dyn Fn(&str) + Send + Sync>;

/// A log that prints to standard error.
pub fn stderr_log() -> Log {
    Arc::new(|m: &str| eprintln!("{m}"))
}

/// Time spent in a stage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTime {
    pub seconds: f64,
    pub calls: usize,
}

impl StageTime {
    pub fn add(&mut self, since: Instant) {
        self.seconds += since.elapsed().as_secs_f64();
        self.calls += 1;
    }

    /// Calls per second of stage time.
    pub fn rate(&self) -> f64 {
        if self.seconds > 0.0 {
            self.calls as f64 / self.seconds
        } else {
            0.0
        }
    }
}

/// Time per stage.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    /// Decoding images.
    pub load: StageTime,
    /// Keypoints and descriptors (FPFDCNN or ORB).
    pub features: StageTime,
    /// Matching, PnP, keyframe decision.
    pub tracking: StageTime,
    /// Semantic source (SDFCNN) per keyframe.
    pub semantics: StageTime,
    /// Multi-view depth of monocular keyframes.
    pub multiview: StageTime,
    /// Fusion into the voxel map (including re-fusions).
    pub fusion: StageTime,
    /// Keyframe-pair verification.
    pub correction: StageTime,
    /// Pose-graph optimisations.
    pub optimisation: StageTime,
    /// Final optimisation, local correction and re-fusion.
    pub finalisation: StageTime,
}

impl Timings {
    /// `(name, time)` of every stage.
    pub fn stages(&self) -> [(&'static str, StageTime); 9] {
        [
            ("load", self.load),
            ("features", self.features),
            ("tracking", self.tracking),
            ("semantics", self.semantics),
            ("multiview", self.multiview),
            ("fusion", self.fusion),
            ("correction", self.correction),
            ("optimisation", self.optimisation),
            ("finalisation", self.finalisation),
        ]
    }
}

/// Progress after a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress {
    pub done: usize,
    pub total: usize,
    pub keyframes: usize,
    pub lost: usize,
}

/// Called after every frame.
pub type FrameCallback = Box<dyn FnMut(&FrameRecord, &Progress)>;

/// How a run is observed and stopped.
pub struct Control {
    /// Set it (Ctrl-C) to stop after the current frame; what was tracked is kept.
    pub stop: Arc<AtomicBool>,
    pub log: Log,
    /// Called on the calling thread after every frame.
    pub on_frame: Option<FrameCallback>,
}

impl Default for Control {
    fn default() -> Self {
        Control {
            stop: Arc::new(AtomicBool::new(false)),
            log: stderr_log(),
            on_frame: None,
        }
    }
}

/// Everything a run needs.
pub struct Slam {
    pub sequence: TumSequence,
    pub camera: Camera,
    pub config: SlamConfig,
    pub depth: DepthMode,
    pub keypoints: Box<dyn KeypointSource>,
    pub semantics: Box<dyn SemanticSource>,
    /// Process at most this many frames.
    pub max_frames: Option<usize>,
}

/// What a run produced.
pub struct SlamOutput {
    pub frames: Vec<FrameRecord>,
    pub map: Map,
    pub semantic_map: SemanticMap,
    /// Unified world points of local correction.
    pub landmarks: Vec<Point3<f64>>,
    pub local: LocalSummary,
    /// Multi-view depth of monocular keyframes, summed over keyframes.
    pub multiview: SweepSummary,
    pub tracking: TrackingCounters,
    pub correction: CorrectionStats,
    /// Frames that could not be read, with the reason.
    pub skipped: Vec<(usize, String)>,
    /// Keyframes whose semantic source failed (void labels used).
    pub semantic_failures: Vec<(usize, String)>,
    pub timings: Timings,
    pub wall_seconds: f64,
    pub interrupted: bool,
    /// Frames the run was asked to process.
    pub total_frames: usize,
    pub threads: bool,
    pub depth: DepthMode,
    pub keypoint_source: &'static str,
    pub semantic_source: &'static str,
}

impl SlamOutput {
    /// Final pose of a frame: its reference keyframe's corrected pose composed
    /// with the tracked relative pose.
    pub fn frame_pose(&self, r: &FrameRecord) -> Pose {
        match r.reference.and_then(|k| self.map.keyframes.get(k)) {
            Some(kf) => kf.pose * r.relative,
            None => r.odom_pose,
        }
    }

    /// Every processed frame, TUM convention.
    pub fn trajectory(&self) -> Trajectory {
        Trajectory {
            stamps: self.frames.iter().map(|r| r.stamp).collect(),
            poses: self.frames.iter().map(|r| self.frame_pose(r)).collect(),
        }
    }

    /// The keyframes' corrected poses.
    pub fn keyframe_trajectory(&self) -> Trajectory {
        Trajectory {
            stamps: self.map.keyframes.iter().map(|k| k.stamp).collect(),
            poses: self.map.keyframes.iter().map(|k| k.pose).collect(),
        }
    }

    /// Frames per second over the whole run.
    pub fn fps(&self) -> f64 {
        if self.wall_seconds > 0.0 {
            self.frames.len() as f64 / self.wall_seconds
        } else {
            0.0
        }
    }
}

/// A keyframe on its way to mapping, with its full-resolution images.
pub struct MapperInput {
    pub keyframe: NewKeyframe,
    pub rgb: RgbImage,
    /// Sensor depth (RGB-D).
    pub depth: Option<DepthImage>,
}

/// The mapping stage: semantics of each keyframe, insertion into the map,
/// fusion into the voxel grid. Keyframes that correction moved are re-fused a few
/// at a time (the most moved first: taken out at the pose they were fused with and
/// fused again at their new one), so the work per keyframe stays bounded; the final
/// map is re-fused from every final pose.
pub struct LocalMapper {
    cfg: SlamConfig,
    camera: Camera,
    monocular: bool,
    semantics: Box<dyn SemanticSource>,
    map: SharedMap,
    log: Log,
    pub semantic_map: SemanticMap,
    fused_epoch: u64,
    /// The pose and depth scale each keyframe was fused with.
    fused: Vec<(Pose, f64)>,
    pub failures: Vec<(usize, String)>,
    pub semantics_time: StageTime,
    pub multiview_time: StageTime,
    pub multiview: SweepSummary,
    /// Full-resolution grey images of the last `multiview.look_back` keyframes (monocular
    /// mode) with their index in the map: the references of multi-view depth.
    recent: VecDeque<(usize, Arc<GrayView>)>,
    pub fusion_time: StageTime,
}

impl LocalMapper {
    pub fn new(
        cfg: SlamConfig,
        camera: Camera,
        monocular: bool,
        semantics: Box<dyn SemanticSource>,
        map: SharedMap,
        log: Log,
    ) -> Self {
        let voxel = cfg.map.voxel_size;
        LocalMapper {
            cfg,
            camera,
            monocular,
            semantics,
            map,
            log,
            semantic_map: SemanticMap::new(voxel),
            fused_epoch: 0,
            fused: Vec::new(),
            failures: Vec::new(),
            semantics_time: StageTime::default(),
            multiview_time: StageTime::default(),
            multiview: SweepSummary::default(),
            recent: VecDeque::new(),
            fusion_time: StageTime::default(),
        }
    }

    /// Processes a keyframe; returns its features with 3D points from the
    /// depth used (predicted in monocular mode), for tracking.
    pub fn process(&mut self, input: MapperInput) -> Arc<KeyframeFeatures> {
        let kf = input.keyframe;
        let (w, h) = input.rgb.dimensions();
        let t = Instant::now();
        let sem = SemanticInput {
            index: kf.frame_index,
            stamp: kf.stamp,
            rgb: &input.rgb,
        };
        let (labels, predicted) = match self.semantics.predict(&sem) {
            Ok(r) => r,
            Err(e) => {
                let msg = e.to_string();
                (self.log)(&format!(
                    "warning: keyframe {} (frame {}): {} labels failed: {msg}; using void labels",
                    kf.id,
                    kf.frame_index,
                    self.semantics.name()
                ));
                self.failures.push((kf.frame_index, msg));
                (LabelImage::new(w, h, crate::dataset::labels::VOID), None)
            }
        };
        self.semantics_time.add(t);
        let depth = if self.monocular {
            predicted
        } else {
            input.depth
        };
        let mut depth = depth.unwrap_or_else(|| DepthImage::new(w, h));
        let track = if self.monocular {
            // The keypoints' 3D points come from the predicted depth.
            Arc::new(KeyframeFeatures::new(
                kf.track.features.clone(),
                Some(&depth),
                &self.camera,
                (self.cfg.tracking.min_depth, self.cfg.tracking.max_depth),
            ))
        } else {
            kf.track.clone()
        };
        drop_depth_edges(
            &mut depth,
            self.cfg.map.depth_edge_reach,
            self.cfg.map.depth_edge_ratio,
        );
        let mut view = KeyframeView::new(self.cfg.map.pixel_stride, &input.rgb, &depth, &labels);
        let mut gray = None;
        if self.monocular && self.cfg.multiview.references > 0 {
            let t = Instant::now();
            let g = Arc::new(GrayView::from_rgb(&input.rgb));
            self.measure_depth(&kf.pose, &g, &mut view);
            gray = Some(g);
            self.multiview_time.add(t);
        }
        let t = Instant::now();
        {
            let mut m = write(&self.map);
            let pose = corrected_pose(&m, &kf.pose);
            if let Some(g) = gray {
                self.recent.push_back((m.keyframes.len(), g));
                if self.recent.len() > self.cfg.multiview.look_back {
                    self.recent.pop_front();
                }
            }
            m.keyframes.push(KeyFrame {
                id: kf.id,
                frame_index: kf.frame_index,
                stamp: kf.stamp,
                odom_pose: kf.pose,
                pose,
                gt_pose: kf.gt_pose,
                track: track.clone(),
                view,
                depth_scale: 1.0,
            });
        }
        {
            let m = read(&self.map);
            if let Some(k) = m.keyframes.last() {
                self.semantic_map
                    .fuse(k, &k.pose, k.depth_scale, &self.camera, &self.cfg.map);
                self.fused.push((k.pose, k.depth_scale));
            }
        }
        self.refuse_moved(self.cfg.map.refuse_per_keyframe);
        self.fusion_time.add(t);
        track
    }

    /// Measures the depth of a monocular keyframe's view against earlier keyframes
    /// ([`super::multiview_depth`]); measured pixels replace the prediction in the view. The
    /// keypoints keep SDFCNN's depth, which re-anchors the scale at every keyframe (on the
    /// box room of `tests/slam_system.rs`, whose predicted depth is exact, measured
    /// keypoints tripled the ATE; on 7-Scenes 600-699 the map was as accurate either way).
    fn measure_depth(&mut self, odom_pose: &Pose, gray: &GrayView, view: &mut KeyframeView) {
        let mv = &self.cfg.multiview;
        let (pose, refs) = {
            let m = read(&self.map);
            let pose = corrected_pose(&m, odom_pose);
            let axis = pose.rotation * Vector3::z();
            let mut near: Vec<(f64, Arc<GrayView>, Pose)> = self
                .recent
                .iter()
                .filter_map(|(i, g)| {
                    let k = m.keyframes.get(*i)?;
                    let baseline = (k.pose.translation.vector - pose.translation.vector).norm();
                    let angle = (k.pose.rotation * Vector3::z()).angle(&axis).to_degrees();
                    (baseline >= mv.min_baseline && angle <= mv.max_angle_deg)
                        .then(|| (baseline, g.clone(), k.pose))
                })
                .collect();
            // The widest baselines first: depth from parallax is more precise.
            near.sort_by(|a, b| b.0.total_cmp(&a.0));
            near.truncate(mv.references);
            (pose, near)
        };
        if refs.is_empty() {
            return;
        }
        let references: Vec<SweepReference> = refs
            .iter()
            .map(|(_, image, pose)| SweepReference { image, pose: *pose })
            .collect();
        let stride = view.stride;
        let (measured, summary) = sweep_depth(
            gray,
            &pose,
            &view.depth,
            &references,
            &self.camera,
            stride,
            mv,
        );
        self.multiview.candidates += summary.candidates;
        self.multiview.confirmed += summary.confirmed;
        merge_measured(
            &mut view.depth,
            &measured,
            mv.keep_unconfirmed,
            mv.rescale_cells,
        );
    }

    /// How far a keyframe's fused view lies from where it is now, metres: the
    /// translation plus the rotation's arc at `max_depth`, and the depth-scale change
    /// at `max_depth`.
    fn displacement(&self, k: &KeyFrame, (pose, scale): &(Pose, f64)) -> f64 {
        let reach = self.cfg.map.max_depth;
        let d = pose.inverse() * k.pose;
        d.translation.vector.norm()
            + d.rotation.angle() * reach
            + (k.depth_scale - scale).abs() * reach
    }

    /// Re-fuses the (at most `limit`) keyframes that correction moved most, by more than a
    /// voxel, since they were fused.
    fn refuse_moved(&mut self, limit: usize) {
        let m = read(&self.map);
        if m.epoch == self.fused_epoch || limit == 0 {
            return;
        }
        let mut moved: Vec<(f64, usize)> = m
            .keyframes
            .iter()
            .zip(&self.fused)
            .enumerate()
            .map(|(i, (k, f))| (self.displacement(k, f), i))
            .filter(|(d, _)| *d > self.cfg.map.voxel_size)
            .collect();
        if moved.len() <= limit {
            // Everything moved is re-fused now: up to date with this correction.
            self.fused_epoch = m.epoch;
        }
        moved.sort_by(|a, b| b.0.total_cmp(&a.0));
        for &(_, i) in moved.iter().take(limit) {
            let (k, (pose, scale)) = (&m.keyframes[i], self.fused[i]);
            let cfg = &self.cfg.map;
            self.semantic_map.unfuse(k, &pose, scale, &self.camera, cfg);
            self.semantic_map
                .fuse(k, &k.pose, k.depth_scale, &self.camera, cfg);
            self.fused[i] = (k.pose, k.depth_scale);
        }
    }

    /// Rebuilds the voxel map from every keyframe's current pose and depth scale.
    pub fn refuse_all(&mut self) {
        let m = read(&self.map);
        self.semantic_map.clear();
        self.fused.clear();
        for k in &m.keyframes {
            self.semantic_map
                .fuse(k, &k.pose, k.depth_scale, &self.camera, &self.cfg.map);
            self.fused.push((k.pose, k.depth_scale));
        }
        self.fused_epoch = m.epoch;
    }
}

/// A keyframe's tracked pose made to follow the corrections made so far (those of the
/// last keyframe in the map).
fn corrected_pose(m: &Map, odom_pose: &Pose) -> Pose {
    match m.keyframes.last() {
        Some(last) => renormalized(&(last.pose * last.odom_pose.inverse() * odom_pose)),
        None => *odom_pose,
    }
}

/// A decoded frame.
struct Loaded {
    rgb: RgbImage,
    depth: Option<DepthImage>,
    stamp: f64,
    gt: Option<Pose>,
}

fn load(seq: &TumSequence, i: usize, monocular: bool) -> Result<Loaded> {
    if monocular {
        let rgb = seq.load_rgb(i)?;
        let stamp = seq.frames[i].rgb_stamp;
        Ok(Loaded {
            rgb,
            depth: None,
            stamp,
            gt: seq.gt_pose_at(stamp),
        })
    } else {
        let f = seq.load_frame(i)?;
        Ok(Loaded {
            rgb: f.rgb,
            depth: f.depth,
            stamp: f.stamp,
            gt: f.gt_pose,
        })
    }
}

/// What the tracking loop produced.
struct TrackingRun {
    tracker: Tracker,
    frames: Vec<FrameRecord>,
    skipped: Vec<(usize, String)>,
    load: StageTime,
    features: StageTime,
    tracking: StageTime,
    interrupted: bool,
}

/// The tracking stage over the frames: load, features, track; keyframes go to
/// `on_keyframe` (which may answer with predicted-depth 3D points), frames to
/// `on_frame`.
#[allow(clippy::too_many_arguments)]
fn tracking_loop(
    seq: &TumSequence,
    n: usize,
    tracker: Tracker,
    keypoints: &dyn KeypointSource,
    monocular: bool,
    stop: &AtomicBool,
    log: &Log,
    mut on_keyframe: impl FnMut(MapperInput) -> Option<Arc<KeyframeFeatures>>,
    mut on_frame: impl FnMut(&FrameRecord, Progress),
) -> TrackingRun {
    let mut run = TrackingRun {
        tracker,
        frames: Vec::new(),
        skipped: Vec::new(),
        load: StageTime::default(),
        features: StageTime::default(),
        tracking: StageTime::default(),
        interrupted: false,
    };
    let tracker = &mut run.tracker;
    for i in 0..n {
        if stop.load(Ordering::SeqCst) {
            run.interrupted = true;
            break;
        }
        let t = Instant::now();
        let frame = match load(seq, i, monocular) {
            Ok(f) => f,
            Err(e) => {
                log(&format!("warning: frame {i} skipped: {e}"));
                run.skipped.push((i, e.to_string()));
                continue;
            }
        };
        run.load.add(t);
        let t = Instant::now();
        let features = match keypoints.detect(&rgb_to_gray(&frame.rgb)) {
            Ok(f) => f,
            Err(e) => {
                log(&format!(
                    "warning: frame {i}: keypoints failed ({e}); no features"
                ));
                Default::default()
            }
        };
        run.features.add(t);
        let t = Instant::now();
        let out = tracker.track(TrackInput {
            index: i,
            stamp: frame.stamp,
            features,
            depth: frame.depth.as_ref(),
            gt_pose: frame.gt,
        });
        run.tracking.add(t);
        for e in &out.events {
            log(e);
        }
        if let Some(kf) = out.keyframe {
            let id = kf.id;
            let reply = on_keyframe(MapperInput {
                keyframe: kf,
                rgb: frame.rgb,
                depth: frame.depth,
            });
            if let Some(track) = reply {
                tracker.update_keyframe(id, track);
            }
        }
        let progress = Progress {
            done: i + 1,
            total: n,
            keyframes: tracker.n_keyframes(),
            lost: tracker.counters.lost.len(),
        };
        on_frame(&out.record, progress);
        run.frames.push(out.record);
    }
    run
}

fn panicked(stage: &str) -> Error {
    Error::msg(format!("the {stage} thread panicked"))
}

impl Slam {
    /// Checks the inputs before any frame is processed.
    pub fn validate(&self) -> Result<()> {
        match self.depth {
            DepthMode::Sensor if !self.sequence.has_depth() => Err(Error::invalid(
                &self.sequence.root,
                "RGB-D mode (--depth sensor) needs depth images, but the sequence has no depth.txt / associations.txt; use --depth predicted for monocular mode",
            )),
            DepthMode::Predicted if !self.semantics.provides_depth() => Err(Error::msg(format!(
                "monocular mode (--depth predicted) takes depth from the semantic source, but '{}' gives none: use --labels sdfcnn (or --labels gt on a synthetic sequence with depth_gt/)",
                self.semantics.name()
            ))),
            _ => Ok(()),
        }?;
        // One missing frame is skipped and counted; a sequence none of whose images exist
        // (a folder not copied, a wrong root) is an error before anything runs.
        let n = self
            .max_frames
            .map_or(self.sequence.len(), |m| m.min(self.sequence.len()));
        let frames = &self.sequence.frames[..n];
        let missing_all = |paths: Vec<&std::path::Path>, what: &str| -> Result<()> {
            match paths.first() {
                Some(first) if !paths.iter().any(|p| p.is_file()) => Err(Error::invalid(
                    first,
                    format!(
                        "none of the sequence's {} {what} images exists (this is the first one); is the folder missing?",
                        paths.len()
                    ),
                )),
                _ => Ok(()),
            }
        };
        missing_all(frames.iter().map(|f| f.rgb_path.as_path()).collect(), "RGB")?;
        if self.depth == DepthMode::Sensor {
            missing_all(
                frames
                    .iter()
                    .filter_map(|f| f.depth_path.as_deref())
                    .collect(),
                "depth",
            )?;
        }
        // A camera of another size than the images would map nothing (every pixel outside
        // the rays it was built for): an error before processing.
        if let Some(first) = frames.iter().find(|f| f.rgb_path.is_file())
            && let Ok((w, h)) = image::image_dimensions(&first.rgb_path)
            && (w, h) != (self.camera.width, self.camera.height)
        {
            return Err(Error::invalid(
                &first.rgb_path,
                format!(
                    "image is {w}x{h} but the camera is {}x{}: give the sequence's camera \
                     (--camera fr1|fr2|fr3|FILE, or a camera.toml in the sequence folder)",
                    self.camera.width, self.camera.height
                ),
            ));
        }
        Ok(())
    }

    /// Runs the system over the sequence.
    pub fn run(self, mut control: Control) -> Result<SlamOutput> {
        self.validate()?;
        let started = Instant::now();
        let Slam {
            sequence,
            camera,
            config,
            depth,
            keypoints,
            semantics,
            max_frames,
        } = self;
        let monocular = depth == DepthMode::Predicted;
        let n = max_frames.map_or(sequence.len(), |m| m.min(sequence.len()));
        let map: SharedMap = Arc::new(RwLock::new(Map::default()));
        let keypoint_source = keypoints.name();
        let semantic_source = semantics.name();
        let tracker = Tracker::new(config.clone(), camera.clone(), monocular);
        let mut mapper = LocalMapper::new(
            config.clone(),
            camera.clone(),
            monocular,
            semantics,
            map.clone(),
            control.log.clone(),
        );
        let mut corrector = Corrector::new(config.clone(), camera.clone());
        let mut timings = Timings::default();
        let online = config.correction.optimise_online;
        let log = control.log.clone();
        let stop = control.stop.clone();
        let mut on_frame = control.on_frame.take();
        let mut notify = |r: &FrameRecord, p: Progress| {
            if let Some(f) = on_frame.as_mut() {
                f(r, &p);
            }
        };
        let run = if config.system.threads {
            let (run, m, c, corr_time, opt_time) = std::thread::scope(|s| -> Result<_> {
                let (kf_tx, kf_rx) = sync_channel::<MapperInput>(config.system.queue);
                let (reply_tx, reply_rx) = channel::<Arc<KeyframeFeatures>>();
                let (corr_tx, corr_rx) = sync_channel::<usize>(config.system.queue * 4);
                // Bounded: tracking stays within two frames of the caller, so a
                // stop request (Ctrl-C) takes effect at once.
                let (ev_tx, ev_rx) = sync_channel::<(FrameRecord, Progress)>(2);
                let mapping = s.spawn(move || {
                    for input in kf_rx {
                        let id = input.keyframe.id;
                        let track = mapper.process(input);
                        if monocular && reply_tx.send(track).is_err() {
                            break;
                        }
                        if corr_tx.send(id).is_err() {
                            break;
                        }
                    }
                    mapper
                });
                let map_c = map.clone();
                let correction = s.spawn(move || {
                    let (mut ct, mut ot) = (StageTime::default(), StageTime::default());
                    for id in corr_rx {
                        let t = Instant::now();
                        let loops = corrector.add_keyframe(&map_c, id);
                        ct.add(t);
                        if loops && online {
                            let t = Instant::now();
                            corrector.optimise(&map_c);
                            ot.add(t);
                        }
                    }
                    (corrector, ct, ot)
                });
                let seq = &sequence;
                let (stop_t, log_t) = (stop.clone(), log.clone());
                let tracking = s.spawn(move || {
                    tracking_loop(
                        seq,
                        n,
                        tracker,
                        keypoints.as_ref(),
                        monocular,
                        &stop_t,
                        &log_t,
                        |input| {
                            kf_tx.send(input).ok()?;
                            if monocular {
                                reply_rx.recv().ok()
                            } else {
                                None
                            }
                        },
                        |r, p| {
                            let _ = ev_tx.send((r.clone(), p));
                        },
                    )
                });
                for (r, p) in ev_rx {
                    notify(&r, p);
                }
                let run = tracking.join().map_err(|_| panicked("tracking"))?;
                let m = mapping.join().map_err(|_| panicked("mapping"))?;
                let (c, ct, ot) = correction.join().map_err(|_| panicked("correction"))?;
                Ok((run, m, c, ct, ot))
            })?;
            mapper = m;
            corrector = c;
            timings.correction = corr_time;
            timings.optimisation = opt_time;
            run
        } else {
            let (mut ct, mut ot) = (StageTime::default(), StageTime::default());
            let run = tracking_loop(
                &sequence,
                n,
                tracker,
                keypoints.as_ref(),
                monocular,
                &stop,
                &log,
                |input| {
                    let id = input.keyframe.id;
                    let track = mapper.process(input);
                    let t = Instant::now();
                    let loops = corrector.add_keyframe(&map, id);
                    ct.add(t);
                    if loops && online {
                        let t = Instant::now();
                        corrector.optimise(&map);
                        ot.add(t);
                    }
                    monocular.then_some(track)
                },
                &mut notify,
            );
            timings.correction = ct;
            timings.optimisation = ot;
            run
        };
        timings.load = run.load;
        timings.features = run.features;
        timings.tracking = run.tracking;
        timings.semantics = mapper.semantics_time;
        // Final correction from all constraints, local correction, re-fusion.
        let t = Instant::now();
        corrector.optimise(&map);
        let (local, landmarks) = local_correction(&mut write(&map), &config, monocular);
        mapper.refuse_all();
        timings.finalisation.add(t);
        timings.fusion = mapper.fusion_time;
        timings.multiview = mapper.multiview_time;
        let LocalMapper {
            semantic_map,
            failures,
            multiview,
            ..
        } = mapper;
        let map = std::mem::take(&mut *write(&map));
        if run.interrupted {
            log(&format!(
                "interrupted after {} of {n} frames: writing what was tracked",
                run.frames.len()
            ));
        }
        Ok(SlamOutput {
            frames: run.frames,
            map,
            semantic_map,
            landmarks,
            local,
            multiview,
            tracking: run.tracker.counters.clone(),
            correction: corrector.stats,
            skipped: run.skipped,
            semantic_failures: failures,
            timings,
            wall_seconds: started.elapsed().as_secs_f64(),
            interrupted: run.interrupted,
            total_frames: n,
            threads: config.system.threads,
            depth,
            keypoint_source,
            semantic_source,
        })
    }
}

/// Frames with a given status.
pub fn count_status(frames: &[FrameRecord], status: FrameStatus) -> usize {
    frames.iter().filter(|f| f.status == status).count()
}
