//! 8-bit label images (class indices), read without any colour conversion so
//! that greyscale and palette PNGs both give their stored indices.

use crate::error::{Error, Result};
use std::path::Path;

/// A row-major label image: NYUv2 40-class indices 0-39, 255 = void.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelImage {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

pub use crate::classes::VOID;

impl LabelImage {
    pub fn new(width: u32, height: u32, fill: u8) -> Self {
        LabelImage {
            width,
            height,
            data: vec![fill; (width * height) as usize],
        }
    }

    #[inline]
    pub fn get(&self, x: u32, y: u32) -> u8 {
        self.data[(y * self.width + x) as usize]
    }

    /// Reads the raw indices of an 8-bit greyscale or palette PNG.
    pub fn read_png(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let (info, buf) = decode_png(path)?;
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
        let (info, buf) = decode_png(path)?;
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

/// Decodes a PNG as stored (no expansion): its header and raw rows.
fn decode_png(path: &Path) -> Result<(png::OutputInfo, Vec<u8>)> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let decoder = png::Decoder::new(std::io::BufReader::new(file));
    let bad = |e: png::DecodingError| Error::invalid(path, format!("cannot decode label PNG: {e}"));
    let mut reader = decoder.read_info().map_err(bad)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| Error::invalid(path, "label image too large"))?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(bad)?;
    Ok((info, buf))
}
