//! FPFDCNN, the keypoint detector/descriptor of SDF-SLAM (Section IV-B, Table 12).

pub mod adaptation;
mod config;
pub mod data;
pub mod derotation;
pub mod evaluate;
pub(crate) mod homography;
pub mod inference;
pub mod loss;
mod model;
pub mod packed;
mod sequence;
pub mod training;

pub use inference::{DetectorConfig, Features, FpfdcnnDetector};
pub use model::{Fpfdcnn, FpfdcnnConfig, FpfdcnnError, FpfdcnnOutput};
pub use packed::PackedFpfdcnn;
