//! `pipeline deblur`: runs a trained network over a video or a folder of images, frame by
//! frame, in tiles with overlapping, blended seams, in bounded memory.
//!
//! The network takes encoded sRGB values in [0, 1] (as the training pairs are written), so frames
//! go in as decoded. Audio is not copied (the report says so).

use crate::io::{png as png_io, write_atomic};
use crate::model::fast::{FastNet, T4};
use crate::{Error, Result};
use burn::tensor::Device;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The model `deblur` uses without `--model`: the shipped U-Net 16 trained on the coded camera
/// (the best coded model on the held-out test clips, docs/eval.md; 3.7 MB).
pub const DEFAULT_MODEL: &[u8] = include_bytes!("../models/unet16-coded/model.safetensors");

/// The default deblur file, embedded.
pub const DEBLUR_TOML: &str = include_str!("../pipelines/deblur.toml");

/// A deblur file (`pipelines/deblur.toml`): `[deblur]`.
#[derive(Debug, Clone, Default, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeblurFile {
    #[serde(default)]
    pub deblur: DeblurConfig,
}

/// `[deblur]`.
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DeblurConfig {
    /// A model file; empty: the embedded default.
    pub model: String,
    pub tile: usize,
    pub overlap: usize,
    pub lossless: bool,
}

impl Default for DeblurConfig {
    fn default() -> Self {
        DeblurConfig { model: String::new(), tile: 1280, overlap: 64, lossless: false }
    }
}

impl DeblurFile {
    /// Parses a deblur file (after `--set`), checking every value.
    ///
    /// # Errors
    /// An unknown key or a bad value, named.
    pub fn from_table(table: toml::Table, origin: &str) -> Result<DeblurFile> {
        let f: DeblurFile = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| Error::ConfigText(format!("{origin}: {}", e.to_string().trim())))?;
        let mut c = crate::optics::config::Checker::new("deblur");
        c.range_usize("tile", f.deblur.tile, 16, 8192);
        if f.deblur.overlap * 2 > f.deblur.tile {
            c.fail("overlap", format!("{} is more than half the tile ({})", f.deblur.overlap, f.deblur.tile));
        }
        if !c.errors.is_empty() {
            return Err(Error::Config(c.errors));
        }
        Ok(f)
    }
}

/// Tiling of a frame: square tiles of `tile` pixels overlapping by `overlap`.
#[derive(Debug, Clone, Copy)]
pub struct Tiling {
    pub tile: usize,
    pub overlap: usize,
}

/// Tiles of at most `t` covering `0..n`, overlapping by at least `o`: as few as that allows,
/// all of one size, spread evenly (so no tile is mostly overlap). Returns the size and the
/// start positions.
fn tiles_1d(n: usize, t: usize, o: usize) -> (usize, Vec<usize>) {
    if n <= t {
        return (n, vec![0]);
    }
    let count = (n - o).div_ceil(t - o);
    let size = (n + (count - 1) * o).div_ceil(count);
    let step = size - o;
    (size, (0..count).map(|i| (i * step).min(n - size)).collect())
}

/// Blending weight of position `i` in a tile of length `len` placed at `start` in `0..n`: a
/// linear ramp over the overlap, except at the frame's own borders.
fn ramp(i: usize, len: usize, start: usize, n: usize, o: usize) -> f32 {
    let mut w = 1.0f32;
    if start > 0 && i < o {
        w = w.min((i as f32 + 0.5) / o as f32);
    }
    if start + len < n && i + o >= len {
        w = w.min((len - i) as f32 / o as f32 - 0.5 / o as f32);
    }
    w.max(1e-3)
}

/// Runs `net` on one interleaved 8-bit RGB frame, whole or in blended tiles. Each tile's
/// forward pass runs on all cores; tiles only bound the memory, and are blended in a fixed
/// order, so the result does not depend on the number of threads.
pub fn run_frame(net: &FastNet, rgb: &[u8], w: usize, h: usize, tiling: Tiling) -> Vec<u8> {
    let (t, o) = (tiling.tile.max(16), tiling.overlap.min(tiling.tile / 2));
    let ((tw, xs), (th, ys)) = (tiles_1d(w, t, o), tiles_1d(h, t, o));
    let tiles: Vec<(usize, usize)> = ys.iter().flat_map(|&y0| xs.iter().map(move |&x0| (x0, y0))).collect();
    let forward = |&(x0, y0): &(usize, usize)| -> Vec<f32> {
        let mut v = vec![0.0f32; 3 * tw * th];
        for y in 0..th {
            for x in 0..tw {
                for c in 0..3 {
                    v[c * tw * th + y * tw + x] = rgb[((y0 + y) * w + x0 + x) * 3 + c] as f32 / 255.0;
                }
            }
        }
        net.forward(&T4::new(1, 3, th, tw, v)).d
    };
    let outs: Vec<Vec<f32>> = tiles.iter().map(forward).collect();
    let mut acc = vec![0.0f32; w * h * 3];
    let mut wsum = vec![0.0f32; w * h];
    for (&(x0, y0), out) in tiles.iter().zip(&outs) {
        for y in 0..th {
            let wy = ramp(y, th, y0, h, o);
            for x in 0..tw {
                let wgt = wy * ramp(x, tw, x0, w, o);
                let p = (y0 + y) * w + x0 + x;
                wsum[p] += wgt;
                for c in 0..3 {
                    acc[p * 3 + c] += wgt * out[c * tw * th + y * tw + x];
                }
            }
        }
    }
    acc.iter().enumerate().map(|(i, v)| ((v / wsum[i / 3]).clamp(0.0, 1.0) * 255.0).round() as u8).collect()
}

/// `report.json` of a deblur run.
#[derive(Debug, serde::Serialize)]
pub struct DeblurReport {
    #[serde(flatten)]
    pub provenance: crate::provenance::Provenance,
    pub input: String,
    pub output: String,
    pub model: String,
    pub frames: u64,
    pub width: usize,
    pub height: usize,
    pub fps: Option<f64>,
    pub tile: usize,
    pub overlap: usize,
    pub seconds: f64,
    pub frames_per_s: f64,
    pub audio: &'static str,
    /// Images that could not be read or written (folder input), and why; the rest were done.
    pub failed: Vec<FailedImage>,
}

#[derive(Debug, serde::Serialize)]
pub struct FailedImage {
    pub path: String,
    pub error: String,
}

impl DeblurReport {
    #[allow(clippy::too_many_arguments)]
    fn new(
        input: &Path,
        output: &Path,
        model: &str,
        frames: u64,
        (width, height): (usize, usize),
        fps: Option<f64>,
        tiling: Tiling,
        t0: Instant,
        audio: &'static str,
    ) -> DeblurReport {
        let seconds = t0.elapsed().as_secs_f64();
        DeblurReport {
            provenance: crate::provenance::Provenance::now(),
            input: input.display().to_string(),
            output: output.display().to_string(),
            model: model.into(),
            frames,
            width,
            height,
            fps,
            tile: tiling.tile,
            overlap: tiling.overlap,
            seconds,
            frames_per_s: frames as f64 / seconds,
            audio,
            failed: Vec::new(),
        }
    }
}

/// Where a file is written before it is renamed into place (same folder, ending in the same
/// extension, so FFmpeg picks the same container; removed at the next start if the run is killed).
fn temp_for(path: &Path) -> PathBuf {
    let name = path.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = path.extension().map(|s| s.to_string_lossy().into_owned());
    path.with_file_name(crate::io::temp_name(&name, ext.as_deref()))
}

/// The message of a run stopped by SIGINT or SIGTERM.
const INTERRUPTED: &str = "interrupted: the unfinished output was removed";

/// Removes temporaries of killed deblur runs in `dir` (this machine, process gone).
fn remove_stale(dir: &Path) {
    for p in crate::io::remove_stale(if dir.as_os_str().is_empty() { Path::new(".") } else { dir }, 0) {
        eprintln!("removed {} (left by a run that was killed)", p.display());
    }
}

/// Deblurs a video into a video of the same size and frame rate.
///
/// # Errors
/// The input cannot be decoded, the output cannot be written (named); nothing is left at the
/// output path on failure.
#[cfg(feature = "ffmpeg")]
pub fn video(
    net: &FastNet,
    model_name: &str,
    input: &Path,
    output: &Path,
    tiling: Tiling,
    lossless: bool,
    progress: bool,
) -> Result<DeblurReport> {
    use crate::io::video::{VideoReader, VideoWriter};
    crate::signal::install();
    let t0 = Instant::now();
    remove_stale(output.parent().unwrap_or(Path::new(".")));
    let name = |p: &Path, e: String| Error::Invalid(format!("{}: {e}", p.display()));
    let mut reader = VideoReader::open(input).map_err(|e| name(input, e))?;
    let (w, h) = (reader.info.width, reader.info.height);
    if lossless && output.extension().and_then(|e| e.to_str()) != Some("mkv") {
        return Err(name(output, "--lossless writes FFV1, which needs a .mkv output".into()));
    }
    let tmp = temp_for(output);
    let mut writer = VideoWriter::create(&tmp, w, h, reader.rate, lossless).map_err(|e| name(output, e))?;
    let bar = progress.then(|| progress_bar(reader.info.frames_announced.unwrap_or(0)));
    let result = (|| -> Result<u64> {
        while let Some(f) = reader.next_frame().map_err(|e| name(input, e))? {
            if crate::signal::interrupted() {
                return Err(Error::Invalid(format!("{}: {INTERRUPTED}", output.display())));
            }
            let rgb = to_rgb8(&f, reader.float);
            let out = run_frame(net, &rgb, w, h, tiling);
            writer.write_rgb8(&out).map_err(|e| name(output, e))?;
            if let Some(b) = &bar {
                b.inc(1);
            }
        }
        let n = writer.finish().map_err(|e| name(output, e))?;
        std::fs::rename(&tmp, output).map_err(|e| Error::Io { path: output.to_path_buf(), cause: e })?;
        Ok(n)
    })();
    let frames = match result {
        Ok(n) => n,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
    };
    Ok(DeblurReport::new(
        input,
        output,
        model_name,
        frames,
        (w, h),
        Some(reader.info.fps),
        tiling,
        t0,
        "not copied: deblur writes the video stream only",
    ))
}

/// Interleaved 8-bit encoded RGB of a decoded frame; float frames (OpenEXR) are linear light
/// and are sRGB-encoded first, as the network sees encoded values.
pub fn to_rgb8(f: &crate::frame::Frame, float_linear: bool) -> Vec<u8> {
    use crate::frame::FrameData;
    let n = f.width * f.height;
    match &*f.data {
        FrameData::Planar8(p) => (0..n).flat_map(|i| [p[0][i], p[1][i], p[2][i]]).collect(),
        FrameData::Planar16(p) => (0..n).flat_map(|i| [0, 1, 2].map(|c| (p[c][i] as f32 / 257.0).round() as u8)).collect(),
        FrameData::Planar(p) => (0..n)
            .flat_map(|i| {
                [0, 1, 2].map(|c| {
                    let v = p[c][i].clamp(0.0, 1.0);
                    let e = if float_linear { png_io::srgb_encode(v) } else { v };
                    (e * 255.0).round() as u8
                })
            })
            .collect(),
    }
}

/// Image formats `deblur` reads from a folder, and writes back in the same format.
pub const IMAGE_EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "tif", "tiff", "exr"];

/// Reads one image as interleaved 8-bit encoded RGB: PNG by our own reader, the others through
/// FFmpeg's decoders (OpenEXR is linear and gets sRGB-encoded).
fn read_image(f: &Path, ext: &str) -> Result<(usize, usize, Vec<u8>)> {
    let bad = |e: String| Error::Invalid(format!("{}: {e}", f.display()));
    if ext == "png" {
        let bytes = std::fs::read(f).map_err(|e| Error::Io { path: f.to_path_buf(), cause: e })?;
        return png_io::read_rgb8(&bytes).map_err(bad);
    }
    #[cfg(feature = "ffmpeg")]
    {
        let (frame, float) = crate::io::video::read_image(f).map_err(bad)?;
        Ok((frame.width, frame.height, to_rgb8(&frame, float)))
    }
    #[cfg(not(feature = "ffmpeg"))]
    Err(bad("only PNG is read without the ffmpeg feature".into()))
}

/// Writes one image in the format its extension names: PNG and OpenEXR (linear light, decoded
/// from sRGB) by our own writers, JPEG and TIFF through FFmpeg's encoders; atomically.
fn write_image(dst: &Path, ext: &str, w: usize, h: usize, rgb: &[u8]) -> Result<()> {
    match ext {
        "png" => write_atomic(dst, |wr| png_io::write_rgb8(wr, w, h, rgb)),
        "exr" => {
            let curve = crate::optics::transfer::Curve::Srgb;
            let planes: [Vec<f32>; 3] =
                std::array::from_fn(|c| (0..w * h).map(|i| curve.to_linear(rgb[i * 3 + c] as f64 / 255.0) as f32).collect());
            write_atomic(dst, |wr| crate::io::exr::write_rgb_f32(wr, w, h, [&planes[0], &planes[1], &planes[2]]))
        }
        #[cfg(feature = "ffmpeg")]
        _ => {
            use crate::io::video::Codec;
            let codec = if ext.starts_with("tif") { Codec::Tiff } else { Codec::Jpeg };
            let tmp = temp_for(dst);
            let res = crate::io::video::write_image(&tmp, w, h, rgb, codec)
                .map_err(|e| Error::Invalid(format!("{}: {e}", dst.display())))
                .and_then(|()| std::fs::rename(&tmp, dst).map_err(|e| Error::Io { path: dst.to_path_buf(), cause: e }));
            if res.is_err() {
                let _ = std::fs::remove_file(&tmp);
            }
            res
        }
        #[cfg(not(feature = "ffmpeg"))]
        _ => Err(Error::Invalid(format!("{}: JPEG and TIFF need the ffmpeg feature", dst.display()))),
    }
}

/// Deblurs every image (PNG, JPEG, TIFF, OpenEXR) of a folder or glob into a folder, keeping
/// the names and formats. An image that cannot be read or written is reported in
/// [`DeblurReport::failed`] and the others are still done.
///
/// # Errors
/// No image found, an output folder that cannot be made, an interruption (SIGINT, SIGTERM;
/// finished images stay, each written whole).
pub fn images(net: &FastNet, model_name: &str, input: &Path, output: &Path, tiling: Tiling, progress: bool) -> Result<DeblurReport> {
    crate::signal::install();
    let t0 = Instant::now();
    let files = crate::config::expand_paths(&[input.display().to_string()], &IMAGE_EXTENSIONS)?;
    if files.is_empty() {
        return Err(Error::Usage(format!("{}: no image found ({})", input.display(), IMAGE_EXTENSIONS.join(", "))));
    }
    std::fs::create_dir_all(output).map_err(|e| Error::Io { path: output.to_path_buf(), cause: e })?;
    remove_stale(output);
    let bar = progress.then(|| progress_bar(files.len() as u64));
    let (mut w, mut h, mut done) = (0, 0, 0);
    let mut failed = Vec::new();
    for f in &files {
        if crate::signal::interrupted() {
            return Err(Error::Invalid(format!(
                "{}: interrupted after {done} of {} images (each written whole)",
                output.display(),
                files.len()
            )));
        }
        let ext = f.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        let res = read_image(f, &ext).and_then(|(fw, fh, rgb)| {
            let out = run_frame(net, &rgb, fw, fh, tiling);
            write_image(&output.join(f.file_name().expect("a file")), &ext, fw, fh, &out).map(|()| (fw, fh))
        });
        match res {
            Ok(size) => {
                (w, h) = size;
                done += 1;
            }
            Err(e) => {
                let msg = e.to_string();
                let error = if msg.contains(&*f.to_string_lossy()) { msg } else { format!("{}: {msg}", f.display()) };
                eprintln!("failed: {error}");
                failed.push(FailedImage { path: f.display().to_string(), error });
            }
        }
        if let Some(b) = &bar {
            b.inc(1);
        }
    }
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    let mut r = DeblurReport::new(input, output, model_name, done, (w, h), None, tiling, t0, "none (images)");
    r.failed = failed;
    Ok(r)
}

/// The progress bar of `deblur`: frames done, frames/s, time left.
fn progress_bar(len: u64) -> indicatif::ProgressBar {
    let b = indicatif::ProgressBar::new(len);
    b.set_style(indicatif::ProgressStyle::with_template("deblur {bar:30} {pos}/{len} frames {per_sec} eta {eta}").expect("template"));
    b
}

/// Loads `--model`, or the embedded default.
///
/// # Errors
/// As [`crate::train::load_model`].
pub fn load(model: Option<&Path>) -> Result<(FastNet, String)> {
    let device = Device::flex();
    let (net, name) = match model {
        Some(p) => crate::train::load_model(p, &device).map(|(n, a)| (n, format!("{} ({})", p.display(), a.name())))?,
        None => crate::train::load_model_bytes(DEFAULT_MODEL, "embedded models/unet16-coded", &device)
            .map(|(n, a)| (n, format!("models/unet16-coded ({})", a.name())))?,
    };
    Ok((FastNet::from_net(&net), name))
}

/// Writes the report beside the output.
///
/// # Errors
/// It cannot be written.
pub fn write_report(path: &Path, r: &DeblurReport) -> Result<()> {
    let bytes = serde_json::to_vec_pretty(r).expect("json");
    write_atomic(path, |w| w.write_all(&bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_frame_with_the_overlap() {
        assert_eq!(tiles_1d(100, 128, 16), (100, vec![0]));
        for (n, t, o) in [(300, 128, 32), (720, 256, 32), (1280, 384, 32), (1081, 200, 17)] {
            let (size, s) = tiles_1d(n, t, o);
            assert!(size <= t && s[0] == 0 && s.last().unwrap() + size == n, "{n} {t} {o}: {size} {s:?}");
            assert!(s.windows(2).all(|p| p[0] + size >= p[1] + o), "{n} {t} {o}: overlap below {o}: {s:?}");
        }
        // Evenly spread: 720 in tiles of at most 256 needs 4, each 204 (not 3 of 256 and a sliver).
        assert_eq!(tiles_1d(720, 256, 32), (204, vec![0, 172, 344, 516]));
    }
}
