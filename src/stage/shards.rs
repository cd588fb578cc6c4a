//! `shards`: WebDataset tar shards and their manifest.
//!
//! Shards: each sample is `key.lq.png`, `key.gt.png`, `key.json`, one after another (a burst
//! sample has `key.gt.00.png` ... `key.gt.{K-1}.png` in place of `key.gt.png`); key
//! `{stem}_{id}_{window:06}[_{patch:03}]` (no dots), where `{stem}_{id}` is the input's key (its
//! file stem and a hash of its canonical path). Shards are named `{prefix}-{stem}_{id}-{seq:04}.tar`,
//! so runs with other inputs and tasks of an array job never collide in one folder. They are
//! written under hidden temporary names and renamed when their input has finished; then the
//! manifest is updated under a lock (read, merge this input, write atomically), so runs that
//! share a folder, one after another or at once, all keep their entries. Each shard's size and
//! CRC-32 are recorded, and a rerun redoes an input whose shards are missing or damaged.

use super::{BuildContext, Built, Completed, Counters, Sink, StageConfig};
use crate::checks::Checker;
use crate::checks::ConfigError;
use crate::frame::{Input, InputInfo};
use crate::io::{tar, write_atomic};
use crate::item::Item;
use crate::sample::{meta_json, png_bytes, sample_key};
use crate::sample::{Pair, Sample};
use serde::{Deserialize, Serialize};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// `type = "shards"`: WebDataset tar shards plus `manifest.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardsConfig {
    pub inputs: Vec<String>,
    #[serde(default = "default_dir")]
    pub dir: String,
    #[serde(default = "default_prefix")]
    pub prefix: String,
    #[serde(default = "default_max_samples")]
    pub max_samples_per_shard: usize,
}

pub(crate) fn default_dir() -> String {
    "out".into()
}
fn default_prefix() -> String {
    "train".into()
}
fn default_max_samples() -> usize {
    1000
}

impl StageConfig for ShardsConfig {
    super::wiring!(sink, Samples);
    fn validate(&self, key: &str) -> Vec<ConfigError> {
        let mut c = Checker::new(key);
        c.range_usize("max_samples_per_shard", self.max_samples_per_shard, 1, 10_000_000);
        if self.prefix.is_empty() || self.prefix.contains(['/', '.']) {
            c.fail("prefix", format!("{:?} must be non-empty, without '/' or '.'", self.prefix));
        }
        c.errors
    }
    fn admits(&self, dir: &Path, task: (usize, usize)) -> crate::Result<()> {
        Manifest::same_split(dir, task.1)
    }
    /// What the manifest lists counts as done only when its shards are whole and were made with
    /// these settings; anything else is redone.
    fn completed(&self, dir: &Path, task: (usize, usize), settings: &str) -> crate::Result<Completed> {
        let mut c = Completed::default();
        let Some(m) = Manifest::load(dir, &Manifest::file_name(task.0, task.1))? else { return Ok(c) };
        let checks: Vec<_> = {
            use rayon::prelude::*;
            m.inputs.par_iter().map(|i| (i, i.verify(dir))).collect()
        };
        for (i, check) in checks {
            match check {
                Ok(()) if i.settings == settings || i.settings.is_empty() => {
                    c.keys.insert(i.key.clone());
                }
                Ok(()) => c.redo.push((i.path.clone(), "made with other settings".into())),
                Err(why) => c.redo.push((i.path.clone(), why.to_string())),
            }
        }
        Ok(c)
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        let (task_index, task_count) = ctx.task;
        let template = Manifest { format: "webdataset".into(), prefix: self.prefix.clone(), task_index, task_count, ..Default::default() };
        Ok(Built::Sink(Box::new(Shards::new(
            ctx.out_dir.to_path_buf(),
            self.prefix.clone(),
            self.max_samples_per_shard,
            template,
            Manifest::file_name(task_index, task_count),
            ctx.settings.to_string(),
            ctx.counters.clone(),
        ))))
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ManifestShard {
    pub name: String,
    pub samples: usize,
    /// Size in bytes and CRC-32 (hex) of the whole file (absent in manifests before 0.2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bytes: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crc32: Option<String>,
}

/// Why a shard a manifest lists is not whole (its input is then redone).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NotWhole {
    #[error("{name:?}: {why}")]
    NotPlain { name: String, why: &'static str },
    #[error("{name}: a symbolic link, not a shard written here")]
    Link { name: String },
    #[error("{name}: {cause}")]
    Io { name: String, cause: std::io::Error },
    #[error("{name}: {got} bytes, the manifest says {want}")]
    Size { name: String, got: u64, want: u64 },
    #[error("{name}: CRC-32 {got}, the manifest says {want}")]
    Crc { name: String, got: String, want: String },
}

impl ManifestShard {
    /// Checks the file in `dir` against the recorded size and checksum. The name was checked to
    /// be a plain file name when the manifest was loaded; a symbolic link is not followed.
    ///
    /// # Errors
    /// Why it is not whole: missing, another size, another checksum, a link.
    pub fn verify(&self, dir: &Path) -> std::result::Result<(), NotWhole> {
        let name = || self.name.clone();
        if let Some(why) = crate::io::paths::not_plain(&self.name) {
            return Err(NotWhole::NotPlain { name: name(), why });
        }
        let p = dir.join(&self.name);
        if std::fs::symlink_metadata(&p).is_ok_and(|m| m.file_type().is_symlink()) {
            return Err(NotWhole::Link { name: name() });
        }
        let io = |cause| NotWhole::Io { name: name(), cause };
        let meta = std::fs::metadata(&p).map_err(io)?;
        if let Some(want) = self.bytes {
            if meta.len() != want {
                return Err(NotWhole::Size { name: name(), got: meta.len(), want });
            }
        }
        if let Some(want) = &self.crc32 {
            let mut h = crc32fast::Hasher::new();
            let mut f = File::open(&p).map_err(io)?;
            std::io::copy(&mut f, &mut HashWriter { inner: std::io::sink(), crc: &mut h, bytes: 0 }).map_err(io)?;
            let got = format!("{:08x}", h.finalize());
            if &got != want {
                return Err(NotWhole::Crc { name: name(), got, want: want.clone() });
            }
        }
        Ok(())
    }
}

/// Passes writes through, counting bytes and updating a CRC-32.
struct HashWriter<'a, W: Write> {
    inner: W,
    crc: &'a mut crc32fast::Hasher,
    bytes: u64,
}

impl<W: Write> Write for HashWriter<'_, W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.crc.update(&buf[..n]);
        self.bytes += n as u64;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
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
    /// Hash of the settings that decide the samples' content ([`crate::sample::content_hash`]): a rerun with
    /// other settings redoes the input instead of keeping samples made differently.
    #[serde(default)]
    pub settings: String,
}

impl ManifestInput {
    /// Checks every shard of the input.
    ///
    /// # Errors
    /// The first shard that is not whole, and why.
    pub fn verify(&self, dir: &Path) -> std::result::Result<(), NotWhole> {
        self.shards.iter().try_for_each(|s| s.verify(dir))
    }
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

    /// How many tasks the run that wrote manifest `name` was split into, if it is one.
    fn task_count_of(name: &str) -> Option<usize> {
        if name == "manifest.json" {
            return Some(1);
        }
        let rest = name.strip_prefix("manifest-")?.strip_suffix(".json")?;
        let (i, n) = rest.split_once("-of-")?;
        (i.len() == 5 && i.bytes().all(|b| b.is_ascii_digit())).then_some(())?;
        n.parse().ok()
    }

    /// One folder holds one way of splitting the inputs into tasks: every task of a split lists
    /// its own inputs' shards, and the manifests of another split would list the same shards
    /// again (a reader of all manifests would read their samples twice).
    ///
    /// # Errors
    /// A usage error naming a manifest of another split and the ways on.
    pub fn same_split(dir: &Path, task_count: usize) -> crate::Result<()> {
        let want = task_count.max(1);
        let Ok(rd) = std::fs::read_dir(dir) else { return Ok(()) };
        let mut other: Vec<(String, usize)> =
            rd.flatten().filter_map(|e| e.file_name().to_str().and_then(|n| Some((n.to_string(), Manifest::task_count_of(n)?)))).collect();
        other.retain(|(_, n)| *n != want);
        other.sort();
        let Some((name, n)) = other.first() else { return Ok(()) };
        let was = if *n == 1 { "one task".to_string() } else { format!("{n} tasks (--shard-count {n})") };
        let now = if want == 1 { "one task".to_string() } else { format!("{want} tasks") };
        Err(crate::Error::Usage(format!(
            "{}: holds the shards of a run split into {was} ({name}); a run split into {now} would list the same inputs again. \
             Use the folder's split, or another output folder",
            dir.display()
        )))
    }

    /// The manifest in `dir`, if any.
    ///
    /// # Errors
    /// It exists but is not a manifest (named in the error).
    pub fn load(dir: &Path, name: &str) -> crate::Result<Option<Manifest>> {
        let p = dir.join(name);
        match std::fs::read(&p) {
            Ok(b) => {
                let m: Manifest = serde_json::from_slice(&b).map_err(|e| crate::Error::Unloadable {
                    path: p.clone(),
                    why: "not a pipeline manifest".into(),
                    source: Box::new(e),
                })?;
                // Shard names are opened, sized and removed in `dir`: each must be a plain name
                // there (a tampered manifest must not reach other files).
                for (i, input) in m.inputs.iter().enumerate() {
                    for (j, sh) in input.shards.iter().enumerate() {
                        if let Some(why) = crate::io::paths::not_plain(&sh.name) {
                            let field = format!("inputs[{i}].shards[{j}].name");
                            return Err(crate::Error::Untrusted { file: p, field, name: sh.name.clone(), why });
                        }
                    }
                }
                Ok(Some(m))
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(e) => Err(crate::Error::Io { path: p, cause: e }),
        }
    }

    /// Reads the manifest `name` in `dir` (or starts `empty`), lets `change` edit it and writes
    /// it back atomically, all under an exclusive lock on `.{name}.lock`, so processes that
    /// share the folder never lose each other's entries. Returns what was written.
    ///
    /// # Errors
    /// The lock, the manifest or the folder cannot be read or written (named).
    pub fn update(dir: &Path, name: &str, empty: Manifest, change: impl FnOnce(&mut Manifest)) -> crate::Result<Manifest> {
        let lp = dir.join(format!(".{name}.lock"));
        let lock = crate::io::open_lock(&lp)?;
        lock.lock().map_err(|e| crate::Error::Io { path: lp.clone(), cause: e })?;
        let mut m = Manifest::load(dir, name)?.unwrap_or(empty);
        change(&mut m);
        m.inputs.sort_by(|a, b| a.path.cmp(&b.path).then(a.key.cmp(&b.key)));
        m.samples = m.inputs.iter().map(|i| i.samples).sum();
        let bytes = serde_json::to_vec_pretty(&m).expect("json");
        write_atomic(&dir.join(name), |w| w.write_all(&bytes))?;
        drop(lock);
        Ok(m)
    }
}

struct OpenShard {
    tmp: PathBuf,
    name: String,
    w: BufWriter<File>,
    crc: crc32fast::Hasher,
    bytes: u64,
    samples: usize,
}

impl OpenShard {
    /// Appends one sample through the checksum: one target, or a burst when `burst` holds any.
    fn append(&mut self, key: &str, lq: &[u8], gt: &[u8], burst: &[Vec<u8>], json: &[u8]) -> std::io::Result<()> {
        let mut hw = HashWriter { inner: &mut self.w, crc: &mut self.crc, bytes: 0 };
        if burst.is_empty() {
            crate::io::wds::append_sample(&mut hw, key, lq, gt, json)?;
        } else {
            crate::io::wds::append_burst(&mut hw, key, lq, burst, json)?;
        }
        self.bytes += hw.bytes;
        Ok(())
    }

    /// Ends the archive, syncs the file; its manifest entry.
    fn close(mut self) -> std::io::Result<(PathBuf, ManifestShard)> {
        let mut hw = HashWriter { inner: &mut self.w, crc: &mut self.crc, bytes: 0 };
        tar::finish(&mut hw)?;
        self.bytes += hw.bytes;
        let f = self.w.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        let sh = ManifestShard {
            name: self.name,
            samples: self.samples,
            bytes: Some(self.bytes),
            crc32: Some(format!("{:08x}", self.crc.finalize())),
        };
        Ok((self.tmp, sh))
    }
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
    /// The manifest as last written (by any process), and an empty one to start from.
    pub manifest: Manifest,
    pub manifest_name: String,
    /// [`crate::sample::content_hash`] of this run's settings, recorded with each input.
    pub settings: String,
    pub counters: Arc<Counters>,
    pub failed: Vec<(String, String)>,
    /// This run's inputs, shards and samples.
    done: (usize, usize, usize),
    cur: Option<Current>,
}

impl Shards {
    pub fn new(
        dir: PathBuf,
        prefix: String,
        max_per_shard: usize,
        manifest: Manifest,
        manifest_name: String,
        settings: String,
        counters: Arc<Counters>,
    ) -> Shards {
        Shards { dir, prefix, max_per_shard, manifest, manifest_name, settings, counters, failed: Vec::new(), done: (0, 0, 0), cur: None }
    }

    fn write_pair(&mut self, s: &Sample, p: &Pair) -> crate::Result<()> {
        let (dir, prefix, max) = (self.dir.clone(), self.prefix.clone(), self.max_per_shard);
        let cur = self.cur.as_mut().expect("a sample belongs to an open input");
        if cur.open.as_ref().is_some_and(|o| o.samples >= max) {
            let o = cur.open.take().expect("checked");
            let tmp = o.tmp.clone();
            cur.closed.push(o.close().map_err(|e| crate::Error::Io { path: tmp, cause: e })?);
        }
        if cur.open.is_none() {
            let name = format!("{prefix}-{}-{:04}.tar", cur.input.key, cur.closed.len());
            let tmp = dir.join(crate::io::temp_name(&name, None));
            let f = crate::io::create_new(&tmp).map_err(|e| crate::Error::Io { path: tmp.clone(), cause: e })?;
            cur.open = Some(OpenShard { tmp, name, w: BufWriter::new(f), crc: crc32fast::Hasher::new(), bytes: 0, samples: 0 });
        }
        let o = cur.open.as_mut().expect("opened");
        let key = sample_key(s, p);
        let burst: Vec<Vec<u8>> = p.burst.iter().map(|b| png_bytes(b, p.w, p.h, s.curve)).collect();
        let gt = if burst.is_empty() { png_bytes(&p.gt, p.w, p.h, s.curve) } else { Vec::new() };
        let res = o.append(&key, &png_bytes(&p.lq, p.w, p.h, s.curve), &gt, &burst, &meta_json(s, p));
        res.map_err(|e| crate::Error::Io { path: o.tmp.clone(), cause: e })?;
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
        if let Some(o) = cur.open.take() {
            let tmp = o.tmp.clone();
            match o.close() {
                Ok(c) => cur.closed.push(c),
                Err(e) => {
                    // Nothing of this input stays: its finished shards and the broken one go.
                    for p in cur.closed.iter().map(|(t, _)| t).chain([&tmp]) {
                        let _ = std::fs::remove_file(p);
                    }
                    return Err(crate::Error::Io { path: tmp, cause: e });
                }
            }
        }
        let mut shards = Vec::new();
        let mut left = cur.closed.into_iter();
        for (tmp, sh) in left.by_ref() {
            let fin = self.dir.join(&sh.name);
            if let Err(e) = std::fs::rename(&tmp, &fin) {
                let _ = std::fs::remove_file(&tmp);
                left.for_each(|(t, _)| drop(std::fs::remove_file(t)));
                self.unlist(&shards);
                return Err(crate::Error::Io { path: fin, cause: e });
            }
            shards.push(sh);
        }
        let entry = ManifestInput {
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
            settings: self.settings.clone(),
        };
        self.done.0 += 1;
        self.done.1 += entry.shards.len();
        self.done.2 += entry.samples;
        Counters::add(&self.counters.samples_kept, entry.samples as u64);
        let empty = Manifest { inputs: Vec::new(), samples: 0, ..self.manifest.clone() };
        let dir = self.dir.clone();
        let names = entry.shards.clone();
        let updated = Manifest::update(&self.dir, &self.manifest_name, empty, |m| {
            // An earlier entry of this input (other settings, damaged shards): its shards that
            // the new entry does not reuse go.
            for old in m.inputs.iter().filter(|i| i.key == entry.key) {
                for sh in old.shards.iter().filter(|o| entry.shards.iter().all(|n| n.name != o.name)) {
                    let _ = std::fs::remove_file(dir.join(&sh.name));
                }
            }
            m.inputs.retain(|i| i.key != entry.key);
            m.inputs.push(entry);
        });
        match updated {
            Ok(m) => {
                self.manifest = m;
                Ok(())
            }
            Err(e) => {
                self.unlist(&names);
                Err(e)
            }
        }
    }

    /// Removes shards of this input already renamed into place when its manifest entry could not
    /// be written (a full disk, say), so that every shard in the folder is one the manifest lists:
    /// a `*.tar` glob never picks up an unlisted one. A shard of the same name that the manifest on
    /// disk still lists (an earlier run's identical shard) stays.
    fn unlist(&self, shards: &[ManifestShard]) {
        let listed = Manifest::load(&self.dir, &self.manifest_name).ok().flatten();
        for sh in shards {
            if !listed.as_ref().is_some_and(|m| m.inputs.iter().any(|i| i.shards.iter().any(|o| o.name == sh.name))) {
                let _ = std::fs::remove_file(self.dir.join(&sh.name));
            }
        }
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
                self.failed.push((input.path.clone(), e.to_string()));
                Counters::add(&self.counters.inputs_failed, 1);
            }
        }
        Ok(())
    }

    fn finish(&mut self) -> crate::Result<serde_json::Value> {
        self.commit()?;
        let (inputs, shards, samples) = self.done;
        Ok(serde_json::json!({
            "sink": "shards",
            "dir": self.dir,
            "manifest": self.manifest_name,
            "this_run": { "inputs": inputs, "shards": shards, "samples": samples },
            "manifest_totals": {
                "inputs": self.manifest.inputs.len(),
                "shards": self.manifest.inputs.iter().map(|i| i.shards.len()).sum::<usize>(),
                "samples": self.manifest.samples,
            },
        }))
    }

    fn abort(&mut self) {
        self.discard();
    }

    fn failures(&self) -> Vec<(String, String)> {
        self.failed.clone()
    }
}
