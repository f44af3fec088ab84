//! Scaffolding shared by the integration tests (each test file that needs it says
//! `mod common;`).
#![allow(dead_code)]

pub use sdf_slam::io::ScratchDir;
use sdf_slam::nn::BackendKind;
use sdf_slam::sdfcnn::{Sdfcnn, SdfcnnConfig, SdfcnnPredictor};
use std::path::{Path, PathBuf};

/// A path under the system's temporary folder unique to this test process,
/// `sdf_<group>_<name>_<pid>`, with nothing there (an earlier run's leftovers removed);
/// removed with what the test wrote there when it goes out of scope.
pub fn fresh_path(group: &str, name: &str) -> ScratchDir {
    ScratchDir::unmade(&format!("{group}_{name}"))
}

/// Like [`fresh_path`], the folder created empty.
pub fn fresh_dir(group: &str, name: &str) -> ScratchDir {
    ScratchDir::new(&format!("{group}_{name}")).unwrap()
}

/// A folder for fixtures a whole test binary shares (built once behind a `OnceLock`, whose
/// value is never dropped): `<target>/tmp/<name>`, emptied when first asked for in a run, so
/// repeated runs reuse one folder instead of leaving one each behind.
pub fn shared_dir(name: &str) -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The crate's root folder.
pub fn manifest_dir() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// The training config of [`tiny_sdfcnn_config`], as a checkpoint's `config.toml`.
pub const TINY_SDFCNN_TOML: &str =
    "model = \"sdfcnn\"\n[network]\ninner_size = [32, 48]\ndecoder_dim = 16\ncrp_stages = 1\n";

/// A tiny SDFCNN (32x48 inside, decoder 16, one CRP stage) for tests.
pub fn tiny_sdfcnn_config() -> SdfcnnConfig {
    SdfcnnConfig::new()
        .with_inner_size([32, 48])
        .with_decoder_dim(16)
        .with_crp_stages(1)
}

/// Writes `model` (built from [`tiny_sdfcnn_config`] on ndarray) as a checkpoint folder
/// in half precision, as the bundled weights are: `dir/model.bpk` + `dir/config.toml`.
pub fn write_tiny_sdfcnn(dir: &Path, model: Sdfcnn) {
    std::fs::create_dir_all(dir).unwrap();
    // (f16 tensors live on flex: ndarray has none.)
    SdfcnnPredictor::from_model(
        model,
        tiny_sdfcnn_config(),
        BackendKind::Ndarray.device().expect("ndarray"),
    )
    .save_f16(&dir.join("model.bpk"))
    .unwrap();
    std::fs::write(dir.join("config.toml"), TINY_SDFCNN_TOML).unwrap();
}

/// Writes frame `i` of `seq` as the 7-Scenes files of `stem`: `STEM.color.png` (copied),
/// `STEM.depth.png` (millimetres, `no_reading` where the sensor has none) and `STEM.pose.txt`
/// (the ground-truth pose as a 4x4 matrix). Returns the pose written.
pub fn write_seven_scenes_frame(
    seq: &sdf_slam::dataset::TumSequence,
    i: usize,
    stem: &Path,
    no_reading: u16,
) -> sdf_slam::geometry::Pose {
    let frame = seq.load_frame(i).unwrap();
    std::fs::copy(
        &seq.frames[i].rgb_path,
        format!("{}.color.png", stem.display()),
    )
    .unwrap();
    let depth = frame.depth.unwrap();
    let mm: Vec<u16> = depth
        .data
        .iter()
        .map(|&z| {
            if z > 0.0 {
                (z as f64 * 1000.0).round() as u16
            } else {
                no_reading
            }
        })
        .collect();
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(depth.width, depth.height, mm)
        .unwrap()
        .save(format!("{}.depth.png", stem.display()))
        .unwrap();
    let pose = frame.gt_pose.unwrap();
    let m = pose.to_homogeneous();
    let text: String = (0..4)
        .map(|r| {
            let row: Vec<String> = (0..4).map(|c| format!("{:.9e}", m[(r, c)])).collect();
            row.join("\t") + "\n"
        })
        .collect();
    std::fs::write(format!("{}.pose.txt", stem.display()), text).unwrap();
    pose
}

/// SDFCNN training targets for `n` images of `h` x `w` on `device`: labels cycling through the
/// 40 classes with every 7th pixel void (255), and depth 0.5-2.95 m with every 11th pixel
/// missing (0).
pub fn sdfcnn_targets(
    n: usize,
    h: usize,
    w: usize,
    device: &burn::prelude::Device,
) -> (
    burn::prelude::Tensor<3, burn::prelude::Int>,
    burn::prelude::Tensor<4>,
) {
    use burn::prelude::*;
    let labels: Vec<i64> = (0..n * h * w)
        .map(|i| if i % 7 == 0 { 255 } else { (i % 40) as i64 })
        .collect();
    let depth: Vec<f32> = (0..n * h * w)
        .map(|i| {
            if i % 11 == 0 {
                0.0
            } else {
                0.5 + (i % 50) as f32 / 20.0
            }
        })
        .collect();
    (
        Tensor::from_data(TensorData::new(labels, [n, h, w]), device),
        Tensor::from_data(TensorData::new(depth, [n, 1, h, w]), device),
    )
}

/// The GPU backends this build has, with a device here; each that finds none is reported and
/// skipped, unless `SDF_SLAM_REQUIRE_GPU=1` makes that a failure (the device checks in the
/// docs set it).
pub fn gpu_devices() -> Vec<(BackendKind, burn::prelude::Device)> {
    let require = std::env::var("SDF_SLAM_REQUIRE_GPU").is_ok_and(|v| v == "1");
    let mut found = Vec::new();
    for b in BackendKind::ALL
        .into_iter()
        .filter(|b| b.is_gpu() && b.is_compiled())
    {
        match b.device() {
            Ok(d) => found.push((b, d)),
            Err(e) if require => panic!("SDF_SLAM_REQUIRE_GPU=1: {e}"),
            Err(e) => eprintln!("skipped: {e}"),
        }
    }
    found
}

/// Every layer a trace recorded, by name, with its values (empty where it kept none).
pub fn traced_layers(trace: &sdf_slam::nn::ShapeTrace) -> Vec<(String, Vec<f32>)> {
    trace
        .layers()
        .iter()
        .map(|l| (l.name.clone(), l.values.clone().unwrap_or_default()))
        .collect()
}
