//! Loading a sweep file, phase by phase: the file itself, the base config, the seeds, the
//! selection, `[set]`, `[grid]` and `[[points]]` (every override checked with the trainer's own
//! parser), the points they expand to, the data they name, and the runs with their folders.
//! The phases run in this order, and each stops at its first error, so a bad sweep always
//! reports the same error first.

use super::values::{
    apply, duplicate, flatten, key_offsets, lookup, lookup_in, sanitize, short_labels, value_label,
};
use super::{At, Point, Run, Select, Sweep, Trainer, larger_is_better, trainer};
use sdf_slam::error::{Error, Result};
use sdf_slam::training::RunOptions;
use serde::Deserialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use toml::{Table, Value};

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

/// Fields the sweep itself sets.
fn reserved(key: &str) -> Option<&'static str> {
    match key {
        "model" => Some("the base config decides the model"),
        "out" => Some("run folders are `out/<values>`; set the sweep's `out`"),
        "seed" => Some("seeds are given by the sweep's `seeds = [...]`"),
        _ => None,
    }
}

/// A field (dotted path) and the value a sweep gives it.
type Field = (String, Value);

/// The sweep file and where its keys are, for errors that name the line of a key.
struct Locator<'a> {
    path: &'a Path,
    text: &'a str,
    offsets: HashMap<String, usize>,
}

impl Locator<'_> {
    /// The line of a key (dotted path, `points[2]` for array-of-tables entries), if the file
    /// has it.
    fn line_of(&self, key: &str) -> Option<usize> {
        self.offsets
            .get(key)
            .map(|&o| self.text[..o.min(self.text.len())].matches('\n').count() + 1)
    }

    /// An error at a key's line, or about the whole file where the key is not in it.
    fn err(&self, key: &str, msg: String) -> Error {
        match self.line_of(key) {
            Some(line) => Error::parse(self.path, line, msg),
            None => Error::invalid(self.path, msg),
        }
    }

    /// Where a key is in the file, for putting keys in file order.
    fn offset(&self, key: &str) -> Option<usize> {
        self.offsets.get(key).copied()
    }
}

/// The base training config and its trainer.
struct Base {
    /// The base config, resolved as given or next to the sweep file.
    path: PathBuf,
    /// The base config as written.
    table: Table,
    trainer: Trainer,
}

/// Checks configs with the trainer's own parser, for errors at a key of the sweep file.
struct Checker<'a> {
    at: &'a Locator<'a>,
    trainer: Trainer,
    base: &'a Path,
}

impl Checker<'_> {
    /// The trainer's name in messages (`SDFCNN`).
    fn label(&self) -> String {
        self.trainer.model.to_uppercase()
    }

    /// Parses `table` as a config of the trainer; `what` names the override in errors.
    fn check(&self, table: &Table, key: &str, what: &str) -> Result<Value> {
        let merged = toml::to_string(table)?;
        (self.trainer.parse)(&merged, self.base).map_err(|e| {
            let msg = match e {
                Error::Parse { msg, .. } | Error::Invalid { msg, .. } => msg,
                other => other.to_string(),
            };
            self.at.err(
                key,
                format!(
                    "{what}: not a valid {} config (base {}): {msg}",
                    self.label(),
                    self.base.display()
                ),
            )
        })
    }

    /// Checks that an override reached the trainer (a field it would silently ignore is an
    /// error too).
    fn reached(&self, normal: &Value, field: &str, key: &str, what: &str) -> Result<()> {
        if lookup(normal, field).is_none() {
            return Err(self.at.err(
                key,
                format!("{what}: the {} config has no field `{field}`", self.label()),
            ));
        }
        Ok(())
    }

    /// Checks one override on its own: `table` with `field = value` must be a valid config
    /// that has the field.
    fn check_alone(
        &self,
        table: &Table,
        (field, value): (&str, &Value),
        key: &str,
        what: &str,
    ) -> Result<()> {
        let mut t = table.clone();
        apply(&mut t, field, value).map_err(|m| self.at.err(key, format!("{what}: {m}")))?;
        let normal = self.check(&t, key, what)?;
        self.reached(&normal, field, key, what)
    }
}

/// The configs of a point: as given to the trainer, and normalised by its parser.
type PointConfig = (Table, Value);

impl Sweep {
    /// Parses and validates a sweep file: reads the base config, checks every override and
    /// every point with the trainer's own parser, checks the data can be opened, and that
    /// existing run folders belong to this sweep. Nothing is trained or written.
    pub fn load(path: &Path, text: &str, opts: &RunOptions) -> Result<Sweep> {
        let (file, at) = parse_file(path, text)?;
        let base = read_base(&file, &at)?;
        let checker = Checker {
            at: &at,
            trainer: base.trainer,
            base: &base.path,
        };
        check_seeds(&file.seeds, &at)?;
        let (select, plots) = selection(&file, &checker)?;
        let (set, common) = set_overrides(&file.set, &base.table, &checker)?;
        let grid = grid_fields(&file.grid, &set, &common, &checker)?;
        let listed = listed_points(&file.points, &set, &common, &checker)?;
        if grid.is_empty() && listed.is_empty() {
            return Err(Error::invalid(
                path,
                "nothing to sweep: [grid] and [[points]] are both empty (e.g. [grid] \"loss.lambda\" = [0.2, 0.4])",
            ));
        }
        let keys = varied_keys(&grid, &listed);
        let combos = combinations(&grid, listed);
        let (points, configs) = expand_points(&combos, &keys, &common, &select, &checker)?;
        check_data(&configs, &checker, path)?;
        let out = opts.out.clone().unwrap_or_else(|| file.out.clone());
        let mut sweep = Sweep {
            path: path.to_path_buf(),
            trainer: base.trainer,
            base: base.path,
            out,
            keys,
            points,
            seeds: file.seeds,
            runs: Vec::new(),
            select,
            plots,
        };
        sweep.runs = plan_runs(&sweep, &configs, opts)?;
        for run in &sweep.runs {
            sweep.check_run_folder(run)?;
        }
        Ok(sweep)
    }
}

/// Parses the sweep file (unknown keys are errors) and checks that it is a sweep.
fn parse_file<'a>(path: &'a Path, text: &'a str) -> Result<(SweepFile, Locator<'a>)> {
    let file: SweepFile =
        toml::from_str(text).map_err(|e| sdf_slam::camera::toml_error(path, text, e))?;
    let at = Locator {
        path,
        text,
        offsets: key_offsets(text),
    };
    if file.model != "sweep" {
        return Err(at.err(
            "model",
            format!(
                "model = \"{}\" is not a sweep (model = \"sweep\")",
                file.model
            ),
        ));
    }
    Ok((file, at))
}

/// Reads the base config and parses it with its trainer.
fn read_base(file: &SweepFile, at: &Locator<'_>) -> Result<Base> {
    let base = sdf_slam::sdfcnn::data::resolve(&file.base, at.path);
    let base_text = sdf_slam::io::read_text(&base)
        .map_err(|e| at.err("base", format!("base = \"{}\": {e}", file.base.display())))?;
    let base_table: Table = toml::from_str(&base_text)
        .map_err(|e| sdf_slam::camera::toml_error(&base, &base_text, e))?;
    let model = sdf_slam::training::config_model(&base_text, &base)?;
    let trainer = trainer(&model).ok_or_else(|| {
        at.err(
            "base",
            format!(
                "base config {} has model = \"{model}\": a sweep runs \"sdfcnn\" or \"fpfdcnn\" configs",
                base.display()
            ),
        )
    })?;
    (trainer.parse)(&base_text, &base)?;
    Ok(Base {
        path: base,
        table: base_table,
        trainer,
    })
}

/// Seeds: at least one, none twice.
fn check_seeds(seeds: &[u64], at: &Locator<'_>) -> Result<()> {
    if seeds.is_empty() {
        return Err(at.err(
            "seeds",
            "seeds = [] is empty: give at least one seed, e.g. seeds = [1]".into(),
        ));
    }
    if let Some(s) = duplicate(seeds) {
        return Err(at.err("seeds", format!("seed {s} is listed twice")));
    }
    Ok(())
}

/// Selection and plotted metrics: every one a metric of the trainer; the selection metric is
/// always plotted.
fn selection(file: &SweepFile, checker: &Checker<'_>) -> Result<(Select, Vec<String>)> {
    let (trainer, at) = (&checker.trainer, checker.at);
    let known = |m: &str| trainer.metrics.contains(&m);
    if !known(&file.select.metric) {
        return Err(at.err(
            "select",
            format!(
                "select.metric = \"{}\" is not a metric of the {} trainer (metrics.csv columns: {})",
                file.select.metric,
                checker.label(),
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
                return Err(at.err(
                    "plot",
                    format!(
                        "plot: \"{bad}\" is not a metric of the {} trainer (metrics.csv columns: {})",
                        checker.label(),
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
    Ok((select, plots))
}

/// `[set]`: overrides for every run, each checked on its own, then all together. Returns the
/// overrides and the base config with all of them (the config every point starts from).
fn set_overrides(
    set_table: &Table,
    base_table: &Table,
    checker: &Checker<'_>,
) -> Result<(Vec<Field>, Table)> {
    let at = checker.at;
    let mut set = Vec::new();
    flatten(set_table, "", &mut set);
    let mut common = base_table.clone();
    for (field, value) in &set {
        let key = format!("set.{field}");
        let what = format!("[set] {field} = {value}");
        if let Some(why) = reserved(field) {
            return Err(at.err(&key, format!("{what}: cannot be set here: {why}")));
        }
        checker.check_alone(base_table, (field, value), &key, &what)?;
        apply(&mut common, field, value).map_err(|m| at.err(&key, m))?;
    }
    checker.check(&common, "set", "[set]")?;
    Ok((set, common))
}

/// `[grid]`, in file order: each field's values must be a non-empty list; each value is
/// checked alone.
fn grid_fields(
    grid_table: &Table,
    set: &[Field],
    common: &Table,
    checker: &Checker<'_>,
) -> Result<Vec<(String, Vec<Value>)>> {
    let at = checker.at;
    let mut grid_fields = Vec::new();
    flatten(grid_table, "", &mut grid_fields);
    grid_fields.sort_by_key(|(f, _)| at.offset(&format!("grid.{f}")));
    let mut grid: Vec<(String, Vec<Value>)> = Vec::new();
    for (field, value) in &grid_fields {
        let key = format!("grid.{field}");
        if let Some(why) = reserved(field) {
            return Err(at.err(
                &key,
                format!("[grid] {field}: cannot be varied here: {why}"),
            ));
        }
        if grid.iter().any(|(f, _)| f == field) {
            return Err(at.err(&key, format!("[grid] {field} is given twice")));
        }
        if set.iter().any(|(f, _)| f == field) {
            return Err(at.err(
                &key,
                format!("[grid] {field} is also in [set]: give it in one place"),
            ));
        }
        let Value::Array(values) = value else {
            return Err(at.err(
                &key,
                format!(
                    "[grid] {field} = {value}: a grid field takes a list of values, e.g. [0.2, 0.4]"
                ),
            ));
        };
        if values.is_empty() {
            return Err(at.err(
                &key,
                format!("[grid] {field} = []: the list of values is empty"),
            ));
        }
        if let Some(v) = duplicate(values) {
            return Err(at.err(
                &key,
                format!("[grid] {field}: the value {v} is listed twice"),
            ));
        }
        for v in values {
            let what = format!("[grid] {field} = {v}");
            checker.check_alone(common, (field, v), &key, &what)?;
        }
        grid.push((field.clone(), values.clone()));
    }
    Ok(grid)
}

/// `[[points]]`: each one a table of field = value (in file order), each field checked alone.
fn listed_points(
    tables: &[Table],
    set: &[Field],
    common: &Table,
    checker: &Checker<'_>,
) -> Result<Vec<Vec<Field>>> {
    let at = checker.at;
    let mut listed: Vec<Vec<Field>> = Vec::new();
    for (i, table) in tables.iter().enumerate() {
        let key = format!("points[{i}]");
        let mut fields = Vec::new();
        flatten(table, "", &mut fields);
        fields.sort_by_key(|(f, _)| at.offset(&format!("{key}.{f}")));
        if fields.is_empty() {
            return Err(at.err(&key, format!("[[points]] #{} sets no field", i + 1)));
        }
        for (field, value) in &fields {
            let fkey = format!("{key}.{field}");
            let what = format!("[[points]] #{} {field} = {value}", i + 1);
            if let Some(why) = reserved(field) {
                return Err(at.err(&fkey, format!("{what}: cannot be varied here: {why}")));
            }
            if set.iter().any(|(f, _)| f == field) {
                return Err(at.err(
                    &fkey,
                    format!("{what}: {field} is also in [set]: give it in one place"),
                ));
            }
            checker.check_alone(common, (field, value), &fkey, &what)?;
        }
        listed.push(fields);
    }
    Ok(listed)
}

/// The varied fields: the grid's in file order, then those only `[[points]]` set.
fn varied_keys(grid: &[(String, Vec<Value>)], listed: &[Vec<Field>]) -> Vec<String> {
    let mut keys: Vec<String> = grid.iter().map(|(f, _)| f.clone()).collect();
    for fields in listed {
        for (f, _) in fields {
            if !keys.contains(f) {
                keys.push(f.clone());
            }
        }
    }
    keys
}

/// The overrides of every point, with the key errors about it are reported at: the grid's
/// combinations (first field slowest), then the listed points.
fn combinations(
    grid: &[(String, Vec<Value>)],
    listed: Vec<Vec<Field>>,
) -> Vec<(String, Vec<Field>)> {
    let mut combos: Vec<(String, Vec<Field>)> = vec![("grid".into(), Vec::new())];
    for (field, values) in grid {
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
    combos
}

/// The points: every combination checked as a whole (validation data where the selection
/// needs it, no two the same configuration), with unique folder names; and their configs.
fn expand_points(
    combos: &[(String, Vec<Field>)],
    keys: &[String],
    common: &Table,
    select: &Select,
    checker: &Checker<'_>,
) -> Result<(Vec<Point>, Vec<PointConfig>)> {
    let (trainer, at) = (&checker.trainer, checker.at);
    let short = short_labels(keys);
    let mut points = Vec::new();
    let mut configs = Vec::new();
    for (key, overrides) in combos {
        let mut t = common.clone();
        for (f, v) in overrides {
            apply(&mut t, f, v).map_err(|m| at.err(key, m))?;
        }
        let desc: Vec<String> = overrides
            .iter()
            .map(|(f, v)| format!("{f} = {v}"))
            .collect();
        let normal = checker.check(&t, key, &format!("the point {}", desc.join(", ")))?;
        if select.metric.starts_with("val_") && !(trainer.has_validation)(&normal) {
            let point = if desc.is_empty() {
                String::new()
            } else {
                format!(" (at the point {})", desc.join(", "))
            };
            return Err(at.err(
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
            return Err(at.err(
                key,
                format!(
                    "the point {} is the same configuration as point {} ({})",
                    desc.join(", "),
                    j + 1,
                    points[j].name
                ),
            ));
        }
        let name = folder_stem(&values, &short);
        points.push(Point { values, name });
        configs.push((t, normal));
    }
    unique_names(&mut points);
    Ok((points, configs))
}

/// A point's folder-name stem, `lambda=0.4_lr=0.01`, from its values and the short labels of
/// the varied fields.
fn folder_stem(values: &[Value], short: &[String]) -> String {
    values
        .iter()
        .zip(short)
        .map(|(v, s)| {
            let label = value_label(v);
            let label = if label == "[]" { "empty" } else { &label };
            sanitize(&format!("{s}={label}"))
        })
        .collect::<Vec<_>>()
        .join("_")
}

/// Folder names must be unique (values that differ only in characters a folder name cannot
/// hold, or very long names, get the point number).
fn unique_names(points: &mut [Point]) {
    for i in 0..points.len() {
        let clash = (0..points.len()).any(|j| j != i && points[j].name == points[i].name);
        if clash || points[i].name.len() > 150 {
            points[i].name = format!("p{:03}", i + 1);
        }
    }
}

/// Data: opens what each distinct data configuration names.
fn check_data(configs: &[PointConfig], checker: &Checker<'_>, path: &Path) -> Result<()> {
    let mut checked = Vec::new();
    for (t, normal) in configs {
        let data = lookup(normal, "data").cloned();
        if checked.contains(&data) {
            continue;
        }
        let text = toml::to_string(t)?;
        (checker.trainer.check_data)(&text, checker.base).map_err(|e| {
            Error::msg(format!(
                "{}: the training data of base {} cannot be opened (its comments may say how to make them): {e}",
                path.display(),
                checker.base.display()
            ))
        })?;
        checked.push(data);
    }
    Ok(())
}

/// The runs of a sweep (all but its `runs`): every point once per seed, each with its folder
/// under `out`, its config text and its epochs.
fn plan_runs(sweep: &Sweep, configs: &[PointConfig], opts: &RunOptions) -> Result<Vec<Run>> {
    let (keys, path, base) = (&sweep.keys, &sweep.path, &sweep.base);
    let mut runs = Vec::new();
    for (p, point) in sweep.points.iter().enumerate() {
        for &seed in &sweep.seeds {
            let (t, normal) = &configs[p];
            let name = format!("{}_seed={seed}", point.name);
            let dir = sweep.out.join(&name);
            let mut t = t.clone();
            t.insert("seed".into(), Value::Integer(seed as i64));
            t.insert("out".into(), Value::String(dir.display().to_string()));
            let body = toml::to_string(&t)?;
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
                file_name(base),
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
                    .ok_or_else(|| Error::invalid(base, "the config has no integer `epochs`"))?,
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
    Ok(runs)
}
