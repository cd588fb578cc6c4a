//! `pipeline deblur`: runs a trained network over a video or a folder of images, frame by
//! frame, in tiles with overlapping, blended seams, in bounded memory.
//!
//! The network takes encoded sRGB values in [0, 1] (as the training pairs are written), so frames
//! go in as decoded. Audio is not copied (the report says so).
//!
//! Files: `mod.rs` (the command, its settings, report and output rules), `images.rs` (images and
//! folders, each written back in its own format), `video.rs`.

mod images;
#[cfg(feature = "ffmpeg")]
mod video;

pub use images::{burst_files, images, images_at, IMAGE_EXTENSIONS};
#[cfg(feature = "ffmpeg")]
pub use video::video;

use super::ConfigArgs;
use crate::io::{png as png_io, write_atomic};
use crate::model::infer::Tiling;
use crate::optics::CameraKind;
use crate::{Error, Result};
use clap::Args;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The default deblur file, embedded.
pub const DEBLUR_TOML: &str = include_str!("../../../pipelines/deblur.toml");

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
        let t = Tiling::default();
        DeblurConfig { model: String::new(), tile: t.tile, overlap: t.overlap, lossless: false }
    }
}

impl DeblurFile {
    /// Parses a deblur file (after `--set`), checking every value.
    ///
    /// # Errors
    /// An unknown key or a bad value, named.
    pub fn from_table(table: toml::Table, origin: &str) -> Result<DeblurFile> {
        let f: DeblurFile = toml::Value::Table(table).try_into().map_err(Error::toml(origin, None))?;
        f.deblur.check("deblur")?;
        Ok(f)
    }
}

impl DeblurConfig {
    /// The values' rules, for the file's keys (`deblur.tile`, prefix `deblur`) and the flags that
    /// override them (`--tile`, prefix `""` and the keys `--tile`, `--overlap`) alike.
    ///
    /// # Errors
    /// Every broken rule, each naming its key (under `prefix`).
    pub fn check(&self, prefix: &str) -> Result<()> {
        let mut c = crate::checks::Checker::new(prefix);
        let (tile, overlap) = if prefix.is_empty() { ("--tile", "--overlap") } else { ("tile", "overlap") };
        c.range_usize(tile, self.tile, 16, 8192);
        if self.overlap * 2 > self.tile {
            c.fail(overlap, format!("{} is more than half the tile ({})", self.overlap, self.tile));
        }
        if c.errors.is_empty() {
            Ok(())
        } else {
            Err(Error::Config(c.errors))
        }
    }
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
    /// Images written in another format than their own (alpha dropped, 16 bits to 8, ...: the
    /// output format could not keep it), and what changed.
    pub changed: Vec<Changed>,
    /// Stopped by SIGINT or SIGTERM after `frames` images, each written whole.
    pub interrupted: bool,
    /// `--burst K`: the times (fractions of each capture's exposure) of the K outputs per
    /// capture, in order; absent for one output per capture.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub burst_times: Option<Vec<f32>>,
    /// A video with a variable frame rate: the most, in milliseconds, that a frame was moved
    /// from its own time to its place at the constant output rate (absent: constant rate).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub retimed_ms: Option<f64>,
}

#[derive(Debug, serde::Serialize)]
pub struct Changed {
    pub path: String,
    pub what: String,
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
            provenance: crate::provenance::Provenance::started_ago(t0.elapsed()),
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
            changed: Vec::new(),
            interrupted: false,
            burst_times: None,
            retimed_ms: None,
        }
    }
}

/// Where a file is written before it is renamed into place (same folder, ending in the same
/// extension, so FFmpeg picks the same container; removed at the next start if the run is killed).
#[cfg(feature = "ffmpeg")]
pub(super) fn temp_for(path: &Path) -> PathBuf {
    let name = path.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = path.extension().map(|s| s.to_string_lossy().into_owned());
    path.with_file_name(crate::io::temp_name(&name, ext.as_deref()))
}

/// Removes the temporaries killed deblur runs left for the files `targets` (this machine,
/// process gone), and nothing else in their folders.
pub(super) fn remove_stale(targets: &[PathBuf]) {
    for p in crate::io::remove_stale_for(targets) {
        eprintln!("removed {} (left by a run that was killed)", p.display());
    }
}

/// The encoded value in [0, 1] that the network sees for channel `c` (R, G, B) of pixel `i` of
/// decoded frame data: 8-bit and 16-bit samples scaled, float (OpenEXR, linear light when
/// `float_linear`) clamped and sRGB-encoded. Not for patch-mode regions.
pub(super) fn encoded_sample(data: &crate::frame::FrameData, float_linear: bool, i: usize, c: usize) -> f32 {
    use crate::frame::FrameData;
    match data {
        FrameData::Planar8(p) => p[c][i] as f32 / 255.0,
        FrameData::Planar16(p) => p[c][i] as f32 / 65535.0,
        FrameData::Planar(p) if float_linear => png_io::srgb_encode(p[c][i]),
        FrameData::Planar(p) => p[c][i].clamp(0.0, 1.0),
        FrameData::Regions8(_) => unreachable!("only patch-mode decoding makes regions"),
    }
}

/// Interleaved 8-bit encoded RGB of a decoded frame; float frames (OpenEXR) are linear light
/// and are sRGB-encoded first, as the network sees encoded values.
pub fn to_rgb8(f: &crate::frame::Frame, float_linear: bool) -> Vec<u8> {
    use crate::frame::FrameData;
    let n = f.width * f.height;
    match &*f.data {
        FrameData::Planar8(p) => (0..n).flat_map(|i| [p[0][i], p[1][i], p[2][i]]).collect(),
        FrameData::Regions8(regions) => {
            // Only patch-mode decoding makes these; the rectangles over black.
            let mut out = vec![0u8; n * 3];
            for r in regions {
                for y in 0..r.h {
                    for x in 0..r.w {
                        let i = (r.y0 + y) * f.width + r.x0 + x;
                        (0..3).for_each(|c| out[i * 3 + c] = r.planes[c][y * r.w + x]);
                    }
                }
            }
            out
        }
        data => (0..n * 3).map(|k| (encoded_sample(data, float_linear, k / 3, k % 3) * 255.0).round() as u8).collect(),
    }
}

/// What `deblur` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutKind {
    Video,
    Image,
    Folder,
}

/// The output's kind, from its extension (or an existing folder), checked against the input's: a
/// video becomes a video, one image an image or a folder, a folder or glob of images a folder.
///
/// # Errors
/// A usage error naming the output: an unknown extension, or a kind the input cannot become.
pub fn output_kind(input: &Path, output: &Path) -> Result<OutKind> {
    let ext = output.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let out = if output.is_dir() {
        OutKind::Folder
    } else {
        match ext.as_deref() {
            None => OutKind::Folder,
            Some(e) if IMAGE_EXTENSIONS.contains(&e) => OutKind::Image,
            Some(e) if crate::stage::input::VIDEO_EXTS.contains(&e) => OutKind::Video,
            Some(e) => {
                return Err(Error::Usage(format!(
                    "{}: .{e} is neither an image ({}) nor a video ({}) extension; a folder has none",
                    output.display(),
                    IMAGE_EXTENSIONS.join(", "),
                    crate::stage::input::VIDEO_EXTS.join(", ")
                )))
            }
        }
    };
    if out == OutKind::Folder && output.is_file() {
        return Err(Error::Usage(format!("{}: a file, and the output has no extension, so it names a folder", output.display())));
    }
    let images = input.is_dir() || input.to_string_lossy().contains('*');
    let one_image = !images && image_ext(input).is_some();
    let (what, ok, want) = match (images, one_image) {
        (true, _) => ("a folder of images", out == OutKind::Folder, "a folder (no extension)"),
        (false, true) => ("an image", out != OutKind::Video, "an image file or a folder"),
        (false, false) => ("a video", out == OutKind::Video, "a video file (.mp4, .mkv, ...)"),
    };
    if !ok {
        let was = match out {
            OutKind::Video => "a video",
            OutKind::Image => "an image",
            OutKind::Folder => "a folder",
        };
        return Err(Error::Usage(format!("{}: the input is {what} and this output names {was}; give {want}", output.display())));
    }
    Ok(out)
}

/// The lower-case extension of `p` when it is one of [`IMAGE_EXTENSIONS`].
pub fn image_ext(p: &Path) -> Option<String> {
    let e = p.extension()?.to_str()?.to_ascii_lowercase();
    IMAGE_EXTENSIONS.contains(&e.as_str()).then_some(e)
}

/// The inputs of a run from `input`: the video or image, or the images of a folder or glob.
fn inputs_of(input: &Path, kind: OutKind) -> Result<Vec<PathBuf>> {
    if kind == OutKind::Video || (kind == OutKind::Image && !input.is_dir()) {
        return Ok(vec![input.to_path_buf()]);
    }
    crate::io::paths::expand_paths(&[input.display().to_string()], &IMAGE_EXTENSIONS)
}

/// The files a run writes at `out` for `inputs`, its report included: the video or image, or the
/// folder's images of the inputs' names.
fn outputs_of(inputs: &[PathBuf], out: &Path, kind: OutKind, burst: Option<usize>) -> Vec<PathBuf> {
    match kind {
        OutKind::Folder => {
            let mut v: Vec<PathBuf> = match burst {
                Some(k) => inputs.iter().flat_map(|f| burst_files(out, f, k)).collect(),
                None => inputs.iter().filter_map(|f| f.file_name()).map(|n| out.join(n)).collect(),
            };
            v.push(out.join("report.json"));
            v
        }
        _ => vec![out.to_path_buf(), PathBuf::from(format!("{}.report.json", out.display()))],
    }
}

/// The outputs an earlier run left that this one would replace (the report aside). None for a
/// folder whose report says its run was interrupted: rerunning it is how it is finished.
fn would_replace(outputs: &[PathBuf], out: &Path, kind: OutKind) -> Vec<PathBuf> {
    if kind == OutKind::Folder {
        let report = std::fs::read(out.join("report.json")).ok().and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok());
        if report.is_some_and(|r| r["interrupted"] == true) {
            return Vec::new();
        }
    }
    outputs.iter().filter(|p| !p.ends_with("report.json") && !p.to_string_lossy().ends_with(".report.json")).cloned().collect()
}

/// Writes the report beside the output.
///
/// # Errors
/// It cannot be written.
pub fn write_report(path: &Path, r: &DeblurReport) -> Result<()> {
    let bytes = serde_json::to_vec_pretty(r).expect("json");
    write_atomic(path, |w| w.write_all(&bytes))
}

#[derive(Args, Debug)]
pub struct DeblurArgs {
    /// A video FFmpeg reads, one image, or a folder (or glob) of PNG, JPEG, TIFF or OpenEXR images.
    pub input: PathBuf,
    /// Output video (.mp4, .mkv, .mov...), image (for one image: its format from the extension) or folder.
    #[arg(short, long)]
    pub out: PathBuf,
    /// A model written by `pipeline train`; default: the shipped U-Net 32 of `--camera`.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Which camera made the input, when no --model is given: `phase_coded` (default; the
    /// coloured streaks of the coded camera) or `conventional` (ordinary motion blur: the shipped
    /// U-Net 32 trained on the conventional camera).
    #[arg(long, conflicts_with = "model", value_parser = ["phase_coded", "conventional"])]
    pub camera: Option<String>,
    /// Tile size in pixels (frames are processed in tiles with blended seams); default 1280 (a 720p frame in one pass; smaller tiles use less memory).
    #[arg(long)]
    pub tile: Option<usize>,
    /// Overlap between tiles in pixels; default 64 (the U-Net sees about 100 px around a pixel).
    #[arg(long)]
    pub overlap: Option<usize>,
    /// Lossless output (FFV1 RGB in .mkv) instead of H.264.
    #[arg(long)]
    pub lossless: bool,
    /// K sharp frames per capture, in time order (2 to 64; 9 = the sub-frames of a 9-frame
    /// window): an image `a.png` gives OUTPUT/a/00.png ... OUTPUT/a/{K-1}.png, a video comes back
    /// at K times its frame rate. Needs a burst model (default: the shipped coded one).
    #[arg(long, value_name = "K")]
    pub burst: Option<usize>,
    /// Replace what an earlier run wrote at the output (refused otherwise; a folder whose report
    /// says the run was interrupted is carried on without it).
    #[arg(long)]
    pub overwrite: bool,
    #[command(flatten)]
    pub file: ConfigArgs,
}

/// The usage errors of the paths, found before anything is made: `--burst` out of range, the
/// output being the input, an input that names nothing, `--burst` into one image file. Returns
/// the kind of output.
fn check_paths(input: &Path, out: &Path, burst: Option<usize>) -> Result<OutKind> {
    if let Some(k) = burst.filter(|k| !(2..=64).contains(k)) {
        return Err(Error::Usage(format!("--burst {k}: the number of frames per capture must be 2 to 64")));
    }
    let same = input.canonicalize().ok().zip(out.canonicalize().ok()).is_some_and(|(a, b)| a == b) || input == out;
    if same {
        return Err(Error::Usage(format!("{}: the output is the input; choose another output path", out.display())));
    }
    // A path that names nothing (and is no glob) is a usage error, before any output folder is
    // made.
    if !input.to_string_lossy().contains('*') && std::fs::symlink_metadata(input).is_err() && input != Path::new("-") {
        return Err(Error::Usage(format!("{}: no such file or folder", input.display())));
    }
    let kind = output_kind(input, out)?;
    if burst.is_some() && kind == OutKind::Image {
        return Err(Error::Usage(format!(
            "{}: --burst writes a folder per image (OUTPUT/{{name}}/00.png ...); give a folder, not an image file",
            out.display()
        )));
    }
    Ok(kind)
}

/// Runs `pipeline deblur`.
///
/// # Errors
/// Whatever the command reports (exit codes in `main.rs`).
pub fn command(a: DeblurArgs) -> anyhow::Result<()> {
    let DeblurArgs { input, out, model, camera, tile, overlap, lossless, burst, overwrite, file } = a;
    let camera = camera.map(|c| if c == "conventional" { CameraKind::Conventional } else { CameraKind::PhaseCoded });
    let kind = check_paths(&input, &out, burst)?;
    let inputs = inputs_of(&input, kind)?;
    let outputs = outputs_of(&inputs, &out, kind, burst);
    crate::io::paths::refuse_replacing_inputs(&outputs, &inputs)?;
    crate::io::paths::refuse_replacing(&out, &would_replace(&outputs, &out, kind), overwrite)?;
    let (table, origin) = file.load(crate::commands::deblur::DEBLUR_TOML, "pipelines/deblur.toml")?;
    let mut d = crate::commands::deblur::DeblurFile::from_table(table, &origin)?.deblur;
    d.tile = tile.unwrap_or(d.tile);
    d.overlap = overlap.unwrap_or(d.overlap);
    // The flags obey the keys' rules (`--tile 0` is refused as `tile = 0` is).
    if tile.is_some() || overlap.is_some() {
        d.check("")?;
    }
    let lossless = lossless || d.lossless;
    // --camera names a shipped model: it stands in for the settings file's `model` too.
    let model = model.or_else(|| (camera.is_none() && !d.model.is_empty()).then(|| PathBuf::from(&d.model)));
    let (net, name) = crate::model::infer::load_for(model.as_deref(), camera, burst.is_some())?;
    let times: Option<Vec<f32>> = burst.map(|k| (0..k).map(|i| (i as f32 + 0.5) / k as f32).collect());
    let times = times.as_deref();
    let tiling = crate::model::infer::Tiling { tile: d.tile, overlap: d.overlap };
    let bar = file.progress;
    if let Some(parent) = out.parent().filter(|p| !p.as_os_str().is_empty() && kind != OutKind::Folder) {
        if let Some(file) = parent.ancestors().find(|a| a.is_file()) {
            return Err(Error::Usage(format!("{}: {} is a file, not a folder", out.display(), file.display())).into());
        }
        std::fs::create_dir_all(parent).map_err(|e| Error::Io { path: parent.to_path_buf(), cause: e })?;
    }
    let r = match kind {
        #[cfg(feature = "ffmpeg")]
        OutKind::Video => crate::commands::deblur::video(&net, &name, &input, &out, tiling, lossless, bar, times)?,
        #[cfg(not(feature = "ffmpeg"))]
        OutKind::Video => {
            let _ = lossless;
            return Err(Error::Usage(format!("{}: videos need a build with the `ffmpeg` feature", input.display())).into());
        }
        OutKind::Folder | OutKind::Image => crate::commands::deblur::images_at(&net, &name, &input, &out, tiling, bar, times)?,
    };
    let mut r = r;
    r.burst_times = times.map(<[f32]>::to_vec);
    let rp = if kind == OutKind::Folder { out.join("report.json") } else { PathBuf::from(format!("{}.report.json", out.display())) };
    crate::commands::deblur::write_report(&rp, &r)?;
    if r.interrupted {
        return Err(Error::Interrupted(format!(
            "{}: {} images written whole before the signal ({} records them); run the same command again for the rest",
            out.display(),
            r.frames,
            rp.display()
        ))
        .into());
    }
    if r.frames == 0 && !r.failed.is_empty() {
        eprintln!("nothing deblurred with {} -> {}", r.model, out.display());
    } else {
        let (n, w, h, s, fps) = (r.frames, r.width, r.height, r.seconds, r.frames_per_s);
        eprintln!("{n} frames of {w}x{h} in {s:.1} s ({fps:.2} frames/s) with {} -> {}", r.model, out.display());
    }
    if !r.failed.is_empty() {
        return Err(crate::Error::InputsFailed { n: r.failed.len(), report: rp }.into());
    }
    Ok(())
}
