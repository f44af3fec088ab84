//! Classical image features: Harris corners (the paper's training labels,
//! section V-B), ORB with brute-force Hamming matching (the baseline of Tables 6
//! and 7), patch correlation and pyramidal Lucas-Kanade optical flow.

pub mod bf_matcher;
pub mod harris;
pub mod match_refine;
pub mod optical_flow;
pub mod orb;
pub mod patch;
pub(crate) mod subpix;

pub use bf_matcher::{HammingMatch, bf_match, hamming};
pub use harris::{HarrisConfig, Keypoint, harris_corners};
pub use orb::{Descriptor, OrbConfig, OrbFeatures, OrbKeypoint, detect_and_compute};
