//! Building blocks shared by both networks: a backend-independent differentiable bilinear
//! resize, pixel shuffle, trainable-parameter counting and a layer-shape trace.

pub mod activation;
pub mod params;
pub mod resize;
pub mod shuffle;
pub mod trace;
pub mod weights;

pub use activation::elu;
pub use params::trainable_params;
pub use resize::{SampleError, resize_bilinear, sample_bilinear_at, taps_at};
pub use shuffle::pixel_shuffle;
pub use trace::ShapeTrace;
