//! `pipeline eval`: the paper's Table 1 on your own footage. Test windows of N frames (7, 9, 11
//! and 13 by default) centred on the same sharp frames, blurred by a camera, with AWGN of each
//! sigma (0 to 3), deblurred by a model, and scored against the sharp middle frame next to the
//! blurred input's own score (PSNR/SSIM, RGB and Y, 8-bit sRGB, [`crate::metrics::CONVENTION`]).
//!
//! Windows of every length share their centre frame, so the rows of the table differ only in
//! the length of the motion, and every sigma of a window shares the same noise pattern (scaled),
//! so the columns differ only in the noise level.

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
        let mut errs = c.errors;
        errs.extend(self.camera.validate("camera"));
        errs.extend(self.optics.validate("optics"));
        errs
    }

    /// Reads an eval file, with `--set` overrides.
    ///
    /// # Errors
    /// Unreadable, not TOML, an unknown key or a bad value (named).
    pub fn from_table(table: toml::Table, origin: &str) -> Result<EvalFile> {
        let f: EvalFile = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| Error::ConfigText(format!("{origin}: {}", e.to_string().trim())))?;
        let errs = f.validate();
        if !errs.is_empty() {
            return Err(Error::Config(errs));
        }
        Ok(f)
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

/// Layout of the side-by-side PNGs: a label bar of `LABEL_H` pixels on top, then the blurred,
/// deblurred and sharp panels, each `GAP` pixels apart.
pub const LABEL_H: usize = 14;
pub const GAP: usize = 4;

fn mean_quality(q: &[&Quality]) -> Quality {
    let n = q.len().max(1) as f64;
    Quality {
        psnr_rgb: q.iter().map(|v| v.psnr_rgb).sum::<f64>() / n,
        ssim_rgb: q.iter().map(|v| v.ssim_rgb).sum::<f64>() / n,
        psnr_y: q.iter().map(|v| v.psnr_y).sum::<f64>() / n,
        ssim_y: q.iter().map(|v| v.ssim_y).sum::<f64>() / n,
    }
}

fn cell(records: &[Record], video: Option<&str>, window: usize, sigma: Option<f64>) -> Cell {
    let sel: Vec<&Record> =
        records.iter().filter(|r| r.window == window && sigma.is_none_or(|s| r.sigma == s) && video.is_none_or(|v| r.video == v)).collect();
    Cell {
        video: video.map(str::to_string),
        window,
        sigma,
        count: sel.len(),
        blurred: mean_quality(&sel.iter().map(|r| &r.blurred).collect::<Vec<_>>()),
        deblurred: mean_quality(&sel.iter().map(|r| &r.deblurred).collect::<Vec<_>>()),
        bound: {
            let b: Vec<&Quality> = sel.iter().filter_map(|r| r.bound.as_ref()).collect();
            (!b.is_empty()).then(|| (mean_quality(&b), b.len()))
        },
    }
}

/// The region scored in a `w x h` frame: a centred square of `crop`, or the whole frame.
pub(crate) fn region(w: usize, h: usize, crop: usize) -> [usize; 4] {
    if crop == 0 || (crop >= w && crop >= h) {
        return [0, 0, w, h];
    }
    let (cw, ch) = (crop.min(w), crop.min(h));
    [(w - cw) / 2, (h - ch) / 2, cw, ch]
}

/// Draws blurred | deblurred | sharp with their PSNR above.
fn side_by_side(path: &Path, w: usize, h: usize, panels: [&[u8]; 3], labels: [String; 3]) -> Result<()> {
    let mut canvas = Canvas::new(3 * w + 2 * GAP, LABEL_H + h, [1.0; 3]);
    for (i, (rgb, label)) in panels.into_iter().zip(labels).enumerate() {
        canvas.draw_panel((i * (w + GAP), 0), LABEL_H, w, &Panel::from_rgb8(label, w, h, rgb), 1);
    }
    canvas.save(path)
}

/// Decodes the frames `first..=last` of a video (stopping early at its end), tagged linear.
pub(crate) fn read_frames(path: &Path, first: u64, last: u64, curve: Curve) -> Result<Vec<Arc<Frame>>> {
    let mut reader = VideoReader::open(path).map_err(Error::video(path))?;
    if reader.info.fps > 0.0 && reader.info.fps < crate::stage::decode::SLOW_FPS {
        eprintln!("warning: {}", crate::stage::decode::slow_footage(path, reader.info.fps));
    }
    let mut out = Vec::new();
    let mut i = 0u64;
    while i <= last {
        let Some(f) = reader.next_frame().map_err(Error::video(path))? else { break };
        if i >= first {
            out.push(Arc::new(Frame { curve: Some(curve), ..f }));
        }
        i += 1;
    }
    Ok(out)
}

/// What every window of an evaluation shares: the camera's light throughput, the longest window
/// and its half, the frames between centres, a blurrer per window length, the encoder and tiling.
pub(crate) struct Setup {
    pub throughput: f64,
    pub maxn: usize,
    pub half: u64,
    pub spacing: u64,
    pub blurrers: Vec<Blurrer>,
    pub enc: Encoder,
    pub tiling: Tiling,
}

impl Setup {
    /// # Errors
    /// A camera whose kernels cannot be made.
    pub(crate) fn new(f: &EvalFile) -> Result<Setup> {
        let e = &f.eval;
        let camera = Arc::new(Camera::new(&f.optics, &f.camera));
        let maxn = *e.windows.iter().max().expect("validated non-empty");
        Ok(Setup {
            throughput: camera.light_throughput(),
            maxn,
            half: (maxn / 2) as u64,
            spacing: if e.spacing == 0 { maxn } else { e.spacing } as u64,
            blurrers: e.windows.iter().map(|&n| Blurrer::new(camera.clone(), n, e.threads, e.max_error)).collect::<Result<Vec<_>>>()?,
            enc: Encoder::new(e.curve),
            tiling: Tiling { tile: e.tile, overlap: e.overlap },
        })
    }

    /// The frames of `path` every window of `e` reads (after `e.skip`), tagged linear.
    ///
    /// # Errors
    /// The video cannot be read, or holds fewer frames than one window of the longest length.
    pub(crate) fn frames(&self, path: &Path, e: &EvalConfig) -> Result<Vec<Arc<Frame>>> {
        let first = e.skip as u64;
        let last = first + 2 * self.half + self.spacing * (e.windows_per_video as u64 - 1);
        let frames = read_frames(path, first, last, e.curve)?;
        if (frames.len() as u64) < 2 * self.half + 1 {
            return Err(Error::File {
                path: path.to_path_buf(),
                why: format!("{} frames after skipping {}, fewer than one window of {}", frames.len(), e.skip, self.maxn),
            });
        }
        Ok(frames)
    }
}

/// Runs the evaluation and writes `eval.json`, `eval.md` and `examples/` under `out`.
///
/// # Errors
/// A video that cannot be read or is too short for one window of the longest length (named),
/// an output that cannot be written.
pub fn run(
    f: &EvalFile,
    net: &FastNet,
    model: &str,
    videos: &[String],
    out: &Path,
    progress: crate::progress::ProgressMode,
) -> Result<EvalReport> {
    let t0 = Instant::now();
    let e = &f.eval;
    let paths = expand_paths(videos, crate::stage::input::VIDEO_EXTS)?;
    crate::io::make_dir_in(out, Path::new("examples"))?;
    let mut s = Setup::new(f)?;
    let (throughput, half, spacing, tiling) = (s.throughput, s.half, s.spacing, s.tiling);
    let total = (paths.len() * e.windows_per_video * e.windows.len() * e.sigmas.len()) as u64;
    let bar = crate::progress::Bar::new(progress, "eval", "windows", Some(total));
    let top_sigma = e.sigmas.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut records = Vec::new();
    // Examples spread evenly over the videos (different content, not N after N of the first
    // clip), each at its video's first sharp frame and the largest sigma: the middle window
    // length, then the next ones where a video gets more than one.
    let mut example_slots: Vec<(usize, usize)> = Vec::new();
    for i in 0..e.examples {
        let vi = i * paths.len() / e.examples;
        let earlier = example_slots.iter().filter(|s| s.0 == vi).count();
        example_slots.push((vi, e.windows[(e.windows.len() / 2 + earlier) % e.windows.len()]));
    }
    let mut reg = [0; 4];
    for (vi, path) in paths.iter().enumerate() {
        let first = e.skip as u64;
        let frames = s.frames(path, e)?;
        let (w, h) = (frames[0].width, frames[0].height);
        reg = region(w, h, e.crop);
        let [rx, ry, rw, rh] = reg;
        if rw < 11 || rh < 11 {
            return Err(Error::File { path: path.to_path_buf(), why: format!("{w}x{h} is too small to score (SSIM needs 11x11)") });
        }
        let video = path.display().to_string();
        let log = crate::imaging::truth::MotionLog::read(path)?;
        let centres = (0..e.windows_per_video as u64).map(|k| half + k * spacing).take_while(|&c| c + half < frames.len() as u64);
        for (ci, c) in centres.enumerate() {
            let mid = &frames[c as usize];
            let sharp = to_8bit(&mid.linear_crop(rx, ry, rw, rh), rw, rh, e.curve);
            for (ni, &n) in e.windows.iter().enumerate() {
                let start = (c - (n / 2) as u64) as usize;
                let blur = s.blurrers[ni].blur_region(&frames[start..start + n], rx as isize, ry as isize, rw, rh);
                let key = hash(&[f.seed, vi as u64, first + c, n as u64, hash_str("eval-noise")]);
                let motion = log.as_ref().and_then(|l| l.kind(first + c)).map(str::to_string);
                // The window's true kernel, where its motion is a known translation of the frame.
                let truth = log
                    .as_ref()
                    .and_then(|l| l.shifts(first + start as u64, n, first + c))
                    .map(|sh| (crate::imaging::truth::window_kernel(&mut s.blurrers[ni], &sh).0, mid.linear_crop(rx, ry, rw, rh)));
                for &sigma in &e.sigmas {
                    let blurred = read_out(&blur, (rx, ry, rw, rh), &s.enc, sigma, throughput, key);
                    let deblurred = run_frame(net, &blurred, rw, rh, tiling);
                    let (qb, qd) = (quality(&blurred, &sharp, rw, rh), quality(&deblurred, &sharp, rw, rh));
                    let bound = truth.as_ref().map(|(k, lin)| {
                        let var = crate::imaging::truth::linear_noise_var(lin, e.curve, crate::imaging::sensor_sigma(sigma, throughput));
                        let rec: [Vec<f32>; 3] =
                            std::array::from_fn(|ch| crate::recon::wiener_bound(&lin[ch], rw, rh, &k[ch], var[ch], key ^ ch as u64).1);
                        quality(&to_8bit(&rec, rw, rh, e.curve), &sharp, rw, rh)
                    });
                    let example = (ci == 0 && sigma == top_sigma && example_slots.contains(&(vi, n))).then(|| {
                        let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
                        format!("examples/{vi:02}-{stem}-f{:05}-n{n:02}-s{sigma}.png", first + c)
                    });
                    if let Some(name) = &example {
                        side_by_side(
                            &out.join(name),
                            rw,
                            rh,
                            [&blurred, &deblurred, &sharp],
                            [
                                format!("N={n} SIGMA={sigma} IN {:.2} DB", qb.psnr_rgb),
                                format!("DEBLURRED {:.2} DB", qd.psnr_rgb),
                                format!("SHARP FRAME {}", first + c),
                            ],
                        )?;
                    }
                    records.push(Record {
                        video: video.clone(),
                        frame: first + c,
                        window: n,
                        sigma,
                        blurred: qb,
                        deblurred: qd,
                        motion: motion.clone(),
                        bound,
                        example,
                    });
                    bar.inc(1);
                    bar.set_message(format!("{} N={n} sigma={sigma}", path.file_name().unwrap_or_default().to_string_lossy()));
                }
            }
        }
    }
    bar.finish();
    let table = e.windows.iter().map(|&n| cell(&records, None, n, None)).collect();
    let per_sigma =
        e.windows.iter().flat_map(|&n| e.sigmas.iter().map(move |&s| (n, s))).map(|(n, s)| cell(&records, None, n, Some(s))).collect();
    let mut videos: Vec<&str> = Vec::new();
    for r in &records {
        if !videos.contains(&r.video.as_str()) {
            videos.push(&r.video);
        }
    }
    let per_video = videos.iter().flat_map(|v| e.windows.iter().map(|&n| cell(&records, Some(v), n, None))).collect();
    let report = EvalReport {
        version: env!("CARGO_PKG_VERSION"),
        model: model.into(),
        camera: f.camera.kind.name().into(),
        convention: crate::metrics::CONVENTION,
        config: f.clone(),
        videos: paths.iter().map(|p| p.display().to_string()).collect(),
        region: reg,
        seconds: t0.elapsed().as_secs_f64(),
        table,
        per_sigma,
        per_video,
        records,
        versus: None,
    };
    let json = serde_json::to_vec_pretty(&report).expect("json");
    write_atomic(&out.join("eval.json"), |w| w.write_all(&json))?;
    let md = markdown(&report);
    write_atomic(&out.join("eval.md"), |w| w.write_all(md.as_bytes()))?;
    Ok(report)
}

fn pair(q: &Quality, y: bool) -> String {
    if y {
        format!("{:.2} / {:.4}", q.psnr_y, q.ssim_y)
    } else {
        format!("{:.2} / {:.4}", q.psnr_rgb, q.ssim_rgb)
    }
}

fn rows(cells: &[Cell], with_sigma: bool, versus: Option<&Versus>) -> String {
    let with_video = cells.iter().any(|c| c.video.is_some());
    let with_bound = cells.iter().any(|c| c.bound.is_some());
    let mut s = String::new();
    s.push_str(if with_video { "| video " } else { "" });
    s.push_str(if with_sigma { "| N | sigma " } else { "| N " });
    s.push_str("| blurred input (RGB) | deblurred (RGB) | gain dB | blurred input (Y) | deblurred (Y) | gain dB | windows ");
    if with_bound {
        s.push_str("| Wiener, true kernel (RGB) | its gain dB | share of it reached ");
    }
    if let Some(v) = versus {
        s.push_str(&format!("| output minus {} output dB ", v.camera));
    }
    s.push_str("|\n");
    s.push_str(if with_video { "|---" } else { "" });
    s.push_str(if with_sigma { "|---|---" } else { "|---" });
    s.push_str("|---|---|---|---|---|---|---");
    s.push_str(if with_bound { "|---|---|---" } else { "" });
    s.push_str(if versus.is_some() { "|---" } else { "" });
    s.push_str("|\n");
    for c in cells {
        if let Some(v) = &c.video {
            s.push_str(&format!("| {} ", Path::new(v).file_name().map_or(v.clone(), |f| f.to_string_lossy().into_owned())));
        }
        s.push_str(&format!("| N={} ", c.window));
        if with_sigma {
            s.push_str(&format!("| {} ", c.sigma.unwrap_or(f64::NAN)));
        }
        s.push_str(&format!(
            "| {} | {} | {:+.2} | {} | {} | {:+.2} | {} ",
            pair(&c.blurred, false),
            pair(&c.deblurred, false),
            c.deblurred.psnr_rgb - c.blurred.psnr_rgb,
            pair(&c.blurred, true),
            pair(&c.deblurred, true),
            c.deblurred.psnr_y - c.blurred.psnr_y,
            c.count
        ));
        if with_bound {
            match &c.bound {
                Some((b, n)) => {
                    let (gain, got) = (b.psnr_rgb - c.blurred.psnr_rgb, c.deblurred.psnr_rgb - c.blurred.psnr_rgb);
                    let share = if gain > 0.05 { format!("{:.0}%", 100.0 * got / gain) } else { "-".into() };
                    s.push_str(&format!("| {} ({n}) | {gain:+.2} | {share} ", pair(b, false)));
                }
                None => s.push_str("| - | - | - "),
            }
        }
        if let Some(v) = versus {
            match v.psnr_rgb.iter().find(|(n, _)| *n == c.window).filter(|_| c.video.is_none() && c.sigma.is_none()) {
                Some((_, o)) => s.push_str(&format!("| {:+.2} ", c.deblurred.psnr_rgb - o)),
                None => s.push_str("| "),
            }
        }
        s.push_str("|\n");
    }
    s
}

/// `eval.md`: Table 1 (mean over sigma) and the per-sigma tables, PSNR dB / SSIM.
pub fn markdown(r: &EvalReport) -> String {
    let sig: Vec<String> = r.config.eval.sigmas.iter().map(|s| s.to_string()).collect();
    let mut s = format!(
        "# pipeline eval\n\nModel: {}  \nCamera: {}  \nVideos: {}  \nScored region: {}x{} at ({}, {})  \nMetrics: {}\n\n",
        r.model,
        r.camera,
        r.videos.join(", "),
        r.region[2],
        r.region[3],
        r.region[0],
        r.region[1],
        r.convention
    );
    s.push_str(&format!("## Table 1 layout: PSNR dB / SSIM, mean over sigma in {{{}}}\n\n", sig.join(", ")));
    s.push_str(&rows(&r.table, false, r.versus.as_ref()));
    s.push_str("\n## Per noise level\n\n");
    s.push_str(&rows(&r.per_sigma, true, None));
    s.push_str(&format!("\n## Per video: mean over sigma in {{{}}}\n\n", sig.join(", ")));
    s.push_str(&rows(&r.per_video, false, None));
    let ex: Vec<&str> = r.records.iter().filter_map(|x| x.example.as_deref()).collect();
    if !ex.is_empty() {
        s.push_str("\n## Examples (blurred | deblurred | sharp)\n\n");
        for e in ex {
            s.push_str(&format!("![{e}]({e})\n"));
        }
    }
    s
}

/// The default eval file, embedded.
pub const EVAL_TOML: &str = include_str!("../../pipelines/eval.toml");

#[cfg(test)]
mod tests {
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
    let mut f = crate::commands::eval::EvalFile::from_table(table, &origin)?;
    if let Some(k) = camera {
        f.camera.kind = k;
    }
    let (net, name) = crate::model::infer::load_for(model.as_deref(), Some(f.camera.kind), true)?;
    // The baseline: the camera's shipped single-frame model (none for the other cameras).
    let single = match (&baseline, f.camera.kind) {
        (Some(p), _) => Some(crate::model::infer::load(Some(p))?),
        (None, k @ (crate::optics::CameraKind::PhaseCoded | crate::optics::CameraKind::Conventional)) => {
            Some(crate::model::infer::load_for(None, Some(k), false)?)
        }
        (None, _) => None,
    };
    let r = crate::commands::eval_burst::run(&f, &net, &name, single.as_ref().map(|(n, s)| (n, s.as_str())), &videos, &out, file.progress)?;
    println!("{}", crate::commands::eval_burst::markdown(&r));
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
    let mut f = crate::commands::eval::EvalFile::from_table(table, &origin)?;
    if let Some(k) = camera {
        f.camera.kind = k;
    }
    let (net, name) = crate::model::infer::load_for(model.as_deref(), Some(f.camera.kind), false)?;
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
