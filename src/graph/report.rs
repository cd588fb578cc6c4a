//! What a run reports: per stage, per input, the counts and speeds, written as
//! `reports/report[-{task}-of-{n}]-{time}-{pid}.json` and `report.json`.

use super::RunOptions;
use crate::config::Plan;
use crate::Result;
use serde::Serialize;
use std::path::Path;

#[derive(Debug, Clone, Serialize)]
pub struct StageReport {
    pub name: String,
    pub kind: String,
    /// Seconds spent working (not waiting on its neighbours).
    pub busy_s: f64,
    pub items_in: u64,
    /// What the stage decided at build time that a reader of the run should know (the blur's
    /// low-rank ranks and error bound), when it has any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub details: Option<serde_json::Value>,
}

#[derive(Debug, Clone, Serialize)]
pub struct FailedInput {
    pub path: String,
    pub error: String,
}

/// A run's report: `reports/report[-{task}-of-{n}]-{time}-{pid}.json`, one per run, never
/// overwritten, and a copy as `report.json` (the latest run).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    #[serde(flatten)]
    pub provenance: crate::provenance::Provenance,
    /// The output folder as resolved (`-o`, else the sink's `dir`).
    pub out_dir: String,
    pub seed: u64,
    pub task_index: usize,
    pub task_count: usize,
    pub inputs_total: usize,
    pub inputs_selected: usize,
    pub inputs_skipped: Vec<String>,
    /// Inputs the manifest listed whose shards were missing, damaged or made with other
    /// settings (redone when this run reads them), and why.
    pub inputs_redone: Vec<FailedInput>,
    /// Temporary files of killed runs removed at the start.
    pub stale_removed: Vec<String>,
    pub inputs_done: u64,
    pub inputs_failed: Vec<FailedInput>,
    /// Size, frame rate, codec and frame counts of every input read.
    pub inputs: Vec<crate::stage::InputReport>,
    pub frames: u64,
    pub windows: u64,
    pub subframes: u64,
    /// Samples of the inputs that finished (none of a failed input).
    pub samples: u64,
    pub seconds: f64,
    pub frames_per_s: f64,
    pub subframes_per_s: f64,
    pub samples_per_s: f64,
    pub stages: Vec<StageReport>,
    pub sink: serde_json::Value,
    pub interrupted: bool,
    /// Why the run stopped before its end (a refused manifest, a full disk), or null.
    pub error: Option<String>,
    /// The process's peak resident memory when the report was written, in MB (Linux), or null.
    pub peak_rss_mb: Option<f64>,
    pub config: serde_json::Value,
}

impl Report {
    /// A report of nothing done yet, for `plan` run with `opts` into `out_dir`.
    pub(super) fn start(
        provenance: crate::provenance::Provenance,
        out_dir: &Path,
        plan: &Plan,
        opts: &RunOptions,
        inputs_total: usize,
    ) -> Report {
        Report {
            provenance,
            out_dir: out_dir.display().to_string(),
            seed: plan.seed,
            task_index: opts.task_index,
            task_count: opts.task_count,
            inputs_total,
            inputs_selected: 0,
            inputs_skipped: Vec::new(),
            inputs_redone: Vec::new(),
            stale_removed: Vec::new(),
            inputs_done: 0,
            inputs_failed: Vec::new(),
            inputs: Vec::new(),
            frames: 0,
            windows: 0,
            subframes: 0,
            samples: 0,
            seconds: 0.0,
            frames_per_s: 0.0,
            subframes_per_s: 0.0,
            samples_per_s: 0.0,
            stages: Vec::new(),
            sink: serde_json::Value::Null,
            interrupted: false,
            error: None,
            peak_rss_mb: None,
            config: serde_json::to_value(&plan.resolved).unwrap_or(serde_json::Value::Null),
        }
    }
}

/// Writes `reports/{stem}[-{task}-of-{n}]-{time}-{pid}.json` (kept) and `{stem}[-{task}-of-{n}].json`
/// (the latest run of this task).
pub(super) fn write_report(dir: &Path, opts: &RunOptions, stem: &str, r: &Report) -> Result<()> {
    let stem = if opts.task_count > 1 { format!("{stem}-{:05}-of-{:05}", opts.task_index, opts.task_count) } else { stem.to_string() };
    let mut r = r.clone();
    r.peak_rss_mb = crate::provenance::peak_rss_kb().map(|k| k as f64 / 1024.0);
    let bytes = serde_json::to_vec_pretty(&r).expect("json");
    let runs = crate::io::make_dir_in(dir, Path::new("reports"))?;
    crate::io::write_atomic(&runs.join(r.provenance.file_name(&stem)), |w| w.write_all(&bytes))?;
    crate::io::write_atomic(&dir.join(format!("{stem}.json")), |w| w.write_all(&bytes))
}
