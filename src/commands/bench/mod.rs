//! `pipeline bench`: measured speed, kept apart from the tests. Each figure is the median of
//! several repeats because the machines are shared and noisy.
//!
//! One file per benchmark, each with its baseline (FFmpeg decode-only, PyTorch on the same
//! network and thread count) and its report: `psf.rs`, `decode.rs`, `generate.rs`, `train.rs`,
//! `deblur.rs`, `kernels.rs` (one convolution layer, direct against Winograd); `clip.rs` makes
//! test clips and times FFmpeg with its CLI.

use crate::optics::{Camera, CameraConfig, CameraKind, OpticsConfig};
use std::time::Instant;

#[cfg(feature = "ffmpeg")]
mod clip;
#[cfg(feature = "infer")]
mod deblur;
mod decode;
mod generate;
#[cfg(feature = "infer")]
mod kernels;
mod psf;
#[cfg(feature = "train")]
mod train;
#[cfg(feature = "ffmpeg")]
use clip::*;
#[cfg(feature = "infer")]
pub use deblur::*;
pub use decode::*;
pub use generate::*;
#[cfg(feature = "infer")]
pub use kernels::*;
pub use psf::*;
#[cfg(feature = "train")]
pub use train::*;

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

/// The Python that runs the PyTorch and SciPy baselines: `PIPELINE_PYTHON`, else `python3`.
#[cfg_attr(not(feature = "ffmpeg"), allow(dead_code))] // used by the benches that need FFmpeg
pub(super) fn python() -> String {
    std::env::var("PIPELINE_PYTHON").unwrap_or_else(|_| "python3".into())
}

/// Whether [`python`] imports `modules` (`"numpy, scipy"`): a baseline that needs them runs.
#[cfg_attr(not(feature = "ffmpeg"), allow(dead_code))] // used by the benches that need FFmpeg
pub(super) fn python_imports(modules: &str) -> bool {
    std::process::Command::new(python())
        .args(["-c", &format!("import {modules}")])
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// `benches/torch_models.py` when [`python`] can import torch (the PyTorch baseline), else `None`.
#[cfg(feature = "infer")]
pub(super) fn torch_script() -> Option<std::path::PathBuf> {
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("benches/torch_models.py");
    (python_imports("torch") && script.exists()).then_some(script)
}

/// What `benches/torch_models.py` prints for `args` (one JSON object), run on as many threads as
/// ours; `None` when it fails.
#[cfg(feature = "infer")]
pub(super) fn torch_json(script: &std::path::Path, args: &[&str]) -> Option<serde_json::Value> {
    std::process::Command::new(python())
        .arg(script)
        .env("TORCH_THREADS", rayon::current_num_threads().to_string())
        .args(args)
        .output()
        .ok()
        .and_then(|o| serde_json::from_slice(&o.stdout).ok())
}

/// Resets the peak-RSS counter (Linux 4.0+); false where unsupported.
pub fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
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
    #[cfg(feature = "infer")]
    Deblur {
        #[arg(long, default_value_t = 1280)]
        width: usize,
        #[arg(long, default_value_t = 720)]
        height: usize,
        /// Repeats; the median is reported.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..=1000))]
        repeats: u16,
        /// Also time K frames from one capture with each U-Net as a burst U-Net: once through
        /// `deblur --burst` (the time-independent part once) against K whole passes.
        #[arg(long, value_name = "K", value_parser = clap::value_parser!(u16).range(2..=64))]
        burst: Option<u16>,
    },
    /// One 3x3 convolution layer of the fast path at the U-Nets' channel counts and sizes on a
    /// 128 px patch, the direct convolution against Winograd F(2x2, 3x3): where the fast path
    /// switches (it takes Winograd where it says `taken`).
    #[cfg(feature = "infer")]
    Kernels {
        /// Repeats each way; the median is reported.
        #[arg(long, default_value_t = 31, value_parser = clap::value_parser!(u16).range(1..=1000))]
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
        /// Rounds alternating PyTorch and the fast path (each `repeats` steps); every ratio
        /// is the median of the rounds' own ratios.
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..=20))]
        rounds: u16,
        /// Skip the paper's full-width U-Net (base 64).
        #[arg(long)]
        quick: bool,
        /// Time only these networks (repeat the flag for several), e.g. `--only unet-16` to
        /// measure one change to the trainer in a few minutes.
        #[arg(long, value_name = "NETWORK", conflicts_with = "quick", value_parser = ["shallow-32", "unet-16", "unet-32", "unet-64"])]
        only: Vec<String>,
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
        BenchCommand::Train { batch, repeats, rounds, quick, only, burn } => {
            use crate::model::Arch;
            let all = [
                ("shallow-32", Arch::Shallow { width: 32 }),
                ("unet-16", Arch::Unet { base: 16 }),
                ("unet-32", Arch::Unet { base: 32 }),
                ("unet-64", Arch::Unet { base: 64 }),
            ];
            let archs: Vec<Arch> = all
                .into_iter()
                .filter(|(name, _)| if only.is_empty() { !(quick && *name == "unet-64") } else { only.iter().any(|o| o == name) })
                .map(|(_, a)| a)
                .collect();
            let r = train(&archs, batch, repeats as usize, rounds as usize, burn)?;
            println!("{}", serde_json::to_string_pretty(&r)?);
            Ok(())
        }
        #[cfg(feature = "infer")]
        BenchCommand::Deblur { width, height, repeats, burst } => {
            let r = deblur(width, height, repeats as usize, burst.map(usize::from))?;
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
        #[cfg(feature = "infer")]
        BenchCommand::Kernels { repeats } => {
            let r = kernels(repeats as usize);
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
