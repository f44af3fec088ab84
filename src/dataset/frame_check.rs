//! The one check of a frame's images against the camera they are read for: every colour,
//! depth and label image of a sequence or data set is read through a [`FrameSpec`], which
//! checks its header (size, channels, bit depth) before any pixel is decoded. A frame that
//! does not fit is an `Err` naming the file, what it is and what the camera expects; `slam`
//! skips such a frame and lists it with its reason in `report.md` / `report.json`, training
//! and evaluation stop on it.
//!
//! What fits: the camera's width and height; colour 8-bit RGB (or RGBA, the alpha ignored);
//! depth 16-bit single-channel; labels 8-bit single-channel or palette, every value a class of
//! [`crate::classes::NUM_CLASSES`] or void ([`LabelImage::read_classes`]).

use super::depth::{DepthImage, read_png_u16_with};
use super::labels::LabelImage;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::imageio::ImageHeader;
use image::{GrayImage, RgbImage};
use std::path::Path;

/// The images of one frame: their camera's size (what each image must be), or for a data set
/// of crops of one camera's images (NYUv2's), the range of sizes its crops have.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameSpec {
    /// The camera's size: the largest an image may be.
    pub width: u32,
    /// The camera's height, pixels (the largest an image may be).
    pub height: u32,
    /// The smallest crop accepted (the camera's size: no crop).
    pub min_width: u32,
    /// The smallest crop height accepted, pixels (the camera's height: no crop).
    pub min_height: u32,
}

/// Which image of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameImage {
    /// The colour image (8-bit RGB or RGBA).
    Colour,
    /// The depth image (16-bit single-channel).
    Depth,
    /// The label image of semantic classes (8-bit single-channel or palette).
    Labels,
}

impl FrameImage {
    fn name(self) -> &'static str {
        match self {
            FrameImage::Colour => "colour image",
            FrameImage::Depth => "depth image",
            FrameImage::Labels => "label image",
        }
    }

    fn expected(self) -> &'static str {
        match self {
            FrameImage::Colour => "8-bit RGB (or RGBA)",
            FrameImage::Depth => "16-bit single-channel",
            FrameImage::Labels => "8-bit single-channel or palette",
        }
    }

    fn accepts(self, h: &ImageHeader) -> bool {
        match self {
            FrameImage::Colour => h.bits == 8 && matches!(h.channels, 3 | 4),
            FrameImage::Depth => h.bits == 16 && h.channels == 1,
            FrameImage::Labels => h.bits == 8 && h.channels == 1,
        }
    }
}

impl FrameSpec {
    /// The frames of `camera`.
    pub fn of(camera: &Camera) -> Self {
        Self::new(camera.width, camera.height)
    }

    /// Frames of `width x height`.
    pub fn new(width: u32, height: u32) -> Self {
        FrameSpec {
            width,
            height,
            min_width: width,
            min_height: height,
        }
    }

    /// Crops of a camera's `width x height` images down to `min_width x min_height` (the
    /// focal length of an uncropped image holds for its crops).
    pub fn crops_of(width: u32, height: u32, min_width: u32, min_height: u32) -> Self {
        FrameSpec {
            width,
            height,
            min_width: min_width.min(width),
            min_height: min_height.min(height),
        }
    }

    fn fits(&self, width: u32, height: u32) -> bool {
        (self.min_width..=self.width).contains(&width)
            && (self.min_height..=self.height).contains(&height)
    }

    /// What the images must be, in words.
    fn size_wanted(&self) -> String {
        if (self.min_width, self.min_height) == (self.width, self.height) {
            format!("the camera is {}x{}", self.width, self.height)
        } else {
            format!(
                "the camera's images are {}x{}, cropped to at least {}x{}",
                self.width, self.height, self.min_width, self.min_height
            )
        }
    }

    /// The check: `found` (an image's header) against this frame size and the image's kind;
    /// an error names the file, what it is and what is expected.
    pub fn check(&self, path: &Path, image: FrameImage, found: &ImageHeader) -> Result<()> {
        if !self.fits(found.width, found.height) {
            return Err(Error::invalid(
                path,
                format!(
                    "{} is {}x{} but {}: a frame of another size than its camera's",
                    image.name(),
                    found.width,
                    found.height,
                    self.size_wanted()
                ),
            ));
        }
        if !image.accepts(found) {
            return Err(Error::invalid(
                path,
                format!(
                    "{} is {}, not {}",
                    image.name(),
                    found.describe(),
                    image.expected()
                ),
            ));
        }
        Ok(())
    }

    /// The largest file an image of this size may be: 8 bytes a pixel (16-bit RGBA stored
    /// uncompressed) and 1 MiB of headers. A bigger file is refused before it is read whole.
    pub fn max_file_bytes(&self) -> u64 {
        self.width as u64 * self.height as u64 * 8 + (1 << 20)
    }

    /// Reads a frame's colour image, checked.
    pub fn read_colour(&self, path: &Path) -> Result<RgbImage> {
        let check = |h: &ImageHeader| self.check(path, FrameImage::Colour, h);
        Ok(crate::imageio::decode(path, self.max_file_bytes(), &check)?.into_rgb8())
    }

    /// Reads a frame's colour image as grey, checked as a colour image.
    pub fn read_gray(&self, path: &Path) -> Result<GrayImage> {
        let check = |h: &ImageHeader| self.check(path, FrameImage::Colour, h);
        Ok(crate::imageio::decode(path, self.max_file_bytes(), &check)?.into_luma8())
    }

    /// Reads a frame's depth image in metres (`metres = value / scale`), checked.
    pub fn read_depth(&self, path: &Path, scale: f64) -> Result<DepthImage> {
        let check = |h: &ImageHeader| self.check(path, FrameImage::Depth, h);
        let buf = read_png_u16_with(path, self.max_file_bytes(), &check)?;
        Ok(DepthImage::from_raw(buf, scale))
    }

    /// Reads a frame's label image, checked, every value a class or void.
    pub fn read_labels(&self, path: &Path) -> Result<LabelImage> {
        let check = |h: &ImageHeader| self.check(path, FrameImage::Labels, h);
        LabelImage::read_classes_with(path, self.max_file_bytes(), &check)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::{ImageBuffer, Luma, Rgb, Rgba};

    #[test]
    fn frames_of_another_size_or_format_are_named_errors() {
        let dir = crate::io::ScratchDir::new("frame_check").unwrap();
        let spec = FrameSpec::of(&Camera::pinhole(64, 48, 60.0, 60.0, 32.0, 24.0));
        let rgb = |w, h, name: &str| {
            let p = dir.join(name);
            RgbImage::from_pixel(w, h, Rgb([10, 20, 30]))
                .save(&p)
                .unwrap();
            p
        };
        let depth = |w, h, name: &str| {
            let p = dir.join(name);
            ImageBuffer::<Luma<u16>, Vec<u16>>::from_pixel(w, h, Luma([5000]))
                .save(&p)
                .unwrap();
            p
        };
        assert_eq!(
            spec.read_colour(&rgb(64, 48, "ok.png"))
                .unwrap()
                .dimensions(),
            (64, 48)
        );
        assert_eq!(
            spec.read_gray(&dir.join("ok.png")).unwrap().dimensions(),
            (64, 48)
        );
        let d = spec.read_depth(&depth(64, 48, "d.png"), 5000.0).unwrap();
        assert_eq!(d.get(3, 3), Some(1.0));
        for (w, h) in [(1, 1), (32, 24), (128, 96), (3000, 20)] {
            let name = format!("c{w}x{h}.png");
            let e = spec.read_colour(&rgb(w, h, &name)).unwrap_err().to_string();
            assert!(
                e.contains(&name) && e.contains(&format!("is {w}x{h}")) && e.contains("64x48"),
                "{e}"
            );
            let name = format!("d{w}x{h}.png");
            let e = spec
                .read_depth(&depth(w, h, &name), 5000.0)
                .unwrap_err()
                .to_string();
            assert!(
                e.contains(&name) && e.contains(&format!("is {w}x{h}")),
                "{e}"
            );
        }
        // Channels and bit depth.
        let grey = dir.join("grey.png");
        GrayImage::new(64, 48).save(&grey).unwrap();
        let e = spec.read_colour(&grey).unwrap_err().to_string();
        assert!(
            e.contains("grey.png") && e.contains("8-bit single-channel, not 8-bit RGB"),
            "{e}"
        );
        let rgba = dir.join("rgba.png");
        ImageBuffer::<Rgba<u8>, Vec<u8>>::new(64, 48)
            .save(&rgba)
            .unwrap();
        assert!(spec.read_colour(&rgba).is_ok());
        let rgb16 = dir.join("rgb16.png");
        ImageBuffer::<Rgb<u16>, Vec<u16>>::new(64, 48)
            .save(&rgb16)
            .unwrap();
        let e = spec.read_colour(&rgb16).unwrap_err().to_string();
        assert!(e.contains("16-bit RGB, not 8-bit RGB"), "{e}");
        let e = spec
            .read_depth(&dir.join("ok.png"), 5000.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("ok.png") && e.contains("16-bit"), "{e}");
        // Labels: format, size and values.
        let labels = dir.join("l.png");
        GrayImage::from_pixel(64, 48, Luma([39]))
            .save(&labels)
            .unwrap();
        assert_eq!(spec.read_labels(&labels).unwrap().get(0, 0), 39);
        GrayImage::from_pixel(64, 48, Luma([40]))
            .save(&labels)
            .unwrap();
        let e = spec.read_labels(&labels).unwrap_err().to_string();
        assert!(e.contains("l.png") && e.contains("label 40"), "{e}");
        let e = spec
            .read_labels(&dir.join("c32x24.png"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("label image is 32x24"), "{e}");
        // Crops.
        let crops = FrameSpec::crops_of(64, 48, 50, 40);
        assert!(crops.read_colour(&dir.join("ok.png")).is_ok());
        let crop = rgb(60, 45, "crop.png");
        assert!(crops.read_colour(&crop).is_ok());
        let e = crops
            .read_colour(&rgb(40, 30, "small.png"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("40x30") && e.contains("cropped to at least 50x40"),
            "{e}"
        );
        // A file much larger than a frame of this size can be: refused unread.
        let big = dir.join("big.png");
        std::fs::write(&big, vec![0u8; spec.max_file_bytes() as usize + 1]).unwrap();
        let e = spec.read_colour(&big).unwrap_err().to_string();
        assert!(e.contains("big.png") && e.contains("bytes"), "{e}");
    }
}
