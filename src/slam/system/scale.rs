//! The scale anchors applied to a finished run ([`crate::slam::mapping::scale_anchor`]).
//!
//! Every run reports the camera height its map implies above the floor and, in monocular
//! mode, the map-level multi-view scale. A monocular run given the camera height
//! (`scale.camera_height`, `slam --camera-height`) is scaled so that the floor lies that far
//! below the cameras; a run where the floor is not seen says so and keeps SDFCNN's scale.
//! Sensor depth is metric: an RGB-D map is never rescaled, the height only compared.

use super::SlamOutput;
use crate::geometry::Pose;
use crate::slam::config::SlamConfig;
use crate::slam::mapping::scale_anchor::{FloorFit, MultiviewScale, fit_floor, fuse_ratios};
use nalgebra::Point3;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// What the scale anchors found, and what was done.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ScaleReport {
    /// The camera height given, metres.
    pub camera_height: Option<f64>,
    /// The floor plane and the camera height it implies (in the map's units before any
    /// rescaling).
    pub floor: Option<FloorFit>,
    /// Why the floor gave no height.
    pub floor_error: Option<String>,
    /// The factor the map was scaled by (monocular mode, camera height given, floor seen).
    pub applied: Option<f64>,
    /// Monocular mode: the keyframes' multi-view / predicted depth ratios, fused.
    pub multiview: Option<MultiviewScale>,
    /// Warnings for the user (a poorly determined scale, a floor not seen).
    pub warnings: Vec<String>,
}

/// A camera-height scale beyond this factor (or below its inverse) is applied with a warning.
const MAX_PLAUSIBLE_SCALE: f64 = 3.0;

/// Measures the anchors of a finished run and, in monocular mode with a camera height, scales
/// `out` by the floor's. `ratios` are the keyframes' multi-view / predicted depth ratios.
pub(crate) fn anchor_scale(out: &mut SlamOutput, cfg: &SlamConfig, ratios: &[f64]) -> ScaleReport {
    let monocular = out.depth == super::DepthMode::Predicted;
    let given = (cfg.scale.camera_height > 0.0).then_some(cfg.scale.camera_height);
    let mut report = ScaleReport {
        camera_height: given,
        multiview: if monocular { fuse_ratios(ratios) } else { None },
        ..ScaleReport::default()
    };
    if let Some(m) = &report.multiview
        && m.poorly_determined
    {
        report.warnings.push(format!(
            "the map-level scale is poorly determined: {} keyframes with multi-view depth, \
             their ratio to SDFCNN's depth {:.3} ± {:.1} % (10-90 %: {:.3}-{:.3})",
            m.keyframes,
            m.scale,
            100.0 * m.relative_error,
            m.p10,
            m.p90
        ));
    }
    let points = out.semantic_map.points(&cfg.labels, cfg.map.min_views);
    let cameras: Vec<Pose> = out.map.keyframes.iter().map(|k| k.pose).collect();
    match fit_floor(&points, &cameras) {
        Ok(fit) => {
            if fit.cameras_below * 10 > cameras.len() {
                report.warnings.push(format!(
                    "{} of {} keyframes are below the floor plane: the plane may not be the floor",
                    fit.cameras_below,
                    cameras.len()
                ));
            }
            if let (true, Some(h)) = (monocular, given) {
                let s = fit.scale_for(h);
                if !(1.0 / MAX_PLAUSIBLE_SCALE..=MAX_PLAUSIBLE_SCALE).contains(&s) {
                    report.warnings.push(format!(
                        "the camera height scales the map by {s:.3}: check the floor the report \
                         gives before trusting it"
                    ));
                }
                out.rescale(s);
                report.applied = Some(s);
            }
            report.floor = Some(fit);
        }
        Err(e) => {
            if given.is_some() && monocular {
                report.warnings.push(format!(
                    "{e}: the camera height cannot fix the scale, SDFCNN's is kept"
                ));
            }
            report.floor_error = Some(e.to_string());
        }
    }
    report
}

impl SlamOutput {
    /// Scales the whole run by `s` about the world origin: every pose's translation, the
    /// keyframes' depth and 3D keypoints, the landmarks and the semantic map (its voxels
    /// scale with it, so no point changes voxel).
    pub fn rescale(&mut self, s: f64) {
        let scaled = |p: &Pose| {
            let mut q = *p;
            q.translation.vector *= s;
            q
        };
        for f in &mut self.frames {
            f.relative = scaled(&f.relative);
            f.odom_pose = scaled(&f.odom_pose);
            if let Some((_, step)) = &mut f.step {
                *step = scaled(step);
            }
            for o in &mut f.observations {
                o.depth = o.depth.map(|d| d * s as f32);
            }
        }
        for k in &mut self.map.keyframes {
            k.pose = scaled(&k.pose);
            k.odom_pose = scaled(&k.odom_pose);
            k.depth_scale *= s;
            let track = Arc::make_mut(&mut k.track);
            for p in track.points_cam.iter_mut().flatten() {
                *p = Point3::from(p.coords * s);
            }
        }
        for c in &mut self.map.constraints {
            c.relative = scaled(&c.relative);
        }
        for p in &mut self.landmarks {
            *p = Point3::from(p.coords * s);
        }
        for p in self.live_poses.iter_mut().chain(&mut self.online_poses) {
            *p = scaled(p);
        }
        self.semantic_map.rescale(s);
    }
}
