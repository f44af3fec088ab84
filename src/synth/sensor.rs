//! From rendered radiance and exact depth to what an RGB-D camera delivers:
//! exposure (with slow auto-exposure drift), vignetting, a soft highlight
//! shoulder, gamma, a slight lens blur and colour noise; Kinect-like depth noise,
//! disparity quantisation and holes. All randomness is a hash of (seed, frame,
//! pixel), so images do not depend on thread scheduling or the platform.

use super::config::{RenderConfig, SensorConfig};
use super::detmath::{gauss, hash, hash2, hash4, noise1, noise2, unit};
use super::render::{FLAG_DARK, FLAG_NO_DEPTH, Render};
use crate::camera::Camera;
use crate::dataset::DepthImage;
use image::{GrayImage, Luma, RgbImage};
use rayon::prelude::*;

/// Auto-exposure gain at time `t` (seconds): a slow smooth drift around 1.
pub(crate) fn exposure_gain(cfg: &SensorConfig, seed: u32, t: f64) -> f32 {
    let v = cfg.exposure_variation as f32;
    if v == 0.0 {
        return 1.0;
    }
    let x = (t * 0.35) as f32;
    let n = 0.7 * noise1(x, seed) + 0.3 * noise1(x * 2.3 + 17.0, seed ^ 0x77);
    1.0 + v * (2.0 * n - 1.0)
}

/// The gain that brings the mean linear luminance of an image to 0.2 (about
/// 45 % grey after gamma), like a camera's auto-exposure; within `[0.3, 4]`.
pub(crate) fn auto_exposure(rgb: &[[f32; 3]]) -> f32 {
    let (mut sum, mut n) = (0.0f64, 0usize);
    for p in rgb.iter().step_by(7) {
        sum += (0.3 * p[0] + 0.59 * p[1] + 0.11 * p[2]).min(2.0) as f64;
        n += 1;
    }
    let mean = (sum / n.max(1) as f64) as f32;
    (0.22 / mean.max(1e-4)).clamp(0.3, 4.0)
}

/// The 8-bit colour image of linear radiance `rgb` (row-major, `w x h`).
pub(crate) fn color_image(
    rgb: &[[f32; 3]],
    w: u32,
    h: u32,
    gain: f32,
    render: &RenderConfig,
    sensor: &SensorConfig,
    seed: u32,
) -> RgbImage {
    let (wu, hu) = (w as usize, h as usize);
    let gain = gain * render.exposure as f32;
    let soft: Vec<[f32; 3]> = if render.soften && wu > 2 && hu > 2 {
        soften(rgb, wu, hu)
    } else {
        rgb.to_vec()
    };
    let (cx, cy) = ((w as f32 - 1.0) * 0.5, (h as f32 - 1.0) * 0.5);
    let norm = 1.0 / (cx * cx + cy * cy).max(1e-6);
    let vig = render.vignetting as f32;
    let noise = sensor.rgb_noise as f32 / 255.0;
    let mut raw = vec![0u8; wu * hu * 3];
    raw.par_chunks_mut(wu * 3).enumerate().for_each(|(y, row)| {
        for x in 0..wu {
            let i = y * wu + x;
            let (dx, dy) = (x as f32 - cx, y as f32 - cy);
            let v = gain * (1.0 - vig * (dx * dx + dy * dy) * norm);
            for c in 0..3 {
                let lin = shoulder(soft[i][c] * v);
                let mut e = lin.sqrt();
                if noise > 0.0 {
                    let g = gauss(hash4(seed, i as u32, c as u32, 0x5eed));
                    e += g * noise * (0.2 + 1.6 * e).sqrt();
                }
                row[x * 3 + c] = (e * 255.0 + 0.5).clamp(0.0, 255.0) as u8;
            }
        }
    });
    RgbImage::from_raw(w, h, raw).unwrap_or_else(|| RgbImage::new(w, h))
}

/// Soft roll-off of highlights above 0.8 (linear), reaching 1 asymptotically.
fn shoulder(x: f32) -> f32 {
    if x <= 0.8 {
        x.max(0.0)
    } else {
        let t = (x - 0.8) / 0.2;
        0.8 + 0.2 * t / (1.0 + t)
    }
}

/// Separable `[1 4 1] / 6` blur.
fn soften(src: &[[f32; 3]], w: usize, h: usize) -> Vec<[f32; 3]> {
    let mut tmp = vec![[0.0f32; 3]; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let s = &src[y * w..(y + 1) * w];
        for x in 0..w {
            let (l, r) = (x.saturating_sub(1), (x + 1).min(w - 1));
            for c in 0..3 {
                row[x][c] = (s[l][c] + 4.0 * s[x][c] + s[r][c]) / 6.0;
            }
        }
    });
    let mut out = vec![[0.0f32; 3]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let (u, d) = (y.saturating_sub(1), (y + 1).min(h - 1));
        for x in 0..w {
            for c in 0..3 {
                row[x][c] = (tmp[u * w + x][c] + 4.0 * tmp[y * w + x][c] + tmp[d * w + x][c]) / 6.0;
            }
        }
    });
    out
}

/// Exact z-depth (0 where nothing was hit).
pub(crate) fn exact_depth(r: &Render) -> DepthImage {
    DepthImage {
        width: r.width,
        height: r.height,
        data: r.px.iter().map(|p| p.depth).collect(),
    }
}

/// The label image.
pub(crate) fn label_image(r: &Render) -> GrayImage {
    GrayImage::from_fn(r.width, r.height, |x, y| {
        Luma([r.px[(y * r.width + x) as usize].label])
    })
}

/// Kinect-like depth: holes, then noise and disparity quantisation.
pub(crate) fn sensor_depth(r: &Render, cam: &Camera, cfg: &SensorConfig, seed: u32) -> DepthImage {
    let (w, h) = (r.width as usize, r.height as usize);
    let z: Vec<f32> = r.px.iter().map(|p| p.depth).collect();
    let mut out = z.clone();
    // Structured-light geometry at this resolution: focal length (pixels) times
    // the 7.5 cm projector baseline, and the 1/8 pixel disparity step.
    let fb = (cam.fx as f32) * 0.075;
    let (lo, hi) = (cfg.min_depth as f32, cfg.max_depth as f32);
    if cfg.depth_holes {
        let blob_scale = 24.0 * w as f32 / 640.0;
        let shadow_max = 12.0 * w as f32 / 640.0;
        out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, out) in row.iter_mut().enumerate() {
                let i = y * w + x;
                let p = &r.px[i];
                let hsh = hash2(seed, i as u32);
                // Patchy, not salt-and-pepper: thresholds vary smoothly.
                let (bx, by) = (x as f32 / blob_scale, y as f32 / blob_scale);
                let patch = noise2(bx * 2.0, by * 2.0, seed ^ 0x9a7c);
                let mut hole = p.flags & FLAG_NO_DEPTH != 0
                    || (p.flags & FLAG_DARK != 0 && patch < 0.7)
                    || p.cos < 0.02 + 0.1 * patch * patch
                    || unit(hsh >> 3 ^ 0xabcd) < 0.0005;
                if !hole {
                    let n = noise2(bx, by, seed ^ 0xb10b);
                    hole = n > 0.975 - 0.015 * (z[i] - 3.0).max(0.0);
                }
                if !hole {
                    // Ragged edges: either side of a depth jump may lose its reading.
                    let jump = [
                        (x.wrapping_sub(1), y),
                        (x + 1, y),
                        (x, y.wrapping_sub(1)),
                        (x, y + 1),
                    ]
                    .iter()
                    .filter(|&&(a, b)| a < w && b < h)
                    .any(|&(a, b)| (z[b * w + a] - z[i]).abs() > 0.03 * z[i] + 0.02);
                    hole = jump && unit(hash(hsh ^ 0x1ed6e)) < 0.5;
                }
                if hole {
                    *out = 0.0;
                }
            }
            // Occlusion shadows: the projector, to the camera's right, cannot
            // light the background just left of a foreground edge. Width in
            // pixels is the disparity difference (halved, capped at 12 px).
            let zr = &z[y * w..(y + 1) * w];
            for x in 1..w {
                let (fg, bg) = (zr[x], zr[x - 1]);
                if fg > 0.0 && bg > fg * 1.04 + 0.02 {
                    let width = (0.5 * fb * (1.0 / fg - 1.0 / bg)).min(shadow_max) as usize;
                    for k in 1..=width.min(x) {
                        if zr[x - k] > fg * 1.04 + 0.02 {
                            row[x - k] = 0.0;
                        }
                    }
                }
            }
        });
    }
    out.par_iter_mut().enumerate().for_each(|(i, d)| {
        if *d <= 0.0 {
            return;
        }
        if *d < lo || *d > hi {
            *d = 0.0;
            return;
        }
        if cfg.depth_noise {
            let sigma = 0.0012 + 0.0019 * (*d - 0.4) * (*d - 0.4);
            let noisy = *d + sigma * gauss(hash2(seed ^ 0xd, i as u32));
            let disparity = ((fb / noisy) * 8.0).round() / 8.0;
            *d = if disparity > 0.0 { fb / disparity } else { 0.0 };
            if *d < lo || *d > hi {
                *d = 0.0;
            }
        }
    });
    DepthImage {
        width: r.width,
        height: r.height,
        data: out,
    }
}
