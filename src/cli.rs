//! The command line: clap definitions and dispatch. `main.rs` only calls [`run`].

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
moving point change colour along its path (blue, then green, then red). `pipeline` models that camera \
and the cameras it is compared with, and looks at their PSFs.",
    after_help = "Examples:\n  pipeline psf --camera phase_coded --psi 0:8:33 --out psfs.npy\n  pipeline psf --camera flutter --window 9 --out flutter.png\n  pipeline psf --help"
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
    /// Measure speed (medians of repeats); not part of the tests.
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
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
            toml::from_str::<OpticsFile>(&text)
                .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?
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

/// Runs a parsed command line.
///
/// # Errors
/// Whatever the command reports; the binary prints it with its cause chain.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Psf(a) => run_psf(a),
        Command::Bench(BenchCommand::Psf {
            camera,
            window,
            repeats,
        }) => {
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
