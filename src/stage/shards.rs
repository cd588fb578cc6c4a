//! Sinks: `shards` (WebDataset tar) and `frames` (GoPro folder layout).
//!
//! Shards: each sample is `key.lq.png`, `key.gt.png`, `key.json`, one after another; key
//! `{stem}_{input:05}_{window:06}[_{patch:03}]` (no dots). Shards are named
//! `{prefix}-{input:05}-{seq:04}.tar` by input index, so tasks of a sharded run never collide;
//! they are written under temporary names and renamed when their input has finished, and the
//! manifest is rewritten (atomically) after each input, so a rerun skips what it lists and an
//! input that failed leaves nothing behind.

use super::{Counters, Sink};
use crate::config::ImageFormat;
use crate::frame::{Img, Input, InputInfo, Item, Pair, Sample};
use crate::io::{exr, png as png_io, tar, write_atomic};
use crate::optics::transfer::{Curve, Encoder};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// 8-bit interleaved RGB of an image (quantising linear light without noise).
fn rgb8(img: &Img, w: usize, h: usize, curve: Curve) -> Vec<u8> {
    match img {
        Img::Encoded8(v) => v.clone(),
        Img::Linear(p) => super::noise::quantise(p, w, h, 0, 0, &Encoder::new(curve), 0.0, 0),
    }
}

fn png_bytes(img: &Img, w: usize, h: usize, curve: Curve) -> Vec<u8> {
    let mut buf = Vec::new();
    png_io::write_rgb8(&mut buf, w, h, &rgb8(img, w, h, curve)).expect("png into memory");
    buf
}

/// The per-sample JSON.
#[derive(Serialize)]
struct SampleMeta<'a> {
    video: &'a str,
    input_index: usize,
    window: u64,
    frames: [u64; 2],
    camera: &'static str,
    psi: &'a [f64],
    curve: &'static str,
    sigma: Option<f64>,
    frame_size: [usize; 2],
    patch: Option<PatchMeta>,
}

#[derive(Serialize)]
struct PatchMeta {
    index: u32,
    x: usize,
    y: usize,
    w: usize,
    h: usize,
}

fn sample_key(s: &Sample, p: &Pair) -> String {
    match p.patch {
        Some(i) => format!("{}_{:06}_{:03}", s.input.key, s.window, i),
        None => format!("{}_{:06}", s.input.key, s.window),
    }
}

fn meta_json(s: &Sample, p: &Pair) -> Vec<u8> {
    let m = SampleMeta {
        video: &s.input.path,
        input_index: s.input.index,
        window: s.window,
        frames: [s.first_frame, s.first_frame + s.frames as u64 - 1],
        camera: s.camera.name(),
        psi: &s.psi,
        curve: s.curve.name(),
        sigma: s.sigma,
        frame_size: [s.frame_width, s.frame_height],
        patch: p.patch.map(|index| PatchMeta { index, x: p.x, y: p.y, w: p.w, h: p.h }),
    };
    serde_json::to_vec(&m).expect("json")
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ManifestShard {
    pub name: String,
    pub samples: usize,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ManifestInput {
    pub index: usize,
    pub path: String,
    pub key: String,
    pub width: usize,
    pub height: usize,
    pub fps: f64,
    pub frames: u64,
    pub windows: u64,
    pub samples: usize,
    pub shards: Vec<ManifestShard>,
}

#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub prefix: String,
    pub task_index: usize,
    pub task_count: usize,
    pub samples: usize,
    pub inputs: Vec<ManifestInput>,
}

impl Manifest {
    /// `manifest.json`, or `manifest-{i:05}-of-{n:05}.json` for a task of a sharded run.
    pub fn file_name(task_index: usize, task_count: usize) -> String {
        if task_count <= 1 {
            "manifest.json".into()
        } else {
            format!("manifest-{task_index:05}-of-{task_count:05}.json")
        }
    }

    /// The manifest in `dir`, if any.
    ///
    /// # Errors
    /// It exists but is not a manifest (named in the error).
    pub fn load(dir: &Path, name: &str) -> crate::Result<Option<Manifest>> {
        let p = dir.join(name);
        match std::fs::read(&p) {
            Ok(b) => serde_json::from_slice(&b)
                .map(Some)
                .map_err(|e| crate::Error::Invalid(format!("{}: not a pipeline manifest ({e})", p.display()))),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(crate::Error::Io { path: p, source: e }),
        }
    }
}

struct OpenShard {
    tmp: PathBuf,
    name: String,
    w: BufWriter<File>,
    samples: usize,
}

struct Current {
    input: Arc<Input>,
    info: InputInfo,
    frames: u64,
    windows: u64,
    samples: usize,
    open: Option<OpenShard>,
    closed: Vec<(PathBuf, ManifestShard)>,
}

pub struct Shards {
    pub dir: PathBuf,
    pub prefix: String,
    pub max_per_shard: usize,
    pub manifest: Manifest,
    pub manifest_name: String,
    pub counters: Arc<Counters>,
    pub failed: Vec<(String, String)>,
    cur: Option<Current>,
}

impl Shards {
    pub fn new(
        dir: PathBuf,
        prefix: String,
        max_per_shard: usize,
        manifest: Manifest,
        manifest_name: String,
        counters: Arc<Counters>,
    ) -> Shards {
        Shards { dir, prefix, max_per_shard, manifest, manifest_name, counters, failed: Vec::new(), cur: None }
    }

    fn io(&self, p: &Path, e: std::io::Error) -> crate::Error {
        crate::Error::Io { path: p.to_path_buf(), source: e }
    }

    fn write_pair(&mut self, s: &Sample, p: &Pair) -> crate::Result<()> {
        let (dir, prefix, max) = (self.dir.clone(), self.prefix.clone(), self.max_per_shard);
        let cur = self.cur.as_mut().expect("a sample belongs to an open input");
        if cur.open.as_ref().is_some_and(|o| o.samples >= max) {
            let mut o = cur.open.take().expect("checked");
            tar::finish(&mut o.w).and_then(|_| o.w.flush()).map_err(|e| crate::Error::Io { path: o.tmp.clone(), source: e })?;
            cur.closed.push((o.tmp, ManifestShard { name: o.name, samples: o.samples }));
        }
        if cur.open.is_none() {
            let name = format!("{prefix}-{:05}-{:04}.tar", cur.input.index, cur.closed.len());
            let tmp = dir.join(format!(".{name}.{}.tmp", std::process::id()));
            let f = File::create(&tmp).map_err(|e| crate::Error::Io { path: tmp.clone(), source: e })?;
            cur.open = Some(OpenShard { tmp, name, w: BufWriter::new(f), samples: 0 });
        }
        let o = cur.open.as_mut().expect("opened");
        let key = sample_key(s, p);
        let res = (|| {
            tar::append(&mut o.w, &format!("{key}.lq.png"), &png_bytes(&p.lq, p.w, p.h, s.curve))?;
            tar::append(&mut o.w, &format!("{key}.gt.png"), &png_bytes(&p.gt, p.w, p.h, s.curve))?;
            tar::append(&mut o.w, &format!("{key}.json"), &meta_json(s, p))
        })();
        res.map_err(|e| crate::Error::Io { path: o.tmp.clone(), source: e })?;
        o.samples += 1;
        cur.samples += 1;
        Ok(())
    }

    fn discard(&mut self) {
        if let Some(cur) = self.cur.take() {
            if let Some(o) = cur.open {
                drop(o.w);
                let _ = std::fs::remove_file(&o.tmp);
            }
            for (tmp, _) in cur.closed {
                let _ = std::fs::remove_file(tmp);
            }
        }
    }

    fn commit(&mut self) -> crate::Result<()> {
        let Some(mut cur) = self.cur.take() else {
            return Ok(());
        };
        if let Some(mut o) = cur.open.take() {
            tar::finish(&mut o.w).and_then(|_| o.w.flush()).map_err(|e| self.io(&o.tmp, e))?;
            let f = o.w.into_inner().map_err(|e| crate::Error::Io { path: o.tmp.clone(), source: e.into_error() })?;
            f.sync_all().map_err(|e| self.io(&o.tmp, e))?;
            cur.closed.push((o.tmp, ManifestShard { name: o.name, samples: o.samples }));
        }
        let mut shards = Vec::new();
        for (tmp, sh) in cur.closed {
            let fin = self.dir.join(&sh.name);
            std::fs::rename(&tmp, &fin).map_err(|e| self.io(&fin, e))?;
            shards.push(sh);
        }
        self.manifest.inputs.retain(|i| i.path != cur.input.path);
        self.manifest.inputs.push(ManifestInput {
            index: cur.input.index,
            path: cur.input.path.clone(),
            key: cur.input.key.clone(),
            width: cur.info.width,
            height: cur.info.height,
            fps: cur.info.fps,
            frames: cur.frames,
            windows: cur.windows,
            samples: cur.samples,
            shards,
        });
        self.manifest.inputs.sort_by_key(|i| i.index);
        self.manifest.samples = self.manifest.inputs.iter().map(|i| i.samples).sum();
        let path = self.dir.join(&self.manifest_name);
        let bytes = serde_json::to_vec_pretty(&self.manifest).expect("json");
        write_atomic(&path, |w| w.write_all(&bytes))
    }
}

impl Sink for Shards {
    fn consume(&mut self, item: Item) -> crate::Result<()> {
        match item {
            Item::Begin(input, info) => {
                self.discard();
                self.cur = Some(Current { input, info, frames: 0, windows: 0, samples: 0, open: None, closed: Vec::new() });
            }
            Item::Frame(..) => {}
            Item::Sample(s) => {
                if let Some(cur) = self.cur.as_mut() {
                    cur.windows += 1;
                    cur.frames = cur.frames.max(s.first_frame + s.frames as u64);
                }
                for p in &s.pairs {
                    self.write_pair(&s, p)?;
                }
                Counters::add(&self.counters.samples, s.pairs.len() as u64);
            }
            Item::End(input, Ok(())) => {
                self.commit()?;
                let _ = input;
                Counters::add(&self.counters.inputs_done, 1);
            }
            Item::End(input, Err(e)) => {
                self.discard();
                self.failed.push((input.path.clone(), e));
                Counters::add(&self.counters.inputs_failed, 1);
            }
        }
        Ok(())
    }

    fn finish(&mut self) -> crate::Result<serde_json::Value> {
        self.commit()?;
        Ok(serde_json::json!({
            "sink": "shards",
            "dir": self.dir,
            "manifest": self.manifest_name,
            "shards": self.manifest.inputs.iter().map(|i| i.shards.len()).sum::<usize>(),
            "samples": self.manifest.samples,
            "inputs": self.manifest.inputs.len(),
        }))
    }

    fn abort(&mut self) {
        self.discard();
    }

    fn failures(&self) -> Vec<(String, String)> {
        self.failed.clone()
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
}

impl Frames {
    pub fn new(dir: PathBuf, format: ImageFormat, counters: Arc<Counters>) -> Frames {
        Frames { dir, format, counters, failed: Vec::new(), written: Vec::new(), samples: 0 }
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
            std::fs::create_dir_all(&d).map_err(|e| crate::Error::Io { path: d.clone(), source: e })?;
            let path = d.join(format!("{name}.{ext}"));
            match self.format {
                ImageFormat::Png => {
                    let bytes = png_bytes(img, p.w, p.h, s.curve);
                    write_atomic(&path, |w| w.write_all(&bytes))?;
                }
                ImageFormat::Exr => {
                    let lin: [Vec<f32>; 3] = match img {
                        Img::Linear(l) => l.clone(),
                        Img::Encoded8(v) => {
                            std::array::from_fn(|c| (0..p.w * p.h).map(|i| s.curve.to_linear(v[i * 3 + c] as f64 / 255.0) as f32).collect())
                        }
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
            Item::Begin(..) => self.written.clear(),
            Item::Sample(s) => {
                for p in &s.pairs {
                    self.write(&s, p)?;
                }
                self.samples += s.pairs.len();
                Counters::add(&self.counters.samples, s.pairs.len() as u64);
            }
            Item::End(_, Ok(())) => {
                self.written.clear();
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

/// Inputs a manifest lists as complete, by path.
pub fn completed(manifest: &Option<Manifest>) -> BTreeMap<String, usize> {
    manifest.iter().flat_map(|m| m.inputs.iter().map(|i| (i.path.clone(), i.samples))).collect()
}

/// `blackhole`: counts what arrives and keeps nothing.
pub struct Blackhole {
    pub counters: Arc<Counters>,
    pub samples: usize,
    pub failed: Vec<(String, String)>,
}

impl Sink for Blackhole {
    fn consume(&mut self, item: Item) -> crate::Result<()> {
        match item {
            Item::Sample(s) => {
                self.samples += s.pairs.len();
                Counters::add(&self.counters.samples, s.pairs.len() as u64);
            }
            Item::End(_, Ok(())) => Counters::add(&self.counters.inputs_done, 1),
            Item::End(input, Err(e)) => {
                self.failed.push((input.path.clone(), e));
                Counters::add(&self.counters.inputs_failed, 1);
            }
            _ => {}
        }
        Ok(())
    }
    fn finish(&mut self) -> crate::Result<serde_json::Value> {
        Ok(serde_json::json!({ "sink": "blackhole", "samples": self.samples }))
    }
    fn abort(&mut self) {}
    fn failures(&self) -> Vec<(String, String)> {
        self.failed.clone()
    }
}
