//! 2-D convolution by real FFTs, with products summed in the frequency domain.
//!
//! A window of N sub-frames needs N forward transforms per channel but one inverse: the blurred
//! image is `F^-1( sum_k F(img_k) F(psf_k) )`. Spectra are kept in a transposed layout
//! (`wc` rows of `hp` complex values, `wc = wp / 2 + 1`) so that the column FFTs run over one
//! contiguous buffer.
//!
//! ## Usage
//! ```
//! use pipeline::optics::fft::FftConv;
//! let mut conv = FftConv::new(8, 8);
//! let mut img = vec![0.0f32; 64];
//! img[9] = 1.0;
//! let kernel = vec![1.0f32]; // a 1 x 1 delta
//! let ks = conv.kernel_spectrum(&kernel);
//! let mut acc = conv.zero_spectrum();
//! conv.accumulate(&mut img.clone(), &ks, &mut acc);
//! let mut out = vec![0.0f32; 64];
//! conv.inverse(&mut acc, &mut out);
//! assert!((out[9] - 1.0).abs() < 1e-6);
//! ```

use num_complex::Complex32;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};
use std::sync::Arc;

/// Smallest n' >= n of the form 2^a 3^b 5^c with b <= 3 and c <= 1. rustfft's transforms of
/// lengths with more factors of 3 or 5 cost up to 1.8 times as much per point here (1350 wide
/// at 720p, 486, 500, 450 against 512 and 480; medians of interleaved timing rounds on this AVX2
/// machine), more than the few percent of points they save.
pub fn fast_size(n: usize) -> usize {
    let mut m = n.max(1);
    loop {
        let mut k = m;
        let mut count = [0usize; 3];
        for (i, p) in [2, 3, 5].into_iter().enumerate() {
            while k.is_multiple_of(p) {
                k /= p;
                count[i] += 1;
            }
        }
        if k == 1 && count[1] <= 3 && count[2] <= 1 {
            return m;
        }
        m += 1;
    }
}

/// In-place forward 2-D DFT of a row-major `w x h` complex array, in f64 (rows, then columns):
/// for the small exact transforms outside the hot path (error bounds, figures).
pub fn fft2_f64(a: &mut [num_complex::Complex64], w: usize, h: usize) {
    assert_eq!(a.len(), w * h, "fft2_f64: {w} x {h} values");
    let mut planner = FftPlanner::<f64>::new();
    let (fw, fh) = (planner.plan_fft_forward(w), planner.plan_fft_forward(h));
    for row in a.chunks_exact_mut(w) {
        fw.process(row);
    }
    let mut col = vec![num_complex::Complex64::new(0.0, 0.0); h];
    for x in 0..w {
        for y in 0..h {
            col[y] = a[y * w + x];
        }
        fh.process(&mut col);
        for y in 0..h {
            a[y * w + x] = col[y];
        }
    }
}

/// The row transforms' real-to-complex forward FFT. For even lengths realfft's own algorithm
/// (a complex FFT of half the length, then a pass of twiddles that untangles the halves) with
/// the same operations in the same order, so the same bits, but the twiddle pass compiled for
/// AVX2 where the CPU has it: realfft's generic pass, built for the baseline x86-64, was 8 to 9%
/// of whole-frame generation. Odd lengths (small tiles only) go to realfft itself.
enum R2c {
    Even { fft: Arc<dyn Fft<f32>>, twiddles: Vec<Complex32> },
    Other(Arc<dyn RealToComplex<f32>>),
}

impl R2c {
    fn new(len: usize, real: &mut RealFftPlanner<f32>, complex: &mut FftPlanner<f32>) -> R2c {
        if len < 2 || !len.is_multiple_of(2) {
            return R2c::Other(real.plan_fft_forward(len));
        }
        // As realfft 3.5's RealToComplexEven::new: twiddle i is exp(-2 pi i / len) / 2, i >= 1.
        let count = if len.is_multiple_of(4) { len / 4 } else { len / 4 + 1 };
        let twiddles = (1..count)
            .map(|i| {
                let angle = -2.0 * std::f64::consts::PI / len as f64 * i as f64;
                Complex32::new(angle.cos() as f32, angle.sin() as f32) * 0.5
            })
            .collect();
        R2c::Even { fft: complex.plan_fft_forward(len / 2), twiddles }
    }

    fn scratch_len(&self) -> usize {
        match self {
            R2c::Even { fft, .. } => fft.get_outofplace_scratch_len(),
            R2c::Other(p) => p.get_scratch_len(),
        }
    }

    /// `output` (`len / 2 + 1` values) = the spectrum of `input` (`len` values, used as scratch).
    fn process(&self, input: &mut [f32], output: &mut [Complex32], scratch: &mut [Complex32]) {
        match self {
            R2c::Other(p) => p.process_with_scratch(input, output, scratch).expect("r2c sizes match"),
            R2c::Even { fft, twiddles } => {
                let half = input.len() / 2;
                assert!(input.len() == 2 * half && output.len() == half + 1, "r2c sizes match");
                // SAFETY: Complex32 is two f32 (repr(C), the alignment of f32): `half` complex
                // values are exactly the `2 half` reals of `input`, borrowed mutably here alone.
                let pairs = unsafe { std::slice::from_raw_parts_mut(input.as_mut_ptr().cast::<Complex32>(), half) };
                fft.process_outofplace_with_scratch(pairs, &mut output[..half], scratch);
                untangle(twiddles, output);
            }
        }
    }
}

/// realfft's twiddle pass (see [`R2c`]), AVX2 where the CPU has it.
fn untangle(twiddles: &[Complex32], output: &mut [Complex32]) {
    #[cfg(target_arch = "x86_64")]
    let vector = std::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    let vector = false;
    untangle_with(twiddles, output, vector)
}

/// The twiddle pass: the first and last values from the first, then each pair (k, n - 1 - k)
/// for k >= 1, the left half against the right half reversed; four pairs at a time in AVX2 when
/// `vector` (the caller has checked the CPU).
fn untangle_with(twiddles: &[Complex32], output: &mut [Complex32], vector: bool) {
    let n = output.len();
    let first = output[0];
    output[0] = Complex32::new(first.re + first.im, 0.0);
    output[n - 1] = Complex32::new(first.re - first.im, 0.0);
    let (left, right) = output.split_at_mut(n / 2);
    let rl = right.len();
    let (left, right) = (&mut left[1..], &mut right[..rl - 1]);
    let m = twiddles.len().min(left.len()).min(right.len());
    #[cfg(target_arch = "x86_64")]
    // SAFETY: `vector` only where the CPU has AVX2.
    let done = if vector { unsafe { untangle_pairs_avx2(twiddles, left, right, m) } } else { 0 };
    #[cfg(not(target_arch = "x86_64"))]
    let done = {
        let _ = vector;
        0
    };
    untangle_pairs(twiddles, left, right, done..m);
    if n % 2 == 1 {
        output[n / 2].im = -output[n / 2].im;
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
/// [`untangle_pairs`] four pairs at a time over `0..m`, as far as whole groups reach; returns
/// where it stopped. Each used lane gets the scalar loop's operations in its order (no fused
/// multiply-add), so the same bits.
unsafe fn untangle_pairs_avx2(twiddles: &[Complex32], left: &mut [Complex32], right: &mut [Complex32], m: usize) -> usize {
    use std::arch::x86_64::{
        __m256, _mm256_add_ps, _mm256_blend_ps, _mm256_castpd_ps, _mm256_castps_pd, _mm256_loadu_ps, _mm256_movehdup_ps,
        _mm256_moveldup_ps, _mm256_mul_ps, _mm256_permute4x64_pd, _mm256_set1_ps, _mm256_storeu_ps, _mm256_sub_ps,
    };
    assert!(m <= twiddles.len() && m <= left.len() && m <= right.len());
    let rl = right.len();
    // Four complex values in reverse order (the 64-bit lanes of the vector).
    let reverse = |v: __m256| _mm256_castpd_ps(_mm256_permute4x64_pd::<0x1B>(_mm256_castps_pd(v)));
    let half = _mm256_set1_ps(0.5);
    let mut k = 0;
    while k + 4 <= m {
        // SAFETY: k + 4 <= m <= each slice's length (asserted), so rl - k - 4 >= 0 starts the
        // right-hand group; Complex32 is two f32.
        unsafe {
            let out = _mm256_loadu_ps(left.as_ptr().add(k).cast::<f32>());
            let out_rev = reverse(_mm256_loadu_ps(right.as_ptr().add(rl - k - 4).cast::<f32>()));
            let tw = _mm256_loadu_ps(twiddles.as_ptr().add(k).cast::<f32>());
            let (tw_re, tw_im) = (_mm256_moveldup_ps(tw), _mm256_movehdup_ps(tw));
            let sum = _mm256_add_ps(out, out_rev);
            let diff = _mm256_sub_ps(out, out_rev);
            let (sum_re, sum_im) = (_mm256_moveldup_ps(sum), _mm256_movehdup_ps(sum));
            let (diff_re, diff_im) = (_mm256_moveldup_ps(diff), _mm256_movehdup_ps(diff));
            let half_sum_re = _mm256_mul_ps(half, sum_re);
            let half_diff_im = _mm256_mul_ps(half, diff_im);
            let re = _mm256_add_ps(_mm256_mul_ps(sum_im, tw_re), _mm256_mul_ps(diff_re, tw_im));
            let im = _mm256_sub_ps(_mm256_mul_ps(sum_im, tw_im), _mm256_mul_ps(diff_re, tw_re));
            // Even lanes the real parts, odd lanes the imaginary ones.
            let new_out = _mm256_blend_ps::<0b1010_1010>(_mm256_add_ps(half_sum_re, re), _mm256_add_ps(half_diff_im, im));
            let new_rev = _mm256_blend_ps::<0b1010_1010>(_mm256_sub_ps(half_sum_re, re), _mm256_sub_ps(im, half_diff_im));
            _mm256_storeu_ps(left.as_mut_ptr().add(k).cast::<f32>(), new_out);
            _mm256_storeu_ps(right.as_mut_ptr().add(rl - k - 4).cast::<f32>(), reverse(new_rev));
        }
        k += 4;
    }
    k
}

/// The pairs `k` of `range`: `left[k]` against `right[len - 1 - k]`, realfft's operations.
fn untangle_pairs(twiddles: &[Complex32], left: &mut [Complex32], right: &mut [Complex32], range: std::ops::Range<usize>) {
    let rl = right.len();
    for k in range {
        let (out, out_rev, tw) = (left[k], right[rl - 1 - k], twiddles[k]);
        let sum = out + out_rev;
        let diff = out - out_rev;
        let twiddled_re_sum = sum * tw.re;
        let twiddled_im_sum = sum * tw.im;
        let twiddled_re_diff = diff * tw.re;
        let twiddled_im_diff = diff * tw.im;
        let half_sum_re = 0.5 * sum.re;
        let half_diff_im = 0.5 * diff.im;
        let re = twiddled_re_sum.im + twiddled_im_diff.re;
        let im = twiddled_im_sum.im - twiddled_re_diff.re;
        left[k] = Complex32::new(half_sum_re + re, half_diff_im + im);
        right[rl - 1 - k] = Complex32::new(half_sum_re - re, im - half_diff_im);
    }
}

/// FFT convolver for images of `hp x wp` (already padded) pixels.
pub struct FftConv {
    pub hp: usize,
    pub wp: usize,
    wc: usize,
    r2c: R2c,
    c2r: Arc<dyn ComplexToReal<f32>>,
    col_fwd: Arc<dyn Fft<f32>>,
    col_inv: Arc<dyn Fft<f32>>,
    /// A strip of row spectra, row-major `STRIP x wc`.
    rows: Vec<Complex32>,
    /// A spectrum buffer for `accumulate`.
    spec: Vec<Complex32>,
    /// An image buffer for `forward_mul`.
    img: Vec<f32>,
    scratch: Vec<Complex32>,
}

impl Clone for FftConv {
    fn clone(&self) -> Self {
        FftConv::new(self.hp, self.wp)
    }
}

impl FftConv {
    pub fn new(hp: usize, wp: usize) -> FftConv {
        let mut rp = RealFftPlanner::<f32>::new();
        let c2r = rp.plan_fft_inverse(wp);
        let mut cp = FftPlanner::<f32>::new();
        let r2c = R2c::new(wp, &mut rp, &mut cp);
        let col_fwd = cp.plan_fft_forward(hp);
        let col_inv = cp.plan_fft_inverse(hp);
        let wc = wp / 2 + 1;
        let scratch_len = [r2c.scratch_len(), c2r.get_scratch_len(), col_fwd.get_inplace_scratch_len(), col_inv.get_inplace_scratch_len()]
            .into_iter()
            .max()
            .unwrap_or(0);
        FftConv {
            hp,
            wp,
            wc,
            r2c,
            c2r,
            col_fwd,
            col_inv,
            rows: vec![Complex32::new(0.0, 0.0); STRIP * wc],
            spec: vec![Complex32::new(0.0, 0.0); hp * wc],
            img: Vec::new(),
            scratch: vec![Complex32::new(0.0, 0.0); scratch_len],
        }
    }

    /// Number of complex values in a spectrum.
    pub fn spectrum_len(&self) -> usize {
        self.wc * self.hp
    }

    pub fn zero_spectrum(&self) -> Vec<Complex32> {
        vec![Complex32::new(0.0, 0.0); self.spectrum_len()]
    }

    /// Forward transform of an `hp x wp` row-major image into `out` (transposed layout).
    /// `img` is used as scratch and left unspecified.
    ///
    /// Row transforms go in strips of [`STRIP`] rows, each scattered into the columns of `out`
    /// while it is still in the first-level cache, so a plan holds no whole-image buffer of row
    /// spectra (4.3 MB per worker at 720p). The scatter itself stays memory-bound at whole-frame
    /// sizes (about a tenth of a whole-frame blur's time, as the blocked transpose was).
    pub fn forward(&mut self, img: &mut [f32], out: &mut [Complex32]) {
        let (hp, wp, wc) = (self.hp, self.wp, self.wc);
        assert_eq!(img.len(), hp * wp);
        assert_eq!(out.len(), hp * wc);
        for y0 in (0..hp).step_by(STRIP) {
            let n = STRIP.min(hp - y0);
            self.forward_rows(&mut img[y0 * wp..(y0 + n) * wp], out, y0);
        }
        self.columns(out, false);
    }

    /// Complex values per row spectrum (`wp / 2 + 1`): the number of columns of the transposed
    /// layout.
    pub fn wc(&self) -> usize {
        self.wc
    }

    /// The row half of [`FftConv::forward`] for at most [`STRIP`] image rows starting at row
    /// `y0`: their real transforms, scattered into rows `y0..` of every column of `out`
    /// (transposed layout, `wc` columns of `hp`). `rows` is used as scratch.
    pub fn forward_rows(&mut self, rows: &mut [f32], out: &mut [Complex32], y0: usize) {
        let (hp, wp, wc) = (self.hp, self.wp, self.wc);
        let n = rows.len() / wp;
        assert!(n * wp == rows.len() && n <= STRIP && y0 + n <= hp && out.len() == hp * wc);
        let mut strip = std::mem::take(&mut self.rows);
        for (row, spec) in rows.chunks_exact_mut(wp).zip(strip.chunks_exact_mut(wc)) {
            self.r2c.process(row, spec, &mut self.scratch);
        }
        rows_to_columns(&strip[..n * wc], out, wc, hp, y0);
        self.rows = strip;
    }

    /// The column transforms (forward, or unnormalised inverse) of whole columns of `hp`
    /// values, in place: `cols` holds any number of them.
    pub fn columns(&mut self, cols: &mut [Complex32], inverse: bool) {
        assert!(cols.len().is_multiple_of(self.hp));
        let plan = if inverse { &self.col_inv } else { &self.col_fwd };
        plan.process_with_scratch(cols, &mut self.scratch);
    }

    /// Spectrum of a centred `(2h + 1)^2` kernel (row-major, `kernel.len()` a square) for this size.
    pub fn kernel_spectrum(&mut self, kernel: &[f32]) -> Vec<Complex32> {
        let n = (kernel.len() as f64).sqrt().round() as usize;
        assert_eq!(n * n, kernel.len(), "kernel must be square");
        assert!(n % 2 == 1 && n <= self.hp && n <= self.wp, "kernel {n} does not fit {}x{}", self.hp, self.wp);
        let h = (n / 2) as isize;
        let mut img = vec![0.0f32; self.hp * self.wp];
        for ky in 0..n as isize {
            for kx in 0..n as isize {
                let y = (ky - h).rem_euclid(self.hp as isize) as usize;
                let x = (kx - h).rem_euclid(self.wp as isize) as usize;
                img[y * self.wp + x] += kernel[(ky * n as isize + kx) as usize];
            }
        }
        let mut out = self.zero_spectrum();
        self.forward(&mut img, &mut out);
        out
    }

    /// `out = F(img) * kernel_spec`; `img` is copied first and left untouched.
    pub fn forward_mul(&mut self, img: &[f32], kernel_spec: &[Complex32], out: &mut [Complex32]) {
        let mut buf = std::mem::take(&mut self.img);
        buf.resize(self.hp * self.wp, 0.0);
        buf.copy_from_slice(img);
        self.forward_mul_in_place(&mut buf, kernel_spec, out);
        self.img = buf;
    }

    /// `out = F(img) * kernel_spec`, using `img` as scratch (left unspecified).
    pub fn forward_mul_in_place(&mut self, img: &mut [f32], kernel_spec: &[Complex32], out: &mut [Complex32]) {
        self.forward(img, out);
        for (o, k) in out.iter_mut().zip(kernel_spec) {
            *o *= k;
        }
    }

    /// `acc += F(img) * kernel_spec`.
    pub fn accumulate(&mut self, img: &mut [f32], kernel_spec: &[Complex32], acc: &mut [Complex32]) {
        let mut spec = std::mem::take(&mut self.spec);
        self.forward(img, &mut spec);
        mul_acc(&spec, kernel_spec, acc);
        self.spec = spec;
    }

    /// Inverse transform of a spectrum (consumed as scratch) into an `hp x wp` image,
    /// normalised so that a delta kernel is the identity.
    pub fn inverse(&mut self, spec: &mut [Complex32], out: &mut [f32]) {
        let (hp, wp, wc) = (self.hp, self.wp, self.wc);
        assert_eq!(spec.len(), hp * wc);
        assert_eq!(out.len(), hp * wp);
        self.columns(spec, true);
        for y0 in (0..hp).step_by(STRIP) {
            let n = STRIP.min(hp - y0);
            self.inverse_rows(spec, y0, &mut out[y0 * wp..(y0 + n) * wp]);
        }
    }

    /// The row half of [`FftConv::inverse`] for at most [`STRIP`] rows from `y0`, of a spectrum
    /// whose columns are already inverse-transformed ([`FftConv::columns`]): rows gathered
    /// from the columns, then the normalised real inverse of each into `out` (rows of `wp`).
    /// Only the rows asked for are transformed; `spec` is only read.
    pub fn inverse_rows(&mut self, spec: &[Complex32], y0: usize, out: &mut [f32]) {
        let (hp, wp, wc) = (self.hp, self.wp, self.wc);
        let n = out.len() / wp;
        assert!(n * wp == out.len() && n <= STRIP && y0 + n <= hp && spec.len() == hp * wc);
        let norm = 1.0 / (hp * wp) as f32;
        let mut strip = std::mem::take(&mut self.rows);
        columns_to_rows(spec, &mut strip[..n * wc], wc, hp, y0);
        for (row, o) in strip.chunks_exact_mut(wc).zip(out.chunks_exact_mut(wp)) {
            // A real signal's DC and (even-length) Nyquist bins are real.
            row[0].im = 0.0;
            if wp % 2 == 0 {
                row[wc - 1].im = 0.0;
            }
            self.c2r.process_with_scratch(row, o, &mut self.scratch).expect("c2r sizes match");
            o.iter_mut().for_each(|v| *v *= norm);
        }
        self.rows = strip;
    }
}

/// Rows per strip in [`FftConv::forward`] and [`FftConv::inverse`]: 8 complex values are one
/// 64-byte cache line of a column.
pub const STRIP: usize = 8;

/// Scatters a strip of `n` row spectra (image rows `y0..y0 + n`, `wc` values each) into the
/// transposed layout: `out[j * hp + y0 + i] = strip[i * wc + j]`.
fn rows_to_columns(strip: &[Complex32], out: &mut [Complex32], wc: usize, hp: usize, y0: usize) {
    let n = strip.len() / wc;
    let mut j0 = 0;
    #[cfg(target_arch = "x86_64")]
    if n == STRIP && std::is_x86_feature_detected!("avx2") {
        assert!(out.len() >= wc * hp && y0 + STRIP <= hp);
        // SAFETY: AVX2 is present (checked above); every access is inside `strip` (n x wc) and
        // `out` (wc columns of hp, y0 + 8 <= hp), as asserted.
        j0 = unsafe { blocks_4x4::<true>(strip.as_ptr().cast_mut(), out.as_mut_ptr(), wc, hp, y0) };
    }
    for (j, col) in out.chunks_exact_mut(hp).take(wc).enumerate().skip(j0) {
        for (i, o) in col[y0..y0 + n].iter_mut().enumerate() {
            *o = strip[i * wc + j];
        }
    }
}

/// The inverse of [`rows_to_columns`]: gathers image rows `y0..y0 + n` out of the transposed
/// layout into `strip` (`n` rows of `wc` values).
fn columns_to_rows(spec: &[Complex32], strip: &mut [Complex32], wc: usize, hp: usize, y0: usize) {
    let n = strip.len() / wc;
    let mut j0 = 0;
    #[cfg(target_arch = "x86_64")]
    if n == STRIP && std::is_x86_feature_detected!("avx2") {
        assert!(spec.len() >= wc * hp && y0 + STRIP <= hp);
        // SAFETY: as in `rows_to_columns`, with the roles of the two buffers swapped.
        j0 = unsafe { blocks_4x4::<false>(strip.as_mut_ptr(), spec.as_ptr().cast_mut(), wc, hp, y0) };
    }
    for (j, col) in spec.chunks_exact(hp).take(wc).enumerate().skip(j0) {
        for (i, &v) in col[y0..y0 + n].iter().enumerate() {
            strip[i * wc + j] = v;
        }
    }
}

/// The transposes of a full strip (8 rows) in blocks of 4 x 4 complex values (one 64-bit lane
/// each), four 256-bit loads and stores per block instead of sixteen of each. `TO_COLUMNS`:
/// strip -> columns, else columns -> strip. Returns the first column left for the caller
/// (`wc` rounded down to a multiple of 4). Pure data movement: the same bits.
///
/// # Safety
/// AVX2; `strip` holds 8 x `wc` values, `cols` `wc` columns of `hp` values, `y0 + 8 <= hp`; the
/// buffer read from is only read.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn blocks_4x4<const TO_COLUMNS: bool>(strip: *mut Complex32, cols: *mut Complex32, wc: usize, hp: usize, y0: usize) -> usize {
    use std::arch::x86_64::{__m256d, _mm256_loadu_pd, _mm256_permute2f128_pd, _mm256_storeu_pd, _mm256_unpackhi_pd, _mm256_unpacklo_pd};
    /// # Safety
    /// AVX2 (called from `blocks_4x4` only).
    #[inline(always)]
    unsafe fn transpose(r: [__m256d; 4]) -> [__m256d; 4] {
        // SAFETY: AVX2 is enabled in the only caller; register operations only.
        unsafe {
            let (t0, t1) = (_mm256_unpacklo_pd(r[0], r[1]), _mm256_unpackhi_pd(r[0], r[1]));
            let (t2, t3) = (_mm256_unpacklo_pd(r[2], r[3]), _mm256_unpackhi_pd(r[2], r[3]));
            [
                _mm256_permute2f128_pd::<0x20>(t0, t2),
                _mm256_permute2f128_pd::<0x20>(t1, t3),
                _mm256_permute2f128_pd::<0x31>(t0, t2),
                _mm256_permute2f128_pd::<0x31>(t1, t3),
            ]
        }
    }
    let end = wc / 4 * 4;
    for j in (0..end).step_by(4) {
        for ib in [0, 4] {
            // SAFETY: (block) rows ib..ib + 4 < 8 of the strip, columns j..j + 4 <= wc, and
            // entries y0 + ib..y0 + ib + 4 <= hp of each column, per the function's contract.
            unsafe {
                let row = |k: usize| strip.add((ib + k) * wc + j).cast::<f64>();
                let col = |k: usize| cols.add((j + k) * hp + y0 + ib).cast::<f64>();
                if TO_COLUMNS {
                    let t = transpose(std::array::from_fn(|k| _mm256_loadu_pd(row(k))));
                    (0..4).for_each(|k| _mm256_storeu_pd(col(k), t[k]));
                } else {
                    let t = transpose(std::array::from_fn(|k| _mm256_loadu_pd(col(k))));
                    (0..4).for_each(|k| _mm256_storeu_pd(row(k), t[k]));
                }
            }
        }
    }
    end
}

/// `acc += a * b`, elementwise.
pub fn mul_acc(a: &[Complex32], b: &[Complex32], acc: &mut [Complex32]) {
    for ((o, x), y) in acc.iter_mut().zip(a).zip(b) {
        *o += x * y;
    }
}

/// Mirror index (`abc|cba` without repeating the edge: OpenCV's BORDER_REFLECT_101) of `i` into
/// `0..n`; handles any distance by folding.
pub fn reflect(i: isize, n: usize) -> usize {
    if n == 1 {
        return 0;
    }
    let period = 2 * (n as isize - 1);
    let m = i.rem_euclid(period);
    (if m < n as isize { m } else { period - m }) as usize
}

/// Direct 2-D convolution with reflected borders: the reference the FFT path is tested against.
/// `img` is `h x w`, `kernel` a centred odd square; output `h x w`.
pub fn convolve_direct(img: &[f32], h: usize, w: usize, kernel: &[f32]) -> Vec<f32> {
    let n = (kernel.len() as f64).sqrt().round() as usize;
    let kh = (n / 2) as isize;
    let mut out = vec![0.0f32; h * w];
    for y in 0..h as isize {
        for x in 0..w as isize {
            let mut s = 0.0f64;
            for dy in -kh..=kh {
                for dx in -kh..=kh {
                    let k = kernel[((dy + kh) * n as isize + dx + kh) as usize] as f64;
                    s += k * img[reflect(y - dy, h) * w + reflect(x - dx, w)] as f64;
                }
            }
            out[(y * w as isize + x) as usize] = s as f32;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lcg(seed: &mut u64) -> f32 {
        *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*seed >> 40) as f32) / (1u64 << 24) as f32
    }

    /// Pads `img` (h x w) by `m` reflected pixels into an hp x wp buffer.
    fn pad(img: &[f32], h: usize, w: usize, m: usize, hp: usize, wp: usize) -> Vec<f32> {
        let mut out = vec![0.0f32; hp * wp];
        for y in 0..h + 2 * m {
            for x in 0..w + 2 * m {
                out[y * wp + x] = img[reflect(y as isize - m as isize, h) * w + reflect(x as isize - m as isize, w)];
            }
        }
        out
    }

    #[test]
    fn fft_sum_of_convolutions_equals_direct_convolution() {
        // 45 x 64 transforms (a ragged last strip of rows), then 45 x 45 (an odd row length: no
        // Nyquist bin), then 16 x 24 (whole strips only).
        for (h, w) in [(37, 56), (37, 37), (8, 16)] {
            sum_of_convolutions_equals_direct(h, w);
        }
    }

    fn sum_of_convolutions_equals_direct(h: usize, w: usize) {
        let kn = 9;
        let m = kn / 2;
        let mut seed = 7;
        let imgs: Vec<Vec<f32>> = (0..3).map(|_| (0..h * w).map(|_| lcg(&mut seed)).collect()).collect();
        let kernels: Vec<Vec<f32>> = (0..3).map(|_| (0..kn * kn).map(|_| lcg(&mut seed)).collect()).collect();
        let (hp, wp) = (fast_size(h + 2 * m), fast_size(w + 2 * m));
        let mut conv = FftConv::new(hp, wp);
        let mut acc = conv.zero_spectrum();
        for (img, k) in imgs.iter().zip(&kernels) {
            let ks = conv.kernel_spectrum(k);
            conv.accumulate(&mut pad(img, h, w, m, hp, wp), &ks, &mut acc);
        }
        let mut out = vec![0.0f32; hp * wp];
        conv.inverse(&mut acc, &mut out);
        let mut want = vec![0.0f32; h * w];
        for (img, k) in imgs.iter().zip(&kernels) {
            for (a, b) in want.iter_mut().zip(convolve_direct(img, h, w, k)) {
                *a += b;
            }
        }
        let mut worst = 0.0f32;
        for y in 0..h {
            for x in 0..w {
                worst = worst.max((out[(y + m) * wp + x + m] - want[y * w + x]).abs());
            }
        }
        // Values are sums of ~240 products of magnitude <= 1.
        assert!(worst < 2e-4, "{h} x {w}: max abs error {worst}");
    }

    #[test]
    fn delta_kernel_is_the_identity() {
        let (h, w) = (16, 30);
        let mut seed = 3;
        let img: Vec<f32> = (0..h * w).map(|_| lcg(&mut seed)).collect();
        let mut conv = FftConv::new(h, w);
        let ks = conv.kernel_spectrum(&[1.0]);
        let mut acc = conv.zero_spectrum();
        conv.accumulate(&mut img.clone(), &ks, &mut acc);
        let mut out = vec![0.0; h * w];
        conv.inverse(&mut acc, &mut out);
        for (a, b) in out.iter().zip(&img) {
            assert!((a - b).abs() < 1e-6);
        }
    }

    #[test]
    fn the_row_transform_gives_realffts_bits_at_every_length() {
        let mut seed = 5u64;
        for len in [1, 2, 3, 4, 6, 10, 12, 45, 90, 432, 480, 512] {
            let x: Vec<f32> = (0..len).map(|_| lcg(&mut seed) - 0.5).collect();
            let (mut rp, mut cp) = (RealFftPlanner::<f32>::new(), FftPlanner::<f32>::new());
            let ours = R2c::new(len, &mut rp, &mut cp);
            let theirs = rp.plan_fft_forward(len);
            let (mut a, mut b) = (x.clone(), x.clone());
            let (mut got, mut want) = (theirs.make_output_vec(), theirs.make_output_vec());
            let mut scratch = vec![Complex32::new(0.0, 0.0); ours.scratch_len().max(theirs.get_scratch_len())];
            ours.process(&mut a, &mut got, &mut scratch);
            theirs.process_with_scratch(&mut b, &mut want, &mut scratch).unwrap();
            let bits = |v: &[Complex32]| v.iter().flat_map(|c| [c.re.to_bits(), c.im.to_bits()]).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&want), "length {len}");
            // The vector pass (on this CPU) and the scalar one agree too.
            if let R2c::Even { twiddles, .. } = &ours {
                let mut plain: Vec<Complex32> = (0..len / 2 + 1).map(|_| Complex32::new(lcg(&mut seed), lcg(&mut seed))).collect();
                let mut fast = plain.clone();
                untangle_with(twiddles, &mut plain, false);
                untangle(twiddles, &mut fast);
                assert_eq!(bits(&fast), bits(&plain), "length {len}: vector and scalar pass");
            }
        }
    }

    #[test]
    fn strip_transposes_match_their_definition_and_invert() {
        // A width whose spectrum is not a multiple of 4 columns (the scalar tail) and a height
        // whose last strip is short (the scalar path), full strips through the AVX2 blocks.
        let (wc, hp) = (257usize, 20usize);
        let mut seed = 5u64;
        let mut out = vec![Complex32::new(0.0, 0.0); wc * hp];
        let mut strips = Vec::new();
        for y0 in (0..hp).step_by(STRIP) {
            let n = STRIP.min(hp - y0);
            let strip: Vec<Complex32> = (0..n * wc).map(|_| Complex32::new(lcg(&mut seed), lcg(&mut seed))).collect();
            rows_to_columns(&strip, &mut out, wc, hp, y0);
            for i in 0..n {
                for j in 0..wc {
                    assert_eq!(out[j * hp + y0 + i], strip[i * wc + j], "row {} column {j}", y0 + i);
                }
            }
            strips.push(strip);
        }
        for (s, y0) in strips.iter().zip((0..hp).step_by(STRIP)) {
            let mut back = vec![Complex32::new(0.0, 0.0); s.len()];
            columns_to_rows(&out, &mut back, wc, hp, y0);
            assert_eq!(&back, s, "strip at row {y0}");
        }
    }

    #[test]
    fn reflect_folds_like_border_reflect_101() {
        let got: Vec<usize> = (-4..8).map(|i| reflect(i, 4)).collect();
        assert_eq!(got, vec![2, 3, 2, 1, 0, 1, 2, 3, 2, 1, 0, 1]);
        assert_eq!(fast_size(127), 128);
        assert_eq!(fast_size(721), 768);
        assert_eq!(fast_size(774), 864);
        assert_eq!(fast_size(182), 192);
        assert_eq!(fast_size(481), 512);
    }
}
