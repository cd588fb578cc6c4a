//! Noise and quantisation as a camera applies them: re-encode linear light with the camera curve,
//! add AWGN (sigma on the 0-255 scale), clip and quantise to 8 bits. The noise of a pixel is a
//! function of (key, absolute x, y, channel), so it does not depend on whether patches were cut
//! before or after.

use crate::optics::transfer::Encoder;
use crate::rng::mix;

/// Standard normal quantiles at (i + 0.5) / 65536: a pixel's three noise values are three
/// 16-bit slices of one hash, looked up here (tails reach 4.3 sigma).
fn normal_table() -> &'static [f32] {
    static T: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    T.get_or_init(|| (0..65536).map(|i| inverse_normal_cdf((i as f64 + 0.5) / 65536.0) as f32).collect())
}

/// Acklam's rational approximation of the inverse normal CDF (relative error < 1.2e-9).
pub fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] =
        [-3.969683028665376e1, 2.209460984245205e2, -2.759285104469687e2, 1.383_577_518_672_69e2, -3.066479806614716e1, 2.506628277459239];
    const B: [f64; 5] = [-5.447609879822406e1, 1.615858368580409e2, -1.556989798598866e2, 6.680131188771972e1, -1.328068155288572e1];
    const C: [f64; 6] =
        [-7.784894002430293e-3, -3.223964580411365e-1, -2.400758277161838, -2.549732539343734, 4.374664141464968, 2.938163982698783];
    const D: [f64; 4] = [7.784695709041462e-3, 3.224671290700398e-1, 2.445134137142996, 3.754408661907416];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5]) / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// Encodes and quantises planar linear RGB to interleaved 8-bit, adding `sigma` (0-255 scale)
/// of noise keyed on absolute pixel positions (`x0`, `y0` is the image's top-left in the frame).
/// Bands of rows run on all cores (each row's values depend on that row alone, so the result is
/// the same for any thread count); a patch-sized image stays on the calling thread.
#[allow(clippy::too_many_arguments)]
pub fn quantise(p: &[Vec<f32>; 3], w: usize, h: usize, x0: usize, y0: usize, enc: &Encoder, sigma: f64, key: u64) -> Vec<u8> {
    let mut out = vec![0u8; w * h * 3];
    if out.is_empty() {
        return out;
    }
    let row = Row { p, w, x0, y0, enc, s: (sigma / 255.0) as f32, noisy: sigma > 0.0, key };
    let band = QUANTISE_BAND_ROWS * w * 3;
    if w * h < QUANTISE_PARALLEL_PIXELS {
        let mut v: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0f32; w]);
        out.chunks_mut(w * 3).enumerate().for_each(|(y, o)| row.quantise(y, &mut v, o));
    } else {
        use rayon::prelude::*;
        out.par_chunks_mut(band).enumerate().for_each_init(
            || -> [Vec<f32>; 3] { std::array::from_fn(|_| vec![0.0f32; w]) },
            |v, (b, chunk)| chunk.chunks_mut(w * 3).enumerate().for_each(|(i, o)| row.quantise(b * QUANTISE_BAND_ROWS + i, v, o)),
        );
    }
    out
}

/// Rows per parallel unit of [`quantise`].
const QUANTISE_BAND_ROWS: usize = 16;
/// Images smaller than this (pixels) are quantised on the calling thread: patches.
const QUANTISE_PARALLEL_PIXELS: usize = 1 << 16;

/// What [`quantise`] needs for one row.
struct Row<'a> {
    p: &'a [Vec<f32>; 3],
    w: usize,
    x0: usize,
    y0: usize,
    enc: &'a Encoder,
    /// Sigma on the 0-1 scale.
    s: f32,
    noisy: bool,
    key: u64,
}

impl Row<'_> {
    /// Row `y` into `o` (interleaved, `3 w`), with `v` as the three channels' scratch: 16
    /// pixels at a time where the CPU has AVX-512 with byte permutes, else one at a time. The
    /// same operations per value either way (no fused multiply-add), so the same bytes.
    fn quantise(&self, y: usize, v: &mut [Vec<f32>; 3], o: &mut [u8]) {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx512f")
            && std::is_x86_feature_detected!("avx512dq")
            && std::is_x86_feature_detected!("avx512bw")
            && std::is_x86_feature_detected!("avx512vbmi")
        {
            // SAFETY: the CPU has each feature the function enables.
            return unsafe { self.quantise_avx512(y, v, o) };
        }
        self.quantise_plain(y, v, o)
    }

    /// [`Row::quantise`] one value at a time.
    fn quantise_plain(&self, y: usize, v: &mut [Vec<f32>; 3], o: &mut [u8]) {
        // In passes: encode (table lookups), add noise (one hash per pixel), then clip and
        // round; the same operations per value as pixel by pixel.
        self.encode_from(y, v, 0);
        if self.noisy {
            self.add_noise_from(y, v, 0);
        }
        self.round_from(v, o, 0);
    }

    /// The key of row `y`'s pixel hashes.
    fn row_key(&self, y: usize) -> u64 {
        mix(self.key ^ ((y + self.y0) as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
    }

    /// Columns `from..w` of row `y`, encoded into `v`.
    fn encode_from(&self, y: usize, v: &mut [Vec<f32>; 3], from: usize) {
        let w = self.w;
        for (c, vc) in v.iter_mut().enumerate() {
            vc[from..w].iter_mut().zip(&self.p[c][y * w + from..(y + 1) * w]).for_each(|(o, &x)| *o = self.enc.encode(x));
        }
    }

    /// Each pixel's noise added to columns `from..w` of `v` (row `y`).
    fn add_noise_from(&self, y: usize, v: &mut [Vec<f32>; 3], from: usize) {
        let (table, row_key, s) = (normal_table(), self.row_key(y), self.s);
        let [r, g, b] = v;
        for x in from..self.w {
            let hsh = mix(row_key ^ (x + self.x0) as u64);
            r[x] += s * table[hsh as usize & 0xFFFF];
            g[x] += s * table[(hsh >> 16) as usize & 0xFFFF];
            b[x] += s * table[(hsh >> 32) as usize & 0xFFFF];
        }
    }

    /// Columns `from..w` of `v` clipped, scaled to 0-255, rounded and interleaved into `o`.
    fn round_from(&self, v: &[Vec<f32>; 3], o: &mut [u8], from: usize) {
        for (c, vc) in v.iter().enumerate() {
            for (x, &val) in vc.iter().enumerate().take(self.w).skip(from) {
                let q = val.clamp(0.0, 1.0) * 255.0 + 0.5;
                // SAFETY: q is finite (clamped, then scaled) and in [0.5, 255.5]: an exact
                // truncation, without the saturation checks of `as`.
                o[x * 3 + c] = unsafe { q.to_int_unchecked::<i32>() } as u8;
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
impl Row<'_> {
    /// [`Row::quantise_plain`] on vectors of 16 pixels (the encoding table and the noise table
    /// gathered, the pixel hash in 64-bit lanes, the three channels' bytes interleaved by one
    /// byte permute), the row's last `w % 16` pixels and the darkest values (the encoder's
    /// exact branch) one at a time.
    #[target_feature(enable = "avx512f,avx512dq,avx512bw,avx512vbmi")]
    unsafe fn quantise_avx512(&self, y: usize, v: &mut [Vec<f32>; 3], o: &mut [u8]) {
        use std::arch::x86_64::*;
        let (w, p) = (self.w, self.p);
        let whole = w / 16 * 16;
        let lut = self.enc.table();
        assert!(lut.len() == 65537 && o.len() >= 3 * w && v.iter().all(|vc| vc.len() >= w));
        let (zero, one) = (_mm512_setzero_ps(), _mm512_set1_ps(1.0));
        // Encode: clamp, scale, interpolate in the table; dark lanes again, exactly.
        for (c, vc) in v.iter_mut().enumerate() {
            let src = &p[c][y * w..(y + 1) * w];
            for i in (0..whole).step_by(16) {
                // SAFETY: i + 16 <= whole <= w, the length of src and of vc's used part.
                let x = _mm512_mul_ps(
                    _mm512_min_ps(_mm512_max_ps(unsafe { _mm512_loadu_ps(src.as_ptr().add(i)) }, zero), one),
                    _mm512_set1_ps(65536.0),
                );
                let dark = _mm512_cmp_ps_mask::<_CMP_LT_OQ>(x, _mm512_set1_ps(64.0));
                let at = _mm512_min_epi32(_mm512_cvttps_epi32(x), _mm512_set1_epi32(65535));
                let f = _mm512_sub_ps(x, _mm512_cvtepi32_ps(at));
                // SAFETY: every index is in 0..=65535 and the one after it in 1..=65536, inside
                // the 65,537 entries (asserted above).
                let (a, b) = unsafe {
                    (
                        _mm512_i32gather_ps::<4>(at, lut.as_ptr()),
                        _mm512_i32gather_ps::<4>(_mm512_add_epi32(at, _mm512_set1_epi32(1)), lut.as_ptr()),
                    )
                };
                let r = _mm512_add_ps(a, _mm512_mul_ps(f, _mm512_sub_ps(b, a)));
                // SAFETY: as for the load.
                unsafe { _mm512_storeu_ps(vc.as_mut_ptr().add(i), r) };
                let mut m = dark;
                while m != 0 {
                    let l = m.trailing_zeros() as usize;
                    vc[i + l] = self.enc.encode(src[i + l]);
                    m &= m - 1;
                }
            }
        }
        self.encode_from(y, v, whole);
        if self.noisy {
            let row_key = self.row_key(y);
            let table = normal_table();
            let s = _mm512_set1_ps(self.s);
            let mix8 = |z: __m512i| {
                let z = _mm512_add_epi64(z, _mm512_set1_epi64(0x9E37_79B9_7F4A_7C15u64 as i64));
                let z =
                    _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64::<30>(z)), _mm512_set1_epi64(0xBF58_476D_1CE4_E5B9u64 as i64));
                let z =
                    _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64::<27>(z)), _mm512_set1_epi64(0x94D0_49BB_1331_11EBu64 as i64));
                _mm512_xor_si512(z, _mm512_srli_epi64::<31>(z))
            };
            let lanes = _mm512_set_epi64(7, 6, 5, 4, 3, 2, 1, 0);
            let low16 = _mm512_set1_epi64(0xFFFF);
            for i in (0..whole).step_by(16) {
                let base = _mm512_add_epi64(_mm512_set1_epi64((i + self.x0) as i64), lanes);
                let h0 = mix8(_mm512_xor_si512(_mm512_set1_epi64(row_key as i64), base));
                let h1 = mix8(_mm512_xor_si512(_mm512_set1_epi64(row_key as i64), _mm512_add_epi64(base, _mm512_set1_epi64(8))));
                // 16 indices from bits [shift, shift + 16) of the 16 hashes.
                let slice = |h0: __m512i, h1: __m512i| {
                    let lo = _mm512_cvtepi64_epi32(_mm512_and_si512(h0, low16));
                    let hi = _mm512_cvtepi64_epi32(_mm512_and_si512(h1, low16));
                    _mm512_inserti64x4::<1>(_mm512_castsi256_si512(lo), hi)
                };
                let idx = [
                    slice(h0, h1),
                    slice(_mm512_srli_epi64::<16>(h0), _mm512_srli_epi64::<16>(h1)),
                    slice(_mm512_srli_epi64::<32>(h0), _mm512_srli_epi64::<32>(h1)),
                ];
                for (vc, idx) in v.iter_mut().zip(idx) {
                    // SAFETY: indices are below 65536, the table's length; i + 16 <= w.
                    unsafe {
                        let t = _mm512_i32gather_ps::<4>(idx, table.as_ptr());
                        let cur = _mm512_loadu_ps(vc.as_ptr().add(i));
                        _mm512_storeu_ps(vc.as_mut_ptr().add(i), _mm512_add_ps(cur, _mm512_mul_ps(s, t)));
                    }
                }
            }
            self.add_noise_from(y, v, whole);
        }
        // Clip, scale, round; the three channels' 16 bytes side by side in one vector, then
        // interleaved (r g b r g b ...) by one permute and stored as 48 bytes.
        // SAFETY: INTERLEAVE holds the 64 bytes read; AVX-512 is this function's contract.
        let interleave = unsafe { _mm512_loadu_si512(INTERLEAVE.as_ptr().cast()) };
        let (scale, half) = (_mm512_set1_ps(255.0), _mm512_set1_ps(0.5));
        for i in (0..whole).step_by(16) {
            let q: [__m128i; 3] = std::array::from_fn(|c| {
                // SAFETY: i + 16 <= w.
                let val = unsafe { _mm512_loadu_ps(v[c].as_ptr().add(i)) };
                let q = _mm512_add_ps(_mm512_mul_ps(_mm512_min_ps(_mm512_max_ps(val, zero), one), scale), half);
                _mm512_cvtepi32_epi8(_mm512_cvttps_epi32(q))
            });
            let rgb = _mm512_inserti32x4::<2>(_mm512_inserti32x4::<1>(_mm512_castsi128_si512(q[0]), q[1]), q[2]);
            // SAFETY: bytes 3 i .. 3 i + 48 of o, inside its 3 w.
            unsafe {
                _mm512_mask_storeu_epi8(o.as_mut_ptr().add(3 * i).cast(), (1u64 << 48) - 1, _mm512_permutexvar_epi8(interleave, rgb))
            };
        }
        self.round_from(v, o, whole);
    }
}

/// Byte `3 x + c` of 16 interleaved pixels is byte `16 c + x` of the three channels side by side.
#[cfg(target_arch = "x86_64")]
static INTERLEAVE: [u8; 64] = {
    let mut t = [0u8; 64];
    let mut k = 0;
    while k < 48 {
        t[k] = ((k % 3) * 16 + k / 3) as u8;
        k += 1;
    }
    t
};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optics::transfer::Curve;

    #[test]
    fn noise_has_the_asked_sigma_and_no_bias() {
        // A mid-grey image: encoded 0.5, so clipping never bites at sigma 9.
        let lin = Curve::Srgb.to_linear(0.5) as f32;
        let (w, h) = (256, 256);
        let p: [Vec<f32>; 3] = std::array::from_fn(|_| vec![lin; w * h]);
        let enc = Encoder::new(Curve::Srgb);
        for sigma in [0.0, 3.0, 9.0] {
            let q = quantise(&p, w, h, 0, 0, &enc, sigma, 11);
            let vals: Vec<f64> = q.iter().map(|&v| v as f64).collect();
            let mean = vals.iter().sum::<f64>() / vals.len() as f64;
            let sd = (vals.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / vals.len() as f64).sqrt();
            // Quantising adds 1/12 of a level of variance.
            let want = (sigma * sigma + 1.0 / 12.0 * f64::from(sigma > 0.0)).sqrt();
            assert!((mean - 127.5).abs() < 0.6, "sigma {sigma}: mean {mean}");
            assert!((sd - want).abs() < 0.05 * want.max(0.5), "sigma {sigma}: sd {sd}, want {want}");
        }
    }

    #[test]
    fn the_vector_rows_give_the_bytes_of_the_scalar_rows() {
        // Widths around the vector's 16, dark values (the encoder's exact branch), values outside
        // [0, 1], with and without noise, every curve, at an offset in the frame.
        let h = 3;
        for w in [1, 15, 16, 17, 40, 333] {
            let p: [Vec<f32>; 3] = std::array::from_fn(|c| {
                (0..w * h)
                    .map(|i| match (i * 7 + c) % 9 {
                        0 => 0.0,
                        1 => (i % 50) as f32 / 65536.0,
                        2 => -0.25,
                        3 => 1.5,
                        _ => ((i * 31 + c * 7) % 1013) as f32 / 1013.0,
                    })
                    .collect()
            });
            for curve in [Curve::Srgb, Curve::Gamma22, Curve::Identity] {
                let enc = Encoder::new(curve);
                for sigma in [0.0, 9.0] {
                    let row = Row { p: &p, w, x0: 5, y0: 11, enc: &enc, s: (sigma / 255.0) as f32, noisy: sigma > 0.0, key: 7 };
                    for y in 0..h {
                        let mut v: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0f32; w]);
                        let (mut fast, mut plain) = (vec![0u8; 3 * w], vec![1u8; 3 * w]);
                        row.quantise(y, &mut v, &mut fast);
                        row.quantise_plain(y, &mut v, &mut plain);
                        assert_eq!(fast, plain, "width {w}, {curve:?}, sigma {sigma}, row {y}");
                    }
                }
            }
        }
    }

    #[test]
    fn noise_depends_on_absolute_position_only() {
        // 320 x 240 is quantised in parallel bands, its crops on this thread: the same bytes.
        let (w, h) = (320, 240);
        assert!(w * h >= QUANTISE_PARALLEL_PIXELS);
        let p: [Vec<f32>; 3] = std::array::from_fn(|c| (0..w * h).map(|i| ((i * 7 + c) % 97) as f32 / 97.0).collect());
        let enc = Encoder::new(Curve::Srgb);
        let full = quantise(&p, w, h, 0, 0, &enc, 5.0, 3);
        assert!(quantise(&p, 0, 5, 0, 0, &enc, 5.0, 3).is_empty() && quantise(&p, 5, 0, 0, 0, &enc, 5.0, 3).is_empty());
        for (x, y, cw, ch) in [(11, 7, 16, 12), (200, 150, 120, 90), (0, 0, 40, 30)] {
            let crop = super::super::blur::crop(&p, w, x, y, cw, ch);
            let part = quantise(&crop, cw, ch, x, y, &enc, 5.0, 3);
            for yy in 0..ch {
                assert_eq!(
                    &part[yy * cw * 3..(yy + 1) * cw * 3],
                    &full[((y + yy) * w + x) * 3..((y + yy) * w + x + cw) * 3],
                    "crop at {x},{y}, row {yy}"
                );
            }
        }
    }

    #[test]
    fn inverse_cdf_matches_known_quantiles() {
        assert!((inverse_normal_cdf(0.975) - 1.959964).abs() < 1e-6);
        assert!((inverse_normal_cdf(0.5)).abs() < 1e-12);
        assert!((inverse_normal_cdf(0.001) + 3.090232).abs() < 1e-5);
    }
}
