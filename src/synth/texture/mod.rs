//! Procedural materials: every surface's albedo (and emission for screens, lamps
//! and the view through windows) is a function of the hit point in the solid's
//! local frame, built from integer-hash noise ([`super::detmath`]) so it is the
//! same on every machine. Colours are linear reflectances in `[0, 1]`.

mod images;
mod surfaces;

use super::detmath::{FastFloor, fbm2, noise2};
use super::geom::{Face, V3};
use surfaces::{
    book, brick, carpet, curtain, door, drawers, fabric, framed_picture, paint, paper, planks,
    screen_surface, tiles, whiteboard, window_surface, wood,
};

/// A linear colour.
pub type Rgb = [f32; 3];

/// Linear reflectance of an 8-bit display colour (gamma 2 approximation, the
/// inverse of the renderer's output encoding).
pub(crate) const fn srgb(r: u8, g: u8, b: u8) -> Rgb {
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
