//! `frames`: full-size pairs in the GoPro folder layout, 8-bit PNG or linear OpenEXR.

use super::shards::{default_dir, png_bytes};
use super::{BuildContext, Built, Counters, Sink, StageConfig};
use crate::frame::{Img, Item, Pair, Sample};
use crate::io::{exr, write_atomic};
use crate::optics::ConfigError;
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ImageFormat {
    Png,
    Exr,
}

/// `type = "frames"`: full-size pairs in the GoPro layout (`blur_gamma/`, `sharp/`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FramesConfig {
    pub inputs: Vec<String>,
    #[serde(default = "default_dir")]
    pub dir: String,
    /// png: 8-bit encoded; exr: linear light, float.
    #[serde(default = "default_format")]
    pub format: ImageFormat,
}

fn default_format() -> ImageFormat {
    ImageFormat::Png
}

impl StageConfig for FramesConfig {
    super::wiring!(sink, Samples);
    fn validate(&self, _key: &str) -> Vec<ConfigError> {
        Vec::new()
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        Ok(Built::Sink(Box::new(Frames::new(ctx.out_dir.to_path_buf(), self.format, ctx.counters.clone()))))
    }
}

/// `frames`: `{dir}/{key}/blur_gamma/{window:06}.png` and `sharp/` (8-bit, encoded), or with
/// `format = "exr"` `blur_linear/` and `sharp_linear/` in linear light.
pub struct Frames {
    pub dir: PathBuf,
    pub format: ImageFormat,
    pub counters: Arc<Counters>,
    pub failed: Vec<(String, String)>,
    written: Vec<PathBuf>,
    samples: usize,
    /// Samples of the input being written.
    pending: usize,
}

impl Frames {
    pub fn new(dir: PathBuf, format: ImageFormat, counters: Arc<Counters>) -> Frames {
        Frames { dir, format, counters, failed: Vec::new(), written: Vec::new(), samples: 0, pending: 0 }
    }

    fn write(&mut self, s: &Sample, p: &Pair) -> crate::Result<()> {
        let name = match p.patch {
            Some(i) => format!("{:06}_{:03}", s.window, i),
            None => format!("{:06}", s.window),
        };
        let base = self.dir.join(&s.input.key);
        let (lq_dir, gt_dir, ext) = match self.format {
            ImageFormat::Png => ("blur_gamma", "sharp", "png"),
            ImageFormat::Exr => ("blur_linear", "sharp_linear", "exr"),
        };
        for (sub, img) in [(lq_dir, &p.lq), (gt_dir, &p.gt)] {
            let d = base.join(sub);
            std::fs::create_dir_all(&d).map_err(|e| crate::Error::Io { path: d.clone(), cause: e })?;
            let path = d.join(format!("{name}.{ext}"));
            match self.format {
                ImageFormat::Png => {
                    let bytes = png_bytes(img, p.w, p.h, s.curve);
                    write_atomic(&path, |w| w.write_all(&bytes))?;
                }
                ImageFormat::Exr => {
                    let lin: [Vec<f32>; 3] = match img {
                        Img::Linear(l) => l.clone(),
                        Img::Encoded8(v) => crate::imaging::from_8bit(v, p.w, p.h, s.curve),
                    };
                    write_atomic(&path, |w| exr::write_rgb_f32(w, p.w, p.h, [&lin[0], &lin[1], &lin[2]]))?;
                }
            }
            self.written.push(path);
        }
        Ok(())
    }
}

impl Sink for Frames {
    fn consume(&mut self, item: Item) -> crate::Result<()> {
        match item {
            Item::Begin(..) => {
                self.written.clear();
                self.pending = 0;
            }
            Item::Sample(s) => {
                for p in &s.pairs {
                    self.write(&s, p)?;
                }
                self.pending += s.pairs.len();
                Counters::add(&self.counters.samples, s.pairs.len() as u64);
            }
            Item::End(_, Ok(())) => {
                self.written.clear();
                self.samples += self.pending;
                Counters::add(&self.counters.samples_kept, self.pending as u64);
                Counters::add(&self.counters.inputs_done, 1);
            }
            Item::End(input, Err(e)) => {
                self.abort();
                self.failed.push((input.path.clone(), e));
                Counters::add(&self.counters.inputs_failed, 1);
            }
            Item::Frame(..) => {}
        }
        Ok(())
    }

    fn finish(&mut self) -> crate::Result<serde_json::Value> {
        Ok(serde_json::json!({ "sink": "frames", "dir": self.dir, "samples": self.samples }))
    }

    fn abort(&mut self) {
        for p in self.written.drain(..) {
            let _ = std::fs::remove_file(p);
        }
    }

    fn failures(&self) -> Vec<(String, String)> {
        self.failed.clone()
    }
}
