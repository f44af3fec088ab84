//! Orientation by the intensity centroid and steered BRIEF (rBRIEF) descriptors
//! (steps 5 and 6 of the pipeline), with OpenCV's learned sampling pattern.

use image::GrayImage;
use rayon::prelude::*;

/// A 256-bit binary descriptor (bit `k` of byte `i` is comparison `8 i + k`).
pub type Descriptor = [u8; 32];

/// Side of the square patch the pattern was learned on.
pub(super) const PATCH_SIZE: usize = 31;
const HALF_PATCH: i32 = 15;

/// Half-widths of the rows of the radius-15 disc (OpenCV's `umax`, made symmetric).
pub(super) fn disc_half_widths() -> [i32; HALF_PATCH as usize + 2] {
    let mut umax = [0i32; HALF_PATCH as usize + 2];
    let hp = HALF_PATCH as f64;
    let vmax = (hp * std::f64::consts::SQRT_2 / 2.0 + 1.0).floor() as usize;
    let vmin = (hp * std::f64::consts::SQRT_2 / 2.0).ceil() as usize;
    for (v, u) in umax.iter_mut().enumerate().take(vmax + 1) {
        *u = (hp * hp - (v * v) as f64).sqrt().round() as i32;
    }
    let mut v0 = 0usize;
    let mut v = HALF_PATCH as usize;
    while v >= vmin {
        while umax[v0] == umax[v0 + 1] {
            v0 += 1;
        }
        umax[v] = v0 as i32;
        v0 += 1;
        v -= 1;
    }
    umax
}

/// Orientation of the intensity centroid of the disc around `(x, y)`, degrees in [0, 360).
pub(super) fn ic_angle(img: &GrayImage, x: i32, y: i32, umax: &[i32]) -> f32 {
    let w = img.width() as i32;
    let d = img.as_raw();
    let p = |xx: i32, yy: i32| d[(yy * w + xx) as usize] as i64;
    let (mut m01, mut m10) = (0i64, 0i64);
    for u in -HALF_PATCH..=HALF_PATCH {
        m10 += u as i64 * p(x + u, y);
    }
    for v in 1..=HALF_PATCH {
        let dmax = umax[v as usize];
        let mut v_sum = 0i64;
        for u in -dmax..=dmax {
            let (plus, minus) = (p(x + u, y + v), p(x + u, y - v));
            v_sum += plus - minus;
            m10 += u as i64 * (plus + minus);
        }
        m01 += v as i64 * v_sum;
    }
    let a = (m01 as f64).atan2(m10 as f64).to_degrees();
    (if a < 0.0 { a + 360.0 } else { a }) as f32
}

/// Index reflected into `[0, n)` without repeating the edge (OpenCV's BORDER_REFLECT_101).
fn reflect101(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let mut i = i;
    while i < 0 || i >= n {
        i = if i < 0 { -i } else { 2 * n - 2 - i };
    }
    i as usize
}

/// The normalised taps of a 7-tap Gaussian with sigma 2.
fn blur_kernel() -> [f32; 7] {
    let mut k = [0f32; 7];
    for (i, v) in k.iter_mut().enumerate() {
        let d = i as f32 - 3.0;
        *v = (-d * d / 8.0).exp();
    }
    let s: f32 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    k
}

/// 7x7 Gaussian blur with sigma 2 and reflected borders.
pub(super) fn gaussian_blur_7x7(img: &GrayImage) -> GrayImage {
    let (w, h) = (img.width() as usize, img.height() as usize);
    let k = blur_kernel();
    let d = img.as_raw();
    // Each sum is taken tap by tap in the same order everywhere (the interior's loops
    // vectorise across pixels), so the result does not depend on where a pixel lies.
    let tap_sum = |v: [f32; 7]| (1..7).fold(k[0] * v[0], |s, j| s + k[j] * v[j]);
    let mut tmp = vec![0f32; w * h];
    tmp.par_chunks_mut(w)
        .zip(d.par_chunks(w))
        .for_each(|(row, src)| {
            let at = |x: usize, j: usize| src[reflect101(x as isize + j as isize - 3, w)] as f32;
            // The three pixels at each end (every pixel of a row narrower than 7).
            let left = w.min(3);
            for x in (0..left).chain(w.saturating_sub(3).max(left)..w) {
                row[x] = tap_sum(std::array::from_fn(|j| at(x, j)));
            }
            if w > 6 {
                let n = w - 6;
                let taps = (src[..n].iter().zip(&src[1..]).zip(&src[2..]).zip(&src[3..]))
                    .zip(src[4..].iter().zip(&src[5..]).zip(&src[6..]));
                for (o, ((((&a, &b), &c), &d), ((&e, &f), &g))) in
                    row[3..w - 3].iter_mut().zip(taps)
                {
                    *o = tap_sum([a, b, c, d, e, f, g].map(f32::from));
                }
            }
        });
    let mut out = vec![0u8; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let rows: [&[f32]; 7] = std::array::from_fn(|j| {
            let yy = reflect101(y as isize + j as isize - 3, h);
            &tmp[yy * w..(yy + 1) * w]
        });
        let [r0, r1, r2, r3, r4, r5, r6] = rows;
        let taps = r0.iter().zip(r1).zip(r2).zip(r3).zip(r4).zip(r5).zip(r6);
        for (o, ((((((&a, &b), &c), &d), &e), &f), &g)) in row.iter_mut().zip(taps) {
            *o = super::round_u8(tap_sum([a, b, c, d, e, f, g]));
        }
    });
    GrayImage::from_raw(w as u32, h as u32, out).unwrap_or_default()
}

/// `x.round_ties_even()` for `|x| < 2^22` without a libm call: adding 1.5 * 2^23 leaves no
/// bits below the unit, so the sum is rounded to an integer, ties to even (the added
/// constant is even), and taking the constant away again is exact.
fn round_ties_even_small(x: f32) -> i32 {
    const MAGIC: f32 = 12_582_912.0;
    ((x + MAGIC) - MAGIC) as i32
}

/// Steered BRIEF descriptor at integer level position `(x, y)` with orientation
/// `angle` (degrees) on the smoothed level image.
pub(super) fn steered_brief(smoothed: &GrayImage, x: i32, y: i32, angle: f32) -> Descriptor {
    let w = smoothed.width() as i32;
    let d = smoothed.as_raw();
    let (b, a) = angle.to_radians().sin_cos();
    let value = |px: i8, py: i8| {
        let (px, py) = (px as f32, py as f32);
        let rx = round_ties_even_small(px * a - py * b);
        let ry = round_ties_even_small(px * b + py * a);
        d[((y + ry) * w + x + rx) as usize]
    };
    let mut desc = [0u8; 32];
    for (i, pair) in BIT_PATTERN_31.iter().enumerate() {
        if value(pair[0], pair[1]) < value(pair[2], pair[3]) {
            desc[i / 8] |= 1 << (i % 8);
        }
    }
    desc
}

// The test pairs below are `bit_pattern_31_` of OpenCV's
// `modules/features2d/src/orb.cpp` (authors Ethan Rublee, Vincent Rabaud, Gary
// Bradski), distributed under this licence:
//
// Copyright (c) 2009, Willow Garage, Inc.
// All rights reserved.
//
// Redistribution and use in source and binary forms, with or without
// modification, are permitted provided that the following conditions are met:
//  * Redistributions of source code must retain the above copyright notice, this
//    list of conditions and the following disclaimer.
//  * Redistributions in binary form must reproduce the above copyright notice,
//    this list of conditions and the following disclaimer in the documentation
//    and/or other materials provided with the distribution.
//  * Neither the name of the Willow Garage nor the names of its contributors may
//    be used to endorse or promote products derived from this software without
//    specific prior written permission.
//
// THIS SOFTWARE IS PROVIDED BY THE COPYRIGHT HOLDERS AND CONTRIBUTORS "AS IS" AND
// ANY EXPRESS OR IMPLIED WARRANTIES, INCLUDING, BUT NOT LIMITED TO, THE IMPLIED
// WARRANTIES OF MERCHANTABILITY AND FITNESS FOR A PARTICULAR PURPOSE ARE
// DISCLAIMED. IN NO EVENT SHALL THE COPYRIGHT OWNER OR CONTRIBUTORS BE LIABLE FOR
// ANY DIRECT, INDIRECT, INCIDENTAL, SPECIAL, EXEMPLARY, OR CONSEQUENTIAL DAMAGES
// (INCLUDING, BUT NOT LIMITED TO, PROCUREMENT OF SUBSTITUTE GOODS OR SERVICES;
// LOSS OF USE, DATA, OR PROFITS; OR BUSINESS INTERRUPTION) HOWEVER CAUSED AND ON
// ANY THEORY OF LIABILITY, WHETHER IN CONTRACT, STRICT LIABILITY, OR TORT
// (INCLUDING NEGLIGENCE OR OTHERWISE) ARISING IN ANY WAY OUT OF THE USE OF THIS
// SOFTWARE, EVEN IF ADVISED OF THE POSSIBILITY OF SUCH DAMAGE.

/// OpenCV's learned rBRIEF test pairs `(x1, y1, x2, y2)` for a 31x31 patch (bit `i`
/// is set when the smoothed intensity at the first point is below the second's).
#[rustfmt::skip]
const BIT_PATTERN_31: [[i8; 4]; 256] = [
    [8, -3, 9, 5], [4, 2, 7, -12], [-11, 9, -8, 2], [7, -12, 12, -13],
    [2, -13, 2, 12], [1, -7, 1, 6], [-2, -10, -2, -4], [-13, -13, -11, -8],
    [-13, -3, -12, -9], [10, 4, 11, 9], [-13, -8, -8, -9], [-11, 7, -9, 12],
    [7, 7, 12, 6], [-4, -5, -3, 0], [-13, 2, -12, -3], [-9, 0, -7, 5],
    [12, -6, 12, -1], [-3, 6, -2, 12], [-6, -13, -4, -8], [11, -13, 12, -8],
    [4, 7, 5, 1], [5, -3, 10, -3], [3, -7, 6, 12], [-8, -7, -6, -2],
    [-2, 11, -1, -10], [-13, 12, -8, 10], [-7, 3, -5, -3], [-4, 2, -3, 7],
    [-10, -12, -6, 11], [5, -12, 6, -7], [5, -6, 7, -1], [1, 0, 4, -5],
    [9, 11, 11, -13], [4, 7, 4, 12], [2, -1, 4, 4], [-4, -12, -2, 7],
    [-8, -5, -7, -10], [4, 11, 9, 12], [0, -8, 1, -13], [-13, -2, -8, 2],
    [-3, -2, -2, 3], [-6, 9, -4, -9], [8, 12, 10, 7], [0, 9, 1, 3],
    [7, -5, 11, -10], [-13, -6, -11, 0], [10, 7, 12, 1], [-6, -3, -6, 12],
    [10, -9, 12, -4], [-13, 8, -8, -12], [-13, 0, -8, -4], [3, 3, 7, 8],
    [5, 7, 10, -7], [-1, 7, 1, -12], [3, -10, 5, 6], [2, -4, 3, -10],
    [-13, 0, -13, 5], [-13, -7, -12, 12], [-13, 3, -11, 8], [-7, 12, -4, 7],
    [6, -10, 12, 8], [-9, -1, -7, -6], [-2, -5, 0, 12], [-12, 5, -7, 5],
    [3, -10, 8, -13], [-7, -7, -4, 5], [-3, -2, -1, -7], [2, 9, 5, -11],
    [-11, -13, -5, -13], [-1, 6, 0, -1], [5, -3, 5, 2], [-4, -13, -4, 12],
    [-9, -6, -9, 6], [-12, -10, -8, -4], [10, 2, 12, -3], [7, 12, 12, 12],
    [-7, -13, -6, 5], [-4, 9, -3, 4], [7, -1, 12, 2], [-7, 6, -5, 1],
    [-13, 11, -12, 5], [-3, 7, -2, -6], [7, -8, 12, -7], [-13, -7, -11, -12],
    [1, -3, 12, 12], [2, -6, 3, 0], [-4, 3, -2, -13], [-1, -13, 1, 9],
    [7, 1, 8, -6], [1, -1, 3, 12], [9, 1, 12, 6], [-1, -9, -1, 3],
    [-13, -13, -10, 5], [7, 7, 10, 12], [12, -5, 12, 9], [6, 3, 7, 11],
    [5, -13, 6, 10], [2, -12, 2, 3], [3, 8, 4, -6], [2, 6, 12, -13],
    [9, -12, 10, 3], [-8, 4, -7, 9], [-11, 12, -4, -6], [1, 12, 2, -8],
    [6, -9, 7, -4], [2, 3, 3, -2], [6, 3, 11, 0], [3, -3, 8, -8],
    [7, 8, 9, 3], [-11, -5, -6, -4], [-10, 11, -5, 10], [-5, -8, -3, 12],
    [-10, 5, -9, 0], [8, -1, 12, -6], [4, -6, 6, -11], [-10, 12, -8, 7],
    [4, -2, 6, 7], [-2, 0, -2, 12], [-5, -8, -5, 2], [7, -6, 10, 12],
    [-9, -13, -8, -8], [-5, -13, -5, -2], [8, -8, 9, -13], [-9, -11, -9, 0],
    [1, -8, 1, -2], [7, -4, 9, 1], [-2, 1, -1, -4], [11, -6, 12, -11],
    [-12, -9, -6, 4], [3, 7, 7, 12], [5, 5, 10, 8], [0, -4, 2, 8],
    [-9, 12, -5, -13], [0, 7, 2, 12], [-1, 2, 1, 7], [5, 11, 7, -9],
    [3, 5, 6, -8], [-13, -4, -8, 9], [-5, 9, -3, -3], [-4, -7, -3, -12],
    [6, 5, 8, 0], [-7, 6, -6, 12], [-13, 6, -5, -2], [1, -10, 3, 10],
    [4, 1, 8, -4], [-2, -2, 2, -13], [2, -12, 12, 12], [-2, -13, 0, -6],
    [4, 1, 9, 3], [-6, -10, -3, -5], [-3, -13, -1, 1], [7, 5, 12, -11],
    [4, -2, 5, -7], [-13, 9, -9, -5], [7, 1, 8, 6], [7, -8, 7, 6],
    [-7, -4, -7, 1], [-8, 11, -7, -8], [-13, 6, -12, -8], [2, 4, 3, 9],
    [10, -5, 12, 3], [-6, -5, -6, 7], [8, -3, 9, -8], [2, -12, 2, 8],
    [-11, -2, -10, 3], [-12, -13, -7, -9], [-11, 0, -10, -5], [5, -3, 11, 8],
    [-2, -13, -1, 12], [-1, -8, 0, 9], [-13, -11, -12, -5], [-10, -2, -10, 11],
    [-3, 9, -2, -13], [2, -3, 3, 2], [-9, -13, -4, 0], [-4, 6, -3, -10],
    [-4, 12, -2, -7], [-6, -11, -4, 9], [6, -3, 6, 11], [-13, 11, -5, 5],
    [11, 11, 12, 6], [7, -5, 12, -2], [-1, 12, 0, 7], [-4, -8, -3, -2],
    [-7, 1, -6, 7], [-13, -12, -8, -13], [-7, -2, -6, -8], [-8, 5, -6, -9],
    [-5, -1, -4, 5], [-13, 7, -8, 10], [1, 5, 5, -13], [1, 0, 10, -13],
    [9, 12, 10, -1], [5, -8, 10, -9], [-1, 11, 1, -13], [-9, -3, -6, 2],
    [-1, -10, 1, 12], [-13, 1, -8, -10], [8, -11, 10, -6], [2, -13, 3, -6],
    [7, -13, 12, -9], [-10, -10, -5, -7], [-10, -8, -8, -13], [4, -6, 8, 5],
    [3, 12, 8, -13], [-4, 2, -3, -3], [5, -13, 10, -12], [4, -13, 5, -1],
    [-9, 9, -4, 3], [0, 3, 3, -9], [-12, 1, -6, 1], [3, 2, 4, -8],
    [-10, -10, -10, 9], [8, -13, 12, 12], [-8, -12, -6, -5], [2, 2, 3, 7],
    [10, 6, 11, -8], [6, 8, 8, -12], [-7, 10, -6, 5], [-3, -9, -3, 9],
    [-1, -13, -1, 5], [-3, -7, -3, 4], [-8, -2, -8, 3], [4, 2, 12, 12],
    [2, -5, 3, 11], [6, -9, 11, -13], [3, -1, 7, 12], [11, -1, 12, 4],
    [-3, 0, -3, 6], [4, -11, 4, 12], [2, -4, 2, 1], [-10, -6, -8, 1],
    [-13, 7, -11, 1], [-13, 12, -11, -13], [6, 0, 11, -13], [0, -1, 1, 4],
    [-13, 3, -9, -2], [-9, 8, -6, -3], [-13, -6, -8, -2], [5, -9, 8, 10],
    [2, 7, 3, -9], [-1, -6, -1, -1], [9, 5, 11, -2], [11, -3, 12, -8],
    [3, 0, 3, 5], [-1, 4, 0, 10], [3, -6, 4, 5], [-13, 0, -10, 5],
    [5, 8, 12, 11], [8, 9, 9, -6], [7, -4, 8, -12], [-10, 4, -10, 9],
    [7, 3, 12, 4], [9, -7, 10, -2], [7, 0, 12, -2], [-1, -6, 0, -11],
];

#[cfg(test)]
mod tests {
    use super::super::tests::{FIXTURE, fixture_gray};
    use super::super::{OrbConfig, detect_and_compute};
    use crate::dataset::TumSequence;
    use crate::features::bf_matcher::bf_match;

    /// The blur as first written (the same taps): every tap through the reflected index,
    /// `f32::round`.
    fn reference_blur(img: &image::GrayImage) -> Vec<u8> {
        let (w, h) = (img.width() as usize, img.height() as usize);
        let k = super::blur_kernel();
        let d = img.as_raw();
        let r = |i: isize, n: usize| super::reflect101(i, n);
        let tmp: Vec<f32> = (0..w * h)
            .map(|p| {
                let (x, y) = (p % w, p / w);
                (0..7)
                    .map(|j| k[j] * d[y * w + r(x as isize + j as isize - 3, w)] as f32)
                    .sum()
            })
            .collect();
        (0..w * h)
            .map(|p| {
                let (x, y) = (p % w, p / w);
                let v: f32 = (0..7)
                    .map(|j| k[j] * tmp[r(y as isize + j as isize - 3, h) * w + x])
                    .sum();
                v.round().clamp(0.0, 255.0) as u8
            })
            .collect()
    }

    #[test]
    fn the_blur_equals_the_plain_one_to_the_bit() {
        let mut state = 0x9e37_79b9_u32;
        for (w, h) in [(37, 23), (7, 9), (5, 4), (1, 1), (64, 48)] {
            let img = image::GrayImage::from_fn(w, h, |x, y| {
                state ^= state << 13;
                state ^= state >> 17;
                state ^= state << 5;
                // Noise on a ramp: every grey level, and sums landing near halves.
                image::Luma([((state % 97) + 3 * x + 2 * y).min(255) as u8])
            });
            assert_eq!(
                super::gaussian_blur_7x7(&img).into_raw(),
                reference_blur(&img),
                "{w}x{h}"
            );
        }
    }

    #[test]
    fn rounding_without_libm_agrees_with_round() {
        assert_eq!(super::round_ties_even_small(2.5), 2);
        assert_eq!(super::round_ties_even_small(-2.5), -2);
        assert_eq!(super::round_ties_even_small(3.5), 4);
        for i in -40_000..40_000 {
            let x = i as f32 * 0.000_75 + 0.25;
            assert_eq!(
                super::round_ties_even_small(x),
                x.round_ties_even() as i32,
                "{x}"
            );
        }
        for v in [
            -3.0f32, -0.5, -0.0, 0.0, 0.49999997, 0.5, 1.5, 254.49998, 254.5, 255.0, 300.0,
        ]
        .into_iter()
        .chain((0..300_000).map(|i| i as f32 * 0.000_9 - 10.0))
        {
            assert_eq!(
                super::super::round_u8(v),
                v.round().clamp(0.0, 255.0) as u8,
                "{v}"
            );
        }
        assert_eq!(super::super::round_u8(f32::NAN), 0);
    }

    #[test]
    fn orientation_makes_descriptors_survive_a_90_degree_rotation() {
        let seq = TumSequence::open(FIXTURE).unwrap();
        let img = fixture_gray(&seq, 0);
        let rot = image::imageops::rotate90(&img); // (x, y) -> (h - 1 - y, x)
        let cfg = OrbConfig::default();
        let f0 = detect_and_compute(&img, &cfg).unwrap();
        let f1 = detect_and_compute(&rot, &cfg).unwrap();
        let h = img.height() as f32;
        let matches = bf_match(&f0.descriptors, &f1.descriptors, true);
        let consistent = matches
            .iter()
            .filter(|m| {
                let (k0, k1) = (f0.keypoints[m.query], f1.keypoints[m.train]);
                let (ex, ey) = (h - 1.0 - k0.y, k0.x);
                (k1.x - ex).hypot(k1.y - ey) <= 2.0
            })
            .count();
        // The angles turn by 90 degrees with the image.
        let turned = matches
            .iter()
            .filter(|m| {
                let d = f1.keypoints[m.train].angle - f0.keypoints[m.query].angle - 90.0;
                d.rem_euclid(360.0).min((-d).rem_euclid(360.0)) < 5.0
            })
            .count();
        eprintln!(
            "rotated 90 deg: {} matches, {consistent} at the rotated position, {turned} with angle +90",
            matches.len()
        );
        assert!(matches.len() >= 350, "{} matches", matches.len());
        assert!(consistent as f64 >= 0.9 * matches.len() as f64);
        assert!(turned as f64 >= 0.9 * matches.len() as f64);
    }
}
