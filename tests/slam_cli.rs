//! The `slam` binary's argument handling: clear errors before any frame is
//! processed, and a short real run writing every output.

use std::path::{Path, PathBuf};
use std::process::Command;

const FIXTURE: &str = "datasets/fixtures/tum_fr1_rpy_head10";

fn tmp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdf_slamcli_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
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
fn missing_default_sequence_says_how_to_make_it() {
    let dir = tmp_dir("default");
    let (ok, _, err) = slam(&[], &dir);
    assert!(!ok);
    assert!(
        err.contains("datasets/generated/default_sequence") && err.contains("generate"),
        "{err}"
    );
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
    // A checkpoint whose weights are not FPFDCNN weights.
    let ckpt = dir.join("ckpt");
    std::fs::create_dir_all(&ckpt).unwrap();
    std::fs::write(ckpt.join("model.bpk"), b"garbage").unwrap();
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/fpfdcnn_tiny.toml"),
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
            "--max-frames",
            "4",
            "--out",
            out.to_str().unwrap(),
        ],
        &dir,
    );
    assert!(ok, "{err}");
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
