//! SDFCNN, the joint semantic segmentation and depth network of SDF-SLAM (Section IV-C,
//! Table 13): the model, its loss (eq. 21), training data, the trainer and inference.

mod blocks;
mod config;
pub mod data;
pub mod focal;
pub mod imagenet;
pub mod inference;
pub mod loss;
mod model;
pub mod packed;
pub mod photometric;
mod source;
pub mod training;
mod validation;
pub mod video;

pub use blocks::BnProbe;
pub use inference::{Prediction, SdfcnnPredictor};
pub use loss::{DepthLoss, LossParts, LossResolution, SdfcnnLossConfig};
pub use model::{Sdfcnn, SdfcnnConfig, SdfcnnError, SdfcnnOutput};
pub use packed::PackedSdfcnn;
pub use training::SdfcnnTrainConfig;
