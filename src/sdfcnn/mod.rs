//! SDFCNN, the joint semantic segmentation and depth network of SDF-SLAM (Section IV-C,
//! Table 13).

mod blocks;
mod model;

pub use model::{Sdfcnn, SdfcnnConfig, SdfcnnError, SdfcnnOutput};
