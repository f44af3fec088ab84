//! Platform-independent maths for the generator: integer hashes, hash-based value
//! noise and Gaussian-like samples, and `sin`/`cos`/`atan2` built from IEEE basic
//! operations only (`+ - * / sqrt`, correctly rounded everywhere), so that a seed
//! gives the same scene, trajectory and images on every machine. The platform's
//! libm transcendental functions may differ in the last bit between systems.

use std::f64::consts::{FRAC_PI_2, PI};

/// A 32-bit integer hash (lowbias32 by C. Wellons): good avalanche, cheap.
#[inline]
pub fn hash(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x21f0_aaad);
    x ^= x >> 15;
    x = x.wrapping_mul(0x735a_2d97);
    x ^= x >> 15;
    x
}

/// Hash of several integers.
#[inline]
pub(crate) fn hash2(a: u32, b: u32) -> u32 {
    hash(a ^ hash(b.wrapping_add(0x9e37_79b9)))
}

/// Hash of three integers.
#[inline]
pub(crate) fn hash3(a: u32, b: u32, c: u32) -> u32 {
    hash2(hash2(a, b), c)
}

/// Hash of four integers.
#[inline]
pub(crate) fn hash4(a: u32, b: u32, c: u32, d: u32) -> u32 {
    hash2(hash3(a, b, c), d)
}

/// A hash mapped to `[0, 1)`.
#[inline]
pub fn unit(h: u32) -> f32 {
    (h >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// An approximately standard-normal value from one hash (Irwin-Hall sum of
/// four 8-bit uniforms, rescaled to unit variance; tails end at ±3.46).
#[inline]
pub(crate) fn gauss(h: u32) -> f32 {
    let s = (h & 0xff) + ((h >> 8) & 0xff) + ((h >> 16) & 0xff) + (h >> 24);
    // Each byte is uniform on 0..=255: mean 127.5, variance (256² - 1) / 12.
    (s as f32 - 510.0) * (1.0 / 147.80)
}

/// `x.floor()` for `|x| < 2^31`, inlined (the x86-64 baseline has no rounding
/// instruction, so `f32::floor` is a library call).
#[inline]
pub fn floor(x: f32) -> f32 {
    let i = x as i32 as f32;
    if i > x { i - 1.0 } else { i }
}

/// Fast `floor` and a fractional part in `[0, 1)` as methods.
pub(crate) trait FastFloor {
    /// [`floor`] of `self`.
    fn ff(self) -> Self;
    /// `self - floor(self)`, in `[0, 1)`.
    fn fr(self) -> Self;
}

impl FastFloor for f32 {
    #[inline]
    fn ff(self) -> f32 {
        floor(self)
    }
    #[inline]
    fn fr(self) -> f32 {
        self - floor(self)
    }
}

#[inline]
fn smooth(t: f32) -> f32 {
    t * t * (3.0 - 2.0 * t)
}

/// Smooth 2D value noise in `[0, 1]`, lattice spacing 1.
pub(crate) fn noise2(x: f32, y: f32, seed: u32) -> f32 {
    let (fx, fy) = (floor(x), floor(y));
    let (ix, iy) = (fx as i32 as u32, fy as i32 as u32);
    let (tx, ty) = (smooth(x - fx), smooth(y - fy));
    let s = seed.wrapping_mul(0xcb1a_b31f);
    let v = |dx: u32, dy: u32| {
        let (x, y) = (ix.wrapping_add(dx), iy.wrapping_add(dy));
        unit(hash(
            x.wrapping_mul(0x8da6_b343) ^ y.wrapping_mul(0xd816_3841) ^ s,
        ))
    };
    let (v00, v10, v01, v11) = (v(0, 0), v(1, 0), v(0, 1), v(1, 1));
    let a = v00 + (v10 - v00) * tx;
    let b = v01 + (v11 - v01) * tx;
    a + (b - a) * ty
}

/// Smooth 1D value noise in `[0, 1]`.
pub(crate) fn noise1(x: f32, seed: u32) -> f32 {
    let fx = floor(x);
    let ix = fx as i32 as u32;
    let t = smooth(x - fx);
    let a = unit(hash2(ix, seed));
    let b = unit(hash2(ix.wrapping_add(1), seed));
    a + (b - a) * t
}

/// Fractal sum of `octaves` noise layers (each twice the frequency, half the
/// amplitude), normalised to `[0, 1]`.
pub(crate) fn fbm2(x: f32, y: f32, seed: u32, octaves: u32) -> f32 {
    let (mut sum, mut amp, mut norm, mut f) = (0.0, 1.0, 0.0, 1.0);
    for o in 0..octaves {
        sum += amp * noise2(x * f, y * f, seed.wrapping_add(o * 1013));
        norm += amp;
        amp *= 0.5;
        f *= 2.0;
    }
    sum / norm
}

/// Fractal 1D noise in `[0, 1]`.
pub(crate) fn fbm1(x: f32, seed: u32, octaves: u32) -> f32 {
    let (mut sum, mut amp, mut norm, mut f) = (0.0, 1.0, 0.0, 1.0);
    for o in 0..octaves {
        sum += amp * noise1(x * f, seed.wrapping_add(o * 7919));
        norm += amp;
        amp *= 0.5;
        f *= 2.0;
    }
    sum / norm
}

/// `sin` and `cos` of `x` (radians) to about 1e-16, from basic operations.
pub(crate) fn sin_cos(x: f64) -> (f64, f64) {
    if !x.is_finite() {
        return (f64::NAN, f64::NAN);
    }
    // Cody-Waite reduction by pi/2 in two parts.
    const P1: f64 = FRAC_PI_2;
    const P2: f64 = 6.123_233_995_736_766e-17;
    let k = (x * (1.0 / FRAC_PI_2)).round();
    let r = (x - k * P1) - k * P2;
    let r2 = r * r;
    // Taylor series on |r| <= pi/4, truncation error below 1e-17.
    let mut s = 0.0;
    let mut c = 0.0;
    for n in (0..=10).rev() {
        let n = n as f64;
        s = 1.0 - s * r2 / ((2.0 * n + 2.0) * (2.0 * n + 3.0));
        c = 1.0 - c * r2 / ((2.0 * n + 1.0) * (2.0 * n + 2.0));
    }
    let (s, c) = (s * r, c);
    match (k as i64).rem_euclid(4) {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// `atan(x)` from basic operations (argument halving, then a short series).
pub(crate) fn atan(x: f64) -> f64 {
    if x.is_nan() {
        return f64::NAN;
    }
    let (sign, a) = if x < 0.0 { (-1.0, -x) } else { (1.0, x) };
    let (inverted, mut a) = if a > 1.0 { (true, 1.0 / a) } else { (false, a) };
    // atan(a) = 2 atan(a / (1 + sqrt(1 + a²))): three halvings give |a| < 0.1.
    for _ in 0..3 {
        a /= 1.0 + (1.0 + a * a).sqrt();
    }
    let a2 = a * a;
    let mut s = 0.0;
    for n in (0..=9).rev() {
        s = 1.0 / (2 * n + 1) as f64 - a2 * s;
    }
    let r = 8.0 * a * s;
    sign * if inverted { FRAC_PI_2 - r } else { r }
}

/// `atan2(y, x)` in `(-pi, pi]`.
pub(crate) fn atan2(y: f64, x: f64) -> f64 {
    if x > 0.0 {
        atan(y / x)
    } else if x < 0.0 {
        if y >= 0.0 {
            atan(y / x) + PI
        } else {
            atan(y / x) - PI
        }
    } else if y > 0.0 {
        FRAC_PI_2
    } else if y < 0.0 {
        -FRAC_PI_2
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trig_matches_libm() {
        for i in -2000..2000 {
            let x = i as f64 * 0.01731;
            let (s, c) = sin_cos(x);
            // Range reduction loses a few ulps of |x|.
            let tol = 4e-16 * x.abs().max(2.0);
            assert!((s - x.sin()).abs() < tol, "sin {x}");
            assert!((c - x.cos()).abs() < tol, "cos {x}");
            let y = (i as f64 * 0.37).cos() * 3.0;
            assert!((atan2(y, x) - y.atan2(x)).abs() < 1e-15, "atan2 {y} {x}");
        }
        assert!((atan(1e9) - 1e9f64.atan()).abs() < 1e-15);
    }

    #[test]
    fn noise_and_gauss_are_in_range() {
        let mut sum = 0.0f64;
        let mut sq = 0.0f64;
        let n = 100_000;
        for i in 0..n {
            let g = gauss(hash(i)) as f64;
            sum += g;
            sq += g * g;
            let v = fbm2(i as f32 * 0.013, i as f32 * 0.007, 3, 4);
            assert!((0.0..=1.0).contains(&v));
        }
        let mean = sum / n as f64;
        let var = sq / n as f64 - mean * mean;
        assert!(
            mean.abs() < 0.02 && (var - 1.0).abs() < 0.03,
            "{mean} {var}"
        );
    }
}
