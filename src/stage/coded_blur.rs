//! `coded_blur`: groups linear frames into windows of N (with a stride) and images each window
//! through a camera ([`crate::imaging::blur::Blurrer`]); the sharp target is the middle frame
//! (frame N / 2). In patch mode (a `patches` stage downstream with `crop_first`, passed in the
//! build context), only each patch plus the kernel margin is cut and blurred: the same pixels as
//! blurring the whole frame.

use super::patches::Selector;
use super::{BuildContext, Built, Counters, Emit, Needs, StageConfig, StageError, StageResult, Transform};
use crate::checks::Checker;
use crate::checks::ConfigError;
use crate::frame::{Frame, Input, InputError};
use crate::imaging::blur::Blurrer;
use crate::item::Item;
use crate::optics::transfer::Curve;
use crate::optics::{Camera, CameraConfig, OpticsConfig};
use crate::sample::{Img, Pair, Sample};
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;
use std::sync::Arc;

/// `type = "coded_blur"`: windows of N frames through a camera.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BlurConfig {
    pub inputs: Vec<String>,
    /// Sub-frames per window (1 to 64).
    #[serde(default = "default_window")]
    pub window: usize,
    /// Frames between window starts (default: the window, no overlap).
    #[serde(default)]
    pub stride: Option<usize>,
    #[serde(default)]
    pub camera: CameraConfig,
    #[serde(default)]
    pub optics: OpticsConfig,
    /// Worker threads for the FFTs (0: all cores).
    #[serde(default)]
    pub threads: usize,
    /// Error budget of the low-rank blur, in 8-bit levels of linear light, RMS: the window's N
    /// kernels are factorised into the fewest directions (one FFT each per channel, instead of
    /// N) whose added error is provably at most this for any sub-frames in [0, 1] (see
    /// `optics::lowrank`; each kernel's total is kept exactly, so flat regions carry no such
    /// error). 0: exact, every direction kept. The coded camera keeps 4 of 9 at the default 0.25
    /// and 3 to 4 at 0.6 to 2. The ranks and the bound are in the run's report
    /// (`stages[].details`).
    #[serde(default = "default_max_error")]
    pub max_error: f64,
    /// Whole frames are blurred in tiles, each transformed with the kernel margin around it
    /// (overlap-save: cache-sized FFTs spread over the cores, memory bounded by the tile).
    /// 0 (default): planned per frame size, the least transformed area with transforms of at
    /// most 512 px a side (720p: six tiles of 427x360 in transforms of 512x432, 1.7 to 2.9
    /// times less time per pixel than one 720p plane); N: square tiles of N px; a size at least
    /// the frame's: one plane with all cores on it. Every choice equals the direct convolution
    /// within float rounding. Patch mode ignores it.
    #[serde(default)]
    pub tile: usize,
    /// Burst targets: the sharp image at each of K times of the exposure, `t_k = (k + 0.5) / K`,
    /// instead of the middle sub-frame alone. `true`: K = the window (the sub-frames
    /// themselves); a number K from 2 to 64: that many times, each mixed in linear light from
    /// the two sub-frames around it; `false` (default): one target.
    #[serde(default)]
    pub burst: Burst,
}

/// [`BlurConfig::burst`]: `true`, `false` or a count.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Burst {
    On(bool),
    Times(usize),
}

impl Default for Burst {
    fn default() -> Self {
        Burst::On(false)
    }
}

impl Burst {
    /// How many targets a window of `n` sub-frames gets (0: none, the middle frame alone).
    pub fn count(self, n: usize) -> usize {
        match self {
            Burst::On(false) => 0,
            Burst::On(true) => n,
            Burst::Times(k) => k,
        }
    }
}

/// The times of `k` burst targets, `(i + 0.5) / k`.
pub fn burst_times(k: usize) -> Vec<f64> {
    (0..k).map(|i| (i as f64 + 0.5) / k as f64).collect()
}

/// Where time `t` (a fraction of the exposure) falls among `n` sub-frames, whose centres are at
/// `(j + 0.5) / n`: the two sub-frames around it and the weight of the second (clamped at the
/// ends of the exposure).
pub fn subframe_mix(t: f64, n: usize) -> (usize, usize, f64) {
    let p = (t * n as f64 - 0.5).clamp(0.0, (n - 1) as f64);
    let j = (p.floor() as usize).min(n - 1);
    let f = p - j as f64;
    if f < 1e-9 {
        (j, j, 0.0)
    } else {
        (j, (j + 1).min(n - 1), f)
    }
}

impl BlurConfig {
    /// The camera of these settings, one per process for each distinct optics and camera
    /// config, so that the plan (asking for the kernel margin) and the stage share its kernels.
    fn camera_shared(&self) -> Arc<Camera> {
        static CAMERAS: std::sync::Mutex<Vec<(String, Arc<Camera>)>> = std::sync::Mutex::new(Vec::new());
        let key = serde_json::to_string(&(&self.optics, &self.camera)).unwrap_or_default();
        let mut cams = CAMERAS.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((_, c)) = cams.iter().find(|(k, _)| *k == key) {
            return c.clone();
        }
        let c = Arc::new(Camera::new(&self.optics, &self.camera));
        cams.push((key, c.clone()));
        c
    }
}

/// The default low-rank error budget: a quarter of an 8-bit level RMS, far below the noise the
/// data gets (sigma 0 to 9 levels).
pub const DEFAULT_MAX_ERROR: f64 = 0.25;

fn default_max_error() -> f64 {
    DEFAULT_MAX_ERROR
}

fn default_window() -> usize {
    9
}

impl StageConfig for BlurConfig {
    super::wiring!(transform, TaggedFrames -> Samples);
    fn validate(&self, key: &str) -> Vec<ConfigError> {
        let mut c = Checker::new(key);
        c.range_usize("window", self.window, 1, 64);
        if let Some(s) = self.stride {
            c.range_usize("stride", s, 1, 4096);
        }
        c.range_usize("threads", self.threads, 0, 256);
        c.range("max_error", self.max_error, 0.0, 255.0);
        if self.tile != 0 {
            c.range_usize("tile", self.tile, 16, 1 << 20);
        }
        c.errors.extend(self.camera.validate(&format!("{key}.camera")));
        c.errors.extend(crate::optics::measured::check(&self.camera, &format!("{key}.camera")));
        c.errors.extend(self.optics.validate(&format!("{key}.optics")));
        if let Burst::Times(k) = self.burst {
            c.range_usize("burst", k, 2, 64);
        }
        if let Some(v) = &self.camera.psi_values {
            if v.len() != self.window {
                c.fail("camera.psi_values", format!("has {} values but window is {}", v.len(), self.window));
            }
        }
        c.errors
    }
    fn needs(&self) -> Needs {
        Needs { frames: self.window as u64, ..Needs::default() }
    }
    fn takes_crop(&self) -> bool {
        true
    }
    fn subframes_per_window(&self) -> usize {
        self.window
    }
    fn crop_geometry(&self) -> crate::Result<Option<super::patches::CropGeometry>> {
        let kernels = self.camera_shared().window(self.window)?;
        let margin = crate::imaging::blur::margin_of(&kernels);
        Ok(Some(super::patches::CropGeometry { window: self.window, stride: self.stride.unwrap_or(self.window), margin }))
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        let cam = self.camera_shared();
        let blurrer = Blurrer::new(cam, self.window, self.threads, self.max_error)?;
        let stride = self.stride.unwrap_or(self.window);
        let mut t = CameraBlur::new(blurrer, stride, ctx.seed, ctx.crop.clone(), ctx.counters.clone());
        t.tile = self.tile;
        t.times = burst_times(self.burst.count(self.window));
        Ok(Built::Transform(Box::new(t)))
    }
}

/// The `coded_blur` stage: windows of frames through a camera (any of them: the TOML name is
/// the paper's, the stage runs the conventional, flutter, parabolic and measured cameras too).
pub struct CameraBlur {
    pub blurrer: Blurrer,
    pub stride: usize,
    pub seed: u64,
    /// Patch selector when patches are cut before blurring.
    pub crop_first: Option<Selector>,
    pub counters: Arc<Counters>,
    /// Tile size of whole-frame blurs (0: [`crate::imaging::blur::plan_tiles`]), as [`BlurConfig::tile`].
    pub tile: usize,
    /// Times of the burst targets ([`BlurConfig::burst`]); empty: the middle frame alone.
    pub times: Vec<f64>,
    buf: VecDeque<(u64, Arc<Frame>)>,
    next_start: u64,
    /// Windows emitted so far for the current input (the next window's index).
    windows_done: u64,
    input: Option<Arc<Input>>,
}

impl CameraBlur {
    pub fn new(blurrer: Blurrer, stride: usize, seed: u64, crop_first: Option<Selector>, counters: Arc<Counters>) -> CameraBlur {
        CameraBlur {
            blurrer,
            stride,
            seed,
            crop_first,
            counters,
            tile: 0,
            times: Vec::new(),
            buf: VecDeque::new(),
            next_start: 0,
            windows_done: 0,
            input: None,
        }
    }

    fn emit_window(&mut self, input: &Arc<Input>, out: &mut Emit) -> StageResult {
        let n = self.blurrer.n;
        let frames: Vec<Arc<Frame>> = self.buf.iter().take(n).map(|(_, f)| f.clone()).collect();
        let first = self.buf[0].0;
        let (w, h) = (frames[0].width, frames[0].height);
        let mid = &frames[n / 2];
        let pairs = match &self.crop_first {
            Some(sel) => {
                let pos = sel
                    .positions(self.seed, input.id, self.windows_done, w, h)
                    .map_err(|e| StageError::Input(input.clone(), e.named(&input.path)))?;
                let lqs = self.blurrer.blur_patches(&frames, &pos, sel.size);
                pos.into_iter()
                    .zip(lqs)
                    .enumerate()
                    .map(|(i, ((x, y), lq))| {
                        let gt = sharp(mid, x, y, sel.size, sel.size);
                        let burst = burst(&frames, &self.times, x, y, sel.size, sel.size);
                        Pair { patch: Some(i as u32), x, y, w: sel.size, h: sel.size, lq: Img::Linear(lq), gt, burst }
                    })
                    .collect()
            }
            None => {
                let lq = self.blurrer.blur_tiled(&frames, self.tile);
                let burst = burst(&frames, &self.times, 0, 0, w, h);
                vec![Pair { patch: None, x: 0, y: 0, w, h, lq: Img::Linear(lq), gt: sharp(mid, 0, 0, w, h), burst }]
            }
        };
        let kernels = self.blurrer.kernels();
        let sample = Sample {
            input: input.clone(),
            window: self.windows_done,
            first_frame: first,
            frames: n,
            camera: self.blurrer.camera.kind(),
            psi: kernels.iter().map(|k| k.psi).collect(),
            // The curve the frames were linearised with (by `linearize`), to re-encode with.
            curve: mid.curve.unwrap_or(Curve::Identity),
            sigma: None,
            light_throughput: self.blurrer.camera.light_throughput(),
            frame_width: w,
            frame_height: h,
            cropped: self.crop_first.is_some(),
            motion: mid.motion.clone(),
            capture: mid
                .highlights
                .map(|h| serde_json::json!({ "highlights": { "gain": h.gain, "threshold_linear": h.threshold } }).to_string().into()),
            times: self.times.clone(),
            pairs,
        };
        Counters::add(&self.counters.windows, 1);
        self.windows_done += 1;
        out.send(Item::Sample(Box::new(sample)));
        Ok(())
    }
}

/// The sharp image of a region: an 8-bit frame's own bytes (what re-encoding its linear light
/// would give, exactly, at a fraction of the cost), else its linear light.
fn sharp(frame: &Frame, x: usize, y: usize, w: usize, h: usize) -> Img {
    match frame.encoded8_crop(x, y, w, h) {
        Some(v) => Img::Encoded8(v),
        None => Img::Linear(frame.linear_crop(x, y, w, h)),
    }
}

/// The sharp images of a region at each time of `times`: a sub-frame's own pixels where a time
/// falls on its centre, else the mix of the two around it in linear light.
fn burst(frames: &[Arc<Frame>], times: &[f64], x: usize, y: usize, w: usize, h: usize) -> Vec<Img> {
    times
        .iter()
        .map(|&t| match subframe_mix(t, frames.len()) {
            (j, _, 0.0) => sharp(&frames[j], x, y, w, h),
            (a, b, f) => {
                let (pa, pb) = (frames[a].linear_crop(x, y, w, h), frames[b].linear_crop(x, y, w, h));
                let f = f as f32;
                Img::Linear(std::array::from_fn(|c| pa[c].iter().zip(&pb[c]).map(|(u, v)| u + f * (v - u)).collect()))
            }
        })
        .collect()
}

impl Transform for CameraBlur {
    fn details(&self) -> Option<serde_json::Value> {
        let b = &self.blurrer;
        Some(serde_json::json!({
            "window": b.n,
            "kernel_margin_px": b.margin,
            "lowrank_ranks": b.ranks(),
            "lowrank_error_bound_levels": b.error_bounds(),
        }))
    }
    fn process(&mut self, item: Item, out: &mut Emit) -> StageResult {
        match item {
            Item::Begin(input, info) => {
                self.buf.clear();
                self.next_start = 0;
                self.windows_done = 0;
                self.input = Some(input.clone());
                out.send(Item::Begin(input, info));
            }
            Item::Frame(input, idx, f) => {
                if idx >= self.next_start {
                    self.buf.push_back((idx, f));
                }
                while self.buf.len() >= self.blurrer.n {
                    self.emit_window(&input, out)?;
                    self.next_start += self.stride as u64;
                    while self.buf.front().is_some_and(|(i, _)| *i < self.next_start) {
                        self.buf.pop_front();
                    }
                }
            }
            Item::End(input, res) => {
                self.buf.clear();
                let res = match res {
                    Ok(()) if self.windows_done == 0 => InputError::NoWindow { path: input.path.clone(), window: self.blurrer.n }.end(),
                    other => other,
                };
                out.send(Item::End(input, res));
            }
            other => {
                out.send(other);
            }
        }
        Ok(())
    }
}
