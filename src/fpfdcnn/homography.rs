//! Homography pairs for FPFDCNN training (SuperPoint's recipe, DeTone et al., CVPRW 2018):
//! a window of one real frame paired with the same frame seen through a random homography.
//! The correspondences are exact, on real texture, without depth or pose, so every real
//! frame gives pairs beside the paper's posed ones (eqs 5-7), and the detector targets of the
//! warped side are frame A's Harris corners mapped through the homography.

use nalgebra::{Matrix3, Vector3};
use rand::RngExt;
use serde::{Deserialize, Serialize};

use crate::raster::GrayF32;

/// The range of the random homographies, about a window's centre (`[network] width` and
/// `height` pixels): rotation, isotropic scale, translation and perspective.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HomographyConfig {
    /// Largest rotation, degrees (uniform in ±).
    pub max_rotation_deg: f64,
    /// Scale range (log-uniform).
    pub scale: [f64; 2],
    /// Largest translation, as a fraction of the window's width and height.
    pub max_translation: f64,
    /// Largest perspective term, per window width: the two bottom-row entries are uniform
    /// in ± this / width.
    pub max_perspective: f64,
}

impl Default for HomographyConfig {
    fn default() -> Self {
        HomographyConfig {
            max_rotation_deg: 20.0,
            scale: [0.8, 1.25],
            max_translation: 0.1,
            max_perspective: 0.3,
        }
    }
}

impl HomographyConfig {
    /// An error message for out-of-range values.
    pub fn validate(&self) -> Result<(), String> {
        let [lo, hi] = self.scale;
        let finite = [
            self.max_rotation_deg,
            lo,
            hi,
            self.max_translation,
            self.max_perspective,
        ]
        .iter()
        .all(|v| v.is_finite());
        let ok = finite
            && (0.0..=90.0).contains(&self.max_rotation_deg)
            && lo > 0.1
            && lo <= hi
            && hi < 10.0
            && (0.0..=0.5).contains(&self.max_translation)
            && (0.0..=1.0).contains(&self.max_perspective);
        if !ok {
            return Err(
                "homography: max_rotation_deg in 0..90, 0.1 < scale[0] <= scale[1] < 10, \
                 max_translation in 0..0.5, max_perspective in 0..1"
                    .into(),
            );
        }
        Ok(())
    }
}

/// A homography between two `width x height` windows, acting on window pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Homography {
    /// Maps homogeneous A-window pixels to B-window pixels.
    pub h: Matrix3<f64>,
    /// Its inverse (B to A).
    pub inv: Matrix3<f64>,
}

impl Homography {
    /// A random homography about the centre of a `width x height` window.
    pub fn random(
        cfg: &HomographyConfig,
        width: usize,
        height: usize,
        rng: &mut impl rand::Rng,
    ) -> Self {
        let (w, h) = (width as f64, height as f64);
        let uniform = |rng: &mut dyn rand::Rng, r: f64| {
            if r > 0.0 {
                rng.random_range(-r..r)
            } else {
                0.0
            }
        };
        let theta = uniform(rng, cfg.max_rotation_deg).to_radians();
        let [lo, hi] = cfg.scale;
        let s = if hi > lo {
            rng.random_range(lo.ln()..hi.ln()).exp()
        } else {
            lo
        };
        let (tx, ty) = (
            uniform(rng, cfg.max_translation * w),
            uniform(rng, cfg.max_translation * h),
        );
        let (px, py) = (
            uniform(rng, cfg.max_perspective / w),
            uniform(rng, cfg.max_perspective / w),
        );
        let (c, sn) = (s * theta.cos(), s * theta.sin());
        Self::about_centre(
            Matrix3::new(c, -sn, tx, sn, c, ty, px, py, 1.0),
            width,
            height,
        )
    }

    /// A rotation by `degrees` about the centre of a `width x height` window (clockwise on
    /// screen for positive angles, image y pointing down): for a camera whose principal
    /// point is near the centre, a roll about its optical axis.
    pub fn rotation(degrees: f64, width: usize, height: usize) -> Self {
        let (sn, c) = degrees.to_radians().sin_cos();
        Self::about_centre(
            Matrix3::new(c, -sn, 0.0, sn, c, 0.0, 0.0, 0.0, 1.0),
            width,
            height,
        )
    }

    /// `m`, which acts on coordinates relative to the window's centre, on window pixels.
    fn about_centre(m: Matrix3<f64>, width: usize, height: usize) -> Self {
        let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
        let to = Matrix3::new(1.0, 0.0, cx, 0.0, 1.0, cy, 0.0, 0.0, 1.0);
        let from = Matrix3::new(1.0, 0.0, -cx, 0.0, 1.0, -cy, 0.0, 0.0, 1.0);
        let hm = to * m * from;
        let inv = hm.try_inverse().unwrap_or_else(Matrix3::identity);
        Homography { h: hm, inv }
    }

    /// A B-window pixel in the A window.
    pub fn map_back(&self, p: [f32; 2]) -> Option<[f32; 2]> {
        Self::apply(&self.inv, p)
    }

    /// `p` mapped by `m`; `None` when it goes to infinity.
    fn apply(m: &Matrix3<f64>, p: [f32; 2]) -> Option<[f32; 2]> {
        let q = m * Vector3::new(p[0] as f64, p[1] as f64, 1.0);
        (q.z.abs() > 1e-9).then(|| [(q.x / q.z) as f32, (q.y / q.z) as f32])
    }

    /// An A-window pixel in the B window.
    pub fn map(&self, p: [f32; 2]) -> Option<[f32; 2]> {
        Self::apply(&self.h, p)
    }

    /// The B window: `frame`'s window at `origin` seen through the homography, sampled
    /// bilinearly from the whole frame (so its content reaches beyond A's window), borders
    /// clamped.
    pub fn warp(
        &self,
        frame: &GrayF32,
        origin: [usize; 2],
        width: usize,
        height: usize,
    ) -> GrayF32 {
        let mut out = GrayF32::new(width, height);
        let (ox, oy) = (origin[0] as f64, origin[1] as f64);
        for (y, row) in out.data.chunks_exact_mut(width).enumerate() {
            for (x, v) in row.iter_mut().enumerate() {
                *v = match Self::apply(&self.inv, [x as f32, y as f32]) {
                    Some([u, w]) => frame.sample(u as f64 + ox, w as f64 + oy),
                    None => 0.0,
                };
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn warp_and_map_agree() {
        let (w, h) = (64, 48);
        let mut frame = GrayF32::new(200, 150);
        for (i, v) in frame.data.iter_mut().enumerate() {
            let (x, y) = ((i % 200) as f32, (i / 200) as f32);
            *v = 0.5 + 0.25 * (x * 0.3).sin() + 0.25 * (y * 0.2).cos();
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let cfg = HomographyConfig::default();
        for _ in 0..10 {
            let hm = Homography::random(&cfg, w, h, &mut rng);
            let origin = [40, 30];
            let b = hm.warp(&frame, origin, w, h);
            for p in [[10.0f32, 12.0], [32.0, 24.0], [50.0, 40.0]] {
                let Some(q) = hm.map(p) else { continue };
                if q[0] < 0.0 || q[1] < 0.0 || q[0] > (w - 1) as f32 || q[1] > (h - 1) as f32 {
                    continue;
                }
                // B at the mapped position shows what A shows at p.
                let in_a = frame.sample((p[0] + 40.0) as f64, (p[1] + 30.0) as f64);
                let in_b = b.sample(q[0] as f64, q[1] as f64);
                assert!(
                    (in_a - in_b).abs() < 0.05,
                    "{p:?} -> {q:?}: {in_a} vs {in_b}"
                );
            }
            // The inverse undoes the map.
            let q = hm.map([20.0, 20.0]).expect("finite");
            let back = Homography::apply(&hm.inv, q).expect("finite");
            assert!((back[0] - 20.0).abs() < 1e-3 && (back[1] - 20.0).abs() < 1e-3);
        }
        // A roll by 90 degrees about the centre of a 64 x 48 window (centre 31.5, 23.5):
        // a pixel right of the centre lands below it, and map_back undoes map.
        let roll = Homography::rotation(90.0, w, h);
        let q = roll.map([41.5, 23.5]).expect("finite");
        assert!(
            (q[0] - 31.5).abs() < 1e-4 && (q[1] - 33.5).abs() < 1e-4,
            "{q:?}"
        );
        let back = roll.map_back(q).expect("finite");
        assert!((back[0] - 41.5).abs() < 1e-4 && (back[1] - 23.5).abs() < 1e-4);
        let mut bad = cfg.clone();
        bad.scale = [2.0, 1.0];
        assert!(bad.validate().is_err());
        assert!(cfg.validate().is_ok());
    }
}
