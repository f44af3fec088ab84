//! One dataset of a config's `[data]` section ([`DataSource`]) and its images ([`Set`]): a
//! NYUv2 layout (PNG folders or the official `.mat` file; labels and depth, NYUv2's camera
//! unless the folder names another) or a TUM RGB-D sequence (depth only, every label void;
//! its camera must be named), checked when opened. [`super::data::SegDepthData`] concatenates
//! them.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

use super::data::{resolve, resolve_camera};
use super::focal::{NYU_FX, nyu_fx_fits};
use crate::camera::Camera;
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
    /// Synthetic sources (`path` a `synth` config): the views an epoch draws, each a fresh
    /// room rendered while training, nothing written to disk.
    #[serde(default)]
    pub samples: Option<usize>,
    /// Synthetic sources: each view's focal length drawn uniformly from `[low, high]` pixels
    /// for a 640-pixel-wide image (scaled to the config's resolution; default: its camera's).
    #[serde(default)]
    pub focal: Option<[f64; 2]>,
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
            samples: None,
            focal: None,
        }
    }

    /// Whether `path` is a `synth` config, whose views are rendered while training.
    pub fn is_synthetic(&self) -> bool {
        self.path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("toml"))
    }

    /// Whether `path` is a TUM RGB-D sequence folder rather than a NYU layout.
    pub fn is_sequence(&self) -> bool {
        self.path.join("rgb.txt").is_file() || self.path.join("associations.txt").is_file()
    }

    /// The source with its relative paths taken from `config_path`'s folder where they do not
    /// exist from the working directory ([`resolve`]).
    pub fn resolved(&self, config_path: &Path) -> Self {
        let camera = self.camera.as_ref().map(|c| resolve_camera(c, config_path));
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
        if self.samples.is_some_and(|n| n == 0 || n > MAX_FRAMES) {
            return bad(format!("samples must be in 1..={MAX_FRAMES}"));
        }
        if let Some([lo, hi]) = self.focal
            && !(lo >= 100.0 && lo <= hi && hi <= 5000.0)
        {
            return bad(format!(
                "focal = [{lo}, {hi}] must be a range of focal lengths in pixels at 640 px width (100-5000)"
            ));
        }
        let synthetic = self.is_synthetic();
        if synthetic != self.samples.is_some() {
            return bad(if synthetic {
                "a synth config as a source needs samples = N (the views an epoch draws)".into()
            } else {
                "samples is for synthetic sources (path = a synth config)".into()
            });
        }
        if self.focal.is_some() && !synthetic {
            return bad("focal is for synthetic sources (path = a synth config)".into());
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
    /// Views rendered on demand.
    Synth(Box<Stream>),
}

/// A synthetic source: `samples` views of fresh rooms, rendered when loaded.
#[derive(Debug, Clone)]
struct Stream {
    path: PathBuf,
    cfg: crate::synth::SynthConfig,
    camera: Camera,
    samples: usize,
    focal: Option<[f64; 2]>,
}

impl Stream {
    /// View `j` of the draw `fresh` (0: the same views every time, as validation needs) and
    /// the focal length it was rendered with, pixels.
    fn render(&self, j: usize, fresh: u64) -> Result<(SetItem, f64)> {
        use rand::{RngExt, SeedableRng};
        let seed = crate::synth::scene_seed(self.cfg.seed ^ fresh, j);
        let mut camera = self.camera.clone();
        if let Some([lo, hi]) = self.focal {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0xf0ca_1000);
            let f = rng.random_range(lo..=hi) * camera.width as f64 / 640.0;
            camera.fx = f;
            camera.fy = f;
        }
        let view = crate::synth::stream_view(&self.cfg, &camera, seed)
            .map_err(|e| Error::invalid(&self.path, format!("view {j}: {e}")))?;
        let labels = LabelImage {
            width: view.labels.width(),
            height: view.labels.height(),
            data: view.labels.into_raw(),
        };
        Ok(((view.rgb, Some(view.depth), labels), camera.fx))
    }
}

/// The images of one [`DataSource`] at their own resolution, with their camera's focal
/// length: what training resamples, and what `eval seg` evaluates.
#[derive(Debug, Clone)]
pub struct Set {
    images: Images,
    focal: Focal,
    pub(super) name: Option<String>,
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
    /// checking it as [`SegDepthData::open`](super::data::SegDepthData::open) does.
    pub fn open(s: &DataSource) -> Result<Self> {
        s.check()?;
        if s.is_synthetic() {
            open_synth(s)
        } else if s.is_sequence() {
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
            Images::Synth(st) => st.samples,
        }
    }

    fn root(&self) -> &Path {
        match &self.images {
            Images::Nyu(d) => &d.root,
            Images::Tum(s, _) => &s.root,
            Images::Synth(_) => Path::new("synth"),
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
            Images::Synth(_) => format!("view{j:06}"),
        }
    }

    pub(super) fn sample_name(&self, j: usize) -> String {
        let id = match &self.images {
            Images::Nyu(d) => d.samples[j].id.clone(),
            Images::Tum(s, f) => s.frames[f[j]]
                .rgb_path
                .file_name()
                .map_or_else(|| format!("frame {}", f[j]), |n| n.to_string_lossy().into()),
            Images::Synth(_) => format!("view{j:06}"),
        };
        format!("{}/{id}", self.root().display())
    }

    /// RGB, depth (metres) and labels of image `j`, with the focal length it was taken with
    /// (pixels); a synthetic source renders view `j` of the draw `fresh`.
    pub fn load_drawn(&self, j: usize, fresh: u64) -> Result<(SetItem, f64)> {
        match &self.images {
            Images::Synth(st) => st.render(j, fresh),
            _ => Ok((self.load(j)?, self.fx())),
        }
    }

    /// Whether the images are rendered on demand (a new draw each epoch in training).
    pub fn is_synthetic(&self) -> bool {
        matches!(self.images, Images::Synth(_))
    }

    /// RGB, depth (metres) and labels of image `j` (a synthetic source's first draw).
    pub fn load(&self, j: usize) -> Result<SetItem> {
        match &self.images {
            Images::Synth(st) => Ok(st.render(j, 0)?.0),
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
    let mut seq = TumSequence::open_with(&s.path, config)?;
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
    let header = crate::imageio::header(first_rgb)?;
    check_camera(&camera, (header.width, header.height), first_rgb)?;
    // Every frame checked against the camera where it is read (size, channels, bit depth).
    seq.expect_camera(&camera);
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

fn open_synth(s: &DataSource) -> Result<Set> {
    if s.split.is_some() || s.frames.is_some() || s.every.is_some() || s.camera.is_some() {
        return Err(Error::invalid(
            &s.path,
            "a synthetic source takes samples, focal, repeat and name (its camera is the synth config's)",
        ));
    }
    let cfg = crate::synth::SynthConfig::from_file(&s.path)?;
    cfg.validate()?;
    let camera = cfg.camera()?;
    let stream = Stream {
        path: s.path.clone(),
        camera: camera.clone(),
        cfg,
        samples: s.samples.unwrap_or(0),
        focal: s.focal,
    };
    Ok(Set {
        images: Images::Synth(Box::new(stream)),
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
    // Every image is checked where it is read (size, channels, bit depth): against the
    // camera, or without one, as a crop of NYUv2's 640x480 images.
    let focal = match source_camera(s)? {
        Some(camera) => {
            if let Some(dims) = first {
                check_camera(&camera, dims, &set.root)?;
            }
            set.expect_frames(crate::dataset::FrameSpec::of(&camera));
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
            let min_width = (1..=640).find(|&w| nyu_fx_fits(w)).unwrap_or(640);
            set.expect_frames(crate::dataset::FrameSpec::crops_of(
                640,
                480,
                min_width,
                min_width * 480 / 640,
            ));
            Focal { fx: NYU_FX }
        }
    };
    Ok(Set {
        images: Images::Nyu(Box::new(set)),
        focal,
        name: s.name.clone(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dataset::augment::AugmentConfig;
    use crate::sdfcnn::data::SegDepthData;
    use crate::sdfcnn::data::tests::{NYU, TUM, tum};
    use crate::training::batch_rng;

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
