//! `docs/configuration.md` against the config structs, both ways: every key of the `synth`,
//! `train` (FPFDCNN, SDFCNN, sweep) and `slam` configs has a row there, every row names a key
//! that exists, and every default the page gives in backticks is the struct's default.
//!
//! The page's format: under a line `<!-- config: NAME -->` (until the next `## ` heading),
//! each key is a table row `` | `section.key` | type | default | meaning | ``; an entry of an
//! array of tables is written `` `list[].key` ``. A default in backticks is read as a TOML
//! value; other defaults (`required`, `none`, words) are not compared.
//!
//! The keys come from the structs themselves: a config (the `Default`, or a minimal config
//! for those with required keys) is serialised to TOML, and each of its tables is then given
//! an unknown key: the config's own parser (`deny_unknown_fields`) answers with the list of
//! every field the table has, `Option` fields included. The sweep file's struct lives in the
//! `train` binary, so its tables are probed through `train --config FILE --dry-run`.

mod common;

use sdf_slam::fpfdcnn::training::FpfdcnnTrainConfig;
use sdf_slam::sdfcnn::SdfcnnTrainConfig;
use sdf_slam::slam::SlamConfig;
use sdf_slam::synth::SynthConfig;
use std::collections::{BTreeMap, BTreeSet};
use toml::{Table, Value};

const DOC: &str = include_str!("../docs/configuration.md");
const DOC_PATH: &str = "docs/configuration.md";

/// The key given to a table to make its parser list the table's fields.
const PROBE: &str = "zz_not_a_key";

/// A config's parser: `Err(message)` where it refuses the text.
type Parse<'a> = &'a dyn Fn(&str) -> Result<(), String>;

/// Every key of a config (dotted, `list[].key` for entries of arrays of tables) and its
/// value in the serialised config, where it has one there.
type Keys = BTreeMap<String, Option<Value>>;

/// One row of the page.
#[derive(Debug)]
struct Row {
    key: String,
    ty: String,
    default: String,
    line: usize,
}

fn serde_parse<T: serde::de::DeserializeOwned>(text: &str) -> Result<(), String> {
    toml::from_str::<T>(text)
        .map(drop)
        .map_err(|e| e.to_string())
}

/// `path` as written on the page: `data.sequences[].path`.
fn dotted(path: &[String]) -> String {
    let mut s = String::new();
    for seg in path {
        if seg == "[]" {
            s.push_str("[]");
        } else {
            if !s.is_empty() {
                s.push('.');
            }
            s.push_str(seg);
        }
    }
    s
}

/// The table at `path` (`"[]"`: the first entry of the array before it).
fn table_at<'a>(doc: &'a Table, path: &[String]) -> &'a Table {
    let mut t = doc;
    let mut i = 0;
    while i < path.len() {
        let entry = t.get(&path[i]).expect("path into the config");
        let v = if path.get(i + 1).is_some_and(|s| s == "[]") {
            i += 1;
            entry.as_array().and_then(|a| a.first()).expect("an entry")
        } else {
            entry
        };
        t = v.as_table().expect("a table");
        i += 1;
    }
    t
}

/// [`table_at`], to change.
fn table_at_mut<'a>(doc: &'a mut Table, path: &[String]) -> &'a mut Table {
    let mut t = doc;
    let mut i = 0;
    while i < path.len() {
        let entry = t.get_mut(&path[i]).expect("path into the config");
        let v = if path.get(i + 1).is_some_and(|s| s == "[]") {
            i += 1;
            entry
                .as_array_mut()
                .and_then(|a| a.first_mut())
                .expect("an entry")
        } else {
            entry
        };
        t = v.as_table_mut().expect("a table");
        i += 1;
    }
    t
}

/// The fields of the table at `path` as its parser lists them when it meets an unknown key
/// there; `None` where the table takes any key (or the parser answers otherwise).
fn listed_fields(parse: Parse, doc: &Table, path: &[String]) -> Option<Vec<String>> {
    let mut probed = doc.clone();
    table_at_mut(&mut probed, path).insert(PROBE.into(), Value::Integer(0));
    let text = toml::to_string(&probed).expect("a config serialises");
    let msg = parse(&text).err()?;
    let needle = format!("unknown field `{PROBE}`");
    let at = msg.find(&needle)?;
    let rest = msg[at + needle.len()..].lines().next().unwrap_or("");
    if rest.contains("there are no fields") {
        return Some(Vec::new());
    }
    let names: Vec<String> = rest
        .split('`')
        .skip(1)
        .step_by(2)
        .map(str::to_string)
        .collect();
    assert!(!names.is_empty(), "cannot read the fields from: {msg}");
    Some(names)
}

/// Adds every key of the table at `path` (whose fields are `fields`) to `out`, descending
/// into the tables and the entries of arrays of tables whose parser lists their fields.
fn walk(parse: Parse, doc: &Table, path: &[String], fields: Vec<String>, out: &mut Keys) {
    let here = table_at(doc, path);
    let names: BTreeSet<String> = fields.into_iter().chain(here.keys().cloned()).collect();
    for name in names {
        let mut sub = path.to_vec();
        sub.push(name.clone());
        let value = here.get(&name);
        match value {
            Some(Value::Table(_)) => match listed_fields(parse, doc, &sub) {
                Some(f) => walk(parse, doc, &sub, f, out),
                None => {
                    out.insert(dotted(&sub), value.cloned());
                }
            },
            Some(Value::Array(items)) if items.first().is_some_and(Value::is_table) => {
                out.insert(dotted(&sub), value.cloned());
                sub.push("[]".into());
                if let Some(f) = listed_fields(parse, doc, &sub) {
                    walk(parse, doc, &sub, f, out);
                }
            }
            _ => {
                out.insert(dotted(&sub), value.cloned());
            }
        }
    }
}

/// Every key of a config, from `doc` (a valid config serialised to a table) and its parser.
fn keys_of(parse: Parse, doc: &Table) -> Keys {
    let fields = listed_fields(parse, doc, &[]).expect("the top level refuses unknown keys");
    let mut out = Keys::new();
    walk(parse, doc, &[], fields, &mut out);
    out
}

fn table<T: serde::Serialize>(cfg: &T) -> Table {
    match Value::try_from(cfg).expect("a config serialises") {
        Value::Table(t) => t,
        other => panic!("not a table: {other:?}"),
    }
}

/// A training config with only its required keys, read by its own struct (so every other
/// key takes its default), as a table.
fn minimal<T: serde::de::DeserializeOwned + serde::Serialize>(text: &str) -> Table {
    table(&toml::from_str::<T>(text).expect("a minimal config"))
}

/// The sweep file's parser: `train --config FILE --dry-run` (the struct is the binary's).
fn sweep_parse(text: &str) -> Result<(), String> {
    let dir = common::fresh_dir("docs_config", "sweep");
    let file = dir.join("sweep.toml");
    std::fs::write(&file, text).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_train"))
        .arg("--config")
        .arg(&file)
        .arg("--dry-run")
        .output()
        .expect("train runs");
    if out.status.success() {
        Ok(())
    } else {
        Err(String::from_utf8_lossy(&out.stderr).into_owned())
    }
}

/// Every config the page documents and its keys.
fn struct_keys() -> BTreeMap<&'static str, Keys> {
    let mut all = BTreeMap::new();
    all.insert(
        "synth",
        keys_of(&serde_parse::<SynthConfig>, &table(&SynthConfig::default())),
    );
    all.insert(
        "slam",
        keys_of(&serde_parse::<SlamConfig>, &table(&SlamConfig::default())),
    );
    let fpfdcnn = minimal::<FpfdcnnTrainConfig>(
        "model = \"fpfdcnn\"\nepochs = 1\n[[data.sequences]]\npath = \"seq\"\n",
    );
    all.insert(
        "train-fpfdcnn",
        keys_of(&serde_parse::<FpfdcnnTrainConfig>, &fpfdcnn),
    );
    let sdfcnn = minimal::<SdfcnnTrainConfig>(
        "model = \"sdfcnn\"\nout = \"runs/x\"\nepochs = 1\nbatch_size = 1\n\
         [[data.train]]\npath = \"data\"\n[[data.video]]\npath = \"v\"\ntrajectory = \"t.txt\"\n",
    );
    all.insert(
        "train-sdfcnn",
        keys_of(&serde_parse::<SdfcnnTrainConfig>, &sdfcnn),
    );
    let sweep: Table = toml::from_str(
        "model = \"sweep\"\nbase = \"base.toml\"\nout = \"runs/x\"\nseeds = [1]\n\
         select = { metric = \"val_loss\" }\n",
    )
    .unwrap();
    all.insert("train-sweep", keys_of(&sweep_parse, &sweep));
    all
}

/// The rows of the page, by config.
fn documented() -> BTreeMap<String, Vec<Row>> {
    let mut rows: BTreeMap<String, Vec<Row>> = BTreeMap::new();
    let mut current: Option<String> = None;
    for (i, line) in DOC.lines().enumerate() {
        let line = line.trim();
        if let Some(name) = line
            .strip_prefix("<!-- config:")
            .and_then(|s| s.strip_suffix("-->"))
        {
            current = Some(name.trim().to_string());
            rows.entry(name.trim().to_string()).or_default();
            continue;
        }
        if line.starts_with("## ") || line.starts_with("# ") {
            current = None;
            continue;
        }
        let (Some(config), Some(body)) = (&current, line.strip_prefix("| `")) else {
            continue;
        };
        let cells: Vec<&str> = line.trim_matches('|').split('|').map(str::trim).collect();
        assert!(
            cells.len() >= 4,
            "{DOC_PATH}:{}: a key row has four cells: | `key` | type | default | meaning |",
            i + 1
        );
        let key = body.split('`').next().unwrap_or("").to_string();
        assert_eq!(
            cells[0],
            format!("`{key}`"),
            "{DOC_PATH}:{}: the first cell is the key alone",
            i + 1
        );
        rows.get_mut(config).unwrap().push(Row {
            key,
            ty: cells[1].to_string(),
            default: cells[2].to_string(),
            line: i + 1,
        });
    }
    rows
}

/// Equal as config values: numbers of one kind, floats to 1e-6 relative (f32 fields
/// serialise with their binary digits).
fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Float(x), Value::Float(y)) => {
            x == y || (x - y).abs() <= 1e-6 * x.abs().max(y.abs())
        }
        (Value::Array(x), Value::Array(y)) => {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| same(p, q))
        }
        (Value::Table(x), Value::Table(y)) => {
            x.len() == y.len() && x.iter().all(|(k, v)| y.get(k).is_some_and(|w| same(v, w)))
        }
        _ => a == b,
    }
}

/// A default written in backticks, read as a TOML value.
fn written_default(cell: &str) -> Option<Result<Value, String>> {
    let inner = cell.strip_prefix('`')?.strip_suffix('`')?;
    if inner.contains('`') {
        return None;
    }
    Some(
        toml::from_str::<Table>(&format!("v = {inner}"))
            .map(|mut t| t.remove("v").unwrap())
            .map_err(|e| e.to_string()),
    )
}

fn kind_of(v: &Value) -> &'static str {
    match v {
        Value::Boolean(_) => "bool",
        Value::Integer(_) => "int",
        Value::Float(_) => "float",
        Value::String(_) => "string",
        Value::Array(_) => "array",
        Value::Table(_) => "table",
        Value::Datetime(_) => "datetime",
    }
}

#[test]
fn configuration_page_lists_every_key_with_its_default() {
    let structs = struct_keys();
    let docs = documented();
    let mut problems = Vec::new();
    for (config, keys) in &structs {
        let Some(rows) = docs.get(*config) else {
            problems.push(format!("no `<!-- config: {config} -->` section"));
            continue;
        };
        let mut seen = BTreeSet::new();
        for row in rows {
            let at = format!("{DOC_PATH}:{} ({config})", row.line);
            if !seen.insert(row.key.clone()) {
                problems.push(format!("{at}: `{}` is documented twice", row.key));
            }
            let Some(value) = keys.get(&row.key) else {
                problems.push(format!("{at}: `{}` is not a key of the config", row.key));
                continue;
            };
            if row.ty.is_empty() || row.default.is_empty() {
                problems.push(format!("{at}: `{}` needs a type and a default", row.key));
            }
            let Some(value) = value else { continue };
            if ["bool", "int", "float", "string"].contains(&row.ty.as_str())
                && row.ty != kind_of(value)
            {
                problems.push(format!(
                    "{at}: `{}` is a {}, the page says {}",
                    row.key,
                    kind_of(value),
                    row.ty
                ));
            }
            match written_default(&row.default) {
                None => {}
                Some(Err(e)) => problems.push(format!(
                    "{at}: the default of `{}` is not a TOML value: {e}",
                    row.key
                )),
                Some(Ok(written)) if !same(&written, value) => problems.push(format!(
                    "{at}: `{}` defaults to {value}, the page says {written}",
                    row.key
                )),
                Some(Ok(_)) => {}
            }
        }
        for key in keys.keys() {
            if !seen.contains(key) {
                problems.push(format!("{DOC_PATH} ({config}): `{key}` is not documented"));
            }
        }
    }
    for config in docs.keys() {
        if !structs.contains_key(config.as_str()) {
            problems.push(format!("{DOC_PATH}: unknown config section `{config}`"));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

/// The probe itself: it finds `Option` fields a serialised default leaves out, and the
/// comparison of defaults tells f32 digits from a wrong value.
#[test]
fn the_probe_lists_optional_fields_and_defaults_compare_by_value() {
    let sdfcnn = minimal::<SdfcnnTrainConfig>(
        "model = \"sdfcnn\"\nout = \"o\"\nepochs = 1\nbatch_size = 1\n[[data.train]]\npath = \"d\"\n",
    );
    assert!(!sdfcnn.contains_key("init"));
    let keys = keys_of(&serde_parse::<SdfcnnTrainConfig>, &sdfcnn);
    for key in [
        "init",
        "network.depth_focal",
        "data.val_size",
        "data.train[].camera",
    ] {
        assert_eq!(keys.get(key), Some(&None), "{key}");
    }
    assert!(keys.contains_key("optimizer.lr") && !keys.contains_key("optimizer"));
    let slam = keys_of(&serde_parse::<SlamConfig>, &table(&SlamConfig::default()));
    assert!(slam.contains_key("dense.levels[].step"), "{slam:?}");
    let smoothing = slam["features.fpfdcnn_smoothing"].clone().unwrap();
    assert!(same(
        &written_default("`2.0`").unwrap().unwrap(),
        &smoothing
    ));
    assert!(!same(
        &written_default("`2.1`").unwrap().unwrap(),
        &smoothing
    ));
    assert!(!same(&Value::Integer(2), &smoothing));
    assert!(written_default("required").is_none());
}
