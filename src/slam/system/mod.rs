//! The SDF-SLAM system (section IV-A, Fig. 1): tracking (camera pose
//! estimation), mapping (SDFCNN semantics + fusion into the 3D semantic map) and
//! data correction run as separate threads passing messages over channels
//! around the shared [`Map`]; or, for tests, the same stages in order on one
//! thread. Both orders give the same trajectory and map: tracking never reads
//! corrected poses, correction candidates depend only on earlier keyframes, and
//! the final pose graph is solved from the tracked poses with all constraints.

mod frame_loop;
pub mod scale;
mod stages;
mod timing;

pub use timing::{StageTime, Timings};

use super::backend::bundle_adjustment::{BaSummary, refine_frames};
use super::backend::colour_instant::move_to_colour_instants;
use super::backend::correction::{CorrectionStats, Corrector, LocalSummary, local_correction};
use super::backend::frame_graph::place_frames;
use super::backend::keyframe_alignment::{KeyframeAlignmentSummary, keyframe_edges};
use super::backend::local_bundle_adjustment::LocalBaStats;
use super::config::SlamConfig;
use super::frontend::keypoints::KeypointSource;
use super::frontend::repeated_images::RepeatCounts;
use super::frontend::tracking::{FrameRecord, FrameStatus, Tracker, TrackingCounters};
use super::map::{Map, SharedMap, read, write};
use super::mapping::local_mapper::LocalMapper;
use super::mapping::multiview_depth::SweepSummary;
use super::mapping::semantic_map::SemanticMap;
use super::mapping::semantic_source::SemanticSource;
use crate::camera::Camera;
use crate::dataset::TumSequence;
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::trajectory::Trajectory;
use frame_loop::Frames;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};
use stages::{CorrectionStage, Stages, run_in_order, run_threaded};
use std::sync::atomic::AtomicBool;
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
pub(crate) fn stderr_log() -> Log {
    Arc::new(|m: &str| eprintln!("{m}"))
}

/// Progress after a frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Progress {
    /// Frames processed so far.
    pub done: usize,
    /// Frames the run will process.
    pub total: usize,
    /// Keyframes created so far.
    pub keyframes: usize,
    /// Frames lost so far (tracking kept the constant-velocity pose).
    pub lost: usize,
}

/// Called after every frame.
pub type FrameCallback = Box<dyn FnMut(&FrameRecord, &Progress)>;

/// How a run is observed and stopped.
pub struct Control {
    /// Set it (Ctrl-C) to stop after the current frame; what was tracked is kept.
    pub stop: Arc<AtomicBool>,
    /// Where warnings and events go.
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
    /// The TUM-layout sequence to run on.
    pub sequence: TumSequence,
    /// The sequence's camera.
    pub camera: Camera,
    /// The system's settings.
    pub config: SlamConfig,
    /// Where depth comes from (sensor or predicted).
    pub depth: DepthMode,
    /// The keypoint detector and descriptor (ORB or FPFDCNN).
    pub keypoints: Box<dyn KeypointSource>,
    /// Where keyframes' labels (and monocular depth) come from.
    pub semantics: Box<dyn SemanticSource>,
    /// Process at most this many frames.
    pub max_frames: Option<usize>,
}

/// What a run produced.
pub struct SlamOutput {
    /// One record per processed frame, in sequence order.
    pub frames: Vec<FrameRecord>,
    /// The final map: keyframes with corrected poses and their constraints.
    pub map: Map,
    /// The fused 3D semantic map.
    pub semantic_map: SemanticMap,
    /// Unified world points of local correction.
    pub landmarks: Vec<Point3<f64>>,
    /// What local correction did.
    pub local: LocalSummary,
    /// The final bundle adjustment (`None`: off).
    pub adjustment: Option<BaSummary>,
    /// The local bundle adjustments during the run.
    pub local_adjustment: LocalBaStats,
    /// Each keyframe's pose right after its correction step (the live estimate) and every
    /// keyframe's pose at the end of the run, before the final optimisation.
    pub live_poses: Vec<Pose>,
    /// Every keyframe's pose at the end of the run, before the final optimisation.
    pub online_poses: Vec<Pose>,
    /// Dense keyframe-to-keyframe edges (RGB-D, `dense.keyframe_edges` > 0).
    pub keyframe_alignment: Option<KeyframeAlignmentSummary>,
    /// Multi-view depth of monocular keyframes, summed over keyframes.
    pub multiview: SweepSummary,
    /// Frames tracking had trouble with (relocalised, lost...).
    pub tracking: TrackingCounters,
    /// `tracking.colour_instant`: frames whose pose was moved from their depth image's instant
    /// to their colour image's.
    pub colour_instant: usize,
    /// Counts of the correction stage.
    pub correction: CorrectionStats,
    /// Frames that could not be read, with the reason.
    pub skipped: Vec<(usize, String)>,
    /// Frames by which of their images repeat the previous frame's.
    pub repeated_frames: RepeatCounts,
    /// Keyframes whose semantic source failed (void labels used).
    pub semantic_failures: Vec<(usize, String)>,
    /// Time spent in each stage.
    pub timings: Timings,
    /// Wall-clock duration of the run, seconds.
    pub wall_seconds: f64,
    /// Whether the run was stopped before its last frame.
    pub interrupted: bool,
    /// Frames the run was asked to process.
    pub total_frames: usize,
    /// Whether tracking, mapping and correction ran in their own threads.
    pub threads: bool,
    /// Threads that prepared frames ahead of tracking (0: tracking did it).
    pub feature_workers: usize,
    /// Where depth came from (sensor or predicted).
    pub depth: DepthMode,
    /// Name of the keypoint source, for reports.
    pub keypoint_source: &'static str,
    /// Name of the semantic source, for reports.
    pub semantic_source: &'static str,
    /// The floor's camera height and the monocular map-level scale, and any rescaling.
    pub scale: scale::ScaleReport,
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
        let tracker = Tracker::new(config.clone(), camera.clone(), monocular);
        let n = max_frames.map_or(sequence.len(), |m| m.min(sequence.len()));
        let map: SharedMap = Arc::new(RwLock::new(Map::default()));
        let keypoint_source = keypoints.name();
        let semantic_source = semantics.name();
        let stages = Stages {
            tracker,
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
            strict: config.system.strict_frames,
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
        if let Some((i, why)) = run.refused.take() {
            return Err(Error::msg(format!(
                "frame {i} of {} could not be read (system.strict_frames is on; off, the frame \
                 is skipped and reported): {why}",
                crate::io::short_path(&sequence.root)
            )));
        }
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
        let back_end = BackEnd {
            map: &map,
            camera: &camera,
            config: &config,
            monocular,
            log: &control.log,
        };
        let finished = back_end.finish(&mut run.frames, &mut correction.corrector, &sequence);
        mapper.refuse_all();
        timings.finalisation.add(t);
        timings.fusion = mapper.fusion_time;
        timings.multiview = mapper.multiview_time;
        let LocalMapper {
            semantic_map,
            failures,
            multiview,
            scale_ratios,
            ..
        } = mapper;
        let map = std::mem::take(&mut *write(&map));
        if run.interrupted {
            (control.log)(&format!(
                "interrupted after {} of {n} frames: writing what was tracked",
                run.frames.len()
            ));
        }
        let mut out = SlamOutput {
            frames: run.frames,
            map,
            semantic_map,
            landmarks: finished.landmarks,
            local: finished.local,
            adjustment: finished.adjustment,
            local_adjustment: correction.local,
            live_poses: correction.live,
            online_poses: finished.online_poses,
            keyframe_alignment: finished.keyframe_alignment,
            multiview,
            tracking: run.tracker.counters.clone(),
            colour_instant: finished.colour_instant,
            correction: correction.corrector.stats,
            skipped: run.skipped,
            repeated_frames: run.repeats,
            semantic_failures: failures,
            timings,
            wall_seconds: started.elapsed().as_secs_f64(),
            interrupted: run.interrupted,
            total_frames: n,
            threads: config.system.threads,
            // The workers load every frame, and detect the keypoints of every frame or (where
            // the frames between keyframes are tracked without them) of the frames due to be
            // keyframes.
            feature_workers: if config.system.threads {
                config.system.feature_workers
            } else {
                0
            },
            depth,
            keypoint_source,
            semantic_source,
            scale: scale::ScaleReport::default(),
        };
        // The tracker's copies of the keyframes' features go first, so that scaling them does
        // not copy them.
        drop(run.tracker);
        out.scale = scale::anchor_scale(&mut out, &config, &scale_ratios);
        log_scale(&out.scale, config.scale.camera_height, &control.log);
        Ok(out)
    }
}

/// Logs what anchoring the scale found: its warnings, then the rescaling if one was applied
/// (`camera_height`: the configured camera height, metres).
fn log_scale(report: &scale::ScaleReport, camera_height: f64, log: &Log) {
    for w in &report.warnings {
        log(&format!("warning: {w}"));
    }
    if let Some(s) = report.applied {
        log(&format!(
            "scale: the floor is {:.3} map units below the cameras; the camera height \
             {:.3} m scales the map by {s:.3}",
            report.floor.as_ref().map_or(f64::NAN, |f| f.camera_height),
            camera_height
        ));
    }
}

/// What the back end's final pass works on.
struct BackEnd<'a> {
    map: &'a SharedMap,
    camera: &'a Camera,
    config: &'a SlamConfig,
    monocular: bool,
    log: &'a Log,
}

/// What the back end's final pass produced.
struct Finished {
    /// Every keyframe's pose at the end of the run, before the final optimisation.
    online_poses: Vec<Pose>,
    keyframe_alignment: Option<KeyframeAlignmentSummary>,
    adjustment: Option<BaSummary>,
    local: LocalSummary,
    landmarks: Vec<Point3<f64>>,
    colour_instant: usize,
}

impl BackEnd<'_> {
    /// After every frame was tracked: the keyframe edges, the final pose-graph solve from
    /// all constraints, bundle adjustment and the frames' refinement, local correction, then
    /// the frames between keyframes placed and moved to their colour instants.
    fn finish(
        &self,
        frames: &mut [FrameRecord],
        corrector: &mut Corrector,
        sequence: &TumSequence,
    ) -> Finished {
        let BackEnd {
            map,
            camera,
            config,
            monocular,
            log,
        } = *self;
        let online_poses: Vec<Pose> = read(map).keyframes.iter().map(|k| k.pose).collect();
        let keyframe_alignment = (!monocular && config.dense.keyframe_edges > 0).then(|| {
            let (edges, summary) = keyframe_edges(&read(map), camera, config);
            corrector.set_extra_edges(edges);
            summary
        });
        corrector.optimise_final(map);
        let adjustment = corrector
            .bundle_adjust(map, monocular)
            .map(|(mut summary, tracks)| {
                let m = read(map);
                summary.frames_refined =
                    refine_frames(&m, &tracks, &mut *frames, camera, config, monocular);
                summary
            });
        let (local, landmarks) = local_correction(&mut write(map), config, monocular);
        if config.dense.frame_graph && !monocular {
            let started = Instant::now();
            let placed = place_frames(&read(map), frames, &config.dense);
            log(&format!(
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
            colour_instant = move_to_colour_instants(&read(map), frames, depth_offset);
            log(&format!(
                "colour instant: {colour_instant} frames moved from their depth image's instant \
                 to their colour image's"
            ));
        }
        Finished {
            online_poses,
            keyframe_alignment,
            adjustment,
            local,
            landmarks,
            colour_instant,
        }
    }
}

/// Frames with a given status.
pub fn count_status(frames: &[FrameRecord], status: FrameStatus) -> usize {
    frames.iter().filter(|f| f.status == status).count()
}
