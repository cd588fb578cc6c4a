//! Imaging a window of N linear frames through a camera: `B = sum_k w_k (PSF_k * S_k)` (weights
//! inside the rendered kernels), by real FFTs with the products summed in the frequency domain
//! and one inverse per channel. Borders are mirrored. Whole frames, regions, or patches plus the
//! kernel margin (the same pixels as blurring the whole frame and cropping).
//!
//! Files: `mod.rs` ([`Blurrer`]: kernels, factorisation, caches, the public calls), `tiles.rs`
//! (tile planning and the per-tile FFT work), `tests.rs` (all of it against direct convolution).
mod tiles;

use crate::frame::{Cols, Frame, PREFETCH_ROWS};
use crate::optics::fft::{fast_size, reflect, FftConv, STRIP};
use crate::optics::lowrank::{factorise_within, LowRank};
use crate::optics::{Camera, SubframeKernel};
use num_complex::Complex32;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use tiles::*;
pub use tiles::{margin_of, plan_tiles, TILE_FFT_MAX};

/// The numerical part of imaging a window: kernels, their low-rank factorisation per channel,
/// spectra caches and worker FFT plans.
///
/// Per channel the N kernels are factorised as `K_k = sum_r a_kr B_r` (see
/// [`crate::optics::lowrank`]), so a window costs R forward FFTs per channel instead of N:
/// `sum_k K_k * S_k = sum_r B_r * (sum_k a_kr S_k)`. R is 1 for the conventional and flutter
/// cameras (one kernel shape), 5 for parabolic with N = 9 (t^2 repeats shifts), and 4 for the
/// coded camera at the default error budget of 0.25 of an 8-bit level (3 to 4 at 0.6 to 2).
pub struct Blurrer {
    pub camera: Arc<Camera>,
    pub n: usize,
    kernels: Arc<Vec<SubframeKernel>>,
    pub margin: usize,
    threads: usize,
    /// A pool of `threads` workers when asked for a count; else rayon's global pool.
    pool: Option<Arc<rayon::ThreadPool>>,
    /// Per channel: basis kernels (rendered, `(2 margin + 1)^2`) and coefficients `[k][r]`.
    factors: [LowRank; 3],
    /// Basis spectra per padded size: [c][r].
    spectra: HashMap<(usize, usize), Arc<Spectra>>,
    /// FFT plans per padded size, one per worker.
    convs: HashMap<(usize, usize), Vec<Mutex<FftConv>>>,
    /// Reused buffers per padded size.
    work: HashMap<(usize, usize), Workspace>,
    /// Per-worker buffers of tiles and patches (one worker each).
    patch_work: HashMap<(usize, usize), Vec<Mutex<TileWork>>>,
}

/// Buffers kept between windows: no page faults on the hot path.
struct Workspace {
    /// Combined images per channel and rank, `hp x wp`; zero outside the region.
    combined: [Vec<Vec<f32>>; 3],
    /// Products per channel and rank.
    slots: [Vec<Vec<Complex32>>; 3],
    /// Each channel's inverse transform, `hp x wp` (kept, like the rest, between windows).
    full: [Vec<f32>; 3],
}

/// The basis spectra of one padded size, `[c][r]`, and where a basis kernel is point-symmetric
/// (`k(x, y) = k(-x, -y)`: every camera whose sub-frame kernels do not move within the
/// exposure, the coded one included) its real part alone. Such a spectrum is real; the
/// imaginary parts an FFT leaves are rounding noise, so they are set to exactly 0 in `full` too,
/// and a product with `real` gives the same values as the complex product with `full`.
struct Spectra {
    full: [Vec<Vec<Complex32>>; 3],
    real: [Vec<Option<Vec<f32>>>; 3],
}

/// Whether a square kernel is point-symmetric about its centre to within `1e-6` of its largest
/// value (then its spectrum's imaginary part is at most that much of the real one's scale).
fn point_symmetric(kernel: &[f32]) -> bool {
    let peak = kernel.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    kernel.iter().zip(kernel.iter().rev()).all(|(a, b)| (a - b).abs() <= 1e-6 * peak)
}

/// Row bands per channel when building the combined images (parallel work units).
const BANDS: usize = 8;

impl Blurrer {
    /// `max_error`: the RMS error the factorisation may add to a blurred window, in 8-bit levels
    /// of linear light, as a bound over all sub-frames in [0, 1] ([`crate::optics::lowrank`]);
    /// 0 keeps every direction: exact up to rounding.
    ///
    /// # Errors
    /// A camera whose psi schedule does not fit N.
    pub fn new(camera: Arc<Camera>, n: usize, threads: usize, max_error: f64) -> crate::Result<Blurrer> {
        let kernels = camera.window(n)?;
        let margin = margin_of(&kernels);
        let pool = match threads {
            0 => None,
            t => Some(Arc::new(
                rayon::ThreadPoolBuilder::new().num_threads(t).build().map_err(|source| crate::Error::Threads { what: "blur", source })?,
            )),
        };
        let threads = pool.as_ref().map_or_else(rayon::current_num_threads, |p| p.current_num_threads());
        // The three channels' factorisations side by side (each is independent).
        let factors = install(&pool, || {
            use rayon::prelude::*;
            let f: Vec<LowRank> = (0..3)
                .into_par_iter()
                .map(|c| {
                    let rendered: Vec<Vec<f32>> = kernels.iter().map(|k| k.render(c, margin)).collect();
                    factorise_within(&rendered, max_error)
                })
                .collect();
            let Ok(f) = <[LowRank; 3]>::try_from(f) else { unreachable!("three channels") };
            f
        });
        Ok(Blurrer {
            camera,
            n,
            kernels,
            margin,
            threads,
            pool,
            factors,
            spectra: HashMap::new(),
            convs: HashMap::new(),
            work: HashMap::new(),
            patch_work: HashMap::new(),
        })
    }

    pub fn kernels(&self) -> &[SubframeKernel] {
        &self.kernels
    }

    /// Rank kept per channel (R, G, B).
    pub fn ranks(&self) -> [usize; 3] {
        std::array::from_fn(|c| self.factors[c].basis.len())
    }

    /// Per channel, the bound on the RMS error the kept ranks add to a window, in 8-bit levels
    /// of linear light (0: exact).
    pub fn error_bounds(&self) -> [f64; 3] {
        std::array::from_fn(|c| self.factors[c].bound_levels)
    }

    fn prepare(&mut self, hp: usize, wp: usize) -> Arc<Spectra> {
        let threads = self.threads;
        self.convs.entry((hp, wp)).or_insert_with(|| (0..threads).map(|_| Mutex::new(FftConv::new(hp, wp))).collect());
        if let Some(s) = self.spectra.get(&(hp, wp)) {
            return s.clone();
        }
        let factors = &self.factors;
        let convs = &self.convs[&(hp, wp)];
        let tasks: Vec<(usize, usize)> = (0..3).flat_map(|c| (0..factors[c].basis.len()).map(move |r| (c, r))).collect();
        let results: Vec<Vec<Complex32>> = install(&self.pool, || {
            use rayon::prelude::*;
            tasks.par_iter().map(|&(c, r)| worker(convs).lock().expect("conv lock").kernel_spectrum(&factors[c].basis[r])).collect()
        });
        let mut it = results.into_iter();
        let mut full: [Vec<Vec<Complex32>>; 3] =
            std::array::from_fn(|c| (0..factors[c].basis.len()).map(|_| it.next().expect("one per basis")).collect());
        let real = std::array::from_fn(|c| {
            full[c]
                .iter_mut()
                .zip(&factors[c].basis)
                .map(|(spec, kernel)| {
                    point_symmetric(kernel).then(|| {
                        spec.iter_mut().for_each(|v| v.im = 0.0);
                        spec.iter().map(|v| v.re).collect()
                    })
                })
                .collect()
        });
        let arc = Arc::new(Spectra { full, real });
        self.spectra.insert((hp, wp), arc.clone());
        arc
    }

    fn workspace(ranks: [usize; 3], hp: usize, wp: usize) -> Workspace {
        Workspace {
            // Written whole every window (the region, then zeros): the forward transforms use
            // them as scratch.
            combined: std::array::from_fn(|c| (0..ranks[c]).map(|_| vec![0.0f32; hp * wp]).collect()),
            slots: std::array::from_fn(|c| (0..ranks[c]).map(|_| vec![Complex32::new(0.0, 0.0); hp * (wp / 2 + 1)]).collect()),
            full: std::array::from_fn(|_| vec![0.0f32; hp * wp]),
        }
    }

    /// Blurs the `rw x rh` region at (x0, y0) of a window of linear frames (mirrored borders),
    /// all workers on this one region; returns planar linear RGB of that region.
    pub fn blur_region(&mut self, frames: &[Arc<Frame>], x0: isize, y0: isize, rw: usize, rh: usize) -> [Vec<f32>; 3] {
        assert_eq!(frames.len(), self.n);
        let m = self.margin;
        let (hp, wp) = (fast_size(rh + 2 * m), fast_size(rw + 2 * m));
        let spectra = self.prepare(hp, wp);
        let ranks = self.ranks();
        let ws = self.work.entry((hp, wp)).or_insert_with(|| Blurrer::workspace(ranks, hp, wp));
        let (factors, convs) = (&self.factors, &self.convs[&(hp, wp)]);
        install(&self.pool, || blur_core(factors, &spectra, convs, ws, frames, m, (x0, y0, rw, rh)))
    }

    /// Blurs `size x size` patches at each top-left corner: patches are spread over the workers,
    /// each blurring whole patches on its own (no synchronisation inside a small patch).
    pub fn blur_patches(&mut self, frames: &[Arc<Frame>], corners: &[(usize, usize)], size: usize) -> Vec<[Vec<f32>; 3]> {
        let rects: Vec<_> = corners.iter().map(|&(x, y)| (x, y, size, size)).collect();
        self.blur_rects(frames, &rects, (size, size))
    }

    /// Blurs the whole frame in tiles, overlap-save: each tile is transformed with the kernel
    /// margin around it (mirrored at the frame's borders) and only the tile is kept, so it equals
    /// the whole-frame blur up to float rounding. Tiles are spread over the workers, each with its
    /// own cache-sized transforms and buffers; memory is a few tiles per worker instead of
    /// whole-frame planes per channel and rank. The result does not depend on the number of
    /// workers. `tile`: 0 plans the tiles ([`plan_tiles`]), else square tiles of at most
    /// `tile x tile`. A frame that fits in one tile is one plane, all workers on it.
    pub fn blur_tiled(&mut self, frames: &[Arc<Frame>], tile: usize) -> [Vec<f32>; 3] {
        let (w, h) = (frames[0].width, frames[0].height);
        let (tw, th) = if tile == 0 { plan_tiles(w, h, self.margin) } else { (tile.clamp(1, w), tile.clamp(1, h)) };
        if w <= tw && h <= th {
            // One tile: the whole plane with every worker on it.
            return self.blur_region(frames, 0, 0, w, h);
        }
        let rects: Vec<_> =
            (0..h).step_by(th).flat_map(|y| (0..w).step_by(tw).map(move |x| (x, y, tw.min(w - x), th.min(h - y)))).collect();
        // Each tile goes into the frame as soon as it is done: no second frame's worth of tiles.
        let out: Mutex<[Vec<f32>; 3]> = Mutex::new(std::array::from_fn(|_| vec![0.0f32; w * h]));
        self.blur_rects_with(frames, &rects, (tw, th), |i, c, p| {
            let (x, y, rw, rh) = rects[i];
            let o = &mut out.lock().expect("frame planes")[c];
            for yy in 0..rh {
                o[(y + yy) * w + x..(y + yy) * w + x + rw].copy_from_slice(&p[yy * rw..(yy + 1) * rw]);
            }
        });
        out.into_inner().expect("frame planes")
    }

    /// Blurs each `(x, y, w, h)` rectangle (at most `max` = (w, h) in size) on its own, the
    /// rectangles spread over the workers; all share one transform size. Results in order.
    fn blur_rects(&mut self, frames: &[Arc<Frame>], rects: &[(usize, usize, usize, usize)], max: (usize, usize)) -> Vec<[Vec<f32>; 3]> {
        let done: Mutex<Vec<[Vec<f32>; 3]>> = Mutex::new(vec![Default::default(); rects.len()]);
        self.blur_rects_with(frames, rects, max, |i, c, p| done.lock().expect("results")[i][c] = p);
        done.into_inner().expect("results")
    }

    /// [`Blurrer::blur_rects`], handing rectangle `i`'s plane of channel `c` to `emit(i, c, plane)`
    /// on the worker that blurred it. The work is one (rectangle, channel) per task: with whole
    /// rectangles (six tiles of a 720p frame on two workers) the last one of a window kept one
    /// worker busy alone for 7 to 10 ms of every 55.
    fn blur_rects_with(
        &mut self,
        frames: &[Arc<Frame>],
        rects: &[(usize, usize, usize, usize)],
        max: (usize, usize),
        emit: impl Fn(usize, usize, Vec<f32>) + Sync,
    ) {
        assert_eq!(frames.len(), self.n);
        let m = self.margin;
        let (hp, wp) = (fast_size(max.1 + 2 * m), fast_size(max.0 + 2 * m));
        let spectra = self.prepare(hp, wp);
        let ranks = self.ranks();
        let threads = self.threads;
        let convs = &self.convs[&(hp, wp)];
        let most = ranks.into_iter().max().unwrap_or(0);
        let pool = self.patch_work.entry((hp, wp)).or_insert_with(|| {
            let conv = convs[0].lock().expect("conv lock");
            (0..threads).map(|_| Mutex::new(TileWork::new(most, &conv))).collect()
        });
        let factors = &self.factors;
        // One channel of one rectangle per task: each blurs it with its worker's plan and buffers.
        install(&self.pool, || {
            use rayon::prelude::*;
            (0..rects.len() * 3).into_par_iter().for_each(|t| {
                let (k, c) = (t / 3, t % 3);
                let (x, y, rw, rh) = rects[k];
                let i = rayon::current_thread_index().unwrap_or(0) % pool.len();
                let plane = {
                    let mut tw = pool[i].lock().expect("workspace");
                    let mut conv = convs[i % convs.len()].lock().expect("conv lock");
                    blur_tile(factors, &spectra, &mut conv, &mut tw, frames, m, (x as isize, y as isize, rw, rh), c)
                };
                emit(k, c, plane);
            })
        })
    }
}

/// Crops `rw x rh` at (x, y) out of planar planes of width `w`.
pub fn crop(p: &[Vec<f32>; 3], w: usize, x: usize, y: usize, rw: usize, rh: usize) -> [Vec<f32>; 3] {
    std::array::from_fn(|c| (0..rh).flat_map(|yy| p[c][(y + yy) * w + x..(y + yy) * w + x + rw].iter().copied()).collect())
}

#[cfg(test)]
mod tests;
