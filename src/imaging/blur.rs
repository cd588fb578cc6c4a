//! Imaging a window of N linear frames through a camera: `B = sum_k w_k (PSF_k * S_k)` (weights
//! inside the rendered kernels), by real FFTs with the products summed in the frequency domain
//! and one inverse per channel. Borders are mirrored. Whole frames, regions, or patches plus the
//! kernel margin (the same pixels as blurring the whole frame and cropping).
use crate::frame::{Cols, Frame};
use crate::optics::fft::{fast_size, reflect, FftConv};
use crate::optics::lowrank::{factorise, LowRank};
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
/// cameras (one kernel shape), 5 for parabolic with N = 9 (t^2 repeats shifts), and about 5 for
/// the coded camera at the default tolerance.
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
    spectra: HashMap<(usize, usize), Arc<[Vec<Vec<Complex32>>; 3]>>,
    /// FFT plans per padded size, one per worker.
    convs: HashMap<(usize, usize), Vec<Mutex<FftConv>>>,
    /// Reused buffers per padded size.
    work: HashMap<(usize, usize), Workspace>,
    /// Per-worker buffers for patch mode.
    patch_work: HashMap<(usize, usize), Vec<Mutex<Workspace>>>,
}

/// Buffers kept between windows: no page faults on the hot path.
struct Workspace {
    /// Combined images per channel and rank, `hp x wp`; zero outside the region.
    combined: [Vec<Vec<f32>>; 3],
    /// Products per channel and rank.
    slots: [Vec<Vec<Complex32>>; 3],
    /// Each channel's inverse transform, `hp x wp` (kept, like the rest, between windows).
    full: [Vec<f32>; 3],
    /// The extended region (w, h) the combined images last held. Outside it they must be zero:
    /// in exact arithmetic what lies there never reaches the kept pixels, but through the FFT's
    /// rounding it would, so a smaller region after a larger one clears them first (the result
    /// then depends only on the region, not on which one this worker blurred before).
    extent: (usize, usize),
}

/// Row bands per channel when building the combined images (parallel work units).
const BANDS: usize = 8;

impl Blurrer {
    /// `rank_tolerance`: relative Frobenius error allowed when factorising the kernels
    /// (0 keeps every direction: exact up to rounding).
    ///
    /// # Errors
    /// A camera whose psi schedule does not fit N.
    pub fn new(camera: Arc<Camera>, n: usize, threads: usize, rank_tolerance: f64) -> crate::Result<Blurrer> {
        let kernels = camera.window(n)?;
        let margin = margin_of(&kernels);
        let pool = match threads {
            0 => None,
            t => Some(Arc::new(
                rayon::ThreadPoolBuilder::new().num_threads(t).build().map_err(|e| crate::Error::Invalid(format!("blur threads: {e}")))?,
            )),
        };
        let threads = pool.as_ref().map_or_else(rayon::current_num_threads, |p| p.current_num_threads());
        let factors = std::array::from_fn(|c| {
            let rendered: Vec<Vec<f32>> = kernels.iter().map(|k| k.render(c, margin)).collect();
            factorise(&rendered, rank_tolerance)
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

    fn prepare(&mut self, hp: usize, wp: usize) -> Arc<[Vec<Vec<Complex32>>; 3]> {
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
        let spectra: [Vec<Vec<Complex32>>; 3] =
            std::array::from_fn(|c| (0..factors[c].basis.len()).map(|_| it.next().expect("one per basis")).collect());
        let arc = Arc::new(spectra);
        self.spectra.insert((hp, wp), arc.clone());
        arc
    }

    fn workspace(ranks: [usize; 3], hp: usize, wp: usize) -> Workspace {
        Workspace {
            // Zeroed here, and again when a smaller region follows a larger one (`extent`).
            combined: std::array::from_fn(|c| (0..ranks[c]).map(|_| vec![0.0f32; hp * wp]).collect()),
            slots: std::array::from_fn(|c| (0..ranks[c]).map(|_| vec![Complex32::new(0.0, 0.0); hp * (wp / 2 + 1)]).collect()),
            full: std::array::from_fn(|_| vec![0.0f32; hp * wp]),
            extent: (0, 0),
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

    /// Blurs the whole frame in tiles of at most `tile x tile` pixels, overlap-save: each tile is
    /// transformed with the kernel margin around it (mirrored at the frame's borders) and only the
    /// tile is kept, so it equals the whole-frame blur up to float rounding. Tiles are spread over
    /// the workers, each with its own cache-sized transforms and buffers; memory is a few tiles
    /// per worker instead of whole-frame planes per channel and rank. The result does not depend
    /// on the number of workers. A frame that fits in one tile is one plane, all workers on it.
    pub fn blur_tiled(&mut self, frames: &[Arc<Frame>], tile: usize) -> [Vec<f32>; 3] {
        let (w, h) = (frames[0].width, frames[0].height);
        if w <= tile && h <= tile {
            // One tile: the whole plane with every worker on it.
            return self.blur_region(frames, 0, 0, w, h);
        }
        let (tw, th) = (tile.clamp(1, w), tile.clamp(1, h));
        let rects: Vec<_> =
            (0..h).step_by(th).flat_map(|y| (0..w).step_by(tw).map(move |x| (x, y, tw.min(w - x), th.min(h - y)))).collect();
        let tiles = self.blur_rects(frames, &rects, (tw, th));
        let mut out: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0f32; w * h]);
        for (&(x, y, rw, rh), t) in rects.iter().zip(&tiles) {
            for (o, p) in out.iter_mut().zip(t) {
                for yy in 0..rh {
                    o[(y + yy) * w + x..(y + yy) * w + x + rw].copy_from_slice(&p[yy * rw..(yy + 1) * rw]);
                }
            }
        }
        out
    }

    /// Blurs each `(x, y, w, h)` rectangle (at most `max` = (w, h) in size) on its own, the
    /// rectangles spread over the workers; all share one transform size.
    fn blur_rects(&mut self, frames: &[Arc<Frame>], rects: &[(usize, usize, usize, usize)], max: (usize, usize)) -> Vec<[Vec<f32>; 3]> {
        assert_eq!(frames.len(), self.n);
        let m = self.margin;
        let (hp, wp) = (fast_size(max.1 + 2 * m), fast_size(max.0 + 2 * m));
        let spectra = self.prepare(hp, wp);
        let ranks = self.ranks();
        let threads = self.threads;
        let pool = self
            .patch_work
            .entry((hp, wp))
            .or_insert_with(|| (0..threads).map(|_| Mutex::new(Blurrer::workspace(ranks, hp, wp))).collect());
        let convs = &self.convs[&(hp, wp)];
        let factors = &self.factors;
        // Whole rectangles per worker: each blurs its own with its own plan and buffers.
        install(&self.pool, || {
            use rayon::prelude::*;
            rects
                .par_iter()
                .map(|&(x, y, rw, rh)| {
                    let i = rayon::current_thread_index().unwrap_or(0) % pool.len();
                    let mut ws = pool[i].lock().expect("workspace");
                    let one = std::slice::from_ref(&convs[i % convs.len()]);
                    blur_core(factors, &spectra, one, &mut ws, frames, m, (x as isize, y as isize, rw, rh))
                })
                .collect()
        })
    }
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
/// inverse per channel. `region` is (x0, y0, rw, rh).
fn blur_core(
    factors: &[LowRank; 3],
    spectra: &[Vec<Vec<Complex32>>; 3],
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
    if ws.extent.0 > ew || ws.extent.1 > eh {
        ws.combined.iter_mut().flatten().for_each(|b| b.fill(0.0));
    }
    ws.extent = (ew, eh);
    // Several plans: work spread over rayon's workers; one: all of it here (a patch).
    let parallel = convs.len() > 1;
    let workers = convs.len();
    // Phase 1: the combined images sum_k a_kr S_k of every channel and rank, by row bands;
    // each job owns its rows of every rank's buffer.
    let bands = if workers == 1 { 1 } else { BANDS };
    let band_rows = eh.div_ceil(bands);
    let mut jobs: Vec<(usize, usize, Vec<&mut [f32]>)> = Vec::new();
    for (c, bufs) in ws.combined.iter_mut().enumerate() {
        let mut per_rank: Vec<_> = bufs.iter_mut().map(|b| b[..eh * wp].chunks_mut(band_rows * wp)).collect();
        for band in 0..eh.div_ceil(band_rows) {
            jobs.push((c, band, per_rank.iter_mut().map(|it| it.next().expect("band")).collect()));
        }
    }
    let cols: Vec<usize> = (0..ew).map(|x| reflect(ex + x as isize, fw)).collect();
    let span = if ex >= 0 && ex as usize + ew <= fw { Cols::From(ex as usize) } else { Cols::Index(&cols) };
    let phase1 = |(c, band, mut outs): (usize, usize, Vec<&mut [f32]>)| {
        let mut row = vec![0.0f32; ew];
        {
            let f = &factors[c];
            // The coefficients a_kr as f32, once per job: `a[k]` holds frame k's for every rank.
            let a: Vec<Vec<f32>> = f.coeffs.iter().map(|ck| ck.iter().map(|&v| v as f32).collect()).collect();
            let y_lo = band * band_rows;
            let rows_here = outs[0].len() / wp;
            for ly in 0..rows_here {
                let sy = reflect(ey + (y_lo + ly) as isize, fh);
                for (k, frame) in frames.iter().enumerate() {
                    frame.linear_row(c, sy, span, &mut row);
                    scale_add_rows(&a[k], &row, &mut outs, ly * wp, k == 0);
                }
            }
        }
    };
    if parallel {
        use rayon::prelude::*;
        jobs.into_par_iter().for_each(phase1);
    } else {
        jobs.into_iter().for_each(phase1);
    }
    // Phase 2: one forward FFT per (channel, rank), times the basis spectrum, into its slot.
    let mut jobs: Vec<(&[f32], &[Complex32], &mut Vec<Complex32>)> = Vec::new();
    for (c, (bufs, slots)) in ws.combined.iter().zip(ws.slots.iter_mut()).enumerate() {
        for (r, (img, slot)) in bufs.iter().zip(slots.iter_mut()).enumerate() {
            jobs.push((img, &spectra[c][r], slot));
        }
    }
    let phase2 = |(img, spec, slot): (&[f32], &[Complex32], &mut Vec<Complex32>)| {
        worker(convs).lock().expect("conv lock").forward_mul(img, spec, slot);
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

/// The combined images' inner loop: for each rank r, `o_r = a_r * row` (`first`) or
/// `o_r += a_r * row` over the row at `at` of rank r's buffer. AVX2 only makes it wider: no fused
/// multiply-adds, so the same bits on every CPU (about 1.4 times faster than SSE2 here).
fn scale_add_rows(a: &[f32], row: &[f32], outs: &mut [&mut [f32]], at: usize, first: bool) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2, checked just above.
        return unsafe { scale_add_rows_avx2(a, row, outs, at, first) };
    }
    scale_add_rows_any(a, row, outs, at, first)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn scale_add_rows_avx2(a: &[f32], row: &[f32], outs: &mut [&mut [f32]], at: usize, first: bool) {
    scale_add_rows_any(a, row, outs, at, first)
}

#[inline(always)]
fn scale_add_rows_any(a: &[f32], row: &[f32], outs: &mut [&mut [f32]], at: usize, first: bool) {
    for (out, &a) in outs.iter_mut().zip(a) {
        let o = &mut out[at..at + row.len()];
        if first {
            o.iter_mut().zip(row).for_each(|(o, v)| *o = a * v);
        } else {
            o.iter_mut().zip(row).for_each(|(o, v)| *o += a * v);
        }
    }
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
mod tests {
    use super::*;
    use crate::frame::FrameData;
    use crate::optics::fft::convolve_direct;
    use crate::optics::{CameraConfig, CameraKind, OpticsConfig};

    fn frames(n: usize, w: usize, h: usize, seed: u64) -> Vec<Arc<Frame>> {
        (0..n)
            .map(|k| {
                let p = std::array::from_fn(|c| {
                    (0..w * h).map(|i| crate::rng::unit(crate::rng::hash(&[seed, k as u64, c as u64, i as u64])) as f32).collect()
                });
                Arc::new(Frame { curve: Some(crate::optics::transfer::Curve::Identity), ..Frame::new(w, h, FrameData::Planar(p)) })
            })
            .collect()
    }

    /// Largest difference per channel between `got` and the sum of direct convolutions of the
    /// whole frames with the window's (exact) kernels.
    fn worst_vs_direct(b: &Blurrer, fr: &[Arc<Frame>], got: &[Vec<f32>; 3]) -> [f32; 3] {
        let (w, h) = (fr[0].width, fr[0].height);
        std::array::from_fn(|c| {
            let mut want = vec![0.0f32; w * h];
            for (k, f) in fr.iter().enumerate() {
                let d = convolve_direct(&f.linear_crop(0, 0, w, h)[c], h, w, &b.kernels()[k].render(c, b.margin));
                want.iter_mut().zip(d).for_each(|(a, v)| *a += v);
            }
            got[c].iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max)
        })
    }

    #[test]
    fn window_blur_equals_sum_of_direct_convolutions() {
        let cam = Arc::new(Camera::new(
            &OpticsConfig { airy_radius_px: Some(0.8), ..Default::default() },
            &CameraConfig::new(CameraKind::PhaseCoded),
        ));
        let mut b = Blurrer::new(cam, 3, 2, 0.0).unwrap();
        let (w, h) = (40, 30);
        let fr = frames(3, w, h, 1);
        let got = b.blur_region(&fr, 0, 0, w, h);
        for (c, worst) in worst_vs_direct(&b, &fr, &got).into_iter().enumerate() {
            assert!(worst < 1e-4, "channel {c}: {worst}");
        }
    }

    #[test]
    fn default_rank_tolerance_stays_far_below_an_8_bit_level() {
        // The coded camera's 9 kernels at rank_tolerance 1e-3 against the exact sum of direct
        // convolutions, on a random image in [0, 1] (the worst case for high frequencies).
        let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::PhaseCoded)));
        let mut b = Blurrer::new(cam, 9, 2, 1e-3).unwrap();
        assert!(b.ranks().iter().all(|&r| r < 9), "ranks {:?}", b.ranks());
        let (w, h) = (48, 40);
        let fr = frames(9, w, h, 4);
        let got = b.blur_region(&fr, 0, 0, w, h);
        for (c, worst) in worst_vs_direct(&b, &fr, &got).into_iter().enumerate() {
            // A tenth of an 8-bit level in linear light.
            assert!(worst < 0.1 / 255.0, "channel {c}: {worst}");
        }
    }

    #[test]
    fn crop_then_blur_equals_blur_then_crop() {
        let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::PhaseCoded)));
        let mut b = Blurrer::new(cam, 5, 2, 1e-3).unwrap();
        let (w, h) = (96, 80);
        let fr = frames(5, w, h, 2);
        let full = b.blur_region(&fr, 0, 0, w, h);
        // A patch at the corner (mirrored borders inside the margin) and one inside.
        let corners = [(0usize, 0usize), (41, 23)];
        let batch = b.blur_patches(&fr, &corners, 32);
        for (i, (x, y)) in corners.into_iter().enumerate() {
            let part = b.blur_region(&fr, x as isize, y as isize, 32, 32);
            // Patch mode (one worker per patch) computes exactly what all workers on one region do.
            assert!(batch[i] == part, "patch {i}: blur_patches differs from blur_region");
            let want = crop(&full, w, x, y, 32, 32);
            for c in 0..3 {
                let worst = part[c].iter().zip(&want[c]).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                assert!(worst < 2e-5, "patch ({x},{y}) channel {c}: {worst}");
            }
        }
    }

    #[test]
    fn tiled_blur_equals_direct_convolution_across_the_seams() {
        // Random frames (every pixel's neighbourhood non-trivial) and impulses on and beside
        // every seam, through the coded camera's exact kernels (rank tolerance 0), in tiles of
        // 32 px (several seams per axis, and smaller last tiles) on 1 and 2 workers.
        let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::PhaseCoded)));
        let (w, h, n, tile) = (100, 75, 3, 32);
        let mut fr = frames(n, w, h, 9);
        let mut impulses: Vec<Vec<f32>> = (0..3).map(|_| vec![0.0f32; w * h]).collect();
        for seam in [32usize, 64, 96] {
            for d in [-2isize, -1, 0, 1] {
                let x = (seam as isize + d) as usize;
                for y in (3..h).step_by(11) {
                    if x < w {
                        impulses.iter_mut().for_each(|p| p[y * w + x] = 1.0);
                    }
                    if let Some(row) = (seam as isize + d).try_into().ok().filter(|&r: &usize| r < h) {
                        impulses.iter_mut().for_each(|p| p[row * w + (y % w)] = 1.0);
                    }
                }
            }
        }
        let imp = Arc::new(Frame {
            curve: Some(crate::optics::transfer::Curve::Identity),
            ..Frame::new(w, h, FrameData::Planar([impulses[0].clone(), impulses[1].clone(), impulses[2].clone()]))
        });
        fr[1] = imp;
        let mut outs = Vec::new();
        for threads in [1, 2] {
            let mut b = Blurrer::new(cam.clone(), n, threads, 0.0).unwrap();
            let got = b.blur_tiled(&fr, tile);
            for (c, worst) in worst_vs_direct(&b, &fr, &got).into_iter().enumerate() {
                assert!(worst < 1e-5, "channel {c} on {threads} workers: {worst}");
            }
            let whole = b.blur_region(&fr, 0, 0, w, h);
            for c in 0..3 {
                let d = got[c].iter().zip(&whole[c]).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                assert!(d < 1e-5, "tiled vs whole frame, channel {c}: {d}");
            }
            outs.push(got);
        }
        assert!(outs[0] == outs[1], "tiles give the same bits on 1 and 2 workers");
    }

    #[test]
    fn identical_frames_through_conventional_give_the_frame_back() {
        let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::Conventional)));
        let mut b = Blurrer::new(cam, 9, 2, 1e-3).unwrap();
        let one = frames(1, 33, 21, 5).remove(0);
        let fr = vec![one.clone(); 9];
        let got = b.blur_region(&fr, 0, 0, 33, 21);
        for c in 0..3 {
            for (a, v) in got[c].iter().zip(&one.linear_crop(0, 0, 33, 21)[c]) {
                assert!((a - v).abs() < 1e-5);
            }
        }
    }
}
