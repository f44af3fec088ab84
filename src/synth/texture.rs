//! Procedural materials: every surface's albedo (and emission for screens, lamps
//! and the view through windows) is a function of the hit point in the solid's
//! local frame, built from integer-hash noise ([`super::detmath`]) so it is the
//! same on every machine. Colours are linear reflectances in `[0, 1]`.

use super::detmath::{FastFloor, fbm1, fbm2, hash2, hash3, noise1, noise2, unit};
use super::geom::{Face, V3};

/// A linear colour.
pub type Rgb = [f32; 3];

/// Linear reflectance of an 8-bit display colour (gamma 2 approximation, the
/// inverse of the renderer's output encoding).
pub const fn srgb(r: u8, g: u8, b: u8) -> Rgb {
    let (r, g, b) = (r as f32 / 255.0, g as f32 / 255.0, b as f32 / 255.0);
    [r * r, g * g, b * b]
}

/// Surface appearance. Parameters are linear colours.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Material {
    /// Painted wall: nearly uniform (low texture).
    Paint {
        /// Paint colour.
        color: Rgb,
    },
    /// Ceiling plaster.
    Plaster {
        /// Plaster colour.
        color: Rgb,
    },
    /// Brick wall with mortar joints.
    Brick {
        /// Brick colour (varied brick by brick).
        color: Rgb,
        /// Colour of the mortar joints.
        mortar: Rgb,
    },
    /// Wooden floor boards along local x.
    Planks {
        /// Board colour.
        color: Rgb,
    },
    /// Square tiles with grout lines; `checker` alternates two shades.
    Tiles {
        /// Tile colour.
        color: Rgb,
        /// Colour of the grout lines.
        grout: Rgb,
        /// Tile side, metres.
        size: f32,
        /// Darken every other tile (checkerboard).
        checker: bool,
    },
    /// Carpet or rug: fine noise and mottling.
    Carpet {
        /// Pile colour.
        color: Rgb,
        /// Add a rug's border and diamond lattice.
        pattern: bool,
    },
    /// Wood with grain along the longer side of each face.
    Wood {
        /// Base wood colour.
        color: Rgb,
    },
    /// Woven fabric (sofas, beds, pillows, bags).
    Fabric {
        /// Fabric colour.
        color: Rgb,
    },
    /// Curtain fabric with vertical folds.
    Curtain {
        /// Curtain colour.
        color: Rgb,
    },
    /// A framed picture or poster on its `+y` face.
    Picture {
        /// Frame colour (also of the other faces).
        frame: Rgb,
    },
    /// A book: spine on `+y`, covers across its thinnest side, pages elsewhere.
    Book {
        /// Cover colour.
        color: Rgb,
    },
    /// Monitor or television: dark bezel, screen on `+y` (emissive when on).
    Screen {
        /// The screen shows an emissive image (off: a dark reflection).
        on: bool,
    },
    /// Window frame with glass on `+y`; the glass shows a distant outdoor view.
    Window {
        /// Frame and mullion colour.
        frame: Rgb,
    },
    /// Horizontal slats.
    Blinds {
        /// Slat colour.
        color: Rgb,
    },
    /// Brushed metal.
    Metal {
        /// Metal colour.
        color: Rgb,
    },
    /// Smooth plastic or paint.
    Plastic {
        /// Surface colour.
        color: Rgb,
    },
    /// Printed paper (text lines on the top face).
    Paper,
    /// Whiteboard with marker strokes on `+y`.
    Whiteboard,
    /// Furniture front with a grid of drawers (`rows x cols`) or doors on `+y`.
    Drawers {
        /// Front colour.
        color: Rgb,
        /// Rows of drawers (cells taller than 0.45 m are doors).
        rows: u8,
        /// Columns of drawers or doors.
        cols: u8,
        /// Wood grain instead of a plain finish.
        wood: bool,
    },
    /// Panel door (both `±y` faces).
    Door {
        /// Door colour.
        color: Rgb,
    },
    /// Cardboard with a tape strip on top.
    Cardboard,
    /// Plant leaves.
    Foliage,
    /// Glowing lamp shade.
    LampShade {
        /// Shade colour, also the colour of its glow.
        color: Rgb,
    },
    /// Ceiling light panel.
    CeilingLight,
    /// Mirror: a soft grey-blue gradient standing in for a reflection.
    Mirror,
}

/// What the renderer needs from a material at a hit.
#[derive(Debug, Clone, Copy)]
pub struct Surface {
    /// Linear reflectance at the hit.
    pub albedo: Rgb,
    /// Emitted linear radiance (screens, lamp shades, the view through windows).
    pub emission: Rgb,
    /// No depth-sensor return (glass).
    pub no_depth: bool,
}

/// A hit as seen by a material.
pub struct TexCtx {
    /// The face hit ([`Face`]).
    pub face: Face,
    /// Hit point relative to the solid's minimum corner, local frame, metres.
    pub p: V3,
    /// Full size of the solid (local frame).
    pub size: V3,
    /// Ray direction in the local frame.
    pub dir: V3,
    /// The solid's texture seed.
    pub seed: u32,
}

impl TexCtx {
    /// Face coordinates in metres: `u` horizontal (along the face), `v` vertical
    /// on side faces, `y` on horizontal faces. On the front face `u` runs from
    /// the viewer's left to right.
    fn uv(&self) -> (f32, f32, f32, f32) {
        let (p, s) = (&self.p, &self.size);
        match self.face {
            0 | 1 => (p.y, p.z, s.y, s.z),
            3 => (s.x - p.x, p.z, s.x, s.z),
            2 => (p.x, p.z, s.x, s.z),
            6 => (p.x + p.y, p.z, s.x + s.y, s.z),
            _ => (p.x, p.y, s.x, s.y),
        }
    }
}

fn scale(c: Rgb, k: f32) -> Rgb {
    [c[0] * k, c[1] * k, c[2] * k]
}

fn mix(a: Rgb, b: Rgb, t: f32) -> Rgb {
    [
        a[0] + (b[0] - a[0]) * t,
        a[1] + (b[1] - a[1]) * t,
        a[2] + (b[2] - a[2]) * t,
    ]
}

fn clamp01(x: f32) -> f32 {
    x.clamp(0.0, 1.0)
}

/// A random colour from a palette, chosen by a hash.
fn pick(palette: &[Rgb], h: u32) -> Rgb {
    palette[(h % palette.len() as u32) as usize]
}

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

const POSTER: [Rgb; 8] = [
    srgb(200, 40, 40),
    srgb(30, 70, 160),
    srgb(240, 200, 40),
    srgb(240, 240, 235),
    srgb(30, 30, 30),
    srgb(40, 140, 90),
    srgb(230, 120, 40),
    srgb(120, 60, 140),
];

/// Face coordinates of a hit (see [`TexCtx::uv`]) with the seed and whether it is the front.
#[derive(Clone, Copy)]
struct FaceUv {
    u: f32,
    v: f32,
    us: f32,
    vs: f32,
    seed: u32,
    front: bool,
}

impl FaceUv {
    /// The face coordinates of `ctx`.
    fn of(ctx: &TexCtx) -> Self {
        let (u, v, us, vs) = ctx.uv();
        FaceUv {
            u,
            v,
            us,
            vs,
            seed: ctx.seed,
            front: ctx.face == 3,
        }
    }
}

impl Material {
    /// The material at a hit: its reflectance, its emission and whether a depth sensor gets a
    /// return from it (all but glass).
    pub fn surface(&self, ctx: &TexCtx) -> Surface {
        let f = FaceUv::of(ctx);
        let FaceUv {
            u, v, us, vs, seed, ..
        } = f;
        let albedo = match *self {
            Material::Paint { color } => paint(&f, color),
            Material::Plaster { color } => {
                scale(color, 0.97 + 0.04 * fbm2(u * 4.0, v * 4.0, seed, 2))
            }
            Material::Brick { color, mortar } => brick(&f, color, mortar),
            Material::Planks { color } => planks(&f, color),
            Material::Tiles {
                color,
                grout,
                size,
                checker,
            } => tiles(&f, color, grout, size, checker),
            Material::Carpet { color, pattern } => carpet(&f, color, pattern),
            Material::Wood { color } => wood(&f, color),
            Material::Fabric { color } => fabric(&f, color),
            Material::Curtain { color } => curtain(&f, color),
            Material::Picture { frame } => framed_picture(&f, frame),
            Material::Book { color } => book(ctx, &f, color),
            Material::Screen { on } => return screen_surface(&f, on),
            Material::Window { frame } => return window_surface(ctx, &f, frame),
            Material::Blinds { color } => {
                let f = (v / 0.025).fr();
                let k = if f < 0.08 { 0.35 } else { 0.7 + 0.35 * f };
                scale(color, k)
            }
            Material::Metal { color } => {
                scale(color, 0.88 + 0.14 * noise2(u * 3.0, v * 300.0, seed))
            }
            Material::Plastic { color } => {
                scale(color, 0.96 + 0.06 * noise2(u * 30.0, v * 30.0, seed))
            }
            Material::Paper => paper(ctx, &f),
            Material::Whiteboard => whiteboard(&f),
            Material::Drawers {
                color,
                rows,
                cols,
                wood,
            } => drawers(&f, color, rows, cols, wood),
            Material::Door { color } => door(ctx, &f, color),
            Material::Cardboard => {
                let c = scale(
                    srgb(190, 150, 100),
                    0.9 + 0.15 * noise2(u * 120.0, v * 120.0, seed),
                );
                if ctx.face == 5 && ((u - us * 0.5).abs() < 0.025) {
                    scale(srgb(200, 180, 140), 1.1)
                } else {
                    c
                }
            }
            Material::Foliage => {
                let n = fbm2(u * 25.0, v * 25.0, seed, 3);
                let dark = noise2(u * 60.0, v * 60.0, seed ^ 4) > 0.7;
                let k = if dark { 0.3 } else { 0.6 + 0.6 * n };
                scale(mix(srgb(40, 110, 40), srgb(110, 150, 60), n), k)
            }
            Material::LampShade { color } => {
                return Surface {
                    albedo: scale(color, 0.9 + 0.1 * noise2(u * 150.0, v * 150.0, seed)),
                    emission: scale(color, 0.9),
                    no_depth: false,
                };
            }
            Material::CeilingLight => {
                let c = srgb(250, 248, 240);
                return Surface {
                    albedo: c,
                    emission: if ctx.face == 4 {
                        scale(c, 3.0)
                    } else {
                        [0.0; 3]
                    },
                    no_depth: false,
                };
            }
            Material::Mirror => {
                let t = v / vs;
                let s = u / us;
                let g = 0.45 + 0.25 * t + 0.1 * fbm2(s * 2.0, t * 2.0, seed, 2);
                [g * 0.5, g * 0.55, g * 0.62]
            }
        };
        Surface {
            albedo,
            emission: [0.0; 3],
            no_depth: false,
        }
    }
}

/// Painted wall: nearly uniform with faint mottling.
fn paint(f: &FaceUv, color: Rgb) -> Rgb {
    let FaceUv { u, v, seed, .. } = *f;
    let k = 0.96
        + 0.06 * fbm2(u * 1.5, v * 1.5, seed, 2)
        + 0.025 * noise2(u * 90.0, v * 90.0, seed ^ 1);
    scale(color, k)
}

/// Brick courses in running bond with mortar joints.
fn brick(f: &FaceUv, color: Rgb, mortar: Rgb) -> Rgb {
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
fn planks(f: &FaceUv, color: Rgb) -> Rgb {
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
fn tiles(f: &FaceUv, color: Rgb, grout: Rgb, size: f32, checker: bool) -> Rgb {
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
fn carpet(f: &FaceUv, color: Rgb, pattern: bool) -> Rgb {
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
fn wood(f: &FaceUv, color: Rgb) -> Rgb {
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
fn fabric(f: &FaceUv, color: Rgb) -> Rgb {
    let FaceUv { u, v, seed, .. } = *f;
    let weave = ((u * 400.0).ff() as i32 + (v * 400.0).ff() as i32) & 1;
    let k = 0.9
        + 0.05 * weave as f32
        + 0.12 * fbm2(u * 8.0, v * 8.0, seed, 2)
        + 0.06 * noise2(u * 150.0, v * 150.0, seed ^ 9);
    scale(color, k)
}

/// Curtain fabric shaded by vertical folds.
fn curtain(f: &FaceUv, color: Rgb) -> Rgb {
    let FaceUv { u, v, seed, .. } = *f;
    let fold = (u / 0.11 + 0.3 * noise1(v * 2.0, seed)).fr();
    let tri = 1.0 - (2.0 * fold - 1.0).abs();
    let k = 0.62 + 0.45 * tri * tri * (3.0 - 2.0 * tri) + 0.06 * noise2(u * 200.0, v * 200.0, seed);
    scale(color, k)
}

/// A picture in its frame; the picture itself only on the front.
fn framed_picture(f: &FaceUv, frame: Rgb) -> Rgb {
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
fn book(ctx: &TexCtx, f: &FaceUv, color: Rgb) -> Rgb {
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
fn screen_surface(f: &FaceUv, on: bool) -> Surface {
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
fn window_surface(ctx: &TexCtx, f: &FaceUv, frame: Rgb) -> Surface {
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
fn paper(ctx: &TexCtx, f: &FaceUv) -> Rgb {
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
fn whiteboard(f: &FaceUv) -> Rgb {
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
fn drawers(f: &FaceUv, color: Rgb, rows: u8, cols: u8, wood_: bool) -> Rgb {
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
fn door(ctx: &TexCtx, f: &FaceUv, color: Rgb) -> Rgb {
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

/// A picture's content at normalised coordinates (`t` upwards).
fn picture(s: f32, t: f32, seed: u32) -> Rgb {
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
fn screen(s: f32, t: f32, seed: u32) -> Rgb {
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
fn outdoor(dir: &V3, seed: u32) -> Rgb {
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
