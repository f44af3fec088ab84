//! Normalised cross-correlation patch search: finds where a patch of one image
//! reappears in another (used to check geometry against real images).

use crate::raster::GrayF32;

/// Zero-mean normalised cross-correlation of two square patches of radius `r`
/// centred at `a` in `img_a` and `b` in `img_b` (sub-pixel centres sampled bilinearly).
pub fn ncc(img_a: &GrayF32, a: (f64, f64), img_b: &GrayF32, b: (f64, f64), r: i32) -> f32 {
    let n = ((2 * r + 1) * (2 * r + 1)) as f32;
    let (mut sa, mut sb, mut saa, mut sbb, mut sab) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    for dy in -r..=r {
        for dx in -r..=r {
            let va = img_a.sample(a.0 + dx as f64, a.1 + dy as f64);
            let vb = img_b.sample(b.0 + dx as f64, b.1 + dy as f64);
            sa += va;
            sb += vb;
            saa += va * va;
            sbb += vb * vb;
            sab += va * vb;
        }
    }
    let cov = sab - sa * sb / n;
    let var = (saa - sa * sa / n) * (sbb - sb * sb / n);
    if var <= 1e-12 { 0.0 } else { cov / var.sqrt() }
}

/// Best NCC match of the patch at `a` within `search` pixels of `guess` in
/// `img_b` (integer search, then a parabolic sub-pixel refinement).
/// Returns the position and its correlation.
pub fn search(
    img_a: &GrayF32,
    a: (f64, f64),
    img_b: &GrayF32,
    guess: (f64, f64),
    r: i32,
    search: i32,
) -> ((f64, f64), f32) {
    let mut best = (guess, f32::MIN);
    let mut scores = vec![f32::MIN; ((2 * search + 1) * (2 * search + 1)) as usize];
    let idx = |dx: i32, dy: i32| ((dy + search) * (2 * search + 1) + dx + search) as usize;
    for dy in -search..=search {
        for dx in -search..=search {
            let p = (guess.0 + dx as f64, guess.1 + dy as f64);
            let s = ncc(img_a, a, img_b, p, r);
            scores[idx(dx, dy)] = s;
            if s > best.1 {
                best = (p, s);
            }
        }
    }
    let (bx, by) = (
        (best.0.0 - guess.0).round() as i32,
        (best.0.1 - guess.1).round() as i32,
    );
    let mut pos = best.0;
    if bx.abs() < search && by.abs() < search {
        pos.0 += parabola_peak(scores[idx(bx - 1, by)], best.1, scores[idx(bx + 1, by)]);
        pos.1 += parabola_peak(scores[idx(bx, by - 1)], best.1, scores[idx(bx, by + 1)]);
    }
    (pos, best.1)
}

/// Sub-pixel offset of the peak of the parabola through scores `m`, `c`, `p` at -1, 0, +1
/// (`c` the largest, which keeps it within ±0.5; clamped there otherwise); 0 when they do
/// not bend down.
pub(crate) fn parabola_peak(m: f32, c: f32, p: f32) -> f64 {
    let d = m - 2.0 * c + p;
    if d < 0.0 {
        f64::from(0.5 * (m - p) / d).clamp(-0.5, 0.5)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::parabola_peak;

    #[test]
    fn parabola_peak_finds_the_vertex_and_stays_within_half_a_pixel() {
        // y = 2 - (x - 0.25)² sampled at -1, 0, 1: the vertex at 0.25.
        let y = |x: f32| 2.0 - (x - 0.25) * (x - 0.25);
        assert!((parabola_peak(y(-1.0), y(0.0), y(1.0)) - 0.25).abs() < 1e-6);
        assert_eq!(parabola_peak(1.0, 2.0, 1.0), 0.0);
        // Flat or bending up: no step.
        assert_eq!(parabola_peak(1.0, 1.0, 1.0), 0.0);
        assert_eq!(parabola_peak(2.0, 1.0, 2.0), 0.0);
        // The middle score not the largest: clamped.
        assert_eq!(parabola_peak(0.5, 0.4, 0.2), -0.5);
        assert_eq!(parabola_peak(0.2, 0.4, 0.5), 0.5);
    }
}
