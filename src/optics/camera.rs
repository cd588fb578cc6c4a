//! Cameras: each turns a window of N sub-frames into N per-sub-frame kernels.
//!
//! A kernel is a colour PSF, a weight (the share of the exposure the sub-frame gets; the
//! weights of a window sum to 1, so exposure is constant across N and cameras) and a shift
//! (where the sensor is relative to the scene during the sub-frame). A camera also reports its
//! light throughput: the fluttered shutter keeps its shutter closed half the time, so its
//! image, brought to the same brightness, carries twice the noise.
//!
//! ## Usage
//! ```
//! use pipeline::optics::{Camera, CameraConfig, CameraKind, OpticsConfig};
//! let cam = Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::Conventional));
//! let window = cam.window(9).unwrap();
//! assert_eq!(window.len(), 9);
//! ```

use super::config::{Axis, CameraConfig, CameraKind, OpticsConfig, PsfAxis, PsiSchedule};
use super::measured::{Stack, StackError};
use super::psf::{Lens, Psf};
use crate::checks::ConfigError;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

/// What a camera does to the light of one sub-frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SubframeKernel {
    /// Colour PSF (unit sum per channel).
    pub psf: Arc<Psf>,
    /// Share of the exposure; a window's weights sum to 1.
    pub weight: f64,
    /// Sensor displacement in pixels (x, y): the image of the sub-frame moves by this much.
    pub shift: [f64; 2],
    /// psi of the sub-frame (0 for cameras without a sweep).
    pub psi: f64,
}

impl SubframeKernel {
    /// Half-width a spatial kernel needs to hold the PSF and the shift.
    pub fn half_extent(&self) -> usize {
        self.psf.half() + self.shift[0].abs().max(self.shift[1].abs()).ceil() as usize
    }

    /// The spatial kernel of channel `c` on a `(2 half + 1)^2` grid, shift included (bilinear
    /// for sub-pixel shifts) and scaled by the weight. Row-major, centred.
    ///
    /// # Panics
    /// If `half < self.half_extent()`.
    pub fn render(&self, c: usize, half: usize) -> Vec<f32> {
        assert!(half >= self.half_extent(), "kernel half-width {half} < {}", self.half_extent());
        let n = 2 * half + 1;
        let mut out = vec![0.0f32; n * n];
        let (fx, fy) = (self.shift[0].floor(), self.shift[1].floor());
        let (ax, ay) = (self.shift[0] - fx, self.shift[1] - fy);
        let taps = [(0, 0, (1.0 - ax) * (1.0 - ay)), (1, 0, ax * (1.0 - ay)), (0, 1, (1.0 - ax) * ay), (1, 1, ax * ay)];
        let p = &self.psf;
        let (ph, h) = (p.half() as isize, half as isize);
        for (dx, dy, w) in taps {
            if w == 0.0 {
                continue;
            }
            let w = (w * self.weight) as f32;
            for y in 0..p.size as isize {
                for x in 0..p.size as isize {
                    let oy = y - ph + h + fy as isize + dy;
                    let ox = x - ph + h + fx as isize + dx;
                    if oy >= 0 && ox >= 0 && oy < n as isize && ox < n as isize {
                        out[(oy * n as isize + ox) as usize] += w * p.channels[c][(y * p.size as isize + x) as usize];
                    }
                }
            }
        }
        out
    }
}

impl SubframeKernel {
    /// As [`SubframeKernel::render`] on a `(2 half + 1)^2` grid of the caller's choice: the parts
    /// of the kernel that fall outside it are dropped.
    pub fn render_cropped(&self, c: usize, half: usize) -> Vec<f32> {
        let need = self.half_extent().max(half);
        if need == half {
            return self.render(c, half);
        }
        let big = self.render(c, need);
        let (bn, off, side) = (2 * need + 1, need - half, 2 * half + 1);
        (0..side * side).map(|i| big[(i / side + off) * bn + i % side + off]).collect()
    }
}

/// A camera with a kernel cache: each (N, k) kernel is computed once per camera.
pub struct Camera {
    optics: OpticsConfig,
    cfg: CameraConfig,
    lens: Option<Lens>,
    /// The `measured` camera's stack, or why it could not be read.
    stack: Option<Result<Arc<Stack>, Arc<StackError>>>,
    /// PSFs by psi bits: different N that share a psi share the PSF.
    psfs: Mutex<HashMap<u64, Arc<Psf>>>,
    windows: Mutex<HashMap<usize, Arc<Vec<SubframeKernel>>>>,
    stats: Mutex<CacheStats>,
}

/// How often the cache answered.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CacheStats {
    pub window_hits: u64,
    pub window_misses: u64,
    pub psfs_computed: u64,
}

impl Camera {
    pub fn new(optics: &OpticsConfig, cfg: &CameraConfig) -> Camera {
        let lens = match cfg.kind {
            CameraKind::PhaseCoded => Some(Lens::new(optics, true)),
            CameraKind::FocusSweep => Some(Lens::new(optics, false)),
            _ if cfg.diffraction => Some(Lens::new(optics, false)),
            _ => None,
        };
        let stack = (cfg.kind == CameraKind::Measured).then(|| match &cfg.psf_path {
            Some(p) => Stack::read(p, cfg.psf_normalise).map(Arc::new).map_err(Arc::new),
            None => Err(Arc::new(StackError::Missing)),
        });
        Camera {
            optics: optics.clone(),
            cfg: cfg.clone(),
            lens,
            stack,
            psfs: Mutex::new(HashMap::new()),
            windows: Mutex::new(HashMap::new()),
            stats: Mutex::new(CacheStats::default()),
        }
    }

    pub fn kind(&self) -> CameraKind {
        self.cfg.kind
    }

    pub fn config(&self) -> &CameraConfig {
        &self.cfg
    }

    pub fn optics(&self) -> &OpticsConfig {
        &self.optics
    }

    pub fn cache_stats(&self) -> CacheStats {
        *self.stats.lock().unwrap()
    }

    /// Fraction of the light a conventional camera would collect in the same exposure.
    pub fn light_throughput(&self) -> f64 {
        match self.cfg.kind {
            CameraKind::Flutter => {
                let code = self.code();
                code.iter().filter(|&&b| b).count() as f64 / code.len() as f64
            }
            _ => 1.0,
        }
    }

    fn code(&self) -> Vec<bool> {
        self.cfg.flutter_code.chars().map(|c| c == '1').collect()
    }

    /// psi of each of the N sub-frames.
    pub fn psi_schedule(&self, n: usize) -> Result<Vec<f64>, ConfigError> {
        let measured_psi = self.cfg.kind == CameraKind::Measured && self.cfg.psf_over == PsfAxis::Psi;
        if !matches!(self.cfg.kind, CameraKind::PhaseCoded | CameraKind::FocusSweep) && !measured_psi {
            return Ok(vec![0.0; n]);
        }
        if let Some(v) = &self.cfg.psi_values {
            if v.len() != n {
                return Err(ConfigError {
                    key: "camera.psi_values".into(),
                    message: format!("has {} values but the window has {n} sub-frames", v.len()),
                });
            }
            return Ok(v.clone());
        }
        let [a, b] = self.cfg.psi;
        Ok((0..n)
            .map(|k| match self.cfg.psi_schedule {
                PsiSchedule::Midpoint => a + (b - a) * (k as f64 + 0.5) / n as f64,
                PsiSchedule::Endpoints if n == 1 => 0.5 * (a + b),
                PsiSchedule::Endpoints => a + (b - a) * k as f64 / (n - 1) as f64,
            })
            .collect())
    }

    /// Weight of each sub-frame (sums to 1).
    pub fn weights(&self, n: usize) -> Vec<f64> {
        match self.cfg.kind {
            CameraKind::Flutter => {
                // Open fraction of sub-frame k's interval [k/n, (k+1)/n) under the chop code.
                let code = self.code();
                let l = code.len();
                let open: Vec<f64> = (0..n)
                    .map(|k| {
                        let (t0, t1) = (k as f64 / n as f64, (k + 1) as f64 / n as f64);
                        (0..l)
                            .filter(|&j| code[j])
                            .map(|j| (t1.min((j + 1) as f64 / l as f64) - t0.max(j as f64 / l as f64)).max(0.0))
                            .sum()
                    })
                    .collect();
                let total: f64 = open.iter().sum();
                open.iter().map(|o| o / total).collect()
            }
            _ => vec![1.0 / n as f64; n],
        }
    }

    /// Sensor displacement of each sub-frame.
    pub fn shifts(&self, n: usize) -> Vec<[f64; 2]> {
        match self.cfg.kind {
            CameraKind::Parabolic => (0..n)
                .map(|k| {
                    let t = -1.0 + 2.0 * (k as f64 + 0.5) / n as f64;
                    let d = self.cfg.parabolic_amplitude_px * t * t;
                    match self.cfg.parabolic_axis {
                        Axis::X => [d, 0.0],
                        Axis::Y => [0.0, d],
                    }
                })
                .collect(),
            _ => vec![[0.0, 0.0]; n],
        }
    }

    fn psf_for(&self, psi: f64) -> Arc<Psf> {
        let Some(lens) = &self.lens else {
            return Arc::new(Psf::delta());
        };
        if let Some(p) = self.psfs.lock().unwrap().get(&psi.to_bits()) {
            return p.clone();
        }
        let p = Arc::new(lens.psf(psi, lens.support_half(psi.abs())));
        self.stats.lock().unwrap().psfs_computed += 1;
        self.psfs.lock().unwrap().entry(psi.to_bits()).or_insert(p).clone()
    }

    /// The image of a point that travels `travel` pixels (x, y) at constant speed over a window
    /// of `n` sub-frames, centred where it is at mid-exposure: the camera's motion PSF for that
    /// velocity, per channel, on a `(2 half + 1)^2` grid (unit sum inside the grid). Sub-frame k
    /// is at time t_k in [-1, 1] ([`crate::render::scene::sub_time`]), the point at `travel / 2 * t_k`.
    ///
    /// # Errors
    /// As [`Camera::window`].
    pub fn moving_point(&self, n: usize, travel: [f64; 2], half: usize) -> Result<[Vec<f32>; 3], ConfigError> {
        let side = 2 * half + 1;
        let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0f32; side * side]);
        for kern in self.moving_kernels(n, travel)? {
            for (c, o) in out.iter_mut().enumerate() {
                o.iter_mut().zip(kern.render_cropped(c, half)).for_each(|(a, v)| *a += v);
            }
        }
        Ok(out)
    }

    /// The window's kernels with a point's motion added to their shifts: sub-frame k (time t_k
    /// in [-1, 1]) is displaced by `travel / 2 * t_k`.
    ///
    /// # Errors
    /// As [`Camera::window`].
    pub fn moving_kernels(&self, n: usize, travel: [f64; 2]) -> Result<Vec<SubframeKernel>, ConfigError> {
        Ok(self
            .window(n)?
            .iter()
            .enumerate()
            .map(|(k, kern)| {
                let t = crate::render::scene::sub_time(k, n);
                SubframeKernel { shift: [kern.shift[0] + travel[0] / 2.0 * t, kern.shift[1] + travel[1] / 2.0 * t], ..kern.clone() }
            })
            .collect())
    }

    /// The N kernels of a window, computed once per N (PSFs in parallel on all cores), then
    /// served from the cache. All PSFs of a window share one trimmed size.
    ///
    /// # Errors
    /// If `psi_values` does not have N entries.
    pub fn window(&self, n: usize) -> Result<Arc<Vec<SubframeKernel>>, ConfigError> {
        if let Some(w) = self.windows.lock().unwrap().get(&n) {
            self.stats.lock().unwrap().window_hits += 1;
            return Ok(w.clone());
        }
        self.stats.lock().unwrap().window_misses += 1;
        let psis = self.psi_schedule(n)?;
        let kernels = match &self.stack {
            Some(stack) => self.measured_kernels(n, stack, &psis)?,
            None => self.computed_kernels(n, &psis),
        };
        let w = Arc::new(kernels);
        self.windows.lock().unwrap().insert(n, w.clone());
        Ok(w)
    }

    /// The computed cameras' kernels of a window: the PSFs of its psi values (in parallel on all
    /// cores, each once per camera), trimmed to one common size.
    fn computed_kernels(&self, n: usize, psis: &[f64]) -> Vec<SubframeKernel> {
        let psfs: Vec<Arc<Psf>> = {
            use rayon::prelude::*;
            psis.par_iter().map(|&p| self.psf_for(p)).collect()
        };
        // One common size for the window: the largest that any kernel needs.
        let half = psfs.iter().map(|p| p.needed_half(self.optics.trim_energy)).max().unwrap_or(0);
        let (weights, shifts) = (self.weights(n), self.shifts(n));
        (0..n)
            .map(|k| SubframeKernel {
                psf: if psfs[k].half() == half { psfs[k].clone() } else { Arc::new(psfs[k].resized(half)) },
                weight: weights[k],
                shift: shifts[k],
                psi: psis[k],
            })
            .collect()
    }

    /// The kernels of a `measured` camera's window: each sub-frame's PSF from the stack, untrimmed (a
    /// stack is used as measured), equal weights, no shift.
    fn measured_kernels(
        &self,
        n: usize,
        stack: &Result<Arc<Stack>, Arc<StackError>>,
        psis: &[f64],
    ) -> Result<Vec<SubframeKernel>, ConfigError> {
        let stack = stack.as_ref().map_err(|e| ConfigError { key: "camera.psf_path".into(), message: e.to_string() })?;
        Ok((0..n)
            .map(|j| {
                let psf = match self.cfg.psf_over {
                    PsfAxis::Instants => stack.at_instant(j, n),
                    PsfAxis::Psi => stack.at_psi(psis[j], self.cfg.psi),
                };
                SubframeKernel { psf: Arc::new(psf), weight: 1.0 / n as f64, shift: [0.0; 2], psi: psis[j] }
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::config::RASKAR_CODE;

    fn cam(kind: CameraKind) -> Camera {
        Camera::new(&OpticsConfig::default(), &CameraConfig::new(kind))
    }

    /// Largest normalised cross-correlation of two square images over all shifts.
    fn best_correlation(a: &[f32], b: &[f32]) -> f64 {
        let n = (a.len() as f64).sqrt() as isize;
        let norm = |v: &[f32]| v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
        let mut best = 0.0f64;
        for dy in -n + 1..n {
            for dx in -n + 1..n {
                let mut s = 0.0;
                for y in 0.max(-dy)..n.min(n - dy) {
                    for x in 0.max(-dx)..n.min(n - dx) {
                        s += a[(y * n + x) as usize] as f64 * b[((y + dy) * n + x + dx) as usize] as f64;
                    }
                }
                best = best.max(s);
            }
        }
        best / (norm(a) * norm(b))
    }

    #[test]
    fn parabolic_blur_is_nearly_the_same_along_its_axis_and_not_across() {
        // a = 8 px: the sensor's speed covers objects travelling up to 4a = 32 px per exposure.
        let c = cam(CameraKind::Parabolic);
        let k = |travel: [f64; 2]| c.moving_point(52, travel, 24).unwrap()[1].clone();
        let still = k([0.0, 0.0]);
        for t in [8.0, -8.0, 16.0, -16.0] {
            let r = best_correlation(&still, &k([t, 0.0]));
            assert!(r > 0.85, "travel {t} px along x: correlation {r}");
        }
        for t in [8.0, 16.0] {
            let r = best_correlation(&still, &k([0.0, t]));
            assert!(r < 0.6, "travel {t} px along y: correlation {r}");
        }
        // A conventional camera's blur changes with speed along x too: that is what the sensor
        // motion buys.
        let conv = cam(CameraKind::Conventional);
        let kc = |t: f64| conv.moving_point(52, [t, 0.0], 24).unwrap()[1].clone();
        assert!(best_correlation(&kc(0.0), &kc(16.0)) < 0.4);
    }

    #[test]
    fn a_moving_point_keeps_its_energy_and_travels() {
        let c = cam(CameraKind::PhaseCoded);
        let p = c.moving_point(9, [12.0, 0.0], 30).unwrap();
        for ch in &p {
            let s: f32 = ch.iter().sum();
            assert!((s - 1.0).abs() < 0.02, "energy {s}");
        }
        // The point moves to the right while psi sweeps 0 -> 8: blue is sharpest early (left),
        // green in the middle, red late (right), so the channels peak left to right.
        let peak_col = |v: &[f32]| v.iter().enumerate().max_by(|a, b| a.1.total_cmp(b.1)).unwrap().0 % 61;
        let (r, g, b) = (peak_col(&p[0]), peak_col(&p[1]), peak_col(&p[2]));
        assert!(b <= g && g <= r && b + 3 <= r, "peak columns: blue {b}, green {g}, red {r}");
    }

    #[test]
    fn conventional_gives_the_same_delta_kernel_for_every_subframe() {
        let w = cam(CameraKind::Conventional).window(9).unwrap();
        assert!(w.iter().all(|k| k.psf == w[0].psf && k.shift == [0.0, 0.0]));
        assert_eq!(*w[0].psf, Psf::delta());
        assert!(w.iter().all(|k| (k.weight - 1.0 / 9.0).abs() < 1e-12));
    }

    #[test]
    fn conventional_with_diffraction_is_the_same_airy_spot_everywhere() {
        let cfg = CameraConfig { diffraction: true, ..CameraConfig::new(CameraKind::Conventional) };
        let w = Camera::new(&OpticsConfig::default(), &cfg).window(7).unwrap();
        assert!(w[0].psf.size > 1);
        assert!(w.iter().all(|k| k.psf == w[0].psf));
    }

    #[test]
    fn flutter_code_has_26_of_52_chops_open_and_weights_follow_it() {
        assert_eq!(RASKAR_CODE.len(), 52);
        assert_eq!(RASKAR_CODE.chars().filter(|&c| c == '1').count(), 26);
        let c = cam(CameraKind::Flutter);
        assert_eq!(c.light_throughput(), 0.5);
        // With one sub-frame per chop the weights are the code itself over 26.
        let w = c.weights(52);
        for (wk, ch) in w.iter().zip(RASKAR_CODE.chars()) {
            let expect = if ch == '1' { 1.0 / 26.0 } else { 0.0 };
            assert!((wk - expect).abs() < 1e-12);
        }
        let w9 = c.weights(9);
        assert!((w9.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(w9.iter().any(|&x| (x - 1.0 / 9.0).abs() > 0.01), "the code must modulate 9 sub-frames: {w9:?}");
    }

    #[test]
    fn parabolic_shifts_follow_a_t_squared() {
        let cfg = CameraConfig { parabolic_amplitude_px: 6.0, ..CameraConfig::new(CameraKind::Parabolic) };
        let c = Camera::new(&OpticsConfig::default(), &cfg);
        let n = 11;
        for (k, s) in c.shifts(n).iter().enumerate() {
            let t = -1.0 + 2.0 * (k as f64 + 0.5) / n as f64;
            assert!((s[0] - 6.0 * t * t).abs() < 1e-12 && s[1] == 0.0);
        }
        // Velocity (first difference) changes linearly: the second difference is constant.
        let s = c.shifts(n);
        let d2: Vec<f64> = (1..n - 1).map(|k| s[k + 1][0] - 2.0 * s[k][0] + s[k - 1][0]).collect();
        assert!(d2.iter().all(|d| (d - d2[0]).abs() < 1e-12 && *d > 0.0));
    }

    #[test]
    fn focus_sweep_widens_every_colour_and_the_mask_colours_it() {
        let sweep = cam(CameraKind::FocusSweep).window(9).unwrap();
        let (first, last) = (&sweep[0].psf, &sweep[8].psf);
        for c in 0..3 {
            assert!(last.peak(c) < 0.5 * first.peak(c), "channel {c} must widen along the sweep");
        }
        let coded = cam(CameraKind::PhaseCoded).window(9).unwrap();
        assert_eq!(coded[0].psf.sharpest_channel(), 2);
        assert_eq!(coded[8].psf.sharpest_channel(), 0);
    }

    #[test]
    fn window_kernels_share_a_size_and_come_from_the_cache() {
        let c = cam(CameraKind::PhaseCoded);
        let a = c.window(9).unwrap();
        assert!(a.iter().all(|k| k.psf.size == a[0].psf.size));
        let b = c.window(9).unwrap();
        assert!(Arc::ptr_eq(&a, &b));
        let s = c.cache_stats();
        assert_eq!((s.window_misses, s.window_hits, s.psfs_computed), (1, 1, 9));
        let psis: Vec<f64> = a.iter().map(|k| k.psi).collect();
        assert!((psis[0] - 8.0 * 0.5 / 9.0).abs() < 1e-12 && (psis[8] - 8.0 * 8.5 / 9.0).abs() < 1e-12);
    }

    #[test]
    fn rendered_kernel_sums_to_weight_and_carries_the_shift() {
        let k = SubframeKernel { psf: Arc::new(Psf::delta()), weight: 0.25, shift: [1.5, -2.0], psi: 0.0 };
        let half = k.half_extent();
        let r = k.render(0, half);
        let n = 2 * half + 1;
        assert!((r.iter().sum::<f32>() - 0.25).abs() < 1e-6);
        // Centroid at the shift.
        let (mut cx, mut cy) = (0.0, 0.0);
        for (i, v) in r.iter().enumerate() {
            cx += (i % n) as f64 * *v as f64;
            cy += (i / n) as f64 * *v as f64;
        }
        assert!((cx / 0.25 - half as f64 - 1.5).abs() < 1e-6 && (cy / 0.25 - half as f64 + 2.0).abs() < 1e-6);
    }

    #[test]
    fn psi_values_of_the_wrong_length_are_an_error_naming_the_key() {
        let cfg = CameraConfig { psi_values: Some(vec![0.0, 1.0]), ..Default::default() };
        let e = Camera::new(&OpticsConfig::default(), &cfg).window(9).unwrap_err();
        assert_eq!(e.key, "camera.psi_values");
    }
}
