//! Photometric degradations of grey images in [0, 1]: brightness, contrast,
//! Gaussian noise, Gaussian blur and horizontal motion blur. They train FPFDCNN to
//! be robust and make the "blurred image" half of the paper's Table 6.
//!
//! Each degradation has a text form, as evaluation options use them:
//! `brightness:D`, `contrast:F`, `noise:SIGMA`, `gaussian:SIGMA`, `motion:K`.

use crate::error::{Error, Result};
use crate::raster::{GrayF32, MAX_BLUR_SIGMA, MAX_MOTION_KERNEL};
use rand::{Rng, RngExt};
use serde::{Deserialize, Serialize};

/// Adds `delta` to every intensity (clamped to [0, 1]).
pub(crate) fn brightness(img: &GrayF32, delta: f32) -> GrayF32 {
    map(img, |v| v + delta)
}

/// Scales intensities about the image mean by `factor` (clamped to [0, 1]).
pub(crate) fn contrast(img: &GrayF32, factor: f32) -> GrayF32 {
    let mean = img.data.iter().map(|&v| v as f64).sum::<f64>() / img.data.len().max(1) as f64;
    let mean = mean as f32;
    map(img, |v| (v - mean) * factor + mean)
}

/// Adds zero-mean Gaussian noise of standard deviation `sigma` (clamped to [0, 1]).
pub(crate) fn gaussian_noise<R: Rng + ?Sized>(img: &GrayF32, sigma: f32, rng: &mut R) -> GrayF32 {
    let mut out = img.clone();
    for v in out.data.iter_mut() {
        *v = (*v + sigma * standard_normal(rng)).clamp(0.0, 1.0);
    }
    out
}

/// Gaussian blur of standard deviation `sigma` pixels (borders replicated).
pub(crate) fn gaussian_blur(img: &GrayF32, sigma: f32) -> GrayF32 {
    if sigma <= 0.0 {
        return img.clone();
    }
    img.gaussian_blur(sigma)
}

/// Horizontal motion blur: the mean of a 1xK box (`motion:K`) over offsets
/// `-⌊K/2⌋ ..= K - 1 - ⌊K/2⌋` (OpenCV's `filter2D` default anchor; centred for odd K),
/// borders replicated.
pub(crate) fn motion_blur(img: &GrayF32, k: usize) -> GrayF32 {
    if k <= 1 {
        return img.clone();
    }
    let kernel = vec![1.0 / k as f32; k];
    let (w, h) = (img.width, img.height);
    let lo = (k / 2) as isize;
    let mut out = GrayF32::new(w, h);
    for y in 0..h {
        for x in 0..w {
            out.data[y * w + x] = kernel
                .iter()
                .enumerate()
                .map(|(j, c)| c * img.get_clamped(x as isize + j as isize - lo, y as isize))
                .sum();
        }
    }
    out
}

fn map(img: &GrayF32, f: impl Fn(f32) -> f32) -> GrayF32 {
    GrayF32 {
        width: img.width,
        height: img.height,
        data: img.data.iter().map(|&v| f(v).clamp(0.0, 1.0)).collect(),
    }
}

/// A standard normal sample (Box-Muller).
fn standard_normal<R: Rng + ?Sized>(rng: &mut R) -> f32 {
    let u1: f64 = 1.0 - rng.random::<f64>(); // (0, 1]
    let u2: f64 = rng.random::<f64>();
    ((-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()) as f32
}

/// One degradation with its parameter.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Degradation {
    /// Add this offset to every intensity (`brightness`).
    Brightness(f32),
    /// Scale intensities about the mean by this factor (`contrast`).
    Contrast(f32),
    /// Add Gaussian noise of this standard deviation (`gaussian_noise`).
    Noise(f32),
    /// Gaussian blur of this sigma, pixels (`gaussian_blur`).
    Gaussian(f32),
    /// Horizontal motion blur with a kernel this many pixels long (`motion_blur`).
    Motion(usize),
}

impl Degradation {
    /// Parses `brightness:D`, `contrast:F`, `noise:SIGMA`, `gaussian:SIGMA` or `motion:K`.
    pub fn parse(spec: &str) -> Result<Self> {
        let (name, value) = spec.split_once(':').ok_or_else(|| {
            Error::msg(format!(
                "degradation '{spec}' must look like motion:9, gaussian:1.5, noise:0.02, brightness:0.1 or contrast:0.8"
            ))
        })?;
        let float = || -> Result<f32> {
            value
                .trim()
                .parse::<f32>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    Error::msg(format!("degradation '{spec}': '{value}' is not a number"))
                })
        };
        let non_negative = |v: f32| -> Result<f32> {
            if v >= 0.0 {
                Ok(v)
            } else {
                Err(Error::msg(format!(
                    "degradation '{spec}' must not be negative"
                )))
            }
        };
        match name.trim().to_ascii_lowercase().as_str() {
            "brightness" => Ok(Degradation::Brightness(float()?)),
            "contrast" => Ok(Degradation::Contrast(non_negative(float()?)?)),
            "noise" => Ok(Degradation::Noise(non_negative(float()?)?)),
            "gaussian" | "gauss" => {
                let sigma = non_negative(float()?)?;
                if sigma > MAX_BLUR_SIGMA {
                    return Err(Error::msg(format!(
                        "degradation '{spec}': the blur must be at most {MAX_BLUR_SIGMA} pixels"
                    )));
                }
                Ok(Degradation::Gaussian(sigma))
            }
            "motion" => value
                .trim()
                .parse::<usize>()
                .ok()
                .filter(|&k| (1..=MAX_MOTION_KERNEL).contains(&k))
                .map(Degradation::Motion)
                .ok_or_else(|| {
                    Error::msg(format!(
                        "degradation '{spec}': the motion kernel length must be an integer in 1..={MAX_MOTION_KERNEL}"
                    ))
                }),
            other => Err(Error::msg(format!(
                "unknown degradation '{other}' in '{spec}' (brightness, contrast, noise, gaussian, motion)"
            ))),
        }
    }

    /// Applies the degradation (`rng` is used by noise only).
    pub fn apply<R: Rng + ?Sized>(&self, img: &GrayF32, rng: &mut R) -> GrayF32 {
        match *self {
            Degradation::Brightness(d) => brightness(img, d),
            Degradation::Contrast(f) => contrast(img, f),
            Degradation::Noise(s) => gaussian_noise(img, s, rng),
            Degradation::Gaussian(s) => gaussian_blur(img, s),
            Degradation::Motion(k) => motion_blur(img, k),
        }
    }
}

/// Random photometric augmentation for training: each parameter drawn uniformly
/// from its range; blurs applied with their probability.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PhotometricAugment {
    /// Brightness offset range.
    pub brightness: [f32; 2],
    /// Contrast factor range.
    pub contrast: [f32; 2],
    /// Noise standard deviation range.
    pub noise_sigma: [f32; 2],
    /// Probability and sigma range of a Gaussian blur.
    pub gaussian_prob: f32,
    /// Gaussian blur sigma range, pixels.
    pub gaussian_sigma: [f32; 2],
    /// Probability and kernel length range (inclusive) of a horizontal motion blur.
    pub motion_prob: f32,
    /// Motion blur kernel length range, pixels (inclusive).
    pub motion_kernel: [usize; 2],
}

impl Default for PhotometricAugment {
    fn default() -> Self {
        PhotometricAugment {
            brightness: [-0.15, 0.15],
            contrast: [0.7, 1.3],
            noise_sigma: [0.0, 0.02],
            gaussian_prob: 0.25,
            gaussian_sigma: [0.5, 1.5],
            motion_prob: 0.25,
            motion_kernel: [3, 15],
        }
    }
}

impl PhotometricAugment {
    /// Checks ranges and probabilities; the message names the field.
    pub fn validate(&self) -> std::result::Result<(), String> {
        for (r, what) in [
            (self.brightness, "brightness"),
            (self.contrast, "contrast"),
            (self.noise_sigma, "noise_sigma"),
            (self.gaussian_sigma, "gaussian_sigma"),
        ] {
            if !(r[0].is_finite() && r[1].is_finite() && r[0] <= r[1]) {
                return Err(format!(
                    "augment.{what} [{}, {}] must be an ordered pair of numbers",
                    r[0], r[1]
                ));
            }
        }
        if self.noise_sigma[0] < 0.0 || self.gaussian_sigma[0] < 0.0 || self.contrast[0] < 0.0 {
            return Err(
                "augment.noise_sigma, gaussian_sigma and contrast must not be negative".into(),
            );
        }
        if self.gaussian_sigma[1] > MAX_BLUR_SIGMA {
            return Err(format!(
                "augment.gaussian_sigma must be at most {MAX_BLUR_SIGMA} pixels, got {}",
                self.gaussian_sigma[1]
            ));
        }
        for (p, what) in [
            (self.gaussian_prob, "gaussian_prob"),
            (self.motion_prob, "motion_prob"),
        ] {
            if !(0.0..=1.0).contains(&p) {
                return Err(format!(
                    "augment.{what} must be a probability in [0, 1], got {p}"
                ));
            }
        }
        let [a, b] = self.motion_kernel;
        if !(a >= 1 && a <= b && b <= MAX_MOTION_KERNEL) {
            return Err(format!(
                "augment.motion_kernel [{a}, {b}] must be an ordered pair of lengths in 1..={MAX_MOTION_KERNEL}"
            ));
        }
        Ok(())
    }

    /// The degradations of one random draw, in the order they are applied
    /// (blurs before noise, as a camera would).
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> Result<Vec<Degradation>> {
        let range = |r: [f32; 2], what: &str, rng: &mut R| -> Result<f32> {
            if !(r[0].is_finite() && r[1].is_finite() && r[0] <= r[1]) {
                return Err(Error::msg(format!(
                    "augmentation range {what} [{}, {}] is not an ordered pair of numbers",
                    r[0], r[1]
                )));
            }
            Ok(if r[0] == r[1] {
                r[0]
            } else {
                rng.random_range(r[0]..=r[1])
            })
        };
        let mut out = Vec::new();
        if rng.random::<f32>() < self.gaussian_prob {
            out.push(Degradation::Gaussian(range(
                self.gaussian_sigma,
                "gaussian_sigma",
                rng,
            )?));
        }
        if rng.random::<f32>() < self.motion_prob {
            let [lo, hi] = self.motion_kernel;
            if lo > hi {
                return Err(Error::msg("augmentation motion_kernel range is reversed"));
            }
            out.push(Degradation::Motion(rng.random_range(lo..=hi)));
        }
        out.push(Degradation::Contrast(range(
            self.contrast,
            "contrast",
            rng,
        )?));
        out.push(Degradation::Brightness(range(
            self.brightness,
            "brightness",
            rng,
        )?));
        out.push(Degradation::Noise(range(
            self.noise_sigma,
            "noise_sigma",
            rng,
        )?));
        Ok(out)
    }

    /// One random augmentation of `img`.
    pub fn apply<R: Rng + ?Sized>(&self, img: &GrayF32, rng: &mut R) -> Result<GrayF32> {
        let mut out = img.clone();
        for d in self.sample(rng)? {
            out = d.apply(&out, rng);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn step(w: usize, h: usize, at: usize) -> GrayF32 {
        let mut img = GrayF32::new(w, h);
        for y in 0..h {
            for x in at..w {
                img.data[y * w + x] = 1.0;
            }
        }
        img
    }

    #[test]
    fn motion_blur_turns_a_step_into_a_ramp() {
        let img = step(40, 3, 20);
        let k = 5;
        let out = motion_blur(&img, k);
        // Offsets -2..=2: x = 17 sees none of the bright side, x = 18 one pixel (0.2),
        // ..., x = 22 all five.
        for x in 0..40 {
            let expected = ((x as i32 + 3 - 20).clamp(0, 5)) as f32 / 5.0;
            assert!(
                (out.get(x, 1) - expected).abs() < 1e-6,
                "x {x}: {}",
                out.get(x, 1)
            );
        }
        // Even kernel: offsets -2..=1.
        let out4 = motion_blur(&img, 4);
        let row: Vec<f32> = (17..23).map(|x| out4.get(x, 0)).collect();
        assert_eq!(row, vec![0.0, 0.0, 0.25, 0.5, 0.75, 1.0]);
        assert_eq!(motion_blur(&img, 1), img);
        assert_eq!(
            Degradation::parse("motion:9").unwrap(),
            Degradation::Motion(9)
        );
    }

    #[test]
    fn photometric_changes_and_parsing() {
        let mut img = GrayF32::new(10, 10);
        img.data
            .iter_mut()
            .enumerate()
            .for_each(|(i, v)| *v = i as f32 / 100.0);
        let b = brightness(&img, 0.5);
        assert!((b.get(2, 0) - 0.52).abs() < 1e-6 && b.get(9, 9) == 1.0);
        let c = contrast(&img, 0.0);
        assert!(c.data.iter().all(|&v| (v - 0.495).abs() < 1e-5));
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let n = gaussian_noise(
            &GrayF32 {
                data: vec![0.5; 10000],
                ..GrayF32::new(100, 100)
            },
            0.05,
            &mut rng,
        );
        let mean = n.data.iter().sum::<f32>() / 1e4;
        let sd = (n.data.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / 1e4).sqrt();
        assert!(
            (mean - 0.5).abs() < 0.003 && (sd - 0.05).abs() < 0.003,
            "{mean} {sd}"
        );
        assert_eq!(
            Degradation::parse("gaussian:1.5").unwrap(),
            Degradation::Gaussian(1.5)
        );
        for bad in [
            "motion",
            "motion:0",
            "motion:x",
            "motion:100000",
            "gaussian:1e5",
            "blur:3",
            "noise:-1",
            "contrast:nan",
        ] {
            assert!(Degradation::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn augmentation_blurs_are_bounded() {
        let ok = PhotometricAugment::default();
        assert!(ok.validate().is_ok());
        let wide = PhotometricAugment {
            gaussian_sigma: [0.5, 1e5],
            ..ok.clone()
        };
        assert!(wide.validate().unwrap_err().contains("gaussian_sigma"));
        let long = PhotometricAugment {
            motion_kernel: [3, 100_000],
            ..ok
        };
        assert!(long.validate().unwrap_err().contains("motion_kernel"));
    }

    #[test]
    fn random_augmentation_is_seeded() {
        let img = step(32, 32, 16);
        let aug = PhotometricAugment::default();
        let a = aug.apply(&img, &mut ChaCha8Rng::seed_from_u64(3)).unwrap();
        let b = aug.apply(&img, &mut ChaCha8Rng::seed_from_u64(3)).unwrap();
        let c = aug.apply(&img, &mut ChaCha8Rng::seed_from_u64(4)).unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert!(a.data.iter().all(|v| (0.0..=1.0).contains(v)));
        let bad = PhotometricAugment {
            contrast: [1.2, 0.8],
            ..aug
        };
        assert!(bad.apply(&img, &mut ChaCha8Rng::seed_from_u64(3)).is_err());
    }
}
