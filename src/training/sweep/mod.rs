//! Config-file sweeps: one training run per point of a grid (or list) of config values and
//! per seed, each in its own run folder, with result tables and plots.
//!
//! ```toml
//! model = "sweep"
//! base = "sdfcnn_sweep_base.toml"     # a training config; as given, else next to this file
//! out = "runs/sweep_lambda_lr"
//! seeds = [1, 2]                      # each point is trained once per seed (sets `seed`)
//! select = { metric = "val_miou", mode = "max", at = "final" }
//! plot = ["val_miou", "val_rms"]      # optional: metrics plotted against the first numeric field
//!
//! [set]                               # optional: overrides for every run
//! epochs = 4
//!
//! [grid]                              # every combination of these values
//! "loss.lambda" = [0.2, 0.4, 0.6, 0.8]
//! "optimizer.lr" = [0.01, 0.1]
//!
//! [[points]]                          # optional: further points, listed one by one
//! "loss.lambda" = 0.4
//! "loss.depth" = "l1"
//! ```
//!
//! Field paths are dotted paths into the base config (`optimizer.lr`, `data.augment.flip`);
//! nested tables (`[grid.loss]`) work too. A field may be one the base file does not list, as
//! long as the trainer's config has it: every point is checked by parsing the merged config with
//! the trainer's own parser before any run starts, so an unknown field, a wrong type or an
//! out-of-range value is an error naming the sweep file, its line and the key.
//!
//! Runs go to `out/<field>=<value>_..._seed=<n>/` (a normal run folder: `config.toml`,
//! `metrics.csv`, plots, checkpoints). A run whose last checkpoint reached its epochs is
//! skipped; one with fewer epochs is resumed from its last checkpoint, so a killed sweep
//! restarts where it stopped. After every run `out/results.csv`, `out/results.md` and the plots
//! are rewritten (see [`report`]); `out/sweep.log` records what was run.

pub mod report;

use crate::error::{Error, Result};
use crate::training::{RunDir, RunOptions};
use serde::Deserialize;
use std::collections::HashMap;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;
use toml::{Table, Value};

/// What a sweep needs to know about a trainer.
#[derive(Clone, Copy)]
pub struct Trainer {
    /// The config's `model`.
    pub model: &'static str,
    /// Parses a config as the trainer does and returns it with every default filled in.
    parse: fn(&str, &Path) -> Result<Value>,
    /// Trains (config path, config text, options).
    run: fn(&Path, &str, &RunOptions) -> Result<()>,
    /// Checks that the data a config names can be opened (config text, config path).
    check_data: fn(&str, &Path) -> Result<()>,
    /// Whether a config (normalised by `parse`) has validation data, which every `val_*`
    /// metric needs.
    has_validation: fn(&Value) -> bool,
    /// What to add to a config that has none.
    validation_hint: &'static str,
    /// Every column the trainer writes to `metrics.csv` (besides epoch, lr, seconds).
    pub metrics: &'static [&'static str],
    /// Metrics reported in the results (final and best value).
    pub main: &'static [&'static str],
    /// Metrics plotted against the first numeric field by default.
    pub plots: &'static [&'static str],
}

const SDFCNN_METRICS: &[&str] = &[
    "train_loss",
    "train_seg_loss",
    "train_depth_loss",
    "val_loss",
    "val_seg_loss",
    "val_depth_loss",
    "val_mpa",
    "val_miou",
    "val_pixel_acc",
    "val_rms",
    "val_rel",
    "val_delta1",
    "val_delta2",
    "val_delta3",
];

const FPFDCNN_METRICS: &[&str] = &[
    "train_loss",
    "train_detector",
    "train_descriptor",
    "train_localization",
    "train_desc_top1",
    "val_loss",
    "val_detector",
    "val_descriptor",
    "val_localization",
    "val_desc_top1",
];

fn normalized<T: serde::Serialize>(cfg: &T, path: &Path) -> Result<Value> {
    Value::try_from(cfg).map_err(|e| Error::invalid(path, format!("cannot re-serialise: {e}")))
}

fn sdfcnn_check_data(text: &str, path: &Path) -> Result<()> {
    use crate::sdfcnn::data::{DataSource, SegDepthData};
    let cfg = crate::sdfcnn::SdfcnnTrainConfig::parse(text, path)?;
    if let Some(init) = &cfg.init {
        let p = crate::sdfcnn::data::resolve(init, path);
        if !p.exists() {
            return Err(Error::invalid(
                path,
                format!("init {} does not exist", p.display()),
            ));
        }
    }
    for list in [&cfg.data.train, &cfg.data.val] {
        let sources: Vec<DataSource> = list.iter().map(|s| s.resolved(path)).collect();
        SegDepthData::open(&sources)?;
    }
    Ok(())
}

fn fpfdcnn_check_data(text: &str, path: &Path) -> Result<()> {
    let cfg = crate::fpfdcnn::training::FpfdcnnTrainConfig::parse(text, path)?;
    if let Some(init) = &cfg.init {
        crate::nn::weights::resolve_checkpoint(init)
            .map_err(|e| Error::invalid(path, format!("init: {e}")))?;
    }
    for s in &cfg.data.sequences {
        crate::dataset::TumSequence::open(&s.path)?;
    }
    Ok(())
}

/// The trainers a sweep can run, by their config's `model`.
pub fn trainer(model: &str) -> Option<Trainer> {
    match model {
        "sdfcnn" => Some(Trainer {
            model: "sdfcnn",
            parse: |t, p| normalized(&crate::sdfcnn::SdfcnnTrainConfig::parse(t, p)?, p),
            run: crate::sdfcnn::training::run,
            check_data: sdfcnn_check_data,
            // `[[data.val]]` sources.
            has_validation: |cfg| {
                lookup(cfg, "data.val")
                    .and_then(Value::as_array)
                    .is_some_and(|v| !v.is_empty())
            },
            validation_hint: "[[data.val]] sources",
            metrics: SDFCNN_METRICS,
            main: &[
                "val_miou",
                "val_mpa",
                "val_rms",
                "val_rel",
                "val_delta1",
                "val_loss",
                "train_loss",
            ],
            plots: &["val_miou", "val_rms"],
        }),
        "fpfdcnn" => Some(Trainer {
            model: "fpfdcnn",
            parse: |t, p| {
                normalized(
                    &crate::fpfdcnn::training::FpfdcnnTrainConfig::parse(t, p)?,
                    p,
                )
            },
            run: crate::fpfdcnn::training::run,
            check_data: fpfdcnn_check_data,
            // The last `data.val_fraction` of every sequence.
            has_validation: |cfg| {
                lookup(cfg, "data.val_fraction")
                    .and_then(Value::as_float)
                    .is_some_and(|f| f > 0.0)
            },
            validation_hint: "data.val_fraction > 0",
            metrics: FPFDCNN_METRICS,
            main: &[
                "val_desc_top1",
                "val_loss",
                "val_descriptor",
                "val_detector",
                "train_loss",
            ],
            plots: &["val_desc_top1", "val_loss"],
        }),
        _ => None,
    }
}

/// Whether larger values of a metric are better (losses and depth errors are minimised).
pub fn larger_is_better(metric: &str) -> bool {
    !(metric.contains("loss")
        || ["rms", "rel", "detector", "descriptor"]
            .iter()
            .any(|s| metric.ends_with(s)))
}

/// Which value of a run's metric curve ranks it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum At {
    /// The last epoch's value.
    #[default]
    Final,
    /// The best value over all epochs.
    Best,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
enum Mode {
    Max,
    Min,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SelectFile {
    metric: String,
    #[serde(default)]
    mode: Option<Mode>,
    #[serde(default)]
    at: At,
}

/// The sweep file as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SweepFile {
    model: String,
    base: PathBuf,
    out: PathBuf,
    seeds: Vec<u64>,
    select: SelectFile,
    #[serde(default)]
    plot: Option<Vec<String>>,
    #[serde(default)]
    set: Table,
    #[serde(default)]
    grid: Table,
    #[serde(default)]
    points: Vec<Table>,
}

/// How runs are ranked.
#[derive(Debug, Clone, PartialEq)]
pub struct Select {
    pub metric: String,
    pub maximize: bool,
    pub at: At,
}

/// One configuration of the sweep (trained once per seed).
#[derive(Debug, Clone)]
pub struct Point {
    /// The value of every varied field (`Sweep::keys`), as the trainer sees it.
    pub values: Vec<Value>,
    /// Folder-name stem, e.g. `lambda=0.4_lr=0.01`.
    pub name: String,
}

/// One training run: a point and a seed.
#[derive(Debug, Clone)]
pub struct Run {
    /// Index into `Sweep::points`.
    pub point: usize,
    pub seed: u64,
    /// Folder name, e.g. `lambda=0.4_lr=0.01_seed=1`.
    pub name: String,
    pub dir: PathBuf,
    /// The merged training config given to the trainer.
    pub config: String,
    /// Epochs to train.
    pub epochs: usize,
    /// The merged config with defaults, for comparing with an existing run folder.
    normalized: Value,
}

/// A validated sweep: every run's config has been parsed by the trainer.
pub struct Sweep {
    /// The sweep file.
    pub path: PathBuf,
    pub trainer: Trainer,
    /// The base training config.
    pub base: PathBuf,
    pub out: PathBuf,
    /// The varied fields (grid keys in file order, then keys only `[[points]]` set).
    pub keys: Vec<String>,
    pub points: Vec<Point>,
    pub seeds: Vec<u64>,
    pub runs: Vec<Run>,
    pub select: Select,
    /// Metrics plotted against the first numeric varied field.
    pub plots: Vec<String>,
}

/// Byte offsets of every key of a TOML document, by dotted path (array-of-tables entries as
/// `points[2]`), for error messages with line numbers and for the file order of keys.
fn key_offsets(text: &str) -> HashMap<String, usize> {
    use toml::de::{DeTable, DeValue};
    fn walk(t: &DeTable<'_>, prefix: &str, out: &mut HashMap<String, usize>) {
        for (k, v) in t.iter() {
            let path = if prefix.is_empty() {
                k.get_ref().to_string()
            } else {
                format!("{prefix}.{}", k.get_ref())
            };
            out.entry(path.clone()).or_insert(k.span().start);
            match v.get_ref() {
                DeValue::Table(t) => walk(t, &path, out),
                DeValue::Array(a) => {
                    for (i, item) in a.iter().enumerate() {
                        if let DeValue::Table(t) = item.get_ref() {
                            let p = format!("{path}[{i}]");
                            out.entry(p.clone()).or_insert(item.span().start);
                            walk(t, &p, out);
                        }
                    }
                }
                _ => {}
            }
        }
    }
    let mut out = HashMap::new();
    if let Ok(root) = DeTable::parse(text) {
        walk(root.get_ref(), "", &mut out);
    }
    out
}

/// Leaves of a table as `(dotted path, value)`; nested tables are walked into.
fn flatten(table: &Table, prefix: &str, out: &mut Vec<(String, Value)>) {
    for (k, v) in table {
        let path = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            Value::Table(t) => flatten(t, &path, out),
            _ => out.push((path, v.clone())),
        }
    }
}

/// Sets `path` (dotted) in `table` to `value`, creating missing tables; a table value is
/// merged into an existing table.
fn apply(table: &mut Table, path: &str, value: &Value) -> std::result::Result<(), String> {
    let segs: Vec<&str> = path.split('.').collect();
    if segs.iter().any(|s| s.trim().is_empty()) {
        return Err(format!(
            "`{path}` is not a field path (names joined by dots, e.g. loss.lambda)"
        ));
    }
    let (last, parents) = segs.split_last().expect("split gives at least one segment");
    let mut t = table;
    for (i, seg) in parents.iter().enumerate() {
        let entry = t
            .entry(seg.to_string())
            .or_insert_with(|| Value::Table(Table::new()));
        match entry {
            Value::Table(inner) => t = inner,
            other => {
                return Err(format!(
                    "`{}` is a {} in the base config, not a table",
                    segs[..=i].join("."),
                    other.type_str()
                ));
            }
        }
    }
    match (t.get_mut(*last), value) {
        (Some(Value::Table(existing)), Value::Table(new)) => {
            for (k, v) in new {
                apply(existing, k, v)?;
            }
        }
        _ => {
            t.insert(last.to_string(), value.clone());
        }
    }
    Ok(())
}

/// The value at a dotted path.
fn lookup<'a>(value: &'a Value, path: &str) -> Option<&'a Value> {
    path.split('.')
        .try_fold(value, |v, seg| v.as_table()?.get(seg))
}

/// A value as shown in folder names, tables and plots: strings without quotes, numbers as
/// Rust prints them (very large or small ones in exponent form), arrays as `[a, b]`.
pub fn value_label(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Integer(i) => i.to_string(),
        Value::Float(f) if *f != 0.0 && !(1e-4..1e6).contains(&f.abs()) => format!("{f:e}"),
        Value::Float(f) => f.to_string(),
        Value::Boolean(b) => b.to_string(),
        Value::Array(a) => {
            let items: Vec<String> = a.iter().map(value_label).collect();
            format!("[{}]", items.join(", "))
        }
        Value::Table(t) => {
            let items: Vec<String> = t
                .iter()
                .map(|(k, v)| format!("{k} = {}", value_label(v)))
                .collect();
            format!("{{{}}}", items.join(", "))
        }
        Value::Datetime(d) => d.to_string(),
    }
}

/// A string usable in a folder name: brackets, braces and quotes are dropped, other
/// characters outside `[A-Za-z0-9._+=-]` become `-`.
fn sanitize(s: &str) -> String {
    let mut out = String::new();
    for c in s.chars().filter(|c| !"[]{}\"'".contains(*c)) {
        let c = if c.is_ascii_alphanumeric() || "._+-=".contains(c) {
            c
        } else {
            '-'
        };
        if !(c == '-' && out.ends_with('-')) {
            out.push(c);
        }
    }
    out.trim_matches('-').to_string()
}

/// The first dotted path at which two values differ.
fn first_difference(a: &Value, b: &Value, prefix: &str) -> Option<String> {
    match (a, b) {
        (Value::Table(x), Value::Table(y)) => {
            for k in x.keys().chain(y.keys()) {
                let p = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                match (x.get(k), y.get(k)) {
                    (Some(u), Some(v)) => {
                        if let Some(d) = first_difference(u, v, &p) {
                            return Some(d);
                        }
                    }
                    _ => return Some(p),
                }
            }
            None
        }
        _ if a == b => None,
        _ => Some(prefix.to_string()),
    }
}

/// Run fields that do not change what a run computes, ignored when comparing an existing run
/// folder's config with the sweep's.
const RUN_ONLY: [&str; 3] = ["epochs", "out", "backend"];

/// Fields the sweep itself sets.
fn reserved(key: &str) -> Option<&'static str> {
    match key {
        "model" => Some("the base config decides the model"),
        "out" => Some("run folders are `out/<values>`; set the sweep's `out`"),
        "seed" => Some("seeds are given by the sweep's `seeds = [...]`"),
        _ => None,
    }
}

impl Sweep {
    /// Parses and validates a sweep file: reads the base config, checks every override and
    /// every point with the trainer's own parser, checks the data can be opened, and that
    /// existing run folders belong to this sweep. Nothing is trained or written.
    pub fn load(path: &Path, text: &str, opts: &RunOptions) -> Result<Sweep> {
        let file: SweepFile =
            toml::from_str(text).map_err(|e| crate::camera::toml_error(path, text, e))?;
        let offsets = key_offsets(text);
        let line_of = |key: &str| -> Option<usize> {
            offsets
                .get(key)
                .map(|&o| text[..o.min(text.len())].matches('\n').count() + 1)
        };
        let err_at = |key: &str, msg: String| -> Error {
            match line_of(key) {
                Some(line) => Error::parse(path, line, msg),
                None => Error::invalid(path, msg),
            }
        };
        if file.model != "sweep" {
            return Err(err_at(
                "model",
                format!(
                    "model = \"{}\" is not a sweep (model = \"sweep\")",
                    file.model
                ),
            ));
        }

        // The base config, parsed by its trainer.
        let base = crate::sdfcnn::data::resolve(&file.base, path);
        let base_text = crate::io::read_text(&base)
            .map_err(|e| err_at("base", format!("base = \"{}\": {e}", file.base.display())))?;
        let base_table: Table = toml::from_str(&base_text)
            .map_err(|e| crate::camera::toml_error(&base, &base_text, e))?;
        let model = crate::training::config_model(&base_text, &base)?;
        let trainer = trainer(&model).ok_or_else(|| {
            err_at(
                "base",
                format!(
                    "base config {} has model = \"{model}\": a sweep runs \"sdfcnn\" or \"fpfdcnn\" configs",
                    base.display()
                ),
            )
        })?;
        (trainer.parse)(&base_text, &base)?;
        let label = |t: &Trainer| t.model.to_uppercase();
        // Parses `table` as a config of the trainer; `what` names the override in errors.
        let check = |table: &Table, key: &str, what: &str| -> Result<Value> {
            let merged = toml::to_string(table).map_err(|e| Error::msg(e.to_string()))?;
            (trainer.parse)(&merged, &base).map_err(|e| {
                let msg = match e {
                    Error::Parse { msg, .. } | Error::Invalid { msg, .. } => msg,
                    other => other.to_string(),
                };
                err_at(
                    key,
                    format!(
                        "{what}: not a valid {} config (base {}): {msg}",
                        label(&trainer),
                        base.display()
                    ),
                )
            })
        };
        // Checks that an override reached the trainer (a field it would silently ignore is
        // an error too).
        let reached = |normal: &Value, field: &str, key: &str, what: &str| -> Result<()> {
            if lookup(normal, field).is_none() {
                return Err(err_at(
                    key,
                    format!(
                        "{what}: the {} config has no field `{field}`",
                        label(&trainer)
                    ),
                ));
            }
            Ok(())
        };

        // Seeds.
        if file.seeds.is_empty() {
            return Err(err_at(
                "seeds",
                "seeds = [] is empty: give at least one seed, e.g. seeds = [1]".into(),
            ));
        }
        if let Some(s) = duplicate(&file.seeds) {
            return Err(err_at("seeds", format!("seed {s} is listed twice")));
        }

        // Selection and plotted metrics.
        let known = |m: &str| trainer.metrics.contains(&m);
        if !known(&file.select.metric) {
            return Err(err_at(
                "select",
                format!(
                    "select.metric = \"{}\" is not a metric of the {} trainer (metrics.csv columns: {})",
                    file.select.metric,
                    label(&trainer),
                    trainer.metrics.join(", ")
                ),
            ));
        }
        let maximize = match file.select.mode {
            Some(m) => m == Mode::Max,
            None => larger_is_better(&file.select.metric),
        };
        let select = Select {
            metric: file.select.metric.clone(),
            maximize,
            at: file.select.at,
        };
        let mut plots: Vec<String> = match &file.plot {
            Some(list) => {
                if let Some(bad) = list.iter().find(|m| !known(m)) {
                    return Err(err_at(
                        "plot",
                        format!(
                            "plot: \"{bad}\" is not a metric of the {} trainer (metrics.csv columns: {})",
                            label(&trainer),
                            trainer.metrics.join(", ")
                        ),
                    ));
                }
                list.clone()
            }
            None => trainer.plots.iter().map(|s| s.to_string()).collect(),
        };
        if !plots.contains(&select.metric) {
            plots.insert(0, select.metric.clone());
        }

        // [set]: overrides for every run, each checked on its own.
        let mut set = Vec::new();
        flatten(&file.set, "", &mut set);
        let mut common = base_table.clone();
        for (field, value) in &set {
            let key = format!("set.{field}");
            let what = format!("[set] {field} = {value}");
            if let Some(why) = reserved(field) {
                return Err(err_at(&key, format!("{what}: cannot be set here: {why}")));
            }
            let mut t = base_table.clone();
            apply(&mut t, field, value).map_err(|m| err_at(&key, format!("{what}: {m}")))?;
            let normal = check(&t, &key, &what)?;
            reached(&normal, field, &key, &what)?;
            apply(&mut common, field, value).map_err(|m| err_at(&key, m))?;
        }
        check(&common, "set", "[set]")?;

        // [grid]: each field's values must be a non-empty list; each value is checked alone.
        let mut grid_fields = Vec::new();
        flatten(&file.grid, "", &mut grid_fields);
        grid_fields.sort_by_key(|(f, _)| offsets.get(&format!("grid.{f}")).copied());
        let mut grid: Vec<(String, Vec<Value>)> = Vec::new();
        for (field, value) in &grid_fields {
            let key = format!("grid.{field}");
            if let Some(why) = reserved(field) {
                return Err(err_at(
                    &key,
                    format!("[grid] {field}: cannot be varied here: {why}"),
                ));
            }
            if grid.iter().any(|(f, _)| f == field) {
                return Err(err_at(&key, format!("[grid] {field} is given twice")));
            }
            if set.iter().any(|(f, _)| f == field) {
                return Err(err_at(
                    &key,
                    format!("[grid] {field} is also in [set]: give it in one place"),
                ));
            }
            let Value::Array(values) = value else {
                return Err(err_at(
                    &key,
                    format!(
                        "[grid] {field} = {value}: a grid field takes a list of values, e.g. [0.2, 0.4]"
                    ),
                ));
            };
            if values.is_empty() {
                return Err(err_at(
                    &key,
                    format!("[grid] {field} = []: the list of values is empty"),
                ));
            }
            if let Some(v) = duplicate(values) {
                return Err(err_at(
                    &key,
                    format!("[grid] {field}: the value {v} is listed twice"),
                ));
            }
            for v in values {
                let what = format!("[grid] {field} = {v}");
                let mut t = common.clone();
                apply(&mut t, field, v).map_err(|m| err_at(&key, format!("{what}: {m}")))?;
                let normal = check(&t, &key, &what)?;
                reached(&normal, field, &key, &what)?;
            }
            grid.push((field.clone(), values.clone()));
        }

        // [[points]]: each one a table of field = value.
        let mut listed: Vec<Vec<(String, Value)>> = Vec::new();
        for (i, table) in file.points.iter().enumerate() {
            let key = format!("points[{i}]");
            let mut fields = Vec::new();
            flatten(table, "", &mut fields);
            fields.sort_by_key(|(f, _)| offsets.get(&format!("{key}.{f}")).copied());
            if fields.is_empty() {
                return Err(err_at(&key, format!("[[points]] #{} sets no field", i + 1)));
            }
            for (field, value) in &fields {
                let fkey = format!("{key}.{field}");
                let what = format!("[[points]] #{} {field} = {value}", i + 1);
                if let Some(why) = reserved(field) {
                    return Err(err_at(
                        &fkey,
                        format!("{what}: cannot be varied here: {why}"),
                    ));
                }
                if set.iter().any(|(f, _)| f == field) {
                    return Err(err_at(
                        &fkey,
                        format!("{what}: {field} is also in [set]: give it in one place"),
                    ));
                }
                let mut t = common.clone();
                apply(&mut t, field, value).map_err(|m| err_at(&fkey, format!("{what}: {m}")))?;
                let normal = check(&t, &fkey, &what)?;
                reached(&normal, field, &fkey, &what)?;
            }
            listed.push(fields);
        }
        if grid.is_empty() && listed.is_empty() {
            return Err(Error::invalid(
                path,
                "nothing to sweep: [grid] and [[points]] are both empty (e.g. [grid] \"loss.lambda\" = [0.2, 0.4])",
            ));
        }

        // The varied fields and the points: the grid's combinations (first field slowest),
        // then the listed points.
        let mut keys: Vec<String> = grid.iter().map(|(f, _)| f.clone()).collect();
        for fields in &listed {
            for (f, _) in fields {
                if !keys.contains(f) {
                    keys.push(f.clone());
                }
            }
        }
        let mut combos: Vec<(String, Vec<(String, Value)>)> = vec![("grid".into(), Vec::new())];
        for (field, values) in &grid {
            combos = combos
                .into_iter()
                .flat_map(|(k, c)| {
                    values.iter().map(move |v| {
                        let mut c = c.clone();
                        c.push((field.clone(), v.clone()));
                        (k.clone(), c)
                    })
                })
                .collect();
        }
        if grid.is_empty() {
            combos.clear();
        }
        combos.extend(
            listed
                .into_iter()
                .enumerate()
                .map(|(i, f)| (format!("points[{i}]"), f)),
        );
        let short = short_labels(&keys);
        let mut points = Vec::new();
        let mut normals = Vec::new();
        for (key, overrides) in &combos {
            let mut t = common.clone();
            for (f, v) in overrides {
                apply(&mut t, f, v).map_err(|m| err_at(key, m))?;
            }
            let desc: Vec<String> = overrides
                .iter()
                .map(|(f, v)| format!("{f} = {v}"))
                .collect();
            let normal = check(&t, key, &format!("the point {}", desc.join(", ")))?;
            if select.metric.starts_with("val_") && !(trainer.has_validation)(&normal) {
                let point = if desc.is_empty() {
                    String::new()
                } else {
                    format!(" (at the point {})", desc.join(", "))
                };
                return Err(err_at(
                    "select",
                    format!(
                        "select.metric = \"{}\" is a validation metric, but the config has no validation data{point}: add {} to the base config or select by a train_* metric",
                        select.metric, trainer.validation_hint
                    ),
                ));
            }
            let values: Vec<Value> = keys
                .iter()
                .map(|k| {
                    lookup_in(&t, k)
                        .or_else(|| lookup(&normal, k))
                        .cloned()
                        .unwrap_or_else(|| Value::String("default".into()))
                })
                .collect();
            if let Some(j) = points.iter().position(|p: &Point| p.values == values) {
                return Err(err_at(
                    key,
                    format!(
                        "the point {} is the same configuration as point {} ({})",
                        desc.join(", "),
                        j + 1,
                        points[j].name
                    ),
                ));
            }
            let name = keys
                .iter()
                .zip(&values)
                .zip(&short)
                .map(|((_, v), s)| {
                    let label = value_label(v);
                    let label = if label == "[]" { "empty" } else { &label };
                    sanitize(&format!("{s}={label}"))
                })
                .collect::<Vec<_>>()
                .join("_");
            points.push(Point { values, name });
            normals.push((t, normal));
        }
        // Folder names must be unique (values that differ only in characters a folder name
        // cannot hold, or very long names, get the point number).
        for i in 0..points.len() {
            let clash = (0..points.len()).any(|j| j != i && points[j].name == points[i].name);
            if clash || points[i].name.len() > 150 {
                points[i].name = format!("p{:03}", i + 1);
            }
        }

        // Data: open what each distinct data configuration names.
        let mut checked = Vec::new();
        for (t, normal) in &normals {
            let data = lookup(normal, "data").cloned();
            if checked.contains(&data) {
                continue;
            }
            let text = toml::to_string(t).map_err(|e| Error::msg(e.to_string()))?;
            (trainer.check_data)(&text, &base).map_err(|e| {
                Error::msg(format!(
                    "{}: the training data of base {} cannot be opened (its comments may say how to make them): {e}",
                    path.display(),
                    base.display()
                ))
            })?;
            checked.push(data);
        }

        // Runs.
        let out = opts.out.clone().unwrap_or_else(|| file.out.clone());
        let mut runs = Vec::new();
        for (p, point) in points.iter().enumerate() {
            for &seed in &file.seeds {
                let (t, normal) = &normals[p];
                let name = format!("{}_seed={seed}", point.name);
                let dir = out.join(&name);
                let mut t = t.clone();
                t.insert("seed".into(), Value::Integer(seed as i64));
                t.insert("out".into(), Value::String(dir.display().to_string()));
                let body = toml::to_string(&t).map_err(|e| Error::msg(e.to_string()))?;
                let values: Vec<String> = keys
                    .iter()
                    .zip(&point.values)
                    .map(|(k, v)| format!("{k} = {v}"))
                    .collect();
                // Only file names in the comment: the text must not depend on how the sweep
                // was invoked (the trainer compares it when resuming).
                let file_name = |p: &Path| {
                    p.file_name()
                        .map_or(String::new(), |n| n.to_string_lossy().into_owned())
                };
                let config = format!(
                    "# Run {name} of the sweep {}:\n# base {} with {}, seed = {seed}.\n{body}",
                    file_name(path),
                    file_name(&base),
                    values.join(", ")
                );
                let mut normal = normal.clone();
                if let Value::Table(n) = &mut normal {
                    n.insert("seed".into(), Value::Integer(seed as i64));
                }
                let epochs = match opts.epochs {
                    Some(e) => e,
                    None => lookup(&normal, "epochs")
                        .and_then(Value::as_integer)
                        .and_then(|e| usize::try_from(e).ok())
                        .ok_or_else(|| {
                            Error::invalid(&base, "the config has no integer `epochs`")
                        })?,
                };
                runs.push(Run {
                    point: p,
                    seed,
                    name,
                    dir,
                    config,
                    epochs,
                    normalized: normal,
                });
            }
        }
        let sweep = Sweep {
            path: path.to_path_buf(),
            trainer,
            base,
            out,
            keys,
            points,
            seeds: file.seeds,
            runs,
            select,
            plots,
        };
        for run in &sweep.runs {
            sweep.check_run_folder(run)?;
        }
        Ok(sweep)
    }

    /// An existing run folder must hold a run of the same config (up to epochs, output folder
    /// and backend): otherwise resuming or skipping it would mix configurations.
    fn check_run_folder(&self, run: &Run) -> Result<()> {
        let cfg_path = run.dir.join("config.toml");
        if !cfg_path.is_file() {
            return Ok(());
        }
        let text = crate::io::read_text(&cfg_path)?;
        let saved = (self.trainer.parse)(&text, &cfg_path)?;
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

    /// `field = value, ..., seed = n` of a run.
    pub fn describe_point(&self, run: &Run) -> String {
        let mut parts: Vec<String> = self
            .keys
            .iter()
            .zip(&self.points[run.point].values)
            .map(|(k, v)| format!("{k} = {v}"))
            .collect();
        parts.push(format!("seed = {}", run.seed));
        parts.join(", ")
    }

    /// Short names of the varied fields (the last path segment, or the whole path where two
    /// fields end the same way).
    pub fn labels(&self) -> Vec<String> {
        short_labels(&self.keys)
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

fn lookup_in<'a>(table: &'a Table, path: &str) -> Option<&'a Value> {
    let (first, rest) = match path.split_once('.') {
        Some((a, b)) => (a, Some(b)),
        None => (path, None),
    };
    let v = table.get(first)?;
    match rest {
        Some(r) => lookup(v, r),
        None => Some(v),
    }
}

fn short_labels(keys: &[String]) -> Vec<String> {
    let last = |k: &str| k.rsplit('.').next().unwrap_or(k).to_string();
    keys.iter()
        .map(|k| {
            let l = last(k);
            if keys.iter().filter(|o| last(o) == l).count() > 1 {
                k.clone()
            } else {
                l
            }
        })
        .collect()
}

fn duplicate<T: PartialEq + std::fmt::Display>(list: &[T]) -> Option<String> {
    list.iter()
        .enumerate()
        .find(|(i, v)| list[..*i].contains(v))
        .map(|(_, v)| v.to_string())
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
fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (H. Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02}",
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    )
}

fn fmt_duration(secs: f64) -> String {
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
    std::fs::create_dir_all(&sweep.out).map_err(|e| Error::io(&sweep.out, e))?;
    crate::io::write_atomic(sweep.out.join("sweep.toml"), text.as_bytes())?;
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
            epochs: Some(run.epochs),
            quiet: opts.quiet,
        };
        std::fs::create_dir_all(&run.dir).map_err(|e| Error::io(&run.dir, e))?;
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
                crate::io::write_atomic(&error_file, format!("{msg}\n").as_bytes())?;
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

/// Parses a training config with its trainer's checks and opens the data and the `init`
/// weights it names (for `train --dry-run`).
pub fn check_training_config(model: &str, path: &Path, text: &str) -> Result<()> {
    let t = trainer(model).ok_or_else(|| {
        Error::invalid(
            path,
            format!("unknown model '{model}' (fpfdcnn, sdfcnn or sweep)"),
        )
    })?;
    (t.parse)(text, path)?;
    (t.check_data)(text, path)
}

#[cfg(test)]
mod tests;
