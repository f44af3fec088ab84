//! SDFCNN training data: samples from one or more NYUv2 datasets
//! ([`crate::dataset::NyuDataset`]: PNG-layout folders or the official `.mat` file, e.g. the
//! real NYUv2 labelled set and `synth` output),
//! decoded and augmented in parallel ([`crate::dataset::augment::augment`]) and stacked into
//! batches of `[N, 3, H, W]` RGB in `[0, 1]`, `[N, H, W]` labels (255 = void) and
//! `[N, 1, H, W]` depth in metres (0 = missing).
//!
//! Augmentation is reproducible: sample `i` of batch `b` of epoch `e` draws from a generator
//! seeded by the `i`-th number of [`crate::training::batch_rng`]`(seed, e, b)`, whatever
//! thread decodes it, so a resumed run sees exactly the batches of an uninterrupted one.

use burn::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

use crate::dataset::NyuDataset;
use crate::dataset::augment::{AugmentConfig, SegDepthSample, augment};
use crate::error::{Error, Result};

/// One dataset (folder or `.mat` file) of a config's `[data]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataSource {
    /// NYUv2-layout folder (`rgb/ depth/ labels/`, or the flat `<id>_rgb.png` layout), or the
    /// official `nyu_depth_v2_labeled.mat`.
    pub path: PathBuf,
    /// Optional split list (ids or 1-based indices, one a line).
    #[serde(default)]
    pub split: Option<PathBuf>,
    /// Depth PNG scale, `metres = value / depth_scale` (5000 by default).
    #[serde(default)]
    pub depth_scale: Option<f64>,
}

impl DataSource {
    /// A folder without a split list.
    pub fn folder(path: impl Into<PathBuf>) -> Self {
        DataSource {
            path: path.into(),
            split: None,
            depth_scale: None,
        }
    }
}

/// The samples of several datasets, concatenated.
#[derive(Debug, Clone)]
pub struct SegDepthData {
    sets: Vec<NyuDataset>,
    /// (set, sample) of every global index.
    index: Vec<(usize, usize)>,
}

impl SegDepthData {
    /// Opens every source (relative paths are taken from the working directory).
    pub fn open(sources: &[DataSource]) -> Result<Self> {
        let mut sets = Vec::new();
        let mut index = Vec::new();
        for (k, s) in sources.iter().enumerate() {
            let mut set = NyuDataset::open(&s.path, s.split.as_deref())?;
            if let Some(scale) = s.depth_scale {
                if !(scale > 0.0 && scale.is_finite()) {
                    return Err(Error::invalid(
                        &s.path,
                        format!("depth_scale {scale} must be positive"),
                    ));
                }
                set.depth_scale = scale;
            }
            index.extend((0..set.len()).map(|i| (k, i)));
            sets.push(set);
        }
        Ok(SegDepthData { sets, index })
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// Whether there is no sample.
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// Name of sample `i` (`folder/id` or `file.mat/id`), for messages.
    pub fn name(&self, i: usize) -> String {
        match self.index.get(i) {
            Some(&(k, j)) => {
                let set = &self.sets[k];
                format!("{}/{}", set.root.display(), set.samples[j].id)
            }
            None => format!("sample {i}"),
        }
    }

    /// Loads sample `i` resampled (and augmented) to `[height, width]`.
    pub fn load(
        &self,
        i: usize,
        [height, width]: [usize; 2],
        aug: &AugmentConfig,
        rng: &mut impl Rng,
    ) -> Result<SegDepthSample> {
        let &(k, j) = self.index.get(i).ok_or_else(|| {
            Error::msg(format!("sample {i} out of range ({} samples)", self.len()))
        })?;
        let item = self.sets[k].load(j)?;
        Ok(augment(
            &item.rgb,
            item.depth.as_ref(),
            &item.labels,
            width,
            height,
            aug,
            rng,
        ))
    }

    /// Loads the samples `indices` in parallel; sample `n` of the list draws its augmentation
    /// from the `n`-th seed of `rng`.
    pub fn load_batch(
        &self,
        indices: &[usize],
        size: [usize; 2],
        aug: &AugmentConfig,
        rng: &mut impl Rng,
    ) -> Result<Vec<SegDepthSample>> {
        let seeds: Vec<u64> = indices.iter().map(|_| rng.next_u64()).collect();
        indices
            .par_iter()
            .zip(seeds)
            .map(|(&i, seed)| self.load(i, size, aug, &mut ChaCha8Rng::seed_from_u64(seed)))
            .collect()
    }
}

/// A batch on a device.
#[derive(Debug, Clone)]
pub struct SdfcnnBatch {
    /// `[N, 3, H, W]` RGB in `[0, 1]`.
    pub images: Tensor<4>,
    /// `[N, H, W]` class indices, 255 = void.
    pub labels: Tensor<3, Int>,
    /// `[N, 1, H, W]` metres, 0 = missing.
    pub depth: Tensor<4>,
}

impl SdfcnnBatch {
    /// Stacks samples of equal size onto `device`.
    pub fn from_samples(samples: &[SegDepthSample], device: &Device) -> Result<Self> {
        let first = samples.first().ok_or_else(|| Error::msg("empty batch"))?;
        let (h, w, n) = (first.height, first.width, samples.len());
        if samples.iter().any(|s| (s.height, s.width) != (h, w)) {
            return Err(Error::msg("batch samples differ in size"));
        }
        let mut rgb = Vec::with_capacity(n * 3 * h * w);
        let mut labels = Vec::with_capacity(n * h * w);
        let mut depth = Vec::with_capacity(n * h * w);
        for s in samples {
            rgb.extend_from_slice(&s.rgb);
            labels.extend(s.labels.iter().map(|&l| l as i64));
            depth.extend_from_slice(&s.depth);
        }
        Ok(SdfcnnBatch {
            images: Tensor::from_data(TensorData::new(rgb, [n, 3, h, w]), device),
            labels: Tensor::from_data(TensorData::new(labels, [n, h, w]), device),
            depth: Tensor::from_data(TensorData::new(depth, [n, 1, h, w]), device),
        })
    }
}

/// Resolves a config-relative path: absolute paths and paths that exist from the working
/// directory are kept, others are taken relative to the config file's folder.
pub fn resolve(path: &Path, config_path: &Path) -> PathBuf {
    if path.is_absolute() || path.exists() {
        return path.to_path_buf();
    }
    match config_path.parent() {
        Some(dir) if dir.join(path).exists() => dir.join(path),
        _ => path.to_path_buf(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::training::batch_rng;

    const NYU: &str = "datasets/fixtures/nyuv2";

    #[test]
    fn batches_from_fixture_are_reproducible() {
        let data = SegDepthData::open(&[DataSource::folder(NYU), DataSource::folder(NYU)])
            .expect("fixture");
        assert_eq!(data.len(), 6);
        assert!(data.name(4).ends_with("000464"));
        let aug = AugmentConfig::default();
        let load = || {
            data.load_batch(&[0, 2, 4], [24, 32], &aug, &mut batch_rng(7, 1, 3))
                .expect("loads")
        };
        let (a, b) = (load(), load());
        assert_eq!(a, b);
        // Sample 0 and 3 are the same image but get different augmentations.
        let c = data
            .load_batch(&[3], [24, 32], &aug, &mut batch_rng(7, 1, 4))
            .expect("loads");
        assert_ne!(a[0].rgb, c[0].rgb);
        // The palette-mask sample has no depth.
        assert!(a[1].depth.iter().all(|&d| d == 0.0));
        assert!(a[0].depth.iter().any(|&d| d > 0.5 && d < 10.0));

        let d = Device::flex();
        let batch = SdfcnnBatch::from_samples(&a, &d).expect("same size");
        assert_eq!(batch.images.dims(), [3, 3, 24, 32]);
        assert_eq!(batch.labels.dims(), [3, 24, 32]);
        assert_eq!(batch.depth.dims(), [3, 1, 24, 32]);
        let labels = batch.labels.into_data().convert::<i64>();
        let labels = labels.as_slice::<i64>().expect("i64");
        assert!(labels.iter().all(|&l| (0..40).contains(&l) || l == 255));
    }

    #[test]
    fn the_official_mat_file_is_a_source() {
        let src = DataSource {
            split: Some("datasets/meta/nyuv2/splits_test_1based.txt".into()),
            ..DataSource::folder("datasets/fixtures/nyuv2_mat/nyu_depth_v2_labeled_fixture.mat")
        };
        let data = SegDepthData::open(&[src]).expect("fixture");
        assert_eq!(data.len(), 654);
        assert!(
            data.name(168).ends_with(".mat/000433"),
            "{}",
            data.name(168)
        );
        let s = data
            .load_batch(
                &[168],
                [24, 32],
                &AugmentConfig::default(),
                &mut batch_rng(1, 0, 0),
            )
            .expect("loads");
        assert!(s[0].depth.iter().any(|&d| d > 0.5 && d < 10.0));
        assert!(s[0].labels.iter().any(|&l| l < 40));
    }

    #[test]
    fn bad_sources_are_errors() {
        let e = SegDepthData::open(&[DataSource::folder("no/such/folder")])
            .expect_err("missing folder");
        assert!(e.to_string().contains("no/such/folder"), "{e}");
        let src = DataSource {
            depth_scale: Some(0.0),
            ..DataSource::folder(NYU)
        };
        assert!(SegDepthData::open(&[src]).is_err());
    }
}
