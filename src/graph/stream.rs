//! The stages without a sink, their samples pulled in this process (the Python dataset).

use super::threads::{build, start, FirstError};
use super::{list_inputs, StageReport};
use crate::config::Plan;
use crate::item::Item;
use crate::sample::content_hash;
use crate::stage::Counters;
use crate::{Error, Result};
use crossbeam_channel::{Receiver, RecvTimeoutError};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

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
    Sample(Box<crate::sample::Sample>),
    /// An input failed (its path, and why: an error that names it); its samples already given
    /// are not taken back.
    Failed(String, std::sync::Arc<crate::frame::InputError>),
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
