//! Camera encoding curves: sRGB, a 2.2 power law or identity, and their exact inverses.
//! `linearize` maps encoded values to linear light; `encode` maps back.

use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum Curve {
    /// IEC 61966-2-1 sRGB.
    Srgb,
    /// Pure power law, gamma 2.2 (the GoPro dataset's `blur_gamma`).
    Gamma22,
    /// Values are already linear.
    Identity,
}

impl Curve {
    pub fn name(self) -> &'static str {
        match self {
            Curve::Srgb => "srgb",
            Curve::Gamma22 => "gamma22",
            Curve::Identity => "identity",
        }
    }

    /// Encoded value in [0, 1] to linear light.
    pub fn to_linear(self, v: f64) -> f64 {
        let v = v.clamp(0.0, 1.0);
        match self {
            Curve::Srgb if v <= 0.040_45 => v / 12.92,
            Curve::Srgb => ((v + 0.055) / 1.055).powf(2.4),
            Curve::Gamma22 => v.powf(2.2),
            Curve::Identity => v,
        }
    }

    /// Linear light to the encoded value in [0, 1] (clipped).
    pub fn encode(self, v: f64) -> f64 {
        let v = v.clamp(0.0, 1.0);
        match self {
            Curve::Srgb if v <= 0.003_130_8 => 12.92 * v,
            Curve::Srgb => 1.055 * v.powf(1.0 / 2.4) - 0.055,
            Curve::Gamma22 => v.powf(1.0 / 2.2),
            Curve::Identity => v,
        }
    }

    /// Table of `to_linear` for every 16-bit code value.
    pub fn decode_lut16(self) -> Vec<f32> {
        (0..=65535u32).map(|i| self.to_linear(i as f64 / 65535.0) as f32).collect()
    }
}

/// Fast `encode` through a table of 65536 intervals with linear interpolation (exact below
/// 1/1024; error below 2e-5 of full scale elsewhere, far under half an 8-bit step).
pub struct Encoder {
    curve: Curve,
    lut: Vec<f32>,
}

impl Encoder {
    pub fn new(curve: Curve) -> Encoder {
        Encoder { curve, lut: (0..=65536u32).map(|i| curve.encode(i as f64 / 65536.0) as f32).collect() }
    }

    /// The table [`Encoder::encode`] interpolates: `curve.encode(i / 65536)` for i in 0..=65536.
    pub fn table(&self) -> &[f32] {
        &self.lut
    }

    #[inline]
    pub fn encode(&self, v: f32) -> f32 {
        let x = v.clamp(0.0, 1.0) * 65536.0;
        if x < 64.0 {
            // The power law's slope is unbounded at 0: compute the darkest values exactly.
            return self.curve.encode(v as f64) as f32;
        }
        let i = (x as usize).min(65535);
        let f = x - i as f32;
        self.lut[i] + f * (self.lut[i + 1] - self.lut[i])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn curves_round_trip_and_fast_encoder_matches() {
        for c in [Curve::Srgb, Curve::Gamma22, Curve::Identity] {
            let e = Encoder::new(c);
            for i in 0..=255 {
                let v = i as f64 / 255.0;
                let lin = c.to_linear(v);
                assert!((c.encode(lin) - v).abs() < 1e-9, "{c:?} {i}");
                assert!((e.encode(lin as f32) as f64 - v).abs() < 2e-5, "{c:?} {i}: {}", e.encode(lin as f32));
                // 8-bit round trip is exact.
                assert_eq!((e.encode(lin as f32) * 255.0).round() as i32, i);
            }
        }
        // sRGB reference values (IEC 61966-2-1): 0.5 encoded is 0.21404 linear.
        assert!((Curve::Srgb.to_linear(0.5) - 0.214_041).abs() < 1e-6);
    }
}
