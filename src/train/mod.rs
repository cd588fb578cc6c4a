//! `pipeline train`: the paper's U-Net or shallow model on (lq, gt) patch pairs from WebDataset
//! shards, with Huber loss and Adam, validation PSNR/SSIM on inputs held apart by source video,
//! checkpoints ([`crate::model::checkpoint`]) and exact resume.
//!
//! Determinism: the shard order, the shuffle buffer and the augmentations are functions of the
//! seed and the step, so `--resume` continues with the data order the uninterrupted run would
//! have had (it replays the sample stream up to the checkpoint).
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
    // A signal during the scan of the shards or the replay of a resume stops there: nothing has
    // been trained since the last checkpoint, so nothing is lost.
    crate::signal::install();
    let stopped = |what: &str| {
        Error::Interrupted(format!("while {what}, before any new step; {} is as it was: run the same command again", cfg.output.dir))
    };
    for s in &shards {
        if crate::signal::interrupted() {
            return Err(stopped("reading the shards"));
        }
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
        if crate::signal::interrupted() {
            return Err(stopped("replaying the data order up to the resumed step"));
        }
        let batch: Vec<Pair> = (0..cfg.optim.batch).map(|_| stream.next()).collect::<Result<_>>()?;
        if step + cfg.validate.bn_batches >= t.step {
            t.remember(&batch);
        }
    }
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
