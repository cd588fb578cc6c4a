//! Winograd F(2x2, 3x3) convolutions (Lavin and Gray, "Fast Algorithms for Convolutional
//! Neural Networks", 2016): each 2 x 2 block of outputs is computed from a 4 x 4 block of
//! inputs with 16 multiplications per (input, output) channel pair instead of 36. The input
//! blocks and the weights are transformed (`V = B^T d B`, `U = G g G^T`), the 16 positions of
//! those 4 x 4 transforms are 16 independent matrix products over the channels
//! (`M[xi] = U[xi] V[xi]`), and each output block is `A^T M A`.
//!
//! The forward pass (inference and training) and the input gradient take it on the layers
//! [`worth_it`] accepts; the weight gradient stays the direct product. The results differ from
//! the direct convolution by float rounding only (the transforms add and subtract, and halve
//! in `G`): tested against it here, and whole networks' gradients against burn's
//! (`tests.rs`). Deterministic: units depend on the sizes alone.

use super::kernels::{by_units, forward_units, mm, Ptr};
use super::T4;

/// The transformed weights `U = G g G^T` of `[cout, cin, 3, 3]` weights, as 16 matrices of
/// `[cout, cin]` (position `xi = 4 i + j` of the 4 x 4 transform), computed in f64.
pub fn weights(weight: &[f32], cout: usize, cin: usize) -> Vec<f32> {
    assert_eq!(weight.len(), cout * cin * 9, "3x3 weights");
    let mut u = vec![0.0f32; 16 * cout * cin];
    // G = [[1, 0, 0], [1/2, 1/2, 1/2], [1/2, -1/2, 1/2], [0, 0, 1]].
    let g_rows = |a: f64, b: f64, c: f64| [a, 0.5 * (a + b + c), 0.5 * (a - b + c), c];
    for co in 0..cout {
        for ci in 0..cin {
            let g = &weight[(co * cin + ci) * 9..][..9];
            let g = |r: usize, c: usize| g[r * 3 + c] as f64;
            // G g: 4 x 3, by columns.
            let cols: [[f64; 4]; 3] = std::array::from_fn(|c| g_rows(g(0, c), g(1, c), g(2, c)));
            for i in 0..4 {
                let row = g_rows(cols[0][i], cols[1][i], cols[2][i]);
                for (j, v) in row.into_iter().enumerate() {
                    u[((4 * i + j) * cout + co) * cin + ci] = v as f32;
                }
            }
        }
    }
    u
}

/// Whether a layer of `cin` inputs and `cout` outputs on `h x w` takes [`conv3x3`]: at least
/// `MIN_CHANNELS` each way and `MIN_BLOCKS` blocks. One 128 x 128 patch, 2 threads, one
/// layer against the direct convolution (`pipeline bench kernels`, medians of 31): 16 channels on
/// 128 x 128 0.57x, 32 on 128 0.70x, 32 on 64 0.92x, 64 on 64 0.66x, 64 on 32 0.78x, 128 on 32
/// 0.61x, 128 on 16 0.49x, 256 on 16 0.57x; but 512 on 8 x 8 1.17x (16 blocks: products only
/// 16 columns wide).
pub fn worth_it(cin: usize, cout: usize, h: usize, w: usize) -> bool {
    cin >= MIN_CHANNELS && cout >= MIN_CHANNELS && h.div_ceil(2) * w.div_ceil(2) >= MIN_BLOCKS
}

/// 2 x 2 output blocks a layer needs at least for [`worth_it`] (a 16 x 16 image).
const MIN_BLOCKS: usize = 64;

/// Input and output channels a layer needs at least for [`worth_it`].
const MIN_CHANNELS: usize = 16;

/// What an inference BatchNorm and (leaky) ReLU do to each value of channel `c` of a
/// convolution's output: `act(v * scale[c] + shift[c])`, `act(v) = v > 0 ? v : slope * v`.
pub struct Post {
    pub scale: Vec<f32>,
    pub shift: Vec<f32>,
    pub slope: f32,
}

impl Post {
    /// Applies channel `c`'s map to `values`.
    #[inline(always)]
    pub fn apply(&self, c: usize, values: &mut [f32]) {
        let (scale, shift, slope) = (self.scale[c], self.shift[c], self.slope);
        values.iter_mut().for_each(|v| {
            let y = *v * scale + shift;
            *v = if y > 0.0 { y } else { slope * y };
        });
    }
}

thread_local! {
    /// Each worker's transformed inputs and products, kept across layers and calls.
    static BUFS: std::cell::Cell<(Vec<f32>, Vec<f32>)> = const { std::cell::Cell::new((Vec::new(), Vec::new())) };
}

/// `y = conv(x, weight) + bias` for 3 x 3 kernels, stride 1, zero padding 1, from the
/// transformed weights `u` ([`weights`]). Units are (sample, band of block rows, block of output
/// channels), their shapes a function of the sizes alone, so the result is the same for any
/// thread count.
pub fn conv3x3(x: &T4, u: &[f32], bias: Option<&[f32]>, cout: usize, post: Option<&Post>) -> T4 {
    let (n, cin, h, w) = (x.n, x.c, x.h, x.w);
    assert_eq!(u.len(), 16 * cout * cin, "transformed weight size");
    let (th, tw) = (h.div_ceil(2), w.div_ceil(2));
    // The direct convolution's unit rules on the grid of blocks: a band's transformed inputs
    // (16 cin per block) within `band_rows`' budget taken as an inner size of 64 cin, so 256 KiB
    // (1 MiB was no faster, and slower at 256 channels on 16 x 16), and a halved band keeping
    // 32 blocks (128 px, as the direct convolution's bands).
    let (rows, cb) = forward_units(n, 64 * cin, cout, th, tw, 32);
    let nb = th.div_ceil(rows);
    let nc = cout.div_ceil(cb);
    let hw = h * w;
    let unit = |s: usize, band: usize, block: usize, yp: Ptr| {
        let (b0, c0) = (band * rows, block * cb);
        let (b1, c1) = ((b0 + rows).min(th), (c0 + cb).min(cout));
        let (t, m) = ((b1 - b0) * tw, c1 - c0);
        let mut bufs = BUFS.with(|c| c.take());
        let (v, prod) = &mut bufs;
        v.resize(v.len().max(16 * cin * t), 0.0);
        prod.resize(prod.len().max(16 * m * t), 0.0);
        transform_inputs(x.sample(s), cin, h, w, b0, b1, v);
        for xi in 0..16 {
            // SAFETY: U[xi] rows c0..c1 (cin each), V[xi] (cin x t) and M[xi] (m x t) are
            // inside `u`, `v` and `prod` (sized above).
            unsafe {
                let a = u.as_ptr().add((xi * cout + c0) * cin);
                let b = v.as_ptr().add(xi * cin * t);
                mm(m, t, cin, prod.as_mut_ptr().add(xi * m * t), t, false, a, cin, 1, b, t, 1);
            }
        }
        // SAFETY: (of `transform_outputs`' contract) this unit writes rows 2 b0 .. 2 b1
        // (within h) of channels c0..c1 of sample s, inside the buffer; no other unit
        // writes or reads them.
        let out = Ptr(unsafe { yp.0.add((s * cout + c0) * hw) });
        transform_outputs(prod, (m, t), (h, w), (b0, b1), bias.map(|b| &b[c0..c1]), post.map(|p| (p, c0)), out);
        BUFS.with(|c| c.set(bufs));
    };
    // SAFETY: (`by_units`' contract) the units cover every sample, block row and output
    // channel, and `transform_outputs` writes every value of its rows.
    let d = unsafe { by_units(n * cout * hw, [n, nb, nc], unit) };
    T4 { n, c: cout, h, w, d }
}

/// Runs `$body` (an `#[inline(always)]` function) compiled for AVX-512 or AVX2 where the CPU
/// has them, else as it is: the transforms add and subtract, and the BatchNorm multiplies and
/// adds without fusing, so every build gives the same bits (test below), and the wider builds
/// vectorise the whole-row loops 16 or 8 lanes at a time.
macro_rules! multiversion {
    ($name:ident, $body:ident, ($($arg:ident: $ty:ty),*)) => {
        #[allow(clippy::too_many_arguments)]
        fn $name($($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn wide($($arg: $ty),*) {
                    $body($($arg),*)
                }
                #[target_feature(enable = "avx2")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn avx2($($arg: $ty),*) {
                    $body($($arg),*)
                }
                if std::is_x86_feature_detected!("avx512f") {
                    // SAFETY: the CPU has AVX-512F.
                    return unsafe { wide($($arg),*) };
                }
                if std::is_x86_feature_detected!("avx2") {
                    // SAFETY: the CPU has AVX2.
                    return unsafe { avx2($($arg),*) };
                }
            }
            $body($($arg),*)
        }
    };
}

multiversion!(transform_inputs, inputs_body, (x: &[f32], cin: usize, h: usize, w: usize, b0: usize, b1: usize, v: &mut [f32]));
multiversion!(
    transform_outputs,
    outputs_body,
    (
        prod: &[f32],
        mt: (usize, usize),
        hw: (usize, usize),
        bands: (usize, usize),
        bias: Option<&[f32]>,
        post: Option<(&Post, usize)>,
        out: Ptr
    )
);

/// `a[j] = f(b[j], c[j])` over the shortest of the three.
#[inline(always)]
fn zip2(a: &mut [f32], b: &[f32], c: &[f32], f: impl Fn(f32, f32) -> f32) {
    a.iter_mut().zip(b.iter().zip(c)).for_each(|(o, (&x, &y))| *o = f(x, y));
}

/// `V = B^T d B` of every 4 x 4 input block of block rows `b0..b1` of one sample (`cin` planes
/// of `h x w`, zero outside), into `v` as 16 matrices `[cin, t]` (`t` blocks, row-major).
/// `B^T = [[1, 0, -1, 0], [0, 1, 1, 0], [0, -1, 1, 0], [0, 1, 0, -1]]`.
///
/// Each input row is split into its odd and even columns first (block `c` reads columns
/// `2c - 1 .. 2c + 3`: odd `c`, even `c`, odd `c + 1`, even `c + 1` below), so that every later
/// step reads and writes whole contiguous runs and vectorises.
#[inline(always)]
fn inputs_body(x: &[f32], cin: usize, h: usize, w: usize, b0: usize, b1: usize, v: &mut [f32]) {
    let tw = w.div_ceil(2);
    let t = (b1 - b0) * tw;
    // Per input row: `[odd, even]` with odd[c] = column 2c - 1 and even[c] = column 2c, for c
    // in 0..=tw (zero outside the row).
    let split = || [vec![0.0f32; tw + 1], vec![0.0f32; tw + 1]];
    let mut rows = [split(), split(), split(), split()];
    let mut r = [split(), split(), split(), split()];
    for ci in 0..cin {
        let plane = &x[ci * h * w..][..h * w];
        for b in b0..b1 {
            // Input rows 2b - 1 .. 2b + 3.
            for (k, [odd, even]) in rows.iter_mut().enumerate() {
                let y = (2 * b + k) as isize - 1;
                if y < 0 || y >= h as isize {
                    odd.fill(0.0);
                    even.fill(0.0);
                    continue;
                }
                let row = &plane[y as usize * w..][..w];
                odd[0] = 0.0;
                odd[1..].iter_mut().zip(row[1..].chunks_exact(2)).for_each(|(o, pair)| *o = pair[0]);
                even.iter_mut().zip(row.chunks_exact(2)).for_each(|(e, pair)| *e = pair[0]);
                if w % 2 == 1 {
                    // The last column is even; the odd one after it is outside.
                    even[tw - 1] = row[w - 1];
                    odd[tw] = 0.0;
                } else {
                    odd[tw] = row[w - 1];
                }
                even[tw] = 0.0;
            }
            // B^T down the rows, on the odd and the even columns alike.
            for half in 0..2 {
                let [d0, d1, d2, d3] = [&rows[0][half], &rows[1][half], &rows[2][half], &rows[3][half]];
                let [r0, r1, r2, r3] = &mut r;
                zip2(&mut r0[half], d0, d2, |a, c| a - c);
                zip2(&mut r1[half], d1, d2, |b, c| b + c);
                zip2(&mut r2[half], d2, d1, |c, b| c - b);
                zip2(&mut r3[half], d1, d3, |b, d| b - d);
            }
            // B along each block's columns.
            let at = ci * t + (b - b0) * tw;
            for (i, [odd, even]) in r.iter().enumerate() {
                let (o0, o1, e0, e1) = (&odd[..tw], &odd[1..=tw], &even[..tw], &even[1..=tw]);
                let plane = |j: usize| (4 * i + j) * cin * t + at;
                zip2(&mut v[plane(0)..][..tw], o0, o1, |a, c| a - c);
                zip2(&mut v[plane(1)..][..tw], e0, o1, |b, c| b + c);
                zip2(&mut v[plane(2)..][..tw], o1, e0, |c, b| c - b);
                zip2(&mut v[plane(3)..][..tw], e0, e1, |b, d| b - d);
            }
        }
    }
}

/// `Y = A^T M A` of every block from the products `prod` (16 matrices `[m, t]`), plus the bias,
/// then `post` (with the unit's first output channel) if any, into rows `2 b0 .. 2 b1` (within
/// `h`) of the `m` output planes at `out` (each `h x w`). `A^T = [[1, 1, 1, 0], [0, 1, -1, -1]]`.
///
/// Contract (the reason `out` is a [`Ptr`]: units of other bands write the other rows of the
/// same planes at the same time): `out` points to `m` planes of `h x w`, and the caller lets
/// this call alone write and read those rows; each row is made a slice of its own.
#[inline(always)]
fn outputs_body(
    prod: &[f32],
    (m, t): (usize, usize),
    (h, w): (usize, usize),
    (b0, b1): (usize, usize),
    bias: Option<&[f32]>,
    post: Option<(&Post, usize)>,
    out: Ptr,
) {
    let tw = w.div_ceil(2);
    let row = || [vec![0.0f32; tw], vec![0.0f32; tw], vec![0.0f32; tw], vec![0.0f32; tw]];
    let (mut s, mut d, mut tmp) = (row(), row(), vec![0.0f32; tw]);
    let (mut even, mut odd) = (vec![0.0f32; tw], vec![0.0f32; tw]);
    for co in 0..m {
        let bv = bias.map_or(0.0, |b| b[co]);
        for b in b0..b1 {
            let at = (b - b0) * tw;
            let p = |xi: usize| &prod[(xi * m + co) * t + at..][..tw];
            // A^T down the rows of M: for each column j, s = m0 + m1 + m2, d = m1 - m2 - m3.
            for j in 0..4 {
                let (m0, m1, m2, m3) = (p(j), p(4 + j), p(8 + j), p(12 + j));
                zip2(&mut tmp, m0, m1, |a, b| a + b);
                zip2(&mut s[j], &tmp, m2, |ab, c| ab + c);
                zip2(&mut tmp, m1, m2, |b, c| b - c);
                zip2(&mut d[j], &tmp, m3, |bc, e| bc - e);
            }
            // A along each block's columns; output rows 2b and 2b + 1.
            for (k, src) in [&s, &d].into_iter().enumerate() {
                let y = 2 * b + k;
                if y >= h {
                    continue;
                }
                zip2(&mut tmp, &src[0], &src[1], |a, b| a + b);
                zip2(&mut even, &tmp, &src[2], |ab, c| ab + c + bv);
                zip2(&mut tmp, &src[1], &src[2], |b, c| b - c);
                zip2(&mut odd, &tmp, &src[3], |bc, e| bc - e + bv);
                if let Some((p, c0)) = post {
                    p.apply(c0 + co, &mut even);
                    p.apply(c0 + co, &mut odd);
                }
                // SAFETY: row y of output channel co is inside the planes at `out` and no one
                // else writes or reads it while this runs (the caller's contract).
                let line = unsafe { std::slice::from_raw_parts_mut(out.0.add(co * h * w + y * w), w) };
                line.chunks_exact_mut(2).zip(even.iter().zip(&odd)).for_each(|(o, (&e, &q))| {
                    o[0] = e;
                    o[1] = q;
                });
                if w % 2 == 1 {
                    line[w - 1] = even[tw - 1];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::fast::kernels::conv_forward;

    fn values(len: usize, seed: u64) -> Vec<f32> {
        (0..len).map(|i| ((crate::rng::mix(seed ^ i as u64) >> 40) as f32 / (1u64 << 24) as f32) - 0.5).collect()
    }

    #[test]
    fn winograd_equals_the_direct_convolution_on_odd_and_even_sizes() {
        // (n, cin, cout, h, w): odd sides (a last half block), one band, several bands and
        // channel blocks, a bias and none.
        for &(n, cin, cout, h, w, bias) in &[
            (1, 16, 16, 5, 7, true),
            (2, 32, 48, 16, 16, false),
            (1, 64, 128, 8, 8, true),
            (1, 24, 160, 33, 30, true),
            (3, 16, 16, 64, 64, false),
        ] {
            let x = T4::new(n, cin, h, w, values(n * cin * h * w, 1));
            let wt = values(cout * cin * 9, 2);
            let b = values(cout, 3);
            let bias = bias.then_some(&b[..]);
            let direct = conv_forward(&x, &wt, bias, cout, 3);
            let fast = conv3x3(&x, &weights(&wt, cout, cin), bias, cout, None);
            assert_eq!((fast.n, fast.c, fast.h, fast.w), (n, cout, h, w));
            let peak = direct.d.iter().fold(0.0f32, |a, v| a.max(v.abs()));
            let worst = direct.d.iter().zip(&fast.d).fold(0.0f32, |a, (p, q)| a.max((p - q).abs()));
            assert!(worst <= 1e-5 * peak, "{n}x{cin}->{cout} {h}x{w}: {worst} of peak {peak}");
        }
    }

    #[test]
    fn batchnorm_and_activation_inside_the_output_transform_equal_a_pass_after_it() {
        let (cin, cout, h, w) = (16, 24, 9, 12);
        let x = T4::new(2, cin, h, w, values(2 * cin * h * w, 8));
        let wt = values(cout * cin * 9, 9);
        let post = Post { scale: values(cout, 10).iter().map(|v| 1.0 + v).collect(), shift: values(cout, 11), slope: 0.1 };
        let u = weights(&wt, cout, cin);
        let fused = conv3x3(&x, &u, None, cout, Some(&post));
        let mut after = conv3x3(&x, &u, None, cout, None);
        for (i, plane) in after.d.chunks_exact_mut(h * w).enumerate() {
            post.apply(i % cout, plane);
        }
        assert_eq!(fused.d, after.d);
        // And some values went through each side of the activation.
        assert!(fused.d.iter().any(|&v| v < 0.0) && fused.d.iter().any(|&v| v > 0.0));
    }

    #[test]
    fn the_vector_builds_of_the_transforms_give_the_baseline_builds_bits() {
        // `transform_*` run the AVX-512 (or AVX2) build where the CPU has it; `*_body` called
        // directly is the baseline x86-64 build. Odd sides, two bands, a bias and a post.
        let (cin, m, h, w) = (5, 3, 11, 13);
        let x = values(cin * h * w, 12);
        let (tw, th) = (w.div_ceil(2), h.div_ceil(2));
        let (b0, b1) = (1, th);
        let t = (b1 - b0) * tw;
        let (mut fast, mut plain) = (vec![0.0f32; 16 * cin * t], vec![0.0f32; 16 * cin * t]);
        transform_inputs(&x, cin, h, w, b0, b1, &mut fast);
        inputs_body(&x, cin, h, w, b0, b1, &mut plain);
        assert_eq!(fast, plain);
        let prod = values(16 * m * t, 13);
        let bias = values(m, 14);
        let post = Post { scale: values(4, 15), shift: values(4, 16), slope: 0.2 };
        let (mut fast, mut plain) = (vec![0.0f32; m * h * w], vec![0.0f32; m * h * w]);
        transform_outputs(&prod, (m, t), (h, w), (b0, b1), Some(&bias), Some((&post, 1)), Ptr(fast.as_mut_ptr()));
        outputs_body(&prod, (m, t), (h, w), (b0, b1), Some(&bias), Some((&post, 1)), Ptr(plain.as_mut_ptr()));
        assert_eq!(fast, plain);
        assert!(fast[2 * w..].iter().any(|&v| v != 0.0), "rows of the bands were written");
    }

    #[test]
    fn winograd_results_do_not_depend_on_the_thread_count() {
        let x = T4::new(1, 32, 16, 16, values(32 * 256, 4));
        let u = weights(&values(128 * 32 * 9, 5), 128, 32);
        let run =
            |t: usize| rayon::ThreadPoolBuilder::new().num_threads(t).build().expect("pool").install(|| conv3x3(&x, &u, None, 128, None));
        assert_eq!(run(1).d, run(3).d);
    }

    #[test]
    fn a_wrong_transform_is_caught() {
        // The comparison above can fail: a weight transform with G's halves dropped differs.
        let x = T4::new(1, 16, 6, 6, values(16 * 36, 6));
        let wt = values(16 * 16 * 9, 7);
        let direct = conv_forward(&x, &wt, None, 16, 3);
        let mut u = weights(&wt, 16, 16);
        u[5 * 256..6 * 256].iter_mut().for_each(|v| *v *= 2.0);
        let fast = conv3x3(&x, &u, None, 16, None);
        let worst = direct.d.iter().zip(&fast.d).fold(0.0f32, |a, (p, q)| a.max((p - q).abs()));
        assert!(worst > 1e-3, "{worst}");
    }
}
