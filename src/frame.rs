//! What flows between stages.

use crate::optics::transfer::Curve;
use crate::optics::CameraKind;
use std::sync::Arc;

/// One frame. Encoded frames come from sources; `linearize` turns them into linear light.
#[derive(Debug, Clone)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    pub data: FrameData,
}

#[derive(Debug, Clone)]
pub enum FrameData {
    /// Encoded values, 16-bit, interleaved RGB (what the decoder's scaler writes).
    Rgb48(Vec<u16>),
    /// Planar RGB f32: encoded values in [0, 1] from a source, or linear light after `linearize`.
    Planar([Vec<f32>; 3]),
}

/// One input (video or still) as the stages know it.
#[derive(Debug)]
pub struct Input {
    /// Position in the sorted list of all inputs (before sharding across tasks).
    pub index: usize,
    pub path: String,
    /// File stem made safe for WebDataset keys (no dots).
    pub key: String,
}

/// Facts about an input, measured by the source.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct InputInfo {
    pub width: usize,
    pub height: usize,
    pub fps: f64,
    /// Frame count announced by the container, if any.
    pub frames_announced: Option<u64>,
    pub codec: String,
    pub pixel_format: String,
}

/// An 8-bit or linear image of one sample: planar f32 linear, or interleaved 8-bit encoded.
#[derive(Debug, Clone)]
pub enum Img {
    Linear([Vec<f32>; 3]),
    Encoded8(Vec<u8>),
}

/// An (lq, gt) pair cut from a window at (x, y), `w x h` pixels.
#[derive(Debug, Clone)]
pub struct Pair {
    /// Patch number within the window (None for a full frame).
    pub patch: Option<u32>,
    pub x: usize,
    pub y: usize,
    pub w: usize,
    pub h: usize,
    pub lq: Img,
    pub gt: Img,
}

/// The coded-blur result of one window, with everything needed to reproduce it.
#[derive(Debug, Clone)]
pub struct Sample {
    pub input: Arc<Input>,
    pub window: u64,
    pub first_frame: u64,
    pub frames: usize,
    pub camera: CameraKind,
    pub psi: Vec<f64>,
    pub curve: Curve,
    /// Noise sigma on the 0-255 scale as applied (after the camera's light loss), None before noise.
    pub sigma: Option<f64>,
    /// Share of a conventional camera's light this camera collects (0.5 for the flutter code);
    /// the noise stage divides sigma by it, as brightening the image to the same level would.
    pub light_throughput: f64,
    pub frame_width: usize,
    pub frame_height: usize,
    /// True when the pairs were cut before blurring (patch mode).
    pub cropped: bool,
    pub pairs: Vec<Pair>,
}

/// A message on a channel between stages.
#[derive(Debug, Clone)]
pub enum Item {
    Begin(Arc<Input>, InputInfo),
    Frame(Arc<Input>, u64, Arc<Frame>),
    Sample(Box<Sample>),
    /// The input is done: Ok, or the reason it failed (its outputs are discarded).
    End(Arc<Input>, Result<(), String>),
}
