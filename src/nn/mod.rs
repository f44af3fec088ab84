//! Building blocks shared by both networks: convolution and max pooling that are fast on
//! ndarray, a backend-independent differentiable bilinear resize, pixel shuffle,
//! trainable-parameter counting, seeded initialisation and a layer-shape trace.

pub mod activation;
pub mod backend;
pub(crate) mod batch_norm_kernel;
pub mod conv;
pub(crate) mod dense_conv_kernel;
pub(crate) mod depthwise_kernel;
pub mod devices;
pub(crate) mod elu_kernel;
pub mod init;
pub(crate) mod nhwc;
pub(crate) mod packed_conv;
pub(crate) mod packed_depthwise;
pub mod params;
pub mod pool;
#[cfg(target_arch = "x86_64")]
mod pool_avx2;
pub(crate) mod pool_kernel;
pub mod reduce;
pub(crate) mod relu6_kernel;
pub mod resize;
pub(crate) mod shuffle;
pub mod trace;
pub mod weights;
pub(crate) mod winograd;

pub use activation::elu;
pub use batch_norm_kernel::batch_norm;
pub use conv::{OpImpl, conv2d, conv2d_matmul, set_op_impl};
pub use init::seeded_init;
pub use params::trainable_params;
pub use pool::max_pool2d;
pub use reduce::sum_all;
pub use relu6_kernel::relu6;
pub use resize::{
    SampleError, resize_bilinear, sample_bilinear_at, sample_bilinear_at_nhwc, taps_at,
};
pub use shuffle::{pixel_shuffle, pixel_unshuffle};
pub use trace::ShapeTrace;

pub use backend::BackendKind;
pub use devices::DeviceSpec;
