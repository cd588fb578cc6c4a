//! Running a trained network on frames: whole or in square tiles with blended seams, on the
//! fast CPU path, plus the shipped default model. Used by `deblur`, `eval`, `figure` and the
//! benchmarks.

use crate::model::fast::{FastNet, T4};
use crate::optics::CameraKind;
use crate::Result;
use std::path::Path;

/// The model `deblur` uses without `--model`: the shipped U-Net 32 trained on the coded camera
/// (the best coded model on the held-out test clips, docs/eval.md; 7.4 MB, stored as F16).
pub const DEFAULT_MODEL: &[u8] = include_bytes!("../../models/unet32-coded/model.safetensors");

/// The model `deblur --burst` uses without `--model`: the shipped burst U-Net 32 of the coded
/// camera (models/README.md; stored as F16).
pub const DEFAULT_BURST_MODEL: &[u8] = include_bytes!("../../models/burst-unet32-coded/model.safetensors");

/// The model `deblur --camera conventional` uses: the shipped U-Net 32 trained on the
/// conventional camera (for ordinary motion blur), embedded.
pub const CONVENTIONAL_MODEL: &[u8] = include_bytes!("../../models/unet32-conventional/model.safetensors");

/// Tiling of a frame: square tiles of `tile` pixels overlapping by `overlap`.
#[derive(Debug, Clone, Copy)]
pub struct Tiling {
    pub tile: usize,
    pub overlap: usize,
}

impl Default for Tiling {
    /// A 720p frame in one pass (1280); an overlap of 64 px (the U-Net sees about 100 px around a
    /// pixel).
    fn default() -> Self {
        Tiling { tile: 1280, overlap: 64 }
    }
}

/// Tiles of at most `t` covering `0..n`, overlapping by at least `o`: as few as that allows,
/// all of one size, spread evenly (so no tile is mostly overlap). Returns the size and the
/// start positions.
fn tiles_1d(n: usize, t: usize, o: usize) -> (usize, Vec<usize>) {
    if n <= t {
        return (n, vec![0]);
    }
    let count = (n - o).div_ceil(t - o);
    let size = (n + (count - 1) * o).div_ceil(count);
    let step = size - o;
    (size, (0..count).map(|i| (i * step).min(n - size)).collect())
}

/// Blending weight of position `i` in a tile of length `len` placed at `start` in `0..n`: a
/// linear ramp over the overlap, except at the frame's own borders.
fn ramp(i: usize, len: usize, start: usize, n: usize, o: usize) -> f32 {
    let mut w = 1.0f32;
    if start > 0 && i < o {
        w = w.min((i as f32 + 0.5) / o as f32);
    }
    if start + len < n && i + o >= len {
        w = w.min((len - i) as f32 / o as f32 - 0.5 / o as f32);
    }
    w.max(1e-3)
}

/// Runs `net` on one interleaved 8-bit RGB frame, whole or in blended tiles. Each tile's
/// forward pass runs on all cores; tiles only bound the memory, and are blended in a fixed
/// order, so the result does not depend on the number of threads.
pub fn run_frame(net: &FastNet, rgb: &[u8], w: usize, h: usize, tiling: Tiling) -> Vec<u8> {
    assert_eq!(rgb.len(), w * h * 3);
    let mut out = vec![0u8; w * h * 3];
    run_rows(net, w, h, tiling, &|i, c| rgb[i * 3 + c] as f32 / 255.0, &mut |y, row| {
        for (o, v) in out[y * w * 3..(y + 1) * w * 3].iter_mut().zip(row) {
            *o = (v * 255.0).round() as u8;
        }
    });
    out
}

/// The streaming form of [`run_frame`] for any sample format: `input(pixel, channel)` gives the
/// encoded value in [0, 1] of channel `channel` (R, G, B) of pixel `y * w + x`; `emit(y, row)`
/// receives each finished output row, interleaved RGB clamped to [0, 1], top to bottom. One row
/// of tiles is held at a time, so the memory beyond the caller's buffers is bounded by the tile
/// size and the frame's width, not its height.
pub fn run_rows(
    net: &FastNet,
    w: usize,
    h: usize,
    tiling: Tiling,
    input: &(dyn Fn(usize, usize) -> f32 + Sync),
    emit: &mut dyn FnMut(usize, &[f32]),
) -> bool {
    run_rows_at(net, w, h, tiling, None, input, &mut |_, y, row| emit(y, row))
}

/// [`run_rows`] for a burst: with `times`, the network's output at each of them, from one pass
/// of the part that does not depend on the time per tile ([`FastNet::forward_burst`]);
/// `emit(k, y, row)` receives row `y` of output `k` (rows in order, outputs in order for each
/// row). `None`: the one output of [`FastNet::forward`], as output 0. Memory: the tile's pass
/// plus a row of tiles per output. Returns false when SIGINT or SIGTERM ([`crate::signal`])
/// stopped it between two tiles (the rows emitted so far are whole; the rest never come).
pub fn run_rows_at(
    net: &FastNet,
    w: usize,
    h: usize,
    tiling: Tiling,
    times: Option<&[f32]>,
    input: &(dyn Fn(usize, usize) -> f32 + Sync),
    emit: &mut dyn FnMut(usize, usize, &[f32]),
) -> bool {
    let outputs = times.map_or(1, <[f32]>::len);
    let (t, o) = (tiling.tile.max(16), tiling.overlap.min(tiling.tile / 2));
    let ((tw, xs), (th, ys)) = (tiles_1d(w, t, o), tiles_1d(h, t, o));
    // The blended rows from `base` on (RGB sums per output, and weights); rows above `base`
    // are emitted.
    let (mut base, mut accs, mut wsum) = (0usize, vec![Vec::<f32>::new(); outputs], Vec::<f32>::new());
    for (k, &y0) in ys.iter().enumerate() {
        let rows = y0 + th - base;
        accs.iter_mut().for_each(|acc| acc.resize(rows * w * 3, 0.0));
        wsum.resize(rows * w, 0.0);
        for &x0 in &xs {
            if crate::signal::interrupted() {
                return false;
            }
            let mut v = vec![0.0f32; 3 * tw * th];
            for c in 0..3 {
                for y in 0..th {
                    for x in 0..tw {
                        v[c * tw * th + y * tw + x] = input((y0 + y) * w + x0 + x, c);
                    }
                }
            }
            let x = T4::new(1, 3, th, tw, v);
            let outs: Vec<T4> = match times {
                Some(ts) => net.forward_burst(&x, ts),
                None => vec![net.forward(&x)],
            };
            drop(x);
            for y in 0..th {
                let wy = ramp(y, th, y0, h, o);
                let r = y0 + y - base;
                for x in 0..tw {
                    let wgt = wy * ramp(x, tw, x0, w, o);
                    let p = r * w + x0 + x;
                    wsum[p] += wgt;
                    for (acc, out) in accs.iter_mut().zip(&outs) {
                        for c in 0..3 {
                            acc[p * 3 + c] += wgt * out.d[c * tw * th + y * tw + x];
                        }
                    }
                }
            }
        }
        // Rows above the next tile row's start get nothing more.
        let done = ys.get(k + 1).map_or(h, |&next| next) - base;
        let mut row = vec![0.0f32; w * 3];
        for r in 0..done {
            for (j, acc) in accs.iter().enumerate() {
                for (i, v) in row.iter_mut().enumerate() {
                    *v = (acc[r * w * 3 + i] / wsum[r * w + i / 3]).clamp(0.0, 1.0);
                }
                emit(j, base + r, &row);
            }
        }
        accs.iter_mut().for_each(|acc| drop(acc.drain(..done * w * 3)));
        wsum.drain(..done * w);
        base += done;
    }
    true
}

/// [`run_frame`] at each of `times`: one interleaved 8-bit RGB frame per time, in order.
pub fn run_frame_burst(net: &FastNet, rgb: &[u8], w: usize, h: usize, tiling: Tiling, times: &[f32]) -> Vec<Vec<u8>> {
    assert_eq!(rgb.len(), w * h * 3);
    let mut outs = vec![vec![0u8; w * h * 3]; times.len()];
    run_rows_at(net, w, h, tiling, Some(times), &|i, c| rgb[i * 3 + c] as f32 / 255.0, &mut |k, y, row| {
        for (o, v) in outs[k][y * w * 3..(y + 1) * w * 3].iter_mut().zip(row) {
            *o = (v * 255.0).round() as u8;
        }
    });
    outs
}

/// The library form of `deblur` and `deblur --burst` on one image held as planes: `chw` is
/// (3, H, W) encoded values in [0, 1]; the network runs in blended tiles as the command runs
/// it, once per image, or with `times` once for the part that does not depend on the time. The
/// outputs (one, or one per time, in order) are (3, H, W) clamped to [0, 1]. The Python
/// package's `deblur_burst` is this.
pub fn deblur_planes(net: &FastNet, chw: &[f32], w: usize, h: usize, tiling: Tiling, times: Option<&[f32]>) -> Vec<Vec<f32>> {
    assert_eq!(chw.len(), 3 * w * h);
    let mut outs = vec![vec![0.0f32; 3 * w * h]; times.map_or(1, <[f32]>::len)];
    let plane = w * h;
    run_rows_at(net, w, h, tiling, times, &|i, c| chw[c * plane + i], &mut |k, y, row| {
        for (x, px) in row.chunks_exact(3).enumerate() {
            for (c, &v) in px.iter().enumerate() {
                outs[k][c * plane + y * w + x] = v;
            }
        }
    });
    outs
}

/// Loads `--model`, or the embedded default.
///
/// # Errors
/// As [`Weights::read`](crate::model::weights::Weights::read).
pub fn load(model: Option<&Path>) -> Result<(FastNet, String)> {
    use crate::model::weights::Weights;
    let (w, name) = match model {
        Some(p) => {
            let w = Weights::read(p)?;
            let name = format!("{} ({})", p.display(), w.arch.name());
            (w, name)
        }
        None => {
            let w = Weights::from_bytes(DEFAULT_MODEL, "embedded models/unet32-coded")?;
            let name = format!("models/unet32-coded ({})", w.arch.name());
            (w, name)
        }
    };
    Ok((FastNet::from_weights(w), name))
}

/// Loads a burst model for `deblur --burst`: `--model`, or the shipped coded burst U-Net.
///
/// # Errors
/// As [`load`]; a model that was not trained for bursts is refused by name (a usage error).
pub fn load_burst(model: Option<&Path>) -> Result<(FastNet, String)> {
    load_for(model, None, true)
}

/// The model for a camera's captures: `model` when given, else the shipped one of `camera`
/// (default: the coded camera): the coded U-Nets and the conventional single-frame U-Net are
/// embedded; the conventional burst U-Net is read from the repository's `models/`. With
/// `burst`, a model that was not trained for bursts is refused by name.
///
/// # Errors
/// As [`load`]; no shipped model for that camera (the flutter, parabolic and focus-sweep
/// cameras), or a single-frame model for a burst (usage errors).
pub fn load_for(model: Option<&Path>, camera: Option<CameraKind>, burst: bool) -> Result<(FastNet, String)> {
    use crate::model::weights::Weights;
    let embedded = |bytes: &[u8], name: &str| -> Result<(FastNet, String)> {
        let w = Weights::from_bytes(bytes, &format!("embedded {name}"))?;
        let label = format!("{name} ({})", w.arch.name());
        Ok((FastNet::from_weights(w), label))
    };
    let (net, name) = match (model, camera.unwrap_or(CameraKind::PhaseCoded), burst) {
        (Some(p), _, _) => load(Some(p))?,
        (None, CameraKind::PhaseCoded, false) => embedded(DEFAULT_MODEL, "models/unet32-coded")?,
        (None, CameraKind::PhaseCoded, true) => embedded(DEFAULT_BURST_MODEL, "models/burst-unet32-coded")?,
        (None, CameraKind::Conventional, false) => embedded(CONVENTIONAL_MODEL, "models/unet32-conventional")?,
        (None, CameraKind::Conventional, true) => {
            let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("models/burst-unet32-conventional");
            if !p.join("model.safetensors").is_file() {
                return Err(crate::Error::Usage(format!(
                    "{}: not found (the conventional burst model is not embedded; pass --model)",
                    p.display()
                )));
            }
            load(Some(&p))?
        }
        (None, other, _) => {
            return Err(crate::Error::Usage(format!(
                "no model ships for the {} camera (only phase_coded and conventional); pass --model",
                other.name()
            )))
        }
    };
    if burst && !net.is_burst() {
        return Err(crate::Error::Usage(format!(
            "{name}: a single-frame model; --burst needs a model trained for bursts (`model.type = \"burst_unet\"`, or models/burst-unet32-coded)"
        )));
    }
    Ok((net, name))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_frame_with_the_overlap() {
        assert_eq!(tiles_1d(100, 128, 16), (100, vec![0]));
        for (n, t, o) in [(300, 128, 32), (720, 256, 32), (1280, 384, 32), (1081, 200, 17)] {
            let (size, s) = tiles_1d(n, t, o);
            assert!(size <= t && s[0] == 0 && s.last().unwrap() + size == n, "{n} {t} {o}: {size} {s:?}");
            assert!(s.windows(2).all(|p| p[0] + size >= p[1] + o), "{n} {t} {o}: overlap below {o}: {s:?}");
        }
        // Evenly spread: 720 in tiles of at most 256 needs 4, each 204 (not 3 of 256 and a sliver).
        assert_eq!(tiles_1d(720, 256, 32), (204, vec![0, 172, 344, 516]));
    }
}
