//! Classical image features: Harris corners (the paper's training labels,
//! section V-B) and patch correlation.

pub mod harris;
pub mod patch;

pub use harris::{HarrisConfig, Keypoint, harris_corners};
