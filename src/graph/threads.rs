//! The stages on their threads: built before any starts, joined by bounded channels, timed;
//! the first fatal error (or a panic, named by its stage) stops them all.

use super::StageReport;
use crate::config::Plan;
use crate::frame::Input;
use crate::item::Item;
use crate::stage::{BuildContext, Built, Counters, Emit, Sink, Source, StageError, Transform};
use crate::{Error, Result};
use crossbeam_channel::{bounded, Receiver, RecvTimeoutError};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Runs a stage loop, timing the work and the waiting.
pub(super) struct Timing {
    start: Instant,
    waiting: Duration,
    items: u64,
}

impl Timing {
    pub(super) fn new() -> Timing {
        Timing { start: Instant::now(), waiting: Duration::ZERO, items: 0 }
    }
    pub(super) fn busy(&self) -> f64 {
        (self.start.elapsed().saturating_sub(self.waiting)).as_secs_f64()
    }
}

pub(super) fn recv(rx: &Receiver<Item>, stop: &AtomicBool, t: &mut Timing) -> Option<Item> {
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

pub(super) type FirstError = Arc<Mutex<Option<Error>>>;

pub(super) fn record(first: &FirstError, stop: &AtomicBool, stage: &str, e: Error) {
    let mut g = first.lock().expect("error slot");
    if g.is_none() {
        *g = Some(Error::Stage { stage: stage.to_string(), source: Box::new(e) });
    }
    stop.store(true, Ordering::Relaxed);
}

/// A plan's stages, built for this task's inputs.
pub(super) struct Stages {
    pub(super) source: (String, Box<dyn Source>),
    /// (name, type, runtime)
    pub(super) transforms: Vec<(String, String, Box<dyn Transform>)>,
    pub(super) sink: Option<(String, Box<dyn Sink>)>,
}

/// Builds every stage (the sink only `with_sink`) before any thread starts; each gets its own
/// config and the context.
pub(super) fn build(
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
/// set or its receiver is dropped; the first fatal error, or a panic, goes to `first`.
pub(super) fn start(
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
            match catch_unwind(AssertUnwindSafe(|| source.run(&mut out))) {
                Ok(Ok(())) => {}
                Ok(Err(e)) => record(&first, &stop, &name, e),
                Err(p) => record(&first, &stop, &name, panicked(p)),
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
            let body = catch_unwind(AssertUnwindSafe(|| transform_loop(&name, tr.as_mut(), &my_rx, &mut out, &stop, &first, &mut t)));
            if let Err(p) = body {
                record(&first, &stop, &name, panicked(p));
            }
            StageReport { name, kind, busy_s: t.busy() - out.waited.as_secs_f64(), items_in: t.items, details: tr.details() }
        }));
    }
    (rx, handles)
}

/// A transform's items until its input ends or the run stops; an input that failed in it is
/// dropped from then on.
fn transform_loop(
    name: &str,
    tr: &mut dyn Transform,
    rx: &Receiver<Item>,
    out: &mut Emit,
    stop: &AtomicBool,
    first: &FirstError,
    t: &mut Timing,
) {
    let fault = failpoint(name);
    let mut failed: Vec<usize> = Vec::new();
    while let Some(item) = recv(rx, stop, t) {
        if fault == Some(t.items) {
            panic!("PIPELINE_FAILPOINT: {name} at item {}", t.items);
        }
        if input_of(&item).is_some_and(|i| failed.contains(&i)) {
            continue;
        }
        match tr.process(item, out) {
            Ok(()) => {}
            Err(StageError::Input(input, e)) => {
                failed.push(input.index);
                out.send(Item::End(input, e.end()));
            }
            Err(StageError::Fatal(e)) => {
                record(first, stop, name, e);
                break;
            }
        }
        if out.closed {
            break;
        }
    }
    if !stop.load(Ordering::Relaxed) {
        if let Err(StageError::Fatal(e)) = tr.finish(out) {
            record(first, stop, name, e);
        }
    }
}

/// The sink's loop: items until the input ends, the sink has enough (a trainer at its last
/// step) or the run stops; then `finish`, or `abort` (unfinished outputs removed) after an
/// error, a panic or a signal. Returns its report, its summary and the inputs it saw fail. The
/// receiver is dropped on return, which unblocks every stage still sending.
pub(super) fn run_sink(
    (name, mut sink): (String, Box<dyn Sink>),
    rx: Receiver<Item>,
    stop: &AtomicBool,
    first: &FirstError,
) -> (StageReport, Option<serde_json::Value>, Vec<(String, String)>) {
    let mut t = Timing::new();
    let fault = failpoint(&name);
    let body = catch_unwind(AssertUnwindSafe(|| {
        let mut satisfied = false;
        while let Some(item) = recv(&rx, stop, &mut t) {
            if fault == Some(t.items) {
                panic!("PIPELINE_FAILPOINT: {name} at item {}", t.items);
            }
            if let Err(e) = sink.consume(item) {
                record(first, stop, &name, e);
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
            return None;
        }
        match sink.finish() {
            Ok(v) => Some(v),
            Err(e) => {
                record(first, stop, &name, e);
                sink.abort();
                None
            }
        }
    }));
    let summary = body.unwrap_or_else(|p| {
        record(first, stop, &name, panicked(p));
        // What the sink had not finished goes; a second panic there is only reported.
        if catch_unwind(AssertUnwindSafe(|| sink.abort())).is_err() {
            eprintln!("{name}: could not remove its unfinished outputs after the panic");
        }
        None
    });
    let failures = sink.failures();
    (StageReport { name, kind: "sink".into(), busy_s: t.busy(), items_in: t.items, details: None }, summary, failures)
}

/// A panic's message as an error.
fn panicked(p: Box<dyn std::any::Any + Send>) -> Error {
    let msg = p.downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| p.downcast_ref::<String>().cloned());
    Error::Panicked(msg.unwrap_or_else(|| "a panic without a message".into()))
}

/// The one fault hook, for the tests of the panic path: `PIPELINE_FAILPOINT=STAGE:N` makes the
/// stage named STAGE panic at its N-th item (1-based). Unset, nothing happens.
fn failpoint(stage: &str) -> Option<u64> {
    let v = std::env::var("PIPELINE_FAILPOINT").ok()?;
    let (s, n) = v.rsplit_once(':')?;
    (s == stage).then(|| n.parse().ok()).flatten()
}
