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
}

/// Reads every sample of one shard, checking each: a corrupt PNG, a missing member or a
/// patch of another size is an error that names the shard and the key.
///
/// # Errors
/// See above.
pub fn read_shard(path: &Path, want: Option<(usize, usize)>) -> Result<Vec<Pair>> {
    let f = std::fs::File::open(path).map_err(|e| Error::Io { path: path.to_path_buf(), cause: e })?;
    let members = tar::read_all(std::io::BufReader::new(f)).map_err(|e| Error::Invalid(format!("{}: {e}", path.display())))?;
    let mut out: Vec<Pair> = Vec::new();
    let mut cur: Option<(String, Option<Vec<u8>>, Option<Vec<u8>>, Option<u64>)> = None;
    let bad = |key: &str, what: String| Error::Invalid(format!("{}: sample {key}: {what}", path.display()));
    let finish = |c: (String, Option<Vec<u8>>, Option<Vec<u8>>, Option<u64>), out: &mut Vec<Pair>| -> Result<()> {
        let (key, lq, gt, idx) = c;
        let lq = lq.ok_or_else(|| bad(&key, "has no lq.png".into()))?;
        let gt = gt.ok_or_else(|| bad(&key, "has no gt.png".into()))?;
        let (w, h, lq) = png_io::read_rgb8(&lq).map_err(|e| bad(&key, format!("lq.png is not a readable PNG ({e})")))?;
        let (gw, gh, gt) = png_io::read_rgb8(&gt).map_err(|e| bad(&key, format!("gt.png is not a readable PNG ({e})")))?;
        if (w, h) != (gw, gh) {
            return Err(bad(&key, format!("lq is {w}x{h} but gt is {gw}x{gh}")));
        }
        if let Some((ww, wh)) = want {
            if (w, h) != (ww, wh) {
                return Err(bad(&key, format!("patch is {w}x{h}, expected {ww}x{wh} like the others")));
            }
        }
        out.push(Pair { key, source: idx.unwrap_or(0), w, h, lq, gt });
        Ok(())
    };
    for (name, bytes) in members {
        let (key, ext) = name.split_once('.').unwrap_or((name.as_str(), ""));
        if cur.as_ref().is_none_or(|c| c.0 != key) {
            if let Some(c) = cur.take() {
                finish(c, &mut out)?;
            }
            cur = Some((key.to_string(), None, None, None));
        }
        let c = cur.as_mut().expect("set above");
        match ext {
            "lq.png" => c.1 = Some(bytes),
            "gt.png" => c.2 = Some(bytes),
            "json" => {
                let v: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| bad(key, format!("json is not valid ({e})")))?;
                c.3 = v["input"].as_str().map(hash_str).or(v["input_index"].as_u64());
            }
            _ => {}
        }
    }
    if let Some(c) = cur.take() {
        finish(c, &mut out)?;
    }
    Ok(out)
}
