//! Things on and against the walls (doors, windows, pictures, whiteboards) and
//! small free-standing items (floor lamps, plants, bags, boxes, rugs).

use super::parts::*;
use super::{Builder, Group};
use crate::classes::label;
use crate::synth::geom::V3;
use crate::synth::texture::{Material, srgb};
use rand::RngExt;

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
