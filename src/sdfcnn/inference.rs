//! SDFCNN inference (Fig. 11): a checkpoint in, 40-class labels and metric depth at the input
//! resolution out, with colourised images and a side-by-side figure.
//!
//! A checkpoint is a `model.bpk` (Burn's burnpack, f32 or f16 weights) with the training
//! `config.toml` beside it, whose `[network]` section describes the network. Either file, the
//! checkpoint folder, or a run folder (its newest checkpoint) can be given.
//!
//! Label colours are the NYU40 palette (`datasets/meta/nyuv2/nyu40_colormap_scannet.csv`, rows
//! 1-40 for classes 0-39; void is black); depth uses matplotlib's viridis (near = dark
//! purple, far = yellow, missing = black).

use burn::prelude::*;
use burn::store::ModuleRecord;
use image::RgbImage;
use plotters::style::colors::colormaps::ViridisRGB;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::config::NetworkConfig;
use super::validation::predictions;
use super::{PackedSdfcnn, Sdfcnn, SdfcnnConfig, SdfcnnOutput};
use crate::dataset::labels::VOID;
use crate::dataset::{DepthImage, LabelImage};
use crate::error::{Error, Result};
use crate::nn::BackendKind;
use crate::nn::trainable_params;
use crate::plot::{Panel, panels_figure};
use crate::training::RunDir;

/// Colour image of a label map (`crate::classes::colorize`).
pub fn colorize_labels(labels: &LabelImage) -> RgbImage {
    RgbImage::from_fn(labels.width, labels.height, |x, y| {
        image::Rgb(crate::classes::colorize(labels.get(x, y)))
    })
}

/// Colour image of a depth map with viridis over `[0, max]` metres (`max`: the largest valid
/// depth when `None`); missing depth is black.
pub fn colorize_depth(depth: &DepthImage, max: Option<f32>) -> RgbImage {
    let max = max
        .unwrap_or_else(|| {
            depth
                .data
                .iter()
                .copied()
                .filter(|d| d.is_finite())
                .fold(0.0, f32::max)
        })
        .max(1e-3);
    RgbImage::from_fn(depth.width, depth.height, |x, y| {
        let d = depth.data[(y * depth.width + x) as usize];
        if !(d > 0.0 && d.is_finite()) {
            return image::Rgb([0, 0, 0]);
        }
        let c = ViridisRGB::get_color_normalized(d.min(max), 0.0, max);
        image::Rgb([c.0, c.1, c.2])
    })
}

/// Classes that occur in `labels` (void excluded), ascending.
pub fn classes_present(labels: &LabelImage) -> Vec<u8> {
    let mut seen = [false; 256];
    for &l in &labels.data {
        seen[l as usize] = true;
    }
    (0..255u8)
        .filter(|&l| seen[l as usize] && l != VOID)
        .collect()
}

/// Writes the figure `RGB | labels | depth` (a second row with the ground truth when given),
/// with a legend of the classes present.
pub fn save_figure(
    path: impl AsRef<Path>,
    rgb: &RgbImage,
    pred: &Prediction,
    gt: Option<(&LabelImage, Option<&DepthImage>)>,
) -> Result<()> {
    let mut max = pred
        .depth
        .data
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .fold(0.0, f32::max);
    if let Some((_, Some(d))) = gt {
        max = max.max(d.data.iter().copied().fold(0.0, f32::max));
    }
    let labels = colorize_labels(&pred.labels);
    let depth = colorize_depth(&pred.depth, Some(max));
    let mut images = vec![
        ("input", rgb.clone()),
        ("SDFCNN labels", labels),
        ("SDFCNN depth", depth),
    ];
    let mut classes = classes_present(&pred.labels);
    if let Some((l, d)) = gt {
        images.push(("", RgbImage::from_pixel(1, 1, image::Rgb([255, 255, 255]))));
        images.push(("ground-truth labels", colorize_labels(l)));
        if let Some(d) = d {
            images.push(("ground-truth depth", colorize_depth(d, Some(max))));
        }
        classes.extend(classes_present(l));
        classes.sort_unstable();
        classes.dedup();
    }
    let panels: Vec<Panel<'_>> = images
        .iter()
        .map(|(title, image)| Panel { title, image })
        .collect();
    let legend: Vec<(String, [u8; 3])> = classes
        .iter()
        .filter_map(|&c| {
            Some((
                crate::classes::name(c)?.to_string(),
                crate::classes::colorize(c),
            ))
        })
        .collect();
    panels_figure(path, &panels, 3, &legend)
}

/// Loads `model_path` into `model` (f16 or f32 records are cast to the model's float type). A
/// record that does not fit is an error naming the checkpoint and the config it was read with.
pub(crate) fn load_weights(model: Sdfcnn, model_path: &Path, config_path: &Path) -> Result<Sdfcnn> {
    let record = ModuleRecord::load(model_path)
        .map_err(|e| Error::invalid(model_path, format!("cannot read the checkpoint: {e}")))?;
    let model = model
        .try_load_record(record.cast_to_module_dtype())
        .map_err(|e| {
            Error::invalid(
                model_path,
                format!(
                    "checkpoint does not fit the network configured in {}: {e}",
                    config_path.display()
                ),
            )
        })?;
    crate::nn::weights::check_finite_weights(&model, model_path)?;
    Ok(model)
}

/// Locates `model.bpk` and its `config.toml` from a file, checkpoint folder or run folder.
pub(crate) fn locate_checkpoint(path: &Path) -> Result<(PathBuf, PathBuf)> {
    let model = if path.is_file() {
        path.to_path_buf()
    } else if path.join("model.bpk").is_file() {
        path.join("model.bpk")
    } else if path.is_dir() {
        let run = RunDir {
            root: path.to_path_buf(),
            keep: 0,
        };
        match run.latest()? {
            Some(c) => c.model_path(),
            None => {
                return Err(Error::invalid(
                    path,
                    "no model.bpk and no checkpoints/last.json in this folder",
                ));
            }
        }
    } else {
        return Err(Error::invalid(path, "checkpoint not found"));
    };
    let dir = model.parent().unwrap_or(Path::new("."));
    let config = dir.join("config.toml");
    if !config.is_file() {
        return Err(Error::invalid(
            &model,
            format!(
                "no config.toml beside the checkpoint (looked for {})",
                config.display()
            ),
        ));
    }
    Ok((model, config))
}

/// The network section of a checkpoint's `config.toml` (the training config).
pub fn read_network_config(config_path: &Path) -> Result<SdfcnnConfig> {
    Ok(read_network_section(config_path)?.to_config())
}

/// The `[network]` section of a checkpoint's `config.toml`, with `depth_focal`.
pub(crate) fn read_network_section(config_path: &Path) -> Result<NetworkConfig> {
    let text = crate::io::read_text(config_path)?;
    let table: toml::Table =
        toml::from_str(&text).map_err(|e| crate::camera::toml_error(config_path, &text, e))?;
    match table.get("model").and_then(|m| m.as_str()) {
        Some("sdfcnn") | None => {}
        Some(other) => {
            return Err(Error::invalid(
                config_path,
                format!("model = \"{other}\": not an SDFCNN checkpoint"),
            ));
        }
    }
    let net: NetworkConfig = match table.get("network") {
        Some(v) => v.clone().try_into().map_err(|e: toml::de::Error| {
            Error::invalid(config_path, format!("[network]: {}", e.message()))
        })?,
        None => NetworkConfig::default(),
    };
    if let Some(f) = net.depth_focal
        && !(f > 0.05 && f < 20.0)
    {
        return Err(Error::invalid(
            config_path,
            format!("[network] depth_focal {f} must be a focal length in image widths (0.05..20)"),
        ));
    }
    Ok(net)
}

/// One image's predictions at its resolution.
#[derive(Debug, Clone, PartialEq)]
pub struct Prediction {
    /// Argmax class per pixel.
    pub labels: LabelImage,
    /// Depth in metres.
    pub depth: DepthImage,
}

/// The packed network on the CPU backends (2-3x Burn's kernels there); `None` on GPUs or for
/// a network the packed layers do not cover (an odd inner size).
fn pack_on_cpu(model: &Sdfcnn, device: &Device) -> Option<PackedSdfcnn> {
    crate::nn::backend::is_cpu(device)
        .then(|| PackedSdfcnn::new(model).ok())
        .flatten()
}

/// A loaded SDFCNN for inference.
#[derive(Debug)]
pub struct SdfcnnPredictor {
    model: Sdfcnn,
    device: Device,
    /// The network configuration.
    pub config: SdfcnnConfig,
    /// The canonical camera's focal length in image widths (`[network] depth_focal`): depth is
    /// scaled from it to the camera given to [`Self::predict_for_camera`]. `None`: as predicted.
    pub depth_focal: Option<f64>,
    /// The weights file.
    pub checkpoint: PathBuf,
    /// On a CPU backend, the network packed for inference ([`PackedSdfcnn`]), made when the
    /// predictor is built.
    packed: Option<PackedSdfcnn>,
}

impl SdfcnnPredictor {
    /// Loads a checkpoint (`model.bpk`, its folder, or a run folder) on `backend`.
    pub fn load(path: &Path, backend: BackendKind) -> Result<Self> {
        let (model_path, config_path) = locate_checkpoint(path)?;
        let network = read_network_section(&config_path)?;
        let config = network.to_config();
        let device = backend.device()?;
        let model = config
            .init(&device)
            .map_err(|e| Error::invalid(&config_path, e.to_string()))?;
        let model = load_weights(model, &model_path, &config_path)?;
        Ok(SdfcnnPredictor {
            packed: pack_on_cpu(&model, &device),
            model,
            device,
            config,
            depth_focal: network.depth_focal,
            checkpoint: model_path,
        })
    }

    /// Wraps a model (e.g. a freshly initialised one).
    pub fn from_model(model: Sdfcnn, config: SdfcnnConfig, device: Device) -> Self {
        SdfcnnPredictor {
            packed: pack_on_cpu(&model, &device),
            model,
            device,
            config,
            depth_focal: None,
            checkpoint: PathBuf::new(),
        }
    }

    /// Trainable parameters.
    pub fn num_params(&self) -> usize {
        trainable_params(&self.model)
    }

    /// The model.
    pub fn model(&self) -> &Sdfcnn {
        &self.model
    }

    /// Outputs (logits, depth) for a batch `[N, 3, H, W]` in `[0, 1]`, at its resolution.
    pub fn forward(&self, images: Tensor<4>) -> Result<SdfcnnOutput> {
        self.model.forward(images).map_err(Error::from)
    }

    /// Labels and depth of one RGB image at its resolution, with the seconds the network and
    /// the argmax took (decoding excluded).
    pub fn predict_timed(&self, rgb: &RgbImage) -> Result<(Prediction, f64)> {
        let (w, h) = rgb.dimensions();
        let (labels, depth, seconds) = match &self.packed {
            Some(packed) => {
                let hwc: Vec<f32> = rgb.as_raw().iter().map(|&v| v as f32 / 255.0).collect();
                let started = Instant::now();
                let (labels, depth) = packed
                    .predict(&hwc, [h as usize, w as usize])
                    .map_err(Error::wrap)?;
                (labels, depth, started.elapsed().as_secs_f64())
            }
            None => {
                let images = image_tensor(rgb, &self.device);
                let started = Instant::now();
                let (labels, depth) = predictions(self.forward(images)?)?;
                (labels, depth, started.elapsed().as_secs_f64())
            }
        };
        Ok((
            Prediction {
                labels: LabelImage {
                    width: w,
                    height: h,
                    data: labels,
                },
                depth: DepthImage {
                    width: w,
                    height: h,
                    data: depth,
                },
            },
            seconds,
        ))
    }

    /// Labels and depth of one RGB image at its resolution.
    pub fn predict(&self, rgb: &RgbImage) -> Result<Prediction> {
        Ok(self.predict_timed(rgb)?.0)
    }

    /// Labels and metric depth of one RGB image taken by a camera of horizontal focal length
    /// `fx` pixels (at the image's resolution): the network's canonical-camera depth scaled by
    /// `(fx / width) / depth_focal` ([`super::focal`]). Without `fx`, or for a network without
    /// `depth_focal`, the depth is as predicted.
    pub fn predict_for_camera(&self, rgb: &RgbImage, fx: Option<f64>) -> Result<Prediction> {
        Ok(self.predict_timed_for_camera(rgb, fx)?.0)
    }

    /// [`Self::predict_for_camera`] with the seconds of [`Self::predict_timed`].
    pub fn predict_timed_for_camera(
        &self,
        rgb: &RgbImage,
        fx: Option<f64>,
    ) -> Result<(Prediction, f64)> {
        let (mut p, seconds) = self.predict_timed(rgb)?;
        let k = self.depth_scale_for(fx, rgb.width());
        if k != 1.0 {
            p.depth.data.iter_mut().for_each(|d| *d *= k);
        }
        Ok((p, seconds))
    }

    /// The factor [`Self::predict_for_camera`] applies to the predicted depth.
    pub fn depth_scale_for(&self, fx: Option<f64>, width: u32) -> f32 {
        match (self.depth_focal, fx) {
            (Some(canonical), Some(fx)) if width > 0 => {
                (1.0 / super::focal::to_canonical(canonical, fx, width as f64, 1.0)) as f32
            }
            _ => 1.0,
        }
    }

    /// Saves the weights as f16 burnpack (half the size), atomically; [`Self::load`] reads
    /// it back into the f32 network.
    pub fn save_f16(&self, path: &Path) -> Result<()> {
        crate::nn::weights::save_f16(self.model.clone(), path)
    }
}

/// `[1, 3, H, W]` tensor of an 8-bit RGB image scaled to `[0, 1]`.
pub fn image_tensor(rgb: &RgbImage, device: &Device) -> Tensor<4> {
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let n = w * h;
    let mut planar = vec![0f32; 3 * n];
    for (i, p) in rgb.pixels().enumerate() {
        for c in 0..3 {
            planar[c * n + i] = p[c] as f32 / 255.0;
        }
    }
    Tensor::from_data(TensorData::new(planar, [1, 3, h, w]), device)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("sdf_infer_{name}_{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("temp dir");
        d
    }

    #[test]
    fn labels_and_depth_are_coloured() {
        let mut l = LabelImage::new(2, 1, VOID);
        l.data[1] = 1;
        let c = colorize_labels(&l);
        assert_eq!(
            (c.get_pixel(0, 0).0, c.get_pixel(1, 0).0),
            ([0, 0, 0], [152, 223, 138])
        );
        assert_eq!(classes_present(&l), vec![1]);
        let mut d = DepthImage::new(3, 1);
        d.data = vec![0.0, 1.0, 2.0];
        let c = colorize_depth(&d, None);
        assert_eq!(c.get_pixel(0, 0).0, [0, 0, 0]);
        assert_ne!(c.get_pixel(1, 0).0, c.get_pixel(2, 0).0);
    }

    #[test]
    fn predictor_roundtrip_f32_and_f16_with_figure() {
        let dir = tmp("roundtrip");
        let config = SdfcnnConfig::new()
            .with_inner_size([32, 48])
            .with_decoder_dim(16)
            .with_crp_stages(1);
        let device = BackendKind::Ndarray.device().expect("ndarray");
        let model = crate::nn::seeded_init(config.init(&device).expect("valid"), 5);
        model
            .clone()
            .save_file(dir.join("model.bpk"))
            .expect("save");
        std::fs::write(
            dir.join("config.toml"),
            "model = \"sdfcnn\"\n[network]\ninner_size = [32, 48]\ndecoder_dim = 16\ncrp_stages = 1\n",
        )
        .expect("config");
        let rgb = RgbImage::from_fn(40, 30, |x, y| {
            image::Rgb([(x * 6) as u8, (y * 8) as u8, 90])
        });
        let a = SdfcnnPredictor::load(&dir, BackendKind::Ndarray).expect("load");
        let pa = a.predict(&rgb).expect("predict");
        assert_eq!((pa.labels.width, pa.labels.height), (40, 30));
        assert!(pa.labels.data.iter().all(|&l| l < 40));
        let direct = SdfcnnPredictor::from_model(model, config, device)
            .predict(&rgb)
            .expect("predict");
        assert_eq!(direct, pa);

        // f16 weights load into the f32 network and predict nearly the same depth.
        let half = dir.join("half");
        std::fs::create_dir_all(&half).expect("dir");
        a.save_f16(&half.join("model.bpk")).expect("save f16");
        std::fs::copy(dir.join("config.toml"), half.join("config.toml")).expect("copy");
        let small = std::fs::metadata(half.join("model.bpk"))
            .expect("f16")
            .len();
        let big = std::fs::metadata(dir.join("model.bpk")).expect("f32").len();
        assert!(small * 10 < big * 6, "{small} vs {big}");
        let b =
            SdfcnnPredictor::load(&half.join("model.bpk"), BackendKind::Flex).expect("load f16");
        let pb = b.predict(&rgb).expect("predict");
        let err = pa
            .depth
            .data
            .iter()
            .zip(&pb.depth.data)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        let scale = pa.depth.data.iter().map(|x| x.abs()).fold(0.0, f32::max);
        assert!(err <= 0.05 * scale.max(1e-3), "{err} vs {scale}");

        save_figure(
            dir.join("fig.png"),
            &rgb,
            &pa,
            Some((&pa.labels, Some(&pa.depth))),
        )
        .expect("figure");
        assert!(dir.join("fig.png").is_file());

        // A config that does not match the weights: both files named.
        std::fs::write(
            dir.join("config.toml"),
            "model = \"sdfcnn\"\n[network]\ninner_size = [32, 48]\ndecoder_dim = 8\n",
        )
        .expect("config");
        let e = SdfcnnPredictor::load(&dir, BackendKind::Flex)
            .expect_err("mismatch")
            .to_string();
        assert!(e.contains("model.bpk") && e.contains("config.toml"), "{e}");
        std::fs::write(dir.join("config.toml"), "model = \"fpfdcnn\"\n").expect("config");
        let e = SdfcnnPredictor::load(&dir, BackendKind::Flex)
            .expect_err("other model")
            .to_string();
        assert!(e.contains("not an SDFCNN"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
