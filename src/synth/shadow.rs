//! Shadow cube maps. The scene is static, so the distance from each shadowing
//! light to the first surface in every direction is cast once (lazily, in tiles
//! of 16x16 texels, when a frame first needs them) and shared by all frames,
//! instead of one shadow ray per pixel and frame. Lookups offset the point
//! along its normal and filter the four nearest texels (soft 1-texel edges).

use super::geom::{Ray, V3};
use super::scene::Scene;
use std::sync::OnceLock;

const TILE: usize = 16;

/// One light's cube map.
pub(crate) struct ShadowMap {
    pos: V3,
    /// Texels per face side (a multiple of [`TILE`]).
    n: usize,
    tiles: Vec<OnceLock<Box<[f32]>>>,
}

impl ShadowMap {
    /// An empty cube map of a light at `pos` with at least `n` texels per face side.
    pub fn new(pos: V3, n: usize) -> Self {
        let n = n.div_ceil(TILE).max(1) * TILE;
        let per_face = (n / TILE) * (n / TILE);
        ShadowMap {
            pos,
            n,
            tiles: (0..6 * per_face).map(|_| OnceLock::new()).collect(),
        }
    }

    /// Direction of texel `(i, j)` of a face (`2 * axis + positive`).
    fn dir(&self, face: usize, i: usize, j: usize) -> V3 {
        let a = face / 2;
        let u = (i as f32 + 0.5) / self.n as f32 * 2.0 - 1.0;
        let v = (j as f32 + 0.5) / self.n as f32 * 2.0 - 1.0;
        let mut d = V3::zeros();
        d[a] = if face % 2 == 1 { 1.0 } else { -1.0 };
        d[(a + 1) % 3] = u;
        d[(a + 2) % 3] = v;
        d.normalize()
    }

    /// Distance from the light to the first surface through texel `(i, j)`.
    fn depth(&self, scene: &Scene, face: usize, i: usize, j: usize) -> f32 {
        let tiles = self.n / TILE;
        let (ti, tj) = (i / TILE, j / TILE);
        let tile = self.tiles[(face * tiles + tj) * tiles + ti].get_or_init(|| {
            let mut t = vec![0.0f32; TILE * TILE];
            for y in 0..TILE {
                for x in 0..TILE {
                    let d = self.dir(face, ti * TILE + x, tj * TILE + y);
                    t[y * TILE + x] = scene
                        .cast(&Ray::new(self.pos, d), 1e-4, 1e4)
                        .map_or(f32::MAX, |h| h.t);
                }
            }
            t.into_boxed_slice()
        });
        tile[(j % TILE) * TILE + i % TILE]
    }

    /// Fraction of the light reaching point `p` with surface normal `normal`.
    pub fn visibility(&self, scene: &Scene, p: &V3, normal: &V3) -> f32 {
        let d = p + normal * 0.015 - self.pos;
        let ad = d.abs();
        let a = if ad.x >= ad.y && ad.x >= ad.z {
            0
        } else if ad.y >= ad.z {
            1
        } else {
            2
        };
        let face = 2 * a + (d[a] > 0.0) as usize;
        let m = ad[a].max(1e-9);
        let (u, v) = (d[(a + 1) % 3] / m, d[(a + 2) % 3] / m);
        let n = self.n as f32;
        let x = ((u + 1.0) * 0.5 * n - 0.5).clamp(0.0, n - 1.0);
        let y = ((v + 1.0) * 0.5 * n - 0.5).clamp(0.0, n - 1.0);
        let (i0, j0) = (x as usize, y as usize);
        let (i1, j1) = ((i0 + 1).min(self.n - 1), (j0 + 1).min(self.n - 1));
        let (fx, fy) = (x - i0 as f32, y - j0 as f32);
        let dist = d.norm();
        let bias = 0.01 + 0.004 * dist;
        let lit = |i: usize, j: usize| (dist <= self.depth(scene, face, i, j) + bias) as u8 as f32;
        let top = lit(i0, j0) * (1.0 - fx) + lit(i1, j0) * fx;
        let bottom = lit(i0, j1) * (1.0 - fx) + lit(i1, j1) * fx;
        top * (1.0 - fy) + bottom * fy
    }
}
