//! WebDataset shards: the reader of (lq, gt) pairs; the writer's sample layout is
//! [`append_sample`] (the `shards` stage names, rotates and indexes the files).

use crate::io::{png as png_io, tar};
use crate::rng::hash_str;
use crate::{Error, Result};
use std::io::Write;
use std::path::Path;

/// Appends one sample: `key.lq.png`, `key.gt.png`, `key.json`, in that order (WebDataset groups
/// consecutive members by the part of the name before the first dot).
///
/// # Errors
/// The writer fails.
pub fn append_sample<W: Write>(w: &mut W, key: &str, lq_png: &[u8], gt_png: &[u8], json: &[u8]) -> std::io::Result<()> {
    tar::append(w, &format!("{key}.lq.png"), lq_png)?;
    tar::append(w, &format!("{key}.gt.png"), gt_png)?;
    tar::append(w, &format!("{key}.json"), json)
}

/// Appends one burst sample: `key.lq.png`, `key.gt.00.png` ... `key.gt.{K-1}.png` (the sharp
/// images at the times the JSON's `times` lists, in order), `key.json`.
///
/// # Errors
/// The writer fails.
pub fn append_burst<W: Write>(w: &mut W, key: &str, lq_png: &[u8], burst_pngs: &[Vec<u8>], json: &[u8]) -> std::io::Result<()> {
    tar::append(w, &format!("{key}.lq.png"), lq_png)?;
    for (k, b) in burst_pngs.iter().enumerate() {
        tar::append(w, &format!("{key}.{}", burst_member(k)), b)?;
    }
    tar::append(w, &format!("{key}.json"), json)
}

/// The member name (after the key) of burst target `k`: `gt.00.png`.
pub fn burst_member(k: usize) -> String {
    format!("gt.{k:02}.png")
}

/// One (lq, gt) pair read from a shard: 8-bit interleaved RGB.
#[derive(Debug, Clone)]
pub struct Pair {
    pub key: String,
    /// The source input it was cut from: a hash of the input's key (`input` in the sample's
    /// JSON), or the run-local `input_index` of shards written before 0.2. The validation split
    /// is by this, never by patch.
    pub source: u64,
    pub w: usize,
    pub h: usize,
    pub lq: Vec<u8>,
    pub gt: Vec<u8>,
    /// A burst sample's sharp images at [`Pair::times`], in order (`gt` is the one nearest the
    /// middle of the exposure, so a single-frame model trains on burst shards too); empty for a
    /// sample with one target.
    pub burst: Vec<Vec<u8>>,
    /// The times of `burst` as fractions of the exposure (the JSON's `times`).
    pub times: Vec<f32>,
}

impl Pair {
    /// The index of the burst target nearest the middle of the exposure (the later of two).
    pub fn middle(times: &[f32]) -> usize {
        (0..times.len()).min_by(|&a, &b| (times[a] - 0.5).abs().total_cmp(&(times[b] - 0.5).abs()).then(b.cmp(&a))).unwrap_or(0)
    }
}

/// One sample of a shard before its images are decoded (the trainer's scan decodes only the
/// samples it keeps: validation samples, and a resumed run's shuffle buffer).
#[derive(Debug, Clone)]
pub struct RawPair {
    pub key: String,
    /// As [`Pair::source`].
    pub source: u64,
    lq: Vec<u8>,
    gt: Vec<u8>,
    burst: Vec<Vec<u8>>,
    times: Vec<f32>,
}

impl RawPair {
    /// Decodes both images, checking that they are PNGs of one size (and of `want`, if given);
    /// errors name `shard` and the key.
    ///
    /// # Errors
    /// See above.
    pub fn decode(self, shard: &Path, want: Option<(usize, usize)>) -> Result<Pair> {
        let RawPair { key, source, lq, gt, burst, times } = self;
        let bad = |what: String| Error::File { path: shard.to_path_buf(), why: format!("sample {key}: {what}") };
        // A member's errors name it as a path inside the shard: `shard.tar/key.lq.png`.
        let png = |member: &str, bytes: &[u8]| png_io::read_rgb8(bytes).map_err(Error::format(&shard.join(format!("{key}.{member}"))));
        let (w, h, lq) = png("lq.png", &lq)?;
        let (gw, gh, gt) = png("gt.png", &gt)?;
        let (w, h) = same_size((w, h), (gw, gh), want).map_err(bad)?;
        let burst = burst
            .iter()
            .enumerate()
            .map(|(k, b)| {
                let (bw, bh, v) = png(&burst_member(k), b)?;
                same_size((w, h), (bw, bh), None).map_err(&bad)?;
                Ok(v)
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Pair { key, source, w, h, lq, gt, burst, times })
    }

    /// The size both images' PNG headers declare (and `want`, if given), without decoding them.
    ///
    /// # Errors
    /// A header that is not a PNG's, or two sizes (naming `shard` and the key).
    pub fn size(&self, shard: &Path, want: Option<(usize, usize)>) -> Result<(usize, usize)> {
        let bad = |what: String| Error::File { path: shard.to_path_buf(), why: format!("sample {}: {what}", self.key) };
        // The signature (8 bytes), then IHDR: length, type, width and height (big-endian).
        let dims = |b: &[u8]| -> Option<(usize, usize)> {
            (b.len() >= 24 && b[..8] == *b"\x89PNG\r\n\x1a\n" && &b[12..16] == b"IHDR").then(|| {
                let be = |i: usize| u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]) as usize;
                (be(16), be(20))
            })
        };
        let lq = dims(&self.lq).ok_or_else(|| bad("lq.png is not a readable PNG (no PNG header)".into()))?;
        let gt = dims(&self.gt).ok_or_else(|| bad("gt.png is not a readable PNG (no PNG header)".into()))?;
        same_size(lq, gt, want).map_err(bad)
    }
}

/// The size of a pair whose images measure `lq` and `gt`: one size, and `want` if given.
fn same_size(lq: (usize, usize), gt: (usize, usize), want: Option<(usize, usize)>) -> std::result::Result<(usize, usize), String> {
    if lq != gt {
        return Err(format!("lq is {}x{} but gt is {}x{}", lq.0, lq.1, gt.0, gt.1));
    }
    match want {
        Some(w) if w != lq => Err(format!("patch is {}x{}, expected {}x{} like the others", lq.0, lq.1, w.0, w.1)),
        _ => Ok(lq),
    }
}

/// Reads every sample of one shard, checking each: a corrupt PNG, a missing member or a
/// patch of another size is an error that names the shard and the key.
///
/// # Errors
/// See above.
pub fn read_shard(path: &Path, want: Option<(usize, usize)>) -> Result<Vec<Pair>> {
    read_shard_raw(path)?.into_iter().map(|r| r.decode(path, want)).collect()
}

/// Reads every sample of one shard without decoding its images: a missing member or a sample
/// JSON that does not parse is an error naming the shard and the key.
///
/// # Errors
/// See above.
pub fn read_shard_raw(path: &Path) -> Result<Vec<RawPair>> {
    let f = std::fs::File::open(path).map_err(|e| Error::Io { path: path.to_path_buf(), cause: e })?;
    let members = tar::read_all(std::io::BufReader::new(f)).map_err(Error::format(path))?;
    let mut out: Vec<RawPair> = Vec::new();
    let bad = |key: &str, what: String| Error::File { path: path.to_path_buf(), why: format!("sample {key}: {what}") };
    let mut cur: Option<Members> = None;
    for (name, bytes) in members {
        let (key, ext) = name.split_once('.').unwrap_or((name.as_str(), ""));
        if cur.as_ref().is_none_or(|c| c.key != key) {
            if let Some(c) = cur.take() {
                out.push(c.finish(&bad)?);
            }
            cur = Some(Members { key: key.to_string(), ..Members::default() });
        }
        let c = cur.as_mut().expect("set above");
        match ext {
            "lq.png" => c.lq = Some(bytes),
            "gt.png" => c.gt = Some(bytes),
            "json" => {
                let v: serde_json::Value = serde_json::from_slice(&bytes).map_err(Error::format(&path.join(&name)))?;
                c.source = Some(v["input"].as_str().map(hash_str).or(v["input_index"].as_u64()).unwrap_or(0));
                if let Some(t) = v.get("times") {
                    let t: Vec<f32> =
                        serde_json::from_value(t.clone()).map_err(|e| bad(key, format!("json's times is not a list of numbers ({e})")))?;
                    c.times = Some(t);
                }
            }
            e => {
                if let Some(k) = e
                    .strip_prefix("gt.")
                    .and_then(|r| r.strip_suffix(".png"))
                    .filter(|k| k.len() == 2)
                    .and_then(|k| k.parse::<usize>().ok())
                {
                    c.burst.push((k, bytes));
                }
            }
        }
    }
    if let Some(c) = cur.take() {
        out.push(c.finish(&bad)?);
    }
    Ok(out)
}

/// The members of one sample as they are read.
#[derive(Default)]
struct Members {
    key: String,
    lq: Option<Vec<u8>>,
    gt: Option<Vec<u8>>,
    burst: Vec<(usize, Vec<u8>)>,
    times: Option<Vec<f32>>,
    source: Option<u64>,
}

impl Members {
    /// The sample, checked: an image and a JSON, and either `gt.png` or a burst of
    /// `gt.00.png` ... whose count is the JSON's `times`.
    fn finish(self, bad: &dyn Fn(&str, String) -> Error) -> Result<RawPair> {
        let Members { key, lq, gt, mut burst, times, source } = self;
        let lq = lq.ok_or_else(|| bad(&key, "has no lq.png".into()))?;
        let source =
            source.ok_or_else(|| bad(&key, "has no json (every sample has one: its source input decides the validation split)".into()))?;
        burst.sort_by_key(|(k, _)| *k);
        let times = times.unwrap_or_default();
        if burst.is_empty() {
            let gt = gt.ok_or_else(|| bad(&key, "has no gt.png".into()))?;
            return Ok(RawPair { key, source, lq, gt, burst: Vec::new(), times: Vec::new() });
        }
        if burst.iter().enumerate().any(|(i, (k, _))| i != *k) || burst.len() != times.len() {
            return Err(bad(
                &key,
                format!(
                    "has burst targets {:?} but its json lists {} times (gt.00.png onwards, one per time)",
                    burst.iter().map(|b| b.0).collect::<Vec<_>>(),
                    times.len()
                ),
            ));
        }
        let burst: Vec<Vec<u8>> = burst.into_iter().map(|(_, b)| b).collect();
        let gt = gt.unwrap_or_else(|| burst[Pair::middle(&times)].clone());
        Ok(RawPair { key, source, lq, gt, burst, times })
    }
}
