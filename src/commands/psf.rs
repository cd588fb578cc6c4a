//! `pipeline psf`: compute the PSFs of a camera and write them for people (a PNG strip like the
//! paper's Fig. 2, a table) and for tools (`.npy` of shape (K, H, W, 3), linear `.exr`).

use crate::io::{exr, font, npy, png as png_io, write_atomic};
use crate::optics::{Camera, CameraConfig, CameraKind, Dispersion, Lens, OpticsConfig, Psf, Spectrum};
use crate::{Error, Result};
use clap::Args;
use std::fmt::Write as _;
use std::path::Path;
use std::path::PathBuf;
use std::sync::Arc;

/// Parses `start:stop:count` (inclusive, evenly spaced) or a comma list of psi values.
pub fn parse_psi_list(s: &str) -> std::result::Result<Vec<f64>, String> {
    let num = |t: &str| t.trim().parse::<f64>().map_err(|_| format!("{t:?} is not a number"));
    let v = if s.contains(':') {
        let parts: Vec<&str> = s.split(':').collect();
        if parts.len() != 3 {
            return Err("expected start:stop:count, e.g. 0:8:33".into());
        }
        let (a, b) = (num(parts[0])?, num(parts[1])?);
        let n: usize = parts[2].trim().parse().map_err(|_| format!("count {:?} is not a whole number", parts[2]))?;
        match n {
            0 => return Err("count must be at least 1".into()),
            n if n > 10_000 => return Err(format!("count {n} is more than 10000 PSFs (each is a full image); ask for fewer")),
            1 => vec![a],
            _ => (0..n).map(|i| a + (b - a) * i as f64 / (n - 1) as f64).collect(),
        }
    } else {
        s.split(',').map(num).collect::<std::result::Result<Vec<_>, _>>()?
    };
    check_psi(&v)?;
    Ok(v)
}

/// psi values must be finite and within -50 to 50.
///
/// # Errors
/// The first value outside, named.
pub fn check_psi(v: &[f64]) -> std::result::Result<(), String> {
    match v.iter().find(|p| !p.is_finite() || p.abs() > 50.0) {
        Some(bad) => Err(format!("psi {bad} is out of range (expected -50 to 50)")),
        None => Ok(()),
    }
}

/// One row of the PSF table.
#[derive(Debug, Clone)]
pub struct PsfRow {
    pub label: String,
    pub psi: f64,
    pub weight: f64,
    pub shift: [f64; 2],
    pub psf: Psf,
}

/// What to compute: the lens PSF over psi values, or the kernels of one exposure window.
pub enum PsfRequest {
    Psi(Vec<f64>),
    Window(usize),
}

/// Computes the rows. For `Psi`, the lens is masked for `phase_coded` and clear otherwise; all
/// rows share one size (the largest any needs after trimming).
///
/// # Errors
/// A window whose `psi_values` do not match its length.
pub fn compute(optics: &OpticsConfig, camera: &CameraConfig, req: &PsfRequest) -> Result<Vec<PsfRow>> {
    match req {
        PsfRequest::Psi(psis) => {
            let lens = Lens::new(optics, camera.kind == CameraKind::PhaseCoded);
            let full: Vec<Psf> = {
                use rayon::prelude::*;
                psis.par_iter().map(|&p| lens.psf(p, lens.support_half(p.abs()))).collect()
            };
            let half = full.iter().map(|p| p.needed_half(optics.trim_energy)).max().unwrap_or(0);
            Ok(psis
                .iter()
                .zip(full)
                .map(|(&psi, p)| PsfRow { label: format!("{psi:.3}"), psi, weight: 1.0, shift: [0.0; 2], psf: p.resized(half) })
                .collect())
        }
        PsfRequest::Window(n) => {
            let cam = Camera::new(optics, camera);
            let w = cam.window(*n)?;
            let half = w.iter().map(|k| k.half_extent()).max().unwrap_or(0);
            Ok(w.iter()
                .enumerate()
                .map(|(i, k)| {
                    // Unit-sum spatial kernel with the shift; the weight goes in the table.
                    let unit = crate::optics::SubframeKernel { weight: 1.0, psf: Arc::clone(&k.psf), ..k.clone() };
                    let channels = std::array::from_fn(|c| unit.render(c, half));
                    PsfRow {
                        label: format!("k={i}"),
                        psi: k.psi,
                        weight: k.weight,
                        shift: k.shift,
                        psf: Psf { size: 2 * half + 1, channels },
                    }
                })
                .collect())
        }
    }
}

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

/// (K, H, W, 3) float32, channels R, G, B.
pub fn to_hwc(rows: &[PsfRow]) -> (Vec<usize>, Vec<f32>) {
    let n = rows.first().map_or(0, |r| r.psf.size);
    let mut data = Vec::with_capacity(rows.len() * n * n * 3);
    for r in rows {
        for i in 0..n * n {
            for c in 0..3 {
                data.push(r.psf.channels[c][i]);
            }
        }
    }
    (vec![rows.len(), n, n, 3], data)
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
        _ => Err(Error::Invalid(format!("{}: unknown output type {ext:?} (expected .npy, .exr or .png)", out.display()))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psi_lists_parse_and_bad_ones_say_why() {
        assert_eq!(parse_psi_list("0:8:5").unwrap(), vec![0.0, 2.0, 4.0, 6.0, 8.0]);
        assert_eq!(parse_psi_list("1, 2.5").unwrap(), vec![1.0, 2.5]);
        assert!(parse_psi_list("0:8").unwrap_err().contains("start:stop:count"));
        assert!(parse_psi_list("0:8:x").unwrap_err().contains("count"));
        assert!(parse_psi_list("0:8:1000000").unwrap_err().contains("more than 10000"));
        assert!(parse_psi_list("a").unwrap_err().contains("not a number"));
        assert!(parse_psi_list("0,99").unwrap_err().contains("out of range"));
    }

    #[test]
    fn window_rows_are_unit_sum_even_with_shifts_and_weights() {
        let cam = CameraConfig { kind: CameraKind::Parabolic, ..Default::default() };
        let rows = compute(&OpticsConfig::default(), &cam, &PsfRequest::Window(9)).unwrap();
        assert_eq!(rows.len(), 9);
        for r in &rows {
            for c in 0..3 {
                assert!((r.psf.channel_sum(c) - 1.0).abs() < 1e-5);
            }
        }
        assert!(rows[0].shift[0] > rows[4].shift[0]);
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

/// `[optics]` and `[camera]` read from a file.
#[derive(serde::Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct OpticsFile {
    pub optics: OpticsConfig,
    pub camera: Option<CameraConfig>,
}

/// The optics, camera and request the arguments describe (the file, then the flags over it),
/// every value checked. The Python package's `psf()` fills a [`PsfArgs`] and calls this too.
///
/// # Errors
/// An unreadable or malformed file, bad values (all named), --psi with --window.
pub fn resolve(a: &PsfArgs) -> crate::Result<(OpticsConfig, CameraConfig, PsfRequest)> {
    let file = match &a.config {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| Error::Io { path: p.clone(), cause: e })?;
            toml::from_str::<OpticsFile>(&text).map_err(|e| Error::ConfigText(format!("{}: {}", p.display(), e.to_string().trim())))?
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
        return Err(crate::Error::Config(errs));
    }
    // clap checks these on the command line; the Python psf() fills PsfArgs directly.
    if let Some(p) = &a.psi {
        check_psi(&p.0).map_err(Error::Usage)?;
    }
    if a.window.is_some_and(|n| !(1..=64).contains(&n)) {
        return Err(Error::Usage(format!("window {} must be 1 to 64", a.window.unwrap_or(0))));
    }
    let req = match (&a.psi, a.window) {
        (Some(p), None) => PsfRequest::Psi(p.0.clone()),
        (None, Some(n)) => PsfRequest::Window(n as usize),
        (None, None) => PsfRequest::Psi(parse_psi_list("0:8:9").expect("default psi list")),
        (Some(_), Some(_)) => return Err(Error::Usage("--psi and --window exclude each other".into())),
    };
    Ok((optics, camera, req))
}

/// Runs `pipeline psf`.
///
/// # Errors
/// Bad optics or camera values (all named), an unwritable output.
pub fn command(a: PsfArgs) -> anyhow::Result<()> {
    let (optics, camera, req) = resolve(&a)?;
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
    print!("{}", table(&rows, window));
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
