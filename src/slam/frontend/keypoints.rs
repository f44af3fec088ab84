//! Where keypoints and descriptors come from (section IV-B): FPFDCNN (the
//! paper's network) or the ORB baseline. Both give L2-normalised float
//! descriptors, so the same range matcher (eq 8) and PnP code serve both: an
//! ORB bit becomes `±1/16`, and the squared L2 distance of two such vectors is
//! their Hamming distance / 64, an order-preserving stand-in for BF Hamming.

use crate::error::Result;
use crate::features::orb::{OrbConfig, detect_and_compute};
use crate::fpfdcnn::inference::FpfdcnnDetector;
use image::GrayImage;

/// Keypoints of one image with row-major `N x dim` unit descriptors.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct KeyFeatures {
    /// Keypoint positions `[x, y]`, pixels.
    pub points: Vec<[f32; 2]>,
    /// Row-major `N x dim` L2-normalised descriptors.
    pub descriptors: Vec<f32>,
    /// Descriptor length (256 for ORB, its bits as `±1/16`).
    pub dim: usize,
}

impl KeyFeatures {
    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Whether there are no keypoints.
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    /// Descriptor of keypoint `i`.
    pub fn descriptor(&self, i: usize) -> &[f32] {
        &self.descriptors[i * self.dim..(i + 1) * self.dim]
    }

    /// The normalised mean descriptor: a global image signature whose cosine
    /// similarity ranks keyframes for relocalisation and correction.
    pub fn mean_descriptor(&self) -> Vec<f32> {
        let mut m = vec![0f32; self.dim];
        for row in self.descriptors.chunks_exact(self.dim.max(1)) {
            for (a, b) in m.iter_mut().zip(row) {
                *a += b;
            }
        }
        let n = m.iter().map(|v| v * v).sum::<f32>().sqrt();
        if n > 0.0 {
            m.iter_mut().for_each(|v| *v /= n);
        }
        m
    }
}

/// Cosine similarity of two normalised signatures (0 when sizes differ).
pub fn similarity(a: &[f32], b: &[f32]) -> f32 {
    if a.len() != b.len() {
        return 0.0;
    }
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// A keypoint detector and descriptor.
pub trait KeypointSource: Send + Sync {
    /// Short name for reports (`orb`, `fpfdcnn`).
    fn name(&self) -> &'static str;
    /// Keypoints and descriptors of a grey image.
    fn detect(&self, gray: &GrayImage) -> Result<KeyFeatures>;
}

/// ORB as `cv::ORB_create(top_k)`, with a lower FAST threshold tried on
/// low-texture images.
#[derive(Debug, Clone)]
pub struct OrbSource {
    /// ORB settings of the first try.
    pub config: OrbConfig,
    /// FAST threshold of the second try when fewer than half of the wanted
    /// keypoints are found (0: no second try).
    pub fallback_threshold: u8,
}

impl OrbSource {
    /// ORB with the keypoint settings of a SLAM configuration.
    pub fn from_config(cfg: &crate::slam::config::FeatureConfig) -> Self {
        OrbSource {
            config: cfg.orb(),
            fallback_threshold: cfg.orb_fallback_threshold,
        }
    }
}

impl KeypointSource for OrbSource {
    fn name(&self) -> &'static str {
        "orb"
    }

    fn detect(&self, gray: &GrayImage) -> Result<KeyFeatures> {
        let mut f = detect_and_compute(gray, &self.config)?;
        let t = self.fallback_threshold;
        if t > 0 && t < self.config.fast_threshold && f.len() * 2 < self.config.n_features {
            let cfg = OrbConfig {
                fast_threshold: t,
                ..self.config.clone()
            };
            f = detect_and_compute(gray, &cfg)?;
        }
        let dim = 256;
        let mut descriptors = Vec::with_capacity(f.len() * dim);
        for d in &f.descriptors {
            for byte in d {
                for bit in 0..8 {
                    descriptors.push(if (byte >> bit) & 1 == 1 {
                        0.0625
                    } else {
                        -0.0625
                    });
                }
            }
        }
        Ok(KeyFeatures {
            points: f.keypoints.iter().map(|k| [k.x, k.y]).collect(),
            descriptors,
            dim,
        })
    }
}

/// FPFDCNN inference (Table 12 `Out`).
#[derive(Debug)]
pub struct FpfdcnnSource {
    /// The loaded FPFDCNN detector.
    pub detector: FpfdcnnDetector,
}

impl KeypointSource for FpfdcnnSource {
    fn name(&self) -> &'static str {
        "fpfdcnn"
    }

    fn detect(&self, gray: &GrayImage) -> Result<KeyFeatures> {
        let f = self.detector.detect(gray)?;
        Ok(KeyFeatures {
            points: f.points,
            descriptors: f.descriptors,
            dim: f.dim,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::hamming;

    #[test]
    fn orb_float_descriptors_preserve_hamming_order() {
        let img = GrayImage::from_fn(160, 120, |x, y| {
            image::Luma([(((x / 9) ^ (y / 7)) % 2 * 200 + (x * y) % 37) as u8])
        });
        let src = OrbSource {
            config: OrbConfig::default(),
            fallback_threshold: 0,
        };
        let f = src.detect(&img).unwrap();
        let raw = detect_and_compute(&img, &OrbConfig::default()).unwrap();
        assert!(f.len() > 5);
        for i in 0..f.len().min(10) {
            let n: f32 = f.descriptor(i).iter().map(|v| v * v).sum();
            assert!((n - 1.0).abs() < 1e-5);
            let d2: f32 = f
                .descriptor(i)
                .iter()
                .zip(f.descriptor(0))
                .map(|(a, b)| (a - b) * (a - b))
                .sum();
            let h = hamming(&raw.descriptors[i], &raw.descriptors[0]);
            assert!((d2 * 64.0 - h as f32).abs() < 1e-3);
        }
        let m = f.mean_descriptor();
        assert!((similarity(&m, &m) - 1.0).abs() < 1e-5);
    }
}
