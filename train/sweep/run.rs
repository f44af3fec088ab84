//! Running a sweep: the run plan and what each run folder already holds (a finished run is
//! skipped, a partly trained one resumed, a folder of another config refused), training the
//! runs one after the other, and the logs.

use super::report;
use super::values::{first_difference, lookup};
use super::{Run, Sweep};
use sdf_slam::error::{Error, Result};
use sdf_slam::output_lock::{OutputLock, command_line};
use sdf_slam::training::{RunContents, RunDir, RunOptions, clear_run};
use std::io::Write as _;
use std::path::Path;
use std::time::Instant;
use toml::Value;

/// Run fields that do not change what a run computes, ignored when comparing an existing run
/// folder's config with the sweep's.
const RUN_ONLY: [&str; 3] = ["epochs", "out", "backend"];

impl Sweep {
    /// An existing run folder must hold a run of the same config (up to epochs, output folder
    /// and backend): otherwise resuming or skipping it would mix configurations.
    pub(super) fn check_run_folder(&self, run: &Run) -> Result<()> {
        let cfg_path = run.dir.join("config.toml");
        if !cfg_path.is_file() {
            return Ok(());
        }
        let text = sdf_slam::io::read_text(&cfg_path)?;
        let saved = (self.trainer.parse_saved)(&text, &cfg_path)?;
        let strip = |v: &Value| {
            let mut v = v.clone();
            if let Value::Table(t) = &mut v {
                for k in RUN_ONLY {
                    t.remove(k);
                }
            }
            v
        };
        if let Some(field) = first_difference(&strip(&saved), &strip(&run.normalized), "") {
            let (a, b) = (lookup(&saved, &field), lookup(&run.normalized, &field));
            let show = |v: Option<&Value>| v.map_or("(absent)".to_string(), |v| v.to_string());
            return Err(Error::invalid(
                &cfg_path,
                format!(
                    "this run folder of the sweep {} was trained with another config ({field} = {} there, {} in the sweep): remove the folder or choose another `out`",
                    self.path.display(),
                    show(a),
                    show(b)
                ),
            ));
        }
        Ok(())
    }

    /// Epochs a run has completed (its newest checkpoint).
    pub fn completed_epochs(run: &Run) -> Result<usize> {
        let dir = RunDir {
            root: run.dir.clone(),
            keep: 0,
        };
        Ok(dir.latest()?.map_or(0, |c| c.state.epoch))
    }

    /// The run plan, one line per run, with what is already done.
    pub fn describe(&self) -> Result<String> {
        let mut s = format!(
            "sweep {}: {} config {}, {} point(s) x {} seed(s) = {} runs -> {}\n",
            self.path.display(),
            self.trainer.model,
            self.base.display(),
            self.points.len(),
            self.seeds.len(),
            self.runs.len(),
            self.out.display()
        );
        for (k, run) in self.runs.iter().enumerate() {
            let done = Self::completed_epochs(run)?;
            let state = if done >= run.epochs {
                "done".to_string()
            } else if done > 0 {
                format!("{done}/{} epochs", run.epochs)
            } else {
                "to run".to_string()
            };
            s.push_str(&format!(
                "[{}/{}] {} ({state})\n",
                k + 1,
                self.runs.len(),
                run.name
            ));
        }
        Ok(s)
    }
}

/// Prints a line and appends it to `out/sweep.log`.
fn log(out: &Path, line: &str) {
    println!("{line}");
    append_line(&out.join("sweep.log"), line);
}

/// Appends a time-stamped line to a log file (a warning if that fails).
fn append_line(path: &Path, line: &str) {
    let stamp = utc_now();
    let write = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .and_then(|mut f| writeln!(f, "{stamp} {line}"));
    if let Err(e) = write {
        eprintln!("warning: cannot append to {}: {e}", path.display());
    }
}

/// Appends the epochs after `done` of a run's `metrics.csv` to its `train.log`.
fn log_epochs(run: &Run, done: usize) {
    let log = run.dir.join("train.log");
    match report::read_metrics(&run.dir.join("metrics.csv")) {
        Ok(rows) => {
            for r in rows.iter().filter(|r| r.epoch > done) {
                let values: Vec<String> = r
                    .values
                    .iter()
                    .map(|(k, v)| format!("{k} {v:.4}"))
                    .collect();
                append_line(
                    &log,
                    &format!(
                        "epoch {}/{} ({:.1} s): {}",
                        r.epoch,
                        run.epochs,
                        r.seconds,
                        values.join(", ")
                    ),
                );
            }
        }
        Err(e) => append_line(&log, &format!("no metrics: {e}")),
    }
}

/// The current UTC time as `YYYY-MM-DD HH:MM:SS`.
pub(super) fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let text = sdf_slam::output_lock::utc_text(secs);
    text.trim_end_matches(" UTC").to_string()
}

pub(super) fn fmt_duration(secs: f64) -> String {
    let s = secs.round() as u64;
    if s >= 3600 {
        format!("{}h{:02}m", s / 3600, s / 60 % 60)
    } else if s >= 60 {
        format!("{}m{:02}s", s / 60, s % 60)
    } else {
        format!("{s}s")
    }
}

/// Runs a sweep file: validates it (nothing starts if any point is invalid), then trains
/// every run not finished yet, rewriting the results after each. `opts.out` replaces the
/// sweep's `out`; `backend`, `epochs` and `quiet` apply to every run; runs always resume.
pub fn run(path: &Path, text: &str, opts: &RunOptions) -> Result<()> {
    let sweep = Sweep::load(path, text, opts)?;
    // One writer per folder: the sweep's, and below each run's while it trains.
    let _lock = OutputLock::acquire(&sweep.out, &command_line())?;
    let contents = RunContents::of(&sweep.out)?;
    if contents.config.is_some() || contents.last_epoch.is_some() || contents.weights {
        return Err(Error::invalid(
            &sweep.out,
            format!(
                "this folder holds {}, not a sweep: give the sweep another `out` (or --out)",
                contents.describe()
            ),
        ));
    }
    sdf_slam::io::write_atomic(sweep.out.join("sweep.toml"), text.as_bytes())?;
    let n = sweep.runs.len();
    log(
        &sweep.out,
        &format!(
            "sweep {}: {} x {} seed(s) = {n} {} runs (base {}) -> {}",
            path.display(),
            sweep.points.len(),
            sweep.seeds.len(),
            sweep.trainer.model,
            sweep.base.display(),
            sweep.out.display()
        ),
    );
    let mut states = Vec::with_capacity(n);
    for run in &sweep.runs {
        states.push(Sweep::completed_epochs(run)?);
    }
    if states.iter().zip(&sweep.runs).any(|(d, r)| *d >= r.epochs) {
        report::write(&sweep)?;
    }
    let (mut trained, mut skipped) = (0usize, 0usize);
    let mut failed: Vec<(String, String)> = Vec::new();
    let mut seconds = Vec::new();
    for (k, run) in sweep.runs.iter().enumerate() {
        let head = format!("[{}/{n}] {}", k + 1, run.name);
        let done = states[k];
        if done >= run.epochs {
            skipped += 1;
            log(
                &sweep.out,
                &format!("{head}: already done ({done} epochs), skipped"),
            );
            continue;
        }
        // Runs still to train, this one included; the estimate uses this session's mean.
        let left = (k..n).filter(|&j| states[j] < sweep.runs[j].epochs).count();
        let eta = if seconds.is_empty() {
            String::new()
        } else {
            let mean = seconds.iter().sum::<f64>() / seconds.len() as f64;
            format!(
                ", about {} left for {left} run(s)",
                fmt_duration(mean * left as f64)
            )
        };
        let how = if done > 0 {
            format!("resuming after epoch {done} of {}", run.epochs)
        } else {
            format!(
                "{} epoch{}",
                run.epochs,
                if run.epochs == 1 { "" } else { "s" }
            )
        };
        log(
            &sweep.out,
            &format!("{head}: training, {how} -> {}{eta}", run.dir.display()),
        );
        let error_file = run.dir.join("error.txt");
        if error_file.exists() {
            std::fs::remove_file(&error_file).map_err(|e| Error::io(&error_file, e))?;
        }
        let run_opts = RunOptions {
            out: Some(run.dir.clone()),
            resume: done > 0,
            backend: opts.backend,
            devices: opts.devices.clone(),
            epochs: Some(run.epochs),
            quiet: opts.quiet,
        };
        let _run_lock = OutputLock::acquire(&run.dir, &command_line())?;
        // A run that saved no checkpoint starts again (its folder holds this sweep point's
        // config, checked when the sweep was loaded): what it left goes first. Checkpoint
        // folders without `last.json` are never removed: the run then fails, naming them.
        if done == 0 && RunContents::of(&run.dir)?.checkpoints.is_empty() {
            clear_run(&run.dir)?;
        }
        let run_log = run.dir.join("train.log");
        append_line(
            &run_log,
            &format!(
                "sweep {} run {}: {how}, config {} with {}",
                path.display(),
                run.name,
                sweep.base.display(),
                sweep.describe_point(run)
            ),
        );
        let started = Instant::now();
        let result = (sweep.trainer.run)(&sweep.base, &run.config, &run_opts);
        let secs = started.elapsed().as_secs_f64();
        log_epochs(run, done);
        match &result {
            Ok(()) => append_line(&run_log, &format!("finished in {}", fmt_duration(secs))),
            Err(e) => append_line(&run_log, &format!("FAILED: {e}")),
        }
        match result {
            Ok(()) => {
                trained += 1;
                seconds.push(secs);
                log(
                    &sweep.out,
                    &format!("{head}: finished in {}", fmt_duration(secs)),
                );
            }
            Err(e) => {
                let msg = e.to_string();
                sdf_slam::io::write_atomic(&error_file, format!("{msg}\n").as_bytes())?;
                log(&sweep.out, &format!("{head}: FAILED: {msg}"));
                failed.push((run.name.clone(), msg));
            }
        }
        report::write(&sweep)?;
    }
    let summary = report::write(&sweep)?;
    log(
        &sweep.out,
        &format!(
            "sweep finished: {trained} trained, {skipped} skipped, {} failed; results in {}",
            failed.len(),
            sweep.out.join("results.md").display()
        ),
    );
    if let Some(best) = summary {
        println!("{best}");
    }
    if let Some((name, msg)) = failed.first() {
        return Err(Error::msg(format!(
            "{} of {n} runs failed (they are retried when the sweep is run again); first, {name}: {msg}",
            failed.len()
        )));
    }
    Ok(())
}
