//! Datasets in their original layouts.

pub mod augment;
pub mod depth;
pub mod fp_pairs;
pub mod tum;

pub use depth::DepthImage;
pub use fp_pairs::{FpConfig, FpMatch, FpPair, fp_pair, fp_pairs};
pub use tum::{Frame, FrameInfo, TumConfig, TumSequence, associate};
