//! Time per stage of a run.

use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

/// Time spent in a stage.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct StageTime {
    /// Total time spent, seconds.
    pub seconds: f64,
    /// Number of timed calls.
    pub calls: usize,
}

impl StageTime {
    /// Adds one call that began at `since` and ends now.
    pub fn add(&mut self, since: Instant) {
        self.add_duration(since.elapsed());
    }

    /// Adds one call that took `d`.
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
