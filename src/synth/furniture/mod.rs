//! Furniture and wall fixtures built from boxes and cylinders, each part with its
//! NYU40 label (following the NYU 894 -> 40 mapping: monitors, keyboards, plants,
//! vases are `otherprop`; door and window frames and ceiling lights are
//! `otherstructure`; headboards `otherfurniture`).
//!
//! An item is built in a local frame: `x` along the wall (centred on 0), `y` out
//! of the wall into the room (the wall face is `y = 0`), `z` up from the floor.
//! [`Builder::try_wall`] and [`Builder::try_centre`] then place it in the room
//! where it fits without overlapping what is already there.

use super::geom::{Shape, Solid, V3};
use super::scene::{Room, yaw};
use super::texture::{Material, Rgb};
use parts::{BOOKS, FABRICS, WOODS};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

mod fixtures;
mod living;
mod parts;
mod storage;

pub use fixtures::*;
pub use living::*;
pub use storage::*;

/// A local frame on the floor: origin and yaw `(c, s)` about `z`.
#[derive(Debug, Clone, Copy)]
pub struct Place {
    /// Origin, metres.
    pub o: V3,
    /// Cosine of the yaw.
    pub c: f32,
    /// Sine of the yaw.
    pub s: f32,
}

impl Place {
    /// A frame at `o` with yaw cosine `c` and sine `s`.
    pub fn new(o: V3, c: f32, s: f32) -> Self {
        Place { o, c, s }
    }

    /// World position of a local point.
    pub fn world(&self, l: V3) -> V3 {
        V3::new(
            self.o.x + self.c * l.x - self.s * l.y,
            self.o.y + self.s * l.x + self.c * l.y,
            self.o.z + l.z,
        )
    }

    /// A sub-frame at a local point, turned by a further yaw.
    pub fn sub(&self, at: [f32; 3], c: f32, s: f32) -> Place {
        Place::new(
            self.world(V3::from(at)),
            self.c * c - self.s * s,
            self.s * c + self.c * s,
        )
    }

    fn apply(&self, s: &Solid) -> Solid {
        Solid {
            center: self.world(s.center),
            cos: self.c * s.cos - self.s * s.sin,
            sin: self.s * s.cos + self.c * s.sin,
            ..s.clone()
        }
    }
}

/// Parts of one item, in its local frame.
#[derive(Debug, Clone, Default)]
pub struct Group {
    /// The item's parts.
    pub solids: Vec<Solid>,
    /// Points a camera may look at.
    pub interest: Vec<V3>,
    /// Points with much to see (desks, shelves, beds...): preferred targets.
    pub focus: Vec<V3>,
    /// Lamp light positions.
    pub lamps: Vec<V3>,
    /// Extra space to keep free (door swing), local bounds.
    pub reserve: Option<(V3, V3)>,
    /// Not counted as an obstacle for later placements (rugs).
    pub flat: bool,
}

impl Group {
    /// A box part: centre and full size in the frame `p`.
    pub fn bx(
        &mut self,
        p: &Place,
        c: [f32; 3],
        size: [f32; 3],
        label: u8,
        material: Material,
        seed: u32,
    ) {
        let s = Solid {
            shape: Shape::Box,
            center: V3::from(c),
            half: V3::from(size) * 0.5,
            cos: 1.0,
            sin: 0.0,
            label,
            material,
            seed,
        };
        self.solids.push(p.apply(&s));
    }

    /// A vertical cylinder part standing on `z0`.
    #[allow(clippy::too_many_arguments)]
    pub fn cyl(
        &mut self,
        p: &Place,
        x: f32,
        y: f32,
        z0: f32,
        r: f32,
        h: f32,
        label: u8,
        material: Material,
        seed: u32,
    ) {
        let s = Solid {
            shape: Shape::Cylinder,
            center: V3::new(x, y, z0 + h * 0.5),
            half: V3::new(r, r, h * 0.5),
            cos: 1.0,
            sin: 0.0,
            label,
            material,
            seed,
        };
        self.solids.push(p.apply(&s));
    }

    fn bounds(&self) -> (V3, V3) {
        let mut min = V3::repeat(f32::MAX);
        let mut max = V3::repeat(f32::MIN);
        for s in &self.solids {
            let (a, b) = s.bounds();
            min = min.inf(&a);
            max = max.sup(&b);
        }
        (min, max)
    }
}

/// Builds a room's contents with one random stream.
pub struct Builder<'a> {
    /// The random stream every choice draws from.
    pub rng: &'a mut ChaCha8Rng,
    /// The room being furnished.
    pub room: Room,
    /// How many optional items and props, in `[0, 1]`.
    pub clutter: f32,
    shell: Vec<Solid>,
    solids: Vec<Solid>,
    occupied: Vec<(V3, V3)>,
    interest: Vec<V3>,
    focus: Vec<V3>,
    lamps: Vec<V3>,
}

/// What a [`Builder`] made.
pub struct Built {
    /// Floor, ceiling and wall slabs.
    pub shell: Vec<Solid>,
    /// Everything else.
    pub solids: Vec<Solid>,
    /// World points a camera may look at.
    pub interest: Vec<V3>,
    /// World points with much to see: preferred camera targets.
    pub focus: Vec<V3>,
    /// World positions of lamp lights.
    pub lamps: Vec<V3>,
}

/// An item builder.
pub type Item = fn(&mut Builder) -> Group;

fn overlap(a: &(V3, V3), b: &(V3, V3), m: f32) -> bool {
    (0..3).all(|k| a.0[k] < b.1[k] + m && b.0[k] < a.1[k] + m)
}

impl<'a> Builder<'a> {
    /// A builder for an empty room; the L-shaped room's notch is already occupied.
    pub fn new(rng: &'a mut ChaCha8Rng, room: Room, clutter: f32) -> Self {
        let occupied = room
            .notch
            .map(|[x0, y0, x1, y1]| (V3::new(x0, y0, 0.0), V3::new(x1, y1, room.height)))
            .into_iter()
            .collect();
        Builder {
            rng,
            room,
            clutter,
            shell: Vec::new(),
            solids: Vec::new(),
            occupied,
            interest: Vec::new(),
            focus: Vec::new(),
            lamps: Vec::new(),
        }
    }

    /// A uniform number in `[lo, hi)`.
    pub fn r(&mut self, lo: f32, hi: f32) -> f32 {
        if hi <= lo {
            lo
        } else {
            self.rng.random_range(lo..hi)
        }
    }

    /// True with probability `p` (clamped to [0, 1]).
    pub fn chance(&mut self, p: f32) -> bool {
        self.rng.random_bool(p.clamp(0.0, 1.0) as f64)
    }

    /// A uniformly chosen colour of `palette`.
    pub fn pick(&mut self, palette: &[Rgb]) -> Rgb {
        palette[self.rng.random_range(0..palette.len())]
    }

    /// A fresh texture seed.
    pub fn seed(&mut self) -> u32 {
        self.rng.random()
    }

    /// Adds a floor, ceiling or wall slab (tested against every ray, not in
    /// the hierarchy, never an obstacle for placement).
    pub fn shell_solid(&mut self, s: Solid) {
        self.shell.push(s);
    }

    /// Adds a fixed part of the room (skirting, ceiling lamps) that is not an
    /// obstacle for placement.
    pub fn fixture(&mut self, s: Solid) {
        self.solids.push(s);
    }

    /// Everything built.
    pub fn finish(self) -> Built {
        Built {
            shell: self.shell,
            solids: self.solids,
            interest: self.interest,
            focus: self.focus,
            lamps: self.lamps,
        }
    }

    fn commit(&mut self, g: &Group, p: &Place) -> bool {
        let world: Vec<Solid> = g.solids.iter().map(|s| p.apply(s)).collect();
        let mut bb = (V3::repeat(f32::MAX), V3::repeat(f32::MIN));
        for s in &world {
            let (a, b) = s.bounds();
            bb = (bb.0.inf(&a), bb.1.sup(&b));
        }
        let mut boxes = vec![bb];
        if let Some((a, b)) = g.reserve {
            let (wa, wb) = (p.world(a), p.world(b));
            boxes.push((wa.inf(&wb), wa.sup(&wb)));
        }
        for (a, b) in &boxes {
            let inside = [(a.x, a.y), (a.x, b.y), (b.x, a.y), (b.x, b.y)]
                .iter()
                .all(|&(x, y)| self.room.contains(x, y, -0.001));
            if !inside || b.z > self.room.height - 0.02 {
                return false;
            }
        }
        if !g.flat
            && boxes
                .iter()
                .any(|bx| self.occupied.iter().any(|o| overlap(bx, o, 0.03)))
        {
            return false;
        }
        if !g.flat {
            self.occupied.extend(boxes);
        }
        self.solids.extend(world);
        self.interest
            .extend(g.interest.iter().chain(&g.focus).map(|&v| p.world(v)));
        self.focus.extend(g.focus.iter().map(|&v| p.world(v)));
        self.lamps.extend(g.lamps.iter().map(|&v| p.world(v)));
        true
    }

    /// Builds an item and places it against a random wall, at least `margin`
    /// metres from the wall's ends. Returns whether it found room.
    /// The item is rebuilt (other random sizes) every ten failed tries.
    pub fn try_wall(&mut self, item: Item, margin: f32, tries: usize) -> bool {
        let mut g = item(self);
        let (mut min, mut max) = g.bounds();
        let total: f32 = self.room.walls.iter().map(|w| w.len).sum();
        for attempt in 0..tries {
            if attempt > 0 && attempt % 10 == 0 {
                g = item(self);
                (min, max) = g.bounds();
            }
            let mut pick = self.r(0.0, total);
            let mut wall = self.room.walls[0];
            for w in &self.room.walls {
                wall = *w;
                if pick < w.len {
                    break;
                }
                pick -= w.len;
            }
            let (lo, hi) = (margin - min.x, wall.len - margin - max.x);
            if hi < lo {
                continue;
            }
            let s = self.r(lo, hi);
            if self.commit(&g, &wall.place(s, 0.0)) {
                return true;
            }
        }
        false
    }

    /// Builds an item and places it freely in the room, turned by a small angle.
    pub fn try_centre(&mut self, item: Item, tries: usize) -> bool {
        let g = item(self);
        let (min, max) = g.bounds();
        let reach = (max.x - min.x).max(max.y - min.y) * 0.5;
        for _ in 0..tries {
            let x = self.r(0.4 + reach, self.room.width - 0.4 - reach);
            let y = self.r(0.4 + reach, self.room.depth - 0.4 - reach);
            let quarter = self.rng.random_range(0..4) as f64 * std::f64::consts::FRAC_PI_2;
            let (c, s) = yaw(quarter + self.r(-0.25, 0.25) as f64);
            if self.commit(&g, &Place::new(V3::new(x, y, 0.0), c, s)) {
                return true;
            }
        }
        false
    }

    fn wood(&mut self) -> Material {
        let color = self.pick(&WOODS);
        Material::Wood { color }
    }

    fn fabric(&mut self) -> Material {
        let color = self.pick(&FABRICS);
        Material::Fabric { color }
    }

    fn book_color(&mut self) -> Rgb {
        let c = self.pick(&BOOKS);
        let k = self.r(0.7, 1.15);
        [c[0] * k, c[1] * k, c[2] * k]
    }

    fn yaw_jitter(&mut self, a: f32) -> (f32, f32) {
        let v = self.r(-a, a) as f64;
        yaw(v)
    }
}
