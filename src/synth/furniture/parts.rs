//! Palettes and parts shared by several items: rows of books, small props,
//! table lamps and chairs.

use super::{Builder, Group, Place};
use crate::classes::label;
use crate::synth::geom::V3;
use crate::synth::scene::yaw;
use crate::synth::texture::{Material, Rgb, srgb};
use rand::RngExt;

pub(super) const WOODS: [Rgb; 6] = [
    srgb(190, 145, 95),
    srgb(150, 100, 60),
    srgb(110, 70, 45),
    srgb(215, 185, 140),
    srgb(90, 60, 40),
    srgb(170, 120, 80),
];

pub(super) const FABRICS: [Rgb; 9] = [
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

pub(super) const PAINTED: [Rgb; 6] = [
    srgb(240, 240, 236),
    srgb(60, 60, 62),
    srgb(200, 205, 210),
    srgb(150, 170, 160),
    srgb(225, 215, 195),
    srgb(40, 60, 90),
];

pub(super) const BOOKS: [Rgb; 12] = [
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

pub(super) const L: Place = Place {
    o: V3::new(0.0, 0.0, 0.0),
    c: 1.0,
    s: 0.0,
};

/// Books standing on a shelf between `x0` and `x1`, spines flush with `front`.
#[allow(clippy::too_many_arguments)]
pub(super) fn book_row(
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
pub(super) fn props(
    b: &mut Builder,
    g: &mut Group,
    x0: f32,
    x1: f32,
    y0: f32,
    y1: f32,
    z: f32,
    n: usize,
) {
    let mut taken: Vec<(f32, f32)> = Vec::new();
    for _ in 0..n {
        let Some((x, y)) = free_spot(b, &taken, x0, x1, y0, y1) else {
            continue;
        };
        taken.push((x, y));
        let (c, s) = b.yaw_jitter(0.6);
        let p = L.sub([x, y, z], c, s);
        let seed = b.seed();
        match b.rng.random_range(0..7) {
            0 => prop_box(b, g, &p, seed),
            1 => prop_bottle(b, g, &p, seed),
            2 => prop_papers(b, g, &p, seed),
            3 => prop_book_stack(b, g, &p),
            4 => prop_plant(g, &p, seed),
            5 => prop_bag(b, g, &p, seed),
            _ => prop_cup(b, g, &p, seed),
        }
    }
}

/// A spot at least 0.3 m from the `taken` ones, if one is found in eight tries.
fn free_spot(
    b: &mut Builder,
    taken: &[(f32, f32)],
    x0: f32,
    x1: f32,
    y0: f32,
    y1: f32,
) -> Option<(f32, f32)> {
    for _ in 0..8 {
        let (x, y) = (b.r(x0 + 0.1, x1 - 0.1), b.r(y0 + 0.08, y1 - 0.08));
        if taken
            .iter()
            .all(|&(u, v)| (u - x) * (u - x) + (v - y) * (v - y) > 0.09)
        {
            return Some((x, y));
        }
    }
    None
}

/// A cardboard box of random size.
fn prop_box(b: &mut Builder, g: &mut Group, p: &Place, seed: u32) {
    let (w, d, h) = (b.r(0.15, 0.35), b.r(0.12, 0.3), b.r(0.08, 0.25));
    g.bx(
        p,
        [0.0, 0.0, h * 0.5],
        [w, d, h],
        label::BOX,
        Material::Cardboard,
        seed,
    );
}

/// A coloured plastic bottle or tin.
fn prop_bottle(b: &mut Builder, g: &mut Group, p: &Place, seed: u32) {
    let color = b.pick(&[
        srgb(200, 80, 60),
        srgb(60, 90, 160),
        srgb(220, 220, 210),
        srgb(60, 140, 90),
    ]);
    let (r, h) = (b.r(0.035, 0.07), b.r(0.1, 0.3));
    g.cyl(
        p,
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

/// An A4 sheet, sometimes with a second one on top.
fn prop_papers(b: &mut Builder, g: &mut Group, p: &Place, seed: u32) {
    g.bx(
        p,
        [0.0, 0.0, 0.001],
        [0.21, 0.297, 0.002],
        label::PAPER,
        Material::Paper,
        seed,
    );
    if b.chance(0.5) {
        g.bx(
            p,
            [0.01, 0.01, 0.003],
            [0.21, 0.297, 0.002],
            label::PAPER,
            Material::Paper,
            seed ^ 1,
        );
    }
}

/// A stack of one to three books lying flat.
fn prop_book_stack(b: &mut Builder, g: &mut Group, p: &Place) {
    let mut zz = 0.0;
    for _ in 0..b.rng.random_range(1..4) {
        let (w, d, t) = (b.r(0.15, 0.25), b.r(0.2, 0.3), b.r(0.02, 0.05));
        let color = b.book_color();
        let s = b.seed();
        g.bx(
            p,
            [0.0, 0.0, zz + t * 0.5],
            [w, d, t],
            label::BOOKS,
            Material::Book { color },
            s,
        );
        zz += t;
    }
}

/// A small plant in a terracotta pot.
fn prop_plant(g: &mut Group, p: &Place, seed: u32) {
    g.cyl(
        p,
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
        p,
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

/// A fabric bag standing upright.
fn prop_bag(b: &mut Builder, g: &mut Group, p: &Place, seed: u32) {
    let color = b.pick(&FABRICS);
    g.bx(
        p,
        [0.0, 0.0, 0.15],
        [0.32, 0.15, 0.3],
        label::BAG,
        Material::Fabric { color },
        seed,
    );
}

/// A mug or cup.
fn prop_cup(b: &mut Builder, g: &mut Group, p: &Place, seed: u32) {
    let color = b.pick(&[srgb(240, 240, 240), srgb(40, 40, 40), srgb(190, 60, 50)]);
    g.cyl(
        p,
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

/// A desk or bedside lamp standing at `(x, y, z)`, with its light.
pub(super) fn table_lamp(b: &mut Builder, g: &mut Group, x: f32, y: f32, z: f32) {
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
pub(super) fn chair(b: &mut Builder, g: &mut Group, p: &Place) {
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

/// A `w x d` top 4 cm thick whose upper face is at height `h`, on four square legs of side
/// `leg` inset by `leg` from the corners; one label and one material for all five boxes.
#[allow(clippy::too_many_arguments)]
pub(super) fn top_on_legs(
    g: &mut Group,
    p: &Place,
    [w, d, h]: [f32; 3],
    leg: f32,
    label: u8,
    material: Material,
    seed: u32,
) {
    g.bx(p, [0.0, 0.0, h - 0.02], [w, d, 0.04], label, material, seed);
    for (sx, sy) in [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)] {
        g.bx(
            p,
            [sx * (w * 0.5 - leg), sy * (d * 0.5 - leg), (h - 0.04) * 0.5],
            [leg, leg, h - 0.04],
            label,
            material,
            seed,
        );
    }
}
