//! Winograd minimal filtering (Lavin & Gray, "Fast Algorithms for Convolutional Neural
//! Networks", CVPR 2016) for the packed stride-1 convolutions of [`super::packed_conv`].
//!
//! A 6×6 tile of the input, transformed (`V = Bᵀ d B`), multiplied point by point with the
//! transformed kernel (`U = G g Gᵀ`) and transformed back (`Y = Aᵀ (U ⊙ V) A`), gives an
//! `m×m` tile of the output: F(4×4, 3×3) for 3×3 kernels and F(5×5, 2×2) for the 2×2 kernels
//! that FPFDCNN's 4×4 stride-2 convolutions become after space-to-depth. Summed over input
//! channels, the point-wise products are 36 matrix products `[tiles, c] × [c, c_out]`: 4x
//! fewer multiply-adds than the direct sum for 3×3 kernels, 2.8x for 2×2. Both use the points
//! 0, ±1, ±2, ∞; their rounding error is about twenty times the direct sum's in `f32`, about
//! 1e-5 of a value's scale (tests below), far below that of the half-precision weights.
//!
//! Large images go in bands of tile rows, one band per task: its transformed input and
//! products stay in cache while each point's transformed kernels stream past. Where reading
//! the kernels once a band would read more than writing and reading back the whole image's
//! transformed input and products (deep layers at low resolution), the image goes whole
//! instead, each point's kernels read once (lab/notes/cpu-speed.md).

use super::nhwc::{Activation, activate, simd_fn};
use rayon::prelude::*;
use std::cell::RefCell;

/// Side of the input tile.
const N: usize = 6;
/// Transformed points per tile.
const NN: usize = N * N;
/// Tiles a band aims at: enough rows for the products to run near their peak.
const BAND_TILES: usize = 128;

// The transforms for the points 0, 1, −1, 2, −2, ∞, written out in `bt`, `at4` and `at5`:
// Bᵀ = [4 0 −5 0 1 0; 0 −4 −4 1 1 0; 0 4 −4 −1 1 0; 0 −2 −1 2 1 0; 0 2 −1 −2 1 0;
//       0 4 0 −5 0 1] for both algorithms; row j of G holds p_jᵗ / Π_{l≠j}(p_j − p_l) for
// the kernel taps t (the ∞ row: 0 … 0 1), row i of Aᵀ the points' i-th powers (the ∞
// column: 1 in the last row), so F(4, 3) (Lavin & Gray's matrices) and F(5, 2) differ only
// in G's columns and Aᵀ's rows.

/// F(4, 3)'s kernel transform `G` (6×3).
const G3: [[f32; 3]; N] = [
    [1.0 / 4.0, 0.0, 0.0],
    [-1.0 / 6.0, -1.0 / 6.0, -1.0 / 6.0],
    [-1.0 / 6.0, 1.0 / 6.0, -1.0 / 6.0],
    [1.0 / 24.0, 1.0 / 12.0, 1.0 / 6.0],
    [1.0 / 24.0, -1.0 / 12.0, 1.0 / 6.0],
    [0.0, 0.0, 1.0],
];

/// F(5, 2)'s kernel transform `G` (6×2).
const G2: [[f32; 2]; N] = [
    [1.0 / 4.0, 0.0],
    [-1.0 / 6.0, -1.0 / 6.0],
    [-1.0 / 6.0, 1.0 / 6.0],
    [1.0 / 24.0, 1.0 / 12.0],
    [1.0 / 24.0, -1.0 / 12.0],
    [0.0, 1.0],
];

/// A stride-1 `k×k` convolution (`k` 2 or 3) with its kernels transformed once.
#[derive(Debug, Clone)]
pub(crate) struct Winograd {
    k: usize,
    /// Output tile side: `N − k + 1`.
    m: usize,
    c: usize,
    cout: usize,
    /// `U[ξ]`, 36 row-major `[c, cout]` matrices.
    weight: Vec<f32>,
}

thread_local! {
    /// A band's transformed input, products, one output tile and a transform's intermediate (grown once per thread, then reused).
    #[allow(clippy::type_complexity)]
    static BAND: RefCell<(Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>)> =
        const { RefCell::new((Vec::new(), Vec::new(), Vec::new(), Vec::new())) };
    /// [`Winograd::forward_whole`]'s transformed input and products.
    static WHOLE: RefCell<(Vec<f32>, Vec<f32>)> = const { RefCell::new((Vec::new(), Vec::new())) };
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

    /// Output tile side (4 for 3×3 kernels, 5 for 2×2).
    #[cfg(test)]
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
    ///
    /// Large images go in bands of tile rows, each band's transformed input and products kept
    /// in cache while every point's transformed kernels stream past; where reading the kernels
    /// once a band would read more than writing and reading back the whole image's
    /// transformed input and products (deep layers at low resolution), the image goes whole,
    /// each point's kernels read once.
    pub fn forward(
        &self,
        src: &[f32],
        ws: usize,
        size: [usize; 2],
        bias: &[f32],
        act: Activation,
        out: &mut [f32],
    ) {
        self.forward_as(src, ws, size, bias, act, out, None)
    }

    /// [`Self::forward`], whole or in bands as `whole` says (`None`: whichever reads less).
    #[allow(clippy::too_many_arguments)]
    fn forward_as(
        &self,
        src: &[f32],
        ws: usize,
        [oh, ow]: [usize; 2],
        bias: &[f32],
        act: Activation,
        out: &mut [f32],
        whole: Option<bool>,
    ) {
        let (m, c, cout, nn) = (self.m, self.c, self.cout, NN);
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
        // Values read from memory: the kernels once a band, or once, plus the whole image's
        // transformed input and products written and read back.
        let read_banded = ty.div_ceil(rows) * nn * c * cout;
        let read_whole = nn * c * cout + 2 * nn * ty * tx * (c + cout);
        if whole.unwrap_or(read_whole < read_banded) {
            return self.forward_whole(src, ws, [ty, tx], ow, bias, act, out);
        }
        out.par_chunks_mut(rows * m * ow * cout)
            .enumerate()
            .for_each(|(b, band_out)| {
                let r0 = b * rows;
                let r1 = (r0 + rows).min(ty);
                let tiles = (r1 - r0) * tx;
                BAND.with(|cell| {
                    let (v, p, y, tmp) = &mut *cell.borrow_mut();
                    tmp.resize(nn * c.max(cout), 0.0);
                    v.resize(nn * tiles * c, 0.0);
                    p.resize(nn * tiles * cout, 0.0);
                    y.resize(m * m * cout, 0.0);
                    // Tile t's point ξ at v[ξ·tiles·c + t·c ..][..c].
                    for r in r0..r1 {
                        for q in 0..tx {
                            let t = (r - r0) * tx + q;
                            let origin = ((r * m) * ws + q * m) * c;
                            input_tile(src, origin, ws * c, c, v, t * c, tiles * c, tmp);
                        }
                    }
                    for xi in 0..nn {
                        // SAFETY: v holds nn blocks of [tiles, c], weight nn blocks of
                        // [c, cout], p nn blocks of [tiles, cout], all row-major.
                        unsafe {
                            self.product(
                                tiles,
                                p.as_mut_ptr().add(xi * tiles * cout),
                                cout,
                                v.as_ptr().add(xi * tiles * c),
                                c,
                                xi,
                            )
                        };
                    }
                    for (r, rows_out) in band_out.chunks_mut(m * ow * cout).enumerate() {
                        let first = r * tx;
                        let at = |q: usize| (first + q) * cout;
                        self.tile_row_out(p, at, tiles * cout, bias, ow, rows_out, y, tmp);
                    }
                });
                activate(band_out, act);
            });
    }

    /// [`Self::forward`] with the image whole: every tile's transformed input (a tile row
    /// per task), then the products (a point per task), then the output (a tile row per
    /// task). Tile t's point ξ lies at `t·36·c + ξ·c` of the input and `t·36·cout + ξ·cout`
    /// of the products.
    #[allow(clippy::too_many_arguments)]
    fn forward_whole(
        &self,
        src: &[f32],
        ws: usize,
        [ty, tx]: [usize; 2],
        ow: usize,
        bias: &[f32],
        act: Activation,
        out: &mut [f32],
    ) {
        let (m, c, cout, nn) = (self.m, self.c, self.cout, NN);
        let tiles = ty * tx;
        // Taken, not borrowed: a task of another convolution may run on this thread while it
        // waits below, and would then find them empty and grow its own.
        let (mut v, mut p) = WHOLE.with(|cell| std::mem::take(&mut *cell.borrow_mut()));
        v.resize(tiles * nn * c, 0.0);
        p.resize(tiles * nn * cout, 0.0);
        v.par_chunks_mut(tx * nn * c)
            .enumerate()
            .for_each(|(r, row)| {
                BAND.with(|cell| {
                    let (_, _, _, tmp) = &mut *cell.borrow_mut();
                    tmp.resize(nn * c.max(cout), 0.0);
                    for q in 0..tx {
                        let origin = ((r * m) * ws + q * m) * c;
                        input_tile(src, origin, ws * c, c, row, q * nn * c, c, tmp);
                    }
                })
            });
        let dst = SharedMut(p.as_mut_ptr());
        (0..nn).into_par_iter().for_each(|xi| {
            // SAFETY: point ξ writes columns ξ·cout .. (ξ+1)·cout of p's `tiles` rows of
            // 36·cout values, which no other point writes; v's rows hold 36·c values.
            unsafe {
                self.product(
                    tiles,
                    dst.get().add(xi * cout),
                    nn * cout,
                    v.as_ptr().add(xi * c),
                    nn * c,
                    xi,
                )
            };
        });
        out.par_chunks_mut(m * ow * cout)
            .enumerate()
            .for_each(|(r, rows_out)| {
                BAND.with(|cell| {
                    let (_, _, y, tmp) = &mut *cell.borrow_mut();
                    tmp.resize(nn * c.max(cout), 0.0);
                    y.resize(m * m * cout, 0.0);
                    let at = |q: usize| (r * tx + q) * nn * cout;
                    self.tile_row_out(&p, at, cout, bias, ow, rows_out, y, tmp);
                });
                activate(rows_out, act);
            });
        WHOLE.with(|cell| *cell.borrow_mut() = (v, p));
    }

    /// `dst = lhs · U[ξ]` for `rows` rows: `lhs` `[rows, c]`, `dst` `[rows, cout]`, row-major
    /// with row strides `lhs_rs` and `dst_rs`.
    ///
    /// # Safety
    /// `lhs` and `dst` must hold `rows` rows of their strides, `dst`'s written by no one else.
    unsafe fn product(
        &self,
        rows: usize,
        dst: *mut f32,
        dst_rs: usize,
        lhs: *const f32,
        lhs_rs: usize,
        xi: usize,
    ) {
        let (c, cout) = (self.c, self.cout);
        // SAFETY: the caller's guarantees, and weight holds 36 blocks of [c, cout].
        unsafe {
            gemm::gemm(
                rows,
                cout,
                c,
                dst,
                1,
                dst_rs as isize,
                false,
                lhs,
                1,
                lhs_rs as isize,
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
        }
    }

    /// The output tiles of one tile row, into `rows_out` (the up to `m` output rows it
    /// covers, `ow·cout` values each); tile `q`'s point ξ's products at `p[at(q) + ξ·step ..]
    /// [..cout]`. Whole tiles go straight in, edge tiles through `y`.
    #[allow(clippy::too_many_arguments)]
    fn tile_row_out(
        &self,
        p: &[f32],
        at: impl Fn(usize) -> usize,
        step: usize,
        bias: &[f32],
        ow: usize,
        rows_out: &mut [f32],
        y: &mut [f32],
        tmp: &mut [f32],
    ) {
        let (m, cout) = (self.m, self.cout);
        let h = rows_out.len() / (ow * cout);
        for q in 0..ow.div_ceil(m) {
            let ox = q * m;
            let w = m.min(ow - ox);
            let (dst, stride) = if h == m && w == m {
                (&mut rows_out[ox * cout..], ow * cout)
            } else {
                (&mut y[..], m * cout)
            };
            output(m, p, at(q), step, bias, dst, stride, tmp);
            if h < m || w < m {
                for i in 0..h {
                    rows_out[(i * ow + ox) * cout..][..w * cout]
                        .copy_from_slice(&y[i * m * cout..][..w * cout]);
                }
            }
        }
    }
}

/// A pointer written at disjoint places by parallel tasks.
struct SharedMut(*mut f32);

// SAFETY: the tasks holding it write disjoint elements (see its uses).
unsafe impl Sync for SharedMut {}

impl SharedMut {
    fn get(&self) -> *mut f32 {
        self.0
    }
}

simd_fn! {
    /// `V = Bᵀ d B` of the tile whose pixel `(a, b)` holds `src[origin + a·row + b·c ..][..c]`,
    /// point `(i, j)` written to `v[at + (i·6 + j)·step ..][..c]`; `tmp` holds `36·c` values.
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
        // Down the columns: tmp[i·6 + b] = (Bᵀ d)[i][b]...
        let tmp = &mut tmp[..NN * c];
        for b in 0..N {
            let d = std::array::from_fn(|a| &src[origin + a * row + b * c..][..c]);
            let mut t = tmp.chunks_exact_mut(c).skip(b).step_by(N);
            let out = std::array::from_fn(|_| t.next().expect("six rows"));
            transform::<N>(d, out, bt);
        }
        // ...then along the rows: V[i][j] = ((Bᵀ d) B)[i][j].
        let mut blocks = v[at..].chunks_mut(step);
        for i in 0..N {
            let t = std::array::from_fn(|b| &tmp[(i * N + b) * c..][..c]);
            let out = std::array::from_fn(|_| &mut blocks.next().expect("36 points")[..c]);
            transform::<N>(t, out, bt);
        }
    }
}

/// `out[i][ch] = f(x[0][ch], …, x[5][ch])[i]` for every channel (vectorised over channels).
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
        let y = f(std::array::from_fn(|i| x[i][ch]));
        for (o, y) in out.iter_mut().zip(y) {
            o[ch] = y;
        }
    }
}

/// `Bᵀ x`.
#[inline(always)]
fn bt([x0, x1, x2, x3, x4, x5]: [f32; N]) -> [f32; N] {
    let (a, b) = (x4 - 4.0 * x2, x3 - 4.0 * x1);
    let (c, d) = (x4 - x2, 2.0 * (x3 - x1));
    [
        4.0 * x0 - 5.0 * x2 + x4,
        a + b,
        a - b,
        c + d,
        c - d,
        4.0 * x1 - 5.0 * x3 + x5,
    ]
}

/// `Aᵀ x` of F(4, 3).
#[inline(always)]
fn at4([x0, x1, x2, x3, x4, x5]: [f32; N]) -> [f32; 4] {
    let (s1, d1, s2, d2) = (x1 + x2, x1 - x2, x3 + x4, x3 - x4);
    [
        x0 + s1 + s2,
        d1 + 2.0 * d2,
        s1 + 4.0 * s2,
        d1 + 8.0 * d2 + x5,
    ]
}

/// `Aᵀ x` of F(5, 2).
#[inline(always)]
fn at5([x0, x1, x2, x3, x4, x5]: [f32; N]) -> [f32; 5] {
    let (s1, d1, s2, d2) = (x1 + x2, x1 - x2, x3 + x4, x3 - x4);
    [
        x0 + s1 + s2,
        d1 + 2.0 * d2,
        s1 + 4.0 * s2,
        d1 + 8.0 * d2,
        s1 + 16.0 * s2 + x5,
    ]
}

/// `Y = Aᵀ P A + bias` of one tile: point `(i, j)`'s products at `p[at + (i·6 + j)·step ..]
/// [..cout]`, pixel `(i, j)`'s channels written to `y[i·stride + j·cout ..]`; `tmp` holds
/// `6·M·cout` values.
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
        let x = std::array::from_fn(|a| &p[(a * N + b) * step + at..][..cout]);
        let mut rows = col.chunks_exact_mut(cout);
        let out = std::array::from_fn(|_| rows.next().expect("M rows"));
        transform::<M>(x, out, f);
    }
    // ...then along the rows: Y[i][j] = ((Aᵀ P) A)[i][j], plus the bias.
    for i in 0..M {
        let row = &mut y[i * stride..][..M * cout];
        let s = std::array::from_fn(|b| &tmp[(b * M + i) * cout..][..cout]);
        let mut px = row.chunks_exact_mut(cout);
        let out = std::array::from_fn(|_| px.next().expect("M pixels"));
        transform::<M>(s, out, f);
        for px in row.chunks_exact_mut(cout) {
            for (v, b) in px.iter_mut().zip(bias) {
                *v += b;
            }
        }
    }
}

simd_fn! {
    /// [`output_tile`] of F(4×4, 3×3) (`m` = 4) or F(5×5, 2×2) (`m` = 5).
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
        if m == 4 {
            output_tile::<4>(p, at, step, bias, y, stride, tmp, at4)
        } else {
            output_tile::<5>(p, at, step, bias, y, stride, tmp, at5)
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
        let cases = [
            (3, 5, 7, 6, 8),
            (3, 16, 9, 7, 11),
            (2, 12, 5, 9, 9),
            (2, 8, 16, 10, 13),
            (3, 3, 4, 41, 3),
            (2, 4, 3, 1, 1),
            (3, 64, 32, 13, 9),
            (2, 256, 16, 11, 7),
        ];
        for (k, c, cout, oh, ow) in cases {
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
            let want = direct(&src, ws, &weight, [k, c, cout], [oh, ow], &bias);
            let scale = want.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            let close = |got: &[f32], what: &str| {
                for (i, (a, b)) in got.iter().zip(&want).enumerate() {
                    assert!(
                        (a - b).abs() <= 3e-5 * scale,
                        "{what}, k {k}, c {c}, value {i}: {a} vs {b} (largest {scale})"
                    );
                }
            };
            // In bands and whole, on one thread and two (bands of one tile row and several).
            for threads in [1, 2] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                for whole in [false, true] {
                    let mut got = vec![f32::NAN; oh * ow * cout];
                    let act = Activation::Identity;
                    pool.install(|| {
                        wino.forward_as(&src, ws, [oh, ow], &bias, act, &mut got, Some(whole))
                    });
                    close(&got, &format!("{threads} threads, whole {whole}"));
                }
            }
            let mut got = vec![f32::NAN; oh * ow * cout];
            wino.forward(&src, ws, [oh, ow], &bias, Activation::Identity, &mut got);
            close(&got, "either");
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
        assert_eq!(Winograd::new(&[0.0; 9], 3, 1, 1).unwrap().tile(), 4);
        assert_eq!(Winograd::new(&[0.0; 4], 2, 1, 1).unwrap().tile(), 5);
    }
}
