//! FAST-9 corners (Rosten & Drummond 2006) with their scores and 3x3 non-maximum
//! suppression, as OpenCV's `FAST` computes them for ORB (step 3 of the pipeline).

use image::GrayImage;
use rayon::prelude::*;

/// A FAST corner at integer level coordinates with its score: the largest
/// threshold for which it is still a corner.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FastCorner {
    pub x: u32,
    pub y: u32,
    pub score: u8,
}

/// Bresenham circle of radius 3, clockwise from the top (x, y offsets).
const CIRCLE: [(i32, i32); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// FAST-9 score of pixel `(x, y)` (at least 3 px from the border): 0 when it is not a
/// corner (no arc of 9 contiguous circle pixels all brighter than `centre + t` or all
/// darker than `centre - t`), else the largest such `t`.
fn fast_score(data: &[u8], w: usize, x: usize, y: usize, t: i16) -> u8 {
    let c = data[y * w + x] as i16;
    let px = |k: usize| {
        let (dx, dy) = CIRCLE[k];
        data[(y as i32 + dy) as usize * w + (x as i32 + dx) as usize] as i16 - c
    };
    // Any arc of 9 contains at least two of the four compass pixels.
    let compass = [px(0), px(4), px(8), px(12)];
    let bright = compass.iter().filter(|&&d| d > t).count();
    let dark = compass.iter().filter(|&&d| d < -t).count();
    if bright < 2 && dark < 2 {
        return 0;
    }
    let mut d = [0i16; 16];
    for (k, v) in d.iter_mut().enumerate() {
        *v = px(k);
    }
    let (mut best_bright, mut best_dark) = (i16::MIN, i16::MIN);
    for start in 0..16 {
        let (mut lo, mut hi) = (i16::MAX, i16::MIN);
        for k in start..start + 9 {
            let v = d[k % 16];
            lo = lo.min(v);
            hi = hi.max(v);
        }
        best_bright = best_bright.max(lo);
        best_dark = best_dark.max(-hi);
    }
    let best = best_bright.max(best_dark);
    if best > t { (best - 1) as u8 } else { 0 }
}

/// FAST-9 corners with 3x3 non-maximum suppression (a corner survives when its score
/// is strictly above its eight neighbours'), in raster order.
pub fn fast_corners(img: &GrayImage, threshold: u8) -> Vec<FastCorner> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w < 7 || h < 7 {
        return Vec::new();
    }
    let data = img.as_raw();
    let t = threshold as i16;
    let mut scores = vec![0u8; w * h];
    scores[3 * w..(h - 3) * w]
        .par_chunks_mut(w)
        .enumerate()
        .for_each(|(r, row)| {
            let y = r + 3;
            for (x, s) in row.iter_mut().enumerate().take(w - 3).skip(3) {
                *s = fast_score(data, w, x, y, t);
            }
        });
    let mut out = Vec::new();
    for y in 3..h - 3 {
        for x in 3..w - 3 {
            let s = scores[y * w + x];
            if s == 0 {
                continue;
            }
            let is_max = (-1i32..=1).all(|dy| {
                (-1i32..=1).all(|dx| {
                    (dx == 0 && dy == 0)
                        || s > scores[(y as i32 + dy) as usize * w + (x as i32 + dx) as usize]
                })
            });
            if is_max {
                out.push(FastCorner {
                    x: x as u32,
                    y: y as u32,
                    score: s,
                });
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_finds_the_corners_of_a_bright_square() {
        // A 200-grey square on black with its four corner pixels at 255: on a binary
        // square the corner and its neighbours tie and suppress each other, as in OpenCV.
        let mut img = GrayImage::new(40, 40);
        for y in 10..30 {
            for x in 10..30 {
                let corner = (x == 10 || x == 29) && (y == 10 || y == 29);
                img.put_pixel(x, y, image::Luma([if corner { 255 } else { 200 }]));
            }
        }
        let c = fast_corners(&img, 20);
        let xy: Vec<_> = c.iter().map(|k| (k.x, k.y)).collect();
        assert_eq!(xy, vec![(10, 10), (29, 10), (10, 29), (29, 29)], "{c:?}");
        assert!(c.iter().all(|k| k.score == 254));
        assert!(fast_corners(&img, 255).is_empty());
    }
}
