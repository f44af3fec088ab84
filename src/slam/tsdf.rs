//! A truncated signed distance volume (Curless and Levoy 1996; KinectFusion's model, Newcombe
//! et al. 2011) kept in blocks of 8x8x8 voxels allocated only where depth is seen (voxel
//! hashing, Nießner et al. 2013), and its view from a pose by ray casting. In RGB-D mode,
//! tracking can refine each frame against the surface fused from every frame before it
//! (`dense.fused_model`) instead of its reference keyframe's single depth image.
//!
//! Distances are projective (the measured depth minus the voxel's depth along the optical
//! axis, as Open3D's integration), stored in units of the truncation distance, clamped to 1
//! in front of the surface; voxels farther than the truncation behind it are left alone.
//! Each voxel keeps a running mean with its weight capped, so the model follows a scene
//! that changes slowly.

use super::map::ViewBounds;
use crate::camera::{Camera, RayTable};
use crate::dataset::DepthImage;
use crate::geometry::Pose;
use nalgebra::Point3;
use rayon::prelude::*;
use rustc_hash::{FxHashMap, FxHashSet};

/// Voxels along each side of a block.
const SIDE: i32 = 8;
/// Voxels in a block.
const VOXELS: usize = (SIDE * SIDE * SIDE) as usize;
/// Block indices stay below this in magnitude, so that voxel indices (times [`SIDE`], plus
/// one) fit an `i32`.
const MAX_BLOCK_INDEX: f64 = (1 << 26) as f64;

/// Whether `pose` can place points: finite, within a thousand kilometres of the origin.
fn usable(pose: &Pose) -> bool {
    let t = pose.translation.vector;
    t.iter().all(|v| v.is_finite() && v.abs() < 1e6)
        && pose.rotation.coords.iter().all(|v| v.is_finite())
}

/// Whether `depth` holds as many values as its size says and is sampled as `rays` is.
fn fits(depth: &DepthImage, rays: &RayTable) -> bool {
    (depth.width, depth.height) == (rays.width, rays.height)
        && depth.data.len() == depth.width as usize * depth.height as usize
}

/// One block: per voxel, the distance in truncation units (-1 to 1) and its weight
/// (0: never observed).
#[derive(Clone)]
struct Block {
    sdf: [f32; VOXELS],
    weight: [f32; VOXELS],
}

impl Block {
    fn empty() -> Box<Self> {
        Box::new(Block {
            sdf: [0.0; VOXELS],
            weight: [0.0; VOXELS],
        })
    }
}

/// The volume's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TsdfParams {
    /// Voxel side, metres.
    pub voxel: f64,
    /// Truncation distance, metres.
    pub truncation: f64,
    /// A voxel's weight stops growing here (its mean then follows new observations).
    pub max_weight: f32,
    /// At most this many blocks (4 KB each) are allocated; depth beyond them is not fused.
    pub max_blocks: usize,
}

/// The volume.
pub struct Tsdf {
    params: TsdfParams,
    index: FxHashMap<[i32; 3], u32>,
    keys: Vec<[i32; 3]>,
    blocks: Vec<Box<Block>>,
    /// Depth samples whose blocks could not be allocated (`max_blocks` reached).
    pub dropped: usize,
}

impl Tsdf {
    pub fn new(params: TsdfParams) -> Self {
        Tsdf {
            params,
            index: FxHashMap::default(),
            keys: Vec::new(),
            blocks: Vec::new(),
            dropped: 0,
        }
    }

    /// Blocks allocated so far.
    pub fn n_blocks(&self) -> usize {
        self.blocks.len()
    }

    /// The block holding `p`; `None` for a point that is not finite or so far out that its
    /// voxel indices would overflow.
    fn block_of(&self, p: &Point3<f64>) -> Option<[i32; 3]> {
        let side = self.params.voxel * SIDE as f64;
        let key = [p.x / side, p.y / side, p.z / side].map(f64::floor);
        key.iter()
            .all(|k| k.abs() < MAX_BLOCK_INDEX)
            .then(|| key.map(|k| k as i32))
    }

    /// Fuses `depth` (sampled as `rays`, seen from `pose`, world from camera): every
    /// `alloc_step`-th sample allocates the blocks within the truncation distance of its
    /// surface point, then every voxel of the blocks this image touched is updated from the
    /// sample its centre projects to (nearest).
    pub fn integrate(
        &mut self,
        depth: &DepthImage,
        rays: &RayTable,
        camera: &Camera,
        pose: &Pose,
        range: (f64, f64),
        alloc_step: usize,
    ) {
        if !fits(depth, rays) || !usable(pose) {
            return;
        }
        let t = self.params.truncation;
        let step = alloc_step.max(1);
        let (w, h) = (depth.width as usize, depth.height as usize);
        let mut touched_keys = FxHashSet::default();
        for v in (0..h).step_by(step) {
            for u in (0..w).step_by(step) {
                let z = f64::from(depth.data[v * w + u]);
                if !(z > range.0 && z < range.1) {
                    continue;
                }
                let p = rays.point(u, v, z);
                // Along the band in steps of at most half a block (the truncation is at most
                // two blocks: `validate`), so that no block it crosses is skipped.
                for f in [-1.0, -0.75, -0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0] {
                    if let Some(key) = self.block_of(&(pose * (p * ((z + f * t) / z)))) {
                        touched_keys.insert(key);
                    }
                }
            }
        }
        let mut touched = vec![false; self.blocks.len()];
        for key in touched_keys {
            match self.index.get(&key) {
                Some(&i) => touched[i as usize] = true,
                None if self.blocks.len() < self.params.max_blocks => {
                    self.index.insert(key, self.blocks.len() as u32);
                    self.keys.push(key);
                    self.blocks.push(Block::empty());
                    touched.push(true);
                }
                None => self.dropped += 1,
            }
        }
        let inverse = pose.inverse();
        let bounds = ViewBounds::new(camera);
        let (voxel, max_weight) = (self.params.voxel, self.params.max_weight);
        let stride = f64::from(rays.stride);
        self.blocks
            .par_iter_mut()
            .zip(self.keys.par_iter())
            .zip(touched.par_iter())
            .filter(|(_, touched)| **touched)
            .for_each(|((block, key), _)| {
                for (i, (sdf, weight)) in block
                    .sdf
                    .iter_mut()
                    .zip(block.weight.iter_mut())
                    .enumerate()
                {
                    let local = [
                        i as i32 % SIDE,
                        i as i32 / SIDE % SIDE,
                        i as i32 / (SIDE * SIDE),
                    ];
                    let centre = Point3::from(std::array::from_fn::<f64, 3, _>(|a| {
                        (f64::from(key[a] * SIDE + local[a]) + 0.5) * voxel
                    }));
                    let c = inverse * centre;
                    if !bounds.contains(&c) {
                        continue;
                    }
                    let Some(px) = camera.project(&c) else {
                        continue;
                    };
                    let (x, y) = ((px.x / stride).round(), (px.y / stride).round());
                    if x < 0.0 || y < 0.0 || x >= w as f64 || y >= h as f64 {
                        continue;
                    }
                    let z = f64::from(depth.data[y as usize * w + x as usize]);
                    if !(z > range.0 && z < range.1) {
                        continue;
                    }
                    let distance = z - c.z;
                    if distance < -t {
                        continue;
                    }
                    let d = (distance / t).min(1.0) as f32;
                    *sdf = (*sdf * *weight + d) / (*weight + 1.0);
                    *weight = (*weight + 1.0).min(max_weight);
                }
            });
    }

    /// The voxel `(i, j, k)`'s distance and weight; `None` where never observed.
    #[inline]
    fn voxel(&self, g: [i32; 3]) -> Option<(f32, f32)> {
        let key = g.map(|c| c.div_euclid(SIDE));
        let l = g.map(|c| c.rem_euclid(SIDE));
        let b = &self.blocks[*self.index.get(&key)? as usize];
        let i = (l[0] + SIDE * (l[1] + SIDE * l[2])) as usize;
        (b.weight[i] > 0.0).then(|| (b.sdf[i], b.weight[i]))
    }

    /// Trilinear distance (truncation units) and least weight at `p`; `None` when any of the
    /// eight voxels around it was never observed.
    fn sample(&self, p: &Point3<f64>) -> Option<(f64, f32)> {
        let v = self.params.voxel;
        let g = [p.x / v - 0.5, p.y / v - 0.5, p.z / v - 0.5];
        let g0 = g.map(|c| c.floor());
        // NaN fails the test too.
        let bound = MAX_BLOCK_INDEX * f64::from(SIDE);
        if !g0.iter().all(|c| c.abs() < bound) {
            return None;
        }
        let f = [g[0] - g0[0], g[1] - g0[1], g[2] - g0[2]];
        let base = g0.map(|c| c as i32);
        let (mut sum, mut least) = (0.0, f32::MAX);
        for corner in 0..8 {
            let o = [corner & 1, (corner >> 1) & 1, (corner >> 2) & 1];
            let (d, w) = self.voxel([base[0] + o[0], base[1] + o[1], base[2] + o[2]])?;
            let a: f64 = (0..3)
                .map(|k| if o[k] == 1 { f[k] } else { 1.0 - f[k] })
                .product();
            sum += a * f64::from(d);
            least = least.min(w);
        }
        Some((sum, least))
    }

    /// The fused surface seen from `pose` (world from camera), sampled as `rays`: for each
    /// sample where `hint` (sampled as `rays` too: the frame's own depth) has a depth, the
    /// zero crossing nearest it along the sample's ray, found by stepping by the distance
    /// the volume stores (within `search` metres of the hint, every voxel on the way
    /// observed at least `min_weight` times); 0 elsewhere.
    pub fn raycast(
        &self,
        pose: &Pose,
        rays: &RayTable,
        hint: &DepthImage,
        range: (f64, f64),
        search: f64,
        min_weight: f32,
    ) -> DepthImage {
        let w = rays.width as usize;
        let mut out = DepthImage::new(rays.width, rays.height);
        if w == 0 || !fits(hint, rays) || !usable(pose) || self.blocks.is_empty() {
            return out;
        }
        let t = self.params.truncation;
        out.data.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            for (u, z_out) in row.iter_mut().enumerate() {
                let start = f64::from(hint.data[v * w + u]);
                if !(start > range.0 && start < range.1) {
                    continue;
                }
                let [nx, ny] = rays.rays[v * w + u];
                let mut z = start;
                for _ in 0..12 {
                    let Some((d, weight)) = self.sample(&(pose * Point3::new(nx * z, ny * z, z)))
                    else {
                        break;
                    };
                    if weight < min_weight {
                        break;
                    }
                    let distance = d * t;
                    if distance.abs() < 5e-4 && d.abs() < 0.99 {
                        *z_out = z as f32;
                        break;
                    }
                    // The stored distance is along the optical axis: a Newton step in z
                    // from a similar viewpoint, at most a truncation at a time.
                    z += distance.clamp(-t, t);
                    if (z - start).abs() > search || z <= range.0 {
                        break;
                    }
                }
            }
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::slam::depth_alignment::tests::render;
    use nalgebra::{Translation3, UnitQuaternion};

    fn params() -> TsdfParams {
        TsdfParams {
            voxel: 0.01,
            truncation: 0.04,
            max_weight: 64.0,
            max_blocks: 100_000,
        }
    }

    fn pose(x: f64, y: f64, z: f64, yaw_deg: f64) -> Pose {
        Pose::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(0.0, yaw_deg.to_radians(), 0.0),
        )
    }

    /// The room fused from three poses and seen from a fourth, with a hint 2 cm off: the
    /// ray cast finds the room's surface there (distorted camera, every second pixel).
    #[test]
    fn raycast_sees_the_fused_room_from_another_pose() {
        let camera = Camera::tum_fr1();
        let rays = RayTable::new(&camera, 2);
        let range = (0.3, 6.0);
        let mut tsdf = Tsdf::new(params());
        for p in [
            pose(0.0, 0.0, 0.0, 0.0),
            pose(0.05, 0.0, 0.1, 3.0),
            pose(-0.04, 0.02, 0.05, -4.0),
        ] {
            let depth = render(&camera, &p).subsample(2);
            tsdf.integrate(&depth, &rays, &camera, &p, range, 2);
        }
        assert!(tsdf.n_blocks() > 0 && tsdf.dropped == 0);
        let view = pose(0.01, -0.01, 0.04, 1.5);
        let truth = render(&camera, &view).subsample(2);
        let mut hint = truth.clone();
        hint.data
            .iter_mut()
            .filter(|z| **z > 0.0)
            .for_each(|z| *z += 0.02);
        let seen = tsdf.raycast(&view, &rays, &hint, range, 0.1, 1.0);
        let (mut close, mut valid) = (0usize, 0usize);
        for (s, t) in seen.data.iter().zip(&truth.data) {
            if *t > 0.0 {
                valid += 1;
                close += usize::from(*s > 0.0 && (s - t).abs() < 0.003);
            }
        }
        assert!(
            close as f64 > 0.85 * valid as f64,
            "{close} of {valid} samples within 3 mm"
        );
        // Nothing is cast where the hint has no depth.
        assert!(
            seen.data
                .iter()
                .zip(&hint.data)
                .all(|(s, h)| *h > 0.0 || *s == 0.0)
        );
    }

    /// `max_blocks` bounds the memory; depth beyond it is counted, not fused, and images
    /// that do not fit the rays change nothing.
    #[test]
    fn block_bound_and_mismatched_images() {
        let camera = Camera::pinhole(80, 60, 70.0, 70.0, 40.0, 30.0);
        let rays = RayTable::new(&camera, 1);
        let p = pose(0.0, 0.0, 0.0, 0.0);
        let depth = render(&camera, &p);
        let mut tsdf = Tsdf::new(TsdfParams {
            max_blocks: 3,
            ..params()
        });
        tsdf.integrate(&depth, &rays, &camera, &p, (0.3, 6.0), 1);
        assert_eq!(tsdf.n_blocks(), 3);
        assert!(tsdf.dropped > 0);
        let mut empty = Tsdf::new(params());
        let small = depth.subsample(2);
        empty.integrate(&small, &rays, &camera, &p, (0.3, 6.0), 1);
        assert_eq!(empty.n_blocks(), 0);
        let seen = tsdf.raycast(&p, &rays, &small, (0.3, 6.0), 0.1, 1.0);
        assert!(seen.data.iter().all(|z| *z == 0.0));
        // Poses that cannot place points (a degenerate solve, a bad start pose) fuse nothing
        // and see nothing, without overflowing the voxel indices.
        for bad in [
            pose(f64::INFINITY, 0.0, 0.0, 0.0),
            pose(f64::NAN, 0.0, 0.0, 0.0),
            pose(1e12, 0.0, 0.0, 0.0),
        ] {
            let mut fresh = Tsdf::new(params());
            fresh.integrate(&depth, &rays, &camera, &bad, (0.3, 6.0), 1);
            assert_eq!(fresh.n_blocks(), 0);
            let seen = tsdf.raycast(&bad, &rays, &depth, (0.3, 6.0), 0.1, 1.0);
            assert!(seen.data.iter().all(|z| *z == 0.0));
        }
        // A depth image whose data does not match its size.
        let mut short = depth.clone();
        short.data.truncate(10);
        tsdf.integrate(&short, &rays, &camera, &p, (0.3, 6.0), 1);
        assert_eq!(
            short
                .subsample(2)
                .data
                .iter()
                .filter(|z| **z != 0.0)
                .count(),
            0
        );
    }
}
