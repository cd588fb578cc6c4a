//! Optics and camera configuration: the serde structs behind `[optics]` and `[camera]` in a
//! pipeline file, with the paper's values as defaults, and their validation.
//!
//! Every struct rejects unknown keys so that a typo is an error that names the key.

use crate::checks::{Checker, ConfigError};
use serde::{Deserialize, Serialize};

/// One phase ring of the aperture mask, in normalised pupil radius (0 = centre, 1 = rim).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ring {
    /// Inner radius, 0..=1.
    pub inner: f64,
    /// Outer radius, 0..=1, larger than `inner`.
    pub outer: f64,
    /// Phase delay in radians at the mask's reference wavelength.
    pub phase: f64,
}

/// Dispersion of the mask material, used to scale the ring phase off the reference wavelength.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum Dispersion {
    /// Refractive index constant: phase scales as lambda_ref / lambda only.
    None,
    /// Schott N-BK7 (Cauchy fit, A = 1.5046, B = 0.00420 um^2).
    Bk7,
    /// Fused silica (Cauchy fit, A = 1.4580, B = 0.00354 um^2).
    FusedSilica,
}

impl Dispersion {
    /// Refractive index at `lambda_nm` (only meaningful in ratios `(n - 1) / (n_ref - 1)`).
    pub fn index(self, lambda_nm: f64) -> f64 {
        let um = lambda_nm * 1e-3;
        match self {
            Dispersion::None => 1.5,
            Dispersion::Bk7 => 1.5046 + 0.00420 / (um * um),
            Dispersion::FusedSilica => 1.4580 + 0.00354 / (um * um),
        }
    }
}

/// Spectral model of the three colour channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum Spectrum {
    /// One wavelength per channel: R 610 nm, G 530 nm, B 455 nm (or `wavelengths_nm`).
    Lines,
    /// Five wavelengths per channel weighted by a Gaussian sensitivity (centres 600, 530,
    /// 460 nm, FWHM 70 nm), a closer model of a Bayer sensor.
    Bands,
}

/// Wavelengths (nm) and weights of one colour channel.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelSpectrum {
    pub wavelengths_nm: Vec<f64>,
    pub weights: Vec<f64>,
}

/// Explicit wavelengths per channel, `{ r = [610.0], g = [530.0], b = [455.0] }`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Wavelengths {
    pub r: Vec<f64>,
    pub g: Vec<f64>,
    pub b: Vec<f64>,
}

/// `[optics]`: the lens, the mask and how PSFs are sampled on the video's pixel grid.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OpticsConfig {
    /// Phase rings of the mask (the paper: [0.55, 0.8] 6.5 rad and [0.8, 1.0] 13.2 rad).
    pub rings: Vec<Ring>,
    /// Wavelength at which ring phases and psi are given, nm.
    pub ref_wavelength_nm: f64,
    pub dispersion: Dispersion,
    /// +1: mask phase and defocus add with the same sign (the convention that makes the colour
    /// code work); -1 flips the defocus, kept so the convention can be tested.
    pub defocus_sign: f64,
    pub spectrum: Spectrum,
    /// Overrides the wavelengths of `spectrum = "lines"`.
    pub wavelengths_nm: Option<Wavelengths>,
    /// Radius of the first dark Airy ring at the reference wavelength, in video pixels. When
    /// absent it follows from the physical keys: 0.61 lambda f / (R p).
    pub airy_radius_px: Option<f64>,
    pub focal_length_mm: f64,
    pub aperture_radius_mm: f64,
    pub pixel_pitch_um: f64,
    /// Sub-samples per pixel side when integrating the PSF over a pixel.
    pub pixel_subsamples: usize,
    /// Pupil samples across its diameter.
    pub pupil_samples: usize,
    /// Fraction of each channel's energy that trimming may drop.
    pub trim_energy: f64,
}

impl Default for OpticsConfig {
    fn default() -> Self {
        OpticsConfig {
            rings: vec![Ring { inner: 0.55, outer: 0.8, phase: 6.5 }, Ring { inner: 0.8, outer: 1.0, phase: 13.2 }],
            ref_wavelength_nm: 455.0,
            dispersion: Dispersion::None,
            defocus_sign: 1.0,
            spectrum: Spectrum::Lines,
            wavelengths_nm: None,
            airy_radius_px: None,
            focal_length_mm: 12.0,
            aperture_radius_mm: 1.14,
            pixel_pitch_um: 1.25,
            pixel_subsamples: 3,
            pupil_samples: 128,
            trim_energy: 5e-3,
        }
    }
}

impl OpticsConfig {
    /// Airy radius (first dark ring) in video pixels at the reference wavelength.
    pub fn airy_radius_ref_px(&self) -> f64 {
        self.airy_radius_px.unwrap_or_else(|| {
            let lambda_m = self.ref_wavelength_nm * 1e-9;
            0.61 * lambda_m * (self.focal_length_mm * 1e-3) / (self.aperture_radius_mm * 1e-3) / (self.pixel_pitch_um * 1e-6)
        })
    }

    /// Channel spectra in R, G, B order.
    pub fn channels(&self) -> [ChannelSpectrum; 3] {
        match (self.spectrum, &self.wavelengths_nm) {
            (Spectrum::Lines, Some(w)) => {
                [&w.r, &w.g, &w.b].map(|l| ChannelSpectrum { wavelengths_nm: l.clone(), weights: vec![1.0; l.len()] })
            }
            (Spectrum::Lines, None) => [610.0, 530.0, 455.0].map(|l| ChannelSpectrum { wavelengths_nm: vec![l], weights: vec![1.0] }),
            (Spectrum::Bands, _) => [600.0, 530.0, 460.0].map(|c| {
                let sigma = 70.0 / 2.3548;
                let wavelengths_nm: Vec<f64> = (-2..=2).map(|i| c + 20.0 * i as f64).collect();
                let weights = wavelengths_nm.iter().map(|l| (-(l - c) * (l - c) / (2.0 * sigma * sigma)).exp()).collect();
                ChannelSpectrum { wavelengths_nm, weights }
            }),
        }
    }

    /// Every problem with the values, each naming its key under `prefix`.
    pub fn validate(&self, prefix: &str) -> Vec<ConfigError> {
        let mut c = Checker::new(prefix);
        for (i, r) in self.rings.iter().enumerate() {
            let k = format!("rings[{i}]");
            if !(0.0 <= r.inner && r.inner < r.outer && r.outer <= 1.0) {
                c.fail(&k, format!("needs 0 <= inner < outer <= 1 (got inner {} outer {})", r.inner, r.outer));
            }
            if !r.phase.is_finite() {
                c.fail(&k, "phase must be finite");
            }
        }
        c.range("ref_wavelength_nm", self.ref_wavelength_nm, 300.0, 1100.0);
        if self.defocus_sign != 1.0 && self.defocus_sign != -1.0 {
            c.fail("defocus_sign", format!("{} is not 1 or -1", self.defocus_sign));
        }
        if let Some(w) = &self.wavelengths_nm {
            if self.spectrum != Spectrum::Lines {
                c.fail("wavelengths_nm", "only applies with spectrum = \"lines\"");
            }
            for (name, l) in [("r", &w.r), ("g", &w.g), ("b", &w.b)] {
                if l.is_empty() {
                    c.fail(&format!("wavelengths_nm.{name}"), "needs at least one wavelength");
                }
                for &x in l {
                    c.range(&format!("wavelengths_nm.{name}"), x, 300.0, 1100.0);
                }
            }
        }
        if let Some(a) = self.airy_radius_px {
            c.range("airy_radius_px", a, 0.05, 50.0);
        }
        c.range("focal_length_mm", self.focal_length_mm, 0.1, 10_000.0);
        c.range("aperture_radius_mm", self.aperture_radius_mm, 0.01, 1_000.0);
        c.range("pixel_pitch_um", self.pixel_pitch_um, 0.1, 1_000.0);
        c.range_usize("pixel_subsamples", self.pixel_subsamples, 1, 16);
        c.range_usize("pupil_samples", self.pupil_samples, 16, 1024);
        c.range("trim_energy", self.trim_energy, 0.0, 0.1);
        if self.airy_radius_px.is_none() && c.errors.is_empty() {
            c.range("airy_radius_px (from focal_length_mm, aperture_radius_mm, pixel_pitch_um)", self.airy_radius_ref_px(), 0.05, 50.0);
        }
        c.errors
    }
}

/// The cameras `pipeline` models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum CameraKind {
    /// Clear aperture, fixed focus: the blur is the plain average of the sub-frames.
    Conventional,
    /// Clear aperture with the psi sweep (no mask): every colour widens together.
    FocusSweep,
    /// The paper's camera: ring phase mask plus the psi sweep.
    PhaseCoded,
    /// Raskar's fluttered shutter: sub-frames weighted by the 52-chop code, half the light.
    Flutter,
    /// Levin's parabolic sensor motion x = a t^2 along one axis.
    Parabolic,
    /// A measured (or exported) PSF stack: `psf_path`, over instants or psi ([`super::measured`]).
    Measured,
}

impl CameraKind {
    pub fn name(self) -> &'static str {
        match self {
            CameraKind::Conventional => "conventional",
            CameraKind::FocusSweep => "focus_sweep",
            CameraKind::PhaseCoded => "phase_coded",
            CameraKind::Flutter => "flutter",
            CameraKind::Parabolic => "parabolic",
            CameraKind::Measured => "measured",
        }
    }
}

/// How psi is spread over the N sub-frames of a window.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum PsiSchedule {
    /// psi_k = start + (end - start) (k + 0.5) / N: the value at the middle of each sub-frame.
    Midpoint,
    /// psi_k = start + (end - start) k / (N - 1): first and last sub-frame at the ends.
    Endpoints,
}

/// Axis of the parabolic sensor motion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum Axis {
    X,
    Y,
}

/// What a measured stack's K entries are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum PsfAxis {
    /// K equal slices of the exposure, in time order.
    #[default]
    Instants,
    /// K values of psi, evenly spaced from the camera's `psi[0]` to `psi[1]`.
    Psi,
}

/// Raskar et al. 2006, the 52-chop code (26 chops open).
pub const RASKAR_CODE: &str = "1010000111000001010000110011110111010111001001100111";

/// `[camera]`: which camera, and its exposure-time behaviour.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    #[serde(rename = "type")]
    pub kind: CameraKind,
    /// psi at the start and the end of the exposure, at the reference wavelength.
    pub psi: [f64; 2],
    pub psi_schedule: PsiSchedule,
    /// Explicit psi per sub-frame; overrides `psi` and `psi_schedule` (length must equal N).
    pub psi_values: Option<Vec<f64>>,
    /// For conventional, flutter and parabolic: include the in-focus diffraction spot of the
    /// clear aperture (false: an ideal lens, a delta PSF).
    pub diffraction: bool,
    /// Flutter shutter code, '1' open and '0' closed.
    pub flutter_code: String,
    pub parabolic_axis: Axis,
    /// Sensor displacement a (pixels) at the ends of the exposure: x(t) = a t^2, t in [-1, 1].
    pub parabolic_amplitude_px: f64,
    /// For `measured`: the PSF stack, `.npy` float32 (K, H, W, 3), as `pipeline psf --out` and
    /// `pipeline calibrate` write it.
    pub psf_path: Option<std::path::PathBuf>,
    /// For `measured`: what the stack's K entries are (`instants` of the exposure, or `psi`
    /// values evenly spaced over `psi`, mapped to sub-frames by `psi_schedule`).
    pub psf_over: PsfAxis,
    /// For `measured`: rescale each channel of each entry to unit sum (else one off by more than
    /// 1% is refused).
    pub psf_normalise: bool,
}

impl Default for CameraConfig {
    fn default() -> Self {
        CameraConfig {
            kind: CameraKind::PhaseCoded,
            psi: [0.0, 8.0],
            psi_schedule: PsiSchedule::Midpoint,
            psi_values: None,
            diffraction: false,
            flutter_code: RASKAR_CODE.to_string(),
            parabolic_axis: Axis::X,
            parabolic_amplitude_px: 8.0,
            psf_path: None,
            psf_over: Default::default(),
            psf_normalise: false,
        }
    }
}

impl CameraConfig {
    pub fn new(kind: CameraKind) -> Self {
        CameraConfig { kind, ..Default::default() }
    }

    pub fn validate(&self, prefix: &str) -> Vec<ConfigError> {
        let mut c = Checker::new(prefix);
        for (i, p) in self.psi.iter().enumerate() {
            c.range(&format!("psi[{i}]"), *p, -50.0, 50.0);
        }
        if let Some(v) = &self.psi_values {
            if v.is_empty() {
                c.fail("psi_values", "needs at least one value");
            }
            for p in v {
                c.range("psi_values", *p, -50.0, 50.0);
            }
        }
        if self.flutter_code.is_empty() || !self.flutter_code.chars().all(|ch| ch == '0' || ch == '1') {
            c.fail("flutter_code", format!("{:?} is not a string of 0 and 1", self.flutter_code));
        } else if !self.flutter_code.contains('1') {
            c.fail("flutter_code", "has no open chop");
        }
        c.range("parabolic_amplitude_px", self.parabolic_amplitude_px, -200.0, 200.0);
        match (&self.psf_path, self.kind) {
            (None, CameraKind::Measured) => c.fail("psf_path", "the measured camera needs a PSF stack (.npy, (K, H, W, 3))"),
            // The stack itself is read and checked by the stages and commands that use it
            // (`measured::check`), beside the camera.
            (Some(_), CameraKind::Measured) => {}
            (Some(_), k) => c.fail("psf_path", format!("only the measured camera reads a PSF stack, not {}", k.name())),
            (None, _) => {}
        }
        c.errors
    }
}
