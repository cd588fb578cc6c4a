//! Motion of the `stills` source drawn per window, like 240 fps footage: camera shake along a
//! curved path, a straight pan, cut-out objects moving over a still or shaking background,
//! rotation or zoom of the scene, or nothing moving. Each window of N frames gets one named
//! motion (drawn by the weights in `[sources.x.motion.weights]`) and an extent drawn from
//! `extent_px`, and every sample's `key.json` records them.
//!
//! Geometry: a layer point `q` (source pixels) appears at `p = c + s R(theta) (q - c) + t` in frame
//! `j`; rendering inverts that per output pixel and samples bilinearly. Objects are RGBA sprites
//! (cut-outs with their own anti-aliased alpha, or shapes cut from the photo with a one-pixel
//! analytic edge) composited over the background in order, so nearer objects occlude farther ones.

pub use super::sprite::Sprite;
use super::texture::Photo;
use crate::checks::Checker;
use crate::rng::Rng;
use serde::{Deserialize, Serialize};

/// `[sources.x.motion]`: the motions and their extents.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionConfig {
    /// Relative weights of the named motions (each window draws one).
    pub weights: MotionWeights,
    /// Extent range in pixels over a window of 9 frames (path length of the camera, of each
    /// object, or the largest displacement of a rotation or zoom); other window lengths scale it
    /// by (N - 1) / 8, as a fixed speed at 240 fps would.
    pub extent_px: [f64; 2],
    /// Extents are `lo + (hi - lo) u^power` for `u` uniform in [0, 1]: a power above 1 makes
    /// most windows slow (2: the median is a quarter of the range), as in real footage.
    pub extent_power: f64,
    /// Objects per `objects` window, [least, most].
    pub objects: [usize; 2],
    /// Object size, as a fraction of the frame's short side, [least, most].
    pub object_size: [f64; 2],
    /// PNG cut-outs with alpha for the objects (files or folders); empty: shapes cut from the photo.
    pub object_paths: Vec<String>,
    /// Chance that the background of an `objects` window shakes too (else it is still).
    pub background_moves: f64,
    /// Frames per motion (0: the blur's window N). Test clips for `pipeline eval` use the longest
    /// N, so that every shorter window centred in it sees the same motion, shorter.
    pub window: usize,
    /// The `hand` motion's trajectories (`[sources.x.motion.hand]`).
    pub hand: super::hand::HandConfig,
}

/// Relative weights of the motions; 0 turns one off.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionWeights {
    pub still: f64,
    pub pan: f64,
    pub shake: f64,
    pub objects: f64,
    pub rotate: f64,
    pub zoom: f64,
    /// Hand-held shake to 60 px of spread ([`super::hand`]); 0 unless asked for.
    pub hand: f64,
}

impl Default for MotionWeights {
    fn default() -> Self {
        MotionWeights { still: 0.15, pan: 0.1, shake: 0.35, objects: 0.25, rotate: 0.075, zoom: 0.075, hand: 0.0 }
    }
}

impl Default for MotionConfig {
    fn default() -> Self {
        MotionConfig {
            weights: MotionWeights::default(),
            extent_px: [0.0, 40.0],
            extent_power: 2.0,
            objects: [1, 4],
            object_size: [0.15, 0.5],
            object_paths: Vec::new(),
            background_moves: 0.5,
            window: 0,
            hand: Default::default(),
        }
    }
}

/// The named motions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MotionKind {
    Still,
    Pan,
    Shake,
    Objects,
    Rotate,
    Zoom,
    Hand,
}

impl MotionKind {
    pub const ALL: [MotionKind; 7] = [
        MotionKind::Still,
        MotionKind::Pan,
        MotionKind::Shake,
        MotionKind::Objects,
        MotionKind::Rotate,
        MotionKind::Zoom,
        MotionKind::Hand,
    ];
    pub fn name(self) -> &'static str {
        match self {
            MotionKind::Still => "still",
            MotionKind::Pan => "pan",
            MotionKind::Shake => "shake",
            MotionKind::Objects => "objects",
            MotionKind::Rotate => "rotate",
            MotionKind::Zoom => "zoom",
            MotionKind::Hand => "hand",
        }
    }
}

impl MotionWeights {
    /// The weights in the order of [`MotionKind::ALL`].
    fn by_kind(&self) -> [f64; 7] {
        [self.still, self.pan, self.shake, self.objects, self.rotate, self.zoom, self.hand]
    }
}

impl MotionConfig {
    pub(crate) fn validate(&self, c: &mut Checker, key: &str) {
        let ws = self.weights.by_kind();
        for (k, v) in MotionKind::ALL.iter().zip(ws) {
            c.range(&format!("{key}.weights.{}", k.name()), v, 0.0, 1e6);
        }
        if ws.iter().sum::<f64>() <= 0.0 {
            c.fail(&format!("{key}.weights"), "all weights are 0: give at least one motion a weight".to_string());
        }
        c.range(&format!("{key}.extent_px[0]"), self.extent_px[0], 0.0, 1000.0);
        c.range(&format!("{key}.extent_px[1]"), self.extent_px[1], self.extent_px[0], 1000.0);
        c.range(&format!("{key}.extent_power"), self.extent_power, 0.1, 10.0);
        c.range_usize(&format!("{key}.objects[0]"), self.objects[0], 1, 16);
        c.range_usize(&format!("{key}.objects[1]"), self.objects[1], self.objects[0], 16);
        c.range(&format!("{key}.object_size[0]"), self.object_size[0], 0.02, 1.0);
        c.range(&format!("{key}.object_size[1]"), self.object_size[1], self.object_size[0], 1.0);
        c.range(&format!("{key}.background_moves"), self.background_moves, 0.0, 1.0);
        c.range_usize(&format!("{key}.window"), self.window, 0, 4096);
        self.hand.validate(c, &format!("{key}.hand"));
    }

    fn kind(&self, rng: &mut Rng) -> MotionKind {
        let ws = self.weights.by_kind();
        let mut u = rng.uniform() * ws.iter().sum::<f64>();
        for (k, v) in MotionKind::ALL.iter().zip(ws) {
            if u < v {
                return *k;
            }
            u -= v;
        }
        *MotionKind::ALL.iter().zip(ws).rev().find(|(_, v)| *v > 0.0).expect("a weight above 0").0
    }

    fn extent(&self, rng: &mut Rng, scale: f64) -> f64 {
        let [lo, hi] = self.extent_px;
        (lo + (hi - lo) * rng.uniform().powf(self.extent_power)) * scale
    }
}

/// Where a layer is in one frame: `p = c + scale R(theta) (q - c) + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub t: (f64, f64),
    pub theta: f64,
    pub scale: f64,
}

impl Pose {
    const REST: Pose = Pose { t: (0.0, 0.0), theta: 0.0, scale: 1.0 };
    /// The layer point shown at `p` (inverse of the pose about `c`).
    fn inverse(&self, c: (f64, f64), p: (f64, f64)) -> (f64, f64) {
        let (dx, dy) = (p.0 - self.t.0 - c.0, p.1 - self.t.1 - c.1);
        let (s, co) = (-self.theta).sin_cos();
        (c.0 + (co * dx - s * dy) / self.scale, c.1 + (s * dx + co * dy) / self.scale)
    }
}

/// One object of a window: its sprite, scale and per-frame pose of its centre.
#[derive(Debug, Clone)]
struct Object {
    sprite: std::sync::Arc<Sprite>,
    scale: f64,
    /// Centre position and rotation per frame.
    path: Vec<((f64, f64), f64)>,
}

impl Object {
    /// One object of an `objects` window of `n` frames of a `(fw, fh)` view: a cut-out of
    /// `sprites` (or a shape cut from the image when there are none), its size, straight path,
    /// spin and extent drawn from `cfg`. Returns it with its extent.
    fn draw(
        cfg: &MotionConfig,
        n: usize,
        (fw, fh): (f64, f64),
        (img, iw, ih): (&[Vec<f32>; 3], usize, usize),
        sprites: &[std::sync::Arc<Sprite>],
        scale: f64,
        rng: &mut Rng,
    ) -> (Object, f64) {
        let side = rng.range(cfg.object_size[0], cfg.object_size[1]) * fw.min(fh);
        let (sprite, sc) = if sprites.is_empty() {
            let (sw, sh) = ((side * rng.range(0.6, 1.4)).max(4.0) as usize, (side * rng.range(0.6, 1.4)).max(4.0) as usize);
            let src = (rng.range(0.0, (iw as f64 - sw as f64).max(0.0)), rng.range(0.0, (ih as f64 - sh as f64).max(0.0)));
            (std::sync::Arc::new(Sprite::cut(img, iw, ih, sw, sh, src, rng)), 1.0)
        } else {
            let s = sprites[rng.below(sprites.len())].clone();
            let sc = side / s.w.max(s.h) as f64;
            (s, sc)
        };
        let e = cfg.extent(rng, scale);
        let a = rng.range(0.0, std::f64::consts::TAU);
        let mid = (rng.range(0.0, fw), rng.range(0.0, fh));
        let radius = sc * sprite.w.max(sprite.h) as f64 / 2.0;
        // A spin that moves the rim by at most half the object's own extent.
        let spin = rng.range(-0.5, 0.5) * e / radius.max(1.0);
        let phi0 = rng.range(0.0, std::f64::consts::TAU);
        let path = (0..n).map(|j| ((mid.0 + tau(j, n) * e * a.cos(), mid.1 + tau(j, n) * e * a.sin()), phi0 + tau(j, n) * spin)).collect();
        (Object { sprite, scale: sc, path }, e)
    }
}

/// The motion of one window: per frame, the background's pose, and the objects over it.
#[derive(Debug, Clone)]
pub struct WindowMotion {
    pub kind: MotionKind,
    pub extent_px: f64,
    pub background: Option<MotionKind>,
    centre: (f64, f64),
    poses: Vec<Pose>,
    objects: Vec<Object>,
}

/// A curved hand-held path of `n` positions: velocity with inertia, jitter and at times a jerk,
/// scaled to path length `extent` and centred on the middle frame.
fn shake_path(n: usize, extent: f64, rng: &mut Rng) -> Vec<(f64, f64)> {
    let a = rng.range(0.0, std::f64::consts::TAU);
    let mut v = (a.cos(), a.sin());
    let (inertia, jitter) = (rng.range(0.6, 0.95), rng.range(0.2, 0.9));
    let jerk = (rng.uniform() < 0.3).then(|| rng.below(n.max(2) - 1));
    let mut p = vec![(0.0, 0.0)];
    for j in 1..n {
        v = (inertia * v.0 + jitter * rng.normal(), inertia * v.1 + jitter * rng.normal());
        if jerk == Some(j - 1) {
            let b = rng.range(0.0, std::f64::consts::TAU);
            v = (v.0 + 2.5 * b.cos(), v.1 + 2.5 * b.sin());
        }
        let last = p[j - 1];
        p.push((last.0 + v.0, last.1 + v.1));
    }
    let len: f64 = p.windows(2).map(|w| ((w[1].0 - w[0].0).powi(2) + (w[1].1 - w[0].1).powi(2)).sqrt()).sum();
    let k = if len > 1e-9 { extent / len } else { 0.0 };
    let mid = p[n / 2];
    p.iter().map(|q| ((q.0 - mid.0) * k, (q.1 - mid.1) * k)).collect()
}

/// Position along a window of `n` frames in [-0.5, 0.5] (0 at the middle frame, which is the
/// sharp target).
fn tau(j: usize, n: usize) -> f64 {
    if n < 2 {
        0.0
    } else {
        (j as f64 - (n / 2) as f64) / (n - 1) as f64
    }
}

impl WindowMotion {
    /// Draws the motion of one window of `n` frames of a `w x h` view of `photo`.
    pub fn draw(
        cfg: &MotionConfig,
        n: usize,
        (w, h): (usize, usize),
        photo: Photo,
        sprites: &[std::sync::Arc<Sprite>],
        rng: &mut Rng,
    ) -> WindowMotion {
        let Photo { planes: img, w: iw, h: ih } = photo;
        let scale = (n.max(2) - 1) as f64 / 8.0;
        let kind = cfg.kind(rng);
        let (fw, fh) = (w as f64, h as f64);
        let centre = (rng.range(0.2, 0.8) * fw, rng.range(0.2, 0.8) * fh);
        // The farthest frame corner from the centre: rotations and zooms move it most.
        let r_max = [(0.0, 0.0), (fw, 0.0), (0.0, fh), (fw, fh)]
            .iter()
            .map(|c: &(f64, f64)| ((c.0 - centre.0).powi(2) + (c.1 - centre.1).powi(2)).sqrt())
            .fold(1.0, f64::max);
        let mut m = WindowMotion { kind, extent_px: 0.0, background: None, centre, poses: vec![Pose::REST; n], objects: Vec::new() };
        match kind {
            MotionKind::Still => {}
            MotionKind::Pan => {
                let (e, a) = (cfg.extent(rng, scale), rng.range(0.0, std::f64::consts::TAU));
                m.extent_px = e;
                for (j, p) in m.poses.iter_mut().enumerate() {
                    p.t = (tau(j, n) * e * a.cos(), tau(j, n) * e * a.sin());
                }
            }
            MotionKind::Shake => {
                m.extent_px = cfg.extent(rng, scale);
                for (p, t) in m.poses.iter_mut().zip(shake_path(n, m.extent_px, rng)) {
                    p.t = t;
                }
            }
            MotionKind::Hand => {
                let (path, extent) = cfg.hand.path(n, scale, rng);
                m.extent_px = extent;
                for (p, t) in m.poses.iter_mut().zip(path) {
                    p.t = t;
                }
            }
            MotionKind::Rotate => {
                m.extent_px = cfg.extent(rng, scale);
                let dtheta = m.extent_px / r_max * if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
                for (j, p) in m.poses.iter_mut().enumerate() {
                    p.theta = tau(j, n) * dtheta;
                }
            }
            MotionKind::Zoom => {
                m.extent_px = cfg.extent(rng, scale);
                let ds = m.extent_px / r_max * if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
                for (j, p) in m.poses.iter_mut().enumerate() {
                    p.scale = 1.0 + tau(j, n) * ds;
                }
            }
            MotionKind::Objects => {
                if rng.uniform() < cfg.background_moves {
                    let e = cfg.extent(rng, scale);
                    m.background = Some(MotionKind::Shake);
                    for (p, t) in m.poses.iter_mut().zip(shake_path(n, e, rng)) {
                        p.t = t;
                    }
                } else {
                    m.background = Some(MotionKind::Still);
                }
                let count = cfg.objects[0] + rng.below(cfg.objects[1] - cfg.objects[0] + 1);
                for _ in 0..count {
                    let o = Object::draw(cfg, n, (fw, fh), (img, iw, ih), sprites, scale, rng);
                    m.extent_px = m.extent_px.max(o.1);
                    m.objects.push(o.0);
                }
            }
        }
        m
    }

    /// What `key.json` records of the window; for a motion of the whole frame by translation
    /// (still, pan, shake, hand) also `shift`, each frame's displacement in pixels, so that a
    /// reconstruction can be told the true kernel (`pipeline eval`'s Wiener bound).
    pub fn label(&self) -> String {
        let mut v = serde_json::json!({ "kind": self.kind.name(), "extent_px": (self.extent_px * 100.0).round() / 100.0 });
        if let Some(b) = self.background {
            v["objects"] = self.objects.len().into();
            v["background"] = b.name().into();
        }
        if matches!(self.kind, MotionKind::Still | MotionKind::Pan | MotionKind::Shake | MotionKind::Hand) {
            let r = |x: f64| (x * 1000.0).round() / 1000.0;
            v["shift"] = self.poses.iter().map(|p| serde_json::json!([r(p.t.0), r(p.t.1)])).collect::<Vec<_>>().into();
        }
        v.to_string()
    }

    /// Frame `j` of the window: the view `w x h` at `off` in `photo`, then the objects.
    pub fn render(&self, j: usize, photo: Photo, (w, h): (usize, usize), off: (f64, f64)) -> [Vec<f32>; 3] {
        let Photo { planes: img, w: iw, h: ih } = photo;
        let mut planes: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0f32; w * h]);
        let pose = self.poses[j];
        for y in 0..h {
            for x in 0..w {
                let q = pose.inverse(self.centre, (x as f64 + 0.5, y as f64 + 0.5));
                for c in 0..3 {
                    planes[c][y * w + x] = super::texture::sample(&img[c], iw, ih, off.0 + q.0 - 0.5, off.1 + q.1 - 0.5);
                }
            }
        }
        for o in &self.objects {
            let ((px, py), phi) = o.path[j];
            let (sw, sh) = (o.sprite.w as f64 * o.scale, o.sprite.h as f64 * o.scale);
            let r = (sw * sw + sh * sh).sqrt() / 2.0 + 2.0;
            let (x0, x1) = ((px - r).floor().max(0.0) as usize, ((px + r).ceil().max(0.0) as usize).min(w));
            let (y0, y1) = ((py - r).floor().max(0.0) as usize, ((py + r).ceil().max(0.0) as usize).min(h));
            let (s, co) = (-phi).sin_cos();
            for y in y0..y1 {
                for x in x0..x1 {
                    let (dx, dy) = (x as f64 + 0.5 - px, y as f64 + 0.5 - py);
                    let (u, v) =
                        ((co * dx - s * dy) / o.scale + o.sprite.w as f64 / 2.0, (s * dx + co * dy) / o.scale + o.sprite.h as f64 / 2.0);
                    let (rgb, a) = o.sprite.at(u, v);
                    if a > 0.0 {
                        let i = y * w + x;
                        for c in 0..3 {
                            planes[c][i] = planes[c][i] * (1.0 - a) + rgb[c];
                        }
                    }
                }
            }
        }
        for p in planes.iter_mut() {
            p.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
        }
        planes
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn texture(w: usize, h: usize) -> [Vec<f32>; 3] {
        super::super::texture::procedural_texture(w, h, 3)
    }

    fn only(kind: &str) -> MotionConfig {
        let mut w = MotionWeights { still: 0.0, pan: 0.0, shake: 0.0, objects: 0.0, rotate: 0.0, zoom: 0.0, hand: 0.0 };
        match kind {
            "still" => w.still = 1.0,
            "pan" => w.pan = 1.0,
            "shake" => w.shake = 1.0,
            "objects" => w.objects = 1.0,
            "rotate" => w.rotate = 1.0,
            "hand" => w.hand = 1.0,
            _ => w.zoom = 1.0,
        }
        let hand = super::super::hand::HandConfig { extent_px: [10.0, 30.0], ..Default::default() };
        MotionConfig { weights: w, extent_px: [10.0, 30.0], hand, ..Default::default() }
    }

    #[test]
    fn a_shake_path_is_curved_has_the_drawn_length_and_rests_at_the_middle_frame() {
        let mut curved = 0;
        for seed in 0..20 {
            let p = shake_path(9, 24.0, &mut Rng::new(seed));
            let len: f64 = p.windows(2).map(|w| ((w[1].0 - w[0].0).powi(2) + (w[1].1 - w[0].1).powi(2)).sqrt()).sum();
            assert!((len - 24.0).abs() < 1e-9, "length {len}");
            assert_eq!(p[4], (0.0, 0.0));
            let chord = ((p[8].0 - p[0].0).powi(2) + (p[8].1 - p[0].1).powi(2)).sqrt();
            curved += usize::from(chord < 0.97 * len);
        }
        assert!(curved >= 15, "only {curved} of 20 paths bend");
    }

    #[test]
    fn every_motion_moves_the_frame_by_its_extent_and_still_moves_nothing() {
        let (iw, ih, w, h) = (160, 128, 96, 80);
        let img = texture(iw, ih);
        let off = (32.0, 24.0);
        for kind in ["still", "pan", "shake", "objects", "rotate", "zoom", "hand"] {
            let cfg = only(kind);
            let photo = Photo { planes: &img, w: iw, h: ih };
            let m = WindowMotion::draw(&cfg, 9, (w, h), photo, &[], &mut Rng::new(5));
            assert_eq!(m.kind.name(), kind);
            let label: serde_json::Value = serde_json::from_str(&m.label()).unwrap();
            assert_eq!(label["kind"], kind);
            let (first, mid) = (m.render(0, photo, (w, h), off), m.render(4, photo, (w, h), off));
            let diff: f32 = first[1].iter().zip(&mid[1]).map(|(a, b)| (a - b).abs()).sum::<f32>() / (w * h) as f32;
            if kind == "still" {
                assert_eq!(m.extent_px, 0.0);
                assert_eq!(diff, 0.0, "a still window moved");
            } else {
                assert!((10.0..=30.0).contains(&m.extent_px), "{kind}: extent {}", m.extent_px);
                assert!(diff > 0.005, "{kind}: frames 0 and 4 differ by only {diff}");
            }
            // The middle frame of a window without objects is the view itself, unmoved.
            if matches!(kind, "still" | "pan" | "shake" | "rotate" | "zoom" | "hand") {
                let x = 40;
                let y = 30;
                let want = super::super::texture::sample(&img[1], iw, ih, off.0 + x as f64, off.1 + y as f64);
                assert!((mid[1][y * w + x] - want).abs() < 1e-5, "{kind}: middle frame moved");
            }
        }
    }

    #[test]
    fn a_cut_out_occludes_with_a_soft_one_pixel_edge() {
        // A 20x20 opaque square sprite with a 50% alpha rim, over a black frame.
        let (sw, sh) = (20, 20);
        let mut rgba = vec![0u8; sw * sh * 4];
        for y in 0..sh {
            for x in 0..sw {
                let rim = x == 0 || y == 0 || x == sw - 1 || y == sh - 1;
                rgba[(y * sw + x) * 4..(y * sw + x) * 4 + 4].copy_from_slice(&[255, 255, 255, if rim { 128 } else { 255 }]);
            }
        }
        let sprite = std::sync::Arc::new(Sprite::from_rgba8(sw, sh, &rgba, 64));
        let black: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0; 64 * 64]);
        let photo = Photo { planes: &black, w: 64, h: 64 };
        let mut m = WindowMotion::draw(&only("still"), 3, (64, 64), photo, &[], &mut Rng::new(1));
        m.objects.push(Object { sprite, scale: 1.0, path: vec![((32.0, 32.0), 0.0); 3] });
        let f = m.render(1, photo, (64, 64), (0.0, 0.0));
        let v = |x: usize, y: usize| f[0][y * 64 + x];
        assert_eq!(v(32, 32), 1.0, "inside: the object hides the background");
        assert_eq!(v(10, 10), 0.0, "outside: the background");
        assert!((v(22, 32) - 128.0 / 255.0).abs() < 0.01, "the rim keeps its partial alpha: {}", v(22, 32));
    }

    #[test]
    fn weights_pick_the_kinds_in_proportion_and_extents_are_mostly_small() {
        let cfg = MotionConfig { extent_px: [0.0, 40.0], ..Default::default() };
        let mut rng = Rng::new(2);
        let mut counts = std::collections::BTreeMap::new();
        let mut ext = Vec::new();
        for _ in 0..4000 {
            *counts.entry(cfg.kind(&mut rng).name()).or_insert(0) += 1;
            ext.push(cfg.extent(&mut rng, 1.0));
        }
        assert!((1250..1550).contains(&counts["shake"]), "{counts:?}");
        assert!((450..750).contains(&counts["still"]), "{counts:?}");
        ext.sort_by(f64::total_cmp);
        assert!((8.0..12.0).contains(&ext[2000]), "median extent {}", ext[2000]);
        assert!(ext[3999] <= 40.0);
    }
}
