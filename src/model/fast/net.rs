use super::*;

#[derive(Debug, Clone)]
pub(super) struct Down {
    pub(super) conv: Double,
    pub(super) idx: Vec<u8>,
    pub(super) hw_in: (usize, usize),
}

#[derive(Debug, Clone)]
pub(super) struct Up {
    pub(super) up: UpConv,
    pub(super) conv: Double,
    pub(super) skip: usize,
    /// A burst U-Net's time conditioning of this level's concatenation.
    pub(super) film: Option<Film>,
}

#[derive(Debug, Clone)]
pub(super) struct FUnet {
    pub(super) inc: Double,
    pub(super) downs: Vec<Down>,
    pub(super) ups: Vec<Up>,
    pub(super) outc: Conv,
}

/// What the U-Net's decoder still needs at its first level told the time: that level's
/// index, its concatenation of skip and upsampled features, and the skips of the levels after it
/// (finest first).
struct Trunk {
    level: usize,
    cat: T4,
    skips: Vec<T4>,
}

impl FUnet {
    /// The index of the first decoder level told the time (`ups.len() - 1` when none is: the
    /// last level's double convolution and the output layer then make the head).
    fn first_timed(&self) -> usize {
        self.ups.iter().position(|u| u.film.is_some()).unwrap_or(self.ups.len() - 1)
    }

    /// The input padded to a multiple of 16, through every level up to the concatenation of
    /// the first decoder level told the time (what does not depend on the time).
    fn trunk(&self, x: &T4) -> Trunk {
        let (h, w) = (x.h.div_ceil(16) * 16, x.w.div_ceil(16) * 16);
        let xp = if (h, w) != (x.h, x.w) { pad_edge(x, h, w) } else { x.clone() };
        let mut xs = vec![self.inc.forward(&xp)];
        drop(xp);
        for d in &self.downs {
            let (p, _) = maxpool(xs.last().expect("level"));
            xs.push(d.conv.forward(&p));
        }
        let mut y = xs.pop().expect("bottom");
        let level = self.first_timed();
        for u in &self.ups[..level] {
            let skip = xs.pop().expect("skip");
            let upy = u.up.forward(&y);
            y = u.conv.forward(&cat(&skip, &upy));
        }
        let skip = xs.pop().expect("skip");
        let cat = cat(&skip, &self.ups[level].up.forward(&y));
        Trunk { level, cat, skips: xs }
    }

    /// The rest, from the trunk, at the times `ts` (one per sample), plus the input `x`
    /// (cropped back to its size).
    fn head(&self, trunk: &Trunk, ts: &[f32], x: &T4) -> T4 {
        let mut skips = trunk.skips.iter().rev();
        let mut c = trunk.cat.clone();
        let mut y;
        let mut level = trunk.level;
        loop {
            let u = &self.ups[level];
            if let Some(f) = &u.film {
                c = f.forward(c, ts);
            }
            y = u.conv.forward(&c);
            level += 1;
            let Some(next) = self.ups.get(level) else { break };
            c = cat(skips.next().expect("skip"), &next.up.forward(&y));
        }
        drop(c);
        let r = self.outc.forward(&y);
        let mut r = if (r.h, r.w) != (x.h, x.w) { crop(&r, x.h, x.w) } else { r };
        add_into(&mut r, x);
        r
    }
}

/// The times of `n` samples: `ts`, or the middle of the exposure for each when it is empty.
fn times_or_middle(ts: &[f32], n: usize) -> Vec<f32> {
    if ts.is_empty() {
        vec![crate::model::MIDDLE; n]
    } else {
        assert_eq!(ts.len(), n, "one time per sample");
        ts.to_vec()
    }
}

#[derive(Debug, Clone)]
pub(super) struct FShallow {
    pub(super) blocks: Vec<ConvBnAct>,
    pub(super) out: Conv,
}

#[derive(Debug, Clone)]
#[allow(clippy::large_enum_variant)] // one network per process: boxing would buy nothing
pub(super) enum Kind {
    Unet(FUnet),
    Shallow(FShallow),
}

/// One of the two networks with its weights as plain vectors: forward (inference or training)
/// and backward on the CPU.
#[derive(Debug, Clone)]
pub struct FastNet {
    pub(super) kind: Kind,
    /// Crop of the padded output during training (U-Net inputs padded to a multiple of 16).
    pub(super) crop: Option<(usize, usize)>,
}

impl FastNet {
    /// The network of a model file's weights ([`Weights`]: no burn needed).
    ///
    /// [`Weights`]: crate::model::weights::Weights
    pub fn from_weights(mut wt: crate::model::weights::Weights) -> FastNet {
        // burn's BatchNorm defaults, which every trained model used.
        const BN: (f32, f32) = (0.1, 1e-5);
        let arch = wt.arch;
        let mut conv_bn = |p: &str, slope: f32| {
            let w = wt.take(&format!("{p}.conv.weight"));
            let bn = ["gamma", "beta", "running_mean", "running_var"].map(|s| wt.take(&format!("{p}.bn.{s}")));
            let (cout, k) = (bn[0].len(), 3);
            let conv = Conv::from_parts(cout, w.len() / (cout * k * k), k, w, None);
            ConvBnAct::from_parts(conv, bn, BN, slope)
        };
        let kind = match arch {
            crate::model::Arch::Unet { .. } | crate::model::Arch::BurstUnet { .. } => {
                let mut double = |p: &str| Double { a: conv_bn(&format!("{p}.a"), 0.01), b: conv_bn(&format!("{p}.b"), 0.01) };
                let inc = double("Unet.inc");
                let downs = (1..=4).map(|k| Down { conv: double(&format!("Unet.down{k}.conv")), idx: Vec::new(), hw_in: (0, 0) }).collect();
                let convs: Vec<Double> = (1..=4).map(|k| double(&format!("Unet.up{k}.conv"))).collect();
                let ups = convs
                    .into_iter()
                    .enumerate()
                    .map(|(i, conv)| {
                        let (w, b) = (wt.take(&format!("Unet.up{}.up.weight", i + 1)), wt.take(&format!("Unet.up{}.up.bias", i + 1)));
                        let c = b.len();
                        let up = UpConv::from_parts(c, c, w, b);
                        let skip = conv.a.conv.cin - up.cout;
                        let film = (i + arch.timed_levels() >= crate::model::DECODER_LEVELS).then(|| {
                            let p = crate::model::film_name(i);
                            Film::from_parts(wt.take(&format!("{p}.gamma")), wt.take(&format!("{p}.beta")))
                        });
                        Up { up, conv, skip, film }
                    })
                    .collect();
                let (w, b) = (wt.take("Unet.outc.weight"), wt.take("Unet.outc.bias"));
                let outc = Conv::from_parts(3, w.len() / 3, 1, w, Some(b));
                Kind::Unet(FUnet { inc, downs, ups, outc })
            }
            crate::model::Arch::Shallow { .. } => {
                let blocks = (0..9).map(|i| conv_bn(&format!("Shallow.blocks.{i}"), 0.0)).collect();
                let (w, b) = (wt.take("Shallow.out.weight"), wt.take("Shallow.out.bias"));
                let out = Conv::from_parts(3, w.len() / 27, 3, w, Some(b));
                Kind::Shallow(FShallow { blocks, out })
            }
        };
        FastNet { kind, crop: None }
    }

    /// A U-Net as a burst U-Net told the time on (at least) its last `levels` decoder levels,
    /// the conditioning it lacked at zero (the same output at every time); any other network
    /// unchanged.
    pub fn into_burst(mut self, levels: usize) -> FastNet {
        if let Kind::Unet(u) = &mut self.kind {
            let n = u.ups.len();
            for up in u.ups.iter_mut().skip(n.saturating_sub(levels)) {
                if up.film.is_none() {
                    let zeros = vec![0.0; crate::model::TIME_FEATURES * up.conv.a.conv.cin];
                    up.film = Some(Film::from_parts(zeros.clone(), zeros));
                }
            }
        }
        self
    }

    /// The weights and running statistics of a burn network.
    #[cfg(feature = "train")]
    pub fn from_net(net: &Net) -> FastNet {
        let kind = match net {
            Net::Unet(u) => Kind::Unet(FUnet {
                inc: Double::from_burn(&u.inc),
                downs: [&u.down1, &u.down2, &u.down3, &u.down4]
                    .iter()
                    .map(|d| Down { conv: Double::from_burn(&d.conv), idx: Vec::new(), hw_in: (0, 0) })
                    .collect(),
                ups: [(&u.up1, &u.up1.film), (&u.up2, &u.up2.film), (&u.up3, &u.up3.film), (&u.up4, &u.film)]
                    .iter()
                    .map(|(up, film)| {
                        let upc = UpConv::from_burn(&up.up);
                        let conv = Double::from_burn(&up.conv);
                        let skip = conv.a.conv.cin - upc.cout;
                        Up { up: upc, conv, skip, film: film.as_ref().map(Film::from_burn) }
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
    #[cfg(feature = "train")]
    pub fn write_into(&self, mut net: Net) -> Net {
        match (&self.kind, &mut net) {
            (Kind::Unet(f), Net::Unet(u)) => {
                f.inc.write(&mut u.inc);
                for (d, b) in f.downs.iter().zip([&mut u.down1, &mut u.down2, &mut u.down3, &mut u.down4]) {
                    d.conv.write(&mut b.conv);
                }
                let films = [u.up1.film.take(), u.up2.film.take(), u.up3.film.take(), u.film.take()];
                let mut films = f.ups.iter().zip(films).map(|(d, b)| match (&d.film, b) {
                    (Some(a), Some(mut b)) => {
                        a.write(&mut b);
                        Some(b)
                    }
                    (None, None) => None,
                    _ => panic!("write_into: U-Nets told the time on different levels"),
                });
                let mut next = || films.next().expect("four levels");
                (u.up1.film, u.up2.film, u.up3.film, u.film) = (next(), next(), next(), next());
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

    /// Inference (BatchNorm with running statistics): `[n, 3, h, w]` in, the same out (a burst
    /// U-Net: at the middle of the exposure).
    pub fn forward(&self, x: &T4) -> T4 {
        self.forward_at(x, &[])
    }

    /// Whether the network takes the time (a burst U-Net).
    pub fn is_burst(&self) -> bool {
        matches!(&self.kind, Kind::Unet(u) if u.ups.iter().any(|u| u.film.is_some()))
    }

    /// [`FastNet::forward`] with sample i at time `ts[i]` (empty: every sample at the middle;
    /// a single-frame network ignores the times).
    pub fn forward_at(&self, x: &T4, ts: &[f32]) -> T4 {
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
                let ts = times_or_middle(ts, x.n);
                m.head(&m.trunk(x), &ts, x)
            }
        }
    }

    /// A burst U-Net's output at each of the times `ts`, every sample at every time: the part
    /// that does not depend on the time (the encoder and the decoder levels before the first
    /// one told the time) runs once. A single-frame network gives its one output for every time.
    pub fn forward_burst(&self, x: &T4, ts: &[f32]) -> Vec<T4> {
        match &self.kind {
            Kind::Unet(m) if self.is_burst() => {
                let trunk = m.trunk(x);
                ts.iter().map(|&t| m.head(&trunk, &vec![t; x.n], x)).collect()
            }
            _ => {
                let y = self.forward(x);
                vec![y; ts.len()]
            }
        }
    }

    /// Training forward (batch statistics, running statistics updated), keeping what the
    /// backward pass needs (a burst U-Net: at the middle of the exposure).
    pub fn forward_train(&mut self, x: &T4) -> T4 {
        self.forward_train_at(x, &[])
    }

    /// [`FastNet::forward_train`] with sample i at time `ts[i]` (empty: the middle).
    pub fn forward_train_at(&mut self, x: &T4, ts: &[f32]) -> T4 {
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
                let ts = times_or_middle(ts, x.n);
                for u in m.ups.iter_mut() {
                    let skip = xs.pop().expect("skip");
                    let upy = u.up.forward_train(y);
                    let c = cat(&skip, &upy);
                    let c = match &mut u.film {
                        Some(f) => f.forward_train(c, &ts),
                        None => c,
                    };
                    y = u.conv.forward_train(Arc::new(c));
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
                let mut d = m.out.backward(dout, true);
                for (i, b) in m.blocks.iter_mut().enumerate().rev() {
                    d = b.backward(d.expect("dx"), i != 0);
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
                    let dcat = u.conv.backward(d, true).expect("dx");
                    let dcat = match &mut u.film {
                        Some(f) => f.backward(&dcat),
                        None => dcat,
                    };
                    let (dskip, dup) = split(&dcat, u.skip);
                    d = u.up.backward(&dup);
                    skips.push(dskip);
                }
                // skips: gradients of x1, x2, x3, x4 (in that order); d: of the bottom x5.
                for (dn, mut s) in m.downs.iter_mut().rev().zip(skips.into_iter().rev()) {
                    let dp = dn.conv.backward(d, true).expect("dx");
                    let (h, w) = dn.hw_in;
                    add_into(&mut s, &maxpool_backward(&dp, &dn.idx, h, w));
                    d = s;
                }
                m.inc.backward(d, false);
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
                // burn's order: each level's time conditioning after its convolutions, the
                // last level's after the output layer (where the first burst models had it).
                let (last, ups) = m.ups.split_last_mut().expect("levels");
                for u in ups {
                    u.up.params(f);
                    u.conv.params(f);
                    if let Some(film) = u.film.as_mut() {
                        film.params(f);
                    }
                }
                last.up.params(f);
                last.conv.params(f);
                m.outc.params(f);
                if let Some(film) = last.film.as_mut() {
                    film.params(f);
                }
            }
        }
    }

    /// Every BatchNorm layer, in a fixed order.
    pub(super) fn bn_layers(&mut self, f: &mut dyn FnMut(&mut ConvBnAct)) {
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
