//! Seeded, counter-based randomness. Every random choice in `pipeline` is a pure function of
//! the config's seed and where it is made (video, window, patch, pixel), never of thread order
//! or of how the work was split, so reruns and sharded runs give the same bytes.

/// SplitMix64 finaliser: a strong 64-bit mix.
pub fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Hash of a sequence of words.
pub fn hash(words: &[u64]) -> u64 {
    words.iter().fold(0x5851_F42D_4C95_7F2D, |h, &w| mix(h ^ mix(w)))
}

/// FNV-1a of a string, for mixing names (video file names) into seeds.
pub fn hash_str(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325, |h, b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

/// FNV-1a of bytes (a path's exact bytes, which need not be UTF-8).
pub fn hash_bytes(b: &[u8]) -> u64 {
    mix(b.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)))
}

/// Uniform in [0, 1) from 53 bits of a hash.
pub fn unit(h: u64) -> f64 {
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// A standard normal from a key (Box-Muller on two derived uniforms).
pub fn normal(key: u64) -> f64 {
    let u1 = unit(mix(key ^ 0x1234_5678_9ABC_DEF1)).max(1e-300);
    let u2 = unit(mix(key ^ 0x0FED_CBA9_8765_4321));
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
}

/// A sequential generator for choices that are naturally ordered (patch positions, motion).
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }
    /// The generator's whole state: `Rng::new(r.state())` continues where `r` is.
    pub fn state(&self) -> u64 {
        self.0
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        mix(self.0)
    }
    /// FNV-1a of bytes (a path's exact bytes, which need not be UTF-8).
    pub fn hash_bytes(b: &[u8]) -> u64 {
        mix(b.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)))
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        unit(self.next_u64())
    }
    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    /// Uniform integer in 0..n (n > 0).
    pub fn below(&mut self, n: usize) -> usize {
        ((self.uniform() * n as f64) as usize).min(n.saturating_sub(1))
    }
    pub fn normal(&mut self) -> f64 {
        normal(self.next_u64())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normals_have_zero_mean_and_unit_variance() {
        let n = 200_000;
        let v: Vec<f64> = (0..n).map(|i| normal(hash(&[42, i]))).collect();
        let mean = v.iter().sum::<f64>() / n as f64;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        assert!(mean.abs() < 0.01 && (var - 1.0).abs() < 0.01, "mean {mean} var {var}");
    }

    #[test]
    fn hashes_differ_by_position_and_seed() {
        assert_ne!(hash(&[1, 2]), hash(&[2, 1]));
        assert_ne!(hash(&[0, 5]), hash(&[1, 5]));
        assert_eq!(hash(&[3, 4]), hash(&[3, 4]));
    }
}
