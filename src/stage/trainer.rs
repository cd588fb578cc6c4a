//! `trainer`: trains a network on the generator's stream, no disk in between (the training
//! itself is [`crate::train`]).

use super::{BuildContext, Built, Sink, StageConfig};
use crate::checks::ConfigError;
use crate::model::Arch;
use crate::rng::{hash, hash_str, Rng};
use crate::train::{
    d_ckpt, d_shuffle, d_true, d_val_fraction, DataConfig, OptimConfig, OutputConfig, Pair, TrainConfig, TrainOptions, TrainReport,
    Trainer, ValidateConfig,
};
use crate::{Error, Result};
use serde::{Deserialize, Serialize};

/// `[sinks.NAME] type = "trainer"`: trains on the generator's stream, no disk in between.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainerSinkConfig {
    pub inputs: Vec<String>,
    /// Output folder: checkpoints, report.json, curves.png.
    pub dir: String,
    pub model: Arch,
    /// Start from this model's weights (as the training file's `init`).
    #[serde(default)]
    pub init: Option<String>,
    #[serde(default)]
    pub optim: OptimConfig,
    #[serde(default)]
    pub validate: ValidateConfig,
    #[serde(default = "d_val_fraction")]
    pub val_fraction: f64,
    #[serde(default = "d_shuffle")]
    pub shuffle_buffer: usize,
    #[serde(default = "d_true")]
    pub augment: bool,
    /// As the training file's `data.burst_ends`.
    #[serde(default, skip_serializing_if = "crate::train::is_zero")]
    pub burst_ends: f64,
    #[serde(default = "d_ckpt")]
    pub checkpoint_every: usize,
}

impl StageConfig for TrainerSinkConfig {
    super::wiring!(sink, Samples);
    /// The training file's checks, named by the keys written here (`sinks.X.val_fraction`, not
    /// the training file's `data.val_fraction`).
    fn validate(&self, key: &str) -> Vec<ConfigError> {
        self.to_train_config(0)
            .validate()
            .into_iter()
            .filter(|e| !e.key.starts_with("data.shards"))
            .map(|e| {
                let k = e.key.strip_prefix("data.").or_else(|| e.key.strip_prefix("output.")).unwrap_or(&e.key);
                ConfigError { key: format!("{key}.{k}"), message: e.message }
            })
            .collect()
    }
    fn report_stem(&self) -> &'static str {
        "generate-report"
    }
    fn build(&self, ctx: &BuildContext) -> crate::Result<Built> {
        Ok(Built::Sink(Box::new(TrainerSink::new(self, ctx.seed, ctx.counters.clone())?)))
    }
}

impl TrainerSinkConfig {
    /// The equivalent training file (with no shards: the stream feeds it).
    pub fn to_train_config(&self, seed: u64) -> TrainConfig {
        TrainConfig {
            seed,
            model: self.model,
            init: self.init.clone(),
            data: DataConfig {
                shards: vec!["(stream)".into()],
                val_fraction: self.val_fraction,
                shuffle_buffer: self.shuffle_buffer,
                augment: self.augment,
                burst_ends: self.burst_ends,
            },
            optim: self.optim.clone(),
            validate: self.validate.clone(),
            output: OutputConfig { dir: self.dir.clone(), checkpoint_every: self.checkpoint_every, average_last: 1 },
        }
    }
}

/// The `trainer` sink: samples go through a seeded shuffle buffer into training steps;
/// samples of validation inputs are kept for validation.
pub struct TrainerSink {
    trainer: Option<Trainer>,
    buffer: Vec<Pair>,
    rng: Rng,
    failed: Vec<(String, String)>,
    summary: Option<TrainReport>,
    /// The run's counters: the sink's step, loss and validation go on its progress line.
    counters: std::sync::Arc<crate::stage::Counters>,
}

impl TrainerSink {
    /// # Errors
    /// As [`Trainer::new`].
    pub fn new(cfg: &TrainerSinkConfig, seed: u64, counters: std::sync::Arc<crate::stage::Counters>) -> Result<TrainerSink> {
        let t = Trainer::new(
            &cfg.to_train_config(seed),
            &TrainOptions { resume: false, overwrite: false, progress: crate::progress::ProgressMode::Never, stop_after: None },
        )?;
        Ok(TrainerSink {
            trainer: Some(t),
            buffer: Vec::new(),
            rng: Rng::new(hash(&[seed, hash_str("stream-shuffle")])),
            failed: Vec::new(),
            summary: None,
            counters,
        })
    }

    fn pump(&mut self, drain: bool) -> Result<()> {
        let t = self.trainer.as_mut().expect("open");
        let (cap, batch) = (t.cfg.data.shuffle_buffer.max(t.cfg.optim.batch), t.cfg.optim.batch);
        while !t.done() && (self.buffer.len() >= cap || (drain && self.buffer.len() >= batch)) {
            let b: Vec<Pair> = (0..batch).map(|_| self.buffer.swap_remove(self.rng.below(self.buffer.len()))).collect();
            t.train_step(&b)?;
            if let Ok(mut s) = self.counters.status.lock() {
                *s = t.status();
            }
        }
        Ok(())
    }
}

impl Sink for TrainerSink {
    fn consume(&mut self, item: crate::item::Item) -> Result<()> {
        use crate::item::Item;
        use crate::sample::Img;
        match item {
            Item::Sample(s) => {
                let t = self.trainer.as_mut().expect("open");
                for p in &s.pairs {
                    let rgb = |img: &Img| img.rgb8(p.w, p.h, s.curve);
                    let pair = Pair {
                        key: format!("{}_{:06}", s.input.key, s.window),
                        source: hash_str(&s.input.key),
                        w: p.w,
                        h: p.h,
                        lq: rgb(&p.lq),
                        gt: rgb(&p.gt),
                        burst: p.burst.iter().map(rgb).collect(),
                        times: if p.burst.is_empty() { Vec::new() } else { s.times.iter().map(|&t| t as f32).collect() },
                    };
                    if t.admit(&pair) {
                        self.buffer.push(pair);
                    } else if t.val.len() < t.cfg.validate.max_samples {
                        t.val.push(pair);
                    }
                }
                self.pump(false)?;
            }
            Item::End(input, Err(e)) => self.failed.push((input.path.clone(), e.to_string())),
            _ => {}
        }
        Ok(())
    }

    fn wants_more(&self) -> bool {
        self.trainer.as_ref().is_some_and(|t| !t.done())
    }

    fn finish(&mut self) -> Result<serde_json::Value> {
        self.pump(true)?;
        let t = self.trainer.take().expect("open");
        if t.step == 0 {
            return Err(Error::Usage(format!(
                "the stream ended before one batch of {} training samples: more input, or a smaller optim.batch",
                t.cfg.optim.batch
            )));
        }
        let r = t.finish()?;
        let v = serde_json::json!({
            "sink": "trainer", "arch": r.arch, "steps": r.steps, "patches_per_s": r.patches_per_s,
            "validation": r.validation.last(), "dir": r.config.output.dir,
        });
        self.summary = Some(r);
        Ok(v)
    }

    fn abort(&mut self) {}

    fn failures(&self) -> Vec<(String, String)> {
        self.failed.clone()
    }
}
