//! Match refinement by patch correlation: each match's point in the second image moves to
//! where the patch around its first-image point correlates best (zero-mean NCC), within a
//! few pixels, then by a parabola to the sub-pixel peak. FPFDCNN places a keypoint from a
//! probability map predicted per 16x16 cell, a pixel or two from the corner it describes
//! (lab/notes/fpfdcnn-results.md, *Matches refined by patch correlation*); the images themselves say where the
//! matched corner lies. The first image's point stays where it is. Like
//! [`super::patch::search`], with the first patch computed once per match and the second
//! turned by the image's roll; unlike it, a flat patch never wins, each axis takes its
//! sub-pixel step where its neighbours lie in the window, and a match moves only when its
//! correlation reaches `min_ncc`.

use nalgebra::Point2;
use serde::{Deserialize, Serialize};

use super::patch::parabola_peak;
use crate::raster::GrayF32;

/// Settings of `refine_matches`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MatchRefineConfig {
    /// Patch radius, pixels: the patch is `(2r + 1)²` pixels.
    pub patch_radius: usize,
    /// Largest move along each axis, pixels (before the sub-pixel step).
    pub search_px: usize,
    /// A match moves only when its best correlation reaches this (−1 to 1).
    pub min_ncc: f32,
}

/// Upper bound of [`MatchRefineConfig::patch_radius`].
pub(crate) const MAX_PATCH_RADIUS: usize = 15;

/// Upper bound of [`MatchRefineConfig::search_px`].
pub(crate) const MAX_SEARCH_PX: usize = 8;

impl Default for MatchRefineConfig {
    /// 15x15 patches, moves up to 3 px, NCC at least 0.7: chosen on the validation pairs
    /// (lab/notes/fpfdcnn-results.md, *Matches refined by patch correlation*).
    fn default() -> Self {
        MatchRefineConfig {
            patch_radius: 7,
            search_px: 3,
            min_ncc: 0.7,
        }
    }
}

impl MatchRefineConfig {
    /// Checks ranges; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        if !(1..=MAX_PATCH_RADIUS).contains(&self.patch_radius) {
            return Err(format!(
                "patch_radius must be in [1, {MAX_PATCH_RADIUS}] pixels, got {}",
                self.patch_radius
            ));
        }
        if !(1..=MAX_SEARCH_PX).contains(&self.search_px) {
            return Err(format!(
                "search_px must be in [1, {MAX_SEARCH_PX}] pixels, got {}",
                self.search_px
            ));
        }
        if !(self.min_ncc.is_finite() && (-1.0..=1.0).contains(&self.min_ncc)) {
            return Err(format!("min_ncc must be in [-1, 1], got {}", self.min_ncc));
        }
        Ok(())
    }
}

/// Moves the second point of each match `(in a, in b)` to where the patch of `a` around the
/// first correlates best in `b` (see the module documentation); `roll_deg` is the image
/// motion's rotation from `a` to `b` (positive: clockwise on screen, image y down, as FPFDCNN's
/// `Homography::rotation` and roll compensation give it), by which `b`'s patch is turned.
/// Returns how many matches moved. Matches whose patch in `a` is flat stay.
pub(crate) fn refine_matches(
    a: &GrayF32,
    b: &GrayF32,
    matches: &mut [(Point2<f64>, Point2<f64>)],
    roll_deg: f64,
    cfg: &MatchRefineConfig,
) -> Result<usize, String> {
    cfg.validate()?;
    let r = cfg.patch_radius as i64;
    let s = cfg.search_px as i64;
    let (sn, cs) = roll_deg.to_radians().sin_cos();
    // Patch offsets in a, and the same offsets in b, turned by the roll.
    let offsets: Vec<([f64; 2], [f64; 2])> = (-r..=r)
        .flat_map(|dy| (-r..=r).map(move |dx| (dx as f64, dy as f64)))
        .map(|(dx, dy)| ([dx, dy], [cs * dx - sn * dy, sn * dx + cs * dy]))
        .collect();
    let side = (2 * s + 1) as usize;
    let mut scores = vec![f32::MIN; side * side];
    let mut moved = 0;
    for (pa, pb) in matches.iter_mut() {
        let Some(patch_a) = unit_patch(
            offsets
                .iter()
                .map(|(o, _)| a.sample(pa.x + o[0], pa.y + o[1])),
        ) else {
            continue;
        };
        let mut best = (0usize, f32::MIN);
        for (i, score) in scores.iter_mut().enumerate() {
            let (dx, dy) = ((i % side) as i64 - s, (i / side) as i64 - s);
            let (cx, cy) = (pb.x + dx as f64, pb.y + dy as f64);
            *score = unit_patch(offsets.iter().map(|(_, o)| b.sample(cx + o[0], cy + o[1])))
                .map_or(f32::MIN, |patch_b| {
                    patch_a.iter().zip(&patch_b).map(|(u, v)| u * v).sum()
                });
            if *score > best.1 {
                best = (i, *score);
            }
        }
        if best.1 < cfg.min_ncc {
            continue;
        }
        let (bx, by) = (best.0 % side, best.0 / side);
        let mut step = [bx as f64 - s as f64, by as f64 - s as f64];
        // Sub-pixel: a parabola through the peak and its neighbours, per axis (not where a
        // neighbour's patch was flat).
        let peak = |m: f32, p: f32| {
            if m > f32::MIN && p > f32::MIN {
                parabola_peak(m, best.1, p)
            } else {
                0.0
            }
        };
        if bx > 0 && bx + 1 < side {
            step[0] += peak(scores[best.0 - 1], scores[best.0 + 1]);
        }
        if by > 0 && by + 1 < side {
            step[1] += peak(scores[best.0 - side], scores[best.0 + side]);
        }
        *pb = Point2::new(pb.x + step[0], pb.y + step[1]);
        moved += 1;
    }
    Ok(moved)
}

/// The patch's values minus their mean, scaled to unit length; `None` when it is flat.
fn unit_patch(values: impl Iterator<Item = f32>) -> Option<Vec<f32>> {
    let mut v: Vec<f32> = values.collect();
    let mean = v.iter().sum::<f32>() / v.len().max(1) as f32;
    v.iter_mut().for_each(|x| *x -= mean);
    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if norm <= 1e-6 {
        return None;
    }
    v.iter_mut().for_each(|x| *x /= norm);
    Some(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth, textured image: no two patches alike.
    fn texture(w: usize, h: usize) -> GrayF32 {
        let mut img = GrayF32::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let (xf, yf) = (x as f32, y as f32);
                img.data[y * w + x] = 0.5
                    + 0.2 * (0.31 * xf + 0.17 * yf).sin()
                    + 0.15 * (0.23 * yf - 0.11 * xf).cos()
                    + 0.1 * (0.07 * xf * yf / 10.0).sin();
            }
        }
        img.gaussian_blur(1.0)
    }

    #[test]
    fn a_match_two_pixels_off_moves_to_the_true_point() {
        let a = texture(80, 60);
        // b is a moved 3.4 px right and 1.7 px down.
        let mut b = GrayF32::new(80, 60);
        for y in 0..60 {
            for x in 0..80 {
                b.data[y * 80 + x] = a.sample(x as f64 - 3.4, y as f64 - 1.7);
            }
        }
        let truth = Point2::new(40.0 + 3.4, 30.0 + 1.7);
        let mut m = vec![(Point2::new(40.0, 30.0), Point2::new(45.0, 30.0))];
        let moved = refine_matches(&a, &b, &mut m, 0.0, &MatchRefineConfig::default()).unwrap();
        assert_eq!(moved, 1);
        assert!((m[0].1 - truth).norm() < 0.3, "{:?}", m[0].1);
        assert_eq!(m[0].0, Point2::new(40.0, 30.0));
    }

    /// Fine random texture: patches decorrelate when turned.
    fn speckle(w: usize, h: usize) -> GrayF32 {
        let mut img = GrayF32::new(w, h);
        let mut state = 0x2545_f491_u32;
        for v in img.data.iter_mut() {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            *v = (state % 1000) as f32 / 1000.0;
        }
        img.gaussian_blur(1.2)
    }

    #[test]
    fn a_rolled_image_needs_the_roll() {
        let a = speckle(120, 100);
        // b is a turned 20 degrees clockwise on screen about its centre.
        let (sn, cs) = 20f64.to_radians().sin_cos();
        let (cx, cy) = (59.5, 49.5);
        let mut b = GrayF32::new(120, 100);
        for y in 0..100 {
            for x in 0..120 {
                let (u, v) = (x as f64 - cx, y as f64 - cy);
                b.data[y * 120 + x] = a.sample(cs * u + sn * v + cx, -sn * u + cs * v + cy);
            }
        }
        let (u, v) = (60.0 - cx, 45.0 - cy);
        let truth = Point2::new(cs * u - sn * v + cx, sn * u + cs * v + cy);
        let start = Point2::new(truth.x.round() + 2.0, truth.y.round() - 1.0);
        let cfg = MatchRefineConfig {
            min_ncc: 0.9,
            ..Default::default()
        };
        let mut m = vec![(Point2::new(60.0, 45.0), start)];
        refine_matches(&a, &b, &mut m, 20.0, &cfg).unwrap();
        assert!((m[0].1 - truth).norm() < 0.5, "{:?} vs {truth:?}", m[0].1);
        // Upright patches correlate worse than 0.9 here: the match stays.
        let mut m = vec![(Point2::new(60.0, 45.0), start)];
        assert_eq!(refine_matches(&a, &b, &mut m, 0.0, &cfg).unwrap(), 0);
        assert_eq!(m[0].1, start);
    }

    #[test]
    fn flat_patches_stay_and_bad_settings_are_errors() {
        let flat = GrayF32::new(40, 40);
        let tex = texture(40, 40);
        let mut m = vec![(Point2::new(20.0, 20.0), Point2::new(21.0, 19.0))];
        let cfg = MatchRefineConfig::default();
        assert_eq!(refine_matches(&flat, &tex, &mut m, 0.0, &cfg).unwrap(), 0);
        assert_eq!(refine_matches(&tex, &flat, &mut m, 0.0, &cfg).unwrap(), 0);
        assert_eq!(m[0].1, Point2::new(21.0, 19.0));
        for bad in [
            MatchRefineConfig {
                patch_radius: 0,
                ..cfg.clone()
            },
            MatchRefineConfig {
                search_px: MAX_SEARCH_PX + 1,
                ..cfg.clone()
            },
            MatchRefineConfig {
                patch_radius: MAX_PATCH_RADIUS + 1,
                ..cfg.clone()
            },
            MatchRefineConfig {
                min_ncc: f32::NAN,
                ..cfg.clone()
            },
            MatchRefineConfig {
                min_ncc: 1.5,
                ..cfg.clone()
            },
        ] {
            assert!(refine_matches(&tex, &tex, &mut m, 0.0, &bad).is_err());
        }
    }
}
