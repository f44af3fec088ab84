//! Depth images in metres, read from and written to 16-bit PNG.

use crate::error::{Error, Result};
use crate::imageio::ImageHeader;
use image::{DynamicImage, ImageBuffer, Luma};
use std::path::Path;

/// A depth image: z-depth in metres, `0.0` where the sensor gave no reading.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Row-major, `width * height` values.
    pub data: Vec<f32>,
}

impl DepthImage {
    /// An all-missing (zero) depth image of the given size.
    pub fn new(width: u32, height: u32) -> Self {
        DepthImage {
            width,
            height,
            data: vec![0.0; (width * height) as usize],
        }
    }

    /// Depth at integer pixel `(x, y)`; `None` outside the image, without a reading, or
    /// beyond `data` when it holds fewer than `width * height` values.
    pub fn get(&self, x: i64, y: i64) -> Option<f32> {
        if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
            return None;
        }
        let d = *self
            .data
            .get((y as u64 * self.width as u64 + x as u64) as usize)?;
        (d > 0.0).then_some(d)
    }

    /// Depth at the pixel nearest to a sub-pixel position.
    pub fn at(&self, x: f64, y: f64) -> Option<f32> {
        self.get(x.round() as i64, y.round() as i64)
    }

    /// Every `stride`-th pixel in x and y (nearest: depths are not blended across edges), the
    /// sides rounded up; all zeros when `data` does not hold `width * height` values.
    pub fn subsample(&self, stride: u32) -> DepthImage {
        let stride = stride.max(1);
        let (w, h) = (self.width.div_ceil(stride), self.height.div_ceil(stride));
        let mut out = DepthImage::new(w, h);
        if self.data.len() != self.width as usize * self.height as usize {
            return out;
        }
        for y in 0..h {
            for x in 0..w {
                out.data[(y * w + x) as usize] =
                    self.data[(y * stride * self.width + x * stride) as usize];
            }
        }
        out
    }

    /// Fraction of pixels with a reading.
    pub fn valid_fraction(&self) -> f64 {
        let n = self.data.iter().filter(|&&d| d > 0.0).count();
        n as f64 / self.data.len().max(1) as f64
    }

    /// Decodes a 16-bit single-channel PNG with `metres = value / scale`
    /// (TUM RGB-D and NYUv2 samples: scale 5000). An 8-bit or colour image is an error.
    /// A frame's depth image is read checked against its camera by
    /// [`crate::dataset::FrameSpec::read_depth`].
    pub fn read_png(path: impl AsRef<Path>, scale: f64) -> Result<Self> {
        let buf = read_png_u16(path.as_ref())?;
        Ok(Self::from_raw(buf, scale))
    }

    /// Depth in metres from raw 16-bit values, `metres = value / scale`.
    pub fn from_raw(buf: ImageBuffer<Luma<u16>, Vec<u16>>, scale: f64) -> Self {
        let (width, height) = buf.dimensions();
        let inv = 1.0 / scale;
        let data = buf
            .as_raw()
            .iter()
            .map(|&v| (v as f64 * inv) as f32)
            .collect();
        DepthImage {
            width,
            height,
            data,
        }
    }

    /// Encodes as a 16-bit PNG with `value = round(metres * scale)`, atomically.
    /// Depths beyond the 16-bit range are written as 0 (no reading).
    pub fn write_png(&self, path: impl AsRef<Path>, scale: f64) -> Result<()> {
        let raw: Vec<u16> = self
            .data
            .iter()
            .map(|&d| {
                let v = (d as f64 * scale).round();
                if d > 0.0 && v <= u16::MAX as f64 {
                    v as u16
                } else {
                    0
                }
            })
            .collect();
        let buf: ImageBuffer<Luma<u16>, Vec<u16>> =
            ImageBuffer::from_raw(self.width, self.height, raw)
                .ok_or_else(|| Error::msg("depth buffer size does not match its dimensions"))?;
        crate::imageio::write_png_atomic(path, &DynamicImage::ImageLuma16(buf))
    }
}

/// Decodes a 16-bit single-channel PNG as it is (raw sensor values); an 8-bit or colour image
/// is an error naming the file.
pub(crate) fn read_png_u16(path: &Path) -> Result<ImageBuffer<Luma<u16>, Vec<u16>>> {
    read_png_u16_with(path, crate::io::MAX_IMAGE_BYTES, &crate::imageio::any_image)
}

/// [`read_png_u16`] of a file of at most `max_bytes`, its header also checked by `check`
/// before the pixels are decoded ([`crate::imageio::decode`]).
pub(crate) fn read_png_u16_with(
    path: &Path,
    max_bytes: u64,
    check: &dyn Fn(&ImageHeader) -> Result<()>,
) -> Result<ImageBuffer<Luma<u16>, Vec<u16>>> {
    let format = |h: &ImageHeader| {
        check(h)?;
        if (h.channels, h.bits) != (1, 16) {
            return Err(Error::invalid(
                path,
                format!(
                    "depth images must be 16-bit single-channel PNG, found {}",
                    h.describe()
                ),
            ));
        }
        Ok(())
    };
    match crate::imageio::decode(path, max_bytes, &format)? {
        DynamicImage::ImageLuma16(buf) => Ok(buf),
        other => Err(Error::invalid(
            path,
            format!(
                "depth images must be 16-bit single-channel PNG, found {:?}",
                other.color()
            ),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::DepthImage;

    #[test]
    fn subsample_takes_every_stride_th_pixel_and_rounds_the_sides_up() {
        let mut d = DepthImage::new(5, 3);
        for (i, v) in d.data.iter_mut().enumerate() {
            *v = i as f32;
        }
        let s = d.subsample(2);
        assert_eq!((s.width, s.height), (3, 2));
        assert_eq!(s.data, vec![0.0, 2.0, 4.0, 10.0, 12.0, 14.0]);
        assert_eq!(d.subsample(1), d);
        assert_eq!(d.subsample(0), d);
        // Data that do not match the size give zeros, not a panic.
        d.data.truncate(4);
        assert!(d.subsample(2).data.iter().all(|v| *v == 0.0));
        // Nor does reading past them: pixel (1, 0) is there, (4, 2) is not.
        assert_eq!(d.get(1, 0), Some(1.0));
        assert_eq!(d.get(4, 2), None);
        assert_eq!(d.at(4.2, 1.8), None);
    }
}
