//! The command line: clap definitions and dispatch. `main.rs` only calls [`run`].

use crate::graph::{ProgressMode, RunOptions};
use crate::optics::{CameraConfig, CameraKind, Dispersion, OpticsConfig, Spectrum};
use crate::psfcmd::{self, PsfRequest};
use anyhow::{bail, Context};
use clap::{Args, Parser, Subcommand};
use std::path::PathBuf;

#[derive(Parser, Debug)]
#[command(
    name = "pipeline",
    version,
    about = "Motion deblurring with a spatiotemporally phase-coded camera",
    long_about = "Motion deblurring with a spatiotemporally phase-coded camera (Elmalem, Giryes and Marom).\n\n\
A ring phase mask in the lens aperture plus a focus sweep during the exposure makes the blur of a \
moving point change colour along its path (blue, then green, then red), so a network can read the \
direction and extent of motion and undo it. `pipeline` models that camera and the cameras it is \
compared with, makes coded-blur training data from high-frame-rate video, and trains the paper's \
networks on it.",
    after_help = "Examples:\n  pipeline psf --camera phase_coded --psi 0:8:33 --out psfs.npy     the coded camera's PSFs\n  pipeline generate clip.mp4 -o out/                                training pairs as WebDataset shards\n  pipeline run pipelines/stills.toml -o out/stills                  the same from still images\n  pipeline train --config pipelines/train.toml                      train the U-Net on them\n  pipeline deblur coded.mp4 -o sharp.mp4                            deblur a video or an image folder\n  pipeline eval clip.mp4 -o eval-out/                               the paper's Table 1 on your footage\n  pipeline figure spoke -o fig5.png                                 the comparison figures\n  pipeline validate pipelines/*.toml                                check configs\n\nEvery command has --help with its own examples."
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Compute a camera's PSFs; print a table and write .npy, .exr or a .png strip.
    #[command(
        after_help = "Examples:\n  pipeline psf --psi 0:8:9 --out strip.png            lens PSF of the coded camera at 9 psi values\n  pipeline psf --psi 0,4,8 --out psfs.npy             (3, H, W, 3) float32, R G B, each channel sums to 1\n  pipeline psf --camera parabolic --window 9 --out k.png   the 9 sub-frame kernels of one exposure\n  pipeline psf --config optics.toml --psi 0:8:33      [optics] and [camera] tables from a file"
    )]
    Psf(PsfArgs),
    /// Make coded-blur training data from videos with the default generate pipeline.
    #[command(
        after_help = "Examples:\n  pipeline generate clip.mp4 -o out/                       patches in WebDataset shards\n  pipeline generate clips/ -o out/ --set transforms.blur.camera.type=conventional\n  pipeline generate a.mp4 b.mkv -o out/ --shard-index 0 --shard-count 2\n\nThe default pipeline is pipelines/generate.toml (embedded); see it for every key."
    )]
    Generate(GenerateArgs),
    /// Run a pipeline file.
    Run(RunArgs),
    /// Train the U-Net or the shallow model on generated shards (Huber loss, Adam).
    #[cfg(feature = "train")]
    #[command(
        after_help = "Examples:\n  pipeline train --config pipelines/train.toml\n  pipeline train --config pipelines/train.toml --set optim.steps=2000 --resume\n  pipeline train --config pipelines/train-shallow.toml --set output.dir=runs/shallow\n\nWrites checkpoints (model-STEP.safetensors + optimizer state), latest.json, report.json and\ncurves.png to output.dir."
    )]
    Train {
        /// Training file (TOML): [model], [data], [optim], [validate], [output].
        #[arg(long)]
        config: PathBuf,
        /// Override one key: --set optim.steps=500 (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
        /// Continue from output.dir/latest.json with the same data order.
        #[arg(long)]
        resume: bool,
        /// Progress display on stderr.
        #[arg(long, value_enum, default_value_t = ProgressMode::Auto)]
        progress: ProgressMode,
    },
    /// Deblur a video (same size and frame rate) or a folder of images (same names and formats).
    #[cfg(feature = "train")]
    #[command(
        after_help = "Examples:\n  pipeline deblur coded.mp4 -o sharp.mp4                  the shipped default model\n  pipeline deblur coded.mkv -o sharp.mkv --lossless       FFV1, lossless RGB\n  pipeline deblur frames/ -o sharp/ --model runs/unet16/model-0000300.safetensors\n\nWrites OUTPUT and OUTPUT.report.json (frames, size, frame rate, frames/s). Audio is not copied."
    )]
    Deblur {
        /// A video FFmpeg reads, or a folder (or glob) of PNG, JPEG, TIFF or OpenEXR images.
        input: PathBuf,
        /// Output video (.mp4, .mkv, .mov...) or folder.
        #[arg(short, long)]
        out: PathBuf,
        /// A model written by `pipeline train`; default: the shipped U-Net 16 (coded camera).
        #[arg(long)]
        model: Option<PathBuf>,
        /// Tile size in pixels (frames are processed in tiles with blended seams); default 1280 (a 720p frame in one pass; smaller tiles use less memory).
        #[arg(long)]
        tile: Option<usize>,
        /// Overlap between tiles in pixels; default 64 (the U-Net sees about 100 px around a pixel).
        #[arg(long)]
        overlap: Option<usize>,
        /// Lossless output (FFV1 RGB in .mkv) instead of H.264.
        #[arg(long)]
        lossless: bool,
        #[command(flatten)]
        file: ConfigArgs,
    },
    /// Score a model the way the paper's Table 1 does: windows of N = 7..13 frames from your
    /// videos, noise sigma 0..3, PSNR/SSIM (RGB and Y) of the deblurred frame and of the blurred
    /// input against the sharp middle frame.
    #[cfg(all(feature = "train", feature = "ffmpeg"))]
    #[command(
        after_help = "Examples:\n  pipeline eval clip.mp4 -o eval-out/                         the shipped model, coded camera\n  pipeline eval clips/ --model models/unet16-conventional/model.safetensors --camera conventional -o eval-conv/\n  pipeline eval clip.mp4 --set eval.crop=256 --set 'eval.windows=[9]'\n\nWrites eval.json (every window, the means, the config), eval.md (Table 1 and per-sigma\ntables) and examples/*.png (blurred | deblurred | sharp). Keys: pipelines/eval.toml (embedded)."
    )]
    Eval {
        /// Videos (files, folders or globs) at a high frame rate: each frame is one sub-frame.
        #[arg(required = true)]
        videos: Vec<String>,
        /// Output folder.
        #[arg(short, long, default_value = "eval-out")]
        out: PathBuf,
        /// A model written by `pipeline train`; default: the shipped U-Net 16 (coded camera).
        #[arg(long)]
        model: Option<PathBuf>,
        /// The camera that blurs the test windows (overrides camera.type); use the one the model
        /// was trained for.
        #[arg(long, value_enum)]
        camera: Option<CameraKind>,
        #[command(flatten)]
        file: ConfigArgs,
    },
    /// Draw one of the paper's comparison figures (conventional, fluttered shutter, parabolic
    /// motion and the coded camera) as a labelled PNG.
    #[cfg(feature = "train")]
    #[command(
        after_help = "Figures:\n  psf-strip   Fig. 2: a moving point through a conventional camera, a focus sweep without the\n              mask, and the coded camera (blue -> green -> red along the path)\n  dots        Fig. 3: moving dots through all four cameras, with noise\n  spectrum    Fig. 4: (x, t) slice of a moving point's PSF, its 2-D Fourier amplitude and phase\n  spoke       Fig. 5: rotating spoke target, captures and reconstructions (flutter least squares,\n              parabolic Lucy-Richardson, the shipped U-Nets); FILE.md and FILE.json with PSNR/SSIM\n\nExamples:\n  pipeline figure psf-strip -o fig2.png\n  pipeline figure spoke -o fig5.png --sigma 3 --travel 16"
    )]
    Figure {
        /// Which figure.
        #[arg(value_enum)]
        name: crate::figure::FigureName,
        /// Output PNG.
        #[arg(short, long)]
        out: PathBuf,
        /// AWGN sigma on the 0-255 scale (the fluttered shutter gets twice: half the light).
        #[arg(long, default_value_t = 3.0)]
        sigma: f64,
        /// Pixels travelled over the exposure by the fastest dot / the spoke target's rim.
        #[arg(long, default_value_t = 16.0)]
        travel: f64,
        /// Scene side in pixels.
        #[arg(long, default_value_t = 192)]
        size: usize,
        /// Folder with the shipped models (unet16-coded, unet16-conventional).
        #[arg(long, default_value = "models")]
        models: PathBuf,
        /// Seed of the noise.
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Lucy-Richardson iterations for the parabolic camera (spoke).
        #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u32).range(1..=10_000))]
        lr_iterations: u32,
        /// Tikhonov weight of the flutter least squares (spoke), above 0: an image row does not
        /// see the scene beyond the frame, so plain least squares is singular there.
        #[arg(long, default_value_t = 1e-2)]
        flutter_lambda: f64,
    },
    /// Check pipeline files and report every error, each naming its key.
    Validate {
        /// Pipeline files.
        #[arg(required = true)]
        pipelines: Vec<PathBuf>,
        /// key.path=value overrides, as for `run`.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        sets: Vec<String>,
    },
    /// Measure speed (medians of repeats); not part of the tests.
    #[command(subcommand)]
    Bench(BenchCommand),
}

/// `--config`, `--set` and `--progress` of the commands that read one settings file
/// (`deblur`: pipelines/deblur.toml, `eval`: pipelines/eval.toml).
#[derive(Args, Debug)]
pub struct ConfigArgs {
    /// The command's settings file; default: its pipelines/*.toml, embedded in the binary.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override one key of that file: --set deblur.tile=512, --set eval.crop=256 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
    #[arg(long, value_enum, default_value_t = ProgressMode::Auto)]
    pub progress: ProgressMode,
}

impl ConfigArgs {
    /// The file, or the embedded default `name`, with the overrides applied; and its name.
    fn load(&self, embedded: &str, name: &str) -> crate::Result<(toml::Table, String)> {
        load_or_embedded(self.config.as_deref(), embedded, name, &self.sets)
    }

    fn bar(&self) -> bool {
        bars(self.progress)
    }
}

/// Progress bars: on a terminal, unless told otherwise.
fn bars(progress: ProgressMode) -> bool {
    progress == ProgressMode::Auto && std::io::IsTerminal::is_terminal(&std::io::stderr())
}

#[derive(Subcommand, Debug)]
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
    /// Generation speed (full frame and patch mode) beside FFmpeg's decode-only speed of the
    /// same clip, which it makes with the ffmpeg CLI; peak memory on a clip twice as long.
    Generate {
        #[arg(long, default_value_t = 1280)]
        width: usize,
        #[arg(long, default_value_t = 720)]
        height: usize,
        #[arg(long, default_value_t = 240)]
        fps: u32,
        /// Length of the clip.
        #[arg(long, default_value_t = 2.0)]
        seconds: f64,
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

/// Options shared by the commands that run a pipeline.
#[derive(Args, Debug, Clone)]
pub struct RunCommon {
    /// Override one key of the pipeline file: --set transforms.noise.sigma=3 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
    /// This task's share of the sorted inputs (input i goes to task i % count). Default:
    /// SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX, else 0.
    #[arg(long)]
    pub shard_index: Option<usize>,
    /// Number of tasks. Default: SLURM_ARRAY_TASK_COUNT, else 1.
    #[arg(long)]
    pub shard_count: Option<usize>,
    /// Progress display on stderr.
    #[arg(long, value_enum, default_value_t = ProgressMode::Auto)]
    pub progress: ProgressMode,
}

#[derive(Args, Debug)]
pub struct GenerateArgs {
    /// Video files, folders of videos, or file-name globs; default: the pipeline's paths.
    pub videos: Vec<String>,
    /// Output folder (shards, manifest.json, report.json).
    #[arg(short, long)]
    pub out: Option<PathBuf>,
    /// Pipeline file instead of the embedded pipelines/generate.toml.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[command(flatten)]
    pub common: RunCommon,
}

#[derive(Args, Debug)]
pub struct RunArgs {
    /// Pipeline file (TOML).
    pub pipeline: PathBuf,
    /// Output folder (sets the sink's dir).
    #[arg(short, long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub common: RunCommon,
}

#[derive(Args, Debug)]
pub struct PsfArgs {
    /// Camera model. With --psi: phase_coded shows the masked lens, every other camera the clear
    /// aperture. With --window: that camera's sub-frame kernels.
    #[arg(long, value_enum, default_value_t = CameraKind::PhaseCoded)]
    pub camera: CameraKind,
    /// psi values (defocus at 455 nm, radians at the pupil rim): start:stop:count or a comma list.
    #[arg(long, value_parser = parse_psi, conflicts_with = "window", allow_hyphen_values = true)]
    pub psi: Option<PsiList>,
    /// Instead of --psi: the N sub-frame kernels of one exposure window (1 to 64).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=64))]
    pub window: Option<u16>,
    /// Output file: .npy (K, H, W, 3) float32; .exr linear, tiles side by side; .png tone-mapped strip.
    #[arg(long, short)]
    pub out: Option<PathBuf>,
    /// TOML file with [optics] and/or [camera] tables (flags below override it).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Airy radius (first dark ring) at 455 nm in video pixels; default from f = 12 mm,
    /// R = 1.14 mm, 1.25 um pixels: 2.34 px.
    #[arg(long, value_parser = parse_positive, allow_hyphen_values = true)]
    pub airy_radius_px: Option<f64>,
    /// Spectral model of the colour channels.
    #[arg(long, value_enum)]
    pub spectrum: Option<Spectrum>,
    /// Dispersion of the mask material.
    #[arg(long, value_enum)]
    pub dispersion: Option<Dispersion>,
    /// Sign of the defocus relative to the mask phase (1 is the paper's convention).
    #[arg(long, allow_hyphen_values = true, value_parser = parse_sign)]
    pub defocus_sign: Option<f64>,
    /// Pixel zoom of the PNG strip.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u16).range(1..=32))]
    pub zoom: u16,
}

/// A list of psi values from `start:stop:count` or `a,b,c`.
#[derive(Debug, Clone)]
pub struct PsiList(pub Vec<f64>);

fn parse_psi(s: &str) -> Result<PsiList, String> {
    psfcmd::parse_psi_list(s).map(PsiList)
}

fn parse_positive(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("{s:?} is not a positive number")),
    }
}

fn parse_sign(s: &str) -> Result<f64, String> {
    match s.trim() {
        "1" | "+1" => Ok(1.0),
        "-1" => Ok(-1.0),
        _ => Err(format!("{s:?} is not 1 or -1")),
    }
}

/// `[optics]` and `[camera]` read from a file.
#[derive(serde::Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
struct OpticsFile {
    optics: OpticsConfig,
    camera: Option<CameraConfig>,
}

fn run_psf(a: PsfArgs) -> anyhow::Result<()> {
    let file = match &a.config {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("{}", p.display()))?;
            toml::from_str::<OpticsFile>(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?
        }
        None => OpticsFile::default(),
    };
    let mut optics = file.optics;
    let mut camera = file.camera.unwrap_or_else(|| CameraConfig::new(a.camera));
    if a.config.is_none() || a.camera != CameraKind::PhaseCoded {
        camera.kind = a.camera;
    }
    if let Some(v) = a.airy_radius_px {
        optics.airy_radius_px = Some(v);
    }
    if let Some(v) = a.spectrum {
        optics.spectrum = v;
    }
    if let Some(v) = a.dispersion {
        optics.dispersion = v;
    }
    if let Some(v) = a.defocus_sign {
        optics.defocus_sign = v;
    }
    let mut errs = optics.validate("optics");
    errs.extend(camera.validate("camera"));
    if !errs.is_empty() {
        return Err(crate::Error::Config(errs).into());
    }
    let req = match (a.psi, a.window) {
        (Some(p), None) => PsfRequest::Psi(p.0),
        (None, Some(n)) => PsfRequest::Window(n as usize),
        (None, None) => PsfRequest::Psi(psfcmd::parse_psi_list("0:8:9").expect("default psi list")),
        (Some(_), Some(_)) => bail!("--psi and --window exclude each other"),
    };
    let window = matches!(req, PsfRequest::Window(_));
    let t0 = std::time::Instant::now();
    let rows = psfcmd::compute(&optics, &camera, &req)?;
    eprintln!(
        "{} PSFs of {} px ({}, Airy radius {:.2} px at {} nm) in {:.2} s",
        rows.len(),
        rows.first().map_or(0, |r| r.psf.size),
        camera.kind.name(),
        optics.airy_radius_ref_px(),
        optics.ref_wavelength_nm,
        t0.elapsed().as_secs_f64()
    );
    print!("{}", psfcmd::table(&rows, window));
    if !window {
        for (psi, from, to) in psfcmd::transitions(&rows) {
            println!("sharpest channel changes {from} -> {to} near psi {psi:.2}");
        }
    }
    if let Some(out) = &a.out {
        psfcmd::write(&rows, out, a.zoom as usize)?;
        eprintln!("wrote {}", out.display());
    }
    Ok(())
}

/// The default generate pipeline, embedded.
pub const GENERATE_TOML: &str = include_str!("../pipelines/generate.toml");

fn env_usize(name: &str) -> anyhow::Result<Option<usize>> {
    match std::env::var(name) {
        Ok(v) if !v.trim().is_empty() => v.trim().parse().map(Some).map_err(|_| anyhow::anyhow!("{name}={v:?} is not a whole number")),
        _ => Ok(None),
    }
}

/// Task index and count from flags, then Slurm or Kubernetes variables.
fn task_split(c: &RunCommon) -> anyhow::Result<(usize, usize)> {
    let (index, index_from) = match c.shard_index {
        Some(i) => (i, "--shard-index"),
        None => match (env_usize("SLURM_ARRAY_TASK_ID")?, env_usize("JOB_COMPLETION_INDEX")?) {
            (Some(i), _) => (i, "SLURM_ARRAY_TASK_ID"),
            (None, Some(i)) => (i, "JOB_COMPLETION_INDEX"),
            (None, None) => (0, "the default"),
        },
    };
    let (count, count_from) = match c.shard_count {
        Some(n) => (n, "--shard-count"),
        None => match env_usize("SLURM_ARRAY_TASK_COUNT")? {
            Some(n) => (n, "SLURM_ARRAY_TASK_COUNT"),
            None => (1, "the default"),
        },
    };
    if count == 0 {
        return Err(crate::Error::Usage(format!("{count_from} is 0; the task count must be at least 1")).into());
    }
    if index >= count {
        let hint = if count_from == "SLURM_ARRAY_TASK_COUNT" {
            " (a retried single array element such as `sbatch --array=17` sees a task count of 1: pass the whole job's count with --shard-count, as docs/scaling.md does)"
        } else if count_from == "the default" {
            " (pass the number of tasks with --shard-count)"
        } else {
            ""
        };
        return Err(crate::Error::Usage(format!(
            "task index {index} (from {index_from}) must be below the task count {count} (from {count_from}){hint}"
        ))
        .into());
    }
    Ok((index, count))
}

fn run_plan(table: toml::Table, origin: &crate::config::Origin, out: Option<&PathBuf>, c: &RunCommon) -> anyhow::Result<()> {
    let mut plan = crate::config::plan_from(table, origin)?;
    if let Some(o) = out {
        plan.set_out_dir(o);
    }
    let (task_index, task_count) = task_split(c)?;
    let opts = RunOptions { task_index, task_count, progress: c.progress };
    let o = crate::graph::run(&plan, &opts)?;
    let r = &o.report;
    eprintln!(
        "{} inputs done ({} skipped as already in the manifest), {} frames, {} windows, {} samples in {:.1} s: {:.1} frames/s, {:.1} sub-frames/s blurred -> {}",
        r.inputs_done,
        r.inputs_skipped.len(),
        r.frames,
        r.windows,
        r.samples,
        r.seconds,
        r.frames_per_s,
        r.subframes_per_s,
        o.out_dir.display()
    );
    if !r.inputs_failed.is_empty() {
        for f in &r.inputs_failed {
            eprintln!("failed: {}", f.error);
        }
        return Err(crate::Error::InputsFailed(r.inputs_failed.len()).into());
    }
    Ok(())
}

/// Checks a TOML file of any kind `pipeline` reads: a training file (`[model]`), an optics
/// file (`[optics]`/`[camera]` only) or a pipeline; says what it is.
fn describe(table: toml::Table, origin: &crate::config::Origin) -> crate::Result<String> {
    let origin_name = origin.name.as_str();
    #[cfg(all(feature = "train", feature = "ffmpeg"))]
    if table.contains_key("eval") {
        let f = crate::eval::EvalFile::from_table(table, origin_name)?;
        return Ok(format!("eval file: N {:?}, sigma {:?}, camera {}", f.eval.windows, f.eval.sigmas, f.camera.kind.name()));
    }
    #[cfg(feature = "train")]
    if table.contains_key("deblur") {
        let f = crate::deblur::DeblurFile::from_table(table, origin_name)?;
        return Ok(format!("deblur file: tiles {} px, overlap {}", f.deblur.tile, f.deblur.overlap));
    }
    #[cfg(feature = "train")]
    if table.contains_key("model") {
        let (cfg, mut errs) = crate::config::deserialize_all::<crate::train::TrainConfig>(&table);
        if let Some(c) = &cfg {
            errs.extend(c.validate());
        }
        match cfg {
            Some(cfg) if errs.is_empty() => return Ok(format!("training file: {}, {} steps", cfg.model.name(), cfg.optim.steps)),
            _ => return Err(origin.errors(errs)),
        }
    }
    if !table.contains_key("sources") && (table.contains_key("optics") || table.contains_key("camera")) {
        let f: OpticsFile = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| crate::Error::ConfigText(format!("{origin_name}: {}", e.to_string().trim())))?;
        let mut errs = f.optics.validate("optics");
        if let Some(c) = &f.camera {
            errs.extend(c.validate("camera"));
        }
        if !errs.is_empty() {
            return Err(crate::Error::Config(errs));
        }
        return Ok(format!("optics file: Airy radius {:.2} px", f.optics.airy_radius_ref_px()));
    }
    let plan = crate::config::plan_from(table, origin)?;
    Ok(plan.stages.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>().join(" -> "))
}

/// The file given with `--config`, or the embedded default named `name`, with `--set` applied;
/// and the name to put in error messages.
fn load_or_embedded(config: Option<&std::path::Path>, embedded: &str, name: &str, sets: &[String]) -> crate::Result<(toml::Table, String)> {
    match config {
        Some(p) => Ok((crate::config::load(p, sets)?, p.display().to_string())),
        None => {
            let origin = format!("{name} (embedded)");
            Ok((crate::config::parse(embedded, &origin, sets)?, origin))
        }
    }
}

/// Runs a parsed command line.
///
/// # Errors
/// Whatever the command reports; the binary prints it with its cause chain.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Psf(a) => run_psf(a),
        Command::Generate(a) => {
            let (mut table, origin) = load_or_embedded(a.config.as_deref(), GENERATE_TOML, "pipelines/generate.toml", &[])?;
            if !a.videos.is_empty() {
                let sources = table
                    .get_mut("sources")
                    .and_then(|s| s.as_table_mut())
                    .ok_or_else(|| anyhow::anyhow!("the pipeline has no [sources]"))?;
                for (_, src) in sources.iter_mut() {
                    if let Some(t) = src.as_table_mut() {
                        t.insert("paths".into(), toml::Value::Array(a.videos.iter().map(|v| toml::Value::String(v.clone())).collect()));
                    }
                }
            }
            crate::config::apply_sets(&mut table, &a.common.sets).map_err(crate::Error::ConfigText)?;
            let text = a.config.is_none().then_some(GENERATE_TOML);
            run_plan(table, &crate::config::Origin::new(&origin, text, &a.common.sets), a.out.as_ref(), &a.common)
        }
        #[cfg(feature = "train")]
        Command::Train { config, sets, resume, progress } => {
            let table = crate::config::load(&config, &sets)?;
            let origin = crate::config::Origin::new(&config.display().to_string(), None, &sets);
            let cfg = match crate::config::deserialize_all::<crate::train::TrainConfig>(&table) {
                (Some(cfg), errs) if errs.is_empty() => cfg,
                (_, errs) => return Err(origin.errors(errs).into()),
            };
            let bar = bars(progress);
            let r = crate::train::train(&cfg, &crate::train::TrainOptions { resume, progress: bar, stop_after: None })?;
            let last = r.validation.last();
            eprintln!(
                "{}: {} steps in {:.0} s ({:.1} patches/s){} -> {}",
                r.arch,
                r.steps,
                r.seconds,
                r.patches_per_s,
                last.map_or(String::new(), |v| format!(
                    ", validation PSNR {:.2} dB / SSIM {:.4} (blurred input {:.2} / {:.4})",
                    v.model.psnr_rgb, v.model.ssim_rgb, v.input.psnr_rgb, v.input.ssim_rgb
                )),
                cfg.output.dir
            );
            Ok(())
        }
        #[cfg(feature = "train")]
        Command::Deblur { input, out, model, tile, overlap, lossless, file } => {
            let same = input.canonicalize().ok().zip(out.canonicalize().ok()).is_some_and(|(a, b)| a == b) || input == out;
            if same {
                bail!("{}: the output is the input; choose another output path", out.display());
            }
            let (table, origin) = file.load(crate::deblur::DEBLUR_TOML, "pipelines/deblur.toml")?;
            let mut d = crate::deblur::DeblurFile::from_table(table, &origin)?.deblur;
            d.tile = tile.unwrap_or(d.tile);
            d.overlap = overlap.unwrap_or(d.overlap);
            let lossless = lossless || d.lossless;
            let model = model.or_else(|| (!d.model.is_empty()).then(|| PathBuf::from(&d.model)));
            let (net, name) = crate::deblur::load(model.as_deref())?;
            let tiling = crate::deblur::Tiling { tile: d.tile, overlap: d.overlap };
            let bar = file.bar();
            let r = if input.is_dir() || input.to_string_lossy().contains('*') {
                crate::deblur::images(&net, &name, &input, &out, tiling, bar)?
            } else {
                crate::deblur::video(&net, &name, &input, &out, tiling, lossless, bar)?
            };
            let rp = if out.is_dir() { out.join("report.json") } else { PathBuf::from(format!("{}.report.json", out.display())) };
            crate::deblur::write_report(&rp, &r)?;
            eprintln!(
                "{} frames of {}x{} in {:.1} s ({:.2} frames/s) with {} -> {}",
                r.frames,
                r.width,
                r.height,
                r.seconds,
                r.frames_per_s,
                r.model,
                out.display()
            );
            if !r.failed.is_empty() {
                return Err(crate::Error::InputsFailed(r.failed.len()).into());
            }
            Ok(())
        }
        #[cfg(all(feature = "train", feature = "ffmpeg"))]
        Command::Eval { videos, out, model, camera, file } => {
            let (table, origin) = file.load(crate::eval::EVAL_TOML, "pipelines/eval.toml")?;
            let mut f = crate::eval::EvalFile::from_table(table, &origin)?;
            if let Some(k) = camera {
                f.camera.kind = k;
            }
            let (net, name) = crate::deblur::load(model.as_deref())?;
            let bar = file.bar();
            let r = crate::eval::run(&f, &net, &name, &videos, &out, bar)?;
            println!("{}", crate::eval::markdown(&r));
            eprintln!("{} windows scored in {:.0} s -> {}", r.records.len(), r.seconds, out.join("eval.md").display());
            Ok(())
        }
        #[cfg(feature = "train")]
        Command::Figure { name, out, sigma, travel, size, models, seed, lr_iterations, flutter_lambda } => {
            if !(0.0..=50.0).contains(&sigma) || !(0.0..=200.0).contains(&travel) || !(32..=2048).contains(&size) {
                bail!("--sigma must be in 0..50, --travel in 0..200 and --size in 32..2048");
            }
            if !(flutter_lambda > 0.0 && flutter_lambda <= 10.0) {
                bail!("--flutter-lambda must be above 0 and at most 10 (got {flutter_lambda})");
            }
            let o = crate::figure::FigureOptions {
                sigma,
                travel_px: travel,
                size,
                models,
                seed,
                lr_iterations: lr_iterations as usize,
                flutter_lambda,
                ..Default::default()
            };
            let r = crate::figure::draw(name, &o, &out)?;
            if !r.scores.is_empty() {
                println!("{}", crate::figure::scores_markdown(&r));
            }
            eprintln!("figure {:?} -> {}", name, out.display());
            Ok(())
        }
        Command::Run(a) => {
            let table = crate::config::load(&a.pipeline, &a.common.sets)?;
            let origin = crate::config::Origin::new(&a.pipeline.display().to_string(), None, &a.common.sets);
            run_plan(table, &origin, a.out.as_ref(), &a.common)
        }
        Command::Validate { pipelines, sets } => {
            let mut bad = 0;
            for p in &pipelines {
                let origin = crate::config::Origin::new(&p.display().to_string(), None, &sets);
                match crate::config::load(p, &sets).and_then(|t| describe(t, &origin)) {
                    Ok(what) => println!("{}: ok ({what})", p.display()),
                    Err(e) => {
                        bad += 1;
                        for line in e.to_string().lines() {
                            println!("{}: {line}", p.display());
                        }
                    }
                }
            }
            if bad > 0 {
                return Err(crate::Error::Config(vec![crate::optics::ConfigError {
                    key: "validate".into(),
                    message: format!("{bad} of {} pipeline files have errors", pipelines.len()),
                }])
                .into());
            }
            Ok(())
        }
        #[cfg(feature = "train")]
        Command::Bench(BenchCommand::Train { batch, repeats, quick, burn }) => {
            use crate::model::Arch;
            let mut archs = vec![Arch::Shallow { width: 32 }, Arch::Unet { base: 16 }, Arch::Unet { base: 32 }];
            if !quick {
                archs.push(Arch::Unet { base: 64 });
            }
            let r = crate::bench::train(&archs, batch, repeats as usize, burn)?;
            println!("{}", serde_json::to_string_pretty(&r)?);
            Ok(())
        }
        #[cfg(feature = "train")]
        Command::Bench(BenchCommand::Deblur { width, height, repeats }) => {
            let r = crate::bench::deblur(width, height, repeats as usize)?;
            println!("{}", serde_json::to_string_pretty(&r)?);
            Ok(())
        }
        Command::Bench(BenchCommand::Generate { width, height, fps, seconds, repeats }) => {
            let r = crate::bench::generate(width, height, fps, seconds, repeats as usize)?;
            println!("{}", serde_json::to_string_pretty(&r)?);
            Ok(())
        }
        Command::Bench(BenchCommand::Psf { camera, window, repeats }) => {
            let r = crate::bench::psf(camera, window as usize, repeats as usize);
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
