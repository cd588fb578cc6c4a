//! Settings files read (with their TOML errors located) and `--set key.path=value` applied; the
//! embedded generate pipeline.

use super::Origin;
use std::path::Path;

/// Applies `key.path=value` overrides to a TOML table. The value is read as TOML (`3`,
/// `[0, 9]`, `"x"`, `true`) and as a bare string when that fails.
///
/// # Errors
/// A `--set` without `=`, or a path through a value that is not a table.
pub fn apply_sets(table: &mut toml::Table, sets: &[String]) -> Result<(), String> {
    for s in sets {
        let (path, value) = s.split_once('=').ok_or_else(|| format!("--set {s:?}: expected key.path=value"))?;
        let value = value.trim();
        let parsed = toml::from_str::<toml::Table>(&format!("v = {value}")).map(|mut t| t.remove("v").expect("v"));
        // A bare word is a string (`camera.type=conventional`); what starts like a number, an
        // array, a table or a quoted string must parse as one, or it is an error in plain words.
        let literal = value.starts_with(|c: char| c.is_ascii_digit() || "[{\"'+-.".contains(c));
        let parsed = match parsed {
            Ok(v) => v,
            Err(e) if literal => {
                let why = e.message().lines().next().unwrap_or("").to_string();
                let hint = if value.trim_start_matches(['+', '-']).chars().all(|c| c.is_ascii_digit()) {
                    " (integers are at most 9223372036854775807)".to_string()
                } else {
                    String::new()
                };
                return Err(format!("--set {}: {value:?} is not a TOML value: {why}{hint}", path.trim()));
            }
            Err(_) => toml::Value::String(value.to_string()),
        };
        let keys: Vec<&str> = path.trim().split('.').collect();
        // Bare TOML keys only: `trans forms.x` would otherwise become a new top-level key, which
        // the unknown-key check would then blame on the settings file.
        if let Some(k) = keys.iter().find(|k| k.is_empty() || !k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')) {
            return Err(format!("--set {s:?}: {k:?} is not a key (keys are letters, digits, _ and -, joined by dots)"));
        }
        let mut cur = &mut *table;
        for (i, k) in keys.iter().enumerate() {
            if i + 1 == keys.len() {
                cur.insert(k.to_string(), parsed.clone());
            } else {
                let next = cur.entry(k.to_string()).or_insert_with(|| toml::Value::Table(toml::Table::new()));
                cur = next.as_table_mut().ok_or_else(|| format!("--set {path}: {k} is not a table"))?;
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

/// A TOML syntax error as the `toml` crate words it, with the line it quotes cut to 80
/// characters around the error: a file of one 600 KB line (deeply nested arrays, say) is
/// reported in a few lines, not echoed whole.
pub fn toml_error(e: &toml::de::Error, text: &str) -> String {
    const HALF: usize = 40;
    let Some(span) = e.span().filter(|s| s.start <= text.len() && text.is_char_boundary(s.start)) else {
        return e.to_string().trim().to_string();
    };
    let before = &text[..span.start];
    let line_no = before.matches('\n').count() + 1;
    let start = before.rfind('\n').map_or(0, |i| i + 1);
    let end = text[start..].find('\n').map_or(text.len(), |i| start + i);
    let line: Vec<char> = text[start..end].trim_end_matches('\r').chars().collect();
    let col = text[start..span.start].chars().count();
    let (from, to) = (col.saturating_sub(HALF), (col + HALF).min(line.len()));
    let pre = if from > 0 { "..." } else { "" };
    let post = if to < line.len() { "..." } else { "" };
    let snippet: String = line[from.min(to)..to].iter().collect();
    let gutter = " ".repeat(line_no.to_string().len());
    format!(
        "TOML parse error at line {line_no}, column {}\n{gutter} |\n{line_no} | {pre}{snippet}{post}\n{gutter} | {}^\n{}",
        col + 1,
        " ".repeat(pre.len() + col - from.min(col)),
        e.message().trim()
    )
}

/// As [`load`], from text.
///
/// # Errors
/// See [`load`].
pub fn parse(text: &str, origin: &str, sets: &[String]) -> Result<toml::Table, crate::Error> {
    let mut table: toml::Table =
        toml::from_str(text).map_err(|e| crate::Error::ConfigText(format!("{origin}: {}", toml_error(&e, text))))?;
    apply_sets(&mut table, sets).map_err(crate::Error::ConfigText)?;
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
            .ok_or_else(|| crate::Error::ConfigText(format!("{origin}: the pipeline has no [sources]")))?;
        for (_, src) in sources.iter_mut() {
            if let Some(t) = src.as_table_mut() {
                t.insert("paths".into(), toml::Value::Array(paths.iter().map(|v| toml::Value::String(v.clone())).collect()));
            }
        }
    }
    apply_sets(&mut table, sets).map_err(crate::Error::ConfigText)?;
    let text = config.is_none().then_some(GENERATE_TOML);
    Ok((table, Origin::new(&origin, text, sets)))
}
