//! Measured PSFs: the `measured` camera reads a stack of colour PSFs, `.npy` float32 of shape
//! (K, H, W, 3) (the format `pipeline psf --out x.npy` writes and `pipeline calibrate` makes from
//! point-source captures), over the exposure's K instants or over K values of psi, and serves the
//! kernels of a window of N sub-frames from it:
//!
//! - `psf_over = "instants"`: entry k is the PSF of the k-th of K equal slices of the exposure.
//!   Sub-frame j of N, at time (j + 0.5) / N, takes the entry at that time, or the linear blend
//!   of the two entries around it (K = N: the entries themselves, unchanged). The sub-frames'
//!   psi is unknown and recorded as 0.
//! - `psf_over = "psi"`: entry k is the PSF at psi = `psi[0] + (psi[1] - psi[0]) k / (K - 1)`, and
//!   the sub-frames' psi follow `psi_schedule` (or `psi_values`), blended between entries.
//!
//! A stack is checked on load: finite, non-negative, odd H and W, each channel of each entry
//! summing to 1 within 1% (`psf_normalise = true` rescales instead). An H x W entry is centred in
//! a square of the larger side.

use super::psf::Psf;
use crate::io::npy;
use std::path::Path;

/// The stack of a `measured` camera read and checked, as configuration errors under `prefix`
/// (`camera.psf_path`); nothing for the other cameras.
pub fn check(camera: &super::CameraConfig, prefix: &str) -> Vec<crate::checks::ConfigError> {
    match (&camera.psf_path, camera.kind) {
        (Some(p), super::CameraKind::Measured) => match Stack::read(p, camera.psf_normalise) {
            Ok(_) => Vec::new(),
            Err(e) => vec![crate::checks::ConfigError { key: format!("{prefix}.psf_path"), message: e.to_string() }],
        },
        _ => Vec::new(),
    }
}

/// Why a PSF stack was refused: the rule it breaks, with the entry, pixel and channel.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StackError {
    #[error("the measured camera needs a PSF stack (camera.psf_path, .npy (K, H, W, 3))")]
    Missing,
    #[error("{}: {source}", path.display())]
    Read { path: std::path::PathBuf, source: std::io::Error },
    #[error("{}: {source}", path.display())]
    Npy { path: std::path::PathBuf, source: npy::NpyError },
    #[error("shape {0:?}: a PSF stack is (K, H, W, 3) with 1 to 4096 entries")]
    Shape(Vec<usize>),
    #[error("entries of {0}x{1}: a PSF needs odd sides (its centre a pixel) of at most 1025")]
    Sides(usize, usize),
    #[error("entry {entry}, pixel ({x}, {y}), channel {channel}: {value} (a PSF is finite and non-negative)")]
    Value { entry: usize, x: usize, y: usize, channel: &'static str, value: f32 },
    #[error("entry {entry}, channel {channel}: sums to {sum:.4}, not 1 (set psf_normalise = true to rescale it)")]
    Sum { entry: usize, channel: &'static str, sum: f64 },
    /// A rule broken by the array of a named file.
    #[error("{}: {source}", path.display())]
    In { path: std::path::PathBuf, source: Box<StackError> },
}

const CHANNELS: [&str; 3] = ["R", "G", "B"];

/// How far a channel's sum may be from 1 before a stack is refused (without `psf_normalise`).
pub const SUM_TOLERANCE: f64 = 0.01;

/// A checked stack of K colour PSFs of one odd size.
#[derive(Debug, Clone, PartialEq)]
pub struct Stack {
    pub psfs: Vec<Psf>,
}

impl Stack {
    /// Reads and checks a stack; the error is the rule it breaks, with the entry and channel.
    ///
    /// # Errors
    /// Not a float32 `.npy` of shape (K, H, W, 3); a value that is not finite or is negative; an
    /// even H or W; a channel whose sum is not 1 within [`SUM_TOLERANCE`] (unless `normalise`).
    pub fn read(path: &Path, normalise: bool) -> Result<Stack, StackError> {
        let bytes = std::fs::read(path).map_err(|source| StackError::Read { path: path.into(), source })?;
        let (shape, data) = npy::read_f32(&bytes).map_err(|source| StackError::Npy { path: path.into(), source })?;
        Stack::from_array(&shape, &data, normalise).map_err(|e| StackError::In { path: path.into(), source: Box::new(e) })
    }

    /// As [`Stack::read`], from the array itself.
    ///
    /// # Errors
    /// As [`Stack::read`].
    pub fn from_array(shape: &[usize], data: &[f32], normalise: bool) -> Result<Stack, StackError> {
        let &[k, h, w, 3] = shape else {
            return Err(StackError::Shape(shape.to_vec()));
        };
        if k == 0 || k > 4096 {
            return Err(StackError::Shape(shape.to_vec()));
        }
        if h.is_multiple_of(2) || w.is_multiple_of(2) || h > 1025 || w > 1025 {
            return Err(StackError::Sides(h, w));
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite() || *v < 0.0) {
            let (entry, rest) = (i / (h * w * 3), i % (h * w * 3));
            return Err(StackError::Value { entry, x: rest / 3 % w, y: rest / 3 / w, channel: CHANNELS[rest % 3], value: data[i] });
        }
        let n = h.max(w);
        let (oy, ox) = ((n - h) / 2, (n - w) / 2);
        let mut psfs = Vec::with_capacity(k);
        for e in 0..k {
            let mut channels: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0f32; n * n]);
            for y in 0..h {
                for x in 0..w {
                    for (ch, plane) in channels.iter_mut().enumerate() {
                        plane[(y + oy) * n + x + ox] = data[((e * h + y) * w + x) * 3 + ch];
                    }
                }
            }
            for (ch, plane) in channels.iter_mut().enumerate() {
                let sum: f64 = plane.iter().map(|&v| v as f64).sum();
                if normalise && sum > 0.0 {
                    plane.iter_mut().for_each(|v| *v = (*v as f64 / sum) as f32);
                } else if (sum - 1.0).abs() > SUM_TOLERANCE {
                    return Err(StackError::Sum { entry: e, channel: CHANNELS[ch], sum });
                }
            }
            psfs.push(Psf { size: n, channels });
        }
        Ok(Stack { psfs })
    }

    /// The PSF at position `u` in [0, K - 1] along the stack: an entry where `u` is whole, else
    /// the linear blend of the two around it.
    pub fn at(&self, u: f64) -> Psf {
        let last = self.psfs.len() - 1;
        let u = u.clamp(0.0, last as f64);
        let (k0, f) = (u.floor() as usize, (u - u.floor()) as f32);
        if f == 0.0 || k0 == last {
            return self.psfs[k0].clone();
        }
        let (a, b) = (&self.psfs[k0], &self.psfs[k0 + 1]);
        Psf {
            size: a.size,
            channels: std::array::from_fn(|c| a.channels[c].iter().zip(&b.channels[c]).map(|(x, y)| (1.0 - f) * x + f * y).collect()),
        }
    }

    /// The PSF of sub-frame `j` of `n` for a stack over instants.
    pub fn at_instant(&self, j: usize, n: usize) -> Psf {
        let k = self.psfs.len();
        if k == n {
            return self.psfs[j].clone();
        }
        self.at((j as f64 + 0.5) / n as f64 * k as f64 - 0.5)
    }

    /// The PSF at `psi` for a stack over psi from `range[0]` to `range[1]`.
    pub fn at_psi(&self, psi: f64, range: [f64; 2]) -> Psf {
        let last = (self.psfs.len() - 1) as f64;
        if last == 0.0 || range[1] == range[0] {
            return self.psfs[0].clone();
        }
        self.at((psi - range[0]) / (range[1] - range[0]) * last)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stack(k: usize, h: usize, w: usize, f: impl Fn(usize, usize, usize, usize) -> f32) -> (Vec<usize>, Vec<f32>) {
        let mut d = Vec::new();
        for e in 0..k {
            for y in 0..h {
                for x in 0..w {
                    for c in 0..3 {
                        d.push(f(e, y, x, c));
                    }
                }
            }
        }
        (vec![k, h, w, 3], d)
    }

    #[test]
    fn a_bad_stack_is_refused_with_the_rule_it_breaks() {
        let (s, d) = stack(2, 4, 3, |_, _, _, _| 1.0 / 12.0);
        assert!(matches!(Stack::from_array(&s, &d, false).unwrap_err(), StackError::Sides(4, 3)));
        let (s, mut d) = stack(2, 3, 3, |_, _, _, _| 1.0 / 9.0);
        d[9 * 3 + 4 * 3 + 1] = f32::NAN;
        let e = Stack::from_array(&s, &d, false).unwrap_err().to_string();
        assert!(e.contains("entry 1, pixel (1, 1), channel G") && e.contains("non-negative"), "{e}");
        let (s, d) = stack(2, 3, 3, |e, _, _, c| if e == 1 && c == 2 { 0.1 } else { 1.0 / 9.0 });
        let err = Stack::from_array(&s, &d, false).unwrap_err().to_string();
        assert!(err.contains("entry 1, channel B: sums to 0.9000"), "{err}");
        let ok = Stack::from_array(&s, &d, true).unwrap();
        assert!((ok.psfs[1].channel_sum(2) - 1.0).abs() < 1e-6);
        assert!(matches!(Stack::from_array(&[2, 3, 3], &d[..18], false).unwrap_err(), StackError::Shape(_)));
    }

    #[test]
    fn entries_are_centred_in_a_square_and_blended_between_instants() {
        // Entry 0 a delta at the centre, entry 1 a delta one pixel right; 1 x 3 entries.
        let (s, d) = stack(2, 1, 3, |e, _, x, _| if x == 1 + e { 1.0 } else { 0.0 });
        let st = Stack::from_array(&s, &d, false).unwrap();
        assert_eq!(st.psfs[0].size, 3);
        assert_eq!(st.psfs[0].channels[0], vec![0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
        // Two instants, four sub-frames: times 1/8, 3/8, 5/8, 7/8 sit at u = -0.25, 0.25, 0.75, 1.25.
        let mid = st.at_instant(1, 4);
        assert_eq!(mid.channels[1][4], 0.75);
        assert_eq!(mid.channels[1][5], 0.25);
        assert_eq!(st.at_instant(0, 4), st.psfs[0]);
        assert_eq!(st.at_instant(1, 2), st.psfs[1]);
        assert_eq!(st.at_psi(4.0, [0.0, 8.0]).channels[2][5], 0.5);
    }
}
