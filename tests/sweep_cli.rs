//! `train --config SWEEP` end to end on the NYUv2 fixtures with a tiny SDFCNN (32×48): every
//! run trains in its own folder, a killed sweep resumes without retraining finished runs, the
//! result table agrees with the runs' `metrics.csv`, and bad sweeps fail before any run.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn tmp(name: &str) -> common::ScratchDir {
    common::fresh_dir("sweep_cli", name)
}

const BASE: &str = r#"model = "sdfcnn"
out = "runs/unused"
epochs = 1
batch_size = 3
[data]
train = [{ path = "datasets/fixtures/nyuv2" }]
val = [{ path = "datasets/fixtures/nyuv2" }]
size = [32, 48]
[optimizer]
kind = "adam"
lr = 0.001
lr_steps = []
[network]
inner_size = [32, 48]
decoder_dim = 16
crp_stages = 1
"#;

const SWEEP: &str = r#"model = "sweep"
base = "base.toml"
out = "OUT"
seeds = [1, 2]
select = { metric = "val_miou", mode = "max" }
[set]
epochs = 2
[grid]
"loss.lambda" = [0.2, 0.8]
"#;

/// Writes the base and the sweep (`extra` appended) into `dir`; returns the sweep's path.
fn write_files(dir: &Path, sweep: &str) -> PathBuf {
    std::fs::write(dir.join("base.toml"), BASE).unwrap();
    let path = dir.join("sweep.toml");
    let out = dir.join("out").display().to_string();
    std::fs::write(&path, sweep.replace("OUT", &out)).unwrap();
    path
}

fn train(args: &[&str]) -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_train"));
    c.args(args);
    c
}

fn text(o: &Output) -> String {
    format!(
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn ok(o: Output) -> String {
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    t
}

/// The fields of a CSV line (`"..."` quoting with `""` for a quote).
fn fields(line: &str) -> Vec<String> {
    let (mut out, mut cur, mut quoted) = (Vec::new(), String::new(), false);
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '"' if quoted && chars.peek() == Some(&'"') => {
                cur.push('"');
                chars.next();
            }
            '"' => quoted = !quoted,
            ',' if !quoted => out.push(std::mem::take(&mut cur)),
            c => cur.push(c),
        }
    }
    out.push(cur);
    out
}

/// A CSV file as its header and one map column -> cell per row.
fn csv(path: &Path) -> (Vec<String>, Vec<BTreeMap<String, String>>) {
    let body = std::fs::read_to_string(path).unwrap();
    let mut lines = body.lines();
    let header = fields(lines.next().unwrap());
    let rows = lines
        .map(|l| {
            let f = fields(l);
            assert_eq!(f.len(), header.len(), "{l}");
            header.iter().cloned().zip(f).collect()
        })
        .collect();
    (header, rows)
}

fn num(s: &str) -> f64 {
    s.parse().unwrap_or_else(|_| panic!("not a number: '{s}'"))
}

fn mtime(p: &Path) -> std::time::SystemTime {
    std::fs::metadata(p).unwrap().modified().unwrap()
}

const RUNS: [&str; 4] = [
    "lambda=0.2_seed=1",
    "lambda=0.2_seed=2",
    "lambda=0.8_seed=1",
    "lambda=0.8_seed=2",
];

#[test]
fn sweep_runs_resumes_after_a_kill_and_reports() {
    let started = Instant::now();
    let dir = tmp("run");
    let sweep = write_files(&dir, SWEEP);
    let cfg = sweep.to_str().unwrap();
    let out = dir.join("out");

    // The plan.
    let plan = ok(train(&["--config", cfg, "--dry-run"]).output().unwrap());
    assert!(
        plan.contains("2 point(s) x 2 seed(s) = 4 runs")
            && plan.contains("[4/4] lambda=0.8_seed=2 (to run)"),
        "{plan}"
    );
    assert!(!out.exists(), "a dry run writes nothing");
    let base = dir.join("base.toml");
    let checked = ok(train(&["--config", base.to_str().unwrap(), "--dry-run"])
        .output()
        .unwrap());
    assert!(checked.contains("a valid sdfcnn config"), "{checked}");

    // 1. Every run trains one epoch (`--epochs` applies to all runs).
    let log = ok(train(&["--config", cfg, "--quiet", "--epochs", "1"])
        .output()
        .unwrap());
    for (k, name) in RUNS.iter().enumerate() {
        assert!(
            log.contains(&format!("[{}/4] {name}: training, 1 epoch ->", k + 1)),
            "{log}"
        );
        let run = out.join(name);
        for f in [
            "config.toml",
            "metrics.csv",
            "loss.png",
            "checkpoints/last.json",
        ] {
            assert!(run.join(f).is_file(), "{name}/{f}");
        }
        let c = std::fs::read_to_string(run.join("config.toml")).unwrap();
        let lambda = if name.contains("0.2") { "0.2" } else { "0.8" };
        let seed = &name[name.len() - 1..];
        assert!(
            c.contains(&format!("lambda = {lambda}")) && c.contains(&format!("seed = {seed}")),
            "{c}"
        );
    }
    let (_, rows) = csv(&out.join("results.csv"));
    assert_eq!(rows.len(), 4);
    assert!(
        rows.iter()
            .all(|r| r["epochs"] == "1" && r["status"] == "done")
    );

    // 2. With the sweep's 2 epochs every run resumes from its checkpoint; kill the sweep once
    // the first run is finished.
    let mut child = train(&["--config", cfg, "--quiet"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let first = out.join(RUNS[0]).join("checkpoints/last.json");
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let done = std::fs::read_to_string(&first).is_ok_and(|t| t.contains("\"epoch\":2"));
        if done || Instant::now() > deadline {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().ok();
    child.wait().unwrap();
    let sweep_log = std::fs::read_to_string(out.join("sweep.log")).unwrap();
    assert!(
        sweep_log.contains("[1/4] lambda=0.2_seed=1: training, resuming after epoch 1 of 2"),
        "{sweep_log}"
    );
    let first_model = out.join(RUNS[0]).join("checkpoints/epoch-0002/model.bpk");
    let before = mtime(&first_model);

    // 3. Restarted: the finished run is skipped, the others continue from their last
    // checkpoint.
    let log = ok(train(&["--config", cfg, "--quiet"]).output().unwrap());
    assert!(
        log.contains("[1/4] lambda=0.2_seed=1: already done (2 epochs), skipped"),
        "{log}"
    );
    for (k, name) in RUNS.iter().enumerate().skip(1) {
        let head = format!("[{}/4] {name}: ", k + 1);
        assert!(
            log.contains(&format!("{head}already done (2 epochs), skipped"))
                || log.contains(&format!("{head}training, resuming after epoch 1 of 2")),
            "{log}"
        );
    }
    assert!(
        !log.contains("training, 2 epochs"),
        "nothing restarts from scratch: {log}"
    );
    assert_eq!(
        mtime(&first_model),
        before,
        "the finished run was not retrained"
    );
    assert!(
        log.contains("sweep finished:") && log.contains("best run: lambda="),
        "{log}"
    );

    // 4. results.csv against every run's metrics.csv.
    let (header, rows) = csv(&out.join("results.csv"));
    assert_eq!(
        header[..5],
        ["run", "loss.lambda", "seed", "status", "epochs"].map(String::from)
    );
    assert_eq!(rows.len(), 4);
    for (row, name) in rows.iter().zip(RUNS) {
        assert_eq!(row["run"], name);
        assert_eq!(
            row["loss.lambda"],
            if name.contains("0.2") { "0.2" } else { "0.8" }
        );
        assert_eq!(row["seed"], &name[name.len() - 1..]);
        assert_eq!(
            (row["status"].as_str(), row["epochs"].as_str()),
            ("done", "2")
        );
        let (_, epochs) = csv(&out.join(name).join("metrics.csv"));
        assert_eq!(epochs.len(), 2, "{name}");
        let col = |k: &str| -> Vec<f64> { epochs.iter().map(|e| num(&e[k])).collect() };
        let secs: f64 = col("seconds").iter().sum();
        assert!((num(&row["seconds"]) - secs).abs() < 2e-3, "{name}");
        for (metric, max) in [
            ("val_miou", true),
            ("val_mpa", true),
            ("val_rms", false),
            ("train_loss", false),
        ] {
            let v = col(metric);
            let best = if max {
                v.iter().cloned().fold(f64::MIN, f64::max)
            } else {
                v.iter().cloned().fold(f64::MAX, f64::min)
            };
            assert_eq!(
                num(&row[&format!("{metric}_final")]),
                v[1],
                "{name} {metric}"
            );
            assert_eq!(
                num(&row[&format!("{metric}_best")]),
                best,
                "{name} {metric}"
            );
        }
    }
    // The table: one row per λ, two seeds each, sorted by mean final mIoU.
    let md = std::fs::read_to_string(out.join("results.md")).unwrap();
    let table: Vec<&str> = md.lines().filter(|l| l.starts_with("| ")).collect();
    assert_eq!(table.len(), 3, "{md}");
    let mean = |lambda: &str| {
        rows.iter()
            .filter(|r| r["loss.lambda"] == lambda)
            .map(|r| num(&r["val_miou_final"]))
            .sum::<f64>()
            / 2.0
    };
    let (a, b) = (mean("0.2"), mean("0.8"));
    let top = if a >= b { ("0.2", a) } else { ("0.8", b) };
    assert!(
        table[1].starts_with(&format!("| 1 | {} | 2/2 | {:.4} ± ", top.0, top.1)),
        "{md}"
    );
    for f in ["metrics_vs_lambda.png", "loss_curves.png", "sweep.toml"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    eprintln!("sweep test took {:.1} s", started.elapsed().as_secs_f64());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bad_sweeps_fail_before_any_run() {
    let dir = tmp("bad");
    let cases = [
        (
            SWEEP.replace("\"loss.lambda\"", "\"loss.lambada\""),
            ":9: [grid] loss.lambada = 0.2: not a valid SDFCNN config",
            "unknown field `lambada`",
        ),
        (
            SWEEP.replace("[0.2, 0.8]", "[0.2, \"high\"]"),
            ":9: [grid] loss.lambda = \"high\"",
            "invalid type: string \"high\", expected f64",
        ),
        (
            SWEEP.replace("\"loss.lambda\" = [0.2, 0.8]\n", ""),
            "sweep.toml: nothing to sweep",
            "[grid] and [[points]] are both empty",
        ),
        (
            SWEEP.replace("[0.2, 0.8]", "[]"),
            ":9: [grid] loss.lambda = []",
            "empty",
        ),
        (
            SWEEP.replace("seeds = [1, 2]", "seeds = []"),
            ":4: seeds = [] is empty",
            "at least one seed",
        ),
    ];
    for (sweep, at, what) in cases {
        let path = write_files(&dir, &sweep);
        let o = train(&["--config", path.to_str().unwrap()])
            .output()
            .unwrap();
        let t = text(&o);
        assert!(!o.status.success(), "accepted:\n{sweep}");
        assert!(t.contains(at) && t.contains(what), "{at} / {what}:\n{t}");
        assert!(!dir.join("out").exists(), "nothing may start: {t}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_failing_run_is_recorded_and_the_others_still_run() {
    let dir = tmp("fail");
    // The second point's learning rate jumps to 1e30 after epoch 1: its loss overflows.
    let sweep = r#"model = "sweep"
base = "base.toml"
out = "OUT"
seeds = [1]
select = { metric = "val_rms" }
[set]
epochs = 2
batch_size = 2
"optimizer.kind" = "sgd"
"optimizer.lr" = 0.01
[grid]
"optimizer.lr_steps" = [[[1, 1e30]], []]
"#;
    let path = write_files(&dir, sweep);
    let o = train(&["--config", path.to_str().unwrap(), "--quiet"])
        .output()
        .unwrap();
    let t = text(&o);
    assert!(!o.status.success(), "{t}");
    assert!(
        t.contains("1 of 2 runs failed") && t.contains("lr_steps=1-1e30_seed=1: loss became"),
        "{t}"
    );
    let out = dir.join("out");
    assert!(
        t.contains("[2/2] lr_steps=empty_seed=1: finished"),
        "the sweep went on: {t}"
    );
    let (_, rows) = csv(&out.join("results.csv"));
    assert_eq!(rows.len(), 2);
    assert_eq!(rows[0]["optimizer.lr_steps"], "[[1, 1e30]]");
    assert_eq!(
        (rows[0]["status"].as_str(), rows[0]["epochs"].as_str()),
        ("failed", "1")
    );
    assert_eq!(
        (rows[1]["status"].as_str(), rows[1]["epochs"].as_str()),
        ("done", "2")
    );
    let err = std::fs::read_to_string(out.join("lr_steps=1-1e30_seed=1/error.txt")).unwrap();
    assert!(err.contains("loss became"), "{err}");
    let md = std::fs::read_to_string(out.join("results.md")).unwrap();
    assert!(
        md.contains("- `lr_steps=1-1e30_seed=1`: failed after 1 epoch(s): loss became"),
        "{md}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
