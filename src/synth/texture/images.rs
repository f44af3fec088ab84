//! Image content: pictures, computer desktops and the outdoor view through windows.

use super::{POSTER, Rgb, clamp01, mix, pick, scale, srgb};
use crate::synth::detmath::{FastFloor, fbm1, fbm2, hash2, hash3, noise1, noise2, unit};
use crate::synth::geom::V3;

/// A picture's content at normalised coordinates (`t` upwards).
pub(super) fn picture(s: f32, t: f32, seed: u32) -> Rgb {
    match seed % 4 {
        0 => {
            // Landscape: sky, mountains, meadow, sun.
            let ridge = 0.35 + 0.3 * fbm1(s * 3.0, seed, 4);
            let hills = 0.25 + 0.12 * fbm1(s * 5.0 + 10.0, seed ^ 3, 3);
            let sun = ((s - 0.75) * (s - 0.75) + (t - 0.8) * (t - 0.8) * 0.6) < 0.004;
            if sun {
                srgb(255, 230, 150)
            } else if t < hills {
                scale(
                    srgb(70, 130, 50),
                    0.7 + 0.5 * noise2(s * 40.0, t * 40.0, seed),
                )
            } else if t < ridge {
                mix(
                    srgb(60, 70, 100),
                    srgb(120, 130, 160),
                    (t - hills) / (ridge - hills + 1e-3),
                )
            } else {
                mix(
                    srgb(180, 205, 235),
                    srgb(60, 110, 190),
                    (t - ridge) / (1.0 - ridge + 1e-3),
                )
            }
        }
        1 => {
            // Rectangles separated by black lines.
            let xs = [
                0.3 + 0.2 * unit(hash2(seed, 1)),
                0.7 + 0.15 * unit(hash2(seed, 2)),
            ];
            let ys = [
                0.25 + 0.2 * unit(hash2(seed, 3)),
                0.65 + 0.2 * unit(hash2(seed, 4)),
            ];
            let line = xs.iter().any(|&x| (s - x).abs() < 0.015)
                || ys.iter().any(|&y| (t - y).abs() < 0.015);
            if line {
                srgb(20, 20, 20)
            } else {
                let cx = xs.iter().filter(|&&x| s > x).count() as u32;
                let cy = ys.iter().filter(|&&y| t > y).count() as u32;
                let h = hash3(cx, cy, seed);
                if h.is_multiple_of(3) {
                    pick(&POSTER, h >> 4)
                } else {
                    srgb(235, 232, 220)
                }
            }
        }
        2 => {
            // Colourful abstract blobs.
            let n = fbm2(s * 3.0, t * 3.0, seed, 4);
            let m = fbm2(s * 2.0 + 5.0, t * 2.0, seed ^ 1, 3);
            let a = pick(&POSTER, seed >> 3);
            let b = pick(&POSTER, seed >> 7);
            scale(mix(a, b, clamp01(n * 2.0 - 0.5)), 0.5 + m)
        }
        _ => {
            // Circles on a plain background.
            let mut c = pick(&POSTER, seed >> 9);
            c = mix(c, srgb(240, 235, 220), 0.6);
            for k in 0..5u32 {
                let h = hash2(seed, k + 10);
                let (x, y, r) = (unit(h), unit(h >> 5), 0.06 + 0.18 * unit(h >> 11));
                if (s - x) * (s - x) + (t - y) * (t - y) < r * r {
                    c = pick(&POSTER, h >> 17);
                }
            }
            c
        }
    }
}

/// A computer desktop: wallpaper gradient and a few windows.
pub(super) fn screen(s: f32, t: f32, seed: u32) -> Rgb {
    let mut c = mix(pick(&POSTER, seed), srgb(20, 40, 90), 0.3 + 0.5 * t);
    for k in 0..3u32 {
        let h = hash2(seed, k);
        let (x0, y0) = (0.05 + 0.5 * unit(h), 0.1 + 0.4 * unit(h >> 6));
        let (x1, y1) = (
            x0 + 0.25 + 0.2 * unit(h >> 12),
            y0 + 0.2 + 0.3 * unit(h >> 18),
        );
        if (x0..x1).contains(&s) && (y0..y1).contains(&t) {
            c = if t > y1 - 0.05 {
                srgb(60, 80, 120)
            } else if ((t - y0) / 0.035).fr() < 0.4 && noise1(s * 30.0, h) > 0.35 {
                srgb(70, 70, 80)
            } else {
                srgb(235, 235, 235)
            };
        }
    }
    c
}

/// Radiance of the outdoor view along a local direction (`-y` points outside):
/// sky above a skyline of trees and buildings, at infinite distance.
pub(super) fn outdoor(dir: &V3, seed: u32) -> Rgb {
    let out = (-dir.y).max(1e-3);
    let (a, e) = (dir.x / out, dir.z / out);
    let skyline = -0.06 + 0.22 * fbm1(a * 1.2 + 7.0, seed, 4);
    let c = if e < -0.35 {
        scale(
            srgb(120, 125, 110),
            0.8 + 0.3 * noise2(a * 20.0, e * 20.0, seed),
        )
    } else if e < skyline {
        let building = noise1(a * 2.5, seed ^ 11) > 0.55;
        if building {
            let win = ((a * 25.0).fr() < 0.4) && ((e * 25.0).fr() < 0.5);
            if win {
                srgb(120, 140, 160)
            } else {
                srgb(170, 160, 150)
            }
        } else {
            scale(
                srgb(60, 100, 50),
                0.6 + 0.6 * fbm2(a * 15.0, e * 15.0, seed, 3),
            )
        }
    } else {
        let sky = mix(
            srgb(225, 235, 245),
            srgb(110, 160, 225),
            clamp01((e - skyline) * 1.2),
        );
        let cloud = clamp01(fbm2(a * 2.0, e * 4.0, seed ^ 5, 4) * 2.2 - 1.0);
        mix(sky, srgb(250, 250, 250), cloud)
    };
    scale(c, 2.2)
}
