//! Depth-edge filtering before fusion. A depth image from a network (SDFCNN predicts at
//! its inner size and is resized up) is smooth across object boundaries: the pixels on a
//! boundary get depths between the near and the far surface ("flying pixels") and
//! belong to neither. Sensor depth has the same defect, milder. Fusing them puts map
//! points in empty space; this drops them, the usual step before TSDF fusion of
//! predicted depth (CNN-SLAM, Tateno et al. 2017, fuses confidence-weighted depth).
//! [`EdgeWindow`] asks the same of one keypoint before its depth becomes a 3D point.

use crate::dataset::DepthImage;

/// Invalidates (sets to 0) every pixel that lies on a depth discontinuity: along x or y,
/// with both neighbours `reach` pixels away valid, the second difference of inverse depth
/// `|1/d₋ + 1/d₊ − 2/d|`, times `d`, exceeds `max_ratio`. A plane has an inverse depth
/// affine in the pixel coordinates, so a slanted floor or a wall seen at a grazing angle
/// scores 0 however steep its depth gradient; a pixel between a near and a far surface
/// does not. `max_ratio <= 0`, `reach == 0`, or data that do not hold `width * height`
/// values leave the image as it is. Returns how many pixels were dropped.
pub fn drop_depth_edges(depth: &mut DepthImage, reach: u32, max_ratio: f32) -> usize {
    let Some(test) = EdgeWindow::new(reach, max_ratio) else {
        return 0;
    };
    let (w, h) = (depth.width as i64, depth.height as i64);
    if depth.data.len() as i64 != w * h {
        return 0;
    }
    let src = depth.data.clone();
    let mut dropped = 0;
    for y in 0..h {
        for x in 0..w {
            if test.at_pixel(&src, (w, h), x, y) {
                depth.data[(y * w + x) as usize] = 0.0;
                dropped += 1;
            }
        }
    }
    dropped
}

/// The test of [`drop_depth_edges`] at one keypoint: when its reading and the readings
/// `reach` pixels to either side (along x or y) do not lie on one plane, the keypoint sits on
/// or beside a depth discontinuity, and its reading may belong to either surface (a corner
/// on an object's outline is one) or, with depth registered to the colour camera (7-Scenes'
/// is good to about 3 px at edges), to the wrong one; such a keypoint gets no 3D point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeWindow {
    /// Pixels to either side.
    pub reach: u32,
    /// The largest second difference of inverse depth, times the depth, of a plane.
    pub max_ratio: f32,
}

impl EdgeWindow {
    /// `None` (no test) when `max_ratio <= 0` or `reach == 0`.
    pub fn new(reach: u32, max_ratio: f32) -> Option<Self> {
        (max_ratio > 0.0 && reach > 0).then_some(EdgeWindow { reach, max_ratio })
    }

    /// Whether the pixel nearest to `(x, y)` lies on a depth discontinuity, as
    /// [`drop_depth_edges`] decides (an axis whose pixel `reach` away on either side has no
    /// reading or lies outside the image tells nothing); a pixel without a reading does not,
    /// nor does any pixel of an image whose data does not hold `width * height` values.
    pub fn straddles(&self, depth: &DepthImage, x: f64, y: f64) -> bool {
        let (w, h) = (depth.width as i64, depth.height as i64);
        depth.data.len() as i64 == w * h
            && self.at_pixel(&depth.data, (w, h), x.round() as i64, y.round() as i64)
    }

    /// The test at integer pixel `(x, y)` of a row-major `w` x `h` image whose `data` hold
    /// `w * h` values.
    #[inline]
    fn at_pixel(&self, data: &[f32], (w, h): (i64, i64), x: i64, y: i64) -> bool {
        let at = |x: i64, y: i64| -> Option<f32> {
            (x >= 0 && y >= 0 && x < w && y < h)
                .then(|| data[(y * w + x) as usize])
                .filter(|&d| d > 0.0)
        };
        let Some(d) = at(x, y) else { return false };
        let r = self.reach as i64;
        [(r, 0), (0, r)]
            .iter()
            .any(|&(dx, dy)| match (at(x - dx, y - dy), at(x + dx, y + dy)) {
                (Some(a), Some(b)) => (1.0 / a + 1.0 / b - 2.0 / d).abs() * d > self.max_ratio,
                _ => false,
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w` x `h` depth image with `depth(x, y)` at each pixel.
    fn image(w: u32, h: u32, depth: impl Fn(u32, u32) -> f32) -> DepthImage {
        let mut img = DepthImage::new(w, h);
        for y in 0..h {
            for x in 0..w {
                img.data[(y * w + x) as usize] = depth(x, y);
            }
        }
        img
    }

    #[test]
    fn drops_the_boundary_of_a_step_and_keeps_slanted_planes() {
        // Left half at 1 m, right half at 2 m, blurred over 4 px as an upsampled
        // prediction would be.
        let (w, h) = (40u32, 10u32);
        let img = image(w, h, |x, _| 1.0 + ((x as f32 - 18.0) / 4.0).clamp(0.0, 1.0));
        let mut f = img.clone();
        let n = drop_depth_edges(&mut f, 3, 0.05);
        assert!(n > 0 && n < (w * h) as usize / 2, "{n}");
        for y in 0..h {
            // Far from the step: kept; on it: dropped.
            assert!(f.data[(y * w + 5) as usize] > 0.0);
            assert!(f.data[(y * w + 35) as usize] > 0.0);
            assert_eq!(f.data[(y * w + 20) as usize], 0.0);
        }
        // A floor seen at a grazing angle: inverse depth affine in y, depth from 0.8 m to
        // 8 m down the image. Every pixel stays.
        let mut floor = image(w, h, |_, y| 1.0 / (0.125 + 0.125 * y as f32));
        let before = floor.data.clone();
        assert_eq!(drop_depth_edges(&mut floor, 3, 0.05), 0);
        assert_eq!(floor.data, before);
        // Off: unchanged.
        let mut g = img.clone();
        assert_eq!(drop_depth_edges(&mut g, 3, 0.0), 0);
        assert_eq!(g.data, img.data);
    }

    #[test]
    fn a_keypoint_on_a_step_straddles_it_and_one_on_a_slanted_plane_does_not() {
        // A box edge: 1.2 m left of x = 20, 2.0 m right of it, a hole of no readings at
        // x = 30..33 on the far side.
        let (w, h) = (40u32, 12u32);
        let step = image(w, h, |x, _| match x {
            0..20 => 1.2,
            30..33 => 0.0,
            _ => 2.0,
        });
        let win = EdgeWindow::new(3, 0.05).unwrap();
        for x in 17..=22 {
            assert!(win.straddles(&step, x as f64, 6.0), "x = {x}");
        }
        // Rounded to the nearest pixel: 16.6 is pixel 17, whose reach crosses the step.
        assert!(win.straddles(&step, 16.6, 6.0));
        // Away from the step, in the hole (no reading) and beside it (the far side's pixel
        // is missing: that axis tells nothing), near the border.
        for x in [5.0, 16.4, 23.4, 26.0, 28.0, 31.0, 33.0, 38.0] {
            assert!(!win.straddles(&step, x, 6.0), "x = {x}");
        }
        // Corners of the image: nothing is read out of bounds.
        assert!(!win.straddles(&step, 0.0, 0.0));
        assert!(!win.straddles(&step, 39.4, 11.4));
        // A floor at a grazing angle (inverse depth affine in y, 0.8 m to 7.3 m): no edge.
        let floor = image(w, 100, |_, y| 1.0 / (1.25 - 0.01125 * y as f32));
        assert!((0..100).all(|y| !win.straddles(&floor, 20.0, y as f64)));
        // Off, and a malformed image: no test, no panic.
        assert!(EdgeWindow::new(3, 0.0).is_none() && EdgeWindow::new(0, 0.05).is_none());
        let bad = DepthImage {
            width: 40,
            height: 12,
            data: vec![1.0; 3],
        };
        assert!(!win.straddles(&bad, 20.0, 6.0));
    }
}
