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
                std::ptr::write_bytes(dst.add(i * dst_rs), 0, n);
            }
        }
        return;
    }
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

/// Rows per band so that a band's im2col matrix (`k` rows of `rows * w` pixels) stays near
/// 1 MiB, cache-sized; a function of the sizes alone.
pub(super) fn band_rows(k: usize, h: usize, w: usize) -> usize {
    ((1usize << 18) / (k * w).max(1)).clamp(1, h.max(1))
}

thread_local! {
    /// Each worker thread's im2col band buffer, kept across layers and steps: a fresh one per
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

/// Runs `f` with this thread's im2col buffer.
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

/// The im2col matrix of rows `r0..r1` of one sample `x` (`cin` planes of `h x w`) in the first
/// `cin * k * k * (r1 - r0) * w` values of `col`: row `(ci, ky, kx)` holds
/// `x[ci, y + ky - p, x + kx - p]` (zero outside) for each pixel of the band. Every one of those
/// values is written (copied or zeroed), so the buffer is reused without clearing; it only grows.
#[allow(clippy::too_many_arguments)]
pub(super) fn im2col(x: &[f32], cin: usize, h: usize, w: usize, k: usize, r0: usize, r1: usize, col: &mut Vec<f32>) {
    let p = (k / 2) as isize;
    let npx = (r1 - r0) * w;
    let need = cin * k * k * npx;
    if col.len() < need {
        col.resize(need, 0.0);
    }
    for ci in 0..cin {
        let plane = &x[ci * h * w..(ci + 1) * h * w];
        for ky in 0..k {
            for kx in 0..k {
                let row = &mut col[((ci * k + ky) * k + kx) * npx..][..npx];
                let dx = kx as isize - p;
                // dst[j] = src[j + dx] where 0 <= j + dx < w, zero elsewhere.
                let lo = ((-dx).max(0) as usize).min(w);
                let hi = ((w as isize - dx).min(w as isize).max(0) as usize).max(lo);
                for y in r0..r1 {
                    let dst = &mut row[(y - r0) * w..][..w];
                    let sy = y as isize + ky as isize - p;
                    if sy < 0 || sy >= h as isize {
                        dst.fill(0.0);
                        continue;
                    }
                    let src = &plane[sy as usize * w..][..w];
                    dst[..lo].fill(0.0);
                    dst[lo..hi].copy_from_slice(&src[(lo as isize + dx) as usize..(hi as isize + dx) as usize]);
                    dst[hi..].fill(0.0);
                }
            }
        }
    }
}

/// `y = conv(x, weight) + bias`: stride 1, zero padding `k / 2`, `weight` as
/// `[cout, cin, k, k]`. Units are (sample, band of rows), all cores.
pub fn conv_forward(x: &T4, weight: &[f32], bias: Option<&[f32]>, cout: usize, k: usize) -> T4 {
    let (n, cin, h, w) = (x.n, x.c, x.h, x.w);
    let kk = cin * k * k;
    assert_eq!(weight.len(), cout * kk, "conv weight size");
    let hw = h * w;
    let rows = band_rows(kk, h, w);
    let nb = h.div_ceil(rows);
    // Not zeroed: the units below write every value (memset was 8% of a training step's profile).
    // Nothing reads it before `set_len`, and by then every value has been written.
    let len = n * cout * hw;
    let mut d: Vec<f32> = Vec::with_capacity(len);
    let yp = Ptr(d.as_mut_ptr());
    (0..n * nb).into_par_iter().for_each(|u| {
        // The whole Ptr (Send), not its raw field: closures capture fields separately.
        #[allow(clippy::redundant_locals)]
        let yp = yp;
        let (s, r0) = (u / nb, (u % nb) * rows);
        let r1 = (r0 + rows).min(h);
        let npx = (r1 - r0) * w;
        let xs = x.sample(s);
        // SAFETY: each unit writes rows r0..r1 of sample s of every output channel only.
        unsafe {
            let dst = yp.0.add(s * cout * hw + r0 * w);
            if k == 1 {
                mm(cout, npx, cin, dst, hw, false, weight.as_ptr(), cin, 1, xs.as_ptr().add(r0 * w), hw, 1);
            } else {
                with_col(|col| {
                    im2col(xs, cin, h, w, k, r0, r1, col);
                    mm(cout, npx, kk, dst, hw, false, weight.as_ptr(), kk, 1, col.as_ptr(), npx, 1);
                });
            }
            if let Some(b) = bias {
                for (co, &bv) in b.iter().enumerate() {
                    let row = std::slice::from_raw_parts_mut(dst.add(co * hw), npx);
                    row.iter_mut().for_each(|v| *v += bv);
                }
            }
        }
    });
    // SAFETY: the (sample, band) units cover every sample and every row 0..h, and `mm` without
    // `acc` writes all `cout` channels of a unit's rows (gemm does not read dst then).
    unsafe { d.set_len(len) };
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
/// Per band of rows, `G^T[kk x cout] += col[kk x px] * dy^T[px x cout]` with the band of `dy`
/// first copied pixel-major. Both `dy` and the im2col matrix run along pixels, the product's
/// inner dimension; gemm wants the operand it packs into its micro-panels to run along the
/// output's contiguous dimension, so given `dy` (or `col`) as they are it packs them with a
/// strided gather, which cost more than the products themselves (11% of a U-Net 16 training
/// step against 6%). `dy`'s band is 9 cin / cout times smaller than the im2col matrix, so it is
/// the one transposed, once, by [`transpose_band`]; `G^T` is transposed back at the end.
pub fn conv_backward_weight(x: &T4, dy: &T4, k: usize) -> Vec<f32> {
    let (n, cin, h, w, cout) = (x.n, x.c, x.h, x.w, dy.c);
    let kk = cin * k * k;
    let hw = h * w;
    let rows = band_rows(kk, h, w);
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
                    // npx at stride hw, the im2col band kk rows of npx.
                    unsafe {
                        if k == 1 {
                            mm(kk, cout, npx, gt.as_mut_ptr(), cout, true, xs.as_ptr().add(r0 * w), hw, 1, dyt.as_ptr(), cout, 1);
                        } else {
                            with_col(|col| {
                                im2col(xs, cin, h, w, k, r0, r1, col);
                                mm(kk, cout, npx, gt.as_mut_ptr(), cout, true, col.as_ptr(), npx, 1, dyt.as_ptr(), cout, 1);
                            });
                        }
                    }
                });
                r0 = r1;
            }
            gt
        })
        .collect();
    // G[co, i] = G^T[i, co]: G^T's kk rows of cout values, written column-major.
    let mut g = Vec::new();
    transpose_band(&sum_in_order(partials), kk, cout, cout, &mut g);
    g
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
