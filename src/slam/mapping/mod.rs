//! Mapping (the paper's semantic mapping, ORB-SLAM3's LocalMapping): each new keyframe's
//! labels and depth, fused into the 3D semantic map (section IV-C).
//!
//! * `local_mapper` — the stage: semantics, depth, fusion and re-fusion of keyframes the
//!   back end moved;
//! * [`semantic_source`] — labels (and monocular depth) per keyframe: SDFCNN, ground truth
//!   or none;
//! * [`multiview_depth`] — monocular mode: the predicted depth measured again by a plane
//!   sweep against earlier keyframes;
//! * [`scale_anchor`] — monocular mode: the floor and the camera height, and the multi-view
//!   depth against the predicted, as checks of the map's scale;
//! * `depth_edges` — pixels on depth discontinuities dropped before fusion;
//! * [`semantic_map`] — the voxel map and its label votes.

pub(crate) mod depth_edges;
pub(crate) mod local_mapper;
pub mod multiview_depth;
pub mod scale_anchor;
pub mod semantic_map;
pub mod semantic_source;
