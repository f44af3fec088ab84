//! Channels-last (NHWC) images for the packed inference networks, and the element-wise steps
//! between their convolutions: activations (vectorised for the CPU at hand), bilinear
//! resizing as [`super::resize_bilinear`] does it, max pooling, sums.

use rayon::prelude::*;

/// An image in channels-last layout: `data[(y·w + x)·c + ch]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Nhwc {
    /// Height, pixels.
    pub h: usize,
    /// Width, pixels.
    pub w: usize,
    /// Channels per pixel.
    pub c: usize,
    /// Values, `h * w * c` of them, channels-last.
    pub data: Vec<f32>,
}

impl Nhwc {
    /// An `h x w` image of `c` channels, all zero.
    pub fn zeros(h: usize, w: usize, c: usize) -> Self {
        Self {
            h,
            w,
            c,
            data: vec![0.0; h * w * c],
        }
    }

    /// The whole image, borrowed (rows `w` pixels apart).
    pub fn view(&self) -> NhwcView<'_> {
        NhwcView {
            h: self.h,
            w: self.w,
            c: self.c,
            stride: self.w,
            data: &self.data,
        }
    }
}

/// A borrowed channels-last image whose rows may hold more pixels than its width (a
/// convolution's output keeps the wide grid's extra columns): `data[(y·stride + x)·c + ch]`.
#[derive(Debug, Clone, Copy)]
pub struct NhwcView<'a> {
    /// Height, pixels.
    pub h: usize,
    /// Width, pixels (the pixels of a row that are the image's).
    pub w: usize,
    /// Channels per pixel.
    pub c: usize,
    /// Pixels per row, at least `w`.
    pub stride: usize,
    /// Values, channels-last, rows `stride` pixels apart.
    pub data: &'a [f32],
}

impl NhwcView<'_> {
    /// The `c` values of pixel `(y, x)`.
    pub fn pixel(&self, y: usize, x: usize) -> &[f32] {
        let at = (y * self.stride + x) * self.c;
        &self.data[at..at + self.c]
    }

    /// A compact copy.
    pub fn to_owned(self) -> Nhwc {
        let row = self.w * self.c;
        let mut data = Vec::with_capacity(self.h * row);
        for y in 0..self.h {
            let at = y * self.stride * self.c;
            data.extend_from_slice(&self.data[at..at + row]);
        }
        Nhwc {
            h: self.h,
            w: self.w,
            c: self.c,
            data,
        }
    }
}

/// What follows the convolution in the epilogue.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Activation {
    /// No activation: the convolution's output as it is.
    Identity,
    /// `max(x, 0)`.
    Relu,
    /// `min(max(x, 0), 6)` (MobileNetV2).
    Relu6,
    /// ELU with α = 1 (FPFDCNN, Table 12).
    Elu,
    /// `1 / (1 + e⁻ˣ)`.
    Sigmoid,
}

/// Defines `fn $name(args)` that runs its body compiled for AVX-512 or AVX2 + FMA when the CPU
/// has them (checked at run time), so that the compiler vectorises the loops inside with the
/// widest registers available; elsewhere the portable build.
macro_rules! simd_fn {
    ($(#[$m:meta])* $vis:vis fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $body:block) => {
        $(#[$m])*
        $vis fn $name($($arg: $ty),*) {
            #[inline(always)]
            fn imp($($arg: $ty),*) $body
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f")]
                fn v4($($arg: $ty),*) {
                    imp($($arg),*)
                }
                #[target_feature(enable = "avx2,fma")]
                fn v3($($arg: $ty),*) {
                    imp($($arg),*)
                }
                if std::arch::is_x86_feature_detected!("avx512f") {
                    // SAFETY: the CPU has AVX-512F (checked just above).
                    return unsafe { v4($($arg),*) };
                }
                if std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                {
                    // SAFETY: the CPU has AVX2 and FMA (checked just above).
                    return unsafe { v3($($arg),*) };
                }
            }
            imp($($arg),*)
        }
    };
}
pub(crate) use simd_fn;

/// Running sums kept per lane by [`sum_lanes`] and [`dot_lanes`]: a strict left-to-right `f32`
/// sum would not vectorise.
const LANES: usize = 16;

/// `Σ v[i]` in [`LANES`] running sums (inline it into a [`simd_fn`] body).
#[inline(always)]
pub(crate) fn sum_lanes(v: &[f32]) -> f32 {
    let mut acc = [0.0f32; LANES];
    let chunks = v.chunks_exact(LANES);
    let tail: f32 = chunks.remainder().iter().sum();
    for c in chunks {
        for i in 0..LANES {
            acc[i] += c[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// `Σ a[i]·b[i]` in [`LANES`] running sums (inline it into a [`simd_fn`] body).
#[inline(always)]
pub(crate) fn dot_lanes(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; LANES];
    let (ca, cb) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..LANES {
            acc[i] += x[i] * y[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

simd_fn! {
    /// Applies `act` in place (the exponential is [`exp`]'s polynomial, which vectorises).
    pub fn activate(v: &mut [f32], act: Activation) {
        match act {
            Activation::Identity => {}
            Activation::Relu => v.iter_mut().for_each(|x| *x = x.max(0.0)),
            Activation::Relu6 => v.iter_mut().for_each(|x| *x = x.clamp(0.0, 6.0)),
            // min(x, 0) keeps the exponential finite; the select vectorises.
            Activation::Elu => v.iter_mut().for_each(|x| {
                let e = exp(x.min(0.0)) - 1.0;
                *x = if *x < 0.0 { e } else { *x };
            }),
            Activation::Sigmoid => v.iter_mut().for_each(|x| *x = 1.0 / (1.0 + exp(-*x))),
        }
    }
}

simd_fn! {
    /// `acc[i] += x[i]`.
    pub(crate) fn add_assign(acc: &mut [f32], x: &[f32]) {
        for (a, &b) in acc.iter_mut().zip(x) {
            *a += b;
        }
    }
}

simd_fn! {
    /// `acc[i] = max(acc[i], x[i])`.
    fn max_assign(acc: &mut [f32], x: &[f32]) {
        for (a, &b) in acc.iter_mut().zip(x) {
            *a = a.max(b);
        }
    }
}

simd_fn! {
    /// `out[i] = a0·x0[i] + a1·x1[i]`.
    pub(crate) fn blend(out: &mut [f32], x0: &[f32], a0: f32, x1: &[f32], a1: f32) {
        for ((o, &p), &q) in out.iter_mut().zip(x0).zip(x1) {
            *o = a0 * p + a1 * q;
        }
    }
}

/// `a += b` pixel by pixel (same size).
pub fn add(a: &mut Nhwc, b: &NhwcView) {
    assert_eq!(
        [a.h, a.w, a.c],
        [b.h, b.w, b.c],
        "adding images of different sizes"
    );
    let row = a.w * a.c;
    a.data.par_chunks_mut(row).enumerate().for_each(|(y, r)| {
        let at = y * b.stride * b.c;
        add_assign(r, &b.data[at..at + row]);
    });
}

/// Max pooling with a `k×k` window (odd `k`), stride 1 and padding `k / 2` that never wins
/// (Burn's and PyTorch's `-inf` padding): a row pass, then a column pass, each taking the
/// maximum with whole rows shifted by `1..=k / 2` pixels (or rows) either way.
pub(crate) fn max_pool(x: &NhwcView, k: usize) -> Nhwc {
    let (r, c) = (k / 2, x.c);
    let row = x.w * c;
    let mut rows = NhwcView::to_owned(*x);
    rows.data
        .par_chunks_mut(row.max(1))
        .enumerate()
        .for_each(|(y, out)| {
            let src = &x.data[y * x.stride * c..][..row];
            for j in 1..=r.min(x.w.saturating_sub(1)) {
                let n = (x.w - j) * c;
                // Pixel xx takes its right neighbour xx + j, then its left one xx − j.
                max_assign(&mut out[..n], &src[j * c..]);
                max_assign(&mut out[j * c..], &src[..n]);
            }
        });
    let mut out = rows.clone();
    out.data
        .par_chunks_mut(row.max(1))
        .enumerate()
        .for_each(|(y, o)| {
            for i in y.saturating_sub(r)..(y + r + 1).min(x.h) {
                if i != y {
                    max_assign(o, &rows.data[i * row..(i + 1) * row]);
                }
            }
        });
    out
}

/// Bilinear resize to `[oh, ow]` with [`super::resize_bilinear`]'s weights (PyTorch's
/// `align_corners = False`): the column pass, then the row pass (Burn's version picks the
/// cheaper order, so results differ in the last bits only).
pub fn resize_bilinear(x: &NhwcView, [oh, ow]: [usize; 2]) -> Nhwc {
    use super::resize::taps;
    let c = x.c;
    let tx: Vec<_> = (0..ow).map(|j| taps(j, x.w, ow)).collect();
    let mut cols = Nhwc::zeros(x.h, ow, c);
    cols.data
        .par_chunks_mut(ow * c)
        .enumerate()
        .for_each(|(y, out)| {
            for (o, t) in out.chunks_exact_mut(c).zip(&tx) {
                blend(o, x.pixel(y, t.i0), t.w0, x.pixel(y, t.i1), t.w1);
            }
        });
    let mut out = Nhwc::zeros(oh, ow, c);
    let row = ow * c;
    out.data.par_chunks_mut(row).enumerate().for_each(|(y, o)| {
        let t = taps(y, x.h, oh);
        let r0 = &cols.data[t.i0 * row..(t.i0 + 1) * row];
        let r1 = &cols.data[t.i1 * row..(t.i1 + 1) * row];
        blend(o, r0, t.w0, r1, t.w1);
    });
    out
}

/// `eˣ` for `f32`, branch-free so that loops over it vectorise: `2ⁿ · p(r)` with
/// `x = n ln 2 + r`, `|r| ≤ ln 2 / 2` and `p` the degree-6 Taylor polynomial (relative error
/// below 2e-7); `x` is clamped to [−87, 88], where `eˣ` is a normal `f32`.
#[inline(always)]
pub(crate) fn exp(x: f32) -> f32 {
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    // Adding 1.5·2²³ rounds to the nearest integer n in the low mantissa bits: no rounding
    // call, which would keep the loop scalar.
    const SHIFT: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let t = x * std::f32::consts::LOG2_E + SHIFT;
    let n = t - SHIFT;
    // Fused multiply-adds: one instruction a step inside `simd_fn!` (AVX2 + FMA, AVX-512).
    let r = n.mul_add(-LN2_LO, n.mul_add(-LN2_HI, x));
    let p = [1.0 / 120.0, 1.0 / 24.0, 1.0 / 6.0, 0.5, 1.0, 1.0]
        .iter()
        .fold(1.0 / 720.0, |acc: f32, &c| acc.mul_add(r, c));
    let n = t.to_bits() as i32 - 0x4B40_0000;
    p * f32::from_bits(((n + 127) as u32) << 23)
}

/// An NCHW tensor of one image (batch 1) as [`Nhwc`].
#[cfg(test)]
pub fn from_nchw(data: &[f32], [c, h, w]: [usize; 3]) -> Nhwc {
    let mut out = Nhwc::zeros(h, w, c);
    for ch in 0..c {
        for (i, &v) in data[ch * h * w..(ch + 1) * h * w].iter().enumerate() {
            out.data[i * c + ch] = v;
        }
    }
    out
}

/// `x` as a row-major `[c, h, w]` vector (the tests' bridge to Burn's layout).
#[cfg(test)]
pub fn to_nchw(x: &NhwcView) -> Vec<f32> {
    let plane = x.h * x.w;
    let mut out = vec![0.0; x.c * plane];
    for y in 0..x.h {
        for xx in 0..x.w {
            for (ch, &v) in x.pixel(y, xx).iter().enumerate() {
                out[ch * plane + y * x.w + xx] = v;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_is_accurate_and_saturates() {
        for i in -8700..=8800 {
            let x = i as f32 / 100.0;
            let (got, want) = (exp(x), (x as f64).exp());
            assert!(
                ((got as f64 - want) / want).abs() < 3e-7,
                "exp({x}) = {got}, not {want}"
            );
        }
        assert!(exp(-1e30) > 0.0 && exp(1e30).is_finite() && exp(f32::NEG_INFINITY) > 0.0);
        let mut v = vec![-100.0f32, -1.0, 0.0, 2.0, 100.0, -1e-4];
        activate(&mut v, Activation::Elu);
        assert_eq!(v[2..5], [0.0, 2.0, 100.0]);
        assert!((v[0] + 1.0).abs() < 1e-7 && (v[1] - (-1.0f32).exp_m1()).abs() < 1e-7);
        assert!((v[5] - (-1e-4f32).exp_m1()).abs() < 1e-7);
        let mut s = vec![-100.0f32, 0.0, 100.0];
        activate(&mut s, Activation::Sigmoid);
        assert!(s[0] >= 0.0 && s[0] < 1e-37 && s[1] == 0.5 && s[2] == 1.0);
    }

    /// The window maximum pixel by pixel, straight from the definition.
    fn max_pool_reference(x: &NhwcView, k: usize) -> Vec<f32> {
        let r = (k / 2) as isize;
        let mut out = Vec::with_capacity(x.h * x.w * x.c);
        for y in 0..x.h as isize {
            for xx in 0..x.w as isize {
                for ch in 0..x.c {
                    let mut m = f32::NEG_INFINITY;
                    for i in (y - r).max(0)..(y + r + 1).min(x.h as isize) {
                        for j in (xx - r).max(0)..(xx + r + 1).min(x.w as isize) {
                            m = m.max(x.pixel(i as usize, j as usize)[ch]);
                        }
                    }
                    out.push(m);
                }
            }
        }
        out
    }

    #[test]
    fn max_pool_equals_the_window_maximum_on_wide_and_narrow_images() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        // Widths and heights below, at and above the window; rows wider than the image.
        for (h, w, c, stride, k) in [
            (1, 1, 3, 1, 5),
            (2, 3, 2, 3, 5),
            (4, 2, 5, 4, 5),
            (7, 9, 16, 9, 5),
            (6, 11, 8, 13, 5),
            (5, 6, 4, 6, 3),
        ] {
            // Small integers: ties are common.
            let data: Vec<f32> = (0..h * stride * c)
                .map(|_| rng.random_range(-4..5) as f32)
                .collect();
            let x = NhwcView {
                h,
                w,
                c,
                stride,
                data: &data,
            };
            let got = max_pool(&x, k);
            assert_eq!([got.h, got.w, got.c], [h, w, c]);
            assert_eq!(got.data, max_pool_reference(&x, k), "{h}x{w}x{c}, k {k}");
        }
    }
}
