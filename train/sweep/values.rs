//! Config values addressed by dotted field paths (`loss.lambda`): where keys are in a TOML
//! file, flattening and merging tables, looking values up, and showing values in folder names
//! and tables.

use std::collections::HashMap;
use toml::{Table, Value};

/// Byte offsets of every key of a TOML document, by dotted path (array-of-tables entries as
/// `points[2]`), for error messages with line numbers and for the file order of keys.
pub(super) fn key_offsets(text: &str) -> HashMap<String, usize> {
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
pub(super) fn flatten(table: &Table, prefix: &str, out: &mut Vec<(String, Value)>) {
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
pub(super) fn apply(
    table: &mut Table,
    path: &str,
    value: &Value,
) -> std::result::Result<(), String> {
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
pub(crate) fn lookup<'a>(value: &'a Value, path: &str) -> Option<&'a Value> {
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
pub(super) fn sanitize(s: &str) -> String {
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
pub(super) fn first_difference(a: &Value, b: &Value, prefix: &str) -> Option<String> {
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

pub(super) fn lookup_in<'a>(table: &'a Table, path: &str) -> Option<&'a Value> {
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

pub(super) fn short_labels(keys: &[String]) -> Vec<String> {
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

pub(super) fn duplicate<T: PartialEq + std::fmt::Display>(list: &[T]) -> Option<String> {
    list.iter()
        .enumerate()
        .find(|(i, v)| list[..*i].contains(v))
        .map(|(_, v)| v.to_string())
}
