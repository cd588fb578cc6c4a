//! What the rendered sources paint with: bilinear sampling with mirrored borders, and a
//! procedural texture with edges and grain.

use crate::rng::{hash, Rng};

/// A photograph the motions view: planar RGB values in [0, 1], `w x h`.
#[derive(Debug, Clone, Copy)]
pub struct Photo<'a> {
    pub planes: &'a [Vec<f32>; 3],
    pub w: usize,
    pub h: usize,
}

/// Bilinear sample of a planar image with mirrored borders.
pub fn sample(img: &[f32], w: usize, h: usize, x: f64, y: f64) -> f32 {
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
