//! Datasets in their original layouts.

pub mod depth;
pub mod tum;

pub use depth::DepthImage;
pub use tum::{Frame, FrameInfo, TumConfig, TumSequence, associate};
