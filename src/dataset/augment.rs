//! Joint augmentation of RGB, depth and label images for SDFCNN training
//! (horizontal flip, scale + crop, colour jitter), producing network-ready
//! planar arrays. Depth and labels are resampled with nearest neighbour so that
//! no label is blended and missing depth (0) never leaks into valid pixels.
//! A zoom below 1 shrinks the whole image into a larger canvas (at a random place):
//! the canvas around it is [`PAD_RGB`], missing depth and void labels, so no loss sees it.
//! Depth stays in metres; the zoom is returned with the sample ([`SegDepthSample::zoom`])
//! because zooming lengthens the focal length, which SDFCNN's canonical camera
//! ([`crate::sdfcnn::focal`]) accounts for.

use super::depth::DepthImage;
use super::labels::{LabelImage, VOID};
use image::RgbImage;
use rand::RngExt;
use serde::{Deserialize, Serialize};

/// Augmentation settings (all off gives a plain resize).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AugmentConfig {
    /// Mirror the sample horizontally with probability 1/2.
    pub flip: bool,
    /// Random zoom factor range before cropping to the output size; below 1 the image is
    /// shrunk into a padded canvas (a shorter focal length: larger canonical depths).
    pub scale_min: f32,
    /// Upper end of the random zoom range; equal to `scale_min` gives a fixed zoom.
    pub scale_max: f32,
    /// Brightness and contrast jitter (relative), saturation jitter.
    pub brightness: f32,
    /// Contrast jitter: contrast scaled about the mean grey by `1 ± contrast`.
    pub contrast: f32,
    /// Saturation jitter: colour distance from grey scaled by `1 ± saturation`.
    pub saturation: f32,
}

impl Default for AugmentConfig {
    fn default() -> Self {
        AugmentConfig {
            flip: true,
            scale_min: 1.0,
            scale_max: 1.3,
            brightness: 0.2,
            contrast: 0.2,
            saturation: 0.2,
        }
    }
}

impl AugmentConfig {
    /// Checks the ranges; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        if !(self.scale_min >= 0.25 && self.scale_min <= self.scale_max && self.scale_max <= 8.0) {
            return Err(format!(
                "augment scale_min ({}) and scale_max ({}) must satisfy 0.25 <= scale_min <= \
                 scale_max <= 8",
                self.scale_min, self.scale_max
            ));
        }
        for (v, what) in [
            (self.brightness, "brightness"),
            (self.contrast, "contrast"),
            (self.saturation, "saturation"),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("augment {what} must be in [0, 1], got {v}"));
            }
        }
        Ok(())
    }

    /// No augmentation: only the resize to the output size.
    pub fn none() -> Self {
        AugmentConfig {
            flip: false,
            scale_min: 1.0,
            scale_max: 1.0,
            brightness: 0.0,
            contrast: 0.0,
            saturation: 0.0,
        }
    }
}

/// A training sample at the network's input size.
#[derive(Debug, Clone, PartialEq)]
pub struct SegDepthSample {
    /// Output width, pixels.
    pub width: usize,
    /// Output height, pixels.
    pub height: usize,
    /// `[3, H, W]` RGB in [0, 1].
    pub rgb: Vec<f32>,
    /// `[H, W]` metres, 0 = missing.
    pub depth: Vec<f32>,
    /// `[H, W]` class indices, 255 = void.
    pub labels: Vec<u8>,
    /// Source pixels per output pixel divided into the whole-image scale: the crop is
    /// `1 / zoom` of the source image's width (1 = the whole image).
    pub zoom: f32,
    /// The factor the depth was multiplied by after loading (1 = metres; see
    /// `crate::sdfcnn::focal`): metres = depth / depth_factor.
    pub depth_factor: f32,
}

/// Resamples (and augments) one sample to `width x height`.
pub fn augment(
    rgb: &RgbImage,
    depth: Option<&DepthImage>,
    labels: &LabelImage,
    width: usize,
    height: usize,
    cfg: &AugmentConfig,
    rng: &mut impl rand::Rng,
) -> SegDepthSample {
    let (sw, sh) = (rgb.width() as f32, rgb.height() as f32);
    // The crop window in source pixels: the whole image zoomed by `scale`.
    let scale = if cfg.scale_max > cfg.scale_min {
        rng.random_range(cfg.scale_min..cfg.scale_max)
    } else {
        cfg.scale_min.max(1e-3)
    };
    let (cw, ch) = (sw / scale, sh / scale);
    // The window's corner: inside the image when zooming in, a random place of the image
    // inside the larger window when zooming out.
    let corner = |source: f32, window: f32, rng: &mut dyn rand::Rng| {
        if source > window {
            rng.random_range(0.0..(source - window))
        } else if window > source {
            -rng.random_range(0.0..(window - source))
        } else {
            0.0
        }
    };
    let x0 = corner(sw, cw, rng);
    let y0 = corner(sh, ch, rng);
    let flip = cfg.flip && rng.random_bool(0.5);
    let jitter = |r: f32, rng: &mut dyn rand::Rng| {
        if r > 0.0 {
            1.0 + rng.random_range(-r..r)
        } else {
            1.0
        }
    };
    let (b, c, s) = (
        jitter(cfg.brightness, rng),
        jitter(cfg.contrast, rng),
        jitter(cfg.saturation, rng),
    );
    let n = width * height;
    let mut out = SegDepthSample {
        width,
        height,
        rgb: vec![0.0; 3 * n],
        depth: vec![0.0; n],
        labels: vec![VOID; n],
        zoom: sw / cw,
        depth_factor: 1.0,
    };
    let (fx, fy) = (cw / width as f32, ch / height as f32);
    let mut mean = 0.0f32;
    let mut inside = 0usize;
    let mut padded = Vec::new();
    for y in 0..height {
        for x in 0..width {
            let xo = if flip { width - 1 - x } else { x };
            // Source position of the output pixel centre.
            let u = x0 + (xo as f32 + 0.5) * fx - 0.5;
            let v = y0 + (y as f32 + 0.5) * fy - 0.5;
            let i = y * width + x;
            if !(-0.5..sw - 0.5).contains(&u) || !(-0.5..sh - 0.5).contains(&v) {
                padded.push(i);
                continue;
            }
            inside += 1;
            let px = bilinear_rgb(rgb, u, v);
            let (ui, vi) = (
                (u.round() as i64).clamp(0, sw as i64 - 1) as u32,
                (v.round() as i64).clamp(0, sh as i64 - 1) as u32,
            );
            out.labels[i] = labels.get(ui, vi);
            if let Some(d) = depth {
                out.depth[i] = d.data[(vi * d.width + ui) as usize];
            }
            let gray = 0.299 * px[0] + 0.587 * px[1] + 0.114 * px[2];
            for (k, c) in px.iter().enumerate() {
                out.rgb[k * n + i] = gray + s * (c - gray);
            }
            mean += gray;
        }
    }
    mean /= inside.max(1) as f32;
    for v in out.rgb.iter_mut() {
        *v = ((*v - mean) * c + mean) * b;
        *v = v.clamp(0.0, 1.0);
    }
    for i in padded {
        for (k, c) in PAD_RGB.iter().enumerate() {
            out.rgb[k * n + i] = *c;
        }
    }
    out
}

/// The canvas colour around a zoomed-out image: SDFCNN's input mean (eq. 15, ImageNet's), which
/// its normalisation maps to zero (as Metric3D pads its canonical-camera images).
pub const PAD_RGB: [f32; 3] = [0.485, 0.456, 0.406];

fn bilinear_rgb(img: &RgbImage, u: f32, v: f32) -> [f32; 3] {
    let (w, h) = (img.width() as i64, img.height() as i64);
    let (x0, y0) = (u.floor(), v.floor());
    let (ax, ay) = (u - x0, v - y0);
    let at = |x: i64, y: i64| {
        let p = img.get_pixel(x.clamp(0, w - 1) as u32, y.clamp(0, h - 1) as u32);
        [p[0] as f32, p[1] as f32, p[2] as f32]
    };
    let (x0, y0) = (x0 as i64, y0 as i64);
    let (p00, p10, p01, p11) = (
        at(x0, y0),
        at(x0 + 1, y0),
        at(x0, y0 + 1),
        at(x0 + 1, y0 + 1),
    );
    let mut out = [0.0; 3];
    for k in 0..3 {
        let top = p00[k] * (1.0 - ax) + p10[k] * ax;
        let bot = p01[k] * (1.0 - ax) + p11[k] * ax;
        out[k] = (top * (1.0 - ay) + bot * ay) / 255.0;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn scene() -> (RgbImage, DepthImage, LabelImage) {
        let (w, h) = (40u32, 30u32);
        let rgb = RgbImage::from_fn(w, h, |x, _| image::Rgb([(x * 6) as u8, 100, 50]));
        let mut depth = DepthImage::new(w, h);
        let mut labels = LabelImage::new(w, h, 0);
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                depth.data[i] = if x < 20 { 1.0 } else { 0.0 };
                labels.data[i] = if x < 20 { 3 } else { 7 };
            }
        }
        (rgb, depth, labels)
    }

    #[test]
    fn plain_resize_keeps_layout() {
        let (rgb, depth, labels) = scene();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let s = augment(
            &rgb,
            Some(&depth),
            &labels,
            20,
            15,
            &AugmentConfig::none(),
            &mut rng,
        );
        assert_eq!(s.labels[0], 3);
        assert_eq!(s.labels[19], 7);
        assert_eq!(s.depth[0], 1.0);
        assert_eq!(s.depth[19], 0.0);
        // Red ramps up from left to right, labels never blend.
        assert!(s.rgb[0] < s.rgb[19]);
        assert!(s.labels.iter().all(|&l| l == 3 || l == 7));
    }

    #[test]
    fn flip_mirrors_all_three_images() {
        let (rgb, depth, labels) = scene();
        let cfg = AugmentConfig {
            flip: true,
            ..AugmentConfig::none()
        };
        let mut flipped = None;
        for seed in 0..20 {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let s = augment(&rgb, Some(&depth), &labels, 20, 15, &cfg, &mut rng);
            if s.labels[0] == 7 {
                flipped = Some(s);
                break;
            }
        }
        let s = flipped.expect("a flip within 20 draws");
        assert_eq!((s.labels[19], s.depth[0], s.depth[19]), (3, 0.0, 1.0));
        assert!(s.rgb[0] > s.rgb[19]);
    }

    #[test]
    fn zooming_out_pads_with_the_mean_colour_no_depth_and_void_labels() {
        let (rgb, depth, labels) = scene();
        let cfg = AugmentConfig {
            scale_min: 0.5,
            scale_max: 0.5,
            ..AugmentConfig::none()
        };
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let s = augment(&rgb, Some(&depth), &labels, 20, 15, &cfg, &mut rng);
        // Half the width: a shorter focal length, which the canonical camera turns into
        // larger depths.
        assert_eq!(s.zoom, 0.5);
        let n = 20 * 15;
        let pad: Vec<usize> = (0..n).filter(|&i| s.labels[i] == VOID).collect();
        // The image covers a quarter of the canvas (10 x 7.5 pixels of 20 x 15).
        assert!(
            (215..=235).contains(&pad.len()),
            "{} padded pixels",
            pad.len()
        );
        for &i in &pad {
            assert_eq!(s.depth[i], 0.0);
            for (k, c) in PAD_RGB.iter().enumerate() {
                assert_eq!(s.rgb[k * n + i], *c);
            }
        }
        // Inside, the image as before: both labels, the valid depth kept.
        assert!(s.labels.contains(&3) && s.labels.contains(&7));
        assert!(s.depth.contains(&1.0));
    }
}
