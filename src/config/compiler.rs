//! A pipeline's checks, one named function each (in the manner of vector's
//! `config/compiler.rs`): counts, roles and stage values, wiring (cycles, fan-out, unknown
//! inputs), the chain from the source, kinds along it. Every error of every check is reported.

use super::{deserialize_all, edit_distance, Origin, Plan, RawPipeline};
use crate::checks::ConfigError;
use crate::stage::{Role, StageKind};
use std::collections::{BTreeMap, BTreeSet};

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
    compile(raw, table, type_errs).map_err(located)
}

fn err(key: impl Into<String>, message: impl Into<String>) -> ConfigError {
    ConfigError { key: key.into(), message: message.into() }
}

/// Every check in turn; the plan when none failed.
fn compile(raw: RawPipeline, table: toml::Table, type_errs: Vec<ConfigError>) -> Result<Plan, Vec<ConfigError>> {
    let mut errs = type_errs;
    check_counts(&raw, &mut errs);
    check_roles(&raw, &mut errs);
    let consumer = check_wiring(&raw, &mut errs);
    if !errs.is_empty() {
        return Err(errs);
    }
    let stages = follow_chain(&raw, &consumer, &mut errs);
    if errs.is_empty() {
        check_kinds(&stages, &mut errs);
    }
    if !errs.is_empty() {
        return Err(errs);
    }
    Ok(Plan { seed: raw.seed, run: raw.run, stages, resolved: table })
}

/// One source, one sink, a channel capacity in range.
fn check_counts(raw: &RawPipeline, errs: &mut Vec<ConfigError>) {
    if raw.sources.len() != 1 {
        errs.push(err("sources", format!("needs exactly one source (found {})", raw.sources.len())));
    }
    if raw.sinks.len() != 1 {
        errs.push(err("sinks", format!("needs exactly one sink (found {})", raw.sinks.len())));
    }
    if !(1..=1024).contains(&raw.run.channel_capacity) {
        errs.push(err("run.channel_capacity", format!("{} is out of range (expected 1 to 1024)", raw.run.channel_capacity)));
    }
}

/// Each stage under the table of its role, with its own value checks.
fn check_roles(raw: &RawPipeline, errs: &mut Vec<ConfigError>) {
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
}

/// The stages whose single input leads back to themselves.
fn cycles<'a>(input_of: &BTreeMap<&'a str, &'a str>) -> BTreeSet<&'a str> {
    let mut in_cycle = BTreeSet::new();
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
    in_cycle
}

/// Every input names a source or transform; each stage feeds at most one other (a chain);
/// stages in a cycle are named as one, never as fan-out. Returns who consumes each stage.
fn check_wiring(raw: &RawPipeline, errs: &mut Vec<ConfigError>) -> BTreeMap<String, String> {
    let names: Vec<&String> = raw.sources.keys().chain(raw.transforms.keys()).chain(raw.sinks.keys()).collect();
    let edges: Vec<(String, &[String])> = raw
        .transforms
        .iter()
        .map(|(n, t)| (format!("transforms.{n}"), t.config().inputs()))
        .chain(raw.sinks.iter().map(|(n, s)| (format!("sinks.{n}"), s.config().inputs())))
        .collect();
    let input_of: BTreeMap<&str, &str> = edges
        .iter()
        .filter(|(_, i)| i.len() == 1)
        .map(|(k, i)| (k.split_once('.').map_or(k.as_str(), |(_, n)| n), i[0].as_str()))
        .collect();
    let in_cycle = cycles(&input_of);
    let mut consumer: BTreeMap<String, String> = BTreeMap::new();
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
    consumer
}

/// The chain from the source to the sink; a stage it does not reach is an error.
fn follow_chain(raw: &RawPipeline, consumer: &BTreeMap<String, String>, errs: &mut Vec<ConfigError>) -> Vec<(String, StageKind)> {
    let (sname, src) = raw.sources.iter().next().expect("one source");
    let mut stages = vec![(sname.clone(), src.clone())];
    let mut cur = sname.clone();
    let mut seen = BTreeSet::new();
    while let Some(next) = consumer.get(&cur) {
        if !seen.insert(next.clone()) {
            errs.push(err("transforms", format!("cycle detected through {next:?}")));
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
    if let Some(n) = raw.transforms.keys().chain(raw.sinks.keys()).find(|n| !reached.contains(n)).filter(|_| errs.is_empty()) {
        errs.push(err(n.to_string(), "is not connected to the source (a cycle or a dangling stage)"));
    }
    stages
}

/// What each stage gets is what the one before it makes.
fn check_kinds(stages: &[(String, StageKind)], errs: &mut Vec<ConfigError>) {
    let mut kind = stages[0].1.config().kinds().1;
    for (name, st) in stages.iter().skip(1) {
        let (want, out) = st.config().kinds();
        if want != kind {
            errs.push(err(name.clone(), format!("data type mismatch: gets {} (expects {})", kind.name(), want.name())));
            return;
        }
        kind = out;
    }
}
