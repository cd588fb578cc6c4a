//! Runs a [`Plan`]: one thread per stage, bounded crossbeam channels between them
//! (backpressure), the first error stops every stage and is reported with the stage's name,
//! Ctrl-C stops cleanly (sinks remove what they had not finished). Progress goes to stderr:
//! bars on a terminal, a plain line every few seconds otherwise. `report.json` is written to
//! the output folder.
//!
//! Files: `mod.rs` (a run: prepare the output and the inputs, execute, assemble the report),
//! `threads.rs` (stages on threads and channels), `report.rs`, `progress.rs`, `stream.rs` (the
//! samples without a sink, for Python).

mod progress;
mod report;
mod stream;
mod threads;

pub use report::{FailedInput, Report, StageReport};
pub use stream::{Next, SampleStream};

use crate::config::Plan;
use crate::frame::Input;
use crate::progress::ProgressMode;
use crate::sample::content_hash;
use crate::stage::{input_key, Counters, InputList};
use crate::{Error, Result};
use progress::Progress;
use report::write_report;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// How this run fits a sharded job and where it writes.
#[derive(Debug, Clone)]
pub struct RunOptions {
    pub task_index: usize,
    pub task_count: usize,
    pub progress: ProgressMode,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions { task_index: 0, task_count: 1, progress: ProgressMode::Never }
    }
}

/// What `run` returns: the report (also written to the output folder).
pub struct Outcome {
    pub report: Report,
    pub out_dir: PathBuf,
}

/// Builds the stages of a plan and runs them to the end: `prepare` the output and the
/// inputs, `execute` the stages, `assemble` the report.
///
/// # Errors
/// Configuration that only shows at build time, an unwritable output folder, or the first
/// fatal error (or panic) of any stage (named). Failed inputs are not errors: they are in the
/// report.
pub fn run(plan: &Plan, opts: &RunOptions) -> Result<Outcome> {
    crate::signal::install();
    let t0 = Instant::now();
    let prep = prepare(plan, opts, t0)?;
    let ran = execute(plan, opts, &prep)?;
    assemble(plan, opts, prep, ran, t0)
}

/// What [`prepare`] settled before any stage is built.
struct Prepared {
    out_dir: PathBuf,
    settings: String,
    stem: &'static str,
    /// The report so far (provenance, task, stale files removed).
    report: Report,
    /// This task's inputs still to do; those the sink holds already; those it redoes, and why.
    selected: Vec<(Arc<Input>, Option<PathBuf>)>,
    skipped: Vec<String>,
    redone: Vec<FailedInput>,
}

/// The output folder checked and made, killed runs' temporaries removed, and this task's
/// inputs minus what the sink already holds. Doing nothing is not success: sources that name
/// no input stop before anything is written.
fn prepare(plan: &Plan, opts: &RunOptions, t0: Instant) -> Result<Prepared> {
    let all = list_inputs(plan)?;
    if all.is_empty() {
        return Err(Error::Usage(format!(
            "no input: the source's paths name no file it reads; give videos ({}) or folders of them on the command line, or set sources.*.paths",
            crate::stage::input::VIDEO_EXTS.join(", ")
        )));
    }
    let settings = content_hash(&plan.resolved);
    let out_dir = plan.out_dir();
    if std::fs::symlink_metadata(&out_dir).is_ok_and(|m| !m.is_dir()) && !out_dir.is_dir() {
        return Err(Error::Usage(format!("{}: a file; the output is a folder (made if missing)", out_dir.display())));
    }
    let task = (opts.task_index, opts.task_count);
    plan.sink().admits(&out_dir, task)?;
    std::fs::create_dir_all(&out_dir).map_err(|e| Error::Io { path: out_dir.clone(), cause: e })?;
    let probe = out_dir.join(format!(".write-test.{}", std::process::id()));
    crate::io::create_new(&probe).map_err(|e| Error::Io { path: out_dir.clone(), cause: e })?;
    let _ = std::fs::remove_file(&probe);
    // Temporary files of killed runs on this machine (their process is gone) go first.
    let stale = crate::io::remove_stale(&out_dir, 3);
    for p in &stale {
        eprintln!("removed {} (left by a run that was killed)", p.display());
    }
    let mut report = Report::start(crate::provenance::Provenance::now(), &out_dir, plan, opts, all.len());
    report.stale_removed = stale.iter().map(|p| p.display().to_string()).collect();
    let stem = plan.sink().report_stem();
    // What the sink already holds from earlier runs (whole, same settings) is skipped. A run
    // refused here (a damaged or tampered manifest) still says so in its report.
    let completed = match plan.sink().completed(&out_dir, task, &settings) {
        Ok(c) => c,
        Err(e) => {
            report.error = Some(e.chain());
            report.seconds = t0.elapsed().as_secs_f64();
            let _ = write_report(&out_dir, opts, stem, &report);
            return Err(e);
        }
    };
    let (mine, skipped): (Vec<_>, Vec<_>) =
        all.into_iter().filter(|(i, _)| i.index % opts.task_count == opts.task_index).partition(|(i, _)| !completed.keys.contains(&i.key));
    let skipped: Vec<String> = skipped.into_iter().map(|(i, _)| i.path.clone()).collect();
    let redone = completed
        .redo
        .into_iter()
        .map(|(path, error)| {
            let ours = mine.iter().any(|(i, _)| i.path == path);
            eprintln!("{}: {path}: {error}", if ours { "redoing" } else { "warning: not redone (not an input of this run)" });
            FailedInput { path, error }
        })
        .collect();
    Ok(Prepared { out_dir, settings, stem, report, selected: mine, skipped, redone })
}

/// What the stages left: their reports, the sink's summary and failed inputs, the first fatal
/// error, and the counters.
struct Ran {
    stages: Vec<StageReport>,
    sink: Option<serde_json::Value>,
    failures: Vec<(String, String)>,
    fatal: Option<Error>,
    counters: Arc<Counters>,
}

/// Builds every stage, runs each on its thread (the sink on this scope's), shows progress
/// until the sink is done.
fn execute(plan: &Plan, opts: &RunOptions, prep: &Prepared) -> Result<Ran> {
    let counters = Arc::new(Counters::default());
    Counters::add(&counters.inputs_total, prep.selected.len() as u64);
    let task = (opts.task_index, opts.task_count);
    let built = threads::build(plan, &prep.selected, &counters, &prep.out_dir, task, &prep.settings, true)?;
    let sink = built.sink.expect("built with its sink");
    let stop = Arc::new(AtomicBool::new(false));
    let first: threads::FirstError = Arc::new(Mutex::new(None));
    let progress = Progress::new(opts.progress, counters.clone(), prep.selected.len());
    let (rx, handles) = threads::start(built.source, built.transforms, plan.run.channel_capacity, &stop, &first);
    let (stages, sink, failures) = std::thread::scope(|s| {
        let sink_handle = s.spawn(|| threads::run_sink(sink, rx, &stop, &first));
        while !sink_handle.is_finished() {
            progress.tick();
            std::thread::sleep(std::time::Duration::from_millis(100));
        }
        let mut stages: Vec<StageReport> = handles.into_iter().map(|h| h.join().expect("stage threads catch their panics")).collect();
        let (report, summary, failures) = sink_handle.join().expect("the sink thread catches its panics");
        stages.push(report);
        (stages, summary, failures)
    });
    progress.finish();
    let fatal = first.lock().expect("error slot").take();
    Ok(Ran { stages, sink, failures, fatal, counters })
}

/// The run's report from what the stages left, written (also for a run that failed); the
/// first fatal error or the interruption as the result.
fn assemble(plan: &Plan, opts: &RunOptions, prep: Prepared, ran: Ran, t0: Instant) -> Result<Outcome> {
    let Prepared { out_dir, stem, report, selected, skipped, redone, .. } = prep;
    let c = &ran.counters;
    let secs = t0.elapsed().as_secs_f64();
    let (frames, windows, samples) = (Counters::get(&c.frames), Counters::get(&c.windows), Counters::get(&c.samples_kept));
    let subframes = windows * plan.subframes_per_window() as u64;
    let n_selected = selected.len() + skipped.len();
    let interrupted = crate::signal::interrupted();
    let report = Report {
        inputs_selected: n_selected,
        inputs_skipped: skipped,
        inputs_redone: redone,
        inputs_done: Counters::get(&c.inputs_done),
        inputs_failed: ran.failures.into_iter().map(|(path, error)| FailedInput { path, error }).collect(),
        inputs: c.inputs.lock().expect("inputs").clone(),
        frames,
        windows,
        subframes,
        samples,
        seconds: secs,
        frames_per_s: frames as f64 / secs,
        subframes_per_s: subframes as f64 / secs,
        samples_per_s: samples as f64 / secs,
        stages: ran.stages,
        sink: ran.sink.unwrap_or(serde_json::Value::Null),
        interrupted,
        error: ran.fatal.as_ref().map(Error::chain),
        ..report
    };
    // A trainer sink writes its own report.json; the generation report then goes beside it.
    if let Some(e) = ran.fatal {
        // The error is what the user must see; the report of a run that failed is best effort.
        let _ = write_report(&out_dir, opts, stem, &report);
        return Err(e);
    }
    write_report(&out_dir, opts, stem, &report)?;
    if interrupted {
        return Err(Error::Interrupted(format!(
            "{} of {} inputs finished and listed in the manifest, unfinished outputs removed (report.json says which); \
             run the same command again to do the rest",
            report.inputs_done, n_selected
        )));
    }
    Ok(Outcome { report, out_dir })
}
/// The inputs of the plan's source, sorted, each with its global index.
///
/// # Errors
/// A path that does not exist as a folder or pattern.
pub fn list_inputs(plan: &Plan) -> Result<Vec<(Arc<Input>, Option<PathBuf>)>> {
    let paths: Vec<Option<PathBuf>> = match plan.source().list()? {
        InputList::Files(f) => f.into_iter().map(Some).collect(),
        InputList::Procedural(n) => (0..n).map(|_| None).collect(),
    };
    Ok(paths
        .into_iter()
        .enumerate()
        .map(|(i, p)| {
            use std::os::unix::ffi::OsStrExt;
            let (path, identity) = match &p {
                // Standard input: a stream of its own each time (never skipped as done).
                Some(p) if p.as_os_str() == "-" || p.as_os_str() == "pipe:0" => {
                    let t = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_nanos());
                    ("stdin".to_string(), format!("stdin {} {t}", std::process::id()).into_bytes())
                }
                Some(p) => {
                    let canon = std::fs::canonicalize(p).unwrap_or_else(|_| p.clone());
                    (p.display().to_string(), canon.as_os_str().as_bytes().to_vec())
                }
                None => (format!("procedural-{i:05}"), format!("procedural-{i:05} seed {}", plan.seed).into_bytes()),
            };
            let id = crate::rng::hash_bytes(&identity);
            (Arc::new(Input { index: i, id, key: input_key(&path, id), path }), p)
        })
        .collect())
}
