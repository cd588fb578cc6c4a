//! Classical reconstructions for the cameras the paper compares against: the fluttered shutter
//! by least squares along a known motion (Raskar et al. 2006), the parabolic-motion camera by
//! Lucy-Richardson deconvolution with its single kernel (Levin et al. 2008). Both work in linear
//! light. And the bound `pipeline eval` sets beside the networks: the linear minimum-mean-square-
//! error (Wiener) reconstruction that is told the true kernel ([`wiener_bound`]).

use crate::optics::fft::{fast_size, reflect, FftConv};
use crate::render::scene::sub_time;
use num_complex::Complex32;

/// How a smeared row meets its ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ends {
    /// The observation is as long as the row; sources beyond the ends repeat the end pixels
    /// (square A; ill-conditioned near the ends).
    Clamp,
    /// The whole smear is observed: `n + 2 pad` values for `n` sources (Raskar's 1-D model;
    /// A has full column rank for any code that is not all zero).
    Full,
    /// The observation is as long as the row and the unknowns extend `pad` past each end (an
    /// image row whose scene goes on beyond the frame): underdetermined, so it needs lambda > 0;
    /// the solution returned by `solve_planes` is the middle `n`. Far better conditioned than
    /// [`Ends::Clamp`], whose merged end pixels make the square system nearly singular.
    Extend,
}

/// The smear of a row of `n` pixels by motion along it: sub-frame k (weight `weights[k]`, time
/// t_k in [-1, 1]) sees the row moved by `travel_px / 2 * t_k` pixels (linear interpolation), so
/// `b = A s`. Returns the number of observed values, of unknowns, and A (row-major).
pub fn smear_matrix(n: usize, weights: &[f64], travel_px: f64, ends: Ends) -> (usize, usize, Vec<f64>) {
    let m = weights.len();
    let pad = (travel_px.abs() / 2.0).ceil() as usize + 1;
    let (rows, cols, row_off, col_off) = match ends {
        Ends::Clamp => (n, n, 0, 0),
        Ends::Full => (n + 2 * pad, n, pad, 0),
        Ends::Extend => (n, n + 2 * pad, 0, pad),
    };
    let mut a = vec![0.0; rows * cols];
    for (k, &wk) in weights.iter().enumerate() {
        let d = travel_px / 2.0 * sub_time(k, m);
        for i in 0..rows {
            // Observed pixel i sees the source that sat at i - d at mid-exposure (in row
            // coordinates; unknown j is row position j - col_off).
            let src = i as f64 - row_off as f64 - d + col_off as f64;
            let j0 = src.floor();
            let f = src - j0;
            for (j, wgt) in [(j0 as isize, 1.0 - f), (j0 as isize + 1, f)] {
                if wgt == 0.0 {
                    continue;
                }
                let j = match ends {
                    Ends::Clamp => j.clamp(0, n as isize - 1),
                    _ if j < 0 || j >= cols as isize => continue,
                    _ => j,
                };
                a[i * cols + j as usize] += wk * wgt;
            }
        }
    }
    (rows, cols, a)
}

/// Least squares along rows for a known smear: `(A^T A + lambda I) s = A^T b`, with the
/// Cholesky factor computed once and reused for every row.
pub struct FlutterSolver {
    /// Unknowns.
    n: usize,
    rows: usize,
    /// Row length and where it starts among the unknowns.
    row_len: usize,
    offset: usize,
    a: Vec<f64>,
    /// Lower-triangular Cholesky factor of A^T A + lambda I, row-major.
    l: Vec<f64>,
}

impl FlutterSolver {
    /// `lambda` regularises against noise (0: plain least squares).
    ///
    /// # Panics
    /// If A^T A + lambda I is not positive definite (a singular smear and lambda 0).
    pub fn new(n: usize, weights: &[f64], travel_px: f64, ends: Ends, lambda: f64) -> FlutterSolver {
        let row_len = n;
        let (rows, n, a) = smear_matrix(row_len, weights, travel_px, ends);
        let offset = (n - row_len) / 2;
        let mut g = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..=i {
                let v: f64 = (0..rows).map(|r| a[r * n + i] * a[r * n + j]).sum();
                g[i * n + j] = v;
                g[j * n + i] = v;
            }
            g[i * n + i] += lambda;
        }
        let mut l = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..=i {
                let s: f64 = g[i * n + j] - (0..j).map(|k| l[i * n + k] * l[j * n + k]).sum::<f64>();
                if i == j {
                    assert!(s > 0.0, "smear normal matrix is singular at {i}");
                    l[i * n + i] = s.sqrt();
                } else {
                    l[i * n + j] = s / l[j * n + j];
                }
            }
        }
        FlutterSolver { n, rows, row_len, offset, a, l }
    }

    /// `A s` (`rows` values).
    pub fn blur(&self, s: &[f64]) -> Vec<f64> {
        (0..self.rows).map(|i| (0..self.n).map(|j| self.a[i * self.n + j] * s[j]).sum()).collect()
    }

    /// The least-squares row for an observed row `b` (`rows` values).
    pub fn solve(&self, b: &[f64]) -> Vec<f64> {
        let n = self.n;
        let atb: Vec<f64> = (0..n).map(|j| (0..self.rows).map(|i| self.a[i * n + j] * b[i]).sum()).collect();
        let mut y = vec![0.0; n];
        for i in 0..n {
            y[i] = (atb[i] - (0..i).map(|k| self.l[i * n + k] * y[k]).sum::<f64>()) / self.l[i * n + i];
        }
        let mut x = vec![0.0; n];
        for i in (0..n).rev() {
            x[i] = (y[i] - (i + 1..n).map(|k| self.l[k * n + i] * x[k]).sum::<f64>()) / self.l[i * n + i];
        }
        x
    }

    /// Every row of every plane (rows as long as the observation: [`Ends::Clamp`] or
    /// [`Ends::Extend`]); returns the rows' own pixels.
    pub fn solve_planes(&self, planes: &[Vec<f32>; 3], h: usize) -> [Vec<f32>; 3] {
        let w = self.row_len;
        assert_eq!(self.rows, w, "solve_planes needs an observation as long as the row");
        std::array::from_fn(|c| {
            (0..h)
                .flat_map(|y| {
                    let row: Vec<f64> = planes[c][y * w..(y + 1) * w].iter().map(|&v| v as f64).collect();
                    self.solve(&row)[self.offset..self.offset + w].iter().map(|&v| v as f32).collect::<Vec<f32>>()
                })
                .collect()
        })
    }
}

/// Lucy-Richardson deconvolution of an `h x w` plane by a centred odd square `kernel` (unit
/// sum), `iters` iterations, on a mirror-padded canvas (FFT, circular on the padding).
pub fn lucy_richardson(img: &[f32], w: usize, h: usize, kernel: &[f32], iters: usize) -> Vec<f32> {
    let kn = (kernel.len() as f64).sqrt().round() as usize;
    let m = kn / 2 + 2;
    let (hp, wp) = (fast_size(h + 2 * m), fast_size(w + 2 * m));
    let mut fft = FftConv::new(hp, wp);
    let k = fft.kernel_spectrum(kernel);
    let kt: Vec<Complex32> = k.iter().map(|v| v.conj()).collect();
    let mut b = vec![0.0f32; hp * wp];
    for y in 0..hp {
        for x in 0..wp {
            let (sy, sx) = (reflect(y as isize - m as isize, h), reflect(x as isize - m as isize, w));
            b[y * wp + x] = img[sy * w + sx].max(0.0);
        }
    }
    let eps = 1e-6f32;
    let mut u = b.clone();
    let mut spec = fft.zero_spectrum();
    let mut tmp = vec![0.0f32; hp * wp];
    for _ in 0..iters {
        fft.forward_mul(&u, &k, &mut spec);
        fft.inverse(&mut spec, &mut tmp);
        for (t, &bv) in tmp.iter_mut().zip(&b) {
            *t = bv / t.max(eps);
        }
        fft.forward_mul(&tmp, &kt, &mut spec);
        fft.inverse(&mut spec, &mut tmp);
        for (uv, &c) in u.iter_mut().zip(&tmp) {
            *uv *= c.max(0.0);
        }
    }
    (0..h).flat_map(|y| u[(y + m) * wp + m..(y + m) * wp + m + w].to_vec()).collect()
}

/// What the linear minimum-mean-square-error (Wiener) reconstruction gets back of an `h x w`
/// plane when it is told the true `kernel` (centred odd square), the noise variance and the
/// sharp plane's power spectrum averaged over rings of equal spatial frequency: the best any
/// linear, shift-invariant reconstruction can do, up to that averaging. The capture is simulated
/// here on a mirror-padded canvas, circularly, with white noise of `noise_var` (seeded by `key`),
/// so the model is exact at the borders (a Wiener filter applied to a crop of a real capture
/// would amplify the crop's edges near the kernel's zeros). Returns (capture, reconstruction).
pub fn wiener_bound(sharp: &[f32], w: usize, h: usize, kernel: &[f32], noise_var: f64, key: u64) -> (Vec<f32>, Vec<f32>) {
    let kn = (kernel.len() as f64).sqrt().round() as usize;
    let m = kn / 2 + 2;
    let (hp, wp) = (fast_size(h + 2 * m), fast_size(w + 2 * m));
    let mut fft = FftConv::new(hp, wp);
    let k = fft.kernel_spectrum(kernel);
    let mut canvas = vec![0.0f32; hp * wp];
    for y in 0..hp {
        for x in 0..wp {
            canvas[y * wp + x] = sharp[reflect(y as isize - m as isize, h) * w + reflect(x as isize - m as isize, w)];
        }
    }
    let ones = vec![Complex32::new(1.0, 0.0); fft.spectrum_len()];
    let mut xs = fft.zero_spectrum();
    fft.forward_mul(&canvas, &ones, &mut xs);
    // The capture: blurred, plus white noise.
    let mut ys: Vec<Complex32> = xs.iter().zip(&k).map(|(x, k)| x * k).collect();
    let mut y = vec![0.0f32; hp * wp];
    fft.inverse(&mut ys, &mut y);
    let sd = noise_var.sqrt();
    for (i, v) in y.iter_mut().enumerate() {
        *v += (sd * crate::rng::normal(crate::rng::hash(&[key, i as u64]))) as f32;
    }
    let crop = |c: &[f32]| -> Vec<f32> { (0..h).flat_map(|r| c[(r + m) * wp + m..(r + m) * wp + m + w].to_vec()).collect() };
    let capture = crop(&y);
    let mut ys = fft.zero_spectrum();
    fft.forward_mul(&y, &ones, &mut ys);
    // Ring-averaged |X|^2 (transposed layout: column fx of hp values fy).
    const BINS: usize = 96;
    let ring = |i: usize| -> usize {
        let (fx, fy) = (i / hp, i % hp);
        let (u, v) = (fx as f64 / wp as f64, fy.min(hp - fy) as f64 / hp as f64);
        (((u * u + v * v).sqrt() / 0.7072) * BINS as f64).min(BINS as f64 - 1.0) as usize
    };
    let (mut pow, mut cnt) = (vec![0.0f64; BINS], vec![0usize; BINS]);
    for (i, x) in xs.iter().enumerate() {
        pow[ring(i)] += x.norm_sqr() as f64;
        cnt[ring(i)] += 1;
    }
    // The unnormalised DFT of white noise has power hp * wp * variance at every frequency.
    let n2 = (hp * wp) as f64 * noise_var;
    for (i, yv) in ys.iter_mut().enumerate() {
        let s = pow[ring(i)] / cnt[ring(i)].max(1) as f64;
        *yv *= k[i].conj() * (s / (k[i].norm_sqr() as f64 * s + n2).max(1e-30)) as f32;
    }
    let mut out = vec![0.0f32; hp * wp];
    fft.inverse(&mut ys, &mut out);
    (capture, crop(&out))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::config::RASKAR_CODE;
    use crate::optics::fft::convolve_direct;

    fn code_weights() -> Vec<f64> {
        let open: Vec<f64> = RASKAR_CODE.chars().map(|c| if c == '1' { 1.0 } else { 0.0 }).collect();
        let s: f64 = open.iter().sum();
        open.into_iter().map(|v| v / s).collect()
    }

    #[test]
    fn a_point_is_smeared_into_the_code() {
        // Two pixels per chop: sub-frame k moves the row by 2k - 51 pixels.
        let (rows, cols, a) = smear_matrix(160, &code_weights(), 104.0, Ends::Clamp);
        assert_eq!((rows, cols), (160, 160));
        let mut s = vec![0.0; 160];
        s[80] = 1.0;
        let b: Vec<f64> = (0..160).map(|i| (0..160).map(|j| a[i * 160 + j] * s[j]).sum()).collect();
        for (k, ch) in RASKAR_CODE.chars().enumerate() {
            let i = (80 + 2 * k as isize - 51) as usize;
            let want = if ch == '1' { 1.0 / 26.0 } else { 0.0 };
            assert!((b[i] - want).abs() < 1e-12, "chop {k}: {} vs {want}", b[i]);
        }
        assert!((b.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }

    #[test]
    fn flutter_least_squares_recovers_a_row_exactly_without_noise() {
        let n = 160;
        let solver = FlutterSolver::new(n, &code_weights(), 104.0, Ends::Full, 0.0);
        let s: Vec<f64> = (0..n).map(|i| crate::rng::unit(crate::rng::hash(&[i as u64, 5]))).collect();
        let b = solver.blur(&s);
        // The blur really mixes: the observation is far from the signal.
        let before = b[53..53 + n].iter().zip(&s).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(before > 0.2, "{before}");
        let x = solver.solve(&b);
        let worst = x.iter().zip(&s).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
        assert!(worst < 1e-6, "recovered to {worst}");
        // Why the code: with a little noise on the observation, the plain least-squares solution
        // of the coded smear stays close, that of a box exposure of the same length does not.
        let boxw = vec![1.0 / 52.0; 52];
        let err = |weights: &[f64]| {
            let sv = FlutterSolver::new(n, weights, 104.0, Ends::Full, 0.0);
            let noisy: Vec<f64> =
                sv.blur(&s).iter().enumerate().map(|(i, v)| v + 0.01 * crate::rng::normal(crate::rng::hash(&[i as u64, 9]))).collect();
            let x = sv.solve(&noisy);
            (x.iter().zip(&s).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / n as f64).sqrt()
        };
        let (coded, boxed) = (err(&code_weights()), err(&boxw));
        assert!(coded * 5.0 < boxed, "noise gain: coded {coded}, box {boxed}");
    }

    #[test]
    fn lucy_richardson_converges_on_a_known_kernel() {
        let (w, h) = (48, 40);
        let img: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                0.2 + 0.6 * (((x / 5.0).sin() * (y / 4.0).cos()) > 0.2) as i32 as f32
            })
            .collect();
        // A horizontal parabolic-like 1-D kernel in a 9x9 grid.
        let mut kernel = vec![0.0f32; 81];
        for (x, v) in [(0, 4.0), (1, 2.0), (2, 1.0), (3, 1.0), (4, 1.0), (5, 1.0), (6, 1.0), (7, 2.0), (8, 4.0)] {
            kernel[4 * 9 + x] = v / 17.0;
        }
        let blurred = convolve_direct(&img, h, w, &kernel);
        let rmse = |a: &[f32]| (a.iter().zip(&img).map(|(x, y)| (x - y).powi(2)).sum::<f32>() / a.len() as f32).sqrt();
        let (e0, e10, e200) =
            (rmse(&blurred), rmse(&lucy_richardson(&blurred, w, h, &kernel, 10)), rmse(&lucy_richardson(&blurred, w, h, &kernel, 200)));
        assert!(e10 < e0 && e200 < e10 && e200 < 0.4 * e0, "rmse blurred {e0}, 10 iterations {e10}, 200 {e200}");
        // A delta kernel leaves the image as it is.
        let mut delta = vec![0.0f32; 9];
        delta[4] = 1.0;
        let same = lucy_richardson(&img, w, h, &delta, 5);
        assert!(same.iter().zip(&img).all(|(a, b)| (a - b).abs() < 1e-4));
    }

    #[test]
    fn wiener_with_the_true_kernel_undoes_a_blur_far_better_than_doing_nothing() {
        let (w, h) = (96, 80);
        let mut rng = crate::rng::Rng::new(4);
        // A photograph-like texture: waves in every direction, amplitude falling as 1 / frequency
        // (the isotropic spectrum the ring-averaged prior assumes).
        let waves: Vec<(f64, f64, f64, f64)> = (0..300)
            .map(|_| {
                let (f, a) = (rng.range(0.05, 2.5), rng.range(0.0, std::f64::consts::TAU));
                (f * a.cos(), f * a.sin(), rng.range(0.0, 6.3), 0.01 / f)
            })
            .collect();
        let sharp: Vec<f32> = (0..w * h)
            .map(|i| {
                (0.5 + waves.iter().map(|(a, b, c, amp)| amp * (a * (i % w) as f64 + b * (i / w) as f64 + c).sin()).sum::<f64>()) as f32
            })
            .collect();
        // A 9-pixel horizontal smear, centred.
        let kn = 11;
        let mut kernel = vec![0.0f32; kn * kn];
        (1..10).for_each(|x| kernel[5 * kn + x] = 1.0 / 9.0);
        let err = |a: &[f32]| (a.iter().zip(&sharp).map(|(x, y)| ((x - y) as f64).powi(2)).sum::<f64>() / a.len() as f64).sqrt();
        let (capture, rec) = wiener_bound(&sharp, w, h, &kernel, 0.002f64.powi(2), 1);
        // The capture is the blur: the direct convolution agrees inside the borders.
        let direct = convolve_direct(&sharp, h, w, &kernel);
        assert!((capture[40 * w + 40] - direct[40 * w + 40]).abs() < 0.01);
        assert!(err(&rec) < 0.6 * err(&capture), "Wiener {} vs blurred {}", err(&rec), err(&capture));
        // With far more noise, it gets back less, but never does worse than the capture.
        let (capture, noisy) = wiener_bound(&sharp, w, h, &kernel, 0.05f64.powi(2), 1);
        assert!(err(&noisy) > err(&rec) && err(&noisy) < err(&capture), "{} vs {}", err(&noisy), err(&capture));
    }
}
