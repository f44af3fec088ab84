//! Image reading and atomic PNG writing with errors that name the file.
//!
//! Every image input is read here ([`decode`]): a regular file of bounded size
//! (`crate::io::read_image_bytes`: a FIFO or device is refused, never waited on), its header
//! checked (sides of at most `MAX_SIDE`, and what the caller expects of it, e.g. a frame's
//! size and bit depth: [`crate::dataset::FrameSpec`]) before any pixel is decoded.

use crate::camera::MAX_SIDE;
use crate::error::{Error, Result};
use image::{DynamicImage, GrayImage, ImageDecoder, RgbImage};
use std::path::Path;

/// What an image file holds, from its header alone.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageHeader {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Channels per pixel (1 grey or palette, 2 grey + alpha, 3 RGB, 4 RGBA).
    pub channels: u8,
    /// Bits per channel (8 or 16; a palette image's indices count as 8).
    pub bits: u8,
}

impl ImageHeader {
    /// The header of an image of the `image` crate's colour type.
    pub fn of(width: u32, height: u32, color: image::ColorType) -> Self {
        let channels = color.channel_count();
        ImageHeader {
            width,
            height,
            channels,
            bits: (color.bytes_per_pixel() / channels.max(1)) * 8,
        }
    }

    /// "640x480 8-bit RGB" and the like.
    pub fn describe(&self) -> String {
        let kind = match self.channels {
            1 => "single-channel",
            2 => "grey + alpha",
            3 => "RGB",
            4 => "RGBA",
            _ => "multi-channel",
        };
        format!("{}x{} {}-bit {kind}", self.width, self.height, self.bits)
    }
}

/// The image's sides checked against [`MAX_SIDE`] (buffers are allocated from them).
pub(crate) fn check_sides(path: &Path, width: u32, height: u32) -> Result<()> {
    if width == 0 || height == 0 || width > MAX_SIDE || height > MAX_SIDE {
        return Err(Error::invalid(
            path,
            format!("image of {width}x{height} pixels: sides must be 1 to {MAX_SIDE}"),
        ));
    }
    Ok(())
}

fn decode_error(path: &Path, e: image::ImageError) -> Error {
    match e {
        image::ImageError::IoError(io) => Error::io(path, io),
        other => Error::invalid(path, format!("cannot decode image: {other}")),
    }
}

/// Decodes an image file: read whole with at most `max_bytes` bytes (and never more than
/// `crate::io::MAX_IMAGE_BYTES`), the format taken from the content, its header checked by
/// `check_sides` and by `check` before any pixel is decoded (at most 512 MiB decoded).
pub fn decode(
    path: &Path,
    max_bytes: u64,
    check: &dyn Fn(&ImageHeader) -> Result<()>,
) -> Result<DynamicImage> {
    let bytes = crate::io::read_image_bytes(path, max_bytes)?;
    let reader = image::ImageReader::new(std::io::Cursor::new(&bytes))
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    let mut decoder = reader.into_decoder().map_err(|e| decode_error(path, e))?;
    let (w, h) = decoder.dimensions();
    check_sides(path, w, h)?;
    check(&ImageHeader::of(w, h, decoder.color_type()))?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_SIDE);
    limits.max_image_height = Some(MAX_SIDE);
    limits
        .reserve(decoder.total_bytes())
        .and_then(|_| decoder.set_limits(limits))
        .map_err(|e| decode_error(path, e))?;
    DynamicImage::from_decoder(decoder).map_err(|e| decode_error(path, e))
}

/// An image's header (size, channels, bit depth) without decoding its pixels.
pub fn header(path: impl AsRef<Path>) -> Result<ImageHeader> {
    let path = path.as_ref();
    let (file, _) = crate::io::open_regular(path, "an image")?;
    let reader = image::ImageReader::new(std::io::BufReader::new(file))
        .with_guessed_format()
        .map_err(|e| Error::io(path, e))?;
    let decoder = reader.into_decoder().map_err(|e| decode_error(path, e))?;
    let (w, h) = decoder.dimensions();
    Ok(ImageHeader::of(w, h, decoder.color_type()))
}

/// No check beyond [`decode`]'s own.
pub(crate) fn any_image(_: &ImageHeader) -> Result<()> {
    Ok(())
}

fn open(path: &Path) -> Result<DynamicImage> {
    decode(path, crate::io::MAX_IMAGE_BYTES, &any_image)
}

/// Reads any image as 8-bit RGB.
pub fn read_rgb(path: impl AsRef<Path>) -> Result<RgbImage> {
    Ok(open(path.as_ref())?.into_rgb8())
}

/// Reads any image as 8-bit grayscale.
pub fn read_gray(path: impl AsRef<Path>) -> Result<GrayImage> {
    Ok(open(path.as_ref())?.into_luma8())
}

/// Reads an 8-bit single-channel image (label maps); anything else is an error.
pub fn read_luma8(path: impl AsRef<Path>) -> Result<GrayImage> {
    let path = path.as_ref();
    match open(path)? {
        DynamicImage::ImageLuma8(b) => Ok(b),
        other => Err(Error::invalid(
            path,
            format!(
                "expected an 8-bit single-channel PNG, found {:?}",
                other.color()
            ),
        )),
    }
}

/// Writes a picture atomically as JPEG (quality 85) when `path` ends in `.jpg` or `.jpeg`,
/// else as PNG.
pub fn write_picture_atomic(path: impl AsRef<Path>, img: &DynamicImage) -> Result<()> {
    let path = path.as_ref();
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if !matches!(ext.as_deref(), Some("jpg" | "jpeg")) {
        return write_png_atomic(path, img);
    }
    let mut bytes = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, 85)
        .encode_image(&img.to_rgb8())
        .map_err(|e| Error::invalid(path, format!("cannot encode JPEG: {e}")))?;
    crate::io::write_atomic(path, &bytes)
}

/// Writes an image as PNG, atomically.
pub fn write_png_atomic(path: impl AsRef<Path>, img: &DynamicImage) -> Result<()> {
    let path = path.as_ref();
    let mut bytes = Vec::new();
    img.write_to(
        &mut std::io::Cursor::new(&mut bytes),
        image::ImageFormat::Png,
    )
    .map_err(|e| Error::invalid(path, format!("cannot encode PNG: {e}")))?;
    crate::io::write_atomic(path, &bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::GenericImageView;

    #[test]
    fn pictures_are_jpeg_or_png_by_extension() {
        let dir = std::env::temp_dir().join(format!("sdf_picture_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let img = DynamicImage::ImageRgb8(image::RgbImage::from_fn(32, 16, |x, y| {
            image::Rgb([(x * 8) as u8, (y * 16) as u8, 128])
        }));
        for (name, magic) in [
            ("a.jpg", &[0xFF, 0xD8][..]),
            ("b.JPEG", &[0xFF, 0xD8][..]),
            ("c.png", &[0x89, b'P', b'N', b'G'][..]),
        ] {
            let p = dir.join(name);
            write_picture_atomic(&p, &img).unwrap();
            let bytes = std::fs::read(&p).unwrap();
            assert!(bytes.starts_with(magic), "{name}");
            assert_eq!(image::open(&p).unwrap().dimensions(), (32, 16));
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn headers_are_checked_before_decoding_and_sizes_bounded() {
        let dir = crate::io::ScratchDir::new("imageio_header").unwrap();
        let p = dir.join("a.png");
        image::GrayImage::new(40, 30).save(&p).unwrap();
        let h = header(&p).unwrap();
        assert_eq!((h.width, h.height, h.channels, h.bits), (40, 30, 1, 8));
        assert_eq!(h.describe(), "40x30 8-bit single-channel");
        let wide = ImageHeader::of(2, 2, image::ColorType::Rgb16);
        assert_eq!((wide.channels, wide.bits), (3, 16));
        // The check sees the header and its error is returned as is.
        let e = decode(&p, 1 << 20, &|h: &ImageHeader| {
            Err(Error::invalid(&p, format!("refused {}", h.describe())))
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("refused 40x30 8-bit"), "{e}");
        // A file larger than the caller's bound is not read.
        let e = decode(&p, 10, &any_image).unwrap_err().to_string();
        assert!(e.contains("a.png") && e.contains("bytes"), "{e}");
        // Not an image; a PNG from its content whatever its name.
        std::fs::write(dir.join("b.png"), b"not a png").unwrap();
        assert!(
            read_rgb(dir.join("b.png"))
                .unwrap_err()
                .to_string()
                .contains("b.png")
        );
        std::fs::copy(&p, dir.join("c.jpg")).unwrap();
        assert_eq!(read_gray(dir.join("c.jpg")).unwrap().dimensions(), (40, 30));
        // Sides beyond MAX_SIDE are refused from the header.
        assert!(check_sides(&p, MAX_SIDE + 1, 1).is_err() && check_sides(&p, 1, 0).is_err());
    }
}
