//! The ORB scale pyramid: the features wanted on each level and the level images,
//! each resized bilinearly from the previous one (steps 1 and 2 of the pipeline).

use super::OrbConfig;
use image::GrayImage;
use rayon::prelude::*;

impl OrbConfig {
    /// Features wanted on each level: a geometric series of ratio
    /// `1 / scale_factor` (OpenCV's distribution: in proportion to the levels' side
    /// lengths, not their areas), the last level taking the remainder.
    pub fn features_per_level(&self) -> Vec<usize> {
        let factor = 1.0 / self.scale_factor;
        let mut per_scale =
            self.n_features as f32 * (1.0 - factor) / (1.0 - factor.powi(self.n_levels as i32));
        let mut out = Vec::with_capacity(self.n_levels);
        let mut sum = 0usize;
        for _ in 0..self.n_levels.saturating_sub(1) {
            let n = per_scale.round_ties_even().max(0.0) as usize;
            out.push(n);
            sum += n;
            per_scale *= factor;
        }
        out.push(self.n_features.saturating_sub(sum));
        out
    }
}

/// The pyramid levels of `img`: level 0 is `img` itself, level `l` is
/// `round(size / scale_factor^l)` pixels, stopping before the first empty level.
pub(super) fn build_pyramid(img: &GrayImage, cfg: &OrbConfig) -> Vec<GrayImage> {
    let (w0, h0) = (img.width() as usize, img.height() as usize);
    // The pyramid: each level resized from the previous one.
    let mut levels: Vec<GrayImage> = vec![img.clone()];
    for l in 1..cfg.n_levels {
        let scale = (cfg.scale_factor as f64).powi(l as i32) as f32;
        let w = (w0 as f32 / scale).round_ties_even() as usize;
        let h = (h0 as f32 / scale).round_ties_even() as usize;
        if w == 0 || h == 0 {
            break;
        }
        let prev = &levels[l - 1];
        levels.push(resize_bilinear(prev, w, h));
    }
    levels
}

/// Bilinear resize with pixel centres aligned (OpenCV's `INTER_LINEAR`).
fn resize_bilinear(src: &GrayImage, w: usize, h: usize) -> GrayImage {
    let (sw, sh) = (src.width() as usize, src.height() as usize);
    let taps = |n_dst: usize, n_src: usize| -> Vec<(usize, f32)> {
        let r = n_src as f64 / n_dst as f64;
        (0..n_dst)
            .map(|i| {
                let f = (i as f64 + 0.5) * r - 0.5;
                let i0 = f.floor();
                if i0 < 0.0 {
                    (0, 0.0)
                } else if i0 as usize >= n_src - 1 {
                    (n_src - 1, 0.0)
                } else {
                    (i0 as usize, (f - i0) as f32)
                }
            })
            .collect()
    };
    let (xs, ys) = (taps(w, sw), taps(h, sh));
    let d = src.as_raw();
    let mut out = vec![0u8; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let (y0, fy) = ys[y];
        let y1 = (y0 + 1).min(sh - 1);
        for (x, o) in row.iter_mut().enumerate() {
            let (x0, fx) = xs[x];
            let x1 = (x0 + 1).min(sw - 1);
            let g = |xx: usize, yy: usize| d[yy * sw + xx] as f32;
            let top = g(x0, y0) * (1.0 - fx) + g(x1, y0) * fx;
            let bottom = g(x0, y1) * (1.0 - fx) + g(x1, y1) * fx;
            *o = super::round_u8(top * (1.0 - fy) + bottom * fy);
        }
    });
    GrayImage::from_raw(w as u32, h as u32, out).unwrap_or_default()
}
