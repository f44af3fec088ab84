//! The front end (ORB-SLAM3's Tracking): each frame's camera pose against the reference
//! keyframe (section IV-B), and the decision to make it a keyframe.
//!
//! * [`keypoints`] — FPFDCNN or ORB keypoints and descriptors of a frame;
//! * `prefetch` — frames loaded and their keypoints detected ahead of tracking;
//! * [`repeated_images`] — frames whose images repeat the previous frame's, counted;
//! * [`tracking`] — the tracker: constant-velocity prediction, matching, PnP + RANSAC,
//!   relocalisation, keyframes; [`matching`] — the 3D-2D correspondences it and the back
//!   end's keyframe-pair verification are made of;
//! * [`depth_alignment`] — point-to-plane ICP of a frame's depth against a keyframe's
//!   (RGB-D), which refines tracked poses and aligns keyframes in the back end.

pub mod depth_alignment;
pub mod keypoints;
pub mod matching;
pub(crate) mod prefetch;
pub mod repeated_images;
pub mod tracking;
