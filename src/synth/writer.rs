//! Output files. Everything is written atomically (temp file + rename).

use super::config::SynthConfig;
use crate::classes::{self, NUM_CLASSES, VOID};
use crate::dataset::DepthImage;
use crate::error::{Error, Result};
use crate::imageio::write_png_atomic;
use crate::io::{write_atomic, write_atomic_with};
use image::{DynamicImage, GrayImage, RgbImage};
use serde_json::{Value, json};
use std::io::Write;
use std::path::Path;

/// Depth PNG value per metre (TUM RGB-D and the NYU PNG conversions).
pub(crate) const DEPTH_SCALE: f64 = 5000.0;

/// Creates the output folder and checks that files can be written in it.
pub(crate) fn prepare_out(out: &Path) -> Result<()> {
    if out.exists() && !out.is_dir() {
        return Err(Error::invalid(
            out,
            "output path exists and is not a folder",
        ));
    }
    std::fs::create_dir_all(out).map_err(|e| {
        Error::msg(format!(
            "cannot create output folder {}: {e}",
            out.display()
        ))
    })?;
    let probe = out.join(".synth_write_test");
    write_atomic(&probe, b"ok").map_err(|e| {
        Error::msg(format!(
            "output folder {} is not writable: {e}",
            out.display()
        ))
    })?;
    std::fs::remove_file(&probe).map_err(|e| Error::io(&probe, e))
}

/// Pixel counts per label: 40 classes, then void.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Histogram(pub [u64; NUM_CLASSES + 1]);

impl Default for Histogram {
    fn default() -> Self {
        Histogram([0; NUM_CLASSES + 1])
    }
}

impl Histogram {
    /// Counts every pixel of a label image (values past the classes count as void).
    pub fn add_image(&mut self, labels: &GrayImage) {
        for p in labels.pixels() {
            let l = p.0[0];
            let k = if (l as usize) < NUM_CLASSES {
                l as usize
            } else {
                NUM_CLASSES
            };
            self.0[k] += 1;
        }
    }

    /// Adds another histogram's counts.
    pub fn add(&mut self, other: &Histogram) {
        for (a, b) in self.0.iter_mut().zip(other.0.iter()) {
            *a += b;
        }
    }

    /// Number of the 40 classes with at least one pixel.
    pub fn classes_present(&self) -> usize {
        self.0[..NUM_CLASSES].iter().filter(|&&c| c > 0).count()
    }

    /// JSON: `[{label, name, pixels}]` for every label with pixels.
    pub fn to_json(&self) -> Value {
        let rows: Vec<Value> = self
            .0
            .iter()
            .enumerate()
            .filter(|(_, c)| **c > 0)
            .map(|(k, &c)| {
                let l = if k < NUM_CLASSES { k as u8 } else { VOID };
                json!({"label": l, "name": classes::name(l), "pixels": c})
            })
            .collect();
        Value::Array(rows)
    }
}

/// The images of one frame.
pub struct FrameFiles {
    /// The rendered colour image.
    pub rgb: RgbImage,
    /// The sensor-model depth, metres (written to `depth/`).
    pub depth: DepthImage,
    /// The exact depth, metres (written to `depth_gt/` when present).
    pub depth_gt: Option<DepthImage>,
    /// NYU40 labels (0-39, 255 = void).
    pub labels: GrayImage,
    /// Also write the labels in the class palette to `labels_color/`.
    pub color_labels: bool,
}

impl FrameFiles {
    /// Writes `rgb/NAME.png`, `depth/NAME.png`, `labels/NAME.png` (and
    /// `depth_gt/`, `labels_color/` when asked) under `dir`.
    pub fn write(&self, dir: &Path, name: &str) -> Result<()> {
        let file = format!("{name}.png");
        write_png_atomic(
            dir.join("rgb").join(&file),
            &DynamicImage::ImageRgb8(self.rgb.clone()),
        )?;
        self.depth
            .write_png(dir.join("depth").join(&file), DEPTH_SCALE)?;
        if let Some(gt) = &self.depth_gt {
            gt.write_png(dir.join("depth_gt").join(&file), DEPTH_SCALE)?;
        }
        write_png_atomic(
            dir.join("labels").join(&file),
            &DynamicImage::ImageLuma8(self.labels.clone()),
        )?;
        if self.color_labels {
            let c = classes::colorize_image(&self.labels);
            write_png_atomic(
                dir.join("labels_color").join(&file),
                &DynamicImage::ImageRgb8(c),
            )?;
        }
        Ok(())
    }
}

/// `rgb.txt`, `depth.txt`, `labels.txt` and `associations.txt` of a sequence.
pub(crate) fn write_lists(dir: &Path, stamps: &[String], gt_depth: bool) -> Result<()> {
    let list = |folder: &str, what: &str| -> Result<()> {
        write_atomic_with(dir.join(format!("{folder}.txt")), |w| {
            writeln!(w, "# {what}")?;
            writeln!(w, "# file: 'sdf-slam synth'")?;
            writeln!(w, "# timestamp filename")?;
            for s in stamps {
                writeln!(w, "{s} {folder}/{s}.png")?;
            }
            Ok(())
        })
    };
    list("rgb", "color images")?;
    list(
        "depth",
        "depth maps (16-bit, metres x 5000, 0 = no reading)",
    )?;
    list("labels", "NYU40 label images (8-bit, 0-based, 255 = void)")?;
    if gt_depth {
        list("depth_gt", "exact depth maps (16-bit, metres x 5000)")?;
    }
    write_atomic_with(dir.join("associations.txt"), |w| {
        for s in stamps {
            writeln!(w, "{s} rgb/{s}.png {s} depth/{s}.png")?;
        }
        Ok(())
    })
}

/// A split list: one image name per line.
pub(crate) fn write_split(path: &Path, names: &[String]) -> Result<()> {
    write_atomic_with(path, |w| {
        for n in names {
            writeln!(w, "{n}")?;
        }
        Ok(())
    })
}

/// `scene.json`: seed, full configuration, per-scene rooms and label
/// histograms; `totals` counts the sequence frames (the NYU-layout views are
/// counted in `nyu`).
pub(crate) fn scene_json(
    cfg: &SynthConfig,
    camera: &crate::camera::Camera,
    scenes: Vec<Value>,
    totals: &Histogram,
    nyu: Value,
) -> Result<Vec<u8>> {
    let v = json!({
        "generator": "sdf-slam synth",
        "version": env!("CARGO_PKG_VERSION"),
        "seed": cfg.seed,
        "config": serde_json::to_value(cfg)?,
        "camera": serde_json::to_value(camera)?,
        "label_coding": "NYU40, 0-based (0 = wall ... 39 = otherprop), 255 = void",
        "depth_scale": DEPTH_SCALE,
        "scenes": scenes,
        "label_histogram": totals.to_json(),
        "classes_in_view": totals.classes_present(),
        "label_histogram_counts": "pixels per class over all sequence frames",
        "nyu": nyu,
    });
    let mut bytes = serde_json::to_vec_pretty(&v)?;
    bytes.push(b'\n');
    Ok(bytes)
}
