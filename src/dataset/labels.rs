//! 8-bit label images (class indices), read without any colour conversion so
//! that greyscale and palette PNGs both give their stored indices.

use crate::error::{Error, Result};
use crate::imageio::{ImageHeader, any_image};
use crate::io::MAX_IMAGE_BYTES;
use std::path::Path;

/// A row-major label image: NYUv2 40-class indices 0-39, 255 = void.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelImage {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Labels row-major, `width * height` values.
    pub data: Vec<u8>,
}

pub use crate::classes::VOID;

impl LabelImage {
    /// An image of `width` x `height` pixels all set to `fill`.
    pub fn new(width: u32, height: u32, fill: u8) -> Self {
        LabelImage {
            width,
            height,
            data: vec![fill; (width * height) as usize],
        }
    }

    /// The label at pixel column `x`, row `y`.
    #[inline]
    pub fn get(&self, x: u32, y: u32) -> u8 {
        self.data[(y * self.width + x) as usize]
    }

    /// Reads the raw indices of an 8-bit greyscale or palette PNG (any values: see
    /// [`LabelImage::read_classes`]).
    pub fn read_png(path: impl AsRef<Path>) -> Result<Self> {
        Self::read_png_with(path.as_ref(), MAX_IMAGE_BYTES, &any_image)
    }

    /// Reads a label image of NYUv2's 40 classes: [`LabelImage::read_png`] with every value
    /// checked to be a class 0-39 or 255 (void) ([`LabelImage::validate`]). Every reader of
    /// ground-truth labels (`eval seg`, training, `slam --labels gt`) reads them so.
    pub fn read_classes(path: impl AsRef<Path>) -> Result<Self> {
        Self::read_classes_with(path.as_ref(), MAX_IMAGE_BYTES, &any_image)
    }

    /// [`LabelImage::read_classes`] of a file of at most `max_bytes` whose header `check`
    /// also passes (a frame's size: [`crate::dataset::FrameSpec::read_labels`]).
    pub fn read_classes_with(
        path: &Path,
        max_bytes: u64,
        check: &dyn Fn(&ImageHeader) -> Result<()>,
    ) -> Result<Self> {
        let labels = Self::read_png_with(path, max_bytes, check)?;
        labels.validate(crate::classes::NUM_CLASSES, path)?;
        Ok(labels)
    }

    fn read_png_with(
        path: &Path,
        max_bytes: u64,
        check: &dyn Fn(&ImageHeader) -> Result<()>,
    ) -> Result<Self> {
        let (info, buf) = decode_png(path, max_bytes, check)?;
        use png::{BitDepth, ColorType};
        match (info.color_type, info.bit_depth) {
            (ColorType::Grayscale | ColorType::Indexed, BitDepth::Eight) => {}
            (c, b) => {
                return Err(Error::invalid(
                    path,
                    format!(
                        "label images must be 8-bit greyscale or palette PNG, found {c:?} {b:?}"
                    ),
                ));
            }
        }
        let (w, h) = (info.width, info.height);
        let mut data = Vec::with_capacity((w * h) as usize);
        for row in buf.chunks(info.line_size).take(h as usize) {
            data.extend_from_slice(&row[..w as usize]);
        }
        Ok(LabelImage {
            width: w,
            height: h,
            data,
        })
    }

    /// Reads a greyscale PNG of class ids, 8- or 16-bit (894-class labels need 16 bits):
    /// `(width, height, ids)` row-major.
    pub fn read_png_ids(path: impl AsRef<Path>) -> Result<(u32, u32, Vec<u16>)> {
        let path = path.as_ref();
        let (info, buf) = decode_png(path, MAX_IMAGE_BYTES, &any_image)?;
        use png::{BitDepth, ColorType};
        let (w, h) = (info.width as usize, info.height as usize);
        let rows = buf.chunks(info.line_size).take(h);
        let ids: Vec<u16> = match (info.color_type, info.bit_depth) {
            (ColorType::Grayscale, BitDepth::Eight) => rows
                .flat_map(|r| r[..w].iter().map(|&v| v as u16))
                .collect(),
            (ColorType::Grayscale, BitDepth::Sixteen) => rows
                .flat_map(|r| {
                    r[..2 * w]
                        .chunks_exact(2)
                        .map(|b| u16::from_be_bytes([b[0], b[1]]))
                })
                .collect(),
            (c, b) => {
                return Err(Error::invalid(
                    path,
                    format!(
                        "class-id images must be 8- or 16-bit greyscale PNG, found {c:?} {b:?}"
                    ),
                ));
            }
        };
        Ok((info.width, info.height, ids))
    }

    /// Checks that every value is a class below `num_classes` or [`VOID`].
    pub fn validate(&self, num_classes: usize, path: &Path) -> Result<()> {
        match self
            .data
            .iter()
            .position(|&v| v != VOID && v as usize >= num_classes)
        {
            None => Ok(()),
            Some(i) => Err(Error::invalid(
                path,
                format!(
                    "label {} at pixel ({}, {}) is not a class 0-{} nor 255 (void)",
                    self.data[i],
                    i as u32 % self.width,
                    i as u32 / self.width,
                    num_classes - 1
                ),
            )),
        }
    }

    /// Writes an 8-bit greyscale PNG, atomically.
    pub fn write_png(&self, path: impl AsRef<Path>) -> Result<()> {
        let img = image::GrayImage::from_raw(self.width, self.height, self.data.clone())
            .ok_or_else(|| Error::msg("label buffer size does not match its dimensions"))?;
        crate::imageio::write_png_atomic(path, &image::DynamicImage::ImageLuma8(img))
    }
}

/// Decodes a PNG as stored (no expansion): its header and raw rows. The file is read as every
/// image is ([`crate::io::read_image_bytes`]: a regular file of at most `max_bytes`), its sides
/// bounded and its header checked by `check` before the rows are allocated.
fn decode_png(
    path: &Path,
    max_bytes: u64,
    check: &dyn Fn(&ImageHeader) -> Result<()>,
) -> Result<(png::OutputInfo, Vec<u8>)> {
    let bytes = crate::io::read_image_bytes(path, max_bytes)?;
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let bad = |e: png::DecodingError| Error::invalid(path, format!("cannot decode label PNG: {e}"));
    let mut reader = decoder.read_info().map_err(bad)?;
    let header = {
        let info = reader.info();
        let channels = match info.color_type {
            png::ColorType::Grayscale | png::ColorType::Indexed => 1,
            png::ColorType::GrayscaleAlpha => 2,
            png::ColorType::Rgb => 3,
            png::ColorType::Rgba => 4,
        };
        ImageHeader {
            width: info.width,
            height: info.height,
            channels,
            bits: info.bit_depth as u8,
        }
    };
    crate::imageio::check_sides(path, header.width, header.height)?;
    check(&header)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| Error::invalid(path, "label image too large"))?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(bad)?;
    Ok((info, buf))
}
