//! The CPU fast path: the same two networks as [`super::Net`], forward and backward written out
//! as im2col + matrix products (the `gemm` crate) on all cores (rayon).
//!
//! Why it exists: burn 0.22's CPU backend (flex) computes a convolution's weight gradient with a
//! nearly scalar loop for small batches and its input gradient through a col2im scatter, so a
//! training step ran 6 to 11 times slower than PyTorch on the same CPU. This module is the one
//! boundary around that work-around: [`FastNet::from_net`] copies a burn [`Net`]'s weights and
//! running statistics in, [`FastNet::write_into`] copies them back, so burn keeps the module
//! definitions, safetensors checkpoints and the GPU backends. When burn's CPU convolutions catch
//! up, deleting this file (and the `Engine::Fast` arms that call it) is the whole change.
//!
//! Layout: `[n, c, h, w]` row-major f32, as burn's. Convolutions are stride 1 with zero
//! padding `k / 2` (k = 1 or 3); the input gradient is the forward convolution of the output
//! gradient with the weights flipped and transposed, so forward and backward share one kernel.
//!
//! Determinism: work is split into units (sample x band of rows) whose shape depends only on the
//! tensor sizes, never on the thread count; per-unit partial weight gradients are summed in unit
//! order, and per-channel statistics are summed in a fixed order in f64. The same seed gives the
//! same weights with any number of threads.
//!
//! Longer than 600 lines on purpose: the layers' forward and backward passes share one buffer
//! layout (NCHW, im2col columns, row bands) and its helpers; split by op, one layout would be
//! spread over files. A third of the file is the tests against burn at the end.

use super::Net;
use burn::module::Param;
use burn::nn::conv::{Conv2d, ConvTranspose2d};
use burn::nn::BatchNorm;
use burn::tensor::{Tensor, TensorData};
use rayon::prelude::*;
use std::sync::Arc;

/// A `[n, c, h, w]` f32 tensor.
#[derive(Debug, Clone, PartialEq)]
pub struct T4 {
    pub n: usize,
    pub c: usize,
    pub h: usize,
    pub w: usize,
    pub d: Vec<f32>,
}

impl T4 {
    pub fn zeros(n: usize, c: usize, h: usize, w: usize) -> T4 {
        T4 { n, c, h, w, d: vec![0.0; n * c * h * w] }
    }
    pub fn new(n: usize, c: usize, h: usize, w: usize, d: Vec<f32>) -> T4 {
        assert_eq!(d.len(), n * c * h * w, "T4 data length");
        T4 { n, c, h, w, d }
    }
    fn hw(&self) -> usize {
        self.h * self.w
    }
    fn sample(&self, s: usize) -> &[f32] {
        let len = self.c * self.hw();
        &self.d[s * len..(s + 1) * len]
    }
    /// From a burn tensor (any device).
    pub fn from_tensor(t: Tensor<4>) -> T4 {
        let [n, c, h, w] = t.dims();
        T4::new(n, c, h, w, values(t))
    }
    pub fn to_tensor(&self, device: &burn::tensor::Device) -> Tensor<4> {
        Tensor::<4>::from_data(TensorData::new(self.d.clone(), [self.n, self.c, self.h, self.w]), device)
    }
}

/// A raw pointer that units running on other threads write through, each into its own
/// disjoint region.
#[derive(Clone, Copy)]
struct Ptr(*mut f32);
unsafe impl Send for Ptr {}
unsafe impl Sync for Ptr {}

/// `dst[m x n] (row stride dst_rs) = (acc ? dst : 0) + a[m x k] * b[k x n]`, single-threaded
/// (parallelism comes from the units around it).
///
/// # Safety
/// Every index the strides reach must be inside the buffers.
#[allow(clippy::too_many_arguments)]
unsafe fn mm(
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

/// Rows per band so that a band's im2col matrix (`k` rows of `rows * w` pixels) stays near
/// 1 MiB, cache-sized; a function of the sizes alone.
fn band_rows(k: usize, h: usize, w: usize) -> usize {
    ((1usize << 18) / (k * w).max(1)).clamp(1, h.max(1))
}

/// The im2col matrix of rows `r0..r1` of one sample `x` (`cin` planes of `h x w`): row
/// `(ci, ky, kx)` holds `x[ci, y + ky - p, x + kx - p]` (zero outside) for each pixel of the band.
#[allow(clippy::too_many_arguments)]
fn im2col(x: &[f32], cin: usize, h: usize, w: usize, k: usize, r0: usize, r1: usize, col: &mut Vec<f32>) {
    let p = (k / 2) as isize;
    let npx = (r1 - r0) * w;
    col.clear();
    col.resize(cin * k * k * npx, 0.0);
    for ci in 0..cin {
        let plane = &x[ci * h * w..(ci + 1) * h * w];
        for ky in 0..k {
            for kx in 0..k {
                let row = &mut col[((ci * k + ky) * k + kx) * npx..][..npx];
                let dx = kx as isize - p;
                for y in r0..r1 {
                    let sy = y as isize + ky as isize - p;
                    if sy < 0 || sy >= h as isize {
                        continue; // already zero
                    }
                    let src = &plane[sy as usize * w..][..w];
                    let dst = &mut row[(y - r0) * w..][..w];
                    // dst[j] = src[j + dx] where 0 <= j + dx < w.
                    let lo = (-dx).max(0) as usize;
                    let hi = (w as isize - dx).min(w as isize).max(0) as usize;
                    if lo < hi {
                        dst[lo..hi].copy_from_slice(&src[(lo as isize + dx) as usize..(hi as isize + dx) as usize]);
                    }
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
    let mut y = T4::zeros(n, cout, h, w);
    let yp = Ptr(y.d.as_mut_ptr());
    (0..n * nb).into_par_iter().for_each_init(Vec::new, |col, u| {
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
                im2col(xs, cin, h, w, k, r0, r1, col);
                mm(cout, npx, kk, dst, hw, false, weight.as_ptr(), kk, 1, col.as_ptr(), npx, 1);
            }
            if let Some(b) = bias {
                for (co, &bv) in b.iter().enumerate() {
                    let row = std::slice::from_raw_parts_mut(dst.add(co * hw), npx);
                    row.iter_mut().for_each(|v| *v += bv);
                }
            }
        }
    });
    y
}

/// `[cin, cout, k, k]` flipped in both spatial axes: the weights whose forward convolution of
/// an output gradient is the input gradient.
fn flip_transpose(weight: &[f32], cout: usize, cin: usize, k: usize) -> Vec<f32> {
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
pub fn conv_backward_weight(x: &T4, dy: &T4, k: usize) -> Vec<f32> {
    let (n, cin, h, w, cout) = (x.n, x.c, x.h, x.w, dy.c);
    let kk = cin * k * k;
    let hw = h * w;
    let rows = band_rows(kk, h, w);
    let partials: Vec<Vec<f32>> = (0..n)
        .into_par_iter()
        .map(|s| {
            let mut g = vec![0.0f32; cout * kk];
            let mut col = Vec::new();
            let (xs, dys) = (x.sample(s), dy.sample(s));
            let mut r0 = 0;
            while r0 < h {
                let r1 = (r0 + rows).min(h);
                let npx = (r1 - r0) * w;
                // SAFETY: g is cout x kk; dy's band is cout rows of npx at stride hw.
                unsafe {
                    if k == 1 {
                        mm(cout, kk, npx, g.as_mut_ptr(), kk, true, dys.as_ptr().add(r0 * w), hw, 1, xs.as_ptr().add(r0 * w), 1, hw);
                    } else {
                        im2col(xs, cin, h, w, k, r0, r1, &mut col);
                        mm(cout, kk, npx, g.as_mut_ptr(), kk, true, dys.as_ptr().add(r0 * w), hw, 1, col.as_ptr(), 1, npx);
                    }
                }
                r0 = r1;
            }
            g
        })
        .collect();
    sum_in_order(partials)
}

fn sum_in_order(partials: Vec<Vec<f32>>) -> Vec<f32> {
    let mut it = partials.into_iter();
    let mut acc = it.next().unwrap_or_default();
    for p in it {
        acc.iter_mut().zip(&p).for_each(|(a, b)| *a += b);
    }
    acc
}

/// Sum of `t` per channel (over samples and pixels), in f64, fixed order.
fn channel_sums(t: &T4) -> Vec<f32> {
    let hw = t.hw();
    (0..t.c)
        .map(|ch| (0..t.n).map(|s| t.d[(s * t.c + ch) * hw..][..hw].iter().map(|&v| v as f64).sum::<f64>()).sum::<f64>() as f32)
        .collect()
}

/// Runs `f(channel, plane)` for every channel on all cores, where `plane(k, s)` is the plane of
/// that channel in sample `s` of `outs[k]`: each call writes only its own channel's planes (the
/// `'static` slices live as long as `outs`, which outlives the call).
fn per_channel<R: Send>(
    c: usize,
    hw: usize,
    outs: &mut [&mut T4],
    f: impl Fn(usize, &mut dyn FnMut(usize, usize) -> &'static mut [f32]) -> R + Sync,
) -> Vec<R> {
    let ptrs: Vec<Ptr> = outs.iter_mut().map(|t| Ptr(t.d.as_mut_ptr())).collect();
    (0..c)
        .into_par_iter()
        .map(|ch| {
            let ptrs = &ptrs;
            // SAFETY: the planes of channel ch are written by this unit only.
            let mut plane = |which: usize, s: usize| -> &'static mut [f32] {
                unsafe { std::slice::from_raw_parts_mut(ptrs[which].0.add((s * c + ch) * hw), hw) }
            };
            f(ch, &mut plane)
        })
        .collect()
}

/// A convolution (no padding beyond `k / 2`, stride 1) with its gradient buffers.
#[derive(Debug, Clone)]
pub struct Conv {
    pub cin: usize,
    pub cout: usize,
    pub k: usize,
    pub w: Vec<f32>,
    pub b: Option<Vec<f32>>,
    gw: Vec<f32>,
    gb: Vec<f32>,
    x: Option<Arc<T4>>,
}

impl Conv {
    fn from_burn(c: &Conv2d) -> Conv {
        let [cout, cin, k, k2] = c.weight.val().dims();
        assert_eq!(k, k2, "square kernels only");
        let w = values(c.weight.val());
        let b = c.bias.as_ref().map(|b| values(b.val()));
        Conv { cin, cout, k, gw: vec![0.0; w.len()], gb: vec![0.0; b.as_ref().map_or(0, Vec::len)], w, b, x: None }
    }
    fn write(&self, c: &mut Conv2d) {
        c.weight = Param::initialized(c.weight.id, tensor(&self.w, [self.cout, self.cin, self.k, self.k], &c.weight.val().device()));
        if let (Some(p), Some(b)) = (c.bias.as_mut(), &self.b) {
            *p = Param::initialized(p.id, tensor(b, [self.cout], &p.val().device()));
        }
    }
    fn forward(&self, x: &T4) -> T4 {
        conv_forward(x, &self.w, self.b.as_deref(), self.cout, self.k)
    }
    fn forward_train(&mut self, x: Arc<T4>) -> T4 {
        let y = self.forward(&x);
        self.x = Some(x);
        y
    }
    /// Accumulates the weight (and bias) gradient; returns the input gradient if asked.
    fn backward(&mut self, dy: &T4, need_dx: bool) -> Option<T4> {
        let x = self.x.take().expect("forward_train before backward");
        let gw = conv_backward_weight(&x, dy, self.k);
        self.gw.iter_mut().zip(&gw).for_each(|(a, b)| *a += b);
        if self.b.is_some() {
            self.gb.iter_mut().zip(channel_sums(dy)).for_each(|(a, b)| *a += b);
        }
        need_dx.then(|| conv_backward_input(dy, &self.w, self.cin, self.k))
    }
    fn params(&mut self, f: &mut dyn FnMut(&mut [f32], &mut [f32])) {
        f(&mut self.w, &mut self.gw);
        if let Some(b) = self.b.as_mut() {
            f(b, &mut self.gb);
        }
    }
}

fn tensor<const D: usize>(v: &[f32], shape: [usize; D], device: &burn::tensor::Device) -> Tensor<D> {
    Tensor::<D>::from_data(TensorData::new(v.to_vec(), shape), device)
}

/// The values of a float tensor of any rank, row-major.
fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().expect("f32 tensor")
}

/// Conv (no bias) + BatchNorm + (leaky) ReLU, fused.
#[derive(Debug, Clone)]
pub struct ConvBnAct {
    conv: Conv,
    gamma: Vec<f32>,
    beta: Vec<f32>,
    rmean: Vec<f32>,
    rvar: Vec<f32>,
    momentum: f32,
    eps: f32,
    slope: f32,
    ggamma: Vec<f32>,
    gbeta: Vec<f32>,
    cache: Option<(T4, Arc<T4>, Vec<f32>)>, // xhat, output, 1 / std
}

impl ConvBnAct {
    fn from_burn(conv: &Conv2d, bn: &BatchNorm, slope: f32) -> ConvBnAct {
        let c = bn.gamma.val().dims()[0];
        ConvBnAct {
            conv: Conv::from_burn(conv),
            gamma: values(bn.gamma.val()),
            beta: values(bn.beta.val()),
            rmean: values(bn.running_mean.value_sync()),
            rvar: values(bn.running_var.value_sync()),
            momentum: bn.momentum as f32,
            eps: bn.epsilon as f32,
            slope,
            ggamma: vec![0.0; c],
            gbeta: vec![0.0; c],
            cache: None,
        }
    }
    fn write(&self, conv: &mut Conv2d, bn: &mut BatchNorm) {
        self.conv.write(conv);
        let dev = bn.gamma.val().device();
        let c = self.gamma.len();
        bn.gamma = Param::initialized(bn.gamma.id, tensor(&self.gamma, [c], &dev));
        bn.beta = Param::initialized(bn.beta.id, tensor(&self.beta, [c], &dev));
        // `update` files the value under this thread; `value_sync` makes it the value.
        bn.running_mean.update(tensor(&self.rmean, [c], &dev));
        bn.running_var.update(tensor(&self.rvar, [c], &dev));
        let _ = (bn.running_mean.value_sync(), bn.running_var.value_sync());
    }
    fn act(&self, v: f32) -> f32 {
        if v > 0.0 {
            v
        } else {
            self.slope * v
        }
    }
    /// Inference: BatchNorm with its running statistics.
    fn forward(&self, x: &T4) -> T4 {
        let mut z = self.conv.forward(x);
        let hw = z.hw();
        for s in 0..z.n {
            for ch in 0..z.c {
                let scale = self.gamma[ch] / (self.rvar[ch] + self.eps).sqrt();
                let shift = self.beta[ch] - self.rmean[ch] * scale;
                for v in &mut z.d[(s * z.c + ch) * hw..][..hw] {
                    *v = self.act(*v * scale + shift);
                }
            }
        }
        z
    }
    /// Training: BatchNorm with the batch's statistics (biased variance, as burn), running
    /// statistics updated with the momentum.
    fn forward_train(&mut self, x: Arc<T4>) -> Arc<T4> {
        let z = self.conv.forward_train(x);
        let (n, c, hw) = (z.n, z.c, z.hw());
        let m = (n * hw) as f64;
        let mut xhat = T4::zeros(n, c, z.h, z.w);
        let mut out = T4::zeros(n, c, z.h, z.w);
        let (gamma, beta, eps, slope) = (&self.gamma, &self.beta, self.eps as f64, self.slope);
        let stats = per_channel(c, hw, &mut [&mut xhat, &mut out], |ch, plane| {
            let zp = |s: usize| &z.d[(s * c + ch) * hw..][..hw];
            let mean = (0..n).map(|s| zp(s).iter().map(|&v| v as f64).sum::<f64>()).sum::<f64>() / m;
            let var = (0..n).map(|s| zp(s).iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>()).sum::<f64>() / m;
            let inv = 1.0 / (var + eps).sqrt();
            let (g, b, meanf, invf) = (gamma[ch], beta[ch], mean as f32, inv as f32);
            for s in 0..n {
                let xh = plane(0, s);
                for (d, &v) in xh.iter_mut().zip(zp(s)) {
                    *d = (v - meanf) * invf;
                }
                let o = plane(1, s);
                for (d, &v) in o.iter_mut().zip(xh.iter()) {
                    let p = g * v + b;
                    *d = if p > 0.0 { p } else { slope * p };
                }
            }
            (mean as f32, var as f32, inv as f32)
        });
        let mo = self.momentum;
        let mut inv = Vec::with_capacity(c);
        for (ch, (mean, var, i)) in stats.into_iter().enumerate() {
            self.rmean[ch] = self.rmean[ch] * (1.0 - mo) + mean * mo;
            self.rvar[ch] = self.rvar[ch] * (1.0 - mo) + var * mo;
            inv.push(i);
        }
        let out = Arc::new(out);
        self.cache = Some((xhat, out.clone(), inv));
        out
    }
    fn backward(&mut self, dout: &T4, need_dx: bool) -> Option<T4> {
        let (xhat, out, inv) = self.cache.take().expect("forward_train before backward");
        let (n, c, hw) = (dout.n, dout.c, dout.hw());
        let m = (n * hw) as f64;
        let mut dz = T4::zeros(n, c, dout.h, dout.w);
        let (gamma, slope) = (&self.gamma, self.slope);
        let sums = per_channel(c, hw, &mut [&mut dz], |ch, plane| {
            let at = |s: usize| (s * c + ch) * hw;
            // dpre = dout * act'(pre); act'(pre) follows the sign of the output.
            let mut sb = 0.0f64;
            let mut sg = 0.0f64;
            for s in 0..n {
                let dp = plane(0, s);
                let (o, d, xh) = (&out.d[at(s)..][..hw], &dout.d[at(s)..][..hw], &xhat.d[at(s)..][..hw]);
                let mut b = 0.0f64;
                let mut g = 0.0f64;
                for i in 0..hw {
                    let v = if o[i] > 0.0 { d[i] } else { slope * d[i] };
                    dp[i] = v;
                    b += v as f64;
                    g += (v * xh[i]) as f64;
                }
                sb += b;
                sg += g;
            }
            let k = gamma[ch] * inv[ch];
            let (mb, mg) = ((sb / m) as f32, (sg / m) as f32);
            for s in 0..n {
                let dp = plane(0, s);
                let xh = &xhat.d[at(s)..][..hw];
                for i in 0..hw {
                    dp[i] = k * (dp[i] - mb - xh[i] * mg);
                }
            }
            (sg as f32, sb as f32)
        });
        for (ch, (g, b)) in sums.into_iter().enumerate() {
            self.ggamma[ch] += g;
            self.gbeta[ch] += b;
        }
        self.conv.backward(&dz, need_dx)
    }
    fn params(&mut self, f: &mut dyn FnMut(&mut [f32], &mut [f32])) {
        self.conv.params(f);
        f(&mut self.gamma, &mut self.ggamma);
        f(&mut self.beta, &mut self.gbeta);
    }
}

/// Two ConvBnAct with LeakyReLU 0.01.
#[derive(Debug, Clone)]
struct Double {
    a: ConvBnAct,
    b: ConvBnAct,
}

impl Double {
    fn from_burn(d: &super::DoubleConv) -> Double {
        Double { a: ConvBnAct::from_burn(&d.a.conv, &d.a.bn, 0.01), b: ConvBnAct::from_burn(&d.b.conv, &d.b.bn, 0.01) }
    }
    fn write(&self, d: &mut super::DoubleConv) {
        self.a.write(&mut d.a.conv, &mut d.a.bn);
        self.b.write(&mut d.b.conv, &mut d.b.bn);
    }
    fn forward(&self, x: &T4) -> T4 {
        self.b.forward(&self.a.forward(x))
    }
    fn forward_train(&mut self, x: Arc<T4>) -> Arc<T4> {
        let y = self.a.forward_train(x);
        self.b.forward_train(y)
    }
    fn backward(&mut self, d: &T4, need_dx: bool) -> Option<T4> {
        let d = self.b.backward(d, true).expect("dx");
        self.a.backward(&d, need_dx)
    }
    fn params(&mut self, f: &mut dyn FnMut(&mut [f32], &mut [f32])) {
        self.a.params(f);
        self.b.params(f);
    }
}

/// 2x2 max-pooling, stride 2; the backward pass routes the gradient to the first maximum.
fn maxpool(x: &T4) -> (T4, Vec<u8>) {
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

fn maxpool_backward(dy: &T4, idx: &[u8], h: usize, w: usize) -> T4 {
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

/// The 2x2 stride-2 transposed convolution with bias: `y[co, 2i+a, 2j+b] = sum_ci
/// w[ci, co, a, b] x[ci, i, j] + bias[co]`, a matrix product plus a shuffle.
#[derive(Debug, Clone)]
struct UpConv {
    cin: usize,
    cout: usize,
    w: Vec<f32>,
    b: Vec<f32>,
    gw: Vec<f32>,
    gb: Vec<f32>,
    x: Option<Arc<T4>>,
}

impl UpConv {
    fn from_burn(c: &ConvTranspose2d) -> UpConv {
        let [cin, cout, kh, kw] = c.weight.val().dims();
        assert!(kh == 2 && kw == 2 && c.stride == [2, 2], "2x2 stride-2 transposed convolutions only");
        let w = values(c.weight.val());
        let b = c.bias.as_ref().map_or(vec![0.0; cout], |b| values(b.val()));
        UpConv { cin, cout, gw: vec![0.0; w.len()], gb: vec![0.0; cout], w, b, x: None }
    }
    fn write(&self, c: &mut ConvTranspose2d) {
        c.weight = Param::initialized(c.weight.id, tensor(&self.w, [self.cin, self.cout, 2, 2], &c.weight.val().device()));
        if let Some(p) = c.bias.as_mut() {
            *p = Param::initialized(p.id, tensor(&self.b, [self.cout], &p.val().device()));
        }
    }
    fn forward(&self, x: &T4) -> T4 {
        let (n, cin, h, w, cout) = (x.n, x.c, x.h, x.w, self.cout);
        let c4 = cout * 4;
        let hw = h * w;
        let rows = band_rows(c4, h, w);
        let nb = h.div_ceil(rows);
        let mut y = T4::zeros(n, cout, 2 * h, 2 * w);
        let yp = Ptr(y.d.as_mut_ptr());
        (0..n * nb).into_par_iter().for_each_init(Vec::new, |t, u| {
            let yp = yp;
            let (s, r0) = (u / nb, (u % nb) * rows);
            let r1 = (r0 + rows).min(h);
            let npx = (r1 - r0) * w;
            t.clear();
            t.resize(c4 * npx, 0.0);
            // SAFETY: t is c4 x npx; w is cin x c4 read transposed; x's band is cin x npx at stride hw.
            unsafe { mm(c4, npx, cin, t.as_mut_ptr(), npx, false, self.w.as_ptr(), 1, c4, x.sample(s).as_ptr().add(r0 * w), hw, 1) };
            // Output rows 2*r0..2*r1 of sample s belong to this unit only.
            for co in 0..cout {
                let base = s * cout * 4 * hw + co * 4 * hw;
                for q in 0..4 {
                    let (a, b) = (q / 2, q % 2);
                    let tr = &t[(co * 4 + q) * npx..][..npx];
                    for i in r0..r1 {
                        for j in 0..w {
                            // SAFETY: inside sample s, channel co, row 2i+a.
                            unsafe { *yp.0.add(base + (2 * i + a) * 2 * w + 2 * j + b) = tr[(i - r0) * w + j] + self.b[co] };
                        }
                    }
                }
            }
        });
        y
    }
    fn forward_train(&mut self, x: Arc<T4>) -> T4 {
        let y = self.forward(&x);
        self.x = Some(x);
        y
    }
    fn backward(&mut self, dy: &T4) -> T4 {
        let x = self.x.take().expect("forward_train before backward");
        let (n, cin, h, w, cout) = (x.n, x.c, x.h, x.w, self.cout);
        let (c4, hw) = (cout * 4, h * w);
        // dT[(co, a, b), (i, j)] = dy[co, 2i + a, 2j + b], per sample.
        let parts: Vec<(Vec<f32>, Vec<f32>)> = (0..n)
            .into_par_iter()
            .map(|s| {
                let dys = dy.sample(s);
                let mut dt = vec![0.0f32; c4 * hw];
                for co in 0..cout {
                    for q in 0..4 {
                        let (a, b) = (q / 2, q % 2);
                        let row = &mut dt[(co * 4 + q) * hw..][..hw];
                        for i in 0..h {
                            for j in 0..w {
                                row[i * w + j] = dys[co * 4 * hw + (2 * i + a) * 2 * w + 2 * j + b];
                            }
                        }
                    }
                }
                let mut dx = vec![0.0f32; cin * hw];
                let mut gw = vec![0.0f32; cin * c4];
                // SAFETY: sizes as allocated above.
                unsafe {
                    // dx[cin, hw] = w[cin, c4] * dT[c4, hw]
                    mm(cin, hw, c4, dx.as_mut_ptr(), hw, false, self.w.as_ptr(), c4, 1, dt.as_ptr(), hw, 1);
                    // gw[cin, c4] = x[cin, hw] * dT^T[hw, c4]
                    mm(cin, c4, hw, gw.as_mut_ptr(), c4, false, x.sample(s).as_ptr(), hw, 1, dt.as_ptr(), 1, hw);
                }
                (dx, gw)
            })
            .collect();
        let mut dx = Vec::with_capacity(n * cin * hw);
        let mut gws = Vec::with_capacity(n);
        for (d, g) in parts {
            dx.extend_from_slice(&d);
            gws.push(g);
        }
        let gw = sum_in_order(gws);
        self.gw.iter_mut().zip(&gw).for_each(|(a, b)| *a += b);
        self.gb.iter_mut().zip(channel_sums(dy)).for_each(|(a, b)| *a += b);
        T4::new(n, cin, h, w, dx)
    }
    fn params(&mut self, f: &mut dyn FnMut(&mut [f32], &mut [f32])) {
        f(&mut self.w, &mut self.gw);
        f(&mut self.b, &mut self.gb);
    }
}

/// Channel concatenation `[a, b]` and its inverse.
fn cat(a: &T4, b: &T4) -> T4 {
    let (ha, hb) = (a.c * a.hw(), b.c * b.hw());
    let mut d = Vec::with_capacity(a.d.len() + b.d.len());
    for s in 0..a.n {
        d.extend_from_slice(&a.d[s * ha..][..ha]);
        d.extend_from_slice(&b.d[s * hb..][..hb]);
    }
    T4::new(a.n, a.c + b.c, a.h, a.w, d)
}

fn split(t: &T4, ca: usize) -> (T4, T4) {
    let hw = t.hw();
    let cb = t.c - ca;
    let (mut a, mut b) = (Vec::with_capacity(t.n * ca * hw), Vec::with_capacity(t.n * cb * hw));
    for s in 0..t.n {
        let x = t.sample(s);
        a.extend_from_slice(&x[..ca * hw]);
        b.extend_from_slice(&x[ca * hw..]);
    }
    (T4::new(t.n, ca, t.h, t.w, a), T4::new(t.n, cb, t.h, t.w, b))
}

fn add_into(a: &mut T4, b: &T4) {
    a.d.par_iter_mut().zip(b.d.par_iter()).for_each(|(x, y)| *x += y);
}

#[derive(Debug, Clone)]
struct Down {
    conv: Double,
    idx: Vec<u8>,
    hw_in: (usize, usize),
}

#[derive(Debug, Clone)]
struct Up {
    up: UpConv,
    conv: Double,
    skip: usize,
}

#[derive(Debug, Clone)]
struct FUnet {
    inc: Double,
    downs: Vec<Down>,
    ups: Vec<Up>,
    outc: Conv,
}

#[derive(Debug, Clone)]
struct FShallow {
    blocks: Vec<ConvBnAct>,
    out: Conv,
}

#[derive(Debug, Clone)]
enum Kind {
    Unet(FUnet),
    Shallow(FShallow),
}

/// One of the two networks with its weights as plain vectors: forward (inference or training)
/// and backward on the CPU.
#[derive(Debug, Clone)]
pub struct FastNet {
    kind: Kind,
    /// Crop of the padded output during training (U-Net inputs padded to a multiple of 16).
    crop: Option<(usize, usize)>,
}

/// Edge-replicating pad of `x` to `h x w` (bottom and right), as the U-Net pads its input.
fn pad_edge(x: &T4, h: usize, w: usize) -> T4 {
    let mut y = T4::zeros(x.n, x.c, h, w);
    for p in 0..x.n * x.c {
        let src = &x.d[p * x.hw()..][..x.hw()];
        let dst = &mut y.d[p * h * w..][..h * w];
        for i in 0..h {
            let si = i.min(x.h - 1);
            for j in 0..w {
                dst[i * w + j] = src[si * x.w + j.min(x.w - 1)];
            }
        }
    }
    y
}

fn crop(x: &T4, h: usize, w: usize) -> T4 {
    let mut d = Vec::with_capacity(x.n * x.c * h * w);
    for p in 0..x.n * x.c {
        for i in 0..h {
            d.extend_from_slice(&x.d[p * x.hw() + i * x.w..][..w]);
        }
    }
    T4::new(x.n, x.c, h, w, d)
}

fn pad_zero(x: &T4, h: usize, w: usize) -> T4 {
    let mut y = T4::zeros(x.n, x.c, h, w);
    for p in 0..x.n * x.c {
        for i in 0..x.h {
            y.d[p * h * w + i * w..][..x.w].copy_from_slice(&x.d[p * x.hw() + i * x.w..][..x.w]);
        }
    }
    y
}

impl FastNet {
    /// The weights and running statistics of a burn network.
    pub fn from_net(net: &Net) -> FastNet {
        let kind = match net {
            Net::Unet(u) => Kind::Unet(FUnet {
                inc: Double::from_burn(&u.inc),
                downs: [&u.down1, &u.down2, &u.down3, &u.down4]
                    .iter()
                    .map(|d| Down { conv: Double::from_burn(&d.conv), idx: Vec::new(), hw_in: (0, 0) })
                    .collect(),
                ups: [&u.up1, &u.up2, &u.up3, &u.up4]
                    .iter()
                    .map(|up| {
                        let upc = UpConv::from_burn(&up.up);
                        let conv = Double::from_burn(&up.conv);
                        let skip = conv.a.conv.cin - upc.cout;
                        Up { up: upc, conv, skip }
                    })
                    .collect(),
                outc: Conv::from_burn(&u.outc),
            }),
            Net::Shallow(s) => Kind::Shallow(FShallow {
                blocks: s.blocks.iter().map(|b| ConvBnAct::from_burn(&b.conv, &b.bn, 0.0)).collect(),
                out: Conv::from_burn(&s.out),
            }),
        };
        FastNet { kind, crop: None }
    }

    /// `net` with this network's weights and running statistics (parameter ids kept).
    pub fn write_into(&self, mut net: Net) -> Net {
        match (&self.kind, &mut net) {
            (Kind::Unet(f), Net::Unet(u)) => {
                f.inc.write(&mut u.inc);
                for (d, b) in f.downs.iter().zip([&mut u.down1, &mut u.down2, &mut u.down3, &mut u.down4]) {
                    d.conv.write(&mut b.conv);
                }
                for (d, b) in f.ups.iter().zip([&mut u.up1, &mut u.up2, &mut u.up3, &mut u.up4]) {
                    d.up.write(&mut b.up);
                    d.conv.write(&mut b.conv);
                }
                f.outc.write(&mut u.outc);
            }
            (Kind::Shallow(f), Net::Shallow(s)) => {
                for (a, b) in f.blocks.iter().zip(s.blocks.iter_mut()) {
                    a.write(&mut b.conv, &mut b.bn);
                }
                f.out.write(&mut s.out);
            }
            _ => panic!("write_into: a network of another architecture"),
        }
        net
    }

    /// Inference (BatchNorm with running statistics): `[n, 3, h, w]` in, the same out.
    pub fn forward(&self, x: &T4) -> T4 {
        match &self.kind {
            Kind::Shallow(m) => {
                let mut y = m.blocks[0].forward(x);
                for b in &m.blocks[1..] {
                    y = b.forward(&y);
                }
                let mut r = m.out.forward(&y);
                add_into(&mut r, x);
                r
            }
            Kind::Unet(m) => {
                let (h, w) = (x.h.div_ceil(16) * 16, x.w.div_ceil(16) * 16);
                let xp = if (h, w) != (x.h, x.w) { pad_edge(x, h, w) } else { x.clone() };
                let mut xs = vec![m.inc.forward(&xp)];
                drop(xp);
                for d in &m.downs {
                    let (p, _) = maxpool(xs.last().expect("level"));
                    xs.push(d.conv.forward(&p));
                }
                let mut y = xs.pop().expect("bottom");
                for u in &m.ups {
                    let skip = xs.pop().expect("skip");
                    let upy = u.up.forward(&y);
                    y = u.conv.forward(&cat(&skip, &upy));
                }
                let r = m.outc.forward(&y);
                let mut r = if (h, w) != (x.h, x.w) { crop(&r, x.h, x.w) } else { r };
                add_into(&mut r, x);
                r
            }
        }
    }

    /// Training forward (batch statistics, running statistics updated), keeping what the
    /// backward pass needs.
    pub fn forward_train(&mut self, x: &T4) -> T4 {
        match &mut self.kind {
            Kind::Shallow(m) => {
                let mut y = Arc::new(x.clone());
                for b in &mut m.blocks {
                    y = b.forward_train(y);
                }
                let mut r = m.out.forward_train(y);
                add_into(&mut r, x);
                r
            }
            Kind::Unet(m) => {
                let (h, w) = (x.h.div_ceil(16) * 16, x.w.div_ceil(16) * 16);
                self.crop = ((h, w) != (x.h, x.w)).then_some((x.h, x.w));
                let xp = Arc::new(if self.crop.is_some() { pad_edge(x, h, w) } else { x.clone() });
                let mut xs = vec![m.inc.forward_train(xp)];
                for d in &mut m.downs {
                    let last = xs.last().expect("level");
                    d.hw_in = (last.h, last.w);
                    let (p, idx) = maxpool(last);
                    d.idx = idx;
                    xs.push(d.conv.forward_train(Arc::new(p)));
                }
                let mut y = xs.pop().expect("bottom");
                for u in &mut m.ups {
                    let skip = xs.pop().expect("skip");
                    let upy = u.up.forward_train(y);
                    y = u.conv.forward_train(Arc::new(cat(&skip, &upy)));
                }
                let r = m.outc.forward_train(y);
                let mut r = if self.crop.is_some() { crop(&r, x.h, x.w) } else { r };
                add_into(&mut r, x);
                r
            }
        }
    }

    /// Accumulates parameter gradients from the gradient of the output of the last
    /// [`forward_train`](Self::forward_train).
    pub fn backward(&mut self, dout: &T4) {
        match &mut self.kind {
            Kind::Shallow(m) => {
                let mut d = m.out.backward(dout, true).expect("dx");
                let last = m.blocks.len() - 1;
                for (i, b) in m.blocks.iter_mut().enumerate().rev() {
                    match b.backward(&d, i != 0) {
                        Some(next) => d = next,
                        None => debug_assert_eq!(i, 0, "{last}"),
                    }
                }
            }
            Kind::Unet(m) => {
                let d = match self.crop {
                    Some(_) => {
                        let x = m.outc.x.as_ref().expect("forward_train before backward");
                        pad_zero(dout, x.h, x.w)
                    }
                    None => dout.clone(),
                };
                let mut d = m.outc.backward(&d, true).expect("dx");
                let mut skips = Vec::new();
                for u in m.ups.iter_mut().rev() {
                    let dcat = u.conv.backward(&d, true).expect("dx");
                    let (dskip, dup) = split(&dcat, u.skip);
                    d = u.up.backward(&dup);
                    skips.push(dskip);
                }
                // skips: gradients of x1, x2, x3, x4 (in that order); d: of the bottom x5.
                for (dn, mut s) in m.downs.iter_mut().rev().zip(skips.into_iter().rev()) {
                    let dp = dn.conv.backward(&d, true).expect("dx");
                    let (h, w) = dn.hw_in;
                    add_into(&mut s, &maxpool_backward(&dp, &dn.idx, h, w));
                    d = s;
                }
                m.inc.backward(&d, false);
            }
        }
    }

    /// Every (parameter, gradient) pair, in a fixed order.
    pub fn params(&mut self, f: &mut dyn FnMut(&mut [f32], &mut [f32])) {
        match &mut self.kind {
            Kind::Shallow(m) => {
                m.blocks.iter_mut().for_each(|b| b.params(f));
                m.out.params(f);
            }
            Kind::Unet(m) => {
                m.inc.params(f);
                m.downs.iter_mut().for_each(|d| d.conv.params(f));
                for u in &mut m.ups {
                    u.up.params(f);
                    u.conv.params(f);
                }
                m.outc.params(f);
            }
        }
    }

    /// Every BatchNorm layer, in a fixed order.
    fn bn_layers(&mut self, f: &mut dyn FnMut(&mut ConvBnAct)) {
        match &mut self.kind {
            Kind::Shallow(m) => m.blocks.iter_mut().for_each(f),
            Kind::Unet(m) => {
                let double = |d: &mut Double, f: &mut dyn FnMut(&mut ConvBnAct)| {
                    f(&mut d.a);
                    f(&mut d.b);
                };
                double(&mut m.inc, f);
                m.downs.iter_mut().for_each(|d| double(&mut d.conv, f));
                m.ups.iter_mut().for_each(|u| double(&mut u.conv, f));
            }
        }
    }

    /// Replaces every BatchNorm layer's running statistics by the exact mean, over `batches`,
    /// of the batch statistics training normalises with ("precise BatchNorm"). The running
    /// averages training keeps (momentum 0.1) remember about ten batches of eight patches, so
    /// at inference they carry a per-channel offset that shows as a colour cast on smooth
    /// regions; the mean over many batches does not. Weights are untouched.
    pub fn recalibrate_bn(&mut self, batches: &[T4]) {
        let mut old = Vec::new();
        self.bn_layers(&mut |l| old.push(l.momentum));
        for (k, x) in batches.iter().enumerate() {
            // Momentum 1 / (k + 1) makes the running value the mean of the k + 1 batches so far.
            self.bn_layers(&mut |l| l.momentum = 1.0 / (k + 1) as f32);
            let _ = self.forward_train(x);
        }
        let mut it = old.into_iter();
        self.bn_layers(&mut |l| {
            l.momentum = it.next().expect("one momentum per layer");
            l.cache = None;
        });
    }

    pub fn zero_grad(&mut self) {
        self.params(&mut |_, g| g.fill(0.0));
    }
}

/// One optimisation step: forward, Huber loss, backward, Adam. Returns the loss before the step;
/// a non-finite loss leaves the network and the optimizer untouched.
pub fn train_step(net: &mut FastNet, adam: &mut Adam, x: &T4, y: &T4, lr: f32, delta: f32, eps: f32) -> f64 {
    net.zero_grad();
    let out = net.forward_train(x);
    let (loss, dout) = huber(&out, y, delta);
    if loss.is_finite() {
        net.backward(&dout);
        adam.step(net, lr, eps);
    }
    loss
}

/// Huber loss (mean over every element) and its gradient with respect to `pred`.
pub fn huber(pred: &T4, target: &T4, delta: f32) -> (f64, T4) {
    let n = pred.d.len() as f64;
    let mut g = T4::zeros(pred.n, pred.c, pred.h, pred.w);
    let mut loss = 0.0f64;
    let inv = (1.0 / n) as f32;
    for ((gv, &p), &t) in g.d.iter_mut().zip(&pred.d).zip(&target.d) {
        let r = p - t;
        if r.abs() <= delta {
            loss += 0.5 * (r as f64) * (r as f64);
            *gv = r * inv;
        } else {
            loss += delta as f64 * (r.abs() as f64 - 0.5 * delta as f64);
            *gv = delta * r.signum() * inv;
        }
    }
    (loss / n, g)
}

/// Adam as burn 0.22 computes it (beta 0.9 / 0.999, the epsilon scaled by the bias
/// correction), with its state as plain vectors.
#[derive(Debug, Clone, Default)]
pub struct Adam {
    pub time: i32,
    pub m: Vec<Vec<f32>>,
    pub v: Vec<Vec<f32>>,
}

impl Adam {
    pub const BETA1: f32 = 0.9;
    pub const BETA2: f32 = 0.999;
    /// burn's default epsilon. Too large for these networks: the mean-reduced loss over
    /// `8 x 3 x 128 x 128` values gives most weights a gradient RMS of 1e-7 to 1e-6, so with
    /// 1e-5 in the denominator they move at a few percent of Adam's step. Training configs use
    /// `optim.adam_epsilon` (PyTorch's 1e-8 by default).
    pub const BURN_EPS: f32 = 1e-5;

    pub fn step(&mut self, net: &mut FastNet, lr: f32, eps: f32) {
        self.time += 1;
        let t = self.time;
        let bc2 = (1.0 - Self::BETA2.powi(t)).sqrt();
        let factor = bc2 / (1.0 - Self::BETA1.powi(t));
        let init = self.m.is_empty();
        let mut i = 0;
        let (ms, vs) = (&mut self.m, &mut self.v);
        net.params(&mut |p, g| {
            if init {
                ms.push(vec![0.0; p.len()]);
                vs.push(vec![0.0; p.len()]);
            }
            let (m, v) = (&mut ms[i], &mut vs[i]);
            p.par_iter_mut().zip(g.par_iter()).zip(m.par_iter_mut().zip(v.par_iter_mut())).for_each(|((p, &g), (m, v))| {
                *m = *m * Self::BETA1 + g * (1.0 - Self::BETA1);
                *v = *v * Self::BETA2 + g * g * (1.0 - Self::BETA2);
                *p -= lr * (*m * factor) / (v.sqrt() + eps * bc2);
            });
            i += 1;
        });
    }

    /// The state as bytes: a JSON header line, then the moments as little-endian f32.
    pub fn to_bytes(&self) -> Vec<u8> {
        let lens: Vec<usize> = self.m.iter().map(Vec::len).collect();
        let mut out = serde_json::to_vec(&serde_json::json!({"format": "pipeline-adam-1", "time": self.time, "lens": lens})).expect("json");
        out.push(b'\n');
        for v in self.m.iter().chain(&self.v) {
            for x in v {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        out
    }

    pub fn from_bytes(b: &[u8]) -> Result<Adam, String> {
        let nl = b.iter().position(|&c| c == b'\n').ok_or("no header line")?;
        let head: serde_json::Value = serde_json::from_slice(&b[..nl]).map_err(|e| e.to_string())?;
        if head["format"] != "pipeline-adam-1" {
            return Err(format!("not a pipeline Adam state (format {})", head["format"]));
        }
        let time = head["time"].as_i64().ok_or("no time")? as i32;
        let lens: Vec<usize> = serde_json::from_value(head["lens"].clone()).map_err(|e| e.to_string())?;
        let body = &b[nl + 1..];
        let total: usize = lens.iter().sum();
        if body.len() != total * 8 {
            return Err(format!("{} bytes of moments, expected {}", body.len(), total * 8));
        }
        let mut floats = body.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]));
        let mut take = |n: usize| -> Vec<f32> { floats.by_ref().take(n).collect() };
        let m = lens.iter().map(|&n| take(n)).collect();
        let v = lens.iter().map(|&n| take(n)).collect();
        Ok(Adam { time, m, v })
    }
}

#[cfg(test)]
mod tests {
    //! Each operation against burn's own implementation on the same inputs (forward and both
    //! gradients), then whole networks and training runs.
    use super::*;
    use burn::module::Module;
    use burn::nn::conv::{Conv2dConfig, ConvTranspose2dConfig};
    use burn::nn::PaddingConfig2d;
    use burn::optim::GradientsParams;
    use burn::tensor::Device;

    fn ad() -> Device {
        Device::flex().autodiff()
    }

    fn rand(n: usize, c: usize, h: usize, w: usize, seed: u64) -> T4 {
        let v = (0..n * c * h * w).map(|i| crate::rng::unit(crate::rng::hash(&[seed, i as u64])) as f32 * 2.0 - 1.0).collect();
        T4::new(n, c, h, w, v)
    }

    /// Largest |a - b| relative to the largest |b| (1e-30 floor).
    fn rel(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len());
        let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-30);
        a.iter().zip(b).fold(0.0f32, |m, (x, y)| m.max((x - y).abs())) / scale
    }

    fn vecf<const D: usize>(t: Tensor<D>) -> Vec<f32> {
        t.into_data().try_to_vec::<f32>().unwrap()
    }

    /// burn: y = conv(x), loss = sum(y * g); returns y, dx, dw, db.
    fn burn_conv(conv: &Conv2d, x: &T4, g: &T4) -> (Vec<f32>, Vec<f32>, Vec<f32>, Option<Vec<f32>>) {
        let xt = x.to_tensor(&ad()).require_grad();
        let y = conv.forward(xt.clone());
        let loss = (y.clone() * g.to_tensor(&ad())).sum();
        let grads = loss.backward();
        let dx = vecf(xt.grad(&grads).unwrap());
        let gp = GradientsParams::from_grads(grads, conv);
        let dw = vecf(gp.get::<4>(conv.weight.id).unwrap());
        let db = conv.bias.as_ref().map(|b| vecf(gp.get::<1>(b.id).unwrap()));
        (vecf(y), dx, dw, db)
    }

    #[test]
    fn convolution_matches_burn_forward_and_both_gradients() {
        // (batch, cin, cout, h, w, kernel, bias): odd sizes, batch 1 and 5.
        for (i, &(n, cin, cout, h, w, k, bias)) in
            [(1, 3, 16, 17, 23, 3, false), (5, 32, 16, 9, 14, 3, false), (2, 16, 3, 12, 7, 1, true), (1, 8, 3, 5, 6, 3, true)]
                .iter()
                .enumerate()
        {
            let mut cfg = Conv2dConfig::new([cin, cout], [k, k]).with_bias(bias);
            if k == 3 {
                cfg = cfg.with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1));
            }
            let conv = cfg.init(&ad());
            let x = rand(n, cin, h, w, 1 + i as u64);
            let g = rand(n, cout, h, w, 100 + i as u64);
            let (y, dx, dw, db) = burn_conv(&conv, &x, &g);
            let mut f = Conv::from_burn(&conv);
            let fy = f.forward_train(Arc::new(x.clone()));
            let fdx = f.backward(&g, true).unwrap();
            assert!(rel(&fy.d, &y) < 1e-4, "case {i} forward {}", rel(&fy.d, &y));
            assert!(rel(&fdx.d, &dx) < 1e-4, "case {i} input gradient {}", rel(&fdx.d, &dx));
            assert!(rel(&f.gw, &dw) < 1e-4, "case {i} weight gradient {}", rel(&f.gw, &dw));
            if let Some(db) = db {
                assert!(rel(&f.gb, &db) < 1e-4, "case {i} bias gradient");
            }
            // The check catches a wrong gradient: one weight's gradient off by 1e-3 of the largest.
            let scale = dw.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            f.gw[dw.len() / 2] += 1e-3 * scale;
            assert!(rel(&f.gw, &dw) > 1e-4, "case {i}: a perturbed weight gradient passes ({})", rel(&f.gw, &dw));
        }
    }

    #[test]
    fn transposed_convolution_matches_burn() {
        for (i, &(n, cin, cout, h, w)) in [(1, 8, 8, 5, 7), (3, 16, 4, 4, 4)].iter().enumerate() {
            let up = ConvTranspose2dConfig::new([cin, cout], [2, 2]).with_stride([2, 2]).init(&ad());
            let x = rand(n, cin, h, w, 7 + i as u64);
            let g = rand(n, cout, 2 * h, 2 * w, 70 + i as u64);
            let xt = x.to_tensor(&ad()).require_grad();
            let y = up.forward(xt.clone());
            let grads = (y.clone() * g.to_tensor(&ad())).sum().backward();
            let dx = vecf(xt.grad(&grads).unwrap());
            let gp = GradientsParams::from_grads(grads, &up);
            let (dw, db) = (vecf(gp.get::<4>(up.weight.id).unwrap()), vecf(gp.get::<1>(up.bias.as_ref().unwrap().id).unwrap()));
            let mut f = UpConv::from_burn(&up);
            let fy = f.forward_train(Arc::new(x));
            let fdx = f.backward(&g);
            assert!(rel(&fy.d, &vecf(y)) < 1e-4, "case {i} forward");
            assert!(rel(&fdx.d, &dx) < 1e-4, "case {i} input gradient");
            assert!(rel(&f.gw, &dw) < 1e-4, "case {i} weight gradient");
            assert!(rel(&f.gb, &db) < 1e-4, "case {i} bias gradient");
        }
    }

    /// Every parameter gradient of a whole network against burn's autodiff.
    fn network_gradients_match(arch: super::super::Arch, n: usize, h: usize, w: usize) {
        let net = Net::seeded(arch, &ad(), 11);
        let x = rand(n, 3, h, w, 5);
        let y = rand(n, 3, h, w, 6);
        // burn
        let out = net.forward(x.to_tensor(&ad()));
        let loss =
            burn::nn::loss::HuberLossConfig::new(0.02).init().forward(out.clone(), y.to_tensor(&ad()), burn::nn::loss::Reduction::Mean);
        let gp = GradientsParams::from_grads(loss.backward(), &net);
        // ours
        let mut f = FastNet::from_net(&net);
        let fo = f.forward_train(&x);
        assert!(rel(&fo.d, &vecf(out)) < 1e-4, "{arch:?} forward");
        let (fl, d) = huber(&fo, &y, 0.02);
        assert!((fl - loss.into_scalar::<f32>() as f64).abs() < 1e-6 * fl.abs().max(1e-3), "{arch:?} loss");
        f.backward(&d);
        let mut ours = Vec::new();
        f.params(&mut |_, g| ours.push(g.to_vec()));
        // burn's gradients in the same order: visit the module's trainable parameters.
        struct Grads<'a>(&'a GradientsParams, Vec<Vec<f32>>);
        impl burn::module::ModuleVisitor for Grads<'_> {
            fn visit_float<const D: usize>(&mut self, p: &burn::module::Param<Tensor<D>>) {
                if let Some(g) = self.0.get::<D>(p.id) {
                    self.1.push(g.into_data().try_to_vec::<f32>().unwrap());
                }
            }
        }
        let mut theirs = Grads(&gp, Vec::new());
        net.visit(&mut theirs);
        // burn visits conv weight before its BatchNorm: the same order as ours.
        assert_eq!(ours.len(), theirs.1.len(), "{arch:?} parameter count");
        for (i, (a, b)) in ours.iter().zip(&theirs.1).enumerate() {
            assert!(rel(a, b) < 1e-3, "{arch:?} parameter {i} ({} values): {}", a.len(), rel(a, b));
        }
    }

    #[test]
    fn shallow_gradients_match_burn() {
        network_gradients_match(super::super::Arch::Shallow { width: 8 }, 2, 13, 11);
    }

    #[test]
    fn unet_gradients_match_burn_including_padding() {
        network_gradients_match(super::super::Arch::Unet { base: 4 }, 2, 32, 32);
        network_gradients_match(super::super::Arch::Unet { base: 4 }, 1, 20, 35);
    }

    #[test]
    fn inference_matches_burn_and_round_trips_through_the_module() {
        for arch in [super::super::Arch::Unet { base: 4 }, super::super::Arch::Shallow { width: 6 }] {
            let dev = Device::flex();
            let mut f = FastNet::from_net(&Net::seeded(arch, &dev, 3));
            // A few training steps move the weights and running statistics off their init.
            let mut adam = Adam::default();
            for s in 0..3 {
                f.zero_grad();
                let o = f.forward_train(&rand(2, 3, 16, 16, s));
                let (_, d) = huber(&o, &rand(2, 3, 16, 16, 50 + s), 0.02);
                f.backward(&d);
                adam.step(&mut f, 1e-2, Adam::BURN_EPS);
            }
            let net = f.write_into(Net::seeded(arch, &dev, 4));
            let x = rand(1, 3, 21, 30, 9);
            let theirs = vecf(net.forward(x.to_tensor(&dev)));
            let e = rel(&f.forward(&x).d, &theirs);
            assert!(e < 1e-4, "{arch:?}: {e}");
            let back = FastNet::from_net(&net);
            assert_eq!(back.forward(&x).d, f.forward(&x).d, "{arch:?} round trip");
        }
    }

    #[test]
    fn recalibrated_batchnorm_makes_inference_equal_training_mode_on_that_batch() {
        for arch in [super::super::Arch::Unet { base: 4 }, super::super::Arch::Shallow { width: 6 }] {
            let dev = Device::flex();
            // Seeded weights (the last layer not zeroed, so BatchNorm shows in the output).
            let mut f = FastNet::from_net(&Net::seeded(arch, &dev, 5));
            let (a, b) = (rand(4, 3, 16, 16, 61), rand(4, 3, 16, 16, 62));
            let train_a = f.clone().forward_train(&a);
            let worst = |p: &T4, q: &T4| p.d.iter().zip(&q.d).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
            // The initial running statistics (mean 0, variance 1) are far from the batch's.
            assert!(worst(&f.forward(&a), &train_a) > 1e-2, "{arch:?}: the test needs stats that differ");
            // Over one batch (or the same batch twice) the running statistics are that batch's.
            f.recalibrate_bn(std::slice::from_ref(&a));
            assert!(worst(&f.forward(&a), &train_a) < 1e-4, "{arch:?}: {}", worst(&f.forward(&a), &train_a));
            f.recalibrate_bn(&[a.clone(), a.clone()]);
            assert!(worst(&f.forward(&a), &train_a) < 1e-4, "{arch:?}: twice");
            // Over two batches they are the mean of both, not the last one's (momentum 0.1 would
            // leave 0.9 of the first batch's).
            f.recalibrate_bn(&[a.clone(), b.clone()]);
            let mut g = FastNet::from_net(&Net::seeded(arch, &dev, 5));
            g.recalibrate_bn(&[b.clone(), a.clone()]);
            assert!(worst(&f.forward(&a), &g.forward(&a)) < 1e-4, "{arch:?}: the order of the batches matters");
            assert!(worst(&f.forward(&a), &train_a) > 1e-3, "{arch:?}: b left no trace");
            // The momentum is restored: a training step moves the statistics by 0.1 of the way.
            let mut rm = Vec::new();
            f.bn_layers(&mut |l| rm.push((l.momentum, l.rmean[0])));
            assert!(rm.iter().all(|&(m, _)| (m - 0.1).abs() < 1e-6), "{rm:?}");
        }
    }

    /// The initial network of the training tests: built once per test, so that burn's shared
    /// random generator (drawn lazily by other tests' modules) cannot differ between two runs.
    fn initial(arch: super::super::Arch, dev: &Device) -> Net {
        Net::seeded(arch, dev, 21).zero_last_layer(dev)
    }

    fn train_steps(mut f: FastNet, steps: usize) -> (Vec<f64>, FastNet) {
        let mut adam = Adam::default();
        let mut losses = Vec::new();
        for s in 0..steps as u64 {
            let (x, y) = (rand(4, 3, 16, 16, 200 + s % 3), rand(4, 3, 16, 16, 300 + s % 3));
            losses.push(train_step(&mut f, &mut adam, &x, &y, 1e-3, 0.02, 1e-8));
        }
        (losses, f)
    }

    #[test]
    fn twenty_steps_give_burns_loss_curve() {
        use burn::optim::AdamConfig;
        for arch in [super::super::Arch::Shallow { width: 4 }, super::super::Arch::Unet { base: 4 }] {
            let mut net = initial(arch, &ad());
            let (ours, _) = train_steps(FastNet::from_net(&net), 20);
            let mut optim = AdamConfig::new().with_epsilon(1e-8).init();
            let huber_b = burn::nn::loss::HuberLossConfig::new(0.02).init();
            for (s, l) in ours.iter().enumerate() {
                let s = s as u64;
                let (x, y) = (rand(4, 3, 16, 16, 200 + s % 3), rand(4, 3, 16, 16, 300 + s % 3));
                let loss = huber_b.forward(net.forward(x.to_tensor(&ad())), y.to_tensor(&ad()), burn::nn::loss::Reduction::Mean);
                let lb = loss.clone().into_scalar::<f32>() as f64;
                assert!((lb - l).abs() <= 1e-4 * lb.abs(), "{arch:?} step {s}: burn {lb} ours {l}");
                let grads = GradientsParams::from_grads(loss.backward(), &net);
                net = optim.step(1e-3, net, grads);
            }
            // Steps 0 and 18 see the same batch.
            assert!(ours[18] < ours[0], "{arch:?} the loss falls: {ours:?}");
        }
    }

    #[test]
    fn the_same_seed_gives_the_same_weights_with_any_thread_count() {
        let arch = super::super::Arch::Unet { base: 4 };
        let init = FastNet::from_net(&initial(arch, &Device::flex()));
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
                let (_, mut f) = train_steps(init.clone(), 4);
                let mut w = Vec::new();
                f.params(&mut |p, _| w.extend_from_slice(p));
                w
            })
        };
        let (a, b, c) = (run(1), run(2), run(2));
        assert_eq!(b, c, "two runs, one seed");
        assert_eq!(a, b, "1 and 2 threads");
    }

    #[test]
    fn adam_state_round_trips() {
        let mut f = FastNet::from_net(&initial(super::super::Arch::Shallow { width: 4 }, &Device::flex()));
        let mut a = Adam::default();
        f.zero_grad();
        a.step(&mut f, 1e-3, 1e-8);
        let b = Adam::from_bytes(&a.to_bytes()).unwrap();
        assert_eq!((a.time, &a.m, &a.v), (b.time, &b.m, &b.v));
        assert!(Adam::from_bytes(b"{}\n").is_err());
    }
}
