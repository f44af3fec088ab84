//! FAST-9 corners (Rosten & Drummond 2006) with their scores and 3x3 non-maximum
//! suppression, as OpenCV's `FAST` computes them for ORB (step 3 of the pipeline).

use image::GrayImage;
use rayon::prelude::*;

/// A FAST corner at integer level coordinates with its score: the largest
/// threshold for which it is still a corner.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FastCorner {
    /// Column of the corner in its pyramid level's image, pixels.
    pub x: u32,
    /// Row of the corner in its pyramid level's image, pixels.
    pub y: u32,
    /// FAST-9 score: the largest threshold at which the pixel is still a corner.
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

/// Whether the 16-bit circle mask `m` has 9 contiguous set bits, around the circle.
fn has_arc_of_9(m: u32) -> bool {
    let m = m | (m << 16);
    (1..9).fold(m, |run, i| run & (m >> i)) & 0xffff != 0
}

/// The necessary condition on the compass pixels (circle pixels 0, 4, 8, 12, minus the
/// centre): any arc of 9 holds two neighbouring ones, so two neighbours must both be
/// brighter than `t` or both darker than `-t`.
#[inline]
fn compass_test(compass: [i16; 4], t: i16) -> bool {
    let bright = compass.map(|d| u8::from(d > t));
    let dark = compass.map(|d| u8::from(d < -t));
    let pairs = |m: [u8; 4]| (m[0] & m[1]) | (m[1] & m[2]) | (m[2] & m[3]) | (m[3] & m[0]);
    pairs(bright) | pairs(dark) != 0
}

/// FAST-9 score of pixel `(x, y)` (at least 3 px from the border; [`fast_corners`] asks
/// only for pixels that pass [`compass_test`]): 0 when it is not a
/// corner (no arc of 9 contiguous circle pixels all brighter than `centre + t` or all
/// darker than `centre - t`), else the largest such `t`.
fn fast_score(data: &[u8], w: usize, x: usize, y: usize, t: i16) -> u8 {
    let c = data[y * w + x] as i16;
    let px = |k: usize| {
        let (dx, dy) = CIRCLE[k];
        data[(y as i32 + dy) as usize * w + (x as i32 + dx) as usize] as i16 - c
    };
    let mut d = [0i16; 16];
    for (k, v) in d.iter_mut().enumerate() {
        *v = px(k);
    }
    // A corner at all (the score below exceeds `t` exactly then): an arc of 9 brighter
    // or darker circle pixels, found on bit masks.
    let (mut bright, mut dark) = (0u32, 0u32);
    for (k, &v) in d.iter().enumerate() {
        bright |= u32::from(v > t) << k;
        dark |= u32::from(v < -t) << k;
    }
    if !has_arc_of_9(bright) && !has_arc_of_9(dark) {
        return 0;
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
            let (up, mid, down) = (
                &data[(y - 3) * w..(y - 2) * w],
                &data[y * w..(y + 1) * w],
                &data[(y + 3) * w..(y + 4) * w],
            );
            // The compass test for the whole row at once (branch-free, so it vectorises),
            // read straight from the rows and marked in the row itself: most pixels stop
            // here, the marked ones are scored.
            let n = w - 6;
            let taps = (up[3..w - 3].iter().zip(&mid[6..]))
                .zip(down[3..w - 3].iter().zip(&mid[..n]))
                .zip(&mid[3..w - 3]);
            for (mark, (((&n0, &e), (&s0, &w0)), &c)) in row[3..w - 3].iter_mut().zip(taps) {
                let c = c as i16;
                *mark = u8::from(compass_test([n0, e, s0, w0].map(|v| v as i16 - c), t));
            }
            for (x, s) in row.iter_mut().enumerate().filter(|(_, s)| **s != 0) {
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

    /// FAST as first written: every pixel's full arc scan, then the suppression.
    fn reference_corners(img: &GrayImage, t: u8) -> Vec<FastCorner> {
        let (w, h) = (img.width() as i32, img.height() as i32);
        let score = |x: i32, y: i32| -> u8 {
            let p = |x: i32, y: i32| img.get_pixel(x as u32, y as u32)[0] as i16;
            let d: Vec<i16> = CIRCLE
                .iter()
                .map(|&(dx, dy)| p(x + dx, y + dy) - p(x, y))
                .collect();
            let best = (0..16)
                .map(|s| {
                    let arc = (s..s + 9).map(|k| d[k % 16]);
                    let lo = arc.clone().min().unwrap();
                    let hi = arc.max().unwrap();
                    lo.max(-hi)
                })
                .max()
                .unwrap();
            if best > t as i16 { (best - 1) as u8 } else { 0 }
        };
        let s = |x: i32, y: i32| {
            if x < 3 || y < 3 || x >= w - 3 || y >= h - 3 {
                0
            } else {
                score(x, y)
            }
        };
        let mut out = Vec::new();
        for y in 3..h - 3 {
            for x in 3..w - 3 {
                let v = s(x, y);
                let max = (-1..=1)
                    .all(|dy| (-1..=1).all(|dx| (dx == 0 && dy == 0) || v > s(x + dx, y + dy)));
                if v > 0 && max {
                    out.push(FastCorner {
                        x: x as u32,
                        y: y as u32,
                        score: v,
                    });
                }
            }
        }
        out
    }

    #[test]
    fn the_early_tests_reject_no_corner() {
        let mut state = 0x2545_f491_u32;
        for (w, h, t) in [(48, 40, 20), (33, 17, 7), (7, 7, 1), (64, 48, 40)] {
            let img = GrayImage::from_fn(w, h, |x, y| {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                // Blocks of noise: corners, edges and flat patches.
                image::Luma([((state % 160) + 40 * ((x / 5 + y / 7) % 3)) as u8])
            });
            let found = fast_corners(&img, t);
            assert_eq!(found, reference_corners(&img, t), "{w}x{h}, t {t}");
            assert!(w < 10 || !found.is_empty());
        }
    }

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
