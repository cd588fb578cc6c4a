//! `decode`: video files through FFmpeg, frame by frame, as encoded frames.

/// Footage slower than this is far from the paper's 240 fps: each sub-frame of a window then
/// spans a long stretch of time, and the windows are exposures no camera makes.
pub const SLOW_FPS: f64 = 120.0;

/// The warning for footage at `fps` below [`SLOW_FPS`]: what the windows become, and the way on.
pub fn slow_footage(path: &std::path::Path, fps: f64) -> String {
    format!(
        "{}: {fps:.1} fps; a window of 9 frames spans {:.0} ms (the paper's: 9 frames of 240 fps, 37 ms). High-frame-rate \
         input is what the blur assumes; from slower footage, make it first (frame interpolation in linear light, e.g. \
         ffmpeg -vf minterpolate=fps=240) and know that the motion between real frames is then invented",
        path.display(),
        9000.0 / fps
    )
}

use super::input::{check_size, VIDEO_EXTS};
use super::{BuildContext, Built, Counters, Emit, InputList, Needs, Source, StageConfig};
use crate::checks::ConfigError;
use crate::frame::{Input, InputError};
use crate::item::Item;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// `type = "decode"`: video files FFmpeg reads.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DecodeConfig {
    /// Files, folders (their video files) or file-name globs (`clips/*.mp4`).
    #[serde(default)]
    pub paths: Vec<String>,
    /// Stop each video after this many frames (0: all).
    #[serde(default)]
    pub max_frames: u64,
}

impl StageConfig for DecodeConfig {
    super::wiring!(source, EncodedFrames);
    fn validate(&self, _key: &str) -> Vec<ConfigError> {
        Vec::new()
    }
    fn list(&self) -> crate::Result<InputList> {
        crate::io::paths::expand_paths(&self.paths, VIDEO_EXTS).map(InputList::Files)
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        Ok(Built::Source(Box::new(Decode {
            inputs: ctx.inputs.iter().map(|(i, p)| (i.clone(), p.clone().expect("decode inputs are files"))).collect(),
            max_frames: self.max_frames,
            needs: ctx.needs,
            counters: ctx.counters.clone(),
            reads: ctx.reads.clone(),
        })))
    }
}

pub struct Decode {
    pub inputs: Vec<(Arc<Input>, PathBuf)>,
    pub max_frames: u64,
    pub needs: Needs,
    pub counters: Arc<Counters>,
    /// In patch mode: convert only what the blur reads of each frame.
    pub reads: Option<super::patches::ReadRegions>,
}

impl Source for Decode {
    fn run(&mut self, out: &mut Emit) -> crate::Result<()> {
        use crate::io::video::VideoReader;
        for (input, path) in &self.inputs {
            let fail = |e: InputError| Item::End(input.clone(), e.end());
            let read = |e| InputError::Read(crate::Error::video(path)(e));
            let mut reader = match VideoReader::open(path) {
                Ok(r) => r,
                Err(e) => {
                    if !out.send(fail(read(e))) {
                        return Ok(());
                    }
                    continue;
                }
            };
            if let Err(e) = check_size(&input.path, &reader.info, &self.needs) {
                if !out.send(fail(e)) {
                    return Ok(());
                }
                continue;
            }
            if reader.info.fps > 0.0 && reader.info.fps < SLOW_FPS {
                eprintln!("warning: {}", slow_footage(path, reader.info.fps));
            }
            if !out.send(Item::Begin(input.clone(), reader.info.clone())) {
                return Ok(());
            }
            let mut n = 0u64;
            let end = loop {
                if out.stop.load(Ordering::Relaxed) {
                    return Ok(());
                }
                if self.max_frames > 0 && n >= self.max_frames {
                    break Ok(());
                }
                let (w, h) = (reader.info.width, reader.info.height);
                reader.regions = self.reads.as_ref().and_then(|r| r.rects(input.id, n, w, h));
                match reader.next_frame() {
                    Ok(Some(f)) => {
                        Counters::add(&self.counters.frames, 1);
                        if !out.send(Item::Frame(input.clone(), n, Arc::new(f))) {
                            return Ok(());
                        }
                        n += 1;
                    }
                    Ok(None) => match reader.info.frames_announced {
                        Some(a) if n < a => {
                            break InputError::Truncated { path: path.display().to_string(), decoded: n, announced: a }.end()
                        }
                        _ => break Ok(()),
                    },
                    Err(e) => break read(e).end(),
                }
            };
            self.counters.input(&input.path, &reader.info, n);
            if !out.send(Item::End(input.clone(), end)) {
                return Ok(());
            }
        }
        Ok(())
    }
}
