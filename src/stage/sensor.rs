//! `sensor`: a camera's read-out in linear raw instead of the paper's AWGN on 8-bit sRGB
//! ([`crate::imaging::sensor`]): photon shot noise and read noise in electrons at an ISO drawn
//! per window, saturation at the full well, a Bayer colour filter array with bilinear
//! demosaicing; then the camera response (the input's transfer curve) and 8 bits. Every value
//! drawn goes into the sample's `key.json` (`capture`).
//!
//! With `bayer`, demosaicing reads each pixel's neighbours: put the stage after `patches` (as
//! `pipelines/realistic.toml` does) so that a patch is demosaiced as a patch of the sensor.

use super::{BuildContext, Built, Emit, StageConfig, StageResult, Transform};
use crate::checks::{Checker, ConfigError};
use crate::imaging::noise::quantise;
use crate::imaging::sensor::{Bayer, Sensor};
use crate::item::Item;
use crate::optics::transfer::{Curve, Encoder, Response};
use crate::rng::{hash, hash_str, unit};
use crate::sample::Img;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// The ISO the sensor's gain is 1 at.
pub const BASE_ISO: f64 = 100.0;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorConfig {
    pub inputs: Vec<String>,
    /// Electrons a pixel holds before it saturates (a 1.25 um phone pixel: about 5,000; a large
    /// one: 30,000 and more).
    #[serde(default = "d_full_well")]
    pub full_well: f64,
    /// Read noise, electrons RMS.
    #[serde(default = "d_read_noise")]
    pub read_noise: f64,
    /// ISO, fixed or drawn per window (log-uniformly) from [low, high]; the gain is ISO / 100.
    #[serde(default = "d_iso")]
    pub iso: [f64; 2],
    /// The colour filter array (`rggb`, `bggr`, `grbg`, `gbrg`), demosaiced bilinearly; absent:
    /// every colour at every pixel (no mosaic).
    #[serde(default)]
    pub bayer: Option<Bayer>,
    /// How the mosaic is filled in: `bilinear` or `malvar` (Malvar-He-Cutler's gradient-corrected
    /// 5x5 filters).
    #[serde(default)]
    pub demosaic: crate::imaging::sensor::Demosaic,
    /// The camera response from linear light to the encoded values written (targets too):
    /// `"input"` (the input's own transfer curve), `"srgb"`, `"gamma22"`, `"identity"`,
    /// `{ gamma = G }`, or a table of encoded values at evenly spaced linear values.
    #[serde(default)]
    pub response: Response,
}

fn d_full_well() -> f64 {
    5000.0
}
fn d_read_noise() -> f64 {
    3.0
}
fn d_iso() -> [f64; 2] {
    [100.0, 1600.0]
}

impl StageConfig for SensorConfig {
    super::wiring!(transform, Samples -> Samples);
    fn validate(&self, key: &str) -> Vec<ConfigError> {
        let mut c = Checker::new(key);
        c.range("full_well", self.full_well, 10.0, 1e7);
        c.range("read_noise", self.read_noise, 0.0, 1000.0);
        c.range("iso[0]", self.iso[0], 25.0, 409_600.0);
        c.range("iso[1]", self.iso[1], 25.0, 409_600.0);
        if self.iso[0] > self.iso[1] {
            c.fail("iso", format!("range [{}, {}] is reversed", self.iso[0], self.iso[1]));
        }
        if let Some(why) = self.response.problem() {
            c.fail("response", why);
        }
        c.errors
    }
    fn per_pixel(&self) -> bool {
        // Demosaicing reads neighbours.
        self.bayer.is_none()
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        Ok(Built::Transform(Box::new(SensorStage { cfg: self.clone(), seed: ctx.seed, encoders: Vec::new() })))
    }
}

pub struct SensorStage {
    cfg: SensorConfig,
    seed: u64,
    encoders: Vec<(Curve, Arc<Encoder>)>,
}

impl SensorStage {
    fn encoder(&mut self, c: Curve) -> Arc<Encoder> {
        if let Some((_, e)) = self.encoders.iter().find(|(k, _)| *k == c) {
            return e.clone();
        }
        let e = Arc::new(self.cfg.response.encoder(c));
        self.encoders.push((c, e.clone()));
        e
    }
}

impl Transform for SensorStage {
    fn process(&mut self, item: Item, out: &mut Emit) -> StageResult {
        let Item::Sample(mut s) = item else {
            out.send(item);
            return Ok(());
        };
        let [lo, hi] = self.cfg.iso;
        let iso = (lo.ln() + (hi.ln() - lo.ln()) * unit(hash(&[self.seed, s.input.id, s.window, hash_str("iso")]))).exp();
        let sensor =
            Sensor { full_well: self.cfg.full_well, read_noise: self.cfg.read_noise, gain: iso / BASE_ISO, demosaic: self.cfg.demosaic };
        let key = hash(&[self.seed, s.input.id, s.window, hash_str("sensor")]);
        let enc = self.encoder(s.curve);
        for p in &mut s.pairs {
            if let Img::Linear(lq) = &p.lq {
                let raw = sensor.capture(lq, p.w, p.h, (p.x, p.y), self.cfg.bayer, key);
                p.lq = Img::Encoded8(quantise(&raw, p.w, p.h, p.x, p.y, &enc, 0.0, key));
            }
            // The targets are what an ideal camera sees: no noise, no mosaic.
            if let Img::Linear(gt) = &p.gt {
                p.gt = Img::Encoded8(quantise(gt, p.w, p.h, p.x, p.y, &enc, 0.0, key));
            }
            for b in &mut p.burst {
                if let Img::Linear(v) = b {
                    *b = Img::Encoded8(quantise(v, p.w, p.h, p.x, p.y, &enc, 0.0, key));
                }
            }
        }
        // Beside what came before (the highlights' gain, say).
        let mut capture = s.capture.as_deref().and_then(|c| serde_json::from_str(c).ok()).unwrap_or_else(|| serde_json::json!({}));
        capture["sensor"] = serde_json::json!({
            "full_well": sensor.full_well, "read_noise": sensor.read_noise, "iso": iso, "gain": sensor.gain,
            "bayer": self.cfg.bayer, "demosaic": self.cfg.bayer.map(|_| self.cfg.demosaic),
            "response": self.cfg.response.describe(s.curve),
        });
        s.capture = Some(capture.to_string().into());
        out.send(Item::Sample(s));
        Ok(())
    }
}
