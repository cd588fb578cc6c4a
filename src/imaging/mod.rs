//! Imaging as a library: what a camera does to a window of linear frames, shared by the
//! `coded_blur` and `noise` stages, `eval`, `figure`, `deblur` and the trainer.
//!
//! - [`blur`]: a window of sub-frames through a camera's PSFs (FFT, low-rank, patches or frames);
//! - [`noise`]: re-encode, AWGN, clip, quantise to 8 bits;
//! - here: the noise a camera adds for its light throughput, and 8-bit <-> linear conversions.

pub mod blur;
pub mod demosaic;
pub mod noise;
pub mod sensor;
pub mod truth;

use crate::optics::transfer::{Curve, Encoder};

/// The sigma (0-255 scale) that reaches an image taken through a camera passing
/// `light_throughput` of the light of a clear aperture: the same sensor noise on a dimmer image,
/// expressed after normalising the image back to full exposure.
pub fn sensor_sigma(sigma: f64, light_throughput: f64) -> f64 {
    sigma / light_throughput.max(1e-6)
}

/// The camera's read-out of a `w x h` image at (x0, y0) of the frame (linear light, normalised
/// to full exposure): re-encode, add sensor noise `sigma` (0-255 scale) as it shows through a
/// camera of `light_throughput`, clip, quantise. The noise is keyed on `key` and absolute pixel
/// positions.
#[allow(clippy::too_many_arguments)]
pub fn read_out(
    planes: &[Vec<f32>; 3],
    (x0, y0, w, h): (usize, usize, usize, usize),
    enc: &Encoder,
    sigma: f64,
    light_throughput: f64,
    key: u64,
) -> Vec<u8> {
    noise::quantise(planes, w, h, x0, y0, enc, sensor_sigma(sigma, light_throughput), key)
}

/// A window's 8-bit capture of the region (x, y, w, h): the sub-frames through the camera, then
/// [`read_out`].
///
/// # Panics
/// As [`blur::Blurrer::blur_region`].
#[allow(clippy::too_many_arguments)]
pub fn capture(
    b: &mut blur::Blurrer,
    frames: &[std::sync::Arc<crate::frame::Frame>],
    region: (usize, usize, usize, usize),
    enc: &Encoder,
    sigma: f64,
    key: u64,
) -> Vec<u8> {
    let (x, y, w, h) = region;
    let planes = b.blur_region(frames, x as isize, y as isize, w, h);
    read_out(&planes, region, enc, sigma, b.camera.light_throughput(), key)
}

/// Interleaved 8-bit RGB of planar linear light, encoded with `curve`, without noise.
pub fn to_8bit(planes: &[Vec<f32>; 3], w: usize, h: usize, curve: Curve) -> Vec<u8> {
    noise::quantise(planes, w, h, 0, 0, &Encoder::new(curve), 0.0, 0)
}

/// Planar linear light of interleaved 8-bit RGB encoded with `curve`.
pub fn from_8bit(rgb: &[u8], w: usize, h: usize, curve: Curve) -> [Vec<f32>; 3] {
    let t: Vec<f32> = (0..256).map(|v| curve.to_linear(v as f64 / 255.0) as f32).collect();
    std::array::from_fn(|c| (0..w * h).map(|i| t[rgb[i * 3 + c] as usize]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eight_bit_round_trip_is_exact_and_throughput_scales_sigma() {
        let rgb: Vec<u8> = (0..4 * 3 * 3).map(|i| (i * 7 % 256) as u8).collect();
        for curve in [Curve::Srgb, Curve::Identity] {
            assert_eq!(to_8bit(&from_8bit(&rgb, 4, 3, curve), 4, 3, curve), rgb);
        }
        assert_eq!(sensor_sigma(3.0, 0.5), 6.0);
        assert!(sensor_sigma(3.0, 0.0).is_finite(), "no division by zero");
    }
}
