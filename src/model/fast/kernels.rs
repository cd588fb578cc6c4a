use super::*;

/// A raw pointer that units running on other threads write through, each into its own
/// disjoint region.
#[derive(Clone, Copy)]
pub(super) struct Ptr(pub(super) *mut f32);
// SAFETY: a Ptr is only made from a buffer that outlives the parallel loop using it, and each
// unit of that loop writes a region no other unit reads or writes (said at each use).
unsafe impl Send for Ptr {}
// SAFETY: as for Send: shared between units that write disjoint regions.
unsafe impl Sync for Ptr {}

/// `dst[m x n] (row stride dst_rs) = (acc ? dst : 0) + a[m x k] * b[k x n]`, single-threaded
/// (parallelism comes from the units around it).
///
/// # Safety
/// Every index the strides reach must be inside the buffers.
#[allow(clippy::too_many_arguments)]
pub(super) unsafe fn mm(
    m: usize,
    n: usize,
    k: usize,
    dst: *mut f32,
    dst_rs: usize,
    acc: bool,
    a: *const f32,
    a_rs: usize,
    a_cs: usize,
    b: *const f32,
    b_rs: usize,
    b_cs: usize,
) {
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        if !acc {
            for i in 0..m {
                // SAFETY: row i's n values are inside `dst` (this function's contract).
                unsafe { std::ptr::write_bytes(dst.add(i * dst_rs), 0, n) };
            }
        }
        return;
    }
    // SAFETY: every index the strides reach is inside the buffers (this function's contract).
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst,
            1,
            dst_rs as isize,
            acc,
            a,
            a_cs as isize,
            a_rs as isize,
            b,
            b_cs as isize,
            b_rs as isize,
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            gemm::Parallelism::None,
        )
    }
}

/// [`mm`] on slices, the reach of every stride checked first: `dst[m x n] (row stride dst_rs) =
/// (acc ? dst : 0) + a[m x k] * b[k x n]` with `a` and `b` given as (values, row stride, column
/// stride). Panics if an index would leave a slice.
pub(super) fn matmul(
    [m, n, k]: [usize; 3],
    (dst, dst_rs): (&mut [f32], usize),
    acc: bool,
    (a, a_rs, a_cs): (&[f32], usize, usize),
    (b, b_rs, b_cs): (&[f32], usize, usize),
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!((m - 1) * dst_rs + n <= dst.len(), "matmul: dst too short");
    if k > 0 {
        assert!((m - 1) * a_rs + (k - 1) * a_cs < a.len(), "matmul: a too short");
        assert!((k - 1) * b_rs + (n - 1) * b_cs < b.len(), "matmul: b too short");
    }
    // SAFETY: every index the strides reach was checked above.
    unsafe { mm(m, n, k, dst.as_mut_ptr(), dst_rs, acc, a.as_ptr(), a_rs, a_cs, b.as_ptr(), b_rs, b_cs) }
}

/// Rows per band so that a band's buffer (`k` rows of `rows * w` values) stays within 1 MiB,
/// cache-sized: a power of two, so that a side that is one (every U-Net level of a 128 x 128
/// patch) splits into equal bands, as many as a power-of-two number of threads can share evenly.
/// A function of the sizes alone.
pub(super) fn band_rows(k: usize, h: usize, w: usize) -> usize {
    let most = ((1usize << 18) / (k * w).max(1)).max(1);
    (1usize << most.ilog2()).min(h.max(1))
}

thread_local! {
    /// Each worker thread's band buffer ([`shifted_band`]), kept across layers and steps: a fresh one per
    /// call was zero-filled every time (3 to 8% of a training step, more with more threads).
    static COL: std::cell::Cell<Vec<f32>> = const { std::cell::Cell::new(Vec::new()) };
    /// Each worker thread's buffer for a band of the output gradient, pixel-major
    /// ([`transpose_band`]), kept the same way.
    static BAND_T: std::cell::Cell<Vec<f32>> = const { std::cell::Cell::new(Vec::new()) };
}

/// Runs `f` with this thread's buffer `key` (taken out for the call, so a nested use gets an
/// empty one rather than a borrow error).
fn with_buf<R>(key: &'static std::thread::LocalKey<std::cell::Cell<Vec<f32>>>, f: impl FnOnce(&mut Vec<f32>) -> R) -> R {
    let mut buf = key.with(|c| c.take());
    let r = f(&mut buf);
    key.with(|c| c.set(buf));
    r
}

/// Runs `f` with this thread's band buffer.
pub(super) fn with_col<R>(f: impl FnOnce(&mut Vec<f32>) -> R) -> R {
    with_buf(&COL, f)
}

/// `c` rows of `npx` values at row stride `rs` from `src`, written pixel-major into the first
/// `npx * c` values of `dst` (`dst[p * c + ch] = src[ch * rs + p]`); tiles of 8 x 8 keep both
/// sides within a few cache lines.
pub(super) fn transpose_band(src: &[f32], c: usize, rs: usize, npx: usize, dst: &mut Vec<f32>) {
    if dst.len() < c * npx {
        dst.resize(c * npx, 0.0);
    }
    const T: usize = 8;
    for c0 in (0..c).step_by(T) {
        let c1 = (c0 + T).min(c);
        for p0 in (0..npx).step_by(T) {
            let p1 = (p0 + T).min(npx);
            for ch in c0..c1 {
                let row = &src[ch * rs..];
                for p in p0..p1 {
                    dst[p * c + ch] = row[p];
                }
            }
        }
    }
}

/// The im2col matrix of rows `r0..r1` of one sample `x` (`cin` planes of `h x w`): row
/// `(ci, ky, kx)` holds `x[ci, y + ky - p, j + kx - p]` (zero outside the image) at
/// `(y - r0) * w + j`, in the first `cin * k^2 * (r1 - r0) * w` values of `col`. Every value is
/// written (copied or zeroed), so the buffer is reused without clearing.
#[allow(clippy::too_many_arguments)]
fn im2col(x: &[f32], cin: usize, h: usize, w: usize, k: usize, r0: usize, r1: usize, col: &mut Vec<f32>) {
    let p = (k / 2) as isize;
    let npx = (r1 - r0) * w;
    if col.len() < cin * k * k * npx {
        col.resize(cin * k * k * npx, 0.0);
    }
    for ci in 0..cin {
        let plane = &x[ci * h * w..(ci + 1) * h * w];
        for ky in 0..k {
            for kx in 0..k {
                let row = &mut col[((ci * k + ky) * k + kx) * npx..][..npx];
                let dx = kx as isize - p;
                let (lo, hi) = shift_span(w, dx);
                for (dst, y) in row.chunks_exact_mut(w).zip(r0..r1) {
                    let sy = y as isize + ky as isize - p;
                    if sy < 0 || sy >= h as isize {
                        dst.fill(0.0);
                    } else {
                        shift_row(&plane[sy as usize * w..][..w], dx, lo, hi, dst);
                    }
                }
            }
        }
    }
}

/// The span `lo..hi` of a row of `w` where `dst[j] = src[j + dx]` lands inside the source row.
fn shift_span(w: usize, dx: isize) -> (usize, usize) {
    let lo = ((-dx).max(0) as usize).min(w);
    (lo, ((w as isize - dx).min(w as isize).max(0) as usize).max(lo))
}

/// `dst[j] = src[j + dx]` on `lo..hi` (from [`shift_span`]), zero elsewhere.
fn shift_row(src: &[f32], dx: isize, lo: usize, hi: usize, dst: &mut [f32]) {
    dst[..lo].fill(0.0);
    dst[lo..hi].copy_from_slice(&src[(lo as isize + dx) as usize..(hi as isize + dx) as usize]);
    dst[hi..].fill(0.0);
}

/// Rows `r0 - p .. r1 + p` of one sample `x` (`cin` planes of `h x w`, `p = k / 2`), each
/// channel `k` times, shifted horizontally by `kx - p`, zero outside the image, in the first
/// `cin * k * len` values of `buf`, `len = (r1 - r0 + k - 1) * w`: row `(ci, kx)` holds
/// `x[ci, r0 - p + t, j + kx - p]` at `t * w + j`. Returns `len`.
///
/// For kernel row `ky`, what output pixel `q = (y - r0) * w + j` of the band takes from channel
/// `ci` and column `kx` is at `(ci * k + kx) * len + ky * w + q`: the `k cin` rows of one `ky`
/// are a uniform stride apart, so the convolution is `k` matrix products over `k cin` rows each,
/// on a third of the copies of an im2col matrix's `k^2 cin` rows (12% of a training step).
/// Every value is written (copied or zeroed), so the buffer is reused without clearing.
#[allow(clippy::too_many_arguments)]
pub(super) fn shifted_band(x: &[f32], cin: usize, h: usize, w: usize, k: usize, r0: usize, r1: usize, buf: &mut Vec<f32>) -> usize {
    let p = (k / 2) as isize;
    let len = (r1 - r0 + k - 1) * w;
    if buf.len() < cin * k * len {
        buf.resize(cin * k * len, 0.0);
    }
    for ci in 0..cin {
        let plane = &x[ci * h * w..(ci + 1) * h * w];
        for kx in 0..k {
            let row = &mut buf[(ci * k + kx) * len..][..len];
            let dx = kx as isize - p;
            let (lo, hi) = shift_span(w, dx);
            for (t, dst) in row.chunks_exact_mut(w).enumerate() {
                let sy = (r0 + t) as isize - p;
                if sy < 0 || sy >= h as isize {
                    dst.fill(0.0);
                } else {
                    shift_row(&plane[sy as usize * w..][..w], dx, lo, hi, dst);
                }
            }
        }
    }
    len
}

/// `[cout, a, b, k]` to `[cout, b, a, k]`: the weights `[cout, cin, ky, kx]` in the order
/// [`shifted_band`]'s products take them (`[cout, ky, cin, kx]`), and back.
pub(super) fn swap_middle(wt: &[f32], cout: usize, a: usize, b: usize, k: usize) -> Vec<f32> {
    let mut out = vec![0.0; wt.len()];
    for co in 0..cout {
        for i in 0..a {
            for j in 0..b {
                let src = &wt[((co * a + i) * b + j) * k..][..k];
                out[((co * b + j) * a + i) * k..][..k].copy_from_slice(src);
            }
        }
    }
    out
}

/// Units of parallel work that a layer is cut into at least, where it can be: bands of rows, and
/// where a small image has too few of those (one 128 x 128 patch at the U-Net's 8 x 8 level has
/// one), blocks of output channels as well. Without them one core did those levels alone.
const MIN_UNITS: usize = 8;

/// Pixels a band keeps at least when it is cut for more units: the matrix product runs 64
/// pixels at a time (gemm's AVX-512 micro-kernel is 64 x 6), and a band under 128 pixels
/// leaves much of it idle.
const MIN_BAND_PX: usize = 128;

/// Output channels a block keeps at least: each block packs its band again for gemm, so blocks
/// of 32 channels packed the band of U-Net 32's 16 x 16 level eight times and made its forward
/// pass 10% slower than no blocks at all.
const MIN_BLOCK: usize = 64;

/// (rows per band, output channels per block) of a convolution's forward units: bands of
/// [`band_rows`] for products of inner size `kin`; where (sample, band) units are fewer than
/// [`MIN_UNITS`], bands halved while they keep [`MIN_BAND_PX`] pixels, then blocks of output
/// channels of at least [`MIN_BLOCK`], as many as that takes. A function of the sizes alone, so
/// the same for any thread count. `min_band`: what a halved band keeps at least, in `w`'s units
/// ([`MIN_BAND_PX`] for pixels; Winograd's bands count 2 x 2 blocks).
pub(super) fn forward_units(n: usize, kin: usize, cout: usize, h: usize, w: usize, min_band: usize) -> (usize, usize) {
    let mut rows = band_rows(kin, h, w);
    while n * h.div_ceil(rows) < MIN_UNITS && rows > 1 && (rows / 2) * w >= min_band {
        rows /= 2;
    }
    let units = n * h.div_ceil(rows);
    let blocks = MIN_UNITS.div_ceil(units).min((cout / MIN_BLOCK).max(1));
    (rows, cout.div_ceil(blocks))
}

/// Inner size `cin * k` from which a convolution takes an im2col matrix and one product
/// (inner size `cin * k^2`) instead of [`shifted_band`]'s `k` products: on the deep levels'
/// wide channels and small images (256 channels at 16 x 16, 512 at 8 x 8) the `k` accumulating
/// products of a 768-deep inner size ran 1.4 to 1.7x slower than one of 2304 (U-Net 32's
/// forward pass 10% slower); at 128 channels and below the shifted band is 3 to 8% faster.
const IM2COL_FROM: usize = 768;

/// A layer's output of `len` values, filled by units `(sample, band, block)` of `[n, nb, nc]`
/// on all cores: `f(sample, band, block, out)` gets a pointer to the whole buffer and writes its
/// own part. Not zeroed first (memset was 8% of a training step's profile).
///
/// # Safety
/// The units together must write every one of the `len` values, and no two units may write
/// the same value: nothing reads the buffer before it is handed back.
pub(super) unsafe fn by_units(len: usize, [n, nb, nc]: [usize; 3], f: impl Fn(usize, usize, usize, Ptr) + Sync) -> Vec<f32> {
    let mut d: Vec<f32> = Vec::with_capacity(len);
    let yp = Ptr(d.as_mut_ptr());
    (0..n * nb * nc).into_par_iter().for_each(|u| {
        // The whole Ptr (Send), not its raw field: closures capture fields separately.
        #[allow(clippy::redundant_locals)]
        let yp = yp;
        f(u / (nb * nc), u / nc % nb, u % nc, yp);
    });
    // SAFETY: every value was written (the caller's contract).
    unsafe { d.set_len(len) };
    d
}

/// `y = conv(x, weight) + bias`: stride 1, zero padding `k / 2`, `weight` as
/// `[cout, cin, k, k]`. Units are (sample, band of rows, block of output channels), all cores.
pub fn conv_forward(x: &T4, weight: &[f32], bias: Option<&[f32]>, cout: usize, k: usize) -> T4 {
    let (n, cin, h, w) = (x.n, x.c, x.h, x.w);
    let kk = cin * k * k;
    assert_eq!(weight.len(), cout * kk, "conv weight size");
    let hw = h * w;
    let by_col = k > 1 && cin * k >= IM2COL_FROM;
    let (rows, cb) = forward_units(n, if by_col { kk } else { cin * k }, cout, h, w, MIN_BAND_PX);
    let nb = h.div_ceil(rows);
    let nc = cout.div_ceil(cb);
    let wp = if k == 1 || by_col { Vec::new() } else { swap_middle(weight, cout, cin, k, k) };
    let unit = |s: usize, band: usize, block: usize, yp: Ptr| {
        let (r0, c0) = (band * rows, block * cb);
        let (r1, c1) = ((r0 + rows).min(h), (c0 + cb).min(cout));
        let (npx, m) = ((r1 - r0) * w, c1 - c0);
        let xs = x.sample(s);
        // SAFETY: each unit writes rows r0..r1 of sample s of output channels c0..c1 only.
        unsafe {
            let dst = yp.0.add((s * cout + c0) * hw + r0 * w);
            if k == 1 {
                mm(m, npx, cin, dst, hw, false, weight.as_ptr().add(c0 * cin), cin, 1, xs.as_ptr().add(r0 * w), hw, 1);
            } else if by_col {
                with_col(|col| {
                    im2col(xs, cin, h, w, k, r0, r1, col);
                    mm(m, npx, kk, dst, hw, false, weight.as_ptr().add(c0 * kk), kk, 1, col.as_ptr(), npx, 1);
                });
            } else {
                with_col(|buf| {
                    let stride = shifted_band(xs, cin, h, w, k, r0, r1, buf);
                    // Per kernel row: rows (ci, kx) of the band, a uniform `stride` apart,
                    // from `ky` rows down; the weights' (ci, kx) block of that row.
                    for ky in 0..k {
                        let (a, b) = (wp.as_ptr().add(c0 * kk + ky * cin * k), buf.as_ptr().add(ky * w));
                        mm(m, npx, cin * k, dst, hw, ky > 0, a, kk, 1, b, stride, 1);
                    }
                });
            }
            if let Some(b) = bias {
                for (co, &bv) in b[c0..c1].iter().enumerate() {
                    let row = std::slice::from_raw_parts_mut(dst.add(co * hw), npx);
                    row.iter_mut().for_each(|v| *v += bv);
                }
            }
        }
    };
    // SAFETY: (`by_units`' contract) the units cover every sample, every row 0..h and every
    // channel 0..cout, and `mm` without `acc` writes all of a unit's values (gemm does not read
    // dst then).
    let d = unsafe { by_units(n * cout * hw, [n, nb, nc], unit) };
    T4 { n, c: cout, h, w, d }
}

/// `[cin, cout, k, k]` flipped in both spatial axes: the weights whose forward convolution of
/// an output gradient is the input gradient.
pub(super) fn flip_transpose(weight: &[f32], cout: usize, cin: usize, k: usize) -> Vec<f32> {
    let mut f = vec![0.0; weight.len()];
    for co in 0..cout {
        for ci in 0..cin {
            for ky in 0..k {
                for kx in 0..k {
                    f[((ci * cout + co) * k + (k - 1 - ky)) * k + (k - 1 - kx)] = weight[((co * cin + ci) * k + ky) * k + kx];
                }
            }
        }
    }
    f
}

/// Gradient of the convolution's input.
pub fn conv_backward_input(dy: &T4, weight: &[f32], cin: usize, k: usize) -> T4 {
    conv_forward(dy, &flip_transpose(weight, dy.c, cin, k), None, cin, k)
}

/// Gradient of the convolution's weight `[cout, cin, k, k]`: per sample, summed in sample order.
///
/// Per band of rows and kernel row `ky`, `G^T[(ci, kx) x cout] += S_ky[(ci, kx) x px] *
/// dy^T[px x cout]`, with `S_ky` the rows of `shifted_band` for that `ky` and the band of `dy`
/// first copied pixel-major. Both `dy` and the input's band run along pixels, the product's
/// inner dimension; gemm wants the operand it packs into its micro-panels to run along the
/// output's contiguous dimension, so given `dy` (or the input) as they are it packs them with a
/// strided gather, which cost more than the products themselves (11% of a U-Net 16 training
/// step against 6%). `dy`'s band is the smaller, so it is the one transposed, once, by
/// `transpose_band`; `G^T` is transposed and its rows put back in (ci, ky, kx) order at the end.
pub fn conv_backward_weight(x: &T4, dy: &T4, k: usize) -> Vec<f32> {
    let (n, cin, h, w, cout) = (x.n, x.c, x.h, x.w, dy.c);
    let kk = cin * k * k;
    let hw = h * w;
    let rows = band_rows(cin * k, h, w);
    let partials: Vec<Vec<f32>> = (0..n)
        .into_par_iter()
        .map(|s| {
            let mut gt = vec![0.0f32; kk * cout];
            let (xs, dys) = (x.sample(s), dy.sample(s));
            let mut r0 = 0;
            while r0 < h {
                let r1 = (r0 + rows).min(h);
                let npx = (r1 - r0) * w;
                with_buf(&BAND_T, |dyt| {
                    transpose_band(&dys[r0 * w..], cout, hw, npx, dyt);
                    // SAFETY: gt is kk x cout; dyt holds npx x cout; x's band is cin rows of
                    // npx at stride hw, the shifted band cin k rows of `stride`.
                    unsafe {
                        if k == 1 {
                            mm(kk, cout, npx, gt.as_mut_ptr(), cout, true, xs.as_ptr().add(r0 * w), hw, 1, dyt.as_ptr(), cout, 1);
                        } else {
                            with_col(|buf| {
                                let stride = shifted_band(xs, cin, h, w, k, r0, r1, buf);
                                // G^T's rows in the order (ky, ci, kx), one block per ky.
                                for ky in 0..k {
                                    let g = gt.as_mut_ptr().add(ky * cin * k * cout);
                                    mm(cin * k, cout, npx, g, cout, true, buf.as_ptr().add(ky * w), stride, 1, dyt.as_ptr(), cout, 1);
                                }
                            });
                        }
                    }
                });
                r0 = r1;
            }
            gt
        })
        .collect();
    // G[co, i] = G^T[i, co]: G^T's kk rows of cout values, written column-major; then from
    // (ky, ci, kx) back to (ci, ky, kx).
    let mut g = Vec::new();
    transpose_band(&sum_in_order(partials), kk, cout, cout, &mut g);
    if k == 1 {
        g
    } else {
        swap_middle(&g, cout, k, cin, k)
    }
}

pub(super) fn sum_in_order(partials: Vec<Vec<f32>>) -> Vec<f32> {
    let mut it = partials.into_iter();
    let mut acc = it.next().unwrap_or_default();
    for p in it {
        acc.iter_mut().zip(&p).for_each(|(a, b)| *a += b);
    }
    acc
}

/// Sum of `t` per channel (over samples and pixels), in f64, fixed order.
pub(super) fn channel_sums(t: &T4) -> Vec<f32> {
    let hw = t.hw();
    (0..t.c).map(|ch| (0..t.n).map(|s| lanes_sum(&t.d[(s * t.c + ch) * hw..][..hw], |v| v)).sum::<f64>() as f32).collect()
}

/// Lanes of f64 accumulators: one sum per lane, added in a fixed order at the end, so the
/// compiler can vectorise what a single running f64 sum serialises (one add per 4 cycles).
pub(super) const LANES: usize = 8;

/// `sum f(x)` over `xs` in f64, with [`LANES`] accumulators added in a fixed order at the end
/// (the same bits for any thread count).
#[inline]
pub(super) fn lanes_sum(xs: &[f32], f: impl Fn(f64) -> f64) -> f64 {
    let mut acc = [0.0f64; LANES];
    let chunks = xs.chunks_exact(LANES);
    let rest = chunks.remainder();
    for c in chunks {
        for (a, &v) in acc.iter_mut().zip(c) {
            *a += f(v as f64);
        }
    }
    rest.iter().fold(acc.iter().sum::<f64>(), |s, &v| s + f(v as f64))
}

/// Runs `f(channel, planes)` for every channel on all cores, where `planes[k][s]` is that
/// channel's plane in sample `s` of `outs[k]`: the planes are split off the tensors up front, so
/// each call holds its own channel's planes and no other.
pub(super) fn per_channel<'a, R: Send, const K: usize>(
    c: usize,
    hw: usize,
    outs: [&'a mut T4; K],
    f: impl Fn(usize, [Vec<&'a mut [f32]>; K]) -> R + Sync,
) -> Vec<R> {
    let mut groups: Vec<[Vec<&'a mut [f32]>; K]> = (0..c).map(|_| std::array::from_fn(|_| Vec::new())).collect();
    for (k, t) in outs.into_iter().enumerate() {
        for (i, plane) in t.d.chunks_mut(hw).enumerate() {
            groups[i % c][k].push(plane);
        }
    }
    groups.into_par_iter().enumerate().map(|(ch, planes)| f(ch, planes)).collect()
}

/// 2x2 max-pooling, stride 2; the backward pass routes the gradient to the first maximum.
pub(super) fn maxpool(x: &T4) -> (T4, Vec<u8>) {
    let (oh, ow) = (x.h / 2, x.w / 2);
    let mut y = T4::zeros(x.n, x.c, oh, ow);
    let mut idx = vec![0u8; y.d.len()];
    y.d.par_chunks_mut(oh * ow).zip(idx.par_chunks_mut(oh * ow)).enumerate().for_each(|(p, (yp, ip))| {
        let xp = &x.d[p * x.h * x.w..][..x.h * x.w];
        for i in 0..oh {
            for j in 0..ow {
                let mut best = f32::NEG_INFINITY;
                let mut at = 0u8;
                for (q, (a, b)) in [(0, 0), (0, 1), (1, 0), (1, 1)].into_iter().enumerate() {
                    let v = xp[(2 * i + a) * x.w + 2 * j + b];
                    if v > best {
                        best = v;
                        at = q as u8;
                    }
                }
                yp[i * ow + j] = best;
                ip[i * ow + j] = at;
            }
        }
    });
    (y, idx)
}

pub(super) fn maxpool_backward(dy: &T4, idx: &[u8], h: usize, w: usize) -> T4 {
    let mut dx = T4::zeros(dy.n, dy.c, h, w);
    let (oh, ow) = (dy.h, dy.w);
    dx.d.par_chunks_mut(h * w).enumerate().for_each(|(p, xp)| {
        for i in 0..oh {
            for j in 0..ow {
                let q = idx[p * oh * ow + i * ow + j] as usize;
                xp[(2 * i + q / 2) * w + 2 * j + q % 2] = dy.d[p * oh * ow + i * ow + j];
            }
        }
    });
    dx
}

/// The 2x2 stride-2 transposed convolution's forward pass (`layers::UpConv`): per unit (sample x
/// band of input rows) one matrix product `T[(co, a, b), px] = w^T x`, then a shuffle of `T` into
/// the output rows `2 r0 .. 2 r1` of that sample, plus the bias.
pub(super) fn upconv_forward(x: &T4, wt: &[f32], bias: &[f32], cout: usize) -> T4 {
    let (n, cin, h, w) = (x.n, x.c, x.h, x.w);
    let c4 = cout * 4;
    let hw = h * w;
    let rows = band_rows(c4, h, w);
    let nb = h.div_ceil(rows);
    let mut y = T4::zeros(n, cout, 2 * h, 2 * w);
    let yp = Ptr(y.d.as_mut_ptr());
    (0..n * nb).into_par_iter().for_each_init(Vec::new, |t, u| {
        // The whole Ptr (Send), not its raw field: closures capture fields separately.
        #[allow(clippy::redundant_locals)]
        let yp = yp;
        let (s, r0) = (u / nb, (u % nb) * rows);
        let r1 = (r0 + rows).min(h);
        let npx = (r1 - r0) * w;
        t.clear();
        t.resize(c4 * npx, 0.0);
        // t is c4 x npx; w is cin x c4 read transposed; x's band is cin x npx at stride hw.
        matmul([c4, npx, cin], (t.as_mut_slice(), npx), false, (wt, 1, c4), (&x.sample(s)[r0 * w..], hw, 1));
        // Output rows 2*r0..2*r1 of sample s belong to this unit only.
        for co in 0..cout {
            let base = s * cout * 4 * hw + co * 4 * hw;
            for q in 0..4 {
                let (a, b) = (q / 2, q % 2);
                let tr = &t[(co * 4 + q) * npx..][..npx];
                for i in r0..r1 {
                    for j in 0..w {
                        // SAFETY: inside sample s, channel co, row 2i+a.
                        unsafe { *yp.0.add(base + (2 * i + a) * 2 * w + 2 * j + b) = tr[(i - r0) * w + j] + bias[co] };
                    }
                }
            }
        }
    });
    y
}
