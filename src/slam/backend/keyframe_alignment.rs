//! Depth between keyframes (RGB-D mode): keyframe depth images aligned to each other by the
//! point-to-plane ICP of [`crate::slam::frontend::depth_alignment`], at the keyframes' fusion resolution:
//! each keyframe to its `dense.keyframe_edges` predecessors, from tracking's relative pose,
//! and (`dense.loop_edges`) the two keyframes of each verified loop constraint, from its PnP
//! pose. An alignment that pairs enough points and stays near its starting pose becomes a
//! relative-pose edge of the final pose graph and of bundle adjustment: the keyframes are then
//! held by whole depth images, not by keypoints alone (what dense trackers such as
//! KinectFusion gain over sparse ones).
//!
//! The starting poses never change once made (tracking's odometry, the constraints' PnP), so
//! the edges do not depend on when they are computed: threaded and single-thread runs agree.

use super::pose_graph::{Edge, information};
use crate::camera::{Camera, RayTable};
use crate::dataset::DepthImage;
use crate::error::{Error, Result};
use crate::geometry::Pose;
use crate::slam::config::{DenseConfig, SlamConfig};
use crate::slam::frontend::depth_alignment::{DepthModel, align};
use crate::slam::map::{ConstraintKind, KeyFrame, Map};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::Instant;

/// What the keyframe alignments did.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct KeyframeAlignmentSummary {
    /// Keyframe pairs aligned (consecutive ones and loop pairs).
    pub pairs: usize,
    /// Pairs that became edges.
    pub edges: usize,
    /// Of those, loop pairs.
    #[serde(default)]
    pub loop_edges: usize,
    /// Median change of the starting relative pose over the kept pairs, metres.
    pub median_correction: f64,
    /// Wall time of the alignments, seconds.
    pub seconds: f64,
}

/// A keyframe paired with an earlier one (whose depth becomes the model).
#[derive(Debug, Clone, Copy)]
struct Pair {
    later: usize,
    /// Starting `T_i⁻¹ T_j`.
    start: Pose,
    is_loop: bool,
}

/// The keyframe pairs to align, grouped by the earlier keyframe.
fn pairs(map: &Map, cfg: &SlamConfig) -> BTreeMap<usize, Vec<Pair>> {
    let d = &cfg.dense;
    let n = map.keyframes.len();
    let mut by_model: BTreeMap<usize, Vec<Pair>> = BTreeMap::new();
    for i in 0..n {
        for j in i + 1..n.min(i + 1 + d.keyframe_edges) {
            let (a, b) = (&map.keyframes[i], &map.keyframes[j]);
            by_model.entry(i).or_default().push(Pair {
                later: j,
                start: a.odom_pose.inverse() * b.odom_pose,
                is_loop: false,
            });
        }
    }
    if d.loop_edges {
        for c in &map.constraints {
            let (i, j) = (c.a.min(c.b), c.a.max(c.b));
            let beyond_window = j > i + d.keyframe_edges;
            if c.kind != ConstraintKind::Odometry && beyond_window && j < n {
                let start = if c.a < c.b {
                    c.relative
                } else {
                    c.relative.inverse()
                };
                let list = by_model.entry(i).or_default();
                if !list.iter().any(|p| p.later == j) {
                    list.push(Pair {
                        later: j,
                        start,
                        is_loop: true,
                    });
                }
            }
        }
    }
    by_model
}

/// The depth a keyframe is aligned with: the sensor's when the view keeps it
/// (`dense.edges_on_filtered_depth` off), else the view's, after the map's depth-edge filter.
fn aligned_depth(k: &KeyFrame) -> &DepthImage {
    k.view.unfiltered_depth.as_ref().unwrap_or(&k.view.depth)
}

/// The edges of the keyframe alignments, in the pose graph's convention (`Z = T_i⁻¹ T_j`,
/// `i < j`), ordered by `i`, then consecutive pairs before loop pairs.
pub fn keyframe_edges(
    map: &Map,
    camera: &Camera,
    cfg: &SlamConfig,
) -> (Vec<Edge>, KeyframeAlignmentSummary) {
    let started = Instant::now();
    let d = &cfg.dense;
    let mut summary = KeyframeAlignmentSummary::default();
    let Some(first) = map.keyframes.first() else {
        return (Vec::new(), summary);
    };
    if d.keyframe_edges == 0 || map.keyframes.len() < 2 {
        return (Vec::new(), summary);
    }
    let range = (cfg.tracking.min_depth, cfg.tracking.max_depth);
    // Every edge's information: the fixed standard deviations.
    let information = information(d.sigma_translation, d.sigma_rotation_deg);
    let rays = Arc::new(RayTable::new(camera, first.view.stride));
    let groups: Vec<(usize, Vec<Pair>)> = pairs(map, cfg).into_iter().collect();
    summary.pairs = groups.iter().map(|(_, list)| list.len()).sum();
    // One model at a time per thread: a keyframe's model is built once and every keyframe
    // paired with it is aligned to it.
    let per_model: Vec<Vec<(Edge, f64, bool)>> = groups
        .par_iter()
        .map(|(i, list)| {
            let a = &map.keyframes[*i];
            let Some(model) =
                DepthModel::new(aligned_depth(a), camera, rays.clone(), d.model_step, range)
            else {
                return Vec::new();
            };
            list.iter()
                .filter_map(|p| {
                    let (j, initial, is_loop) = (p.later, p.start, p.is_loop);
                    let depth = aligned_depth(&map.keyframes[j]);
                    let found = align(&model, depth, &initial, range, d)?;
                    let moved = (initial.inverse() * found.pose).translation.vector.norm();
                    found.passes_edge_gates(&initial, d).then(|| {
                        let edge = Edge {
                            i: *i,
                            j,
                            measurement: found.pose,
                            information,
                            // Not the keypoint constraints' robust kernel: an edge passed
                            // the gates above, and the kernel would let many slightly wrong
                            // keypoint constraints outvote a precise edge.
                            robust: false,
                        };
                        (edge, moved, is_loop)
                    })
                })
                .collect()
        })
        .collect();
    let mut moved: Vec<f64> = per_model.iter().flatten().map(|(_, m, _)| *m).collect();
    moved.sort_by(f64::total_cmp);
    summary.median_correction = moved.get(moved.len() / 2).copied().unwrap_or(0.0);
    summary.loop_edges = per_model.iter().flatten().filter(|(_, _, l)| *l).count();
    let edges: Vec<Edge> = per_model.into_iter().flatten().map(|(e, _, _)| e).collect();
    summary.edges = edges.len();
    summary.seconds = started.elapsed().as_secs_f64();
    (edges, summary)
}

/// Two full-resolution depth images of one camera aligned as the keyframe alignments align
/// keyframes: the `[dense]` settings and edge gates of a [`SlamConfig`], every
/// `map.pixel_stride`-th pixel, without the map's depth-edge filter. For the diagnostics that
/// hold a sequence's frames against its ground truth (`lab/examples/refined_gt_check.rs`,
/// `lab/examples/epipolar_check.rs`).
pub struct PairAlignment {
    camera: Camera,
    rays: Arc<RayTable>,
    stride: u32,
    range: (f64, f64),
    dense: DenseConfig,
}

impl PairAlignment {
    /// An aligner for `camera` with the `[dense]` settings, depth range and pixel stride of `cfg`.
    pub fn new(camera: &Camera, cfg: &SlamConfig) -> Self {
        let stride = cfg.map.pixel_stride;
        Self {
            camera: camera.clone(),
            rays: Arc::new(RayTable::new(camera, stride)),
            stride,
            range: (cfg.tracking.min_depth, cfg.tracking.max_depth),
            dense: cfg.dense.clone(),
        }
    }

    /// `T_a_b` refined from `initial` by aligning `b` to `a`; `Ok(None)` when the alignment
    /// fails or its gates, an error when an image is not the camera's size.
    pub fn refine(&self, a: &DepthImage, b: &DepthImage, initial: &Pose) -> Result<Option<Pose>> {
        let (c, d) = (&self.camera, &self.dense);
        if let Some(bad) = [a, b]
            .into_iter()
            .find(|x| (x.width, x.height) != (c.width, c.height))
        {
            return Err(Error::msg(format!(
                "a depth image is {}x{} but the camera is {}x{}",
                bad.width, bad.height, c.width, c.height
            )));
        }
        let (a, b) = (a.subsample(self.stride), b.subsample(self.stride));
        Ok(
            DepthModel::new(&a, c, self.rays.clone(), d.model_step, self.range)
                .and_then(|model| align(&model, &b, initial, self.range, d))
                .filter(|found| found.passes_edge_gates(initial, d))
                .map(|found| found.pose),
        )
    }
}

#[cfg(test)]
pub(crate) mod tests;
