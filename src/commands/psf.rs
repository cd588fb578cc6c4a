//! `pipeline psf`: compute the PSFs of a camera and write them for people (a PNG strip like the
//! paper's Fig. 2, a table) and for tools (`.npy` of shape (K, H, W, 3), linear `.exr`).

use crate::io::{exr, font, npy, png as png_io, write_atomic};
pub use crate::optics::request::{check_psi, compute, parse_psi_list, resolve, to_hwc, PsfRequest, PsfRow, PsfSpec};
use crate::optics::{CameraKind, Dispersion, Psf, Spectrum};
use crate::{Error, Result};
use clap::Args;
use std::fmt::Write as _;
use std::path::Path;
use std::path::PathBuf;

const NAMES: [&str; 3] = ["R", "G", "B"];

/// The table printed by `pipeline psf`: psi, per-channel peak, 50%-energy radius, sharpest.
pub fn table(rows: &[PsfRow], window: bool) -> String {
    let mut s = String::new();
    let lead = if window { format!("{:>5} {:>7} {:>7} {:>13}", "k", "psi", "weight", "shift px") } else { format!("{:>7}", "psi") };
    let _ = writeln!(s, "{lead}  {:>8} {:>8} {:>8}  {:>6} {:>6} {:>6}  sharpest", "peak R", "peak G", "peak B", "r50 R", "r50 G", "r50 B");
    for (i, r) in rows.iter().enumerate() {
        let lead = if window {
            format!("{i:>5} {:>7.3} {:>7.4} {:>6.2},{:>6.2}", r.psi, r.weight, r.shift[0], r.shift[1])
        } else {
            format!("{:>7.3}", r.psi)
        };
        let _ = writeln!(
            s,
            "{lead}  {:>8.5} {:>8.5} {:>8.5}  {:>6.2} {:>6.2} {:>6.2}  {}",
            r.psf.peak(0),
            r.psf.peak(1),
            r.psf.peak(2),
            r.psf.energy_radius(0, 0.5),
            r.psf.energy_radius(1, 0.5),
            r.psf.energy_radius(2, 0.5),
            NAMES[r.psf.sharpest_channel()]
        );
    }
    s
}

/// psi values where the sharpest channel changes (midpoint between neighbouring rows).
pub fn transitions(rows: &[PsfRow]) -> Vec<(f64, &'static str, &'static str)> {
    rows.windows(2)
        .filter_map(|w| {
            let (a, b) = (w[0].psf.sharpest_channel(), w[1].psf.sharpest_channel());
            (a != b).then(|| (0.5 * (w[0].psi + w[1].psi), NAMES[a], NAMES[b]))
        })
        .collect()
}

/// Lays the tiles out in a grid of at most `per_row` columns, `gap` pixels apart, with a label
/// strip of `label_h` pixels under each; returns (width, height, planar RGB). `map` turns one
/// tile into display values.
fn mosaic(
    rows: &[PsfRow],
    zoom: usize,
    per_row: usize,
    gap: usize,
    label_h: usize,
    bg: f32,
    map: impl Fn(&Psf) -> [Vec<f32>; 3],
) -> (usize, usize, [Vec<f32>; 3]) {
    let n = rows.first().map_or(1, |r| r.psf.size);
    let t = n * zoom;
    let cols = rows.len().clamp(1, per_row);
    let lines = rows.len().div_ceil(cols).max(1);
    let (w, h) = (cols * t + (cols + 1) * gap, lines * (t + label_h) + (lines + 1) * gap);
    let mut out = [vec![bg; w * h], vec![bg; w * h], vec![bg; w * h]];
    for (i, r) in rows.iter().enumerate() {
        let tile = map(&r.psf);
        let (ox, oy) = (gap + (i % cols) * (t + gap), gap + (i / cols) * (t + label_h + gap));
        for y in 0..t {
            for x in 0..t {
                for c in 0..3 {
                    out[c][(oy + y) * w + ox + x] = tile[c][(y / zoom) * n + x / zoom];
                }
            }
        }
        if label_h > 0 {
            let scale = (label_h / 7).max(1);
            let label = if r.label.starts_with('k') { r.label.clone() } else { format!("PSI {:.2}", r.psi) };
            let tx = ox + t.saturating_sub(font::text_width(&label, scale)) / 2;
            font::draw_text(&mut out, w, tx, oy + t + scale, &label, scale, [0.9, 0.9, 0.9]);
        }
    }
    (w, h, out)
}

/// Tone map for display: each tile scaled linearly by its brightest pixel over all channels,
/// so the colour of the spot shows as the channels' ratio.
fn tone_map(p: &Psf) -> [Vec<f32>; 3] {
    let m = (0..3).map(|c| p.peak(c)).fold(1e-12, f32::max);
    std::array::from_fn(|c| p.channels[c].iter().map(|v| (v / m).min(1.0)).collect())
}

/// Writes the rows to `out`; the format follows the extension (`.npy`, `.exr`, `.png`).
///
/// # Errors
/// Unknown extension, or the file cannot be written (nothing half-written is left behind).
pub fn write(rows: &[PsfRow], out: &Path, zoom: usize) -> Result<()> {
    let ext = out.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
    match ext.as_str() {
        "npy" => {
            let (shape, data) = to_hwc(rows);
            write_atomic(out, |w| npy::write_f32(w, &shape, &data))
        }
        "exr" => {
            let (w, h, planes) = mosaic(rows, 1, rows.len(), 0, 0, 0.0, |p| p.channels.clone());
            write_atomic(out, |wr| exr::write_rgb_f32(wr, w, h, [&planes[0], &planes[1], &planes[2]]))
        }
        "png" => {
            // Display crop: the region holding 99% of every tile's energy.
            let half = rows.iter().map(|r| r.psf.needed_half(0.01)).max().unwrap_or(0).max(4);
            let shown: Vec<PsfRow> = rows.iter().map(|r| PsfRow { psf: r.psf.resized(half), ..r.clone() }).collect();
            let zoom = zoom.max(1);
            let (w, h, planes) = mosaic(&shown, zoom, 12, 2, 7 * (zoom / 2).max(1) + 2 * zoom, 0.2, tone_map);
            let rgb: Vec<u8> = (0..w * h).flat_map(|i| [0, 1, 2].map(|c| (planes[c][i] * 255.0).round().clamp(0.0, 255.0) as u8)).collect();
            write_atomic(out, |wr| png_io::write_rgb8(wr, w, h, &rgb))
        }
        _ => Err(Error::Usage(format!("{}: unknown output type {ext:?} (expected .npy, .exr or .png)", out.display()))),
    }
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
    #[allow(rustdoc::broken_intra_doc_links)] // `--help` text: the brackets are TOML tables
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
    parse_psi_list(s).map(PsiList)
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

/// The library's [`PsfSpec`] of the arguments.
pub fn spec(a: &PsfArgs) -> PsfSpec {
    PsfSpec {
        camera: a.camera,
        psi: a.psi.as_ref().map(|p| p.0.clone()),
        window: a.window.map(usize::from),
        config: a.config.clone(),
        airy_radius_px: a.airy_radius_px,
        spectrum: a.spectrum,
        dispersion: a.dispersion,
        defocus_sign: a.defocus_sign,
    }
}

/// Runs `pipeline psf`.
///
/// # Errors
/// Bad optics or camera values (all named), an unwritable output.
pub fn command(a: PsfArgs) -> anyhow::Result<()> {
    let (optics, camera, req) = resolve(&spec(&a))?;
    let window = matches!(req, PsfRequest::Window(_));
    let t0 = std::time::Instant::now();
    let rows = compute(&optics, &camera, &req)?;
    eprintln!(
        "{} PSFs of {} px ({}, Airy radius {:.2} px at {} nm) in {:.2} s",
        rows.len(),
        rows.first().map_or(0, |r| r.psf.size),
        camera.kind.name(),
        optics.airy_radius_ref_px(),
        optics.ref_wavelength_nm,
        t0.elapsed().as_secs_f64()
    );
    println!("{}", table(&rows, window).trim_end_matches('\n'));
    if !window {
        for (psi, from, to) in transitions(&rows) {
            println!("sharpest channel changes {from} -> {to} near psi {psi:.2}");
        }
    }
    if let Some(out) = &a.out {
        write(&rows, out, a.zoom as usize)?;
        eprintln!("wrote {}", out.display());
    }
    Ok(())
}
