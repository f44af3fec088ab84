//! Tracking, mapping and correction run as three threads passing messages, or in order on
//! the calling thread; data correction's share of each keyframe is the same either way.

use super::Progress;
use super::frame_loop::{Frames, TrackingRun, tracking_loop};
use super::timing::StageTime;
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::slam::backend::correction::Corrector;
use crate::slam::backend::local_bundle_adjustment::LocalBaStats;
use crate::slam::config::CorrectionConfig;
use crate::slam::frontend::keypoints::KeypointSource;
use crate::slam::frontend::tracking::{FrameRecord, Tracker};
use crate::slam::map::{KeyframeFeatures, SharedMap, read};
use crate::slam::mapping::local_mapper::{LocalMapper, MapperInput};
use std::sync::Arc;
use std::sync::mpsc::{channel, sync_channel};
use std::time::{Duration, Instant};

fn panicked(stage: &str) -> Error {
    Error::msg(format!("the {stage} thread panicked"))
}

/// The three stages before a run.
pub(super) struct Stages {
    pub(super) tracker: Tracker,
    pub(super) keypoints: Box<dyn KeypointSource>,
    pub(super) mapper: LocalMapper,
    pub(super) correction: CorrectionStage,
}

/// Data correction's share of each keyframe, the same in both run orders: keyframe-pair
/// constraints; the keyframe placed where its predecessor's correction puts it; when
/// `correction.optimise_online` is set, a pose-graph solve once a loop has closed since the
/// last one and `correction.optimise_every` keyframes have passed (RGB-D mode; monocular
/// mode solves at every closed loop, since its multi-view depth is measured between
/// keyframes placed by the corrections made so far); then the local bundle adjustment of
/// its window (`bundle_adjustment.local_keyframes` > 0).
pub(super) struct CorrectionStage {
    pub(super) corrector: Corrector,
    online: bool,
    every: usize,
    /// Keyframes since the last online solve, and whether one of them closed a loop.
    since_solve: usize,
    loop_pending: bool,
    pub(super) time: StageTime,
    pub(super) optimisation: StageTime,
    monocular: bool,
    /// Local bundle adjustment: what it did and its time (one call per adjustment run).
    pub(super) local: LocalBaStats,
    pub(super) local_time: StageTime,
    /// Each keyframe's pose right after its correction step: the live estimate.
    pub(super) live: Vec<Pose>,
}

impl CorrectionStage {
    pub(super) fn new(corrector: Corrector, cfg: &CorrectionConfig, monocular: bool) -> Self {
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

/// RGB-D: the rayon pool mapping and correction each run on, with half the machine's threads
/// (one on two cores), as each feature worker has: beside tracking and the workers they would
/// otherwise split every SDFCNN layer and keyframe alignment over threads busy elsewhere (on
/// two cores, 7-Scenes 0-299: the semantics stage 5.6-5.9 -> 4.1-4.4 s, correction 2.9-3.3 ->
/// 2.6-2.7 s, the same maps; lab/notes/cpu-speed.md). Monocular tracking waits for each
/// keyframe's mapping, so there they keep every thread (`None`).
fn stage_pool(monocular: bool) -> Option<rayon::ThreadPool> {
    if monocular {
        return None;
    }
    let threads = (rayon::current_num_threads() / 2).max(1);
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .ok()
}

/// Tracking, mapping and correction as three threads passing messages, with frames
/// prepared by `workers` threads ahead of tracking; frame events reach `notify` on the
/// calling thread.
pub(super) fn run_threaded(
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
            let run = || {
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
            };
            match stage_pool(monocular) {
                Some(pool) => pool.install(run),
                None => run(),
            }
        });
        let map_c = map.clone();
        let correcting = s.spawn(move || {
            let run = || {
                for id in corr_rx {
                    correction.add_keyframe(&map_c, id);
                }
                correction
            };
            match stage_pool(monocular) {
                Some(pool) => pool.install(run),
                None => run(),
            }
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
pub(super) fn run_in_order(
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::slam::config::SlamConfig;

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
