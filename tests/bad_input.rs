//! Hostile input as a standing test: a corpus of malformed inputs per input kind (TUM text
//! files, images, SLAM / training / synthesis / sweep configs, camera files, checkpoints,
//! trajectories, command-line arguments) run through the binaries (`slam`, `eval`, `train`,
//! `synth`, `bench`). Every case must end in
//! a clean error: an exit code other than 0 and 101 (panic) and not a signal (abort), no
//! "panicked at" or failed allocation, a message naming the file (and its line where the
//! parser knows it), and files already in the output folder left as they were. After the
//! corpus, the largest child's peak memory stays bounded (no size from a file is
//! allocated before it is checked).

mod common;

use burn::module::{Module, ModuleMapper, Param};
use burn::prelude::*;
use sdf_slam::fpfdcnn::FpfdcnnConfig;
use sdf_slam::nn::BackendKind;
use std::path::{Path, PathBuf};
use std::process::Command;

const FIXTURE: &str = "datasets/fixtures/tum_fr1_rpy_head10";
/// A file put in each case's output folder before the run; it must survive.
const SENTINEL: &str = "written_before.txt";

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(FIXTURE)
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), &target).unwrap();
        }
    }
}

/// One malformed input.
struct Case {
    name: &'static str,
    bin: &'static str,
    args: Vec<String>,
    /// Files written into the case's folder first (relative path, contents).
    files: Vec<(&'static str, Vec<u8>)>,
    /// Prepares the folder further (a damaged copy of the fixture sequence).
    setup: Option<fn(&Path)>,
    /// Substrings the error output must contain (file names, lines, the field).
    expect: Vec<&'static str>,
}

fn case(name: &'static str, bin: &'static str, args: &[&str], expect: &[&'static str]) -> Case {
    Case {
        name,
        bin,
        args: args.iter().map(|s| s.to_string()).collect(),
        files: Vec::new(),
        setup: None,
        expect: expect.to_vec(),
    }
}

impl Case {
    fn file(mut self, path: &'static str, text: &str) -> Self {
        self.files.push((path, text.as_bytes().to_vec()));
        self
    }

    fn setup(mut self, f: fn(&Path)) -> Self {
        self.setup = Some(f);
        self
    }
}

fn bin(name: &str) -> &'static str {
    match name {
        "slam" => env!("CARGO_BIN_EXE_slam"),
        "eval" => env!("CARGO_BIN_EXE_eval"),
        "train" => env!("CARGO_BIN_EXE_train"),
        "synth" => env!("CARGO_BIN_EXE_synth"),
        "bench" => env!("CARGO_BIN_EXE_bench"),
        other => panic!("no binary {other}"),
    }
}

/// Replaces line `line` (1-based) of a text file of a copy of the fixture with garbage.
fn garble(dir: &Path, file: &str, line: usize) {
    copy_dir(&fixture(), &dir.join("seq"));
    let p = dir.join("seq").join(file);
    let text = std::fs::read_to_string(&p).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    lines[line - 1] = "garbage line".into();
    std::fs::write(&p, lines.join("\n")).unwrap();
}

/// The fixture sequence with garbage on line 3 of `associations.txt`.
fn garbage_associations(dir: &Path) {
    garble(dir, "associations.txt", 3);
}

/// The fixture sequence without `associations.txt`, and garbage on line 5 of `rgb.txt`
/// (after its three comment lines).
fn garbage_rgb_list(dir: &Path) {
    garble(dir, "rgb.txt", 5);
    std::fs::remove_file(dir.join("seq/associations.txt")).unwrap();
}

/// The fixture sequence with a NaN position on line 5 of `groundtruth.txt`.
fn nan_ground_truth(dir: &Path) {
    copy_dir(&fixture(), &dir.join("seq"));
    let p = dir.join("seq/groundtruth.txt");
    let text = std::fs::read_to_string(&p).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let stamp = lines[4].split_whitespace().next().unwrap().to_string();
    lines[4] = format!("{stamp} nan 0 0 0 0 0 1");
    std::fs::write(&p, lines.join("\n")).unwrap();
}

/// The fixture sequence whose every colour image is text, not an image.
fn corrupt_images(dir: &Path) {
    copy_dir(&fixture(), &dir.join("seq"));
    for e in std::fs::read_dir(dir.join("seq/rgb")).unwrap() {
        std::fs::write(e.unwrap().path(), b"not a png").unwrap();
    }
}

/// The fixture sequence whose every depth image reads 0 (no reading).
fn zero_depth(dir: &Path) {
    copy_dir(&fixture(), &dir.join("seq"));
    for e in std::fs::read_dir(dir.join("seq/depth")).unwrap() {
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(640, 480)
            .save(e.unwrap().path())
            .unwrap();
    }
}

/// The fixture sequence whose ground truth starts 100 s after its last image.
fn late_ground_truth(dir: &Path) {
    copy_dir(&fixture(), &dir.join("seq"));
    let p = dir.join("seq/groundtruth.txt");
    let text = std::fs::read_to_string(&p).unwrap();
    let lines: Vec<String> = text
        .lines()
        .map(|l| match l.split_once(' ') {
            Some((stamp, rest)) if !l.starts_with('#') => {
                format!("{} {rest}", stamp.parse::<f64>().unwrap() + 100.0)
            }
            _ => l.to_string(),
        })
        .collect();
    std::fs::write(&p, lines.join("\n")).unwrap();
}

/// The fixture sequence with a `camera.toml` of 320x240 for its 640x480 images.
fn small_camera_file(dir: &Path) {
    copy_dir(&fixture(), &dir.join("seq"));
    sdf_slam::camera::Camera::tum_fr1()
        .resized(320, 240)
        .save(dir.join("seq/camera.toml"))
        .unwrap();
}

/// The FPFDCNN smoke config training on `seq` (the case's damaged copy of the fixture),
/// with `camera = "fr1"` or without a `camera` key.
fn training_on_copy(with_camera: bool) -> String {
    let fixture = format!(
        "path = \"{}/datasets/fixtures/tum_fr1_rpy_head10\"\ncamera = \"fr1\"",
        env!("CARGO_MANIFEST_DIR")
    );
    let to = if with_camera {
        "path = \"seq\"\ncamera = \"fr1\""
    } else {
        "path = \"seq\""
    };
    tiny_training_config(&fixture, to)
}

/// Multiplies every float parameter by NaN.
struct Poison;

impl ModuleMapper for Poison {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        param.map(|t| t.mul_scalar(f32::NAN))
    }
}

/// An FPFDCNN checkpoint of the right shape whose weights are NaN (a diverged run).
fn nan_fpfdcnn(dir: &Path) {
    let ckpt = dir.join("nan");
    std::fs::create_dir_all(&ckpt).unwrap();
    let device = BackendKind::Ndarray.device().expect("ndarray");
    let model = FpfdcnnConfig::new().init(&device).unwrap().map(&mut Poison);
    model.save_file(ckpt.join("model.bpk")).unwrap();
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/train/fpfdcnn_tiny.toml"),
        ckpt.join("config.toml"),
    )
    .unwrap();
}

/// A tiny SDFCNN checkpoint whose weights are NaN, in half precision as bundled.
fn nan_sdfcnn(dir: &Path) {
    let device = BackendKind::Ndarray.device().expect("ndarray");
    let model = common::tiny_sdfcnn_config().init(&device).unwrap();
    common::write_tiny_sdfcnn(&dir.join("nan"), model.map(&mut Poison));
}

/// The FPFDCNN smoke config with one line changed (paths made absolute).
fn tiny_training_config(from: &str, to: &str) -> String {
    smoke_config("fpfdcnn_tiny.toml", from, to)
}

/// A smoke config of `configs/train/` with one line changed (paths made absolute).
fn smoke_config(name: &str, from: &str, to: &str) -> String {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("configs/train")
            .join(name),
    )
    .unwrap()
    .replace(
        "\"datasets/fixtures",
        &format!("\"{}/datasets/fixtures", env!("CARGO_MANIFEST_DIR")),
    );
    assert!(text.contains(from), "{name} has no '{from}'");
    text.replace(from, to)
}

/// A GPU backend this build lacks (`cuda` when built with `wgpu`).
fn gpu_left_out() -> &'static str {
    if cfg!(feature = "wgpu") {
        "cuda"
    } else {
        "wgpu"
    }
}

/// The error's hint for [`gpu_left_out`].
fn not_compiled() -> &'static str {
    if cfg!(feature = "wgpu") {
        "--features cuda"
    } else {
        "--features wgpu"
    }
}

fn corpus() -> Vec<Case> {
    let fx = fixture().display().to_string();
    let slam = |name, extra: &[&str], expect: &[&'static str]| {
        let mut args = vec![
            "--sequence",
            fx.as_str(),
            "--labels",
            "none",
            "--features",
            "orb",
        ];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--out", "out"]);
        case(name, "slam", &args, expect)
    };
    let camera = |extra: &str| {
        format!(
            "width = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n{extra}"
        )
    };
    let trajectory = "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0 1\n3.0 0 1 0 0 0 0 1\n";
    vec![
        // SLAM configs: sizes and values bounded before anything is allocated.
        slam("topdown size", &["--config", "c.toml"], &["c.toml", "map.topdown_size"])
            .file("c.toml", "[map]\ntopdown_size = 200000\n"),
        slam("unknown key", &["--config", "c.toml"], &["c.toml:3", "bogus"])
            .file("c.toml", "[map]\nvoxel_size = 0.02\nbogus = 1\n"),
        slam("TOML syntax", &["--config", "c.toml"], &["c.toml:2"])
            .file("c.toml", "[map]\nvoxel_size = = 1\n"),
        slam("sweep steps", &["--config", "c.toml"], &["c.toml", "multiview.steps"])
            .file("c.toml", "[multiview]\nsteps = 100000000\n"),
        slam("sweep range", &["--config", "c.toml"], &["c.toml", "multiview.range"])
            .file("c.toml", "[multiview]\nrange = nan\n"),
        slam("no PnP iterations", &["--config", "c.toml"], &["c.toml", "pnp.max_iterations"])
            .file("c.toml", "[pnp]\nmax_iterations = 0\n"),
        slam("ORB scale 1", &["--config", "c.toml"], &["c.toml", "features.orb_scale_factor"])
            .file("c.toml", "[features]\norb_scale_factor = 1.0\n"),
        slam("ORB scale 0.5", &["--config", "c.toml"], &["c.toml", "features.orb_scale_factor"])
            .file("c.toml", "[features]\norb_scale_factor = 0.5\n"),
        slam("ORB no levels", &["--config", "c.toml"], &["c.toml", "features.orb_levels"])
            .file("c.toml", "[features]\norb_levels = 0\n"),
        slam("too many keypoints", &["--config", "c.toml"], &["c.toml", "features.top_k"])
            .file("c.toml", "[features]\ntop_k = 100000000\n"),
        // Camera files.
        slam("camera 4e9 pixels", &["--camera", "cam.toml"], &["cam.toml", "larger than"])
            .file(
                "cam.toml",
                "width = 4000000000\nheight = 4000000000\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n",
            ),
        slam("camera 64000x48000", &["--camera", "cam.toml"], &["cam.toml", "64000x48000"])
            .file(
                "cam.toml",
                "width = 64000\nheight = 48000\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n",
            ),
        slam("camera NaN distortion", &["--camera", "cam.toml"], &["cam.toml", "finite"])
            .file("cam.toml", &camera("[distortion]\nk1 = nan\n")),
        slam("camera missing field", &["--camera", "cam.toml"], &["cam.toml:1", "fy"])
            .file("cam.toml", "width = 640\nheight = 480\nfx = 500.0\n"),
        slam(
            "camera smaller than the images",
            &["--camera", "cam.toml"],
            &["640x480", "320x240"],
        )
        .file(
            "cam.toml",
            "width = 320\nheight = 240\nfx = 250.0\nfy = 250.0\ncx = 160.0\ncy = 120.0\n",
        ),
        slam(
            "camera larger than the images",
            &["--camera", "cam.toml"],
            &["640x480", "1280x960"],
        )
        .file(
            "cam.toml",
            "width = 1280\nheight = 960\nfx = 1000.0\nfy = 1000.0\ncx = 640.0\ncy = 480.0\n",
        ),
        slam("unknown camera name", &["--camera", "fr9"], &["fr9"]),
        slam("missing camera file", &["--camera", "nocam.toml"], &["nocam.toml", "does not exist"]),
        // Checkpoints.
        case(
            "FPFDCNN checkpoint of garbage",
            "slam",
            &["--sequence", &fx, "--labels", "none", "--features", "fpfdcnn", "--fpfdcnn", "bad.bpk", "--out", "out"],
            &["bad.bpk"],
        )
        .file("bad.bpk", "not a checkpoint"),
        case(
            "SDFCNN checkpoint of garbage",
            "slam",
            &["--sequence", &fx, "--labels", "sdfcnn", "--sdfcnn", "bad.bpk", "--features", "orb", "--out", "out"],
            &["bad.bpk"],
        )
        .file("bad.bpk", "not a checkpoint"),
        case(
            "FPFDCNN weights that are NaN",
            "slam",
            &["--sequence", &fx, "--labels", "none", "--features", "fpfdcnn", "--fpfdcnn", "nan", "--out", "out"],
            &["nan/model.bpk", "NaN or infinite"],
        )
        .setup(nan_fpfdcnn),
        case(
            "SDFCNN weights that are NaN",
            "slam",
            &["--sequence", &fx, "--labels", "sdfcnn", "--sdfcnn", "nan", "--features", "orb", "--out", "out"],
            &["nan/model.bpk", "NaN or infinite"],
        )
        .setup(nan_sdfcnn),
        // Command-line arguments.
        slam("--out is a file", &[], &["--out out", "is a file"]).setup(|dir| {
            std::fs::write(dir.join("out"), "a file").unwrap();
        }),
        slam("--first past the end", &["--first", "10"], &["--first 10", "10 frames"]),
        case("missing sequence", "slam", &["--sequence", "no/such/seq", "--out", "out"], &["no/such/seq", "does not exist"]),
        // TUM text files and images.
        case(
            "associations.txt with a garbage line",
            "slam",
            &["--sequence", "seq", "--labels", "none", "--features", "orb", "--out", "out"],
            &["associations.txt:3", "found 2 field(s)"],
        )
        .setup(garbage_associations),
        case(
            "rgb.txt with a garbage line",
            "slam",
            &["--sequence", "seq", "--labels", "none", "--features", "orb", "--out", "out"],
            &["rgb.txt:5", "garbage"],
        )
        .setup(garbage_rgb_list),
        case(
            "NaN in groundtruth.txt",
            "slam",
            &["--sequence", "seq", "--labels", "none", "--features", "orb", "--out", "out"],
            &["groundtruth.txt:5", "not finite"],
        )
        .setup(nan_ground_truth),
        case(
            "no readable image",
            "slam",
            &["--sequence", "seq", "--labels", "none", "--features", "orb", "--out", "out"],
            &["no frame of seq could be processed"],
        )
        .setup(corrupt_images),
        // Sequences that cannot be scored or trained on.
        case("matching on depth that reads 0", "eval", &["matching", "--sequence", "seq", "--orb-only", "--gap", "1", "--pairs", "2"], &["seq", "valid depth pixel"])
            .setup(zero_depth),
        case("matching without ground truth at the frames", "eval", &["matching", "--sequence", "seq", "--orb-only", "--gap", "1", "--pairs", "2"], &["seq", "ground-truth pose"])
            .setup(late_ground_truth),
        case("matching with the folder's camera too small", "eval", &["matching", "--sequence", "seq", "--orb-only", "--gap", "1", "--pairs", "2"], &["seq/rgb", "640x480", "320x240"])
            .setup(small_camera_file),
        case("FPFDCNN training on depth that reads 0", "train", &["--config", "t.toml", "--out", "out"], &["seq", "valid depth pixel"])
            .file("t.toml", &training_on_copy(true))
            .setup(zero_depth),
        case("FPFDCNN training without ground truth at the frames", "train", &["--config", "t.toml", "--out", "out"], &["seq", "ground truth"])
            .file("t.toml", &training_on_copy(true))
            .setup(late_ground_truth),
        case("FPFDCNN training with the folder's camera too small", "train", &["--config", "t.toml", "--out", "out"], &["seq", "640x480", "320x240"])
            .file("t.toml", &training_on_copy(false))
            .setup(small_camera_file),
        // Trajectories (eval ate).
        case("position 1e300", "eval", &["ate", "gt.txt", "est.txt"], &["gt.txt:1", "out of range"])
            .file("gt.txt", "1.0 1e300 0 0 0 0 0 1\n2.0 1e300 0 0 0 0 0 1\n")
            .file("est.txt", trajectory),
        case("seven fields", "eval", &["ate", "gt.txt", "est.txt"], &["gt.txt:1", "expected 8 fields"])
            .file("gt.txt", "1.0 0 0 0 0 0 1\n")
            .file("est.txt", trajectory),
        case("decreasing stamps", "eval", &["ate", "gt.txt", "est.txt"], &["gt.txt:2", "strictly increasing"])
            .file("gt.txt", "2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n")
            .file("est.txt", trajectory),
        case("zero quaternion", "eval", &["ate", "gt.txt", "est.txt"], &["gt.txt:1", "quaternion"])
            .file("gt.txt", "1.0 0 0 0 0 0 0 0\n")
            .file("est.txt", trajectory),
        case("one pose, aligned", "eval", &["ate", "gt.txt", "gt.txt", "--align", "se3"], &["1 matched position", "--align none"])
            .file("gt.txt", "1.0 0 0 0 0 0 0 1\n"),
        case("missing trajectory", "eval", &["ate", "nofile.txt", "est.txt"], &["nofile.txt"])
            .file("est.txt", trajectory),
        case("missing keyframes", "eval", &["rpe", "est.txt", "est.txt", "--keyframes", "kf.txt"], &["kf.txt"])
            .file("est.txt", trajectory),
        case("keyframes line of six fields", "eval", &["rpe", "est.txt", "est.txt", "--keyframes", "kf.txt"], &["kf.txt:2", "expected 8 fields"])
            .file("est.txt", trajectory)
            .file("kf.txt", "1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 1\n"),
        case("no keypoints", "eval", &["matching", "--sequence", "seq", "--keypoints", "0"], &["--keypoints", "got 0"]),
        case("refinement search 99 px", "eval", &["matching", "--sequence", "seq", "--refine-search", "99"], &["--refine-search", "search_px", "got 99"]),
        case("refinement NCC 3", "eval", &["matching", "--sequence", "seq", "--refine-min-ncc", "3"], &["--refine-min-ncc", "got 3"]),
        // Training configs.
        case("batch size 1e12", "train", &["--config", "t.toml", "--out", "out", "--dry-run"], &["t.toml", "batch_size"])
            .file("t.toml", &tiny_training_config("batch_size = 2", "batch_size = 1000000000000")),
        case("negative temperature", "train", &["--config", "t.toml", "--out", "out", "--dry-run"], &["t.toml", "loss.tau"])
            .file("t.toml", &tiny_training_config("tau = 0.1", "tau = -1.0")),
        case("1x1 images", "train", &["--config", "t.toml", "--out", "out", "--dry-run"], &["t.toml", "1x1"])
            .file(
                "t.toml",
                &tiny_training_config("size = [96, 128]", "size = [1, 1]"),
            ),
        case("NaN learning rate", "train", &["--config", "t.toml", "--out", "out", "--dry-run"], &["t.toml", "learning rate"])
            .file("t.toml", &tiny_training_config("lr = 0.001", "lr = nan")),
        case("zero epochs", "train", &["--config", "t.toml", "--out", "out"], &["t.toml", "epochs"])
            .file("t.toml", &tiny_training_config("epochs = 2", "epochs = 0")),
        case("SDFCNN step of 201 million pixels", "train", &["--config", "t.toml", "--out", "out", "--dry-run"], &["t.toml", "million pixels"])
            .file("t.toml", &smoke_config("sdfcnn_tiny.toml", "inner_size = [96, 128]", "inner_size = [8192, 8192]")),
        case("SDFCNN zero epochs", "train", &["--config", "t.toml", "--out", "out"], &["t.toml", "epochs"])
            .file("t.toml", &smoke_config("sdfcnn_tiny.toml", "epochs = 60", "epochs = 0")),
        case("SDFCNN NaN gradient clip", "train", &["--config", "t.toml", "--out", "out", "--dry-run"], &["t.toml", "grad_clip_norm"])
            .file(
                "t.toml",
                &smoke_config("sdfcnn_tiny.toml", "lr = 0.001", "lr = 0.001\ngrad_clip_norm = nan"),
            ),
        case("unknown model", "train", &["--config", "t.toml"], &["t.toml", "no trainer"])
            .file("t.toml", "model = \"nope\"\n"),
        case("training TOML syntax", "train", &["--config", "t.toml"], &["t.toml:2"])
            .file("t.toml", "model = \"fpfdcnn\"\nepochs = [\n"),
        case("missing training config", "train", &["--config", "nofile.toml"], &["nofile.toml"]),
        case("sweep without out", "train", &["--config", "sweep.toml"], &["sweep.toml", "out"])
            .file("sweep.toml", "model = \"sweep\"\nbase = \"nofile.toml\"\n"),
        // Backends left out of this build (GPU features off): an error naming the feature,
        // before any data is read or any run folder made.
        case("training backend not compiled in", "train", &["--config", "t.toml", "--out", "out"], &[not_compiled()])
            .file("t.toml", &tiny_training_config("backend = \"ndarray\"", &format!("backend = \"{}\"", gpu_left_out()))),
        case("SDFCNN training backend not compiled in", "train", &["--config", "t.toml", "--out", "out", "--backend", gpu_left_out()], &[not_compiled()])
            .file("t.toml", &smoke_config("sdfcnn_tiny.toml", "epochs = 60", "epochs = 1")),
        case("SLAM backend not compiled in", "slam", &["--sequence", fx.as_str(), "--backend", gpu_left_out(), "--out", "out"], &[not_compiled()]),
        case("benchmark backend not compiled in", "bench", &["--backend", gpu_left_out(), "--runs", "1", "--warmup", "0", "--case", "fpfdcnn-infer"], &[not_compiled()]),
        // Benchmark arguments.
        case("no timed runs", "bench", &["--runs", "0"], &["--runs", "1..=1000"]),
        case("a billion runs", "bench", &["--runs", "1000000000"], &["--runs"]),
        case("PyTorch interpreter missing", "bench", &["--torch", "no/such/python", "--runs", "1", "--case", "fpfdcnn-infer"], &["cannot run no/such/python"]),
        case("PyTorch script missing", "bench", &["--torch", "python3", "--torch-script", "none.py", "--case", "fpfdcnn-infer"], &["none.py", "does not exist"]),
        // Synthesis configs.
        case("synth 1e12 frames", "synth", &["--config", "s.toml", "--out", "out"], &["s.toml", "frames must be at most"])
            .file("s.toml", "frames = 1000000000000\n"),
        case("synth --frames 1e12", "synth", &["--frames", "1000000000000", "--out", "out"], &["frames must be at most"]),
        case("synth field of the wrong type", "synth", &["--config", "s.toml", "--out", "out"], &["s.toml:1"])
            .file("s.toml", "frames = \"many\"\n"),
    ]
}

/// Peak resident memory of the largest child waited for, bytes.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn children_peak_rss() -> Option<u64> {
    // SAFETY: getrusage writes into the zeroed struct it is given.
    unsafe {
        let mut usage: libc::rusage = std::mem::zeroed();
        (libc::getrusage(libc::RUSAGE_CHILDREN, &mut usage) == 0)
            .then(|| usage.ru_maxrss as u64 * 1024)
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn children_peak_rss() -> Option<u64> {
    None
}

#[test]
fn every_malformed_input_is_a_clean_error() {
    let root = std::env::temp_dir().join(format!("sdf_bad_input_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let mut failures = Vec::new();
    let cases = corpus();
    for (i, c) in cases.iter().enumerate() {
        let dir = root.join(format!("{i:02}"));
        std::fs::create_dir_all(&dir).unwrap();
        for (path, bytes) in &c.files {
            std::fs::write(dir.join(path), bytes).unwrap();
        }
        if let Some(f) = c.setup {
            f(&dir);
        }
        // Something already written where the run writes.
        let out = dir.join("out");
        let sentinel = out.is_dir().then(|| out.join(SENTINEL)).or_else(|| {
            (!out.exists()).then(|| {
                std::fs::create_dir_all(&out).unwrap();
                out.join(SENTINEL)
            })
        });
        if let Some(s) = &sentinel {
            std::fs::write(s, "kept").unwrap();
        }
        let output = Command::new(bin(c.bin))
            .args(&c.args)
            .current_dir(&dir)
            .env("RUST_BACKTRACE", "0")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&output.stderr);
        let mut problems = Vec::new();
        match output.status.code() {
            None => problems.push(format!("killed by a signal ({:?})", output.status)),
            Some(0) => problems.push("exit code 0".into()),
            Some(101) => problems.push("exit code 101 (panic)".into()),
            Some(_) => {}
        }
        for bad in ["panicked at", "memory allocation of"] {
            if err.contains(bad) {
                problems.push(format!("'{bad}' in the output"));
            }
        }
        for want in &c.expect {
            if !err.contains(want) {
                problems.push(format!("no '{want}' in the message"));
            }
        }
        if let Some(s) = &sentinel
            && std::fs::read_to_string(s).ok().as_deref() != Some("kept")
        {
            problems.push(format!("{} was not kept", s.display()));
        }
        if !problems.is_empty() {
            failures.push(format!(
                "{} ({} {}): {}\n--- stderr ---\n{}",
                c.name,
                c.bin,
                c.args.join(" "),
                problems.join("; "),
                err.chars().take(1500).collect::<String>()
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n\n")
    );
    if let Some(peak) = children_peak_rss() {
        assert!(
            peak < 2 << 30,
            "a case peaked at {} MiB of memory",
            peak >> 20
        );
    }
    let _ = std::fs::remove_dir_all(&root);
}
