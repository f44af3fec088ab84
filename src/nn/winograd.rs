//! Winograd minimal filtering (Lavin & Gray, "Fast Algorithms for Convolutional Neural
//! Networks", CVPR 2016) for the packed stride-1 convolutions of [`super::packed_conv`].
//!
//! A 4×4 tile of the input, transformed (`V = Bᵀ d B`), multiplied point by point with the
//! transformed kernel (`U = G g Gᵀ`) and transformed back (`Y = Aᵀ (U ⊙ V) A`), gives an
//! `m×m` tile of the output: F(2×2, 3×3) for 3×3 kernels and F(3×3, 2×2) for the 2×2 kernels
//! that FPFDCNN's 4×4 stride-2 convolutions become after space-to-depth. Summed over input
//! channels, the point-wise products are 16 matrix products `[tiles, c] × [c, c_out]`, against
//! 36 multiply-adds per tile and channel pair directly: 2.25x fewer. Both use the points
//! 0, ±1, ∞, whose transforms hold only 0, ±1 and ±½, so the result differs from the direct
//! sum by float rounding alone (tests below).
//!
//! Tiles are processed in bands of tile rows, one band per task: its transformed input and
//! products stay in cache, and each band writes its own output rows.

use super::nhwc::{Activation, activate, simd_fn};
use rayon::prelude::*;
use std::cell::RefCell;

/// Side of the input tile.
const N: usize = 4;
/// Transformed points per tile.
const NN: usize = N * N;
/// Tiles a band aims at: enough rows for the products to run near their peak.
const BAND_TILES: usize = 128;

// The transforms (points 0, 1, −1, ∞), written out in `bt`, `at2` and `at3` below:
// Bᵀ = [1 0 −1 0; 0 1 1 0; 0 −1 1 0; 0 1 0 −1] for both algorithms;
// F(2, 3): G = [1 0 0; ½ ½ ½; ½ −½ ½; 0 0 1], Aᵀ = [1 1 1 0; 0 1 −1 −1];
// F(3, 2) is its transpose: G = [1 0; 1 1; 1 −1; 0 −1], Aᵀ = [1 ½ ½ 0; 0 ½ −½ 0; 0 ½ ½ 1].

/// F(2, 3)'s kernel transform `G` (4×3).
const G3: [[f32; 3]; N] = [
    [1.0, 0.0, 0.0],
    [0.5, 0.5, 0.5],
    [0.5, -0.5, 0.5],
    [0.0, 0.0, 1.0],
];

/// F(3, 2)'s kernel transform `G` (4×2).
const G2: [[f32; 2]; N] = [[1.0, 0.0], [1.0, 1.0], [1.0, -1.0], [0.0, -1.0]];

/// A stride-1 `k×k` convolution (`k` 2 or 3) with its kernels transformed once.
#[derive(Debug, Clone)]
pub struct Winograd {
    k: usize,
    /// Output tile side: `N − k + 1`.
    m: usize,
    c: usize,
    cout: usize,
    /// `U[ξ]`, 16 row-major `[c, cout]` matrices.
    weight: Vec<f32>,
}

thread_local! {
    /// A band's transformed input, products, one output tile and a transform's intermediate (grown once per thread, then reused).
    #[allow(clippy::type_complexity)]
    static BAND: RefCell<(Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>)> =
        const { RefCell::new((Vec::new(), Vec::new(), Vec::new(), Vec::new())) };
}

impl Winograd {
    /// Transforms kernels laid out as [`super::packed_conv::PackedConv`] keeps them: per tap
    /// `(ky, kx)` a row-major `[c, cout]` matrix at `((ky·k + kx)·c)·cout`. `None` for other
    /// kernel sizes.
    pub fn new(weight: &[f32], k: usize, c: usize, cout: usize) -> Option<Self> {
        if !(k == 2 || k == 3) || c == 0 || cout == 0 || weight.len() != k * k * c * cout {
            return None;
        }
        let g = |i: usize, t: usize| -> f32 { if k == 3 { G3[i][t] } else { G2[i][t] } };
        let mut u = vec![0.0f32; NN * c * cout];
        for i in 0..N {
            for j in 0..N {
                let dst = &mut u[(i * N + j) * c * cout..][..c * cout];
                for ky in 0..k {
                    for kx in 0..k {
                        let s = g(i, ky) * g(j, kx);
                        if s == 0.0 {
                            continue;
                        }
                        let src = &weight[(ky * k + kx) * c * cout..][..c * cout];
                        for (d, w) in dst.iter_mut().zip(src) {
                            *d += s * w;
                        }
                    }
                }
            }
        }
        Some(Self {
            k,
            m: N - k + 1,
            c,
            cout,
            weight: u,
        })
    }

    /// Output tile side (2 for 3×3 kernels, 3 for 2×2).
    pub fn tile(&self) -> usize {
        self.m
    }

    /// The source size a `oh×ow` output needs: whole tiles, `[rows, columns]`.
    pub fn source_size(&self, [oh, ow]: [usize; 2]) -> [usize; 2] {
        let m = self.m;
        [
            oh.div_ceil(m) * m + self.k - 1,
            ow.div_ceil(m) * m + self.k - 1,
        ]
    }

    /// `out` (compact `[oh, ow, cout]`) = the "valid" convolution of `src` (row-major pixels of
    /// `c` channels, `ws` per row, at least [`Self::source_size`]), plus `bias`, then `act`.
    pub fn forward(
        &self,
        src: &[f32],
        ws: usize,
        [oh, ow]: [usize; 2],
        bias: &[f32],
        act: Activation,
        out: &mut [f32],
    ) {
        let (m, c, cout) = (self.m, self.c, self.cout);
        let [hs, wneed] = self.source_size([oh, ow]);
        assert!(ws >= wneed && src.len() >= hs * ws * c, "source too small");
        assert!(out.len() == oh * ow * cout && bias.len() == cout);
        if oh == 0 || ow == 0 {
            return;
        }
        let (ty, tx) = (oh.div_ceil(m), ow.div_ceil(m));
        // Bands of whole tile rows: about BAND_TILES tiles each (at least one tile row), and
        // about four bands per thread where the image allows it (the last band of an uneven
        // split is the short one).
        let threads = rayon::current_num_threads().max(1);
        let rows = BAND_TILES.div_ceil(tx).min(ty.div_ceil(4 * threads)).max(1);
        out.par_chunks_mut(rows * m * ow * cout)
            .enumerate()
            .for_each(|(b, band_out)| {
                let r0 = b * rows;
                let r1 = (r0 + rows).min(ty);
                let tiles = (r1 - r0) * tx;
                BAND.with(|cell| {
                    let (v, p, y, tmp) = &mut *cell.borrow_mut();
                    tmp.resize(NN * c.max(cout), 0.0);
                    v.resize(NN * tiles * c, 0.0);
                    p.resize(NN * tiles * cout, 0.0);
                    for r in r0..r1 {
                        for q in 0..tx {
                            let t = (r - r0) * tx + q;
                            let origin = ((r * m) * ws + q * m) * c;
                            input_tile(src, origin, ws * c, c, v, t * c, tiles * c, tmp);
                        }
                    }
                    for xi in 0..NN {
                        // SAFETY: v holds NN blocks of [tiles, c], weight NN blocks of
                        // [c, cout], p NN blocks of [tiles, cout], all row-major.
                        unsafe {
                            gemm::gemm(
                                tiles,
                                cout,
                                c,
                                p.as_mut_ptr().add(xi * tiles * cout),
                                1,
                                cout as isize,
                                false,
                                v.as_ptr().add(xi * tiles * c),
                                1,
                                c as isize,
                                self.weight.as_ptr().add(xi * c * cout),
                                1,
                                cout as isize,
                                1.0,
                                1.0,
                                false,
                                false,
                                false,
                                gemm::Parallelism::None,
                            )
                        };
                    }
                    y.resize(m * m * cout, 0.0);
                    let band_rows = band_out.len() / (ow * cout);
                    for r in r0..r1 {
                        for q in 0..tx {
                            let t = (r - r0) * tx + q;
                            let (at, step) = (t * cout, tiles * cout);
                            let (oy, ox) = ((r - r0) * m, q * m);
                            let (h, w) = (m.min(band_rows - oy), m.min(ow - ox));
                            // Whole tiles straight into the band; edge tiles through `y`.
                            let (dst, stride) = if h == m && w == m {
                                (&mut band_out[(oy * ow + ox) * cout..], ow * cout)
                            } else {
                                (&mut y[..], m * cout)
                            };
                            output(m, p, at, step, bias, dst, stride, tmp);
                            if h < m || w < m {
                                for i in 0..h {
                                    band_out[((oy + i) * ow + ox) * cout..][..w * cout]
                                        .copy_from_slice(&y[i * m * cout..][..w * cout]);
                                }
                            }
                        }
                    }
                });
                activate(band_out, act);
            });
    }
}

simd_fn! {
    /// `V = Bᵀ d B` of the tile whose pixel `(a, b)` holds `src[origin + a·row + b·c ..][..c]`,
    /// point `(i, j)` written to `v[(i·4 + j)·step + at ..][..c]`; `tmp` holds `16·c` values.
    #[allow(clippy::too_many_arguments)]
    fn input_tile(
        src: &[f32],
        origin: usize,
        row: usize,
        c: usize,
        v: &mut [f32],
        at: usize,
        step: usize,
        tmp: &mut [f32],
    ) {
        // Down the columns: tmp[i·4 + b] = (Bᵀ d)[i][b]...
        let tmp = &mut tmp[..NN * c];
        for b in 0..N {
            let d = |a: usize| &src[origin + a * row + b * c..][..c];
            let mut t = tmp.chunks_exact_mut(c).skip(b).step_by(N);
            let mut next = || t.next().expect("four rows");
            transform::<4>([d(0), d(1), d(2), d(3)], [next(), next(), next(), next()], bt);
        }
        // ...then along the rows: V[i][j] = ((Bᵀ d) B)[i][j].
        let mut blocks = v.chunks_exact_mut(step);
        for i in 0..N {
            let t = |b: usize| &tmp[(i * N + b) * c..][..c];
            let mut next = || &mut blocks.next().expect("sixteen points")[at..at + c];
            transform::<4>([t(0), t(1), t(2), t(3)], [next(), next(), next(), next()], bt);
        }
    }
}

/// `out[i][ch] = f(x[0][ch], …, x[3][ch])[i]` for every channel (vectorised over channels).
#[inline(always)]
fn transform<const M: usize>(
    x: [&[f32]; N],
    out: [&mut [f32]; M],
    f: impl Fn([f32; N]) -> [f32; M],
) {
    let n = out[0].len();
    let x = x.map(|s| &s[..n]);
    let mut out = out.map(|s| &mut s[..n]);
    for ch in 0..n {
        let y = f([x[0][ch], x[1][ch], x[2][ch], x[3][ch]]);
        for (o, y) in out.iter_mut().zip(y) {
            o[ch] = y;
        }
    }
}

/// `Bᵀ x` for the points 0, ±1, ∞.
#[inline(always)]
fn bt([x0, x1, x2, x3]: [f32; N]) -> [f32; N] {
    [x0 - x2, x1 + x2, x2 - x1, x1 - x3]
}

/// `Aᵀ x` of F(2, 3).
#[inline(always)]
fn at2([x0, x1, x2, x3]: [f32; N]) -> [f32; 2] {
    [x0 + x1 + x2, x1 - x2 - x3]
}

/// `Aᵀ x` of F(3, 2).
#[inline(always)]
fn at3([x0, x1, x2, x3]: [f32; N]) -> [f32; 3] {
    let (s, d) = (0.5 * (x1 + x2), 0.5 * (x1 - x2));
    [x0 + s, d, s + x3]
}

/// `Y = Aᵀ P A + bias` of one tile: point `(i, j)`'s products at `p[(i·4 + j)·step + at ..]
/// [..cout]`, pixel `(i, j)`'s channels written to `y[i·stride + j·cout ..]`; `tmp` holds
/// `4·M·cout` values.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn output_tile<const M: usize>(
    p: &[f32],
    at: usize,
    step: usize,
    bias: &[f32],
    y: &mut [f32],
    stride: usize,
    tmp: &mut [f32],
    f: impl Fn([f32; N]) -> [f32; M] + Copy,
) {
    let cout = bias.len();
    // Down the columns: tmp[b·M + i] = (Aᵀ P)[i][b]...
    let tmp = &mut tmp[..N * M * cout];
    for (b, col) in tmp.chunks_exact_mut(M * cout).enumerate() {
        let x = |a: usize| &p[(a * N + b) * step + at..][..cout];
        let mut rows = col.chunks_exact_mut(cout);
        let out = std::array::from_fn(|_| rows.next().expect("M rows"));
        transform::<M>([x(0), x(1), x(2), x(3)], out, f);
    }
    // ...then along the rows: Y[i][j] = ((Aᵀ P) A)[i][j], plus the bias.
    for i in 0..M {
        let row = &mut y[i * stride..][..M * cout];
        let s = |b: usize| &tmp[(b * M + i) * cout..][..cout];
        let mut px = row.chunks_exact_mut(cout);
        let out = std::array::from_fn(|_| px.next().expect("M pixels"));
        transform::<M>([s(0), s(1), s(2), s(3)], out, f);
        for px in row.chunks_exact_mut(cout) {
            for (v, b) in px.iter_mut().zip(bias) {
                *v += b;
            }
        }
    }
}

simd_fn! {
    /// [`output_tile`] of F(2×2, 3×3) (`m` = 2) or F(3×3, 2×2) (`m` = 3).
    #[allow(clippy::too_many_arguments)]
    fn output(
        m: usize,
        p: &[f32],
        at: usize,
        step: usize,
        bias: &[f32],
        y: &mut [f32],
        stride: usize,
        tmp: &mut [f32],
    ) {
        if m == 2 {
            output_tile::<2>(p, at, step, bias, y, stride, tmp, at2)
        } else {
            output_tile::<3>(p, at, step, bias, y, stride, tmp, at3)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// The direct sum of the same convolution, in f64.
    fn direct(
        src: &[f32],
        ws: usize,
        weight: &[f32],
        [k, c, cout]: [usize; 3],
        [oh, ow]: [usize; 2],
        bias: &[f32],
    ) -> Vec<f32> {
        let mut out = vec![0.0f32; oh * ow * cout];
        for y in 0..oh {
            for x in 0..ow {
                for o in 0..cout {
                    let mut acc = bias[o] as f64;
                    for ky in 0..k {
                        for kx in 0..k {
                            for i in 0..c {
                                let s = src[((y + ky) * ws + x + kx) * c + i] as f64;
                                acc += s * weight[((ky * k + kx) * c + i) * cout + o] as f64;
                            }
                        }
                    }
                    out[(y * ow + x) * cout + o] = acc as f32;
                }
            }
        }
        out
    }

    #[test]
    fn equals_the_direct_convolution_up_to_rounding() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        // Sizes that are and are not multiples of the tile, one band and several.
        for (k, c, cout, oh, ow) in [
            (3, 5, 7, 6, 8),
            (3, 16, 9, 7, 11),
            (2, 12, 5, 9, 9),
            (2, 8, 16, 10, 13),
            (3, 3, 4, 41, 3),
            (2, 4, 3, 1, 1),
        ] {
            let wino_probe = Winograd::new(&vec![0.0; k * k * c * cout], k, c, cout).unwrap();
            let [hs, ws] = wino_probe.source_size([oh, ow]);
            let src: Vec<f32> = (0..hs * ws * c)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect();
            let weight: Vec<f32> = (0..k * k * c * cout)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect();
            let bias: Vec<f32> = (0..cout).map(|_| rng.random_range(-1.0..1.0)).collect();
            let wino = Winograd::new(&weight, k, c, cout).unwrap();
            let mut got = vec![f32::NAN; oh * ow * cout];
            wino.forward(&src, ws, [oh, ow], &bias, Activation::Identity, &mut got);
            let want = direct(&src, ws, &weight, [k, c, cout], [oh, ow], &bias);
            for (i, (a, b)) in got.iter().zip(&want).enumerate() {
                assert!(
                    (a - b).abs() <= 1e-5 * (c * k * k) as f32,
                    "k {k}, value {i}: {a} vs {b}"
                );
            }
            // A wider source row than needed reads the same pixels.
            let wider: Vec<f32> = src
                .chunks(ws * c)
                .flat_map(|row| row.iter().copied().chain(std::iter::repeat_n(9.0, 2 * c)))
                .collect();
            let mut again = vec![0.0f32; oh * ow * cout];
            wino.forward(
                &wider,
                ws + 2,
                [oh, ow],
                &bias,
                Activation::Identity,
                &mut again,
            );
            assert_eq!(got, again);
        }
    }

    #[test]
    fn only_two_and_three_tap_kernels() {
        assert!(Winograd::new(&[0.0; 25], 5, 1, 1).is_none());
        assert!(Winograd::new(&[0.0; 1], 1, 1, 1).is_none());
        assert!(Winograd::new(&[0.0; 8], 3, 1, 1).is_none());
        assert!(Winograd::new(&[], 3, 0, 4).is_none());
        assert!(Winograd::new(&[], 3, 4, 0).is_none());
        assert_eq!(Winograd::new(&[0.0; 9], 3, 1, 1).unwrap().tile(), 2);
        assert_eq!(Winograd::new(&[0.0; 4], 2, 1, 1).unwrap().tile(), 3);
    }
}
