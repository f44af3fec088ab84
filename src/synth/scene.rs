//! Procedural rooms: a rectangular or L-shaped shell (walls, floor, ceiling,
//! skirting), doors, windows, pictures, and furniture chosen by room kind, placed
//! against the walls and in the middle without overlaps. Every solid carries its
//! NYU40 label. World frame: metres, `z` up, the room spans `[0, width] x [0, depth]`.

use super::config::{RoomConfig, RoomKind};
use super::detmath::sin_cos;
use super::furniture::{self, Group, Place};
use super::geom::{Bvh, Hit, Prim, Ray, Shape, Solid, V3};
use super::texture::{Material, Rgb, srgb};
use crate::classes::label;
use crate::error::{Error, Result};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// A point light; `shadows` casts shadow rays towards it.
#[derive(Debug, Clone, Serialize)]
pub struct Light {
    /// Position in the world frame, metres.
    pub pos: [f32; 3],
    /// Linear RGB intensity.
    pub color: Rgb,
    /// Whether shading casts shadow rays towards it.
    pub shadows: bool,
}

/// One straight wall: from `a` to `b` (counter-clockwise), `n` points into the room.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Wall {
    /// Start point `(x, y)` on the floor, metres.
    pub a: [f32; 2],
    /// End point `(x, y)` on the floor, metres.
    pub b: [f32; 2],
    /// Unit normal pointing into the room.
    pub n: [f32; 2],
    /// Length from `a` to `b`, metres.
    pub len: f32,
}

impl Wall {
    /// Unit direction from `a` to `b` (the normal turned back: no division per call).
    pub fn dir(&self) -> [f32; 2] {
        [self.n[1], -self.n[0]]
    }

    /// The placement frame of an item against this wall, centred at `s` metres
    /// along it, `gap` metres off the wall (local `+x` along the wall, `+y` into the room).
    pub fn place(&self, s: f32, gap: f32) -> Place {
        let d = self.dir();
        Place::new(
            V3::new(
                self.a[0] + d[0] * s + self.n[0] * gap,
                self.a[1] + d[1] * s + self.n[1] * gap,
                0.0,
            ),
            self.n[1],
            -self.n[0],
        )
    }
}

/// The room shell.
#[derive(Debug, Clone, Serialize)]
pub struct Room {
    /// Extent along `x`, metres.
    pub width: f32,
    /// Extent along `y`, metres.
    pub depth: f32,
    /// Floor-to-ceiling height, metres.
    pub height: f32,
    /// The solid block cut out of an L-shaped room: `[x0, y0, x1, y1]`.
    pub notch: Option<[f32; 4]>,
    /// The footprint's walls, counter-clockwise.
    pub walls: Vec<Wall>,
    /// What kind of room it is (chooses the furniture).
    pub kind: RoomKind,
}

impl Room {
    /// Whether a floor point lies inside the room (with a margin).
    pub fn contains(&self, x: f32, y: f32, margin: f32) -> bool {
        let inside =
            x >= margin && y >= margin && x <= self.width - margin && y <= self.depth - margin;
        inside
            && !self.notch.is_some_and(|[x0, y0, x1, y1]| {
                x > x0 - margin && x < x1 + margin && y > y0 - margin && y < y1 + margin
            })
    }

    /// Floor area, square metres.
    pub fn area(&self) -> f32 {
        let notch = self
            .notch
            .map_or(0.0, |[x0, y0, x1, y1]| (x1 - x0) * (y1 - y0));
        self.width * self.depth - notch
    }
}

/// A generated scene, ready to render.
#[derive(Debug, Clone)]
pub struct Scene {
    /// The room shell.
    pub room: Room,
    /// Every solid of the scene, shell first, each with its NYU40 label.
    pub solids: Vec<Solid>,
    /// Point lights.
    pub lights: Vec<Light>,
    /// Ambient light (stands in for inter-reflections).
    pub ambient: Rgb,
    /// Points worth looking at (furniture tops, pictures, windows...).
    pub interest: Vec<V3>,
    /// The subset of `interest` with much to see (desks, shelves, beds...).
    pub focus: Vec<V3>,
    /// The floor, ceiling and wall slabs (`solids[..shell.len()]`): tested
    /// against every ray; the rest are in the hierarchy.
    shell: Vec<Prim>,
    /// Index in `shell` of the slab behind each face of the room's bounding
    /// box (`2 * axis + positive`); `None` when that does not apply.
    exit: Option<[usize; 6]>,
    /// The L-shape's inner wall slabs.
    inner: Vec<Prim>,
    bvh: Bvh,
}

const WALL_PAINT: [Rgb; 8] = [
    srgb(236, 234, 228),
    srgb(226, 222, 210),
    srgb(214, 216, 218),
    srgb(224, 210, 184),
    srgb(196, 212, 222),
    srgb(206, 220, 196),
    srgb(236, 224, 180),
    srgb(222, 200, 196),
];

impl Scene {
    /// Builds a random room from a seed.
    pub fn generate(cfg: &RoomConfig, seed: u64) -> Result<Scene> {
        cfg.validate()?;
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let kind = cfg.kinds[rng.random_range(0..cfg.kinds.len())];
        let width = rng.random_range(cfg.min_size[0]..=cfg.max_size[0]) as f32;
        let depth = rng.random_range(cfg.min_size[1]..=cfg.max_size[1]) as f32;
        let height = rng.random_range(cfg.height[0]..=cfg.height[1]) as f32;
        let notch = rng.random_bool(cfg.l_shape_probability).then(|| {
            let (nw, nd) = (
                width * rng.random_range(0.28..0.42f32),
                depth * rng.random_range(0.28..0.42f32),
            );
            match rng.random_range(0..4) {
                0 => [0.0, 0.0, nw, nd],
                1 => [width - nw, 0.0, width, nd],
                2 => [width - nw, depth - nd, width, depth],
                _ => [0.0, depth - nd, nw, depth],
            }
        });
        let room = Room {
            width,
            depth,
            height,
            notch,
            walls: walls(width, depth, notch),
            kind,
        };
        let mut b = furniture::Builder::new(&mut rng, room.clone(), cfg.clutter as f32);
        shell(&mut b);
        furnish(&mut b);
        let built = b.finish();
        let (interest, focus, lamps) = (built.interest, built.focus, built.lamps);
        let mut solids = built.shell;
        let n_shell = solids.len();
        solids.extend(built.solids);
        let mut lights = ceiling_lights(&mut rng, &room);
        for l in lamps {
            lights.push(Light {
                pos: l.into(),
                color: [0.25, 0.21, 0.15],
                shadows: false,
            });
        }
        for s in &solids {
            if s.label == label::WINDOW && matches!(s.material, Material::Window { .. }) {
                // Daylight through the window: a soft fill light just inside it.
                let inward = s.to_world(V3::new(0.0, 1.0, 0.0));
                let p = s.center + inward * 0.8;
                let k = 0.35 * (s.half.x * s.half.z * 4.0).min(2.0);
                lights.push(Light {
                    pos: p.into(),
                    color: [0.8 * k, 0.88 * k, 1.0 * k],
                    shadows: false,
                });
            }
        }
        if solids.len() > 60_000 {
            return Err(Error::msg("scene has too many solids"));
        }
        // The hierarchy indexes all solids; the shell ones are made unreachable
        // by building it over the objects and shifting their ids.
        let bvh = Bvh::build_offset(&solids, n_shell);
        let shell: Vec<Prim> = solids[..n_shell]
            .iter()
            .enumerate()
            .map(|(i, s)| Prim::new(s, i as u32))
            .collect();
        // Which slab a ray leaving the room's bounding box through each of its
        // faces hits (floor and ceiling are shell solids 0 and 1, walls follow).
        let mut exit = [None; 6];
        exit[4] = Some(0);
        exit[5] = Some(1);
        let mut inner = Vec::new();
        for (k, wall) in room.walls.iter().enumerate() {
            let face = if wall.a[0] == wall.b[0] && (wall.a[0] == 0.0 || wall.a[0] == width) {
                Some((wall.a[0] == width) as usize)
            } else if wall.a[1] == wall.b[1] && (wall.a[1] == 0.0 || wall.a[1] == depth) {
                Some(2 + (wall.a[1] == depth) as usize)
            } else {
                None
            };
            match face {
                Some(f) => exit[f] = Some(k + 2),
                None => inner.push(shell[k + 2]),
            }
        }
        let exit = exit
            .iter()
            .all(Option::is_some)
            .then(|| exit.map(|e| e.unwrap_or(0)));
        let a = 0.12 + 0.04 * rng.random::<f32>();
        Ok(Scene {
            room,
            solids,
            lights,
            ambient: [a, a * 0.98, a * 0.95],
            interest,
            focus,
            shell,
            exit,
            inner,
            bvh,
        })
    }

    /// Nearest hit along a ray.
    #[inline]
    pub fn cast(&self, ray: &Ray, tmin: f32, tmax: f32) -> Option<Hit> {
        let mut best = None;
        let mut tmax = tmax;
        let r = &self.room;
        let o = ray.o;
        let inside =
            o.x > 0.0 && o.y > 0.0 && o.z > 0.0 && o.x < r.width && o.y < r.depth && o.z < r.height;
        let candidates: &mut dyn Iterator<Item = &Prim> = match (&self.exit, inside) {
            (Some(exit), true) => {
                // The face through which the ray leaves the bounding box tells
                // which floor, ceiling or outer wall slab it meets.
                let size = [r.width, r.depth, r.height];
                let (mut te, mut face) = (f32::INFINITY, 4);
                for a in 0..3 {
                    if ray.d[a] != 0.0 {
                        let bound = if ray.d[a] > 0.0 { size[a] } else { 0.0 };
                        let t = (bound - o[a]) * ray.inv[a];
                        if t < te {
                            te = t;
                            face = 2 * a + (ray.d[a] > 0.0) as usize;
                        }
                    }
                }
                &mut std::iter::once(&self.shell[exit[face]]).chain(&self.inner)
            }
            _ => &mut self.shell.iter(),
        };
        for p in candidates {
            if let Some((t, face, local)) = p.intersect(ray, tmin, tmax) {
                tmax = t;
                best = Some(Hit {
                    t,
                    solid: p.id,
                    face,
                    local,
                });
            }
        }
        self.bvh.closest(ray, tmin, tmax).or(best)
    }

    /// Distance from a point to the nearest solid (0 inside one); points outside
    /// the room's bounding box count as inside the walls.
    pub fn clearance(&self, p: &V3) -> f32 {
        let r = &self.room;
        if p.z <= 0.0 || p.z >= r.height || !r.contains(p.x, p.y, 0.0) {
            return 0.0;
        }
        self.solids
            .iter()
            .map(|s| distance(s, p))
            .fold(f32::MAX, f32::min)
    }

    /// Labels present among the solids.
    pub fn labels(&self) -> Vec<u8> {
        let mut l: Vec<u8> = self.solids.iter().map(|s| s.label).collect();
        l.sort_unstable();
        l.dedup();
        l
    }
}

/// Distance from a point to a solid.
fn distance(s: &Solid, p: &V3) -> f32 {
    let q = s.to_local(p - s.center);
    match s.shape {
        Shape::Box => {
            let d = q.abs() - s.half;
            d.map(|v| v.max(0.0)).norm()
        }
        Shape::Cylinder => {
            let radial = ((q.x * q.x + q.y * q.y).sqrt() - s.half.x).max(0.0);
            let dz = (q.z.abs() - s.half.z).max(0.0);
            (radial * radial + dz * dz).sqrt()
        }
    }
}

/// Walls of the footprint, counter-clockwise with inward normals.
fn walls(w: f32, d: f32, notch: Option<[f32; 4]>) -> Vec<Wall> {
    let poly: Vec<[f32; 2]> = match notch {
        None => vec![[0.0, 0.0], [w, 0.0], [w, d], [0.0, d]],
        Some([x0, y0, x1, y1]) => {
            if x0 == 0.0 && y0 == 0.0 {
                vec![[x1, 0.0], [w, 0.0], [w, d], [0.0, d], [0.0, y1], [x1, y1]]
            } else if x1 == w && y0 == 0.0 {
                vec![[0.0, 0.0], [x0, 0.0], [x0, y1], [w, y1], [w, d], [0.0, d]]
            } else if x1 == w {
                vec![[0.0, 0.0], [w, 0.0], [w, y0], [x0, y0], [x0, d], [0.0, d]]
            } else {
                vec![[0.0, 0.0], [w, 0.0], [w, d], [x1, d], [x1, y0], [0.0, y0]]
            }
        }
    };
    (0..poly.len())
        .map(|i| {
            let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let len = (dx * dx + dy * dy).sqrt();
            let dir = [(b[0] - a[0]) / len, (b[1] - a[1]) / len];
            Wall {
                a,
                b,
                n: [-dir[1], dir[0]],
                len,
            }
        })
        .collect()
}

/// Floor, ceiling, walls, the L-shape's block, skirting boards and ceiling lamps.
fn shell(b: &mut furniture::Builder) {
    let r = b.room.clone();
    let t = 0.2;
    floor_and_ceiling(b, &r, t);
    wall_slabs(b, &r, t);
    skirting(b, &r);
    ceiling_lamps(b, &r);
}

/// The floor (planks, tiles or carpet; kitchens mostly tiled) and ceiling slabs, `t` thick.
fn floor_and_ceiling(b: &mut furniture::Builder, r: &Room, t: f32) {
    let floor = match b.rng.random_range(0..10) {
        0..=4 => Material::Planks {
            color: b.pick(&[
                srgb(190, 140, 90),
                srgb(160, 110, 70),
                srgb(210, 175, 130),
                srgb(120, 85, 60),
            ]),
        },
        5..=7 => Material::Tiles {
            color: b.pick(&[
                srgb(220, 215, 205),
                srgb(180, 170, 160),
                srgb(200, 200, 200),
            ]),
            grout: srgb(140, 135, 130),
            size: b.rng.random_range(0.3..0.6),
            checker: b.rng.random_bool(0.25),
        },
        _ => Material::Carpet {
            color: b.pick(&[srgb(120, 110, 100), srgb(90, 100, 120), srgb(150, 130, 110)]),
            pattern: false,
        },
    };
    let floor = if r.kind == RoomKind::Kitchen && b.rng.random_bool(0.7) {
        Material::Tiles {
            color: srgb(225, 222, 215),
            grout: srgb(150, 150, 150),
            size: 0.3,
            checker: b.rng.random_bool(0.4),
        }
    } else {
        floor
    };
    let (w, d, h) = (r.width, r.depth, r.height);
    let seed = b.seed();
    b.shell_solid(Solid {
        seed,
        ..Solid::aabb(
            V3::new(-t, -t, -t),
            V3::new(w + t, d + t, 0.0),
            label::FLOOR,
            floor,
        )
    });
    let seed = b.seed();
    b.shell_solid(Solid {
        seed,
        ..Solid::aabb(
            V3::new(-t, -t, h),
            V3::new(w + t, d + t, h + t),
            label::CEILING,
            Material::Plaster {
                color: srgb(240, 240, 236),
            },
        )
    });
}

/// A `t`-thick slab behind each wall line, painted, one maybe an accent wall.
fn wall_slabs(b: &mut furniture::Builder, r: &Room, t: f32) {
    let h = r.height;
    let paint = Material::Paint {
        color: b.pick(&WALL_PAINT),
    };
    // One accent wall may be brick or a second colour.
    let accent = b.rng.random_range(0..r.walls.len() + 2);
    let accent_mat = if b.rng.random_bool(0.5) {
        Material::Brick {
            color: srgb(170, 90, 70),
            mortar: srgb(200, 195, 185),
        }
    } else {
        Material::Paint {
            color: b.pick(&WALL_PAINT),
        }
    };
    for (i, wall) in r.walls.iter().enumerate() {
        let (x0, x1) = (wall.a[0].min(wall.b[0]), wall.a[0].max(wall.b[0]));
        let (y0, y1) = (wall.a[1].min(wall.b[1]), wall.a[1].max(wall.b[1]));
        // The slab behind the wall line, extended past the corners.
        let (min, max) = if wall.n[0] != 0.0 {
            let x = if wall.n[0] > 0.0 { x0 - t } else { x0 };
            (V3::new(x, y0 - t, 0.0), V3::new(x + t, y1 + t, h))
        } else {
            let y = if wall.n[1] > 0.0 { y0 - t } else { y0 };
            (V3::new(x0 - t, y, 0.0), V3::new(x1 + t, y + t, h))
        };
        let mat = if i == accent { accent_mat } else { paint };
        let seed = b.seed();
        b.shell_solid(Solid {
            seed,
            ..Solid::aabb(min, max, label::WALL, mat)
        });
    }
}

/// Skirting boards along every wall, plastic or wood.
fn skirting(b: &mut furniture::Builder, r: &Room) {
    let skirting = if b.rng.random_bool(0.6) {
        Material::Plastic {
            color: srgb(235, 235, 230),
        }
    } else {
        Material::Wood {
            color: srgb(150, 105, 70),
        }
    };
    for wall in &r.walls {
        // In pieces of at most a metre, so that the hierarchy stays tight.
        let pieces = (wall.len / 1.0).ceil().max(1.0) as usize;
        let len = (wall.len - 0.002) / pieces as f32;
        let mut g = Group::default();
        for k in 0..pieces {
            let p = wall.place(0.001 + len * (k as f32 + 0.5), 0.0);
            g.bx(
                &p,
                [0.0, 0.006, 0.04],
                [len, 0.012, 0.08],
                label::WALL,
                skirting,
                0,
            );
        }
        for s in g.solids {
            b.fixture(s);
        }
    }
}

/// Ceiling lamps: flush discs (NYU "light" -> otherstructure) or pendants (lamp).
fn ceiling_lamps(b: &mut furniture::Builder, r: &Room) {
    let h = r.height;
    let n = if r.area() > 18.0 { 2 } else { 1 };
    let pendant = b.rng.random_bool(0.5);
    for k in 0..n {
        let (x, y) = lamp_xy(r, k, n);
        let rad = b.rng.random_range(0.18..0.3);
        let disc = |z0: f32, hh: f32, label: u8, material: Material| Solid {
            shape: Shape::Cylinder,
            center: V3::new(x, y, z0 + hh * 0.5),
            half: V3::new(rad, rad, hh * 0.5),
            cos: 1.0,
            sin: 0.0,
            label,
            material,
            seed: 0,
        };
        if pendant {
            let cord = Solid {
                half: V3::new(0.006, 0.006, 0.15),
                center: V3::new(x, y, h - 0.15),
                ..disc(
                    0.0,
                    0.0,
                    label::LAMP,
                    Material::Plastic {
                        color: srgb(40, 40, 40),
                    },
                )
            };
            b.fixture(cord);
            let color = b.pick(&[
                srgb(240, 235, 220),
                srgb(230, 230, 230),
                srgb(250, 240, 210),
            ]);
            b.fixture(disc(
                h - 0.45,
                0.15,
                label::LAMP,
                Material::LampShade { color },
            ));
        } else {
            b.fixture(disc(
                h - 0.06,
                0.06,
                label::OTHER_STRUCTURE,
                Material::CeilingLight,
            ));
        }
    }
}

/// Where the `k`-th of `n` ceiling lamps hangs.
fn lamp_xy(r: &Room, k: usize, n: usize) -> (f32, f32) {
    let (mut x, mut y) = (r.width * 0.5, r.depth * 0.5);
    if n == 2 {
        if r.width > r.depth {
            x = r.width * (0.28 + 0.44 * k as f32);
        } else {
            y = r.depth * (0.28 + 0.44 * k as f32);
        }
    }
    if !r.contains(x, y, 0.3) {
        // The L-shape's block took the centre: use the middle of the largest free part.
        let [x0, y0, x1, y1] = r.notch.unwrap_or([0.0; 4]);
        if x1 - x0 < r.width {
            x = if x0 > 0.0 {
                x0 * 0.5
            } else {
                (x1 + r.width) * 0.5
            };
        }
        if !r.contains(x, y, 0.3) {
            y = if y0 > 0.0 {
                y0 * 0.5
            } else {
                (y1 + r.depth) * 0.5
            };
        }
    }
    (x, y)
}

fn ceiling_lights(rng: &mut ChaCha8Rng, r: &Room) -> Vec<Light> {
    let n = if r.area() > 18.0 { 2 } else { 1 };
    let power = rng.random_range(1.6..2.4f32) * (r.area() / 20.0).clamp(0.7, 1.4) / n as f32;
    let warm = rng.random_range(0.0..0.12f32);
    (0..n)
        .map(|k| {
            let (x, y) = lamp_xy(r, k, n);
            Light {
                pos: [x, y, r.height - 0.5],
                color: [power, power * (1.0 - warm * 0.5), power * (1.0 - warm)],
                shadows: true,
            }
        })
        .collect()
}

/// Doors, windows, furniture by room kind, then wall decoration.
fn furnish(b: &mut furniture::Builder) {
    let kind = b.room.kind;
    let clutter = b.clutter;
    let doors = if b.room.walls.len() > 4 || b.rng.random_bool(0.3) {
        2
    } else {
        1
    };
    for _ in 0..doors {
        b.try_wall(furniture::door, 0.15, 40);
    }
    let windows = b
        .rng
        .random_range(1..=if b.room.area() > 16.0 { 3 } else { 2 });
    for _ in 0..windows {
        b.try_wall(furniture::window, 0.35, 40);
    }
    use furniture as f;
    let items: Vec<(furniture::Item, f32)> = match kind {
        RoomKind::Office => vec![
            (f::desk, 1.0),
            (f::desk, 0.8),
            (f::desk, 0.4),
            (f::bookshelf, 0.9),
            (f::shelves, 0.6),
            (f::cabinet, 0.8),
            (f::cabinet, 0.4),
            (f::boxes, 0.5),
            (f::plant, 0.5),
        ],
        RoomKind::Bedroom => vec![
            (f::bed, 1.0),
            (f::dresser, 0.8),
            (f::wardrobe, 0.6),
            (f::desk, 0.5),
            (f::bookshelf, 0.4),
            (f::floor_lamp, 0.4),
            (f::bag, 0.5),
            (f::plant, 0.3),
        ],
        RoomKind::Living => vec![
            (f::sofa, 1.0),
            (f::tv_stand, 1.0),
            (f::armchair, 0.6),
            (f::bookshelf, 0.6),
            (f::floor_lamp, 0.6),
            (f::shelves, 0.4),
            (f::cabinet, 0.4),
            (f::plant, 0.6),
        ],
        RoomKind::Library => vec![
            (f::bookshelf, 1.0),
            (f::bookshelf, 1.0),
            (f::bookshelf, 0.9),
            (f::bookshelf, 0.7),
            (f::shelves, 0.6),
            (f::desk, 0.6),
            (f::armchair, 0.4),
            (f::floor_lamp, 0.5),
            (f::boxes, 0.4),
        ],
        RoomKind::Kitchen => vec![
            (f::counter, 1.0),
            (f::counter, 0.7),
            (f::fridge, 1.0),
            (f::cabinet, 0.5),
            (f::shelves, 0.4),
            (f::plant, 0.3),
        ],
    };
    for (item, p) in items {
        if b.rng
            .random_bool((p * (0.6 + 0.4 * clutter)).min(1.0) as f64)
        {
            b.try_wall(item, 0.02, 30);
        }
    }
    // The middle of the room.
    match kind {
        RoomKind::Office | RoomKind::Library | RoomKind::Kitchen => {
            if b.rng
                .random_bool(if kind == RoomKind::Office { 0.6 } else { 0.9 })
            {
                b.try_centre(f::dining_table, 30);
            }
        }
        RoomKind::Living => {
            b.try_centre(f::rug, 20);
            b.try_centre(f::coffee_table, 30);
        }
        RoomKind::Bedroom => {
            if b.rng.random_bool(0.6) {
                b.try_centre(f::rug, 20);
            }
        }
    }
    // Wall decoration above whatever stands there.
    if kind == RoomKind::Office && b.rng.random_bool(0.6) {
        b.try_wall(furniture::whiteboard, 0.2, 40);
    }
    let pictures = b.rng.random_range(2..=5);
    for _ in 0..pictures {
        b.try_wall(furniture::picture, 0.15, 40);
    }
}

/// Yaw `(cos, sin)` of an angle in radians.
pub fn yaw(angle: f64) -> (f32, f32) {
    let (s, c) = sin_cos(angle);
    (c as f32, s as f32)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synth::config::RoomConfig;

    #[test]
    fn rooms_are_closed_and_furnished_without_overlaps() {
        for seed in 0..12 {
            let cfg = RoomConfig {
                l_shape_probability: if seed % 2 == 0 { 1.0 } else { 0.0 },
                ..RoomConfig::default()
            };
            let scene = Scene::generate(&cfg, seed).unwrap();
            assert!(
                scene.solids.len() > 30,
                "seed {seed}: {} solids",
                scene.solids.len()
            );
            assert!(
                scene.labels().len() >= 8,
                "seed {seed}: {:?}",
                scene.labels()
            );
            // Rays from the room centre in all directions hit something.
            let r = &scene.room;
            let mut o = V3::new(r.width * 0.5, r.depth * 0.5, 1.4);
            if !r.contains(o.x, o.y, 0.5) {
                let [x0, y0, x1, y1] = r.notch.unwrap();
                o.x = if x0 > 0.0 {
                    x0 * 0.5
                } else {
                    (x1 + r.width) * 0.5
                };
                o.y = if y0 > 0.0 {
                    y0 * 0.5
                } else {
                    (y1 + r.depth) * 0.5
                };
            }
            for k in 0..200u32 {
                let u = |j| crate::synth::detmath::unit(crate::synth::detmath::hash2(k, j)) - 0.5;
                let ray = Ray::new(o, V3::new(u(0), u(1), u(2)));
                assert!(
                    scene.cast(&ray, 1e-4, 1e4).is_some(),
                    "seed {seed}: ray escaped"
                );
            }
        }
    }

    #[test]
    fn fast_cast_agrees_with_brute_force() {
        for seed in 0..6 {
            let cfg = RoomConfig {
                l_shape_probability: if seed % 2 == 0 { 1.0 } else { 0.0 },
                ..RoomConfig::default()
            };
            let scene = Scene::generate(&cfg, seed).unwrap();
            let r = &scene.room;
            for k in 0..3000u32 {
                let u = |j| {
                    crate::synth::detmath::unit(crate::synth::detmath::hash3(k, j, seed as u32))
                };
                let o = V3::new(u(0) * r.width, u(1) * r.depth, u(2) * r.height);
                if !r.contains(o.x, o.y, 0.0) {
                    continue;
                }
                let ray = Ray::new(o, V3::new(u(3) - 0.5, u(4) - 0.5, u(5) - 0.5));
                let brute = scene
                    .solids
                    .iter()
                    .enumerate()
                    .filter_map(|(i, s)| s.intersect(&ray, 1e-4, 1e4).map(|h| (h.0, i as u32)))
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                let fast = scene.cast(&ray, 1e-4, 1e4).map(|h| (h.t, h.solid));
                match (brute, fast) {
                    (Some(a), Some(b)) => assert!(
                        (a.0 - b.0).abs() < 1e-4 * a.0.max(1.0),
                        "seed {seed} ray {k}: {a:?} {b:?}"
                    ),
                    (a, b) => assert_eq!(a.is_some(), b.is_some(), "seed {seed} ray {k}"),
                }
            }
        }
    }

    #[test]
    fn same_seed_same_scene() {
        let cfg = RoomConfig::default();
        let a = Scene::generate(&cfg, 42).unwrap();
        let b = Scene::generate(&cfg, 42).unwrap();
        assert_eq!(a.solids.len(), b.solids.len());
        for (x, y) in a.solids.iter().zip(&b.solids) {
            assert_eq!(x.center, y.center);
            assert_eq!(x.material, y.material);
        }
        let c = Scene::generate(&cfg, 43).unwrap();
        assert!(c.solids.len() != a.solids.len() || c.solids[0].center != a.solids[0].center);
    }
}
