//! The picture of the middle pair's matches (like the paper's Figs. 7-8).

use super::matching::PixelMatches;
use crate::metrics::matching::CORRECT_MATCH_PX;
use image::{GrayImage, Rgb, RgbImage};

/// A row of the picture: images A and B, the matches, their errors and a caption.
pub(super) type Row = (GrayImage, GrayImage, PixelMatches, Vec<Option<f64>>, String);

/// Rows of `A | B` with match lines: green correct, red wrong, grey unjudged.
pub(super) fn draw_matches(rows: &[Row]) -> RgbImage {
    let (w, h) = rows
        .first()
        .map(|r| (r.0.width(), r.0.height()))
        .unwrap_or((1, 1));
    let mut img = RgbImage::new(2 * w, h * rows.len() as u32);
    for (r, (a, b, m, errs, _)) in rows.iter().enumerate() {
        let y0 = r as u32 * h;
        for (x0, g) in [(0, a), (w, b)] {
            for (x, y, p) in g.enumerate_pixels() {
                let v = (p[0] as f32 * 0.8) as u8;
                img.put_pixel(x0 + x, y0 + y, Rgb([v, v, v]));
            }
        }
        for ((pa, pb), e) in m.iter().zip(errs) {
            let color = match e {
                Some(e) if *e <= CORRECT_MATCH_PX => Rgb([40, 220, 60]),
                Some(_) => Rgb([240, 40, 40]),
                None => Rgb([160, 160, 160]),
            };
            draw_line(
                &mut img,
                (pa.x, pa.y + y0 as f64),
                (pb.x + w as f64, pb.y + y0 as f64),
                color,
            );
        }
    }
    img
}

fn draw_line(img: &mut RgbImage, a: (f64, f64), b: (f64, f64), c: Rgb<u8>) {
    let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil() as usize).max(1);
    for k in 0..=n {
        let t = k as f64 / n as f64;
        let (x, y) = (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
        if x >= 0.0 && y >= 0.0 && (x as u32) < img.width() && (y as u32) < img.height() {
            img.put_pixel(x as u32, y as u32, c);
        }
    }
}
