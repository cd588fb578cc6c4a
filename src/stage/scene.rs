//! `scene`: the synthetic moving scenes of the paper's comparison figures ([`crate::render::scene`]).

use super::input::emit_clip;
use super::{BuildContext, Built, Counters, Emit, InputList, Needs, Source, StageConfig};
use crate::checks::Checker;
use crate::checks::ConfigError;
use crate::frame::{Frame, FrameData, Input};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// `type = "scene"`: the synthetic moving scenes of the paper's comparison figures (moving
/// dots, rotating spoke target), `clips` exposures of `frames` sub-frames each.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneSourceConfig {
    pub scene: crate::render::scene::SceneKind,
    /// [width, height]
    pub size: [usize; 2],
    /// Sub-frames per clip (one exposure).
    pub frames: usize,
    /// Travel over the clip of the fastest dot or the spoke target's rim, pixels.
    pub travel_px: f64,
    pub dots_per_arm: usize,
    pub spokes: usize,
    pub clips: usize,
    /// Nominal frame rate written to the report.
    pub fps: f64,
}

impl Default for SceneSourceConfig {
    fn default() -> Self {
        let p = crate::render::scene::SceneParams::default();
        SceneSourceConfig {
            scene: p.kind,
            size: [p.width, p.height],
            frames: p.frames,
            travel_px: p.travel_px,
            dots_per_arm: p.dots_per_arm,
            spokes: p.spokes,
            clips: 1,
            fps: 240.0,
        }
    }
}

impl StageConfig for SceneSourceConfig {
    super::wiring!(source, EncodedFrames);
    fn validate(&self, key: &str) -> Vec<ConfigError> {
        let mut c = Checker::new(key);
        c.range_usize("frames", self.frames, 1, 100_000);
        c.range_usize("clips", self.clips, 1, 100_000);
        c.range("travel_px", self.travel_px, 0.0, 1000.0);
        c.range_usize("spokes", self.spokes, 1, 1000);
        c.range_usize("dots_per_arm", self.dots_per_arm, 1, 1000);
        c.range("fps", self.fps, 1.0, 100_000.0);
        for (i, v) in self.size.iter().enumerate() {
            c.range_usize(&format!("size[{i}]"), *v, 16, 8192);
        }
        c.errors
    }
    fn list(&self) -> crate::Result<InputList> {
        Ok(InputList::Procedural(self.clips))
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        Ok(Built::Source(Box::new(Scene {
            cfg: self.clone(),
            inputs: ctx.inputs.iter().map(|(i, _)| i.clone()).collect(),
            needs: ctx.needs,
            counters: ctx.counters.clone(),
        })))
    }
}

/// `type = "scene"`: synthetic moving scenes ([`crate::render::scene`]), one exposure of `frames`
/// sub-frames per clip, as encoded sRGB frames (a `linearize` with curve srgb gives back the
/// rendered linear light).
pub struct Scene {
    pub cfg: SceneSourceConfig,
    pub inputs: Vec<Arc<Input>>,
    pub needs: Needs,
    pub counters: Arc<Counters>,
}

impl Source for Scene {
    fn run(&mut self, out: &mut Emit) -> crate::Result<()> {
        let c = &self.cfg;
        let params = crate::render::scene::SceneParams {
            kind: c.scene,
            width: c.size[0],
            height: c.size[1],
            frames: c.frames,
            travel_px: c.travel_px,
            dots_per_arm: c.dots_per_arm,
            spokes: c.spokes,
        };
        let enc = crate::optics::transfer::Encoder::new(crate::optics::transfer::Curve::Srgb);
        // Every clip is the same exposure: render it once (frames share their pixels).
        let frames: Vec<Frame> = params
            .render()
            .into_iter()
            .map(|p| {
                Frame::new(
                    params.width,
                    params.height,
                    FrameData::Planar(p.map(|v| v.into_iter().map(|x| enc.encode(x.min(1.0))).collect())),
                )
            })
            .collect();
        for input in &self.inputs {
            if !emit_clip(out, input, frames.clone(), c.fps, "scene", &self.needs, &self.counters) {
                return Ok(());
            }
        }
        Ok(())
    }
}
