//! `noise`: the camera's read-out ([`crate::imaging::noise`]): re-encode, add AWGN with sigma
//! fixed or drawn per window (scaled by the camera's light throughput), quantise to 8 bits.

use super::{BuildContext, Built, Emit, StageConfig, StageResult, Transform};
use crate::checks::Checker;
use crate::checks::ConfigError;
use crate::imaging::noise::quantise;
use crate::item::Item;
use crate::optics::transfer::{Curve, Encoder};
use crate::rng::{hash, hash_str, unit};
use crate::sample::Img;
use serde::{Deserialize, Serialize};

/// Noise sigma: fixed, or drawn per window from [low, high].
#[derive(Debug, Clone, Copy, Serialize, Deserialize, PartialEq)]
#[serde(untagged, expecting = "a number or a range [low, high] of two numbers (0 to 255 levels)")]
pub enum Sigma {
    Fixed(f64),
    Range([f64; 2]),
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NoiseConfig {
    pub inputs: Vec<String>,
    /// AWGN sigma on the 0-255 scale, added after re-encoding, before clipping and quantising.
    #[serde(default = "default_sigma")]
    pub sigma: Sigma,
}

fn default_sigma() -> Sigma {
    Sigma::Range([0.0, 9.0])
}

impl StageConfig for NoiseConfig {
    super::wiring!(transform, Samples -> Samples);
    fn validate(&self, key: &str) -> Vec<ConfigError> {
        let mut c = Checker::new(key);
        match self.sigma {
            Sigma::Fixed(s) => c.range("sigma", s, 0.0, 50.0),
            Sigma::Range([a, b]) => {
                c.range("sigma[0]", a, 0.0, 50.0);
                c.range("sigma[1]", b, 0.0, 50.0);
                if a > b {
                    c.fail("sigma", format!("range [{a}, {b}] is reversed"));
                }
            }
        }
        c.errors
    }
    fn per_pixel(&self) -> bool {
        true
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        Ok(Built::Transform(Box::new(Noise::new(self.sigma, ctx.seed))))
    }
}

pub struct Noise {
    pub sigma: Sigma,
    pub seed: u64,
    encoders: Vec<(Curve, Encoder)>,
}

impl Noise {
    pub fn new(sigma: Sigma, seed: u64) -> Noise {
        Noise { sigma, seed, encoders: Vec::new() }
    }

    fn encoder(&mut self, c: Curve) -> &Encoder {
        if let Some(i) = self.encoders.iter().position(|(k, _)| *k == c) {
            return &self.encoders[i].1;
        }
        self.encoders.push((c, Encoder::new(c)));
        &self.encoders.last().expect("pushed").1
    }
}

impl Transform for Noise {
    fn process(&mut self, item: Item, out: &mut Emit) -> StageResult {
        let Item::Sample(mut s) = item else {
            out.send(item);
            return Ok(());
        };
        let base = match self.sigma {
            Sigma::Fixed(v) => v,
            Sigma::Range([a, b]) => a + (b - a) * unit(hash(&[self.seed, s.input.id, s.window, hash_str("sigma")])),
        };
        let sigma = crate::imaging::sensor_sigma(base, s.light_throughput);
        let key = hash(&[self.seed, s.input.id, s.window, hash_str("noise")]);
        let curve = s.curve;
        let enc = self.encoder(curve);
        for p in &mut s.pairs {
            if let Img::Linear(lq) = &p.lq {
                p.lq = Img::Encoded8(quantise(lq, p.w, p.h, p.x, p.y, enc, sigma, key));
            }
            if let Img::Linear(gt) = &p.gt {
                p.gt = Img::Encoded8(quantise(gt, p.w, p.h, p.x, p.y, enc, 0.0, key));
            }
            for b in &mut p.burst {
                if let Img::Linear(v) = b {
                    *b = Img::Encoded8(quantise(v, p.w, p.h, p.x, p.y, enc, 0.0, key));
                }
            }
        }
        s.sigma = Some(sigma);
        out.send(Item::Sample(s));
        Ok(())
    }
}
