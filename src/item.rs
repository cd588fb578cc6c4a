//! What flows between stages: one message type on every channel.

use crate::frame::{Frame, Input, InputError, InputInfo};
use crate::sample::Sample;
use std::sync::Arc;

/// A message on a channel between stages.
#[derive(Debug, Clone)]
pub enum Item {
    Begin(Arc<Input>, InputInfo),
    Frame(Arc<Input>, u64, Arc<Frame>),
    Sample(Box<Sample>),
    /// The input is done: Ok, or the reason it failed (its outputs are discarded).
    End(Arc<Input>, Result<(), Arc<InputError>>),
}
