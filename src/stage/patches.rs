//! `patches`: cuts K patches per window, at seeded random positions or on a grid. The positions
//! are a pure function of (seed, input, window, frame size), so cutting before the blur (crop
//! first) and after it pick the same pixels.

use super::{Emit, StageError, StageResult, Transform};
use crate::config::{PatchesConfig, Placement};
use crate::frame::{Img, Item, Pair};
use crate::rng::{hash, hash_str, Rng};

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
        Img::Linear(p) => Img::Linear(super::blur::crop(p, fw, x, y, s, s)),
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
