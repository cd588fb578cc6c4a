//! `patches`: cuts K patches per window, at seeded random positions or on a grid. The positions
//! are a pure function of (seed, input, window, frame size), so cutting before the blur (crop
//! first) and after it pick the same pixels.

use super::{BuildContext, Built, Emit, Needs, StageConfig, StageError, StageResult, Transform};
use crate::frame::{Img, Item, Pair};
use crate::optics::config::Checker;
use crate::optics::ConfigError;
use crate::rng::{hash, hash_str, Rng};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Placement {
    Random,
    Grid,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PatchesConfig {
    pub inputs: Vec<String>,
    #[serde(default = "default_patch")]
    pub size: usize,
    /// Patches per window (grid: at most this many; 0 with grid: all).
    #[serde(default = "default_per_window")]
    pub per_window: usize,
    #[serde(default = "default_placement")]
    pub placement: Placement,
    /// Cut patches (plus the kernel margin) before blurring: the same pixels for less work.
    #[serde(default = "default_true")]
    pub crop_first: bool,
}

fn default_patch() -> usize {
    128
}
fn default_per_window() -> usize {
    8
}
fn default_placement() -> Placement {
    Placement::Random
}
fn default_true() -> bool {
    true
}

impl StageConfig for PatchesConfig {
    super::wiring!(transform, Samples -> Samples);
    fn validate(&self, key: &str) -> Vec<ConfigError> {
        let mut c = Checker::new(key);
        c.range_usize("size", self.size, 8, 4096);
        if self.placement == Placement::Random {
            c.range_usize("per_window", self.per_window, 1, 4096);
        }
        c.errors
    }
    fn needs(&self) -> Needs {
        Needs { frames: 0, width: self.size, height: self.size }
    }
    fn crop_selector(&self) -> Option<Selector> {
        self.crop_first.then(|| Selector::new(self))
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        Ok(Built::Transform(Box::new(Patches { selector: Selector::new(self), seed: ctx.seed })))
    }
}

#[derive(Debug, Clone)]
pub struct Selector {
    pub size: usize,
    pub per_window: usize,
    pub placement: Placement,
}

impl Selector {
    pub fn new(cfg: &PatchesConfig) -> Selector {
        Selector { size: cfg.size, per_window: cfg.per_window, placement: cfg.placement }
    }

    /// Top-left corners of the patches of one window.
    ///
    /// # Errors
    /// The frame is smaller than a patch.
    pub fn positions(&self, seed: u64, input: u64, window: u64, w: usize, h: usize) -> Result<Vec<(usize, usize)>, String> {
        let s = self.size;
        if w < s || h < s {
            return Err(format!("frames are {w}x{h}, smaller than a {s}x{s} patch"));
        }
        Ok(match self.placement {
            Placement::Random => {
                let mut rng = Rng::new(hash(&[seed, input, window, hash_str("patches")]));
                (0..self.per_window).map(|_| (rng.below(w - s + 1), rng.below(h - s + 1))).collect()
            }
            Placement::Grid => {
                let (nx, ny) = (w / s, h / s);
                let (ox, oy) = ((w - nx * s) / 2, (h - ny * s) / 2);
                let all = (0..ny).flat_map(|j| (0..nx).map(move |i| (ox + i * s, oy + j * s)));
                if self.per_window == 0 {
                    all.collect()
                } else {
                    all.take(self.per_window).collect()
                }
            }
        })
    }
}

fn crop_img(img: &Img, fw: usize, x: usize, y: usize, s: usize) -> Img {
    match img {
        Img::Linear(p) => Img::Linear(crate::imaging::blur::crop(p, fw, x, y, s, s)),
        Img::Encoded8(v) => {
            Img::Encoded8((0..s).flat_map(|yy| v[((y + yy) * fw + x) * 3..((y + yy) * fw + x + s) * 3].iter().copied()).collect())
        }
    }
}

pub struct Patches {
    pub selector: Selector,
    pub seed: u64,
}

impl Transform for Patches {
    fn process(&mut self, item: Item, out: &mut Emit) -> StageResult {
        let Item::Sample(mut s) = item else {
            out.send(item);
            return Ok(());
        };
        if !s.cropped {
            let full = s.pairs.remove(0);
            let pos = self
                .selector
                .positions(self.seed, s.input.id, s.window, full.w, full.h)
                .map_err(|e| StageError::Input(s.input.clone(), format!("{}: {e}", s.input.path)))?;
            let sz = self.selector.size;
            s.pairs = pos
                .into_iter()
                .enumerate()
                .map(|(i, (x, y))| Pair {
                    patch: Some(i as u32),
                    x,
                    y,
                    w: sz,
                    h: sz,
                    lq: crop_img(&full.lq, full.w, x, y, sz),
                    gt: crop_img(&full.gt, full.w, x, y, sz),
                })
                .collect();
            s.cropped = true;
        }
        out.send(Item::Sample(s));
        Ok(())
    }
}
