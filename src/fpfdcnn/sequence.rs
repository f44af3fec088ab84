//! One TUM-layout training sequence read into FPFDCNN's training and validation splits
//! ([`FpDataset::build`]): its checks, its frames with their detector targets, its posed pairs
//! with their ground-truth matches, its homography pairs and its repeats.

use super::data::{FpDataConfig, FpDataset, FrameEntry, PairEntry, Sampling, SequenceSource};
use super::data::{inside, resize_gray};
use crate::camera::Camera;
use crate::dataset::fp_pairs::{FpMatch, fp_pairs, pair_indices};
use crate::dataset::tum::{TumConfig, TumSequence};
use crate::error::{Error, Result};
use crate::raster::GrayF32;
use rayon::prelude::*;

/// Opens a training sequence and its camera, checking that it can be trained on: `repeat`
/// and `homographies` in range, depth and ground truth present, frames no smaller than the
/// training crops.
pub(super) fn open_source(
    src: &SequenceSource,
    crop: bool,
    [height, width]: [usize; 2],
) -> Result<(TumSequence, Camera)> {
    if src.repeat == 0 {
        return Err(Error::invalid(&src.path, "repeat must be at least 1"));
    }
    if src.homographies > 100 || (src.homographies > 0 && !crop) {
        return Err(Error::invalid(
            &src.path,
            "homographies must be at most 100 and needs sampling = \"crop\"",
        ));
    }
    if !(src.gt_time_offset_ms.is_finite() && src.gt_time_offset_ms.abs() <= 100.0) {
        return Err(Error::invalid(
            &src.path,
            format!(
                "gt_time_offset_ms must be within [-100, 100], got {}",
                src.gt_time_offset_ms
            ),
        ));
    }
    let config = TumConfig {
        gt_time_offset: src.gt_time_offset_ms / 1000.0,
        ..TumConfig::default()
    };
    let mut seq = TumSequence::open_with(&src.path, config)?;
    if let Some([first, end]) = src.frames {
        if first >= end || end > seq.len() {
            return Err(Error::invalid(
                &src.path,
                format!(
                    "frames = [{first}, {end}] must be a non-empty range [first, end) of the sequence's {} frames",
                    seq.len()
                ),
            ));
        }
        seq.frames.truncate(end);
        seq.frames.drain(..first);
    }
    if let Some(v) = src.val_fraction
        && !(0.0..1.0).contains(&v)
    {
        return Err(Error::invalid(
            &src.path,
            format!("val_fraction must be in [0, 1), got {v}"),
        ));
    }
    let camera = Camera::for_sequence(src.camera.as_deref(), &src.path)?;
    // Every frame checked against the camera where it is read (size, channels, bit depth).
    seq.expect_camera(&camera);
    if !seq.has_depth() || seq.groundtruth.is_none() {
        return Err(Error::invalid(
            &src.path,
            "FPFDCNN training needs depth and groundtruth.txt",
        ));
    }
    if crop && ((camera.width as usize) < width || (camera.height as usize) < height) {
        return Err(Error::invalid(
            &src.path,
            format!(
                "frames of {}x{} are smaller than the {width}x{height} training crops \
                 (use sampling = \"resize\" or a smaller height/width)",
                camera.width, camera.height
            ),
        ));
    }
    Ok((seq, camera))
}

/// Adds one sequence to the splits: its first frames (all but the last `val_fraction`, the
/// sequence's own when it has one; frame indices count from its `frames` range) to
/// `train`, the others to `val`, each pair to the split holding both its frames, the
/// homography pairs of the training frames, all pairs `repeat` times.
pub(super) fn add_sequence(
    train: &mut FpDataset,
    val: &mut FpDataset,
    src: &SequenceSource,
    seq: &TumSequence,
    camera: &Camera,
    cfg: &FpDataConfig,
) -> Result<()> {
    let size = [train.height, train.width];
    let n = seq.len();
    let val_fraction = src.val_fraction.unwrap_or(cfg.val_fraction);
    let cut = ((n as f64) * (1.0 - val_fraction)).round() as usize;
    // Frames at the training resolution, with their detector targets.
    let offset_train = train.frames.len();
    let offset_val = val.frames.len();
    let (first_train_pair, first_val_pair) = (train.pairs.len(), val.pairs.len());
    for (i, f) in load_frames(seq, cfg, size).into_iter().enumerate() {
        let f = f?;
        if i < cut {
            train.frames.push(f)
        } else {
            val.frames.push(f)
        }
    }
    let mut posed = 0;
    for pair in posed_pairs(seq, camera, cfg, size) {
        let (a, b, matches) = pair.map_err(|e| {
            let from = match src.frames {
                Some([first, _]) if first > 0 => {
                    format!(" (frame numbers count from frame {first}, the start of `frames`)")
                }
                _ => String::new(),
            };
            Error::invalid(&src.path, format!("{e}{from}"))
        })?;
        posed += 1;
        if b < cut {
            train.pairs.push(PairEntry {
                a: offset_train + a,
                b: offset_train + b,
                matches,
                homography: false,
            });
        } else if a >= cut {
            val.pairs.push(PairEntry {
                a: offset_val + a - cut,
                b: offset_val + b - cut,
                matches,
                homography: false,
            });
        }
    }
    if posed == 0
        && let Some(reason) = no_pairs_reason(seq, &cfg.pairs.gaps, src.homographies > 0)
    {
        return Err(Error::invalid(&src.path, reason));
    }
    for f in offset_train..train.frames.len() {
        for _ in 0..src.homographies {
            train.pairs.push(PairEntry {
                a: f,
                b: f,
                matches: Vec::new(),
                homography: true,
            });
        }
    }
    let (train_block, val_block) = (
        first_train_pair..train.pairs.len(),
        first_val_pair..val.pairs.len(),
    );
    for _ in 1..src.repeat {
        train.pairs.extend_from_within(train_block.clone());
        val.pairs.extend_from_within(val_block.clone());
    }
    Ok(())
}

/// Why a sequence gave no posed pair with at least 8 ground-truth matches, when that is an
/// error: no valid depth pixel in any frame always; too few frames for the smallest gap, or
/// pairs with too few matches, unless the sequence trains on its homography pairs.
fn no_pairs_reason(seq: &TumSequence, gaps: &[usize], homographies: bool) -> Option<String> {
    let n = seq.len();
    let any_depth =
        (0..n).any(|i| matches!(seq.load_depth(i), Ok(Some(d)) if d.valid_fraction() > 0.0));
    if !any_depth {
        return Some(format!(
            "none of its {n} frames has a valid depth pixel (0 = no reading): FPFDCNN's posed \
             pairs need depth"
        ));
    }
    if homographies {
        return None;
    }
    Some(if pair_indices(n, gaps).is_empty() {
        format!(
            "its {n} frames are too few for a pair at the smallest gap ({}): widen `frames` \
             or lower `[data.pairs] gaps`",
            gaps.iter().min().copied().unwrap_or(0)
        )
    } else {
        format!(
            "none of its {n} frames forms a posed pair with at least 8 ground-truth matches \
             (eqs 5-7): check its depth, its ground truth and the pairs' gaps"
        )
    })
}

/// Every frame of `seq` as stored (full resolution when cropping, else resized to
/// `[height, width]`) with its Harris targets, decoded in parallel; an image that does not
/// fit the camera is an error ([`TumSequence::expect_camera`], set by [`open_source`]).
fn load_frames(
    seq: &TumSequence,
    cfg: &FpDataConfig,
    [height, width]: [usize; 2],
) -> Vec<Result<FrameEntry>> {
    let crop = cfg.sampling == Sampling::Crop;
    (0..seq.len())
        .into_par_iter()
        .map(|i| {
            let gray = GrayF32::from_gray(&seq.load_gray(i)?);
            let gray = if crop {
                gray
            } else {
                resize_gray(&gray, width, height)
            };
            let targets = cfg.target_pixels(&gray)?;
            Ok(FrameEntry { gray, targets })
        })
        .collect()
}

/// The posed pairs of `seq` (eqs 5-7) as `(frame a, frame b, matches)`, matches in
/// stored-frame pixels; pairs with fewer than 8 matches inside both frames are left out.
fn posed_pairs<'a>(
    seq: &'a TumSequence,
    camera: &'a Camera,
    cfg: &'a FpDataConfig,
    [height, width]: [usize; 2],
) -> impl Iterator<Item = Result<(usize, usize, Vec<FpMatch>)>> + 'a {
    // Frame pixels to stored-frame pixels.
    let (fw, fh) = if cfg.sampling == Sampling::Crop {
        (camera.width as usize, camera.height as usize)
    } else {
        (width, height)
    };
    let (sx, sy) = (
        fw as f32 / camera.width as f32,
        fh as f32 / camera.height as f32,
    );
    fp_pairs(seq, camera, &cfg.pairs)
        .into_iter()
        .filter_map(move |pair| {
            let pair = match pair {
                Ok(p) => p,
                Err(e) => return Some(Err(e)),
            };
            let (a, b) = (pair.frame_a, pair.frame_b);
            let matches: Vec<FpMatch> = pair
                .matches
                .iter()
                .map(|m| FpMatch {
                    a: scale_point(m.a, sx, sy),
                    b: scale_point(m.b, sx, sy),
                })
                .filter(|m| inside(m.a, fw, fh) && inside(m.b, fw, fh))
                .collect();
            (matches.len() >= 8).then_some(Ok((a, b, matches)))
        })
}

/// Maps a pixel position to an image resized by `scale` (pixel centres aligned).
fn scale_point(p: [f32; 2], sx: f32, sy: f32) -> [f32; 2] {
    [(p[0] + 0.5) * sx - 0.5, (p[1] + 0.5) * sy - 0.5]
}
