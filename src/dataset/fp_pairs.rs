//! The paper's feature-point ("FP") dataset (section IV-B, eqs 5-7, and section
//! V-B): Harris corners of a frame A, back-projected with A's depth and carried
//! into a frame B by the ground-truth poses, give the matching pairs that train
//! FPFDCNN's descriptors; the corners themselves are its detector targets.
//!
//! With camera-to-world poses `T_A`, `T_B` (TUM convention), eq 7 reads
//! `p2 = T_B⁻¹ T_A p1`: the paper's `q, t` are world-to-camera.

use super::depth::DepthImage;
use super::tum::{Frame, TumSequence};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::features::harris::{HarrisConfig, Keypoint, harris_corners};
use crate::geometry::Pose;
use crate::raster::GrayF32;
use image::RgbImage;
use nalgebra::{Point2, Point3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// How pairs are built.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FpConfig {
    /// Frame gaps `k` of the pairs `(i, i + k)`.
    pub gaps: Vec<usize>,
    /// Harris detector producing the corners of frame A. The default keeps weaker
    /// corners than [`HarrisConfig::default`] (threshold 0.1 % of the strongest
    /// response, at most 1000): about 140 on a TUM fr1 frame instead of 60.
    pub harris: HarrisConfig,
    /// Depth agreement in B: `|z_B(pixel) − z_projected| ≤ max(abs, rel · z_projected)`.
    pub depth_tolerance_abs: f64,
    /// Relative part `rel` of the depth agreement above, as a fraction of the projected depth.
    pub depth_tolerance_rel: f64,
    /// Keep projections that land where B has no depth reading (visibility unknown).
    pub keep_unverified: bool,
}

impl FpConfig {
    /// Checks the settings; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if self.gaps.is_empty() || self.gaps.iter().any(|&g| g == 0 || g > 10_000) {
            return Err(format!(
                "pairs.gaps {:?} must list frame gaps in 1..=10000",
                self.gaps
            ));
        }
        self.harris.validate().map_err(|m| format!("pairs.{m}"))?;
        for (v, what) in [
            (self.depth_tolerance_abs, "depth_tolerance_abs"),
            (self.depth_tolerance_rel, "depth_tolerance_rel"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!(
                    "pairs.{what} must be a non-negative number, got {v}"
                ));
            }
        }
        Ok(())
    }
}

impl Default for FpConfig {
    fn default() -> Self {
        FpConfig {
            gaps: vec![1, 2, 3],
            harris: HarrisConfig {
                relative_threshold: 0.001,
                max_corners: 1000,
                ..HarrisConfig::default()
            },
            depth_tolerance_abs: 0.03,
            depth_tolerance_rel: 0.03,
            keep_unverified: false,
        }
    }
}

/// A ground-truth correspondence: a corner of A and where it is seen in B (sub-pixel).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FpMatch {
    /// Corner pixel in frame A.
    pub a: [f32; 2],
    /// Where it projects in frame B, pixels (sub-pixel).
    pub b: [f32; 2],
}

/// The pairs of one frame pair, with why the other corners were rejected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FpPair {
    /// Index of frame A in its sequence.
    pub frame_a: usize,
    /// Index of frame B in its sequence.
    pub frame_b: usize,
    /// Harris corners of A, strongest first.
    pub corners_a: Vec<Keypoint>,
    /// Corners of A seen in B, with their positions there.
    pub matches: Vec<FpMatch>,
    /// Corners without a depth reading in A.
    pub no_depth: usize,
    /// Corners projecting outside B (or behind its camera).
    pub outside: usize,
    /// Corners whose projected depth disagrees with B's depth at that pixel
    /// (hidden behind something nearer, or a surface that moved).
    pub occluded: usize,
    /// Corners landing where B has no depth reading (dropped unless
    /// [`FpConfig::keep_unverified`]).
    pub unverified: usize,
}

/// Eq 7: pixel `px_a` of camera A at z-depth `z_a` seen from camera B, as a
/// (distorted) pixel of B and its z-depth there. `None` behind camera B.
pub fn transfer(
    camera: &Camera,
    px_a: &Point2<f64>,
    z_a: f64,
    pose_a: &Pose,
    pose_b: &Pose,
) -> Option<(Point2<f64>, f64)> {
    let p1 = camera.back_project(px_a, z_a);
    let p2: Point3<f64> = pose_b.inverse() * (pose_a * p1);
    camera.project(&p2).map(|px| (px, p2.z))
}

/// A full-resolution binary map of detector targets: 1 at corner pixels.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct TargetMap {
    /// Map width, pixels.
    pub width: usize,
    /// Map height, pixels.
    pub height: usize,
    /// Row-major, `width * height` values in {0, 1}.
    pub data: Vec<u8>,
}

impl TargetMap {
    /// Marks the pixel nearest to each keypoint (keypoints outside are ignored).
    pub fn from_keypoints(keypoints: &[Keypoint], width: usize, height: usize) -> Self {
        let mut data = vec![0u8; width * height];
        for k in keypoints {
            let (x, y) = (k.x.round(), k.y.round());
            if x >= 0.0 && y >= 0.0 && (x as usize) < width && (y as usize) < height {
                data[y as usize * width + x as usize] = 1;
            }
        }
        TargetMap {
            width,
            height,
            data,
        }
    }

    /// Number of target pixels.
    #[cfg(test)]
    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&v| v != 0).count()
    }
}

/// Detector targets of a colour image: its Harris corners (on the ITU-R 601 luma)
/// and their full-resolution map.
pub(crate) fn detector_targets(
    rgb: &RgbImage,
    harris: &HarrisConfig,
) -> (Vec<Keypoint>, TargetMap) {
    let gray = GrayF32::from_rgb(rgb);
    let corners = harris_corners(&gray, harris);
    let map = TargetMap::from_keypoints(&corners, gray.width, gray.height);
    (corners, map)
}

/// Frame pairs `(i, i + k)` of a sequence of `n_frames`, by `i` then by gap order.
pub(crate) fn pair_indices(n_frames: usize, gaps: &[usize]) -> Vec<(usize, usize)> {
    (0..n_frames)
        .flat_map(|i| {
            gaps.iter()
                .filter(move |&&k| k > 0 && i + k < n_frames)
                .map(move |&k| (i, i + k))
        })
        .collect()
}

fn frame_parts<'f>(f: &'f Frame, camera: &Camera, role: &str) -> Result<(&'f DepthImage, Pose)> {
    let depth = f.depth.as_ref().ok_or_else(|| {
        Error::msg(format!(
            "FP pairs need depth: frame {} ({role}) has none",
            f.index
        ))
    })?;
    let pose = f.gt_pose.ok_or_else(|| {
        Error::msg(format!(
            "FP pairs need ground truth: frame {} ({role}) has no pose within the gap limit",
            f.index
        ))
    })?;
    if (depth.width, depth.height) != (camera.width, camera.height) {
        return Err(Error::msg(format!(
            "frame {} ({role}) is {}x{} but the camera is {}x{}",
            f.index, depth.width, depth.height, camera.width, camera.height
        )));
    }
    Ok((depth, pose))
}

/// Maps given corners of A into B (eqs 5-7) with the occlusion check; the corners
/// are kept in the result as `corners_a`.
pub(crate) fn map_corners(
    camera: &Camera,
    a: &Frame,
    b: &Frame,
    corners_a: Vec<Keypoint>,
    cfg: &FpConfig,
) -> Result<FpPair> {
    let (depth_a, pose_a) = frame_parts(a, camera, "A")?;
    let (depth_b, pose_b) = frame_parts(b, camera, "B")?;
    let mut pair = FpPair {
        frame_a: a.index,
        frame_b: b.index,
        corners_a: Vec::new(),
        matches: Vec::new(),
        no_depth: 0,
        outside: 0,
        occluded: 0,
        unverified: 0,
    };
    for k in &corners_a {
        let Some(z) = depth_a.at(k.x as f64, k.y as f64) else {
            pair.no_depth += 1;
            continue;
        };
        let px_a = Point2::new(k.x as f64, k.y as f64);
        let Some((px_b, z_b)) = transfer(camera, &px_a, z as f64, &pose_a, &pose_b) else {
            pair.outside += 1;
            continue;
        };
        if !camera.contains(&px_b, 0.0) {
            pair.outside += 1;
            continue;
        }
        match depth_b.at(px_b.x, px_b.y) {
            None if !cfg.keep_unverified => {
                pair.unverified += 1;
                continue;
            }
            None => pair.unverified += 1,
            Some(d) => {
                let tol = cfg.depth_tolerance_abs.max(cfg.depth_tolerance_rel * z_b);
                if (d as f64 - z_b).abs() > tol {
                    pair.occluded += 1;
                    continue;
                }
            }
        }
        pair.matches.push(FpMatch {
            a: [k.x, k.y],
            b: [px_b.x as f32, px_b.y as f32],
        });
    }
    pair.corners_a = corners_a;
    Ok(pair)
}

/// The FP pair of two loaded frames: Harris corners of A mapped into B.
pub fn fp_pair(camera: &Camera, a: &Frame, b: &Frame, cfg: &FpConfig) -> Result<FpPair> {
    let (corners, _) = detector_targets(&a.rgb, &cfg.harris);
    map_corners(camera, a, b, corners, cfg)
}

/// Consecutive first frames whose pairs one worker of [`fp_pairs`] computes, decoding each
/// frame they need once (a block decodes `PAIR_BLOCK` + the largest gap frames).
const PAIR_BLOCK: usize = 32;

/// All FP pairs of a sequence, in `pair_indices` order, computed in parallel: the pairs
/// are cut into blocks of `PAIR_BLOCK` consecutive first frames, and each block decodes
/// the frames it needs once and keeps them only while it runs.
pub fn fp_pairs(seq: &TumSequence, camera: &Camera, cfg: &FpConfig) -> Vec<Result<FpPair>> {
    pairs_in_blocks(seq, camera, cfg, PAIR_BLOCK)
}

fn pairs_in_blocks(
    seq: &TumSequence,
    camera: &Camera,
    cfg: &FpConfig,
    block: usize,
) -> Vec<Result<FpPair>> {
    let pairs = pair_indices(seq.len(), &cfg.gaps);
    let block = block.max(1);
    let blocks: Vec<&[(usize, usize)]> =
        pairs.chunk_by(|p, q| p.0 / block == q.0 / block).collect();
    let done: Vec<Vec<Result<FpPair>>> = blocks
        .par_iter()
        .map(|block| {
            let mut cache: BTreeMap<usize, Frame> = BTreeMap::new();
            // A's corners, for the consecutive pairs that share A ([`fp_pair`] per pair).
            let mut corners: Option<(usize, Vec<Keypoint>)> = None;
            block
                .iter()
                .map(|&(i, j)| {
                    cache.retain(|&k, _| k >= i);
                    for idx in [i, j] {
                        if let std::collections::btree_map::Entry::Vacant(e) = cache.entry(idx) {
                            e.insert(seq.load_frame(idx)?);
                        }
                    }
                    let (Some(a), Some(b)) = (cache.get(&i), cache.get(&j)) else {
                        return Err(Error::msg(format!(
                            "frames {i} and {j} could not be loaded"
                        )));
                    };
                    if corners.as_ref().is_none_or(|(k, _)| *k != i) {
                        corners = Some((i, detector_targets(&a.rgb, &cfg.harris).0));
                    }
                    let of_a = corners.as_ref().map(|(_, c)| c.clone()).unwrap_or_default();
                    map_corners(camera, a, b, of_a, cfg)
                })
                .collect()
        })
        .collect();
    done.into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    const FIXTURE: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/datasets/fixtures/tum_fr1_rpy_head10"
    );

    #[test]
    fn pair_indices_respect_sequence_end() {
        assert_eq!(
            pair_indices(4, &[1, 3]),
            vec![(0, 1), (0, 3), (1, 2), (2, 3)]
        );
        assert!(pair_indices(3, &[0, 5]).is_empty());
    }

    #[test]
    fn transfer_is_identity_for_equal_poses() {
        let cam = Camera::tum_fr1();
        let pose = Pose::identity();
        let (px, z) = transfer(&cam, &Point2::new(100.0, 50.0), 2.0, &pose, &pose).unwrap();
        assert!((px - Point2::new(100.0, 50.0)).norm() < 1e-9 && (z - 2.0).abs() < 1e-12);
    }

    #[test]
    fn real_pair_gives_matches_and_targets() {
        let seq = TumSequence::open(FIXTURE).unwrap();
        let cam = Camera::tum_fr1();
        let cfg = FpConfig::default();
        let (a, b) = (seq.load_frame(0).unwrap(), seq.load_frame(3).unwrap());
        let pair = fp_pair(&cam, &a, &b, &cfg).unwrap();
        let n = pair.corners_a.len();
        assert_eq!(
            n,
            pair.matches.len() + pair.no_depth + pair.outside + pair.occluded + pair.unverified
        );
        eprintln!(
            "FP pair 0-3: {n} corners, {} matches, {} without depth, {} outside, {} occluded, {} unverified",
            pair.matches.len(),
            pair.no_depth,
            pair.outside,
            pair.occluded,
            pair.unverified
        );
        assert!(pair.matches.len() >= 80, "{} matches", pair.matches.len());
        let (corners, map) = detector_targets(&a.rgb, &cfg.harris);
        assert_eq!(corners, pair.corners_a);
        assert_eq!(map.count(), corners.len());
        assert_eq!((map.width, map.height), (640, 480));
        // Lazily over the fixture: 7 pairs (i, i + 3) in 10 frames.
        let cfg3 = FpConfig {
            gaps: vec![3],
            ..cfg.clone()
        };
        let all: Vec<FpPair> = fp_pairs(&seq, &cam, &cfg3)
            .into_iter()
            .collect::<Result<_>>()
            .unwrap();
        assert_eq!(all.len(), 7);
        assert_eq!(all[0], pair);
    }

    #[test]
    fn pairs_in_parallel_blocks_equal_pairs_one_by_one() {
        let seq = TumSequence::open(FIXTURE).unwrap();
        let cam = Camera::tum_fr1();
        let cfg = FpConfig {
            gaps: vec![1, 3],
            ..FpConfig::default()
        };
        let expected: Vec<FpPair> = pair_indices(seq.len(), &cfg.gaps)
            .into_iter()
            .map(|(i, j)| {
                let (a, b) = (seq.load_frame(i).unwrap(), seq.load_frame(j).unwrap());
                fp_pair(&cam, &a, &b, &cfg).unwrap()
            })
            .collect();
        assert_eq!(expected.len(), 16);
        for block in [1, 3, PAIR_BLOCK] {
            let got: Vec<FpPair> = pairs_in_blocks(&seq, &cam, &cfg, block)
                .into_iter()
                .collect::<Result<_>>()
                .unwrap();
            assert_eq!(got, expected, "blocks of {block} first frames");
        }
    }

    #[test]
    fn nearer_depth_in_b_rejects_as_occluded() {
        let seq = TumSequence::open(FIXTURE).unwrap();
        let cam = Camera::tum_fr1();
        let cfg = FpConfig::default();
        let a = seq.load_frame(0).unwrap();
        let mut b = seq.load_frame(3).unwrap();
        let clean = fp_pair(&cam, &a, &b, &cfg).unwrap();
        // Something 20 cm in front of everything in B hides every corner.
        if let Some(d) = b.depth.as_mut() {
            d.data.iter_mut().for_each(|v| {
                if *v > 0.0 {
                    *v = (*v - 0.2).max(0.01)
                }
            });
        }
        let hidden = fp_pair(&cam, &a, &b, &cfg).unwrap();
        assert!(hidden.matches.is_empty(), "{} kept", hidden.matches.len());
        assert!(hidden.occluded >= clean.matches.len());
        // Without depth in B nothing can be verified.
        b.depth
            .as_mut()
            .unwrap()
            .data
            .iter_mut()
            .for_each(|v| *v = 0.0);
        let blind = fp_pair(&cam, &a, &b, &cfg).unwrap();
        assert!(blind.matches.is_empty());
        let kept = fp_pair(
            &cam,
            &a,
            &b,
            &FpConfig {
                keep_unverified: true,
                ..cfg
            },
        )
        .unwrap();
        assert_eq!(kept.matches.len(), blind.unverified);
        // Missing ground truth is an error, not a panic.
        b.gt_pose = None;
        assert!(fp_pair(&cam, &a, &b, &FpConfig::default()).is_err());
    }
}
