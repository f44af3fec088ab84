//! # sdf-slam
//!
//! A pure-Rust reproduction of SDF-SLAM (Yang et al., IEEE Access 2021): learned
//! keypoints and descriptors ([`fpfdcnn`], Table 12), joint semantic segmentation
//! and metric depth ([`sdfcnn`], Table 13), and a monocular / RGB-D SLAM that
//! builds a 3D semantic map.
//!
//! Foundation modules: [`camera`] (pinhole + Brown-Conrady), [`geometry`]
//! (SE(3)/Sim(3)), [`trajectory`] (TUM trajectories), [`dataset`] (TUM RGB-D
//! sequences, NYUv2), [`metrics`] (ATE/RPE as evo computes them, errT/errR,
//! segmentation and depth accuracy), [`plot`], [`training`] (checkpoints, logs),
//! [`classes`] (NYU40 names and palette), [`synth`] (synthetic indoor RGB-D data),
//! [`malloc`] (allocator tuning for tensor workloads).
//! The SLAM system itself is [`slam`] (`cargo run --release --bin slam`).

#![warn(missing_docs)]

pub mod bundled;
pub mod camera;
pub mod classes;
pub mod dataset;
pub mod error;
pub mod features;
pub mod fpfdcnn;
pub mod geometry;
pub mod imageio;
pub mod io;
pub mod malloc;
pub mod metrics;
pub mod nn;
pub mod output_lock;
pub mod plot;
pub mod pnp;
pub mod range_matcher;
pub mod raster;
pub mod sdfcnn;
pub mod signals;
pub mod slam;
pub mod synth;
pub mod training;
pub mod trajectory;

pub use error::{Error, Result};
