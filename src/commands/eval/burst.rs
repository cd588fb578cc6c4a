//! `pipeline eval --burst`: how well a burst model returns every sub-frame of a capture. The
//! test windows are `pipeline eval`'s (N frames centred on the same sharp frames, each camera,
//! AWGN of each sigma); the model gives the sharp image at each of the N sub-frames' times, and
//! each is scored against its own sub-frame. Beside it: the blurred input and a single-frame
//! model's one output, each scored against every sub-frame (the baseline: a user with only a
//! deblurred still), and the direction score, the share of windows whose first and last outputs
//! are closer to the first and last sub-frames than to the last and first (50% is a coin). And
//! the true middle sub-frame itself, scored against every sub-frame: how far the ends are from
//! the middle, so the most a model blind to the time could score there even if it restored the
//! middle perfectly (the room a burst model has at the ends).

use super::EvalFile;
use crate::imaging::to_8bit;
use crate::io::paths::expand_paths;
use crate::io::write_atomic;
use crate::metrics::quality;
use crate::model::fast::FastNet;
use crate::model::infer::{run_frame, run_frame_burst};
use crate::rng::{hash, hash_str};
use crate::{Error, Result};
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// The PSNR (RGB, dB) of one way of answering a window, at each sub-frame.
#[derive(Debug, Clone, Serialize)]
pub struct PerTime {
    pub first: f64,
    pub middle: f64,
    pub last: f64,
    /// The mean over every sub-frame.
    pub all: f64,
}

impl PerTime {
    fn of(psnr: &[f64]) -> PerTime {
        let n = psnr.len();
        PerTime { first: psnr[0], middle: psnr[n / 2], last: psnr[n - 1], all: psnr.iter().sum::<f64>() / n as f64 }
    }
    fn mean(v: &[&PerTime]) -> PerTime {
        let n = v.len().max(1) as f64;
        let m = |f: fn(&PerTime) -> f64| v.iter().map(|p| f(p)).sum::<f64>() / n;
        PerTime { first: m(|p| p.first), middle: m(|p| p.middle), last: m(|p| p.last), all: m(|p| p.all) }
    }
}

/// One scored window at one noise level.
#[derive(Debug, Clone, Serialize)]
pub struct BurstRecord {
    pub video: String,
    pub frame: u64,
    pub window: usize,
    pub sigma: f64,
    /// The motion kind the clip's `.motion.jsonl` names, or "unlabelled".
    pub motion: String,
    /// The burst model's output k against sub-frame k.
    pub burst: PerTime,
    /// The single-frame model's one output against every sub-frame.
    pub single: Option<PerTime>,
    /// The blurred capture against every sub-frame.
    pub blurred: PerTime,
    /// The true middle sub-frame against every sub-frame (99 dB at the middle itself).
    pub sharp_middle: PerTime,
    /// First and last outputs closer to the first and last sub-frames than to the reverse.
    pub right_order: bool,
}

/// Means over the records of one motion kind, N and sigma.
#[derive(Debug, Clone, Serialize)]
pub struct BurstCell {
    pub motion: String,
    pub window: usize,
    pub sigma: f64,
    pub count: usize,
    pub burst: PerTime,
    pub single: Option<PerTime>,
    pub blurred: PerTime,
    pub sharp_middle: PerTime,
    /// Share of windows in the right order, in [0, 1].
    pub direction: f64,
}

/// `burst.json`.
#[derive(Debug, Serialize)]
pub struct BurstReport {
    pub version: &'static str,
    pub model: String,
    pub baseline: Option<String>,
    pub camera: String,
    pub convention: &'static str,
    pub config: EvalFile,
    pub videos: Vec<String>,
    pub seconds: f64,
    pub table: Vec<BurstCell>,
    pub records: Vec<BurstRecord>,
}

/// Sum of squared differences of two 8-bit images.
fn sq_dist(a: &[u8], b: &[u8]) -> f64 {
    a.iter().zip(b).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum()
}

/// Runs the burst evaluation and writes `burst.json` and `burst.md` under `out`.
///
/// # Errors
/// As [`super::run`].
pub fn run(
    f: &EvalFile,
    net: &FastNet,
    model: &str,
    baseline: Option<(&FastNet, &str)>,
    videos: &[String],
    out: &Path,
    progress: crate::progress::ProgressMode,
) -> Result<BurstReport> {
    let t0 = Instant::now();
    let e = &f.eval;
    let paths = expand_paths(videos, crate::stage::input::VIDEO_EXTS)?;
    std::fs::create_dir_all(out).map_err(|err| Error::Io { path: out.to_path_buf(), cause: err })?;
    let mut s = super::Setup::new(f)?;
    let (throughput, half, spacing, tiling) = (s.throughput, s.half, s.spacing, s.tiling);
    let bar = super::score::windows_bar(progress, "eval --burst", e, paths.len());
    let mut records = Vec::new();
    for (vi, path) in paths.iter().enumerate() {
        let first = e.skip as u64;
        let (frames, [rx, ry, rw, rh], log) = s.open(path, e)?;
        let centres = (0..e.windows_per_video as u64).map(|k| half + k * spacing).take_while(|&c| c + half < frames.len() as u64);
        for c in centres {
            let motion = log.as_ref().and_then(|l| l.kind(first + c)).unwrap_or("unlabelled").to_string();
            for (ni, &n) in e.windows.iter().enumerate() {
                let start = (c - (n / 2) as u64) as usize;
                let window = &frames[start..start + n];
                let sharp: Vec<Vec<u8>> = window.iter().map(|fr| to_8bit(&fr.linear_crop(rx, ry, rw, rh), rw, rh, e.curve)).collect();
                let blur = s.blurrers[ni].blur_region(window, rx as isize, ry as isize, rw, rh);
                let key = hash(&[f.seed, vi as u64, first + c, n as u64, hash_str("eval-noise")]);
                let times: Vec<f32> = (0..n).map(|k| (k as f32 + 0.5) / n as f32).collect();
                for &sigma in &e.sigmas {
                    let blurred = e.read_out(&blur, (rx, ry, rw, rh), &s.enc, sigma, throughput, key);
                    let outs = run_frame_burst(net, &blurred, rw, rh, tiling, &times);
                    let psnr = |img: &[u8], k: usize| quality(img, &sharp[k], rw, rh).psnr_rgb.min(99.0);
                    let burst: Vec<f64> = (0..n).map(|k| psnr(&outs[k], k)).collect();
                    // One image against every sub-frame.
                    let against_all = |img: &[u8]| PerTime::of(&(0..n).map(|k| psnr(img, k)).collect::<Vec<_>>());
                    let single = baseline.map(|(b, _)| against_all(&run_frame(b, &blurred, rw, rh, tiling)));
                    let (a, z) = (n - 1, 0);
                    let right = sq_dist(&outs[z], &sharp[z]) + sq_dist(&outs[a], &sharp[a]);
                    let reversed = sq_dist(&outs[z], &sharp[a]) + sq_dist(&outs[a], &sharp[z]);
                    records.push(BurstRecord {
                        video: path.display().to_string(),
                        frame: first + c,
                        window: n,
                        sigma,
                        motion: motion.clone(),
                        burst: PerTime::of(&burst),
                        single,
                        blurred: against_all(&blurred),
                        sharp_middle: against_all(&sharp[n / 2]),
                        right_order: right < reversed,
                    });
                    bar.inc(1);
                }
            }
        }
    }
    bar.finish();
    let table = cells(&records);
    let report = BurstReport {
        version: env!("CARGO_PKG_VERSION"),
        model: model.into(),
        baseline: baseline.map(|(_, n)| n.to_string()),
        camera: f.camera.kind.name().into(),
        convention: crate::metrics::CONVENTION,
        config: f.clone(),
        videos: paths.iter().map(|p| p.display().to_string()).collect(),
        seconds: t0.elapsed().as_secs_f64(),
        table,
        records,
    };
    let json = serde_json::to_vec_pretty(&report).expect("json");
    write_atomic(&out.join("burst.json"), |w| w.write_all(&json))?;
    let md = markdown(&report);
    write_atomic(&out.join("burst.md"), |w| w.write_all(md.as_bytes()))?;
    Ok(report)
}

/// Means per motion kind (and over all kinds, "all"), N and sigma.
fn cells(records: &[BurstRecord]) -> Vec<BurstCell> {
    let mut keys: Vec<(String, usize, u64)> = Vec::new();
    for r in records {
        for m in [r.motion.clone(), "all".to_string()] {
            let k = (m, r.window, r.sigma.to_bits());
            if !keys.contains(&k) {
                keys.push(k);
            }
        }
    }
    keys.sort_by(|a, b| {
        (a.0 == "all")
            .cmp(&(b.0 == "all"))
            .then(a.0.cmp(&b.0))
            .then(a.1.cmp(&b.1))
            .then(f64::from_bits(a.2).total_cmp(&f64::from_bits(b.2)))
    });
    keys.into_iter()
        .map(|(m, n, s)| {
            let sel: Vec<&BurstRecord> =
                records.iter().filter(|r| (m == "all" || r.motion == m) && r.window == n && r.sigma.to_bits() == s).collect();
            let singles: Vec<&PerTime> = sel.iter().filter_map(|r| r.single.as_ref()).collect();
            BurstCell {
                motion: m,
                window: n,
                sigma: f64::from_bits(s),
                count: sel.len(),
                burst: PerTime::mean(&sel.iter().map(|r| &r.burst).collect::<Vec<_>>()),
                single: (!singles.is_empty()).then(|| PerTime::mean(&singles)),
                blurred: PerTime::mean(&sel.iter().map(|r| &r.blurred).collect::<Vec<_>>()),
                sharp_middle: PerTime::mean(&sel.iter().map(|r| &r.sharp_middle).collect::<Vec<_>>()),
                direction: sel.iter().filter(|r| r.right_order).count() as f64 / sel.len().max(1) as f64,
            }
        })
        .collect()
}

/// `burst.md`: per motion kind, N and sigma, PSNR (RGB, dB) at the first, middle and last
/// sub-frames and over all, for the burst model, the single-frame model repeated and the input;
/// the true middle sub-frame against the first and last.
pub fn markdown(r: &BurstReport) -> String {
    let mut s = format!(
        "# pipeline eval --burst\n\nBurst model: {}  \nSingle-frame baseline: {}  \nCamera: {}  \nVideos: {}  \nMetrics: PSNR RGB dB, {}\n\n",
        r.model,
        r.baseline.as_deref().unwrap_or("none"),
        r.camera,
        r.videos.len(),
        r.convention
    );
    s.push_str(
        "| motion | N | sigma | burst first / middle / last / all | single-frame repeated | blurred input | true middle vs first / last | right order | windows |\n",
    );
    s.push_str("|---|---|---|---|---|---|---|---|---|\n");
    let fmt = |p: &PerTime| format!("{:.2} / {:.2} / {:.2} / {:.2}", p.first, p.middle, p.last, p.all);
    for c in &r.table {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {:.2} / {:.2} | {:.0}% | {} |\n",
            c.motion,
            c.window,
            c.sigma,
            fmt(&c.burst),
            c.single.as_ref().map_or("-".into(), fmt),
            fmt(&c.blurred),
            c.sharp_middle.first,
            c.sharp_middle.last,
            100.0 * c.direction,
            c.count
        ));
    }
    s
}
