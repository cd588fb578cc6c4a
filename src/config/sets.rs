//! Settings files read (with their TOML errors located) and `--set key.path=value` applied; the
//! embedded generate pipeline.

use super::Origin;
use crate::error::SetError;
use std::path::Path;

/// Applies `key.path=value` overrides to a TOML table. The value is read as TOML (`3`,
/// `[0, 9]`, `"x"`, `true`) and as a bare string when that fails.
///
/// # Errors
/// A `--set` without `=`, a value that starts like a number, array, table or quoted string but
/// is not one, a key that is not a bare TOML key, or a path through a value that is not a table.
pub fn apply_sets(table: &mut toml::Table, sets: &[String]) -> Result<(), SetError> {
    for s in sets {
        let (path, value) = s.split_once('=').ok_or_else(|| SetError::NoEquals { set: s.clone() })?;
        let value = value.trim();
        let parsed = toml::from_str::<toml::Table>(&format!("v = {value}")).map(|mut t| t.remove("v").expect("v"));
        // A bare word is a string (`camera.type=conventional`); what starts like a number, an
        // array, a table or a quoted string must parse as one, or it is an error in plain words.
        let literal = value.starts_with(|c: char| c.is_ascii_digit() || "[{\"'+-.".contains(c));
        let parsed = match parsed {
            Ok(v) => v,
            Err(e) if literal => {
                return Err(SetError::NotValue { key: path.trim().into(), value: value.into(), cause: Box::new(e) });
            }
            Err(_) => toml::Value::String(value.to_string()),
        };
        let keys: Vec<&str> = path.trim().split('.').collect();
        // Bare TOML keys only: `trans forms.x` would otherwise become a new top-level key, which
        // the unknown-key check would then blame on the settings file.
        if let Some(k) = keys.iter().find(|k| k.is_empty() || !k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')) {
            return Err(SetError::NotKey { set: s.clone(), key: k.to_string() });
        }
        let mut cur = &mut *table;
        for (i, k) in keys.iter().enumerate() {
            if i + 1 == keys.len() {
                cur.insert(k.to_string(), parsed.clone());
            } else {
                let next = cur.entry(k.to_string()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
                cur = next.as_table_mut().ok_or_else(|| SetError::NotTable { key: path.into(), part: k.to_string() })?;
            }
        }
    }
    Ok(())
}

/// Reads a pipeline file and applies overrides; syntax and unknown keys are errors naming
/// the file, line and key.
///
/// # Errors
/// See above.
pub fn load(path: &Path, sets: &[String]) -> Result<toml::Table, crate::Error> {
    let bytes = crate::io::paths::read_regular(path, crate::io::paths::MAX_CONFIG_BYTES, "TOML settings file").map_err(|e| match e {
        // A config that is not there is a mistake in the command line: exit 2.
        crate::Error::Io { cause, .. } if cause.kind() == std::io::ErrorKind::NotFound => {
            crate::Error::Usage(format!("{}: no such configuration file", path.display()))
        }
        e => e,
    })?;
    let text = String::from_utf8(bytes)
        .map_err(|_| crate::Error::File { path: path.to_path_buf(), why: "not UTF-8 text; expected a TOML settings file".into() })?;
    parse(&text, &path.display().to_string(), sets)
}

/// As [`load`], from text.
///
/// # Errors
/// See [`load`].
pub fn parse(text: &str, origin: &str, sets: &[String]) -> Result<toml::Table, crate::Error> {
    let mut table: toml::Table = toml::from_str(text).map_err(crate::Error::toml(origin, Some(text)))?;
    apply_sets(&mut table, sets)?;
    Ok(table)
}

/// The default generate pipeline, embedded.
pub const GENERATE_TOML: &str = include_str!("../../pipelines/generate.toml");

/// The file given with `--config`, or the embedded default named `name`, with `--set` applied;
/// and the name to put in error messages.
pub fn load_or_embedded(
    config: Option<&std::path::Path>,
    embedded: &str,
    name: &str,
    sets: &[String],
) -> crate::Result<(toml::Table, String)> {
    match config {
        Some(p) => Ok((load(p, sets)?, p.display().to_string())),
        None => {
            let origin = format!("{name} (embedded)");
            Ok((parse(embedded, &origin, sets)?, origin))
        }
    }
}

/// The pipeline `pipeline generate` runs: `config` (default: the embedded
/// pipelines/generate.toml) with every source reading `paths` (when given), then the `sets`
/// applied; and where each value came from, for error messages. The Python dataset builds its
/// plan here too, so it makes what `generate` makes.
///
/// # Errors
/// An unreadable or malformed file, a pipeline without sources, a bad `--set`.
pub fn generate_table(
    config: Option<&std::path::Path>,
    paths: &[String],
    sets: &[String],
) -> crate::Result<(toml::Table, crate::config::Origin)> {
    let (mut table, origin) = load_or_embedded(config, GENERATE_TOML, "pipelines/generate.toml", &[])?;
    if !paths.is_empty() {
        let sources = table
            .get_mut("sources")
            .and_then(|s| s.as_table_mut())
            .ok_or_else(|| crate::checks::ConfigError { key: "sources".into(), message: format!("{origin} has none") })?;
        for (_, src) in sources.iter_mut() {
            if let Some(t) = src.as_table_mut() {
                t.insert("paths".into(), toml::Value::Array(paths.iter().map(|v| toml::Value::String(v.clone())).collect()));
            }
        }
    }
    apply_sets(&mut table, sets)?;
    let text = config.is_none().then_some(GENERATE_TOML);
    Ok((table, Origin::new(&origin, text, sets)))
}
