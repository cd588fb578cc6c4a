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

mod compiler;
mod deserialize;
mod reads;
mod sets;

pub use crate::checks::Origin;
pub use crate::error::toml_error;
use crate::stage::StageKind;
pub use compiler::{plan, plan_from};
pub use deserialize::deserialize_all;
use serde::{Deserialize, Serialize};
pub use sets::{apply_sets, generate_table, load, load_or_embedded, parse, GENERATE_TOML};
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

pub(crate) fn edit_distance(a: &str, b: &str) -> usize {
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
    #[cfg(feature = "ffmpeg")] // generate.toml reads video (`decode`)
    fn type_errors_and_unknown_keys_all_come_in_one_pass_with_their_full_keys_and_origins() {
        let text = include_str!("../../pipelines/generate.toml").replace("per_window = 8", "per_window = \"eight\"");
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
