//! Ray casting: one ray per pixel through the camera model (each distorted pixel
//! is back-projected with [`Camera::normalized`], so images follow the lens
//! distortion exactly), rows in parallel with rayon. Shading is Lambertian with
//! point lights (shadows of the ceiling lights from cached cube maps), ambient light darkened
//! near the room's corners and edges, and emissive screens, lamps and windows.

use super::config::RenderConfig;
use super::geom::{Ray, V3};
use super::scene::Scene;
use super::shadow::ShadowMap;
use super::texture::TexCtx;
use crate::camera::Camera;
use crate::classes::VOID;
use crate::geometry::Pose;
use nalgebra::Point2;
use rayon::prelude::*;

/// One rendered pixel.
#[derive(Debug, Clone, Copy, Default)]
pub struct Px {
    /// Linear radiance.
    pub rgb: [f32; 3],
    /// Exact z-depth in metres, 0 where the ray hit nothing.
    pub depth: f32,
    /// `|cos|` of the angle between the ray and the surface normal.
    pub cos: f32,
    /// NYU40 class of the surface hit (void where the ray hit nothing).
    pub label: u8,
    /// `FLAG_NO_DEPTH`, `FLAG_DARK`.
    pub flags: u8,
}

/// The surface gives no depth reading (glass).
pub(crate) const FLAG_NO_DEPTH: u8 = 1;
/// The surface is very dark (IR absorbing).
pub(crate) const FLAG_DARK: u8 = 2;

/// A rendered image, row-major.
#[derive(Debug, Clone)]
pub struct Render {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// The pixels, row-major.
    pub px: Vec<Px>,
}

/// Renders a scene with one camera.
pub struct Renderer<'a> {
    /// The scene rendered.
    pub scene: &'a Scene,
    /// The camera (intrinsics, distortion and image size).
    pub camera: Camera,
    /// Shading settings.
    pub config: RenderConfig,
    /// Undistorted normalised coordinates `(X/Z, Y/Z)` of each pixel.
    rays: Vec<[f32; 2]>,
    /// Shadow cube map of each light that casts shadows.
    shadows: Vec<Option<ShadowMap>>,
}

/// Overall light gain that maps the scene's light powers to a well exposed image.
const LIGHT_GAIN: f32 = 3.0;

impl<'a> Renderer<'a> {
    /// Prepares the pixel rays and a shadow map for each light that casts shadows.
    pub fn new(scene: &'a Scene, camera: &Camera, config: &RenderConfig) -> Self {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let rays = (0..w * h)
            .into_par_iter()
            .map(|i| {
                let n = camera.normalized(&Point2::new((i % w) as f64, (i / w) as f64));
                [n.x as f32, n.y as f32]
            })
            .collect();
        let shadows = scene
            .lights
            .iter()
            .map(|l| (l.shadows && config.shadows).then(|| ShadowMap::new(V3::from(l.pos), 512)))
            .collect();
        Renderer {
            scene,
            camera: camera.clone(),
            config: config.clone(),
            rays,
            shadows,
        }
    }

    /// Renders the view from a camera-to-world pose.
    pub fn render(&self, pose: &Pose) -> Render {
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        let r = pose.rotation.to_rotation_matrix();
        let m = r.matrix().map(|v| v as f32);
        let o = pose.translation.vector.map(|v| v as f32);
        let mut px = vec![Px::default(); w * h];
        px.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, out) in row.iter_mut().enumerate() {
                let [nx, ny] = self.rays[y * w + x];
                let d = m * V3::new(nx, ny, 1.0);
                *out = self.trace(&Ray::new(o, d));
            }
        });
        Render {
            width: w as u32,
            height: h as u32,
            px,
        }
    }

    /// Shades the first surface along a camera ray whose direction has unit
    /// z-component in the camera frame (so the hit distance is the z-depth).
    fn trace(&self, ray: &Ray) -> Px {
        let scene = self.scene;
        let Some(hit) = scene.cast(ray, 1e-4, 1e4) else {
            return Px {
                label: VOID,
                ..Px::default()
            };
        };
        let s = &scene.solids[hit.solid as usize];
        let n = s.to_world(s.local_normal(hit.face, &hit.local));
        let p = ray.o + ray.d * hit.t;
        let surf = s.material.surface(&TexCtx {
            face: hit.face,
            p: hit.local + s.half,
            size: s.half * 2.0,
            dir: s.to_local(ray.d),
            seed: s.seed,
        });
        let dn = ray.d.norm();
        let cos = (n.dot(&ray.d) / dn).abs();
        let mut direct = [0.0f32; 3];
        for (l, shadow) in scene.lights.iter().zip(&self.shadows) {
            let to = V3::from(l.pos) - p;
            let d2 = to.norm_squared();
            let ndl = n.dot(&to) / d2.sqrt();
            if ndl <= 0.0 {
                continue;
            }
            let vis = shadow.as_ref().map_or(1.0, |m| m.visibility(scene, &p, &n));
            if vis <= 0.0 {
                continue;
            }
            let k = LIGHT_GAIN * ndl * vis / (d2 + 1.0);
            for (d, c) in direct.iter_mut().zip(l.color) {
                *d += c * k;
            }
        }
        let ao = self.occlusion(&p);
        // Light bounced off the floor reaches downward-facing surfaces (ceilings).
        let amb = ao * (1.0 + 1.2 * (-n.z).max(0.0));
        let mut rgb = [0.0; 3];
        for c in 0..3 {
            let light = scene.ambient[c] * amb + direct[c] * (0.75 + 0.25 * ao);
            rgb[c] = surf.albedo[c] * light + surf.emission[c];
        }
        let a = surf.albedo;
        let dark = 0.3 * a[0] + 0.59 * a[1] + 0.11 * a[2] < 0.02 && surf.emission == [0.0; 3];
        Px {
            rgb,
            depth: hit.t,
            cos,
            label: s.label,
            flags: ((surf.no_depth as u8) * FLAG_NO_DEPTH) | ((dark as u8) * FLAG_DARK),
        }
    }

    /// Cheap ambient occlusion: darker within a few decimetres of the room's
    /// floor, ceiling and walls (the plane a point lies on is skipped).
    fn occlusion(&self, p: &V3) -> f32 {
        let r = &self.scene.room;
        let mut d = f32::MAX;
        let mut consider = |v: f32| {
            if v > 2e-3 {
                d = d.min(v);
            }
        };
        consider(p.z);
        consider(r.height - p.z);
        for wall in &r.walls {
            let dist = (p.x - wall.a[0]) * wall.n[0] + (p.y - wall.a[1]) * wall.n[1];
            let dir = wall.dir();
            let s = (p.x - wall.a[0]) * dir[0] + (p.y - wall.a[1]) * dir[1];
            if (-0.05..wall.len + 0.05).contains(&s) {
                consider(dist);
            }
        }
        let q = d / 0.3;
        1.0 - 0.45 / (1.0 + q * q)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::config::RoomConfig;
    use crate::synth::scene::Scene;
    use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

    #[test]
    fn depth_is_z_and_labels_are_set() {
        let scene = Scene::generate(&RoomConfig::default(), 5).unwrap();
        let cam = Camera::tum_fr1().resized(64, 48);
        let r = Renderer::new(&scene, &cam, &RenderConfig::default());
        // Camera at the room centre looking straight down at the floor.
        let (x, y) = (scene.room.width as f64 * 0.5, scene.room.depth as f64 * 0.5);
        let down = UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI);
        let pose = Isometry3::from_parts(Translation3::new(x, y, 1.5), down);
        let img = r.render(&pose);
        let labels: Vec<u8> = img.px.iter().map(|p| p.label).collect();
        assert!(labels.iter().all(|&l| l != VOID));
        assert!(
            img.px
                .iter()
                .all(|p| p.depth > 0.0 && p.depth <= 1.5 + 1e-4)
        );
    }
}
