//! Pipeline files: TOML -> [`RawPipeline`] (serde, unknown keys rejected) -> [`Plan`] (a checked
//! chain of stages). All semantic errors are reported in one pass, each naming its key.
//!
//! ```toml
//! seed = 0
//! [sources.video]
//! type = "decode"
//! paths = ["clips/*.mp4"]
//! [transforms.linear]
//! type = "linearize"
//! inputs = ["video"]
//! [transforms.blur]
//! type = "coded_blur"
//! inputs = ["linear"]
//! [sinks.out]
//! type = "shards"
//! inputs = ["blur"]
//! ```

use crate::checks::ConfigError;
pub use crate::checks::Origin;
use crate::stage::{Role, StageKind};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// `[run]`: how the graph runs.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Capacity of each bounded channel between stages (backpressure).
    pub channel_capacity: usize,
}

impl Default for RunConfig {
    fn default() -> Self {
        RunConfig { channel_capacity: 4 }
    }
}

/// A pipeline file as written; each stage's config is its own type in `src/stage/`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawPipeline {
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub run: RunConfig,
    #[serde(default)]
    pub sources: BTreeMap<String, StageKind>,
    #[serde(default)]
    pub transforms: BTreeMap<String, StageKind>,
    #[serde(default)]
    pub sinks: BTreeMap<String, StageKind>,
}

/// A checked chain: source, transforms in order, sink.
#[derive(Debug, Clone)]
pub struct Plan {
    pub seed: u64,
    pub run: RunConfig,
    /// (name, stage) from source to sink.
    pub stages: Vec<(String, StageKind)>,
    /// The resolved file, for the report.
    pub resolved: toml::Table,
}

impl Plan {
    pub fn source(&self) -> &dyn crate::stage::StageConfig {
        self.stages[0].1.config()
    }
    pub fn sink(&self) -> &dyn crate::stage::StageConfig {
        self.stages.last().expect("non-empty plan").1.config()
    }
    /// What the stages after stage `i` need of each input.
    pub fn needs_after(&self, i: usize) -> crate::stage::Needs {
        self.stages[i + 1..].iter().map(|(_, s)| s.config().needs()).fold(crate::stage::Needs::default(), |a, b| a.max(b))
    }
    /// Sub-frames per window of the plan (0 without a blur).
    pub fn subframes_per_window(&self) -> usize {
        self.stages.iter().map(|(_, s)| s.config().subframes_per_window()).max().unwrap_or(0)
    }
    /// The output folder of the sink.
    pub fn out_dir(&self) -> PathBuf {
        PathBuf::from(self.sink().out_dir().unwrap_or("out"))
    }
    pub fn set_out_dir(&mut self, dir: &Path) {
        let d = dir.to_string_lossy().into_owned();
        // The recorded config shows the folder actually written.
        let name = self.stages.last().expect("non-empty plan").0.clone();
        if let Some(toml::Value::Table(t)) = self.resolved.get_mut("sinks").and_then(|s| s.get_mut(&name)) {
            t.insert("dir".into(), toml::Value::String(d.clone()));
        }
        self.stages.last_mut().expect("non-empty plan").1.config_mut().set_out_dir(d);
    }
}

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
        // Bare TOML keys only: `trans forms.x` used to become a new top-level key that the
        // unknown-key check then blamed on the settings file.
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

fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut cur = vec![i + 1];
        for (j, cb) in b.iter().enumerate() {
            cur.push((prev[j] + usize::from(ca != *cb)).min(prev[j + 1] + 1).min(cur[j] + 1));
        }
        prev = cur;
    }
    prev[b.len()]
}

/// The default generate pipeline, embedded.
pub const GENERATE_TOML: &str = include_str!("../pipelines/generate.toml");

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

/// Deserialises `table` as `T`, collecting every type error and unknown key (serde stops at the
/// first): each error's culprit is the leaf whose removal makes that error go away; it is
/// removed and the rest tried again. Returns the value (with the bad keys at their defaults) if
/// one could be made, and the errors with their full keys.
pub fn deserialize_all<T: serde::de::DeserializeOwned>(table: &toml::Table) -> (Option<T>, Vec<ConfigError>) {
    fn leaves(t: &toml::Table, prefix: &str, out: &mut Vec<String>) {
        for (k, v) in t {
            let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
            match v {
                toml::Value::Table(sub) if !sub.is_empty() => leaves(sub, &key, out),
                _ => out.push(key),
            }
        }
    }
    fn remove(t: &mut toml::Table, key: &str) {
        match key.split_once('.') {
            Some((head, rest)) => {
                if let Some(toml::Value::Table(sub)) = t.get_mut(head) {
                    remove(sub, rest);
                }
            }
            None => {
                t.remove(key);
            }
        }
    }
    fn get<'a>(t: &'a toml::Table, key: &str) -> Option<&'a toml::Table> {
        key.split('.').filter(|k| !k.is_empty()).try_fold(t, |t, k| t.get(k)?.as_table())
    }
    let de = |t: &toml::Table| toml::Value::Table(t.clone()).try_into::<T>().map_err(|e| e.to_string());
    let mut t = table.clone();
    let mut errs = Vec::new();
    for _ in 0..256 {
        let e = match de(&t) {
            Ok(v) => return (Some(v), errs),
            Err(e) => e,
        };
        let message = e.lines().next().unwrap_or("").trim().to_string();
        let at = e.lines().find_map(|l| l.trim().strip_prefix("in `").and_then(|l| l.strip_suffix('`'))).unwrap_or("").to_string();
        let mut cands = Vec::new();
        if let Some(sub) = get(&t, &at) {
            leaves(sub, &at, &mut cands);
        } else if !at.is_empty() {
            // The error names a value itself (`seed = -4`): that value is the culprit.
            cands.push(at.clone());
        }
        let culprit = cands.into_iter().find(|leaf| {
            let mut u = t.clone();
            remove(&mut u, leaf);
            match de(&u) {
                Ok(_) => true,
                Err(e2) => e2 != e && !e2.contains("missing field"),
            }
        });
        match culprit {
            Some(leaf) => {
                errs.push(ConfigError { key: leaf.clone(), message });
                remove(&mut t, &leaf);
            }
            None => {
                errs.push(ConfigError { key: if at.is_empty() { "(file)".into() } else { at }, message });
                return (None, errs);
            }
        }
    }
    (None, errs)
}

/// Checks a resolved table and builds the plan, or returns every error found.
///
/// # Errors
/// Every error at once (wrong types, unknown keys, bad values, wiring), each with its full key.
pub fn plan(table: toml::Table, origin: &str) -> Result<Plan, crate::Error> {
    plan_from(table, &Origin::from(origin))
}

/// As [`plan`], each error saying where its value came from (file line or `--set`).
///
/// # Errors
/// See [`plan`].
pub fn plan_from(table: toml::Table, origin: &Origin) -> Result<Plan, crate::Error> {
    let located = |errs| origin.errors(errs);
    // A stage this build leaves out is named as such, not as an unknown kind.
    #[cfg(not(feature = "train"))]
    {
        let trainers: Vec<ConfigError> = ["sources", "transforms", "sinks"]
            .iter()
            .filter_map(|role| Some((role, table.get(*role)?.as_table()?)))
            .flat_map(|(role, stages)| stages.iter().map(move |(n, s)| (role, n, s)))
            .filter(|(_, _, s)| s.get("type").and_then(|t| t.as_str()) == Some("trainer"))
            .map(|(role, n, _)| ConfigError {
                key: format!("{role}.{n}.type"),
                message: "the `trainer` sink trains, which this build leaves out (burn): cargo build --release --features train".into(),
            })
            .collect();
        if !trainers.is_empty() {
            return Err(located(trainers));
        }
    }
    let (raw, type_errs) = deserialize_all::<RawPipeline>(&table);
    let Some(raw) = raw else { return Err(located(type_errs)) };
    plan_checked(raw, table, type_errs).map_err(|e| match e {
        crate::Error::Config(errs) => located(errs),
        e => e,
    })
}

fn plan_checked(raw: RawPipeline, table: toml::Table, type_errs: Vec<ConfigError>) -> Result<Plan, crate::Error> {
    let mut errs: Vec<ConfigError> = type_errs;
    let err = |key: String, message: String| ConfigError { key, message };
    if raw.sources.len() != 1 {
        errs.push(err("sources".into(), format!("needs exactly one source (found {})", raw.sources.len())));
    }
    if raw.sinks.len() != 1 {
        errs.push(err("sinks".into(), format!("needs exactly one sink (found {})", raw.sinks.len())));
    }
    if !(1..=1024).contains(&raw.run.channel_capacity) {
        errs.push(err("run.channel_capacity".into(), format!("{} is out of range (expected 1 to 1024)", raw.run.channel_capacity)));
    }
    // Each stage under the table of its role, with its own checks.
    for (table_name, stages, role) in
        [("sources", &raw.sources, Role::Source), ("transforms", &raw.transforms, Role::Transform), ("sinks", &raw.sinks, Role::Sink)]
    {
        for (n, s) in stages {
            let c = s.config();
            if c.role() != role {
                errs.push(err(
                    format!("{table_name}.{n}.type"),
                    format!("a {} stage belongs under [{}.{n}]", c.role().table(), c.role().table()),
                ));
            }
            errs.extend(c.validate(&format!("{table_name}.{n}")));
        }
    }
    // Wiring: every input names a stage; each stage feeds at most one other (a chain).
    let names: Vec<&String> = raw.sources.keys().chain(raw.transforms.keys()).chain(raw.sinks.keys()).collect();
    let mut consumer: BTreeMap<String, String> = BTreeMap::new();
    let edges: Vec<(String, &[String])> = raw
        .transforms
        .iter()
        .map(|(n, t)| (format!("transforms.{n}"), t.config().inputs()))
        .chain(raw.sinks.iter().map(|(n, s)| (format!("sinks.{n}"), s.config().inputs())))
        .collect();
    // Stages whose inputs lead back to themselves: named as a cycle, never as fan-out.
    let input_of: BTreeMap<&str, &str> = edges
        .iter()
        .filter(|(_, i)| i.len() == 1)
        .map(|(k, i)| (k.split_once('.').map_or(k.as_str(), |(_, n)| n), i[0].as_str()))
        .collect();
    let mut in_cycle = std::collections::BTreeSet::new();
    for &start in input_of.keys() {
        let mut cur = start;
        for _ in 0..input_of.len() {
            match input_of.get(cur) {
                Some(&next) if next == start => {
                    in_cycle.insert(start);
                    break;
                }
                Some(&next) => cur = next,
                None => break,
            }
        }
    }
    for (key, inputs) in &edges {
        let short = key.split_once('.').map_or(key.as_str(), |(_, n)| n);
        if in_cycle.contains(short) {
            let mut cycle = vec![short];
            while let Some(&next) = input_of.get(cycle[cycle.len() - 1]).filter(|n| **n != short) {
                cycle.push(next);
            }
            let what = if cycle.len() == 1 {
                format!("{short:?} names itself as its input")
            } else {
                format!("{short:?} is in a cycle ({} <- {short})", cycle.join(" <- "))
            };
            errs.push(err(format!("{key}.inputs"), format!("{what}; stages form a chain from the source")));
            continue;
        }
        if inputs.len() != 1 {
            errs.push(err(format!("{key}.inputs"), format!("needs exactly one input (found {}); stages form a chain", inputs.len())));
            continue;
        }
        let input = &inputs[0];
        if !names.contains(&input) || raw.sinks.contains_key(input) {
            let best = names.iter().filter(|n| !raw.sinks.contains_key(n.as_str())).min_by_key(|n| edit_distance(n, input));
            let hint = best.filter(|b| edit_distance(b, input) <= 2).map(|b| format!(" (did you mean {b:?}?)")).unwrap_or_default();
            errs.push(err(format!("{key}.inputs"), format!("input {input:?} doesn't match any source or transform{hint}")));
            continue;
        }
        if let Some(prev) = consumer.insert(input.clone(), short.to_string()) {
            errs.push(err(format!("{key}.inputs"), format!("{input:?} already feeds {prev:?}; fan-out is not supported")));
        }
    }
    // Follow the chain from the source.
    let mut stages: Vec<(String, StageKind)> = Vec::new();
    if errs.is_empty() {
        let (sname, src) = raw.sources.iter().next().expect("one source");
        stages.push((sname.clone(), src.clone()));
        let mut cur = sname.clone();
        let mut seen = std::collections::BTreeSet::new();
        while let Some(next) = consumer.get(&cur) {
            if !seen.insert(next.clone()) {
                errs.push(err("transforms".into(), format!("cycle detected through {next:?}")));
                break;
            }
            if let Some(t) = raw.transforms.get(next) {
                stages.push((next.clone(), t.clone()));
            } else if let Some(s) = raw.sinks.get(next) {
                stages.push((next.clone(), s.clone()));
                break;
            }
            cur = next.clone();
        }
        let reached: Vec<&String> = stages.iter().map(|(n, _)| n).collect();
        for n in raw.transforms.keys().chain(raw.sinks.keys()) {
            if !reached.contains(&n) && errs.is_empty() {
                errs.push(err(n.to_string(), "is not connected to the source (a cycle or a dangling stage)".into()));
            }
        }
        // Kinds along the chain.
        let mut kind = stages[0].1.config().kinds().1;
        for (name, st) in stages.iter().skip(1) {
            let (want, out) = st.config().kinds();
            if want != kind {
                errs.push(err(name.clone(), format!("data type mismatch: gets {} (expects {})", kind.name(), want.name())));
                break;
            }
            kind = out;
        }
    }
    if !errs.is_empty() {
        return Err(crate::Error::Config(errs));
    }
    Ok(Plan { seed: raw.seed, run: raw.run, stages, resolved: table })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_syntax_error_on_a_huge_line_is_quoted_in_a_few_lines() {
        // Issue 31: 100,000 nested arrays were echoed as one 200 KB line.
        let deep = format!("seed = 1\na = {}{}\n", "[".repeat(100_000), "]".repeat(100_000));
        let e = parse(&deep, "deep.toml", &[]).unwrap_err().to_string();
        assert!(e.len() < 400, "{} bytes: {}", e.len(), &e[..400.min(e.len())]);
        assert!(e.starts_with("deep.toml: TOML parse error at line 2, column "), "{e}");
        assert!(e.contains("recursion"), "{e}");
        // A short line is quoted whole, the caret under the error.
        let e = parse("seed = 1\nx = = 2\n", "f.toml", &[]).unwrap_err().to_string();
        assert!(e.contains("2 | x = = 2\n  |     ^"), "{e}");
    }

    const GOOD: &str = r#"
seed = 3
[sources.video]
type = "stills"
[transforms.linear]
type = "linearize"
inputs = ["video"]
[transforms.blur]
type = "coded_blur"
inputs = ["linear"]
[sinks.out]
type = "shards"
inputs = ["blur"]
"#;

    fn plan_of(text: &str, sets: &[&str]) -> Result<Plan, crate::Error> {
        let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
        plan(parse(text, "test.toml", &sets)?, "test.toml")
    }

    #[test]
    fn a_chain_plans_in_order() {
        let p = plan_of(GOOD, &[]).unwrap();
        let names: Vec<&str> = p.stages.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["video", "linear", "blur", "out"]);
        assert_eq!(p.seed, 3);
    }

    #[test]
    fn a_typo_is_rejected_naming_the_key() {
        let e = plan_of(&GOOD.replace("inputs = [\"linear\"]", "inputs = [\"linear\"]\nwindw = 9"), &[]).unwrap_err().to_string();
        assert!(e.contains("windw") && e.contains("test.toml"), "{e}");
        let e = plan_of(GOOD, &["transforms.blur.camera.typ=\"flutter\""]).unwrap_err().to_string();
        assert!(e.contains("typ"), "{e}");
    }

    #[test]
    fn every_value_error_comes_in_one_pass() {
        let e = plan_of(GOOD, &["transforms.blur.window=99", "transforms.blur.optics.pupil_samples=2", "run.channel_capacity=0"])
            .unwrap_err()
            .to_string();
        for key in ["transforms.blur.window", "transforms.blur.optics.pupil_samples", "run.channel_capacity"] {
            assert!(e.contains(key), "{key} missing from: {e}");
        }
    }

    #[test]
    fn type_errors_and_unknown_keys_all_come_in_one_pass_with_their_full_keys_and_origins() {
        let text = include_str!("../pipelines/generate.toml").replace("per_window = 8", "per_window = \"eight\"");
        let sets = vec!["transforms.blur.window=\"x\"".to_string(), "sinks.shards.colour=1".to_string()];
        let mut t: toml::Table = toml::from_str(&text).unwrap();
        apply_sets(&mut t, &sets).unwrap();
        let origin = Origin::new("g.toml", Some(&text), &sets);
        let Err(crate::Error::Config(errs)) = plan_from(t, &origin) else { panic!("must fail") };
        let msgs: Vec<String> = errs.iter().map(|e| e.to_string()).collect();
        let line = text.lines().position(|l| l.starts_with("per_window")).unwrap() + 1;
        let want = [
            ("sinks.shards.colour", "--set sinks.shards.colour=1".to_string()),
            ("transforms.blur.window", "--set transforms.blur.window=\"x\"".to_string()),
            ("transforms.patches.per_window", format!("g.toml line {line}")),
        ];
        assert_eq!(msgs.len(), 3, "{msgs:#?}");
        for ((key, from), m) in want.iter().zip(&msgs) {
            assert!(m.starts_with(&format!("{key}: ")) && m.ends_with(&format!("({from})")), "{m}");
        }
    }

    #[test]
    fn wiring_errors_say_what_is_wrong() {
        let e = plan_of(&GOOD.replace("inputs = [\"linear\"]", "inputs = [\"linaer\"]"), &[]).unwrap_err().to_string();
        assert!(e.contains("did you mean \"linear\""), "{e}");
        // linear <-> blur form a loop cut off from the source.
        let cyc = GOOD
            .replace("inputs = [\"video\"]", "inputs = [\"blur\"]")
            .replace("type = \"shards\"\ninputs = [\"blur\"]", "type = \"shards\"\ninputs = [\"video\"]");
        let e = plan_of(&cyc, &[]).unwrap_err().to_string();
        assert!(e.contains("cycle (linear <- blur <- linear)"), "{e}");
        let e = plan_of(
            &GOOD
                .replace("inputs = [\"blur\"]", "inputs = [\"linear\"]")
                .replace("inputs = [\"linear\"]\n[sinks", "inputs = [\"video\"]\n[sinks"),
            &[],
        );
        assert!(e.is_err());
        // blur fed encoded frames: a type mismatch.
        let e = plan_of(
            &GOOD
                .replace("inputs = [\"linear\"]", "inputs = [\"video\"]")
                .replace("[transforms.linear]\ntype = \"linearize\"\ninputs = [\"video\"]\n", ""),
            &[],
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("data type mismatch"), "{e}");
    }

    #[test]
    fn sets_parse_values_as_toml() {
        let p = plan_of(GOOD, &["transforms.blur.window=11", "transforms.blur.camera.type=conventional"]).unwrap();
        let blur = p.stages.iter().find_map(|(_, s)| match s {
            StageKind::CodedBlur(b) => Some(b),
            _ => None,
        });
        assert_eq!(blur.unwrap().window, 11);
        assert_eq!(blur.unwrap().camera.kind, crate::optics::CameraKind::Conventional);
    }

    /// Values that start like a TOML literal but do not parse are named in plain words (issue
    /// 31), not passed on as strings for serde to call "invalid type: string".
    #[test]
    fn a_set_value_that_is_not_toml_is_named_in_plain_words() {
        let e = plan_of(GOOD, &["seed=18446744073709551615"]).unwrap_err().to_string();
        assert!(e.contains("--set seed") && e.contains("not a TOML value") && e.contains("at most 9223372036854775807"), "{e}");
        let noisy = GOOD.replace(
            "[sinks.out]\ntype = \"shards\"\ninputs = [\"blur\"]",
            "[transforms.noise]\ntype = \"noise\"\ninputs = [\"blur\"]\nsigma = 1.0\n[sinks.out]\ntype = \"shards\"\ninputs = [\"noise\"]",
        );
        assert!(plan_of(&noisy, &[]).is_ok());
        let e = plan_of(&noisy, &["transforms.noise.sigma=[1,"]).unwrap_err().to_string();
        assert!(e.contains("--set transforms.noise.sigma") && e.contains("not a TOML value") && !e.contains("untagged"), "{e}");
        let e = plan_of(&noisy, &["transforms.noise.sigma=abc"]).unwrap_err().to_string();
        assert!(e.contains("transforms.noise.sigma") && e.contains("a number or a range") && !e.contains("untagged"), "{e}");
    }

    /// A stage that names itself, or stages that feed each other, are named as such on their
    /// own keys (issue 31: they were "fan-out is not supported" against another stage's key).
    #[test]
    fn a_stage_naming_itself_or_a_cycle_is_named_on_its_own_key() {
        let own = GOOD.replace("inputs = [\"linear\"]", "inputs = [\"blur\"]");
        let e = plan_of(&own, &[]).unwrap_err().to_string();
        assert!(e.contains("transforms.blur.inputs") && e.contains("names itself"), "{e}");
        assert!(!e.contains("fan-out"), "{e}");
        let cycle = GOOD.replace("inputs = [\"video\"]", "inputs = [\"blur\"]");
        let e = plan_of(&cycle, &[]).unwrap_err().to_string();
        assert!(e.contains("transforms.linear.inputs") && e.contains("cycle (linear <- blur <- linear)"), "{e}");
        assert!(!e.contains("fan-out"), "{e}");
    }
}
