//! Where a keyframe's semantic labels (and, in monocular mode, its depth) come
//! from (section IV-C step 1): SDFCNN, which predicts both from the RGB image
//! in one forward pass ([`SdfcnnSource`]); the ground-truth labels (and exact
//! depth) of a synthetic sequence ([`GroundTruthSource`], a "perfect SDFCNN"
//! for tests); or none ([`NoLabels`]).
//!
//! The mapping stage calls [`SemanticSource::predict`] once per keyframe and
//! uses the result twice: the labels (and predicted depth) are fused into the
//! map, and in monocular mode the predicted depth gives the keyframe's 3D
//! keypoints, which tracking uses as the reference for PnP (eqs 9-10). Only
//! keyframes are ever references (the previous frame's 3D points are the PnP
//! inliers' map points), so SDFCNN runs exactly once per keyframe and on no
//! other frame.

use crate::dataset::{DepthImage, LabelImage};
use crate::error::{Error, Result};
use crate::io::{parse_f64, read_text, records};
use crate::nn::BackendKind;
use crate::sdfcnn::SdfcnnPredictor;
use image::RgbImage;
use std::path::{Path, PathBuf};

/// What a source sees of a keyframe: the RGB image, and the frame's identity
/// for sources that read per-frame files (ground truth).
#[derive(Debug, Clone, Copy)]
pub struct SemanticInput<'a> {
    /// Index of the frame in the sequence.
    pub index: usize,
    /// Time stamp of the frame, seconds.
    pub stamp: f64,
    /// The frame's colour image.
    pub rgb: &'a RgbImage,
}

/// Labels (NYU40, 0-based, 255 = void) and optionally metric depth for an image.
pub trait SemanticSource: Send {
    /// Short name for reports.
    fn name(&self) -> &'static str;
    /// Whether `predict` returns depth (required by monocular mode).
    fn provides_depth(&self) -> bool;
    /// Labels and depth, both at the RGB image's size.
    fn predict(&self, input: &SemanticInput<'_>) -> Result<(LabelImage, Option<DepthImage>)>;
}

/// No semantics: every pixel void, the map is coloured by RGB only.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoLabels;

impl SemanticSource for NoLabels {
    fn name(&self) -> &'static str {
        "none"
    }

    fn provides_depth(&self) -> bool {
        false
    }

    fn predict(&self, input: &SemanticInput<'_>) -> Result<(LabelImage, Option<DepthImage>)> {
        let (w, h) = input.rgb.dimensions();
        Ok((LabelImage::new(w, h, crate::dataset::labels::VOID), None))
    }
}

/// SDFCNN (Table 13): NYU40 labels and metric depth of the keyframe's RGB
/// image, both at the image's resolution, from one forward pass.
#[derive(Debug)]
pub struct SdfcnnSource {
    /// The loaded network.
    pub predictor: SdfcnnPredictor,
    /// The camera's horizontal focal length in pixels: depth is scaled from the network's
    /// canonical camera to it (`crate::sdfcnn::focal`). `None`: depth as predicted.
    pub fx: Option<f64>,
}

/// Classes of the semantic map (NYU40).
const MAP_CLASSES: usize = 40;

impl SdfcnnSource {
    /// Loads a checkpoint (`model.bpk` in f32 or f16, its folder, or a
    /// training run folder) on `backend`. Weights that do not fit the network
    /// described by the `config.toml` beside them, a checkpoint of another
    /// network, or a network whose classes are not the map's NYU40 are errors.
    pub fn load(path: &Path, backend: BackendKind) -> Result<Self> {
        let predictor = SdfcnnPredictor::load(path, backend)?;
        Self::new(predictor)
    }

    /// Wraps a loaded predictor (an error unless it predicts NYU40 classes).
    pub fn new(predictor: SdfcnnPredictor) -> Result<Self> {
        let classes = predictor.config.num_classes;
        if classes != MAP_CLASSES {
            return Err(Error::invalid(
                &predictor.checkpoint,
                format!(
                    "this SDFCNN predicts {classes} classes; the semantic map uses the \
                     {MAP_CLASSES} NYUv2 classes"
                ),
            ));
        }
        Ok(SdfcnnSource {
            predictor,
            fx: None,
        })
    }

    /// Metric depth for the camera that takes the sequence (its `fx` at the images' size).
    pub fn with_camera(mut self, camera: &crate::camera::Camera) -> Self {
        self.fx = Some(camera.fx);
        self
    }
}

impl SemanticSource for SdfcnnSource {
    fn name(&self) -> &'static str {
        "sdfcnn"
    }

    fn provides_depth(&self) -> bool {
        true
    }

    fn predict(&self, input: &SemanticInput<'_>) -> Result<(LabelImage, Option<DepthImage>)> {
        let p = self
            .predictor
            .predict_for_camera(input.rgb, self.fx)
            .map_err(|e| {
                Error::msg(format!(
                    "frame {}: SDFCNN inference failed: {e}",
                    input.index
                ))
            })?;
        Ok((p.labels, Some(p.depth)))
    }
}

/// A `timestamp filename` list of a sequence folder, searchable by stamp.
#[derive(Debug, Clone, PartialEq)]
pub struct StampedFiles {
    /// Path of the list file.
    pub list: PathBuf,
    /// `(stamp in seconds, file path)` entries sorted by stamp.
    pub entries: Vec<(f64, PathBuf)>,
}

impl StampedFiles {
    /// Reads `root/<name>`; `None` when the file does not exist.
    pub fn open(root: &Path, name: &str) -> Result<Option<Self>> {
        let list = root.join(name);
        if !list.is_file() {
            return Ok(None);
        }
        let text = read_text(&list)?;
        let mut entries: Vec<(f64, PathBuf)> = Vec::new();
        for rec in records(&text) {
            if rec.fields.len() < 2 {
                return Err(Error::parse(
                    &list,
                    rec.line,
                    "expected 'timestamp filename'",
                ));
            }
            let t = parse_f64(&list, rec.line, "timestamp", rec.fields[0])?;
            entries.push((t, root.join(rec.fields[1])));
        }
        entries.sort_by(|a, b| a.0.total_cmp(&b.0));
        Ok(Some(StampedFiles { list, entries }))
    }

    /// The file whose stamp is nearest to `stamp`, within `max_diff` seconds.
    pub fn nearest(&self, stamp: f64, max_diff: f64) -> Option<&Path> {
        let k = self.entries.partition_point(|e| e.0 < stamp);
        [k.checked_sub(1), Some(k)]
            .into_iter()
            .flatten()
            .filter_map(|i| self.entries.get(i))
            .filter(|e| (e.0 - stamp).abs() <= max_diff)
            .min_by(|a, b| (a.0 - stamp).abs().total_cmp(&(b.0 - stamp).abs()))
            .map(|e| e.1.as_path())
    }
}

/// Ground-truth labels of a synthetic sequence (`labels.txt` + `labels/`), and
/// its exact depth (`depth_gt.txt` + `depth_gt/`) when present, as a "perfect
/// SDFCNN" for testing the monocular path.
#[derive(Debug, Clone)]
pub struct GroundTruthSource {
    /// The sequence's `labels.txt` list.
    pub labels: StampedFiles,
    /// The sequence's `depth_gt.txt` list, when it has exact depth.
    pub depth: Option<StampedFiles>,
    /// Depth PNG value per metre (`metres = value / depth_scale`).
    pub depth_scale: f64,
    /// Largest stamp difference accepted when looking up a file, seconds.
    pub max_diff: f64,
}

impl GroundTruthSource {
    /// Opens a sequence folder's label list; an error when it has none.
    pub fn open(root: &Path, depth_scale: f64) -> Result<Self> {
        let labels = StampedFiles::open(root, "labels.txt")?.ok_or_else(|| {
            Error::invalid(
                root,
                "no labels.txt: ground-truth labels (--labels gt) need a synthetic sequence with labels/",
            )
        })?;
        Ok(GroundTruthSource {
            labels,
            depth: StampedFiles::open(root, "depth_gt.txt")?,
            depth_scale,
            max_diff: 0.02,
        })
    }

    /// The label image of a stamp.
    pub fn labels_at(&self, stamp: f64) -> Result<LabelImage> {
        let path = self.labels.nearest(stamp, self.max_diff).ok_or_else(|| {
            Error::invalid(
                &self.labels.list,
                format!("no label image within {} s of {stamp:.6}", self.max_diff),
            )
        })?;
        LabelImage::read_classes(path)
    }

    /// The exact depth of a stamp, if the sequence has exact depth.
    pub fn depth_at(&self, stamp: f64) -> Result<Option<DepthImage>> {
        let Some(list) = &self.depth else {
            return Ok(None);
        };
        let path = list.nearest(stamp, self.max_diff).ok_or_else(|| {
            Error::invalid(
                &list.list,
                format!("no depth image within {} s of {stamp:.6}", self.max_diff),
            )
        })?;
        DepthImage::read_png(path, self.depth_scale).map(Some)
    }
}

impl SemanticSource for GroundTruthSource {
    fn name(&self) -> &'static str {
        "gt"
    }

    fn provides_depth(&self) -> bool {
        self.depth.is_some()
    }

    fn predict(&self, input: &SemanticInput<'_>) -> Result<(LabelImage, Option<DepthImage>)> {
        let labels = self.labels_at(input.stamp)?;
        let size = input.rgb.dimensions();
        if (labels.width, labels.height) != size {
            return Err(Error::msg(format!(
                "frame {}: label image is {}x{} but the RGB image is {}x{}",
                input.index, labels.width, labels.height, size.0, size.1
            )));
        }
        let depth = self.depth_at(input.stamp)?;
        if let Some(d) = &depth
            && (d.width, d.height) != size
        {
            return Err(Error::msg(format!(
                "frame {}: exact depth image is {}x{} but the RGB image is {}x{}",
                input.index, d.width, d.height, size.0, size.1
            )));
        }
        Ok((labels, depth))
    }
}
