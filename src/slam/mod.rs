//! The SDF-SLAM system (section IV, Fig. 1), split like ORB-SLAM3 around a
//! shared [`map::Map`]:
//!
//! * [`tracking`] — camera pose estimation (IV-B): keypoints ([`keypoints`]:
//!   FPFDCNN or ORB), range matching (eq 8), PnP + RANSAC (eqs 9-10),
//!   keyframes, relocalisation;
//! * mapping ([`local_mapper::LocalMapper`]) — semantics and depth of keyframes
//!   ([`semantic_source`]: SDFCNN, ground truth or none) fused into the 3D
//!   semantic map ([`semantic_map`], IV-C), written by [`ply`], drawn by [`topdown`];
//! * [`correction`] — data correction (IV-A): keyframe-pair constraints and a
//!   pose graph ([`pose_graph`]), plus local unification of matched points;
//! * [`system`] — the three stages as threads passing messages, or in order on
//!   one thread; [`evaluation`] — ATE/RPE and Table 11 accuracy against ground
//!   truth; [`report`] — `report.md` / `report.json`; [`output`] — every file
//!   of a run; [`config`] — every tunable. The bundled weights and the default
//!   sequence of a run with no arguments are the binaries' concern
//!   ([`crate::bundled`]).

pub mod bundle_adjustment;
pub mod cholesky;
pub mod colour_instant;
pub mod config;
pub mod correction;
pub mod depth_alignment;
pub mod depth_edges;
pub mod evaluation;
#[cfg(test)]
pub(crate) mod fixtures;
pub mod frame_graph;
pub mod keyframe_alignment;
pub mod keypoints;
pub mod local_bundle_adjustment;
pub mod local_mapper;
pub mod map;
pub mod multiview_depth;
pub mod output;
pub mod ply;
pub mod pose_graph;
pub mod prefetch;
pub mod repeated_images;
pub mod report;
pub mod semantic_map;
pub mod semantic_source;
pub mod system;
pub mod topdown;
pub mod tracking;

pub use config::SlamConfig;
pub use keypoints::{FpfdcnnSource, KeyFeatures, KeypointSource, OrbSource};
pub use semantic_source::{
    GroundTruthSource, NoLabels, SdfcnnSource, SemanticInput, SemanticSource,
};
pub use system::{Control, DepthMode, Slam, SlamOutput};
