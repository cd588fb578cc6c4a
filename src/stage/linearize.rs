//! `linearize`: tags frames with the transfer curve that makes their values linear light. No
//! pixel changes here: the conversion is by table where a later stage reads a pixel
//! ([`Frame::linear_row`]), so patch mode converts only its patches. The stage's type name says
//! what the frames are from here on (linear light, to whoever reads them); the Rust names say
//! what it does (`CurveTag`, [`super::Kind::TaggedFrames`]).

use super::{BuildContext, Built, Emit, StageConfig, StageResult, Transform};
use crate::checks::ConfigError;
use crate::frame::{Frame, Item};
use crate::optics::transfer::Curve;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinearizeConfig {
    pub inputs: Vec<String>,
    #[serde(default = "default_curve")]
    pub curve: Curve,
}

fn default_curve() -> Curve {
    Curve::Srgb
}

impl StageConfig for LinearizeConfig {
    super::wiring!(transform, EncodedFrames -> TaggedFrames);
    fn validate(&self, _key: &str) -> Vec<ConfigError> {
        Vec::new()
    }
    fn keeps_positions(&self) -> bool {
        true
    }
    fn build(&self, _ctx: &BuildContext) -> crate::Result<Built> {
        Ok(Built::Transform(Box::new(CurveTag::new(self.curve))))
    }
}

/// `linearize`: tags frames with `curve`. The pixels are converted lazily, by table, where they
/// are read ([`Frame::linear_row`]): patch mode converts only its patches.
pub struct CurveTag {
    curve: Curve,
}

impl CurveTag {
    pub fn new(curve: Curve) -> CurveTag {
        CurveTag { curve }
    }

    /// The same pixels, tagged with the curve.
    pub fn apply(&self, f: &Frame) -> Frame {
        Frame { curve: Some(self.curve), ..f.clone() }
    }
}

impl Transform for CurveTag {
    fn process(&mut self, item: Item, out: &mut Emit) -> StageResult {
        let item = match item {
            Item::Frame(input, i, f) => Item::Frame(input, i, Arc::new(self.apply(&f))),
            other => other,
        };
        out.send(item);
        Ok(())
    }
}
