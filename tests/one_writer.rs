//! One writer per output folder, and runs never silently mixed: two `slam` or `train`
//! processes into one folder (the second fails naming the first's pid, the folder holds the
//! first's files), a lock left by a killed process taken over, a training folder that holds
//! another run (or checkpoints without `last.json`), `train export` onto its own source,
//! `train average` across runs, and `--resume` with another network's optimizer state or an
//! impossible epoch counter. The processes are paused with SIGSTOP while the other one tries,
//! so the overlap does not depend on timing.
#![cfg(unix)]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const LOCK: &str = sdf_slam::output_lock::LOCK_FILE;

fn tmp(name: &str) -> common::ScratchDir {
    common::fresh_dir("one_writer", name)
}

fn root() -> &'static Path {
    common::manifest_dir()
}

fn fixture() -> String {
    root()
        .join("datasets/fixtures/tum_fr1_rpy_head10")
        .display()
        .to_string()
}

fn text(o: &Output) -> String {
    format!(
        "{}\n{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn slam_args(out: &Path, first: usize) -> Vec<String> {
    [
        "--sequence",
        &fixture(),
        "--features",
        "orb",
        "--labels",
        "none",
        "--single-thread",
        "--first",
        &first.to_string(),
        "--out",
        out.to_str().unwrap(),
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

fn command(bin: &str, args: &[String]) -> Command {
    let mut c = Command::new(bin);
    c.args(args).current_dir(root());
    c
}

fn spawn(bin: &str, args: &[String]) -> Child {
    command(bin, args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn run(bin: &str, args: &[String]) -> Output {
    command(bin, args).output().unwrap()
}

fn signal(pid: u32, sig: &str) {
    let ok = Command::new("kill")
        .args([sig, &pid.to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok, "kill {sig} {pid}");
}

/// Waits until `child` holds `dir`'s lock (its pid in the lock file), then stops it
/// (SIGSTOP): it holds the folder for as long as the test wants.
fn stop_when_locked(child: &mut Child, dir: &Path) {
    let want = format!("pid = {}\n", child.id());
    let started = Instant::now();
    loop {
        if std::fs::read_to_string(dir.join(LOCK)).is_ok_and(|t| t.contains(&want)) {
            signal(child.id(), "-STOP");
            return;
        }
        if let Some(status) = child.try_wait().unwrap() {
            panic!("the first process ended ({status}) before it was seen holding the lock");
        }
        assert!(
            started.elapsed() < Duration::from_secs(300),
            "no lock after 5 min"
        );
        std::thread::sleep(Duration::from_millis(1));
    }
}

fn first_pose_time(out: &Path) -> String {
    let traj = std::fs::read_to_string(out.join("trajectory.txt")).unwrap();
    let line = traj
        .lines()
        .find(|l| !l.starts_with('#') && !l.trim().is_empty())
        .unwrap();
    line.split_whitespace().next().unwrap().to_string()
}

#[test]
fn a_second_slam_into_the_same_folder_fails_naming_the_first() {
    let dir = tmp("slam_two");
    let out = dir.join("out");
    let slam = env!("CARGO_BIN_EXE_slam");
    let mut first = spawn(slam, &slam_args(&out, 0));
    stop_when_locked(&mut first, &out);
    // The second, another segment of the sequence into the same folder.
    let second = run(slam, &slam_args(&out, 3));
    signal(first.id(), "-CONT");
    let t = text(&second);
    assert!(!second.status.success(), "{t}");
    assert!(
        t.contains(&format!(
            "{} is being written by process {} (`slam ",
            out.display(),
            first.id()
        )) && t.contains("choose another --out"),
        "{t}"
    );
    let first = first.wait_with_output().unwrap();
    assert!(first.status.success(), "{}", text(&first));
    // The folder holds the first run's outputs only (the second's would start at frame 3).
    assert!(!first_pose_time(&out).starts_with("1305031229.6287"));
    for f in ["trajectory.txt", "map.ply", "report.json"] {
        assert!(out.join(f).is_file(), "{f}");
    }
    assert!(!out.join(LOCK).exists(), "the lock file goes with the lock");
}

#[test]
fn a_lock_left_by_a_killed_process_is_taken_over() {
    let dir = tmp("slam_killed");
    let out = dir.join("out");
    let slam = env!("CARGO_BIN_EXE_slam");
    let mut killed = spawn(slam, &slam_args(&out, 0));
    stop_when_locked(&mut killed, &out);
    signal(killed.id(), "-KILL");
    killed.wait().unwrap();
    // What it left: the lock file, naming it, and no lock.
    let left = std::fs::read_to_string(out.join(LOCK)).unwrap();
    assert!(left.contains(&format!("pid = {}", killed.id())), "{left}");
    assert_eq!(sdf_slam::output_lock::holder(&out), None);
    let again = run(slam, &slam_args(&out, 3));
    assert!(again.status.success(), "{}", text(&again));
    assert!(first_pose_time(&out).starts_with("1305031229.6287"));
    assert!(!out.join(LOCK).exists());
}

#[test]
fn a_finished_run_is_replaced_only_with_overwrite() {
    let dir = tmp("slam_finished");
    let out = dir.join("out");
    let slam = env!("CARGO_BIN_EXE_slam");
    let first = run(slam, &slam_args(&out, 0));
    assert!(first.status.success(), "{}", text(&first));
    let before = first_pose_time(&out);
    // Sequentially, not at once: still refused, the earlier run kept whole.
    let second = run(slam, &slam_args(&out, 3));
    let t = text(&second);
    assert!(
        !second.status.success()
            && t.contains("holds an earlier run's outputs")
            && t.contains("--overwrite"),
        "{t}"
    );
    assert_eq!(first_pose_time(&out), before, "the earlier run is kept");
    assert!(out.join("report.json").is_file());
    let mut args = slam_args(&out, 3);
    args.push("--overwrite".into());
    let third = run(slam, &args);
    assert!(third.status.success(), "{}", text(&third));
    assert!(text(&third).contains("replacing an earlier run's outputs"));
    assert!(first_pose_time(&out).starts_with("1305031229.6287"));
}

/// A tiny SDFCNN training config (three fixture images at 32x48) into `out`.
fn sdfcnn_config(dir: &Path, name: &str, out: &Path, lr: f64) -> PathBuf {
    let nyu = root().join("datasets/fixtures/nyuv2").display().to_string();
    let text = format!(
        r#"model = "sdfcnn"
out = "{}"
backend = "ndarray"
seed = 1
epochs = 1
batch_size = 3
[data]
train = [{{ path = "{nyu}" }}]
val = [{{ path = "{nyu}" }}]
size = [32, 48]
[optimizer]
kind = "adam"
lr = {lr}
lr_steps = []
[network]
inner_size = [32, 48]
decoder_dim = 16
crp_stages = 1
"#,
        out.display()
    );
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

/// A tiny FPFDCNN training config (the TUM fixture at 32x48, four pairs an epoch).
fn fpfdcnn_config(dir: &Path, name: &str, out: &Path, seed: u64) -> PathBuf {
    let text = format!(
        r#"model = "fpfdcnn"
out = "{}"
backend = "ndarray"
seed = {seed}
epochs = 2
batch_size = 2
keep_checkpoints = 0
[optimizer]
lr = 0.001
[network]
descriptor_dim = 32
[data]
size = [32, 48]
pairs_per_epoch = 4
val_fraction = 0.3
[[data.sequences]]
path = "{}"
[data.pairs]
gaps = [1, 2]
[loss]
max_matches = 16
exclusion_px = 2.0
"#,
        out.display(),
        fixture()
    );
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn train(args: &[&str]) -> Output {
    let args: Vec<String> = args.iter().map(|s| s.to_string()).collect();
    run(env!("CARGO_BIN_EXE_train"), &args)
}

fn ok(o: Output) -> String {
    let t = text(&o);
    assert!(o.status.success(), "{t}");
    t
}

fn fails(o: Output, wanted: &[&str]) -> String {
    let t = text(&o);
    assert!(!o.status.success(), "exit 0: {t}");
    for w in wanted {
        assert!(t.contains(w), "missing {w:?} in: {t}");
    }
    t
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn two_trainings_never_share_a_folder() {
    let dir = tmp("train_two");
    let out = dir.join("run");
    let a = sdfcnn_config(&dir, "a.toml", &out, 0.001);
    let b = sdfcnn_config(&dir, "b.toml", &out, 0.002);
    let trainer = env!("CARGO_BIN_EXE_train");
    let args = |c: &Path| vec!["--config".to_string(), s(c).to_string(), "--quiet".into()];
    // At once: the second fails naming the first.
    let mut first = spawn(trainer, &args(&a));
    stop_when_locked(&mut first, &out);
    let second = run(trainer, &args(&b));
    signal(first.id(), "-CONT");
    fails(
        second,
        &[&format!(
            "is being written by process {} (`train ",
            first.id()
        )],
    );
    ok(first.wait_with_output().unwrap());
    let saved = std::fs::read_to_string(out.join("config.toml")).unwrap();
    assert!(saved.contains("lr = 0.001"), "{saved}");
    // One after the other: the folder holds a run; what is there and the three ways out.
    fails(
        train(&["--config", s(&b), "--quiet"]),
        &[
            "already holds a training run",
            "checkpoints up to epoch 1",
            "--resume",
            "another --out",
            "--overwrite",
        ],
    );
    // --resume with another learning rate names the field.
    fails(
        train(&["--config", s(&b), "--resume", "--epochs", "2", "--quiet"]),
        &["optimizer.lr", "0.001", "0.002"],
    );
    // --overwrite replaces it: the second run's config, its checkpoint only.
    ok(train(&["--config", s(&b), "--overwrite", "--quiet"]));
    let saved = std::fs::read_to_string(out.join("config.toml")).unwrap();
    assert!(saved.contains("lr = 0.002"), "{saved}");
    let metrics = std::fs::read_to_string(out.join("metrics.csv")).unwrap();
    assert_eq!(metrics.lines().count(), 2, "{metrics}");
    // --overwrite and --resume contradict each other.
    fails(
        train(&["--config", s(&b), "--overwrite", "--resume"]),
        &["--overwrite", "--resume"],
    );
}

#[test]
fn checkpoints_without_last_json_are_never_trained_over() {
    let dir = tmp("no_last");
    let out = dir.join("run");
    let cfg = sdfcnn_config(&dir, "a.toml", &out, 0.001);
    ok(train(&["--config", s(&cfg), "--quiet"]));
    std::fs::remove_file(out.join("checkpoints/last.json")).unwrap();
    let kept = std::fs::read(out.join("checkpoints/epoch-0001/model.bpk")).unwrap();
    fails(
        train(&["--config", s(&cfg), "--quiet"]),
        &["epoch-0001 but no checkpoints/last.json", "--overwrite"],
    );
    fails(
        train(&["--config", s(&cfg), "--resume", "--quiet"]),
        &["no checkpoint to resume from", "epoch-0001"],
    );
    let still = std::fs::read(out.join("checkpoints/epoch-0001/model.bpk")).unwrap();
    assert!(still == kept, "the checkpoint was touched");
}

#[test]
fn resume_refuses_a_foreign_optimizer_state_and_an_impossible_epoch() {
    let dir = tmp("resume");
    let (sd, fp) = (dir.join("sd"), dir.join("fp"));
    let sd_cfg = sdfcnn_config(&dir, "sd.toml", &sd, 0.001);
    let fp_cfg = fpfdcnn_config(&dir, "fp.toml", &fp, 7);
    ok(train(&["--config", s(&sd_cfg), "--quiet"]));
    ok(train(&["--config", s(&fp_cfg), "--epochs", "1", "--quiet"]));
    let ckpt = sd.join("checkpoints/epoch-0001");
    let own = std::fs::read(ckpt.join("optimizer.bpk")).unwrap();
    std::fs::copy(
        fp.join("checkpoints/epoch-0001/optimizer.bpk"),
        ckpt.join("optimizer.bpk"),
    )
    .unwrap();
    fails(
        train(&[
            "--config",
            s(&sd_cfg),
            "--resume",
            "--epochs",
            "2",
            "--quiet",
        ]),
        &["optimizer.bpk", "not one of the SDFCNN"],
    );
    std::fs::write(ckpt.join("optimizer.bpk"), &own).unwrap();
    // An epoch counter no run can have, in state.json alone and with last.json agreeing.
    let state_path = ckpt.join("state.json");
    let state = std::fs::read_to_string(&state_path).unwrap();
    let huge = state.replacen("\"epoch\": 1,", "\"epoch\": 1000000000000000,", 1);
    assert_ne!(huge, state, "{state}");
    std::fs::write(&state_path, &huge).unwrap();
    fails(
        train(&[
            "--config",
            s(&sd_cfg),
            "--resume",
            "--epochs",
            "2",
            "--quiet",
        ]),
        &["1000000000000000"],
    );
    std::fs::write(
        sd.join("checkpoints/last.json"),
        r#"{"checkpoint":"epoch-1000000000000000","epoch":1000000000000000}"#,
    )
    .unwrap();
    std::fs::rename(&ckpt, sd.join("checkpoints/epoch-1000000000000000")).unwrap();
    fails(
        train(&[
            "--config",
            s(&sd_cfg),
            "--resume",
            "--epochs",
            "2",
            "--quiet",
        ]),
        &["1000000000000000", "more than any run has"],
    );
    // A run trained further than asked is not resumed silently either.
    std::fs::rename(sd.join("checkpoints/epoch-1000000000000000"), &ckpt).unwrap();
    std::fs::write(&state_path, &state).unwrap();
    std::fs::write(
        sd.join("checkpoints/last.json"),
        r#"{"checkpoint":"epoch-0001","epoch":1}"#,
    )
    .unwrap();
    ok(train(&[
        "--config",
        s(&sd_cfg),
        "--resume",
        "--epochs",
        "2",
        "--quiet",
    ]));
    fails(
        train(&[
            "--config",
            s(&sd_cfg),
            "--resume",
            "--epochs",
            "1",
            "--quiet",
        ]),
        &["2 epochs done, more than the 1"],
    );
}

#[test]
fn export_and_average_never_replace_a_training_checkpoint_or_mix_runs() {
    let dir = tmp("export_average");
    let (a, b) = (dir.join("a"), dir.join("b"));
    let a_cfg = fpfdcnn_config(&dir, "a.toml", &a, 7);
    let b_cfg = fpfdcnn_config(&dir, "b.toml", &b, 8);
    ok(train(&["--config", s(&a_cfg), "--quiet"]));
    ok(train(&["--config", s(&b_cfg), "--epochs", "1", "--quiet"]));
    let (a1, a2, b1) = (
        a.join("checkpoints/epoch-0001"),
        a.join("checkpoints/epoch-0002"),
        b.join("checkpoints/epoch-0001"),
    );
    let weights = std::fs::read(a2.join("model.bpk")).unwrap();
    // Export onto its own checkpoint folder, into the run folder, into another checkpoint.
    fails(
        train(&["export", s(&a2), "--out", s(&a2)]),
        &["the folder of the checkpoint"],
    );
    fails(
        train(&["export", s(&a), "--out", s(&a)]),
        &["checkpoints up to epoch 2"],
    );
    fails(
        train(&["export", s(&a2), "--out", s(&a1)]),
        &["training checkpoint", "optimizer.bpk"],
    );
    assert!(std::fs::read(a2.join("model.bpk")).unwrap() == weights);
    // Into a folder of its own, twice (an earlier export is replaced).
    let exported = dir.join("exported");
    ok(train(&["export", s(&a2), "--out", s(&exported)]));
    ok(train(&["export", s(&a1), "--out", s(&exported)]));
    // Averaging two runs: refused, naming the difference.
    let averaged = dir.join("averaged");
    fails(
        train(&["average", s(&a1), s(&b1), "--out", s(&averaged)]),
        &["one run", "`seed` was 7, now 8"],
    );
    // Two runs of one config disagree on their history.
    let c = dir.join("c");
    ok(train(&[
        "--config",
        s(&a_cfg),
        "--out",
        s(&c),
        "--epochs",
        "1",
        "--quiet",
    ]));
    fails(
        train(&[
            "average",
            s(&a1),
            s(&c.join("checkpoints/epoch-0001")),
            "--out",
            s(&averaged),
        ]),
        &["disagree on epoch 1"],
    );
    assert!(!averaged.exists());
    // One run's checkpoints: averaged; not over an export, nor an export over the average.
    ok(train(&["average", s(&a1), s(&a2), "--out", s(&averaged)]));
    fails(
        train(&["average", s(&a1), s(&a2), "--out", s(&exported)]),
        &["half-precision weights of `train export`"],
    );
    fails(
        train(&["export", s(&a2), "--out", s(&averaged)]),
        &["full-precision weights of `train average`"],
    );
}
