//! The tracking stage's loop over the frames: each frame loaded, its keypoints detected (here
//! or by workers ahead of it) and tracked; keyframes handed on to mapping.

use super::timing::StageTime;
use super::{Log, Progress};
use crate::dataset::{DepthImage, TumSequence};
use crate::error::Result;
use crate::geometry::Pose;
use crate::raster::rgb_to_gray;
use crate::slam::frontend::keypoints::{KeyFeatures, KeypointSource};
use crate::slam::frontend::prefetch::ordered_map;
use crate::slam::frontend::repeated_images::{ImageKeys, RepeatCounts};
use crate::slam::frontend::tracking::{FrameRecord, TrackInput, Tracker};
use crate::slam::map::KeyframeFeatures;
use crate::slam::mapping::local_mapper::MapperInput;
use image::RgbImage;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

/// The frames a run goes over, and how it is told to stop.
pub(super) struct Frames<'a> {
    pub(super) sequence: &'a TumSequence,
    pub(super) n: usize,
    pub(super) monocular: bool,
    /// `system.strict_frames`: a frame that cannot be read ends the run with an error.
    pub(super) strict: bool,
    pub(super) stop: Arc<AtomicBool>,
    pub(super) log: Log,
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
pub(super) struct TrackingRun {
    pub(super) tracker: Tracker,
    pub(super) frames: Vec<FrameRecord>,
    pub(super) skipped: Vec<(usize, String)>,
    /// `system.strict_frames`: the frame that could not be read, and why; the run stopped.
    pub(super) refused: Option<(usize, String)>,
    pub(super) load: StageTime,
    pub(super) features: StageTime,
    pub(super) tracking: StageTime,
    pub(super) interrupted: bool,
    /// Frames by which of their images repeat the previous frame's.
    pub(super) repeats: RepeatCounts,
}

/// A frame loaded and its keypoints detected (or why not; `None`: left to tracking), with
/// the time each took.
struct Prepared {
    frame: Result<(Loaded, Option<Result<KeyFeatures>>)>,
    load: Duration,
    detect: Duration,
    /// The keypoints were detected because the frame was due to be a keyframe, not because
    /// every frame needs them.
    ahead: bool,
}

/// Loads frame `i` and, with `detect`, its keypoints.
fn prepare(
    seq: &TumSequence,
    i: usize,
    monocular: bool,
    keypoints: &dyn KeypointSource,
    detect: bool,
) -> Prepared {
    let t = Instant::now();
    let frame = load(seq, i, monocular);
    let load = t.elapsed();
    let t = Instant::now();
    let frame = frame.map(|f| {
        let features = detect.then(|| keypoints.detect(&rgb_to_gray(&f.rgb)));
        (f, features)
    });
    Prepared {
        frame,
        load,
        detect: t.elapsed(),
        ahead: false,
    }
}

/// The tracking stage over the frames: load, features, track; keyframes go to
/// `on_keyframe` (which may answer with predicted-depth 3D points), frames to
/// `on_frame`. With `workers` > 0, frames are loaded and their keypoints detected on that
/// many threads ahead of tracking ([`crate::slam::frontend::prefetch`]); with 0, on this thread before each
/// is tracked. Either way each frame is tracked with the same features (the real sequences
/// of the README give byte-identical trajectories). With workers, the `load` and `features`
/// times are each worker's, summed: they overlap tracking and each other. With
/// `tracking.keypoints_every_frame = false` (RGB-D) keypoints are detected on this thread, and
/// only for the frames the dense alignment alone cannot track, or (monocular,
/// `tracking.monocular_flow`) that optical flow cannot follow
/// ([`Tracker::track_without_keypoints`]); with workers, those of the frame at which the next
/// keyframe is due by the frame count ([`Tracker::frame_due_by_count`]) are detected by a
/// worker ahead of tracking, as soon as tracking has named that frame (they are the
/// keypoints tracking would detect, so the trajectory is the same; a keyframe made earlier
/// can leave them unused).
pub(super) fn tracking_loop(
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
        strict,
        ref stop,
        ref log,
    } = *frames;
    let mut run = TrackingRun {
        tracker,
        frames: Vec::new(),
        skipped: Vec::new(),
        refused: None,
        load: StageTime::default(),
        features: StageTime::default(),
        tracking: StageTime::default(),
        interrupted: false,
        repeats: RepeatCounts::default(),
    };
    let detect = run.tracker.needs_keypoints_every_frame();
    // The frame at which the next keyframe is due by the frame count, set by tracking after
    // each frame. A worker takes frame `i` only once frame `i − 2·workers` is tracked
    // ([`ordered_map`]), so the due frame is named in time when the count is at least that.
    let due = AtomicUsize::new(usize::MAX);
    let flow = run.tracker.tracks_by_flow();
    // The last loaded frame's index and image hashes.
    let mut previous: Option<(usize, ImageKeys)> = None;
    let mut track = |i: usize, p: Prepared| -> bool {
        if stop.load(Ordering::SeqCst) {
            run.interrupted = true;
            return false;
        }
        let (frame, features) = match p.frame {
            Ok(f) => f,
            Err(e) if strict => {
                run.refused = Some((i, e.to_string()));
                return false;
            }
            Err(e) => {
                log(&format!("warning: frame {i} skipped: {e}"));
                run.skipped.push((i, e.to_string()));
                return true;
            }
        };
        run.load.add_duration(p.load);
        let before = previous.filter(|(j, _)| j + 1 == i).map(|(_, k)| k);
        let repeats = frame.keys.repeats(before.as_ref());
        previous = Some((i, frame.keys));
        run.repeats.add(repeats);
        let tracker = &mut run.tracker;
        // The dense alignment's try and the tracking by keypoints count as tracking, a
        // detection here as features.
        let t = Instant::now();
        // Monocular tracking by optical flow: the frame's grey image (also the detector's) and
        // its pyramid.
        let gray = flow.then(|| rgb_to_gray(&frame.rgb));
        let pyramid = gray.as_ref().map(Tracker::flow_pyramid);
        // (It declines every frame when every frame needs its keypoints.)
        let without =
            tracker.track_without_keypoints(i, frame.stamp, frame.depth.as_ref(), pyramid.as_ref());
        let mut tracking = t.elapsed();
        if p.ahead {
            tracker.counters.detected_ahead += 1;
            if without.is_some() {
                tracker.counters.detected_ahead_unused += 1;
                run.features.add_duration(p.detect);
            }
        }
        let out = match without {
            Some(out) => out,
            None => {
                let features = match features {
                    Some(f) => {
                        run.features.add_duration(p.detect);
                        f
                    }
                    None => {
                        let t = Instant::now();
                        let f = match &gray {
                            Some(g) => keypoints.detect(g),
                            None => keypoints.detect(&rgb_to_gray(&frame.rgb)),
                        };
                        run.features.add(t);
                        f
                    }
                };
                let features = features.unwrap_or_else(|e| {
                    log(&format!(
                        "warning: frame {i}: keypoints failed ({e}); no features"
                    ));
                    Default::default()
                });
                let t = Instant::now();
                let out = tracker.track(TrackInput {
                    index: i,
                    stamp: frame.stamp,
                    features,
                    depth: frame.depth.as_ref(),
                    gt_pose: frame.gt,
                });
                tracking += t.elapsed();
                out
            }
        };
        if let Some(p) = pyramid {
            tracker.keep_image(i, p);
        }
        due.store(
            tracker.frame_due_by_count().unwrap_or(usize::MAX),
            Ordering::SeqCst,
        );
        run.tracking.add_duration(tracking);
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
    let produce = |i: usize| {
        let ahead = !detect && workers > 0 && due.load(Ordering::SeqCst) == i;
        let mut p = prepare(seq, i, monocular, keypoints, detect || ahead);
        p.ahead = ahead;
        p
    };
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
        ordered_map(n, workers, produce, &mut track);
    }
    run.interrupted |= stopped;
    run
}
