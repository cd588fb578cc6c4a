//! Synthetic moving scenes rendered at fine time steps, in linear light: the paper's moving
//! points (Fig. 3) and rotating spoke target (Fig. 5). One rendered frame is one sub-frame of an
//! exposure, so a camera's code (e.g. the 52 chops of the fluttered shutter) can be used exactly.

use serde::{Deserialize, Serialize};

/// Which scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum SceneKind {
    /// Two orthogonal lines of single-pixel dots crossing at the centre; the joint dot stays,
    /// the others move along their own line, faster the farther out (both signs).
    Dots,
    /// A Siemens star (spoke resolution target) rotating about its centre: motion in every
    /// direction, faster towards the rim.
    Spoke,
}

/// The geometry of a scene.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneParams {
    pub kind: SceneKind,
    pub width: usize,
    pub height: usize,
    /// Sub-frames of one exposure.
    pub frames: usize,
    /// Distance travelled over the exposure by the fastest dot or by the rim of the spoke
    /// target, in pixels.
    pub travel_px: f64,
    /// Dots per arm of each line (dots scene).
    pub dots_per_arm: usize,
    /// Black/white sector pairs (spoke scene).
    pub spokes: usize,
}

impl Default for SceneParams {
    fn default() -> Self {
        SceneParams { kind: SceneKind::Spoke, width: 192, height: 192, frames: 52, travel_px: 16.0, dots_per_arm: 4, spokes: 18 }
    }
}

/// Time of sub-frame `k` of `n` in [-1, 1] (the middle of its interval), as the cameras use.
pub fn sub_time(k: usize, n: usize) -> f64 {
    -1.0 + 2.0 * (k as f64 + 0.5) / n as f64
}

/// One dot: position at t = 0 and velocity in pixels per unit of t (t runs -1..1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dot {
    pub pos: [f64; 2],
    pub vel: [f64; 2],
}

impl SceneParams {
    /// The dots of the dots scene: the joint dot still at the centre, the others on a
    /// horizontal and a vertical line, moving along their line at speeds in proportion to their
    /// signed distance from the centre (the outermost travels `travel_px`).
    pub fn dots(&self) -> Vec<Dot> {
        // Pixel centres (i + 0.5), whole-pixel spacing.
        let c = [(self.width / 2) as f64 + 0.5, (self.height / 2) as f64 + 0.5];
        let arm = (self.width.min(self.height) as f64 / 2.0 - self.travel_px / 2.0 - 4.0).max(4.0).floor();
        let n = self.dots_per_arm.max(1);
        let mut out = vec![Dot { pos: c, vel: [0.0, 0.0] }];
        for axis in 0..2 {
            for side in [-1.0, 1.0] {
                for i in 1..=n {
                    let frac = i as f64 / n as f64;
                    let mut pos = c;
                    pos[axis] += side * (arm * frac).round();
                    let mut vel = [0.0, 0.0];
                    vel[axis] = side * frac * self.travel_px / 2.0;
                    out.push(Dot { pos, vel });
                }
            }
        }
        out
    }

    /// Angle turned over the exposure by the spoke target (radians): the rim travels
    /// `travel_px`.
    pub fn spoke_angle(&self) -> f64 {
        self.travel_px / self.spoke_radius()
    }

    pub fn spoke_radius(&self) -> f64 {
        self.width.min(self.height) as f64 * 0.45
    }

    /// The `frames` sub-frames of the exposure, linear RGB planes.
    pub fn render(&self) -> Vec<[Vec<f32>; 3]> {
        (0..self.frames).map(|k| self.render_at(sub_time(k, self.frames))).collect()
    }

    /// The scene at time `t` in [-1, 1] (0 is the middle of the exposure: the sharp target).
    pub fn render_at(&self, t: f64) -> [Vec<f32>; 3] {
        let (w, h) = (self.width, self.height);
        let mut p = vec![0.0f32; w * h];
        match self.kind {
            SceneKind::Dots => {
                for d in self.dots() {
                    // Bilinear splat of a unit point at the pixel-centre coordinate.
                    let (x, y) = (d.pos[0] + d.vel[0] * t - 0.5, d.pos[1] + d.vel[1] * t - 0.5);
                    let (fx, fy) = (x.floor(), y.floor());
                    let (ax, ay) = ((x - fx) as f32, (y - fy) as f32);
                    for (dx, dy, wgt) in
                        [(0, 0, (1.0 - ax) * (1.0 - ay)), (1, 0, ax * (1.0 - ay)), (0, 1, (1.0 - ax) * ay), (1, 1, ax * ay)]
                    {
                        let (px, py) = (fx as isize + dx, fy as isize + dy);
                        if px >= 0 && py >= 0 && (px as usize) < w && (py as usize) < h {
                            p[py as usize * w + px as usize] += wgt;
                        }
                    }
                }
            }
            SceneKind::Spoke => {
                let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
                let r = self.spoke_radius();
                let turn = 0.5 * self.spoke_angle() * t;
                const S: usize = 4;
                for y in 0..h {
                    for x in 0..w {
                        let mut acc = 0.0;
                        for sy in 0..S {
                            for sx in 0..S {
                                let u = x as f64 + (sx as f64 + 0.5) / S as f64 - cx;
                                let v = y as f64 + (sy as f64 + 0.5) / S as f64 - cy;
                                let rho = (u * u + v * v).sqrt();
                                acc += if rho > r {
                                    0.18
                                } else {
                                    let a = v.atan2(u) - turn;
                                    if (a * self.spokes as f64).sin() >= 0.0 {
                                        0.8
                                    } else {
                                        0.03
                                    }
                                };
                            }
                        }
                        p[y * w + x] = (acc / (S * S) as f64) as f32;
                    }
                }
            }
        }
        [p.clone(), p.clone(), p]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dots_land_on_the_expected_pixels() {
        let s =
            SceneParams { kind: SceneKind::Dots, width: 64, height: 48, frames: 9, travel_px: 8.0, dots_per_arm: 2, ..Default::default() };
        let dots = s.dots();
        assert_eq!(dots.len(), 9);
        assert_eq!(dots[0].vel, [0.0, 0.0]);
        // Integer positions at t = -1 and t = 1 (pos and vel chosen so): each dot is one pixel.
        for t in [-1.0, 0.0, 1.0] {
            let img = &s.render_at(t)[1];
            for d in &dots {
                let (x, y) = (d.pos[0] + d.vel[0] * t, d.pos[1] + d.vel[1] * t);
                let (px, py) = ((x - 0.5).round() as usize, (y - 0.5).round() as usize);
                let v = img[py * 64 + px];
                assert!(v > 0.99, "dot {d:?} at t {t}: pixel ({px}, {py}) holds {v}");
            }
            assert!((img.iter().sum::<f32>() - 9.0).abs() < 1e-4, "every dot carries unit energy");
        }
        // The fastest horizontal dot moves travel_px over the exposure; vertical dots move in y only.
        let fastest = dots.iter().map(|d| d.vel[0].abs() * 2.0).fold(0.0, f64::max);
        assert!((fastest - 8.0).abs() < 1e-12);
        assert!(dots.iter().all(|d| d.vel[0] == 0.0 || d.vel[1] == 0.0));
    }

    #[test]
    fn the_spoke_target_turns_by_the_asked_rim_travel() {
        let s = SceneParams { width: 96, height: 96, travel_px: 12.0, ..Default::default() };
        let (a, b) = (s.render_at(-1.0), s.render_at(1.0));
        assert_ne!(a[0], b[0]);
        assert!((s.spoke_angle() * s.spoke_radius() - 12.0).abs() < 1e-9);
        // The centre region's mean is that of a half-black, half-white disk.
        let mean = a[0].iter().sum::<f32>() / a[0].len() as f32;
        assert!(mean > 0.2 && mean < 0.5, "{mean}");
    }
}
