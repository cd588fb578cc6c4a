//! Pupil and intensity PSF of the (optionally phase-masked) lens, sampled on the video's pixels.
//!
//! ## Model
//! Pupil at normalised radius rho in [0, 1] and wavelength lambda:
//! `P = circ(rho) exp(i (phi_mask(rho, lambda) + s psi(lambda) rho^2))` with `s` the defocus sign
//! (+1: same sign as the mask), `psi(lambda) = psi_ref lambda_ref / lambda` and
//! `phi_mask(lambda) = phi_ref (lambda_ref / lambda) (n(lambda) - 1) / (n(lambda_ref) - 1)`.
//! The intensity PSF is `|F{P}|^2`, evaluated by a matrix DFT directly at pixel sub-sample
//! positions, so the spot grows in proportion to lambda without any resampling. In pixels the
//! Fourier kernel is `exp(-i 2 pi (0.61 / a(lambda)) (x rho_x + y rho_y))`, where
//! `a(lambda) = a_ref lambda / lambda_ref` is the Airy radius in pixels.
//!
//! ## Usage
//! ```
//! use pipeline::optics::{OpticsConfig, Lens};
//! let lens = Lens::new(&OpticsConfig::default(), true);
//! let psf = lens.psf(4.0, 15);
//! assert!((psf.channel_sum(1) - 1.0).abs() < 1e-4);
//! ```

use super::config::{ChannelSpectrum, OpticsConfig};
use num_complex::Complex64;
use std::f64::consts::PI;

/// A three-channel PSF: linear light, f32, planar R, G, B, each `size x size`, odd `size`,
/// centred on the middle pixel, each channel summing to 1.
#[derive(Debug, Clone, PartialEq)]
pub struct Psf {
    pub size: usize,
    pub channels: [Vec<f32>; 3],
}

impl Psf {
    /// A delta: the identity kernel of an ideal lens.
    pub fn delta() -> Psf {
        Psf { size: 1, channels: [vec![1.0], vec![1.0], vec![1.0]] }
    }

    pub fn half(&self) -> usize {
        self.size / 2
    }

    pub fn channel_sum(&self, c: usize) -> f64 {
        self.channels[c].iter().map(|&v| v as f64).sum()
    }

    /// Largest pixel of channel `c`.
    pub fn peak(&self, c: usize) -> f32 {
        self.channels[c].iter().copied().fold(0.0, f32::max)
    }

    /// Radius (pixels, from the centre pixel) of the smallest centred disc that holds
    /// `fraction` of channel `c`'s energy; linear between pixel distances.
    pub fn energy_radius(&self, c: usize, fraction: f64) -> f64 {
        let h = self.half() as i64;
        // Energy per distinct squared distance from the centre pixel.
        let mut rings: std::collections::BTreeMap<i64, f64> = std::collections::BTreeMap::new();
        for (i, v) in self.channels[c].iter().enumerate() {
            let (y, x) = ((i / self.size) as i64 - h, (i % self.size) as i64 - h);
            *rings.entry(x * x + y * y).or_insert(0.0) += *v as f64;
        }
        let total: f64 = rings.values().sum();
        let target = fraction * total;
        // Cumulative energy against radius, linear in between; the centre pixel counts as a
        // disc of the same area (radius 1/sqrt(pi)).
        let (mut prev_r, mut acc) = (0.0, 0.0);
        for (k, (d2, e)) in rings.into_iter().enumerate() {
            let r = if k == 0 { 1.0 / std::f64::consts::PI.sqrt() } else { (d2 as f64).sqrt() };
            if acc + e >= target {
                return prev_r + (r - prev_r) * (target - acc) / e.max(1e-300);
            }
            acc += e;
            prev_r = r;
        }
        prev_r
    }

    /// Channel with the highest peak (0 = R, 1 = G, 2 = B).
    pub fn sharpest_channel(&self) -> usize {
        (0..3).max_by(|&a, &b| self.peak(a).total_cmp(&self.peak(b))).unwrap_or(0)
    }

    /// Smallest half-width keeping all but `eps` of every channel's energy.
    pub fn needed_half(&self, eps: f64) -> usize {
        let h = self.half();
        (0..=h).find(|&k| (0..3).all(|c| 1.0 - self.box_sum(c, k) <= eps * self.channel_sum(c).max(1e-30))).unwrap_or(h)
    }

    fn box_sum(&self, c: usize, k: usize) -> f64 {
        let h = self.half();
        let mut s = 0.0;
        for y in h - k..=h + k {
            for x in h - k..=h + k {
                s += self.channels[c][y * self.size + x] as f64;
            }
        }
        s / self.channel_sum(c).max(1e-30)
    }

    /// Cuts to `2 * half + 1` (or pads with zeros) around the centre and renormalises each
    /// channel to unit sum.
    pub fn resized(&self, half: usize) -> Psf {
        let n = 2 * half + 1;
        let (h0, h1) = (self.half() as isize, half as isize);
        let channels = std::array::from_fn(|c| {
            let mut out = vec![0.0f32; n * n];
            for y in 0..n as isize {
                for x in 0..n as isize {
                    let (sy, sx) = (y - h1 + h0, x - h1 + h0);
                    if sy >= 0 && sx >= 0 && sy < self.size as isize && sx < self.size as isize {
                        out[(y * n as isize + x) as usize] = self.channels[c][(sy * self.size as isize + sx) as usize];
                    }
                }
            }
            let s: f64 = out.iter().map(|&v| v as f64).sum();
            if s > 0.0 {
                out.iter_mut().for_each(|v| *v = (*v as f64 / s) as f32);
            }
            out
        });
        Psf { size: n, channels }
    }
}

/// A lens with (or without) the phase mask, ready to make PSFs for any psi.
#[derive(Debug, Clone)]
pub struct Lens {
    cfg: OpticsConfig,
    masked: bool,
    channels: [ChannelSpectrum; 3],
    airy_ref: f64,
}

impl Lens {
    /// `masked = false` gives the clear aperture of the same lens.
    pub fn new(cfg: &OpticsConfig, masked: bool) -> Lens {
        Lens { cfg: cfg.clone(), masked, channels: cfg.channels(), airy_ref: cfg.airy_radius_ref_px() }
    }

    pub fn config(&self) -> &OpticsConfig {
        &self.cfg
    }

    /// Airy radius (first dark ring) in pixels at `lambda_nm`.
    pub fn airy_radius_px(&self, lambda_nm: f64) -> f64 {
        self.airy_ref * lambda_nm / self.cfg.ref_wavelength_nm
    }

    /// Geometric blur radius (pixels) of defocus `psi` (it does not depend on lambda).
    pub fn geometric_radius_px(&self, psi: f64) -> f64 {
        // Transverse ray aberration of psi rho^2 at the rim: lambda f psi / (pi R p) = psi a / (0.61 pi).
        psi.abs() * self.airy_ref / (0.61 * PI)
    }

    /// Mask phase at normalised radius `rho` and wavelength `lambda_nm`.
    pub fn mask_phase(&self, rho: f64, lambda_nm: f64) -> f64 {
        if !self.masked {
            return 0.0;
        }
        let d = &self.cfg.dispersion;
        let l0 = self.cfg.ref_wavelength_nm;
        let scale = (l0 / lambda_nm) * (d.index(lambda_nm) - 1.0) / (d.index(l0) - 1.0);
        self.cfg.rings.iter().filter(|r| rho >= r.inner && rho < r.outer).map(|r| r.phase * scale).sum()
    }

    /// Complex pupil on an `n x n` grid over [-1, 1]^2; each cell is the mean of 4 x 4
    /// sub-samples, so the rim and the ring edges are anti-aliased.
    pub fn pupil(&self, psi_ref: f64, lambda_nm: f64) -> Vec<Complex64> {
        let n = self.cfg.pupil_samples;
        let mut p = vec![Complex64::new(0.0, 0.0); n * n];
        for j in 0..n {
            for i in 0..n {
                p[j * n + i] = self.pupil_cell(psi_ref, lambda_nm, j, i);
            }
        }
        p
    }

    /// One pupil cell (row `j`, column `i`): the mean of its 4 x 4 sub-samples.
    fn pupil_cell(&self, psi_ref: f64, lambda_nm: f64, j: usize, i: usize) -> Complex64 {
        let n = self.cfg.pupil_samples;
        let psi = self.cfg.defocus_sign * psi_ref * self.cfg.ref_wavelength_nm / lambda_nm;
        let (s, d) = (4usize, 2.0 / n as f64);
        let mut acc = Complex64::new(0.0, 0.0);
        for sj in 0..s {
            for si in 0..s {
                let y = -1.0 + d * (j as f64 + (sj as f64 + 0.5) / s as f64);
                let x = -1.0 + d * (i as f64 + (si as f64 + 0.5) / s as f64);
                let rho2 = x * x + y * y;
                if rho2 <= 1.0 {
                    let phase = self.mask_phase(rho2.sqrt(), lambda_nm) + psi * rho2;
                    acc += Complex64::from_polar(1.0, phase);
                }
            }
        }
        acc / (s * s) as f64
    }

    /// Pupil cell centres along one axis.
    fn pupil_coords(&self) -> Vec<f64> {
        let n = self.cfg.pupil_samples;
        (0..n).map(|i| -1.0 + (i as f64 + 0.5) * 2.0 / n as f64).collect()
    }

    /// Optical field at arbitrary sensor points (pixels from the optical axis): used for
    /// checks against closed forms, not on hot paths.
    pub fn field_at(&self, psi_ref: f64, lambda_nm: f64, points: &[(f64, f64)]) -> Vec<Complex64> {
        let pupil = self.pupil(psi_ref, lambda_nm);
        let rho = self.pupil_coords();
        let k = 2.0 * PI * 0.61 / self.airy_radius_px(lambda_nm);
        let n = rho.len();
        points
            .iter()
            .map(|&(x, y)| {
                let ex: Vec<Complex64> = rho.iter().map(|r| Complex64::from_polar(1.0, -k * x * r)).collect();
                let mut acc = Complex64::new(0.0, 0.0);
                for j in 0..n {
                    let ey = Complex64::from_polar(1.0, -k * y * rho[j]);
                    let row: Complex64 = (0..n).map(|i| pupil[j * n + i] * ex[i]).sum();
                    acc += row * ey;
                }
                acc
            })
            .collect()
    }

    /// Intensity of one wavelength on a `(2 half + 1)^2` pixel grid, integrated over each
    /// pixel with `pixel_subsamples^2` points, normalised to unit sum.
    ///
    /// The pupil is even in x and in y (a radial mask and defocus on a grid symmetric about
    /// the axis), and so are the sample positions, so the matrix DFT `U = E P E^T` folds: with
    /// `Q` the pupil's quarter and `C = 2 cos(k x rho)` (1 on an axis cell of odd grids),
    /// `U = C Q C^T` over half the pupil samples per axis with a real kernel, and only a
    /// quarter of `U` is evaluated (it is even in both sensor axes). About 20 times fewer
    /// operations than the direct product, which the tests keep as the reference.
    pub fn psf_mono(&self, psi_ref: f64, lambda_nm: f64, half: usize) -> Vec<f64> {
        let n = self.cfg.pupil_samples;
        let rho = self.pupil_coords();
        // Folded pupil indices: the cells with rho >= 0 (the axis cell first on odd grids).
        let nq = n.div_ceil(2);
        let idx: Vec<usize> = (n - nq..n).collect();
        let fold_w: Vec<f64> = idx.iter().map(|&i| if n - 1 - i == i { 1.0 } else { 2.0 }).collect();
        let q: Vec<Complex64> =
            idx.iter().flat_map(|&j| idx.iter().map(move |&i| (j, i))).map(|(j, i)| self.pupil_cell(psi_ref, lambda_nm, j, i)).collect();
        let s = self.cfg.pixel_subsamples;
        let size = 2 * half + 1;
        let m = size * s;
        // Sample positions in pixels, centred on the middle pixel (even: xs[m - 1 - a] = -xs[a]).
        let xs: Vec<f64> = (0..m).map(|i| (i as f64 + 0.5) / s as f64 - 0.5 - half as f64).collect();
        let mh = m.div_ceil(2);
        let k = 2.0 * PI * 0.61 / self.airy_radius_px(lambda_nm);
        // C[a][q] = w_q cos(k xs[a] rho_q) for the first half of the sample positions.
        let (idx_r, rho_r, w_r) = (&idx, &rho, &fold_w);
        let c: Vec<f64> = xs[..mh].iter().flat_map(|&x| idx_r.iter().zip(w_r).map(move |(&i, w)| w * (k * x * rho_r[i]).cos())).collect();
        // T = Q C^T: nq x mh.
        let mut t = vec![Complex64::new(0.0, 0.0); nq * mh];
        for j in 0..nq {
            let qrow = &q[j * nq..(j + 1) * nq];
            if qrow.iter().all(|v| v.norm_sqr() == 0.0) {
                continue;
            }
            for a in 0..mh {
                let crow = &c[a * nq..(a + 1) * nq];
                t[j * mh + a] = qrow.iter().zip(crow).map(|(p, w)| p * w).sum();
            }
        }
        // |U|^2 on the quarter a, b < mh; the rest by mirroring.
        let mut quarter = vec![0.0f64; mh * mh];
        let mut col = vec![Complex64::new(0.0, 0.0); nq];
        for b in 0..mh {
            for j in 0..nq {
                col[j] = t[j * mh + b];
            }
            for a in 0..mh {
                let crow = &c[a * nq..(a + 1) * nq];
                let u: Complex64 = crow.iter().zip(&col).map(|(w, v)| v * w).sum();
                quarter[a * mh + b] = u.norm_sqr();
            }
        }
        let fold = |a: usize| a.min(m - 1 - a);
        let mut out = vec![0.0f64; size * size];
        for a in 0..m {
            for b in 0..m {
                out[(a / s) * size + b / s] += quarter[fold(a) * mh + fold(b)];
            }
        }
        let total: f64 = out.iter().sum();
        out.iter_mut().for_each(|v| *v /= total);
        out
    }

    /// Half-width that holds the PSF of any psi up to `psi_max` with room for diffraction
    /// lobes: the geometric radius plus six Airy radii of the longest wavelength.
    pub fn support_half(&self, psi_max: f64) -> usize {
        let lmax = self.channels.iter().flat_map(|c| c.wavelengths_nm.iter().copied()).fold(0.0, f64::max);
        (self.geometric_radius_px(psi_max) + 6.0 * self.airy_radius_px(lmax)).ceil() as usize + 1
    }

    /// The colour PSF at `psi_ref` on a `(2 half + 1)^2` grid (not trimmed).
    pub fn psf(&self, psi_ref: f64, half: usize) -> Psf {
        let size = 2 * half + 1;
        let channels = std::array::from_fn(|c| {
            let spec = &self.channels[c];
            let wsum: f64 = spec.weights.iter().sum();
            let mut acc = vec![0.0f64; size * size];
            for (l, w) in spec.wavelengths_nm.iter().zip(&spec.weights) {
                let mono = self.psf_mono(psi_ref, *l, half);
                acc.iter_mut().zip(mono).for_each(|(a, m)| *a += m * w / wsum);
            }
            acc.into_iter().map(|v| v as f32).collect()
        });
        Psf { size, channels }
    }

    /// The PSF at `psi_ref` with automatic support, trimmed to drop at most `trim_energy`.
    pub fn psf_auto(&self, psi_ref: f64) -> Psf {
        let p = self.psf(psi_ref, self.support_half(psi_ref.abs()));
        let h = p.needed_half(self.cfg.trim_energy);
        p.resized(h)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lens(masked: bool) -> Lens {
        Lens::new(&OpticsConfig::default(), masked)
    }

    /// Bessel J1 by its power series (|x| < 12 is plenty here): an independent reference.
    fn bessel_j1(x: f64) -> f64 {
        let (mut term, mut sum) = (x / 2.0, x / 2.0);
        for k in 1..60 {
            term *= -(x * x / 4.0) / (k as f64 * (k + 1) as f64);
            sum += term;
        }
        sum
    }

    /// The direct matrix DFT `U = E P E^T` over the whole pupil (what `psf_mono` folds).
    fn psf_mono_direct(l: &Lens, psi_ref: f64, lambda_nm: f64, half: usize) -> Vec<f64> {
        let pupil = l.pupil(psi_ref, lambda_nm);
        let rho = l.pupil_coords();
        let n = rho.len();
        let s = l.cfg.pixel_subsamples;
        let size = 2 * half + 1;
        let m = size * s;
        let xs: Vec<f64> = (0..m).map(|i| (i as f64 + 0.5) / s as f64 - 0.5 - half as f64).collect();
        let k = 2.0 * PI * 0.61 / l.airy_radius_px(lambda_nm);
        let e: Vec<Complex64> = xs.iter().flat_map(|&x| rho.iter().map(move |&r| Complex64::from_polar(1.0, -k * x * r))).collect();
        let mut out = vec![0.0f64; size * size];
        for a in 0..m {
            for b in 0..m {
                let mut u = Complex64::new(0.0, 0.0);
                for j in 0..n {
                    let row: Complex64 = (0..n).map(|i| pupil[j * n + i] * e[b * n + i]).sum();
                    u += e[a * n + j] * row;
                }
                out[(a / s) * size + b / s] += u.norm_sqr();
            }
        }
        let total: f64 = out.iter().sum();
        out.iter_mut().for_each(|v| *v /= total);
        out
    }

    #[test]
    fn folded_psf_equals_the_direct_matrix_dft() {
        // Masked and clear, in and out of focus, even and odd pupil grids and sub-sampling.
        for (masked, psi, lambda, samples, sub) in
            [(true, 0.0, 455.0, 32, 3), (true, 5.5, 610.0, 32, 2), (false, 8.0, 530.0, 33, 3), (true, 2.0, 530.0, 21, 1)]
        {
            let cfg = OpticsConfig { pupil_samples: samples, pixel_subsamples: sub, ..Default::default() };
            let l = Lens::new(&cfg, masked);
            let half = 6;
            let (fast, direct) = (l.psf_mono(psi, lambda, half), psf_mono_direct(&l, psi, lambda, half));
            let peak = direct.iter().copied().fold(0.0, f64::max);
            let worst = fast.iter().zip(&direct).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
            assert!(worst < 1e-12 * peak.max(1e-3), "masked {masked} psi {psi} n {samples}: {worst} of peak {peak}");
        }
    }

    #[test]
    fn psf_sums_to_one_per_channel() {
        for masked in [false, true] {
            for psi in [0.0, 3.0, 8.0] {
                let p = lens(masked).psf_auto(psi);
                for c in 0..3 {
                    assert!((p.channel_sum(c) - 1.0).abs() < 1e-5, "masked {masked} psi {psi} c {c}");
                }
            }
        }
    }

    #[test]
    fn clear_aperture_in_focus_matches_airy_pattern() {
        // Closed form: I(r) ~ (2 J1(v) / v)^2 with v = 1.21967 pi r / a (first zero of J1 at
        // v = 3.8317, i.e. at r = a, the Airy radius).
        let l = lens(false);
        let lambda = 530.0;
        let a = l.airy_radius_px(lambda);
        let radii: Vec<f64> = (1..30).map(|i| i as f64 * 0.1 * a).collect();
        let pts: Vec<(f64, f64)> = radii.iter().map(|&r| (r, 0.0)).collect();
        let i0 = l.field_at(0.0, lambda, &[(0.0, 0.0)])[0].norm_sqr();
        let field = l.field_at(0.0, lambda, &pts);
        for (r, u) in radii.iter().zip(field) {
            let v = 3.831706 * r / a;
            let airy = (2.0 * bessel_j1(v) / v).powi(2);
            assert!((u.norm_sqr() / i0 - airy).abs() < 2e-3, "r {r}: {} vs {airy}", u.norm_sqr() / i0);
        }
    }

    #[test]
    fn first_dark_ring_at_1_22_lambda_f_number() {
        let cfg = OpticsConfig::default();
        let l = Lens::new(&cfg, false);
        for lambda in [455.0, 530.0, 610.0] {
            // 1.22 lambda F# with F# = f / 2R, in pixels of pitch p.
            let expect = 1.22 * lambda * 1e-9 * (cfg.focal_length_mm / (2.0 * cfg.aperture_radius_mm)) / (cfg.pixel_pitch_um * 1e-6);
            let pts: Vec<(f64, f64)> = (0..400).map(|i| (0.5 * expect + i as f64 * expect / 400.0, 0.0)).collect();
            let inten: Vec<f64> = l.field_at(0.0, lambda, &pts).iter().map(|u| u.norm_sqr()).collect();
            let imin = (1..inten.len() - 1).find(|&i| inten[i] < inten[i - 1] && inten[i] <= inten[i + 1]).unwrap();
            let r = pts[imin].0;
            assert!((r / expect - 1.0).abs() < 0.02, "lambda {lambda}: dark ring at {r}, expected {expect}");
        }
    }

    #[test]
    fn psf_width_grows_with_wavelength() {
        let p = lens(false).psf_auto(0.0);
        let r50: Vec<f64> = (0..3).map(|c| p.energy_radius(c, 0.5)).collect();
        assert!(r50[0] > r50[1] && r50[1] > r50[2], "R G B r50 {r50:?}");
        // Diffraction scales with lambda: 610/455 = 1.34; pixel integration softens it a little.
        assert!(r50[0] / r50[2] > 1.15, "{r50:?}");
    }

    #[test]
    fn clear_aperture_in_focus_is_rotationally_symmetric() {
        let l = lens(false);
        let a = l.airy_radius_px(530.0);
        for r in [0.3 * a, 0.7 * a, 1.4 * a, 1.8 * a] {
            let angles: Vec<(f64, f64)> = (0..12)
                .map(|i| {
                    let t = i as f64 * PI / 12.0 + 0.1;
                    (r * t.cos(), r * t.sin())
                })
                .collect();
            let v: Vec<f64> = l.field_at(0.0, 530.0, &angles).iter().map(|u| u.norm_sqr()).collect();
            let (lo, hi) = v.iter().fold((f64::MAX, 0.0f64), |(lo, hi), &x| (lo.min(x), hi.max(x)));
            let i0 = l.field_at(0.0, 530.0, &[(0.0, 0.0)])[0].norm_sqr();
            assert!((hi - lo) / i0 < 2e-3, "r {r}: spread {} of peak", (hi - lo) / i0);
        }
    }

    #[test]
    fn phase_coded_sharpest_channel_goes_blue_green_red() {
        let l = lens(true);
        let sharp: Vec<usize> = [0.0, 4.0, 8.0].iter().map(|&psi| l.psf_auto(psi).sharpest_channel()).collect();
        assert_eq!(sharp, vec![2, 1, 0], "sharpest channel (0 R, 1 G, 2 B) at psi 0, 4, 8");
    }

    #[test]
    fn flipped_defocus_sign_breaks_the_colour_code() {
        // The convention test: with the defocus sign opposite to the mask phase, the sharpest
        // channel does not go blue -> green -> red.
        let cfg = OpticsConfig { defocus_sign: -1.0, ..Default::default() };
        let l = Lens::new(&cfg, true);
        let sharp: Vec<usize> = [0.0, 4.0, 8.0].iter().map(|&psi| l.psf_auto(psi).sharpest_channel()).collect();
        assert_ne!(sharp, vec![2, 1, 0]);
    }

    #[test]
    fn defocus_widens_the_clear_aperture_psf_to_its_geometric_radius() {
        let l = lens(false);
        let p = l.psf_auto(8.0);
        let r90 = p.energy_radius(2, 0.9);
        let geo = l.geometric_radius_px(8.0);
        assert!(r90 > 0.7 * geo && r90 < 1.1 * geo, "r90 {r90}, geometric {geo}");
    }

    #[test]
    fn trimming_keeps_the_energy_and_the_centre() {
        let l = lens(true);
        let full = l.psf(6.0, l.support_half(6.0));
        let h = full.needed_half(5e-3);
        assert!(h < full.half());
        let t = full.resized(h);
        assert_eq!(t.size, 2 * h + 1);
        // The centre pixel keeps its value up to the renormalisation, which is at most
        // 1 / (1 - 0.005) since trimming dropped at most 0.5% of the energy.
        let c_full = full.channels[1][full.half() * full.size + full.half()];
        let c_trim = t.channels[1][h * t.size + h];
        let gain = c_trim / c_full;
        assert!((1.0..=1.0 / (1.0 - 5e-3) + 1e-6).contains(&gain), "gain {gain}");
    }
}
