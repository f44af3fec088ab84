//! The `slam` binary's argument handling: clear errors before any frame is
//! processed, and a short real run writing every output.

mod common;

use burn::module::Module;
use sdf_slam::bundled::{
    BUNDLED_FPFDCNN, BUNDLED_SDFCNN, DEFAULT_SEQUENCE, default_sequence_config, generate_sequence,
};
use sdf_slam::fpfdcnn::FpfdcnnConfig;
use sdf_slam::nn::BackendKind;
use std::path::{Path, PathBuf};
use std::process::Command;

const FIXTURE: &str = "datasets/fixtures/tum_fr1_rpy_head10";

fn tmp_dir(name: &str) -> common::ScratchDir {
    common::fresh_dir("slamcli", name)
}

fn slam(args: &[&str], cwd: &Path) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_slam"))
        .args(args)
        .current_dir(cwd)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

fn fixture() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(FIXTURE)
        .display()
        .to_string()
}

#[test]
fn missing_sequence_and_monocular_without_sdfcnn_are_errors() {
    let dir = tmp_dir("missing");
    let (ok, _, err) = slam(&["--sequence", "no/such/sequence"], &dir);
    assert!(!ok);
    assert!(
        err.contains("no/such/sequence") && err.contains("does not exist"),
        "{err}"
    );
    let fx = fixture();
    let (ok, _, err) = slam(
        &[
            "--sequence",
            &fx,
            "--depth",
            "predicted",
            "--labels",
            "none",
        ],
        &dir,
    );
    assert!(!ok);
    assert!(err.contains("monocular") && err.contains("SDFCNN"), "{err}");
    let (ok, _, err) = slam(&["--sequence", &fx, "--first", "10"], &dir);
    assert!(!ok);
    assert!(
        err.contains("--first 10") && err.contains("10 frames"),
        "{err}"
    );
    // Zero frames is refused before any output is written.
    let out = dir.join("zero");
    let (ok, _, err) = slam(
        &[
            "--sequence",
            &fx,
            "--max-frames",
            "0",
            "--out",
            out.to_str().unwrap(),
        ],
        &dir,
    );
    assert!(!ok);
    assert!(err.contains("--max-frames 0"), "{err}");
    assert!(!out.exists());
}

#[test]
fn bad_camera_file_and_checkpoint_fail_before_processing() {
    let dir = tmp_dir("bad");
    let cam = dir.join("cam.toml");
    std::fs::write(
        &cam,
        "width = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\n",
    )
    .unwrap();
    let fx = fixture();
    let (ok, _, err) = slam(
        &["--sequence", &fx, "--camera", cam.to_str().unwrap()],
        &dir,
    );
    assert!(!ok);
    assert!(err.contains("cam.toml") && err.contains("cy"), "{err}");
    // A camera of another size than the images, one of an absurd size, a NaN distortion,
    // and --out naming a file: errors before processing.
    for (text, want) in [
        (
            "width = 320\nheight = 240\nfx = 258.0\nfy = 258.0\ncx = 160.0\ncy = 120.0\n",
            "320x240",
        ),
        (
            "width = 64000\nheight = 48000\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n",
            "64000x48000",
        ),
        (
            "width = 640\nheight = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n[distortion]\nk1 = nan\n",
            "distortion",
        ),
    ] {
        std::fs::write(&cam, text).unwrap();
        let (ok, _, err) = slam(
            &[
                "--sequence",
                &fx,
                "--camera",
                cam.to_str().unwrap(),
                "--features",
                "orb",
            ],
            &dir,
        );
        assert!(!ok && err.contains(want), "{want}: {err}");
    }
    let file = dir.join("a_file");
    std::fs::write(&file, "x").unwrap();
    let (ok, _, err) = slam(
        &[
            "--sequence",
            &fx,
            "--features",
            "orb",
            "--labels",
            "none",
            "--out",
            file.to_str().unwrap(),
        ],
        &dir,
    );
    assert!(
        !ok && err.contains("a_file") && err.contains("not a folder"),
        "{err}"
    );
    // A checkpoint whose weights are not FPFDCNN weights.
    let ckpt = dir.join("ckpt");
    std::fs::create_dir_all(&ckpt).unwrap();
    std::fs::write(ckpt.join("model.bpk"), b"garbage").unwrap();
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/train/fpfdcnn_tiny.toml"),
        ckpt.join("config.toml"),
    )
    .unwrap();
    let (ok, _, err) = slam(
        &["--sequence", &fx, "--fpfdcnn", ckpt.to_str().unwrap()],
        &dir,
    );
    assert!(!ok);
    assert!(
        err.contains("FPFDCNN") && err.contains("model.bpk"),
        "{err}"
    );
    // An SDFCNN checkpoint that is not SDFCNN weights: an error naming the
    // file, before any output is written.
    let sdf = dir.join("sdf");
    std::fs::create_dir_all(&sdf).unwrap();
    std::fs::write(sdf.join("model.bpk"), b"garbage").unwrap();
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/train/sdfcnn_tiny.toml"),
        sdf.join("config.toml"),
    )
    .unwrap();
    let out = dir.join("out");
    let (ok, _, err) = slam(
        &[
            "--sequence",
            &fx,
            "--features",
            "orb",
            "--sdfcnn",
            sdf.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        &dir,
    );
    assert!(!ok);
    assert!(err.contains("SDFCNN") && err.contains("model.bpk"), "{err}");
    assert!(!out.exists());
    // FPFDCNN weights given as SDFCNN weights.
    let (ok, _, err) = slam(
        &[
            "--sequence",
            &fx,
            "--features",
            "orb",
            "--sdfcnn",
            ckpt.to_str().unwrap(),
        ],
        &dir,
    );
    assert!(!ok);
    assert!(err.contains("not an SDFCNN checkpoint"), "{err}");
    let (ok, _, err) = slam(&["--sequence", &fx, "--labels", "gt"], &dir);
    assert!(!ok);
    assert!(err.contains("labels.txt"), "{err}");
    let bad_cfg = dir.join("slam.toml");
    std::fs::write(&bad_cfg, "[tracking]\nmax_depth = -1.0\n").unwrap();
    let (ok, _, err) = slam(
        &["--sequence", &fx, "--config", bad_cfg.to_str().unwrap()],
        &dir,
    );
    assert!(!ok);
    assert!(err.contains("tracking.max_depth"), "{err}");
}

#[test]
fn short_run_writes_every_output() {
    let dir = tmp_dir("run");
    let out = dir.join("out");
    let fx = fixture();
    let (ok, stdout, err) = slam(
        &[
            "--sequence",
            &fx,
            "--first",
            "3",
            "--max-frames",
            "4",
            "--features",
            "orb",
            "--labels",
            "none",
            "--out",
            out.to_str().unwrap(),
        ],
        &dir,
    );
    assert!(ok, "{err}");
    // --first 3: the trajectory starts at the fixture's fourth frame.
    let traj = std::fs::read_to_string(out.join("trajectory.txt")).unwrap();
    let first = traj
        .lines()
        .find(|l| !l.starts_with('#') && !l.trim().is_empty())
        .unwrap();
    assert!(first.starts_with("1305031229.6287"), "{first}");
    assert_eq!(traj.lines().filter(|l| !l.starts_with('#')).count(), 4);
    assert!(
        stdout.contains("ATE") && stdout.contains("keyframes"),
        "{stdout}"
    );
    for f in [
        "trajectory.txt",
        "keyframes.txt",
        "map.ply",
        "map_topdown.png",
        "trajectory.png",
        "report.md",
        "report.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
}

/// A tiny synthetic sequence made by the function `slam` calls when the
/// default sequence is absent, at `root/datasets/generated/default_sequence`.
fn tiny_default_sequence(root: &Path, frames: usize) -> PathBuf {
    let dest = root.join(DEFAULT_SEQUENCE);
    let mut cfg = default_sequence_config();
    cfg.frames = frames;
    cfg.resolution = "160x120".into();
    generate_sequence(&cfg, &dest, &|_| {}).unwrap();
    dest
}

/// A randomly initialised tiny SDFCNN checkpoint in half precision, as bundled.
fn tiny_sdfcnn(dir: &Path) {
    let device = BackendKind::Ndarray.device().expect("ndarray");
    let model = common::tiny_sdfcnn_config().init(&device).unwrap();
    common::write_tiny_sdfcnn(dir, sdf_slam::nn::seeded_init(model, 3));
}

/// A randomly initialised FPFDCNN checkpoint (Table 12) with the smoke-run config.
fn random_fpfdcnn(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let device = BackendKind::Ndarray.device().expect("ndarray");
    let model = sdf_slam::nn::seeded_init(FpfdcnnConfig::new().init(&device).unwrap(), 4);
    model.save_file(dir.join("model.bpk")).unwrap();
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/train/fpfdcnn_tiny.toml"),
        dir.join("config.toml"),
    )
    .unwrap();
}

fn bundled(rel: &str) -> bool {
    let d = Path::new(env!("CARGO_MANIFEST_DIR")).join(rel);
    d.join("model.bpk").is_file() && d.join("config.toml").is_file()
}

#[test]
fn no_arguments_run_the_default_sequence_with_the_bundled_weights() {
    // The default sequence already exists here (generating the full-size one
    // is for real runs); the weights are the bundled ones when the crate has
    // them, else ORB keypoints and no labels, each with a note saying why.
    let dir = tmp_dir("noargs");
    tiny_default_sequence(&dir, 6);
    let (ok, stdout, err) = slam(&[], &dir);
    assert!(ok, "{err}");
    assert!(
        err.contains(DEFAULT_SEQUENCE) && err.contains("RGB-D"),
        "{err}"
    );
    if bundled(BUNDLED_FPFDCNN) {
        assert!(
            err.contains("fpfdcnn keypoints (") && err.contains(BUNDLED_FPFDCNN),
            "{err}"
        );
    } else {
        assert!(
            err.contains("note: using ORB keypoints") && err.contains("orb keypoints"),
            "{err}"
        );
    }
    if bundled(BUNDLED_SDFCNN) {
        assert!(
            err.contains("sdfcnn labels (") && err.contains(BUNDLED_SDFCNN),
            "{err}"
        );
    } else {
        assert!(
            err.contains("note: no semantic labels") && err.contains("none labels"),
            "{err}"
        );
    }
    for what in [
        "frames 6 / 6",
        "keyframes",
        "frames/s",
        "ATE",
        "labels:",
        "wrote:",
    ] {
        assert!(stdout.contains(what), "{what}: {stdout}");
    }
    let out = dir.join("runs/slam/default_sequence");
    for f in ["trajectory.txt", "map.ply", "report.json"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
}

#[test]
fn sdfcnn_checkpoint_gives_labels_and_monocular_depth() {
    let dir = tmp_dir("sdfcnn");
    let seq = tiny_default_sequence(&dir, 6);
    let ckpt = dir.join("sdfcnn");
    tiny_sdfcnn(&ckpt);
    let out = dir.join("out");
    let (ok, stdout, err) = slam(
        &[
            "--sequence",
            seq.to_str().unwrap(),
            "--depth",
            "predicted",
            "--features",
            "orb",
            "--sdfcnn",
            ckpt.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ],
        &dir,
    );
    assert!(ok, "{err}");
    assert!(
        err.contains("monocular mode") && err.contains("sdfcnn labels ("),
        "{err}"
    );
    assert!(stdout.contains("frames 6 / 6"), "{stdout}");
    let traj = sdf_slam::trajectory::Trajectory::read_tum(out.join("trajectory.txt")).unwrap();
    assert_eq!(traj.len(), 6);
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["labels"], "sdfcnn");
    assert_eq!(json["mode"], "monocular");
}

#[test]
fn weights_in_the_current_directory_are_the_defaults() {
    // weights/{fpfdcnn,sdfcnn} under the current directory come first.
    let dir = tmp_dir("cwd_weights");
    tiny_default_sequence(&dir, 4);
    random_fpfdcnn(&dir.join(BUNDLED_FPFDCNN));
    tiny_sdfcnn(&dir.join(BUNDLED_SDFCNN));
    let (ok, stdout, err) = slam(&["--single-thread"], &dir);
    assert!(ok, "{err}");
    assert!(
        err.contains(&format!("fpfdcnn keypoints ({BUNDLED_FPFDCNN})"))
            && err.contains(&format!("sdfcnn labels ({BUNDLED_SDFCNN})")),
        "{err}"
    );
    assert!(!err.contains("note:"), "{err}");
    assert!(stdout.contains("frames 4 / 4"), "{stdout}");
    let json: serde_json::Value = serde_json::from_slice(
        &std::fs::read(dir.join("runs/slam/default_sequence/report.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(json["features"], "fpfdcnn");
    assert_eq!(json["labels"], "sdfcnn");
    // --labels gt is used only when asked for.
    let (ok, _, err) = slam(
        &["--single-thread", "--labels", "gt", "--max-frames", "2"],
        &dir,
    );
    assert!(ok, "{err}");
    assert!(err.contains("gt labels"), "{err}");
}

/// A long sequence made of the fixture's ten frames over and over (symbolic links, fresh
/// time stamps 1/30 s apart), without ground truth.
#[cfg(unix)]
fn looped_fixture(dir: &Path, frames: usize) -> PathBuf {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join(FIXTURE);
    let pairs: Vec<(String, String)> = std::fs::read_to_string(src.join("associations.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            (f[1].to_string(), f[3].to_string())
        })
        .collect();
    let seq = dir.join("looped");
    std::fs::create_dir_all(seq.join("rgb")).unwrap();
    std::fs::create_dir_all(seq.join("depth")).unwrap();
    let mut assoc = String::new();
    for i in 0..frames {
        let (rgb, depth) = &pairs[i % pairs.len()];
        let t = 1000.0 + i as f64 / 30.0;
        let (r, d) = (format!("rgb/{t:.6}.png"), format!("depth/{t:.6}.png"));
        std::os::unix::fs::symlink(src.join(rgb), seq.join(&r)).unwrap();
        std::os::unix::fs::symlink(src.join(depth), seq.join(&d)).unwrap();
        assoc.push_str(&format!("{t:.6} {r} {t:.6} {d}\n"));
    }
    std::fs::write(seq.join("associations.txt"), assoc).unwrap();
    seq
}

#[cfg(unix)]
#[test]
fn ctrl_c_stops_the_run_writes_its_outputs_and_exits_130() {
    signal_stops_the_run("ctrl_c", libc::SIGINT, 130);
}

/// What `timeout`, systemd, Docker and schedulers send: handled as Ctrl-C is.
#[cfg(unix)]
#[test]
fn sigterm_stops_the_run_writes_its_outputs_and_exits_143() {
    signal_stops_the_run("sigterm", libc::SIGTERM, 143);
}

#[cfg(unix)]
#[test]
fn sighup_stops_the_run_writes_its_outputs_and_exits_129() {
    signal_stops_the_run("sighup", libc::SIGHUP, 129);
}

#[cfg(unix)]
fn signal_stops_the_run(name: &str, signal: i32, code: i32) {
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    let dir = tmp_dir(name);
    let seq = looped_fixture(&dir, 600);
    let mut child = Command::new(env!("CARGO_BIN_EXE_slam"))
        .args(["--sequence", seq.to_str().unwrap(), "--camera", "fr1"])
        .args(["--features", "orb", "--labels", "none", "--out", "out"])
        .current_dir(&dir)
        .env("RUST_BACKTRACE", "0")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The header is printed once the Ctrl-C handler is installed.
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut header = String::new();
    err.read_line(&mut header).unwrap();
    assert!(header.starts_with("sequence"), "{header}");
    // Let it track a few frames (600 take far longer than this).
    std::thread::sleep(std::time::Duration::from_millis(1500));
    // SAFETY: kill sends a signal to the child we spawned.
    assert_eq!(unsafe { libc::kill(child.id() as i32, signal) }, 0);
    let mut rest = String::new();
    let _ = std::io::Read::read_to_string(&mut err, &mut rest);
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(code), "{rest}");
    let out = dir.join("out");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["interrupted"], true);
    let done = report["frames_processed"].as_u64().unwrap();
    assert!(done < 600, "{done} frames: the run was not stopped");
    // Stopped before its first frame on a very slow machine, it has no trajectory to write.
    if done > 0 {
        let traj = sdf_slam::trajectory::Trajectory::read_tum(out.join("trajectory.txt")).unwrap();
        assert_eq!(traj.len() as u64, done);
    }
}
