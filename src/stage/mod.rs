//! Stages: sources make frames, transforms turn items into items, sinks write them.
//!
//! A stage returns [`StageError::Input`] for a problem with one input (a video shorter than a
//! window, frames smaller than a patch): the runner then marks that input failed, tells the
//! stages downstream, and drops the rest of its items, so the sink discards its partial output
//! while the other inputs go on. Any other error stops the whole run.

pub mod blur;
pub mod noise;
pub mod patches;
pub mod shards;
pub mod source;

use crate::frame::{Frame, Input, Item};
use crate::optics::transfer::Curve;
use crossbeam_channel::Sender;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

#[derive(Debug)]
pub enum StageError {
    /// One input cannot be processed; the message names what is wrong with it.
    Input(Arc<Input>, String),
    Fatal(crate::Error),
}

impl From<crate::Error> for StageError {
    fn from(e: crate::Error) -> Self {
        StageError::Fatal(e)
    }
}

pub type StageResult<T = ()> = Result<T, StageError>;

/// Counters the progress display and the report read.
#[derive(Debug, Default)]
pub struct Counters {
    pub frames: AtomicU64,
    pub windows: AtomicU64,
    pub samples: AtomicU64,
    /// Samples of inputs that finished (what the sink kept); `samples` also counts those of an
    /// input still running or failed later.
    pub samples_kept: AtomicU64,
    pub inputs_done: AtomicU64,
    pub inputs_failed: AtomicU64,
    pub inputs_total: AtomicU64,
    /// What each source measured of its inputs (path, size, frame rate, frame counts).
    pub inputs: std::sync::Mutex<Vec<InputReport>>,
}

/// One input as the report shows it.
#[derive(Debug, Clone, serde::Serialize)]
pub struct InputReport {
    pub path: String,
    #[serde(flatten)]
    pub info: crate::frame::InputInfo,
    pub frames_read: u64,
}

impl Counters {
    pub fn add(c: &AtomicU64, n: u64) {
        c.fetch_add(n, Ordering::Relaxed);
    }
    pub fn get(c: &AtomicU64) -> u64 {
        c.load(Ordering::Relaxed)
    }
    /// Records an input's facts once it has been read.
    pub fn input(&self, path: &str, info: &crate::frame::InputInfo, frames_read: u64) {
        self.inputs.lock().expect("inputs").push(InputReport { path: path.to_string(), info: info.clone(), frames_read });
    }
}

/// Sends items downstream; remembers when downstream has gone.
pub struct Emit<'a> {
    tx: &'a Sender<Item>,
    pub closed: bool,
    pub stop: &'a AtomicBool,
    /// Time spent blocked because downstream was full.
    pub waited: std::time::Duration,
}

impl<'a> Emit<'a> {
    pub fn new(tx: &'a Sender<Item>, stop: &'a AtomicBool) -> Emit<'a> {
        Emit { tx, closed: false, stop, waited: std::time::Duration::ZERO }
    }
    /// False when downstream has stopped (then the caller should return quietly).
    pub fn send(&mut self, item: Item) -> bool {
        if self.closed || self.stop.load(Ordering::Relaxed) {
            self.closed = true;
            return false;
        }
        let t = std::time::Instant::now();
        if self.tx.send(item).is_err() {
            self.closed = true;
        }
        self.waited += t.elapsed();
        !self.closed
    }
}

/// A transform: one item in, zero or more out.
pub trait Transform: Send {
    fn process(&mut self, item: Item, out: &mut Emit) -> StageResult;
    /// Runs once after upstream closes.
    fn finish(&mut self, _out: &mut Emit) -> StageResult {
        Ok(())
    }
}

/// A source: produces every item of every input, checking `stop` between frames.
pub trait Source: Send {
    fn run(&mut self, out: &mut Emit) -> crate::Result<()>;
}

/// A sink: consumes items; `finish` returns its summary for the report; `abort` removes
/// anything half-written after an error or Ctrl-C.
pub trait Sink: Send {
    fn consume(&mut self, item: Item) -> crate::Result<()>;
    fn finish(&mut self) -> crate::Result<serde_json::Value>;
    fn abort(&mut self);
    /// Inputs that failed: (path, reason).
    fn failures(&self) -> Vec<(String, String)>;
    /// False once the sink needs nothing more (a trainer that has done its steps): the run
    /// then stops its sources and finishes normally.
    fn wants_more(&self) -> bool {
        true
    }
}

/// `linearize`: marks frames as linear light through `curve`. The pixels are converted lazily,
/// by table, where they are read ([`Frame::linear_row`]): patch mode converts only its patches.
pub struct Linearize {
    curve: Curve,
}

impl Linearize {
    pub fn new(curve: Curve) -> Linearize {
        Linearize { curve }
    }

    /// The same pixels, tagged with the curve.
    pub fn apply(&self, f: &Frame) -> Frame {
        Frame { curve: Some(self.curve), ..f.clone() }
    }
}

impl Transform for Linearize {
    fn process(&mut self, item: Item, out: &mut Emit) -> StageResult {
        let item = match item {
            Item::Frame(input, i, f) => Item::Frame(input, i, Arc::new(self.apply(&f))),
            other => other,
        };
        out.send(item);
        Ok(())
    }
}
