//! Loading: TOML text and `--set` overrides merged into one `toml::Table`, then checked key by
//! key so that every unknown key and wrong type is reported with its dotted path, all at once.
//!
//! How the per-key check works: each leaf of the user's table is deserialized on its own, nested
//! under its path in an otherwise empty table (every section has `serde(default)`, so the only
//! way such a probe fails is that leaf). Failing leaves are reported and removed; the rest is
//! deserialized into a [`Config`] that is then validated, so range problems are listed in the
//! same error as parse problems.

use toml::{Table, Value};

use super::error::{Checker, ConfigError, ConfigIssue};
use super::Config;

/// Parses TOML text into a table; `origin` names the source in the error (a path or `--set`).
pub(crate) fn parse_table(text: &str, origin: &str) -> Result<Table, ConfigError> {
    text.parse::<Table>().map_err(|err| ConfigError::Syntax {
        origin: origin.to_owned(),
        message: err.to_string().trim_end().to_owned(),
    })
}

/// Applies one `dotted.key=value` override to `table`. The value is parsed as a TOML value
/// (`0.5`, `true`, `[256, 256]`, `"text"`); if it is not valid TOML it is taken as a bare string,
/// so `--set env.task=antmaze-s` works without quotes.
pub(crate) fn apply_override(table: &mut Table, arg: &str) -> Result<(), ConfigError> {
    let bad = |reason: &str| ConfigError::Override {
        arg: arg.to_owned(),
        reason: reason.to_owned(),
    };
    let (key, raw) = arg.split_once('=').ok_or_else(|| bad("missing `=`"))?;
    let segments: Vec<&str> = key.trim().split('.').collect();
    let valid_segment =
        |s: &&str| !s.is_empty() && s.chars().all(|ch| ch.is_ascii_alphanumeric() || ch == '_');
    if !segments.iter().all(valid_segment) {
        return Err(bad(
            "the key must be dot-separated names of letters, digits and `_`",
        ));
    }
    let value = parse_override_value(raw.trim());
    let (last, parents) = segments.split_last().ok_or_else(|| bad("empty key"))?;
    let mut node = table;
    for (depth, segment) in parents.iter().enumerate() {
        let entry = node
            .entry((*segment).to_owned())
            .or_insert_with(|| Value::Table(Table::new()));
        node = entry.as_table_mut().ok_or_else(|| {
            bad(&format!(
                "`{}` is a value, not a section",
                segments[..=depth].join(".")
            ))
        })?;
    }
    node.insert((*last).to_owned(), value);
    Ok(())
}

/// A TOML value from override text, or the text itself as a string.
fn parse_override_value(raw: &str) -> Value {
    let parsed = format!("v = {raw}")
        .parse::<Table>()
        .ok()
        .and_then(|mut t| t.remove("v"));
    parsed.unwrap_or_else(|| Value::String(raw.to_owned()))
}

/// Deserializes `table` into a [`Config`], reporting every bad key and every invalid value.
pub(crate) fn table_to_config(mut table: Table) -> Result<Config, ConfigError> {
    let mut checker = Checker::new();
    let mut bad_paths = Vec::new();
    probe_table(&table, &mut Vec::new(), &mut checker, &mut bad_paths);
    for path in &bad_paths {
        remove_path(&mut table, path);
    }
    let config: Config = table.try_into().map_err(|err: toml::de::Error| {
        let issue = ConfigIssue {
            path: "(config)".to_owned(),
            value: "(whole file)".to_owned(),
            message: err.message().trim().to_owned(),
        };
        ConfigError::Invalid(super::ConfigErrors {
            issues: vec![issue],
        })
    })?;
    let mut issues = checker.into_issues();
    if let Err(errors) = config.validate() {
        issues.extend(errors.issues);
    }
    if issues.is_empty() {
        Ok(config)
    } else {
        Err(ConfigError::Invalid(super::ConfigErrors { issues }))
    }
}

/// Walks `table` (found at `prefix`), probing each key; records failing paths in `bad`.
fn probe_table(
    table: &Table,
    prefix: &mut Vec<String>,
    checker: &mut Checker,
    bad: &mut Vec<Vec<String>>,
) {
    for (key, value) in table {
        prefix.push(key.clone());
        let probe_value = match value {
            Value::Table(_) => Value::Table(Table::new()),
            other => other.clone(),
        };
        match probe(prefix, probe_value) {
            Err(message) => {
                let shown = if value.is_table() {
                    "{…}".to_owned()
                } else {
                    value.to_string()
                };
                checker.issue(&prefix.join("."), shown, message);
                bad.push(prefix.clone());
            }
            Ok(()) => {
                if let Value::Table(inner) = value {
                    probe_table(inner, prefix, checker, bad);
                }
            }
        }
        prefix.pop();
    }
}

/// Deserializes a table holding only `value` at `path`; `Err` carries serde's message.
fn probe(path: &[String], value: Value) -> Result<(), String> {
    let mut nested = value;
    for key in path.iter().rev() {
        let mut table = Table::new();
        table.insert(key.clone(), nested);
        nested = Value::Table(table);
    }
    let Value::Table(table) = nested else {
        return Ok(());
    };
    table
        .try_into::<Config>()
        .map(drop)
        .map_err(|err| describe_serde_error(err.message()))
}

/// Rewords serde's messages into advice where a common case is recognised.
fn describe_serde_error(message: &str) -> String {
    let message = message.trim();
    if message.starts_with("unknown field") {
        format!(
            "unknown key: {}",
            message.trim_start_matches("unknown field").trim()
        )
    } else {
        message.to_owned()
    }
}

/// Removes the value at `path` from `table` (no-op if absent).
fn remove_path(table: &mut Table, path: &[String]) {
    let Some((last, parents)) = path.split_last() else {
        return;
    };
    let mut node = table;
    for key in parents {
        match node.get_mut(key).and_then(Value::as_table_mut) {
            Some(inner) => node = inner,
            None => return,
        }
    }
    node.remove(last);
}
