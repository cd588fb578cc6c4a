//! Demosaicing: the colours a Bayer mosaic did not sample at a pixel, from its neighbours.
//! Bilinear (the mean of the nearest sites of that colour) and Malvar, He and Cutler's
//! gradient-corrected linear filters ("High-quality linear interpolation for demosaicing of
//! Bayer-patterned color images", ICASSP 2004: 5x5 kernels that add a Laplacian of the pixel's own
//! colour to the bilinear estimate, so edges keep their colour better). Borders are mirrored
//! inside the patch; `(x0, y0)` places the patch on the frame's colour filter array.

use crate::optics::fft::reflect;

/// The colour of each site of a 2x2 Bayer tile, in reading order (0 R, 1 G, 2 B).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Bayer {
    Rggb,
    Bggr,
    Grbg,
    Gbrg,
}

impl Bayer {
    /// The colour sampled at frame position (x, y).
    pub fn colour(self, x: usize, y: usize) -> usize {
        let tile = match self {
            Bayer::Rggb => [0, 1, 1, 2],
            Bayer::Bggr => [2, 1, 1, 0],
            Bayer::Grbg => [1, 0, 2, 1],
            Bayer::Gbrg => [1, 2, 0, 1],
        };
        tile[(y % 2) * 2 + x % 2]
    }
}

/// Which demosaicing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Demosaic {
    #[default]
    Bilinear,
    /// Malvar, He and Cutler's 5x5 gradient-corrected filters.
    Malvar,
}

/// Bilinear demosaicing: each missing colour is the mean of the nearest sites of that colour (the
/// 2 or 4 neighbours), borders mirrored inside the patch. `(x0, y0)` places the patch on the
/// frame's colour filter array.
pub fn demosaic_bilinear(raw: &[f32], w: usize, h: usize, (x0, y0): (usize, usize), b: Bayer) -> [Vec<f32>; 3] {
    let at = |x: isize, y: isize| {
        let (x, y) = (reflect(x, w), reflect(y, h));
        (raw[y * w + x], b.colour(x0 + x, y0 + y))
    };
    let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0; w * h]);
    for y in 0..h as isize {
        for x in 0..w as isize {
            let i = y as usize * w + x as usize;
            let (v, own) = at(x, y);
            for (c, plane) in out.iter_mut().enumerate() {
                if c == own {
                    plane[i] = v;
                    continue;
                }
                // The neighbours of colour c: the 4 edge neighbours, else the 4 diagonal ones.
                let pick = |offsets: &[(isize, isize)]| {
                    let (s, n) = offsets
                        .iter()
                        .map(|&(dx, dy)| at(x + dx, y + dy))
                        .filter(|&(_, k)| k == c)
                        .fold((0.0f32, 0u32), |(s, n), (v, _)| (s + v, n + 1));
                    (n > 0).then(|| s / n as f32)
                };
                plane[i] = pick(&[(-1, 0), (1, 0), (0, -1), (0, 1)]).or_else(|| pick(&[(-1, -1), (1, -1), (-1, 1), (1, 1)])).unwrap_or(v);
            }
        }
    }
    out
}

/// Malvar-He-Cutler's kernels (x 8), as offsets (dx, dy, weight): green at a red or blue site;
/// red or blue at a green site whose row holds that colour; the same whose column does; red at
/// blue and blue at red.
const G_AT_RB: [(isize, isize, f32); 9] =
    [(0, -2, -1.0), (0, -1, 2.0), (-2, 0, -1.0), (-1, 0, 2.0), (0, 0, 4.0), (1, 0, 2.0), (2, 0, -1.0), (0, 1, 2.0), (0, 2, -1.0)];
const ROW: [(isize, isize, f32); 11] = [
    (0, -2, 0.5),
    (-1, -1, -1.0),
    (1, -1, -1.0),
    (-2, 0, -1.0),
    (-1, 0, 4.0),
    (0, 0, 5.0),
    (1, 0, 4.0),
    (2, 0, -1.0),
    (-1, 1, -1.0),
    (1, 1, -1.0),
    (0, 2, 0.5),
];
const DIAGONAL: [(isize, isize, f32); 9] =
    [(0, -2, -1.5), (-1, -1, 2.0), (1, -1, 2.0), (-2, 0, -1.5), (0, 0, 6.0), (2, 0, -1.5), (-1, 1, 2.0), (1, 1, 2.0), (0, 2, -1.5)];

/// Malvar-He-Cutler demosaicing; outputs clamped to [0, 1] (the filters overshoot at edges).
pub fn demosaic_malvar(raw: &[f32], w: usize, h: usize, (x0, y0): (usize, usize), b: Bayer) -> [Vec<f32>; 3] {
    let at = |x: isize, y: isize| raw[reflect(y, h) * w + reflect(x, w)];
    let colour = |x: isize, y: isize| b.colour(x0 + reflect(x, w), y0 + reflect(y, h));
    let apply = |x: isize, y: isize, k: &[(isize, isize, f32)], transpose: bool| {
        k.iter().map(|&(dx, dy, wt)| if transpose { wt * at(x + dy, y + dx) } else { wt * at(x + dx, y + dy) }).sum::<f32>() / 8.0
    };
    let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0; w * h]);
    for y in 0..h as isize {
        for x in 0..w as isize {
            let i = y as usize * w + x as usize;
            let own = colour(x, y);
            for (c, plane) in out.iter_mut().enumerate() {
                let v = if c == own {
                    at(x, y)
                } else if c == 1 {
                    apply(x, y, &G_AT_RB, false)
                } else if own == 1 {
                    // A green site: the colour sits left and right of it, or above and below.
                    apply(x, y, &ROW, colour(x + 1, y) != c)
                } else {
                    apply(x, y, &DIAGONAL, false)
                };
                plane[i] = v.clamp(0.0, 1.0);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const PATTERNS: [Bayer; 4] = [Bayer::Rggb, Bayer::Bggr, Bayer::Grbg, Bayer::Gbrg];

    #[test]
    fn each_kernel_sums_to_one() {
        for k in [&G_AT_RB[..], &ROW[..], &DIAGONAL[..]] {
            assert_eq!(k.iter().map(|t| t.2).sum::<f32>(), 8.0);
        }
    }

    #[test]
    fn malvar_is_exact_on_flat_colours_and_on_linear_ramps_away_from_the_border() {
        let (w, h) = (12, 10);
        for b in PATTERNS {
            for off in [(0, 0), (1, 0), (0, 1), (3, 5)] {
                // Each channel a different plane a + bx + cy (in [0, 1]): the Laplacian terms
                // vanish, and each kernel is exact on it.
                let plane = |c: usize, x: usize, y: usize| 0.2 + 0.1 * c as f32 + 0.02 * x as f32 + 0.015 * (c as f32 - 1.0) * y as f32;
                let raw: Vec<f32> = (0..w * h).map(|i| plane(b.colour(off.0 + i % w, off.1 + i / w), i % w, i / w)).collect();
                let out = demosaic_malvar(&raw, w, h, off, b);
                for y in 2..h - 2 {
                    for x in 2..w - 2 {
                        for c in 0..3 {
                            let (got, want) = (out[c][y * w + x], plane(c, x, y));
                            assert!((got - want).abs() < 1e-5, "{b:?} {off:?} ({x}, {y}) channel {c}: {got} for {want}");
                        }
                    }
                }
                let flat: Vec<f32> = (0..w * h).map(|i| [0.8, 0.3, 0.1][b.colour(off.0 + i % w, off.1 + i / w)]).collect();
                let out = demosaic_malvar(&flat, w, h, off, b);
                for c in 0..3 {
                    assert!(out[c].iter().all(|&v| (v - [0.8, 0.3, 0.1][c]).abs() < 1e-6), "{b:?} {off:?} channel {c}");
                }
            }
        }
    }

    #[test]
    fn on_smooth_detail_with_correlated_channels_malvar_errs_less_than_bilinear() {
        // A sinusoidal pattern, each channel a scaled copy (channels correlated, as in most
        // photographs: the premise of the gradient correction); squared error inside the border.
        let (w, h) = (24, 20);
        let b = Bayer::Grbg;
        let truth = |c: usize, x: usize, y: usize| 0.5 + [0.3f32, 0.35, 0.25][c] * (0.7 * x as f32 + 0.4 * y as f32).sin();
        let raw: Vec<f32> = (0..w * h).map(|i| truth(b.colour(i % w, i / w), i % w, i / w)).collect();
        let err = |out: &[Vec<f32>; 3]| -> f32 {
            (2..h - 2)
                .flat_map(|y| (2..w - 2).map(move |x| (x, y)))
                .map(|(x, y)| (0..3).map(|c| (out[c][y * w + x] - truth(c, x, y)).powi(2)).sum::<f32>())
                .sum()
        };
        let (bil, mal) = (err(&demosaic_bilinear(&raw, w, h, (0, 0), b)), err(&demosaic_malvar(&raw, w, h, (0, 0), b)));
        assert!(mal < 0.5 * bil, "Malvar {mal}, bilinear {bil}");
    }
}
