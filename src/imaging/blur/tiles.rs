//! The blur's inner work: tile planning, the per-tile low-rank sums of shifted spectra and
//! their inverse transforms, and the combining of the rank terms along rows and columns.

use super::*;

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
pub(super) fn install<R: Send>(pool: &Option<Arc<rayon::ThreadPool>>, f: impl FnOnce() -> R + Send) -> R {
    match pool {
        Some(p) => p.install(f),
        None => f(),
    }
}

/// The FFT plan of the current worker (one per rayon thread, so never contended).
pub(super) fn worker(convs: &[Mutex<FftConv>]) -> &Mutex<FftConv> {
    &convs[rayon::current_thread_index().unwrap_or(0) % convs.len()]
}

/// The three phases on one region: combined images, forward FFTs times basis spectra, one
/// inverse per channel. `region` is (x0, y0, rw, rh). This is the path of every worker on one
/// region (a frame that fits in one tile, [`Blurrer::blur_region`]); tiles and patches, one
/// worker each, take [`blur_tile`], which gives the same bits.
pub(super) fn blur_core(
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
    let (ew, eh) = (rw + 2 * m, rh + 2 * m);
    let (ex, ey) = (x0 - m as isize, y0 - m as isize);
    // Several plans: work spread over rayon's workers; one: all of it here (a patch).
    let parallel = convs.len() > 1;
    combine(factors, ws, frames, convs.len(), wp, (ex, ey, ew, eh));
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

/// Phase 1 of [`blur_core`]: the combined images sum_k a_kr S_k of every channel and rank of the
/// extended region (ex, ey, ew, eh) into `ws.combined`, by row bands on `workers` threads.
fn combine(
    factors: &[LowRank; 3],
    ws: &mut Workspace,
    frames: &[Arc<Frame>],
    workers: usize,
    wp: usize,
    (ex, ey, ew, eh): (isize, isize, usize, usize),
) {
    let parallel = workers > 1;
    let (fw, fh) = (frames[0].width, frames[0].height);
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
}

/// The coefficients a_kr of a channel's factorisation as f32, frame-major (frame k's for every
/// rank), as [`combine_rows`] reads them.
pub(super) fn coefficients(f: &LowRank) -> Vec<f32> {
    f.coeffs.iter().flat_map(|ck| ck.iter().map(|&v| v as f32)).collect()
}

/// Where the combined images of one channel read their rows: the window's frames, the channel,
/// the columns (`span`, `ew` wide) and the frame columns they lie in (`px`, for prefetching).
pub(super) struct RowSource<'a> {
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
pub(super) struct TileWork {
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
    pub(super) fn new(ranks: usize, conv: &FftConv) -> TileWork {
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
pub(super) const COLUMN_GROUP: usize = 8;

/// [`blur_core`] for channel `c` on one worker, in an order that keeps its data in the caches:
/// each strip of [`STRIP`] rows is combined, row-transformed while it is in the first-level
/// cache and scattered into the ranks' column buffers; then each group of columns is
/// transformed, multiplied by the basis spectra, summed over the ranks in order and
/// inverse-transformed while it stays in the second-level cache; last, only the rows of the
/// region itself are inverse-transformed. The combined images (R whole padded planes per
/// channel) are never written, and the inverse skips the margin's rows. The same operations in
/// the same order as [`blur_core`], so the same bits.
#[allow(clippy::too_many_arguments)]
pub(super) fn blur_tile(
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
pub(super) fn combine_rows(a: &[f32], rows: &[f32], ew: usize, outs: &mut [&mut [f32]], at: usize, wp: usize) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX2 when it is called.
    let done = if std::is_x86_feature_detected!("avx2") { unsafe { combine_rows_avx2(a, rows, ew, outs, at) } } else { 0 };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    combine_cols(a, rows, ew, outs, at, done);
    outs.iter_mut().for_each(|o| o[at + ew..at + wp].fill(0.0));
}

/// [`combine_rows`] for columns `x0..ew`, one value at a time.
pub(super) fn combine_cols(a: &[f32], rows: &[f32], ew: usize, outs: &mut [&mut [f32]], at: usize, x0: usize) {
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
        // SAFETY: (all arms) AVX2 is enabled here; `combine_block` reads `rows` and writes
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
pub(super) fn mul_real(acc: &mut [Complex32], v: &[Complex32], k: &[f32], add: bool) {
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU has AVX2.
        return unsafe { mul_real_avx2(acc, v, k, add) };
    }
    mul_real_plain(acc, v, k, add)
}

#[inline(always)]
pub(super) fn mul_real_plain(acc: &mut [Complex32], v: &[Complex32], k: &[f32], add: bool) {
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

pub(super) fn mul_acc_add(acc: &mut [Complex32], other: &[Complex32]) {
    for (a, b) in acc.iter_mut().zip(other) {
        *a += b;
    }
}
