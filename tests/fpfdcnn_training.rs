//! FPFDCNN training end to end on the real fixture frames at a tiny size:
//! checkpoints, metrics, resume that continues exactly, bad configs.

mod common;

use sdf_slam::training::{RunDir, RunOptions};
use std::path::Path;

const CONFIG: &str = r#"
model = "fpfdcnn"
seed = 7
epochs = 2
batch_size = 2

[optimizer]
lr = 0.001

[network]
descriptor_dim = 32

[data]
size = [32, 48]
pairs_per_epoch = 4
val_fraction = 0.3

[[data.sequences]]
path = "datasets/fixtures/tum_fr1_rpy_head10"

[data.pairs]
gaps = [1, 2]

[loss]
max_matches = 16
exclusion_px = 2.0
"#;

/// Burn's seeded random stream is global to the process, so two trainings at once would draw
/// from each other's: the tests that train take turns.
static TRAINING: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn tmp(name: &str) -> common::ScratchDir {
    common::fresh_path("fptrain", name)
}

fn run(out: &Path, epochs: usize, resume: bool) -> sdf_slam::Result<()> {
    let opts = RunOptions {
        out: Some(out.to_path_buf()),
        resume,
        epochs: Some(epochs),
        quiet: true,
        ..Default::default()
    };
    sdf_slam::fpfdcnn::training::run(Path::new("inline.toml"), CONFIG, &opts)
}

#[test]
fn resumed_training_continues_exactly() {
    let _turn = TRAINING.lock().unwrap_or_else(|e| e.into_inner());
    let (full, split) = (tmp("full"), tmp("split"));
    run(&full, 2, false).unwrap();
    run(&split, 1, false).unwrap();
    // Starting again without --resume would overwrite: refused.
    assert!(
        run(&split, 2, false)
            .unwrap_err()
            .to_string()
            .contains("--resume")
    );
    run(&split, 2, true).unwrap();
    let a = RunDir {
        root: full.to_path_buf(),
        keep: 0,
    }
    .latest()
    .unwrap()
    .unwrap();
    let b = RunDir {
        root: split.to_path_buf(),
        keep: 0,
    }
    .latest()
    .unwrap()
    .unwrap();
    assert_eq!(a.state.epoch, 2);
    assert_eq!(b.state.epoch, 2);
    for (ea, eb) in a.state.history.epochs.iter().zip(&b.state.history.epochs) {
        for (k, va) in &ea.values {
            let vb = eb.values[k];
            assert!(
                (va - vb).abs() <= 1e-5 * va.abs().max(1.0),
                "epoch {} {k}: {va} vs {vb}",
                ea.epoch
            );
        }
    }
    for f in [
        "metrics.csv",
        "loss.png",
        "config.toml",
        "checkpoints/epoch-0002/model.bpk",
        "checkpoints/epoch-0002/optimizer.bpk",
        "checkpoints/epoch-0002/config.toml",
    ] {
        assert!(split.join(f).is_file(), "{f}");
    }
    let csv = std::fs::read_to_string(split.join("metrics.csv")).unwrap();
    assert_eq!(csv.lines().count(), 3, "{csv}");
    // The checkpoint loads for inference, and a checkpoint from another config is refused.
    let det =
        sdf_slam::fpfdcnn::FpfdcnnDetector::load(&split, Default::default(), Default::default())
            .unwrap();
    let img =
        image::GrayImage::from_fn(64, 48, |x, y| image::Luma([((x * 13 + y * 7) % 255) as u8]));
    assert!(!det.detect(&img).unwrap().is_empty());
    let ckpt = split.join("checkpoints/epoch-0002");
    let cfg = std::fs::read_to_string(ckpt.join("config.toml")).unwrap();
    std::fs::write(
        ckpt.join("config.toml"),
        cfg.replace("descriptor_dim = 32", "descriptor_dim = 64"),
    )
    .unwrap();
    let e = sdf_slam::fpfdcnn::FpfdcnnDetector::load(&ckpt, Default::default(), Default::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("model.bpk") && e.contains("config.toml"), "{e}");
    std::fs::remove_dir_all(full).unwrap();
    std::fs::remove_dir_all(split).unwrap();
}

/// Both shift-consistency terms run in a real training step and reach the metrics.
#[test]
fn shift_consistency_terms_train_and_are_recorded() {
    let _turn = TRAINING.lock().unwrap_or_else(|e| e.into_inner());
    let out = tmp("shift");
    let config = CONFIG.replace(
        "[loss]\n",
        "[loss]\nshift_consistency = 1.0\ndescriptor_shift_consistency = 4.0\n",
    );
    let opts = RunOptions {
        out: Some(out.to_path_buf()),
        epochs: Some(1),
        quiet: true,
        ..Default::default()
    };
    sdf_slam::fpfdcnn::training::run(Path::new("inline.toml"), &config, &opts).unwrap();
    let latest = RunDir {
        root: out.to_path_buf(),
        keep: 0,
    }
    .latest()
    .unwrap()
    .unwrap();
    let values = &latest.state.history.epochs[0].values;
    for key in ["train_shift", "train_dshift", "val_shift", "val_dshift"] {
        let v = values[key];
        assert!(v.is_finite() && v >= 0.0, "{key} = {v}");
    }
    // 1 - cos of unit descriptors towards their mean: below 1 unless they oppose.
    assert!(values["train_dshift"] < 1.0, "{values:?}");
    std::fs::remove_dir_all(out).unwrap();
}

#[test]
fn bad_configs_are_clear_errors() {
    let out = tmp("bad");
    let opts = RunOptions {
        out: Some(out.to_path_buf()),
        quiet: true,
        ..Default::default()
    };
    let e = sdf_slam::fpfdcnn::training::run(
        Path::new("x.toml"),
        &CONFIG.replace("lr = 0.001", "lr = 0.001\nlearning_rate = 3"),
        &opts,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("x.toml:") && e.contains("learning_rate"), "{e}");
    let e = sdf_slam::fpfdcnn::training::run(
        Path::new("x.toml"),
        &CONFIG.replace("size = [32, 48]", "size = [30, 48]"),
        &opts,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("multiples of 16"), "{e}");
    let e = sdf_slam::fpfdcnn::training::run(
        Path::new("x.toml"),
        &CONFIG.replace("tum_fr1_rpy_head10", "nowhere"),
        &opts,
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("nowhere"), "{e}");
}
