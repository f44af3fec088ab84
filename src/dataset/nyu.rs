//! NYU Depth v2 labelled images, from the official `nyu_depth_v2_labeled.mat` itself
//! ([`NyuMat`]) or from the PNG layouts people convert it to, with a split list.
//!
//! Two PNG layouts are recognised:
//! * **folders**: `rgb/<id>.png`, `depth/<id>.png` (optional), `labels/<id>.png`
//!   (what `synth` writes, and common converters);
//! * **flat**: `<id>_rgb.png`, `<id>_depth.png` (optional), and `<id>_seg40.png`
//!   (40 classes) or `<id>_seg894.png` (894 classes, mapped to 40), or
//!   `<id>.png` + `<id>_mask.png` (40 classes, no depth).
//!
//! Depth is 16-bit with `metres = value / depth_scale` (5000 by default), 0 =
//! missing. Labels are 0-based 40-class indices (0 = wall ... 39 = otherprop)
//! with 255 = void; 894-class labels use 0 = unlabelled and are mapped with
//! `datasets/meta/nyuv2/nyu894_to_nyu40.csv`. A split list names one sample per
//! line, by id (`000433`) or by 1-based index (`433`, as the standard
//! `splits_{train,test}_1based.txt`).

use super::depth::DepthImage;
use super::frame_check::{FrameImage, FrameSpec};
use super::labels::{LabelImage, VOID};
use super::nyu_mat::NyuMat;
use crate::error::{Error, Result};
use crate::io::{read_text, records};
use image::RgbImage;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

pub use crate::classes::NUM_CLASSES;

/// One sample: its id and where it is.
#[derive(Debug, Clone, PartialEq)]
pub struct NyuSample {
    /// Sample id: the file stem, or for the `.mat` file the 1-based image number (`000433`).
    pub id: String,
    /// Where the sample's images are stored.
    pub source: SampleSource,
}

/// Where a sample is stored.
#[derive(Debug, Clone, PartialEq)]
pub enum SampleSource {
    /// PNG files; `labels_894`: the labels are 894-class and need mapping to 40.
    Png {
        /// Colour image path.
        rgb: PathBuf,
        /// 16-bit depth image path; `None` when the layout has no depth.
        depth: Option<PathBuf>,
        /// Label image path.
        labels: PathBuf,
        /// The labels are 894-class and are mapped to 40 classes on load.
        labels_894: bool,
    },
    /// Image `index` (0-based) of the dataset's `.mat` file.
    Mat(usize),
}

/// A loaded sample.
#[derive(Debug, Clone)]
pub struct NyuItem {
    /// The sample's id.
    pub id: String,
    /// Colour image.
    pub rgb: RgbImage,
    /// Depth in metres; `None` when the dataset has no depth.
    pub depth: Option<DepthImage>,
    /// 40-class labels (255 = void).
    pub labels: LabelImage,
}

/// A NYUv2 dataset: a folder in one of the PNG layouts (894-class labels are mapped with
/// the folder's own `nyu894_to_nyu40.csv` if it has one, else the standard table), or the
/// official `.mat` file.
#[derive(Debug, Clone)]
pub struct NyuDataset {
    /// The folder or `.mat` file.
    pub root: PathBuf,
    /// The samples, in split-list order (or all, without a split).
    pub samples: Vec<NyuSample>,
    /// Depth PNG scale, `metres = value / depth_scale` (the `.mat` file stores metres).
    pub depth_scale: f64,
    map894: Option<Vec<u8>>,
    mat: Option<NyuMat>,
    /// What every image must be ([`NyuDataset::expect_frames`]); `None`: any size, label and
    /// depth images only checked against their colour image.
    pub frame_spec: Option<FrameSpec>,
}

fn png_stems(dir: &Path) -> Result<Vec<String>> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).map_err(|e| Error::io(dir, e))? {
        let p = e.map_err(|e| Error::io(dir, e))?.path();
        if p.extension().is_some_and(|x| x.eq_ignore_ascii_case("png"))
            && let Some(s) = p.file_stem()
        {
            out.push(s.to_string_lossy().into_owned());
        }
    }
    out.sort();
    Ok(out)
}

/// Reads the 894 -> 40 class map (`id894,name894,id40,name40`, 1-based ids) as a
/// lookup from 894-class value (0 = unlabelled) to 0-based 40-class index or void.
pub(crate) fn read_894_to_40(path: impl AsRef<Path>) -> Result<Vec<u8>> {
    let path = path.as_ref();
    parse_894_to_40(&read_text(path)?, path)
}

/// The standard NYUv2 894 -> 40 mapping shipped in `datasets/meta/nyuv2`.
pub fn default_894_to_40() -> Vec<u8> {
    const CSV: &str = include_str!("../../datasets/meta/nyuv2/nyu894_to_nyu40.csv");
    // The shipped table is checked by a test, so it parses.
    parse_894_to_40(CSV, Path::new("nyu894_to_nyu40.csv")).unwrap_or_default()
}

fn parse_894_to_40(text: &str, path: &Path) -> Result<Vec<u8>> {
    let mut map = vec![VOID; 1024];
    let mut max_id = 0usize;
    for (i, line) in text.lines().enumerate().skip(1) {
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let parse = |s: &str| s.parse::<usize>().ok();
        let (Some(a), Some(b)) = (
            f.first().and_then(|s| parse(s)),
            f.get(2).and_then(|s| parse(s)),
        ) else {
            return Err(Error::parse(
                path,
                i + 1,
                "expected 'id894,name894,id40,name40'",
            ));
        };
        if a == 0 || a >= map.len() || b == 0 || b > NUM_CLASSES {
            return Err(Error::parse(
                path,
                i + 1,
                format!("ids out of range: {a} -> {b}"),
            ));
        }
        map[a] = (b - 1) as u8;
        max_id = max_id.max(a);
    }
    map.truncate(max_id + 1);
    Ok(map)
}

/// Maps 894-class ids (row-major, `width` pixels a row) to 40-class indices with `map`
/// ([`read_894_to_40`]); an id the table does not have is an error naming the pixel.
pub(crate) fn map_894_to_40(
    ids: &[u16],
    width: usize,
    map: &[u8],
) -> std::result::Result<Vec<u8>, String> {
    ids.iter()
        .enumerate()
        .map(|(k, &v)| {
            map.get(v as usize).copied().ok_or_else(|| {
                format!(
                    "label {v} at pixel ({}, {}) is not an 894-class id (0-{})",
                    k % width.max(1),
                    k / width.max(1),
                    map.len().saturating_sub(1)
                )
            })
        })
        .collect()
}

impl NyuDataset {
    /// Opens a dataset folder or `.mat` file, optionally restricted to the samples of a
    /// split list.
    pub fn open(root: impl AsRef<Path>, split: Option<&Path>) -> Result<Self> {
        let root = root.as_ref().to_path_buf();
        let mat = if root.is_dir() {
            None
        } else if root.exists() {
            // A FIFO or device is refused here, not handed to the HDF5 reader.
            crate::io::open_regular(&root, "a NYUv2 .mat file")?;
            Some(NyuMat::open(&root)?)
        } else {
            return Err(Error::invalid(&root, "no such dataset folder or .mat file"));
        };
        let mut samples = match &mat {
            Some(m) => (0..m.len())
                .map(|i| NyuSample {
                    id: NyuMat::id(i),
                    source: SampleSource::Mat(i),
                })
                .collect(),
            None if root.join("rgb").is_dir() && root.join("labels").is_dir() => {
                Self::folder_layout(&root)?
            }
            None => Self::flat_layout(&root)?,
        };
        if samples.is_empty() {
            return Err(Error::invalid(
                &root,
                match mat {
                    Some(_) => "the file holds no image",
                    None => {
                        "no samples found: expected rgb/ + labels/ folders, or <id>_rgb.png + <id>_seg40.png files"
                    }
                },
            ));
        }
        if let Some(split) = split {
            samples = Self::apply_split(samples, split)?;
        }
        let needs_map = |s: &NyuSample| {
            matches!(
                s.source,
                SampleSource::Png {
                    labels_894: true,
                    ..
                }
            )
        };
        let map894 = if samples.iter().any(needs_map) {
            let candidates = [
                root.join("nyu894_to_nyu40.csv"),
                PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                    .join("datasets/meta/nyuv2/nyu894_to_nyu40.csv"),
            ];
            let p = candidates.iter().find(|p| p.is_file()).ok_or_else(|| {
                Error::invalid(
                    &root,
                    "894-class labels found but no nyu894_to_nyu40.csv to map them",
                )
            })?;
            Some(read_894_to_40(p)?)
        } else {
            None
        };
        Ok(NyuDataset {
            root,
            samples,
            depth_scale: 5000.0,
            map894,
            mat,
            frame_spec: None,
        })
    }

    fn folder_layout(root: &Path) -> Result<Vec<NyuSample>> {
        let mut out = Vec::new();
        for id in png_stems(&root.join("rgb"))? {
            let labels = root.join("labels").join(format!("{id}.png"));
            if !labels.is_file() {
                continue;
            }
            let depth = root.join("depth").join(format!("{id}.png"));
            out.push(NyuSample {
                source: SampleSource::Png {
                    rgb: root.join("rgb").join(format!("{id}.png")),
                    depth: depth.is_file().then_some(depth),
                    labels,
                    labels_894: false,
                },
                id,
            });
        }
        Ok(out)
    }

    fn flat_layout(root: &Path) -> Result<Vec<NyuSample>> {
        let stems = png_stems(root)?;
        let has = |s: &str| stems.binary_search_by(|x| x.as_str().cmp(s)).is_ok();
        let mut out = Vec::new();
        for stem in &stems {
            let (id, rgb) = if let Some(id) = stem.strip_suffix("_rgb") {
                (id.to_string(), root.join(format!("{stem}.png")))
            } else if !stem.contains('_') && has(&format!("{stem}_mask")) {
                (stem.clone(), root.join(format!("{stem}.png")))
            } else {
                continue;
            };
            let (labels, labels_894) = if has(&format!("{id}_seg40")) {
                (format!("{id}_seg40"), false)
            } else if has(&format!("{id}_mask")) {
                (format!("{id}_mask"), false)
            } else if has(&format!("{id}_seg894")) {
                (format!("{id}_seg894"), true)
            } else {
                continue;
            };
            let depth = has(&format!("{id}_depth")).then(|| root.join(format!("{id}_depth.png")));
            out.push(NyuSample {
                id,
                source: SampleSource::Png {
                    rgb,
                    depth,
                    labels: root.join(format!("{labels}.png")),
                    labels_894,
                },
            });
        }
        Ok(out)
    }

    fn apply_split(samples: Vec<NyuSample>, split: &Path) -> Result<Vec<NyuSample>> {
        let text = read_text(split)?;
        let key = |s: &str| {
            s.parse::<u64>()
                .map(|n| n.to_string())
                .unwrap_or_else(|_| s.to_string())
        };
        let by_key: HashMap<String, &NyuSample> = samples.iter().map(|s| (key(&s.id), s)).collect();
        let mut out = Vec::new();
        let mut missing = 0;
        for rec in records(&text) {
            match by_key.get(&key(rec.fields[0])) {
                Some(s) => out.push((*s).clone()),
                None => missing += 1,
            }
        }
        if out.is_empty() {
            return Err(Error::invalid(
                split,
                format!(
                    "split list selects no sample of the dataset ({missing} listed ids not found)"
                ),
            ));
        }
        Ok(out)
    }

    /// From now on every image is checked where it is read against `spec` (the camera's size;
    /// [`FrameSpec`]): an image of another size, channel count or bit depth is an error naming
    /// the file. Training and `eval seg` call this once they know the camera.
    pub fn expect_frames(&mut self, spec: FrameSpec) {
        self.frame_spec = Some(spec);
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether there are no samples.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Loads sample `index`, checking sizes and label values.
    pub fn load(&self, index: usize) -> Result<NyuItem> {
        let s = self.samples.get(index).ok_or_else(|| {
            Error::invalid(
                &self.root,
                format!(
                    "sample {index} out of range ({} samples)",
                    self.samples.len()
                ),
            )
        })?;
        match (&s.source, &self.mat) {
            (SampleSource::Mat(i), Some(mat)) => {
                let item = mat.load(*i)?;
                if let Some(spec) = &self.frame_spec {
                    let (w, h) = item.rgb.dimensions();
                    let header = crate::imageio::ImageHeader::of(w, h, image::ColorType::Rgb8);
                    spec.check(&self.root, FrameImage::Colour, &header)?;
                }
                Ok(item)
            }
            (SampleSource::Mat(_), None) => Err(Error::invalid(
                &self.root,
                format!("sample {} is a .mat image but this is a folder", s.id),
            )),
            (
                SampleSource::Png {
                    rgb,
                    depth,
                    labels,
                    labels_894,
                },
                _,
            ) => self.load_png(&s.id, rgb, depth.as_deref(), labels, *labels_894),
        }
    }

    fn load_png(
        &self,
        id: &str,
        rgb_path: &Path,
        depth_path: Option<&Path>,
        labels_path: &Path,
        labels_894: bool,
    ) -> Result<NyuItem> {
        let spec = self.frame_spec.as_ref();
        let rgb = match spec {
            Some(s) => s.read_colour(rgb_path)?,
            None => crate::imageio::read_rgb(rgb_path)?,
        };
        let labels = if labels_894 {
            let (width, height, ids) = LabelImage::read_png_ids(labels_path)?;
            let map = self.map894.as_deref().unwrap_or(&[]);
            let data = map_894_to_40(&ids, width as usize, map)
                .map_err(|m| Error::invalid(labels_path, m))?;
            LabelImage {
                width,
                height,
                data,
            }
        } else {
            match spec {
                Some(s) => s.read_labels(labels_path)?,
                None => LabelImage::read_classes(labels_path)?,
            }
        };
        if (labels.width, labels.height) != rgb.dimensions() {
            return Err(Error::invalid(
                labels_path,
                format!(
                    "label image is {}x{} but its RGB image is {}x{}",
                    labels.width,
                    labels.height,
                    rgb.width(),
                    rgb.height()
                ),
            ));
        }
        let depth = match depth_path {
            Some(p) => {
                let d = match spec {
                    Some(s) => s.read_depth(p, self.depth_scale)?,
                    None => DepthImage::read_png(p, self.depth_scale)?,
                };
                if (d.width, d.height) != rgb.dimensions() {
                    return Err(Error::invalid(
                        p,
                        format!(
                            "depth image is {}x{} but its RGB image is {}x{}",
                            d.width,
                            d.height,
                            rgb.width(),
                            rgb.height()
                        ),
                    ));
                }
                Some(d)
            }
            None => None,
        };
        Ok(NyuItem {
            id: id.to_string(),
            rgb,
            depth,
            labels,
        })
    }
}
