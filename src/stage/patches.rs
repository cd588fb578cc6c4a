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
    /// Runs of pixels (row by row, ascending, merged) of frame `frame` of `input` that the blur
    /// reads; `None` (read everything) when the frame is smaller than a patch, which the blur
    /// reports as the input's error.
    pub fn spans(&self, input: u64, frame: u64, w: usize, h: usize) -> Option<Vec<crate::io::yuv::Span>> {
        let CropGeometry { window, stride, margin: m } = self.geometry;
        let (n, st, s) = (window as u64, stride.max(1) as u64, self.selector.size);
        // Windows k start at k * stride and hold frames k * stride .. k * stride + n.
        let first = (frame + 1).saturating_sub(n).div_ceil(st);
        let mut rects = Vec::new();
        for k in (first..=frame / st).filter(|k| k * st + n > frame) {
            let pos = self.selector.positions(self.seed, input, k, w, h).ok()?;
            rects.extend(pos.into_iter().map(|(x, y)| (x.saturating_sub(m), (x + s + m).min(w), y.saturating_sub(m), (y + s + m).min(h))));
        }
        let mut spans = Vec::new();
        let mut runs: Vec<(usize, usize)> = Vec::new();
        for y in 0..h {
            runs.clear();
            runs.extend(rects.iter().filter(|r| y >= r.2 && y < r.3).map(|r| (r.0, r.1)));
            runs.sort_unstable();
            let mut cur: Option<(usize, usize)> = None;
            for &(a, b) in &runs {
                cur = match cur {
                    Some((c0, c1)) if a <= c1 => Some((c0, c1.max(b))),
                    Some((c0, c1)) => {
                        spans.push(crate::io::yuv::Span { y, x0: c0, x1: c1 });
                        Some((a, b))
                    }
                    None => Some((a, b)),
                };
            }
            if let Some((c0, c1)) = cur {
                spans.push(crate::io::yuv::Span { y, x0: c0, x1: c1 });
            }
        }
        Some(spans)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn read_regions_cover_every_patch_and_margin_of_every_window_of_a_frame() {
        // Overlapping windows (stride < N), gaps (stride > N) and plain ones; each frame's runs
        // must hold every pixel the blur reads for each window the frame is in (the patch plus
        // the margin, clamped: mirrored reads near a border land inside it), and nothing of
        // windows the frame is not in.
        let sel = Selector { size: 16, per_window: 3, placement: Placement::Random };
        let (w, h) = (97usize, 71usize);
        for (window, stride, margin) in [(9usize, 9usize, 5usize), (7, 3, 11), (5, 8, 2)] {
            let rr = ReadRegions { selector: sel.clone(), seed: 4, geometry: CropGeometry { window, stride, margin } };
            for frame in 0..40u64 {
                let spans = rr.spans(42, frame, w, h).unwrap();
                let covered = |x: usize, y: usize| spans.iter().any(|s| s.y == y && x >= s.x0 && x < s.x1);
                let mut want = vec![false; w * h];
                for k in 0..40u64 {
                    let start = k * stride as u64;
                    if frame < start || frame >= start + window as u64 {
                        continue;
                    }
                    for (px, py) in sel.positions(4, 42, k, w, h).unwrap() {
                        for y in py.saturating_sub(margin)..(py + 16 + margin).min(h) {
                            for x in px.saturating_sub(margin)..(px + 16 + margin).min(w) {
                                want[y * w + x] = true;
                            }
                        }
                    }
                }
                for y in 0..h {
                    for x in 0..w {
                        assert_eq!(covered(x, y), want[y * w + x], "N {window} stride {stride} frame {frame} at ({x}, {y})");
                    }
                }
                // Runs of a row are ascending and apart (merged).
                for p in spans.windows(2) {
                    assert!(p[0].y < p[1].y || (p[0].y == p[1].y && p[0].x1 < p[1].x0), "{p:?}");
                }
            }
        }
    }
}
