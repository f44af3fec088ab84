//! Single-channel images and the few filters the feature code needs: grey conversion,
//! Gaussian blur, Sobel gradients, bilinear sampling; and a picture of keypoint matches.

use image::{GrayImage, Rgb, RgbImage};
use nalgebra::Point2;
use rayon::prelude::*;

/// A row-major `f32` image.
#[derive(Debug, Clone, PartialEq)]
pub struct GrayF32 {
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Row-major values, `width * height` of them.
    pub data: Vec<f32>,
}

impl GrayF32 {
    /// A `width x height` image, all zero.
    pub fn new(width: usize, height: usize) -> Self {
        GrayF32 {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    /// Intensities in [0, 1].
    pub fn from_gray(img: &GrayImage) -> Self {
        GrayF32 {
            width: img.width() as usize,
            height: img.height() as usize,
            data: img.as_raw().iter().map(|&v| v as f32 / 255.0).collect(),
        }
    }

    /// Luma (ITU-R 601, as OpenCV's `cvtColor`) in [0, 1].
    pub fn from_rgb(img: &RgbImage) -> Self {
        GrayF32 {
            width: img.width() as usize,
            height: img.height() as usize,
            data: img
                .pixels()
                .map(|p| (0.299 * p[0] as f32 + 0.587 * p[1] as f32 + 0.114 * p[2] as f32) / 255.0)
                .collect(),
        }
    }

    /// Value at pixel `(x, y)`, which must lie inside the image.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Value at integer coordinates clamped to the border.
    #[inline]
    pub fn get_clamped(&self, x: isize, y: isize) -> f32 {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        self.data[y * self.width + x]
    }

    /// Bilinear sample at a sub-pixel position (borders clamped).
    pub fn sample(&self, x: f64, y: f64) -> f32 {
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let (x0, y0) = (x0 as isize, y0 as isize);
        let a = self.get_clamped(x0, y0) * (1.0 - fx) + self.get_clamped(x0 + 1, y0) * fx;
        let b = self.get_clamped(x0, y0 + 1) * (1.0 - fx) + self.get_clamped(x0 + 1, y0 + 1) * fx;
        a * (1.0 - fy) + b * fy
    }

    /// Separable convolution with a symmetric kernel (borders clamped).
    pub fn convolve_separable(&self, kx: &[f32], ky: &[f32]) -> GrayF32 {
        let (w, h) = (self.width, self.height);
        if w == 0 || h == 0 {
            return GrayF32::new(w, h);
        }
        let (rx, ry) = (kx.len() / 2, (ky.len() / 2) as isize);
        // Rows: each padded by its clamped border pixels, then one multiply-add pass per
        // tap over the whole row (vectorised; the taps are summed in order, as a per-pixel
        // sum over the taps would).
        let mut tmp = GrayF32::new(w, h);
        tmp.data
            .par_chunks_mut(w)
            .zip(self.data.par_chunks(w))
            .for_each_init(Vec::new, |padded, (out, row)| {
                padded.clear();
                padded.extend(std::iter::repeat_n(row[0], rx));
                padded.extend_from_slice(row);
                padded.extend(std::iter::repeat_n(
                    row[w - 1],
                    kx.len().saturating_sub(rx + 1),
                ));
                for (k, &c) in kx.iter().enumerate() {
                    for (o, &v) in out.iter_mut().zip(&padded[k..k + w]) {
                        *o += c * v;
                    }
                }
            });
        // Columns: each output row is the taps' rows (clamped at the borders) multiplied
        // and added in order.
        let mut out = GrayF32::new(w, h);
        out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (k, &c) in ky.iter().enumerate() {
                let sy = (y as isize + k as isize - ry).clamp(0, h as isize - 1) as usize;
                for (o, &v) in row.iter_mut().zip(&tmp.data[sy * w..(sy + 1) * w]) {
                    *o += c * v;
                }
            }
        });
        out
    }

    /// Gaussian blur with standard deviation `sigma` pixels.
    pub fn gaussian_blur(&self, sigma: f32) -> GrayF32 {
        let k = gaussian_kernel(sigma);
        self.convolve_separable(&k, &k)
    }

    /// Sobel derivatives `(d/dx, d/dy)`.
    pub fn sobel(&self) -> (GrayF32, GrayF32) {
        let gx = self.convolve_separable(&[-1.0, 0.0, 1.0], &[1.0, 2.0, 1.0]);
        let gy = self.convolve_separable(&[1.0, 2.0, 1.0], &[-1.0, 0.0, 1.0]);
        (gx, gy)
    }
}

/// The largest Gaussian blur a config or command line may ask for, pixels: its kernel has 97
/// taps; a typo such as 1e5 would take hours a frame (and overflow the kernel's index).
pub(crate) const MAX_BLUR_SIGMA: f32 = 16.0;

/// The longest motion-blur kernel a config or command line may ask for, pixels.
pub(crate) const MAX_MOTION_KERNEL: usize = 255;

/// Normalised Gaussian kernel of radius `ceil(3 sigma)`.
pub(crate) fn gaussian_kernel(sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as i32;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f32 = k.iter().sum();
    k.into_iter().map(|v| v / s).collect()
}

/// Grey conversion of OpenCV's `cvtColor(RGB2GRAY)` for 8-bit images (fixed point,
/// 0.299 R + 0.587 G + 0.114 B, rounded).
pub fn rgb_to_gray(img: &RgbImage) -> GrayImage {
    let data = img
        .pixels()
        .map(|p| {
            let v = p[0] as u32 * 4899 + p[1] as u32 * 9617 + p[2] as u32 * 1868;
            ((v + (1 << 13)) >> 14) as u8
        })
        .collect();
    GrayImage::from_raw(img.width(), img.height(), data).unwrap_or_default()
}

/// An intensity image in [0, 1] as 8-bit grey levels (rounded, clamped), e.g. after
/// photometric augmentation, for ORB.
pub fn gray_from_f32(img: &GrayF32) -> GrayImage {
    let data = img
        .data
        .iter()
        .map(|&v| (v * 255.0).round().clamp(0.0, 255.0) as u8)
        .collect();
    GrayImage::from_raw(img.width as u32, img.height as u32, data).unwrap_or_default()
}

/// Line colours of [`match_picture`], cycled so that neighbouring lines differ.
const MATCH_COLOURS: [[u8; 3]; 6] = [
    [40, 220, 60],
    [250, 200, 30],
    [60, 160, 255],
    [240, 70, 200],
    [250, 120, 40],
    [80, 230, 220],
];

/// Two grey images side by side (`a` left, `b` right, top-aligned, slightly darkened) with
/// a line from each match's pixel in `a` to its pixel in `b` (pairs as
/// [`crate::fpfdcnn::evaluate::fpfdcnn_matches`] returns them), each line ended by a small
/// square at both keypoints. Parts of a line outside the picture are left out.
pub fn match_picture(
    a: &GrayImage,
    b: &GrayImage,
    matches: &[(Point2<f64>, Point2<f64>)],
) -> RgbImage {
    let (wa, w) = (a.width(), a.width() + b.width());
    let h = a.height().max(b.height()).max(1);
    let mut img = RgbImage::new(w.max(1), h);
    for (x0, g) in [(0, a), (wa, b)] {
        for (x, y, p) in g.enumerate_pixels() {
            let v = (p[0] as f32 * 0.8) as u8;
            img.put_pixel(x0 + x, y, Rgb([v, v, v]));
        }
    }
    let put = |img: &mut RgbImage, x: f64, y: f64, c: Rgb<u8>| {
        if x >= 0.0 && y >= 0.0 && (x as u32) < img.width() && (y as u32) < img.height() {
            img.put_pixel(x as u32, y as u32, c);
        }
    };
    for (k, (pa, pb)) in matches.iter().enumerate() {
        let c = Rgb(MATCH_COLOURS[k % MATCH_COLOURS.len()]);
        let (x1, y1, x2, y2) = (pa.x, pa.y, pb.x + wa as f64, pb.y);
        if ![x1, y1, x2, y2].iter().all(|v| v.is_finite()) {
            continue;
        }
        let n = ((x2 - x1).abs().max((y2 - y1).abs()).ceil() as usize).clamp(1, 1 << 16);
        for s in 0..=n {
            let t = s as f64 / n as f64;
            put(&mut img, x1 + t * (x2 - x1), y1 + t * (y2 - y1), c);
        }
        for (x, y) in [(x1, y1), (x2, y2)] {
            for dy in -1..=1 {
                for dx in -1..=1 {
                    put(&mut img, x + dx as f64, y + dy as f64, c);
                }
            }
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn match_picture_puts_the_images_side_by_side_and_draws_each_match() {
        let a = GrayImage::from_pixel(10, 6, image::Luma([100]));
        let b = GrayImage::from_pixel(8, 4, image::Luma([200]));
        let m = [
            (Point2::new(2.0, 2.0), Point2::new(5.0, 2.0)),
            (Point2::new(1.0, 5.0), Point2::new(f64::NAN, 0.0)),
            (Point2::new(-50.0, 0.0), Point2::new(1.0, 0.0)),
        ];
        let img = match_picture(&a, &b, &m);
        assert_eq!(img.dimensions(), (18, 6));
        // Darkened images, black below the shorter one.
        assert_eq!(img.get_pixel(0, 4), &Rgb([80, 80, 80]));
        assert_eq!(img.get_pixel(17, 3), &Rgb([160, 160, 160]));
        assert_eq!(img.get_pixel(17, 5), &Rgb([0, 0, 0]));
        // The first match: a horizontal line of the first colour from (2, 2) to (15, 2).
        let first = Rgb(MATCH_COLOURS[0]);
        assert!((2..=15).all(|x| img.get_pixel(x, 2) == &first));
        // The non-finite match is skipped; the third is clipped to the picture.
        assert_eq!(img.get_pixel(1, 5), &Rgb([80, 80, 80]));
        assert_eq!(img.get_pixel(0, 0), &Rgb(MATCH_COLOURS[2]));
        assert_eq!(img.get_pixel(11, 0), &Rgb(MATCH_COLOURS[2]));
    }

    #[test]
    fn sobel_of_a_ramp_is_constant() {
        let mut img = GrayF32::new(8, 6);
        for y in 0..6 {
            for x in 0..8 {
                img.data[y * 8 + x] = x as f32;
            }
        }
        let (gx, gy) = img.sobel();
        assert_eq!(gx.get(4, 3), 8.0); // (1 + 2 + 1) * (5 - 3)
        assert_eq!(gy.get(4, 3), 0.0);
        assert!((img.sample(2.5, 1.0) - 2.5).abs() < 1e-6);
        assert!((gaussian_kernel(1.0).iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }

    /// The per-pixel definition: each output the in-order sum over the taps of the clamped
    /// input.
    fn convolve_reference(img: &GrayF32, kx: &[f32], ky: &[f32]) -> GrayF32 {
        let (w, h) = (img.width, img.height);
        let (rx, ry) = ((kx.len() / 2) as isize, (ky.len() / 2) as isize);
        let mut tmp = GrayF32::new(w, h);
        let mut out = GrayF32::new(w, h);
        for y in 0..h {
            for x in 0..w {
                tmp.data[y * w + x] = kx
                    .iter()
                    .enumerate()
                    .map(|(k, c)| c * img.get_clamped(x as isize + k as isize - rx, y as isize))
                    .fold(0.0, |a, b| a + b);
            }
        }
        for y in 0..h {
            for x in 0..w {
                out.data[y * w + x] = ky
                    .iter()
                    .enumerate()
                    .map(|(k, c)| c * tmp.get_clamped(x as isize, y as isize + k as isize - ry))
                    .fold(0.0, |a, b| a + b);
            }
        }
        out
    }

    #[test]
    fn separable_convolution_equals_its_per_pixel_definition_bit_for_bit() {
        let kernels: [&[f32]; 4] = [
            &gaussian_kernel(2.0),
            &[-1.0, 0.0, 1.0],
            &[0.25, 0.75],
            &[1.0],
        ];
        for (w, h) in [(37, 23), (3, 2), (1, 1), (640, 4)] {
            let mut img = GrayF32::new(w, h);
            for (i, v) in img.data.iter_mut().enumerate() {
                *v = ((i * 7919) % 257) as f32 / 256.0 - 0.3;
            }
            for kx in kernels {
                for ky in kernels {
                    let fast = img.convolve_separable(kx, ky);
                    let slow = convolve_reference(&img, kx, ky);
                    assert_eq!(
                        fast.data,
                        slow.data,
                        "{w}x{h}, {} x {} taps",
                        kx.len(),
                        ky.len()
                    );
                }
            }
        }
    }
}
