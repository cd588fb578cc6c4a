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

/// A camera response of the `sensor` stage: linear light in [0, 1] to the encoded value.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Response {
    /// `"input"` (the input's own transfer curve: what the photographs were encoded with) or
    /// one of the curves: `"srgb"`, `"gamma22"`, `"identity"`.
    Named(ResponseName),
    /// `{ gamma = 2.4 }`: the encoded value is linear^(1 / gamma).
    Gamma { gamma: f64 },
    /// The encoded values at evenly spaced linear values from 0 to 1 (2 or more, in [0, 1],
    /// never decreasing), interpolated linearly: a measured response.
    Table(Vec<f64>),
}

/// The named responses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ResponseName {
    Input,
    Srgb,
    Gamma22,
    Identity,
}

impl Default for Response {
    fn default() -> Self {
        Response::Named(ResponseName::Input)
    }
}

impl Response {
    /// Why the response cannot be used, if it cannot.
    pub fn problem(&self) -> Option<String> {
        match self {
            Response::Gamma { gamma } if !(0.1..=10.0).contains(gamma) => Some(format!("gamma {gamma} is outside 0.1 to 10")),
            Response::Table(t) if t.len() < 2 => Some("a table needs 2 values or more (at linear 0 and 1)".into()),
            Response::Table(t) => match t.iter().position(|v| !(0.0..=1.0).contains(v)) {
                Some(i) => Some(format!("value {i} ({}) is outside 0 to 1", t[i])),
                None => t
                    .windows(2)
                    .position(|w| w[1] < w[0])
                    .map(|i| format!("value {} is below value {i}: a response never decreases", i + 1)),
            },
            _ => None,
        }
    }

    /// What `key.json` records: the curve's name (the input's for `input`), `gamma G` or
    /// `table of N`.
    pub fn describe(&self, input: Curve) -> String {
        match self.resolve(input) {
            Resolved::Curve(c) => c.name().to_string(),
            Resolved::Gamma(g) => format!("gamma {g}"),
            Resolved::Table(t) => format!("table of {}", t.len()),
        }
    }

    /// The response for frames of the curve `input`: a named one as its curve.
    fn resolve(&self, input: Curve) -> Resolved<'_> {
        match self {
            Response::Named(ResponseName::Input) => Resolved::Curve(input),
            Response::Named(ResponseName::Srgb) => Resolved::Curve(Curve::Srgb),
            Response::Named(ResponseName::Gamma22) => Resolved::Curve(Curve::Gamma22),
            Response::Named(ResponseName::Identity) => Resolved::Curve(Curve::Identity),
            Response::Gamma { gamma } => Resolved::Gamma(*gamma),
            Response::Table(t) => Resolved::Table(t),
        }
    }

    /// The encoder of this response for frames of the curve `input`.
    pub fn encoder(&self, input: Curve) -> Encoder {
        match self.resolve(input) {
            Resolved::Curve(c) => Encoder::new(c),
            Resolved::Gamma(gamma) => Encoder::from_fn(move |v| v.clamp(0.0, 1.0).powf(1.0 / gamma)),
            Resolved::Table(t) => {
                let t = t.to_vec();
                Encoder::from_fn(move |v| {
                    let x = v.clamp(0.0, 1.0) * (t.len() - 1) as f64;
                    let i = (x as usize).min(t.len() - 2);
                    t[i] + (x - i as f64) * (t[i + 1] - t[i])
                })
            }
        }
    }
}

/// A [`Response`] with `input` resolved.
enum Resolved<'a> {
    Curve(Curve),
    Gamma(f64),
    Table(&'a [f64]),
}

/// Fast `encode` through a table of 65536 intervals with linear interpolation (exact below
/// 1/1024; error below 2e-5 of full scale elsewhere, far under half an 8-bit step).
pub struct Encoder {
    /// The exact function, for the darkest values.
    exact: Box<dyn Fn(f64) -> f64 + Send + Sync>,
    lut: Vec<f32>,
}

impl Encoder {
    pub fn new(curve: Curve) -> Encoder {
        Encoder::from_fn(move |v| curve.encode(v))
    }

    /// The encoder of any response `f` (linear light in [0, 1] to the encoded value).
    pub fn from_fn(f: impl Fn(f64) -> f64 + Send + Sync + 'static) -> Encoder {
        let lut = (0..=65536u32).map(|i| f(i as f64 / 65536.0) as f32).collect();
        Encoder { exact: Box::new(f), lut }
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
            return (self.exact)(v as f64) as f32;
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

    #[test]
    fn responses_read_from_toml_encode_as_written_and_bad_ones_are_named() {
        let read = |v: &str| toml::from_str::<std::collections::BTreeMap<String, Response>>(&format!("r = {v}")).unwrap()["r"].clone();
        let gamma = read("{ gamma = 2.4 }");
        let e = gamma.encoder(Curve::Srgb);
        for v in [1e-7f32, 0.001, 0.2, 0.9] {
            assert!((e.encode(v) as f64 - (v as f64).powf(1.0 / 2.4)).abs() < 2e-5, "{v}");
        }
        // A table: 0.25 of the way is a quarter between its first two of four intervals' ends.
        let e = read("[0.0, 0.4, 0.8, 1.0]").encoder(Curve::Srgb);
        assert!((e.encode(0.5) - 0.6).abs() < 1e-5 && (e.encode(1.0) - 1.0).abs() < 1e-6);
        assert_eq!(read("\"input\"").describe(Curve::Gamma22), "gamma22");
        assert_eq!(read("\"srgb\"").describe(Curve::Identity), "srgb");
        assert!(read("\"input\"").problem().is_none() && gamma.problem().is_none());
        assert!(read("{ gamma = 0.0 }").problem().unwrap().contains("outside 0.1 to 10"));
        assert!(read("[0.5]").problem().unwrap().contains("2 values"));
        assert!(read("[0.0, 1.5]").problem().unwrap().contains("value 1 (1.5)"));
        assert!(read("[0.0, 0.6, 0.5, 1.0]").problem().unwrap().contains("value 2 is below value 1"));
    }
}
