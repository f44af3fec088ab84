//! Pyramidal Lucas-Kanade optical flow (Bouguet, "Pyramidal implementation of the Lucas Kanade
//! feature tracker", Intel 2000): where each point of one image went in the next, by
//! Gauss-Newton on the intensity of a square window, coarse to fine, with a forward-backward
//! check. Monocular tracking follows the last keypoints with it between keyframes
//! (`crate::slam::frontend::tracking`), so the keypoint network runs on keyframes only.

use image::GrayImage;
use rayon::prelude::*;

/// An image and its gradients at a few scales, each half the size of the one before.
#[derive(Debug, Clone)]
pub struct Pyramid {
    levels: Vec<Level>,
}

/// One scale: intensities in `[0, 1]` and their Scharr derivatives along x and y.
#[derive(Debug, Clone)]
struct Level {
    width: usize,
    height: usize,
    image: Vec<f32>,
    dx: Vec<f32>,
    dy: Vec<f32>,
}

/// How [`track`] follows points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlowParams {
    /// Half the window's side: the window is `2·radius + 1` pixels square.
    pub radius: usize,
    /// Gauss-Newton iterations per level at most.
    pub iterations: usize,
    /// An iteration's step below this (pixels) ends the level.
    pub epsilon: f32,
    /// The window's smaller structure-tensor eigenvalue per pixel below this: too little
    /// texture to follow (intensities in `[0, 1]`).
    pub min_eigenvalue: f32,
    /// A point tracked back from where it went must land within this many pixels of where it
    /// started.
    pub max_back_error: f32,
}

impl Default for FlowParams {
    fn default() -> Self {
        FlowParams {
            radius: 7,
            iterations: 20,
            epsilon: 0.01,
            min_eigenvalue: 1e-4,
            max_back_error: 1.0,
        }
    }
}

impl Pyramid {
    /// `levels` scales of `gray` (at least one; fewer where a level would be under 16 pixels a
    /// side).
    pub fn new(gray: &GrayImage, levels: usize) -> Self {
        let (w, h) = (gray.width() as usize, gray.height() as usize);
        let image: Vec<f32> = gray
            .as_raw()
            .iter()
            .map(|&v| f32::from(v) / 255.0)
            .collect();
        let mut out = vec![Level::new(w, h, image)];
        while out.len() < levels.max(1) {
            let last = &out[out.len() - 1];
            let (w2, h2) = (last.width / 2, last.height / 2);
            if w2 < 16 || h2 < 16 {
                break;
            }
            let half = (0..h2)
                .flat_map(|y| (0..w2).map(move |x| (x, y)))
                .map(|(x, y)| {
                    let at =
                        |dx: usize, dy: usize| last.image[(2 * y + dy) * last.width + 2 * x + dx];
                    0.25 * (at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1))
                })
                .collect();
            out.push(Level::new(w2, h2, half));
        }
        Pyramid { levels: out }
    }

    /// Width and height of the full-size image.
    pub fn size(&self) -> (usize, usize) {
        (self.levels[0].width, self.levels[0].height)
    }
}

impl Level {
    fn new(width: usize, height: usize, image: Vec<f32>) -> Self {
        // Scharr's derivative (3, 10, 3 across; −1, 0, 1 along) / 32: per pixel. Borders 0.
        let mut dx = vec![0.0; width * height];
        let mut dy = vec![0.0; width * height];
        for y in 1..height.saturating_sub(1) {
            for x in 1..width.saturating_sub(1) {
                let p = |dx: isize, dy: isize| {
                    image[(y as isize + dy) as usize * width + (x as isize + dx) as usize]
                };
                let i = y * width + x;
                dx[i] = (3.0 * (p(1, -1) - p(-1, -1))
                    + 10.0 * (p(1, 0) - p(-1, 0))
                    + 3.0 * (p(1, 1) - p(-1, 1)))
                    / 32.0;
                dy[i] = (3.0 * (p(-1, 1) - p(-1, -1))
                    + 10.0 * (p(0, 1) - p(0, -1))
                    + 3.0 * (p(1, 1) - p(1, -1)))
                    / 32.0;
            }
        }
        Level {
            width,
            height,
            image,
            dx,
            dy,
        }
    }

    /// Whether the window of `radius` around `(x, y)` lies where bilinear sampling is defined
    /// (nowhere in an image under two pixels a side).
    fn holds(&self, x: f32, y: f32, radius: usize) -> bool {
        let r = radius as f32;
        x - r >= 0.0
            && y - r >= 0.0
            && x + r < self.width as f32 - 1.0
            && y + r < self.height as f32 - 1.0
    }
}

/// `plane` (row-major, `width` wide) at `(x, y)`, bilinearly; `(x, y)` within
/// `[0, width − 1) × [0, height − 1)`.
#[inline]
fn sample(plane: &[f32], width: usize, x: f32, y: f32) -> f32 {
    let (x0, y0) = (x.floor(), y.floor());
    let (ax, ay) = (x - x0, y - y0);
    let i = y0 as usize * width + x0 as usize;
    let top = plane[i] + ax * (plane[i + 1] - plane[i]);
    let bottom = plane[i + width] + ax * (plane[i + width + 1] - plane[i + width]);
    top + ay * (bottom - top)
}

/// A window's intensities and gradients in the image a point comes from, kept between the
/// points a task follows.
#[derive(Default)]
struct Window {
    template: Vec<f32>,
    gx: Vec<f32>,
    gy: Vec<f32>,
}

/// Where `point` of `from` went in `to`, starting from the displacement `guess`; `None` where
/// the window leaves an image, has too little texture, or the iterations diverge.
fn follow(
    from: &Pyramid,
    to: &Pyramid,
    point: [f32; 2],
    guess: [f32; 2],
    p: &FlowParams,
    window: &mut Window,
) -> Option<[f32; 2]> {
    let top = from.levels.len().min(to.levels.len()) - 1;
    let side = 2 * p.radius + 1;
    let n = side * side;
    let Window { template, gx, gy } = window;
    for v in [&mut *template, &mut *gx, &mut *gy] {
        v.resize(n, 0.0);
    }
    let scale = (1u32 << top) as f32;
    let mut g = [guess[0] / scale, guess[1] / scale];
    for level in (0..=top).rev() {
        let s = 1.0 / (1u32 << level) as f32;
        let (a, b) = (&from.levels[level], &to.levels[level]);
        let (px, py) = (point[0] * s, point[1] * s);
        if !a.holds(px, py, p.radius) {
            return None;
        }
        let (mut sxx, mut sxy, mut syy) = (0.0f32, 0.0f32, 0.0f32);
        let r = p.radius as f32;
        for k in 0..n {
            let (x, y) = (px - r + (k % side) as f32, py - r + (k / side) as f32);
            template[k] = sample(&a.image, a.width, x, y);
            let (ix, iy) = (sample(&a.dx, a.width, x, y), sample(&a.dy, a.width, x, y));
            gx[k] = ix;
            gy[k] = iy;
            sxx += ix * ix;
            sxy += ix * iy;
            syy += iy * iy;
        }
        let det = sxx * syy - sxy * sxy;
        let half_trace = 0.5 * (sxx + syy);
        let min_eig = half_trace - (0.25 * (sxx - syy) * (sxx - syy) + sxy * sxy).sqrt();
        if min_eig / n as f32 <= p.min_eigenvalue || det <= f32::MIN_POSITIVE {
            return None;
        }
        let mut d = [0.0f32; 2];
        for _ in 0..p.iterations {
            let (qx, qy) = (px + g[0] + d[0], py + g[1] + d[1]);
            if !b.holds(qx, qy, p.radius) {
                return None;
            }
            let (mut bx, mut by) = (0.0f32, 0.0f32);
            for k in 0..n {
                let (x, y) = (qx - r + (k % side) as f32, qy - r + (k / side) as f32);
                let e = template[k] - sample(&b.image, b.width, x, y);
                bx += e * gx[k];
                by += e * gy[k];
            }
            let step = [(syy * bx - sxy * by) / det, (sxx * by - sxy * bx) / det];
            d[0] += step[0];
            d[1] += step[1];
            if !(d[0].is_finite() && d[1].is_finite()) {
                return None;
            }
            if step[0] * step[0] + step[1] * step[1] < p.epsilon * p.epsilon {
                break;
            }
        }
        g = [g[0] + d[0], g[1] + d[1]];
        if level > 0 {
            g = [2.0 * g[0], 2.0 * g[1]];
        }
    }
    Some([point[0] + g[0], point[1] + g[1]])
}

/// Where each of `points` of `from` went in `to` (`None`: lost), each started from the
/// displacement `guesses` gives (none: no motion), and kept only when followed back from
/// where it went it lands within [`FlowParams::max_back_error`] of where it started. The
/// points run in parallel.
pub fn track(
    from: &Pyramid,
    to: &Pyramid,
    points: &[[f32; 2]],
    guesses: Option<&[[f32; 2]]>,
    p: &FlowParams,
) -> Vec<Option<[f32; 2]>> {
    assert!(guesses.is_none_or(|g| g.len() == points.len()));
    points
        .par_iter()
        .enumerate()
        .map_init(Window::default, |window, (i, &pt)| {
            let guess = guesses.map_or([0.0; 2], |g| g[i]);
            let q = follow(from, to, pt, guess, p, window)?;
            let back = follow(to, from, q, [pt[0] - q[0], pt[1] - q[1]], p, window)?;
            let (ex, ey) = (back[0] - pt[0], back[1] - pt[1]);
            (ex * ex + ey * ey <= p.max_back_error * p.max_back_error).then_some(q)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth textured image: sums of sines, shifted by `(sx, sy)` pixels.
    fn texture(w: u32, h: u32, sx: f32, sy: f32) -> GrayImage {
        GrayImage::from_fn(w, h, |x, y| {
            let (x, y) = (x as f32 - sx, y as f32 - sy);
            let v = 0.5
                + 0.2 * (x * 0.21).sin() * (y * 0.17).cos()
                + 0.15 * (x * 0.07 + y * 0.11).sin()
                + 0.1 * (y * 0.31 - x * 0.05).cos();
            image::Luma([(v.clamp(0.0, 1.0) * 255.0).round() as u8])
        })
    }

    #[test]
    fn a_shifted_image_is_followed_to_a_tenth_of_a_pixel() {
        let (sx, sy) = (6.3, -4.7);
        let a = Pyramid::new(&texture(160, 120, 0.0, 0.0), 3);
        let b = Pyramid::new(&texture(160, 120, sx, sy), 3);
        let points: Vec<[f32; 2]> = (0..5)
            .flat_map(|i| (0..4).map(move |j| [40.0 + 20.0 * i as f32, 35.0 + 15.0 * j as f32]))
            .collect();
        let moved = track(&a, &b, &points, None, &FlowParams::default());
        for (p, q) in points.iter().zip(&moved) {
            let q = q.expect("followed");
            assert!(
                (q[0] - p[0] - sx).abs() < 0.1 && (q[1] - p[1] - sy).abs() < 0.1,
                "{p:?} went to {q:?}"
            );
        }
    }

    #[test]
    fn flat_windows_and_points_that_leave_the_image_are_lost() {
        let flat = Pyramid::new(&GrayImage::from_pixel(80, 60, image::Luma([128])), 2);
        let points = [[40.0, 30.0]];
        assert_eq!(
            track(&flat, &flat, &points, None, &FlowParams::default()),
            [None]
        );
        // An image too small for any window: lost, no panic.
        let dot = Pyramid::new(&GrayImage::from_pixel(1, 1, image::Luma([9])), 3);
        let params = FlowParams::default();
        assert_eq!(track(&dot, &dot, &[[0.0, 0.0]], None, &params), [None]);
        let a = Pyramid::new(&texture(80, 60, 0.0, 0.0), 2);
        let edge = [[3.0, 30.0], [40.0, 58.5]];
        assert_eq!(
            track(&a, &a, &edge, None, &FlowParams::default()),
            [None, None]
        );
        // A guess that moves the window off the image loses the point too.
        let far = track(
            &a,
            &a,
            &[[40.0, 30.0]],
            Some(&[[100.0, 0.0]]),
            &FlowParams::default(),
        );
        assert_eq!(far, [None]);
    }

    #[test]
    fn a_point_that_does_not_come_back_is_dropped() {
        // The second image is unrelated noise: forward flow lands somewhere, backward flow
        // does not return to the start.
        let a = Pyramid::new(&texture(120, 90, 0.0, 0.0), 3);
        let noise = GrayImage::from_fn(120, 90, |x, y| {
            let h = (x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)).wrapping_mul(97);
            image::Luma([(h >> 13) as u8])
        });
        let b = Pyramid::new(&noise, 3);
        let points: Vec<[f32; 2]> = (0..6).map(|i| [30.0 + 10.0 * i as f32, 45.0]).collect();
        let kept = track(&a, &b, &points, None, &FlowParams::default());
        let n = kept.iter().filter(|q| q.is_some()).count();
        assert!(n <= 1, "{kept:?}");
    }
}
