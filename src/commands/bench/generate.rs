use super::*;

/// One measured configuration of `bench generate`.
#[derive(Debug, serde::Serialize)]
pub struct GenerateRow {
    pub mode: String,
    pub frames: u64,
    pub subframes_per_s_median: f64,
    pub subframes_per_s_all: Vec<f64>,
    pub ratio_to_ffmpeg_decode: f64,
    pub ratio_to_own_decode: f64,
    pub peak_rss_mb: Option<f64>,
}

/// Result of `bench generate`.
#[derive(Debug, serde::Serialize)]
pub struct GenerateBench {
    pub clip: String,
    pub width: usize,
    pub height: usize,
    pub fps: u32,
    pub frames: u64,
    pub repeats: usize,
    pub threads: usize,
    pub ffmpeg_decode_fps_median: f64,
    pub own_decode_fps_median: f64,
    /// The decoder alone in alternating rounds beside FFmpeg (own conversion and swscale's).
    pub decode: DecodeBench,
    pub rows: Vec<GenerateRow>,
    /// The FFT floor of a full-frame coded window on this machine.
    pub fft_floor: FftFloor,
    /// Peak memory of full-frame generation on a 3840x2160 clip (2 windows).
    pub peak_rss_mb_4k: Option<f64>,
    /// The same physics in SciPy and PyTorch (`benches/peers_generate.py`), where installed.
    pub peers: Vec<PeerRow>,
}

/// A Python peer of whole-frame coded generation, timed on the same clip and threads.
#[derive(Debug, serde::Serialize)]
pub struct PeerRow {
    pub peer: String,
    pub version: String,
    pub subframes_per_s_median: f64,
    /// Our whole-frame coded speed over the peer's (above 1: we are faster).
    pub ours_over_peer: f64,
}

/// Times `benches/peers_generate.py` for SciPy and PyTorch (each where [`super::train::python`]
/// imports it) on `clip`, `repeats` times, with the kernels of the default coded camera.
#[cfg(feature = "ffmpeg")]
fn peers(clip: &std::path::Path, (w, h): (usize, usize), dir: &std::path::Path, repeats: usize, ours: f64) -> Vec<PeerRow> {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/peers_generate.py");
    let python = python();
    let kernels = dir.join("kernels.npy");
    let made = std::env::current_exe().ok().is_some_and(|exe| {
        std::process::Command::new(exe)
            .args(["psf", "--camera", "phase_coded", "--window", "9", "--out"])
            .arg(&kernels)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    });
    let mut rows = Vec::new();
    for peer in ["scipy", "torch"] {
        if !made || !script.exists() || !python_imports(&format!("numpy, {peer}")) {
            eprintln!("bench: {peer} peer: not installed in {python} (PIPELINE_PYTHON), skipped");
            continue;
        }
        let runs: Vec<serde_json::Value> = (0..repeats)
            .filter_map(|_| {
                let o = std::process::Command::new(&python)
                    .arg(&script)
                    .args([peer, &clip.display().to_string(), &w.to_string(), &h.to_string(), &kernels.display().to_string()])
                    .arg(rayon::current_num_threads().to_string())
                    .output()
                    .ok()?;
                serde_json::from_slice(&o.stdout).ok()
            })
            .collect();
        let mut rates: Vec<f64> = runs.iter().filter_map(|r| r["subframes_per_s"].as_f64()).collect();
        if rates.is_empty() {
            eprintln!("bench: {peer} peer: failed to run {}", script.display());
            continue;
        }
        let m = median(&mut rates);
        let version = runs[0]["version"].as_str().unwrap_or("?").to_string();
        eprintln!(
            "bench: {peer} {version} peer of full frame: {m:.1} sub-frames/s (median of {}); ours {:.2}x as fast",
            rates.len(),
            ours / m
        );
        rows.push(PeerRow { peer: peer.into(), version, subframes_per_s_median: m, ours_over_peer: ours / m });
    }
    rows
}

/// What a full-frame coded window must cost at least: its forward transforms (one per channel
/// and kept rank) and three inverses per tile of the planned tiling, each timed alone at the
/// tile's padded size; beside it, the same transforms as one whole-frame plane.
#[derive(Debug, serde::Serialize)]
pub struct FftFloor {
    /// Padded transform size of one tile (width, height), and the tiles per frame.
    pub padded: [usize; 2],
    pub tiles: usize,
    pub ranks: [usize; 3],
    /// The ranks' error bound per channel, 8-bit levels RMS (`coded_blur.max_error`).
    pub error_bound_levels: [f64; 3],
    pub transforms_per_window: usize,
    /// Median time of one tile's forward transform with its product (one thread).
    pub ms_per_transform: f64,
    /// Median time of one whole-frame plane's transform (one thread) and its padded size.
    pub plane_ms_per_transform: f64,
    pub plane_padded: [usize; 2],
    /// Sub-frames per second if the tiles' transforms were all there was, on every core.
    pub subframes_per_s: f64,
    pub ratio_to_ffmpeg_decode: f64,
}

/// Median seconds of one forward transform with its product at `hp x wp` (one thread).
#[cfg_attr(not(feature = "ffmpeg"), allow(dead_code))] // used by the benches that need FFmpeg
pub(super) fn time_transform(hp: usize, wp: usize, repeats: usize) -> f64 {
    use crate::optics::fft::FftConv;
    let mut conv = FftConv::new(hp, wp);
    let mut img = vec![0.5f32; hp * wp];
    let spec = conv.kernel_spectrum(&[1.0]);
    let mut out = conv.zero_spectrum();
    let mut times: Vec<f64> = (0..repeats.max(3))
        .map(|_| {
            img.fill(0.5);
            let t = Instant::now();
            conv.forward_mul_in_place(&mut img, &spec, &mut out);
            t.elapsed().as_secs_f64()
        })
        .collect();
    median(&mut times)
}

/// Times the transforms of one full-frame window of the default coded camera.
#[cfg_attr(not(feature = "ffmpeg"), allow(dead_code))] // used by the benches that need FFmpeg
pub(super) fn fft_floor(w: usize, h: usize, window: usize, repeats: usize, ff_decode: f64) -> crate::Result<FftFloor> {
    use crate::optics::fft::fast_size;
    let cam = std::sync::Arc::new(crate::optics::Camera::new(
        &Default::default(),
        &crate::optics::CameraConfig::new(crate::optics::CameraKind::PhaseCoded),
    ));
    let b = crate::imaging::blur::Blurrer::new(cam, window, 1, crate::stage::coded_blur::DEFAULT_MAX_ERROR)?;
    let m = b.margin;
    let (tw, th) = crate::imaging::blur::plan_tiles(w, h, m);
    let tiles = w.div_ceil(tw) * h.div_ceil(th);
    let (hp, wp) = (fast_size(th + 2 * m), fast_size(tw + 2 * m));
    let (php, pwp) = (fast_size(h + 2 * m), fast_size(w + 2 * m));
    let ranks = b.ranks();
    // Enough repeats of a small tile for a stable median.
    let t1 = time_transform(hp, wp, repeats.max(5) * tiles);
    let plane = time_transform(php, pwp, repeats.max(5));
    let transforms = ranks.iter().sum::<usize>() + 3;
    let threads = rayon::current_num_threads() as f64;
    let sps = window as f64 * threads / (transforms as f64 * tiles as f64 * t1);
    Ok(FftFloor {
        padded: [wp, hp],
        tiles,
        ranks,
        error_bound_levels: b.error_bounds(),
        transforms_per_window: transforms,
        ms_per_transform: t1 * 1e3,
        plane_ms_per_transform: plane * 1e3,
        plane_padded: [pwp, php],
        subframes_per_s: sps,
        ratio_to_ffmpeg_decode: sps / ff_decode,
    })
}

#[cfg(feature = "ffmpeg")]
pub(super) fn bench_plan(mode: &str, clip: &std::path::Path, out: &std::path::Path) -> crate::Result<crate::config::Plan> {
    crate::config::plan(bench_table(mode, clip, out)?, &format!("bench ({mode})"))
}

/// The configurations `bench generate` times, each a row (`bench_table` reads the words).
pub const MODES: [&str; 6] = [
    "full frame",
    "full frame, one plane (tile = 1048576)",
    "full frame, conventional",
    "patches",
    "patches, through a sensor (pipelines/realistic.toml)",
    "patches, clip twice as long",
];

#[cfg(feature = "ffmpeg")]
const REALISTIC_TOML: &str = include_str!("../../../pipelines/realistic.toml");

/// The configuration of [`bench_plan`], as a TOML table.
#[cfg(feature = "ffmpeg")]
fn bench_table(mode: &str, clip: &std::path::Path, out: &std::path::Path) -> crate::Result<toml::Table> {
    let mut sets = vec![
        format!("sources.video.paths=[{:?}]", clip.display().to_string()),
        format!("sinks.shards.dir={:?}", out.display().to_string()),
    ];
    if mode.starts_with("full frame") {
        // Whole frames, noise, into a blackhole: the cost of generation without PNG encoding.
        sets.extend([
            "transforms.patches.type=\"noise\"".into(),
            "transforms.patches.sigma=0.0".into(),
            "transforms.patches.inputs=[\"noise\"]".into(),
        ]);
        sets.extend(["sinks.shards.type=\"blackhole\"".into()]);
    }
    if mode.contains("conventional") {
        sets.push("transforms.blur.camera.type=\"conventional\"".into());
    }
    if mode.contains("one plane") {
        sets.push("transforms.blur.tile=1048576".into());
    }
    // The realistic chain: patches read out by a sensor (shot and read noise, saturation, an
    // RGGB mosaic demosaiced, the camera response) instead of AWGN.
    let (text, origin) = if mode.contains("sensor") {
        (REALISTIC_TOML, "pipelines/realistic.toml (embedded)")
    } else {
        (crate::commands::generate::GENERATE_TOML, "pipelines/generate.toml (embedded)")
    };
    let mut table = crate::config::parse(text, origin, &[])?;
    if mode.starts_with("full frame") {
        // Drop the patch keys that a noise stage does not have.
        if let Some(t) = table.get_mut("transforms").and_then(|t| t.get_mut("patches")).and_then(|p| p.as_table_mut()) {
            t.retain(|k, _| k == "inputs");
        }
        if let Some(t) = table.get_mut("sinks").and_then(|t| t.get_mut("shards")).and_then(|p| p.as_table_mut()) {
            t.retain(|k, _| k == "inputs" || k == "dir");
        }
    }
    crate::config::apply_sets(&mut table, &sets)?;
    Ok(table)
}

/// Peak memory of a whole-frame run of `clip` as its own `pipeline generate` process (from its
/// report's `peak_rss_mb`): in this process the earlier rounds' caches and allocator pools
/// would count too.
#[cfg(feature = "ffmpeg")]
fn peak_in_child(clip: &std::path::Path, dir: &std::path::Path) -> crate::Result<Option<f64>> {
    let out = dir.join("out-4k");
    let config = dir.join("full-frame.toml");
    let table = bench_table("full frame", clip, &out)?;
    let text = toml::to_string(&table).map_err(|e| crate::Error::Serialise { what: config.display().to_string(), source: Box::new(e) })?;
    std::fs::write(&config, text).map_err(|e| crate::Error::Io { path: config.clone(), cause: e })?;
    let exe = std::env::current_exe().map_err(|e| crate::Error::Io { path: "current executable".into(), cause: e })?;
    let status = std::process::Command::new(&exe)
        .arg("generate")
        .arg("--config")
        .arg(&config)
        .args(["--progress", "never"])
        .stdout(std::process::Stdio::null())
        .status()
        .map_err(|e| crate::Error::Io { path: exe.clone(), cause: e })?;
    if !status.success() {
        return Err(crate::Error::Program {
            program: exe.display().to_string(),
            why: format!("the 4K run of {} failed ({status})", clip.display()),
            source: None,
        });
    }
    let report = out.join("report.json");
    let text = std::fs::read_to_string(&report).map_err(|e| crate::Error::Io { path: report.clone(), cause: e })?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(crate::Error::format(&report))?;
    Ok(v["peak_rss_mb"].as_f64())
}

/// `bench generate`: generation speed beside FFmpeg's decode-only speed of the same clip.
///
/// # Errors
/// The ffmpeg CLI is missing, or a run fails.
#[cfg(feature = "ffmpeg")]
pub fn generate(w: usize, h: usize, fps: u32, seconds: f64, repeats: usize) -> crate::Result<GenerateBench> {
    let dir = std::env::temp_dir().join(format!("pipeline-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| crate::Error::Io { path: dir.clone(), cause: e })?;
    let clip = dir.join(format!("bench-{w}x{h}-{fps}fps.mp4"));
    let long = dir.join(format!("bench-{w}x{h}-{fps}fps-long.mp4"));
    eprintln!("bench: making {} and a clip twice as long with the ffmpeg CLI", clip.display());
    make_clip(&clip, w, h, fps, seconds)?;
    make_clip(&long, w, h, fps, 2.0 * seconds)?;
    let repeats = repeats.max(1);
    let dec = decode_rounds(&clip, "the clip below", repeats)?;
    let (ff_med, own_med, frames) = (dec.ffmpeg_decode_fps_median, dec.own_decode_fps_median, dec.frames);
    eprintln!(
        "bench: decode only: ffmpeg CLI {ff_med:.0} frames/s, pipeline decoder (with RGB conversion) {own_med:.0} frames/s ({:.2}x, median of the rounds' ratios); with swscale's conversion {:.0} ({:.2}x)",
        dec.ratio_own_to_ffmpeg, dec.own_decode_swscale_fps_median, dec.ratio_swscale_to_ffmpeg
    );
    let mut rows = Vec::new();
    for mode in MODES {
        let path = if mode.contains("twice as long") { &long } else { &clip };
        rows.push(generate_row(mode, path, &dir, repeats, (ff_med, own_med))?);
    }
    let floor = fft_floor(w, h, 9, repeats.max(5), ff_med)?;
    eprintln!(
        "bench: FFT floor of a coded window: {} tiles in transforms of {}x{}, {} transforms each (ranks {:?} within {:.2?} of an 8-bit level RMS, + 3 inverses) x {:.2} ms = {:.0} sub-frames/s on {} threads ({:.2}x ffmpeg decode-only); one {}x{} plane instead: {:.2} ms a transform ({:.2} ms per tile's worth of pixels)",
        floor.tiles,
        floor.padded[0],
        floor.padded[1],
        floor.transforms_per_window,
        floor.ranks,
        floor.error_bound_levels,
        floor.ms_per_transform,
        floor.subframes_per_s,
        rayon::current_num_threads(),
        floor.ratio_to_ffmpeg_decode,
        floor.plane_padded[0],
        floor.plane_padded[1],
        floor.plane_ms_per_transform,
        floor.plane_ms_per_transform / floor.tiles as f64,
    );
    let full = rows.iter().find(|r| r.mode == "full frame").map_or(f64::NAN, |r| r.subframes_per_s_median);
    let peers = peers(&clip, (w, h), &dir, repeats, full);
    // Peak memory at 4K: two windows of full frames.
    let uhd = dir.join("bench-3840x2160.mp4");
    make_clip(&uhd, 3840, 2160, fps, 18.0 / fps as f64)?;
    let peak_4k = peak_in_child(&uhd, &dir)?;
    eprintln!("bench: full frame at 3840x2160: peak RSS {}", peak_4k.map_or("n/a".into(), |p| format!("{p:.0} MB")));
    let _ = std::fs::remove_dir_all(&dir);
    Ok(GenerateBench {
        clip: format!("testsrc2 {w}x{h} {fps} fps H.264 (x264 veryfast), {seconds} s"),
        width: w,
        height: h,
        fps,
        frames,
        repeats,
        threads: std::thread::available_parallelism().map_or(1, |t| t.get()),
        ffmpeg_decode_fps_median: ff_med,
        own_decode_fps_median: own_med,
        decode: dec,
        rows,
        fft_floor: floor,
        peak_rss_mb_4k: peak_4k,
        peers,
    })
}

/// One mode of `bench generate` run `repeats` times on `clip` into `dir/out`: the median rate
/// against FFmpeg's and our decoder's (`decode`: frames/s of each) and the peak memory.
#[cfg(feature = "ffmpeg")]
fn generate_row(
    mode: &str,
    clip: &std::path::Path,
    dir: &std::path::Path,
    repeats: usize,
    decode: (f64, f64),
) -> crate::Result<GenerateRow> {
    let (ff_med, own_med) = decode;
    let mut rates = Vec::new();
    let mut peak = None;
    let mut n_frames = 0;
    for _ in 0..repeats {
        let out = dir.join("out");
        let _ = std::fs::remove_dir_all(&out);
        let plan = bench_plan(mode, clip, &out)?;
        let reset = reset_peak_rss();
        let o = crate::graph::run(&plan, &crate::graph::RunOptions::default())?;
        if reset {
            let p = crate::provenance::peak_rss_kb().map(|k| k as f64 / 1024.0);
            peak = match (peak, p) {
                (Some(a), Some(b)) => Some(f64::max(a, b)),
                (a, b) => a.or(b),
            };
        }
        n_frames = o.report.frames;
        rates.push(o.report.subframes_per_s);
    }
    let all = rates.clone();
    let m = median(&mut rates);
    eprintln!(
        "bench: {mode}: {m:.1} sub-frames/s (median of {repeats}), {:.2}x ffmpeg decode-only, peak RSS {}",
        m / ff_med,
        peak.map_or("n/a".into(), |p| format!("{p:.0} MB"))
    );
    Ok(GenerateRow {
        mode: mode.into(),
        frames: n_frames,
        subframes_per_s_median: m,
        subframes_per_s_all: all,
        ratio_to_ffmpeg_decode: m / ff_med,
        ratio_to_own_decode: m / own_med,
        peak_rss_mb: peak,
    })
}

#[cfg(all(test, feature = "ffmpeg"))]
mod tests {
    use super::*;

    #[test]
    fn every_mode_plans_the_chain_its_name_says() {
        let dir = crate::io::paths::scratch_dir("bench_modes");
        for mode in MODES {
            let t = bench_table(mode, &dir.join("clip.mp4"), &dir.join("out")).unwrap();
            let stage = |k: &str| t["transforms"].get(k).map(|s| s["type"].as_str().unwrap().to_string());
            let sink = t["sinks"]["shards"]["type"].as_str().unwrap();
            assert_eq!(sink == "blackhole", mode.starts_with("full frame"), "{mode}");
            assert_eq!(stage("sensor").as_deref() == Some("sensor"), mode.contains("sensor"), "{mode}");
            let camera = t["transforms"]["blur"]["camera"]["type"].as_str().unwrap();
            assert_eq!(camera == "conventional", mode.contains("conventional"), "{mode}");
            bench_plan(mode, &dir.join("clip.mp4"), &dir.join("out")).unwrap_or_else(|e| panic!("{mode}: {e}"));
        }
    }
}
