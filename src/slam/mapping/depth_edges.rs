//! Depth-edge filtering before fusion. A depth image from a network (SDFCNN predicts at
//! its inner size and is resized up) is smooth across object boundaries: the pixels on a
//! boundary get depths between the near and the far surface ("flying pixels") and
//! belong to neither. Sensor depth has the same defect, milder. Fusing them puts map
//! points in empty space; this drops them, the usual step before TSDF fusion of
//! predicted depth (CNN-SLAM, Tateno et al. 2017, fuses confidence-weighted depth).

use crate::dataset::DepthImage;

/// Invalidates (sets to 0) every pixel that lies on a depth discontinuity: along x or y,
/// with both neighbours `reach` pixels away valid, the second difference of inverse depth
/// `|1/d₋ + 1/d₊ − 2/d|`, times `d`, exceeds `max_ratio`. A plane has an inverse depth
/// affine in the pixel coordinates, so a slanted floor or a wall seen at a grazing angle
/// scores 0 however steep its depth gradient; a pixel between a near and a far surface
/// does not. `max_ratio <= 0`, `reach == 0`, or data that do not hold `width * height`
/// values leave the image as it is. Returns how many pixels were dropped.
pub(crate) fn drop_depth_edges(depth: &mut DepthImage, reach: u32, max_ratio: f32) -> usize {
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

/// The test of [`drop_depth_edges`]: whether a pixel's reading and the readings `reach`
/// pixels to either side (along x or y) do not lie on one plane.
#[derive(Debug, Clone, Copy, PartialEq)]
struct EdgeWindow {
    /// Pixels to either side.
    reach: u32,
    /// The largest second difference of inverse depth, times the depth, of a plane.
    max_ratio: f32,
}

impl EdgeWindow {
    /// `None` (no test) when `max_ratio <= 0` or `reach == 0`.
    fn new(reach: u32, max_ratio: f32) -> Option<Self> {
        (max_ratio > 0.0 && reach > 0).then_some(EdgeWindow { reach, max_ratio })
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
}
