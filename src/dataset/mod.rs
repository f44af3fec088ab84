//! Datasets in their original layouts.

pub mod augment;
pub mod depth;
pub mod labels;
pub mod nyu;
pub mod tum;

pub use depth::DepthImage;
pub use labels::LabelImage;
pub use nyu::{NyuDataset, NyuItem};
pub use tum::{Frame, FrameInfo, TumConfig, TumSequence, associate};
