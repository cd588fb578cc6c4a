//! `stills`: high-frame-rate clips rendered from still photographs (or procedural textures):
//! with a `[motion]` table, a motion drawn per window (shake, pan, objects, rotate, zoom or
//! still; [`crate::render::motion`]); without one, the older per-clip shake, pan and moving layers.

use super::input::emit_clip;
use super::{BuildContext, Built, Counters, Emit, InputList, Needs, Source, StageConfig};
use crate::checks::Checker;
use crate::checks::ConfigError;
use crate::frame::{Frame, FrameData, Input, InputError};
use crate::item::Item;
use crate::render::motion::{MotionConfig, Sprite, WindowMotion};
use crate::render::texture::Photo;
use crate::render::texture::{procedural_texture, sample};
use crate::rng::{hash, hash_str, Rng};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::sync::Arc;

/// `type = "stills"`: renders high-frame-rate clips from still photographs (or a procedural
/// texture when `paths` is empty) with seeded camera shake and independently moving layers.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StillsConfig {
    /// PNG files or folders of them; empty: procedural textures (`clips` of them).
    pub paths: Vec<String>,
    /// Procedural clips when `paths` is empty.
    pub clips: usize,
    /// Frames rendered per clip.
    pub frames: u64,
    /// Nominal frame rate written to the report.
    pub fps: f64,
    /// Output frame size [width, height]; for photos, the centre crop (0: the photo's size).
    pub size: [usize; 2],
    /// Standard deviation of the camera's velocity change per frame, pixels.
    pub shake_px: f64,
    /// Moving layers pasted over the background.
    pub layers: usize,
    /// Largest layer speed, pixels per frame.
    pub layer_speed_px: f64,
    /// Largest steady camera (pan) speed, pixels per frame: each clip draws a speed uniformly
    /// from [0, this] in a random direction, on top of the shake (0: shake only).
    pub pan_px: f64,
    /// A motion drawn per window ([`MotionConfig`]); when present, `shake_px`, `layers`,
    /// `layer_speed_px` and `pan_px` are not used.
    pub motion: Option<MotionConfig>,
}

impl Default for StillsConfig {
    fn default() -> Self {
        StillsConfig {
            paths: Vec::new(),
            clips: 2,
            frames: 36,
            fps: 240.0,
            size: [256, 192],
            shake_px: 0.15,
            layers: 3,
            layer_speed_px: 2.0,
            pan_px: 0.0,
            motion: None,
        }
    }
}

impl StageConfig for StillsConfig {
    super::wiring!(source, EncodedFrames);
    fn validate(&self, key: &str) -> Vec<ConfigError> {
        let mut c = Checker::new(key);
        c.range_usize("frames", self.frames as usize, 1, 1_000_000);
        c.range("fps", self.fps, 1.0, 100_000.0);
        c.range("shake_px", self.shake_px, 0.0, 50.0);
        c.range_usize("layers", self.layers, 0, 64);
        c.range("layer_speed_px", self.layer_speed_px, 0.0, 100.0);
        c.range("pan_px", self.pan_px, 0.0, 100.0);
        if let Some(m) = &self.motion {
            m.validate(&mut c, "motion");
        }
        if self.paths.is_empty() {
            c.range_usize("clips", self.clips, 1, 100_000);
            for (i, v) in self.size.iter().enumerate() {
                c.range_usize(&format!("size[{i}]"), *v, 16, 8192);
            }
        }
        c.errors
    }
    fn list(&self) -> crate::Result<InputList> {
        if self.paths.is_empty() {
            return Ok(InputList::Procedural(self.clips));
        }
        crate::io::paths::expand_paths(&self.paths, &["png"]).map(InputList::Files)
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        Ok(Built::Source(Box::new(Stills {
            cfg: self.clone(),
            seed: ctx.seed,
            inputs: ctx.inputs.to_vec(),
            needs: ctx.needs,
            counters: ctx.counters.clone(),
            sprites: match &self.motion {
                // Reduced to the largest object the frame can hold, so sampling never skips pixels
                // (size 0 is the photo's own: up to 1024 px then).
                Some(m) if !m.object_paths.is_empty() => {
                    let side = match self.size[0].max(self.size[1]) {
                        0 => 1024,
                        s => s,
                    };
                    load_sprites(&m.object_paths, (m.object_size[1] * side as f64).ceil() as usize)?
                }
                _ => Vec::new(),
            },
        })))
    }
}

/// Reads a PNG into planar encoded values in [0, 1].
fn read_png(path: &std::path::Path) -> crate::Result<(usize, usize, [Vec<f32>; 3])> {
    let bytes = std::fs::read(path).map_err(|cause| crate::Error::Io { path: path.into(), cause })?;
    let (w, h, rgb) = crate::io::png::read_rgb8(&bytes).map_err(crate::Error::format(path))?;
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
    /// The cut-outs of `motion.object_paths`.
    pub sprites: Vec<Arc<Sprite>>,
}

impl Stills {
    /// Renders the clip of one input: `frames` frames of `width x height`, encoded values.
    pub fn render(&self, input: &Input, image: &(usize, usize, [Vec<f32>; 3])) -> Vec<Frame> {
        let (iw, ih, img) = image;
        let (iw, ih) = (*iw, *ih);
        let w = if self.cfg.size[0] == 0 { iw } else { self.cfg.size[0].min(iw) };
        let h = if self.cfg.size[1] == 0 { ih } else { self.cfg.size[1].min(ih) };
        let off = ((iw - w) as f64 / 2.0, (ih - h) as f64 / 2.0);
        if let Some(m) = &self.cfg.motion {
            return self.render_windows(m, input, img, iw, ih, w, h, off);
        }
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

impl Stills {
    /// Frames in windows of the blur's length, each window with a motion of its own.
    #[allow(clippy::too_many_arguments)]
    fn render_windows(
        &self,
        m: &MotionConfig,
        input: &Input,
        img: &[Vec<f32>; 3],
        iw: usize,
        ih: usize,
        w: usize,
        h: usize,
        off: (f64, f64),
    ) -> Vec<Frame> {
        let n = if m.window > 0 { m.window } else { (self.needs.frames as usize).max(1) };
        let mut frames = Vec::with_capacity(self.cfg.frames as usize);
        let mut k = 0u64;
        while (frames.len() as u64) < self.cfg.frames {
            let mut rng = Rng::new(hash(&[self.seed, input.id, k, hash_str("motion")]));
            let photo = Photo { planes: img, w: iw, h: ih };
            let wm = WindowMotion::draw(m, n, (w, h), photo, &self.sprites, &mut rng);
            let label: Arc<str> = wm.label().into();
            for j in 0..n.min((self.cfg.frames - frames.len() as u64) as usize) {
                let mut f = Frame::new(w, h, FrameData::Planar(wm.render(j, photo, (w, h), off)));
                f.motion = Some(label.clone());
                frames.push(f);
            }
            k += 1;
        }
        frames
    }
}

/// Reads the cut-outs of `motion.object_paths` (PNG with alpha), each reduced so its longer side
/// is at most `max_side`.
///
/// # Errors
/// A file that is not a readable PNG, or one without any transparent pixel (not a cut-out).
pub fn load_sprites(paths: &[String], max_side: usize) -> crate::Result<Vec<Arc<Sprite>>> {
    let files = crate::io::paths::expand_paths(paths, &["png"])?;
    let mut out = Vec::with_capacity(files.len());
    for f in files {
        let bytes = std::fs::read(&f).map_err(|e| crate::Error::Io { path: f.clone(), cause: e })?;
        let (w, h, rgba) = crate::io::png::read_rgba8(&bytes).map_err(crate::Error::format(&f))?;
        if !rgba.chunks_exact(4).any(|p| p[3] < 255) {
            return Err(crate::Error::File {
                path: f.clone(),
                why: "no transparent pixel, so not a cut-out (motion.object_paths wants PNGs with alpha)".into(),
            });
        }
        out.push(Arc::new(Sprite::from_rgba8(w, h, &rgba, max_side)));
    }
    Ok(out)
}

impl Source for Stills {
    fn run(&mut self, out: &mut Emit) -> crate::Result<()> {
        for (input, path) in &self.inputs {
            let image = match path {
                Some(p) => match read_png(p) {
                    Ok(i) => i,
                    Err(e) => {
                        if !out.send(Item::End(input.clone(), InputError::Read(e).end())) {
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
            sprites: Vec::new(),
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
}
