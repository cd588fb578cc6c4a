//! `pipeline train`: the paper's U-Net or shallow model on (lq, gt) patch pairs from WebDataset
//! shards, with Huber loss and Adam, validation PSNR/SSIM on inputs held apart by source video,
//! checkpoints ([`crate::model::checkpoint`]) and exact resume.
//!
//! Determinism: the shard order, the shuffle buffer and the augmentations are functions of the
//! seed and the step, so `--resume` continues with the data order the uninterrupted run would
//! have had: each checkpoint saves the stream's position (`stream-NNNNNNN.json`: the shard
//! order left, the shuffle buffer's samples by origin, the generator's state), which a resume
//! restores after its scan of the shards; without one it replays the stream up to the step.
//!
//! Files: `config.rs` (the training file), `data.rs` (the shard stream, its shuffle and split,
//! augmentation, tensors from patches), `engine.rs` (the fast CPU path or burn's autodiff behind
//! one step and one evaluation), `trainer.rs` (the training state: start, resume, fine-tune, step,
//! checkpoint, average), `folder.rs` (the run folder's lock and what may be reused), `report.rs`
//! (`report.json`, `history.csv`, `curves.png`); [`train`] here ties them together.

pub use crate::io::wds::{read_shard, Pair};
use crate::io::write_atomic;
use crate::metrics;
pub use crate::model::checkpoint::{load_model, load_model_bytes};
use crate::model::checkpoint::{read_meta, save_checkpoint, save_model, IdSetter, Latest};
use crate::model::fast::{self, Adam, FastNet, T4};
use crate::model::{Arch, Net};
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
mod data;
mod engine;
mod folder;
mod report;
#[cfg(test)]
mod tests;
mod trainer;
pub use config::*;
pub use data::*;
pub use engine::*;
use folder::*;
pub use report::*;
pub use trainer::*;

/// Options of one `pipeline train` call.
pub struct TrainOptions {
    pub resume: bool,
    /// Start afresh in an output folder that holds a run, removing its checkpoints and history.
    pub overwrite: bool,
    pub progress: crate::progress::ProgressMode,
    /// Stop after this step (tests of resume); None: run to `optim.steps`.
    pub stop_after: Option<usize>,
}

/// The shards of `data.shards`: a pattern or folder that matches nothing is a usage error naming
/// the key, found before the output folder is made.
fn find_shards(cfg: &TrainConfig) -> Result<Vec<std::path::PathBuf>> {
    let shards = crate::io::paths::expand_paths(&cfg.data.shards, &["tar"]).map_err(|e| match e {
        Error::Io { path, cause } if cause.kind() == std::io::ErrorKind::NotFound => {
            Error::Usage(format!("data.shards: {}: no such folder", path.display()))
        }
        Error::Usage(m) => Error::Usage(format!("data.shards: {m}")),
        e => e,
    })?;
    if shards.is_empty() {
        return Err(Error::Usage(format!("data.shards = {:?}: no .tar file found", cfg.data.shards)));
    }
    if let Some(p) = shards.iter().find(|p| !p.exists()) {
        return Err(Error::Usage(format!("data.shards: {}: no such file or folder", p.display())));
    }
    Ok(shards)
}

/// Replays the data order up to a resumed step saved without its data position, remembering the
/// batches BatchNorm is recalibrated from. False when a signal stopped it.
fn replay(t: &mut Trainer, stream: &mut Stream, cfg: &TrainConfig) -> Result<bool> {
    for step in 0..t.step {
        if crate::signal::interrupted() {
            return Ok(false);
        }
        let batch = stream.batch(cfg.optim.batch)?;
        if step + cfg.validate.bn_batches >= t.step {
            t.remember(&batch);
        }
    }
    t.resumed_data = Some(format!("replayed {} steps (no data position saved with the checkpoint)", t.step));
    Ok(true)
}

const NO_VALIDATION: &str = "nothing is validated and the curves have no validation panel; raise data.val_fraction or give more inputs";

/// Runs training from shards.
///
/// # Errors
/// Bad shards (named), an unwritable output folder, or a non-finite loss (naming the step; the
/// last good checkpoint stays).
pub fn train(cfg: &TrainConfig, opts: &TrainOptions) -> Result<TrainReport> {
    // Every value error first, all at once (the shards are only looked for in a valid file).
    let errs = cfg.validate();
    if !errs.is_empty() {
        return Err(Error::Config(errs));
    }
    let shards = find_shards(cfg)?;
    let mut t = Trainer::new(cfg, opts)?;
    // Where the data stream stood at the resumed checkpoint; without it (a checkpoint of an
    // earlier version, other shards) the data order is replayed up to the step instead.
    let resume_at = (t.step > 0).then(|| StreamState::read(&t.dir, t.step, &shards, cfg)).flatten();
    let needed = resume_at.as_ref().map(StreamState::needed).unwrap_or_default();
    let mut found = std::collections::HashMap::new();
    // Which inputs went where, and the validation samples.
    let mut size = None;
    let mut val = ValPick::new(cfg.validate.max_samples, cfg.seed);
    // A signal during the scan of the shards or the replay of a resume stops there: nothing has
    // been trained since the last checkpoint, so nothing is lost.
    crate::signal::install();
    let stopped = |what: &str| {
        Error::Interrupted(format!("while {what}, before any new step; {} is as it was: run the same command again", cfg.output.dir))
    };
    // Only the samples kept are decoded: the validation picks, and a resumed run's buffer. The
    // others' PNG headers are checked here, their pixels when the stream reaches them.
    for (i, s) in shards.iter().enumerate() {
        if crate::signal::interrupted() {
            return Err(stopped("reading the shards"));
        }
        for (j, raw) in crate::io::wds::read_shard_raw(s)?.into_iter().enumerate() {
            size = Some(raw.size(s, size)?);
            if !t.admit_source(raw.source) {
                val.push(&raw.key.clone(), (i, raw));
            } else if needed.contains(&(i as u32, j as u32)) {
                found.insert((i as u32, j as u32), raw.decode(s, size)?);
            }
        }
    }
    let val: Vec<Pair> = val.finish().into_iter().map(|(i, raw)| raw.decode(&shards[i], size)).collect::<Result<_>>()?;
    if val.is_empty() && cfg.data.val_fraction > 0.0 {
        // The split is by input: with few inputs, a fraction can hold none of them.
        let (f, n) = (cfg.data.val_fraction, t.train_inputs.len());
        eprintln!("warning: no input fell in the validation split (data.val_fraction {f} of {n} inputs): {NO_VALIDATION}");
    }
    t.val = val;
    if t.train_inputs.is_empty() {
        return Err(Error::Usage(format!(
            "data: every input ({:?}) went to validation; lower data.val_fraction or add inputs",
            t.val_inputs
        )));
    }
    let mut stream = Stream::new(shards, cfg.seed, cfg.data.val_fraction, cfg.data.shuffle_buffer, size, t.bn_batches());
    if let Some(state) = resume_at {
        // The buffer and the batches BatchNorm is recalibrated from, as they were.
        for batch in stream.restore(state, &found)? {
            t.remember(&batch);
        }
        drop(found);
        t.resumed_data = Some(format!("restored from {}", StreamState::path(&t.dir, t.step).display()));
    } else if t.step > 0 && !replay(&mut t, &mut stream, cfg)? {
        return Err(stopped("replaying the data order up to the resumed step"));
    }
    if let Some(how) = &t.resumed_data {
        eprintln!("resuming after step {}: the data order {how}", t.step);
    }
    while !t.done() {
        let batch = stream.batch(cfg.optim.batch)?;
        if t.saves_after(t.step + 1) {
            t.stream = Some(stream.state());
        }
        t.train_step(&batch)?;
        if crate::signal::interrupted() {
            // SIGTERM (Slurm preemption, a time limit) or Ctrl-C: keep every finished step.
            t.stream = Some(stream.state());
            return Err(t.checkpoint_and_stop());
        }
    }
    t.finish()
}
