//! Sources: `decode` (FFmpeg) and `stills` (clips rendered from photographs or procedural
//! textures with seeded motion).

use super::{Counters, Emit, Source};
use crate::config::StillsConfig;
use crate::frame::{Frame, FrameData, Input, InputInfo, Item};
use crate::rng::{hash, hash_str, Rng};
use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;

/// A WebDataset-safe key for an input: its file stem with anything but letters, digits, '-'
/// and '_' replaced, plus 12 hex digits of `id`, the hash of its identity (the canonical path's
/// bytes, or a procedural clip's number and seed). Shard names and sample keys derive from it, so runs
/// with other inputs, tasks of an array job and equal stems in other folders never collide,
/// while a rerun of the same input finds its own shards.
pub fn input_key(stem_of: &str, id: u64) -> String {
    let stem = std::path::Path::new(stem_of).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let clean: String = stem.chars().take(40).map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' }).collect();
    format!("{clean}_{:012x}", id >> 16)
}

/// Minimum frames and frame size the stages downstream need, checked by the source.
#[derive(Debug, Clone, Copy, Default)]
pub struct Needs {
    pub frames: u64,
    pub width: usize,
    pub height: usize,
}

fn check_size(info: &InputInfo, needs: &Needs) -> Result<(), String> {
    if info.width < needs.width || info.height < needs.height {
        return Err(format!("frames are {}x{}, smaller than a {}x{} patch", info.width, info.height, needs.width, needs.height));
    }
    if let Some(n) = info.frames_announced {
        if n < needs.frames {
            return Err(format!("{n} frames, shorter than one window of {}", needs.frames));
        }
    }
    Ok(())
}

#[cfg(feature = "ffmpeg")]
pub struct Decode {
    pub inputs: Vec<(Arc<Input>, PathBuf)>,
    pub max_frames: u64,
    pub needs: Needs,
    pub counters: Arc<Counters>,
}

#[cfg(feature = "ffmpeg")]
impl Source for Decode {
    fn run(&mut self, out: &mut Emit) -> crate::Result<()> {
        use crate::io::video::VideoReader;
        for (input, path) in &self.inputs {
            let fail = |msg: String| Item::End(input.clone(), Err(format!("{}: {msg}", path.display())));
            let mut reader = match VideoReader::open(path) {
                Ok(r) => r,
                Err(e) => {
                    if !out.send(fail(e)) {
                        return Ok(());
                    }
                    continue;
                }
            };
            if let Err(e) = check_size(&reader.info, &self.needs) {
                if !out.send(fail(e)) {
                    return Ok(());
                }
                continue;
            }
            if !out.send(Item::Begin(input.clone(), reader.info.clone())) {
                return Ok(());
            }
            let mut n = 0u64;
            let end = loop {
                if out.stop.load(Ordering::Relaxed) {
                    return Ok(());
                }
                if self.max_frames > 0 && n >= self.max_frames {
                    break Ok(());
                }
                match reader.next_frame() {
                    Ok(Some(f)) => {
                        Counters::add(&self.counters.frames, 1);
                        if !out.send(Item::Frame(input.clone(), n, Arc::new(f))) {
                            return Ok(());
                        }
                        n += 1;
                    }
                    Ok(None) => match reader.info.frames_announced {
                        Some(a) if n < a => break Err(format!("truncated: decoded {n} of the {a} frames the container announces")),
                        _ => break Ok(()),
                    },
                    Err(e) => break Err(e),
                }
            };
            self.counters.input(&input.path, &reader.info, n);
            let end = end.map_err(|e| format!("{}: {e}", path.display()));
            if !out.send(Item::End(input.clone(), end)) {
                return Ok(());
            }
        }
        Ok(())
    }
}

/// Bilinear sample of a planar image with mirrored borders.
fn sample(img: &[f32], w: usize, h: usize, x: f64, y: f64) -> f32 {
    use crate::optics::fft::reflect;
    let (fx, fy) = (x.floor(), y.floor());
    let (ax, ay) = ((x - fx) as f32, (y - fy) as f32);
    let (x0, y0) = (fx as isize, fy as isize);
    let at = |xx: isize, yy: isize| img[reflect(yy, h) * w + reflect(xx, w)];
    let top = at(x0, y0) * (1.0 - ax) + at(x0 + 1, y0) * ax;
    let bot = at(x0, y0 + 1) * (1.0 - ax) + at(x0 + 1, y0 + 1) * ax;
    top * (1.0 - ay) + bot * ay
}

/// A procedural texture (encoded values in [0, 1]): gratings, sharp-edged discs and boxes,
/// and fine grain, so that blur has edges and texture to act on.
pub fn procedural_texture(w: usize, h: usize, seed: u64) -> [Vec<f32>; 3] {
    let mut rng = Rng::new(seed);
    let mut p: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0f32; w * h]);
    let base: [f64; 3] = std::array::from_fn(|_| rng.range(0.2, 0.6));
    let gratings: Vec<(f64, f64, f64, [f64; 3])> = (0..4)
        .map(|_| {
            let (ang, per) = (rng.range(0.0, std::f64::consts::PI), rng.range(6.0, 40.0));
            (ang, per, rng.range(0.0, 6.3), std::array::from_fn(|_| rng.range(-0.12, 0.12)))
        })
        .collect();
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                let mut v = base[c];
                for (ang, per, ph, amp) in &gratings {
                    let t = (x as f64 * ang.cos() + y as f64 * ang.sin()) * std::f64::consts::TAU / per + ph;
                    v += amp[c] * t.sin();
                }
                p[c][y * w + x] = v as f32;
            }
        }
    }
    let shapes = 12 + (w * h) / 4000;
    for _ in 0..shapes {
        let col: [f32; 3] = std::array::from_fn(|_| rng.range(0.0, 1.0) as f32);
        let (cx, cy) = (rng.range(0.0, w as f64), rng.range(0.0, h as f64));
        let r = rng.range(3.0, (w.min(h) as f64 / 6.0).max(4.0));
        let disc = rng.uniform() < 0.5;
        let (x0, x1) = ((cx - r).max(0.0) as usize, ((cx + r) as usize).min(w));
        let (y0, y1) = ((cy - r).max(0.0) as usize, ((cy + r) as usize).min(h));
        for y in y0..y1 {
            for x in x0..x1 {
                let (dx, dy) = (x as f64 + 0.5 - cx, y as f64 + 0.5 - cy);
                if !disc || dx * dx + dy * dy <= r * r {
                    for c in 0..3 {
                        p[c][y * w + x] = col[c];
                    }
                }
            }
        }
    }
    for (i, v) in p.iter_mut().flat_map(|c| c.iter_mut()).enumerate() {
        let g = (crate::rng::unit(hash(&[seed, i as u64])) - 0.5) * 0.06;
        *v = (*v + g as f32).clamp(0.0, 1.0);
    }
    p
}

/// Reads a PNG into planar encoded values in [0, 1].
fn read_png(path: &std::path::Path) -> Result<(usize, usize, [Vec<f32>; 3]), String> {
    let bytes = std::fs::read(path).map_err(|e| e.to_string())?;
    let (w, h, rgb) = crate::io::png::read_rgb8(&bytes).map_err(|e| format!("not a readable PNG ({e})"))?;
    let p = std::array::from_fn(|c| (0..w * h).map(|i| rgb[i * 3 + c] as f32 / 255.0).collect());
    Ok((w, h, p))
}

struct Layer {
    w: f64,
    h: f64,
    src: (f64, f64),
    pos: (f64, f64),
    vel: (f64, f64),
}

/// `stills`: one clip per photograph (or per procedural texture).
pub struct Stills {
    pub cfg: StillsConfig,
    pub seed: u64,
    pub inputs: Vec<(Arc<Input>, Option<PathBuf>)>,
    pub needs: Needs,
    pub counters: Arc<Counters>,
}

impl Stills {
    /// Renders the clip of one input: `frames` frames of `width x height`, encoded values.
    pub fn render(&self, input: &Input, image: &(usize, usize, [Vec<f32>; 3])) -> Vec<Frame> {
        let (iw, ih, img) = image;
        let (iw, ih) = (*iw, *ih);
        let w = if self.cfg.size[0] == 0 { iw } else { self.cfg.size[0].min(iw) };
        let h = if self.cfg.size[1] == 0 { ih } else { self.cfg.size[1].min(ih) };
        let off = ((iw - w) as f64 / 2.0, (ih - h) as f64 / 2.0);
        let mut rng = Rng::new(hash(&[self.seed, input.id, hash_str("stills")]));
        let layers: Vec<Layer> = (0..self.cfg.layers)
            .map(|_| {
                let (lw, lh) = (rng.range(0.2, 0.45) * w as f64, rng.range(0.2, 0.45) * h as f64);
                let ang = rng.range(0.0, std::f64::consts::TAU);
                let speed = rng.range(0.3, 1.0) * self.cfg.layer_speed_px;
                Layer {
                    w: lw,
                    h: lh,
                    src: (rng.range(0.0, iw as f64 - lw), rng.range(0.0, ih as f64 - lh)),
                    pos: (rng.range(0.0, w as f64 - lw), rng.range(0.0, h as f64 - lh)),
                    vel: (speed * ang.cos(), speed * ang.sin()),
                }
            })
            .collect();
        let (mut cam, mut vel) = ((0.0f64, 0.0f64), (rng.normal() * self.cfg.shake_px * 2.0, rng.normal() * self.cfg.shake_px * 2.0));
        if self.cfg.pan_px > 0.0 {
            // A steady pan of random direction and speed (drawn after the layers, so configs
            // without a pan render as before).
            let (speed, ang) = (rng.range(0.0, self.cfg.pan_px), rng.range(0.0, std::f64::consts::TAU));
            vel = (vel.0 + speed * ang.cos(), vel.1 + speed * ang.sin());
        }
        let mut frames = Vec::with_capacity(self.cfg.frames as usize);
        for f in 0..self.cfg.frames {
            let mut planes: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0f32; w * h]);
            for y in 0..h {
                for x in 0..w {
                    let (sx, sy) = (x as f64 + 0.5 + off.0 + cam.0 - 0.5, y as f64 + 0.5 + off.1 + cam.1 - 0.5);
                    let mut px: [f32; 3] = std::array::from_fn(|c| sample(&img[c], iw, ih, sx, sy));
                    for l in &layers {
                        // Layer-local coordinates; the layer moves with its velocity and the camera.
                        let u = x as f64 + 0.5 - (l.pos.0 + l.vel.0 * f as f64 - cam.0);
                        let v = y as f64 + 0.5 - (l.pos.1 + l.vel.1 * f as f64 - cam.1);
                        let (nx, ny) = ((u - l.w / 2.0) / (l.w / 2.0), (v - l.h / 2.0) / (l.h / 2.0));
                        let r = (nx * nx + ny * ny).sqrt();
                        // Anti-aliased ellipse edge, about one pixel wide.
                        let edge = (l.w.min(l.h) / 2.0).max(1.0);
                        let alpha = ((1.0 - r) * edge + 0.5).clamp(0.0, 1.0) as f32;
                        if alpha > 0.0 {
                            for c in 0..3 {
                                let s = sample(&img[c], iw, ih, l.src.0 + u - 0.5, l.src.1 + v - 0.5);
                                px[c] = px[c] * (1.0 - alpha) + s * alpha;
                            }
                        }
                    }
                    for c in 0..3 {
                        planes[c][y * w + x] = px[c].clamp(0.0, 1.0);
                    }
                }
            }
            frames.push(Frame::new(w, h, FrameData::Planar(planes)));
            vel = (vel.0 + rng.normal() * self.cfg.shake_px, vel.1 + rng.normal() * self.cfg.shake_px);
            cam = (cam.0 + vel.0, cam.1 + vel.1);
        }
        frames
    }
}

impl Source for Stills {
    fn run(&mut self, out: &mut Emit) -> crate::Result<()> {
        for (input, path) in &self.inputs {
            let image = match path {
                Some(p) => match read_png(p) {
                    Ok(i) => i,
                    Err(e) => {
                        if !out.send(Item::End(input.clone(), Err(format!("{}: {e}", p.display())))) {
                            return Ok(());
                        }
                        continue;
                    }
                },
                None => {
                    let (w, h) = (self.cfg.size[0] + 64, self.cfg.size[1] + 64);
                    (w, h, procedural_texture(w, h, hash(&[self.seed, input.id, hash_str("texture")])))
                }
            };
            let frames = self.render(input, &image);
            if !emit_clip(out, input, frames, self.cfg.fps, "stills", &self.needs, &self.counters) {
                return Ok(());
            }
        }
        Ok(())
    }
}

/// Sends one rendered clip downstream (Begin, its frames, End); false when the graph stops.
fn emit_clip(out: &mut Emit, input: &Arc<Input>, frames: Vec<Frame>, fps: f64, codec: &str, needs: &Needs, counters: &Counters) -> bool {
    let info = InputInfo {
        width: frames.first().map_or(0, |f| f.width),
        height: frames.first().map_or(0, |f| f.height),
        fps,
        frames_announced: Some(frames.len() as u64),
        codec: codec.into(),
        pixel_format: "rgbf32".into(),
    };
    if let Err(e) = check_size(&info, needs) {
        return out.send(Item::End(input.clone(), Err(format!("{}: {e}", input.path))));
    }
    counters.input(&input.path, &info, frames.len() as u64);
    if !out.send(Item::Begin(input.clone(), info)) {
        return false;
    }
    for (i, f) in frames.into_iter().enumerate() {
        if out.stop.load(Ordering::Relaxed) {
            return false;
        }
        Counters::add(&counters.frames, 1);
        if !out.send(Item::Frame(input.clone(), i as u64, Arc::new(f))) {
            return false;
        }
    }
    out.send(Item::End(input.clone(), Ok(())))
}

/// `type = "scene"`: synthetic moving scenes ([`crate::scene`]), one exposure of `frames`
/// sub-frames per clip, as encoded sRGB frames (a `linearize` with curve srgb gives back the
/// rendered linear light).
pub struct Scene {
    pub cfg: crate::config::SceneSourceConfig,
    pub inputs: Vec<Arc<Input>>,
    pub needs: Needs,
    pub counters: Arc<Counters>,
}

impl Source for Scene {
    fn run(&mut self, out: &mut Emit) -> crate::Result<()> {
        let c = &self.cfg;
        let params = crate::scene::SceneParams {
            kind: c.scene,
            width: c.size[0],
            height: c.size[1],
            frames: c.frames,
            travel_px: c.travel_px,
            dots_per_arm: c.dots_per_arm,
            spokes: c.spokes,
        };
        let enc = crate::optics::transfer::Encoder::new(crate::optics::transfer::Curve::Srgb);
        // Every clip is the same exposure: render it once (frames share their pixels).
        let frames: Vec<Frame> = params
            .render()
            .into_iter()
            .map(|p| {
                Frame::new(
                    params.width,
                    params.height,
                    FrameData::Planar(p.map(|v| v.into_iter().map(|x| enc.encode(x.min(1.0))).collect())),
                )
            })
            .collect();
        for input in &self.inputs {
            if !emit_clip(out, input, frames.clone(), c.fps, "scene", &self.needs, &self.counters) {
                return Ok(());
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stills_are_reproducible_and_move() {
        let s = Stills {
            cfg: StillsConfig { size: [64, 48], frames: 5, layers: 2, ..Default::default() },
            seed: 9,
            inputs: vec![],
            needs: Needs::default(),
            counters: Arc::default(),
        };
        let input = Input { index: 0, id: 0, path: "procedural:0".into(), key: "procedural_000000000000".into() };
        let img = (128, 112, procedural_texture(128, 112, 1));
        let a = s.render(&input, &img);
        let b = s.render(&input, &img);
        let px = |f: &Frame| match &*f.data {
            FrameData::Planar(p) => p[1].clone(),
            _ => unreachable!(),
        };
        assert_eq!(px(&a[4]), px(&b[4]));
        assert_ne!(px(&a[0]), px(&a[4]), "frames must differ over time");
        assert_eq!((a[0].width, a[0].height), (64, 48));
    }

    #[test]
    fn bilinear_sample_is_exact_on_pixels_and_between() {
        let img = vec![0.0, 1.0, 2.0, 3.0];
        assert_eq!(sample(&img, 2, 2, 1.0, 0.0), 1.0);
        assert!((sample(&img, 2, 2, 0.5, 0.5) - 1.5).abs() < 1e-6);
    }

    #[test]
    fn keys_have_no_dots() {
        let id = |p: &str| crate::rng::hash_bytes(p.as_bytes());
        let k = input_key("/a/b/my.clip.v2.mp4", id("/a/b/my.clip.v2.mp4"));
        assert!(k.starts_with("my_clip_v2_") && k.len() == "my_clip_v2_".len() + 12 && !k.contains('.'), "{k}");
        assert_ne!(k, input_key("/a/c/my.clip.v2.mp4", id("/a/c/my.clip.v2.mp4")), "equal stems in other folders");
        assert_eq!(k, input_key("my.clip.v2.mp4", id("/a/b/my.clip.v2.mp4")), "the identity decides, not the spelling");
    }
}
