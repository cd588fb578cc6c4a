//! `linearize`: tags frames with the transfer curve that makes their values linear light. No
//! pixel changes here: the conversion is by table where a later stage reads a pixel
//! ([`Frame::linear_row`]), so patch mode converts only its patches. The stage's type name says
//! what the frames are from here on (linear light, to whoever reads them); the Rust names say
//! what it does (`CurveTag`, [`super::Kind::TaggedFrames`]).

use super::{BuildContext, Built, Emit, StageConfig, StageResult, Transform};
use crate::checks::ConfigError;
use crate::frame::{Frame, Highlights};
use crate::item::Item;
use crate::optics::transfer::Curve;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinearizeConfig {
    pub inputs: Vec<String>,
    #[serde(default = "default_curve")]
    pub curve: Curve,
    /// Clipped highlights made bright again before the blur; absent: left as they are.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub highlights: Option<HighlightsConfig>,
}

/// `[transforms.x.highlights]`: pixels whose encoded value is at least `threshold` (1: only
/// the top code, what clipping leaves) have their linear light multiplied by a gain drawn per
/// input, log-uniformly from `gain` (RSBlur, Rim et al. 2022, does the same to saturated pixels).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HighlightsConfig {
    pub gain: [f64; 2],
    #[serde(default = "top_code")]
    pub threshold: f64,
}

fn top_code() -> f64 {
    1.0
}

fn default_curve() -> Curve {
    Curve::Srgb
}

impl StageConfig for LinearizeConfig {
    super::wiring!(transform, EncodedFrames -> TaggedFrames);
    fn validate(&self, key: &str) -> Vec<ConfigError> {
        let mut c = crate::checks::Checker::new(key);
        if let Some(h) = &self.highlights {
            c.range("highlights.gain[0]", h.gain[0], 1.0, 100.0);
            c.range("highlights.gain[1]", h.gain[1], 1.0, 100.0);
            if h.gain[0] > h.gain[1] {
                c.fail("highlights.gain", format!("range [{}, {}] is reversed", h.gain[0], h.gain[1]));
            }
            if !(h.threshold > 0.0 && h.threshold <= 1.0) {
                c.fail("highlights.threshold", format!("{} is not an encoded value in (0, 1]", h.threshold));
            }
        }
        c.errors
    }
    fn keeps_positions(&self) -> bool {
        true
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        let highlights = self.highlights.clone().map(|h| (h, ctx.seed));
        Ok(Built::Transform(Box::new(CurveTag { curve: self.curve, highlights })))
    }
}

/// `linearize`: tags frames with `curve`. The pixels are converted lazily, by table, where they
/// are read ([`Frame::linear_row`]): patch mode converts only its patches.
pub struct CurveTag {
    curve: Curve,
    /// The highlights' settings and the run's seed.
    highlights: Option<(HighlightsConfig, u64)>,
}

impl CurveTag {
    pub fn new(curve: Curve) -> CurveTag {
        CurveTag { curve, highlights: None }
    }

    /// The same pixels, tagged with the curve (and the highlights of input `input`).
    pub fn apply(&self, f: &Frame, input: u64) -> Frame {
        let highlights = self.highlights.as_ref().map(|(h, seed)| {
            let u = crate::rng::unit(crate::rng::hash(&[*seed, input, crate::rng::hash_str("highlights")]));
            let gain = (h.gain[0].ln() + (h.gain[1].ln() - h.gain[0].ln()) * u).exp();
            // Half a code below the threshold, so that the threshold's own code is in.
            let threshold = self.curve.to_linear(h.threshold - 0.5 / 255.0);
            Highlights { threshold: threshold as f32, gain: gain as f32 }
        });
        Frame { curve: Some(self.curve), highlights, ..f.clone() }
    }
}

impl Transform for CurveTag {
    fn process(&mut self, item: Item, out: &mut Emit) -> StageResult {
        let item = match item {
            Item::Frame(input, i, f) => {
                let id = input.id;
                Item::Frame(input, i, Arc::new(self.apply(&f, id)))
            }
            other => other,
        };
        out.send(item);
        Ok(())
    }
}
