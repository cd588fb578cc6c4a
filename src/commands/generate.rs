//! `pipeline generate` and `run`: pipelines from the command line.

use crate::graph::RunOptions;
use crate::progress::ProgressMode;
use clap::Args;
use std::path::PathBuf;

/// Options shared by the commands that run a pipeline.
#[derive(Args, Debug, Clone)]
pub struct RunCommon {
    /// Override one key of the pipeline file: --set transforms.noise.sigma=3 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
    /// This task's share of the sorted inputs (input i goes to task i % count). Default:
    /// SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX, else 0.
    #[arg(long)]
    pub shard_index: Option<usize>,
    /// Number of tasks. Default: SLURM_ARRAY_TASK_COUNT, else 1.
    #[arg(long)]
    pub shard_count: Option<usize>,
    /// Progress display on stderr.
    #[arg(long, value_enum, default_value_t = ProgressMode::Auto)]
    pub progress: ProgressMode,
}

#[derive(Args, Debug)]
pub struct GenerateArgs {
    /// Video files, folders of videos, file-name globs, or - for a stream on standard input
    /// (`ffmpeg ... -f nut - | pipeline generate -`); default: the pipeline's paths.
    pub videos: Vec<String>,
    /// Output folder (shards, manifest.json, report.json).
    #[arg(short, long)]
    pub out: Option<PathBuf>,
    /// Pipeline file instead of the embedded pipelines/generate.toml.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub common: RunCommon,
}

#[derive(Args, Debug)]
pub struct RunArgs {
    /// Pipeline file (TOML).
    pub pipeline: PathBuf,
    /// Output folder (sets the sink's dir).
    #[arg(short, long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub common: RunCommon,
}

pub use crate::config::{generate_table, GENERATE_TOML};

fn env_usize(name: &str) -> anyhow::Result<Option<usize>> {
    match std::env::var(name) {
        Ok(v) if !v.trim().is_empty() => {
            v.trim().parse().map(Some).map_err(|_| crate::Error::Usage(format!("{name}={v:?} is not a whole number")).into())
        }
        _ => Ok(None),
    }
}

/// Task index and count from flags, then Slurm or Kubernetes variables.
fn task_split(c: &RunCommon) -> anyhow::Result<(usize, usize)> {
    let (index, index_from) = match c.shard_index {
        Some(i) => (i, "--shard-index"),
        None => match (env_usize("SLURM_ARRAY_TASK_ID")?, env_usize("JOB_COMPLETION_INDEX")?) {
            (Some(i), _) => (i, "SLURM_ARRAY_TASK_ID"),
            (None, Some(i)) => (i, "JOB_COMPLETION_INDEX"),
            (None, None) => (0, "the default"),
        },
    };
    let (count, count_from) = match c.shard_count {
        Some(n) => (n, "--shard-count"),
        None => match env_usize("SLURM_ARRAY_TASK_COUNT")? {
            Some(n) => (n, "SLURM_ARRAY_TASK_COUNT"),
            None => (1, "the default"),
        },
    };
    if count == 0 {
        return Err(crate::Error::Usage(format!("{count_from} is 0; the task count must be at least 1")).into());
    }
    if index >= count {
        let hint = if count_from == "SLURM_ARRAY_TASK_COUNT" {
            " (a retried single array element such as `sbatch --array=17` sees a task count of 1: pass the whole job's count with --shard-count, as docs/scaling.md does)"
        } else if count_from == "the default" {
            " (pass the number of tasks with --shard-count)"
        } else {
            ""
        };
        return Err(crate::Error::Usage(format!(
            "task index {index} (from {index_from}) must be below the task count {count} (from {count_from}){hint}"
        ))
        .into());
    }
    Ok((index, count))
}

fn run_plan(table: toml::Table, origin: &crate::config::Origin, out: Option<&PathBuf>, c: &RunCommon) -> anyhow::Result<()> {
    let mut plan = crate::config::plan_from(table, origin)?;
    if let Some(o) = out {
        plan.set_out_dir(o);
    }
    let (task_index, task_count) = task_split(c)?;
    let opts = RunOptions { task_index, task_count, progress: c.progress };
    let o = crate::graph::run(&plan, &opts)?;
    let r = &o.report;
    eprintln!(
        "{} inputs done ({} skipped as already in the manifest), {} frames, {} windows, {} samples in {:.1} s: {:.1} frames/s, {:.1} sub-frames/s blurred -> {}",
        r.inputs_done,
        r.inputs_skipped.len(),
        r.frames,
        r.windows,
        r.samples,
        r.seconds,
        r.frames_per_s,
        r.subframes_per_s,
        o.out_dir.display()
    );
    if !r.inputs_failed.is_empty() {
        for f in &r.inputs_failed {
            eprintln!("failed: {}", f.error);
        }
        return Err(crate::Error::InputsFailed { n: r.inputs_failed.len(), report: o.out_dir.join("report.json") }.into());
    }
    Ok(())
}

/// Runs `pipeline generate`: the embedded pipelines/generate.toml (or `--config`) over the
/// videos given.
///
/// # Errors
/// As [`crate::graph::run`]; failed inputs as [`crate::Error::InputsFailed`].
pub fn generate(a: GenerateArgs) -> anyhow::Result<()> {
    let (table, origin) = generate_table(a.config.as_deref(), &a.videos, &a.common.sets)?;
    run_plan(table, &origin, a.out.as_ref(), &a.common)
}

/// Runs `pipeline run`: a pipeline file.
///
/// # Errors
/// As [`generate`].
pub fn run(a: RunArgs) -> anyhow::Result<()> {
    let table = crate::config::load(&a.pipeline, &a.common.sets)?;
    let origin = crate::config::Origin::new(&a.pipeline.display().to_string(), None, &a.common.sets);
    run_plan(table, &origin, a.out.as_ref(), &a.common)
}
