//! `pipeline train`: the paper's U-Net or shallow model on (lq, gt) patch pairs from WebDataset
//! shards, with Huber loss and Adam, validation PSNR/SSIM on inputs held apart by source video,
//! checkpoints ([`crate::model::checkpoint`]) and exact resume.
//!
//! Determinism: the shard order, the shuffle buffer and the augmentations are functions of the
//! seed and the step, so `--resume` continues with the data order the uninterrupted run would
//! have had (it replays the sample stream up to the checkpoint).

pub use crate::io::wds::{read_shard, Pair};
use crate::io::write_atomic;
use crate::metrics;
pub use crate::model::checkpoint::{load_model, load_model_bytes};
use crate::model::checkpoint::{read_meta, save_checkpoint, save_model, IdSetter, Latest};
use crate::model::fast::{self, Adam, FastNet, T4};
use crate::model::Net;
use crate::rng::{hash, hash_str, unit, Rng};
use crate::{Error, Result};
use burn::module::Module;
use burn::nn::loss::{HuberLossConfig, Reduction};
use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::{Device, Tensor};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

mod config;
pub use config::*;

/// Train/validation split by source input (never by patch).
pub fn is_validation(seed: u64, source: u64, fraction: f64) -> bool {
    unit(hash(&[seed, source, hash_str("val-split")])) < fraction
}

/// Flip or rotate an interleaved RGB square patch in place of `t` (0..8: the dihedral group).
fn augment(img: &[u8], n: usize, t: u64) -> Vec<u8> {
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
struct Stream {
    shards: Vec<PathBuf>,
    seed: u64,
    fraction: f64,
    buffer: Vec<Pair>,
    cap: usize,
    epoch: u64,
    queue: Vec<PathBuf>,
    pending: std::collections::VecDeque<Pair>,
    rng: Rng,
    size: Option<(usize, usize)>,
}

impl Stream {
    fn new(shards: Vec<PathBuf>, seed: u64, fraction: f64, cap: usize, size: Option<(usize, usize)>) -> Stream {
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

    fn refill(&mut self) -> Result<bool> {
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

    fn next(&mut self) -> Result<Pair> {
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

fn to_tensor(imgs: &[&[u8]], w: usize, h: usize, device: &Device) -> Tensor<4> {
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

/// Mean quality of a model's outputs on validation pairs, and of the inputs themselves.
pub fn evaluate(model: &Net, val: &[Pair], device: &Device) -> (metrics::Quality, metrics::Quality) {
    evaluate_with(val, |x, w, h| from_tensor(model.forward(to_tensor(x, w, h, device))))
}

/// [`evaluate`] with the CPU fast path.
pub fn evaluate_fast(model: &FastNet, val: &[Pair]) -> (metrics::Quality, metrics::Quality) {
    evaluate_with(val, |x, w, h| from_t4(&model.forward(&to_t4(x, w, h))))
}

fn evaluate_with(val: &[Pair], forward: impl Fn(&[&[u8]], usize, usize) -> Vec<Vec<u8>>) -> (metrics::Quality, metrics::Quality) {
    let mut sums = [[0.0f64; 4]; 2];
    for chunk in val.chunks(8) {
        let (w, h) = (chunk[0].w, chunk[0].h);
        let outs = forward(&chunk.iter().map(|p| p.lq.as_slice()).collect::<Vec<_>>(), w, h);
        for (p, o) in chunk.iter().zip(outs) {
            for (k, img) in [o.as_slice(), p.lq.as_slice()].iter().enumerate() {
                let q = metrics::quality(img, &p.gt, w, h);
                let v = [q.psnr_rgb.min(99.0), q.ssim_rgb, q.psnr_y.min(99.0), q.ssim_y];
                for i in 0..4 {
                    sums[k][i] += v[i];
                }
            }
        }
    }
    let n = val.len().max(1) as f64;
    let q = |s: [f64; 4]| metrics::Quality { psnr_rgb: s[0] / n, ssim_rgb: s[1] / n, psnr_y: s[2] / n, ssim_y: s[3] / n };
    (q(sums[0]), q(sums[1]))
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LossPoint {
    pub step: usize,
    pub loss: f64,
    pub lr: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ValPoint {
    pub step: usize,
    pub model: metrics::Quality,
    pub input: metrics::Quality,
}

/// `report.json` of a training run.
#[derive(Debug, Clone, Serialize)]
pub struct TrainReport {
    pub version: &'static str,
    pub arch: String,
    pub parameters: usize,
    pub steps: usize,
    pub resumed_from: Option<usize>,
    /// Stopped by SIGINT or SIGTERM; `steps` were done and checkpointed.
    pub interrupted: bool,
    pub seconds: f64,
    pub patches_per_s: f64,
    pub train_inputs: Vec<u64>,
    pub val_inputs: Vec<u64>,
    pub val_samples: usize,
    pub metrics_convention: &'static str,
    pub loss: Vec<LossPoint>,
    pub validation: Vec<ValPoint>,
    /// The learning-rate schedule this run followed, in words.
    pub schedule: String,
    /// With `init`: the initial model's own training, whose steps come before this run's step 1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub before: Option<Before>,
    /// `model.safetensors`, the mean of the last checkpoints (`output.average_last`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub averaged: Option<Averaged>,
    pub config: TrainConfig,
}

/// The training history of the model a fine-tuning run started from (`init`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Before {
    /// The `init` value.
    pub model: String,
    /// Its training steps; in the curves they run up to step 0 of this run.
    pub steps: usize,
    pub loss: Vec<LossPoint>,
    pub validation: Vec<ValPoint>,
}

/// The averaged model of a run and its validation score.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Averaged {
    /// The checkpoints averaged, by step.
    pub steps: Vec<usize>,
    pub model: metrics::Quality,
    pub input: metrics::Quality,
}

/// Options of one `pipeline train` call.
pub struct TrainOptions {
    pub resume: bool,
    /// Start afresh in an output folder that holds a run, removing its checkpoints and history.
    pub overwrite: bool,
    pub progress: crate::progress::ProgressMode,
    /// Stop after this step (tests of resume); None: run to `optim.steps`.
    pub stop_after: Option<usize>,
}

/// A model and its optimizer state, in one of the two implementations.
enum Engine {
    /// burn's autodiff (the reference path; the GPU path with the `wgpu`/`cuda` features).
    Burn { device: Device, model: Net, optim: burn::optim::ModuleOptimizer, huber: burn::nn::loss::HuberLoss },
    /// `src/model/fast.rs`; `template` carries the parameter ids the checkpoints are written with.
    Fast { net: Box<FastNet>, adam: Adam, template: Net },
}

impl Engine {
    /// One optimisation step; returns the loss before it.
    fn step(&mut self, x: &T4, y: &T4, lr: f64, delta: f64, eps: f64) -> f64 {
        match self {
            Engine::Burn { device, model, optim, huber } => {
                let loss = huber.forward(model.forward(x.to_tensor(device)), y.to_tensor(device), Reduction::Mean);
                let lv = loss.clone().into_scalar::<f32>() as f64;
                if lv.is_finite() {
                    let grads = GradientsParams::from_grads(loss.backward(), model);
                    // The module holds tensor handles: cloning it is cheap.
                    *model = optim.step(lr, model.clone(), grads);
                }
                lv
            }
            Engine::Fast { net, adam, .. } => fast::train_step(net, adam, x, y, lr as f32, delta as f32, eps as f32),
        }
    }

    /// The network as a burn module on the CPU (for checkpoints and reports).
    fn net(&self) -> Net {
        match self {
            Engine::Burn { model, .. } => model.valid(),
            Engine::Fast { net, template, .. } => net.write_into(template.clone()),
        }
    }

    fn num_params(&self) -> usize {
        match self {
            Engine::Burn { model, .. } => model.num_params(),
            Engine::Fast { template, .. } => template.num_params(),
        }
    }

    fn optim_bytes(&self) -> Result<Vec<u8>> {
        match self {
            Engine::Burn { optim, .. } => {
                Ok(optim.clone().into_bytes().map_err(|e| Error::Invalid(format!("optimizer state: {e:?}")))?.to_vec())
            }
            Engine::Fast { adam, .. } => Ok(adam.to_bytes()),
        }
    }

    fn evaluate(&self, val: &[Pair]) -> (metrics::Quality, metrics::Quality) {
        match self {
            Engine::Burn { model, device, .. } => evaluate(&model.valid(), val, &device.clone().inner()),
            Engine::Fast { net, .. } => evaluate_fast(net, val),
        }
    }
}

/// Takes `dir/.train.lock` for the life of the run: a second `pipeline train` into the same
/// folder is refused rather than left to overwrite the first one's checkpoints.
///
/// # Errors
/// The lock is held by another process (a usage error naming the folder), or cannot be made.
fn lock_run_folder(dir: &Path) -> Result<std::fs::File> {
    let lp = dir.join(".train.lock");
    let f = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&lp)
        .map_err(|e| Error::Io { path: lp.clone(), cause: e })?;
    match f.try_lock() {
        Ok(()) => Ok(f),
        Err(std::fs::TryLockError::WouldBlock) => Err(Error::Usage(format!(
            "{}: another `pipeline train` is writing to this folder (it holds {}); wait for it to finish or choose another output.dir",
            dir.display(),
            lp.display()
        ))),
        Err(std::fs::TryLockError::Error(e)) => Err(Error::Io { path: lp, cause: e }),
    }
}

/// The files a training run writes in its folder.
fn run_files(dir: &Path) -> Vec<PathBuf> {
    let fixed = ["latest.json", "report.json", "history.csv", "curves.png", "model.safetensors"];
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            let n = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            fixed.contains(&n.as_str())
                || (n.starts_with("model-") && n.ends_with(".safetensors"))
                || (n.starts_with("optim-") && n.ends_with(".bin"))
        })
        .collect();
    v.sort();
    v
}

/// `--resume` continues the learning-rate schedule the run started with: a changed one would
/// jump (more `optim.steps` raises the cosine's rate again), so it is refused, naming the keys.
fn schedule_unchanged(was: &serde_json::Value, now: &OptimConfig, dir: &Path) -> Result<()> {
    let now = serde_json::to_value(now).expect("json");
    let changed: Vec<String> = ["steps", "lr", "warmup_steps", "lr_min_factor", "schedule"]
        .iter()
        .filter(|k| was.get(**k).is_some() && was.get(**k) != now.get(**k))
        .map(|k| format!("optim.{k} {} -> {}", was[*k], now[*k]))
        .collect();
    if changed.is_empty() {
        return Ok(());
    }
    Err(Error::Usage(format!(
        "{}: --resume continues the run's learning-rate schedule, and this changes it ({}); resume without the change, or \
         train further on a new schedule with --set init={:?} and a fresh output.dir",
        dir.display(),
        changed.join(", "),
        dir.display().to_string()
    )))
}

/// A run that does not resume starts in a folder without one: refused when the folder holds a
/// run, unless `overwrite`, which removes that run's files first (so no old checkpoint is left
/// beside the new ones).
///
/// # Errors
/// The folder holds a run and `overwrite` is off (a usage error saying what to do instead).
fn fresh_run_folder(dir: &Path, overwrite: bool) -> Result<()> {
    let files = run_files(dir);
    if files.is_empty() {
        return Ok(());
    }
    if !overwrite {
        let step = std::fs::read(dir.join("latest.json")).ok().and_then(|b| serde_json::from_slice::<Latest>(&b).ok()).map(|l| l.step);
        return Err(Error::Usage(format!(
            "{} holds a training run ({}{} files): add --resume to continue it, train a new model from it with --set init={:?} and a fresh \
             output.dir, or choose a fresh output.dir (--overwrite deletes that run)",
            dir.display(),
            step.map_or(String::new(), |s| format!("step {s}, ")),
            files.len(),
            dir.display().to_string()
        )));
    }
    for f in files {
        std::fs::remove_file(&f).map_err(|e| Error::Io { path: f, cause: e })?;
    }
    Ok(())
}

/// The training state: model, optimizer, schedule, history. Fed batches by [`train`] (from
/// shards) or by the `trainer` sink (straight from the generator).
pub struct Trainer {
    pub cfg: TrainConfig,
    dir: PathBuf,
    engine: Engine,
    pub step: usize,
    start: usize,
    before: Option<Before>,
    interrupted: bool,
    end: usize,
    pub val: Vec<Pair>,
    pub train_inputs: std::collections::BTreeSet<u64>,
    pub val_inputs: std::collections::BTreeSet<u64>,
    losses: Vec<LossPoint>,
    vals: Vec<ValPoint>,
    /// The inputs of the latest `validate.bn_batches` training batches, for [`FastNet::recalibrate_bn`].
    recent: std::collections::VecDeque<T4>,
    averaged: Option<Averaged>,
    t0: Instant,
    t_train: Instant,
    /// The folder's `.train.lock`, held until the run ends.
    _lock: std::fs::File,
    bar: crate::progress::Bar,
}

impl Trainer {
    /// A fresh model (or the checkpoint in `output.dir` with `resume`).
    ///
    /// # Errors
    /// Bad config values (all named), an unwritable output folder, an unreadable checkpoint.
    pub fn new(cfg: &TrainConfig, opts: &TrainOptions) -> Result<Trainer> {
        let errs = cfg.validate();
        if !errs.is_empty() {
            return Err(Error::Config(errs));
        }
        let dir = PathBuf::from(&cfg.output.dir);
        std::fs::create_dir_all(&dir).map_err(|e| Error::Io { path: dir.clone(), cause: e })?;
        let lock = lock_run_folder(&dir)?;
        if !opts.resume {
            fresh_run_folder(&dir, opts.overwrite)?;
        }
        let fast = cfg.optim.engine == EngineKind::Fast;
        let device = if fast { Device::flex() } else { Device::flex().autodiff() };
        // Initial weights are a function of the config's seed alone.
        let mut model = Net::seeded(cfg.model, &device, hash(&[cfg.seed, hash_str("init")]));
        if cfg.optim.zero_init {
            model = model.zero_last_layer(&device);
        }
        let mut optim_bytes = None;
        let mut start = 0;
        let mut history: (Vec<LossPoint>, Vec<ValPoint>) = (Vec::new(), Vec::new());
        let mut before = None;
        // What an earlier report.json holds of its run.
        #[derive(Deserialize)]
        struct History {
            steps: usize,
            loss: Vec<LossPoint>,
            validation: Vec<ValPoint>,
            #[serde(default)]
            before: Option<Before>,
            config: Option<serde_json::Value>,
        }
        let read_history = |p: &Path| -> Option<History> { std::fs::read(p).ok().and_then(|b| serde_json::from_slice(&b).ok()) };
        if let (Some(init), false) = (&cfg.init, opts.resume) {
            let path = Path::new(init);
            let (net, arch) = load_model(path, &device).map_err(|e| Error::Invalid(format!("init: {e}")))?;
            if arch != cfg.model {
                return Err(Error::Invalid(format!(
                    "init: {init} holds a {} model, the config's model is {}",
                    arch.name(),
                    cfg.model.name()
                )));
            }
            model = net;
            // A fine-tuning run is a run of its own (steps 1 to optim.steps, a fresh schedule
            // peaking at optim.lr); the initial model's history is kept for the curves.
            before = path.is_dir().then(|| read_history(&path.join("report.json"))).flatten().map(|h| Before {
                model: init.clone(),
                steps: h.steps,
                loss: h.loss,
                validation: h.validation,
            });
        }
        if opts.resume {
            let lp = dir.join("latest.json");
            let (latest, mpath, op) =
                Latest::read(&dir)?.ok_or_else(|| Error::Io { path: lp, cause: std::io::Error::from(std::io::ErrorKind::NotFound) })?;
            let (net, arch) = load_model(&mpath, &device)?;
            if arch != cfg.model {
                return Err(Error::Usage(format!(
                    "{}: the run being resumed is a {} model and the config asks for {}: --resume continues the same network \
                     (to start another from it, use --set init={:?} with a fresh output.dir)",
                    mpath.display(),
                    arch.name(),
                    cfg.model.name(),
                    dir.display().to_string()
                )));
            }
            let bytes = std::fs::read(&mpath).map_err(|e| Error::Io { path: mpath.clone(), cause: e })?;
            let ids: Vec<u64> = read_meta(&bytes)
                .ok()
                .and_then(|m| m["param_ids"].as_str().and_then(|s| serde_json::from_str(s).ok()))
                .ok_or_else(|| Error::Invalid(format!("{}: no param_ids in the metadata; cannot resume the optimizer", mpath.display())))?;
            model = net.map(&mut IdSetter { ids, next: 0 });
            optim_bytes = Some((op.clone(), std::fs::read(&op).map_err(|e| Error::Io { path: op, cause: e })?));
            start = latest.step;
            // A run stopped before writing its report resumes without the history.
            if let Some(mut h) = read_history(&dir.join("report.json")) {
                if let Some(was) = h.config.as_ref().and_then(|c| c.get("optim")) {
                    schedule_unchanged(was, &cfg.optim, &dir)?;
                }
                h.loss.retain(|p| p.step <= start);
                h.validation.retain(|p| p.step <= start);
                history = (h.loss, h.validation);
                before = h.before;
            }
        }
        let engine = if fast {
            let adam = match optim_bytes {
                Some((path, b)) => Adam::from_bytes(&b).map_err(|e| {
                    Error::Invalid(format!("{}: {e} (a checkpoint of optim.engine = \"burn\" resumes with that engine)", path.display()))
                })?,
                None => Adam::default(),
            };
            Engine::Fast { net: Box::new(FastNet::from_net(&model)), adam, template: model }
        } else {
            let mut optim = AdamConfig::new().with_epsilon(cfg.optim.adam_epsilon as f32).init();
            if let Some((path, b)) = optim_bytes {
                optim = optim.from_bytes(burn::tensor::Bytes::from_bytes_vec(b)).map_err(|e| {
                    Error::Invalid(format!("{}: {e:?} (a checkpoint of optim.engine = \"fast\" resumes with that engine)", path.display()))
                })?;
            }
            Engine::Burn { device, model, optim, huber: HuberLossConfig::new(cfg.optim.huber_delta as f32).init() }
        };
        let end = opts.stop_after.unwrap_or(cfg.optim.steps).min(cfg.optim.steps);
        let bar = crate::progress::Bar::new(opts.progress, "train", "steps", Some(end.saturating_sub(start) as u64));
        Ok(Trainer {
            cfg: cfg.clone(),
            dir,
            engine,
            step: start,
            start,
            before,
            interrupted: false,
            end,
            val: Vec::new(),
            train_inputs: Default::default(),
            val_inputs: Default::default(),
            losses: history.0,
            vals: history.1,
            recent: Default::default(),
            averaged: None,
            t0: Instant::now(),
            t_train: Instant::now(),
            _lock: lock,
            bar,
        })
    }

    /// True once the last step is done.
    pub fn done(&self) -> bool {
        self.step >= self.end
    }

    /// Files a sample under training or validation by its source input; true if it is for
    /// training.
    pub fn admit(&mut self, p: &Pair) -> bool {
        if is_validation(self.cfg.seed, p.source, self.cfg.data.val_fraction) {
            self.val_inputs.insert(p.source);
            false
        } else {
            self.train_inputs.insert(p.source);
            true
        }
    }

    /// Keeps the inputs of a training batch for the BatchNorm recalibration; a resumed run
    /// passes the batches it replays, so it recalibrates from the same ones.
    pub fn remember(&mut self, batch: &[Pair]) {
        let k = if matches!(self.engine, Engine::Fast { .. }) { self.cfg.validate.bn_batches } else { 0 };
        keep_latest(&mut self.recent, k, batch);
    }

    /// Recomputes BatchNorm's running statistics from the remembered batches (fast engine).
    fn recalibrate(&mut self) {
        if let Engine::Fast { net, .. } = &mut self.engine {
            net.recalibrate_bn(self.recent.make_contiguous());
        }
    }

    /// One optimisation step on `batch`, then validation and checkpoint when due.
    ///
    /// # Errors
    /// A non-finite loss (naming the step), or a checkpoint that cannot be written.
    pub fn train_step(&mut self, batch: &[Pair]) -> Result<()> {
        let cfg = &self.cfg;
        let step = self.step;
        let (w, h) = (batch[0].w, batch[0].h);
        let aug = |img: &[u8], i: usize| -> Vec<u8> {
            if cfg.data.augment && w == h {
                augment(img, w, hash(&[cfg.seed, step as u64, i as u64, hash_str("augment")]) % 8)
            } else {
                img.to_vec()
            }
        };
        let lqs: Vec<Vec<u8>> = batch.iter().enumerate().map(|(i, p)| aug(&p.lq, i)).collect();
        let gts: Vec<Vec<u8>> = batch.iter().enumerate().map(|(i, p)| aug(&p.gt, i)).collect();
        let x = to_t4(&lqs.iter().map(|v| v.as_slice()).collect::<Vec<_>>(), w, h);
        let y = to_t4(&gts.iter().map(|v| v.as_slice()).collect::<Vec<_>>(), w, h);
        let lr = cfg.lr_at(step);
        let lv = self.engine.step(&x, &y, lr, cfg.optim.huber_delta, cfg.optim.adam_epsilon);
        if !lv.is_finite() {
            return Err(Error::Invalid(format!(
                "step {}: the loss is {lv}; stopped. The last good checkpoint is listed in {}",
                step + 1,
                self.dir.join("latest.json").display()
            )));
        }
        self.losses.push(LossPoint { step: step + 1, loss: lv, lr });
        self.step += 1;
        let done = self.step;
        let (validate, save) = (
            (done.is_multiple_of(cfg.validate.every) || done == self.end) && !self.val.is_empty(),
            done.is_multiple_of(cfg.output.checkpoint_every) || done == self.end,
        );
        self.remember(batch);
        if validate || save {
            self.recalibrate();
        }
        let cfg = &self.cfg;
        if validate {
            let (m, i) = self.engine.evaluate(&self.val);
            self.vals.push(ValPoint { step: done, model: m, input: i });
        }
        if save {
            save_checkpoint(&self.dir, &self.engine.net(), self.engine.optim_bytes()?, &cfg.model, cfg.seed, done)?;
            self.write_report()?;
        }
        let rate = ((done - self.start) * batch.len()) as f64 / self.t_train.elapsed().as_secs_f64();
        let msg = format!(
            "loss {lv:.5} lr {lr:.2e} {rate:.1} patches/s{}",
            self.vals.last().map_or(String::new(), |v| format!(" val PSNR {:.2}", v.model.psnr_rgb))
        );
        self.bar.set_message(format!("(step {done}/{}) {msg}", self.end));
        self.bar.set_position((done - self.start) as u64);
        Ok(())
    }

    /// Saves a checkpoint at the current step (unless one was just saved) and the report; the
    /// error to stop with, which says how to continue.
    fn checkpoint_and_stop(&mut self) -> Error {
        let done = self.step;
        self.interrupted = true;
        let saved = done % self.cfg.output.checkpoint_every == 0;
        let res = if saved {
            Ok(())
        } else {
            self.recalibrate();
            self.engine
                .optim_bytes()
                .and_then(|o| save_checkpoint(&self.dir, &self.engine.net(), o, &self.cfg.model, self.cfg.seed, done).map(|_| ()))
        }
        .and_then(|()| self.write_report().map(|_| ()));
        match res {
            Ok(()) => {
                Error::Interrupted(format!("after step {done}: checkpoint saved in {}; continue with --resume", self.dir.display()))
            }
            Err(e) => e,
        }
    }

    /// The report of the run so far.
    fn report(&self) -> TrainReport {
        TrainReport {
            version: env!("CARGO_PKG_VERSION"),
            arch: self.cfg.model.name(),
            parameters: self.engine.num_params(),
            steps: self.step,
            resumed_from: (self.start > 0).then_some(self.start),
            interrupted: self.interrupted,
            seconds: self.t0.elapsed().as_secs_f64(),
            patches_per_s: ((self.step - self.start) * self.cfg.optim.batch) as f64 / self.t_train.elapsed().as_secs_f64().max(1e-9),
            train_inputs: self.train_inputs.iter().copied().collect(),
            val_inputs: self.val_inputs.iter().copied().collect(),
            val_samples: self.val.len(),
            metrics_convention: metrics::CONVENTION,
            loss: self.losses.clone(),
            validation: self.vals.clone(),
            schedule: self.cfg.schedule_words(),
            before: self.before.clone(),
            averaged: self.averaged.clone(),
            config: self.cfg.clone(),
        }
    }

    /// `report.json`, `history.csv` and `curves.png` of the run so far (the whole history,
    /// resumed parts included).
    fn write_report(&self) -> Result<TrainReport> {
        let report = self.report();
        let bytes = serde_json::to_vec_pretty(&report).expect("json");
        write_atomic(&self.dir.join("report.json"), |w| w.write_all(&bytes))?;
        write_atomic(&self.dir.join("history.csv"), |w| w.write_all(history_csv(&report).as_bytes()))?;
        training_curves(&self.dir.join("curves.png"), &report)?;
        Ok(report)
    }

    /// Writes `report.json`, `history.csv` and `curves.png`.
    ///
    /// # Errors
    /// They cannot be written.
    pub fn finish(mut self) -> Result<TrainReport> {
        self.bar.finish();
        if self.cfg.output.average_last > 1 {
            self.average()?;
        }
        self.write_report()
    }

    /// Writes `model.safetensors`: the mean weights of the last `output.average_last`
    /// checkpoints up to this step, BatchNorm recalibrated on it, and scores it.
    fn average(&mut self) -> Result<()> {
        let Engine::Fast { template, .. } = &self.engine else { return Ok(()) };
        let mut steps: Vec<usize> = std::fs::read_dir(&self.dir)
            .map_err(|e| Error::Io { path: self.dir.clone(), cause: e })?
            .filter_map(|e| {
                let name = e.ok()?.file_name().into_string().ok()?;
                name.strip_prefix("model-")?.strip_suffix(".safetensors")?.parse::<usize>().ok()
            })
            .filter(|&s| s <= self.step)
            .collect();
        steps.sort_unstable();
        let steps = steps.split_off(steps.len().saturating_sub(self.cfg.output.average_last));
        let device = Device::flex();
        let mut sum: Option<(FastNet, Vec<Vec<f64>>)> = None;
        for &s in &steps {
            let (net, _) = load_model(&self.dir.join(format!("model-{s:07}.safetensors")), &device)?;
            let mut f = FastNet::from_net(&net);
            let mut vals = Vec::new();
            f.params(&mut |p, _| vals.push(p.to_vec()));
            match &mut sum {
                None => sum = Some((f, vals.iter().map(|v| v.iter().map(|&x| x as f64).collect()).collect())),
                Some((_, acc)) => acc.iter_mut().zip(&vals).for_each(|(a, v)| a.iter_mut().zip(v).for_each(|(a, &x)| *a += x as f64)),
            }
        }
        let Some((mut net, acc)) = sum else { return Ok(()) };
        let n = steps.len() as f64;
        let mut it = acc.into_iter();
        net.params(&mut |p, _| p.iter_mut().zip(it.next().expect("same layout")).for_each(|(p, a)| *p = (a / n) as f32));
        net.recalibrate_bn(self.recent.make_contiguous());
        let (m, i) = evaluate_fast(&net, &self.val);
        save_model(&self.dir.join("model.safetensors"), &net.write_into(template.clone()), &self.cfg.model, self.cfg.seed, self.step)?;
        eprintln!(
            "model.safetensors: the mean of checkpoints {:?}; validation PSNR {:.2} dB (the last checkpoint's: {})",
            steps,
            m.psnr_rgb,
            self.vals.last().map_or("none".into(), |v| format!("{:.2}", v.model.psnr_rgb))
        );
        self.averaged = Some(Averaged { steps, model: m, input: i });
        Ok(())
    }
}

/// `curves.png`: the training loss (log10) and the validation PSNR against steps.
///
/// # Errors
/// The file cannot be written.
pub fn training_curves(path: &std::path::Path, r: &TrainReport) -> crate::Result<()> {
    let mut c = crate::plot::Canvas::new(900, 640, [0.12, 0.12, 0.14]);
    let loss = crate::plot::Series {
        name: "LOG10 HUBER LOSS",
        points: r.loss.iter().map(|p| (p.step as f64, p.loss.max(1e-12).log10())).collect(),
        color: [0.95, 0.6, 0.2],
    };
    // Per-step losses of batch 8 scatter over half a decade; the trailing mean of 1% of the run
    // shows the trend through them.
    let k = (r.loss.len() / 100).max(1);
    let mean_name = format!("MEAN OF {k} STEPS");
    let mean = crate::plot::Series {
        name: &mean_name,
        points: r
            .loss
            .windows(k)
            .map(|w| (w[k - 1].step as f64, (w.iter().map(|p| p.loss).sum::<f64>() / k as f64).max(1e-12).log10()))
            .collect(),
        color: [1.0, 1.0, 1.0],
    };
    // A fine-tuning run draws the initial model's own training before its step 0, in grey (on
    // the initial run's own data, so its levels need not join this run's).
    let grey = [0.5, 0.5, 0.5];
    let shift = |step: usize| step as f64 - r.before.as_ref().map_or(0.0, |b| b.steps as f64);
    let earlier: Vec<crate::plot::Series> = r
        .before
        .iter()
        .map(|b| {
            let kb = (b.loss.len() / 100).max(1);
            let points = b.loss.windows(kb).map(|w| (shift(w[kb - 1].step), (w.iter().map(|p| p.loss).sum::<f64>() / kb as f64).max(1e-12).log10()));
            crate::plot::Series { name: "INITIAL MODEL'S RUN", points: points.collect(), color: grey }
        })
        .collect();
    let series: Vec<crate::plot::Series> = [loss, mean].into_iter().chain(earlier).collect();
    crate::plot::panel(&mut c, (10, 10, 880, 300), &format!("LOG10 TRAINING LOSS ({})", r.arch.to_uppercase()), "STEP", &series);
    let model = crate::plot::Series {
        name: "MODEL",
        points: r.validation.iter().map(|v| (v.step as f64, v.model.psnr_rgb)).collect(),
        color: [0.3, 0.8, 0.4],
    };
    let input = crate::plot::Series {
        name: "BLURRED INPUT",
        points: r.validation.iter().map(|v| (v.step as f64, v.input.psnr_rgb)).collect(),
        color: [0.6, 0.6, 0.9],
    };
    let earlier = r.before.iter().map(|b| crate::plot::Series {
        name: "INITIAL MODEL'S RUN",
        points: b.validation.iter().map(|v| (shift(v.step), v.model.psnr_rgb)).collect(),
        color: grey,
    });
    let series: Vec<crate::plot::Series> = [model, input].into_iter().chain(earlier).collect();
    crate::plot::panel(&mut c, (10, 330, 880, 300), "VALIDATION PSNR RGB (DB)", "STEP", &series);
    c.save(path)
}

/// The scalars of a run, one row per step: step, lr, loss, then (at validation steps) the model's
/// and the input's PSNR/SSIM on RGB (8-bit, BasicSR's convention).
pub fn history_csv(r: &TrainReport) -> String {
    let mut s = String::from("step,lr,loss,val_psnr_rgb,val_ssim_rgb,input_psnr_rgb,input_ssim_rgb\n");
    let vals: std::collections::BTreeMap<usize, &ValPoint> = r.validation.iter().map(|v| (v.step, v)).collect();
    for p in &r.loss {
        s += &format!("{},{:e},{:e}", p.step, p.lr, p.loss);
        match vals.get(&p.step) {
            Some(v) => s += &format!(",{:.4},{:.5},{:.4},{:.5}\n", v.model.psnr_rgb, v.model.ssim_rgb, v.input.psnr_rgb, v.input.ssim_rgb),
            None => s += ",,,,\n",
        }
    }
    s
}

/// The validation samples: the `max` held-out samples of smallest seeded key hash, so they
/// spread over every held-out input (the first ones in shard order came from one or two
/// photographs), in bounded memory.
struct ValPick {
    max: usize,
    seed: u64,
    /// (hash, ordinal, sample): the ordinal breaks ties of equal keys (shards of different
    /// window lengths cut from the same clips).
    v: Vec<(u64, usize, Pair)>,
    held: usize,
}

impl ValPick {
    fn new(max: usize, seed: u64) -> ValPick {
        ValPick { max, seed, v: Vec::new(), held: 0 }
    }
    fn push(&mut self, p: Pair) {
        if self.max == 0 {
            return;
        }
        self.v.push((hash(&[self.seed, hash_str(&p.key), hash_str("val-pick")]), self.held, p));
        self.held += 1;
        if self.v.len() >= 2 * self.max {
            self.keep();
        }
    }
    fn keep(&mut self) {
        self.v.sort_unstable_by_key(|v| (v.0, v.1));
        self.v.truncate(self.max);
    }
    fn finish(mut self) -> Vec<Pair> {
        self.keep();
        self.v.into_iter().map(|v| v.2).collect()
    }
}

/// Appends a batch's inputs to `recent`, keeping the latest `k`.
fn keep_latest(recent: &mut std::collections::VecDeque<T4>, k: usize, batch: &[Pair]) {
    if k == 0 {
        return;
    }
    if recent.len() == k {
        recent.pop_front();
    }
    let (w, h) = (batch[0].w, batch[0].h);
    recent.push_back(to_t4(&batch.iter().map(|p| p.lq.as_slice()).collect::<Vec<_>>(), w, h));
}

/// Runs training from shards.
///
/// # Errors
/// Bad shards (named), an unwritable output folder, or a non-finite loss (naming the step; the
/// last good checkpoint stays).
pub fn train(cfg: &TrainConfig, opts: &TrainOptions) -> Result<TrainReport> {
    // Shards that match nothing are a usage error naming the key, found before the output
    // folder is made.
    let shards = crate::io::paths::expand_paths(&cfg.data.shards, &["tar"]).map_err(|e| match e {
        Error::Io { path, cause } if cause.kind() == std::io::ErrorKind::NotFound => {
            Error::Usage(format!("data.shards: {}: no such folder", path.display()))
        }
        Error::Invalid(m) => Error::Usage(format!("data.shards: {m}")),
        e => e,
    })?;
    if shards.is_empty() {
        return Err(Error::Usage(format!("data.shards = {:?}: no .tar file found", cfg.data.shards)));
    }
    if let Some(p) = shards.iter().find(|p| !p.exists()) {
        return Err(Error::Usage(format!("data.shards: {}: no such file or folder", p.display())));
    }
    let mut t = Trainer::new(cfg, opts)?;
    // Which inputs went where, and the validation samples.
    let mut size = None;
    let mut val = ValPick::new(cfg.validate.max_samples, cfg.seed);
    for s in &shards {
        for p in read_shard(s, size)? {
            size.get_or_insert((p.w, p.h));
            if !t.admit(&p) {
                val.push(p);
            }
        }
    }
    t.val = val.finish();
    if t.train_inputs.is_empty() {
        return Err(Error::Invalid(format!(
            "data: every input ({:?}) went to validation; lower data.val_fraction or add inputs",
            t.val_inputs
        )));
    }
    let mut stream = Stream::new(shards, cfg.seed, cfg.data.val_fraction, cfg.data.shuffle_buffer, size);
    // Replay the data order up to the resumed step, remembering the batches BatchNorm is
    // recalibrated from.
    for step in 0..t.step {
        let batch: Vec<Pair> = (0..cfg.optim.batch).map(|_| stream.next()).collect::<Result<_>>()?;
        if step + cfg.validate.bn_batches >= t.step {
            t.remember(&batch);
        }
    }
    crate::signal::install();
    while !t.done() {
        let batch: Vec<Pair> = (0..cfg.optim.batch).map(|_| stream.next()).collect::<Result<_>>()?;
        t.train_step(&batch)?;
        if crate::signal::interrupted() {
            // SIGTERM (Slurm preemption, a time limit) or Ctrl-C: keep every finished step.
            return Err(t.checkpoint_and_stop());
        }
    }
    t.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A shallow model of 4 filters; data and output paths that are never read.
    fn tiny_config() -> TrainConfig {
        toml::from_str("[model]\ntype = \"shallow\"\nwidth = 4\n[data]\nshards = [\"x\"]\n[output]\ndir = \"x\"\n").unwrap()
    }

    #[test]
    fn the_loss_curve_carries_its_running_mean() {
        let cfg = tiny_config();
        // Losses alternating between 1e-4 and 1e-2: the raw series fills the band between them,
        // the mean of 20 steps (1% of 2000) is a flat line near log10(5e-3) in the middle.
        let loss = (1..=2000).map(|step| LossPoint { step, loss: if step % 2 == 0 { 1e-4 } else { 1e-2 }, lr: 1e-3 }).collect();
        let r = TrainReport {
            version: "test",
            arch: "shallow-4".into(),
            parameters: 1,
            steps: 2000,
            resumed_from: None,
            interrupted: false,
            seconds: 1.0,
            patches_per_s: 1.0,
            train_inputs: Vec::new(),
            val_inputs: Vec::new(),
            val_samples: 0,
            metrics_convention: "test",
            loss,
            validation: Vec::new(),
            schedule: String::new(),
            before: None,
            averaged: None,
            config: cfg,
        };
        let path = std::env::temp_dir().join(format!("pipeline-curves-{}.png", std::process::id()));
        training_curves(&path, &r).unwrap();
        let (w, _, rgb) = crate::io::png::read_rgb8(&std::fs::read(&path).unwrap()).unwrap();
        std::fs::remove_file(&path).ok();
        // Pure white (the mean's colour; axes and labels are 0.9 grey) along one row inside the
        // loss panel's plot area (rows 34 to 286, the axes at its edges excluded).
        let px = |x: usize, y: usize| &rgb[(y * w + x) * 3..(y * w + x) * 3 + 3];
        let white: Vec<usize> = (40..284).filter(|&y| (200..800).filter(|&x| px(x, y) == [255, 255, 255]).count() > 300).collect();
        assert!(!white.is_empty(), "no running-mean line in the loss panel");
        // log10(5.05e-3) = -2.30 on an axis from -4 to -2: 85% of the way up the plot area.
        let want = 286.0 - 0.85 * 252.0;
        assert!(white.iter().all(|&y| (y as f64 - want).abs() < 4.0), "mean line at rows {white:?}, want about {want}");
    }

    #[test]
    fn a_model_with_non_finite_weights_is_refused_by_name() {
        let dir = std::env::temp_dir().join(format!("pipeline-nan-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cfg = tiny_config();
        let dev = Device::flex();
        let net = Net::seeded(cfg.model, &dev, 1);
        save_checkpoint(&dir, &net, Vec::new(), &cfg.model, cfg.seed, 1).unwrap();
        assert!(load_model(&dir.join("model-0000001.safetensors"), &dev).is_ok());
        let mut f = FastNet::from_net(&net);
        let mut first = true;
        f.params(&mut |p, _| {
            if std::mem::take(&mut first) {
                p[0] = f32::NAN;
            }
        });
        save_checkpoint(&dir, &f.write_into(net), Vec::new(), &cfg.model, cfg.seed, 2).unwrap();
        let e = load_model(&dir.join("model-0000002.safetensors"), &dev).err().expect("refused").to_string();
        assert!(e.contains("model-0000002.safetensors") && e.contains("1 weights are not finite"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn validation_samples_spread_over_the_held_out_inputs_whatever_their_order() {
        let pair = |src: u64, i: usize| Pair { key: format!("clip{src}_{i:06}"), source: src, w: 1, h: 1, lq: vec![0; 3], gt: vec![0; 3] };
        let pick = |order: &mut dyn Iterator<Item = (u64, usize)>| {
            let mut v = ValPick::new(16, 0);
            order.for_each(|(s, i)| v.push(pair(s, i)));
            v.finish().into_iter().map(|p| p.key).collect::<std::collections::BTreeSet<_>>()
        };
        // Four inputs of 100 samples each, in shard order: the first 16 would all be clip0's.
        let a = pick(&mut (0..4u64).flat_map(|s| (0..100).map(move |i| (s, i))));
        assert_eq!(a.len(), 16);
        for s in 0..4 {
            assert!(a.iter().any(|k| k.starts_with(&format!("clip{s}_"))), "no sample of clip{s}: {a:?}");
        }
        // The same samples in reverse order give the same set.
        assert_eq!(pick(&mut (0..4u64).rev().flat_map(|s| (0..100).rev().map(move |i| (s, i)))), a);
    }

    #[test]
    fn lr_warms_up_then_decays_by_cosine() {
        let cfg: TrainConfig = toml::from_str("[model]\ntype = \"shallow\"\nwidth = 4\n[data]\nshards = [\"x\"]\n[optim]\nsteps = 100\nwarmup_steps = 10\nlr = 1e-3\n[output]\ndir = \"x\"\n").unwrap();
        assert!((cfg.lr_at(0) - 1e-4).abs() < 1e-12);
        assert!((cfg.lr_at(10) - 1e-3).abs() < 1e-9);
        assert!((cfg.lr_at(99) - 1e-4).abs() < 1e-6);
        assert!(cfg.lr_at(50) < cfg.lr_at(20));
    }

    #[test]
    fn augmentations_are_the_eight_symmetries_of_the_square() {
        let img: Vec<u8> = (0..4 * 4 * 3).map(|i| i as u8).collect();
        let all: std::collections::BTreeSet<Vec<u8>> = (0..8).map(|t| augment(&img, 4, t)).collect();
        assert_eq!(all.len(), 8);
        assert_eq!(augment(&img, 4, 0), img);
    }
}
