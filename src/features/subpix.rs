//! Sub-pixel corner refinement (Förstner's operator, as OpenCV's `cornerSubPix`): the
//! corner is the point `q` that minimises `Σ_w (g(x)ᵀ (x − q))²` over a window of image
//! gradients `g`, i.e. `q = (Σ g gᵀ)⁻¹ Σ g gᵀ x`, iterated with the window re-centred.

use crate::raster::GrayF32;

/// Refinement settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SubPixConfig {
    /// Window radius, pixels (window side `2 r + 1`).
    pub radius: usize,
    /// Iterations at most.
    pub iterations: usize,
    /// A point that would move farther than this from its start keeps its start.
    pub max_shift: f32,
    /// Gaussian smoothing of the image before the gradients.
    pub sigma: f32,
}

impl Default for SubPixConfig {
    fn default() -> Self {
        SubPixConfig {
            radius: 4,
            iterations: 6,
            max_shift: 4.0,
            sigma: 1.0,
        }
    }
}

/// Gradients `(gx, gy)` of the smoothed image, computed once per image.
pub fn gradients(img: &GrayF32, cfg: &SubPixConfig) -> (GrayF32, GrayF32) {
    let smooth = if cfg.sigma > 0.0 {
        img.gaussian_blur(cfg.sigma)
    } else {
        img.clone()
    };
    smooth.sobel()
}

/// Refines `p` to the corner position; returns `p` unchanged where the window holds no
/// corner (a near-singular gradient matrix: an edge or a flat patch) or where the
/// estimate leaves `max_shift`.
pub(crate) fn refine_corner(
    gx: &GrayF32,
    gy: &GrayF32,
    p: [f32; 2],
    cfg: &SubPixConfig,
) -> [f32; 2] {
    let (w, h) = (gx.width as isize, gx.height as isize);
    let r = cfg.radius as isize;
    let mut q = p;
    for _ in 0..cfg.iterations {
        let (cx, cy) = (q[0].round() as isize, q[1].round() as isize);
        if cx - r < 1 || cy - r < 1 || cx + r >= w - 1 || cy + r >= h - 1 {
            return p;
        }
        let (mut a, mut b, mut c, mut bx, mut by) = (0f64, 0f64, 0f64, 0f64, 0f64);
        let s2 = (r as f64 / 2.0).max(1.0).powi(2);
        for y in cy - r..=cy + r {
            for x in cx - r..=cx + r {
                let (dx, dy) = (x as f64 - q[0] as f64, y as f64 - q[1] as f64);
                let wgt = (-(dx * dx + dy * dy) / (2.0 * s2)).exp();
                let k = (y * w + x) as usize;
                let (u, v) = (gx.data[k] as f64, gy.data[k] as f64);
                let (uu, uv, vv) = (wgt * u * u, wgt * u * v, wgt * v * v);
                a += uu;
                b += uv;
                c += vv;
                bx += uu * x as f64 + uv * y as f64;
                by += uv * x as f64 + vv * y as f64;
            }
        }
        let det = a * c - b * b;
        // Smaller eigenvalue of [[a, b], [b, c]] against the larger: edges and flat
        // patches have no well-defined corner.
        let tr = a + c;
        let disc = ((a - c).powi(2) + 4.0 * b * b).sqrt();
        let (lmin, lmax) = ((tr - disc) / 2.0, (tr + disc) / 2.0);
        if lmax <= 1e-12 || lmin < 0.05 * lmax || det <= 0.0 {
            return p;
        }
        let nx = ((c * bx - b * by) / det) as f32;
        let ny = ((a * by - b * bx) / det) as f32;
        if !(nx.is_finite() && ny.is_finite()) {
            return p;
        }
        let moved = ((nx - q[0]).powi(2) + (ny - q[1]).powi(2)).sqrt();
        q = [nx, ny];
        if ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2)).sqrt() > cfg.max_shift {
            return p;
        }
        if moved < 0.01 {
            break;
        }
    }
    q
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A bright quadrant whose corner is at (x0, y0), anti-aliased by area.
    fn quadrant(x0: f32, y0: f32) -> GrayF32 {
        let (w, h) = (48, 40);
        let mut img = GrayF32::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let cover = |v: f32, c: f32| (v + 0.5 - c).clamp(0.0, 1.0);
                img.data[y * w + x] = cover(x as f32, x0) * cover(y as f32, y0);
            }
        }
        img
    }

    #[test]
    fn finds_a_corner_to_a_third_of_a_pixel_from_three_pixels_away() {
        let cfg = SubPixConfig::default();
        for (x0, y0) in [(20.3, 17.6), (23.5, 20.5), (18.8, 22.2)] {
            let img = quadrant(x0, y0);
            let (gx, gy) = gradients(&img, &cfg);
            let q = refine_corner(&gx, &gy, [x0.round() + 2.0, y0.round() - 2.0], &cfg);
            // Pixel centres are at integer coordinates; pixel x covers [x - 0.5, x + 0.5].
            let want = [x0, y0];
            assert!(
                (q[0] - want[0]).abs() < 0.3 && (q[1] - want[1]).abs() < 0.3,
                "{q:?} vs {want:?}"
            );
        }
    }

    #[test]
    fn edges_flat_patches_and_borders_keep_the_point() {
        let cfg = SubPixConfig::default();
        let mut edge = GrayF32::new(40, 40);
        for y in 0..40 {
            for x in 20..40 {
                edge.data[y * 40 + x] = 1.0;
            }
        }
        let (gx, gy) = gradients(&edge, &cfg);
        assert_eq!(refine_corner(&gx, &gy, [18.0, 20.0], &cfg), [18.0, 20.0]);
        let flat = GrayF32::new(40, 40);
        let (gx, gy) = gradients(&flat, &cfg);
        assert_eq!(refine_corner(&gx, &gy, [20.0, 20.0], &cfg), [20.0, 20.0]);
        let img = quadrant(20.0, 20.0);
        let (gx, gy) = gradients(&img, &cfg);
        assert_eq!(refine_corner(&gx, &gy, [2.0, 20.0], &cfg), [2.0, 20.0]);
    }
}
