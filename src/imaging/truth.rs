//! The true motion of a test clip, where it is known: `pipelines/test-clips.toml` renders clips
//! from photographs with the `stills` source, and its `frames` sink writes each frame's motion
//! (one JSON line per frame, `motion.jsonl`), which `scripts/training-data.sh` keeps beside the clip
//! as `{clip}.motion.jsonl`. For a window moved as a whole by translation (still, pan, shake) that
//! gives the window's true kernel per channel, and with it `pipeline eval`'s Wiener bound.

use crate::frame::{Frame, FrameData};
use crate::imaging::blur::Blurrer;
use crate::{Error, Result};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Each frame's motion label, by frame index.
#[derive(Debug, Clone, Default)]
pub struct MotionLog {
    frames: Vec<Option<Arc<serde_json::Value>>>,
}

/// Where the log of `video` is: `clip.mkv` -> `clip.motion.jsonl`.
pub fn log_path(video: &Path) -> PathBuf {
    video.with_extension("motion.jsonl")
}

impl MotionLog {
    /// The log beside `video`, if there is one.
    ///
    /// # Errors
    /// A log that exists but cannot be read or has a malformed line (named, with its line).
    pub fn read(video: &Path) -> Result<Option<MotionLog>> {
        let p = log_path(video);
        let text = match std::fs::read_to_string(&p) {
            Ok(t) => t,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(Error::Io { path: p, cause: e }),
        };
        let mut log = MotionLog::default();
        for (i, line) in text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty()) {
            let v: serde_json::Value = serde_json::from_str(line).map_err(|e| Error::Unloadable {
                path: p.clone(),
                why: format!("line {}", i + 1),
                source: Box::new(e),
            })?;
            let frame =
                v["window"].as_u64().ok_or_else(|| Error::File { path: p.clone(), why: format!("line {}: no `window` index", i + 1) })?
                    as usize;
            if frame >= 1 << 24 {
                return Err(Error::File { path: p.clone(), why: format!("line {}: frame {frame} is out of range", i + 1) });
            }
            if log.frames.len() <= frame {
                log.frames.resize(frame + 1, None);
            }
            log.frames[frame] = Some(Arc::new(v["motion"].clone()));
        }
        Ok(Some(log))
    }

    /// The motion kind of frame `f` (`shake`, `objects`, ...).
    pub fn kind(&self, f: u64) -> Option<&str> {
        self.frames.get(f as usize)?.as_ref()?["kind"].as_str()
    }

    /// The displacement of each frame of `first..first + n` relative to frame `centre`, when the
    /// whole window is one segment moved by translation alone (its label has `shift`); `None`
    /// otherwise (objects, rotation, zoom, or a window across two segments).
    pub fn shifts(&self, first: u64, n: usize, centre: u64) -> Option<Vec<(f64, f64)>> {
        let label = self.frames.get(first as usize)?.as_ref()?;
        let shift = label["shift"].as_array()?;
        let len = shift.len() as u64;
        // The same segment: every frame carries the same label, and the segment (frames aligned
        // to multiples of its length) holds the whole window.
        if len == 0 || first / len != (first + n as u64 - 1) / len {
            return None;
        }
        if (first..first + n as u64).any(|f| self.frames.get(f as usize).and_then(|l| l.as_deref()) != Some(label)) {
            return None;
        }
        let at = |f: u64| -> Option<(f64, f64)> {
            let p = shift.get((f % len) as usize)?.as_array()?;
            Some((p.first()?.as_f64()?, p.get(1)?.as_f64()?))
        };
        let c = at(centre)?;
        (first..first + n as u64).map(|f| at(f).map(|p| (p.0 - c.0, p.1 - c.1))).collect()
    }
}

/// The kernel per channel of a window whose frames are the sharp middle frame moved by `shifts`
/// (pixels), imaged by `blurrer`: the blurrer's own response to a point, so it is exactly the
/// blur eval applies. Returns the kernels (`side x side`, centred) and `side`.
pub fn window_kernel(blurrer: &mut Blurrer, shifts: &[(f64, f64)]) -> ([Vec<f32>; 3], usize) {
    let reach = shifts.iter().map(|s| s.0.abs().max(s.1.abs())).fold(0.0, f64::max).ceil() as usize;
    let half = blurrer.margin + reach + 2;
    let side = 2 * half + 1;
    let frames: Vec<Arc<Frame>> = shifts
        .iter()
        .map(|&(dx, dy)| {
            // A frame that shows the scene moved by (dx, dy) shows a point at the centre there;
            // between pixels it is split bilinearly, as the stills renderer samples.
            let (x, y) = (half as f64 + dx, half as f64 + dy);
            let (x0, y0) = (x.floor(), y.floor());
            let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
            let mut p = vec![0.0f32; side * side];
            for (xx, yy, wgt) in [
                (x0, y0, (1.0 - fx) * (1.0 - fy)),
                (x0 + 1.0, y0, fx * (1.0 - fy)),
                (x0, y0 + 1.0, (1.0 - fx) * fy),
                (x0 + 1.0, y0 + 1.0, fx * fy),
            ] {
                p[yy as usize * side + xx as usize] += wgt;
            }
            let mut f = Frame::new(side, side, FrameData::Planar([p.clone(), p.clone(), p]));
            f.curve = Some(crate::optics::transfer::Curve::Identity);
            Arc::new(f)
        })
        .collect();
    (blurrer.blur_region(&frames, 0, 0, side, side), side)
}

/// The noise variance in linear light of an encoded 8-bit read-out with sensor noise
/// `sigma_255` (0-255 scale), per channel: the noise and the quantisation step through the slope
/// of the decoding curve, averaged over the image `lin` (linear light).
pub fn linear_noise_var(lin: &[Vec<f32>; 3], curve: crate::optics::transfer::Curve, sigma_255: f64) -> [f64; 3] {
    let var_enc = (sigma_255 / 255.0).powi(2) + (1.0 / 255.0f64).powi(2) / 12.0;
    std::array::from_fn(|c| {
        let n = lin[c].len().max(1) as f64;
        lin[c]
            .iter()
            .map(|&v| {
                let e = curve.encode(v as f64);
                let h = 1e-3;
                let slope =
                    (curve.to_linear((e + h).min(1.0)) - curve.to_linear((e - h).max(0.0))) / (((e + h).min(1.0)) - ((e - h).max(0.0)));
                slope * slope * var_enc
            })
            .sum::<f64>()
            / n
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_log_gives_the_shifts_of_a_window_inside_one_segment_only() {
        let dir = crate::io::paths::scratch_dir("truth");
        let video = dir.join("clip.mkv");
        let seg = |k: usize| -> String {
            let shift: Vec<[f64; 2]> = (0..5).map(|j| [(j as f64 - 2.0) * (k + 1) as f64, 0.5 * j as f64]).collect();
            serde_json::json!({ "kind": "pan", "extent_px": 4.0, "shift": shift }).to_string()
        };
        let lines: String = (0..10).map(|f| format!("{{\"window\":{f},\"first_frame\":{f},\"motion\":{}}}\n", seg(f / 5))).collect();
        std::fs::write(log_path(&video), lines).unwrap();
        let log = MotionLog::read(&video).unwrap().unwrap();
        assert_eq!(log.kind(7), Some("pan"));
        // Frames 5..10 are the second segment, moving 2 px per frame; centred on frame 7.
        assert_eq!(log.shifts(5, 5, 7).unwrap(), vec![(-4.0, -1.0), (-2.0, -0.5), (0.0, 0.0), (2.0, 0.5), (4.0, 1.0)]);
        assert_eq!(log.shifts(6, 3, 7).unwrap().len(), 3);
        assert!(log.shifts(3, 5, 5).is_none(), "a window across two segments has no single motion");
        assert!(MotionLog::read(&dir.join("none.mkv")).unwrap().is_none());
        std::fs::write(log_path(&video), "{not json\n").unwrap();
        assert!(MotionLog::read(&video).unwrap_err().to_string().contains("clip.motion.jsonl: line 1"));
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn the_window_kernel_is_the_blur_eval_applies_to_a_moving_frame() {
        use crate::optics::{Camera, CameraConfig, OpticsConfig};
        let camera = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::default()));
        let mut b = Blurrer::new(camera, 5, 1, 0.0).unwrap();
        let (w, h) = (96, 80);
        let tex = crate::render::texture::procedural_texture(w, h, 7);
        let lin: [Vec<f32>; 3] = std::array::from_fn(|c| tex[c].iter().map(|v| v * v).collect());
        // Frames moved by whole pixels (so shifting needs no interpolation): 2 px right per frame.
        let shifts: Vec<(f64, f64)> = (0..5).map(|j| (2.0 * (j as f64 - 2.0), -(j as f64 - 2.0))).collect();
        let frames: Vec<Arc<Frame>> = shifts
            .iter()
            .map(|&(dx, dy)| {
                let planes = std::array::from_fn(|c| {
                    (0..w * h)
                        .map(|i| {
                            let (x, y) = ((i % w) as isize - dx as isize, (i / w) as isize - dy as isize);
                            lin[c][crate::optics::fft::reflect(y, h) * w + crate::optics::fft::reflect(x, w)]
                        })
                        .collect()
                });
                let mut f = Frame::new(w, h, FrameData::Planar(planes));
                f.curve = Some(crate::optics::transfer::Curve::Identity);
                Arc::new(f)
            })
            .collect();
        let blurred = b.blur_region(&frames, 0, 0, w, h);
        let (k, side) = window_kernel(&mut b, &shifts);
        for c in 0..3 {
            assert!((k[c].iter().sum::<f32>() - 1.0).abs() < 1e-3, "channel {c}: kernel sums to {}", k[c].iter().sum::<f32>());
            let direct = crate::optics::fft::convolve_direct(&lin[c], h, w, &k[c]);
            // Away from the borders (the frames mirror where a convolution of the middle frame does not).
            let m = side / 2 + 1;
            let worst = (m..h - m)
                .flat_map(|y| (m..w - m).map(move |x| (x, y)))
                .map(|(x, y)| (direct[y * w + x] - blurred[c][y * w + x]).abs())
                .fold(0.0f32, f32::max);
            assert!(worst < 2e-4, "channel {c}: the kernel's blur differs from the window's by up to {worst}");
        }
    }
}
