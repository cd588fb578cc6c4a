//! PSNR and SSIM with the conventions deblurring papers report (BasicSR `psnr_ssim.py`,
//! DeepDeblur `metric.py`):
//!
//! - inputs are 8-bit encoded images (sRGB as written), compared as f64 in [0, 255];
//! - PSNR = 10 log10(255^2 / MSE) over all pixels and channels; identical images give infinity;
//! - SSIM: 11 x 11 Gaussian window (sigma 1.5), K1 = 0.01, K2 = 0.03, data range 255, computed on
//!   the valid region (5 pixels from each border dropped), averaged over the channels;
//! - the `_y` variants use BT.601 luma, Y = 16 + (65.481 R + 128.553 G + 24.966 B) / 255 on
//!   0-255 values (BasicSR's `rgb2ycbcr(y_only=True)`).
//!
//! No border is cropped before the metrics (crop_border = 0). [`CONVENTION`] says all this in
//! one line for reports.

/// The convention, for `report.json`.
pub const CONVENTION: &str = "8-bit sRGB, data range 255, crop_border 0; SSIM 11x11 Gaussian sigma 1.5, K1 0.01, K2 0.03, valid region, channel mean; Y = BT.601 luma (BasicSR rgb2ycbcr)";

/// PSNR / SSIM on RGB and on Y.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Quality {
    pub psnr_rgb: f64,
    pub ssim_rgb: f64,
    pub psnr_y: f64,
    pub ssim_y: f64,
}

/// BT.601 luma of interleaved 8-bit RGB, on the 16-235 scale.
pub fn luma(rgb: &[u8]) -> Vec<f64> {
    rgb.chunks_exact(3).map(|p| 16.0 + (65.481 * p[0] as f64 + 128.553 * p[1] as f64 + 24.966 * p[2] as f64) / 255.0).collect()
}

/// PSNR of two planes of values on the 0-255 scale.
pub fn psnr(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let mse = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len().max(1) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * (255.0 * 255.0 / mse).log10()
    }
}

fn gaussian_window() -> [f64; 11] {
    let mut g = [0.0; 11];
    for (i, v) in g.iter_mut().enumerate() {
        let x = i as f64 - 5.0;
        *v = (-x * x / (2.0 * 1.5 * 1.5)).exp();
    }
    let s: f64 = g.iter().sum();
    g.map(|v| v / s)
}

/// Separable valid filtering with the 11-tap Gaussian: (w - 10) x (h - 10).
fn filter_valid(p: &[f64], w: usize, h: usize) -> Vec<f64> {
    let g = gaussian_window();
    let (ow, oh) = (w - 10, h - 10);
    let mut tmp = vec![0.0; ow * h];
    for y in 0..h {
        for x in 0..ow {
            tmp[y * ow + x] = (0..11).map(|i| g[i] * p[y * w + x + i]).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = (0..11).map(|i| g[i] * tmp[(y + i) * ow + x]).sum();
        }
    }
    out
}

/// SSIM of one plane (0-255 scale), `w x h`, at least 11 x 11.
pub fn ssim(a: &[f64], b: &[f64], w: usize, h: usize) -> f64 {
    assert!(w >= 11 && h >= 11, "SSIM needs at least 11x11 pixels, got {w}x{h}");
    let (c1, c2) = ((0.01f64 * 255.0).powi(2), (0.03f64 * 255.0).powi(2));
    let prod = |x: &[f64], y: &[f64]| x.iter().zip(y).map(|(p, q)| p * q).collect::<Vec<f64>>();
    let (mu_a, mu_b) = (filter_valid(a, w, h), filter_valid(b, w, h));
    let (saa, sbb, sab) = (filter_valid(&prod(a, a), w, h), filter_valid(&prod(b, b), w, h), filter_valid(&prod(a, b), w, h));
    let n = mu_a.len();
    let mut total = 0.0;
    for i in 0..n {
        let (ma, mb) = (mu_a[i], mu_b[i]);
        let (va, vb, cov) = (saa[i] - ma * ma, sbb[i] - mb * mb, sab[i] - ma * mb);
        total += ((2.0 * ma * mb + c1) * (2.0 * cov + c2)) / ((ma * ma + mb * mb + c1) * (va + vb + c2));
    }
    total / n as f64
}

/// All four numbers for two interleaved 8-bit RGB images of `w x h`.
///
/// # Panics
/// If the images differ in size or are smaller than 11 x 11.
pub fn quality(a: &[u8], b: &[u8], w: usize, h: usize) -> Quality {
    assert_eq!(a.len(), b.len());
    assert_eq!(a.len(), w * h * 3);
    let chan = |img: &[u8], c: usize| img.iter().skip(c).step_by(3).map(|&v| v as f64).collect::<Vec<f64>>();
    let all = |img: &[u8]| img.iter().map(|&v| v as f64).collect::<Vec<f64>>();
    let ssim_rgb = (0..3).map(|c| ssim(&chan(a, c), &chan(b, c), w, h)).sum::<f64>() / 3.0;
    let (ya, yb) = (luma(a), luma(b));
    Quality { psnr_rgb: psnr(&all(a), &all(b)), ssim_rgb, psnr_y: psnr(&ya, &yb), ssim_y: ssim(&ya, &yb, w, h) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_of_a_one_level_error_is_48_13_db() {
        let a = vec![100.0; 64];
        let b = vec![101.0; 64];
        // 10 log10(255^2 / 1) = 48.1308
        assert!((psnr(&a, &b) - 48.1308).abs() < 1e-4);
        assert!(psnr(&a, &a).is_infinite());
    }

    #[test]
    fn ssim_of_constant_images_is_the_luminance_term() {
        // Both variances and the covariance are 0, so SSIM = (2ab + C1) / (a^2 + b^2 + C1).
        let (w, h) = (20, 16);
        let (a, b) = (vec![80.0; w * h], vec![120.0; w * h]);
        let c1 = (0.01f64 * 255.0).powi(2);
        let want = (2.0 * 80.0 * 120.0 + c1) / (80.0f64.powi(2) + 120.0f64.powi(2) + c1);
        assert!((ssim(&a, &b, w, h) - want).abs() < 1e-12);
        assert!((ssim(&a, &a, w, h) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn ssim_falls_with_noise_and_luma_matches_bt601() {
        let (w, h) = (32, 32);
        let img: Vec<u8> = (0..w * h * 3).map(|i| ((i * 37) % 251) as u8).collect();
        let noisy = |amp: u64| -> Vec<u8> {
            img.iter().enumerate().map(|(i, &v)| v.saturating_add((crate::rng::hash(&[i as u64]) % amp) as u8)).collect()
        };
        let (q5, q40) = (quality(&img, &noisy(5), w, h), quality(&img, &noisy(40), w, h));
        assert!(q40.ssim_rgb < q5.ssim_rgb && q5.ssim_rgb < 1.0, "{q5:?} {q40:?}");
        assert!(q40.psnr_rgb < q5.psnr_rgb && q40.ssim_y < q5.ssim_y, "{q5:?} {q40:?}");
        // White is Y 235, black Y 16.
        assert!((luma(&[255, 255, 255])[0] - 235.0).abs() < 1e-9 && (luma(&[0, 0, 0])[0] - 16.0).abs() < 1e-12);
    }

    #[test]
    fn ssim_and_psnr_of_a_textured_pair_match_scikit_image() {
        // The fixture's cat fur against itself plus a fixed pattern of -30 to +30 levels, clipped.
        // Reference values from scikit-image 0.26 (structural_similarity with gaussian_weights,
        // sigma 1.5, use_sample_covariance=False, data_range 255, per channel then the mean;
        // peak_signal_noise_ratio), computed once:
        //   a = PIL RGB of fixtures/chelsea-160x128.png as int64; i = arange(a.size).reshape(a.shape)
        //   b = clip(a + (i * 7919) % 61 - 30, 0, 255); Y = 16 + (65.481 R + 128.553 G + 24.966 B) / 255
        let png = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/chelsea-160x128.png")).unwrap();
        let (w, h, a) = crate::io::png::read_rgb8(&png).unwrap();
        let b: Vec<u8> = a.iter().enumerate().map(|(i, &v)| (v as i64 + (i as i64 * 7919) % 61 - 30).clamp(0, 255) as u8).collect();
        let q = quality(&a, &b, w, h);
        assert!((q.ssim_rgb - 0.5175354863199558).abs() < 1e-9, "{q:?}");
        assert!((q.psnr_rgb - 23.29367820419392).abs() < 1e-9, "{q:?}");
        assert!((q.ssim_y - 0.6902786998549327).abs() < 1e-9, "{q:?}");
        assert!((q.psnr_y - 27.81677881444374).abs() < 1e-9, "{q:?}");
    }
}
