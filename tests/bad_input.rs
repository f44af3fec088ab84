//! Hostile input as a standing test: a corpus of malformed inputs per input kind (TUM text
//! files, images, SLAM / training / synthesis / sweep configs, camera files, checkpoints,
//! trajectories, 7-Scenes folders, command-line arguments) run through the binaries (`slam`,
//! `eval`, `train`, `synth`, `bench`, `dataset`). Classes: unbounded reads (FIFOs, devices,
//! oversized tables and lines), frames that do not fit the camera in the middle of a
//! sequence, cameras and data that cannot be right (principal point off the image, absurd
//! focal lengths and distortion, poses kilometres away, gaps in a numbering). Every case must
//! end in
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
        "dataset" => env!("CARGO_BIN_EXE_dataset"),
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

/// The fixture's frames as listed by its `associations.txt`: (colour, depth) file names.
fn fixture_frames() -> Vec<(String, String)> {
    std::fs::read_to_string(fixture().join("associations.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            (f[1].to_string(), f[3].to_string())
        })
        .collect()
}

/// In a copy of the fixture at `dir/seq`, frame `index`'s colour image replaced by one of
/// `w x h` pixels.
fn colour_of_size(dir: &Path, index: usize, w: u32, h: u32) {
    let seq = dir.join("seq");
    if !seq.exists() {
        copy_dir(&fixture(), &seq);
    }
    let (rgb, _) = &fixture_frames()[index];
    image::RgbImage::from_pixel(w, h, image::Rgb([90, 120, 150]))
        .save(seq.join(rgb))
        .unwrap();
}

/// In a copy of the fixture at `dir/seq`, frame `index`'s depth image replaced by a 16-bit
/// one of `w x h` pixels.
fn depth_of_size(dir: &Path, index: usize, w: u32, h: u32) {
    let seq = dir.join("seq");
    if !seq.exists() {
        copy_dir(&fixture(), &seq);
    }
    let (_, depth) = &fixture_frames()[index];
    image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_pixel(w, h, image::Luma([5000]))
        .save(seq.join(depth))
        .unwrap();
}

/// A named pipe with no writer: reading it would block forever.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn mkfifo(path: &Path) {
    use std::os::unix::ffi::OsStrExt;
    let _ = std::fs::remove_file(path);
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(
        unsafe { libc::mkfifo(c.as_ptr(), 0o600) },
        0,
        "mkfifo {}",
        path.display()
    );
}

/// The fixture sequence with a `groundtruth.txt` of 65 MiB (sparse: nothing is written).
fn huge_ground_truth(dir: &Path) {
    copy_dir(&fixture(), &dir.join("seq"));
    let f = std::fs::OpenOptions::new()
        .write(true)
        .open(dir.join("seq/groundtruth.txt"))
        .unwrap();
    f.set_len(65 << 20).unwrap();
}

/// The fixture sequence whose `associations.txt` lists a million and one frames (17 MB).
fn million_associations(dir: &Path) {
    copy_dir(&fixture(), &dir.join("seq"));
    let mut text = String::with_capacity(18 << 20);
    for i in 0..1_000_001u64 {
        use std::fmt::Write;
        let _ = writeln!(text, "{i} r/{i} {i} d/{i}");
    }
    std::fs::write(dir.join("seq/associations.txt"), text).unwrap();
}

/// The fixture sequence without `associations.txt`, line 5 of `rgb.txt` naming a file of a
/// megabyte.
fn megabyte_line(dir: &Path) {
    garble(dir, "rgb.txt", 5);
    std::fs::remove_file(dir.join("seq/associations.txt")).unwrap();
    let p = dir.join("seq/rgb.txt");
    let text = std::fs::read_to_string(&p).unwrap().replace(
        "garbage line",
        &format!("1305031229.60 rgb/{}.png", "a".repeat(1 << 20)),
    );
    std::fs::write(&p, text).unwrap();
}

/// The fixture sequence with line 3 of `associations.txt` naming a colour file of 5000 bytes.
fn long_file_name(dir: &Path) {
    copy_dir(&fixture(), &dir.join("seq"));
    let p = dir.join("seq/associations.txt");
    let text = std::fs::read_to_string(&p).unwrap();
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    let f: Vec<String> = lines[2].split_whitespace().map(String::from).collect();
    lines[2] = format!("{} rgb/{}.png {} {}", f[0], "b".repeat(5000), f[2], f[3]);
    std::fs::write(&p, lines.join("\n")).unwrap();
}

/// Writes the fixture's first `n` frames as a 7-Scenes folder `dir/src` numbered 0..n
/// (colour copied, depth in millimetres, the ground-truth pose as a 4x4 matrix), skipping the
/// numbers in `skip`.
fn seven_scenes_folder(dir: &Path, n: usize, skip: &[usize]) {
    let seq = sdf_slam::dataset::TumSequence::open(fixture()).unwrap();
    let out = dir.join("src");
    std::fs::create_dir_all(&out).unwrap();
    for i in (0..n).filter(|i| !skip.contains(i)) {
        let stem = out.join(format!("frame-{i:06}"));
        common::write_seven_scenes_frame(&seq, i, &stem, 0);
    }
}

/// A 7-Scenes folder of four frames whose frame 1 sits 1e300 m from the origin.
fn seven_scenes_far_pose(dir: &Path) {
    seven_scenes_folder(dir, 4, &[]);
    std::fs::write(
        dir.join("src/frame-000001.pose.txt"),
        "1 0 0 1e300\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
    )
    .unwrap();
}

/// A 7-Scenes folder of frames 0, 1, 3, 4: frame 2 missing.
fn seven_scenes_gap(dir: &Path) {
    seven_scenes_folder(dir, 5, &[2]);
}

/// A 7-Scenes folder of four frames.
fn seven_scenes_four(dir: &Path) {
    seven_scenes_folder(dir, 4, &[]);
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
    let mut cases = vec![
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
        // A camera height must be a positive finite number of metres under 10.
        slam("negative camera height", &["--camera-height", "-1.2"], &["--camera-height", "under 10"]),
        slam("zero camera height", &["--camera-height", "0"], &["--camera-height", "positive"]),
        slam("NaN camera height", &["--camera-height", "NaN"], &["--camera-height", "NaN"]),
        slam("tall camera", &["--camera-height", "12"], &["--camera-height", "12"]),
        slam("camera height not a number", &["--camera-height", "tall"], &["--camera-height", "tall"]),
        slam("camera height in the config", &["--config", "c.toml"], &["c.toml", "scale.camera_height"])
            .file("c.toml", "[scale]\ncamera_height = 25.0\n"),
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
        case("synth views above the ceiling", "synth", &["--config", "s.toml", "--out", "out"], &["s.toml:4", "motion.view_height", "lowest ceiling"])
            .file("s.toml", "[room]\nheight = [2.4, 3.0]\n[motion]\nview_height = [0.5, 2.5]\n"),
        case("synth ceiling range upside down", "synth", &["--config", "s.toml", "--out", "out"], &["s.toml:2", "room.height"])
            .file("s.toml", "[room]\nheight = [3.5, 2.5]\n"),
        case("synth 100 million views a scene", "synth", &["--config", "s.toml", "--out", "out"], &["s.toml", "nyu_views_per_scene"])
            .file("s.toml", "[output]\nnyu_views_per_scene = 100000000\n"),
        case("synth 100 scenes of a million frames", "synth", &["--config", "s.toml", "--out", "out"], &["s.toml", "renders"])
            .file("s.toml", "scenes = 100\nframes = 1000000\n"),
        // Reads with no bound: endless devices, oversized tables, lines and file names.
        slam("SLAM config /dev/zero", &["--config", "/dev/zero"], &["/dev/zero", "character device"]),
        slam("camera /dev/zero", &["--camera", "/dev/zero"], &["/dev/zero", "character device"]),
        slam("camera file is a folder", &["--camera", "cam.toml"], &["cam.toml", "a directory"])
            .setup(|dir| std::fs::create_dir_all(dir.join("cam.toml")).unwrap()),
        case("trajectory /dev/zero", "eval", &["ate", "/dev/zero", "est.txt"], &["/dev/zero", "character device"])
            .file("est.txt", trajectory),
        case("training config /dev/urandom", "train", &["--config", "/dev/urandom", "--dry-run"], &["/dev/urandom", "character device"]),
        case("groundtruth.txt of 65 MiB", "slam", &["--sequence", "seq", "--labels", "none", "--features", "orb", "--out", "out"], &["groundtruth.txt", "64 MiB"])
            .setup(huge_ground_truth),
        case("associations.txt of a million and one frames", "slam", &["--sequence", "seq", "--labels", "none", "--features", "orb", "--max-frames", "5", "--out", "out"], &["associations.txt:1000001", "1000000 entries: longer than any sequence this reads (9 hours at 30 Hz)"])
            .setup(million_associations),
        case("a file name of a megabyte", "slam", &["--sequence", "seq", "--labels", "none", "--features", "orb", "--out", "out"], &["rgb.txt:5", "64 KiB"])
            .setup(megabyte_line),
        case("a file name of 5000 bytes", "slam", &["--sequence", "seq", "--labels", "none", "--features", "orb", "--out", "out"], &["associations.txt:3", "longer than any path", "bbbb...("])
            .setup(long_file_name),
        // Frames that do not fit the camera, in the middle of a sequence: evaluation and
        // training stop on them, naming the file (`slam` skips them: see below).
        case("matching on a 1280x960 frame", "eval", &["matching", "--sequence", "seq", "--orb-only", "--gap", "1", "--pairs", "2"], &["seq/rgb/", "1280x960", "640x480"])
            .setup(|dir| colour_of_size(dir, 1, 1280, 960)),
        case("matching on a 3000x20 depth image", "eval", &["matching", "--sequence", "seq", "--orb-only", "--gap", "1", "--pairs", "2"], &["seq/depth/", "3000x20", "640x480"])
            .setup(|dir| depth_of_size(dir, 4, 3000, 20)),
        case("FPFDCNN training on a 320x240 frame", "train", &["--config", "t.toml", "--out", "out"], &["seq/rgb/", "320x240", "640x480"])
            .file("t.toml", &training_on_copy(true))
            .setup(|dir| colour_of_size(dir, 5, 320, 240)),
        case("FPFDCNN training on a grey frame", "train", &["--config", "t.toml", "--out", "out"], &["seq/rgb/", "single-channel", "8-bit RGB"])
            .file("t.toml", &training_on_copy(true))
            .setup(|dir| {
                copy_dir(&fixture(), &dir.join("seq"));
                image::GrayImage::new(640, 480)
                    .save(dir.join("seq").join(&fixture_frames()[7].0))
                    .unwrap();
            }),
        // Cameras that cannot be right.
        slam("principal point a million pixels away", &["--camera", "cam.toml"], &["cam.toml", "cx = 1000000", "outside the image"])
            .file("cam.toml", "width = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 1000000.0\ncy = 240.0\n"),
        slam("principal point above the image", &["--camera", "cam.toml"], &["cam.toml", "cy = -300"])
            .file("cam.toml", "width = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = -300.0\n"),
        slam("focal length 1e-30", &["--camera", "cam.toml"], &["cam.toml", "fx = 1e-30 px", "image widths"])
            .file("cam.toml", &camera("").replace("fx = 500.0", "fx = 1e-30")),
        slam("focal length 1e30", &["--camera", "cam.toml"], &["cam.toml", "fy = 1e30 px", "image heights"])
            .file("cam.toml", &camera("").replace("fy = 500.0", "fy = 1e30")),
        slam("distortion k1 1e10", &["--camera", "cam.toml"], &["cam.toml", "distortion.k1 = 1e10", "squeezes"])
            .file("cam.toml", &camera("[distortion]\nk1 = 1e10\n")),
        slam("distortion p2 1e10", &["--camera", "cam.toml"], &["cam.toml", "distortion.p2"])
            .file("cam.toml", &camera("[distortion]\np2 = 1e10\n")),
        slam("distortion folding inside the image", &["--camera", "cam.toml"], &["cam.toml", "distortion.k2", "folds back"])
            .file("cam.toml", &camera("[distortion]\nk2 = -6.0\n")),
        // 7-Scenes folders that cannot be right.
        case("7-Scenes pose 1e300 m away", "dataset", &["seven-scenes", "src", "--out", "out"], &["frame-000001.pose.txt:1", "1e300"])
            .setup(seven_scenes_far_pose),
        case("7-Scenes folder with a frame missing", "dataset", &["seven-scenes", "src", "--out", "out"], &["src", "missing from the numbering", "frames 0 and 4: 2 "])
            .setup(seven_scenes_gap),
        case("7-Scenes --count beyond the frames", "dataset", &["seven-scenes", "src", "--out", "out", "--count", "100"], &["100 frames asked for (--count)", "has 4"])
            .setup(seven_scenes_four),
        // Training configs `--dry-run` must refuse.
        case("FPFDCNN config without sequences", "train", &["--config", "t.toml", "--out", "out", "--dry-run"], &["t.toml", "data.sequences"])
            .file("t.toml", &no_sequences()),
        case("FPFDCNN lr_steps out of order", "train", &["--config", "t.toml", "--out", "out", "--dry-run"], &["t.toml", "optimizer.lr_steps"])
            .file("t.toml", &tiny_training_config("lr = 0.001", "lr = 0.001\nlr_steps = [[20, 0.0001], [10, 0.00001]]")),
        case("SDFCNN lr_steps out of order", "train", &["--config", "t.toml", "--out", "out", "--dry-run"], &["t.toml", "optimizer.lr_steps"])
            .file("t.toml", &smoke_config("sdfcnn_tiny.toml", "lr_steps = [[40, 0.0003]]", "lr_steps = [[40, 0.0003], [40, 0.0001]]")),
    ];
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    cases.extend(fifo_cases(&fx));
    cases
}

/// Inputs that are named pipes with no writer: each must be refused, not waited on.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn fifo_cases(fx: &str) -> Vec<Case> {
    let slam = |name, extra: &[&str], expect: &[&'static str]| {
        let mut args = vec!["--sequence", fx, "--labels", "none", "--features", "orb"];
        args.extend_from_slice(extra);
        args.extend_from_slice(&["--out", "out"]);
        case(name, "slam", &args, expect)
    };
    vec![
        slam(
            "SLAM config a FIFO",
            &["--config", "c.toml"],
            &["c.toml", "FIFO"],
        )
        .setup(|dir| mkfifo(&dir.join("c.toml"))),
        slam(
            "camera a FIFO",
            &["--camera", "cam.toml"],
            &["cam.toml", "FIFO"],
        )
        .setup(|dir| mkfifo(&dir.join("cam.toml"))),
        case(
            "trajectory a FIFO",
            "eval",
            &["ate", "gt.txt", "gt.txt"],
            &["gt.txt", "FIFO"],
        )
        .setup(|dir| mkfifo(&dir.join("gt.txt"))),
        case(
            "associations.txt a FIFO",
            "eval",
            &[
                "matching",
                "--sequence",
                "seq",
                "--orb-only",
                "--gap",
                "1",
                "--pairs",
                "2",
            ],
            &["associations.txt", "FIFO"],
        )
        .setup(|dir| {
            copy_dir(&fixture(), &dir.join("seq"));
            mkfifo(&dir.join("seq/associations.txt"));
        }),
        case(
            "matching on a depth image that is a FIFO",
            "eval",
            &[
                "matching",
                "--sequence",
                "seq",
                "--orb-only",
                "--gap",
                "1",
                "--pairs",
                "2",
            ],
            &["seq/depth/", "FIFO"],
        )
        .setup(|dir| {
            copy_dir(&fixture(), &dir.join("seq"));
            mkfifo(&dir.join("seq").join(&fixture_frames()[0].1));
        }),
        case(
            "training config a FIFO",
            "train",
            &["--config", "t.toml", "--dry-run"],
            &["t.toml", "FIFO"],
        )
        .setup(|dir| mkfifo(&dir.join("t.toml"))),
    ]
}

/// The FPFDCNN smoke config with its one `[[data.sequences]]` table left out.
fn no_sequences() -> String {
    let block = format!(
        "[[data.sequences]]\npath = \"{}/datasets/fixtures/tum_fr1_rpy_head10\"\ncamera = \"fr1\"\n",
        env!("CARGO_MANIFEST_DIR")
    );
    tiny_training_config(&block, "")
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

/// Waits for a child at most `limit`; kills it past that (a hang is a failure, not a stall).
fn wait_at_most(
    mut child: std::process::Child,
    limit: std::time::Duration,
) -> std::process::Output {
    let start = std::time::Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > limit {
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!(
                "still running after {limit:?}: {}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    child.wait_with_output().unwrap()
}

/// Frames of another size (and, on Linux, a depth image that is a FIFO) in the middle of a
/// sequence: `slam` skips each one, says so, and lists it with its reason in `report.json`
/// and `report.md`; the other frames are processed and the run ends normally.
#[test]
fn slam_skips_frames_that_do_not_fit_the_camera_with_their_reason() {
    let dir = sdf_slam::io::ScratchDir::new("bad_input_skip").unwrap();
    colour_of_size(&dir, 2, 1, 1);
    colour_of_size(&dir, 4, 320, 240);
    colour_of_size(&dir, 6, 3000, 20);
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    mkfifo(&dir.join("seq").join(&fixture_frames()[8].1));
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    depth_of_size(&dir, 8, 1280, 960);
    let child = Command::new(bin("slam"))
        .args([
            "--sequence",
            "seq",
            "--labels",
            "none",
            "--features",
            "orb",
            "--out",
            "out",
        ])
        .current_dir(&dir)
        .env("RUST_BACKTRACE", "0")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let out = wait_at_most(child, std::time::Duration::from_secs(300));
    let text =
        String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{text}");
    assert!(text.contains("(4 skipped)"), "{text}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("out/report.json")).unwrap())
            .unwrap();
    let skipped = report["frames_skipped"]
        .as_array()
        .unwrap_or_else(|| panic!("{report}"));
    let frames = fixture_frames();
    let expect: [(usize, String, &str); 4] = [
        (2, frames[2].0.clone(), "is 1x1 but the camera is 640x480"),
        (
            4,
            frames[4].0.clone(),
            "is 320x240 but the camera is 640x480",
        ),
        (
            6,
            frames[6].0.clone(),
            "is 3000x20 but the camera is 640x480",
        ),
        (
            8,
            frames[8].1.clone(),
            if cfg!(all(target_os = "linux", target_env = "gnu")) {
                "FIFO"
            } else {
                "is 1280x960"
            },
        ),
    ];
    assert_eq!(skipped.len(), expect.len(), "{skipped:?}");
    for (s, (index, file, why)) in skipped.iter().zip(&expect) {
        assert_eq!(s[0].as_u64(), Some(*index as u64), "{s}");
        let reason = s[1].as_str().unwrap();
        assert!(
            reason.contains(file.as_str()) && reason.contains(why),
            "{index}: {reason}"
        );
    }
    let md = std::fs::read_to_string(dir.join("out/report.md")).unwrap();
    assert!(md.contains("is 320x240 but the camera is 640x480"), "{md}");
    assert_eq!(report["frames_processed"].as_u64(), Some(6), "{report}");
}

/// Training and evaluation read their data through the same frame check: a frame of another
/// size in a TUM sequence or a NYUv2 folder is an error naming it (crops of NYUv2's images
/// stay accepted), and label values outside the 40 classes and void are refused.
#[test]
fn training_data_is_checked_frame_by_frame() {
    use sdf_slam::dataset::LabelImage;
    use sdf_slam::sdfcnn::data::{DataSource, Set};
    let dir = sdf_slam::io::ScratchDir::new("bad_input_sets").unwrap();
    // A TUM sequence (SDFCNN depth source, `eval seg --data SEQ`).
    colour_of_size(&dir, 4, 3000, 20);
    let source = DataSource {
        camera: Some("fr1".into()),
        ..DataSource::folder(dir.join("seq"))
    };
    let set = Set::open(&source).unwrap();
    for j in 0..set.len() {
        match set.load(j) {
            Ok(_) => assert_ne!(j, 4),
            Err(e) => {
                let e = e.to_string();
                assert!(
                    j == 4 && e.contains(&fixture_frames()[4].0) && e.contains("3000x20"),
                    "{j}: {e}"
                );
            }
        }
    }
    // A NYUv2 folder: one image 320x240 among 640x480 ones and a 625x468 crop.
    let nyu = dir.join("nyu");
    copy_dir(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("datasets/fixtures/nyuv2"),
        &nyu,
    );
    image::RgbImage::new(320, 240)
        .save(nyu.join("000464_rgb.png"))
        .unwrap();
    let set = Set::open(&DataSource::folder(&nyu)).unwrap();
    let mut refused = 0;
    for j in 0..set.len() {
        if let Err(e) = set.load(j) {
            let e = e.to_string();
            assert!(e.contains("000464_rgb.png") && e.contains("320x240"), "{e}");
            refused += 1;
        }
    }
    assert_eq!((set.len(), refused), (3, 1));
    // Label values outside 0-39 and 255, as `eval seg` and `slam --labels gt` read them.
    let labels = dir.join("labels.png");
    for (value, ok) in [
        (0u8, true),
        (39, true),
        (255, true),
        (40, false),
        (254, false),
    ] {
        image::GrayImage::from_pixel(8, 6, image::Luma([value]))
            .save(&labels)
            .unwrap();
        match LabelImage::read_classes(&labels) {
            Ok(l) => assert!(ok && l.get(7, 5) == value),
            Err(e) => assert!(
                !ok && e.to_string().contains(&format!("label {value}")),
                "{e}"
            ),
        }
    }
}
