//! `pipeline bench`: measured speed, kept apart from the tests. Each figure is the median of
//! several repeats because the machines are shared and noisy.
//!
//! Longer than 600 lines because each benchmark carries its baseline (FFmpeg decode-only,
//! PyTorch on the same network and thread count) and its report in the same place.

use crate::optics::{Camera, CameraConfig, CameraKind, OpticsConfig};
use std::time::Instant;

/// Median of a sample (sorts in place).
pub fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Result of `bench psf`.
#[derive(Debug, serde::Serialize)]
pub struct PsfBench {
    pub camera: &'static str,
    pub window: usize,
    pub repeats: usize,
    pub kernel_px: usize,
    pub cold_ms_median: f64,
    pub cached_us_median: f64,
    pub cold_ms_all: Vec<f64>,
}

/// Builds the kernels of one window with a fresh camera (cold) and again from its cache.
pub fn psf(kind: CameraKind, window: usize, repeats: usize) -> PsfBench {
    let optics = OpticsConfig::default();
    let (mut cold, mut cached) = (Vec::new(), Vec::new());
    let mut kernel_px = 0;
    for _ in 0..repeats.max(1) {
        let cam = Camera::new(&optics, &CameraConfig::new(kind));
        let t = Instant::now();
        let w = cam.window(window).expect("default schedule fits any window");
        cold.push(t.elapsed().as_secs_f64() * 1e3);
        kernel_px = w[0].psf.size;
        let t = Instant::now();
        for _ in 0..100 {
            std::hint::black_box(cam.window(window).expect("cached"));
        }
        cached.push(t.elapsed().as_secs_f64() * 1e6 / 100.0);
    }
    let cold_all = cold.clone();
    PsfBench {
        camera: kind.name(),
        window,
        repeats: repeats.max(1),
        kernel_px,
        cold_ms_median: median(&mut cold),
        cached_us_median: median(&mut cached),
        cold_ms_all: cold_all,
    }
}

/// Peak resident memory (kB) since the last [`reset_peak_rss`], from /proc (Linux).
pub fn peak_rss_kb() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    s.lines().find(|l| l.starts_with("VmHWM:"))?.split_whitespace().nth(1)?.parse().ok()
}

/// Resets the peak-RSS counter (Linux 4.0+); false where unsupported.
pub fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

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
fn time_transform(hp: usize, wp: usize, repeats: usize) -> f64 {
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
fn fft_floor(w: usize, h: usize, window: usize, repeats: usize, ff_decode: f64) -> crate::Result<FftFloor> {
    use crate::optics::fft::fast_size;
    let cam = std::sync::Arc::new(crate::optics::Camera::new(
        &Default::default(),
        &crate::optics::CameraConfig::new(crate::optics::CameraKind::PhaseCoded),
    ));
    let b = crate::imaging::blur::Blurrer::new(cam, window, 1, 1e-3)?;
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
        transforms_per_window: transforms,
        ms_per_transform: t1 * 1e3,
        plane_ms_per_transform: plane * 1e3,
        plane_padded: [pwp, php],
        subframes_per_s: sps,
        ratio_to_ffmpeg_decode: sps / ff_decode,
    })
}

#[cfg(feature = "ffmpeg")]
fn ffmpeg_cli(args: &[&str]) -> crate::Result<()> {
    let st = std::process::Command::new("ffmpeg")
        .args(["-v", "error", "-y"])
        .args(args)
        .status()
        .map_err(|e| crate::Error::Invalid(format!("ffmpeg CLI not found ({e}); run .ci/setup.sh")))?;
    if !st.success() {
        return Err(crate::Error::Invalid(format!("ffmpeg {args:?} failed")));
    }
    Ok(())
}

#[cfg(feature = "ffmpeg")]
/// Makes a `w x h`, `fps` H.264 clip of `seconds` with FFmpeg's test pattern (fine detail,
/// moving objects, scrolling gradient).
fn make_clip(path: &std::path::Path, w: usize, h: usize, fps: u32, seconds: f64) -> crate::Result<()> {
    let src = format!("testsrc2=size={w}x{h}:rate={fps}");
    ffmpeg_cli(&[
        "-f",
        "lavfi",
        "-i",
        &src,
        "-t",
        &format!("{seconds}"),
        "-c:v",
        "libx264",
        "-preset",
        "veryfast",
        "-pix_fmt",
        "yuv420p",
        path.to_str().unwrap_or_default(),
    ])
}

/// Frames/s of the pipeline's decoder (decode + RGB planes); `swscale`: with swscale's
/// conversion instead of its own (the path before it had one).
#[cfg(feature = "ffmpeg")]
fn own_decode_fps_with(path: &std::path::Path, swscale: bool) -> crate::Result<(f64, u64)> {
    let mut r = crate::io::video::VideoReader::open(path).map_err(|e| crate::Error::Invalid(format!("{}: {e}", path.display())))?;
    r.force_swscale = swscale;
    let t = Instant::now();
    let mut n = 0u64;
    while r.next_frame().map_err(crate::Error::Invalid)?.is_some() {
        n += 1;
    }
    Ok((n as f64 / t.elapsed().as_secs_f64(), n))
}

#[cfg(feature = "ffmpeg")]
fn ffmpeg_decode_fps(path: &std::path::Path, frames: u64) -> crate::Result<f64> {
    let t = Instant::now();
    ffmpeg_cli(&["-threads", "0", "-i", path.to_str().unwrap_or_default(), "-f", "null", "-"])?;
    Ok(frames as f64 / t.elapsed().as_secs_f64())
}

#[cfg(feature = "ffmpeg")]
fn bench_plan(mode: &str, clip: &std::path::Path, out: &std::path::Path) -> crate::Result<crate::config::Plan> {
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
    let mut table = crate::config::parse(super::generate::GENERATE_TOML, "pipelines/generate.toml (embedded)", &[])?;
    if mode.starts_with("full frame") {
        // Drop the patch keys that a noise stage does not have.
        if let Some(t) = table.get_mut("transforms").and_then(|t| t.get_mut("patches")).and_then(|p| p.as_table_mut()) {
            t.retain(|k, _| k == "inputs");
        }
        if let Some(t) = table.get_mut("sinks").and_then(|t| t.get_mut("shards")).and_then(|p| p.as_table_mut()) {
            t.retain(|k, _| k == "inputs" || k == "dir");
        }
    }
    crate::config::apply_sets(&mut table, &sets).map_err(crate::Error::Invalid)?;
    crate::config::plan(table, &format!("bench ({mode})"))
}

#[derive(Debug, serde::Serialize)]
pub struct DecodeBench {
    pub clip: String,
    pub frames: u64,
    pub repeats: usize,
    pub ffmpeg_decode_fps_median: f64,
    pub own_decode_fps_median: f64,
    pub own_decode_swscale_fps_median: f64,
    /// Medians of the per-round ratios (each round times all three back to back).
    pub ratio_own_to_ffmpeg: f64,
    pub ratio_swscale_to_ffmpeg: f64,
}

/// `bench decode`: the pipeline's decoder (decode + RGB planes, with its own conversion and
/// with swscale's) beside FFmpeg's decode-only speed of the same clip, in alternating rounds.
///
/// # Errors
/// The ffmpeg CLI is missing, or decoding fails.
#[cfg(feature = "ffmpeg")]
pub fn decode(w: usize, h: usize, fps: u32, seconds: f64, repeats: usize) -> crate::Result<DecodeBench> {
    let dir = std::env::temp_dir().join(format!("pipeline-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| crate::Error::Io { path: dir.clone(), cause: e })?;
    let clip = dir.join(format!("bench-{w}x{h}-{fps}fps.mp4"));
    make_clip(&clip, w, h, fps, seconds)?;
    let b = decode_rounds(&clip, &format!("testsrc2 {w}x{h} {fps} fps H.264 (x264 veryfast), {seconds} s"), repeats)?;
    let _ = std::fs::remove_dir_all(&dir);
    eprintln!(
        "bench: decode {w}x{h}: ffmpeg decode-only {:.0} frames/s; pipeline decoder {:.0} ({:.2}x); with swscale's conversion {:.0} ({:.2}x) (medians of {})",
        b.ffmpeg_decode_fps_median, b.own_decode_fps_median, b.ratio_own_to_ffmpeg, b.own_decode_swscale_fps_median, b.ratio_swscale_to_ffmpeg, b.repeats
    );
    Ok(b)
}

/// Rounds of: the decoder with its own conversion, with swscale's, then FFmpeg decode-only.
#[cfg(feature = "ffmpeg")]
fn decode_rounds(clip: &std::path::Path, name: &str, repeats: usize) -> crate::Result<DecodeBench> {
    let repeats = repeats.max(1);
    let (mut ff, mut own, mut sws, mut r_own, mut r_sws) = (vec![], vec![], vec![], vec![], vec![]);
    let mut frames = 0;
    for _ in 0..repeats {
        let (o, n) = own_decode_fps_with(clip, false)?;
        let (s, _) = own_decode_fps_with(clip, true)?;
        let f = ffmpeg_decode_fps(clip, n)?;
        frames = n;
        r_own.push(o / f);
        r_sws.push(s / f);
        own.push(o);
        sws.push(s);
        ff.push(f);
    }
    Ok(DecodeBench {
        clip: name.into(),
        frames,
        repeats,
        ffmpeg_decode_fps_median: median(&mut ff),
        own_decode_fps_median: median(&mut own),
        own_decode_swscale_fps_median: median(&mut sws),
        ratio_own_to_ffmpeg: median(&mut r_own),
        ratio_swscale_to_ffmpeg: median(&mut r_sws),
    })
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
    for (mode, path) in [
        ("full frame", &clip),
        ("full frame, one plane (tile = 1048576)", &clip),
        ("full frame, conventional", &clip),
        ("patches", &clip),
        ("patches, clip twice as long", &long),
    ] {
        let mut rates = Vec::new();
        let mut peak = None;
        let mut n_frames = 0;
        for _ in 0..repeats {
            let out = dir.join("out");
            let _ = std::fs::remove_dir_all(&out);
            let plan = bench_plan(mode, path, &out)?;
            let reset = reset_peak_rss();
            let o = crate::graph::run(&plan, &crate::graph::RunOptions::default())?;
            if reset {
                let p = peak_rss_kb().map(|k| k as f64 / 1024.0);
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
        rows.push(GenerateRow {
            mode: mode.into(),
            frames: n_frames,
            subframes_per_s_median: m,
            subframes_per_s_all: all,
            ratio_to_ffmpeg_decode: m / ff_med,
            ratio_to_own_decode: m / own_med,
            peak_rss_mb: peak,
        });
    }
    let floor = fft_floor(w, h, 9, repeats.max(5), ff_med)?;
    eprintln!(
        "bench: FFT floor of a coded window: {} tiles in transforms of {}x{}, {} transforms each (ranks {:?} + 3 inverses) x {:.2} ms = {:.0} sub-frames/s on {} threads ({:.2}x ffmpeg decode-only); one {}x{} plane instead: {:.2} ms a transform ({:.2} ms per tile's worth of pixels)",
        floor.tiles,
        floor.padded[0],
        floor.padded[1],
        floor.transforms_per_window,
        floor.ranks,
        floor.ms_per_transform,
        floor.subframes_per_s,
        rayon::current_num_threads(),
        floor.ratio_to_ffmpeg_decode,
        floor.plane_padded[0],
        floor.plane_padded[1],
        floor.plane_ms_per_transform,
        floor.plane_ms_per_transform / floor.tiles as f64,
    );
    // Peak memory at 4K: two windows of full frames.
    let uhd = dir.join("bench-3840x2160.mp4");
    make_clip(&uhd, 3840, 2160, fps, 18.0 / fps as f64)?;
    let out = dir.join("out-4k");
    let plan = bench_plan("full frame", &uhd, &out)?;
    let reset = reset_peak_rss();
    crate::graph::run(&plan, &crate::graph::RunOptions::default())?;
    let peak_4k = if reset { peak_rss_kb().map(|k| k as f64 / 1024.0) } else { None };
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
    })
}

/// One model's speed in `bench train`.
#[cfg(feature = "train")]
#[derive(Debug, serde::Serialize)]
pub struct ModelSpeed {
    pub model: String,
    pub engine: &'static str,
    pub parameters: usize,
    pub batch: usize,
    pub threads: usize,
    pub train_patches_per_s_median: f64,
    pub forward_ms_per_patch_median: f64,
    pub torch: Option<serde_json::Value>,
    /// Our time per patch over PyTorch's (training step; forward of one patch): 1.0 is parity.
    pub train_time_ratio_vs_torch: Option<f64>,
    pub forward_time_ratio_vs_torch: Option<f64>,
}

#[cfg(feature = "train")]
fn bench_data(n: usize, salt: usize) -> crate::model::fast::T4 {
    let v: Vec<f32> = (0..n * 3 * 128 * 128).map(|i| (((i + salt) * 7919) % 1000) as f32 / 1000.0).collect();
    crate::model::fast::T4::new(n, 3, 128, 128, v)
}

/// Seconds per training step and ms per 128x128 forward with burn's autodiff on flex.
#[cfg(feature = "train")]
fn time_burn(arch: crate::model::Arch, batch: usize, repeats: usize) -> (Vec<f64>, Vec<f64>) {
    use burn::module::Module;
    use burn::nn::loss::{HuberLossConfig, Reduction};
    use burn::optim::{AdamConfig, GradientsParams};
    use burn::tensor::Device;
    let device = Device::flex().autodiff();
    let mut model = crate::model::Net::seeded(arch, &device, 7);
    let mut optim = AdamConfig::new().with_epsilon(1e-8).init();
    let huber = HuberLossConfig::new(0.02).init();
    let (x, y) = (bench_data(batch, 0), bench_data(batch, 1));
    let mut steps = Vec::new();
    for r in 0..repeats + 1 {
        let t = Instant::now();
        let loss = huber.forward(model.forward(x.to_tensor(&device)), y.to_tensor(&device), Reduction::Mean);
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optim.step(1e-4, model, grads);
        if r > 0 {
            steps.push(t.elapsed().as_secs_f64());
        }
    }
    let valid = model.valid();
    let dev = device.clone().inner();
    let one = bench_data(1, 2);
    let mut fwd = Vec::new();
    for r in 0..repeats + 1 {
        let t = Instant::now();
        std::hint::black_box(valid.forward(one.to_tensor(&dev)).into_data());
        if r > 0 {
            fwd.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    (steps, fwd)
}

/// The same with the CPU fast path (`src/model/fast.rs`).
#[cfg(feature = "train")]
fn time_fast(arch: crate::model::Arch, batch: usize, repeats: usize) -> (Vec<f64>, Vec<f64>) {
    use crate::model::fast::{train_step, Adam, FastNet};
    let mut net = FastNet::from_net(&crate::model::Net::seeded(arch, &burn::tensor::Device::flex(), 7));
    let mut adam = Adam::default();
    let (x, y) = (bench_data(batch, 0), bench_data(batch, 1));
    let mut steps = Vec::new();
    for r in 0..repeats + 1 {
        let t = Instant::now();
        train_step(&mut net, &mut adam, &x, &y, 1e-4, 0.02, 1e-8);
        if r > 0 {
            steps.push(t.elapsed().as_secs_f64());
        }
    }
    let one = bench_data(1, 2);
    let mut fwd = Vec::new();
    for r in 0..repeats + 1 {
        let t = Instant::now();
        std::hint::black_box(net.forward(&one));
        if r > 0 {
            fwd.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    (steps, fwd)
}

/// `bench train`: training step and forward speed per 128x128 patch of the given
/// architectures with the fast path (and burn's path with `with_burn`), beside PyTorch on the
/// same architectures with the same number of threads when torch is installed
/// (`benches/torch_models.py`).
#[cfg(feature = "train")]
pub fn train(archs: &[crate::model::Arch], batch: usize, repeats: usize, with_burn: bool) -> crate::Result<Vec<ModelSpeed>> {
    use burn::module::Module;
    let script = torch_script();
    let threads = rayon::current_num_threads();
    let mut out = Vec::new();
    for &arch in archs {
        let parameters = crate::model::Net::new(arch, &burn::tensor::Device::flex()).num_params();
        let torch_row: Option<serde_json::Value> = script.as_ref().and_then(|script| {
            let (kind, width) = match arch {
                crate::model::Arch::Unet { base } => ("unet", base),
                crate::model::Arch::Shallow { width } => ("shallow", width),
            };
            std::process::Command::new(python())
                .arg(script)
                .args([kind, &width.to_string(), &batch.to_string(), &repeats.to_string()])
                .env("TORCH_THREADS", threads.to_string())
                .output()
                .ok()
                .and_then(|o| serde_json::from_slice(&o.stdout).ok())
        });
        let mut engines: Vec<(&'static str, fn(crate::model::Arch, usize, usize) -> (Vec<f64>, Vec<f64>))> = vec![("fast", time_fast)];
        if with_burn {
            engines.push(("burn", time_burn));
        }
        for (engine, f) in engines {
            let (mut steps, mut fwd) = f(arch, batch, repeats);
            let (step, fwd) = (median(&mut steps), median(&mut fwd));
            let tt = torch_row.as_ref().and_then(|t| t["train_patches_per_s_median"].as_f64());
            let tf = torch_row.as_ref().and_then(|t| t["forward_ms_per_patch_median"].as_f64());
            let row = ModelSpeed {
                model: arch.name(),
                engine,
                parameters,
                batch,
                threads,
                train_patches_per_s_median: batch as f64 / step,
                forward_ms_per_patch_median: fwd,
                torch: torch_row.clone(),
                train_time_ratio_vs_torch: tt.map(|t| t * step / batch as f64),
                forward_time_ratio_vs_torch: tf.map(|t| fwd / t),
            };
            eprintln!(
                "bench: {} ({engine}, {threads} threads): {:.2} patches/s training (batch {batch}), forward {:.1} ms per 128x128 patch{}",
                row.model,
                row.train_patches_per_s_median,
                row.forward_ms_per_patch_median,
                match (tt, tf) {
                    (Some(tt), Some(tf)) => format!(
                        "; PyTorch {tt:.2} patches/s, {tf:.1} ms: our time {:.2}x training, {:.2}x forward",
                        row.train_time_ratio_vs_torch.unwrap_or(f64::NAN),
                        row.forward_time_ratio_vs_torch.unwrap_or(f64::NAN)
                    ),
                    _ => "; torch not installed, no comparison".into(),
                }
            );
            out.push(row);
        }
    }
    Ok(out)
}

/// The Python that runs the PyTorch baseline: `PIPELINE_PYTHON`, else `python3`.
#[cfg(feature = "train")]
fn python() -> String {
    std::env::var("PIPELINE_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// `benches/torch_models.py` when [`python`] can import torch (the PyTorch baseline), else `None`.
#[cfg(feature = "train")]
fn torch_script() -> Option<std::path::PathBuf> {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/torch_models.py");
    let torch = std::process::Command::new(python())
        .args(["-c", "import torch"])
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    (torch && script.exists()).then_some(script)
}

/// One shipped model's speed in `bench deblur`.
#[cfg(feature = "train")]
#[derive(Debug, serde::Serialize)]
pub struct DeblurSpeed {
    pub model: String,
    pub arch: String,
    pub width: usize,
    pub height: usize,
    /// The whole frame in one forward pass.
    pub whole_frames_per_s_median: f64,
    /// As `pipeline deblur` runs by default (tiles of at most 384 px overlapping by 32, blended,
    /// on all cores).
    pub tiled_frames_per_s_median: f64,
    /// PyTorch CPU, the same architecture, whole frame, in the same run (when installed).
    pub torch: Option<serde_json::Value>,
    /// torch frames/s (whole frame, the same thread count) over ours as `deblur` runs by
    /// default: our time per frame over PyTorch's.
    pub torch_over_ours: Option<f64>,
    /// The same against our whole-frame pass.
    pub torch_over_ours_whole: Option<f64>,
}

/// `bench deblur`: frames/s of each shipped model on a `width x height` frame, whole and tiled,
/// beside PyTorch on the same architecture when torch is installed.
#[cfg(feature = "train")]
pub fn deblur(width: usize, height: usize, repeats: usize) -> crate::Result<Vec<DeblurSpeed>> {
    use crate::model::infer::{run_frame, Tiling};
    use crate::model::Arch;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let script = torch_script();
    let device = burn::tensor::Device::flex();
    let frame: Vec<u8> = (0..width * height * 3).map(|i| (crate::rng::hash(&[i as u64 / 7]) % 256) as u8).collect();
    let mut out = Vec::new();
    let mut names: Vec<String> = std::fs::read_dir(root.join("models"))
        .map_err(|e| crate::Error::Io { path: root.join("models"), cause: e })?
        .filter_map(|e| e.ok())
        .filter(|e| e.path().join("model.safetensors").exists())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    for name in &names {
        let path = root.join("models").join(name).join("model.safetensors");
        let (net, arch) = crate::train::load_model(&path, &device)?;
        let net = crate::model::fast::FastNet::from_net(&net);
        let time = |tiling: Tiling| {
            let mut t = Vec::new();
            for r in 0..repeats + 1 {
                let t0 = Instant::now();
                std::hint::black_box(run_frame(&net, &frame, width, height, tiling));
                if r > 0 {
                    t.push(t0.elapsed().as_secs_f64());
                }
            }
            1.0 / median(&mut t)
        };
        let whole = time(Tiling { tile: width.max(height), overlap: 0 });
        let tiled = time(Tiling::default());
        let torch_row: Option<serde_json::Value> = if let Some(script) = &script {
            let (kind, w) = match arch {
                Arch::Unet { base } => ("unet", base),
                Arch::Shallow { width } => ("shallow", width),
            };
            std::process::Command::new(python())
                .arg(&script)
                .env("TORCH_THREADS", rayon::current_num_threads().to_string())
                .args(["infer", kind, &w.to_string(), &height.to_string(), &width.to_string(), &repeats.to_string()])
                .output()
                .ok()
                .and_then(|o| serde_json::from_slice(&o.stdout).ok())
        } else {
            None
        };
        let torch_fps = torch_row.as_ref().and_then(|t| t["frames_per_s_median"].as_f64());
        let ratio = torch_fps.map(|t| t / tiled);
        eprintln!(
            "bench: {name} ({}) {width}x{height}: {whole:.3} frames/s whole, {tiled:.3} tiled (default){}",
            arch.name(),
            match ratio {
                Some(r) => format!("; torch {:.3} frames/s = {r:.2}x ours", r * tiled),
                None => "; torch not installed, no comparison".into(),
            }
        );
        out.push(DeblurSpeed {
            model: format!("models/{name}"),
            arch: arch.name(),
            width,
            height,
            whole_frames_per_s_median: whole,
            tiled_frames_per_s_median: tiled,
            torch: torch_row,
            torch_over_ours: ratio,
            torch_over_ours_whole: torch_fps.map(|t| t / whole),
        });
    }
    Ok(out)
}

/// The test clip a generation or decoding benchmark makes with the ffmpeg CLI.
#[cfg(feature = "ffmpeg")]
#[derive(clap::Args, Debug)]
pub struct ClipArgs {
    #[arg(long, default_value_t = 1280)]
    width: usize,
    #[arg(long, default_value_t = 720)]
    height: usize,
    #[arg(long, default_value_t = 240)]
    fps: u32,
    /// Length of the clip.
    #[arg(long, default_value_t = 2.0)]
    seconds: f64,
}

#[derive(clap::Subcommand, Debug)]
pub enum BenchCommand {
    /// Deblurring speed (frames/s) of each shipped model on a 1280x720 frame, whole and in
    /// tiles, beside PyTorch CPU on the same architecture when torch is installed.
    #[cfg(feature = "train")]
    Deblur {
        #[arg(long, default_value_t = 1280)]
        width: usize,
        #[arg(long, default_value_t = 720)]
        height: usize,
        /// Repeats; the median is reported.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..=1000))]
        repeats: u16,
    },
    /// Time to build the kernels of one window, cold (new camera) and from the cache.
    Psf {
        #[arg(long, value_enum, default_value_t = CameraKind::PhaseCoded)]
        camera: CameraKind,
        /// Sub-frames per window.
        #[arg(long, default_value_t = 9, value_parser = clap::value_parser!(u16).range(1..=64))]
        window: u16,
        /// Repeats; the median is reported.
        #[arg(long, default_value_t = 7, value_parser = clap::value_parser!(u16).range(1..=1000))]
        repeats: u16,
    },
    #[cfg(feature = "ffmpeg")]
    /// Decoding speed: the pipeline's decoder (decode + RGB planes, its own conversion and
    /// swscale's) beside FFmpeg's decode-only speed of the same clip, in alternating rounds.
    Decode {
        #[command(flatten)]
        clip: ClipArgs,
        /// Rounds; medians are reported.
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u16).range(1..=100))]
        repeats: u16,
    },
    #[cfg(feature = "ffmpeg")]
    /// Generation speed (full frame and patch mode) beside FFmpeg's decode-only speed of the
    /// same clip, which it makes with the ffmpeg CLI; peak memory on a clip twice as long.
    Generate {
        #[command(flatten)]
        clip: ClipArgs,
        /// Repeats; the median is reported.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..=100))]
        repeats: u16,
    },
    /// Training step and forward speed per 128x128 patch of shallow-32 and U-Net 16, 32 and 64
    /// on the fast CPU path, beside PyTorch CPU on the same architectures with the same thread
    /// count (RAYON_NUM_THREADS, else all cores) when torch is importable by python3 or by
    /// $PIPELINE_PYTHON; prints each time ratio (ours / PyTorch's) and JSON on stdout.
    #[cfg(feature = "train")]
    Train {
        /// Patches per training step.
        #[arg(long, default_value_t = 8)]
        batch: usize,
        /// Repeats; the median is reported.
        #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u16).range(1..=100))]
        repeats: u16,
        /// Skip the paper's full-width U-Net (base 64).
        #[arg(long)]
        quick: bool,
        /// Also time burn's own CPU path (the reference the fast path replaces; slow).
        #[arg(long)]
        burn: bool,
    },
}

/// Runs `pipeline bench ...`.
///
/// # Errors
/// A benchmark that cannot run (no ffmpeg CLI, an unwritable temporary folder).
pub fn command(c: BenchCommand) -> anyhow::Result<()> {
    match c {
        #[cfg(feature = "train")]
        BenchCommand::Train { batch, repeats, quick, burn } => {
            use crate::model::Arch;
            let mut archs = vec![Arch::Shallow { width: 32 }, Arch::Unet { base: 16 }, Arch::Unet { base: 32 }];
            if !quick {
                archs.push(Arch::Unet { base: 64 });
            }
            let r = train(&archs, batch, repeats as usize, burn)?;
            println!("{}", serde_json::to_string_pretty(&r)?);
            Ok(())
        }
        #[cfg(feature = "train")]
        BenchCommand::Deblur { width, height, repeats } => {
            let r = deblur(width, height, repeats as usize)?;
            println!("{}", serde_json::to_string_pretty(&r)?);
            Ok(())
        }
        #[cfg(feature = "ffmpeg")]
        BenchCommand::Decode { clip: c, repeats } => {
            let r = decode(c.width, c.height, c.fps, c.seconds, repeats as usize)?;
            println!("{}", serde_json::to_string_pretty(&r)?);
            Ok(())
        }
        #[cfg(feature = "ffmpeg")]
        BenchCommand::Generate { clip: c, repeats } => {
            let r = generate(c.width, c.height, c.fps, c.seconds, repeats as usize)?;
            println!("{}", serde_json::to_string_pretty(&r)?);
            Ok(())
        }
        BenchCommand::Psf { camera, window, repeats } => {
            let r = psf(camera, window as usize, repeats as usize);
            eprintln!(
                "{} window {}: kernels {} px; cold {:.1} ms (median of {}), cached {:.2} us; ratio {:.0}x",
                r.camera,
                r.window,
                r.kernel_px,
                r.cold_ms_median,
                r.repeats,
                r.cached_us_median,
                r.cold_ms_median * 1e3 / r.cached_us_median.max(1e-9)
            );
            println!("{}", serde_json::to_string_pretty(&r)?);
            Ok(())
        }
    }
}
