//! Building blocks shared by both networks: a backend-independent differentiable bilinear
//! resize, pixel shuffle, fast 1×1 / depthwise convolution and max pooling, trainable-parameter
//! counting, seeded initialisation and a layer-shape trace.

pub mod fast;
pub mod init;
pub mod params;
pub mod resize;
pub mod shuffle;
pub mod trace;

pub use init::seeded_init;
pub use params::trainable_params;
pub use resize::{SampleError, resize_bilinear, sample_bilinear_at};
pub use shuffle::pixel_shuffle;
pub use trace::ShapeTrace;
