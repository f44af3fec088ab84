//! The three-dimensional semantic map (section IV-C steps 2-3): each keyframe's
//! pixels with depth are back-projected (eq 9 inverted) to camera points, moved
//! to the world by the keyframe's pose, and fused as `(X, Y, Z, R, G, B, label)`
//! in a voxel grid (hash map of voxel indices): positions and colours are
//! averaged, labels voted. Written to file by [`crate::slam::output::ply`], drawn by
//! [`crate::slam::output::topdown`].

use crate::camera::{Camera, RayTable};
use crate::classes;
use crate::geometry::Pose;
use crate::slam::config::{LabelVoteConfig, MapConfig};
use crate::slam::map::KeyFrame;
use nalgebra::Point3;
use rustc_hash::FxHashMap;

/// The accumulated observations of one voxel.
#[derive(Debug, Clone)]
pub struct Voxel {
    /// Sum of the observed world positions, metres.
    pub sum: [f64; 3],
    /// Sum of the observed colours.
    pub rgb: [u32; 3],
    /// Number of observations (void ones included).
    pub count: u32,
    /// Votes per class (0-39).
    pub votes: [u16; classes::NUM_CLASSES],
    /// Void observations.
    pub void: u16,
    /// Keyframes with at least one observation in the voxel.
    pub views: u16,
    /// The last fusion (or de-fusion) of a keyframe that counted it in `views`.
    stamp: u32,
}

impl Default for Voxel {
    fn default() -> Self {
        Voxel {
            sum: [0.0; 3],
            rgb: [0; 3],
            count: 0,
            votes: [0; classes::NUM_CLASSES],
            void: 0,
            views: 0,
            stamp: 0,
        }
    }
}

impl Voxel {
    /// The voted label: the most voted class (lowest index on ties) if it has
    /// `min_votes` votes and `min_share` of the votes, else void.
    pub fn label(&self, rules: &LabelVoteConfig) -> u8 {
        let (best, &n) = self
            .votes
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(&a.0)))
            .unwrap_or((0, &0));
        let total: u32 = self.votes.iter().map(|&v| v as u32).sum::<u32>()
            + if rules.void_votes {
                self.void as u32
            } else {
                0
            };
        if n == 0 || (n as u32) < rules.min_votes || (n as f64) < rules.min_share * total as f64 {
            classes::VOID
        } else {
            best as u8
        }
    }
}

/// A fused map point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPoint {
    /// Mean observed world position, metres.
    pub position: Point3<f32>,
    /// Mean observed colour.
    pub rgb: [u8; 3],
    /// Voted class (255 = void).
    pub label: u8,
}

/// The voxel grid.
#[derive(Debug, Clone)]
pub struct SemanticMap {
    /// Voxel side, metres.
    pub voxel_size: f64,
    /// Occupied voxels by integer index (`floor(position / voxel_size)`).
    pub voxels: FxHashMap<[i32; 3], Voxel>,
    rays: Option<RayTable>,
    /// Fusions and de-fusions so far: each voxel's `stamp` says which last counted it.
    epoch: u32,
}

impl SemanticMap {
    /// An empty grid of voxels `voxel_size` metres on a side.
    pub fn new(voxel_size: f64) -> Self {
        SemanticMap {
            voxel_size,
            voxels: FxHashMap::default(),
            rays: None,
            epoch: 0,
        }
    }

    /// Number of occupied voxels (map points).
    pub fn len(&self) -> usize {
        self.voxels.len()
    }

    /// Whether no voxel is occupied.
    pub fn is_empty(&self) -> bool {
        self.voxels.is_empty()
    }

    /// Removes every voxel.
    pub fn clear(&mut self) {
        self.voxels.clear();
    }

    /// Scales the map by `s` about the origin: the voxel size with it, so every point keeps
    /// its voxel and its votes.
    pub fn rescale(&mut self, s: f64) {
        self.voxel_size *= s;
        for v in self.voxels.values_mut() {
            v.sum = v.sum.map(|c| c * s);
        }
        self.rays = None;
    }

    /// Voxel index of a world point.
    pub fn key(&self, p: &Point3<f64>) -> [i32; 3] {
        let f = |v: f64| (v / self.voxel_size).floor() as i32;
        [f(p.x), f(p.y), f(p.z)]
    }

    /// Adds one observation.
    pub fn insert(&mut self, p: &Point3<f64>, rgb: [u8; 3], label: u8) {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return;
        }
        self.insert_at(self.key(p), p, rgb, label);
    }

    /// [`Self::insert`] into the voxel `key`; returns it.
    fn insert_at(&mut self, key: [i32; 3], p: &Point3<f64>, rgb: [u8; 3], label: u8) -> &mut Voxel {
        let v = self.voxels.entry(key).or_default();
        for a in 0..3 {
            v.sum[a] += p[a];
            v.rgb[a] += rgb[a] as u32;
        }
        v.count += 1;
        match label as usize {
            l if l < classes::NUM_CLASSES => v.votes[l] = v.votes[l].saturating_add(1),
            _ => v.void = v.void.saturating_add(1),
        }
        v
    }

    /// Takes back one observation made by [`Self::insert`] with the same arguments; a voxel
    /// left without observations is removed.
    pub fn remove(&mut self, p: &Point3<f64>, rgb: [u8; 3], label: u8) {
        if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
            return;
        }
        self.remove_at(self.key(p), p, rgb, label);
    }

    /// [`Self::remove`] from the voxel `key`; returns it unless it is gone (or was not there).
    fn remove_at(
        &mut self,
        key: [i32; 3],
        p: &Point3<f64>,
        rgb: [u8; 3],
        label: u8,
    ) -> Option<&mut Voxel> {
        use std::collections::hash_map::Entry;
        let v = match self.voxels.entry(key) {
            Entry::Vacant(_) => return None,
            Entry::Occupied(o) if o.get().count <= 1 => {
                o.remove();
                return None;
            }
            Entry::Occupied(o) => o.into_mut(),
        };
        for a in 0..3 {
            v.sum[a] -= p[a];
            v.rgb[a] = v.rgb[a].saturating_sub(rgb[a] as u32);
        }
        v.count -= 1;
        match label as usize {
            l if l < classes::NUM_CLASSES => v.votes[l] = v.votes[l].saturating_sub(1),
            _ => v.void = v.void.saturating_sub(1),
        }
        Some(v)
    }

    /// Fuses a keyframe's view at `pose`, its depth multiplied by `depth_scale`.
    pub fn fuse(
        &mut self,
        kf: &KeyFrame,
        pose: &Pose,
        depth_scale: f64,
        camera: &Camera,
        cfg: &MapConfig,
    ) {
        self.integrate(kf, pose, depth_scale, camera, cfg, true);
    }

    /// Takes back what [`Self::fuse`] added with the same pose and depth scale (voxel
    /// de-integration, as BundleFusion re-integrates frames whose poses changed).
    pub fn unfuse(
        &mut self,
        kf: &KeyFrame,
        pose: &Pose,
        depth_scale: f64,
        camera: &Camera,
        cfg: &MapConfig,
    ) {
        self.integrate(kf, pose, depth_scale, camera, cfg, false);
    }

    /// Adds (`adding`) or takes back every fused pixel of the keyframe; each voxel it touches
    /// gains or loses the keyframe's view once (a voxel whose stamp is not this integration's
    /// epoch is touched for the first time; a voxel the keyframe empties is gone).
    fn integrate(
        &mut self,
        kf: &KeyFrame,
        pose: &Pose,
        depth_scale: f64,
        camera: &Camera,
        cfg: &MapConfig,
        adding: bool,
    ) {
        self.epoch = self.epoch.wrapping_add(1).max(1);
        let epoch = self.epoch;
        let view = &kf.view;
        let stale = self.rays.as_ref().is_none_or(|r| {
            r.stride != view.stride || (r.width, r.height) != (view.depth.width, view.depth.height)
        });
        if stale {
            self.rays = Some(RayTable::new(camera, view.stride));
        }
        let Some(rays) = self.rays.take() else {
            return;
        };
        if (rays.width, rays.height) == (view.depth.width, view.depth.height) {
            for (i, ray) in rays.rays.iter().enumerate() {
                let d = view.depth.data[i] as f64 * depth_scale;
                if !(d >= cfg.min_depth && d <= cfg.max_depth) || d <= 0.0 {
                    continue;
                }
                let p = pose * Point3::new(ray[0] * d, ray[1] * d, d);
                if !(p.x.is_finite() && p.y.is_finite() && p.z.is_finite()) {
                    continue;
                }
                let (x, y) = (i as u32 % rays.width, i as u32 / rays.width);
                let c = view.rgb.get_pixel(x, y).0;
                let (key, label) = (self.key(&p), view.labels.data[i]);
                let voxel = if adding {
                    Some(self.insert_at(key, &p, c, label))
                } else {
                    self.remove_at(key, &p, c, label)
                };
                if let Some(v) = voxel
                    && v.stamp != epoch
                {
                    v.stamp = epoch;
                    v.views = if adding {
                        v.views.saturating_add(1)
                    } else {
                        v.views.saturating_sub(1)
                    };
                }
            }
        }
        self.rays = Some(rays);
    }

    /// Map points (voxel means) of the voxels seen by at least `min_views` keyframes
    /// (a multi-view consistency check: predicted depth that disagrees across keyframes
    /// scatters over voxels only one keyframe sees), ordered by voxel index so output is
    /// deterministic. Voxels filled by [`Self::insert`] alone count as seen once.
    pub fn points(&self, rules: &LabelVoteConfig, min_views: u16) -> Vec<MapPoint> {
        let mut keys: Vec<&[i32; 3]> = self
            .voxels
            .iter()
            .filter(|(_, v)| v.views.max(1) >= min_views)
            .map(|(k, _)| k)
            .collect();
        keys.sort_unstable();
        keys.into_iter()
            .map(|k| {
                let v = &self.voxels[k];
                let n = v.count.max(1) as f64;
                MapPoint {
                    position: Point3::new(
                        (v.sum[0] / n) as f32,
                        (v.sum[1] / n) as f32,
                        (v.sum[2] / n) as f32,
                    ),
                    rgb: [0, 1, 2].map(|a| (v.rgb[a] as f64 / n).round().min(255.0) as u8),
                    label: v.label(rules),
                }
            })
            .collect()
    }
}

/// Points per label (index 40 counts void).
pub fn label_histogram(points: &[MapPoint]) -> [usize; classes::NUM_CLASSES + 1] {
    let mut h = [0usize; classes::NUM_CLASSES + 1];
    for p in points {
        h[(p.label as usize).min(classes::NUM_CLASSES)] += 1;
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn voxel_label_voting_and_colour_averaging() {
        let mut m = SemanticMap::new(0.1);
        let p = Point3::new(0.01, 0.02, 0.03);
        m.insert(&p, [10, 20, 30], 1);
        m.insert(&Point3::new(0.05, 0.05, 0.05), [30, 40, 50], 1);
        m.insert(&Point3::new(0.09, 0.01, 0.02), [20, 30, 40], 4);
        m.insert(&Point3::new(0.02, 0.02, 0.02), [20, 30, 40], classes::VOID);
        m.insert(&Point3::new(0.02, 0.02, 0.02), [20, 30, 40], classes::VOID);
        m.insert(&Point3::new(0.5, 0.5, 0.5), [0, 0, 0], 7);
        assert_eq!(m.len(), 2);
        let rules = LabelVoteConfig::default();
        let pts = m.points(&rules, 1);
        assert_eq!(pts[0].label, 1, "majority of class votes, void ignored");
        assert_eq!(pts[0].rgb, [20, 30, 40]);
        assert!((pts[0].position.x - 0.038).abs() < 1e-6);
        assert_eq!(pts[1].label, 7);
        // Void votes counted: 2 of 5 for class 1 is below a 50 % share.
        let strict = LabelVoteConfig {
            void_votes: true,
            min_share: 0.5,
            ..rules.clone()
        };
        assert_eq!(m.points(&strict, 1)[0].label, classes::VOID);
        let min2 = LabelVoteConfig {
            min_votes: 2,
            ..rules
        };
        assert_eq!(m.points(&min2, 1)[1].label, classes::VOID);
        // Ties go to the lower class.
        let mut t = SemanticMap::new(1.0);
        t.insert(&p, [0; 3], 5);
        t.insert(&p, [0; 3], 3);
        assert_eq!(t.points(&LabelVoteConfig::default(), 1)[0].label, 3);
        let h = label_histogram(&pts);
        assert_eq!((h[1], h[7], h[40]), (1, 1, 0));
    }

    #[test]
    fn removing_observations_gives_the_map_without_them() {
        let obs: Vec<(Point3<f64>, [u8; 3], u8)> = (0..200)
            .map(|i| {
                let t = i as f64 * 0.013;
                (
                    Point3::new(t.sin(), (2.0 * t).cos(), 0.3 * t),
                    [(i % 256) as u8, (3 * i % 256) as u8, 7],
                    if i % 9 == 0 {
                        classes::VOID
                    } else {
                        (i % 5) as u8
                    },
                )
            })
            .collect();
        let mut all = SemanticMap::new(0.05);
        let mut kept = SemanticMap::new(0.05);
        for (k, (p, c, l)) in obs.iter().enumerate() {
            all.insert(p, *c, *l);
            if k % 3 != 0 {
                kept.insert(p, *c, *l);
            }
        }
        for (p, c, l) in obs.iter().step_by(3) {
            all.remove(p, *c, *l);
        }
        let rules = LabelVoteConfig::default();
        let (a, b) = (all.points(&rules, 1), kept.points(&rules, 1));
        assert_eq!(a.len(), b.len(), "emptied voxels are removed");
        for (x, y) in a.iter().zip(&b) {
            assert_eq!((x.rgb, x.label), (y.rgb, y.label));
            assert!((x.position - y.position).norm() < 1e-5);
        }
        // Taking back an observation that was never made changes nothing.
        all.remove(&Point3::new(50.0, 50.0, 50.0), [1, 2, 3], 4);
        assert_eq!(all.len(), b.len());
    }

    /// A keyframe looking down +z at a wall `depth` metres away.
    fn wall_keyframe(id: usize, depth: f32) -> KeyFrame {
        use crate::dataset::{DepthImage, LabelImage};
        use crate::slam::map::{KeyframeFeatures, KeyframeView};
        let (w, h) = (32, 24);
        let mut d = DepthImage::new(w, h);
        d.data.iter_mut().for_each(|v| *v = depth);
        let view = KeyframeView::new(
            1,
            &image::RgbImage::new(w, h),
            &d,
            &LabelImage::new(w, h, 3),
        );
        KeyFrame {
            id,
            frame_index: id,
            stamp: id as f64,
            odom_pose: Pose::identity(),
            pose: Pose::identity(),
            gt_pose: None,
            track: std::sync::Arc::new(KeyframeFeatures::default()),
            view,
            depth_scale: 1.0,
        }
    }

    #[test]
    fn map_points_need_min_views_keyframes_and_unfuse_takes_a_view_back() {
        let camera = Camera::pinhole(32, 24, 30.0, 30.0, 15.5, 11.5);
        let cfg = MapConfig::default();
        let rules = LabelVoteConfig::default();
        let (near, far) = (wall_keyframe(0, 1.0), wall_keyframe(1, 1.5));
        let mut m = SemanticMap::new(0.02);
        for k in [&near, &near, &far] {
            m.fuse(k, &k.pose, 1.0, &camera, &cfg);
        }
        let all = m.points(&rules, 1).len();
        let agreed = m.points(&rules, 2);
        assert!(!agreed.is_empty() && agreed.len() < all);
        assert!(
            agreed.iter().all(|p| (p.position.z - 1.0).abs() < 0.02),
            "only the wall both views saw"
        );
        assert!(m.points(&rules, 3).is_empty());
        m.unfuse(&near, &near.pose, 1.0, &camera, &cfg);
        assert!(m.points(&rules, 2).is_empty());
        assert_eq!(m.points(&rules, 1).len(), all);
        assert!(m.voxels.values().all(|v| v.views == 1));
    }
}
