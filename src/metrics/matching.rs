//! Feature-matching accuracy of the paper's Table 6 (section V-B): a match
//! `(pixel in A, pixel in B)` is correct when the B keypoint lies within 5 px of the
//! ground-truth projection of its A partner (A's depth, the camera with its
//! distortion and the ground-truth poses: eq 7). Matches whose A keypoint has no
//! depth reading cannot be judged and are not counted.

use crate::camera::Camera;
use crate::dataset::fp_pairs::{FpConfig, map_corners, transfer};
use crate::dataset::{DepthImage, Frame};
use crate::error::{Error, Result};
use crate::features::harris::Keypoint;
use crate::geometry::Pose;
use nalgebra::{Point2, Vector2};
use serde::{Deserialize, Serialize};

/// The paper's correctness radius, pixels.
pub const CORRECT_MATCH_PX: f64 = 5.0;

/// Correct matches among the judged ones (Table 6: "correct matching / match point").
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct MatchingAccuracy {
    /// Judged matches whose B keypoint lies within [`CORRECT_MATCH_PX`] of the ground-truth
    /// projection of its A partner.
    pub correct: usize,
    /// Judged matches (those whose A keypoint has a depth reading).
    pub matches: usize,
    /// `correct / matches` (0 without matches).
    pub accuracy: f64,
}

impl MatchingAccuracy {
    /// Counts with their ratio `correct / matches` (0 without matches).
    pub fn new(correct: usize, matches: usize) -> Self {
        MatchingAccuracy {
            correct,
            matches,
            accuracy: if matches == 0 {
                0.0
            } else {
                correct as f64 / matches as f64
            },
        }
    }

    /// Pools several frame pairs as the paper's totals do (sums of counts).
    pub fn pool(items: &[MatchingAccuracy]) -> Self {
        Self::new(
            items.iter().map(|m| m.correct).sum(),
            items.iter().map(|m| m.matches).sum(),
        )
    }
}

/// Distance in pixels between each match's B keypoint and the ground-truth
/// projection of its A keypoint; `None` when A has no depth there. A point that
/// projects behind camera B gets an infinite error.
pub(crate) fn match_errors(
    matches: &[(Point2<f64>, Point2<f64>)],
    depth_a: &DepthImage,
    camera: &Camera,
    pose_a: &Pose,
    pose_b: &Pose,
) -> Result<Vec<Option<f64>>> {
    Ok(
        match_error_vectors(matches, depth_a, camera, pose_a, pose_b)?
            .into_iter()
            .map(|e| e.map(|v| v.norm()))
            .collect(),
    )
}

/// [`match_errors`] as vectors, ground-truth projection minus B keypoint, pixels; a point
/// that projects behind camera B gets infinite components.
pub(crate) fn match_error_vectors(
    matches: &[(Point2<f64>, Point2<f64>)],
    depth_a: &DepthImage,
    camera: &Camera,
    pose_a: &Pose,
    pose_b: &Pose,
) -> Result<Vec<Option<Vector2<f64>>>> {
    if (depth_a.width, depth_a.height) != (camera.width, camera.height) {
        return Err(Error::msg(format!(
            "depth image is {}x{} but the camera is {}x{}",
            depth_a.width, depth_a.height, camera.width, camera.height
        )));
    }
    Ok(matches
        .iter()
        .map(|(pa, pb)| {
            let z = depth_a.at(pa.x, pa.y)?;
            Some(match transfer(camera, pa, z as f64, pose_a, pose_b) {
                Some((gt, _)) => gt - pb,
                None => Vector2::repeat(f64::INFINITY),
            })
        })
        .collect())
}

/// How many of one pair's match errors lie within `tolerance_px` of the pair's common
/// offset, the component-wise median of its finite errors. A ground-truth pose or clock
/// that is off moves every match's projection alike (on TUM fr1_rpy by up to 9 px a pair,
/// lab/notes/fpfdcnn-results.md *What the fr1_rpy pairs' accuracy measures*); this count asks how well the
/// matches agree with one another's motion instead. A diagnostic beside the paper's
/// accuracy, not a replacement: a matcher whose errors all share a direction scores well.
pub fn within_common_offset(errors: &[Vector2<f64>], tolerance_px: f64) -> usize {
    common_offset(errors).map_or(0, |offset| within_offset(errors, offset, tolerance_px))
}

/// How many of `errors` lie within `tolerance_px` of `offset` (infinite errors never do).
pub fn within_offset(errors: &[Vector2<f64>], offset: Vector2<f64>, tolerance_px: f64) -> usize {
    errors
        .iter()
        .filter(|e| (**e - offset).norm() <= tolerance_px)
        .count()
}

/// One pair's common offset: the component-wise median of its finite match errors (`None`
/// when it has none). It stands for the ground truth's error only while most of the pair's
/// matches are right; where most are wrong it is as scattered as they are, and few matches
/// lie within a few pixels of it (fr1_rpy frames 48-55, blurred by a fast turn: ORB's
/// medians 180-270 px off, none of its matches within 5 px of them).
pub(crate) fn common_offset(errors: &[Vector2<f64>]) -> Option<Vector2<f64>> {
    let finite: Vec<&Vector2<f64>> = errors
        .iter()
        .filter(|e| e.iter().all(|c| c.is_finite()))
        .collect();
    if finite.is_empty() {
        return None;
    }
    let median = |axis: usize| {
        let mut c: Vec<f64> = finite.iter().map(|e| e[axis]).collect();
        c.sort_by(f64::total_cmp);
        c[c.len() / 2]
    };
    Some(Vector2::new(median(0), median(1)))
}

/// Matching accuracy of one frame pair with correctness radius `tolerance_px`
/// ([`CORRECT_MATCH_PX`] in the paper). Poses are camera-to-world ground truth at
/// the two images' timestamps.
pub fn matching_accuracy(
    matches: &[(Point2<f64>, Point2<f64>)],
    depth_a: &DepthImage,
    camera: &Camera,
    pose_a: &Pose,
    pose_b: &Pose,
    tolerance_px: f64,
) -> Result<MatchingAccuracy> {
    if !(tolerance_px.is_finite() && tolerance_px > 0.0) {
        return Err(Error::msg(format!(
            "match tolerance must be a positive number of pixels, got {tolerance_px}"
        )));
    }
    let errors = match_errors(matches, depth_a, camera, pose_a, pose_b)?;
    let judged: Vec<f64> = errors.into_iter().flatten().collect();
    let correct = judged.iter().filter(|&&e| e <= tolerance_px).count();
    Ok(MatchingAccuracy::new(correct, judged.len()))
}

/// [`matching_accuracy`] of a loaded frame pair: A's depth and both frames'
/// ground-truth poses (interpolated at their RGB timestamps). Errors when A has no
/// depth or either frame no ground truth.
pub fn frame_pair_accuracy(
    matches: &[(Point2<f64>, Point2<f64>)],
    a: &Frame,
    b: &Frame,
    camera: &Camera,
) -> Result<MatchingAccuracy> {
    let depth = a.depth.as_ref().ok_or_else(|| {
        Error::msg(format!(
            "matching accuracy needs the first frame's depth: frame {} has none",
            a.index
        ))
    })?;
    let pose = |f: &Frame| {
        f.gt_pose.ok_or_else(|| {
            Error::msg(format!(
                "matching accuracy needs ground truth: frame {} has no pose",
                f.index
            ))
        })
    };
    matching_accuracy(
        matches,
        depth,
        camera,
        &pose(a)?,
        &pose(b)?,
        CORRECT_MATCH_PX,
    )
}

/// Radius of keypoint repeatability, pixels (SuperPoint's ε = 3).
pub(crate) const REPEATED_PX: f64 = 3.0;

/// Keypoint repeatability (Schmid, Mohr and Bauckhage 2000; SuperPoint's measure, DeTone et
/// al. 2018) pooled over both directions of frame pairs: a keypoint of one image is
/// *visible* when ground truth (its depth, both poses) carries it inside the other image
/// onto a surface that image's depth confirms (the FP pairs' occlusion check, eq 7), and
/// *repeated* when the other image has a keypoint within `REPEATED_PX` of it. Repeatability
/// bounds what any descriptor can match; correct matches per visible keypoint (the
/// matching score) measure detector and descriptor together.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Repeatability {
    /// Visible keypoints with a keypoint of the other image within `REPEATED_PX`.
    pub repeated: usize,
    /// Keypoints that ground truth carries onto a confirmed surface of the other image.
    pub visible: usize,
}

impl Repeatability {
    /// `repeated / visible` (0 when nothing is visible).
    pub fn rate(&self) -> f64 {
        self.repeated as f64 / self.visible.max(1) as f64
    }

    /// Sums of counts.
    pub fn pool(items: &[Repeatability]) -> Self {
        Repeatability {
            repeated: items.iter().map(|r| r.repeated).sum(),
            visible: items.iter().map(|r| r.visible).sum(),
        }
    }
}

/// [`Repeatability`] of two images' keypoints, A to B and B to A, within `tolerance_px`.
/// Both frames need depth and ground-truth poses.
pub fn repeatability(
    camera: &Camera,
    a: &Frame,
    b: &Frame,
    points_a: &[Point2<f64>],
    points_b: &[Point2<f64>],
    tolerance_px: f64,
) -> Result<Repeatability> {
    let cfg = FpConfig::default();
    let keypoints = |p: &[Point2<f64>]| -> Vec<Keypoint> {
        p.iter()
            .map(|p| Keypoint {
                x: p.x as f32,
                y: p.y as f32,
                score: 0.0,
            })
            .collect()
    };
    let mut r = Repeatability::default();
    for (from, to, p_from, p_to) in [(a, b, points_a, points_b), (b, a, points_b, points_a)] {
        let carried = map_corners(camera, from, to, keypoints(p_from), &cfg)?;
        let t2 = tolerance_px * tolerance_px;
        for m in &carried.matches {
            let q = Point2::new(m.b[0] as f64, m.b[1] as f64);
            r.visible += 1;
            if p_to.iter().any(|p| (p - q).norm_squared() <= t2) {
                r.repeated += 1;
            }
        }
    }
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    #[test]
    fn counts_correct_wrong_and_unjudged_matches() {
        let cam = Camera::tum_fr1();
        let mut depth = DepthImage::new(640, 480);
        depth.data.iter_mut().for_each(|d| *d = 2.0);
        depth.data[100 * 640 + 100] = 0.0; // no reading at (100, 100)
        let pose_a = Pose::identity();
        let pose_b = Pose::from_parts(
            Translation3::new(0.1, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.02),
        );
        let gt = |u: f64, v: f64| {
            transfer(&cam, &Point2::new(u, v), 2.0, &pose_a, &pose_b)
                .unwrap()
                .0
        };
        let g1 = gt(300.0, 200.0);
        let g2 = gt(400.0, 300.0);
        let matches = vec![
            (Point2::new(300.0, 200.0), g1 + Vector2::new(2.94, 3.92)), // 4.9 px: correct
            (Point2::new(400.0, 300.0), g2 + Vector2::new(5.1, 0.0)),   // wrong
            (Point2::new(100.0, 100.0), Point2::new(0.0, 0.0)),         // not judged
        ];
        let acc =
            matching_accuracy(&matches, &depth, &cam, &pose_a, &pose_b, CORRECT_MATCH_PX).unwrap();
        assert_eq!((acc.correct, acc.matches), (1, 2));
        assert!((acc.accuracy - 0.5).abs() < 1e-12);
        let errs = match_errors(&matches, &depth, &cam, &pose_a, &pose_b).unwrap();
        assert!((errs[0].unwrap() - 4.9).abs() < 1e-9 && errs[2].is_none());
        let pooled = MatchingAccuracy::pool(&[acc, MatchingAccuracy::new(3, 4)]);
        assert_eq!((pooled.correct, pooled.matches), (4, 6));
        assert_eq!(MatchingAccuracy::pool(&[]).accuracy, 0.0);
        assert!(matching_accuracy(&matches, &depth, &cam, &pose_a, &pose_b, 0.0).is_err());
        let small = DepthImage::new(320, 240);
        assert!(match_errors(&matches, &small, &cam, &pose_a, &pose_b).is_err());
    }

    #[test]
    fn repeatability_counts_visible_keypoints_found_again() {
        let cam = Camera::tum_fr1();
        let frame = |index: usize, pose: Pose, near: bool| {
            let mut depth = DepthImage::new(640, 480);
            depth.data.iter_mut().for_each(|d| *d = 2.0);
            if near {
                // A box 0.5 m in front of the wall hides pixels x >= 600 of B.
                for y in 0..480 {
                    for x in 600..640 {
                        depth.data[y * 640 + x] = 1.5;
                    }
                }
            }
            Frame {
                index,
                stamp: index as f64,
                rgb: image::RgbImage::new(640, 480),
                depth: Some(depth),
                gt_pose: Some(pose),
            }
        };
        let pose_b = Pose::from_parts(
            Translation3::new(0.05, 0.0, 0.0),
            UnitQuaternion::identity(),
        );
        let (a, b) = (frame(0, Pose::identity(), false), frame(1, pose_b, true));
        let carry = |u: f64, v: f64| {
            transfer(&cam, &Point2::new(u, v), 2.0, &Pose::identity(), &pose_b)
                .unwrap()
                .0
        };
        let points_a = vec![
            Point2::new(300.0, 200.0), // found again 2 px away
            Point2::new(400.0, 300.0), // not found (4 px away)
            Point2::new(5.0, 240.0),   // carried outside B: not visible
        ];
        let points_b = vec![
            carry(300.0, 200.0) + Vector2::new(2.0, 0.0),
            carry(400.0, 300.0) + Vector2::new(0.0, 4.0),
            Point2::new(620.0, 240.0), // on B's box: A sees the wall there, hidden
        ];
        let r = repeatability(&cam, &a, &b, &points_a, &points_b, REPEATED_PX).unwrap();
        // A to B: two visible, one repeated. B to A: the first two visible (both have an A
        // keypoint within 3 px? the second is 4 px away: no), the third occluded.
        assert_eq!((r.visible, r.repeated), (4, 2), "{r:?}");
        assert!((r.rate() - 0.5).abs() < 1e-12);
        let pooled = Repeatability::pool(&[
            r,
            Repeatability {
                repeated: 1,
                visible: 4,
            },
        ]);
        assert_eq!((pooled.repeated, pooled.visible), (3, 8));
        assert_eq!(Repeatability::default().rate(), 0.0);
        let no_depth = Frame {
            depth: None,
            ..b.clone()
        };
        assert!(repeatability(&cam, &a, &no_depth, &points_a, &points_b, 3.0).is_err());
    }

    #[test]
    fn serialises_as_table_6_needs() {
        let json = serde_json::to_string(&MatchingAccuracy::new(276, 329)).unwrap();
        assert!(json.contains("\"correct\":276") && json.contains("\"matches\":329"));
    }

    #[test]
    fn a_common_offset_is_removed_and_outliers_stay_wrong() {
        // Eight matches 7 px off to the right (a ground truth that is off), give or take a
        // pixel; one wrong partner 30 px away; one behind the camera.
        let mut e: Vec<Vector2<f64>> = (0..8)
            .map(|k| Vector2::new(7.0 + 0.25 * k as f64, 0.5 - 0.125 * k as f64))
            .collect();
        e.push(Vector2::new(-23.0, 0.0));
        e.push(Vector2::repeat(f64::INFINITY));
        assert_eq!(e.iter().filter(|v| v.norm() <= CORRECT_MATCH_PX).count(), 0);
        assert_eq!(within_common_offset(&e, CORRECT_MATCH_PX), 8);
        assert_eq!(within_common_offset(&e, 1.0), 7);
        assert_eq!(within_common_offset(&[], CORRECT_MATCH_PX), 0);
        assert_eq!(within_common_offset(&e[9..], CORRECT_MATCH_PX), 0);
    }

    #[test]
    fn error_vectors_agree_with_the_distances() {
        let cam = Camera::tum_fr1();
        let mut depth = DepthImage::new(640, 480);
        depth.data.iter_mut().for_each(|d| *d = 2.0);
        depth.data[10 * 640 + 10] = 0.0;
        let pose_b = Pose::from_parts(
            Translation3::new(0.05, 0.01, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::x_axis(), 0.03),
        );
        let matches = vec![
            (Point2::new(300.0, 200.0), Point2::new(310.0, 190.0)),
            (Point2::new(10.0, 10.0), Point2::new(12.0, 12.0)),
        ];
        let id = Pose::identity();
        let d = match_errors(&matches, &depth, &cam, &id, &pose_b).unwrap();
        let v = match_error_vectors(&matches, &depth, &cam, &id, &pose_b).unwrap();
        assert!(d[1].is_none() && v[1].is_none());
        let g = transfer(&cam, &matches[0].0, 2.0, &id, &pose_b).unwrap().0;
        assert!((v[0].unwrap() - (g - matches[0].1)).norm() < 1e-12);
        assert!((d[0].unwrap() - v[0].unwrap().norm()).abs() < 1e-12);
    }
}
