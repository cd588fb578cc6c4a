//! `noise`: re-encode with the camera curve, add AWGN (sigma on the 0-255 scale, fixed or drawn
//! per window), clip and quantise to 8 bits, as a camera would. The noise of a pixel is a
//! function of (seed, input, window, absolute x, y, channel), so it does not depend on whether
//! patches were cut before or after.

use super::{Emit, StageResult, Transform};
use crate::config::Sigma;
use crate::frame::{Img, Item};
use crate::optics::transfer::{Curve, Encoder};
use crate::rng::{hash, hash_str, mix, normal, unit};

pub struct Noise {
    pub sigma: Sigma,
    pub seed: u64,
    encoders: Vec<(Curve, Encoder)>,
}

impl Noise {
    pub fn new(sigma: Sigma, seed: u64) -> Noise {
        Noise {
            sigma,
            seed,
            encoders: Vec::new(),
        }
    }

    fn encoder(&mut self, c: Curve) -> &Encoder {
        if let Some(i) = self.encoders.iter().position(|(k, _)| *k == c) {
            return &self.encoders[i].1;
        }
        self.encoders.push((c, Encoder::new(c)));
        &self.encoders.last().expect("pushed").1
    }
}

/// Encodes and quantises planar linear RGB to interleaved 8-bit, adding `sigma` (0-255 scale)
/// of noise keyed on absolute pixel positions (`x0`, `y0` is the image's top-left in the frame).
pub fn quantise(
    p: &[Vec<f32>; 3],
    w: usize,
    h: usize,
    x0: usize,
    y0: usize,
    enc: &Encoder,
    sigma: f64,
    key: u64,
) -> Vec<u8> {
    let mut out = vec![0u8; w * h * 3];
    let s = (sigma / 255.0) as f32;
    for y in 0..h {
        let row_key = mix(key ^ ((y + y0) as u64).wrapping_mul(0x9E37_79B9));
        for x in 0..w {
            let i = y * w + x;
            for c in 0..3 {
                let mut v = enc.encode(p[c][i]);
                if sigma > 0.0 {
                    let k = mix(row_key ^ (((x + x0) as u64) << 2 | c as u64));
                    v += s * normal(k) as f32;
                }
                out[i * 3 + c] = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            }
        }
    }
    out
}

impl Transform for Noise {
    fn process(&mut self, item: Item, out: &mut Emit) -> StageResult {
        let Item::Sample(mut s) = item else {
            out.send(item);
            return Ok(());
        };
        let base = match self.sigma {
            Sigma::Fixed(v) => v,
            Sigma::Range([a, b]) => {
                a + (b - a)
                    * unit(hash(&[
                        self.seed,
                        s.input.index as u64,
                        s.window,
                        hash_str("sigma"),
                    ]))
            }
        };
        let sigma = base / s.light_throughput.max(1e-6);
        let key = hash(&[self.seed, s.input.index as u64, s.window, hash_str("noise")]);
        let curve = s.curve;
        let enc = self.encoder(curve);
        for p in &mut s.pairs {
            if let Img::Linear(lq) = &p.lq {
                p.lq = Img::Encoded8(quantise(lq, p.w, p.h, p.x, p.y, enc, sigma, key));
            }
            if let Img::Linear(gt) = &p.gt {
                p.gt = Img::Encoded8(quantise(gt, p.w, p.h, p.x, p.y, enc, 0.0, key));
            }
        }
        s.sigma = Some(sigma);
        out.send(Item::Sample(s));
        Ok(())
    }
}
