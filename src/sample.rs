//! A window's result ([`Sample`]: its pairs of blurred and sharp images) and the sample format
//! every sink writes and the Python dataset yields: a sample's key (`{input}_{window}[_{patch}]`),
//! its per-sample JSON, and the hash of the settings that decide the samples' content (kept in the
//! manifest to tell a finished input from one to redo).

use crate::frame::Input;
use crate::optics::transfer::Curve;
use crate::optics::CameraKind;
use serde::Serialize;
use std::sync::Arc;

/// An 8-bit or linear image of one sample: planar f32 linear, or interleaved 8-bit encoded.
#[derive(Debug, Clone)]
pub enum Img {
    Linear([Vec<f32>; 3]),
    Encoded8(Vec<u8>),
}

impl Img {
    /// Interleaved 8-bit encoded RGB (linear light quantised through `curve`, without noise).
    pub fn rgb8(&self, w: usize, h: usize, curve: Curve) -> Vec<u8> {
        match self {
            Img::Encoded8(v) => v.clone(),
            Img::Linear(p) => crate::imaging::to_8bit(p, w, h, curve),
        }
    }
}

/// An (lq, gt) pair cut from a window at (x, y), `w x h` pixels.
#[derive(Debug, Clone)]
pub struct Pair {
    /// Patch number within the window (None for a full frame).
    pub patch: Option<u32>,
    pub x: usize,
    pub y: usize,
    pub w: usize,
    pub h: usize,
    pub lq: Img,
    pub gt: Img,
    /// The sharp images at each of the sample's [`Sample::times`] (burst targets), in time
    /// order; empty when the window has one target, `gt`, the middle sub-frame.
    pub burst: Vec<Img>,
}

/// The coded-blur result of one window, with everything needed to reproduce it.
#[derive(Debug, Clone)]
pub struct Sample {
    pub input: Arc<Input>,
    pub window: u64,
    pub first_frame: u64,
    pub frames: usize,
    pub camera: CameraKind,
    pub psi: Vec<f64>,
    pub curve: Curve,
    /// Noise sigma on the 0-255 scale as applied (after the camera's light loss), None before noise.
    pub sigma: Option<f64>,
    /// Share of a conventional camera's light this camera collects (0.5 for the flutter code);
    /// the noise stage divides sigma by it, as brightening the image to the same level would.
    pub light_throughput: f64,
    pub frame_width: usize,
    pub frame_height: usize,
    /// True when the pairs were cut before blurring (patch mode).
    pub cropped: bool,
    /// The middle frame's motion label ([`crate::frame::Frame::motion`]).
    pub motion: Option<Arc<str>>,
    /// What the capture stage drew (the `sensor` stage's ISO and constants), as JSON.
    pub capture: Option<Arc<str>>,
    /// The times of the burst targets ([`Pair::burst`]) as fractions of the exposure, in (0, 1):
    /// `(k + 0.5) / K`; empty without a burst.
    pub times: Vec<f64>,
    pub pairs: Vec<Pair>,
}

/// A sample image as PNG: linear light quantised to 8 bits through `curve`, without noise.
pub fn png_bytes(img: &Img, w: usize, h: usize, curve: Curve) -> Vec<u8> {
    let mut buf = Vec::new();
    crate::io::png::write_rgb8(&mut buf, w, h, &img.rgb8(w, h, curve)).expect("png into memory");
    buf
}

/// The per-sample JSON.
#[derive(Serialize)]
struct SampleMeta<'a> {
    video: &'a str,
    /// The input's key (file stem and path hash), the same in every run that reads the file.
    input: &'a str,
    window: u64,
    frames: [u64; 2],
    camera: &'static str,
    psi: &'a [f64],
    curve: &'static str,
    sigma: Option<f64>,
    frame_size: [usize; 2],
    patch: Option<PatchMeta>,
    #[serde(skip_serializing_if = "Option::is_none")]
    motion: Option<serde_json::Value>,
    /// The `sensor` stage's draws and constants.
    #[serde(skip_serializing_if = "Option::is_none")]
    capture: Option<serde_json::Value>,
    /// Burst samples: the times of `gt.00.png`, `gt.01.png`, ... as fractions of the exposure.
    #[serde(skip_serializing_if = "<[f64]>::is_empty")]
    times: &'a [f64],
}

#[derive(Serialize)]
struct PatchMeta {
    index: u32,
    x: usize,
    y: usize,
    w: usize,
    h: usize,
}

pub fn sample_key(s: &Sample, p: &Pair) -> String {
    match p.patch {
        Some(i) => format!("{}_{:06}_{:03}", s.input.key, s.window, i),
        None => format!("{}_{:06}", s.input.key, s.window),
    }
}

pub fn meta_json(s: &Sample, p: &Pair) -> Vec<u8> {
    let m = SampleMeta {
        video: &s.input.path,
        input: &s.input.key,
        window: s.window,
        frames: [s.first_frame, s.first_frame + s.frames as u64 - 1],
        camera: s.camera.name(),
        psi: &s.psi,
        curve: s.curve.name(),
        sigma: s.sigma,
        frame_size: [s.frame_width, s.frame_height],
        patch: p.patch.map(|index| PatchMeta { index, x: p.x, y: p.y, w: p.w, h: p.h }),
        motion: s.motion.as_deref().and_then(|m| serde_json::from_str(m).ok()),
        capture: s.capture.as_deref().and_then(|m| serde_json::from_str(m).ok()),
        times: if p.burst.is_empty() { &[] } else { &s.times },
    };
    serde_json::to_vec(&m).expect("json")
}

/// Hash of what decides the samples' content: the seed, the sources' and transforms' settings,
/// minus input lists and thread counts (which change neither pixels nor keys).
pub fn content_hash(resolved: &toml::Table) -> String {
    fn strip(v: &toml::Value) -> toml::Value {
        match v {
            toml::Value::Table(t) => toml::Value::Table(
                t.iter()
                    .filter(|(k, _)| !matches!(k.as_str(), "paths" | "threads"))
                    .map(|(k, v)| match (k.as_str(), v.as_str()) {
                        // A measured camera's samples follow its stack's bytes, not its file name:
                        // a stack calibrated again under the same name redoes the inputs.
                        ("psf_path", Some(p)) => {
                            (k.clone(), std::fs::read(p).map_or(v.clone(), |b| crate::rng::hash_bytes(&b).to_string().into()))
                        }
                        _ => (k.clone(), strip(v)),
                    })
                    .collect(),
            ),
            v => v.clone(),
        }
    }
    let mut t = toml::Table::new();
    for k in ["seed", "sources", "transforms"] {
        if let Some(v) = resolved.get(k) {
            t.insert(k.into(), strip(v));
        }
    }
    format!("{:016x}", crate::rng::hash_bytes(toml::to_string(&t).unwrap_or_default().as_bytes()))
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_content_hash_follows_a_measured_stack_by_its_bytes_not_its_name() {
        let d = crate::io::paths::scratch_dir("hash");
        let table = |p: &std::path::Path| -> toml::Table {
            toml::from_str(&format!("seed = 1\n[transforms.blur.camera]\ntype = \"measured\"\npsf_path = {:?}\n", p.to_str().unwrap()))
                .unwrap()
        };
        let (a, b) = (d.join("a.npy"), d.join("b.npy"));
        std::fs::write(&a, b"one stack").unwrap();
        std::fs::write(&b, b"one stack").unwrap();
        let first = super::content_hash(&table(&a));
        assert_eq!(first, super::content_hash(&table(&b)), "the same bytes under another name");
        std::fs::write(&a, b"calibrated again").unwrap();
        assert_ne!(first, super::content_hash(&table(&a)), "new bytes under the same name");
        let _ = std::fs::remove_dir_all(&d);
    }
}
