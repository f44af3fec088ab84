//! The `train --config` and `eval seg` commands end to end on the NYUv2 fixtures, with a tiny
//! network (32×48, one epoch).

mod common;

use std::process::Command;

fn tmp(name: &str) -> common::ScratchDir {
    common::fresh_dir("cli", name)
}

const TINY: &str = r#"model = "sdfcnn"
out = "OUT"
epochs = 1
batch_size = 3
[data]
train = [{ path = "datasets/fixtures/nyuv2" }]
val = [{ path = "datasets/fixtures/nyuv2" }]
size = [32, 48]
[network]
inner_size = [32, 48]
decoder_dim = 16
crp_stages = 1
"#;

#[test]
fn train_then_eval_seg() {
    let dir = tmp("train_eval");
    let run = dir.join("run");
    let cfg = dir.join("tiny.toml");
    std::fs::write(&cfg, TINY.replace("OUT", &run.display().to_string())).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_train"))
        .args(["--config", cfg.to_str().unwrap(), "--quiet"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        stdout.contains("epoch 1/1") && stdout.contains("val_miou"),
        "{stdout}"
    );
    assert!(run.join("checkpoints/epoch-0001/model.bpk").is_file());

    let pred = dir.join("pred");
    let json = dir.join("seg.json");
    let out = Command::new(env!("CARGO_BIN_EXE_eval"))
        .args(["seg", "--checkpoint", run.to_str().unwrap()])
        .args([
            "--data",
            "datasets/fixtures/nyuv2",
            "--limit",
            "2",
            "--backend",
            "flex",
        ])
        .args([
            "--out",
            pred.to_str().unwrap(),
            "--json",
            json.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for s in [
        "Table 8",
        "Table 9",
        "| SDFCNN (this run) |",
        "| 19 | floor mat |",
    ] {
        assert!(stdout.contains(s), "{s}: {stdout}");
    }
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["images"], 2);
    assert!(v["mpa"].as_f64().unwrap() >= 0.0 && v["depth"]["rms"].as_f64().unwrap() > 0.0);
    for f in ["000433_labels.png", "000433_depth.png", "000464_figure.png"] {
        assert!(pred.join(f).is_file(), "{f}");
    }

    // A TUM-layout sequence: depth only, its camera named, frames selected.
    let tum = "datasets/fixtures/tum_fr1_rpy_head10";
    let eval = |extra: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_eval"))
            .args(["seg", "--checkpoint", run.to_str().unwrap(), "--data", tum])
            .args(["--json", json.to_str().unwrap()])
            .args(extra)
            .output()
            .unwrap()
    };
    let out = eval(&["--camera", "fr1", "--frames", "2", "8", "--every", "2"]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("no ground-truth labels"), "{stdout}");
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["images"], 3);
    assert!(v["mpa"].is_null() && v["depth"]["rms"].as_f64().unwrap() > 0.0);
    // Each image's depth range, true against predicted.
    let per_image = v["per_image"].as_array().expect("per_image");
    assert_eq!(per_image.len(), 3);
    for im in per_image {
        for key in ["true_median_m", "predicted_median_m", "log_slope"] {
            assert!(im[key].as_f64().is_some_and(f64::is_finite), "{key}: {im}");
        }
        assert!(im["true_median_m"].as_f64().unwrap() > 0.1, "{im}");
    }
    for (args, want) in [
        (&[][..], "camera"),
        (
            &["--camera", "fr1", "--frames", "4", "4"][..],
            "non-empty range",
        ),
        (&["--camera", "fr1", "--frames", "4", "11"][..], "10 frames"),
        (
            &["--camera", "configs/cameras/missing.toml"][..],
            "missing.toml",
        ),
        (&["--camera", "fr1", "--limit", "0"][..], "--limit 0"),
    ] {
        let out = eval(args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && stderr.contains(want),
            "{want}: {stderr}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn train_config_errors_name_the_line() {
    let dir = tmp("bad_config");
    let cfg = dir.join("bad.toml");
    std::fs::write(
        &cfg,
        TINY.replace("batch_size = 3", "batch_size = 3\nbatch_sise = 4"),
    )
    .unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_train"))
        .args(["--config", cfg.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("bad.toml:5:") && stderr.contains("batch_sise"),
        "{stderr}"
    );
    std::fs::write(&cfg, "model = \"unknown\"\n").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_train"))
        .args(["--config", cfg.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(String::from_utf8_lossy(&out.stderr).contains("no trainer"));
    std::fs::remove_dir_all(&dir).ok();
}
