//! Evaluation metrics: trajectory errors as evo computes them (ATE/RPE), the
//! paper's errT/errR (eqs 11-14), feature-matching accuracy (Table 6),
//! segmentation (eqs 16-17) and depth (eqs 18-20) accuracy, summary statistics, and the
//! per-axis scale of one trajectory's steps against another's.

pub(crate) mod axis_scale;
pub mod depth;
pub mod matching;
pub(crate) mod pose_error;
pub mod segmentation;
pub mod stats;
pub mod trajectory;

pub use axis_scale::AxisScale;
pub use depth::{DepthAccumulator, DepthMetrics, median_scale};
pub use matching::{MatchingAccuracy, frame_pair_accuracy, matching_accuracy};
pub use pose_error::{PoseError, PoseErrorSegment};
pub use segmentation::{ClassScore, ConfusionMatrix};
pub use stats::Stats;
pub use trajectory::{
    Alignment, Ape, DeltaUnit, Rpe, RpeAtKeyframes, RpeSplit, ape, associate, rpe, umeyama,
};
