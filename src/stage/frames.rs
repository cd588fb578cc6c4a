//! `frames`: full-size (or patch) pairs as image folders, 8-bit PNG or linear OpenEXR, in the
//! layouts deblurring loaders read: per-clip folders, DeepDeblur's GoPro layout with a train/test
//! split by source video, or BasicSR's paired `lq/` + `gt/` folders with a meta-info file.

use super::shards::default_dir;
use super::{BuildContext, Built, Counters, Sink, StageConfig};
use crate::checks::ConfigError;
use crate::io::{exr, write_atomic};
use crate::item::Item;
use crate::sample::png_bytes;
use crate::sample::{Img, Pair, Sample};
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
    /// folders | gopro | basicsr.
    #[serde(default)]
    pub layout: Layout,
    /// Share of source videos written to `test/` (gopro and basicsr layouts), by video, never by
    /// frame; seeded.
    #[serde(default)]
    pub test_fraction: f64,
}

fn default_format() -> ImageFormat {
    ImageFormat::Png
}

/// How the pairs are laid out under `dir`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Layout {
    /// `{clip}/blur_gamma/NNNNNN.png` and `{clip}/sharp/` (EXR: `blur_linear/`, `sharp_linear/`).
    #[default]
    Folders,
    /// DeepDeblur's GoPro layout: `{train|test}/{clip}/{blur,blur_gamma,sharp}/NNNNNN.png`.
    /// `blur` and `blur_gamma` hold the same image: the camera's blur computed in linear light
    /// and re-encoded (what GoPro calls `blur_gamma`), so a loader reading either finds pairs.
    Gopro,
    /// BasicSR's paired folders: `{train|test}/lq/{clip}_NNNNNN.png`, `gt/` with the same names,
    /// and `{train|test}/meta_info.txt` (one `name (h,w,3)` per pair).
    Basicsr,
}

impl StageConfig for FramesConfig {
    super::wiring!(sink, Samples);
    fn validate(&self, key: &str) -> Vec<ConfigError> {
        let mut c = crate::checks::Checker::new(key);
        c.range("test_fraction", self.test_fraction, 0.0, 1.0);
        if self.layout != Layout::Folders && self.format == ImageFormat::Exr {
            c.fail("format", "the gopro and basicsr layouts are 8-bit PNG");
        }
        c.errors
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        let mut f = Frames::new(ctx.out_dir.to_path_buf(), self.format, ctx.counters.clone());
        (f.layout, f.test_fraction, f.seed) = (self.layout, self.test_fraction, ctx.seed);
        Ok(Built::Sink(Box::new(f)))
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
    pub layout: Layout,
    pub test_fraction: f64,
    pub seed: u64,
    /// Meta-info lines of the input being written (basicsr): (split, line).
    meta: Vec<(&'static str, String)>,
}

impl Frames {
    pub fn new(dir: PathBuf, format: ImageFormat, counters: Arc<Counters>) -> Frames {
        Frames {
            dir,
            format,
            counters,
            failed: Vec::new(),
            written: Vec::new(),
            samples: 0,
            pending: 0,
            layout: Layout::Folders,
            test_fraction: 0.0,
            seed: 0,
            meta: Vec::new(),
        }
    }

    /// `train` or `test` for a source video.
    fn split(&self, s: &Sample) -> &'static str {
        use crate::rng::{hash, hash_str, unit};
        if unit(hash(&[self.seed, s.input.id, hash_str("test-split")])) < self.test_fraction {
            "test"
        } else {
            "train"
        }
    }

    fn write(&mut self, s: &Sample, p: &Pair) -> crate::Result<()> {
        if !p.burst.is_empty() {
            return Err(crate::Error::Usage(
                "the frames sink writes one sharp image per sample; burst targets (the blur stage's `burst`) are written by a shards sink"
                    .into(),
            ));
        }
        let name = match p.patch {
            Some(i) => format!("{:06}_{:03}", s.window, i),
            None => format!("{:06}", s.window),
        };
        let ext = match self.format {
            ImageFormat::Png => "png",
            ImageFormat::Exr => "exr",
        };
        // Each image once, with every (folder, file name) it is written to (GoPro's `blur` and
        // `blur_gamma` hold the same encoded bytes).
        let files: [(&Img, Vec<(PathBuf, String)>); 2] = match self.layout {
            Layout::Folders => {
                let base = self.dir.join(&s.input.key);
                let (lq_dir, gt_dir) = if ext == "png" { ("blur_gamma", "sharp") } else { ("blur_linear", "sharp_linear") };
                [(&p.lq, vec![(base.join(lq_dir), format!("{name}.{ext}"))]), (&p.gt, vec![(base.join(gt_dir), format!("{name}.{ext}"))])]
            }
            Layout::Gopro => {
                let base = self.dir.join(self.split(s)).join(&s.input.key);
                let file = format!("{name}.png");
                [
                    (&p.lq, vec![(base.join("blur"), file.clone()), (base.join("blur_gamma"), file.clone())]),
                    (&p.gt, vec![(base.join("sharp"), file)]),
                ]
            }
            Layout::Basicsr => {
                let split = self.split(s);
                let base = self.dir.join(split);
                let file = format!("{}_{name}.png", s.input.key);
                self.meta.push((split, format!("{file} ({},{},3)", p.h, p.w)));
                [(&p.lq, vec![(base.join("lq"), file.clone())]), (&p.gt, vec![(base.join("gt"), file)])]
            }
        };
        for (img, places) in files {
            let bytes = match self.format {
                ImageFormat::Png => png_bytes(img, p.w, p.h, s.curve),
                ImageFormat::Exr => {
                    let converted;
                    let lin = match img {
                        Img::Linear(l) => l,
                        Img::Encoded8(v) => {
                            converted = crate::imaging::from_8bit(v, p.w, p.h, s.curve);
                            &converted
                        }
                    };
                    let mut b = Vec::new();
                    exr::write_rgb_f32(&mut b, p.w, p.h, [&lin[0], &lin[1], &lin[2]]).expect("EXR into memory");
                    b
                }
            };
            for (d, file) in places {
                let d = crate::io::make_dir_in(&self.dir, d.strip_prefix(&self.dir).expect("inside the output"))?;
                let path = d.join(file);
                write_atomic(&path, |w| w.write_all(&bytes))?;
                self.written.push(path);
            }
        }
        Ok(())
    }
}

impl Frames {
    /// Appends the finished input's lines to `{split}/meta_info.txt`, one write per split (runs
    /// sharing the folder append whole lines).
    fn append_meta(&mut self) -> crate::Result<()> {
        for split in ["train", "test"] {
            let lines: String = self.meta.iter().filter(|(s, _)| *s == split).map(|(_, l)| format!("{l}\n")).collect();
            if lines.is_empty() {
                continue;
            }
            append(&self.dir.join(split).join("meta_info.txt"), &lines)?;
        }
        self.meta.clear();
        Ok(())
    }
}

/// Appends whole lines to a file (made if missing), in one write.
fn append(path: &std::path::Path, lines: &str) -> crate::Result<()> {
    let io = |e| crate::Error::Io { path: path.to_path_buf(), cause: e };
    let mut f = crate::io::open_append(path)?;
    std::io::Write::write_all(&mut f, lines.as_bytes()).map_err(io)
}

impl Sink for Frames {
    fn consume(&mut self, item: Item) -> crate::Result<()> {
        match item {
            Item::Begin(..) => {
                self.written.clear();
                self.meta.clear();
                self.pending = 0;
            }
            Item::Sample(s) => {
                for p in &s.pairs {
                    self.write(&s, p)?;
                }
                // The stills source's motion of each window, one JSON line per window, beside the
                // clip's folders (what `pipeline eval` reads as `{video}.motion.jsonl`).
                if let (Some(m), Layout::Folders) = (&s.motion, self.layout) {
                    let path = self.dir.join(&s.input.key).join("motion.jsonl");
                    append(&path, &format!("{{\"window\":{},\"first_frame\":{},\"motion\":{m}}}\n", s.window, s.first_frame))?;
                    if !self.written.contains(&path) {
                        self.written.push(path);
                    }
                }
                self.pending += s.pairs.len();
                Counters::add(&self.counters.samples, s.pairs.len() as u64);
            }
            Item::End(_, Ok(())) => {
                self.append_meta()?;
                self.written.clear();
                self.samples += self.pending;
                Counters::add(&self.counters.samples_kept, self.pending as u64);
                Counters::add(&self.counters.inputs_done, 1);
            }
            Item::End(input, Err(e)) => {
                self.abort();
                self.failed.push((input.path.clone(), e.to_string()));
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
