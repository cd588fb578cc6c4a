//! Cut-out objects: RGBA layers with premultiplied colour, from PNGs with alpha or cut from the
//! photograph itself, sampled bilinearly.

use crate::rng::Rng;

/// An RGBA layer with premultiplied colour (linear in the encoded values, as the stills are).
#[derive(Debug, Clone)]
pub struct Sprite {
    pub w: usize,
    pub h: usize,
    pub rgb: [Vec<f32>; 3],
    pub alpha: Vec<f32>,
}

impl Sprite {
    /// From interleaved RGBA 8-bit, box-reduced by an integer factor so its longer side is at
    /// most `max_side` (the bilinear sampling later then never skips source pixels).
    pub fn from_rgba8(w: usize, h: usize, rgba: &[u8], max_side: usize) -> Sprite {
        let k = w.max(h).div_ceil(max_side.max(1)).max(1);
        let (ow, oh) = (w / k, h / k);
        let mut s = Sprite {
            w: ow.max(1),
            h: oh.max(1),
            rgb: std::array::from_fn(|_| vec![0.0; ow.max(1) * oh.max(1)]),
            alpha: vec![0.0; ow.max(1) * oh.max(1)],
        };
        for y in 0..oh {
            for x in 0..ow {
                let mut acc = [0.0f32; 4];
                for yy in y * k..(y + 1) * k {
                    for xx in x * k..(x + 1) * k {
                        let p = &rgba[(yy * w + xx) * 4..(yy * w + xx) * 4 + 4];
                        let a = p[3] as f32 / 255.0;
                        for c in 0..3 {
                            acc[c] += p[c] as f32 / 255.0 * a;
                        }
                        acc[3] += a;
                    }
                }
                let n = (k * k) as f32;
                for c in 0..3 {
                    s.rgb[c][y * ow + x] = acc[c] / n;
                }
                s.alpha[y * ow + x] = acc[3] / n;
            }
        }
        s
    }

    /// A shape cut from `img` at `src` (top-left, image pixels): an ellipse or a convex polygon
    /// with a one-pixel anti-aliased edge.
    pub(super) fn cut(img: &[Vec<f32>; 3], iw: usize, ih: usize, w: usize, h: usize, src: (f64, f64), rng: &mut Rng) -> Sprite {
        let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
        // A polygon as its edges: a point on each and the inward unit normal (inside is where
        // every edge's cross product has the sign of the polygon's area).
        let polygon: Option<Vec<(f64, f64, f64, f64)>> = (rng.uniform() < 0.5).then(|| {
            let n = 3 + rng.below(5);
            let mut angles: Vec<f64> = (0..n).map(|_| rng.range(0.0, std::f64::consts::TAU)).collect();
            angles.sort_by(f64::total_cmp);
            let v: Vec<(f64, f64)> = angles.iter().map(|a| (cx + (cx - 1.0) * a.cos(), cy + (cy - 1.0) * a.sin())).collect();
            let next = |i: usize| v[(i + 1) % v.len()];
            let sign = (0..v.len()).map(|i| v[i].0 * next(i).1 - next(i).0 * v[i].1).sum::<f64>().signum();
            (0..v.len())
                .map(|i| {
                    let (ex, ey) = (next(i).0 - v[i].0, next(i).1 - v[i].1);
                    let len = (ex * ex + ey * ey).sqrt().max(1e-9);
                    (v[i].0, v[i].1, -sign * ey / len, sign * ex / len)
                })
                .collect()
        });
        let mut s = Sprite { w, h, rgb: std::array::from_fn(|_| vec![0.0; w * h]), alpha: vec![0.0; w * h] };
        for y in 0..h {
            for x in 0..w {
                let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
                // Signed distance inside the edge, in pixels (approximate for the ellipse).
                let d = match &polygon {
                    Some(edges) => edges.iter().map(|&(ax, ay, nx, ny)| nx * (px - ax) + ny * (py - ay)).fold(f64::INFINITY, f64::min),
                    _ => {
                        let (nx, ny) = ((px - cx) / cx, (py - cy) / cy);
                        (1.0 - (nx * nx + ny * ny).sqrt()) * cx.min(cy)
                    }
                };
                let a = (d + 0.5).clamp(0.0, 1.0) as f32;
                let i = y * w + x;
                s.alpha[i] = a;
                for c in 0..3 {
                    s.rgb[c][i] = a * super::texture::sample(&img[c], iw, ih, src.0 + px - 0.5, src.1 + py - 0.5);
                }
            }
        }
        s
    }

    /// Premultiplied colour and alpha at sprite point `(x, y)`, zero outside.
    pub(super) fn at(&self, x: f64, y: f64) -> ([f32; 3], f32) {
        let (fx, fy) = ((x - 0.5).floor(), (y - 0.5).floor());
        let (ax, ay) = ((x - 0.5 - fx) as f32, (y - 0.5 - fy) as f32);
        let (x0, y0) = (fx as isize, fy as isize);
        let mut out = ([0.0f32; 3], 0.0f32);
        for (dx, dy, wgt) in [(0, 0, (1.0 - ax) * (1.0 - ay)), (1, 0, ax * (1.0 - ay)), (0, 1, (1.0 - ax) * ay), (1, 1, ax * ay)] {
            let (xx, yy) = (x0 + dx, y0 + dy);
            if wgt == 0.0 || xx < 0 || yy < 0 || xx >= self.w as isize || yy >= self.h as isize {
                continue;
            }
            let i = yy as usize * self.w + xx as usize;
            for c in 0..3 {
                out.0[c] += wgt * self.rgb[c][i];
            }
            out.1 += wgt * self.alpha[i];
        }
        out
    }
}
