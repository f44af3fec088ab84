//! The SDF-SLAM system (section IV-A, Fig. 1): tracking (camera pose
//! estimation), mapping (SDFCNN semantics + fusion into the 3D semantic map) and
//! data correction run as separate threads passing messages over channels
//! around the shared [`Map`]; or, for tests, the same stages in order on one
//! thread. Both orders give the same trajectory and map: tracking never reads
//! corrected poses, correction candidates depend only on earlier keyframes, and
//! the final pose graph is solved from the tracked poses with all constraints.

use super::bundle_adjustment::{BaSummary, refine_frames};
use super::colour_instant::move_to_colour_instants;
use super::config::{CorrectionConfig, SlamConfig};
use super::correction::{CorrectionStats, Corrector, LocalSummary, local_correction};
use super::frame_graph::place_frames;
use super::keyframe_alignment::{KeyframeAlignmentSummary, keyframe_edges};
use super::keypoints::KeypointSource;
use super::local_bundle_adjustment::LocalBaStats;
use super::local_mapper::{LocalMapper, MapperInput};
use super::map::{KeyframeFeatures, Map, SharedMap, read, write};
use super::multiview_depth::SweepSummary;
use super::repeated_images::{ImageKeys, RepeatCounts};
use super::semantic_map::SemanticMap;
use super::semantic_source::SemanticSource;
use super::tracking::{FrameRecord, FrameStatus, TrackInput, Tracker, TrackingCounters};
use crate::camera::Camera;
use crate::dataset::{DepthImage, TumSequence};
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::raster::rgb_to_gray;
use crate::trajectory::Trajectory;
use image::RgbImage;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, sync_channel};
use std::sync::{Arc, RwLock};
use std::time::{Duration, Instant};

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
        self.add_duration(since.elapsed());
    }

    pub fn add_duration(&mut self, d: Duration) {
        self.seconds += d.as_secs_f64();
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
    /// Local bundle adjustment per keyframe.
    #[serde(default)]
    pub local_adjustment: StageTime,
    /// Final optimisation, local correction and re-fusion.
    pub finalisation: StageTime,
}

impl Timings {
    /// `(name, time)` of every stage.
    pub fn stages(&self) -> [(&'static str, StageTime); 10] {
        [
            ("load", self.load),
            ("features", self.features),
            ("tracking", self.tracking),
            ("semantics", self.semantics),
            ("multiview", self.multiview),
            ("fusion", self.fusion),
            ("correction", self.correction),
            ("optimisation", self.optimisation),
            ("local BA", self.local_adjustment),
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
    /// The final bundle adjustment (`None`: off).
    pub adjustment: Option<BaSummary>,
    /// The local bundle adjustments during the run.
    pub local_adjustment: LocalBaStats,
    /// Each keyframe's pose right after its correction step (the live estimate) and every
    /// keyframe's pose at the end of the run, before the final optimisation.
    pub live_poses: Vec<Pose>,
    pub online_poses: Vec<Pose>,
    /// Dense keyframe-to-keyframe edges (RGB-D, `dense.keyframe_edges` > 0).
    pub keyframe_alignment: Option<KeyframeAlignmentSummary>,
    /// Multi-view depth of monocular keyframes, summed over keyframes.
    pub multiview: SweepSummary,
    pub tracking: TrackingCounters,
    /// `tracking.colour_instant`: frames whose pose was moved from their depth image's instant
    /// to their colour image's.
    pub colour_instant: usize,
    pub correction: CorrectionStats,
    /// Frames that could not be read, with the reason.
    pub skipped: Vec<(usize, String)>,
    /// Frames by which of their images repeat the previous frame's.
    pub repeated_frames: RepeatCounts,
    /// Keyframes whose semantic source failed (void labels used).
    pub semantic_failures: Vec<(usize, String)>,
    pub timings: Timings,
    pub wall_seconds: f64,
    pub interrupted: bool,
    /// Frames the run was asked to process.
    pub total_frames: usize,
    pub threads: bool,
    /// Threads that prepared frames ahead of tracking (0: tracking did it).
    pub feature_workers: usize,
    pub depth: DepthMode,
    pub keypoint_source: &'static str,
    pub semantic_source: &'static str,
}

impl SlamOutput {
    /// Final pose of a frame: its reference keyframe's corrected pose composed
    /// with the tracked relative pose.
    pub fn frame_pose(&self, r: &FrameRecord) -> Pose {
        r.pose_in(&self.map)
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

/// A decoded frame.
struct Loaded {
    rgb: RgbImage,
    depth: Option<DepthImage>,
    stamp: f64,
    gt: Option<Pose>,
    keys: ImageKeys,
}

fn load(seq: &TumSequence, i: usize, monocular: bool) -> Result<Loaded> {
    if monocular {
        let rgb = seq.load_rgb(i)?;
        let stamp = seq.frames[i].rgb_stamp;
        Ok(Loaded {
            keys: ImageKeys::new(&rgb, None),
            rgb,
            depth: None,
            stamp,
            gt: seq.gt_pose_at(stamp),
        })
    } else {
        let f = seq.load_frame(i)?;
        Ok(Loaded {
            keys: ImageKeys::new(&f.rgb, f.depth.as_ref()),
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
    /// Frames by which of their images repeat the previous frame's.
    repeats: RepeatCounts,
}

/// A frame loaded and its keypoints detected (or why not), with the time each took.
struct Prepared {
    frame: Result<(Loaded, Result<super::keypoints::KeyFeatures>)>,
    load: Duration,
    detect: Duration,
}

fn prepare(
    seq: &TumSequence,
    i: usize,
    monocular: bool,
    keypoints: &dyn KeypointSource,
) -> Prepared {
    let t = Instant::now();
    let frame = load(seq, i, monocular);
    let load = t.elapsed();
    let t = Instant::now();
    let frame = frame.map(|f| {
        let features = keypoints.detect(&rgb_to_gray(&f.rgb));
        (f, features)
    });
    Prepared {
        frame,
        load,
        detect: t.elapsed(),
    }
}

/// The tracking stage over the frames: load, features, track; keyframes go to
/// `on_keyframe` (which may answer with predicted-depth 3D points), frames to
/// `on_frame`. With `workers` > 0, frames are loaded and their keypoints detected on that
/// many threads ahead of tracking ([`super::prefetch`]); with 0, on this thread before each
/// is tracked. Either way each frame is tracked with the same features (the real sequences
/// of the README give byte-identical trajectories). With workers, the `load` and `features`
/// times are each worker's, summed: they overlap tracking and each other.
fn tracking_loop(
    frames: &Frames,
    tracker: Tracker,
    keypoints: &dyn KeypointSource,
    workers: usize,
    mut on_keyframe: impl FnMut(MapperInput) -> Option<Arc<KeyframeFeatures>>,
    mut on_frame: impl FnMut(&FrameRecord, Progress),
) -> TrackingRun {
    let Frames {
        sequence: seq,
        n,
        monocular,
        ref stop,
        ref log,
    } = *frames;
    let mut run = TrackingRun {
        tracker,
        frames: Vec::new(),
        skipped: Vec::new(),
        load: StageTime::default(),
        features: StageTime::default(),
        tracking: StageTime::default(),
        interrupted: false,
        repeats: RepeatCounts::default(),
    };
    // The last loaded frame's index and image hashes.
    let mut previous: Option<(usize, ImageKeys)> = None;
    let mut track = |i: usize, p: Prepared| -> bool {
        if stop.load(Ordering::SeqCst) {
            run.interrupted = true;
            return false;
        }
        let (frame, features) = match p.frame {
            Ok(f) => f,
            Err(e) => {
                log(&format!("warning: frame {i} skipped: {e}"));
                run.skipped.push((i, e.to_string()));
                return true;
            }
        };
        run.load.add_duration(p.load);
        let features = features.unwrap_or_else(|e| {
            log(&format!(
                "warning: frame {i}: keypoints failed ({e}); no features"
            ));
            Default::default()
        });
        run.features.add_duration(p.detect);
        let before = previous.filter(|(j, _)| j + 1 == i).map(|(_, k)| k);
        let repeats = frame.keys.repeats(before.as_ref());
        previous = Some((i, frame.keys));
        run.repeats.add(repeats);
        let tracker = &mut run.tracker;
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
        true
    };
    let produce = |i: usize| prepare(seq, i, monocular, keypoints);
    let mut stopped = false;
    if workers == 0 {
        for i in 0..n {
            // Checked before loading too: a stop request skips the frame's work.
            if stop.load(Ordering::SeqCst) {
                stopped = true;
                break;
            }
            if !track(i, produce(i)) {
                break;
            }
        }
    } else {
        super::prefetch::ordered_map(n, workers, produce, &mut track);
    }
    run.interrupted |= stopped;
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
        let stages = Stages {
            tracker: Tracker::new(config.clone(), camera.clone(), monocular),
            keypoints,
            mapper: LocalMapper::new(
                config.clone(),
                camera.clone(),
                monocular,
                semantics,
                map.clone(),
                control.log.clone(),
            ),
            correction: CorrectionStage::new(
                Corrector::new(config.clone(), camera.clone()),
                &config.correction,
                monocular,
            ),
        };
        let frames = Frames {
            sequence: &sequence,
            n,
            monocular,
            stop: control.stop.clone(),
            log: control.log.clone(),
        };
        let mut on_frame = control.on_frame.take();
        let mut notify = |r: &FrameRecord, p: Progress| {
            if let Some(f) = on_frame.as_mut() {
                f(r, &p);
            }
        };
        let (mut run, mut mapper, mut correction) = if config.system.threads {
            let (queue, workers) = (config.system.queue, config.system.feature_workers);
            run_threaded(&frames, stages, &map, queue, workers, &mut notify)?
        } else {
            run_in_order(&frames, stages, &map, &mut notify)
        };
        let mut timings = Timings {
            load: run.load,
            features: run.features,
            tracking: run.tracking,
            semantics: mapper.semantics_time,
            correction: correction.time,
            optimisation: correction.optimisation,
            local_adjustment: correction.local_time,
            ..Timings::default()
        };
        // Final correction from all constraints, local correction, re-fusion.
        let t = Instant::now();
        let online_poses: Vec<Pose> = read(&map).keyframes.iter().map(|k| k.pose).collect();
        let keyframe_alignment = (!monocular && config.dense.keyframe_edges > 0).then(|| {
            let (edges, summary) = keyframe_edges(&read(&map), &camera, &config);
            correction.corrector.set_extra_edges(edges);
            summary
        });
        correction.corrector.optimise_final(&map);
        let adjustment =
            correction
                .corrector
                .bundle_adjust(&map, monocular)
                .map(|(mut summary, tracks)| {
                    summary.frames_refined = refine_frames(
                        &read(&map),
                        &tracks,
                        &mut run.frames,
                        &camera,
                        &config,
                        monocular,
                    );
                    summary
                });
        let (local, landmarks) = local_correction(&mut write(&map), &config, monocular);
        if config.dense.frame_graph && !monocular {
            let started = Instant::now();
            let placed = place_frames(&read(&map), &mut run.frames, &config.dense);
            (control.log)(&format!(
                "frame graph: {} frames placed in {} spans between keyframes ({} held at both \
                 ends), {:.1} ms",
                placed.frames,
                placed.spans,
                placed.closed,
                started.elapsed().as_secs_f64() * 1e3
            ));
        }
        let mut colour_instant = 0;
        if config.tracking.colour_instant && !monocular {
            let depth_offset = |i: usize| sequence.frames[i].depth_offset();
            colour_instant = move_to_colour_instants(&read(&map), &mut run.frames, depth_offset);
            (control.log)(&format!(
                "colour instant: {colour_instant} frames moved from their depth image's instant \
                 to their colour image's"
            ));
        }
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
            (control.log)(&format!(
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
            adjustment,
            local_adjustment: correction.local,
            live_poses: correction.live,
            online_poses,
            keyframe_alignment,
            multiview,
            tracking: run.tracker.counters.clone(),
            colour_instant,
            correction: correction.corrector.stats,
            skipped: run.skipped,
            repeated_frames: run.repeats,
            semantic_failures: failures,
            timings,
            wall_seconds: started.elapsed().as_secs_f64(),
            interrupted: run.interrupted,
            total_frames: n,
            threads: config.system.threads,
            feature_workers: if config.system.threads {
                config.system.feature_workers
            } else {
                0
            },
            depth,
            keypoint_source,
            semantic_source,
        })
    }
}

/// The frames a run goes over, and how it is told to stop.
struct Frames<'a> {
    sequence: &'a TumSequence,
    n: usize,
    monocular: bool,
    stop: Arc<AtomicBool>,
    log: Log,
}

/// The three stages before a run.
struct Stages {
    tracker: Tracker,
    keypoints: Box<dyn KeypointSource>,
    mapper: LocalMapper,
    correction: CorrectionStage,
}

/// Data correction's share of each keyframe, the same in both run orders: keyframe-pair
/// constraints; the keyframe placed where its predecessor's correction puts it; when
/// `correction.optimise_online` is set, a pose-graph solve once a loop has closed since the
/// last one and `correction.optimise_every` keyframes have passed (RGB-D mode; monocular
/// mode solves at every closed loop, since its multi-view depth is measured between
/// keyframes placed by the corrections made so far); then the local bundle adjustment of
/// its window (`bundle_adjustment.local_keyframes` > 0).
struct CorrectionStage {
    corrector: Corrector,
    online: bool,
    every: usize,
    /// Keyframes since the last online solve, and whether one of them closed a loop.
    since_solve: usize,
    loop_pending: bool,
    time: StageTime,
    optimisation: StageTime,
    monocular: bool,
    /// Local bundle adjustment: what it did and its time (one call per adjustment run).
    local: LocalBaStats,
    local_time: StageTime,
    /// Each keyframe's pose right after its correction step: the live estimate.
    live: Vec<Pose>,
}

impl CorrectionStage {
    fn new(corrector: Corrector, cfg: &CorrectionConfig, monocular: bool) -> Self {
        CorrectionStage {
            monocular,
            local: LocalBaStats::default(),
            local_time: StageTime::default(),
            live: Vec::new(),
            corrector,
            online: cfg.optimise_online,
            every: if monocular {
                1
            } else {
                cfg.optimise_every.max(1)
            },
            since_solve: 0,
            loop_pending: false,
            time: StageTime::default(),
            optimisation: StageTime::default(),
        }
    }

    fn add_keyframe(&mut self, map: &SharedMap, id: usize) {
        let t = Instant::now();
        self.loop_pending |= self.corrector.add_keyframe(map, id);
        self.since_solve += 1;
        self.time.add(t);
        self.corrector.follow_predecessor(map, id);
        if self.online && self.loop_pending && self.since_solve >= self.every {
            let t = Instant::now();
            self.corrector.optimise(map);
            self.optimisation.add(t);
            (self.since_solve, self.loop_pending) = (0, false);
        }
        if let Some((summary, seconds)) = self.corrector.adjust_local(map, id, self.monocular) {
            self.local.add(&summary, seconds);
            self.local_time
                .add_duration(Duration::from_secs_f64(seconds));
        }
        if let Some(k) = read(map).keyframes.get(id) {
            self.live.push(k.pose);
        }
    }
}

/// Tracking, mapping and correction as three threads passing messages, with frames
/// prepared by `workers` threads ahead of tracking; frame events reach `notify` on the
/// calling thread.
fn run_threaded(
    frames: &Frames,
    stages: Stages,
    map: &SharedMap,
    queue: usize,
    workers: usize,
    notify: &mut impl FnMut(&FrameRecord, Progress),
) -> Result<(TrackingRun, LocalMapper, CorrectionStage)> {
    let Stages {
        tracker,
        keypoints,
        mut mapper,
        mut correction,
    } = stages;
    let monocular = frames.monocular;
    std::thread::scope(|s| -> Result<_> {
        let (kf_tx, kf_rx) = sync_channel::<MapperInput>(queue);
        let (reply_tx, reply_rx) = channel::<Arc<KeyframeFeatures>>();
        let (corr_tx, corr_rx) = sync_channel::<usize>(queue * 4);
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
        let correcting = s.spawn(move || {
            for id in corr_rx {
                correction.add_keyframe(&map_c, id);
            }
            correction
        });
        let tracking = s.spawn(move || {
            tracking_loop(
                frames,
                tracker,
                keypoints.as_ref(),
                workers,
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
        let mapper = mapping.join().map_err(|_| panicked("mapping"))?;
        let correction = correcting.join().map_err(|_| panicked("correction"))?;
        Ok((run, mapper, correction))
    })
}

/// The same stages in order on the calling thread: each keyframe is mapped and
/// corrected before the next frame is tracked.
fn run_in_order(
    frames: &Frames,
    stages: Stages,
    map: &SharedMap,
    notify: &mut impl FnMut(&FrameRecord, Progress),
) -> (TrackingRun, LocalMapper, CorrectionStage) {
    let Stages {
        tracker,
        keypoints,
        mut mapper,
        mut correction,
    } = stages;
    let run = tracking_loop(
        frames,
        tracker,
        keypoints.as_ref(),
        0,
        |input| {
            let id = input.keyframe.id;
            let track = mapper.process(input);
            correction.add_keyframe(map, id);
            frames.monocular.then_some(track)
        },
        notify,
    );
    (run, mapper, correction)
}

/// Frames with a given status.
pub fn count_status(frames: &[FrameRecord], status: FrameStatus) -> usize {
    frames.iter().filter(|f| f.status == status).count()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monocular_mode_solves_the_pose_graph_at_every_closed_loop() {
        // Its multi-view depth is measured between keyframes placed by the online solves.
        let cfg = SlamConfig::default();
        let stage = |monocular| {
            let corrector = Corrector::new(cfg.clone(), Camera::tum_fr1());
            CorrectionStage::new(corrector, &cfg.correction, monocular).every
        };
        assert_eq!(stage(false), cfg.correction.optimise_every);
        assert!(cfg.correction.optimise_every > 1);
        assert_eq!(stage(true), 1);
    }
}
