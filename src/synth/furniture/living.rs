//! Furniture to sit, sleep and work at: desks with computers, beds, sofas,
//! armchairs, dining and coffee tables.

use super::parts::*;
use super::{Builder, Group};
use crate::classes::label;
use crate::synth::geom::V3;
use crate::synth::scene::yaw;
use crate::synth::texture::{Material, srgb};
use rand::RngExt;

/// A desk with monitor(s), keyboard, props, maybe a lamp and drawers, and a chair.
pub fn desk(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d, h) = (b.r(1.0, 1.6), b.r(0.6, 0.78), b.r(0.72, 0.76));
    let y0 = 0.02;
    desk_frame(b, &mut g, w, d, h, y0);
    let dark = Material::Plastic {
        color: srgb(30, 30, 32),
    };
    desk_screens(b, &mut g, w, h, y0, dark);
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
    desk_chair_and_box(b, &mut g, w, d, y0);
    g.focus.push(V3::new(0.0, y0 + d * 0.5, h + 0.1));
    g.focus.push(V3::new(0.0, y0 + 0.2, h + 0.3));
    g
}

/// The desk's top, legs and maybe a drawer pedestal in place of the right legs.
fn desk_frame(b: &mut Builder, g: &mut Group, w: f32, d: f32, h: f32, y0: f32) {
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
}

/// Monitors (NYU "monitor" -> otherprop) or a television on a bigger desk.
fn desk_screens(b: &mut Builder, g: &mut Group, w: f32, h: f32, y0: f32, dark: Material) {
    let screens = if w > 1.3 && b.chance(0.4) { 2 } else { 1 };
    let screen_label = if b.chance(0.25) {
        label::TELEVISION
    } else {
        label::OTHER_PROP
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
}

/// The chair, pulled up to the desk and facing it, and maybe a box under the desk.
fn desk_chair_and_box(b: &mut Builder, g: &mut Group, w: f32, d: f32, y0: f32) {
    let (c, sn) = yaw(std::f64::consts::PI + b.r(-0.5, 0.5) as f64);
    let cp = L.sub([b.r(-0.2, 0.2), y0 + d + b.r(0.05, 0.35), 0.0], c, sn);
    chair(b, g, &cp);
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

/// A table with chairs around it and things on it.
pub fn dining_table(b: &mut Builder) -> Group {
    let mut g = Group::default();
    let (w, d, h) = (b.r(1.1, 1.8), b.r(0.75, 1.0), b.r(0.72, 0.77));
    let wood = b.wood();
    let s = b.seed();
    top_on_legs(&mut g, &L, [w, d, h], 0.06, label::TABLE, wood, s);
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
    top_on_legs(&mut g, &L, [w, d, h], 0.04, label::TABLE, wood, s);
    let n = b.rng.random_range(1..4);
    props(b, &mut g, -w * 0.5, w * 0.5, -d * 0.5, d * 0.5, h, n);
    g.focus.push(V3::new(0.0, 0.0, h));
    g
}
