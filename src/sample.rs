//! The sample format every sink writes and the Python dataset yields: a sample's key
//! (`{input}_{window}[_{patch}]`), its per-sample JSON, and the hash of the settings that decide
//! the samples' content (kept in the manifest to tell a finished input from one to redo).

use crate::frame::{Img, Pair, Sample};
use crate::optics::transfer::Curve;
use serde::Serialize;

/// A sample image as PNG: linear light quantised to 8 bits through `curve`, without noise.
pub fn png_bytes(img: &Img, w: usize, h: usize, curve: Curve) -> Vec<u8> {
    let mut buf = Vec::new();
    crate::io::png::write_rgb8(&mut buf, w, h, &crate::imaging::img_rgb8(img, w, h, curve)).expect("png into memory");
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
