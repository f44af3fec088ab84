//! Single-channel images and the few filters the feature code needs: grey conversion,
//! Gaussian blur, Sobel gradients, bilinear sampling.

use image::{GrayImage, RgbImage};
use rayon::prelude::*;

/// A row-major `f32` image.
#[derive(Debug, Clone, PartialEq)]
pub struct GrayF32 {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

impl GrayF32 {
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
        let (rx, ry) = ((kx.len() / 2) as isize, (ky.len() / 2) as isize);
        let mut tmp = GrayF32::new(w, h);
        tmp.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, out) in row.iter_mut().enumerate() {
                *out = kx
                    .iter()
                    .enumerate()
                    .map(|(k, c)| c * self.get_clamped(x as isize + k as isize - rx, y as isize))
                    .sum();
            }
        });
        let mut out = GrayF32::new(w, h);
        out.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                *o = ky
                    .iter()
                    .enumerate()
                    .map(|(k, c)| c * tmp.get_clamped(x as isize, y as isize + k as isize - ry))
                    .sum();
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

/// Normalised Gaussian kernel of radius `ceil(3 sigma)`.
pub fn gaussian_kernel(sigma: f32) -> Vec<f32> {
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

#[cfg(test)]
mod tests {
    use super::*;

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
}
