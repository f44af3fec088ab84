//! FPFDCNN, the keypoint detector/descriptor of SDF-SLAM (Section IV-B, Table 12).

mod model;

pub use model::{Fpfdcnn, FpfdcnnConfig, FpfdcnnError, FpfdcnnOutput};
