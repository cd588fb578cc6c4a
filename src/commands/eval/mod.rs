//! `pipeline eval`: the paper's Table 1 on your own footage. Test windows of N frames (7, 9, 11
//! and 13 by default) centred on the same sharp frames, blurred by a camera, with AWGN of each
//! sigma (0 to 3), deblurred by a model, and scored against the sharp middle frame next to the
//! blurred input's own score (PSNR/SSIM, RGB and Y, 8-bit sRGB, [`crate::metrics::CONVENTION`]).
//!
//! Windows of every length share their centre frame, so the rows of the table differ only in
//! the length of the motion, and every sigma of a window shares the same noise pattern (scaled),
//! so the columns differ only in the noise level.
//!
//! Files: `mod.rs` (the eval file, the records, the command), `score.rs` (the windows of each
//! clip scored), `table.rs` (the markdown tables), `burst.rs` (`eval --burst`: every sub-frame).

pub mod burst;
mod score;
mod table;

pub(crate) use score::{read_frames, Setup};
pub use score::{run, GAP, LABEL_H};
pub use table::markdown;

use crate::checks::Checker;
use crate::checks::ConfigError;
use crate::frame::Frame;
use crate::imaging::blur::Blurrer;
use crate::imaging::{read_out, to_8bit};
use crate::io::paths::expand_paths;
use crate::io::video::VideoReader;
use crate::io::write_atomic;
use crate::metrics::{quality, Quality};
use crate::model::fast::FastNet;
use crate::model::infer::{run_frame, Tiling};
use crate::optics::transfer::{Curve, Encoder};
use crate::optics::{Camera, CameraConfig, OpticsConfig};
use crate::plot::{Canvas, Panel};
use crate::rng::{hash, hash_str};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

/// An eval file (`pipelines/eval.toml`): `seed`, `[eval]`, `[camera]`, `[optics]`.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EvalFile {
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub eval: EvalConfig,
    #[serde(default)]
    pub camera: CameraConfig,
    #[serde(default)]
    pub optics: OpticsConfig,
}

/// `[eval]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalConfig {
    /// Window lengths N (odd: each window is centred on its sharp frame).
    pub windows: Vec<usize>,
    /// Noise sigmas on the 0-255 scale (divided by the camera's light throughput, as in `noise`).
    pub sigmas: Vec<f64>,
    /// Sharp frames per video; each is the centre of one window of every length.
    pub windows_per_video: usize,
    /// Frames between centres (0: the longest window, so windows do not overlap).
    pub spacing: usize,
    /// Frames skipped at the start of each video.
    pub skip: usize,
    /// Side of a centred square crop to score (0: the whole frame). The blur still reads the
    /// real pixels around the crop.
    pub crop: usize,
    /// Side-by-side PNGs (blurred | deblurred | sharp) to write, spread over the videos.
    pub examples: usize,
    pub tile: usize,
    pub overlap: usize,
    pub curve: Curve,
    /// FFT worker threads for the blur (0: all cores).
    pub threads: usize,
    /// Low-rank blur error budget in 8-bit levels RMS, as the `coded_blur` stage's (0: exact).
    pub max_error: f64,
    /// A sensor's read-out before the camera response (`[eval.sensor]`): shot and read noise at
    /// one ISO, saturation, a Bayer mosaic; the AWGN of `sigmas` is added after it. Absent: the
    /// paper's ideal read-out.
    pub sensor: Option<EvalSensor>,
}

/// `[eval.sensor]`: the sensor of [`crate::imaging::sensor`] at one ISO.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalSensor {
    pub full_well: f64,
    pub read_noise: f64,
    pub iso: f64,
    /// The colour filter array (`rggb`, ...); absent: no mosaic.
    pub bayer: Option<crate::imaging::sensor::Bayer>,
    /// How the mosaic is filled in (`bilinear`, `malvar`).
    pub demosaic: crate::imaging::sensor::Demosaic,
}

impl Default for EvalSensor {
    fn default() -> Self {
        EvalSensor { full_well: 5000.0, read_noise: 3.0, iso: 800.0, bayer: None, demosaic: Default::default() }
    }
}

impl EvalConfig {
    /// The 8-bit capture of a blurred region (linear planes): through the sensor if there is
    /// one, then sigma's AWGN and the curve ([`read_out`]).
    pub fn read_out(
        &self,
        blur: &[Vec<f32>; 3],
        region: (usize, usize, usize, usize),
        enc: &crate::optics::transfer::Encoder,
        sigma: f64,
        throughput: f64,
        key: u64,
    ) -> Vec<u8> {
        match &self.sensor {
            Some(sn) => read_out(&sn.capture(blur, region, key), region, enc, sigma, throughput, key),
            None => read_out(blur, region, enc, sigma, throughput, key),
        }
    }
}

impl EvalSensor {
    /// The region's linear planes as the sensor reads them out (noise keyed by `key` and the
    /// pixel's place in the frame).
    pub fn capture(&self, planes: &[Vec<f32>; 3], (x, y, w, h): (usize, usize, usize, usize), key: u64) -> [Vec<f32>; 3] {
        let s = crate::imaging::sensor::Sensor {
            full_well: self.full_well,
            read_noise: self.read_noise,
            gain: self.iso / crate::stage::sensor::BASE_ISO,
            demosaic: self.demosaic,
        };
        s.capture(planes, w, h, (x, y), self.bayer, crate::rng::hash(&[key, crate::rng::hash_str("eval-sensor")]))
    }
}

impl Default for EvalConfig {
    fn default() -> Self {
        EvalConfig {
            windows: vec![7, 9, 11, 13],
            sigmas: vec![0.0, 1.0, 2.0, 3.0],
            windows_per_video: 4,
            spacing: 0,
            skip: 0,
            crop: 0,
            examples: 4,
            tile: 1280,
            overlap: 64,
            curve: Curve::Srgb,
            threads: 0,
            max_error: crate::stage::coded_blur::DEFAULT_MAX_ERROR,
            sensor: None,
        }
    }
}

impl EvalFile {
    /// Every value error, each naming its key.
    pub fn validate(&self) -> Vec<ConfigError> {
        let e = &self.eval;
        let mut c = Checker::new("eval");
        if e.windows.is_empty() {
            c.fail("windows", "names no window length");
        }
        for &n in &e.windows {
            c.range_usize("windows", n, 1, 63);
            if n % 2 == 0 {
                c.fail("windows", format!("{n} is even; windows are centred on their sharp middle frame, so N must be odd"));
            }
        }
        if e.sigmas.is_empty() {
            c.fail("sigmas", "names no noise level");
        }
        for &s in &e.sigmas {
            c.range("sigmas", s, 0.0, 50.0);
        }
        c.range_usize("windows_per_video", e.windows_per_video, 1, 100_000);
        c.range_usize("tile", e.tile, 16, 8192);
        if e.overlap * 2 > e.tile {
            c.fail("overlap", format!("{} is more than half the tile ({})", e.overlap, e.tile));
        }
        if e.crop != 0 {
            c.range_usize("crop", e.crop, 11, 16384);
        }
        c.range("max_error", e.max_error, 0.0, 255.0);
        if let Some(s) = &e.sensor {
            c.range("sensor.full_well", s.full_well, 10.0, 1e7);
            c.range("sensor.read_noise", s.read_noise, 0.0, 1000.0);
            c.range("sensor.iso", s.iso, 25.0, 409_600.0);
        }
        let mut errs = c.errors;
        errs.extend(self.camera.validate("camera"));
        errs.extend(crate::optics::measured::check(&self.camera, "camera"));
        errs.extend(self.optics.validate("optics"));
        errs
    }

    /// Reads an eval file, with `--set` overrides.
    ///
    /// # Errors
    /// Unreadable, not TOML, an unknown key or a bad value (named).
    pub fn from_table(table: toml::Table, origin: &str) -> Result<EvalFile> {
        let f: EvalFile = toml::Value::Table(table).try_into().map_err(Error::toml(origin, None))?;
        let errs = f.validate();
        if !errs.is_empty() {
            return Err(Error::Config(errs));
        }
        Ok(f)
    }

    /// The eval file of `table` with `camera` put in, and the model it scores: `model`, else the
    /// camera's shipped one (a burst model when `burst`). The command and the Python package's
    /// `evaluate` start here.
    ///
    /// # Errors
    /// As [`EvalFile::from_table`]; a model that cannot be read or is of the wrong kind.
    pub fn with_model(
        table: toml::Table,
        origin: &str,
        camera: Option<crate::optics::CameraKind>,
        model: Option<&Path>,
        burst: bool,
    ) -> Result<(EvalFile, FastNet, String)> {
        let mut f = EvalFile::from_table(table, origin)?;
        if let Some(k) = camera {
            f.camera.kind = k;
        }
        let (net, name) = crate::model::infer::load_for(model, Some(f.camera.kind), burst)?;
        Ok((f, net, name))
    }
}

/// One scored window at one noise level.
#[derive(Debug, Clone, Serialize)]
pub struct Record {
    pub video: String,
    /// Index of the sharp (centre) frame in the video.
    pub frame: u64,
    pub window: usize,
    pub sigma: f64,
    pub blurred: Quality,
    pub deblurred: Quality,
    /// The motion of the window, where the clip's `.motion.jsonl` says it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub motion: Option<String>,
    /// The Wiener reconstruction told the true kernel ([`crate::recon::wiener_bound`]), for
    /// windows moved as a whole by translation with a known path.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bound: Option<Quality>,
    /// How far the window's path spreads the image (the distance between its two farthest
    /// positions, pixels), for windows moved as a whole by translation with a known path.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spread_px: Option<f64>,
    /// The side-by-side PNG of this record, if one was written.
    pub example: Option<String>,
}

/// Means over records.
#[derive(Debug, Clone, Serialize)]
pub struct Cell {
    /// `Some`: the records of one video only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub video: Option<String>,
    pub window: usize,
    /// `None`: the mean over every sigma (the paper's Table 1).
    pub sigma: Option<f64>,
    pub count: usize,
    pub blurred: Quality,
    pub deblurred: Quality,
    /// The mean Wiener bound over the records that have one, and their count.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bound: Option<(Quality, usize)>,
}

/// Shaking windows of one motion, N and range of spread: the mean over every sigma.
#[derive(Debug, Clone, Serialize)]
pub struct SpreadCell {
    pub motion: String,
    pub window: usize,
    /// Spread range in pixels, [from, to) (`to` infinite for the last bin).
    pub spread_px: [f64; 2],
    pub count: usize,
    pub blurred: Quality,
    pub deblurred: Quality,
    /// The mean Wiener bound told the true kernel, where every window of the bin has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub bound: Option<Quality>,
}

/// The spread bins of the shake table, pixels: 0-10, 10-20, 20-40, 40-60, 60 and more.
pub const SPREAD_BINS: [f64; 5] = [0.0, 10.0, 20.0, 40.0, 60.0];

/// `eval.json`.
#[derive(Debug, Serialize)]
pub struct EvalReport {
    pub version: &'static str,
    pub model: String,
    pub camera: String,
    pub convention: &'static str,
    pub config: EvalFile,
    pub videos: Vec<String>,
    pub region: [usize; 4],
    pub seconds: f64,
    /// Rows of Table 1: per N, the mean over all sigmas.
    pub table: Vec<Cell>,
    /// Per N and sigma.
    pub per_sigma: Vec<Cell>,
    /// Per video and N, the mean over all sigmas: which footage carries the averages.
    pub per_video: Vec<Cell>,
    /// Camera shake (`shake`, `hand`) per N and spread of the path, the mean over every sigma.
    pub per_spread: Vec<SpreadCell>,
    pub records: Vec<Record>,
    /// Another model's Table 1 on the same clips (`--versus`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub versus: Option<Versus>,
}

/// Another eval's Table 1, to compare outputs with (`--versus`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Versus {
    pub file: String,
    pub model: String,
    pub camera: String,
    /// Per N: the other model's mean output PSNR (RGB).
    pub psnr_rgb: Vec<(usize, f64)>,
}

impl Versus {
    /// # Errors
    /// A file that cannot be read or is not an eval.json (a usage error, named).
    pub fn read(p: &Path) -> Result<Versus> {
        let bad = |why: String| Error::Usage(format!("--versus {}: {why}", p.display()));
        let bytes = std::fs::read(p).map_err(|e| bad(e.to_string()))?;
        let v: serde_json::Value = serde_json::from_slice(&bytes).map_err(|e| bad(format!("not JSON ({e})")))?;
        let table = v["table"].as_array().ok_or_else(|| bad("no `table`: not an eval.json of `pipeline eval`".into()))?;
        let psnr_rgb = table
            .iter()
            .map(|c| Some((c["window"].as_u64()? as usize, c["deblurred"]["psnr_rgb"].as_f64()?)))
            .collect::<Option<Vec<_>>>()
            .ok_or_else(|| bad("a `table` row without window or deblurred.psnr_rgb".into()))?;
        Ok(Versus {
            file: p.display().to_string(),
            model: v["model"].as_str().unwrap_or("?").into(),
            camera: v["camera"].as_str().unwrap_or("?").into(),
            psnr_rgb,
        })
    }
}

/// The default eval file, embedded.
pub const EVAL_TOML: &str = include_str!("../../../pipelines/eval.toml");

#[cfg(test)]
mod tests {
    use super::score::region;
    use super::*;

    #[test]
    fn the_shipped_eval_file_is_valid_and_even_windows_are_refused() {
        let t = crate::config::parse(EVAL_TOML, "pipelines/eval.toml", &[]).unwrap();
        let f = EvalFile::from_table(t, "pipelines/eval.toml").unwrap();
        assert_eq!(f.eval.windows, vec![7, 9, 11, 13]);
        assert_eq!(f.eval.sigmas, vec![0.0, 1.0, 2.0, 3.0]);
        let t = crate::config::parse(EVAL_TOML, "x", &["eval.windows=[7, 8]".into()]).unwrap();
        let err = EvalFile::from_table(t, "x").unwrap_err().to_string();
        assert!(err.contains("eval.windows") && err.contains("8 is even"), "{err}");
        let t = crate::config::parse(EVAL_TOML, "x", &["eval.sigma=[1]".into()]).unwrap();
        let err = EvalFile::from_table(t, "x").unwrap_err().to_string();
        assert!(err.contains("sigma"), "{err}");
    }

    #[test]
    fn region_is_centred() {
        assert_eq!(region(320, 240, 0), [0, 0, 320, 240]);
        assert_eq!(region(320, 240, 128), [96, 56, 128, 128]);
        assert_eq!(region(100, 60, 80), [10, 0, 80, 60]);
    }
}

#[derive(clap::Args, Debug)]
pub struct EvalArgs {
    /// Videos (files, folders or globs) at a high frame rate: each frame is one sub-frame.
    #[arg(required = true)]
    pub videos: Vec<String>,
    /// Output folder.
    #[arg(short, long, default_value = "eval-out")]
    pub out: std::path::PathBuf,
    /// A model written by `pipeline train`; default: the camera's shipped U-Net 32 (coded or
    /// conventional; with --burst, the camera's burst U-Net).
    #[arg(long)]
    pub model: Option<std::path::PathBuf>,
    /// The camera that blurs the test windows (overrides camera.type); use the one the model
    /// was trained for.
    #[arg(long, value_enum)]
    pub camera: Option<crate::optics::CameraKind>,
    /// The eval.json of another model on the same clips (the other camera's, say): eval.md then
    /// also gives this model's output minus that one's, per N.
    #[arg(long, value_name = "EVAL_JSON")]
    pub versus: Option<std::path::PathBuf>,
    /// Replace the eval.json and eval.md an earlier run left in the output folder (refused otherwise).
    #[arg(long)]
    pub overwrite: bool,
    /// Score a burst model (`--model`): the sharp image at each sub-frame of every window against
    /// that sub-frame (first, middle, last, all), per motion kind, with the direction score;
    /// writes burst.json and burst.md.
    #[arg(long)]
    pub burst: bool,
    /// With --burst: the single-frame model repeated for every sub-frame, as the baseline
    /// (default: the camera's shipped U-Net 32, coded or conventional; none for the others).
    #[arg(long, requires = "burst")]
    pub baseline: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub file: super::ConfigArgs,
}

/// `pipeline eval --burst`.
fn command_burst(
    videos: Vec<String>,
    out: std::path::PathBuf,
    model: Option<std::path::PathBuf>,
    camera: Option<crate::optics::CameraKind>,
    baseline: Option<std::path::PathBuf>,
    overwrite: bool,
    file: super::ConfigArgs,
) -> anyhow::Result<()> {
    crate::io::paths::refuse_replacing(&out, &[out.join("burst.json"), out.join("burst.md")], overwrite)?;
    let (table, origin) = file.load(crate::commands::eval::EVAL_TOML, "pipelines/eval.toml")?;
    let (f, net, name) = EvalFile::with_model(table, &origin, camera, model.as_deref(), true)?;
    // The baseline: the camera's shipped single-frame model (none for the other cameras).
    let single = match (&baseline, f.camera.kind) {
        (Some(p), _) => Some(crate::model::infer::load(Some(p))?),
        (None, k @ (crate::optics::CameraKind::PhaseCoded | crate::optics::CameraKind::Conventional)) => {
            Some(crate::model::infer::load_for(None, Some(k), false)?)
        }
        (None, _) => None,
    };
    let r = burst::run(&f, &net, &name, single.as_ref().map(|(n, s)| (n, s.as_str())), &videos, &out, file.progress)?;
    println!("{}", burst::markdown(&r));
    eprintln!("{} windows scored in {:.0} s -> {}", r.records.len(), r.seconds, out.join("burst.md").display());
    Ok(())
}

/// Runs `pipeline eval`.
///
/// # Errors
/// Whatever the command reports (exit codes in `main.rs`).
pub fn command(a: EvalArgs) -> anyhow::Result<()> {
    let EvalArgs { videos, out, model, camera, versus, overwrite, burst, baseline, file } = a;
    if burst {
        return command_burst(videos, out, model, camera, baseline, overwrite, file);
    }
    crate::io::paths::refuse_replacing(&out, &[out.join("eval.json"), out.join("eval.md")], overwrite)?;
    // Read first: a missing or foreign file is a usage error before any work.
    let versus = versus.map(|p| Versus::read(&p)).transpose()?;
    let (table, origin) = file.load(crate::commands::eval::EVAL_TOML, "pipelines/eval.toml")?;
    let (f, net, name) = EvalFile::with_model(table, &origin, camera, model.as_deref(), false)?;
    let bar = file.progress;
    let mut r = crate::commands::eval::run(&f, &net, &name, &videos, &out, bar)?;
    if let Some(v) = versus {
        r.versus = Some(v);
        let md = markdown(&r);
        write_atomic(&out.join("eval.md"), |w| w.write_all(md.as_bytes()))?;
        let json = serde_json::to_vec_pretty(&r).expect("json");
        write_atomic(&out.join("eval.json"), |w| w.write_all(&json))?;
    }
    println!("{}", crate::commands::eval::markdown(&r));
    eprintln!("{} windows scored in {:.0} s -> {}", r.records.len(), r.seconds, out.join("eval.md").display());
    Ok(())
}
