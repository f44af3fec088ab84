//! Per-material albedo and surface functions evaluated on a hit's face coordinates.

use super::images::{outdoor, picture, screen};
use super::{FaceUv, POSTER, Rgb, Surface, TexCtx, clamp01, mix, pick, scale, srgb};
use crate::synth::detmath::{FastFloor, fbm2, hash2, hash3, noise1, noise2, unit};

/// Streaky wood grain along `u`, brightness factor around 1.
fn grain(u: f32, v: f32, seed: u32) -> f32 {
    let warp = fbm2(u * 0.8, v * 6.0, seed, 2);
    let rings = (v * 40.0 + warp * 9.0).fr();
    let x = 1.0 - (2.0 * rings - 1.0).abs();
    let x2 = x * x;
    let ring = 1.0 - 0.18 * x2 * x2 * x2;
    let streak = 0.9 + 0.2 * fbm2(u * 1.5, v * 120.0, seed ^ 0x55, 2);
    ring * streak
}

/// Painted wall: nearly uniform with faint mottling.
pub(super) fn paint(f: &FaceUv, color: Rgb) -> Rgb {
    let FaceUv { u, v, seed, .. } = *f;
    let k = 0.96
        + 0.06 * fbm2(u * 1.5, v * 1.5, seed, 2)
        + 0.025 * noise2(u * 90.0, v * 90.0, seed ^ 1);
    scale(color, k)
}

/// Brick courses in running bond with mortar joints.
pub(super) fn brick(f: &FaceUv, color: Rgb, mortar: Rgb) -> Rgb {
    let FaceUv { u, v, seed, .. } = *f;
    let row = (v / 0.075).ff();
    let off = if (row as i32) & 1 == 1 { 0.1125 } else { 0.0 };
    let col = ((u + off) / 0.225).ff();
    let (fu, fv) = (u + off - col * 0.225, v - row * 0.075);
    if fu < 0.011 || fv < 0.011 {
        scale(mortar, 0.9 + 0.2 * noise2(u * 200.0, v * 200.0, seed))
    } else {
        let h = hash3(row as i32 as u32, col as i32 as u32, seed);
        let k = 0.75 + 0.4 * unit(h) + 0.15 * noise2(u * 60.0, v * 60.0, seed ^ 7);
        scale(mix(color, srgb(90, 50, 40), 0.3 * unit(h >> 3)), k)
    }
}

/// Floor boards along `u` with staggered ends and dark joints.
pub(super) fn planks(f: &FaceUv, color: Rgb) -> Rgb {
    let FaceUv { u, v, seed, .. } = *f;
    let row = (v / 0.16).ff();
    let off = unit(hash2(row as i32 as u32, seed)) * 1.4;
    let col = ((u + off) / 1.4).ff();
    let (fu, fv) = (u + off - col * 1.4, v - row * 0.16);
    let h = hash3(row as i32 as u32, col as i32 as u32, seed);
    if fv < 0.003 || fu < 0.003 {
        scale(color, 0.35)
    } else {
        let k = (0.78 + 0.4 * unit(h)) * grain(u, v + unit(h >> 4) * 3.0, seed);
        scale(color, k)
    }
}

/// Square tiles with grout lines, optionally in a checker of two shades.
pub(super) fn tiles(f: &FaceUv, color: Rgb, grout: Rgb, size: f32, checker: bool) -> Rgb {
    let FaceUv { u, v, seed, .. } = *f;
    let (iu, iv) = ((u / size).ff(), (v / size).ff());
    let (fu, fv) = (u - iu * size, v - iv * size);
    if fu < 0.004 || fv < 0.004 {
        grout
    } else {
        let h = hash3(iu as i32 as u32, iv as i32 as u32, seed);
        let alt = checker && ((iu as i32 + iv as i32) & 1 == 1);
        let base = if alt { scale(color, 0.45) } else { color };
        scale(
            base,
            0.92 + 0.12 * unit(h) + 0.05 * noise2(u * 25.0, v * 25.0, seed),
        )
    }
}

/// Carpet pile and mottling; a rug `pattern` adds a border and a diamond lattice.
pub(super) fn carpet(f: &FaceUv, color: Rgb, pattern: bool) -> Rgb {
    let FaceUv {
        u, v, us, vs, seed, ..
    } = *f;
    let mut k = 0.8
        + 0.25 * noise2(u * 220.0, v * 220.0, seed)
        + 0.15 * fbm2(u * 3.0, v * 3.0, seed ^ 3, 3);
    if pattern {
        // A border and a diamond lattice, as on many rugs.
        let (s, t) = (u / us, v / vs);
        let edge = s.min(1.0 - s).min(t).min(1.0 - t);
        let d = ((s * 6.0).fr() - 0.5).abs() + ((t * 4.0).fr() - 0.5).abs();
        if (0.04..0.08).contains(&edge) || (edge > 0.1 && d < 0.18) {
            k *= 0.55;
        }
    }
    scale(color, k)
}

/// Wood with grain along the longer side of the face.
pub(super) fn wood(f: &FaceUv, color: Rgb) -> Rgb {
    let FaceUv {
        u, v, us, vs, seed, ..
    } = *f;
    let g = if us >= vs {
        grain(u, v, seed)
    } else {
        grain(v, u, seed)
    };
    scale(color, g)
}

/// Woven fabric: a fine weave plus mottling.
pub(super) fn fabric(f: &FaceUv, color: Rgb) -> Rgb {
    let FaceUv { u, v, seed, .. } = *f;
    let weave = ((u * 400.0).ff() as i32 + (v * 400.0).ff() as i32) & 1;
    let k = 0.9
        + 0.05 * weave as f32
        + 0.12 * fbm2(u * 8.0, v * 8.0, seed, 2)
        + 0.06 * noise2(u * 150.0, v * 150.0, seed ^ 9);
    scale(color, k)
}

/// Curtain fabric shaded by vertical folds.
pub(super) fn curtain(f: &FaceUv, color: Rgb) -> Rgb {
    let FaceUv { u, v, seed, .. } = *f;
    let fold = (u / 0.11 + 0.3 * noise1(v * 2.0, seed)).fr();
    let tri = 1.0 - (2.0 * fold - 1.0).abs();
    let k = 0.62 + 0.45 * tri * tri * (3.0 - 2.0 * tri) + 0.06 * noise2(u * 200.0, v * 200.0, seed);
    scale(color, k)
}

/// A picture in its frame; the picture itself only on the front.
pub(super) fn framed_picture(f: &FaceUv, frame: Rgb) -> Rgb {
    let FaceUv {
        u,
        v,
        us,
        vs,
        seed,
        front,
    } = *f;
    let (s, t) = (u / us, v / vs);
    let b = 0.035 / us.min(vs).max(0.1) + 0.02;
    if !front {
        frame
    } else if s < b || s > 1.0 - b || t < b || t > 1.0 - b {
        scale(frame, 0.9 + 0.2 * noise2(u * 80.0, v * 80.0, seed))
    } else {
        let (s, t) = ((s - b) / (1.0 - 2.0 * b), (t - b) / (1.0 - 2.0 * b));
        picture(s, t, seed)
    }
}

/// A book: spine with bands and a title on the front, covers, page edges elsewhere.
pub(super) fn book(ctx: &TexCtx, f: &FaceUv, color: Rgb) -> Rgb {
    let FaceUv {
        u,
        v,
        us,
        vs,
        seed,
        front,
    } = *f;
    let thin_x = ctx.size.x <= ctx.size.z;
    let cover = if thin_x { ctx.face < 2 } else { ctx.face >= 4 };
    if front {
        // Spine: bands and a title block.
        let (s, t) = if thin_x {
            (u / us, v / vs)
        } else {
            (v / vs, u / us)
        };
        let h = hash2(seed, 77);
        let band = |c: f32| (t - c).abs() < 0.025;
        let accent = pick(&POSTER, h >> 5);
        if band(0.1 + 0.05 * unit(h)) || band(0.88 - 0.05 * unit(h >> 2)) {
            mix(accent, srgb(220, 190, 90), 0.5)
        } else if (0.35..0.7).contains(&t) && (0.25..0.75).contains(&s) && (h & 1 == 1) {
            let mark = noise2(t * 40.0, s * 3.0, seed) > 0.45;
            if mark { scale(accent, 1.2) } else { color }
        } else {
            scale(color, 0.9 + 0.15 * noise2(u * 300.0, v * 300.0, seed))
        }
    } else if cover {
        color
    } else {
        let lines = 0.9 + 0.1 * noise2(u * 10.0, v * 900.0, seed);
        scale(srgb(235, 228, 205), lines)
    }
}

/// Monitor or television: dark bezel around a glowing (or dark, reflective) screen.
pub(super) fn screen_surface(f: &FaceUv, on: bool) -> Surface {
    let FaceUv {
        u,
        v,
        us,
        vs,
        seed,
        front,
    } = *f;
    let mut emission = [0.0; 3];
    let (s, t) = (u / us, v / vs);
    let b = 0.025 / us.min(vs).max(0.05);
    let albedo = if !front || s < b || s > 1.0 - b || t < b || t > 1.0 - b * 1.6 {
        srgb(20, 20, 22)
    } else if on {
        let (s, t) = ((s - b) / (1.0 - 2.0 * b), (t - b * 1.6) / (1.0 - 2.6 * b));
        emission = scale(screen(s, t, seed), 1.1);
        srgb(10, 10, 10)
    } else {
        let refl = 0.02 + 0.03 * clamp01(1.0 - (s - t).abs() * 2.0);
        [refl, refl, refl * 1.1]
    };
    Surface {
        albedo,
        emission,
        no_depth: false,
    }
}

/// Window frame and mullions; the glass shows the outdoors and returns no depth.
pub(super) fn window_surface(ctx: &TexCtx, f: &FaceUv, frame: Rgb) -> Surface {
    let FaceUv {
        u,
        v,
        us,
        vs,
        seed,
        front,
    } = *f;
    let mut emission = [0.0; 3];
    let mut no_depth = false;
    let fw = 0.055;
    let mid = if us > 0.9 {
        ((u - us * 0.5).abs()) < fw * 0.5
    } else {
        false
    };
    let tr = (v - vs * 0.62).abs() < fw * 0.4;
    let border = u < fw || u > us - fw || v < fw || v > vs - fw;
    let albedo = if !front || border || mid || tr {
        scale(frame, 0.95 + 0.05 * noise2(u * 50.0, v * 50.0, seed))
    } else {
        no_depth = true;
        emission = outdoor(&ctx.dir, seed);
        srgb(10, 12, 14)
    };
    Surface {
        albedo,
        emission,
        no_depth,
    }
}

/// Printed paper: lines of words on the top face.
pub(super) fn paper(ctx: &TexCtx, f: &FaceUv) -> Rgb {
    let FaceUv {
        u, v, us, vs, seed, ..
    } = *f;
    let white = srgb(238, 238, 232);
    if ctx.face == 5 {
        let (s, t) = (u / us, v / vs);
        let line = (t * vs / 0.009).fr() < 0.45;
        let word = noise2(u / 0.012, (t * vs / 0.009).ff(), seed) > 0.4;
        if line && word && (0.1..0.9).contains(&s) && (0.08..0.92).contains(&t) {
            srgb(60, 60, 70)
        } else {
            white
        }
    } else {
        white
    }
}

/// Whiteboard with a border and a few marker strokes on the front.
pub(super) fn whiteboard(f: &FaceUv) -> Rgb {
    let FaceUv {
        u,
        v,
        us,
        vs,
        seed,
        front,
    } = *f;
    let white = srgb(240, 242, 242);
    let border = 0.025;
    if !front {
        srgb(170, 172, 175)
    } else if u < border || u > us - border || v < border || v > vs - border {
        srgb(175, 178, 182)
    } else {
        let (s, t) = (u / us, v / vs);
        let mut c = white;
        for k in 0..4u32 {
            let h = hash2(seed, k);
            let y0 = 0.2 + 0.6 * unit(h);
            let (s0, s1) = (0.1 + 0.3 * unit(h >> 3), 0.5 + 0.4 * unit(h >> 6));
            let y = y0 + 0.08 * (noise1(s * 12.0, h) - 0.5);
            if (t - y).abs() < 0.006 && (s0..s1).contains(&s) && noise1(s * 60.0, h ^ 5) > 0.25 {
                c = [srgb(20, 40, 160), srgb(170, 20, 20), srgb(25, 25, 25)][(k % 3) as usize];
            }
        }
        scale(c, 0.98 + 0.04 * fbm2(u * 3.0, v * 3.0, seed, 2))
    }
}

/// Furniture front: a `rows x cols` grid of drawers (or doors) with handles.
pub(super) fn drawers(f: &FaceUv, color: Rgb, rows: u8, cols: u8, wood_: bool) -> Rgb {
    let FaceUv {
        u,
        v,
        us,
        vs,
        seed,
        front,
    } = *f;
    let base = if wood_ {
        wood(f, color)
    } else {
        scale(color, 0.97 + 0.05 * noise2(u * 40.0, v * 40.0, seed))
    };
    if front {
        let (cw, rh) = (us / cols as f32, vs / rows as f32);
        let (ci, ri) = ((u / cw).ff(), (v / rh).ff());
        let (fu, fv) = (u - ci * cw, v - ri * rh);
        let gap = 0.005;
        let doors = rh > 0.45;
        let handle = if doors {
            // Vertical bar near the inner edge of each door.
            let hx = if (ci as i32) % 2 == 0 {
                cw - 0.05
            } else {
                0.05
            };
            (fu - hx).abs() < 0.008 && (fv - rh * 0.65).abs() < 0.07
        } else {
            (fu - cw * 0.5).abs() < 0.06 && (fv - rh * 0.7).abs() < 0.008
        };
        if fu < gap || fv < gap || fu > cw - gap || fv > rh - gap {
            scale(base, 0.3)
        } else if handle {
            srgb(170, 170, 175)
        } else {
            base
        }
    } else {
        base
    }
}

/// Panel door: two recessed panels with shadowed edges on both broad faces.
pub(super) fn door(ctx: &TexCtx, f: &FaceUv, color: Rgb) -> Rgb {
    let FaceUv {
        u, v, us, vs, seed, ..
    } = *f;
    let base = scale(color, 0.96 + 0.05 * noise2(u * 20.0, v * 20.0, seed));
    if ctx.face == 2 || ctx.face == 3 {
        let m = 0.12;
        let split = vs * 0.55;
        let inset = u > m && u < us - m && v > m && v < vs - m && (v - split).abs() > m * 0.5;
        let edge = inset
            && (u < m + 0.012
                || u > us - m - 0.012
                || v < m + 0.012
                || v > vs - m - 0.012
                || (v - split).abs() < m * 0.5 + 0.012);
        if edge {
            scale(base, 0.72)
        } else if inset {
            scale(base, 0.93)
        } else {
            base
        }
    } else {
        scale(base, 0.8)
    }
}
