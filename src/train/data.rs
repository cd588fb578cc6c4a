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

/// Where a training sample came from: the index of its shard in the run's shard list and its
/// place among that shard's samples (validation samples included), so a checkpoint can name the
/// samples in the shuffle buffer without storing them.
pub type Origin = (u32, u32);

/// The training stream: shards in a seeded order per epoch, through a seeded shuffle buffer.
/// Its position ([`StreamState`]) is saved with each checkpoint, so `--resume` picks the data
/// order up where it stopped instead of replaying every earlier step's samples.
pub(super) struct Stream {
    pub(super) shards: Vec<PathBuf>,
    pub(super) seed: u64,
    pub(super) fraction: f64,
    pub(super) buffer: Vec<(Origin, Pair)>,
    pub(super) cap: usize,
    pub(super) epoch: u64,
    /// The shards left in this epoch, by index, the next one last.
    pub(super) queue: Vec<u32>,
    /// The shard being drained and how many of its training samples were taken.
    pub(super) current: Option<(u32, u32)>,
    pub(super) pending: std::collections::VecDeque<(Origin, Pair)>,
    pub(super) rng: Rng,
    pub(super) size: Option<(usize, usize)>,
    /// The origins of the latest `keep` batches (BatchNorm is recalibrated from them).
    pub(super) recent: std::collections::VecDeque<Vec<Origin>>,
    pub(super) keep: usize,
}

/// A `Stream`'s position: `stream-NNNNNNN.json` beside the checkpoint of step NNNNNNN.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StreamState {
    /// The shard list it indexes; a resume with other shards replays instead.
    pub shards: Vec<PathBuf>,
    pub seed: u64,
    pub val_fraction: f64,
    pub shuffle_buffer: usize,
    pub epoch: u64,
    pub queue: Vec<u32>,
    pub current: Option<(u32, u32)>,
    pub buffer: Vec<Origin>,
    pub rng: u64,
    pub recent: Vec<Vec<Origin>>,
}

impl StreamState {
    pub(super) fn path(dir: &Path, step: usize) -> PathBuf {
        dir.join(format!("stream-{step:07}.json"))
    }

    /// The saved position of step `step` in `dir`, if there is one for this shard list and data
    /// config; None (so the caller replays) when it is missing, unreadable or for other data.
    pub(super) fn read(dir: &Path, step: usize, shards: &[PathBuf], cfg: &TrainConfig) -> Option<StreamState> {
        let s: StreamState = serde_json::from_slice(&std::fs::read(Self::path(dir, step)).ok()?).ok()?;
        let n = shards.len() as u32;
        let fits = s.shards == shards
            && s.seed == cfg.seed
            && s.val_fraction == cfg.data.val_fraction
            && s.shuffle_buffer == cfg.data.shuffle_buffer
            && s.queue.iter().all(|&q| q < n)
            && s.current.is_none_or(|c| c.0 < n)
            && s.buffer.iter().chain(s.recent.iter().flatten()).all(|o| o.0 < n);
        fits.then_some(s)
    }

    /// The samples [`Stream::restore`] needs from the shards: the buffer's and the recent batches'.
    pub(super) fn needed(&self) -> std::collections::HashSet<Origin> {
        self.buffer.iter().chain(self.recent.iter().flatten()).copied().collect()
    }
}

impl Stream {
    pub(super) fn new(shards: Vec<PathBuf>, seed: u64, fraction: f64, cap: usize, size: Option<(usize, usize)>, keep: usize) -> Stream {
        Stream {
            shards,
            seed,
            fraction,
            buffer: Vec::new(),
            cap,
            epoch: 0,
            queue: Vec::new(),
            current: None,
            pending: Default::default(),
            rng: Rng::new(hash(&[seed, hash_str("shuffle")])),
            size,
            recent: Default::default(),
            keep,
        }
    }

    /// The training samples of shard `i` with their origins, skipping the first `skip`.
    fn shard_samples(&self, i: u32, skip: usize) -> Result<Vec<(Origin, Pair)>> {
        let pairs = read_shard(&self.shards[i as usize], self.size)?;
        Ok(pairs
            .into_iter()
            .enumerate()
            .filter(|(_, p)| !is_validation(self.seed, p.source, self.fraction))
            .skip(skip)
            .map(|(j, p)| ((i, j as u32), p))
            .collect())
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
                let mut order: Vec<u32> = (0..self.shards.len() as u32).collect();
                let mut r = Rng::new(hash(&[self.seed, self.epoch, hash_str("shard-order")]));
                for i in (1..order.len()).rev() {
                    order.swap(i, r.below(i + 1));
                }
                order.reverse();
                self.queue = order;
                self.epoch += 1;
            }
            let s = self.queue.pop().expect("refilled");
            self.current = Some((s, 0));
            let samples = self.shard_samples(s, 0)?;
            self.pending.extend(samples);
            if !self.pending.is_empty() {
                read_epochs = 0;
            }
        }
        Ok(true)
    }

    /// The next sample, drawn from the shuffle buffer, and its origin.
    fn take(&mut self) -> Result<(Origin, Pair)> {
        while self.buffer.len() < self.cap {
            if !self.refill()? {
                return Err(Error::Usage("data.shards: the shards hold no training sample (all inputs went to validation?)".into()));
            }
            let (o, p) = self.pending.pop_front().expect("refilled");
            if let Some(c) = &mut self.current {
                c.1 += 1;
            }
            if self.size.is_none() {
                self.size = Some((p.w, p.h));
            }
            self.buffer.push((o, p));
        }
        let i = self.rng.below(self.buffer.len());
        Ok(self.buffer.swap_remove(i))
    }

    /// The next batch of `n` samples, remembering the latest `keep` batches' origins.
    pub(super) fn batch(&mut self, n: usize) -> Result<Vec<Pair>> {
        let (origins, batch): (Vec<Origin>, Vec<Pair>) = (0..n).map(|_| self.take()).collect::<Result<Vec<_>>>()?.into_iter().unzip();
        push_latest(&mut self.recent, self.keep, || origins);
        Ok(batch)
    }

    /// Its position now.
    pub(super) fn state(&self) -> StreamState {
        StreamState {
            shards: self.shards.clone(),
            seed: self.seed,
            val_fraction: self.fraction,
            shuffle_buffer: self.cap,
            epoch: self.epoch,
            queue: self.queue.clone(),
            current: self.current,
            buffer: self.buffer.iter().map(|b| b.0).collect(),
            rng: self.rng.state(),
            recent: self.recent.iter().cloned().collect(),
        }
    }

    /// The stream at `state`, with the buffered samples taken from `found` (the samples
    /// [`StreamState::needed`] names, read by the caller's scan of the shards); the batches
    /// `state.recent` names come back for the BatchNorm recalibration.
    ///
    /// # Errors
    /// A sample `state` names is not in `found` (the shards changed under the same names), or the
    /// shard being drained cannot be read.
    pub(super) fn restore(&mut self, state: StreamState, found: &std::collections::HashMap<Origin, Pair>) -> Result<Vec<Vec<Pair>>> {
        let get = |o: &Origin| {
            found.get(o).cloned().ok_or_else(|| Error::File {
                path: self.shards[o.0 as usize].clone(),
                why: format!(
                    "sample {} is not where the checkpoint's data position says (were the shards rewritten?); resume \
                         after deleting the stream-*.json files to replay the data order instead",
                    o.1
                ),
            })
        };
        self.buffer = state.buffer.iter().map(|o| Ok((*o, get(o)?))).collect::<Result<_>>()?;
        let recent: Vec<Vec<Pair>> = state.recent.iter().map(|b| b.iter().map(&get).collect::<Result<_>>()).collect::<Result<_>>()?;
        self.epoch = state.epoch;
        self.queue = state.queue;
        self.current = state.current;
        self.rng = Rng::new(state.rng);
        self.recent = state.recent.into_iter().collect();
        self.pending = match state.current {
            Some((s, taken)) => self.shard_samples(s, taken as usize)?.into(),
            None => Default::default(),
        };
        Ok(recent)
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
/// photographs), in bounded memory. `T` is the sample (the scan of the shards keeps them
/// undecoded and decodes only the ones picked).
pub(super) struct ValPick<T> {
    pub(super) max: usize,
    pub(super) seed: u64,
    /// (hash, ordinal, sample): the ordinal breaks ties of equal keys (shards of different
    /// window lengths cut from the same clips).
    pub(super) v: Vec<(u64, usize, T)>,
    pub(super) held: usize,
}

impl<T> ValPick<T> {
    pub(super) fn new(max: usize, seed: u64) -> ValPick<T> {
        ValPick { max, seed, v: Vec::new(), held: 0 }
    }
    pub(super) fn push(&mut self, key: &str, p: T) {
        if self.max == 0 {
            return;
        }
        self.v.push((hash(&[self.seed, hash_str(key), hash_str("val-pick")]), self.held, p));
        self.held += 1;
        if self.v.len() >= 2 * self.max {
            self.keep();
        }
    }
    pub(super) fn keep(&mut self) {
        self.v.sort_unstable_by_key(|v| (v.0, v.1));
        self.v.truncate(self.max);
    }
    pub(super) fn finish(mut self) -> Vec<T> {
        self.keep();
        self.v.into_iter().map(|v| v.2).collect()
    }
}

/// Appends a batch's inputs to `recent`, keeping the latest `k`.
pub(super) fn keep_latest(recent: &mut std::collections::VecDeque<T4>, k: usize, batch: &[Pair]) {
    let (w, h) = (batch[0].w, batch[0].h);
    push_latest(recent, k, || to_t4(&batch.iter().map(|p| p.lq.as_slice()).collect::<Vec<_>>(), w, h));
}

/// Appends `item()` to `recent`, keeping the latest `k` (none, and `item` not called, for 0).
pub(super) fn push_latest<T>(recent: &mut std::collections::VecDeque<T>, k: usize, item: impl FnOnce() -> T) {
    if k == 0 {
        return;
    }
    if recent.len() == k {
        recent.pop_front();
    }
    recent.push_back(item());
}
