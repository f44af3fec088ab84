//! Local mapping (section IV-C, ORB-SLAM's LocalMapping): each keyframe's semantics and
//! depth from the semantic source (SDFCNN, ground truth or none), multi-view depth in
//! monocular mode, insertion into the shared map and fusion into the voxel grid;
//! keyframes that correction moved are fused again, a few at a time.

use super::depth_edges::drop_depth_edges;
use super::multiview_depth::{GrayView, SweepReference, SweepSummary, merge_measured, sweep_depth};
use super::semantic_map::SemanticMap;
use super::semantic_source::{SemanticInput, SemanticSource};
use crate::camera::Camera;
use crate::dataset::{DepthImage, LabelImage};
use crate::geometry::Pose;
use crate::slam::config::SlamConfig;
use crate::slam::frontend::tracking::NewKeyframe;
use crate::slam::map::{
    KeyFrame, KeyframeFeatures, KeyframeView, KeypointDepth, Map, SharedMap, read, write,
};
use crate::slam::system::{Log, StageTime};
use image::RgbImage;
use nalgebra::Vector3;
use std::collections::VecDeque;
use std::sync::Arc;
use std::time::Instant;

/// A keyframe on its way to mapping, with its full-resolution images.
pub(crate) struct MapperInput {
    /// The keyframe from tracking.
    pub keyframe: NewKeyframe,
    /// Full-resolution colour image.
    pub rgb: RgbImage,
    /// Sensor depth (RGB-D).
    pub depth: Option<DepthImage>,
}

/// The mapping stage: semantics of each keyframe, insertion into the map,
/// fusion into the voxel grid. Keyframes that correction moved are re-fused a few
/// at a time (the most moved first: taken out at the pose they were fused with and
/// fused again at their new one), so the work per keyframe stays bounded; the final
/// map is re-fused from every final pose.
pub(crate) struct LocalMapper {
    cfg: SlamConfig,
    camera: Camera,
    monocular: bool,
    semantics: Box<dyn SemanticSource>,
    map: SharedMap,
    log: Log,
    /// The voxel grid the keyframes are fused into.
    pub semantic_map: SemanticMap,
    fused_epoch: u64,
    /// The pose and depth scale each keyframe was fused with.
    fused: Vec<(Pose, f64)>,
    /// Semantic-source failures: frame index and message (those keyframes got void labels).
    pub failures: Vec<(usize, String)>,
    /// Time spent predicting labels (and depth) with the semantic source.
    pub semantics_time: StageTime,
    /// Time spent on multi-view depth (monocular mode).
    pub multiview_time: StageTime,
    /// Multi-view depth counts summed over the keyframes.
    pub multiview: SweepSummary,
    /// Each measured keyframe's median multi-view / predicted depth ratio (monocular mode, with
    /// `multiview.keep_unconfirmed` and `rescale_cells`), fused over the run by
    /// [`super::scale_anchor::fuse_ratios`].
    pub scale_ratios: Vec<f64>,
    /// Full-resolution grey images of the last `multiview.look_back` keyframes (monocular
    /// mode) with their index in the map: the references of multi-view depth.
    recent: VecDeque<(usize, Arc<GrayView>)>,
    /// Time spent inserting keyframes into the map and fusing (and re-fusing) them.
    pub fusion_time: StageTime,
}

impl LocalMapper {
    /// A mapper with an empty voxel grid; `monocular`: depth comes from the semantic source.
    pub fn new(
        cfg: SlamConfig,
        camera: Camera,
        monocular: bool,
        semantics: Box<dyn SemanticSource>,
        map: SharedMap,
        log: Log,
    ) -> Self {
        let voxel = cfg.map.voxel_size;
        LocalMapper {
            cfg,
            camera,
            monocular,
            semantics,
            map,
            log,
            semantic_map: SemanticMap::new(voxel),
            fused_epoch: 0,
            fused: Vec::new(),
            failures: Vec::new(),
            semantics_time: StageTime::default(),
            multiview_time: StageTime::default(),
            multiview: SweepSummary::default(),
            scale_ratios: Vec::new(),
            recent: VecDeque::new(),
            fusion_time: StageTime::default(),
        }
    }

    /// Processes a keyframe; returns its features with 3D points from the
    /// depth used (predicted in monocular mode), for tracking.
    pub fn process(&mut self, input: MapperInput) -> Arc<KeyframeFeatures> {
        let kf = input.keyframe;
        let (w, h) = input.rgb.dimensions();
        let t = Instant::now();
        let sem = SemanticInput {
            index: kf.frame_index,
            stamp: kf.stamp,
            rgb: &input.rgb,
        };
        let (labels, predicted) = match self.semantics.predict(&sem) {
            Ok(r) => r,
            Err(e) => {
                let msg = e.to_string();
                (self.log)(&format!(
                    "warning: keyframe {} (frame {}): {} labels failed: {msg}; using void labels",
                    kf.id,
                    kf.frame_index,
                    self.semantics.name()
                ));
                self.failures.push((kf.frame_index, msg));
                (LabelImage::new(w, h, crate::dataset::labels::VOID), None)
            }
        };
        self.semantics_time.add(t);
        let depth = if self.monocular {
            predicted
        } else {
            input.depth
        };
        let mut depth = depth.unwrap_or_else(|| DepthImage::new(w, h));
        let unfiltered = (!self.monocular && !self.cfg.dense.edges_on_filtered_depth)
            .then(|| depth.subsample(self.cfg.map.pixel_stride));
        let track = if self.monocular {
            // The keypoints' 3D points come from the predicted depth.
            Arc::new(KeyframeFeatures::new(
                kf.track.features.clone(),
                Some(&depth),
                &self.camera,
                KeypointDepth::from_config(&self.cfg.tracking),
            ))
        } else {
            kf.track.clone()
        };
        drop_depth_edges(
            &mut depth,
            self.cfg.map.depth_edge_reach,
            self.cfg.map.depth_edge_ratio,
        );
        let mut view = KeyframeView::new(self.cfg.map.pixel_stride, &input.rgb, &depth, &labels);
        view.unfiltered_depth = unfiltered;
        let mut gray = None;
        if self.monocular && self.cfg.multiview.references > 0 {
            let t = Instant::now();
            let g = Arc::new(GrayView::from_rgb(&input.rgb));
            self.measure_depth(&kf.pose, &g, &mut view);
            gray = Some(g);
            self.multiview_time.add(t);
        }
        let t = Instant::now();
        {
            let mut m = write(&self.map);
            let pose = corrected_pose(&m, &kf.pose);
            if let Some(g) = gray {
                self.recent.push_back((m.keyframes.len(), g));
                if self.recent.len() > self.cfg.multiview.look_back {
                    self.recent.pop_front();
                }
            }
            m.keyframes.push(KeyFrame {
                id: kf.id,
                frame_index: kf.frame_index,
                stamp: kf.stamp,
                odom_pose: kf.pose,
                pose,
                gt_pose: kf.gt_pose,
                track: track.clone(),
                view,
                depth_scale: 1.0,
            });
        }
        {
            let m = read(&self.map);
            if let Some(k) = m.keyframes.last() {
                self.semantic_map
                    .fuse(k, &k.pose, k.depth_scale, &self.camera, &self.cfg.map);
                self.fused.push((k.pose, k.depth_scale));
            }
        }
        self.refuse_moved(self.cfg.map.refuse_per_keyframe);
        self.fusion_time.add(t);
        track
    }

    /// Measures the depth of a monocular keyframe's view against earlier keyframes
    /// ([`super::multiview_depth`]); measured pixels replace the prediction in the view. The
    /// keypoints keep SDFCNN's depth, which re-anchors the scale at every keyframe (on the
    /// box room of `tests/slam_system.rs`, whose predicted depth is exact, measured
    /// keypoints tripled the ATE; on 7-Scenes 600-699 the map was as accurate either way).
    fn measure_depth(&mut self, odom_pose: &Pose, gray: &GrayView, view: &mut KeyframeView) {
        let mv = &self.cfg.multiview;
        let (pose, refs) = {
            let m = read(&self.map);
            let pose = corrected_pose(&m, odom_pose);
            let axis = pose.rotation * Vector3::z();
            let mut near: Vec<(f64, Arc<GrayView>, Pose)> = self
                .recent
                .iter()
                .filter_map(|(i, g)| {
                    let k = m.keyframes.get(*i)?;
                    let baseline = (k.pose.translation.vector - pose.translation.vector).norm();
                    let angle = (k.pose.rotation * Vector3::z()).angle(&axis).to_degrees();
                    (baseline >= mv.min_baseline && angle <= mv.max_angle_deg)
                        .then(|| (baseline, g.clone(), k.pose))
                })
                .collect();
            // The widest baselines first: depth from parallax is more precise.
            near.sort_by(|a, b| b.0.total_cmp(&a.0));
            near.truncate(mv.references);
            (pose, near)
        };
        if refs.is_empty() {
            return;
        }
        let references: Vec<SweepReference> = refs
            .iter()
            .map(|(_, image, pose)| SweepReference { image, pose: *pose })
            .collect();
        let stride = view.stride;
        let (measured, summary) = sweep_depth(
            gray,
            &pose,
            &view.depth,
            &references,
            &self.camera,
            stride,
            mv,
        );
        self.multiview.candidates += summary.candidates;
        self.multiview.confirmed += summary.confirmed;
        // The keyframe's median measured / predicted ratio, for the map-level scale.
        if let Some(r) = merge_measured(
            &mut view.depth,
            &measured,
            mv.keep_unconfirmed,
            mv.rescale_cells,
        ) {
            self.scale_ratios.push(r as f64);
        }
    }

    /// How far a keyframe's fused view lies from where it is now, metres: the
    /// translation plus the rotation's arc at `max_depth`, and the depth-scale change
    /// at `max_depth`.
    fn displacement(&self, k: &KeyFrame, (pose, scale): &(Pose, f64)) -> f64 {
        let reach = self.cfg.map.max_depth;
        let d = pose.inverse() * k.pose;
        d.translation.vector.norm()
            + d.rotation.angle() * reach
            + (k.depth_scale - scale).abs() * reach
    }

    /// Re-fuses the (at most `limit`) keyframes that correction moved most, by more than a
    /// voxel, since they were fused.
    fn refuse_moved(&mut self, limit: usize) {
        let m = read(&self.map);
        if m.epoch == self.fused_epoch || limit == 0 {
            return;
        }
        let mut moved: Vec<(f64, usize)> = m
            .keyframes
            .iter()
            .zip(&self.fused)
            .enumerate()
            .map(|(i, (k, f))| (self.displacement(k, f), i))
            .filter(|(d, _)| *d > self.cfg.map.voxel_size)
            .collect();
        if moved.len() <= limit {
            // Everything moved is re-fused now: up to date with this correction.
            self.fused_epoch = m.epoch;
        }
        moved.sort_by(|a, b| b.0.total_cmp(&a.0));
        for &(_, i) in moved.iter().take(limit) {
            let (k, (pose, scale)) = (&m.keyframes[i], self.fused[i]);
            let cfg = &self.cfg.map;
            self.semantic_map.unfuse(k, &pose, scale, &self.camera, cfg);
            self.semantic_map
                .fuse(k, &k.pose, k.depth_scale, &self.camera, cfg);
            self.fused[i] = (k.pose, k.depth_scale);
        }
    }

    /// Rebuilds the voxel map from every keyframe's current pose and depth scale.
    pub fn refuse_all(&mut self) {
        let m = read(&self.map);
        self.semantic_map.clear();
        self.fused.clear();
        for k in &m.keyframes {
            self.semantic_map
                .fuse(k, &k.pose, k.depth_scale, &self.camera, &self.cfg.map);
            self.fused.push((k.pose, k.depth_scale));
        }
        self.fused_epoch = m.epoch;
    }
}

/// A keyframe's tracked pose made to follow the corrections made so far (those of the
/// last keyframe in the map).
fn corrected_pose(m: &Map, odom_pose: &Pose) -> Pose {
    m.keyframes
        .last()
        .map_or(*odom_pose, |last| last.carry(odom_pose))
}
