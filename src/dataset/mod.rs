//! Datasets in their original layouts, training pairs and augmentation.

pub mod augment;
pub mod depth;
pub mod fp_pairs;
pub(crate) mod frame_check;
pub mod labels;
pub mod nyu;
pub mod nyu_mat;
pub mod photometric;
pub mod seven_scenes;
pub mod tum;

pub use depth::DepthImage;
pub use fp_pairs::{FpConfig, FpMatch, FpPair, fp_pair, fp_pairs};
pub use frame_check::{FrameImage, FrameSpec};
pub use labels::LabelImage;
pub use nyu::{NyuDataset, NyuItem};
pub use nyu_mat::NyuMat;
pub use seven_scenes::{ConvertOptions, Registration};
pub use tum::{Frame, FrameInfo, TumConfig, TumSequence, associate};
