use super::*;

/// The training state: model, optimizer, schedule, history. Fed batches by [`train`] (from
/// shards) or by the `trainer` sink (straight from the generator).
pub struct Trainer {
    pub cfg: TrainConfig,
    pub(super) dir: PathBuf,
    pub(super) engine: Engine,
    pub step: usize,
    pub(super) start: usize,
    pub(super) before: Option<Before>,
    pub(super) interrupted: bool,
    pub(super) end: usize,
    pub val: Vec<Pair>,
    pub train_inputs: std::collections::BTreeSet<u64>,
    pub val_inputs: std::collections::BTreeSet<u64>,
    pub(super) losses: Vec<LossPoint>,
    pub(super) vals: Vec<ValPoint>,
    /// The inputs of the latest `validate.bn_batches` training batches, for [`FastNet::recalibrate_bn`].
    pub(super) recent: std::collections::VecDeque<T4>,
    pub(super) averaged: Option<Averaged>,
    pub(super) t0: Instant,
    pub(super) t_train: Instant,
    /// The folder's `.train.lock`, held until the run ends.
    pub(super) _lock: std::fs::File,
    pub(super) bar: crate::progress::Bar,
    /// The data stream's position after the batch of the step in progress, set by [`train`]
    /// before a step that checkpoints; saved beside the checkpoint.
    pub(super) stream: Option<StreamState>,
    /// How a resumed run found its place in the data (restored or replayed), for the report.
    pub(super) resumed_data: Option<String>,
}

/// The run's folder: refused when it holds what a run does not write (a fresh run), or nothing
/// to resume (`--resume`); made, locked, its killed runs' temporaries removed, and for a fresh
/// run its earlier checkpoints cleared (`--overwrite`) or refused.
fn open_folder(cfg: &TrainConfig, opts: &TrainOptions) -> Result<(PathBuf, std::fs::File)> {
    let dir = PathBuf::from(&cfg.output.dir);
    if opts.resume {
        if !dir.join("latest.json").exists() {
            return Err(Error::Usage(format!(
                "{}: nothing to resume (no latest.json: no checkpoint was written there); train without --resume to start a run",
                dir.display()
            )));
        }
    } else {
        own_folder(&dir)?;
    }
    std::fs::create_dir_all(&dir).map_err(|e| Error::Io { path: dir.clone(), cause: e })?;
    let lock = lock_run_folder(&dir)?;
    // What a killed run of this folder left half-written (this machine, process gone).
    for p in crate::io::remove_stale(&dir, 0) {
        eprintln!("removed {} (left by a run that was killed)", p.display());
    }
    if !opts.resume {
        fresh_run_folder(&dir, opts.overwrite)?;
    }
    Ok((dir, lock))
}

/// What an earlier report.json holds of its run.
#[derive(Deserialize)]
struct History {
    steps: usize,
    loss: Vec<LossPoint>,
    validation: Vec<ValPoint>,
    #[serde(default)]
    before: Option<Before>,
    config: Option<serde_json::Value>,
}

fn read_history(p: &Path) -> Option<History> {
    std::fs::read(p).ok().and_then(|b| serde_json::from_slice(&b).ok())
}

/// Where a run starts: its model, the optimizer state (file and bytes) when resumed, the
/// step, the history so far and the history of the model it was started from.
struct Start {
    model: Net,
    optim: Option<(PathBuf, Vec<u8>)>,
    step: usize,
    history: (Vec<LossPoint>, Vec<ValPoint>),
    before: Option<Before>,
}

impl Start {
    /// Fresh weights: a function of the config's seed alone.
    fn fresh(cfg: &TrainConfig, device: &Device) -> Start {
        let mut model = Net::seeded(cfg.model, device, hash(&[cfg.seed, hash_str("init")]));
        if cfg.optim.zero_init {
            model = model.zero_last_layer(device);
        }
        Start { model, optim: None, step: 0, history: Default::default(), before: None }
    }

    /// A trained model's weights (`init`), on a schedule of its own (steps 1 to optim.steps,
    /// peaking at optim.lr); the initial model's history is kept for the curves. A burst U-Net
    /// starts from a U-Net of its width told the time on as many levels or fewer (a
    /// single-frame one: none): the same weights, the missing time conditioning at zero (at every
    /// time, what the U-Net gave).
    fn from_init(cfg: &TrainConfig, init: &str, device: &Device) -> Result<Start> {
        let path = Path::new(init);
        if std::fs::symlink_metadata(path).is_err() {
            return Err(Error::Usage(format!("init: {init}: no such model file or folder")));
        }
        let (mut net, mut arch) = load_model(path, device).map_err(|e| Error::Context { what: "init".into(), source: Box::new(e) })?;
        if let (Arch::Unet { base } | Arch::BurstUnet { base, .. }, Arch::BurstUnet { base: want, levels }) = (arch, cfg.model) {
            if base == want && arch.timed_levels() <= levels {
                (net, arch) = (net.into_burst(levels, device), cfg.model);
            }
        }
        if arch != cfg.model {
            return Err(Error::File {
                path: path.to_path_buf(),
                why: format!("(init) holds a {} model, the config's model is {}", arch.name(), cfg.model.name()),
            });
        }
        let before = path.is_dir().then(|| read_history(&path.join("report.json"))).flatten().map(|h| Before {
            model: init.to_string(),
            steps: h.steps,
            loss: h.loss,
            validation: h.validation,
        });
        Ok(Start { model: net, optim: None, step: 0, history: Default::default(), before })
    }

    /// The checkpoint `latest.json` names in `dir`, with its parameter ids (the optimizer state
    /// is keyed by them), its optimizer state and the run's history up to its step. The
    /// schedule must be the run's own.
    fn resumed(cfg: &TrainConfig, dir: &Path, device: &Device) -> Result<Start> {
        let lp = dir.join("latest.json");
        let (latest, mpath, op) =
            Latest::read(dir)?.ok_or_else(|| Error::Io { path: lp, cause: std::io::Error::from(std::io::ErrorKind::NotFound) })?;
        let (net, arch) = load_model(&mpath, device)?;
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
        let bytes = crate::io::paths::read_regular(&mpath, crate::io::paths::MAX_MODEL_BYTES, "safetensors model file")?;
        let ids: Vec<u64> =
            read_meta(&bytes).ok().and_then(|m| m["param_ids"].as_str().and_then(|s| serde_json::from_str(s).ok())).ok_or_else(|| {
                Error::File { path: mpath.to_path_buf(), why: "no param_ids in the metadata; cannot resume the optimizer".into() }
            })?;
        let model = net.map(&mut IdSetter { ids, next: 0 });
        let optim = Some((op.clone(), std::fs::read(&op).map_err(|e| Error::Io { path: op, cause: e })?));
        let step = latest.step;
        let mut start = Start { model, optim, step, history: Default::default(), before: None };
        // A run stopped before writing its report resumes without the history.
        if let Some(mut h) = read_history(&dir.join("report.json")) {
            if let Some(was) = h.config.as_ref().and_then(|c| c.get("optim")) {
                schedule_unchanged(was, &cfg.optim, dir)?;
            }
            h.loss.retain(|p| p.step <= step);
            h.validation.retain(|p| p.step <= step);
            start.history = (h.loss, h.validation);
            start.before = h.before;
        }
        Ok(start)
    }
}

/// The engine that trains `model`: the fast CPU path or burn's autodiff, with the optimizer
/// state of a resumed run (refused, with the reason, when it is another engine's or damaged).
fn engine(cfg: &TrainConfig, device: Device, model: Net, optim: Option<(PathBuf, Vec<u8>)>) -> Result<Engine> {
    if cfg.optim.engine == EngineKind::Fast {
        let adam = match optim {
            Some((path, b)) => Adam::from_bytes(&b).map_err(|e| {
                // The hint fits the cause: a fast-engine file that is damaged, or another engine's.
                let hint = if b.starts_with(br#"{"format":"pipeline-adam-1""#) {
                    "the file is damaged or truncated; the checkpoints before it are whole files of their own"
                } else {
                    "a checkpoint of optim.engine = \"burn\" resumes with that engine"
                };
                Error::Unloadable {
                    path: path.to_path_buf(),
                    why: format!("cannot resume the optimizer from it ({hint})"),
                    source: Box::new(e),
                }
            })?,
            None => Adam::default(),
        };
        return Ok(Engine::Fast { net: Box::new(FastNet::from_net(&model)), adam, template: model });
    }
    let mut opt = AdamConfig::new().with_epsilon(cfg.optim.adam_epsilon as f32).init();
    if let Some((path, b)) = optim {
        opt = opt.from_bytes(burn::tensor::Bytes::from_bytes_vec(b)).map_err(|e| Error::Unloadable {
            path: path.to_path_buf(),
            why: "not a burn optimizer state (a checkpoint of optim.engine = \"fast\" resumes with that engine)".into(),
            source: Box::new(e),
        })?;
    }
    Ok(Engine::Burn { device, model, optim: opt, huber: HuberLossConfig::new(cfg.optim.huber_delta as f32).init() })
}

impl Trainer {
    /// A run of `cfg`: from fresh weights, from `init`'s, or (with `resume`) from the
    /// checkpoint in `output.dir` (`Start`).
    ///
    /// # Errors
    /// Bad config values (all named), an unwritable output folder, an unreadable checkpoint.
    pub fn new(cfg: &TrainConfig, opts: &TrainOptions) -> Result<Trainer> {
        let errs = cfg.validate();
        if !errs.is_empty() {
            return Err(Error::Config(errs));
        }
        let (dir, lock) = open_folder(cfg, opts)?;
        let fast = cfg.optim.engine == EngineKind::Fast;
        let device = if fast { Device::flex() } else { Device::flex().autodiff() };
        let start = match (&cfg.init, opts.resume) {
            (_, true) => Start::resumed(cfg, &dir, &device)?,
            (Some(init), false) => Start::from_init(cfg, init, &device)?,
            (None, false) => Start::fresh(cfg, &device),
        };
        let engine = engine(cfg, device, start.model, start.optim)?;
        let end = opts.stop_after.unwrap_or(cfg.optim.steps).min(cfg.optim.steps);
        let bar = crate::progress::Bar::from(opts.progress, "train", "steps", start.step as u64, Some(end as u64));
        Ok(Trainer {
            cfg: cfg.clone(),
            dir,
            engine,
            step: start.step,
            start: start.step,
            before: start.before,
            interrupted: false,
            end,
            val: Vec::new(),
            train_inputs: Default::default(),
            val_inputs: Default::default(),
            losses: start.history.0,
            vals: start.history.1,
            recent: Default::default(),
            averaged: None,
            t0: Instant::now(),
            t_train: Instant::now(),
            _lock: lock,
            bar,
            stream: None,
            resumed_data: None,
        })
    }

    /// True once the last step is done.
    pub fn done(&self) -> bool {
        self.step >= self.end
    }

    /// Files a sample under training or validation by its source input; true if it is for
    /// training.
    pub fn admit(&mut self, p: &Pair) -> bool {
        self.admit_source(p.source)
    }

    /// [`Trainer::admit`] by the sample's source input.
    pub fn admit_source(&mut self, source: u64) -> bool {
        if is_validation(self.cfg.seed, source, self.cfg.data.val_fraction) {
            self.val_inputs.insert(source);
            false
        } else {
            self.train_inputs.insert(source);
            true
        }
    }

    /// Keeps the inputs of a training batch for the BatchNorm recalibration; a resumed run
    /// passes the batches it replays, so it recalibrates from the same ones.
    pub fn remember(&mut self, batch: &[Pair]) {
        let k = self.bn_batches();
        keep_latest(&mut self.recent, k, batch);
    }

    /// How many of the latest training batches BatchNorm is recalibrated from (the fast
    /// engine's `validate.bn_batches`; burn's keeps running statistics of its own).
    pub(super) fn bn_batches(&self) -> usize {
        if matches!(self.engine, Engine::Fast { .. }) {
            self.cfg.validate.bn_batches
        } else {
            0
        }
    }

    /// Recomputes BatchNorm's running statistics from the remembered batches (fast engine).
    pub(super) fn recalibrate(&mut self) {
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
        // A burst model learns each sample at one of its burst's times, drawn per step.
        let burst = cfg.model.is_burst();
        let targets: Vec<(f32, &[u8])> =
            batch.iter().enumerate().map(|(i, p)| target(p, burst, |k| burst_time(cfg.seed, step, i, k, cfg.data.burst_ends))).collect();
        let ts: Vec<f32> = if burst { targets.iter().map(|t| t.0).collect() } else { Vec::new() };
        let gts: Vec<Vec<u8>> = targets.iter().enumerate().map(|(i, t)| aug(t.1, i)).collect();
        let x = to_t4(&lqs.iter().map(|v| v.as_slice()).collect::<Vec<_>>(), w, h);
        let y = to_t4(&gts.iter().map(|v| v.as_slice()).collect::<Vec<_>>(), w, h);
        let lr = cfg.lr_at(step);
        let lv = self.engine.step(&x, &ts, &y, lr, cfg.optim.huber_delta, cfg.optim.adam_epsilon);
        if !lv.is_finite() {
            return Err(Error::Diverged { step: step + 1, loss: lv, latest: self.dir.join("latest.json") });
        }
        self.losses.push(LossPoint { step: step + 1, loss: lv, lr });
        self.step += 1;
        let done = self.step;
        let (validate, save) =
            ((done.is_multiple_of(cfg.validate.every) || done == self.end) && !self.val.is_empty(), self.saves_after(done));
        self.remember(batch);
        if validate || save {
            self.recalibrate();
        }
        if validate {
            let (m, i) = self.engine.evaluate(&self.val);
            self.vals.push(ValPoint { step: done, model: m, input: i });
        }
        if save {
            self.save_stream(done)?;
            let cfg = &self.cfg;
            save_checkpoint(&self.dir, &self.engine.net(), self.engine.optim_bytes()?, &cfg.model, cfg.seed, done)?;
            self.write_report()?;
        }
        let rate = ((done - self.start) * batch.len()) as f64 / self.t_train.elapsed().as_secs_f64();
        let msg = format!(
            "loss {lv:.5} lr {lr:.2e} {rate:.1} patches/s{}",
            self.vals.last().map_or(String::new(), |v| format!(" val PSNR {:.2}", v.model.psnr_rgb))
        );
        // The step count is the bar's own (its position is the step), so count and text agree.
        self.bar.set_message(msg);
        self.bar.set_position(done as u64);
        Ok(())
    }

    /// The last step in words: `step 120/2000, loss 0.01234, val PSNR 28.10` (the `trainer`
    /// sink's part of a run's progress line).
    pub fn status(&self) -> String {
        let loss = self.losses.last().map_or(String::new(), |l| format!(", loss {:.5}", l.loss));
        let val = self.vals.last().map_or(String::new(), |v| format!(", val PSNR {:.2} at step {}", v.model.psnr_rgb, v.step));
        format!("step {}/{}{loss}{val}", self.step, self.end)
    }

    /// True if the step that ends at `done` writes a checkpoint.
    pub fn saves_after(&self, done: usize) -> bool {
        done.is_multiple_of(self.cfg.output.checkpoint_every) || done == self.end
    }

    /// Writes the data stream's position for the checkpoint of step `done`, before the
    /// checkpoint itself (so `latest.json` never names a step whose position is missing because
    /// of a crash between them; a missing one only means a replay).
    fn save_stream(&mut self, done: usize) -> Result<()> {
        let Some(state) = self.stream.take() else { return Ok(()) };
        // A shard path that is not UTF-8 cannot go into JSON: that run replays on resume.
        let Ok(bytes) = serde_json::to_vec(&state) else { return Ok(()) };
        write_atomic(&StreamState::path(&self.dir, done), |w| w.write_all(&bytes))
    }

    /// Saves a checkpoint at the current step (unless one was just saved) and the report; the
    /// error to stop with, which says how to continue.
    pub(super) fn checkpoint_and_stop(&mut self) -> Error {
        let done = self.step;
        self.interrupted = true;
        let saved = done.is_multiple_of(self.cfg.output.checkpoint_every);
        let res = if saved {
            Ok(())
        } else {
            self.recalibrate();
            self.save_stream(done)
                .and_then(|()| self.engine.optim_bytes())
                .and_then(|o| save_checkpoint(&self.dir, &self.engine.net(), o, &self.cfg.model, self.cfg.seed, done).map(|_| ()))
        }
        .and_then(|()| self.write_report().map(|_| ()));
        match res {
            Ok(()) => Error::Interrupted(format!("after step {done}: checkpoint saved in {}; continue with --resume", self.dir.display())),
            Err(e) => e,
        }
    }

    /// The report of the run so far.
    pub(super) fn report(&self) -> TrainReport {
        TrainReport {
            version: env!("CARGO_PKG_VERSION"),
            arch: self.cfg.model.name(),
            parameters: self.engine.num_params(),
            steps: self.step,
            resumed_from: (self.start > 0).then_some(self.start),
            resumed_data: self.resumed_data.clone(),
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
    pub(super) fn write_report(&self) -> Result<TrainReport> {
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
    pub(super) fn average(&mut self) -> Result<()> {
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
