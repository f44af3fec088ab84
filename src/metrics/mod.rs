//! Evaluation metrics: trajectory errors as evo computes them (ATE/RPE), the
//! paper's errT/errR (eqs 11-14), feature-matching accuracy (Table 6), and summary
//! statistics.

pub mod matching;
pub mod pose_error;
pub mod stats;
pub mod trajectory;

pub use matching::{MatchingAccuracy, frame_pair_accuracy, matching_accuracy};
pub use pose_error::{PoseError, PoseErrorSegment};
pub use stats::Stats;
pub use trajectory::{Alignment, Ape, DeltaUnit, Rpe, ape, associate, rpe, umeyama};
