//! Inputs as the stages see them: keys, what downstream needs of an input, and the source-side
//! helpers shared by the sources.

use super::{Counters, Emit};
use crate::frame::{Frame, Input, InputError, InputInfo};
use crate::item::Item;
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// File extensions taken from a folder of videos.
pub const VIDEO_EXTS: &[&str] = &["mp4", "mkv", "mov", "avi", "webm", "m4v", "mts", "ts", "y4m", "nut"];

/// A source's inputs: files, or a number of procedural clips.
#[derive(Debug, Clone)]
pub enum InputList {
    Files(Vec<PathBuf>),
    Procedural(usize),
}

/// A WebDataset-safe key for an input: its file stem with anything but letters, digits, '-'
/// and '_' replaced, plus 12 hex digits of `id`, the hash of its identity (the canonical path's
/// bytes, or a procedural clip's number and seed). Shard names and sample keys derive from it, so runs
/// with other inputs, tasks of an array job and equal stems in other folders never collide,
/// while a rerun of the same input finds its own shards.
pub fn input_key(stem_of: &str, id: u64) -> String {
    let stem = std::path::Path::new(stem_of).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let clean: String = stem.chars().take(40).map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect();
    format!("{clean}_{:012x}", id >> 16)
}

/// Minimum frames and frame size the stages downstream need, checked by the source.
#[derive(Debug, Clone, Copy, Default)]
pub struct Needs {
    pub frames: u64,
    pub width: usize,
    pub height: usize,
}

impl Needs {
    /// What both need.
    pub fn max(self, o: Needs) -> Needs {
        Needs { frames: self.frames.max(o.frames), width: self.width.max(o.width), height: self.height.max(o.height) }
    }
}

pub(crate) fn check_size(path: &str, info: &InputInfo, needs: &Needs) -> Result<(), InputError> {
    if info.width < needs.width || info.height < needs.height {
        let (width, height, patch) = (info.width, info.height, (needs.width, needs.height));
        return Err(InputError::TooSmall { path: path.into(), width, height, patch });
    }
    if let Some(n) = info.frames_announced {
        if n < needs.frames {
            return Err(InputError::TooShort { path: path.into(), frames: n, window: needs.frames as usize });
        }
    }
    Ok(())
}

/// Sends one rendered clip downstream (Begin, its frames, End); false when the graph stops.
pub(crate) fn emit_clip(
    out: &mut Emit,
    input: &Arc<Input>,
    frames: Vec<Frame>,
    fps: f64,
    codec: &str,
    needs: &Needs,
    counters: &Counters,
) -> bool {
    let info = InputInfo {
        width: frames.first().map_or(0, |f| f.width),
        height: frames.first().map_or(0, |f| f.height),
        fps,
        frames_announced: Some(frames.len() as u64),
        codec: codec.into(),
        pixel_format: "rgbf32".into(),
    };
    if let Err(e) = check_size(&input.path, &info, needs) {
        return out.send(Item::End(input.clone(), e.end()));
    }
    counters.input(&input.path, &info, frames.len() as u64);
    if !out.send(Item::Begin(input.clone(), info)) {
        return false;
    }
    for (i, f) in frames.into_iter().enumerate() {
        if out.stop.load(Ordering::Relaxed) {
            return false;
        }
        Counters::add(&counters.frames, 1);
        if !out.send(Item::Frame(input.clone(), i as u64, Arc::new(f))) {
            return false;
        }
    }
    out.send(Item::End(input.clone(), Ok(())))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_have_no_dots() {
        let id = |p: &str| crate::rng::hash_bytes(p.as_bytes());
        let k = input_key("/a/b/my.clip.v2.mp4", id("/a/b/my.clip.v2.mp4"));
        assert!(k.starts_with("my_clip_v2_") && k.len() == "my_clip_v2_".len() + 12 && !k.contains('.'), "{k}");
        assert_ne!(k, input_key("/a/c/my.clip.v2.mp4", id("/a/c/my.clip.v2.mp4")), "equal stems in other folders");
        assert_eq!(k, input_key("my.clip.v2.mp4", id("/a/b/my.clip.v2.mp4")), "the identity decides, not the spelling");
    }
}
