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
