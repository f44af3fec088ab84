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
use super::texture::{Material, Rgb, srgb};
use crate::classes::label;
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

/// A local frame on the floor: origin and yaw `(c, s)` about `z`.
#[derive(Debug, Clone, Copy)]
pub struct Place {
    pub o: V3,
    pub c: f32,
    pub s: f32,
}

impl Place {
    pub fn new(o: V3, c: f32, s: f32) -> Self {
        Place { o, c, s }
    }

    pub fn identity() -> Self {
        Place::new(V3::zeros(), 1.0, 0.0)
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
    pub rng: &'a mut ChaCha8Rng,
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
    pub interest: Vec<V3>,
    pub focus: Vec<V3>,
    pub lamps: Vec<V3>,
}

/// An item builder.
pub type Item = fn(&mut Builder) -> Group;

fn overlap(a: &(V3, V3), b: &(V3, V3), m: f32) -> bool {
    (0..3).all(|k| a.0[k] < b.1[k] + m && b.0[k] < a.1[k] + m)
}

impl<'a> Builder<'a> {
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

    pub fn chance(&mut self, p: f32) -> bool {
        self.rng.random_bool(p.clamp(0.0, 1.0) as f64)
    }

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

    fn commit(&mut self, g: Group, p: &Place) -> bool {
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
            if self.commit(g.clone(), &wall.place(s, 0.0)) {
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
            if self.commit(g.clone(), &Place::new(V3::new(x, y, 0.0), c, s)) {
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

const WOODS: [Rgb; 6] = [
    srgb(190, 145, 95),
    srgb(150, 100, 60),
    srgb(110, 70, 45),
    srgb(215, 185, 140),
    srgb(90, 60, 40),
    srgb(170, 120, 80),
];

const FABRICS: [Rgb; 9] = [
    srgb(110, 120, 140),
    srgb(150, 60, 55),
    srgb(80, 110, 80),
    srgb(200, 190, 170),
    srgb(70, 70, 75),
    srgb(170, 140, 100),
    srgb(60, 80, 130),
    srgb(190, 120, 60),
    srgb(130, 100, 140),
];

const PAINTED: [Rgb; 6] = [
    srgb(240, 240, 236),
    srgb(60, 60, 62),
    srgb(200, 205, 210),
    srgb(150, 170, 160),
    srgb(225, 215, 195),
    srgb(40, 60, 90),
];

const BOOKS: [Rgb; 12] = [
    srgb(150, 30, 30),
    srgb(30, 50, 120),
    srgb(30, 90, 50),
    srgb(200, 170, 60),
    srgb(40, 40, 40),
    srgb(220, 220, 210),
    srgb(120, 60, 30),
    srgb(90, 40, 100),
    srgb(200, 90, 40),
    srgb(60, 130, 150),
    srgb(170, 150, 120),
    srgb(200, 60, 90),
];

const L: Place = Place {
    o: V3::new(0.0, 0.0, 0.0),
    c: 1.0,
    s: 0.0,
};

/// Books standing on a shelf between `x0` and `x1`, spines flush with `front`.
#[allow(clippy::too_many_arguments)]
fn book_row(
    b: &mut Builder,
    g: &mut Group,
    p: &Place,
    x0: f32,
    x1: f32,
    z: f32,
    max_h: f32,
    front: f32,
    max_d: f32,
) {
    let mut x = x0 + b.r(0.0, 0.04);
    while x < x1 - 0.02 {
        if b.chance(0.06) {
            x += b.r(0.03, 0.12);
            continue;
        }
        if b.chance(0.05) && x1 - x > 0.3 {
            // A lying stack.
            let (w, d) = (b.r(0.17, 0.26), b.r(0.13, max_d.max(0.14)));
            let mut zz = z;
            for _ in 0..b.rng.random_range(2..6) {
                let t = b.r(0.02, 0.045);
                if zz + t > z + max_h {
                    break;
                }
                let color = b.book_color();
                let s = b.seed();
                g.bx(
                    p,
                    [x + w * 0.5, front - d * 0.5, zz + t * 0.5],
                    [w, d, t],
                    label::BOOKS,
                    Material::Book { color },
                    s,
                );
                zz += t;
            }
            x += w + 0.01;
            continue;
        }
        let t = b.r(0.018, 0.055);
        if x + t > x1 {
            break;
        }
        let h = b.r(0.16, max_h.clamp(0.17, 0.32));
        let d = b.r(0.12, max_d.max(0.13));
        let color = b.book_color();
        let s = b.seed();
        g.bx(
            p,
            [x + t * 0.5, front - d * 0.5, z + h * 0.5],
            [t, d, h],
            label::BOOKS,
            Material::Book { color },
            s,
        );
        x += t + 0.001;
    }
}

/// Small things to put on a surface at height `z` within `[x0, x1] x [y0, y1]`.
#[allow(clippy::too_many_arguments)]
fn props(b: &mut Builder, g: &mut Group, x0: f32, x1: f32, y0: f32, y1: f32, z: f32, n: usize) {
    let mut taken: Vec<(f32, f32)> = Vec::new();
    for _ in 0..n {
        // A spot at least 0.3 m from the other props, if one is found.
        let mut spot = None;
        for _ in 0..8 {
            let (x, y) = (b.r(x0 + 0.1, x1 - 0.1), b.r(y0 + 0.08, y1 - 0.08));
            if taken
                .iter()
                .all(|&(u, v)| (u - x) * (u - x) + (v - y) * (v - y) > 0.09)
            {
                spot = Some((x, y));
                break;
            }
        }
        let Some((x, y)) = spot else {
            continue;
        };
        taken.push((x, y));
        let (c, s) = b.yaw_jitter(0.6);
        let p = L.sub([x, y, z], c, s);
        let seed = b.seed();
        match b.rng.random_range(0..7) {
            0 => {
                let (w, d, h) = (b.r(0.15, 0.35), b.r(0.12, 0.3), b.r(0.08, 0.25));
                g.bx(
                    &p,
                    [0.0, 0.0, h * 0.5],
                    [w, d, h],
                    label::BOX,
                    Material::Cardboard,
                    seed,
                );
            }
            1 => {
                let color = b.pick(&[
                    srgb(200, 80, 60),
                    srgb(60, 90, 160),
                    srgb(220, 220, 210),
                    srgb(60, 140, 90),
                ]);
                let (r, h) = (b.r(0.035, 0.07), b.r(0.1, 0.3));
                g.cyl(
                    &p,
                    0.0,
                    0.0,
                    0.0,
                    r,
                    h,
                    label::OTHER_PROP,
                    Material::Plastic { color },
                    seed,
                );
            }
            2 => {
                g.bx(
                    &p,
                    [0.0, 0.0, 0.001],
                    [0.21, 0.297, 0.002],
                    label::PAPER,
                    Material::Paper,
                    seed,
                );
                if b.chance(0.5) {
                    g.bx(
                        &p,
                        [0.01, 0.01, 0.003],
                        [0.21, 0.297, 0.002],
                        label::PAPER,
                        Material::Paper,
                        seed ^ 1,
                    );
                }
            }
            3 => {
                let mut zz = 0.0;
                for _ in 0..b.rng.random_range(1..4) {
                    let (w, d, t) = (b.r(0.15, 0.25), b.r(0.2, 0.3), b.r(0.02, 0.05));
                    let color = b.book_color();
                    let s = b.seed();
                    g.bx(
                        &p,
                        [0.0, 0.0, zz + t * 0.5],
                        [w, d, t],
                        label::BOOKS,
                        Material::Book { color },
                        s,
                    );
                    zz += t;
                }
            }
            4 => {
                g.cyl(
                    &p,
                    0.0,
                    0.0,
                    0.0,
                    0.07,
                    0.12,
                    label::OTHER_PROP,
                    Material::Plastic {
                        color: srgb(170, 90, 60),
                    },
                    seed,
                );
                g.cyl(
                    &p,
                    0.0,
                    0.0,
                    0.12,
                    0.1,
                    0.15,
                    label::OTHER_PROP,
                    Material::Foliage,
                    seed ^ 3,
                );
            }
            5 => {
                let color = b.pick(&FABRICS);
                g.bx(
                    &p,
                    [0.0, 0.0, 0.15],
                    [0.32, 0.15, 0.3],
                    label::BAG,
                    Material::Fabric { color },
                    seed,
                );
            }
            _ => {
                let color = b.pick(&[srgb(240, 240, 240), srgb(40, 40, 40), srgb(190, 60, 50)]);
                g.cyl(
                    &p,
                    0.0,
                    0.0,
                    0.0,
                    0.04,
                    0.1,
                    label::OTHER_PROP,
                    Material::Plastic { color },
                    seed,
                );
            }
        }
    }
}

/// A desk or bedside lamp standing at `(x, y, z)`, with its light.
fn table_lamp(b: &mut Builder, g: &mut Group, x: f32, y: f32, z: f32) {
    let s = b.seed();
    let metal = Material::Metal {
        color: srgb(180, 180, 185),
    };
    g.cyl(&L, x, y, z, 0.08, 0.02, label::LAMP, metal, s);
    g.cyl(&L, x, y, z + 0.02, 0.012, 0.3, label::LAMP, metal, s);
    let color = b.pick(&[
        srgb(240, 230, 200),
        srgb(230, 220, 210),
        srgb(250, 240, 220),
    ]);
    g.cyl(
        &L,
        x,
        y,
        z + 0.3,
        0.13,
        0.18,
        label::LAMP,
        Material::LampShade { color },
        s,
    );
    g.lamps.push(V3::new(x, y, z + 0.39));
}

/// A chair in frame `p`, the sitter facing `+y`.
fn chair(b: &mut Builder, g: &mut Group, p: &Place) {
    let office = b.chance(0.5);
    let seed = b.seed();
    let (w, seat) = (b.r(0.42, 0.5), b.r(0.44, 0.48));
    if office {
        let fabric = b.fabric();
        let dark = Material::Plastic {
            color: srgb(35, 35, 38),
        };
        for k in 0..5 {
            let (c, s) = yaw(k as f64 * 1.2566370614359172);
            g.bx(
                &p.sub([0.0, 0.0, 0.0], c, s),
                [0.0, 0.15, 0.03],
                [0.05, 0.3, 0.04],
                label::CHAIR,
                dark,
                seed,
            );
        }
        g.cyl(
            p,
            0.0,
            0.0,
            0.05,
            0.025,
            seat - 0.1,
            label::CHAIR,
            Material::Metal {
                color: srgb(150, 150, 155),
            },
            seed,
        );
        g.bx(
            p,
            [0.0, 0.0, seat - 0.04],
            [w, w, 0.08],
            label::CHAIR,
            fabric,
            seed,
        );
        g.bx(
            p,
            [0.0, -w * 0.5 + 0.03, seat + 0.32],
            [w * 0.95, 0.06, 0.5],
            label::CHAIR,
            fabric,
            seed ^ 1,
        );
        g.bx(
            p,
            [0.0, -w * 0.5 + 0.01, seat + 0.1],
            [0.05, 0.03, 0.22],
            label::CHAIR,
            dark,
            seed,
        );
    } else {
        let wood = b.wood();
        let leg = 0.035;
        for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
            let (x, y) = (sx * (w * 0.5 - leg), sy * (w * 0.5 - leg));
            g.bx(
                p,
                [x, y, (seat - 0.04) * 0.5],
                [leg, leg, seat - 0.04],
                label::CHAIR,
                wood,
                seed,
            );
        }
        g.bx(
            p,
            [0.0, 0.0, seat - 0.02],
            [w, w, 0.04],
            label::CHAIR,
            wood,
            seed,
        );
        for sx in [-1.0, 1.0] {
            g.bx(
                p,
                [sx * (w * 0.5 - leg), -w * 0.5 + leg, seat + 0.22],
                [leg, leg, 0.44],
                label::CHAIR,
                wood,
                seed,
            );
        }
        g.bx(
            p,
            [0.0, -w * 0.5 + leg, seat + 0.36],
            [w, 0.025, 0.14],
            label::CHAIR,
            wood,
            seed ^ 2,
        );
        if b.chance(0.5) {
            let fabric = b.fabric();
            g.bx(
                p,
                [0.0, 0.01, seat + 0.015],
                [w - 0.06, w - 0.08, 0.03],
                label::CHAIR,
                fabric,
                seed ^ 3,
            );
        }
    }
}

/// A door with its frame and handle; keeps its swing area free.
pub fn door(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, h) = (b.r(0.8, 0.92), b.r(2.0, 2.1));
    let color = b.pick(&[
        srgb(245, 245, 240),
        srgb(170, 120, 80),
        srgb(120, 80, 55),
        srgb(220, 215, 205),
    ]);
    let frame = Material::Plastic {
        color: srgb(235, 235, 230),
    };
    let s = b.seed();
    g.bx(
        &L,
        [0.0, 0.025, h * 0.5],
        [w, 0.04, h],
        label::DOOR,
        Material::Door { color },
        s,
    );
    g.bx(
        &L,
        [-w * 0.5 - 0.035, 0.015, (h + 0.07) * 0.5],
        [0.07, 0.03, h + 0.07],
        label::OTHER_STRUCTURE,
        frame,
        s,
    );
    g.bx(
        &L,
        [w * 0.5 + 0.035, 0.015, (h + 0.07) * 0.5],
        [0.07, 0.03, h + 0.07],
        label::OTHER_STRUCTURE,
        frame,
        s,
    );
    g.bx(
        &L,
        [0.0, 0.015, h + 0.035],
        [w, 0.03, 0.07],
        label::OTHER_STRUCTURE,
        frame,
        s,
    );
    let side = if b.chance(0.5) { 1.0 } else { -1.0 };
    let metal = Material::Metal {
        color: srgb(190, 190, 195),
    };
    g.bx(
        &L,
        [side * (w * 0.5 - 0.09), 0.07, 1.0],
        [0.13, 0.05, 0.022],
        label::DOOR,
        metal,
        s,
    );
    g.reserve = Some((V3::new(-w * 0.5, 0.0, 0.0), V3::new(w * 0.5, w + 0.1, h)));
    g.interest.push(V3::new(0.0, 0.05, 1.5));
    g
}

/// A window (frame, glass showing the outdoors, sill), maybe with curtains or blinds.
pub fn window(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, z0) = (b.r(0.8, 1.7), b.r(0.75, 1.0));
    let h = b.r(1.0, 1.45).min(b.room.height - 0.25 - z0);
    let frame = b.pick(&[srgb(245, 245, 245), srgb(235, 235, 230), srgb(150, 105, 70)]);
    let s = b.seed();
    g.bx(
        &L,
        [0.0, 0.02, z0 + h * 0.5],
        [w, 0.04, h],
        label::WINDOW,
        Material::Window { frame },
        s,
    );
    g.bx(
        &L,
        [0.0, 0.07, z0 - 0.02],
        [w + 0.12, 0.14, 0.04],
        label::WINDOW,
        Material::Plastic { color: frame },
        s,
    );
    match b.rng.random_range(0..10) {
        0..=3 => {
            let color = b.pick(&FABRICS);
            let top = (z0 + h + 0.15).min(b.room.height - 0.05);
            let bottom = if b.chance(0.5) { 0.02 } else { z0 - 0.15 };
            for side in [-1.0, 1.0] {
                let cw = b.r(0.25, 0.45);
                let x = side * (w * 0.5 + cw * 0.5 - 0.12);
                let s = b.seed();
                g.bx(
                    &L,
                    [x, 0.11, (top + bottom) * 0.5],
                    [cw, 0.06, top - bottom],
                    label::CURTAIN,
                    Material::Curtain { color },
                    s,
                );
            }
        }
        4..=6 => {
            let color = b.pick(&[
                srgb(240, 240, 235),
                srgb(225, 215, 190),
                srgb(200, 200, 200),
            ]);
            let bh = h * b.r(0.15, 0.7);
            g.bx(
                &L,
                [0.0, 0.055, z0 + h - bh * 0.5],
                [w - 0.04, 0.02, bh],
                label::BLINDS,
                Material::Blinds { color },
                s ^ 1,
            );
        }
        _ => {}
    }
    g.interest.push(V3::new(0.0, 0.1, z0 + h * 0.5));
    g
}

/// A framed picture or poster.
pub fn picture(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let w = b.r(0.3, 1.1);
    let h = (w * b.r(0.6, 1.4)).clamp(0.25, 0.9);
    let zc = b.r(1.35, 1.75).min(b.room.height - 0.2 - h * 0.5);
    let frame = b.pick(&[
        srgb(30, 30, 30),
        srgb(150, 105, 70),
        srgb(240, 240, 240),
        srgb(190, 160, 90),
    ]);
    let s = b.seed();
    g.bx(
        &L,
        [0.0, 0.015, zc],
        [w, 0.025, h],
        label::PICTURE,
        Material::Picture { frame },
        s,
    );
    g.interest.push(V3::new(0.0, 0.03, zc));
    g
}

/// A whiteboard with its marker tray.
pub fn whiteboard(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, h, z0) = (b.r(1.2, 2.0), b.r(0.85, 1.2), b.r(0.85, 1.0));
    let s = b.seed();
    g.bx(
        &L,
        [0.0, 0.012, z0 + h * 0.5],
        [w, 0.02, h],
        label::WHITEBOARD,
        Material::Whiteboard,
        s,
    );
    g.bx(
        &L,
        [0.0, 0.04, z0 - 0.01],
        [w * 0.6, 0.06, 0.02],
        label::WHITEBOARD,
        Material::Metal {
            color: srgb(180, 182, 185),
        },
        s,
    );
    g.interest.push(V3::new(0.0, 0.03, z0 + h * 0.5));
    g
}

/// A bookshelf full of books (and the odd box).
pub fn bookshelf(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d) = (b.r(0.7, 1.25), b.r(0.28, 0.38));
    let h = b.r(1.5, 2.1).min(b.room.height - 0.3);
    let wood = if b.chance(0.7) {
        b.wood()
    } else {
        Material::Plastic {
            color: b.pick(&PAINTED),
        }
    };
    let (t, y0) = (0.022, 0.02);
    let s = b.seed();
    let yc = y0 + d * 0.5;
    for sx in [-1.0, 1.0] {
        g.bx(
            &L,
            [sx * (w - t) * 0.5, yc, h * 0.5],
            [t, d, h],
            label::BOOKSHELF,
            wood,
            s,
        );
    }
    g.bx(
        &L,
        [0.0, y0 + 0.005, h * 0.5],
        [w - 2.0 * t, 0.01, h],
        label::BOOKSHELF,
        wood,
        s ^ 1,
    );
    g.bx(
        &L,
        [0.0, yc, h - t * 0.5],
        [w - 2.0 * t, d, t],
        label::BOOKSHELF,
        wood,
        s,
    );
    g.bx(
        &L,
        [0.0, yc, 0.04],
        [w - 2.0 * t, d, 0.08],
        label::BOOKSHELF,
        wood,
        s,
    );
    let levels = ((h - 0.1) / 0.34).floor().max(2.0) as usize;
    let step = (h - 0.08 - t) / levels as f32;
    for k in 0..levels {
        let z = 0.08 + k as f32 * step;
        if k > 0 {
            g.bx(
                &L,
                [0.0, yc, z - t * 0.5],
                [w - 2.0 * t, d - 0.01, t],
                label::BOOKSHELF,
                wood,
                s ^ 2,
            );
        }
        let (x0, x1) = (-w * 0.5 + t, w * 0.5 - t);
        if b.chance(0.12) {
            // A box and a few books.
            let bw = b.r(0.2, 0.35).min(x1 - x0 - 0.05);
            let bh = (step - t - 0.03).min(0.25);
            let s = b.seed();
            g.bx(
                &L,
                [x1 - bw * 0.5 - 0.01, yc + 0.01, z + bh * 0.5],
                [bw, d - 0.05, bh],
                label::BOX,
                Material::Cardboard,
                s,
            );
            book_row(
                b,
                &mut g,
                &L,
                x0,
                x1 - bw - 0.03,
                z,
                step - t - 0.02,
                y0 + d - 0.005,
                d - 0.03,
            );
        } else {
            book_row(
                b,
                &mut g,
                &L,
                x0,
                x1,
                z,
                step - t - 0.02,
                y0 + d - 0.005,
                d - 0.03,
            );
        }
    }
    g.focus.push(V3::new(0.0, y0 + d, h * 0.55));
    g.focus.push(V3::new(0.0, y0 + d, h * 0.3));
    g
}

/// Open shelves with boxes, books and props.
pub fn shelves(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d, h) = (b.r(0.8, 1.4), b.r(0.3, 0.45), b.r(1.2, 1.9));
    let metal = b.chance(0.5);
    let frame = if metal {
        Material::Metal {
            color: srgb(160, 162, 165),
        }
    } else {
        b.wood()
    };
    let board = if metal {
        Material::Plastic {
            color: b.pick(&PAINTED),
        }
    } else {
        frame
    };
    let s = b.seed();
    let y0 = 0.02;
    for (sx, sy) in [(-1.0, 0.0), (1.0, 0.0), (-1.0, 1.0), (1.0, 1.0)] {
        g.bx(
            &L,
            [
                sx * (w * 0.5 - 0.015),
                y0 + 0.015 + sy * (d - 0.03),
                h * 0.5,
            ],
            [0.03, 0.03, h],
            label::SHELVES,
            frame,
            s,
        );
    }
    let levels = b.rng.random_range(3..6);
    for k in 0..levels {
        let z = 0.1 + k as f32 * (h - 0.12) / (levels - 1) as f32;
        g.bx(
            &L,
            [0.0, y0 + d * 0.5, z - 0.01],
            [w - 0.06, d, 0.02],
            label::SHELVES,
            board,
            s ^ 1,
        );
        if k + 1 < levels {
            let n = b.rng.random_range(1..4);
            if b.chance(0.4) {
                let gap = (h - 0.12) / (levels - 1) as f32 - 0.04;
                let x1 = b.r(-0.1, w * 0.4);
                book_row(
                    b,
                    &mut g,
                    &L,
                    -w * 0.5 + 0.04,
                    x1,
                    z,
                    gap,
                    y0 + d - 0.01,
                    d - 0.04,
                );
            } else {
                props(b, &mut g, -w * 0.5 + 0.03, w * 0.5 - 0.03, y0, y0 + d, z, n);
            }
        }
    }
    g.focus.push(V3::new(0.0, y0 + d, h * 0.5));
    g
}

/// A low cabinet with drawers, or a tall one with doors, props on top.
pub fn cabinet(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let tall = b.chance(0.35);
    let (w, d) = (b.r(0.6, 1.2), b.r(0.4, 0.6));
    let h = if tall { b.r(1.6, 2.0) } else { b.r(0.7, 0.95) };
    let wood = b.chance(0.5);
    let color = if wood {
        b.pick(&WOODS)
    } else {
        b.pick(&PAINTED)
    };
    let (rows, cols) = if tall {
        (1, 2)
    } else {
        (b.rng.random_range(1..4), if w > 0.8 { 2 } else { 1 })
    };
    let s = b.seed();
    g.bx(
        &L,
        [0.0, 0.02 + d * 0.5, h * 0.5],
        [w, d, h],
        label::CABINET,
        Material::Drawers {
            color,
            rows,
            cols,
            wood,
        },
        s,
    );
    if !tall {
        let n = (b.clutter * 3.0) as usize + 1;
        props(b, &mut g, -w * 0.5, w * 0.5, 0.02, 0.02 + d, h, n);
        if b.chance(0.3) {
            table_lamp(b, &mut g, w * 0.3, 0.02 + d * 0.5, h);
        }
    }
    g.interest.push(V3::new(0.0, 0.02 + d, h * 0.7));
    g
}

/// A wardrobe: a tall two-door cabinet.
pub fn wardrobe(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d) = (b.r(0.9, 1.6), b.r(0.55, 0.62));
    let h = b.r(1.9, 2.15).min(b.room.height - 0.15);
    let wood = b.chance(0.6);
    let color = if wood {
        b.pick(&WOODS)
    } else {
        b.pick(&PAINTED)
    };
    let s = b.seed();
    let cols = if w > 1.2 { 3 } else { 2 };
    g.bx(
        &L,
        [0.0, 0.02 + d * 0.5, h * 0.5],
        [w, d, h],
        label::CABINET,
        Material::Drawers {
            color,
            rows: 1,
            cols,
            wood,
        },
        s,
    );
    g.interest.push(V3::new(0.0, 0.02 + d, h * 0.6));
    g
}

/// A chest of drawers with a mirror above it.
pub fn dresser(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d, h) = (b.r(0.9, 1.5), b.r(0.42, 0.55), b.r(0.75, 1.0));
    let color = b.pick(&WOODS);
    let s = b.seed();
    let rows = b.rng.random_range(3..5);
    g.bx(
        &L,
        [0.0, 0.02 + d * 0.5, h * 0.5],
        [w, d, h],
        label::DRESSER,
        Material::Drawers {
            color,
            rows,
            cols: 2,
            wood: true,
        },
        s,
    );
    if b.chance(0.6) {
        let (mw, mh) = (w * b.r(0.5, 0.8), b.r(0.5, 0.8));
        g.bx(
            &L,
            [0.0, 0.012, h + 0.15 + mh * 0.5],
            [mw, 0.02, mh],
            label::MIRROR,
            Material::Mirror,
            s ^ 1,
        );
    }
    let n = b.rng.random_range(1..4);
    props(b, &mut g, -w * 0.5, w * 0.5, 0.02, 0.02 + d, h, n);
    g.focus.push(V3::new(0.0, 0.02 + d, h));
    g
}

/// A desk with monitor(s), keyboard, props, maybe a lamp and drawers, and a chair.
pub fn desk(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d, h) = (b.r(1.0, 1.6), b.r(0.6, 0.78), b.r(0.72, 0.76));
    let wood = b.chance(0.6);
    let top = if wood {
        b.wood()
    } else {
        Material::Plastic {
            color: b.pick(&PAINTED),
        }
    };
    let legs = Material::Metal {
        color: b.pick(&[srgb(60, 60, 62), srgb(190, 190, 195)]),
    };
    let s = b.seed();
    let y0 = 0.02;
    g.bx(
        &L,
        [0.0, y0 + d * 0.5, h - 0.015],
        [w, d, 0.03],
        label::DESK,
        top,
        s,
    );
    let pedestal = b.chance(0.5);
    for (sx, sy) in [(-1.0, 0.0), (1.0, 0.0), (-1.0, 1.0), (1.0, 1.0)] {
        if pedestal && sx > 0.0 {
            continue;
        }
        g.bx(
            &L,
            [
                sx * (w * 0.5 - 0.03),
                y0 + 0.03 + sy * (d - 0.06),
                (h - 0.03) * 0.5,
            ],
            [0.04, 0.04, h - 0.03],
            label::DESK,
            legs,
            s,
        );
    }
    if pedestal {
        let color = if wood {
            b.pick(&WOODS)
        } else {
            b.pick(&PAINTED)
        };
        g.bx(
            &L,
            [w * 0.5 - 0.22, y0 + d * 0.5, (h - 0.03) * 0.5],
            [0.42, d - 0.02, h - 0.03],
            label::DESK,
            Material::Drawers {
                color,
                rows: 3,
                cols: 1,
                wood,
            },
            s ^ 1,
        );
    }
    // Monitors (NYU "monitor" -> otherprop) or a television on a bigger desk.
    let screens = if w > 1.3 && b.chance(0.4) { 2 } else { 1 };
    let screen_label = if b.chance(0.25) {
        label::TELEVISION
    } else {
        label::OTHER_PROP
    };
    let dark = Material::Plastic {
        color: srgb(30, 30, 32),
    };
    for k in 0..screens {
        let x = if screens == 2 {
            (k as f32 - 0.5) * 0.58
        } else {
            b.r(-0.15, 0.15)
        };
        let (mw, mh) = (b.r(0.48, 0.6), b.r(0.3, 0.36));
        let (c, sn) = b.yaw_jitter(0.15);
        let p = L.sub([x, y0 + 0.2, h], c, sn);
        let on = b.chance(0.75);
        let s = b.seed();
        g.bx(
            &p,
            [0.0, 0.0, 0.008],
            [0.22, 0.16, 0.016],
            screen_label,
            dark,
            s,
        );
        g.bx(
            &p,
            [0.0, -0.02, 0.17],
            [0.05, 0.03, 0.32],
            screen_label,
            dark,
            s,
        );
        g.bx(
            &p,
            [0.0, 0.0, 0.12 + mh * 0.5],
            [mw, 0.03, mh],
            screen_label,
            Material::Screen { on },
            s,
        );
    }
    let s = b.seed();
    g.bx(
        &L,
        [b.r(-0.1, 0.1), y0 + 0.45, h + 0.012],
        [0.44, 0.14, 0.024],
        label::OTHER_PROP,
        dark,
        s,
    );
    g.bx(
        &L,
        [0.32, y0 + 0.45, h + 0.015],
        [0.06, 0.1, 0.03],
        label::OTHER_PROP,
        dark,
        s ^ 1,
    );
    let n = (b.clutter * 3.0) as usize + b.rng.random_range(0..2);
    props(
        b,
        &mut g,
        -w * 0.5,
        -w * 0.5 + 0.45,
        y0,
        y0 + d,
        h,
        n.min(3),
    );
    if b.chance(0.5) {
        table_lamp(b, &mut g, w * 0.5 - 0.15, y0 + 0.15, h);
    }
    // The chair, pulled up to the desk and facing it.
    let (c, sn) = yaw(std::f64::consts::PI + b.r(-0.5, 0.5) as f64);
    let cp = L.sub([b.r(-0.2, 0.2), y0 + d + b.r(0.05, 0.35), 0.0], c, sn);
    chair(b, &mut g, &cp);
    if b.chance(0.3 + 0.4 * b.clutter) {
        let s = b.seed();
        g.bx(
            &L,
            [-w * 0.5 + 0.25, y0 + 0.2, 0.15],
            [0.35, 0.3, 0.3],
            label::BOX,
            Material::Cardboard,
            s,
        );
    }
    g.focus.push(V3::new(0.0, y0 + d * 0.5, h + 0.1));
    g.focus.push(V3::new(0.0, y0 + 0.2, h + 0.3));
    g
}

/// A bed (frame, mattress, duvet, headboard, pillows) with night stands and lamps.
pub fn bed(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let double = b.chance(0.65);
    let w = if double {
        b.r(1.4, 1.8)
    } else {
        b.r(0.9, 1.05)
    };
    let l = b.r(1.95, 2.1);
    let wood = b.wood();
    let s = b.seed();
    let y0 = 0.02;
    g.bx(
        &L,
        [0.0, y0 + 0.06 + l * 0.5, 0.15],
        [w, l, 0.3],
        label::BED,
        wood,
        s,
    );
    g.bx(
        &L,
        [0.0, y0 + 0.06 + l * 0.5, 0.4],
        [w - 0.04, l - 0.04, 0.2],
        label::BED,
        Material::Fabric {
            color: srgb(235, 235, 230),
        },
        s ^ 1,
    );
    let duvet = b.fabric();
    let cover = b.r(0.55, 0.75);
    g.bx(
        &L,
        [0.0, y0 + 0.06 + l * (1.0 - cover * 0.5) + 0.01, 0.53],
        [w + 0.04, l * cover, 0.07],
        label::BED,
        duvet,
        s ^ 2,
    );
    let hh = b.r(0.8, 1.2);
    let head = if b.chance(0.5) { wood } else { b.fabric() };
    g.bx(
        &L,
        [0.0, y0 + 0.03, hh * 0.5],
        [w + 0.06, 0.06, hh],
        label::OTHER_FURNITURE,
        head,
        s ^ 3,
    );
    let pillow = if b.chance(0.6) {
        Material::Fabric {
            color: srgb(240, 240, 238),
        }
    } else {
        b.fabric()
    };
    let np = if double { 2 } else { 1 };
    for k in 0..np {
        let x = if np == 2 {
            (k as f32 - 0.5) * w * 0.5
        } else {
            0.0
        };
        let (c, sn) = b.yaw_jitter(0.12);
        let s = b.seed();
        let pw = (w / np as f32 - 0.12).min(0.7);
        g.bx(
            &L.sub([x, y0 + 0.3, 0.5], c, sn),
            [0.0, 0.0, 0.065],
            [pw, 0.34, 0.13],
            label::PILLOW,
            pillow,
            s,
        );
    }
    if b.chance(0.3) {
        let (c, sn) = b.yaw_jitter(0.8);
        let color = b.pick(&FABRICS);
        let s = b.seed();
        let x = b.r(-0.3, 0.3) * w;
        g.bx(
            &L.sub([x, y0 + l * 0.7, 0.56], c, sn),
            [0.0, 0.0, 0.02],
            [0.5, 0.4, 0.04],
            label::CLOTHES,
            Material::Fabric { color },
            s,
        );
    }
    let sides: &[f32] = if double || b.chance(0.5) {
        &[-1.0, 1.0]
    } else {
        &[1.0]
    };
    let ns = b.pick(&WOODS);
    for &sx in sides {
        let x = sx * (w * 0.5 + 0.06 + 0.23);
        let s = b.seed();
        g.bx(
            &L,
            [x, y0 + 0.21, 0.28],
            [0.46, 0.4, 0.56],
            label::NIGHT_STAND,
            Material::Drawers {
                color: ns,
                rows: 2,
                cols: 1,
                wood: true,
            },
            s,
        );
        if b.chance(0.7) {
            table_lamp(b, &mut g, x, y0 + 0.18, 0.56);
        }
    }
    g.focus.push(V3::new(0.0, y0 + l * 0.5, 0.6));
    g.focus.push(V3::new(0.0, y0 + 0.3, 0.7));
    g
}

fn couch(b: &mut Builder, lab: u8, w: f32) -> Group {
    let mut g = Group::default();
    let d = b.r(0.82, 0.95);
    let fabric = b.fabric();
    let s = b.seed();
    let y0 = 0.02;
    let arm = 0.17;
    g.bx(&L, [0.0, y0 + d * 0.5, 0.25], [w, d, 0.34], lab, fabric, s);
    g.bx(
        &L,
        [0.0, y0 + 0.11, 0.55],
        [w, 0.22, 0.62],
        lab,
        fabric,
        s ^ 1,
    );
    for sx in [-1.0, 1.0] {
        g.bx(
            &L,
            [sx * (w - arm) * 0.5, y0 + d * 0.5, 0.36],
            [arm, d, 0.56],
            lab,
            fabric,
            s ^ 2,
        );
    }
    let seats = ((w - 2.0 * arm) / 0.6).round().max(1.0) as usize;
    let sw = (w - 2.0 * arm) / seats as f32;
    for k in 0..seats {
        let x = -w * 0.5 + arm + sw * (k as f32 + 0.5);
        g.bx(
            &L,
            [x, y0 + 0.22 + (d - 0.22) * 0.5, 0.47],
            [sw - 0.012, d - 0.23, 0.1],
            lab,
            fabric,
            s ^ (3 + k as u32),
        );
    }
    let pillows = if lab == label::SOFA {
        b.rng.random_range(0..4)
    } else {
        b.rng.random_range(0..2)
    };
    for _ in 0..pillows {
        let (c, sn) = b.yaw_jitter(0.25);
        let x = b.r(-w * 0.5 + arm + 0.22, w * 0.5 - arm - 0.22);
        let color = b.pick(&FABRICS);
        let s = b.seed();
        g.bx(
            &L.sub([x, y0 + 0.3, 0.52], c, sn),
            [0.0, 0.0, 0.2],
            [0.42, 0.13, 0.4],
            label::PILLOW,
            Material::Fabric { color },
            s,
        );
    }
    g.focus.push(V3::new(0.0, y0 + d * 0.5, 0.5));
    g
}

/// A sofa with cushions and pillows.
pub fn sofa(b: &mut Builder) -> Group {
    let w = b.r(1.6, 2.3);
    couch(b, label::SOFA, w)
}

/// An armchair (NYU: chair).
pub fn armchair(b: &mut Builder) -> Group {
    let w = b.r(0.8, 0.95);
    couch(b, label::CHAIR, w)
}

/// A low TV cabinet with a television and props.
pub fn tv_stand(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d, h) = (b.r(1.2, 1.8), b.r(0.4, 0.5), b.r(0.42, 0.6));
    let wood = b.chance(0.5);
    let color = if wood {
        b.pick(&WOODS)
    } else {
        b.pick(&PAINTED)
    };
    let s = b.seed();
    g.bx(
        &L,
        [0.0, 0.02 + d * 0.5, h * 0.5],
        [w, d, h],
        label::CABINET,
        Material::Drawers {
            color,
            rows: 1,
            cols: 3,
            wood,
        },
        s,
    );
    let tw = b.r(0.9, (w - 0.1).min(1.4));
    let th = tw * 0.58;
    let dark = Material::Plastic {
        color: srgb(25, 25, 28),
    };
    let on = b.chance(0.6);
    g.bx(
        &L,
        [0.0, 0.2, h + 0.01],
        [0.35, 0.2, 0.02],
        label::TELEVISION,
        dark,
        s,
    );
    g.bx(
        &L,
        [0.0, 0.2, h + 0.06],
        [0.06, 0.04, 0.1],
        label::TELEVISION,
        dark,
        s,
    );
    g.bx(
        &L,
        [0.0, 0.2, h + 0.08 + th * 0.5],
        [tw, 0.05, th],
        label::TELEVISION,
        Material::Screen { on },
        s ^ 1,
    );
    let x = w * 0.5 - 0.15;
    props(b, &mut g, x - 0.12, x + 0.12, 0.02, 0.02 + d, h, 1);
    g.focus.push(V3::new(0.0, 0.25, h + 0.08 + th * 0.5));
    g
}

/// A floor lamp with its light.
pub fn floor_lamp(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let s = b.seed();
    let metal = Material::Metal {
        color: b.pick(&[srgb(50, 50, 52), srgb(190, 180, 150)]),
    };
    let y = 0.3;
    let h = b.r(1.35, 1.65);
    g.cyl(&L, 0.0, y, 0.0, 0.16, 0.03, label::LAMP, metal, s);
    g.cyl(&L, 0.0, y, 0.03, 0.015, h - 0.03, label::LAMP, metal, s);
    let color = b.pick(&[srgb(240, 230, 200), srgb(235, 225, 215)]);
    g.cyl(
        &L,
        0.0,
        y,
        h,
        0.2,
        0.3,
        label::LAMP,
        Material::LampShade { color },
        s,
    );
    g.lamps.push(V3::new(0.0, y, h + 0.15));
    g.interest.push(V3::new(0.0, y, h));
    g
}

/// A potted plant (otherprop).
pub fn plant(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let s = b.seed();
    let (r, ph) = (b.r(0.13, 0.22), b.r(0.25, 0.4));
    let pot = b.pick(&[srgb(170, 90, 60), srgb(230, 230, 225), srgb(60, 60, 65)]);
    let y = r + 0.05;
    g.cyl(
        &L,
        0.0,
        y,
        0.0,
        r,
        ph,
        label::OTHER_PROP,
        Material::Plastic { color: pot },
        s,
    );
    let mut z = ph;
    for k in 0..b.rng.random_range(2..4) {
        let (fr, fh) = (r * b.r(1.1, 1.8), b.r(0.25, 0.45));
        g.cyl(
            &L,
            b.r(-0.03, 0.03),
            y + b.r(-0.03, 0.03),
            z,
            fr,
            fh,
            label::OTHER_PROP,
            Material::Foliage,
            s ^ k,
        );
        z += fh * 0.8;
    }
    g.interest.push(V3::new(0.0, y, z * 0.7));
    g
}

/// A bag on the floor.
pub fn bag(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let color = b.pick(&FABRICS);
    let s = b.seed();
    let (c, sn) = b.yaw_jitter(0.4);
    let (w, d, h) = (b.r(0.3, 0.45), b.r(0.15, 0.25), b.r(0.3, 0.45));
    g.bx(
        &L.sub([0.0, 0.05 + d * 0.5, 0.0], c, sn),
        [0.0, 0.0, h * 0.5],
        [w, d, h],
        label::BAG,
        Material::Fabric { color },
        s,
    );
    g.interest.push(V3::new(0.0, 0.2, h * 0.5));
    g
}

/// A stack of cardboard boxes.
pub fn boxes(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let mut z = 0.0;
    for _ in 0..b.rng.random_range(1..4) {
        let (w, d, h) = (b.r(0.3, 0.6), b.r(0.3, 0.5), b.r(0.2, 0.45));
        let (c, sn) = b.yaw_jitter(0.15);
        let s = b.seed();
        g.bx(
            &L.sub([0.0, 0.05 + 0.25, z], c, sn),
            [0.0, 0.0, h * 0.5],
            [w, d, h],
            label::BOX,
            Material::Cardboard,
            s,
        );
        z += h;
    }
    g.interest.push(V3::new(0.0, 0.3, z * 0.6));
    g
}

/// Kitchen counter: base cabinets, worktop, sink, wall cabinets and a backsplash.
pub fn counter(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d, h) = (b.r(1.4, 2.6), 0.6, b.r(0.86, 0.92));
    let color = b.pick(&PAINTED);
    let s = b.seed();
    let cols = ((w / 0.6).round() as u8).max(1);
    g.bx(
        &L,
        [0.0, 0.02 + d * 0.5, (h - 0.04) * 0.5],
        [w, d, h - 0.04],
        label::CABINET,
        Material::Drawers {
            color,
            rows: 1,
            cols,
            wood: false,
        },
        s,
    );
    let top = if b.chance(0.5) {
        b.wood()
    } else {
        Material::Metal {
            color: b.pick(&[srgb(60, 60, 60), srgb(200, 200, 195)]),
        }
    };
    g.bx(
        &L,
        [0.0, 0.02 + d * 0.5 + 0.01, h - 0.02],
        [w + 0.02, d + 0.03, 0.04],
        label::COUNTER,
        top,
        s ^ 1,
    );
    let sx = b.r(-w * 0.5 + 0.35, w * 0.5 - 0.35);
    let steel = Material::Metal {
        color: srgb(200, 200, 205),
    };
    g.bx(
        &L,
        [sx, 0.02 + d * 0.5, h + 0.004],
        [0.5, 0.4, 0.008],
        label::SINK,
        steel,
        s,
    );
    g.cyl(&L, sx, 0.08, h, 0.018, 0.28, label::OTHER_PROP, steel, s);
    let uh = (b.room.height - 0.25 - (h + 0.6)).min(0.75);
    if uh > 0.4 && b.chance(0.6) {
        // Wall cabinets above a tiled backsplash.
        let tiles = Material::Tiles {
            color: b.pick(&[
                srgb(235, 235, 230),
                srgb(180, 200, 210),
                srgb(210, 200, 180),
            ]),
            grout: srgb(170, 170, 170),
            size: 0.1,
            checker: false,
        };
        g.bx(
            &L,
            [0.0, 0.005, h + 0.3],
            [w, 0.01, 0.6],
            label::WALL,
            tiles,
            s ^ 2,
        );
        g.bx(
            &L,
            [0.0, 0.02 + 0.17, h + 0.6 + uh * 0.5],
            [w, 0.34, uh],
            label::CABINET,
            Material::Drawers {
                color,
                rows: 1,
                cols,
                wood: false,
            },
            s ^ 3,
        );
    }
    let n = b.rng.random_range(1..4);
    props(b, &mut g, -w * 0.5, sx - 0.3, 0.02, 0.02 + d, h, n);
    if b.chance(0.5) {
        let mx = (sx + w * 0.5) * 0.5 + 0.15;
        if mx + 0.25 < w * 0.5 {
            g.bx(
                &L,
                [mx, 0.3, h + 0.15],
                [0.48, 0.36, 0.28],
                label::OTHER_PROP,
                Material::Screen { on: false },
                s ^ 4,
            );
        }
    }
    g.focus.push(V3::new(0.0, 0.02 + d, h));
    g
}

/// A refrigerator.
pub fn fridge(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d) = (b.r(0.6, 0.8), b.r(0.62, 0.72));
    let h = b.r(1.7, 1.95).min(b.room.height - 0.2);
    let color = b.pick(&[srgb(240, 240, 240), srgb(190, 192, 195), srgb(60, 60, 62)]);
    let s = b.seed();
    g.bx(
        &L,
        [0.0, 0.02 + d * 0.5, h * 0.5],
        [w, d, h],
        label::REFRIGERATOR,
        Material::Drawers {
            color,
            rows: 2,
            cols: 1,
            wood: false,
        },
        s,
    );
    g.interest.push(V3::new(0.0, 0.02 + d, h * 0.6));
    g
}

/// A table with chairs around it and things on it.
pub fn dining_table(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d, h) = (b.r(1.1, 1.8), b.r(0.75, 1.0), b.r(0.72, 0.77));
    let wood = b.wood();
    let s = b.seed();
    g.bx(
        &L,
        [0.0, 0.0, h - 0.02],
        [w, d, 0.04],
        label::TABLE,
        wood,
        s,
    );
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        g.bx(
            &L,
            [
                sx * (w * 0.5 - 0.06),
                sy * (d * 0.5 - 0.06),
                (h - 0.04) * 0.5,
            ],
            [0.06, 0.06, h - 0.04],
            label::TABLE,
            wood,
            s,
        );
    }
    let per_side = if w > 1.4 { 2 } else { 1 };
    for side in [-1.0f32, 1.0] {
        for k in 0..per_side {
            if b.chance(0.2) {
                continue;
            }
            let x = if per_side == 2 {
                (k as f32 - 0.5) * w * 0.5
            } else {
                0.0
            } + b.r(-0.08, 0.08);
            let facing = if side < 0.0 {
                0.0
            } else {
                std::f64::consts::PI
            };
            let (c, sn) = yaw(facing + b.r(-0.3, 0.3) as f64);
            let p = L.sub([x, side * (d * 0.5 + b.r(0.05, 0.3)), 0.0], c, sn);
            chair(b, &mut g, &p);
        }
    }
    let n = 1 + (b.clutter * 3.0) as usize;
    props(b, &mut g, -w * 0.5, w * 0.5, -d * 0.5, d * 0.5, h, n);
    g.focus.push(V3::new(0.0, 0.0, h));
    g
}

/// A coffee table with a few things on it.
pub fn coffee_table(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d, h) = (b.r(0.8, 1.2), b.r(0.45, 0.65), b.r(0.38, 0.46));
    let wood = b.wood();
    let s = b.seed();
    g.bx(
        &L,
        [0.0, 0.0, h - 0.02],
        [w, d, 0.04],
        label::TABLE,
        wood,
        s,
    );
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        g.bx(
            &L,
            [
                sx * (w * 0.5 - 0.04),
                sy * (d * 0.5 - 0.04),
                (h - 0.04) * 0.5,
            ],
            [0.04, 0.04, h - 0.04],
            label::TABLE,
            wood,
            s,
        );
    }
    let n = b.rng.random_range(1..4);
    props(b, &mut g, -w * 0.5, w * 0.5, -d * 0.5, d * 0.5, h, n);
    g.focus.push(V3::new(0.0, 0.0, h));
    g
}

/// A patterned rug (floor mat); furniture may stand on it.
pub fn rug(b: &mut Builder) -> Group {
    let mut g = Group {
        flat: true,
        ..Group::default()
    };
    let (w, d) = (b.r(1.4, 2.6), b.r(1.0, 1.8));
    let color = b.pick(&FABRICS);
    let s = b.seed();
    g.bx(
        &L,
        [0.0, 0.0, 0.005],
        [w, d, 0.01],
        label::FLOOR_MAT,
        Material::Carpet {
            color,
            pattern: true,
        },
        s,
    );
    g
}
