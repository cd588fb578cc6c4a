use super::*;

/// A convolution (no padding beyond `k / 2`, stride 1) with its gradient buffers.
#[derive(Debug, Clone)]
pub struct Conv {
    pub cin: usize,
    pub cout: usize,
    pub k: usize,
    pub w: Vec<f32>,
    pub b: Option<Vec<f32>>,
    pub(super) gw: Vec<f32>,
    pub(super) gb: Vec<f32>,
    pub(super) x: Option<Arc<T4>>,
    /// The Winograd transform of `w` ([`winograd::weights`]) for the forward pass, made on first
    /// use and dropped whenever `params` hands `w` out to be changed.
    pub(super) wino: std::sync::OnceLock<Vec<f32>>,
}

impl Conv {
    #[cfg(feature = "train")]
    pub(super) fn from_burn(c: &Conv2d) -> Conv {
        let [cout, cin, k, k2] = c.weight.val().dims();
        assert_eq!(k, k2, "square kernels only");
        Conv::from_parts(cout, cin, k, values(c.weight.val()), c.bias.as_ref().map(|b| values(b.val())))
    }
    /// A `k x k` convolution from its weights `[cout, cin, k, k]` and bias.
    pub(super) fn from_parts(cout: usize, cin: usize, k: usize, w: Vec<f32>, b: Option<Vec<f32>>) -> Conv {
        assert_eq!(w.len(), cout * cin * k * k, "weights of a {cout}x{cin}x{k}x{k} convolution");
        Conv {
            cin,
            cout,
            k,
            gw: vec![0.0; w.len()],
            gb: vec![0.0; b.as_ref().map_or(0, Vec::len)],
            w,
            b,
            x: None,
            wino: Default::default(),
        }
    }
    #[cfg(feature = "train")]
    pub(super) fn write(&self, c: &mut Conv2d) {
        c.weight = Param::initialized(c.weight.id, tensor(&self.w, [self.cout, self.cin, self.k, self.k], &c.weight.val().device()));
        if let (Some(p), Some(b)) = (c.bias.as_mut(), &self.b) {
            *p = Param::initialized(p.id, tensor(b, [self.cout], &p.val().device()));
        }
    }
    /// `conv(x) + bias`: 3 x 3 layers wide enough take Winograd's F(2x2, 3x3) (16 multiplications
    /// where the direct convolution does 36; the same values up to float rounding).
    pub(super) fn forward(&self, x: &T4) -> T4 {
        self.forward_then(x, None)
    }
    /// [`Conv::forward`], then `post` (an inference BatchNorm and activation) on every value:
    /// inside the Winograd output transform, or as a pass of its own after the direct
    /// convolution. The same operations in the same order either way.
    pub(super) fn forward_then(&self, x: &T4, post: Option<&winograd::Post>) -> T4 {
        if self.k == 3 && winograd::worth_it(self.cin, self.cout, x.h, x.w) {
            let u = self.wino.get_or_init(|| winograd::weights(&self.w, self.cout, self.cin));
            return winograd::conv3x3(x, u, self.b.as_deref(), self.cout, post);
        }
        let mut z = conv_forward(x, &self.w, self.b.as_deref(), self.cout, self.k);
        if let Some(post) = post {
            let hw = z.hw();
            for (i, plane) in z.d.chunks_exact_mut(hw.max(1)).enumerate() {
                post.apply(i % self.cout, plane);
            }
        }
        z
    }
    /// Training: as [`Conv::forward`] (Winograd where it is worth it), keeping the input for
    /// the backward pass.
    pub(super) fn forward_train(&mut self, x: Arc<T4>) -> T4 {
        let y = self.forward(&x);
        self.x = Some(x);
        y
    }
    /// Accumulates the weight (and bias) gradient; returns the input gradient if asked.
    pub(super) fn backward(&mut self, dy: &T4, need_dx: bool) -> Option<T4> {
        let x = self.x.take().expect("forward_train before backward");
        let gw = conv_backward_weight(&x, dy, self.k);
        self.gw.iter_mut().zip(&gw).for_each(|(a, b)| *a += b);
        if self.b.is_some() {
            self.gb.iter_mut().zip(channel_sums(dy)).for_each(|(a, b)| *a += b);
        }
        need_dx.then(|| {
            // The input gradient is the forward convolution of `dy` with the flipped, transposed
            // weights (`cout` inputs, `cin` outputs): Winograd where that is worth it.
            if self.k == 3 && winograd::worth_it(self.cout, self.cin, dy.h, dy.w) {
                let u = winograd::weights(&flip_transpose(&self.w, self.cout, self.cin, 3), self.cin, self.cout);
                winograd::conv3x3(dy, &u, None, self.cin, None)
            } else {
                conv_backward_input(dy, &self.w, self.cin, self.k)
            }
        })
    }
    pub(super) fn params(&mut self, f: &mut dyn FnMut(&mut [f32], &mut [f32])) {
        self.wino.take();
        f(&mut self.w, &mut self.gw);
        if let Some(b) = self.b.as_mut() {
            f(b, &mut self.gb);
        }
    }
}

/// Conv (no bias) + BatchNorm + (leaky) ReLU, fused.
#[derive(Debug, Clone)]
pub struct ConvBnAct {
    pub(super) conv: Conv,
    pub(super) gamma: Vec<f32>,
    pub(super) beta: Vec<f32>,
    pub(super) rmean: Vec<f32>,
    pub(super) rvar: Vec<f32>,
    pub(super) momentum: f32,
    pub(super) eps: f32,
    pub(super) slope: f32,
    pub(super) ggamma: Vec<f32>,
    pub(super) gbeta: Vec<f32>,
    /// From `forward_train` for `backward`: the convolution's output z and, per channel, the
    /// batch mean and 1 / std. x-hat and the activation's sign are recomputed from them with
    /// the forward's own operations (the same bits), so neither is stored: a whole tensor
    /// written and read again per layer and step.
    pub(super) cache: Option<(T4, Vec<f32>, Vec<f32>)>,
}

impl ConvBnAct {
    #[cfg(feature = "train")]
    pub(super) fn from_burn(conv: &Conv2d, bn: &BatchNorm, slope: f32) -> ConvBnAct {
        let bn_parts = [bn.gamma.val(), bn.beta.val(), bn.running_mean.value_sync(), bn.running_var.value_sync()].map(values);
        ConvBnAct::from_parts(Conv::from_burn(conv), bn_parts, (bn.momentum as f32, bn.epsilon as f32), slope)
    }
    /// A convolution with its BatchNorm (`[gamma, beta, running mean, running variance]`,
    /// `(momentum, epsilon)`) and an activation of negative `slope` (0: ReLU).
    pub(super) fn from_parts(conv: Conv, bn: [Vec<f32>; 4], (momentum, eps): (f32, f32), slope: f32) -> ConvBnAct {
        let [gamma, beta, rmean, rvar] = bn;
        let c = conv.cout;
        assert!([&gamma, &beta, &rmean, &rvar].iter().all(|v| v.len() == c), "one BatchNorm value per channel");
        ConvBnAct { conv, gamma, beta, rmean, rvar, momentum, eps, slope, ggamma: vec![0.0; c], gbeta: vec![0.0; c], cache: None }
    }
    #[cfg(feature = "train")]
    pub(super) fn write(&self, conv: &mut Conv2d, bn: &mut BatchNorm) {
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
    /// Inference: BatchNorm with its running statistics.
    pub(super) fn forward(&self, x: &T4) -> T4 {
        let scale: Vec<f32> = (0..self.gamma.len()).map(|ch| self.gamma[ch] / (self.rvar[ch] + self.eps).sqrt()).collect();
        let shift = (0..self.gamma.len()).map(|ch| self.beta[ch] - self.rmean[ch] * scale[ch]).collect();
        self.conv.forward_then(x, Some(&winograd::Post { scale, shift, slope: self.slope }))
    }
    /// Training: BatchNorm with the batch's statistics (biased variance, as burn), running
    /// statistics updated with the momentum.
    pub(super) fn forward_train(&mut self, x: Arc<T4>) -> Arc<T4> {
        let z = self.conv.forward_train(x);
        let (n, c, hw) = (z.n, z.c, z.hw());
        let m = (n * hw) as f64;
        let mut out = T4::zeros(n, c, z.h, z.w);
        let (gamma, beta, eps, slope) = (&self.gamma, &self.beta, self.eps as f64, self.slope);
        let stats = per_channel(c, hw, [&mut out], |ch, [mut os]| {
            let zp = |s: usize| &z.d[(s * c + ch) * hw..][..hw];
            let mean = (0..n).map(|s| lanes_sum(zp(s), |v| v)).sum::<f64>() / m;
            // Two passes (mean, then squared deviations), not E[z^2] - mean^2, which cancels.
            let var = (0..n).map(|s| lanes_sum(zp(s), |v| (v - mean) * (v - mean))).sum::<f64>() / m;
            let inv = 1.0 / (var + eps).sqrt();
            let (g, b, meanf, invf) = (gamma[ch], beta[ch], mean as f32, inv as f32);
            for s in 0..n {
                for (o, &v) in os[s].iter_mut().zip(zp(s)) {
                    let p = g * ((v - meanf) * invf) + b;
                    *o = if p > 0.0 { p } else { slope * p };
                }
            }
            (mean as f32, var as f32, inv as f32)
        });
        let mo = self.momentum;
        let (mut means, mut inv) = (Vec::with_capacity(c), Vec::with_capacity(c));
        for (ch, (mean, var, i)) in stats.into_iter().enumerate() {
            self.rmean[ch] = self.rmean[ch] * (1.0 - mo) + mean * mo;
            self.rvar[ch] = self.rvar[ch] * (1.0 - mo) + var * mo;
            means.push(mean);
            inv.push(i);
        }
        self.cache = Some((z, means, inv));
        Arc::new(out)
    }
    /// The gradients from the gradient of this layer's output; `dout` becomes the gradient of
    /// the convolution's output in place (no buffer of its own).
    pub(super) fn backward(&mut self, mut dout: T4, need_dx: bool) -> Option<T4> {
        let (z, means, inv) = self.cache.take().expect("forward_train before backward");
        let (n, c, hw) = (dout.n, dout.c, dout.hw());
        let m = (n * hw) as f64;
        let (gamma, beta, slope) = (&self.gamma, &self.beta, self.slope);
        let sums = per_channel(c, hw, [&mut dout], |ch, [mut dps]| {
            let at = |s: usize| (s * c + ch) * hw;
            let (g, b, meanf, invf) = (gamma[ch], beta[ch], means[ch], inv[ch]);
            // x-hat as the forward computed it.
            let xhat = |v: f32| (v - meanf) * invf;
            // dpre = dout * act'(pre); act'(pre) follows the sign of pre = g x-hat + b (the
            // output's sign: the slope is not negative).
            let mut sb = 0.0f64;
            let mut sg = 0.0f64;
            for (s, dp) in dps.iter_mut().enumerate() {
                let zs = &z.d[at(s)..][..hw];
                for (d, &v) in dp.iter_mut().zip(zs) {
                    // A select, not a branch: the signs are as good as random.
                    *d = if g * xhat(v) + b > 0.0 { *d } else { slope * *d };
                }
                // The two sums in f64 lanes (a running f64 sum would serialise them).
                let mut acc = [[0.0f64; LANES]; 2];
                let (dc, zc) = (dp.chunks_exact(LANES), zs.chunks_exact(LANES));
                let (dr, zr) = (dc.remainder(), zc.remainder());
                for (dv, zv) in dc.zip(zc) {
                    for l in 0..LANES {
                        acc[0][l] += dv[l] as f64;
                        acc[1][l] += (dv[l] * xhat(zv[l])) as f64;
                    }
                }
                let (mut b, mut g) = (acc[0].iter().sum::<f64>(), acc[1].iter().sum::<f64>());
                for (&v, &x) in dr.iter().zip(zr) {
                    b += v as f64;
                    g += (v * xhat(x)) as f64;
                }
                sb += b;
                sg += g;
            }
            let k = g * invf;
            let (mb, mg) = ((sb / m) as f32, (sg / m) as f32);
            for (s, dp) in dps.iter_mut().enumerate() {
                let zs = &z.d[at(s)..][..hw];
                for (d, &v) in dp.iter_mut().zip(zs) {
                    *d = k * (*d - mb - xhat(v) * mg);
                }
            }
            (sg as f32, sb as f32)
        });
        for (ch, (g, b)) in sums.into_iter().enumerate() {
            self.ggamma[ch] += g;
            self.gbeta[ch] += b;
        }
        self.conv.backward(&dout, need_dx)
    }
    pub(super) fn params(&mut self, f: &mut dyn FnMut(&mut [f32], &mut [f32])) {
        self.conv.params(f);
        f(&mut self.gamma, &mut self.ggamma);
        f(&mut self.beta, &mut self.gbeta);
    }
}

/// Two ConvBnAct with LeakyReLU 0.01.
#[derive(Debug, Clone)]
pub(super) struct Double {
    pub(super) a: ConvBnAct,
    pub(super) b: ConvBnAct,
}

impl Double {
    #[cfg(feature = "train")]
    pub(super) fn from_burn(d: &crate::model::DoubleConv) -> Double {
        Double { a: ConvBnAct::from_burn(&d.a.conv, &d.a.bn, 0.01), b: ConvBnAct::from_burn(&d.b.conv, &d.b.bn, 0.01) }
    }
    #[cfg(feature = "train")]
    pub(super) fn write(&self, d: &mut crate::model::DoubleConv) {
        self.a.write(&mut d.a.conv, &mut d.a.bn);
        self.b.write(&mut d.b.conv, &mut d.b.bn);
    }
    pub(super) fn forward(&self, x: &T4) -> T4 {
        self.b.forward(&self.a.forward(x))
    }
    pub(super) fn forward_train(&mut self, x: Arc<T4>) -> Arc<T4> {
        let y = self.a.forward_train(x);
        self.b.forward_train(y)
    }
    pub(super) fn backward(&mut self, d: T4, need_dx: bool) -> Option<T4> {
        let d = self.b.backward(d, true).expect("dx");
        self.a.backward(d, need_dx)
    }
    pub(super) fn params(&mut self, f: &mut dyn FnMut(&mut [f32], &mut [f32])) {
        self.a.params(f);
        self.b.params(f);
    }
}

/// The 2x2 stride-2 transposed convolution with bias: `y[co, 2i+a, 2j+b] = sum_ci
/// w[ci, co, a, b] x[ci, i, j] + bias[co]`, a matrix product plus a shuffle.
#[derive(Debug, Clone)]
pub(super) struct UpConv {
    #[cfg_attr(not(feature = "train"), allow(dead_code))] // read by the burn conversion
    pub(super) cin: usize,
    pub(super) cout: usize,
    pub(super) w: Vec<f32>,
    pub(super) b: Vec<f32>,
    pub(super) gw: Vec<f32>,
    pub(super) gb: Vec<f32>,
    pub(super) x: Option<Arc<T4>>,
}

impl UpConv {
    #[cfg(feature = "train")]
    pub(super) fn from_burn(c: &ConvTranspose2d) -> UpConv {
        let [cin, cout, kh, kw] = c.weight.val().dims();
        assert!(kh == 2 && kw == 2 && c.stride == [2, 2], "2x2 stride-2 transposed convolutions only");
        UpConv::from_parts(cin, cout, values(c.weight.val()), c.bias.as_ref().map_or(vec![0.0; cout], |b| values(b.val())))
    }
    /// The 2x2 stride-2 transposed convolution from its weights `[cin, cout, 2, 2]` and bias.
    pub(super) fn from_parts(cin: usize, cout: usize, w: Vec<f32>, b: Vec<f32>) -> UpConv {
        assert!(w.len() == cin * cout * 4 && b.len() == cout, "weights of a {cin}x{cout}x2x2 transposed convolution");
        UpConv { cin, cout, gw: vec![0.0; w.len()], gb: vec![0.0; cout], w, b, x: None }
    }
    #[cfg(feature = "train")]
    pub(super) fn write(&self, c: &mut ConvTranspose2d) {
        c.weight = Param::initialized(c.weight.id, tensor(&self.w, [self.cin, self.cout, 2, 2], &c.weight.val().device()));
        if let Some(p) = c.bias.as_mut() {
            *p = Param::initialized(p.id, tensor(&self.b, [self.cout], &p.val().device()));
        }
    }
    pub(super) fn forward(&self, x: &T4) -> T4 {
        upconv_forward(x, &self.w, &self.b, self.cout)
    }
    pub(super) fn forward_train(&mut self, x: Arc<T4>) -> T4 {
        let y = self.forward(&x);
        self.x = Some(x);
        y
    }
    pub(super) fn backward(&mut self, dy: &T4) -> T4 {
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
                // dx[cin, hw] = w[cin, c4] * dT[c4, hw]
                matmul([cin, hw, c4], (&mut dx, hw), false, (&self.w, c4, 1), (&dt, hw, 1));
                // gw[cin, c4] = x[cin, hw] * dT^T[hw, c4]
                matmul([cin, c4, hw], (&mut gw, c4), false, (x.sample(s), hw, 1), (&dt, 1, hw));
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
    pub(super) fn params(&mut self, f: &mut dyn FnMut(&mut [f32], &mut [f32])) {
        f(&mut self.w, &mut self.gw);
        f(&mut self.b, &mut self.gb);
    }
}

/// The burst U-Net's time conditioning ([`crate::model::Film`]): channel `c` of sample `i`
/// becomes `x * (1 + f(t_i) G[:, c]) + f(t_i) B[:, c]`, with `f` the time's features.
#[derive(Debug, Clone)]
pub(super) struct Film {
    pub(super) c: usize,
    /// `G` and `B`, `[TIME_FEATURES, c]` row-major, and their gradients.
    pub(super) g: Vec<f32>,
    pub(super) b: Vec<f32>,
    pub(super) gg: Vec<f32>,
    pub(super) gb: Vec<f32>,
    /// Training: the input and the times, for the backward pass.
    pub(super) cache: Option<(T4, Vec<f32>)>,
}

use crate::model::{time_features, TIME_FEATURES};

impl Film {
    #[cfg(feature = "train")]
    pub(super) fn from_burn(f: &crate::model::Film) -> Film {
        Film::from_parts(values(f.gamma.val()), values(f.beta.val()))
    }
    /// From `G` and `B`, each `[TIME_FEATURES, c]`.
    pub(super) fn from_parts(g: Vec<f32>, b: Vec<f32>) -> Film {
        let c = g.len() / TIME_FEATURES;
        assert!(g.len() == c * TIME_FEATURES && b.len() == g.len(), "FiLM weights of [{TIME_FEATURES}, c]");
        Film { c, gg: vec![0.0; g.len()], gb: vec![0.0; b.len()], g, b, cache: None }
    }
    #[cfg(feature = "train")]
    pub(super) fn write(&self, f: &mut crate::model::Film) {
        let dev = f.gamma.val().device();
        f.gamma = Param::initialized(f.gamma.id, tensor(&self.g, [TIME_FEATURES, self.c], &dev));
        f.beta = Param::initialized(f.beta.id, tensor(&self.b, [TIME_FEATURES, self.c], &dev));
    }
    /// Each channel's scale and shift at time `t`.
    fn affine(&self, t: f32) -> (Vec<f32>, Vec<f32>) {
        let f = time_features(t);
        let (mut scale, mut shift) = (vec![1.0f32; self.c], vec![0.0f32; self.c]);
        for (p, fp) in f.iter().enumerate() {
            for c in 0..self.c {
                scale[c] += fp * self.g[p * self.c + c];
                shift[c] += fp * self.b[p * self.c + c];
            }
        }
        (scale, shift)
    }
    /// `x` with sample i at time `ts[i]`, in place.
    pub(super) fn forward(&self, mut x: T4, ts: &[f32]) -> T4 {
        assert_eq!((ts.len(), x.c), (x.n, self.c), "one time per sample, the film's channels");
        let (c, hw) = (x.c, x.hw());
        for (i, &t) in ts.iter().enumerate() {
            let (scale, shift) = self.affine(t);
            let s = &mut x.d[i * c * hw..(i + 1) * c * hw];
            s.par_chunks_mut(hw.max(1)).enumerate().for_each(|(c, plane)| plane.iter_mut().for_each(|v| *v = *v * scale[c] + shift[c]));
        }
        x
    }
    /// Training: keeps the input for the backward pass (the one copy training needs).
    pub(super) fn forward_train(&mut self, x: T4, ts: &[f32]) -> T4 {
        let y = self.forward(x.clone(), ts);
        self.cache = Some((x, ts.to_vec()));
        y
    }
    /// Accumulates the gradients of `G` and `B`; returns the input's.
    pub(super) fn backward(&mut self, dy: &T4) -> T4 {
        let (x, ts) = self.cache.take().expect("forward_train before backward");
        let hw = x.hw();
        let mut dx = dy.clone();
        for (i, &t) in ts.iter().enumerate() {
            let f = time_features(t);
            let (scale, _) = self.affine(t);
            let at = i * x.c * hw;
            // Per channel: the gradient of its scale (sum of dy * x) and shift (sum of dy), in f64.
            let sums: Vec<(f64, f64)> = (0..x.c)
                .into_par_iter()
                .map(|c| {
                    let (xs, ds) = (&x.d[at + c * hw..at + (c + 1) * hw], &dy.d[at + c * hw..at + (c + 1) * hw]);
                    xs.iter().zip(ds).fold((0.0, 0.0), |(a, b), (&xv, &dv)| (a + (xv * dv) as f64, b + dv as f64))
                })
                .collect();
            dx.d[at..at + x.c * hw]
                .par_chunks_mut(hw.max(1))
                .enumerate()
                .for_each(|(c, plane)| plane.iter_mut().for_each(|v| *v *= scale[c]));
            for (p, fp) in f.iter().enumerate() {
                for (c, (ds, db)) in sums.iter().enumerate() {
                    self.gg[p * self.c + c] += fp * *ds as f32;
                    self.gb[p * self.c + c] += fp * *db as f32;
                }
            }
        }
        dx
    }
    pub(super) fn params(&mut self, f: &mut dyn FnMut(&mut [f32], &mut [f32])) {
        f(&mut self.g, &mut self.gg);
        f(&mut self.b, &mut self.gb);
    }
}
