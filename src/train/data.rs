use super::*;

/// Train/validation split by source input (never by patch).
pub fn is_validation(seed: u64, source: u64, fraction: f64) -> bool {
    unit(hash(&[seed, source, hash_str("val-split")])) < fraction
}

/// Flip or rotate an interleaved RGB square patch in place of `t` (0..8: the dihedral group).
pub(super) fn augment(img: &[u8], n: usize, t: u64) -> Vec<u8> {
    let mut out = vec![0u8; img.len()];
    for y in 0..n {
        for x in 0..n {
            let (mut sx, mut sy) = (x, y);
            if t & 1 == 1 {
                sx = n - 1 - sx;
            }
            if t & 2 == 2 {
                sy = n - 1 - sy;
            }
            if t & 4 == 4 {
                std::mem::swap(&mut sx, &mut sy);
            }
            out[(y * n + x) * 3..(y * n + x) * 3 + 3].copy_from_slice(&img[(sy * n + sx) * 3..(sy * n + sx) * 3 + 3]);
        }
    }
    out
}

/// The training stream: shards in a seeded order per epoch, through a seeded shuffle buffer.
pub(super) struct Stream {
    pub(super) shards: Vec<PathBuf>,
    pub(super) seed: u64,
    pub(super) fraction: f64,
    pub(super) buffer: Vec<Pair>,
    pub(super) cap: usize,
    pub(super) epoch: u64,
    pub(super) queue: Vec<PathBuf>,
    pub(super) pending: std::collections::VecDeque<Pair>,
    pub(super) rng: Rng,
    pub(super) size: Option<(usize, usize)>,
}

impl Stream {
    pub(super) fn new(shards: Vec<PathBuf>, seed: u64, fraction: f64, cap: usize, size: Option<(usize, usize)>) -> Stream {
        Stream {
            shards,
            seed,
            fraction,
            buffer: Vec::new(),
            cap,
            epoch: 0,
            queue: Vec::new(),
            pending: Default::default(),
            rng: Rng::new(hash(&[seed, hash_str("shuffle")])),
            size,
        }
    }

    pub(super) fn refill(&mut self) -> Result<bool> {
        let mut read_epochs = 0;
        while self.pending.is_empty() {
            if self.queue.is_empty() {
                // A whole pass over the shards gave no training sample.
                if read_epochs == 1 {
                    return Ok(false);
                }
                read_epochs += 1;
                let mut order = self.shards.clone();
                let mut r = Rng::new(hash(&[self.seed, self.epoch, hash_str("shard-order")]));
                for i in (1..order.len()).rev() {
                    order.swap(i, r.below(i + 1));
                }
                order.reverse();
                self.queue = order;
                self.epoch += 1;
            }
            let s = self.queue.pop().expect("refilled");
            let pairs = read_shard(&s, self.size)?;
            self.pending.extend(pairs.into_iter().filter(|p| !is_validation(self.seed, p.source, self.fraction)));
            if !self.pending.is_empty() {
                read_epochs = 0;
            }
        }
        Ok(true)
    }

    pub(super) fn next(&mut self) -> Result<Pair> {
        while self.buffer.len() < self.cap {
            if !self.refill()? {
                return Err(Error::Invalid("the shards hold no training sample (all inputs went to validation?)".into()));
            }
            let p = self.pending.pop_front().expect("refilled");
            if self.size.is_none() {
                self.size = Some((p.w, p.h));
            }
            self.buffer.push(p);
        }
        let i = self.rng.below(self.buffer.len());
        Ok(self.buffer.swap_remove(i))
    }
}

pub(super) fn to_tensor(imgs: &[&[u8]], w: usize, h: usize, device: &Device) -> Tensor<4> {
    to_t4(imgs, w, h).to_tensor(device)
}

/// `[n, 3, h, w]` values in [0, 1] from 8-bit interleaved RGB images.
pub fn to_t4(imgs: &[&[u8]], w: usize, h: usize) -> T4 {
    let n = imgs.len();
    let mut v = vec![0.0f32; n * 3 * h * w];
    for (b, img) in imgs.iter().enumerate() {
        for i in 0..h * w {
            for c in 0..3 {
                v[((b * 3 + c) * h * w) + i] = img[i * 3 + c] as f32 / 255.0;
            }
        }
    }
    T4::new(n, 3, h, w, v)
}

/// 8-bit interleaved RGB images from a `[n, 3, h, w]` tensor of values in [0, 1].
pub fn from_tensor(t: Tensor<4>) -> Vec<Vec<u8>> {
    from_t4(&T4::from_tensor(t))
}

/// 8-bit interleaved RGB images from `[n, 3, h, w]` values in [0, 1].
pub fn from_t4(t: &T4) -> Vec<Vec<u8>> {
    let (n, h, w, v) = (t.n, t.h, t.w, &t.d);
    (0..n)
        .map(|b| {
            let mut img = vec![0u8; h * w * 3];
            for i in 0..h * w {
                for c in 0..3 {
                    img[i * 3 + c] = (v[(b * 3 + c) * h * w + i].clamp(0.0, 1.0) * 255.0).round() as u8;
                }
            }
            img
        })
        .collect()
}

/// The validation samples: the `max` held-out samples of smallest seeded key hash, so they
/// spread over every held-out input (the first ones in shard order came from one or two
/// photographs), in bounded memory.
pub(super) struct ValPick {
    pub(super) max: usize,
    pub(super) seed: u64,
    /// (hash, ordinal, sample): the ordinal breaks ties of equal keys (shards of different
    /// window lengths cut from the same clips).
    pub(super) v: Vec<(u64, usize, Pair)>,
    pub(super) held: usize,
}

impl ValPick {
    pub(super) fn new(max: usize, seed: u64) -> ValPick {
        ValPick { max, seed, v: Vec::new(), held: 0 }
    }
    pub(super) fn push(&mut self, p: Pair) {
        if self.max == 0 {
            return;
        }
        self.v.push((hash(&[self.seed, hash_str(&p.key), hash_str("val-pick")]), self.held, p));
        self.held += 1;
        if self.v.len() >= 2 * self.max {
            self.keep();
        }
    }
    pub(super) fn keep(&mut self) {
        self.v.sort_unstable_by_key(|v| (v.0, v.1));
        self.v.truncate(self.max);
    }
    pub(super) fn finish(mut self) -> Vec<Pair> {
        self.keep();
        self.v.into_iter().map(|v| v.2).collect()
    }
}

/// Appends a batch's inputs to `recent`, keeping the latest `k`.
pub(super) fn keep_latest(recent: &mut std::collections::VecDeque<T4>, k: usize, batch: &[Pair]) {
    if k == 0 {
        return;
    }
    if recent.len() == k {
        recent.pop_front();
    }
    let (w, h) = (batch[0].w, batch[0].h);
    recent.push_back(to_t4(&batch.iter().map(|p| p.lq.as_slice()).collect::<Vec<_>>(), w, h));
}
