//! Range checks of every SLAM setting, before anything is allocated or run; the message
//! names the field as the TOML file spells it.

use super::*;

impl SlamConfig {
    /// Checks ranges; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        self.validate_counts()?;
        self.validate_tracking()?;
        self.validate_map()?;
        self.validate_multiview()?;
        self.validate_dense()?;
        self.validate_correction()?;
        self.validate_bundle_adjustment()?;
        let h = self.scale.camera_height;
        if h != 0.0 {
            crate::slam::mapping::scale_anchor::check_camera_height(h)
                .map_err(|e| format!("scale.camera_height: {e} (0: not known)"))?;
        }
        Ok(())
    }

    /// Counts that size allocations or loops, bounded before anything runs.
    fn validate_counts(&self) -> std::result::Result<(), String> {
        count(self.features.top_k, 1, MAX_KEYPOINTS, "features.top_k")?;
        count(self.features.orb_levels, 1, 16, "features.orb_levels")?;
        if !(self.features.orb_scale_factor > 1.0 && self.features.orb_scale_factor <= 4.0) {
            return Err(format!(
                "features.orb_scale_factor must be in (1, 4] (each pyramid level this much \
                 smaller), got {}",
                self.features.orb_scale_factor
            ));
        }
        count(
            self.features.fpfdcnn_nms_radius,
            0,
            64,
            "features.fpfdcnn_nms_radius",
        )?;
        count(
            self.features.fpfdcnn_border,
            0,
            256,
            "features.fpfdcnn_border",
        )?;
        count(self.pnp.max_iterations, 1, 1_000_000, "pnp.max_iterations")?;
        // Work per keyframe or per frame that no real run needs this much of.
        count(
            self.map.refuse_per_keyframe,
            0,
            1000,
            "map.refuse_per_keyframe",
        )?;
        count(self.map.min_views as usize, 0, 1000, "map.min_views")?;
        count(self.labels.min_votes as usize, 0, 1000, "labels.min_votes")?;
        count(
            self.pnp.min_inliers,
            0,
            self.features.top_k,
            "pnp.min_inliers (at most features.top_k)",
        )?;
        for (v, name) in [
            (self.matcher.window, "matcher.window"),
            (self.matcher.wide_window, "matcher.wide_window"),
        ] {
            if v > MAX_WINDOW_PX {
                return Err(format!(
                    "{name} must be at most {MAX_WINDOW_PX} px (the search radius), got {v}"
                ));
            }
        }
        count(
            self.pnp.refine_iterations,
            0,
            10_000,
            "pnp.refine_iterations",
        )?;
        count(
            self.tracking.relocalisation_candidates,
            0,
            1000,
            "tracking.relocalisation_candidates",
        )?;
        count(
            self.keyframes.max_frames,
            1,
            1_000_000,
            "keyframes.max_frames",
        )?;
        count(
            self.keyframes.max_frames_depth_tracked,
            1,
            1_000_000,
            "keyframes.max_frames_depth_tracked",
        )?;
        count(
            self.keyframes.max_frames_flow_tracked,
            1,
            1_000_000,
            "keyframes.max_frames_flow_tracked",
        )?;
        for (v, name) in [
            (self.correction.random_pairs, "correction.random_pairs"),
            (
                self.correction.proximity_pairs,
                "correction.proximity_pairs",
            ),
            (
                self.correction.similarity_pairs,
                "correction.similarity_pairs",
            ),
        ] {
            count(v, 0, 1000, name)?;
        }
        count(
            self.correction.lm_iterations,
            0,
            10_000,
            "correction.lm_iterations",
        )?;
        count(
            self.correction.optimise_every,
            1,
            1_000_000,
            "correction.optimise_every",
        )?;
        count(self.system.queue, 1, 1024, "system.queue")?;
        count(self.system.feature_workers, 0, 16, "system.feature_workers")?;
        count(
            self.system.max_eval_points,
            1,
            100_000_000,
            "system.max_eval_points",
        )?;
        if !(-1.0..=1.0).contains(&self.correction.min_similarity) {
            return Err(format!(
                "correction.min_similarity must be a cosine in [-1, 1], got {}",
                self.correction.min_similarity
            ));
        }
        Ok(())
    }

    /// Keypoints, matcher, PnP and tracking depth range.
    fn validate_tracking(&self) -> std::result::Result<(), String> {
        // The FPFDCNN fields, named as in this file.
        self.features
            .detector()
            .validate()
            .map_err(|m| format!("features.fpfdcnn_{m}"))?;
        pos(self.matcher.window as f64, "matcher.window")?;
        pos(self.matcher.wide_window as f64, "matcher.wide_window")?;
        for (r, name) in [
            (self.matcher.ratio, "matcher.ratio"),
            (self.matcher.wide_ratio, "matcher.wide_ratio"),
        ] {
            if !(0.0..=1.0).contains(&r) {
                return Err(format!("{name} must be in [0, 1] (0: off), got {r}"));
            }
        }
        if !(0.0..=256.0).contains(&self.matcher.ratio_exclusion_px) {
            return Err(format!(
                "matcher.ratio_exclusion_px must be in [0, 256] pixels, got {}",
                self.matcher.ratio_exclusion_px
            ));
        }
        pos(self.pnp.threshold_px, "pnp.threshold_px")?;
        if !(self.pnp.confidence > 0.0 && self.pnp.confidence < 1.0) {
            return Err(format!(
                "pnp.confidence must be in (0, 1), got {}",
                self.pnp.confidence
            ));
        }
        if self.pnp.min_inliers < 4 {
            return Err("pnp.min_inliers must be at least 4".into());
        }
        pos(self.tracking.max_depth, "tracking.max_depth")?;
        if !(self.tracking.min_depth >= 0.0 && self.tracking.min_depth < self.tracking.max_depth) {
            return Err("tracking.min_depth must be in [0, tracking.max_depth)".into());
        }
        if self.tracking.monocular_flow && self.tracking.keypoints_every_frame {
            return Err(
                "tracking.monocular_flow = true follows keypoints between keyframes, which \
                 tracking.keypoints_every_frame = true detects on every frame: set one of them"
                    .into(),
            );
        }
        Ok(())
    }

    /// Dense refinement: bounded steps, levels and iterations, positive distances.
    fn validate_dense(&self) -> std::result::Result<(), String> {
        let d = &self.dense;
        count(d.model_step, 1, 64, "dense.model_step")?;
        count(d.levels.len(), 1, 8, "dense.levels (count)")?;
        for (i, level) in d.levels.iter().enumerate() {
            count(level.step, 1, 64, &format!("dense.levels[{i}].step"))?;
            pos(
                level.max_distance,
                &format!("dense.levels[{i}].max_distance"),
            )?;
        }
        count(d.iterations, 1, 100, "dense.iterations")?;
        pos(d.huber, "dense.huber")?;
        count(d.min_pairs, 6, 10_000_000, "dense.min_pairs")?;
        fraction(d.min_inlier_fraction, "dense.min_inlier_fraction")?;
        pos(d.agree_translation, "dense.agree_translation")?;
        pos(d.agree_rotation_deg, "dense.agree_rotation_deg")?;
        count(d.keyframe_edges, 0, 16, "dense.keyframe_edges")?;
        fraction(d.edge_min_inlier_fraction, "dense.edge_min_inlier_fraction")?;
        pos(d.edge_agree_translation, "dense.edge_agree_translation")?;
        pos(d.edge_agree_rotation_deg, "dense.edge_agree_rotation_deg")?;
        pos(d.sigma_translation, "dense.sigma_translation")?;
        pos(d.sigma_rotation_deg, "dense.sigma_rotation_deg")?;
        pos(d.prior_sigma_translation, "dense.prior_sigma_translation")?;
        pos(d.prior_sigma_rotation_deg, "dense.prior_sigma_rotation_deg")?;
        let w = d.frame_graph_reference_weight;
        if !(w > 0.0 && w <= 1000.0) {
            return Err(format!(
                "dense.frame_graph_reference_weight must be in (0, 1000], got {w}"
            ));
        }
        Ok(())
    }

    /// Keyframe selection and the semantic map.
    fn validate_map(&self) -> std::result::Result<(), String> {
        pos(self.keyframes.max_translation, "keyframes.max_translation")?;
        pos(
            self.keyframes.max_rotation_deg,
            "keyframes.max_rotation_deg",
        )?;
        // Voxel keys are i32 cells: below a millimetre far points would saturate into one.
        if !(0.001..=10.0).contains(&self.map.voxel_size) {
            return Err(format!(
                "map.voxel_size must be in [0.001, 10] metres, got {}",
                self.map.voxel_size
            ));
        }
        pos(self.map.max_depth, "map.max_depth")?;
        if !(self.map.min_depth >= 0.0 && self.map.min_depth < self.map.max_depth) {
            return Err("map.min_depth must be in [0, map.max_depth)".into());
        }
        if self.map.pixel_stride == 0 || self.map.pixel_stride > 64 {
            return Err("map.pixel_stride must be in 1..=64".into());
        }
        if !(0.0..=10.0).contains(&self.map.depth_edge_ratio) || self.map.depth_edge_reach > 64 {
            return Err(format!(
                "map.depth_edge_ratio must be in [0, 10] (0: off) and map.depth_edge_reach in \
                 0..=64 pixels, got {} and {}",
                self.map.depth_edge_ratio, self.map.depth_edge_reach
            ));
        }
        if self.map.min_views == 0 {
            return Err("map.min_views must be at least 1 (1: every voxel)".into());
        }
        if !(100..=MAX_TOPDOWN).contains(&self.map.topdown_size) {
            return Err(format!(
                "map.topdown_size must be 100..={MAX_TOPDOWN} pixels (the picture is allocated \
                 before it is drawn)"
            ));
        }
        Ok(())
    }

    /// Multi-view depth (monocular mode).
    fn validate_multiview(&self) -> std::result::Result<(), String> {
        let mv = &self.multiview;
        count(mv.references, 0, 16, "multiview.references")?;
        count(mv.look_back, 1, 64, "multiview.look_back")?;
        count(mv.steps, 5, 256, "multiview.steps")?;
        count(mv.patch_radius, 1, 8, "multiview.patch_radius")?;
        count(mv.patch_step, 1, 8, "multiview.patch_step")?;
        count(mv.rescale_cells, 0, 256, "multiview.rescale_cells")?;
        pos(mv.min_baseline, "multiview.min_baseline")?;
        pos(mv.max_angle_deg, "multiview.max_angle_deg")?;
        if !(mv.range > 0.0 && mv.range <= 2.0) {
            return Err(format!(
                "multiview.range must be in (0, 2] (log depth), got {}",
                mv.range
            ));
        }
        for (v, name) in [
            (mv.min_ncc, "multiview.min_ncc"),
            (mv.uniqueness, "multiview.uniqueness"),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("{name} must be in [0, 1], got {v}"));
            }
        }
        if !(mv.min_texture >= 0.0 && mv.min_texture <= 255.0) {
            return Err(format!(
                "multiview.min_texture must be in [0, 255] grey levels, got {}",
                mv.min_texture
            ));
        }
        if !(mv.min_parallax_px >= 0.0 && mv.min_parallax_px <= 1000.0) {
            return Err(format!(
                "multiview.min_parallax_px must be in [0, 1000], got {}",
                mv.min_parallax_px
            ));
        }
        Ok(())
    }

    /// Labels, data correction and evaluation.
    fn validate_correction(&self) -> std::result::Result<(), String> {
        fraction(self.labels.min_share, "labels.min_share")?;
        pos(
            self.correction.proximity_radius,
            "correction.proximity_radius",
        )?;
        pos(
            self.correction.proximity_angle_deg,
            "correction.proximity_angle_deg",
        )?;
        pos(
            self.correction.sigma_translation,
            "correction.sigma_translation",
        )?;
        pos(
            self.correction.sigma_rotation_deg,
            "correction.sigma_rotation_deg",
        )?;
        pos(self.correction.robust_delta, "correction.robust_delta")?;
        if self.correction.min_inliers < 4 {
            return Err("correction.min_inliers must be at least 4".into());
        }
        fraction(
            self.correction.min_inlier_ratio,
            "correction.min_inlier_ratio",
        )?;
        if !(0.0..1.0).contains(&self.correction.local_max_scale_change) {
            return Err("correction.local_max_scale_change must be in [0, 1)".into());
        }
        if self.correction.min_id_gap == 0 {
            return Err("correction.min_id_gap must be at least 1".into());
        }
        pos(self.system.position_tolerance, "system.position_tolerance")?;
        Ok(())
    }
}

impl SlamConfig {
    /// Bundle adjustment: bounded iterations and keyframes (the reduced system is dense,
    /// 6 rows per free keyframe: 300 is a 1800x1800 Cholesky per iteration), positive
    /// scales, non-negative depth weights.
    fn validate_bundle_adjustment(&self) -> std::result::Result<(), String> {
        let b = &self.bundle_adjustment;
        count(b.iterations, 1, 200, "bundle_adjustment.iterations")?;
        count(b.max_keyframes, 1, 300, "bundle_adjustment.max_keyframes")?;
        count(
            b.local_keyframes,
            0,
            300,
            "bundle_adjustment.local_keyframes",
        )?;
        count(
            b.local_iterations,
            1,
            200,
            "bundle_adjustment.local_iterations",
        )?;
        pos(b.sigma_px, "bundle_adjustment.sigma_px")?;
        pos(b.huber, "bundle_adjustment.huber")?;
        pos(b.outlier_chi2, "bundle_adjustment.outlier_chi2")?;
        for (v, name) in [
            (b.depth_bf, "bundle_adjustment.depth_bf"),
            (b.predicted_depth_bf, "bundle_adjustment.predicted_depth_bf"),
            (b.edge_weight, "bundle_adjustment.edge_weight"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!(
                    "{name} must be a non-negative number (0: off), got {v}"
                ));
            }
        }
        Ok(())
    }
}

/// A share, in [0, 1] (NaN is not).
fn fraction(v: f64, name: &str) -> std::result::Result<(), String> {
    if (0.0..=1.0).contains(&v) {
        Ok(())
    } else {
        Err(format!("{name} must be in [0, 1], got {v}"))
    }
}

/// A positive, finite setting.
fn pos(v: f64, name: &str) -> std::result::Result<(), String> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(format!("{name} must be a positive number, got {v}"))
    }
}

/// The largest matcher search radius, pixels (far beyond any image side it searches).
const MAX_WINDOW_PX: f32 = 4096.0;

/// A count that sizes allocations or loops, bounded before anything runs.
fn count(v: usize, lo: usize, hi: usize, name: &str) -> std::result::Result<(), String> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(format!("{name} must be in {lo}..={hi}, got {v}"))
    }
}
