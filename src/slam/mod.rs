//! The SDF-SLAM system (section IV, Fig. 1), in rooms by role, as ORB-SLAM3 splits its
//! threads around a shared [`map::Map`]:
//!
//! * [`frontend`] — tracking (IV-B): keypoints (FPFDCNN or ORB), range matching (eq 8),
//!   PnP + RANSAC (eqs 9-10), dense refinement against the keyframe's depth, keyframe
//!   decisions, relocalisation; frames loaded ahead of it;
//! * [`mapping`] — each keyframe's semantics and depth (SDFCNN, ground truth or none;
//!   multi-view depth in monocular mode) fused into the 3D semantic map (IV-C);
//! * [`backend`] — data correction (IV-A): keyframe-pair constraints, the pose graph,
//!   bundle adjustment (global, and local during the run), depth edges between keyframes,
//!   and the frames placed between the corrected keyframes;
//! * [`output`] — every file of a run: trajectory, `map.ply`, pictures, `report.md` /
//!   `report.json`, with ATE/RPE and Table 11 accuracy against ground truth;
//! * [`system`] — the stages as threads passing messages, or in order on one thread;
//!   [`config`] — every setting. The bundled weights and the default sequence of a run with
//!   no arguments are the binaries' concern ([`crate::bundled`]).

pub mod backend;
pub mod config;
#[cfg(test)]
pub(crate) mod fixtures;
pub mod frontend;
pub mod map;
pub mod mapping;
pub mod output;
pub mod system;

pub use config::SlamConfig;
pub use frontend::keypoints::{FpfdcnnSource, KeyFeatures, KeypointSource, OrbSource};
pub use frontend::tracking::{FrameRecord, FrameStatus};
pub use mapping::semantic_source::{
    GroundTruthSource, NoLabels, SdfcnnSource, SemanticInput, SemanticSource,
};
pub use system::{Control, DepthMode, Slam, SlamOutput};
