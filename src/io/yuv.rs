//! 8-bit planar Y'CbCr (4:2:0, 4:2:2, 4:4:4) to planar 8-bit R'G'B', written for the decoder's
//! hot path: the chroma is upsampled bilinearly with centre siting (the weights 3/4 and 1/4 per
//! axis, what swscale's bilinear, full-chroma-interpolation path computes for these formats), the
//! matrix and range are the stream's, and each row is a few passes of f32 arithmetic that the
//! compiler vectorises. swscale's accurate path spent as long converting a 720p frame as FFmpeg
//! spent decoding it; this one costs a fraction of that (numbers in README.md) and gives the
//! same values within one level (tested against swscale in `io::video`).

/// The luma weights of a Y'CbCr matrix (Kr, Kb).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Matrix {
    pub kr: f32,
    pub kb: f32,
}

impl Matrix {
    pub const BT601: Matrix = Matrix { kr: 0.299, kb: 0.114 };
    pub const BT709: Matrix = Matrix { kr: 0.2126, kb: 0.0722 };
    pub const BT2020: Matrix = Matrix { kr: 0.2627, kb: 0.0593 };
    pub const SMPTE240M: Matrix = Matrix { kr: 0.212, kb: 0.087 };
    pub const FCC: Matrix = Matrix { kr: 0.30, kb: 0.11 };
}

/// One conversion: matrix, range and chroma subsampling (log2 per axis: 1, 1 for 4:2:0).
#[derive(Debug, Clone, Copy)]
pub struct Converter {
    /// Per output channel R, G, B: weights of (Y, Cb, Cr) and the offset, folded with the range.
    rows: [[f32; 4]; 3],
    pub sub_x: u32,
    pub sub_y: u32,
}

/// A decoded frame's three planes and its size (luma pixels).
#[derive(Debug, Clone, Copy)]
pub struct Source<'a> {
    pub y: Plane<'a>,
    pub cb: Plane<'a>,
    pub cr: Plane<'a>,
    pub w: usize,
    pub h: usize,
}

/// One 8-bit plane: its bytes and the stride between rows.
#[derive(Debug, Clone, Copy)]
pub struct Plane<'a> {
    pub data: &'a [u8],
    pub stride: usize,
}

impl Converter {
    /// `full_range`: Y and C use 0..255 (JPEG); else 16..235 and 16..240 (video).
    pub fn new(m: Matrix, full_range: bool, sub_x: u32, sub_y: u32) -> Converter {
        let kg = 1.0 - m.kr - m.kb;
        let (ys, cs, y0) = if full_range { (1.0f32, 1.0f32, 0.0f32) } else { (255.0 / 219.0, 255.0 / 224.0, 16.0) };
        // R = Y' + 2(1 - Kr) Cr;  B = Y' + 2(1 - Kb) Cb;  G = Y' - (2 Kb (1 - Kb) Cb + 2 Kr (1 - Kr) Cr) / Kg
        let (r_cr, b_cb) = (2.0 * (1.0 - m.kr) * cs, 2.0 * (1.0 - m.kb) * cs);
        let (g_cb, g_cr) = (-2.0 * m.kb * (1.0 - m.kb) / kg * cs, -2.0 * m.kr * (1.0 - m.kr) / kg * cs);
        // Offsets for Y - y0 and C - 128, plus 0.5 so that truncation rounds.
        let row = |cb: f32, cr: f32| [ys, cb, cr, -ys * y0 - 128.0 * (cb + cr) + 0.5];
        Converter { rows: [row(0.0, r_cr), row(g_cb, g_cr), row(b_cb, 0.0)], sub_x, sub_y }
    }

    /// Converts a whole frame into three planes of `w x h` bytes (R, G, B), no padding.
    /// The same arithmetic (no fused multiply-adds) on every CPU; AVX2 only makes it wider.
    pub fn convert(&self, src: &Source, out: [&mut [u8]; 3]) {
        self.dispatch(src, (0, 0, src.w, src.h), out)
    }

    /// Converts the `rw x rh` rectangle at (x0, y0) of a frame (inside it) into three planes
    /// of `rw x rh` bytes: each pixel the same as in [`Converter::convert`].
    pub fn convert_rect(&self, src: &Source, rect: (usize, usize, usize, usize), out: [&mut [u8]; 3]) {
        self.dispatch(src, rect, out)
    }

    fn dispatch(&self, src: &Source, rect: (usize, usize, usize, usize), out: [&mut [u8]; 3]) {
        #[cfg(target_arch = "x86_64")]
        if std::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2, checked just above.
            return unsafe { self.convert_avx2(src, rect, out) };
        }
        self.convert_any(src, rect, out, false)
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn convert_avx2(&self, src: &Source, rect: (usize, usize, usize, usize), out: [&mut [u8]; 3]) {
        self.convert_any(src, rect, out, true)
    }

    /// Converts the rectangle (x0, y0, rw, rh); pixel (x, y) goes to `out[(y - y0) * rw + x - x0]`.
    /// `simd`: pack the output rows with AVX2 ([`rgb_row_avx2`]; only from `convert_avx2`).
    #[inline(always)]
    fn convert_any(&self, src: &Source, rect: (usize, usize, usize, usize), out: [&mut [u8]; 3], simd: bool) {
        let Source { y, cb, cr, w, h } = *src;
        let cw = (w + (1 << self.sub_x) - 1) >> self.sub_x;
        let ch = (h + (1 << self.sub_y) - 1) >> self.sub_y;
        let (x0, y0, rw, rh) = rect;
        let x1 = (x0 + rw).min(w);
        if x0 >= x1 {
            return;
        }
        let mut vrow = [vec![0.0f32; cw], vec![0.0f32; cw]];
        let mut full = [vec![0.0f32; w], vec![0.0f32; w]];
        let [r, g, b] = out;
        let (cx0, cx1) = ((x0 >> self.sub_x).saturating_sub(1), ((x1 - 1) >> self.sub_x) + 2);
        for yy in y0..(y0 + rh).min(h) {
            // The rows read PREFETCH_ROWS rows from now, into the cache (a rectangle's rows are
            // short and a stride apart: the hardware prefetchers miss them).
            if yy + crate::frame::PREFETCH_ROWS < h {
                let ahead = yy + crate::frame::PREFETCH_ROWS;
                crate::frame::prefetch(&y.data[ahead * y.stride + x0..ahead * y.stride + x1]);
                let (r0, r1, _) = taps(ahead, self.sub_y, ch);
                for p in [cb, cr] {
                    for row in [r0, r1] {
                        crate::frame::prefetch(&p.data[row * p.stride + cx0.min(cw)..row * p.stride + cx1.min(cw)]);
                    }
                }
            }
            // Vertical: the two chroma rows around this luma row and their weights, over the
            // chroma columns this run reads (its own and one either side).
            let (r0, r1, w1) = taps(yy, self.sub_y, ch);
            let (c0, c1) = if self.sub_x == 0 { (x0, x1) } else { ((x0 >> 1).saturating_sub(1), (((x1 - 1) >> 1) + 2).min(cw)) };
            for (c, p) in [cb, cr].iter().enumerate() {
                let (a, bb) = (&p.data[r0 * p.stride + c0..r0 * p.stride + c1], &p.data[r1 * p.stride + c0..r1 * p.stride + c1]);
                vrow[c][c0..c1].iter_mut().zip(a.iter().zip(bb)).for_each(|(o, (&a, &b))| *o = a as f32 + w1 * (b as f32 - a as f32));
                upsample_span(&vrow[c], self.sub_x, &mut full[c], x0, x1);
            }
            let lum = &y.data[yy * y.stride + x0..yy * y.stride + x1];
            let (u, v) = (&full[0][x0..x1], &full[1][x0..x1]);
            let base = (yy - y0) * rw;
            for (o, k) in [&mut *r, &mut *g, &mut *b].into_iter().zip(&self.rows) {
                let o = &mut o[base..base + (x1 - x0)];
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `simd` is only true in the AVX2 build (`convert_avx2`).
                let done = if simd { unsafe { rgb_row_avx2(k, lum, u, v, o) } } else { 0 };
                #[cfg(not(target_arch = "x86_64"))]
                let done = 0;
                rgb_row(k, &lum[done..], &u[done..], &v[done..], &mut o[done..]);
            }
        }
    }
}

/// One output channel of a row: `k . (Y, Cb, Cr, 1)`, clamped to 0..255 and truncated (the
/// offset in `k` carries the + 0.5 that makes it round).
#[inline(always)]
fn rgb_row(k: &[f32; 4], lum: &[u8], u: &[f32], v: &[f32], o: &mut [u8]) {
    for (((o, &l), &u), &v) in o.iter_mut().zip(lum).zip(u).zip(v) {
        let x = (k[0] * l as f32 + k[1] * u + k[2] * v + k[3]).clamp(0.0, 255.0);
        // SAFETY: x is finite and in [0, 255] (clamped), so the conversion is exact
        // truncation; unlike `as`, it needs no saturation checks and vectorises.
        *o = unsafe { x.to_int_unchecked::<i32>() } as u8;
    }
}

/// [`rgb_row`] 32 pixels at a time, returning how many it did (the rest is the caller's): the
/// same multiplies and adds in the same order (no fused multiply-add), so the same bytes. The
/// compiler's version packed each 8 results to bytes with two shuffles and a 64-bit store,
/// half of the conversion's time; here 32 results take two packs, one permute and one store
/// (the packs saturate, which changes nothing: the values are already clamped to 0..255).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn rgb_row_avx2(k: &[f32; 4], lum: &[u8], u: &[f32], v: &[f32], o: &mut [u8]) -> usize {
    use std::arch::x86_64::*;
    let n = o.len().min(lum.len()).min(u.len()).min(v.len());
    let [k0, k1, k2, k3] = k.map(|c| _mm256_set1_ps(c));
    let (lo, hi) = (_mm256_setzero_ps(), _mm256_set1_ps(255.0));
    let order = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    let mut x = 0;
    while x + 32 <= n {
        let mut q = [_mm256_setzero_si256(); 4];
        for (j, q) in q.iter_mut().enumerate() {
            let at = x + 8 * j;
            // SAFETY: at + 8 <= x + 32 <= n, within every slice.
            let (l, uu, vv) = unsafe {
                let l = _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(lum.as_ptr().add(at).cast())));
                (l, _mm256_loadu_ps(u.as_ptr().add(at)), _mm256_loadu_ps(v.as_ptr().add(at)))
            };
            let s = _mm256_add_ps(_mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(k0, l), _mm256_mul_ps(k1, uu)), _mm256_mul_ps(k2, vv)), k3);
            *q = _mm256_cvttps_epi32(_mm256_min_ps(_mm256_max_ps(s, lo), hi));
        }
        // Packs work per 128-bit lane: the bytes come out as 4-pixel groups
        // (q0 q1 q2 q3 low halves | high halves); the permute puts them back in order.
        let p = _mm256_packus_epi16(_mm256_packs_epi32(q[0], q[1]), _mm256_packs_epi32(q[2], q[3]));
        // SAFETY: x + 32 <= n <= o.len().
        unsafe { _mm256_storeu_si256(o.as_mut_ptr().add(x).cast(), _mm256_permutevar8x32_epi32(p, order)) };
        x += 32;
    }
    x
}

/// Chroma rows (`r0`, `r1`) and the weight of `r1` for luma row `y` (centre siting; edges
/// repeat the last row).
fn taps(y: usize, sub: u32, n: usize) -> (usize, usize, f32) {
    if sub == 0 {
        return (y, y, 0.0);
    }
    // Chroma sample j sits at luma coordinate 2j + 0.5: luma row y is chroma j = y / 2 - 1/4.
    let j = y >> 1;
    let last = n - 1;
    if y & 1 == 0 {
        (j.saturating_sub(1).min(last), j.min(last), if j == 0 { 0.0 } else { 0.75 })
    } else {
        (j.min(last), (j + 1).min(last), 0.25)
    }
}

/// Horizontal upsampling of a chroma row to luma columns `x0..x1` of `out`, as [`taps`] does
/// vertically: `out[2i] = 3/4 c[i] + 1/4 c[i-1]`, `out[2i+1] = 3/4 c[i] + 1/4 c[i+1]`, edges
/// repeated. Reads `c` only around those columns.
#[inline(always)]
fn upsample_span(c: &[f32], sub: u32, out: &mut [f32], x0: usize, x1: usize) {
    if sub == 0 {
        out[x0..x1].copy_from_slice(&c[x0..x1]);
        return;
    }
    let n = c.len();
    let at = |x: usize| {
        let i = (x >> 1).min(n - 1);
        let nb = if x & 1 == 0 { i.saturating_sub(1) } else { (i + 1).min(n - 1) };
        0.75 * c[i] + 0.25 * c[nb]
    };
    // Interior pairs (both neighbours exist, both pixels in the run), on slices of one length
    // so that the loop has no bounds checks and vectorises (an interleaving store); the same
    // expression as `at`, so the same bits.
    let i0 = x0.div_ceil(2).max(1);
    let i1 = (x1 / 2).min(n.saturating_sub(1)).max(i0);
    let k = i1 - i0;
    if k > 0 {
        let (prev, cur, next) = (&c[i0 - 1..i1 - 1], &c[i0..i1], &c[i0 + 1..i1 + 1]);
        let o = &mut out[2 * i0..2 * i1];
        for i in 0..k {
            let m = 0.75 * cur[i];
            o[2 * i] = m + 0.25 * prev[i];
            o[2 * i + 1] = m + 0.25 * next[i];
        }
    }
    for x in (x0..(2 * i0).min(x1)).chain((2 * i1).max(x0)..x1) {
        out[x] = at(x);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(v: &[u8], stride: usize) -> Plane<'_> {
        Plane { data: v, stride }
    }

    #[test]
    fn bt601_limited_reference_colours() {
        // Y'CbCr of 75% colour bars (ITU-R BT.601, studio range) and their R'G'B' (0-255):
        // white 235/128/128, yellow 162/44/142, cyan 131/156/44, red 65/100/212, blue 35/212/114.
        let bars: [([u8; 3], [u8; 3]); 5] = [
            ([235, 128, 128], [255, 255, 255]),
            ([162, 44, 142], [191, 191, 0]),
            ([131, 156, 44], [0, 191, 191]),
            ([65, 100, 212], [191, 0, 0]),
            ([35, 212, 114], [0, 0, 191]),
        ];
        let conv = Converter::new(Matrix::BT601, false, 0, 0);
        for (ycc, rgb) in bars {
            let (y, u, v) = ([ycc[0]], [ycc[1]], [ycc[2]]);
            let (mut r, mut g, mut b) = ([0u8], [0u8], [0u8]);
            conv.convert(&Source { y: plane(&y, 1), cb: plane(&u, 1), cr: plane(&v, 1), w: 1, h: 1 }, [&mut r, &mut g, &mut b]);
            for (got, want) in [r[0], g[0], b[0]].iter().zip(rgb) {
                assert!((*got as i32 - want as i32).abs() <= 1, "{ycc:?} -> {:?}, want {rgb:?}", [r[0], g[0], b[0]]);
            }
        }
    }

    #[test]
    fn full_range_grey_is_the_luma_and_chroma_is_bilinear() {
        // A 4:2:0 frame of grey luma 100 whose Cr is 128 except one chroma sample: the red
        // channel moves by the Cr weight times 3/4 x 3/4 next to it, and not at all two chroma
        // samples away.
        let (w, h) = (8usize, 8usize);
        let y = vec![100u8; w * h];
        let u = vec![128u8; 16];
        let mut v = vec![128u8; 16];
        v[4 + 1] = 228; // chroma (1, 1): luma 2..4 x 2..4
        let conv = Converter::new(Matrix::BT709, true, 1, 1);
        let (mut r, mut g, mut b) = (vec![0u8; 64], vec![0u8; 64], vec![0u8; 64]);
        conv.convert(&Source { y: plane(&y, w), cb: plane(&u, 4), cr: plane(&v, 4), w, h }, [&mut r, &mut g, &mut b]);
        let k = 2.0 * (1.0 - 0.2126);
        let at = |x: usize, yy: usize| r[yy * w + x] as f32;
        assert_eq!(b, vec![100u8; 64], "Cb is neutral: blue equals luma");
        assert!((at(2, 2) - (100.0 + k * 100.0 * 0.5625)).abs() <= 0.5, "{}", at(2, 2));
        assert!((at(1, 2) - (100.0 + k * 100.0 * 0.1875)).abs() <= 0.5, "{}", at(1, 2));
        assert_eq!(at(6, 6), 100.0);
        assert_eq!(at(0, 0), 100.0);
    }

    #[test]
    fn odd_sizes_read_only_their_planes() {
        // 5 x 3 luma with 3 x 2 chroma: no index past the planes (a panic would fail the test).
        let y = vec![50u8; 15];
        let c = vec![128u8; 6];
        let conv = Converter::new(Matrix::BT601, false, 1, 1);
        let (mut r, mut g, mut b) = (vec![0u8; 15], vec![0u8; 15], vec![0u8; 15]);
        conv.convert(&Source { y: plane(&y, 5), cb: plane(&c, 3), cr: plane(&c, 3), w: 5, h: 3 }, [&mut r, &mut g, &mut b]);
        let want = ((50.0 - 16.0) * 255.0 / 219.0f32 + 0.5) as u8;
        assert!(r.iter().chain(&g).chain(&b).all(|&v| v == want), "{r:?}");
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn packed_rows_have_the_same_bytes_in_the_vector_and_the_scalar_build() {
        if !std::is_x86_feature_detected!("avx2") {
            return;
        }
        // Values below 0 and above 255 after the matrix (clamped), near .5 (rounding), and a
        // length with a scalar tail.
        let n = 32 * 5 + 13;
        let lum: Vec<u8> = (0..n).map(|i| ((i * 37 + 11) % 256) as u8).collect();
        let u: Vec<f32> = (0..n).map(|i| ((i * 53) % 256) as f32 + 0.25 * (i % 4) as f32).collect();
        let v: Vec<f32> = (0..n).map(|i| ((i * 91 + 7) % 256) as f32 - 0.5 * (i % 3) as f32).collect();
        for conv in [Converter::new(Matrix::BT709, false, 1, 1), Converter::new(Matrix::BT601, true, 1, 1)] {
            for k in &conv.rows {
                let mut want = vec![0u8; n];
                rgb_row(k, &lum, &u, &v, &mut want);
                let mut got = vec![0u8; n];
                // SAFETY: AVX2 checked above.
                let done = unsafe { rgb_row_avx2(k, &lum, &u, &v, &mut got) };
                assert_eq!(done, 160);
                rgb_row(k, &lum[done..], &u[done..], &v[done..], &mut got[done..]);
                assert_eq!(got, want);
                assert!(want.contains(&0) && want.contains(&255), "the clamps are exercised");
            }
        }
    }

    #[test]
    fn rectangles_convert_to_the_same_bytes_as_the_whole_frame() {
        // Random planes, every subsampling, rectangles starting and ending on odd and even
        // columns and rows, at the edges and inside: each pixel equals the whole conversion's.
        let (w, h) = (37usize, 23usize);
        let mut seed = 7u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 33) as u8
        };
        for (sx, sy) in [(1u32, 1u32), (1, 0), (0, 0)] {
            let (cw, ch) = ((w + (1 << sx) - 1) >> sx, (h + (1 << sy) - 1) >> sy);
            let y: Vec<u8> = (0..w * h).map(|_| next()).collect();
            let u: Vec<u8> = (0..cw * ch).map(|_| next()).collect();
            let v: Vec<u8> = (0..cw * ch).map(|_| next()).collect();
            let conv = Converter::new(Matrix::BT709, false, sx, sy);
            let mut whole = [vec![0u8; w * h], vec![0u8; w * h], vec![0u8; w * h]];
            let [a, b, c] = &mut whole;
            conv.convert(&Source { y: plane(&y, w), cb: plane(&u, cw), cr: plane(&v, cw), w, h }, [a, b, c]);
            for rect in [(0usize, 0usize, 5usize, 4usize), (3, 1, 9, 7), (12, 9, 25, 14), (36, 22, 1, 1), (1, 0, 36, 23), (0, 5, 37, 1)] {
                let (x0, y0, rw, rh) = rect;
                let mut part = [vec![0u8; rw * rh], vec![0u8; rw * rh], vec![0u8; rw * rh]];
                let [a, b, c] = &mut part;
                conv.convert_rect(&Source { y: plane(&y, w), cb: plane(&u, cw), cr: plane(&v, cw), w, h }, rect, [a, b, c]);
                for ch_ in 0..3 {
                    for yy in 0..rh {
                        for x in 0..rw {
                            let want = whole[ch_][(y0 + yy) * w + x0 + x];
                            assert_eq!(part[ch_][yy * rw + x], want, "sub {sx},{sy} rect {rect:?} channel {ch_} at ({x}, {yy})");
                        }
                    }
                }
            }
        }
    }
}
