//! `patches`: cuts K patches per window, at seeded random positions or on a grid. The positions
//! are a pure function of (seed, input, window, frame size), so cutting before the blur (crop
//! first) and after it pick the same pixels.

use super::{BuildContext, Built, Emit, Needs, StageConfig, StageError, StageResult, Transform};
use crate::checks::Checker;
use crate::checks::ConfigError;
use crate::frame::InputError;
use crate::item::Item;
use crate::rng::{hash, hash_str, Rng};
use crate::sample::{Img, Pair};
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

/// A frame smaller than a patch.
#[derive(Debug, Clone, Copy)]
pub struct TooSmall {
    pub width: usize,
    pub height: usize,
    pub patch: usize,
}

impl TooSmall {
    /// The input's failure, naming it.
    pub fn named(self, path: &str) -> InputError {
        InputError::TooSmall { path: path.into(), width: self.width, height: self.height, patch: (self.patch, self.patch) }
    }
}

impl Selector {
    pub fn new(cfg: &PatchesConfig) -> Selector {
        Selector { size: cfg.size, per_window: cfg.per_window, placement: cfg.placement }
    }

    /// Top-left corners of the patches of one window.
    ///
    /// # Errors
    /// The frame is smaller than a patch.
    pub fn positions(&self, seed: u64, input: u64, window: u64, w: usize, h: usize) -> Result<Vec<(usize, usize)>, TooSmall> {
        let s = self.size;
        if w < s || h < s {
            return Err(TooSmall { width: w, height: h, patch: s });
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

/// Windowing of a blur that cuts patches first: window length, stride, kernel margin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CropGeometry {
    pub window: usize,
    pub stride: usize,
    pub margin: usize,
}

/// The parts of each frame a patch-mode blur reads: every patch (plus the kernel margin) of
/// every window the frame belongs to. Patch positions are a pure function of (seed, input,
/// window, frame size), so the source can tell before decoding, and convert only those pixels.
#[derive(Debug, Clone)]
pub struct ReadRegions {
    pub selector: Selector,
    pub seed: u64,
    pub geometry: CropGeometry,
}

impl ReadRegions {
    /// Rectangles (x0, y0, w, h) of frame `frame` of `input` that the blur reads, one per
    /// patch of each window the frame belongs to (the patch plus the margin, clamped to the
    /// frame: mirrored reads near a border land inside it); `None` (read everything) when the
    /// frame is smaller than a patch, which the blur reports as the input's error.
    pub fn rects(&self, input: u64, frame: u64, w: usize, h: usize) -> Option<Vec<(usize, usize, usize, usize)>> {
        let CropGeometry { window, stride, margin: m } = self.geometry;
        let (n, st, s) = (window as u64, stride.max(1) as u64, self.selector.size);
        // Windows k start at k * stride and hold frames k * stride .. k * stride + n.
        let first = (frame + 1).saturating_sub(n).div_ceil(st);
        let mut rects = Vec::new();
        for k in (first..=frame / st).filter(|k| k * st + n > frame) {
            for (x, y) in self.selector.positions(self.seed, input, k, w, h).ok()? {
                let (x0, y0) = (x.saturating_sub(m), y.saturating_sub(m));
                let r = (x0, y0, (x + s + m).min(w) - x0, (y + s + m).min(h) - y0);
                if !rects.contains(&r) {
                    rects.push(r);
                }
            }
        }
        Some(rects)
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
                .map_err(|e| StageError::Input(s.input.clone(), e.named(&s.input.path)))?;
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
                    burst: full.burst.iter().map(|b| crop_img(b, full.w, x, y, sz)).collect(),
                })
                .collect();
            s.cropped = true;
        }
        out.send(Item::Sample(s));
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn read_regions_hold_every_patch_and_margin_of_every_window_of_a_frame() {
        // Overlapping windows (stride < N), gaps (stride > N) and plain ones: each patch of each
        // window a frame is in has a rectangle holding it with its margin (clamped: mirrored
        // reads near a border land inside it), and no rectangle belongs to another window.
        let sel = Selector { size: 16, per_window: 3, placement: Placement::Random };
        let (w, h) = (97usize, 71usize);
        for (window, stride, margin) in [(9usize, 9usize, 5usize), (7, 3, 11), (5, 8, 2)] {
            let rr = ReadRegions { selector: sel.clone(), seed: 4, geometry: CropGeometry { window, stride, margin } };
            for frame in 0..40u64 {
                let rects = rr.rects(42, frame, w, h).unwrap();
                let mut want = Vec::new();
                for k in 0..40u64 {
                    let start = k * stride as u64;
                    if frame < start || frame >= start + window as u64 {
                        continue;
                    }
                    for (px, py) in sel.positions(4, 42, k, w, h).unwrap() {
                        let (x0, y0) = (px.saturating_sub(margin), py.saturating_sub(margin));
                        want.push((x0, y0, (px + 16 + margin).min(w) - x0, (py + 16 + margin).min(h) - y0));
                    }
                }
                want.dedup();
                for r in &want {
                    assert!(rects.contains(r), "N {window} stride {stride} frame {frame}: {r:?} missing from {rects:?}");
                }
                assert!(rects.iter().all(|r| want.contains(r)), "N {window} stride {stride} frame {frame}: extra rectangles");
                assert!(rects.iter().all(|r| r.0 + r.2 <= w && r.1 + r.3 <= h));
            }
        }
    }
}
