//! A sensor's read-out in linear raw, before the camera response: photon shot noise (Poisson in
//! electrons), read noise (Gaussian), saturation at the full well, and a Bayer colour filter
//! array with demosaicing. Every random draw is a function of a key and the pixel's position in
//! the frame, so a patch gets the noise the whole frame would have there.
//!
//! Units: a linear value `v` in [0, 1] is `v * full_well / gain` electrons (`gain` = ISO / base
//! ISO: at a higher ISO the same output level is made of fewer electrons, so shot noise grows).
//! The read-out is `min(electrons + read noise, full_well) * gain / full_well`, clipped to [0, 1].

pub use super::demosaic::{demosaic_bilinear, demosaic_malvar, Bayer, Demosaic};
use crate::rng::{hash, normal, unit};

/// The sensor's constants.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sensor {
    /// Electrons a pixel holds before it saturates.
    pub full_well: f64,
    /// Read noise, electrons RMS.
    pub read_noise: f64,
    /// ISO / base ISO (1 at base ISO).
    pub gain: f64,
    /// How a mosaic's missing colours are filled in.
    pub demosaic: Demosaic,
}

/// A Poisson draw of mean `lambda` from the key: exact (inversion of the CDF) below 64, the
/// normal approximation with continuity correction above (its relative error in the variance
/// is below 1% there).
pub fn poisson(lambda: f64, key: u64) -> f64 {
    if lambda <= 0.0 {
        return 0.0;
    }
    if lambda >= 64.0 {
        return (lambda + lambda.sqrt() * normal(key) + 0.5).floor().max(0.0);
    }
    let u = unit(key);
    let (mut k, mut p) = (0.0, (-lambda).exp());
    let mut cdf = p;
    while u > cdf && k < 1000.0 {
        k += 1.0;
        p *= lambda / k;
        cdf += p;
    }
    k
}

impl Sensor {
    /// The read-out of linear value `v` at a site whose noise comes from `key`.
    pub fn read(&self, v: f32, key: u64) -> f32 {
        let scale = self.full_well / self.gain;
        let electrons = poisson(f64::from(v.max(0.0)) * scale, hash(&[key, 0])) + self.read_noise * normal(hash(&[key, 1]));
        (electrons.min(self.full_well) / scale).clamp(0.0, 1.0) as f32
    }

    /// The read-out of a `w x h` patch at (x0, y0) of its frame: every channel of every pixel,
    /// or with `cfa` the one colour of each site, then demosaiced ([`Sensor::demosaic`]).
    pub fn capture(&self, p: &[Vec<f32>; 3], w: usize, h: usize, (x0, y0): (usize, usize), cfa: Option<Bayer>, key: u64) -> [Vec<f32>; 3] {
        let site = |x: usize, y: usize, c: usize| hash(&[key, (y0 + y) as u64, (x0 + x) as u64, c as u64]);
        match cfa {
            None => std::array::from_fn(|c| (0..w * h).map(|i| self.read(p[c][i], site(i % w, i / w, c))).collect()),
            Some(b) => {
                let raw: Vec<f32> = (0..w * h)
                    .map(|i| {
                        let (x, y) = (i % w, i / w);
                        let c = b.colour(x0 + x, y0 + y);
                        self.read(p[c][i], site(x, y, c))
                    })
                    .collect();
                match self.demosaic {
                    Demosaic::Bilinear => demosaic_bilinear(&raw, w, h, (x0, y0), b),
                    Demosaic::Malvar => demosaic_malvar(&raw, w, h, (x0, y0), b),
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mean_var(v: &[f64]) -> (f64, f64) {
        let m = v.iter().sum::<f64>() / v.len() as f64;
        (m, v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / (v.len() - 1) as f64)
    }

    #[test]
    fn a_flat_field_has_the_poisson_gaussian_variance() {
        // Variance of the read-out (in [0, 1] units) = (v * scale + read^2) / scale^2.
        for (full_well, read, gain, v) in
            [(1000.0, 5.0, 1.0, 0.3f32), (20000.0, 3.0, 8.0, 0.1), (50.0, 0.0, 1.0, 0.5), (4000.0, 2.0, 4.0, 0.02)]
        {
            let s = Sensor { full_well, read_noise: read, gain, demosaic: Demosaic::Bilinear };
            let scale = full_well / gain;
            let draws: Vec<f64> = (0..40_000u64).map(|i| f64::from(s.read(v, hash(&[7, i])))).collect();
            let (m, var) = mean_var(&draws);
            let want = (f64::from(v) * scale + read * read) / (scale * scale);
            assert!((m - f64::from(v)).abs() < 4.0 * (want / draws.len() as f64).sqrt() + 1e-4, "mean {m} for {v}");
            assert!((var / want - 1.0).abs() < 0.05, "variance {var}, formula {want} ({full_well}, {read}, {gain}, {v})");
        }
    }

    #[test]
    fn exact_poisson_below_the_switch_has_its_mean_and_variance() {
        for lambda in [0.5, 3.0, 20.0, 63.0, 64.0, 200.0] {
            let draws: Vec<f64> = (0..40_000u64).map(|i| poisson(lambda, hash(&[3, i]))).collect();
            let (m, var) = mean_var(&draws);
            assert!((m / lambda - 1.0).abs() < 0.03 && (var / lambda - 1.0).abs() < 0.05, "lambda {lambda}: {m} {var}");
        }
    }

    #[test]
    fn saturation_clips_at_the_full_well() {
        let s = Sensor { full_well: 1000.0, read_noise: 2.0, gain: 2.0, demosaic: Demosaic::Bilinear };
        // Light beyond the full well (v * 500 electrons > 1000 for v > 2: a highlight) reads 1.
        assert_eq!(s.read(3.0, 1), 1.0);
        assert_eq!(s.read(10.0, 2), 1.0);
        assert!(s.read(0.5, 3) < 1.0);
        let s = Sensor { full_well: 100.0, read_noise: 0.0, gain: 1.0, demosaic: Demosaic::Bilinear };
        assert_eq!(s.read(1.0, 4).max(s.read(1.0, 5)), 1.0);
    }

    #[test]
    fn demosaicing_a_flat_colour_is_exact_for_every_pattern_and_phase() {
        let (w, h) = (7, 6);
        let col = [0.8f32, 0.3, 0.1];
        for b in [Bayer::Rggb, Bayer::Bggr, Bayer::Grbg, Bayer::Gbrg] {
            for off in [(0, 0), (1, 0), (0, 1), (3, 5)] {
                let raw: Vec<f32> = (0..w * h).map(|i| col[b.colour(off.0 + i % w, off.1 + i / w)]).collect();
                let out = demosaic_bilinear(&raw, w, h, off, b);
                for c in 0..3 {
                    assert!(out[c].iter().all(|&v| (v - col[c]).abs() < 1e-6), "{b:?} {off:?} channel {c}");
                }
            }
        }
    }

    #[test]
    fn bilinear_matches_a_hand_computed_case() {
        // RGGB, 4x4, raw values 1..16 in reading order. At (1, 1) (a blue site): red is the mean
        // of the 4 diagonal reds (0,0), (2,0), (0,2), (2,2) = (1 + 3 + 9 + 11) / 4; green the mean
        // of the 4 edge greens (1,0), (0,1), (2,1), (1,2) = (2 + 5 + 7 + 10) / 4.
        let raw: Vec<f32> = (1..=16).map(|v| v as f32).collect();
        let out = demosaic_bilinear(&raw, 4, 4, (0, 0), Bayer::Rggb);
        let i = 4 + 1;
        assert_eq!(out[2][i], 6.0);
        assert_eq!(out[0][i], 6.0);
        assert_eq!(out[1][i], 6.0);
        // At (1, 0) (green, red row): red = mean of (0,0), (2,0) = 2; blue = mean of (1,1) and
        // the mirrored (1,-1) = (1,1): 6.
        assert_eq!(out[0][1], 2.0);
        assert_eq!(out[2][1], 6.0);
        assert_eq!(out[1][1], 2.0);
    }

    #[test]
    fn a_patch_gets_the_noise_of_its_place_in_the_frame() {
        let s = Sensor { full_well: 5000.0, read_noise: 3.0, gain: 2.0, demosaic: Demosaic::Bilinear };
        let (w, h) = (12, 10);
        let frame: [Vec<f32>; 3] = std::array::from_fn(|c| (0..w * h).map(|i| ((i * 7 + c * 3) % 11) as f32 / 11.0).collect());
        let whole = s.capture(&frame, w, h, (0, 0), None, 99);
        let patch: [Vec<f32>; 3] = std::array::from_fn(|c| (0..16).map(|i| frame[c][(3 + i / 4) * w + 5 + i % 4]).collect());
        let part = s.capture(&patch, 4, 4, (5, 3), None, 99);
        for c in 0..3 {
            for i in 0..16 {
                assert_eq!(part[c][i], whole[c][(3 + i / 4) * w + 5 + i % 4]);
            }
        }
        assert_eq!(s.capture(&frame, w, h, (0, 0), Some(Bayer::Grbg), 5), s.capture(&frame, w, h, (0, 0), Some(Bayer::Grbg), 5));
        assert_ne!(s.capture(&frame, w, h, (0, 0), None, 5), s.capture(&frame, w, h, (0, 0), None, 6));
    }
}
