//! The run's progress: a bar on a terminal, a line every few seconds otherwise.

use crate::progress::ProgressMode;
use crate::stage::Counters;
use std::sync::Arc;
use std::time::Instant;

/// The run's progress line or bar: inputs finished, with frames, windows and samples so far.
pub(super) struct Progress {
    bar: crate::progress::Bar,
    counters: Arc<Counters>,
    start: Instant,
}

impl Progress {
    pub(super) fn new(mode: ProgressMode, counters: Arc<Counters>, inputs: usize) -> Progress {
        Progress { bar: crate::progress::Bar::new(mode, "generate", "inputs", Some(inputs as u64)), counters, start: Instant::now() }
    }

    pub(super) fn tick(&self) {
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

    pub(super) fn finish(&self) {
        self.tick();
        self.bar.finish();
    }
}
