//! `train` with no `--config`: the default run (SDFCNN on the NYUv2 fixtures), here cut to one
//! epoch, from a working directory outside the repository (the config and the fixtures are
//! found in the crate's folder; the run folder is written under the working directory).

mod common;

use std::path::Path;
use std::process::{Command, Output};

fn train(cwd: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_train"))
        .args(args)
        .current_dir(cwd)
        .output()
        .unwrap()
}

fn text(out: &Output) -> String {
    format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

#[test]
fn the_default_run_trains_reports_and_replaces_its_earlier_run() {
    let cwd = common::fresh_dir("train_default", "cwd");
    let out = train(&cwd, &["--epochs", "1", "--quiet"]);
    let said = text(&out);
    assert!(out.status.success(), "{said}");
    let run = cwd.join("runs/train/default");
    assert!(
        run.join("checkpoints/epoch-0001/model.bpk").is_file(),
        "{said}"
    );
    let metrics = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    assert_eq!(metrics.lines().count(), 2, "{metrics}");
    assert!(metrics.starts_with("epoch,lr,seconds") && metrics.contains("train_loss"));
    for s in [
        "no --config: the default run",
        "Trained SDFCNN",
        "for 1 epoch in",
        "Outputs in runs/train/default:",
        "metrics.csv  one row per epoch",
        "checkpoints/epoch-0001/  the newest checkpoint",
        "loss.png",
        "train --config configs/train/sdfcnn_real.toml",
        "train --config configs/train/sweep_lambda_lr.toml",
        "FPFDCNN as bundled",
        "eval seg --checkpoint runs/train/default",
    ] {
        assert!(said.contains(s), "{s}: {said}");
    }
    assert!(!said.contains("replacing"), "{said}");

    // Again: the earlier default run is replaced, not refused.
    let out = train(&cwd, &["--epochs", "1", "--quiet"]);
    let said = text(&out);
    assert!(out.status.success(), "{said}");
    assert!(said.contains("replacing the earlier default run"), "{said}");
    assert!(!run.join("checkpoints/epoch-0002").exists());

    // A folder there that another run made is left alone.
    std::fs::remove_dir_all(&run).unwrap();
    std::fs::create_dir_all(&run).unwrap();
    std::fs::write(
        run.join("config.toml"),
        "model = \"sdfcnn\"\nout = \"mine\"\n",
    )
    .unwrap();
    let out = train(&cwd, &["--epochs", "1"]);
    let said = text(&out);
    assert!(!out.status.success(), "{said}");
    assert!(said.contains("is not a default run"), "{said}");
    assert!(run.join("config.toml").is_file());
}

#[test]
fn the_default_run_checks_with_dry_run_and_help_still_prints() {
    let cwd = common::fresh_dir("train_default", "dry");
    let out = train(&cwd, &["--dry-run"]);
    let said = text(&out);
    assert!(out.status.success(), "{said}");
    assert!(
        said.contains("the default run: a valid sdfcnn config"),
        "{said}"
    );
    assert!(!cwd.join("runs").exists(), "a dry run writes nothing");

    let out = train(&cwd, &["--help"]);
    let said = text(&out);
    assert!(out.status.success(), "{said}");
    assert!(
        said.contains("--config") && said.contains("runs/train/default"),
        "{said}"
    );
}
