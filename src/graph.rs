//! Runs a [`Plan`]: one thread per stage, bounded crossbeam channels between them
//! (backpressure), the first error stops every stage and is reported with the stage's name,
//! Ctrl-C stops cleanly (sinks remove what they had not finished). Progress goes to stderr:
//! bars on a terminal, a plain line every few seconds otherwise. `report.json` is written to
//! the output folder.

use crate::config::Plan;
use crate::frame::{Input, Item};
use crate::sample::content_hash;
use crate::stage::{input_key, BuildContext, Built, Counters, Emit, InputList, Sink, Source, StageError, Transform};
use crate::{Error, Result};
use crossbeam_channel::{bounded, Receiver, RecvTimeoutError};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::progress::ProgressMode;

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
    fn start(provenance: crate::provenance::Provenance, out_dir: &Path, plan: &Plan, opts: &RunOptions, inputs_total: usize) -> Report {
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

/// Read planning: which pixels each stage needs, decided from the plan before any stage is built.
impl Plan {
    /// The patches stage `i` may cut first: when it takes them and the stages after it up to a
    /// patch stage all work pixel by pixel.
    pub fn crop_for(&self, i: usize) -> Option<crate::stage::patches::Selector> {
        if !self.stages[i].1.config().takes_crop() {
            return None;
        }
        self.stages[i + 1..].iter().map(|(_, s)| s.config()).find(|c| !c.per_pixel()).and_then(|c| c.crop_selector())
    }
    /// What a source (stage `i` = 0) needs to decode of each frame: with patches cut before the
    /// blur and only position-keeping stages (linearize) between it and the blur, the patches
    /// plus the kernel margin of the windows each frame belongs to.
    ///
    /// # Errors
    /// The blur's kernels cannot be made.
    pub fn reads_for(&self, i: usize, seed: u64) -> crate::Result<Option<crate::stage::patches::ReadRegions>> {
        if i != 0 || self.stages.len() < 2 {
            return Ok(None);
        }
        let Some(j) = (1..self.stages.len()).find(|&j| !self.stages[j].1.config().keeps_positions()) else {
            return Ok(None);
        };
        let (Some(selector), Some(geometry)) = (self.crop_for(j), self.stages[j].1.config().crop_geometry()?) else {
            return Ok(None);
        };
        Ok(Some(crate::stage::patches::ReadRegions { selector, seed, geometry }))
    }
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

/// Runs a stage loop, timing the work and the waiting.
struct Timing {
    start: Instant,
    waiting: Duration,
    items: u64,
}

impl Timing {
    fn new() -> Timing {
        Timing { start: Instant::now(), waiting: Duration::ZERO, items: 0 }
    }
    fn busy(&self) -> f64 {
        (self.start.elapsed().saturating_sub(self.waiting)).as_secs_f64()
    }
}

fn recv(rx: &Receiver<Item>, stop: &AtomicBool, t: &mut Timing) -> Option<Item> {
    let w = Instant::now();
    loop {
        if stop.load(Ordering::Relaxed) || crate::signal::interrupted() {
            stop.store(true, Ordering::Relaxed);
            t.waiting += w.elapsed();
            return None;
        }
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(i) => {
                t.waiting += w.elapsed();
                t.items += 1;
                return Some(i);
            }
            Err(RecvTimeoutError::Timeout) => continue,
            Err(RecvTimeoutError::Disconnected) => {
                t.waiting += w.elapsed();
                return None;
            }
        }
    }
}

fn input_of(item: &Item) -> Option<usize> {
    match item {
        Item::Begin(i, _) | Item::Frame(i, _, _) | Item::End(i, _) => Some(i.index),
        Item::Sample(s) => Some(s.input.index),
    }
}

type FirstError = Arc<Mutex<Option<Error>>>;

fn record(first: &FirstError, stop: &AtomicBool, stage: &str, e: Error) {
    let mut g = first.lock().expect("error slot");
    if g.is_none() {
        *g = Some(Error::Stage { stage: stage.to_string(), source: Box::new(e) });
    }
    stop.store(true, Ordering::Relaxed);
}

/// What `run` returns: the report (also written to the output folder).
pub struct Outcome {
    pub report: Report,
    pub out_dir: PathBuf,
}

/// Builds the stages of a plan and runs them to the end.
///
/// # Errors
/// Configuration that only shows at build time, an unwritable output folder, or the first
/// fatal error of any stage (named). Failed inputs are not errors: they are in the report.
pub fn run(plan: &Plan, opts: &RunOptions) -> Result<Outcome> {
    crate::signal::install();
    let t0 = Instant::now();
    let provenance = crate::provenance::Provenance::now();
    // Inputs: sorted, then this task's share, minus what the manifest already lists. Doing
    // nothing is not success: sources that name no input stop before anything is written.
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
    plan.sink().admits(&out_dir, (opts.task_index, opts.task_count))?;
    std::fs::create_dir_all(&out_dir).map_err(|e| Error::Io { path: out_dir.clone(), cause: e })?;
    let probe = out_dir.join(format!(".write-test.{}", std::process::id()));
    crate::io::create_new(&probe).map_err(|e| Error::Io { path: out_dir.clone(), cause: e })?;
    let _ = std::fs::remove_file(&probe);

    // Temporary files of killed runs on this machine (their process is gone) go first.
    let stale = crate::io::remove_stale(&out_dir, 3);
    for p in &stale {
        eprintln!("removed {} (left by a run that was killed)", p.display());
    }

    // What the sink already holds from earlier runs (whole, same settings) is skipped.
    let task = (opts.task_index, opts.task_count);
    let mut report = Report::start(provenance, &out_dir, plan, opts, all.len());
    report.stale_removed = stale.iter().map(|p| p.display().to_string()).collect();
    let stem = plan.sink().report_stem();
    // A run refused here (a damaged or tampered manifest) still says so in its report.
    let completed = match plan.sink().completed(&out_dir, task, &settings) {
        Ok(c) => c,
        Err(e) => {
            report.error = Some(e.chain());
            report.seconds = t0.elapsed().as_secs_f64();
            let _ = write_report(&out_dir, opts, stem, &report);
            return Err(e);
        }
    };
    let mut skipped = Vec::new();
    let selected: Vec<(Arc<Input>, Option<PathBuf>)> = all
        .into_iter()
        .filter(|(i, _)| i.index % opts.task_count == opts.task_index)
        .filter(|(i, _)| {
            let skip = completed.keys.contains(&i.key);
            if skip {
                skipped.push(i.path.clone());
            }
            !skip
        })
        .collect();
    let redone: Vec<FailedInput> = completed
        .redo
        .into_iter()
        .map(|(path, error)| {
            let ours = selected.iter().any(|(i, _)| i.path == path);
            eprintln!("{}: {path}: {error}", if ours { "redoing" } else { "warning: not redone (not an input of this run)" });
            FailedInput { path, error }
        })
        .collect();
    let n_selected = selected.len() + skipped.len();

    let counters = Arc::new(Counters::default());
    Counters::add(&counters.inputs_total, selected.len() as u64);

    // Build every stage before any thread starts; each gets its own config and the context.
    let built = build(plan, &selected, &counters, &out_dir, task, &settings, true)?;
    let (sink_name, mut sink) = built.sink.expect("built with its sink");
    let stop = Arc::new(AtomicBool::new(false));
    let first: FirstError = Arc::new(Mutex::new(None));
    let cap = plan.run.channel_capacity;
    let mut reports: Vec<StageReport> = Vec::new();
    let sink_summary: Mutex<Option<serde_json::Value>> = Mutex::new(None);
    let mut failures = Vec::new();
    let progress = Progress::new(opts.progress, counters.clone(), selected.len());

    std::thread::scope(|s| {
        let (rx, handles) = start(built.source, built.transforms, cap, &stop, &first);
        let sink_handle = {
            let (stop, first, name, summary) = (stop.clone(), first.clone(), sink_name.clone(), &sink_summary);
            let sink = &mut sink;
            s.spawn(move || {
                let mut t = Timing::new();
                let mut satisfied = false;
                while let Some(item) = recv(&rx, &stop, &mut t) {
                    if let Err(e) = sink.consume(item) {
                        record(&first, &stop, &name, e);
                        break;
                    }
                    if !sink.wants_more() {
                        // Done early (a trainer at its last step): stop the sources, finish.
                        satisfied = true;
                        stop.store(true, Ordering::Relaxed);
                        break;
                    }
                }
                if stop.load(Ordering::Relaxed) && !satisfied {
                    sink.abort();
                } else {
                    match sink.finish() {
                        Ok(v) => *summary.lock().expect("summary") = Some(v),
                        Err(e) => {
                            record(&first, &stop, &name, e);
                            sink.abort();
                        }
                    }
                }
                StageReport { name, kind: "sink".into(), busy_s: t.busy(), items_in: t.items, details: None }
            })
        };
        while !sink_handle.is_finished() {
            progress.tick();
            std::thread::sleep(Duration::from_millis(100));
        }
        for h in handles {
            reports.push(h.join().expect("stage thread"));
        }
        reports.push(sink_handle.join().expect("sink thread"));
    });
    progress.finish();
    failures.extend(sink.failures());
    let fatal = first.lock().expect("error slot").take();
    let interrupted = crate::signal::interrupted();
    let secs = t0.elapsed().as_secs_f64();
    let (frames, windows, samples) =
        (Counters::get(&counters.frames), Counters::get(&counters.windows), Counters::get(&counters.samples_kept));
    let subframes = windows * plan.subframes_per_window() as u64;
    let report = Report {
        inputs_selected: n_selected,
        inputs_skipped: skipped,
        inputs_redone: redone,
        inputs_done: Counters::get(&counters.inputs_done),
        inputs_failed: failures.into_iter().map(|(path, error)| FailedInput { path, error }).collect(),
        inputs: counters.inputs.lock().expect("inputs").clone(),
        frames,
        windows,
        subframes,
        samples,
        seconds: secs,
        frames_per_s: frames as f64 / secs,
        subframes_per_s: subframes as f64 / secs,
        samples_per_s: samples as f64 / secs,
        stages: reports,
        sink: sink_summary.into_inner().expect("summary").unwrap_or(serde_json::Value::Null),
        interrupted,
        error: fatal.as_ref().map(Error::chain),
        ..report
    };
    // A trainer sink writes its own report.json; the generation report then goes beside it.
    if let Some(e) = fatal {
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

/// A plan's stages, built for this task's inputs.
struct Stages {
    source: (String, Box<dyn Source>),
    /// (name, type, runtime)
    transforms: Vec<(String, String, Box<dyn Transform>)>,
    sink: Option<(String, Box<dyn Sink>)>,
}

/// Builds every stage (the sink only `with_sink`) before any thread starts; each gets its own
/// config and the context.
fn build(
    plan: &Plan,
    selected: &[(Arc<Input>, Option<PathBuf>)],
    counters: &Arc<Counters>,
    out_dir: &Path,
    task: (usize, usize),
    settings: &str,
    with_sink: bool,
) -> Result<Stages> {
    let (mut source, mut transforms, mut sink) = (None, Vec::new(), None);
    let last = plan.stages.len() - 1;
    for (i, (name, st)) in plan.stages.iter().enumerate() {
        if i == last && !with_sink {
            break;
        }
        let ctx = BuildContext {
            name,
            seed: plan.seed,
            inputs: selected,
            needs: plan.needs_after(i),
            crop: plan.crop_for(i),
            reads: plan.reads_for(i, plan.seed).map_err(|e| Error::Stage { stage: name.clone(), source: Box::new(e) })?,
            counters: counters.clone(),
            out_dir,
            task,
            settings,
        };
        match st.config().build(&ctx).map_err(|e| Error::Stage { stage: name.clone(), source: Box::new(e) })? {
            Built::Source(s) => source = Some((name.clone(), s)),
            Built::Transform(t) => transforms.push((name.clone(), st.type_name(), t)),
            Built::Sink(s) => sink = Some((name.clone(), s)),
        }
    }
    Ok(Stages { source: source.expect("a plan starts with a source"), transforms, sink })
}

/// Starts the source and each transform on its own thread, joined by bounded channels; the
/// last transform's items come out of the returned receiver. Every stage stops when `stop` is
/// set or its receiver is dropped; the first fatal error goes to `first`.
fn start(
    source: (String, Box<dyn Source>),
    transforms: Vec<(String, String, Box<dyn Transform>)>,
    cap: usize,
    stop: &Arc<AtomicBool>,
    first: &FirstError,
) -> (Receiver<Item>, Vec<std::thread::JoinHandle<StageReport>>) {
    let (tx0, mut rx) = bounded::<Item>(cap);
    let mut handles = Vec::new();
    {
        let (stop, first, (name, mut source)) = (stop.clone(), first.clone(), source);
        handles.push(std::thread::spawn(move || {
            let t = Timing::new();
            let mut out = Emit::new(&tx0, &stop);
            if let Err(e) = source.run(&mut out) {
                record(&first, &stop, &name, e);
            }
            StageReport { name, kind: "source".into(), busy_s: t.busy() - out.waited.as_secs_f64(), items_in: 0, details: None }
        }));
    }
    for (name, kind, mut tr) in transforms {
        let (tx, next_rx) = bounded::<Item>(cap);
        let my_rx = std::mem::replace(&mut rx, next_rx);
        let (stop, first) = (stop.clone(), first.clone());
        handles.push(std::thread::spawn(move || {
            let mut t = Timing::new();
            let mut out = Emit::new(&tx, &stop);
            let mut failed: Vec<usize> = Vec::new();
            while let Some(item) = recv(&my_rx, &stop, &mut t) {
                if input_of(&item).is_some_and(|i| failed.contains(&i)) {
                    continue;
                }
                match tr.process(item, &mut out) {
                    Ok(()) => {}
                    Err(StageError::Input(input, msg)) => {
                        failed.push(input.index);
                        out.send(Item::End(input, Err(msg)));
                    }
                    Err(StageError::Fatal(e)) => {
                        record(&first, &stop, &name, e);
                        break;
                    }
                }
                if out.closed {
                    break;
                }
            }
            if !stop.load(Ordering::Relaxed) {
                if let Err(StageError::Fatal(e)) = tr.finish(&mut out) {
                    record(&first, &stop, &name, e);
                }
            }
            StageReport { name, kind, busy_s: t.busy() - out.waited.as_secs_f64(), items_in: t.items, details: tr.details() }
        }));
    }
    (rx, handles)
}

/// A plan's samples in this process, as its stages make them, without its sink: what the
/// Python dataset iterates. Inputs are this task's share (`i % count == index` of the sorted
/// list, as `generate --shard-index` takes them), read in order, so with one task the samples
/// come in the order `pipeline generate` writes them. Dropping the stream stops every stage.
pub struct SampleStream {
    rx: Option<Receiver<Item>>,
    stop: Arc<AtomicBool>,
    first: FirstError,
    handles: Vec<std::thread::JoinHandle<StageReport>>,
}

/// What [`SampleStream::next`] found.
pub enum Next {
    Sample(Box<crate::frame::Sample>),
    /// An input failed (path, reason); its samples already given are not taken back.
    Failed(String, String),
    /// Nothing within the timeout; ask again.
    Waiting,
    /// Every input is done.
    End,
}

impl SampleStream {
    /// Starts the plan's source and transforms on this task's inputs.
    ///
    /// # Errors
    /// No input, a bad task split, or a stage that fails to build (named).
    pub fn open(plan: &Plan, task: (usize, usize)) -> Result<SampleStream> {
        if task.1 == 0 || task.0 >= task.1 {
            return Err(Error::Usage(format!("task index {} must be below the task count {}", task.0, task.1)));
        }
        let all = list_inputs(plan)?;
        if all.is_empty() {
            return Err(Error::Usage("no input: the paths name no file the source reads".into()));
        }
        let selected: Vec<_> = all.into_iter().filter(|(i, _)| i.index % task.1 == task.0).collect();
        let stop = Arc::new(AtomicBool::new(false));
        let first: FirstError = Arc::new(Mutex::new(None));
        if selected.is_empty() {
            // Nothing for this task (more tasks than inputs): an empty stream, nothing built.
            return Ok(SampleStream { rx: None, stop, first, handles: Vec::new() });
        }
        let counters = Arc::new(Counters::default());
        let settings = content_hash(&plan.resolved);
        let stages = build(plan, &selected, &counters, &plan.out_dir(), task, &settings, false)?;
        let (rx, handles) = start(stages.source, stages.transforms, plan.run.channel_capacity, &stop, &first);
        Ok(SampleStream { rx: Some(rx), stop, first, handles })
    }

    /// The next sample or failed input, waiting at most `timeout`.
    ///
    /// # Errors
    /// The first fatal error of any stage (named).
    pub fn next(&mut self, timeout: Duration) -> Result<Next> {
        let Some(rx) = &self.rx else { return Ok(Next::End) };
        loop {
            match rx.recv_timeout(timeout) {
                Ok(Item::Sample(s)) => return Ok(Next::Sample(s)),
                Ok(Item::End(input, Err(e))) => return Ok(Next::Failed(input.path.clone(), e)),
                Ok(_) => continue,
                Err(RecvTimeoutError::Timeout) => return Ok(Next::Waiting),
                Err(RecvTimeoutError::Disconnected) => {
                    self.rx = None;
                    for h in self.handles.drain(..) {
                        let _ = h.join();
                    }
                    return match self.first.lock().expect("error slot").take() {
                        Some(e) => Err(e),
                        None => Ok(Next::End),
                    };
                }
            }
        }
    }
}

impl Drop for SampleStream {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        self.rx = None;
        for h in self.handles.drain(..) {
            let _ = h.join();
        }
    }
}

/// Writes `reports/{stem}[-{task}-of-{n}]-{time}-{pid}.json` (kept) and `{stem}[-{task}-of-{n}].json`
/// (the latest run of this task).
fn write_report(dir: &Path, opts: &RunOptions, stem: &str, r: &Report) -> Result<()> {
    let stem = if opts.task_count > 1 { format!("{stem}-{:05}-of-{:05}", opts.task_index, opts.task_count) } else { stem.to_string() };
    let mut r = r.clone();
    r.peak_rss_mb = crate::provenance::peak_rss_kb().map(|k| k as f64 / 1024.0);
    let bytes = serde_json::to_vec_pretty(&r).expect("json");
    let runs = crate::io::make_dir_in(dir, Path::new("reports"))?;
    crate::io::write_atomic(&runs.join(r.provenance.file_name(&stem)), |w| w.write_all(&bytes))?;
    crate::io::write_atomic(&dir.join(format!("{stem}.json")), |w| w.write_all(&bytes))
}

/// The run's progress line or bar: inputs finished, with frames, windows and samples so far.
struct Progress {
    bar: crate::progress::Bar,
    counters: Arc<Counters>,
    start: Instant,
}

impl Progress {
    fn new(mode: ProgressMode, counters: Arc<Counters>, inputs: usize) -> Progress {
        Progress { bar: crate::progress::Bar::new(mode, "generate", "inputs", Some(inputs as u64)), counters, start: Instant::now() }
    }

    fn tick(&self) {
        let c = &self.counters;
        let secs = self.start.elapsed().as_secs_f64().max(1e-9);
        let f = Counters::get(&c.frames);
        let status = c.status.lock().map(|s| if s.is_empty() { String::new() } else { format!("; {s}") }).unwrap_or_default();
        self.bar.set_message(format!(
            "{f} frames ({:.1}/s), {} windows, {} samples, {} failed{status}",
            f as f64 / secs,
            Counters::get(&c.windows),
            Counters::get(&c.samples),
            Counters::get(&c.inputs_failed)
        ));
        self.bar.set_position(Counters::get(&c.inputs_done) + Counters::get(&c.inputs_failed));
    }

    fn finish(&self) {
        self.tick();
        self.bar.finish();
    }
}
