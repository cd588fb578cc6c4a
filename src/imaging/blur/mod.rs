//! Imaging a window of N linear frames through a camera: `B = sum_k w_k (PSF_k * S_k)` (weights
//! inside the rendered kernels), by real FFTs with the products summed in the frequency domain
//! and one inverse per channel. Borders are mirrored. Whole frames, regions, or patches plus the
//! kernel margin (the same pixels as blurring the whole frame and cropping).
use crate::frame::{Cols, Frame, PREFETCH_ROWS};
use crate::optics::fft::{fast_size, reflect, FftConv, STRIP};
use crate::optics::lowrank::{factorise_within, LowRank};
use crate::optics::{Camera, SubframeKernel};
use num_complex::Complex32;
use std::collections::HashMap;
use std::sync::{Arc, Mutex};

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

/// Largest side of a planned tile's padded transform. A 512 x 512 transform's spectrum (1 MB)
/// stays in a core's cache; at 720p one whole-plane transform (864 x 1440 or 800 x 1350) cost
/// 1.7 to 2.9 times as much per pixel as six of 432 x 512 (`bench generate`, same run).
pub const TILE_FFT_MAX: usize = 512;

/// The tile size (width, height) of `tile = 0` for a `w x h` frame and kernel `margin`: of the
/// grids whose padded transforms ([`fast_size`] of tile plus both margins) are at most
/// [`TILE_FFT_MAX`] on each side, the one with the least transformed area in all (fewer tiles
/// on a tie). A frame no grid fits (a margin near the limit) is one plane. It depends on the
/// frame and the kernels only, never on the thread count, so the output does not either.
pub fn plan_tiles(w: usize, h: usize, margin: usize) -> (usize, usize) {
    let sides = |len: usize| -> Vec<(usize, usize, usize)> {
        // (tile side, tiles along the axis, padded side) for every distinct tile side.
        let mut v: Vec<(usize, usize, usize)> = Vec::new();
        for parts in 1..=len.max(1) {
            let t = len.max(1).div_ceil(parts);
            let p = fast_size(t + 2 * margin);
            if v.last().is_some_and(|l| l.0 == t) {
                continue;
            }
            if p <= TILE_FFT_MAX {
                v.push((t, len.max(1).div_ceil(t), p));
            }
            if t <= 16 {
                break;
            }
        }
        v
    };
    let (xs, ys) = (sides(w), sides(h));
    let mut best: Option<(usize, usize, usize, usize)> = None;
    for &(tw, nx, wp) in &xs {
        for &(th, ny, hp) in &ys {
            let cand = (nx * ny * wp * hp, nx * ny, tw, th);
            if best.is_none_or(|b| (cand.0, cand.1) < (b.0, b.1)) {
                best = Some(cand);
            }
        }
    }
    best.map_or((w, h), |b| (b.2, b.3))
}

/// The margin a window's kernels read around each pixel (their largest half extent).
pub fn margin_of(kernels: &[SubframeKernel]) -> usize {
    kernels.iter().map(|k| k.half_extent()).max().unwrap_or(0)
}

/// Runs `f` in the blurrer's own pool, or in rayon's global one.
fn install<R: Send>(pool: &Option<Arc<rayon::ThreadPool>>, f: impl FnOnce() -> R + Send) -> R {
    match pool {
        Some(p) => p.install(f),
        None => f(),
    }
}

/// The FFT plan of the current worker (one per rayon thread, so never contended).
fn worker(convs: &[Mutex<FftConv>]) -> &Mutex<FftConv> {
    &convs[rayon::current_thread_index().unwrap_or(0) % convs.len()]
}

/// The three phases on one region: combined images, forward FFTs times basis spectra, one
/// inverse per channel. `region` is (x0, y0, rw, rh). This is the path of every worker on one
/// region (a frame that fits in one tile, [`Blurrer::blur_region`]); tiles and patches, one
/// worker each, take [`blur_tile`], which gives the same bits.
fn blur_core(
    factors: &[LowRank; 3],
    spectra: &Spectra,
    convs: &[Mutex<FftConv>],
    ws: &mut Workspace,
    frames: &[Arc<Frame>],
    m: usize,
    region: (isize, isize, usize, usize),
) -> [Vec<f32>; 3] {
    let (x0, y0, rw, rh) = region;
    let wp = convs[0].lock().expect("conv").wp;
    let (fw, fh) = (frames[0].width, frames[0].height);
    let (ew, eh) = (rw + 2 * m, rh + 2 * m);
    let (ex, ey) = (x0 - m as isize, y0 - m as isize);
    // Several plans: work spread over rayon's workers; one: all of it here (a patch).
    let parallel = convs.len() > 1;
    let workers = convs.len();
    // Phase 1: the combined images sum_k a_kr S_k of every channel and rank, by row bands;
    // each job owns its rows of every rank's buffer. The region fills `ew` columns of the first
    // `eh` rows; the rest of each buffer is zeroed every window, because the forward transforms
    // below use the buffers as scratch.
    let bands = if workers == 1 { 1 } else { BANDS };
    let band_rows = eh.div_ceil(bands);
    let mut jobs: Vec<(usize, usize, Vec<&mut [f32]>)> = Vec::new();
    for (c, bufs) in ws.combined.iter_mut().enumerate() {
        let mut per_rank: Vec<_> = bufs
            .iter_mut()
            .map(|b| {
                let (region, below) = b.split_at_mut(eh * wp);
                below.fill(0.0);
                region.chunks_mut(band_rows * wp)
            })
            .collect();
        for band in 0..eh.div_ceil(band_rows) {
            jobs.push((c, band, per_rank.iter_mut().map(|it| it.next().expect("band")).collect()));
        }
    }
    let span = if ex >= 0 && ex as usize + ew <= fw { Cols::From(ex as usize) } else { Cols::Mirror(ex) };
    let n = frames.len();
    let phase1 = |(c, band, mut outs): (usize, usize, Vec<&mut [f32]>)| {
        // The N frames' linear rows side by side (N x ew, in the first-level cache), then
        // every rank's row from them in one pass.
        let mut rows = vec![0.0f32; n * ew];
        let a = coefficients(&factors[c]);
        let y_lo = band * band_rows;
        let rows_here = outs[0].len() / wp;
        let px = ((ex.max(0) as usize).min(fw), ((ex + ew as isize).max(0) as usize).min(fw));
        let src = RowSource { frames, c, span, px };
        for ly in 0..rows_here {
            let sy = reflect(ey + (y_lo + ly) as isize, fh);
            let ahead = (ly + PREFETCH_ROWS < rows_here).then(|| reflect(ey + (y_lo + ly + PREFETCH_ROWS) as isize, fh));
            src.combined_row(sy, ahead, &mut rows, &a, &mut outs, ly * wp, wp);
        }
    };
    if parallel {
        use rayon::prelude::*;
        jobs.into_par_iter().for_each(phase1);
    } else {
        jobs.into_iter().for_each(phase1);
    }
    // Phase 2: one forward FFT per (channel, rank), in place, times the basis spectrum.
    let mut jobs: Vec<(&mut [f32], &[Complex32], &mut Vec<Complex32>)> = Vec::new();
    for (c, (bufs, slots)) in ws.combined.iter_mut().zip(ws.slots.iter_mut()).enumerate() {
        for (r, (img, slot)) in bufs.iter_mut().zip(slots.iter_mut()).enumerate() {
            jobs.push((img, &spectra.full[c][r], slot));
        }
    }
    let phase2 = |(img, spec, slot): (&mut [f32], &[Complex32], &mut Vec<Complex32>)| {
        worker(convs).lock().expect("conv lock").forward_mul_in_place(img, spec, slot);
    };
    if parallel {
        use rayon::prelude::*;
        jobs.into_par_iter().for_each(phase2);
    } else {
        jobs.into_iter().for_each(phase2);
    }
    // Phase 3: sum the ranks in order (deterministic), one inverse per channel.
    // The slots are overwritten every window, so the ranks are summed into slot 0 in place.
    let phase3 = |(ranks, full): (&mut Vec<Vec<Complex32>>, &mut Vec<f32>)| -> Vec<f32> {
        let (first, rest) = ranks.split_first_mut().expect("rank 0");
        for slot in rest.iter() {
            mul_acc_add(first, slot);
        }
        worker(convs).lock().expect("conv lock").inverse(first, full);
        let mut o = Vec::with_capacity(rw * rh);
        for y in 0..rh {
            o.extend_from_slice(&full[(y + m) * wp + m..(y + m) * wp + m + rw]);
        }
        o
    };
    let outs: Vec<Vec<f32>> = if parallel {
        use rayon::prelude::*;
        ws.slots.par_iter_mut().zip(ws.full.par_iter_mut()).map(phase3).collect()
    } else {
        ws.slots.iter_mut().zip(ws.full.iter_mut()).map(phase3).collect()
    };
    let mut it = outs.into_iter();
    std::array::from_fn(|_| it.next().expect("3 channels"))
}

/// The coefficients a_kr of a channel's factorisation as f32, frame-major (frame k's for every
/// rank), as [`combine_rows`] reads them.
fn coefficients(f: &LowRank) -> Vec<f32> {
    f.coeffs.iter().flat_map(|ck| ck.iter().map(|&v| v as f32)).collect()
}

/// Where the combined images of one channel read their rows: the window's frames, the channel,
/// the columns (`span`, `ew` wide) and the frame columns they lie in (`px`, for prefetching).
struct RowSource<'a> {
    frames: &'a [Arc<Frame>],
    c: usize,
    span: Cols<'a>,
    px: (usize, usize),
}

impl RowSource<'_> {
    /// One row of every rank's combined image: the N frames' linear rows at frame row `sy` side
    /// by side in `rows` (N x ew, in the first-level cache), then [`combine_rows`] into row `at`
    /// of `outs`. `ahead`: a frame row to prefetch for a later call.
    #[allow(clippy::too_many_arguments)]
    fn combined_row(&self, sy: usize, ahead: Option<usize>, rows: &mut [f32], a: &[f32], outs: &mut [&mut [f32]], at: usize, wp: usize) {
        if let Some(ahead) = ahead {
            self.frames.iter().for_each(|f| f.prefetch_row(self.c, ahead, self.px.0, self.px.1));
        }
        let ew = rows.len() / self.frames.len();
        for (frame, row) in self.frames.iter().zip(rows.chunks_exact_mut(ew)) {
            frame.linear_row(self.c, sy, self.span, row);
        }
        combine_rows(a, rows, ew, outs, at, wp);
    }
}

/// Buffers of one worker's [`blur_tile`], kept between windows (no page faults on the hot path).
struct TileWork {
    /// Per rank: a strip of combined rows (`STRIP x wp`), the row transforms' input and scratch.
    lines: Vec<Vec<f32>>,
    /// Per rank: its transform in the transposed layout (`wc` columns of `hp`).
    cols: Vec<Vec<Complex32>>,
    /// One channel's products summed over the ranks, then inverse-transformed by columns.
    acc: Vec<Complex32>,
    /// A strip of inverse-transformed rows (`STRIP x wp`).
    back: Vec<f32>,
    /// The N frames' linear rows of a strip's row, side by side (N x the region's width).
    frame_rows: Vec<f32>,
}

impl TileWork {
    fn new(ranks: usize, conv: &FftConv) -> TileWork {
        let (hp, wp, wc) = (conv.hp, conv.wp, conv.wc());
        TileWork {
            lines: (0..ranks).map(|_| vec![0.0f32; STRIP * wp]).collect(),
            cols: (0..ranks).map(|_| vec![Complex32::new(0.0, 0.0); wc * hp]).collect(),
            acc: vec![Complex32::new(0.0, 0.0); wc * hp],
            back: vec![0.0f32; STRIP * wp],
            frame_rows: Vec::new(),
        }
    }
}

/// Columns per group in [`blur_tile`]'s column pass: every rank's group, the basis spectra's
/// and the sum stay in the second-level cache (8 columns of 432 are 28 KB each).
const COLUMN_GROUP: usize = 8;

/// [`blur_core`] for channel `c` on one worker, in an order that keeps its data in the caches:
/// each strip of [`STRIP`] rows is combined, row-transformed while it is in the first-level
/// cache and scattered into the ranks' column buffers; then each group of columns is
/// transformed, multiplied by the basis spectra, summed over the ranks in order and
/// inverse-transformed while it stays in the second-level cache; last, only the rows of the
/// region itself are inverse-transformed. The combined images (R whole padded planes per
/// channel) are never written, and the inverse skips the margin's rows. The same operations in
/// the same order as [`blur_core`], so the same bits.
#[allow(clippy::too_many_arguments)]
fn blur_tile(
    factors: &[LowRank; 3],
    spectra: &Spectra,
    conv: &mut FftConv,
    tw: &mut TileWork,
    frames: &[Arc<Frame>],
    m: usize,
    region: (isize, isize, usize, usize),
    c: usize,
) -> Vec<f32> {
    let (x0, y0, rw, rh) = region;
    let (hp, wp, wc) = (conv.hp, conv.wp, conv.wc());
    let (fw, fh) = (frames[0].width, frames[0].height);
    let (ew, eh) = (rw + 2 * m, rh + 2 * m);
    let (ex, ey) = (x0 - m as isize, y0 - m as isize);
    let span = if ex >= 0 && ex as usize + ew <= fw { Cols::From(ex as usize) } else { Cols::Mirror(ex) };
    let src_px = ((ex.max(0) as usize).min(fw), ((ex + ew as isize).max(0) as usize).min(fw));
    // The N frames' rows of the region, side by side (kept by the worker: no allocation per task).
    let rows = &mut tw.frame_rows;
    rows.resize(frames.len() * ew, 0.0);
    let ranks = factors[c].basis.len();
    let a = coefficients(&factors[c]);
    let src = RowSource { frames, c, span, px: src_px };
    // Rows: combined, transformed and scattered a strip at a time.
    for s0 in (0..hp).step_by(STRIP) {
        let ns = STRIP.min(hp - s0);
        let mut outs: Vec<&mut [f32]> = tw.lines[..ranks].iter_mut().map(|l| &mut l[..ns * wp]).collect();
        for i in 0..ns {
            let ly = s0 + i;
            if ly < eh {
                let sy = reflect(ey + ly as isize, fh);
                let ahead = (ly + PREFETCH_ROWS < eh).then(|| reflect(ey + (ly + PREFETCH_ROWS) as isize, fh));
                src.combined_row(sy, ahead, rows, &a, &mut outs, i * wp, wp);
            } else {
                outs.iter_mut().for_each(|o| o[i * wp..(i + 1) * wp].fill(0.0));
            }
        }
        for (line, col) in tw.lines[..ranks].iter_mut().zip(&mut tw.cols) {
            conv.forward_rows(&mut line[..ns * wp], col, s0);
        }
    }
    // Columns: forward, times the basis spectrum, summed over the ranks, inverse.
    for j0 in (0..wc).step_by(COLUMN_GROUP) {
        let g = j0 * hp..(j0 + COLUMN_GROUP).min(wc) * hp;
        let acc = &mut tw.acc[g.clone()];
        for (r, col) in tw.cols[..ranks].iter_mut().enumerate() {
            let col = &mut col[g.clone()];
            conv.columns(col, false);
            match &spectra.real[c][r] {
                Some(k) => mul_real(acc, col, &k[g.clone()], r > 0),
                None => {
                    let k = &spectra.full[c][r][g.clone()];
                    if r == 0 {
                        acc.iter_mut().zip(col.iter()).zip(k).for_each(|((o, v), k)| *o = v * k);
                    } else {
                        acc.iter_mut().zip(col.iter()).zip(k).for_each(|((o, v), k)| *o += v * k);
                    }
                }
            }
        }
        conv.columns(acc, true);
    }
    // The region's rows back to the image domain.
    let mut out = Vec::with_capacity(rw * rh);
    for s0 in (m..m + rh).step_by(STRIP) {
        let ns = STRIP.min(m + rh - s0);
        conv.inverse_rows(&tw.acc, s0, &mut tw.back[..ns * wp]);
        for row in tw.back[..ns * wp].chunks_exact(wp) {
            out.extend_from_slice(&row[m..m + rw]);
        }
    }
    out
}

/// The combined images' inner loop: `rows` holds the N frames' rows (N x `ew`) and `a` the
/// coefficients (N x R, frame-major); for each rank r the row at `at` of rank r's buffer becomes
/// `sum_k a[k][r] rows[k]` over `ew` values, summed in frame order, then zeros up to `wp`.
/// The AVX2 build keeps eight columns of up to eight ranks' sums in registers, so each frame
/// value is loaded once rather than once per rank; it multiplies and adds separately (no
/// fused multiply-add), so both builds give the same bits.
fn combine_rows(a: &[f32], rows: &[f32], ew: usize, outs: &mut [&mut [f32]], at: usize, wp: usize) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX2 when it is called.
    let done = if std::is_x86_feature_detected!("avx2") { unsafe { combine_rows_avx2(a, rows, ew, outs, at) } } else { 0 };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    combine_cols(a, rows, ew, outs, at, done);
    outs.iter_mut().for_each(|o| o[at + ew..at + wp].fill(0.0));
}

/// [`combine_rows`] for columns `x0..ew`, one value at a time.
fn combine_cols(a: &[f32], rows: &[f32], ew: usize, outs: &mut [&mut [f32]], at: usize, x0: usize) {
    let ranks = outs.len();
    for (r, out) in outs.iter_mut().enumerate() {
        for x in x0..ew {
            let mut acc = a[r] * rows[x];
            for k in 1..a.len() / ranks {
                acc += a[k * ranks + r] * rows[k * ew + x];
            }
            out[at + x] = acc;
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
/// The columns that fill whole vectors; returns how many (the rest is the caller's).
unsafe fn combine_rows_avx2(a: &[f32], rows: &[f32], ew: usize, outs: &mut [&mut [f32]], at: usize) -> usize {
    let ranks = outs.len();
    let mut r0 = 0;
    while r0 < ranks {
        let nr = (ranks - r0).min(8);
        // SAFETY (all arms): AVX2 is enabled here; `combine_block` reads `rows` and writes
        // `outs` within `ew` columns only.
        unsafe {
            match nr {
                8 => combine_block::<8>(a, rows, ew, outs, at, r0),
                7 => combine_block::<7>(a, rows, ew, outs, at, r0),
                6 => combine_block::<6>(a, rows, ew, outs, at, r0),
                5 => combine_block::<5>(a, rows, ew, outs, at, r0),
                4 => combine_block::<4>(a, rows, ew, outs, at, r0),
                3 => combine_block::<3>(a, rows, ew, outs, at, r0),
                2 => combine_block::<2>(a, rows, ew, outs, at, r0),
                _ => combine_block::<1>(a, rows, ew, outs, at, r0),
            }
        }
        r0 += nr;
    }
    ew / 8 * 8
}

/// Ranks `r0..r0 + NR` of [`combine_rows_avx2`] over the columns that fill whole vectors.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn combine_block<const NR: usize>(a: &[f32], rows: &[f32], ew: usize, outs: &mut [&mut [f32]], at: usize, r0: usize) {
    use std::arch::x86_64::{__m256, _mm256_add_ps, _mm256_loadu_ps, _mm256_mul_ps, _mm256_set1_ps, _mm256_setzero_ps, _mm256_storeu_ps};
    let ranks = outs.len();
    let n = a.len() / ranks;
    assert!(rows.len() >= n * ew && r0 + NR <= ranks && outs.iter().all(|o| o.len() >= at + ew));
    let mut x = 0;
    while x + 8 <= ew {
        let mut acc: [__m256; NR] = [_mm256_setzero_ps(); NR];
        for k in 0..n {
            // SAFETY: k * ew + x + 8 <= n * ew <= rows.len() (asserted above).
            let v = unsafe { _mm256_loadu_ps(rows.as_ptr().add(k * ew + x)) };
            for (j, s) in acc.iter_mut().enumerate() {
                let p = _mm256_mul_ps(_mm256_set1_ps(a[k * ranks + r0 + j]), v);
                *s = if k == 0 { p } else { _mm256_add_ps(*s, p) };
            }
        }
        for (j, s) in acc.iter().enumerate() {
            // SAFETY: at + x + 8 <= at + ew <= the buffer's length (asserted above).
            unsafe { _mm256_storeu_ps(outs[r0 + j].as_mut_ptr().add(at + x), *s) };
        }
        x += 8;
    }
}

/// `acc (+)= v * k` for a real spectrum `k`: each value's real and imaginary part times its
/// `k`, the same values as the complex product with `k + 0i` (`x - 0 = x`, `0 + y = y`; at most
/// the sign of a zero differs) with half the spectrum read and a third of the arithmetic.
fn mul_real(acc: &mut [Complex32], v: &[Complex32], k: &[f32], add: bool) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { mul_real_avx2(acc, v, k, add) };
    }
    mul_real_plain(acc, v, k, add)
}

#[inline(always)]
fn mul_real_plain(acc: &mut [Complex32], v: &[Complex32], k: &[f32], add: bool) {
    assert!(acc.len() == v.len() && v.len() == k.len());
    if add {
        acc.iter_mut().zip(v).zip(k).for_each(|((o, v), &k)| *o += Complex32::new(v.re * k, v.im * k));
    } else {
        acc.iter_mut().zip(v).zip(k).for_each(|((o, v), &k)| *o = Complex32::new(v.re * k, v.im * k));
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
/// [`mul_real_plain`] compiled for AVX2 (no fused multiply-add: the same bits).
unsafe fn mul_real_avx2(acc: &mut [Complex32], v: &[Complex32], k: &[f32], add: bool) {
    mul_real_plain(acc, v, k, add)
}

fn mul_acc_add(acc: &mut [Complex32], other: &[Complex32]) {
    for (a, b) in acc.iter_mut().zip(other) {
        *a += b;
    }
}

/// Crops `rw x rh` at (x, y) out of planar planes of width `w`.
pub fn crop(p: &[Vec<f32>; 3], w: usize, x: usize, y: usize, rw: usize, rh: usize) -> [Vec<f32>; 3] {
    std::array::from_fn(|c| (0..rh).flat_map(|yy| p[c][(y + yy) * w + x..(y + yy) * w + x + rw].iter().copied()).collect())
}

#[cfg(test)]
mod tests;
