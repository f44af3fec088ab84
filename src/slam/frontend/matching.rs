//! The 3D-2D correspondences tracking and keyframe-pair verification are made of: keypoints
//! with world points (a keyframe's, the previous frame's) range-matched (Fig. 4, eq 8) to a
//! frame's keypoints, each current keypoint keeping its nearest-descriptor match.

use super::keypoints::KeyFeatures;
use crate::camera::Camera;
use crate::geometry::Pose;
use crate::pnp::solve_pnp_ransac;
use crate::range_matcher::{RangeMatcherConfig, range_match};
use crate::slam::config::SlamConfig;
use crate::slam::map::{KeyframeFeatures, ViewBounds};
use nalgebra::{Point2, Point3};

/// 3D-2D correspondences for PnP (world points, current pixels).
#[derive(Default)]
pub(super) struct Correspondences {
    pub(super) world: Vec<Point3<f64>>,
    pub(super) pixels: Vec<Point2<f64>>,
    pub(super) current: Vec<usize>,
    pub(super) from_reference: Vec<bool>,
    /// Keypoint index in its source.
    pub(super) source: Vec<usize>,
}

/// Keypoints with world points to match against (a keyframe or the previous frame).
#[derive(Clone, Copy)]
pub(super) struct Source<'a> {
    pub(super) features: &'a KeyFeatures,
    pub(super) world: &'a [Option<Point3<f64>>],
    /// Whether it is the reference keyframe.
    pub(super) reference: bool,
}

/// The best match of a current keypoint so far.
#[derive(Clone, Copy)]
struct Candidate {
    distance: f32,
    world: Point3<f64>,
    reference: bool,
    source: usize,
}

/// A verified keyframe pair.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct PairMatch {
    /// `T_a⁻¹ T_b`.
    pub relative: Pose,
    /// Number of PnP inliers.
    pub inliers: usize,
    /// Inlier keypoint pairs `(in a, in b)`.
    pub matches: Vec<(u32, u32)>,
}

/// 3D-2D correspondences between sources (keypoints with world points) and the
/// current keypoints. With `guide` (a camera-to-world pose of the current
/// frame), search windows are centred on the projections of the world points.
pub(super) fn correspond(
    camera: &Camera,
    sources: &[Source<'_>],
    current: &KeyFeatures,
    guide: Option<&Pose>,
    cfg: &RangeMatcherConfig,
) -> Correspondences {
    let world_to_cam = guide.map(|g| g.inverse());
    let bounds = ViewBounds::new(camera);
    // Best (distance, world point, from reference) per current keypoint.
    let mut best: Vec<Option<Candidate>> = vec![None; current.len()];
    for &Source {
        features,
        world,
        reference,
    } in sources
    {
        if features.dim != current.dim || features.dim == 0 {
            continue;
        }
        let ids: Vec<usize> = (0..features.len())
            .filter(|&i| world.get(i).is_some_and(|w| w.is_some()))
            .collect();
        if ids.is_empty() || current.is_empty() {
            continue;
        }
        let mut centres = Vec::with_capacity(ids.len());
        let mut desc = Vec::with_capacity(ids.len() * features.dim);
        for &i in &ids {
            let mut c = features.points[i];
            if let (Some(t), Some(Some(w))) = (&world_to_cam, world.get(i)) {
                let q = t * w;
                if bounds.contains(&q)
                    && let Some(px) = camera.project(&q)
                {
                    c = [px.x as f32, px.y as f32];
                }
            }
            centres.push(c);
            desc.extend_from_slice(features.descriptor(i));
        }
        let Ok(matches) = range_match(
            &centres,
            &desc,
            &current.points,
            &current.descriptors,
            current.dim,
            cfg,
        ) else {
            continue;
        };
        for m in matches {
            let Some(Some(w)) = world.get(ids[m.i]) else {
                continue;
            };
            if best[m.j].is_none_or(|b| m.distance < b.distance) {
                best[m.j] = Some(Candidate {
                    distance: m.distance,
                    world: *w,
                    reference,
                    source: ids[m.i],
                });
            }
        }
    }
    let mut corr = Correspondences::default();
    for (j, b) in best.into_iter().enumerate() {
        if let Some(c) = b {
            let p = current.points[j];
            corr.world.push(c.world);
            corr.pixels.push(Point2::new(p[0] as f64, p[1] as f64));
            corr.current.push(j);
            corr.from_reference.push(c.reference);
            corr.source.push(c.source);
        }
    }
    corr
}

/// Matches keyframe `a`'s keypoints (with 3D points) to keyframe `b`'s and
/// estimates `T_a⁻¹ T_b` by PnP: guided by `guess` (that relative pose) with the
/// normal window, else with the wide window. Returns the relative pose, the
/// inliers and the inlier keypoint pairs `(in a, in b)`.
pub(crate) fn verify_pair(
    camera: &Camera,
    cfg: &SlamConfig,
    a: &KeyframeFeatures,
    b: &KeyframeFeatures,
    guess: Option<&Pose>,
) -> Option<PairMatch> {
    let attempt = |guide: Option<&Pose>, mcfg: &RangeMatcherConfig| {
        let corr = correspond(
            camera,
            &[Source {
                features: &a.features,
                world: &a.points_cam,
                reference: true,
            }],
            &b.features,
            guide,
            mcfg,
        );
        if corr.world.len() < cfg.correction.min_inliers {
            return None;
        }
        let prior = guide.map(|g| g.inverse());
        let r = solve_pnp_ransac(
            &corr.world,
            &corr.pixels,
            camera,
            prior.as_ref(),
            &cfg.pnp.pnp(),
        )
        .ok()?;
        let ok = r.n_inliers >= cfg.correction.min_inliers
            && r.n_inliers as f64 >= cfg.correction.min_inlier_ratio * corr.world.len() as f64;
        ok.then_some((r, corr))
    };
    let (r, corr) = guess
        .and_then(|g| attempt(Some(g), &cfg.matcher.range()))
        .or_else(|| attempt(None, &cfg.matcher.wide()))?;
    let pairs = (0..corr.world.len())
        .filter(|&k| r.inliers[k])
        .map(|k| (corr.source[k] as u32, corr.current[k] as u32))
        .collect();
    Some(PairMatch {
        relative: r.pose.inverse(),
        inliers: r.n_inliers,
        matches: pairs,
    })
}
