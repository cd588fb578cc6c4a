//! `pipeline calibrate`: a measured PSF stack from captures of a point source, one per instant of
//! the exposure (or per psi), in the format the `measured` camera reads: `.npy` float32 of shape
//! (K, H, W, 3), each channel of each entry normalised, cropped around the source. Beside it, a
//! report (`<out>.json`: dark level, noise, centroid, crop and signal per capture) and a contact
//! sheet (`<out>.png`, the tone-mapped strip of `pipeline psf`). The math is
//! [`crate::optics::calibrate`].

use crate::io::{npy, write_atomic};
use crate::optics::calibrate::{calibrate, Centre, Options, Planes};
use crate::optics::transfer::Curve;
use crate::{Error, Result};
use clap::Args;
use std::path::{Path, PathBuf};

/// Arguments of `pipeline calibrate`.
#[derive(Args, Debug)]
#[command(after_help = "Example, nine captures of a pinhole (one per ninth of the exposure) and a dark frame:
  pipeline calibrate captures/ --dark dark.png --size 31 -o lens.npy
  pipeline generate clip.mp4 -o out/ --set transforms.blur.camera.type='\"measured\"' \\
    --set transforms.blur.camera.psf_path='\"lens.npy\"'")]
pub struct CalibrateArgs {
    /// Captures of the point source, in order (files, folders or globs; PNG 8 or 16 bits, and
    /// TIFF or OpenEXR through FFmpeg). A folder is read in name order.
    #[arg(required = true)]
    pub captures: Vec<String>,
    /// The output stack (.npy); the report and contact sheet go beside it (.json, .png).
    #[arg(long, short)]
    pub out: PathBuf,
    /// A dark frame (the sensor with the source off), taken off every capture; without one the
    /// median of each capture's border is.
    #[arg(long)]
    pub dark: Option<PathBuf>,
    /// Side of the PSFs in pixels (odd).
    #[arg(long, default_value_t = 31)]
    pub size: usize,
    /// Values within this many noise deviations of the dark level count as zero. A PSF's faint
    /// halo sits near the noise: 1 loses least of it (measured on the coded camera's stack,
    /// where 3 misplaces twice the energy); average captures to raise the signal over the noise.
    #[arg(long, default_value_t = 1.0)]
    pub threshold: f64,
    /// One centre for the stack (keeps the shifts between captures) or each capture's own.
    #[arg(long, value_enum, default_value_t = Centre::Common)]
    pub centre: Centre,
    /// How the captures' values map to linear light (identity: linear raw data).
    #[arg(long, value_enum, default_value_t = Curve::Identity)]
    pub curve: Curve,
    /// Border width in pixels where the dark level and the noise are measured.
    #[arg(long, default_value_t = 8)]
    pub border: usize,
    /// Replace existing outputs.
    #[arg(long)]
    pub overwrite: bool,
}

/// One capture as linear planes: PNG by our reader, the rest through FFmpeg; 8- and 16-bit
/// values through `curve`, float (OpenEXR) as stored.
fn read(path: &Path, curve: Curve) -> Result<Planes> {
    let ext = path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    let lin = |v: f32| curve.to_linear(v as f64) as f32;
    if ext == "png" {
        let bytes = std::fs::read(path).map_err(|e| Error::Io { path: path.to_path_buf(), cause: e })?;
        let s = crate::io::png::read_samples(&bytes).map_err(Error::format(path))?;
        let n = s.width * s.height;
        let rgb = std::array::from_fn(|c| (0..n).map(|i| lin(s.get(i, if s.channels <= 2 { 0 } else { c }))).collect());
        return Ok(Planes { width: s.width, height: s.height, rgb });
    }
    #[cfg(feature = "ffmpeg")]
    {
        use crate::frame::FrameData;
        let (f, _) = crate::io::video::read_image_with(path).map_err(Error::video(path))?;
        let rgb = match &*f.data {
            FrameData::Planar8(p) => std::array::from_fn(|c| p[c].iter().map(|&v| lin(v as f32 / 255.0)).collect()),
            FrameData::Planar16(p) => std::array::from_fn(|c| p[c].iter().map(|&v| lin(v as f32 / 65535.0)).collect()),
            FrameData::Planar(p) => p.clone(),
            FrameData::Regions8(_) => unreachable!("only patch-mode decoding makes regions"),
        };
        Ok(Planes { width: f.width, height: f.height, rgb })
    }
    #[cfg(not(feature = "ffmpeg"))]
    Err(Error::File { path: path.to_path_buf(), why: "only PNG is read without the ffmpeg feature".into() })
}

/// Runs `pipeline calibrate`.
///
/// # Errors
/// No capture found, an unreadable capture (named), captures of different sizes, a capture
/// with no signal, an existing output without `--overwrite` (exit 2).
pub fn command(a: CalibrateArgs) -> anyhow::Result<()> {
    if a.out.extension().and_then(|e| e.to_str()) != Some("npy") {
        return Err(Error::Usage(format!("{}: the stack is written as .npy", a.out.display())).into());
    }
    let (report, sheet) = (a.out.with_extension("json"), a.out.with_extension("png"));
    let files = crate::io::paths::expand_paths(&a.captures, &["png", "tif", "tiff", "exr"])?;
    // A capture path that names nothing is a usage error (exit 2), as in `deblur`.
    if let Some(f) = files.iter().chain(&a.dark).find(|f| std::fs::symlink_metadata(f).is_err()) {
        return Err(Error::Usage(format!("{}: no such file or folder", f.display())).into());
    }
    let outputs = [a.out.clone(), report.clone(), sheet.clone()];
    crate::io::paths::refuse_replacing_inputs(&outputs, &files)?;
    let found: Vec<PathBuf> = outputs.iter().filter(|p| p.exists()).cloned().collect();
    crate::io::paths::refuse_replacing(&a.out, &found, a.overwrite)?;
    let captures = files.iter().map(|f| read(f, a.curve)).collect::<Result<Vec<_>>>()?;
    let dark = a.dark.as_deref().map(|d| read(d, a.curve)).transpose()?;
    let o = Options { size: a.size, threshold: a.threshold, centre: a.centre, border: a.border };
    let (psfs, entries) = calibrate(&captures, dark.as_ref(), &o).map_err(|e| Error::Usage(e.to_string()))?;
    let rows: Vec<crate::optics::request::PsfRow> = psfs
        .into_iter()
        .enumerate()
        .map(|(k, psf)| crate::optics::request::PsfRow { label: format!("k={k}"), psi: 0.0, weight: 1.0, shift: [0.0; 2], psf })
        .collect();
    let (shape, data) = crate::optics::request::to_hwc(&rows);
    write_atomic(&a.out, |w| npy::write_f32(w, &shape, &data))?;
    crate::commands::psf::write(&rows, &sheet, 4)?;
    let json = serde_json::json!({
        "version": env!("CARGO_PKG_VERSION"),
        "captures": files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>(),
        "dark": a.dark.as_ref().map(|d| d.display().to_string()),
        "size": a.size, "threshold": a.threshold, "centre": a.centre, "curve": a.curve.name(), "border": a.border,
        "shape": shape,
        "entries": entries,
    });
    write_atomic(&report, |w| w.write_all(serde_json::to_string_pretty(&json).expect("json").as_bytes()))?;
    let least = entries.iter().flat_map(|e| e.inside).fold(1.0, f64::min);
    eprintln!(
        "{} PSFs of {}x{} from {} captures{}; the crop holds at least {:.1}% of each capture's signal -> {} ({}, {})",
        rows.len(),
        a.size,
        a.size,
        files.len(),
        if dark.is_some() { " and a dark frame" } else { "" },
        100.0 * least,
        a.out.display(),
        report.display(),
        sheet.display()
    );
    if least < 0.95 {
        eprintln!("note: a crop of {} px loses more than 5% of some capture's signal; a larger --size keeps it", a.size);
    }
    Ok(())
}
