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
//! seeded by the `i`-th number of [`crate::training::batch_rng`]`(seed, e, b)`, whatever
//! thread decodes it, so a resumed run sees exactly the batches of an uninterrupted one.

use burn::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

use super::focal::{NYU_FX, nyu_fx_fits, to_canonical};
use crate::camera::Camera;
use crate::dataset::augment::{AugmentConfig, SegDepthSample, augment};
use crate::dataset::labels::VOID;
use crate::dataset::{LabelImage, NyuDataset, TumConfig, TumSequence};
use crate::error::{Error, Result};

/// Most frames a TUM source may select, and most repeats of a source (bounds checked before
/// anything is read).
const MAX_FRAMES: usize = 10_000_000;
const MAX_REPEAT: usize = 1000;

/// One dataset (folder or `.mat` file) of a config's `[data]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataSource {
    /// NYUv2-layout folder (`rgb/ depth/ labels/`, or the flat `<id>_rgb.png` layout), the
    /// official `nyu_depth_v2_labeled.mat`, or a TUM RGB-D sequence folder (`rgb.txt` or
    /// `associations.txt`; PNG or JPEG colour), whose frames are depth-only samples.
    pub path: PathBuf,
    /// Optional split list (ids or 1-based indices, one a line); NYU layouts only.
    #[serde(default)]
    pub split: Option<PathBuf>,
    /// Depth PNG scale, `metres = value / depth_scale` (5000 by default).
    #[serde(default)]
    pub depth_scale: Option<f64>,
    /// The camera: `fr1`, `fr2`, `fr3` or a camera TOML file. Default: the folder's
    /// `camera.toml`; NYU layouts without one use NYUv2's camera (fx 518.86 px); a TUM
    /// sequence without one must name it.
    #[serde(default)]
    pub camera: Option<String>,
    /// TUM sequences: the frames `[first, end)` (0-based, in association order; default all).
    #[serde(default)]
    pub frames: Option<[usize; 2]>,
    /// TUM sequences: every n-th frame of `frames` (default 1).
    #[serde(default)]
    pub every: Option<usize>,
    /// Each sample enters an epoch this many times (default 1): the source's weight.
    #[serde(default)]
    pub repeat: Option<usize>,
    /// Name of the source in per-source validation metrics (`val_<name>_delta1`, ...).
    #[serde(default)]
    pub name: Option<String>,
}

impl DataSource {
    /// A folder without a split list.
    pub fn folder(path: impl Into<PathBuf>) -> Self {
        DataSource {
            path: path.into(),
            split: None,
            depth_scale: None,
            camera: None,
            frames: None,
            every: None,
            repeat: None,
            name: None,
        }
    }

    /// Whether `path` is a TUM RGB-D sequence folder rather than a NYU layout.
    pub fn is_sequence(&self) -> bool {
        self.path.join("rgb.txt").is_file() || self.path.join("associations.txt").is_file()
    }

    /// The source with its relative paths taken from `config_path`'s folder where they do not
    /// exist from the working directory ([`resolve`]).
    pub fn resolved(&self, config_path: &Path) -> Self {
        let camera = self.camera.as_ref().map(|c| {
            if Camera::preset(c).is_some() {
                c.clone()
            } else {
                resolve(Path::new(c), config_path).display().to_string()
            }
        });
        DataSource {
            path: resolve(&self.path, config_path),
            split: self.split.as_ref().map(|p| resolve(p, config_path)),
            camera,
            ..self.clone()
        }
    }

    fn check(&self) -> Result<()> {
        let bad = |m: String| Err(Error::invalid(&self.path, m));
        if let Some(scale) = self.depth_scale
            && !(scale > 0.0 && scale.is_finite())
        {
            return bad(format!("depth_scale {scale} must be positive"));
        }
        if let Some([a, b]) = self.frames
            && (a >= b || b > MAX_FRAMES)
        {
            return bad(format!(
                "frames = [{a}, {b}] must be a non-empty range [first, end) below {MAX_FRAMES}"
            ));
        }
        if self.every.is_some_and(|e| e == 0 || e > MAX_FRAMES) {
            return bad("every must be at least 1".into());
        }
        if self.repeat.is_some_and(|r| r == 0 || r > MAX_REPEAT) {
            return bad(format!("repeat must be in 1..={MAX_REPEAT}"));
        }
        if let Some(n) = &self.name
            && (n.is_empty() || !n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_'))
        {
            return bad(format!(
                "name \"{n}\" must be letters, digits and '_' (it names metrics)"
            ));
        }
        Ok(())
    }
}

/// A source's camera as far as depth needs it.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Focal {
    /// Horizontal focal length, pixels.
    fx: f64,
}

/// The images of one source.
#[derive(Debug, Clone)]
enum Images {
    Nyu(Box<NyuDataset>),
    /// A TUM sequence's selected frames (indices into its association list).
    Tum(TumSequence, Vec<usize>),
}

/// The images of one [`DataSource`] at their own resolution, with their camera's focal
/// length: what training resamples, and what `eval seg` evaluates.
#[derive(Debug, Clone)]
pub struct Set {
    images: Images,
    focal: Focal,
    name: Option<String>,
}

/// One image of a [`Set`]: colour, depth in metres (0 = missing) and labels (void where
/// unlabelled; everywhere for TUM sequences).
pub type SetItem = (
    image::RgbImage,
    Option<crate::dataset::DepthImage>,
    LabelImage,
);

impl Set {
    /// Opens a source (its relative paths as they are; see [`DataSource::resolved`]),
    /// checking it as [`SegDepthData::open`] does.
    pub fn open(s: &DataSource) -> Result<Self> {
        s.check()?;
        if s.is_sequence() {
            open_sequence(s)
        } else {
            open_nyu(s)
        }
    }

    /// The camera's horizontal focal length, pixels.
    pub fn fx(&self) -> f64 {
        self.focal.fx
    }

    /// Number of images.
    pub fn len(&self) -> usize {
        match &self.images {
            Images::Nyu(d) => d.len(),
            Images::Tum(_, frames) => frames.len(),
        }
    }

    fn root(&self) -> &Path {
        match &self.images {
            Images::Nyu(d) => &d.root,
            Images::Tum(s, _) => &s.root,
        }
    }

    /// Whether there is no image.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Image `j`'s id: the NYU id, or `frameNNNNN` (the index in the sequence).
    pub fn id(&self, j: usize) -> String {
        match &self.images {
            Images::Nyu(d) => d.samples[j].id.clone(),
            Images::Tum(_, f) => format!("frame{:05}", f[j]),
        }
    }

    fn sample_name(&self, j: usize) -> String {
        let id = match &self.images {
            Images::Nyu(d) => d.samples[j].id.clone(),
            Images::Tum(s, f) => s.frames[f[j]]
                .rgb_path
                .file_name()
                .map_or_else(|| format!("frame {}", f[j]), |n| n.to_string_lossy().into()),
        };
        format!("{}/{id}", self.root().display())
    }

    /// RGB, depth (metres) and labels of image `j`.
    pub fn load(&self, j: usize) -> Result<SetItem> {
        match &self.images {
            Images::Nyu(d) => {
                let item = d.load(j)?;
                Ok((item.rgb, item.depth, item.labels))
            }
            Images::Tum(seq, frames) => {
                let frame = frames[j];
                let rgb = seq.load_rgb(frame)?;
                let depth = seq.load_depth(frame)?;
                if let Some(d) = &depth
                    && (d.width, d.height) != rgb.dimensions()
                {
                    return Err(Error::invalid(
                        &seq.frames[frame].rgb_path,
                        format!(
                            "colour image is {}x{} but its depth image is {}x{}",
                            rgb.width(),
                            rgb.height(),
                            d.width,
                            d.height
                        ),
                    ));
                }
                let labels = LabelImage::new(rgb.width(), rgb.height(), VOID);
                Ok((rgb, depth, labels))
            }
        }
    }
}

/// The camera a source names or holds; `None` when it has none (an error for sequences).
fn source_camera(s: &DataSource) -> Result<Option<Camera>> {
    if let Some(spec) = &s.camera {
        return Camera::load(spec)
            .map(Some)
            .map_err(|e| Error::invalid(&s.path, format!("camera: {e}")));
    }
    let file = s.path.join("camera.toml");
    if file.is_file() {
        return Camera::from_file(file).map(Some);
    }
    Ok(None)
}

/// An error unless `camera` describes images of `width x height`.
fn check_camera(camera: &Camera, (width, height): (u32, u32), image: &Path) -> Result<()> {
    if (camera.width, camera.height) != (width, height) {
        return Err(Error::invalid(
            image,
            format!(
                "image is {width}x{height} but the source's camera is {}x{}: give the camera of \
                 these images (camera = \"fr1\" | \"fr2\" | \"fr3\" | FILE)",
                camera.width, camera.height
            ),
        ));
    }
    Ok(())
}

fn open_sequence(s: &DataSource) -> Result<Set> {
    if s.split.is_some() {
        return Err(Error::invalid(
            &s.path,
            "split lists are for NYU layouts; select a sequence's frames with frames = [first, end] and every = N",
        ));
    }
    let config = TumConfig {
        depth_scale: s.depth_scale.unwrap_or(TumConfig::default().depth_scale),
        ..TumConfig::default()
    };
    let seq = TumSequence::open_with(&s.path, config)?;
    if !seq.has_depth() {
        return Err(Error::invalid(
            &s.path,
            "sequence has no depth images: an SDFCNN depth source needs depth.txt or associations.txt",
        ));
    }
    let [first, end] = s.frames.unwrap_or([0, seq.len()]);
    if end > seq.len() {
        return Err(Error::invalid(
            &s.path,
            format!(
                "frames = [{first}, {end}] but the sequence has {} frames",
                seq.len()
            ),
        ));
    }
    let frames: Vec<usize> = (first..end).step_by(s.every.unwrap_or(1)).collect();
    let camera = source_camera(s)?.ok_or_else(|| {
        Error::invalid(
            &s.path,
            "sequence has no camera.toml: name its camera (camera = \"fr1\" | \"fr2\" | \"fr3\" | FILE)",
        )
    })?;
    let first_rgb = &seq.frames[frames[0]].rgb_path;
    let dims = image::image_dimensions(first_rgb)
        .map_err(|e| Error::invalid(first_rgb, format!("cannot read the image size: {e}")))?;
    check_camera(&camera, dims, first_rgb)?;
    // A source whose depth is all missing would train nothing: an error before training
    // (usually the first frame answers).
    let mut valid = false;
    for &f in &frames {
        if seq.load_depth(f)?.is_some_and(|d| d.valid_fraction() > 0.0) {
            valid = true;
            break;
        }
    }
    if !valid {
        return Err(Error::invalid(
            &s.path,
            format!(
                "none of the {} selected frames has a valid depth pixel",
                frames.len()
            ),
        ));
    }
    Ok(Set {
        images: Images::Tum(seq, frames),
        focal: Focal { fx: camera.fx },
        name: s.name.clone(),
    })
}

fn open_nyu(s: &DataSource) -> Result<Set> {
    if s.frames.is_some() || s.every.is_some() {
        return Err(Error::invalid(
            &s.path,
            "frames and every select a TUM sequence's frames; this is a NYU layout (use split)",
        ));
    }
    let mut set = NyuDataset::open(&s.path, s.split.as_deref())?;
    if let Some(scale) = s.depth_scale {
        set.depth_scale = scale;
    }
    let first = if set.is_empty() {
        None
    } else {
        Some(set.load(0)?.rgb.dimensions())
    };
    let focal = match source_camera(s)? {
        Some(camera) => {
            if let Some(dims) = first {
                check_camera(&camera, dims, &set.root)?;
            }
            Focal { fx: camera.fx }
        }
        None => {
            if let Some((w, _)) = first.filter(|&(w, _)| !nyu_fx_fits(w)) {
                return Err(Error::invalid(
                    &set.root,
                    format!(
                        "images are {w} px wide, not NYUv2's 640 (or a crop of it), and the folder \
                         has no camera.toml: name their camera (camera = \"fr1\" | FILE)"
                    ),
                ));
            }
            Focal { fx: NYU_FX }
        }
    };
    Ok(Set {
        images: Images::Nyu(Box::new(set)),
        focal,
        name: s.name.clone(),
    })
}

/// The samples of several datasets, concatenated (each `repeat` times).
#[derive(Debug, Clone)]
pub struct SegDepthData {
    sets: Vec<Set>,
    /// (set, sample) of every global index.
    index: Vec<(usize, usize)>,
    /// Canonical focal length in image widths ([`super::focal`]); `None`: metric depth as is.
    canonical: Option<f64>,
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
        })
    }

    /// Depth targets for the canonical camera of focal length `focal` image widths
    /// ([`super::focal`]); `None` keeps metric depth.
    pub fn with_canonical(mut self, focal: Option<f64>) -> Self {
        self.canonical = focal;
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
    /// canonical focal length).
    pub fn depth_factor(&self, i: usize, width: u32, zoom: f32) -> f32 {
        match (self.canonical, self.index.get(i)) {
            (Some(c), Some(&(k, _))) => {
                to_canonical(c, self.sets[k].focal.fx, width as f64, zoom as f64) as f32
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
        let (rgb, depth, labels) = self.sets[k].load(j)?;
        let mut sample = augment(&rgb, depth.as_ref(), &labels, width, height, aug, rng);
        let factor = self.depth_factor(i, rgb.width(), sample.zoom);
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

    const TUM: &str = "datasets/fixtures/tum_fr1_rpy_head10";

    fn tum() -> DataSource {
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

    #[test]
    fn tum_source_errors_name_the_sequence() {
        let no_camera = SegDepthData::open(&[DataSource::folder(TUM)]).expect_err("no camera");
        assert!(
            no_camera.to_string().contains("tum_fr1_rpy_head10")
                && no_camera.to_string().contains("camera"),
            "{no_camera}"
        );
        let dir = std::env::temp_dir().join(format!("sdf_data_cam_{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        let cam = dir.join("small.toml");
        crate::camera::Camera::tum_fr1()
            .resized(320, 240)
            .save(&cam)
            .expect("camera");
        let wrong = DataSource {
            camera: Some(cam.display().to_string()),
            ..tum()
        };
        let e = SegDepthData::open(&[wrong]).expect_err("camera of another size");
        assert!(
            e.to_string().contains("640x480") && e.to_string().contains("320x240"),
            "{e}"
        );
        for (bad, what) in [
            (
                DataSource {
                    frames: Some([5, 5]),
                    ..tum()
                },
                "frames",
            ),
            (
                DataSource {
                    frames: Some([0, 11]),
                    ..tum()
                },
                "10 frames",
            ),
            (
                DataSource {
                    every: Some(0),
                    ..tum()
                },
                "every",
            ),
            (
                DataSource {
                    repeat: Some(0),
                    ..tum()
                },
                "repeat",
            ),
            (
                DataSource {
                    name: Some("a b".into()),
                    ..tum()
                },
                "name",
            ),
            (
                DataSource {
                    split: Some("x.txt".into()),
                    ..tum()
                },
                "split",
            ),
        ] {
            let e = SegDepthData::open(&[bad]).expect_err(what).to_string();
            assert!(
                e.contains(what) && e.contains("tum_fr1_rpy_head10"),
                "{what}: {e}"
            );
        }

        // Two sources named alike would overwrite each other's metrics.
        let named = DataSource {
            name: Some("tum".into()),
            ..tum()
        };
        let e = SegDepthData::open(&[named.clone(), named]).expect_err("same name twice");
        assert!(e.to_string().contains("two sources"), "{e}");
        // A NYU layout at another width than NYUv2's, without a camera.toml.
        let small = dir.join("small_nyu");
        std::fs::create_dir_all(&small).expect("dir");
        image::RgbImage::new(320, 240)
            .save(small.join("000001_rgb.png"))
            .expect("rgb");
        image::GrayImage::new(320, 240)
            .save(small.join("000001_seg40.png"))
            .expect("labels");
        let e = SegDepthData::open(&[DataSource::folder(&small)]).expect_err("no camera");
        assert!(e.to_string().contains("320 px wide"), "{e}");
        let ok = DataSource {
            camera: Some(cam.display().to_string()),
            ..DataSource::folder(&small)
        };
        SegDepthData::open(&[ok]).expect("its camera given");

        // A sequence whose depth images hold no valid pixel.
        let seq = dir.join("nodepth");
        std::fs::create_dir_all(seq.join("rgb")).expect("dir");
        std::fs::create_dir_all(seq.join("depth")).expect("dir");
        let src = std::path::Path::new(TUM);
        let assoc = std::fs::read_to_string(src.join("associations.txt")).expect("assoc");
        let first = assoc
            .lines()
            .find(|l| !l.starts_with('#') && !l.trim().is_empty())
            .expect("a frame");
        let f: Vec<&str> = first.split_whitespace().collect();
        std::fs::copy(src.join(f[1]), seq.join(f[1])).expect("rgb");
        crate::dataset::DepthImage::new(640, 480)
            .write_png(seq.join(f[3]), 5000.0)
            .expect("depth");
        std::fs::write(seq.join("associations.txt"), format!("{first}\n")).expect("assoc");
        let e = SegDepthData::open(&[DataSource {
            camera: Some("fr1".into()),
            ..DataSource::folder(&seq)
        }])
        .expect_err("no valid depth")
        .to_string();
        assert!(e.contains("nodepth") && e.contains("valid depth"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
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
