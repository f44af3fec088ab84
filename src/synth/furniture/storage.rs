//! Storage furniture: bookshelves, shelves, cabinets, wardrobes, dressers, TV
//! stands, kitchen counters and refrigerators.

use super::parts::*;
use super::{Builder, Group};
use crate::classes::label;
use crate::synth::geom::V3;
use crate::synth::texture::{Material, srgb};
use rand::RngExt;

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
