//! SDFCNN training data: samples from NYUv2-layout datasets ([`crate::dataset::NyuDataset`]:
//! PNG-layout folders or the official `.mat` file, e.g. the real NYUv2 labelled set and `synth`
//! output; labels and depth) and TUM RGB-D-layout sequences ([`crate::dataset::TumSequence`]:
//! real RGB-D frames, depth only, every label void so that eq. 21's segmentation term ignores
//! them), decoded and augmented in parallel ([`crate::dataset::augment::augment`]) and stacked
//! into batches of `[N, 3, H, W]` RGB in `[0, 1]`, `[N, H, W]` labels (255 = void) and
//! `[N, 1, H, W]` depth in metres (0 = missing).
//!
//! Every source has a camera (its `camera.toml`, a `camera = ...` entry, or NYUv2's for NYU
//! folders without one). With a canonical focal length set ([`SegDepthData::with_canonical`],
//! from `[network] depth_focal`), depth targets are those of the canonical camera
//! ([`super::focal`]), zoom included.
//!
//! Augmentation is reproducible: sample `i` of batch `b` of epoch `e` draws from a generator
//! seeded by the `i`-th number of `crate::training::batch_rng(seed, e, b)`, whatever
//! thread decodes it, so a resumed run sees exactly the batches of an uninterrupted one.

use burn::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::{Path, PathBuf};

use super::focal::to_canonical;
pub use super::source::{DataSource, Set, SetItem};
use crate::dataset::augment::{AugmentConfig, SegDepthSample, augment};
use crate::error::{Error, Result};

/// The samples of several datasets, concatenated (each `repeat` times).
#[derive(Debug, Clone)]
pub struct SegDepthData {
    sets: Vec<Set>,
    /// (set, sample) of every global index.
    index: Vec<(usize, usize)>,
    /// Canonical focal length in image widths ([`super::focal`]); `None`: metric depth as is.
    canonical: Option<f64>,
    /// Synthetic sources render their first draw whatever the generator (validation: the same
    /// views every epoch and whatever the batch size).
    fixed_draws: bool,
}

impl SegDepthData {
    /// Opens every source (relative paths are taken from the working directory). Bad values,
    /// a camera that does not fit the images, or a sequence without valid depth are errors
    /// naming the source.
    pub fn open(sources: &[DataSource]) -> Result<Self> {
        let mut sets = Vec::new();
        let mut index = Vec::new();
        for (k, s) in sources.iter().enumerate() {
            if let Some(name) = &s.name
                && sources[..k].iter().any(|o| o.name.as_ref() == Some(name))
            {
                return Err(Error::invalid(
                    &s.path,
                    format!("name \"{name}\" is given to two sources (it names their metrics)"),
                ));
            }
            let set = Set::open(s)?;
            for _ in 0..s.repeat.unwrap_or(1) {
                index.extend((0..set.len()).map(|i| (k, i)));
            }
            sets.push(set);
        }
        Ok(SegDepthData {
            sets,
            index,
            canonical: None,
            fixed_draws: false,
        })
    }

    /// Depth targets for the canonical camera of focal length `focal` image widths
    /// ([`super::focal`]); `None` keeps metric depth.
    pub fn with_canonical(mut self, focal: Option<f64>) -> Self {
        self.canonical = focal;
        self
    }

    /// Synthetic sources keep to their first draw (validation data).
    pub fn with_fixed_draws(mut self) -> Self {
        self.fixed_draws = true;
        self
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
            Some(&(k, j)) => self.sets[k].sample_name(j),
            None => format!("sample {i}"),
        }
    }

    /// Number of sources.
    pub fn num_sources(&self) -> usize {
        self.sets.len()
    }

    /// The source of sample `i`.
    pub fn source_of(&self, i: usize) -> Option<usize> {
        self.index.get(i).map(|&(k, _)| k)
    }

    /// The `name` of source `k`, if it has one.
    pub fn source_name(&self, k: usize) -> Option<&str> {
        self.sets.get(k).and_then(|s| s.name.as_deref())
    }

    /// Global indices of at most `limit` samples of each source (its first ones, once each).
    pub fn first_of_each(&self, limit: Option<usize>) -> Vec<usize> {
        let mut taken = vec![0usize; self.sets.len()];
        let mut seen = std::collections::HashSet::new();
        let mut out = Vec::new();
        for (i, &(k, j)) in self.index.iter().enumerate() {
            if limit.is_some_and(|l| taken[k] >= l) || !seen.insert((k, j)) {
                continue;
            }
            taken[k] += 1;
            out.push(i);
        }
        out
    }

    /// The factor from metric depth to the target depth of sample `i` at `zoom` (1 without a
    /// canonical focal length), for its source's camera (a synthetic source with `focal`
    /// draws each view's own, which [`Self::load`] uses).
    pub fn depth_factor(&self, i: usize, width: u32, zoom: f32) -> f32 {
        match (self.canonical, self.index.get(i)) {
            (Some(c), Some(&(k, _))) => {
                to_canonical(c, self.sets[k].fx(), width as f64, zoom as f64) as f32
            }
            _ => 1.0,
        }
    }

    /// Loads sample `i` resampled (and augmented) to `[height, width]`, its depth scaled to the
    /// canonical camera when one is set.
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
        let set = &self.sets[k];
        // A synthetic source renders a new view each draw (from the sample's generator), with
        // its own focal length.
        let fresh = if set.is_synthetic() && !self.fixed_draws {
            rng.next_u64()
        } else {
            0
        };
        let ((rgb, depth, labels), fx) = set.load_drawn(j, fresh)?;
        let mut sample = augment(&rgb, depth.as_ref(), &labels, width, height, aug, rng);
        let factor = match self.canonical {
            Some(c) => to_canonical(c, fx, rgb.width() as f64, sample.zoom as f64) as f32,
            None => 1.0,
        };
        if factor != 1.0 {
            sample.depth.iter_mut().for_each(|d| *d *= factor);
            sample.depth_factor = factor;
        }
        Ok(sample)
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
pub(crate) struct SdfcnnBatch {
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

/// A source's `camera`: a preset name (`fr1`, ...) as it is, a camera file resolved as
/// [`resolve`] does.
pub fn resolve_camera(spec: &str, config_path: &Path) -> String {
    if crate::camera::Camera::preset(spec).is_some() {
        spec.to_string()
    } else {
        resolve(Path::new(spec), config_path).display().to_string()
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::dataset::labels::VOID;
    use crate::training::batch_rng;

    pub(crate) const NYU: &str = "datasets/fixtures/nyuv2";

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

    pub(crate) const TUM: &str = "datasets/fixtures/tum_fr1_rpy_head10";

    pub(crate) fn tum() -> DataSource {
        DataSource {
            camera: Some("fr1".into()),
            ..DataSource::folder(TUM)
        }
    }

    #[test]
    fn tum_sequences_are_depth_only_sources() {
        let src = DataSource {
            frames: Some([2, 9]),
            every: Some(3),
            repeat: Some(2),
            name: Some("tum".into()),
            ..tum()
        };
        let data = SegDepthData::open(&[src, DataSource::folder(NYU)]).expect("fixture");
        // Frames 2, 5, 8, twice, then the three NYU samples.
        assert_eq!(data.len(), 3 * 2 + 3);
        assert_eq!(data.first_of_each(None).len(), 6);
        assert_eq!(data.first_of_each(Some(1)), vec![0, 6]);
        assert_eq!(data.source_name(0), Some("tum"));
        assert!(data.name(1).ends_with(".png"), "{}", data.name(1));
        let none = AugmentConfig::none();
        let s = data
            .load_batch(&[0], [24, 32], &none, &mut batch_rng(1, 0, 0))
            .expect("loads");
        assert!(s[0].labels.iter().all(|&l| l == VOID));
        assert!(s[0].depth.iter().any(|&d| d > 0.3 && d < 6.0));
        assert_eq!(s[0].depth_factor, 1.0);

        // The canonical camera: fr1's 517.3 px lens becomes NYUv2's 518.86 px.
        let canonical = data
            .clone()
            .with_canonical(Some(super::super::focal::NYU_FOCAL));
        let c = canonical
            .load_batch(&[0], [24, 32], &none, &mut batch_rng(1, 0, 0))
            .expect("loads");
        let k = c[0].depth_factor;
        assert!((k - (518.8579 / 517.3) as f32).abs() < 1e-4, "{k}");
        for (a, b) in s[0].depth.iter().zip(&c[0].depth) {
            assert!((a * k - b).abs() < 1e-5);
        }
        // NYU folders without camera.toml have NYUv2's camera: factor 1 at 640 px.
        assert!((canonical.depth_factor(6, 640, 1.0) - 1.0).abs() < 1e-6);
        // A 1.5x zoom makes the canonical depth 1.5x smaller.
        assert!((canonical.depth_factor(6, 640, 1.5) - 1.0 / 1.5).abs() < 1e-6);
    }
}
