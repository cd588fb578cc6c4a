//! What `pipeline psf` computes, as a library: a [`PsfSpec`] (camera, psi values or a window,
//! optics overrides) resolved against an optional `[optics]`/`[camera]` file, then the PSF rows
//! of the lens over psi or of one exposure window's sub-frame kernels, and their (K, H, W, 3)
//! array. The command writes them for people and tools; the Python package returns the array.

use crate::optics::{Camera, CameraConfig, CameraKind, Dispersion, Lens, OpticsConfig, Psf, Spectrum};
use crate::{Error, Result};
use std::path::PathBuf;
use std::sync::Arc;

/// A PSF request as values: what `pipeline psf`'s flags and the Python `psf()` describe.
#[derive(Debug, Clone)]
pub struct PsfSpec {
    pub camera: CameraKind,
    /// psi values (checked: finite, -50 to 50); `None` with no window: 0 to 8 in 9 steps.
    pub psi: Option<Vec<f64>>,
    /// The N sub-frame kernels of one exposure window (1 to 64) instead of psi values.
    pub window: Option<usize>,
    /// A TOML file with `[optics]` and/or `[camera]` tables, the values below over it.
    pub config: Option<PathBuf>,
    pub airy_radius_px: Option<f64>,
    pub spectrum: Option<Spectrum>,
    pub dispersion: Option<Dispersion>,
    pub defocus_sign: Option<f64>,
}

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

/// `[optics]` and `[camera]` read from a file.
#[derive(serde::Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct OpticsFile {
    pub optics: OpticsConfig,
    pub camera: Option<CameraConfig>,
}

/// The optics, camera and request a [`PsfSpec`] describes (the file, then the values over it),
/// every value checked. `pipeline psf` and the Python package's `psf()` both call this.
///
/// # Errors
/// An unreadable or malformed file, bad values (all named), --psi with --window.
pub fn resolve(a: &PsfSpec) -> crate::Result<(OpticsConfig, CameraConfig, PsfRequest)> {
    let file = match &a.config {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| Error::Io { path: p.clone(), cause: e })?;
            toml::from_str::<OpticsFile>(&text).map_err(Error::toml(&p.display().to_string(), Some(&text)))?
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
    errs.extend(crate::optics::measured::check(&camera, "camera"));
    if !errs.is_empty() {
        return Err(crate::Error::Config(errs));
    }
    // clap checks these on the command line; the Python psf() fills a PsfSpec directly.
    if let Some(p) = &a.psi {
        check_psi(p).map_err(Error::Usage)?;
    }
    if a.window.is_some_and(|n| !(1..=64).contains(&n)) {
        return Err(Error::Usage(format!("window {} must be 1 to 64", a.window.unwrap_or(0))));
    }
    let req = match (&a.psi, a.window) {
        (Some(p), None) => PsfRequest::Psi(p.clone()),
        (None, Some(n)) => PsfRequest::Window(n),
        (None, None) => PsfRequest::Psi(parse_psi_list("0:8:9").expect("default psi list")),
        (Some(_), Some(_)) => return Err(Error::Usage("--psi and --window exclude each other".into())),
    };
    Ok((optics, camera, req))
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
