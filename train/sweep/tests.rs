use super::report::{self, Status};
use super::run::utc_now;
use super::values::sanitize;
use super::*;
use sdf_slam::error::Result;
use sdf_slam::training::{EpochRecord, History, RunDir, RunOptions, TrainState};
use std::path::Path;
use toml::Table;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sdf_sweep_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

/// A tiny SDFCNN config on the NYUv2 fixtures.
const BASE: &str = r#"model = "sdfcnn"
out = "unused"
epochs = 3
batch_size = 3
[data]
train = [{ path = "datasets/fixtures/nyuv2" }]
val = [{ path = "datasets/fixtures/nyuv2" }]
size = [32, 48]
[loss]
lambda = 0.4
[network]
inner_size = [32, 48]
decoder_dim = 16
crp_stages = 1
"#;

/// The grid lists `optimizer.lr` before `loss.lambda`: runs follow the file's order.
const SWEEP: &str = r#"model = "sweep"
base = "base.toml"
out = "OUT"
seeds = [1, 2]
select = { metric = "val_miou" }

[set]
epochs = 2
"optimizer.momentum" = 0.5

[grid]
"optimizer.lr" = [0.01, 0.1]
"loss.lambda" = [0.2, 0.8]
"#;

/// Writes `base.toml` and `sweep.toml` (with `OUT` replaced) into `dir`.
fn files(dir: &Path, base: &str, sweep: &str) -> (PathBuf, String) {
    std::fs::write(dir.join("base.toml"), base).expect("write base");
    let text = sweep.replace("OUT", &dir.join("out").display().to_string());
    let path = dir.join("sweep.toml");
    std::fs::write(&path, &text).expect("write sweep");
    (path, text)
}

fn load(dir: &Path, base: &str, sweep: &str) -> Result<Sweep> {
    let (path, text) = files(dir, base, sweep);
    Sweep::load(&path, &text, &RunOptions::default())
}

#[test]
fn sdfcnn_sweep_plans_every_point_and_seed() {
    let dir = tmp("plan");
    let s = load(&dir, BASE, SWEEP).expect("valid sweep");
    assert_eq!(s.keys, ["optimizer.lr", "loss.lambda"]);
    assert_eq!(s.labels(), ["lr", "lambda"]);
    let names: Vec<&str> = s.runs.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "lr=0.01_lambda=0.2_seed=1",
            "lr=0.01_lambda=0.2_seed=2",
            "lr=0.01_lambda=0.8_seed=1",
            "lr=0.01_lambda=0.8_seed=2",
            "lr=0.1_lambda=0.2_seed=1",
            "lr=0.1_lambda=0.2_seed=2",
            "lr=0.1_lambda=0.8_seed=1",
            "lr=0.1_lambda=0.8_seed=2",
        ]
    );
    assert_eq!(s.select.metric, "val_miou");
    assert!(s.select.maximize, "mIoU: larger is better");
    assert_eq!(s.plots, ["val_miou", "val_rms"]);
    // Each run's config is a complete trainer config with the point's values.
    let r = &s.runs[6];
    assert_eq!(r.epochs, 2);
    assert_eq!(r.dir, dir.join("out").join(&r.name));
    let cfg = sdf_slam::sdfcnn::SdfcnnTrainConfig::parse(&r.config, Path::new("run.toml"))
        .expect("run config parses");
    assert_eq!(
        (cfg.optimizer.lr, cfg.loss.lambda, cfg.seed, cfg.epochs),
        (0.1, 0.8, 1, 2)
    );
    assert_eq!(cfg.optimizer.momentum, 0.5, "[set] applies to every run");
    assert_eq!(cfg.out, r.dir);
    assert_eq!(cfg.data.size, [32, 48], "the base's other fields are kept");
    // --epochs and --out apply to every run.
    let (path, text) = files(&dir, BASE, SWEEP);
    let opts = RunOptions {
        epochs: Some(5),
        out: Some(dir.join("elsewhere")),
        ..Default::default()
    };
    let s = Sweep::load(&path, &text, &opts).expect("valid");
    assert!(s.runs.iter().all(|r| r.epochs == 5));
    assert!(s.runs[0].dir.starts_with(dir.join("elsewhere")));
    // The run configs do not depend on how the sweep file is named (resuming compares them).
    let other = Sweep::load(&dir.join(".").join("sweep.toml"), &text, &opts).expect("valid");
    assert_eq!(other.runs[3].config, s.runs[3].config);
    let plan = s.describe().expect("plan");
    assert!(
        plan.contains("[8/8] lr=0.1_lambda=0.8_seed=2 (to run)"),
        "{plan}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn points_nested_tables_and_defaults() {
    let dir = tmp("points");
    // A field the base file does not list (`loss.depth` has a default), nested grid tables,
    // and listed points; a point that leaves a varied field alone shows the base's value.
    let sweep = r#"model = "sweep"
base = "base.toml"
out = "OUT"
seeds = [7]
select = { metric = "val_rms", at = "best" }
plot = ["val_delta1"]
[grid.loss]
depth = ["l1", "berhu"]
[[points]]
loss = { lambda = 0.9 }
[[points]]
"loss.depth" = "l2"
"data.augment.flip" = false
"#;
    let s = load(&dir, BASE, sweep).expect("valid sweep");
    assert_eq!(s.keys, ["loss.depth", "loss.lambda", "data.augment.flip"]);
    let names: Vec<&str> = s.points.iter().map(|p| p.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "depth=l1_lambda=0.4_flip=true",
            "depth=berhu_lambda=0.4_flip=true",
            "depth=berhu_lambda=0.9_flip=true",
            "depth=l2_lambda=0.4_flip=false",
        ]
    );
    assert!(!s.select.maximize, "RMS: smaller is better");
    assert_eq!(s.select.at, At::Best);
    assert_eq!(s.plots, ["val_rms", "val_delta1"]);
    std::fs::remove_dir_all(&dir).ok();
}

/// The error of `sweep` (the default base), which must name the sweep file and line and
/// contain every one of `parts`.
fn expect_error(dir: &Path, sweep: &str, line: Option<usize>, parts: &[&str]) {
    let e = match load(dir, BASE, sweep) {
        Ok(_) => panic!("accepted:\n{sweep}"),
        Err(e) => e.to_string(),
    };
    let file = dir.join("sweep.toml").display().to_string();
    match line {
        Some(l) => assert!(e.starts_with(&format!("{file}:{l}: ")), "{e}"),
        None => assert!(e.starts_with(&file), "{e}"),
    }
    for p in parts {
        assert!(e.contains(p), "'{p}' not in: {e}");
    }
}

#[test]
fn bad_sweeps_are_rejected_before_any_run() {
    let dir = tmp("bad");
    let head = "model = \"sweep\"\nbase = \"base.toml\"\nout = \"OUT\"\nseeds = [1]\nselect = { metric = \"val_miou\" }\n";
    bad_overrides(&dir, head);
    bad_lists_and_seeds(&dir, head);
    bad_sweep_fields(&dir, head);
    bad_bases(&dir, head);
    std::fs::remove_dir_all(&dir).ok();
}

/// Overrides the trainer refuses.
fn bad_overrides(dir: &Path, head: &str) {
    let with = |rest: &str| format!("{head}{rest}");
    // A field the trainer does not have (lines: the key's line in the sweep file).
    expect_error(
        dir,
        &with("[grid]\n\"loss.lambada\" = [0.2]\n"),
        Some(7),
        &[
            "[grid] loss.lambada = 0.2",
            "SDFCNN",
            "unknown field `lambada`",
        ],
    );
    expect_error(
        dir,
        &with("[grid]\n\"optimiser.lr\" = [0.2]\n"),
        Some(7),
        &["unknown field `optimiser`"],
    );
    // A wrong type, and a value the trainer refuses.
    expect_error(
        dir,
        &with("[grid]\n\"loss.lambda\" = [0.2, \"high\"]\n"),
        Some(7),
        &["loss.lambda = \"high\"", "invalid type: string \"high\""],
    );
    expect_error(
        dir,
        &with("[grid]\n\"loss.depth\" = [\"l3\"]\n"),
        Some(7),
        &["loss.depth = \"l3\"", "unknown variant `l3`"],
    );
    expect_error(
        dir,
        &with("[grid]\n\"loss.lambda\" = [0.2, 2.0]\n"),
        Some(7),
        &["loss.lambda = 2.0", "must be in [0, 1]"],
    );
    expect_error(
        dir,
        &with("[set]\n\"batch_size\" = \"big\"\n[grid]\n\"loss.lambda\" = [0.2]\n"),
        Some(7),
        &["[set] batch_size", "invalid type"],
    );
    // A path through a value that is not a table.
    expect_error(
        dir,
        &with("[grid]\n\"loss.lambda.x\" = [1]\n"),
        Some(7),
        &["`loss.lambda` is a float in the base config, not a table"],
    );
}

/// Nothing to sweep, bad value lists, bad seeds.
fn bad_lists_and_seeds(dir: &Path, head: &str) {
    let with = |rest: &str| format!("{head}{rest}");
    // Empty grid, empty list, a value that is not a list, no seeds.
    expect_error(dir, &with("[grid]\n"), None, &["nothing to sweep"]);
    expect_error(
        dir,
        &with("[grid]\n\"loss.lambda\" = []\n"),
        Some(7),
        &["[grid] loss.lambda = []", "empty"],
    );
    expect_error(
        dir,
        &with("[grid]\n\"loss.lambda\" = 0.4\n"),
        Some(7),
        &["takes a list of values"],
    );
    expect_error(
        dir,
        &with("[grid]\n\"loss.lambda\" = [0.2, 0.2]\n"),
        Some(7),
        &["0.2 is listed twice"],
    );
    expect_error(
        dir,
        &head.replace("seeds = [1]", "seeds = []").to_string(),
        Some(4),
        &["seeds = [] is empty"],
    );
    expect_error(
        dir,
        &with("[grid]\n\"loss.lambda\" = [0.2]\n").replace("seeds = [1]\n", ""),
        None,
        &["missing field `seeds`"],
    );
}

/// Bad fields of the sweep itself.
fn bad_sweep_fields(dir: &Path, head: &str) {
    let with = |rest: &str| format!("{head}{rest}");
    // The sweep's own fields: unknown ones, reserved fields, metrics the trainer lacks.
    expect_error(
        dir,
        &with("grids = 1\n[grid]\n\"loss.lambda\" = [0.2]\n"),
        Some(6),
        &["unknown field `grids`"],
    );
    expect_error(
        dir,
        &with("[grid]\nseed = [1, 2]\n"),
        Some(7),
        &["seeds are given by the sweep's `seeds"],
    );
    expect_error(
        dir,
        &with("[set]\n\"loss.lambda\" = 0.3\n[grid]\n\"loss.lambda\" = [0.2]\n"),
        Some(9),
        &["also in [set]"],
    );
    expect_error(
        dir,
        &with("[grid]\n\"loss.lambda\" = [0.2]\n").replace("val_miou", "val_top1"),
        Some(5),
        &[
            "\"val_top1\" is not a metric of the SDFCNN trainer",
            "val_miou",
        ],
    );
    expect_error(
        dir,
        &with("[grid]\n\"loss.lambda\" = [0.4]\n[[points]]\n\"loss.lambda\" = 0.4\n"),
        Some(8),
        &["same configuration as point"],
    );
}

/// Base configs a sweep cannot run.
fn bad_bases(dir: &Path, head: &str) {
    let with = |rest: &str| format!("{head}{rest}");
    // A base that is not a training config.
    let e = load(
        dir,
        "model = \"slam\"\n",
        &with("[grid]\n\"loss.lambda\" = [0.2]\n"),
    )
    .err()
    .expect("bad base");
    assert!(
        e.to_string().contains(":2: ") && e.to_string().contains("model = \"slam\""),
        "{e}"
    );
    // A base naming data that does not exist.
    let e = load(
        dir,
        &BASE.replace(
            "datasets/fixtures/nyuv2\" }]\nval",
            "datasets/missing\" }]\nval",
        ),
        &with("[grid]\n\"loss.lambda\" = [0.2]\n"),
    )
    .err()
    .expect("missing data");
    assert!(
        e.to_string().contains("cannot be opened") && e.to_string().contains("datasets/missing"),
        "{e}"
    );
    // Selecting by a validation metric when the base has no validation data.
    let no_val = BASE.replace("val = [{ path = \"datasets/fixtures/nyuv2\" }]\n", "");
    assert_ne!(no_val, BASE);
    let e = load(dir, &no_val, &with("[grid]\n\"loss.lambda\" = [0.2]\n"))
        .err()
        .expect("no validation data");
    let e = e.to_string();
    assert!(
        e.contains(":5: ") && e.contains("is a validation metric") && e.contains("[[data.val]]"),
        "{e}"
    );
    // A train_* metric is fine then.
    load(
        dir,
        &no_val,
        &with("[grid]\n\"loss.lambda\" = [0.2]\n").replace("val_miou", "train_loss"),
    )
    .expect("train metric without validation data");
}

#[test]
fn fpfdcnn_sweep_validates() {
    let dir = tmp("fpfdcnn");
    let base = std::fs::read_to_string("configs/train/fpfdcnn_tiny.toml").expect("shipped config");
    let sweep = r#"model = "sweep"
base = "base.toml"
out = "OUT"
seeds = [1]
select = { metric = "val_desc_top1" }
[grid]
"optimizer.lr" = [0.001, 0.0003]
"loss.descriptor_weight" = [0.5, 1.0, 2.0]
"#;
    let s = load(&dir, &base, sweep).expect("valid fpfdcnn sweep");
    assert_eq!(s.trainer.model, "fpfdcnn");
    assert_eq!(s.runs.len(), 6);
    assert_eq!(s.runs[5].name, "lr=0.0003_descriptor_weight=2_seed=1");
    assert_eq!(s.plots, ["val_desc_top1", "val_loss"]);
    let cfg =
        sdf_slam::fpfdcnn::training::FpfdcnnTrainConfig::parse(&s.runs[5].config, Path::new("x"))
            .expect("run config parses");
    assert_eq!(
        (cfg.optimizer.lr, cfg.loss.descriptor_weight),
        (0.0003, 2.0)
    );
    // The keys of before 2026-11-26 say where they moved; SDFCNN's metrics are not FPFDCNN's.
    let e = load(&dir, &base, &sweep.replace("\"optimizer.lr\" = ", "lr = "))
        .err()
        .expect("top-level lr is refused");
    assert!(e.to_string().contains("`lr` -> `optimizer.lr`"), "{e}");
    let e = load(&dir, &base, &sweep.replace("val_desc_top1", "val_miou"))
        .err()
        .expect("no mIoU");
    assert!(e.to_string().contains("FPFDCNN trainer"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

/// Writes a fake finished (or partial) run: a checkpoint without weights and its metrics.
fn fake_run(run: &Run, epochs: usize, miou: &[f64], rms: f64) {
    let dir = RunDir {
        root: run.dir.clone(),
        keep: 0,
    };
    std::fs::create_dir_all(&run.dir).expect("run dir");
    sdf_slam::io::write_atomic(run.dir.join("config.toml"), run.config.as_bytes()).expect("cfg");
    let mut history = History::default();
    for e in 1..=epochs {
        let mut values = BTreeMap::new();
        values.insert("train_loss".to_string(), 2.0 / e as f64);
        values.insert("val_loss".to_string(), 2.5 / e as f64);
        values.insert("val_miou".to_string(), miou[e - 1]);
        values.insert("val_rms".to_string(), rms / e as f64);
        history.push(EpochRecord {
            epoch: e,
            lr: 0.1,
            seconds: 10.0,
            values,
        });
    }
    history.write_csv(run.dir.join("metrics.csv")).expect("csv");
    let state = TrainState {
        epoch: epochs,
        step: epochs as u64,
        history,
    };
    dir.save(&state, &run.config, |_| Ok(()))
        .expect("checkpoint");
}

use std::collections::BTreeMap;

#[test]
fn results_tables_and_plots_from_run_folders() {
    let dir = tmp("report");
    let s = load(&dir, BASE, SWEEP).expect("valid sweep");
    // Point lr=0.01, lambda=0.2 (runs 0, 1): final mIoU 0.3 and 0.5; lr=0.1, lambda=0.8 (runs
    // 6, 7): 0.6 and 0.6, run 7 only after 1 of 2 epochs; run 2 finished with 0.1.
    fake_run(&s.runs[0], 2, &[0.2, 0.3], 1.0);
    fake_run(&s.runs[1], 2, &[0.6, 0.5], 2.0);
    fake_run(&s.runs[2], 2, &[0.05, 0.1], 1.0);
    fake_run(&s.runs[6], 2, &[0.4, 0.6], 1.0);
    fake_run(&s.runs[7], 1, &[0.6], 1.0);
    // A folder written by another config is refused before anything runs.
    let (path, text) = files(&dir, BASE, SWEEP);
    let other = text.replace(
        "\"optimizer.momentum\" = 0.5",
        "\"optimizer.momentum\" = 0.6",
    );
    let e = Sweep::load(&path, &other, &RunOptions::default())
        .err()
        .expect("config changed");
    assert!(
        e.to_string()
            .contains("optimizer.momentum = 0.5 there, 0.6 in the sweep"),
        "{e}"
    );
    // A changed number of epochs is fine (the runs are then resumed).
    let more = text.replace("epochs = 2", "epochs = 4");
    Sweep::load(&path, &more, &RunOptions::default()).expect("only epochs changed");

    let best = report::write(&s).expect("reports").expect("a best run");
    assert_eq!(
        best,
        "best run: lr=0.1_lambda=0.8_seed=1 (val_miou 0.6000 at epoch 2)"
    );
    let results = report::collect(&s).expect("collect");
    assert_eq!(results.len(), 5);
    assert_eq!(results[4].status, Status::Incomplete);
    let csv = std::fs::read_to_string(s.out.join("results.csv")).expect("csv");
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(
        lines[0],
        "run,optimizer.lr,loss.lambda,seed,status,epochs,seconds,val_miou_final,val_miou_best,\
         val_miou_best_epoch,val_mpa_final,val_mpa_best,val_rms_final,val_rms_best,val_rel_final,\
         val_rel_best,val_delta1_final,val_delta1_best,val_loss_final,val_loss_best,\
         train_loss_final,train_loss_best"
    );
    assert!(
        lines[2].starts_with("lr=0.01_lambda=0.2_seed=2,0.01,0.2,2,done,2,20.000,0.5,0.6,1,,,1,1,"),
        "{}",
        lines[2]
    );
    assert!(lines[5].contains(",incomplete,1,"), "{}", lines[5]);
    let md = std::fs::read_to_string(s.out.join("results.md")).expect("md");
    let rows: Vec<&str> = md.lines().filter(|l| l.starts_with("| ")).collect();
    assert!(
        rows[0].starts_with("| rank | lr | lambda | seeds | val_miou |"),
        "{md}"
    );
    // Sorted by mean final mIoU: 0.6 (one finished seed), 0.4 ± 0.1414, 0.1.
    assert!(
        rows[1].starts_with("| 1 | 0.1 | 0.8 | 1/2 | 0.6000 | 0.6000 |"),
        "{md}"
    );
    assert!(
        rows[2].starts_with("| 2 | 0.01 | 0.2 | 2/2 | 0.4000 ± 0.1414 | 0.4500 ± 0.2121 |"),
        "{md}"
    );
    assert!(
        rows[3].starts_with("| 3 | 0.01 | 0.8 | 1/2 | 0.1000 |"),
        "{md}"
    );
    assert!(
        md.contains("- `lr=0.1_lambda=0.8_seed=2`: 1 of 2 epochs"),
        "{md}"
    );
    assert!(md.contains("- 3 run(s) not started"), "{md}");
    for f in ["metrics_vs_lr.png", "loss_curves.png"] {
        let img = image::open(s.out.join(f)).expect(f);
        assert_eq!(img.width(), 1800, "{f}: two charts side by side");
    }
    // A metrics.csv behind its checkpoint (killed between the writes) is rebuilt from it.
    let csv0 = s.runs[0].dir.join("metrics.csv");
    let full = std::fs::read_to_string(&csv0).expect("csv");
    let first: String = full.lines().take(2).map(|l| format!("{l}\n")).collect();
    std::fs::write(&csv0, first).expect("truncate");
    report::collect(&s).expect("collect");
    assert_eq!(std::fs::read_to_string(&csv0).expect("csv"), full);
    // A malformed metrics.csv names its file and line.
    std::fs::write(&csv0, "epoch,lr,seconds,val_miou\n1,0.1,2.0,abc\n").expect("write");
    let e = report::collect(&s).expect_err("bad csv").to_string();
    assert!(e.contains("metrics.csv:2:") && e.contains("abc"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn names_labels_and_statistics() {
    assert_eq!(sanitize("lr_steps=[[20, 0.01]]"), "lr_steps=20-0.01");
    assert_eq!(sanitize("name=\"a b/c\""), "name=a-b-c");
    assert_eq!(value_label(&Value::Float(0.1)), "0.1");
    assert_eq!(value_label(&Value::Float(1.0)), "1");
    assert_eq!(value_label(&Value::Float(1e30)), "1e30");
    assert_eq!(value_label(&Value::Float(-2e-5)), "-2e-5");
    assert_eq!(value_label(&Value::Float(0.0)), "0");
    let steps: Value = toml::from_str::<Table>("v = [[1, 1e30], [5, 0.5]]").unwrap()["v"].clone();
    assert_eq!(value_label(&steps), "[[1, 1e30], [5, 0.5]]");
    assert_eq!(value_label(&Value::String("berhu".into())), "berhu");
    let keys = [
        "optimizer.lr".to_string(),
        "loss.lr".into(),
        "loss.lambda".into(),
    ];
    assert_eq!(short_labels(&keys), ["optimizer.lr", "loss.lr", "lambda"]);
    assert_eq!(report::mean_std(&[1.0, 3.0]), Some((2.0, 2f64.sqrt())));
    assert_eq!(report::mean_std(&[4.0]), Some((4.0, 0.0)));
    assert!(larger_is_better("val_miou") && larger_is_better("val_desc_top1"));
    assert!(!larger_is_better("val_rms") && !larger_is_better("val_detector"));
    let stamp = utc_now();
    assert!(stamp.len() == 19 && stamp.starts_with("20"), "{stamp}");
}

#[test]
fn shipped_sweeps_validate() {
    let p = Path::new("configs/train/sweep_fpfdcnn_tiny.toml");
    let text = std::fs::read_to_string(p).expect("shipped sweep");
    let s = Sweep::load(p, &text, &RunOptions::default()).expect("valid");
    assert_eq!((s.trainer.model, s.runs.len()), ("fpfdcnn", 4));
    // The λ x lr sweep: its data are generated (datasets/generated/sweep, not in git), so
    // without them only the data check, which comes after every point's, may fail.
    let p = Path::new("configs/train/sweep_lambda_lr.toml");
    let text = std::fs::read_to_string(p).expect("shipped sweep");
    match Sweep::load(p, &text, &RunOptions::default()) {
        Ok(s) => {
            assert_eq!(s.keys, ["loss.lambda", "optimizer.lr"]);
            assert_eq!(s.runs.len(), 8);
            assert_eq!(s.runs[2].name, "lambda=0.4_lr=0.01_seed=1");
        }
        Err(e) => {
            let e = e.to_string();
            assert!(
                e.contains("cannot be opened") && e.contains("datasets/generated/sweep"),
                "{e}"
            );
        }
    }
}
