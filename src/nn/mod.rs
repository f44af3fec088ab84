//! Building blocks shared by both networks: convolution and max pooling that are fast on
//! ndarray, a backend-independent differentiable bilinear resize, pixel shuffle,
//! trainable-parameter counting, seeded initialisation and a layer-shape trace.

pub mod activation;
pub mod backend;
pub mod batch_norm_kernel;
pub mod conv;
pub mod dense_conv_kernel;
pub mod depthwise_kernel;
pub mod elu_kernel;
pub mod init;
pub mod nhwc;
pub mod packed_conv;
pub mod packed_depthwise;
pub mod params;
pub mod pool;
pub mod pool_kernel;
pub mod relu6_kernel;
pub mod resize;
pub mod shuffle;
pub mod trace;
pub mod weights;
pub mod winograd;

pub use activation::elu;
pub use batch_norm_kernel::batch_norm;
pub use conv::{OpImpl, conv2d, conv2d_matmul, set_op_impl};
pub use init::seeded_init;
pub use params::trainable_params;
pub use pool::max_pool2d;
pub use relu6_kernel::relu6;
pub use resize::{SampleError, resize_bilinear, sample_bilinear_at, taps_at};
pub use shuffle::{pixel_shuffle, pixel_unshuffle};
pub use trace::ShapeTrace;

pub use backend::BackendKind;
