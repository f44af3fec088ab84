//! Image reading and atomic PNG writing with errors that name the file.

use crate::error::{Error, Result};
use image::{DynamicImage, GrayImage, RgbImage};
use std::path::Path;

fn open(path: &Path) -> Result<DynamicImage> {
    image::open(path).map_err(|e| match e {
        image::ImageError::IoError(io) => Error::io(path, io),
        other => Error::invalid(path, format!("cannot decode image: {other}")),
    })
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
}
