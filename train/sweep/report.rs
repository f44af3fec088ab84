//! Sweep results, rebuilt from every run folder's `metrics.csv` after each run (all written
//! atomically):
//!
//! - `results.csv`: one row per run that has metrics: the varied values, seed, status
//!   (`done`, `incomplete`, `failed`), epochs, training time (the sum of the per-epoch
//!   `seconds`), and the final and best value of the selection metric (with its best epoch) and
//!   of the trainer's main metrics;
//! - `results.md`: the finished runs grouped by point, mean ± sample standard deviation over
//!   the seeds, sorted by the selection metric, then unfinished and failed runs;
//! - `metrics_vs_<field>.png`: the plotted metrics (mean over seeds, at the selection's `at`)
//!   against the first varied field whose values are all numbers, one line per combination of
//!   the other varied fields;
//! - `loss_curves.png`: training and validation loss per epoch of every run.

use super::values::sanitize;
use super::{At, Run, Sweep, value_label};
use sdf_slam::error::{Error, Result};
use sdf_slam::plot::{Chart, Series, line_charts};
use sdf_slam::training::RunDir;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// How far a run got.
#[derive(Debug, Clone, PartialEq)]
pub enum Status {
    /// All epochs trained.
    Done,
    /// Stopped before its last epoch (killed, or still running).
    Incomplete,
    /// The trainer returned an error (the message is in the run's `error.txt`).
    Failed(String),
}

impl Status {
    fn word(&self) -> &'static str {
        match self {
            Status::Done => "done",
            Status::Incomplete => "incomplete",
            Status::Failed(_) => "failed",
        }
    }
}

/// One epoch of a run's `metrics.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct EpochRow {
    pub epoch: usize,
    pub seconds: f64,
    pub values: BTreeMap<String, f64>,
}

/// What a run folder holds.
#[derive(Debug, Clone)]
pub struct RunResult<'a> {
    pub run: &'a Run,
    pub status: Status,
    pub rows: Vec<EpochRow>,
}

impl RunResult<'_> {
    /// The last epoch's value.
    pub fn final_value(&self, metric: &str) -> Option<f64> {
        self.rows
            .last()
            .and_then(|r| r.values.get(metric))
            .copied()
            .filter(|v| v.is_finite())
    }

    /// The best value and its epoch.
    pub fn best(&self, metric: &str, maximize: bool) -> Option<(usize, f64)> {
        self.rows
            .iter()
            .filter_map(|r| Some((r.epoch, *r.values.get(metric)?)))
            .filter(|(_, v)| v.is_finite())
            .reduce(|a, b| {
                let better = if maximize { b.1 > a.1 } else { b.1 < a.1 };
                if better { b } else { a }
            })
    }

    fn at(&self, metric: &str, maximize: bool, at: At) -> Option<f64> {
        match at {
            At::Final => self.final_value(metric),
            At::Best => self.best(metric, maximize).map(|b| b.1),
        }
    }

    /// Training time: the sum of the per-epoch seconds.
    pub fn seconds(&self) -> f64 {
        self.rows.iter().map(|r| r.seconds).sum()
    }
}

/// Reads a trainer's `metrics.csv` (`epoch,lr,seconds,<metrics...>`, empty cells for missing
/// values).
pub fn read_metrics(path: &Path) -> Result<Vec<EpochRow>> {
    let text = sdf_slam::io::read_text(path)?;
    let mut lines = text.lines().enumerate();
    let header: Vec<&str> = match lines.next() {
        Some((_, h)) => h.split(',').collect(),
        None => return Ok(Vec::new()),
    };
    if header.len() < 3 || header[..3] != ["epoch", "lr", "seconds"] {
        return Err(Error::parse(
            path,
            1,
            "expected a header starting with epoch,lr,seconds",
        ));
    }
    let mut rows = Vec::new();
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let cells: Vec<&str> = line.split(',').collect();
        if cells.len() != header.len() {
            return Err(Error::parse(
                path,
                i + 1,
                format!("{} fields, the header has {}", cells.len(), header.len()),
            ));
        }
        let num = |k: usize| -> Result<f64> {
            cells[k].trim().parse::<f64>().map_err(|_| {
                Error::parse(
                    path,
                    i + 1,
                    format!("{} is not a number: '{}'", header[k], cells[k]),
                )
            })
        };
        let epoch = num(0)?;
        if !(epoch >= 1.0 && epoch.fract() == 0.0) {
            return Err(Error::parse(
                path,
                i + 1,
                format!("bad epoch '{}'", cells[0]),
            ));
        }
        let mut values = BTreeMap::new();
        for k in 3..header.len() {
            if !cells[k].trim().is_empty() {
                values.insert(header[k].to_string(), num(k)?);
            }
        }
        rows.push(EpochRow {
            epoch: epoch as usize,
            seconds: num(2)?,
            values,
        });
    }
    Ok(rows)
}

/// The results of every run that has a `metrics.csv` or failed, in plan order. A
/// `metrics.csv` behind the run's last checkpoint (a kill between the two writes) is rewritten
/// from the checkpoint's history first.
pub fn collect(sweep: &Sweep) -> Result<Vec<RunResult<'_>>> {
    let mut out = Vec::new();
    for run in &sweep.runs {
        let csv = run.dir.join("metrics.csv");
        let err = run.dir.join("error.txt");
        let latest = RunDir {
            root: run.dir.clone(),
            keep: 0,
        }
        .latest()?;
        let mut rows = if csv.is_file() {
            read_metrics(&csv)?
        } else {
            Vec::new()
        };
        if let Some(ck) = &latest {
            let last = rows.last().map_or(0, |r| r.epoch);
            if ck.state.epoch > last {
                ck.state.history.write_csv(&csv)?;
                rows = read_metrics(&csv)?;
            }
        }
        let status = if err.is_file() {
            Status::Failed(sdf_slam::io::read_text(&err)?.trim().to_string())
        } else if latest.as_ref().is_some_and(|c| c.state.epoch >= run.epochs) {
            Status::Done
        } else {
            Status::Incomplete
        };
        if rows.is_empty() && status == Status::Incomplete {
            continue;
        }
        out.push(RunResult { run, status, rows });
    }
    Ok(out)
}

/// Mean and sample standard deviation (0 for one value).
pub fn mean_std(values: &[f64]) -> Option<(f64, f64)> {
    if values.is_empty() {
        return None;
    }
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let std = if values.len() > 1 {
        (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
    } else {
        0.0
    };
    Some((mean, std))
}

fn cell(values: &[f64]) -> String {
    match mean_std(values) {
        None => "–".into(),
        Some((m, _)) if values.len() == 1 => format!("{m:.4}"),
        Some((m, s)) => format!("{m:.4} ± {s:.4}"),
    }
}

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |v| v.to_string())
}

/// The metrics reported: the selection metric first, then the trainer's main metrics.
fn reported(sweep: &Sweep) -> Vec<&str> {
    let mut m = vec![sweep.select.metric.as_str()];
    m.extend(
        sweep
            .trainer
            .main
            .iter()
            .copied()
            .filter(|x| *x != sweep.select.metric),
    );
    m
}

/// `results.csv`.
pub fn results_csv(sweep: &Sweep, results: &[RunResult<'_>]) -> String {
    let sel = &sweep.select;
    let metrics = reported(sweep);
    let mut s = String::from("run");
    for k in &sweep.keys {
        s.push(',');
        s.push_str(&csv_field(k));
    }
    s.push_str(",seed,status,epochs,seconds");
    for m in &metrics {
        let _ = write!(s, ",{m}_final,{m}_best");
        if *m == sel.metric {
            let _ = write!(s, ",{m}_best_epoch");
        }
    }
    s.push('\n');
    for r in results {
        s.push_str(&csv_field(&r.run.name));
        for v in &sweep.points[r.run.point].values {
            s.push(',');
            s.push_str(&csv_field(&value_label(v)));
        }
        let epochs = r.rows.last().map_or(0, |e| e.epoch);
        let _ = write!(
            s,
            ",{},{},{epochs},{:.3}",
            r.run.seed,
            r.status.word(),
            r.seconds()
        );
        for m in &metrics {
            let maximize = if *m == sel.metric {
                sel.maximize
            } else {
                super::larger_is_better(m)
            };
            let best = r.best(m, maximize);
            let _ = write!(s, ",{},{}", opt(r.final_value(m)), opt(best.map(|b| b.1)));
            if *m == sel.metric {
                let _ = write!(s, ",{}", best.map_or(String::new(), |b| b.0.to_string()));
            }
        }
        s.push('\n');
    }
    s
}

/// Finished runs of each point, with the point's ranking value (mean over seeds).
fn ranked<'r, 'a>(
    sweep: &Sweep,
    results: &'r [RunResult<'a>],
) -> Vec<(usize, Vec<&'r RunResult<'a>>, Option<f64>)> {
    let sel = &sweep.select;
    let mut groups: Vec<(usize, Vec<&RunResult<'_>>, Option<f64>)> = (0..sweep.points.len())
        .map(|p| {
            let runs: Vec<&RunResult<'_>> = results
                .iter()
                .filter(|r| r.run.point == p && r.status == Status::Done)
                .collect();
            let vals: Vec<f64> = runs
                .iter()
                .filter_map(|r| r.at(&sel.metric, sel.maximize, sel.at))
                .collect();
            let key = mean_std(&vals).map(|m| m.0);
            (p, runs, key)
        })
        .filter(|g| !g.1.is_empty())
        .collect();
    groups.sort_by(|a, b| match (a.2, b.2) {
        (Some(x), Some(y)) if sel.maximize => y.total_cmp(&x),
        (Some(x), Some(y)) => x.total_cmp(&y),
        (Some(_), None) => std::cmp::Ordering::Less,
        (None, Some(_)) => std::cmp::Ordering::Greater,
        (None, None) => a.0.cmp(&b.0),
    });
    groups
}

/// `results.md`, and a one-line summary of the best run.
pub fn results_md(sweep: &Sweep, results: &[RunResult<'_>]) -> (String, Option<String>) {
    let sel = &sweep.select;
    let at = match sel.at {
        At::Final => "final epoch",
        At::Best => "best epoch",
    };
    let better = if sel.maximize { "higher" } else { "lower" };
    let done = results.iter().filter(|r| r.status == Status::Done).count();
    let labels = sweep.labels();
    let mut s = format!("# Sweep results: `{}`\n\n", sweep.path.display());
    let seeds: Vec<String> = sweep.seeds.iter().map(|s| s.to_string()).collect();
    let _ = writeln!(
        s,
        "{} runs of `{}` ({}): {} point(s) x seeds {} = {} runs, {done} finished.",
        sweep.trainer.model.to_uppercase(),
        sweep.base.display(),
        sweep
            .keys
            .iter()
            .map(|k| format!("`{k}`"))
            .collect::<Vec<_>>()
            .join(", "),
        sweep.points.len(),
        seeds.join(", "),
        sweep.runs.len()
    );
    let _ = writeln!(
        s,
        "Ranked by **{}** at the {at} ({better} is better). Cells: mean ± sample standard \
         deviation over the finished seeds, at the final epoch unless marked *best*; time/run \
         is the sum of the epoch times (training and validation).\n",
        sel.metric
    );
    let metrics = reported(sweep);
    s.push_str("| rank |");
    for l in &labels {
        let _ = write!(s, " {l} |");
    }
    s.push_str(" seeds |");
    for (i, m) in metrics.iter().enumerate() {
        let _ = write!(s, " {m} |");
        if i == 0 {
            let _ = write!(s, " {m} *best* |");
        }
    }
    s.push_str(" epochs | time/run |\n|");
    for _ in 0..labels.len() + metrics.len() + 5 {
        s.push_str("---|");
    }
    s.push('\n');
    for (rank, (p, runs, _)) in ranked(sweep, results).iter().enumerate() {
        let _ = write!(s, "| {} |", rank + 1);
        for v in &sweep.points[*p].values {
            let _ = write!(s, " {} |", value_label(v).replace('|', "\\|"));
        }
        let _ = write!(s, " {}/{} |", runs.len(), sweep.seeds.len());
        for (i, m) in metrics.iter().enumerate() {
            let finals: Vec<f64> = runs.iter().filter_map(|r| r.final_value(m)).collect();
            let _ = write!(s, " {} |", cell(&finals));
            if i == 0 {
                let bests: Vec<f64> = runs
                    .iter()
                    .filter_map(|r| r.best(m, sel.maximize).map(|b| b.1))
                    .collect();
                let _ = write!(s, " {} |", cell(&bests));
            }
        }
        let epochs = runs
            .iter()
            .filter_map(|r| r.rows.last())
            .map(|e| e.epoch)
            .max();
        let secs: Vec<f64> = runs.iter().map(|r| r.seconds()).collect();
        let time = mean_std(&secs).map_or("–".into(), |m| super::run::fmt_duration(m.0));
        let _ = writeln!(s, " {} | {time} |", epochs.unwrap_or(0));
    }
    // The best single run.
    let best = results
        .iter()
        .filter(|r| r.status == Status::Done)
        .filter_map(|r| Some((r, r.at(&sel.metric, sel.maximize, sel.at)?)))
        .reduce(|a, b| {
            let better = if sel.maximize { b.1 > a.1 } else { b.1 < a.1 };
            if better { b } else { a }
        });
    let summary = best.map(|(r, v)| {
        let epoch = match sel.at {
            At::Final => r.rows.last().map_or(0, |e| e.epoch),
            At::Best => r.best(&sel.metric, sel.maximize).map_or(0, |b| b.0),
        };
        format!(
            "best run: {} ({} {v:.4} at epoch {epoch})",
            r.run.name, sel.metric
        )
    });
    if let Some(line) = &summary {
        let _ = writeln!(s, "\n{}{}.", line[..1].to_uppercase(), &line[1..]);
    }
    let unfinished: Vec<&RunResult<'_>> = results
        .iter()
        .filter(|r| r.status != Status::Done)
        .collect();
    let pending = sweep.runs.len() - results.len();
    if !unfinished.is_empty() || pending > 0 {
        s.push_str("\n## Not finished\n\n");
        for r in unfinished {
            let epochs = r.rows.last().map_or(0, |e| e.epoch);
            match &r.status {
                Status::Failed(msg) => {
                    let _ = writeln!(
                        s,
                        "- `{}`: failed after {epochs} epoch(s): {}",
                        r.run.name,
                        msg.lines().next().unwrap_or("")
                    );
                }
                _ => {
                    let _ = writeln!(s, "- `{}`: {epochs} of {} epochs", r.run.name, r.run.epochs);
                }
            }
        }
        if pending > 0 {
            let _ = writeln!(s, "- {pending} run(s) not started");
        }
    }
    s.push_str("\nPer-run values: `results.csv`; curves: each run's `metrics.csv`.\n");
    (s, summary)
}

/// The index of the first varied field whose values are all numbers.
pub fn numeric_axis(sweep: &Sweep) -> Option<usize> {
    (0..sweep.keys.len()).find(|&k| {
        sweep
            .points
            .iter()
            .all(|p| p.values[k].is_integer() || p.values[k].is_float())
    })
}

fn as_f64(v: &toml::Value) -> f64 {
    v.as_float()
        .or_else(|| v.as_integer().map(|i| i as f64))
        .unwrap_or(f64::NAN)
}

/// `metrics_vs_<field>.png` (when a numeric field is varied and runs finished).
fn plot_metrics(sweep: &Sweep, results: &[RunResult<'_>]) -> Result<()> {
    let Some(x) = numeric_axis(sweep) else {
        return Ok(());
    };
    let sel = &sweep.select;
    let labels = sweep.labels();
    let group_of = |p: usize| -> String {
        let parts: Vec<String> = (0..sweep.keys.len())
            .filter(|&k| k != x)
            .map(|k| format!("{}={}", labels[k], value_label(&sweep.points[p].values[k])))
            .collect();
        parts.join(", ")
    };
    let mut groups: Vec<String> = Vec::new();
    for p in 0..sweep.points.len() {
        let g = group_of(p);
        if !groups.contains(&g) {
            groups.push(g);
        }
    }
    let at = match sel.at {
        At::Final => "final",
        At::Best => "best",
    };
    let titles: Vec<(String, String)> = sweep
        .plots
        .iter()
        .map(|m| {
            (
                format!("{m} vs {}", labels[x]),
                format!("{m} ({at}, mean over seeds)"),
            )
        })
        .collect();
    let mut charts = Vec::new();
    for (m, (title, y)) in sweep.plots.iter().zip(&titles) {
        let maximize = if *m == sel.metric {
            sel.maximize
        } else {
            super::larger_is_better(m)
        };
        let mut series = Vec::new();
        for g in &groups {
            let mut pts: Vec<(f64, f64)> = (0..sweep.points.len())
                .filter(|&p| group_of(p) == *g)
                .filter_map(|p| {
                    let vals: Vec<f64> = results
                        .iter()
                        .filter(|r| r.run.point == p && r.status == Status::Done)
                        .filter_map(|r| r.at(m, maximize, sel.at))
                        .collect();
                    let (mean, _) = mean_std(&vals)?;
                    Some((as_f64(&sweep.points[p].values[x]), mean))
                })
                .collect();
            pts.sort_by(|a, b| a.0.total_cmp(&b.0));
            if !pts.is_empty() {
                let name = if g.is_empty() { m.as_str() } else { g.as_str() };
                series.push(Series { name, points: pts });
            }
        }
        if !series.is_empty() {
            charts.push(Chart {
                title,
                x_label: &sweep.keys[x],
                y_label: y,
                series,
                log_y: false,
                markers: true,
            });
        }
    }
    if charts.is_empty() {
        return Ok(());
    }
    let file = format!("metrics_vs_{}.png", sanitize(&labels[x]));
    line_charts(sweep.out.join(file), &charts, 2)
}

/// `loss_curves.png`: training and validation loss of every run.
fn plot_losses(sweep: &Sweep, results: &[RunResult<'_>]) -> Result<()> {
    let mut charts = Vec::new();
    let most = results.iter().map(|r| r.rows.len()).max().unwrap_or(0);
    for (metric, title) in [
        ("train_loss", "training loss"),
        ("val_loss", "validation loss"),
    ] {
        let series: Vec<Series<'_>> = results
            .iter()
            .map(|r| Series {
                name: &r.run.name,
                points: r
                    .rows
                    .iter()
                    .filter_map(|e| Some((e.epoch as f64, *e.values.get(metric)?)))
                    .filter(|p| p.1.is_finite())
                    .collect(),
            })
            .filter(|s| !s.points.is_empty())
            .collect();
        if series.is_empty() {
            continue;
        }
        // A log axis when the losses span more than a decade (plotters labels decades).
        let ys = || series.iter().flat_map(|s| s.points.iter().map(|p| p.1));
        let (lo, hi) = ys().fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
        let log_y = lo > 0.0 && hi / lo > 20.0;
        charts.push(Chart {
            title,
            x_label: "epoch",
            y_label: metric,
            series,
            log_y,
            markers: most <= 12,
        });
    }
    if charts.is_empty() {
        return Ok(());
    }
    line_charts(sweep.out.join("loss_curves.png"), &charts, 2)
}

/// Rewrites every result file from the run folders; returns the best-run summary line.
pub fn write(sweep: &Sweep) -> Result<Option<String>> {
    let results = collect(sweep)?;
    sdf_slam::io::write_atomic(
        sweep.out.join("results.csv"),
        results_csv(sweep, &results).as_bytes(),
    )?;
    let (md, summary) = results_md(sweep, &results);
    sdf_slam::io::write_atomic(sweep.out.join("results.md"), md.as_bytes())?;
    plot_metrics(sweep, &results)?;
    plot_losses(sweep, &results)?;
    Ok(summary)
}
