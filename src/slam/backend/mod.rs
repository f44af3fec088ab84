//! The back end: data correction (section IV-A; ORB-SLAM3's LoopClosing and its global
//! optimisations) and what places the frames once the keyframes are corrected.
//!
//! * [`correction`] — keyframe-pair constraints (random, proximity and similarity pairs,
//!   verified by PnP), online and final pose-graph solves, local correction of matched
//!   points; it runs the local bundle adjustment of each new keyframe;
//! * `pose_graph` — SE(3) pose-graph optimisation (Levenberg-Marquardt), with
//!   `cholesky` for its dense systems;
//! * [`bundle_adjustment`] — keyframe poses and points adjusted together after the final
//!   solve, then each frame refined against them; `local_bundle_adjustment` — a keyframe's
//!   window adjusted during the run;
//! * [`keyframe_alignment`] — keyframe depth images aligned to each other (RGB-D), edges of
//!   the final pose graph and bundle adjustment;
//! * [`frame_graph`] — the frames between two corrected keyframes placed by their
//!   frame-to-frame depth steps; [`colour_instant`] — each frame's pose moved from its depth
//!   image's instant to its colour image's.

pub mod bundle_adjustment;
pub(crate) mod cholesky;
pub mod colour_instant;
pub mod correction;
pub mod frame_graph;
pub mod keyframe_alignment;
pub(crate) mod local_bundle_adjustment;
pub(crate) mod pose_graph;
