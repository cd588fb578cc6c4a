//! The training file: `[model]`, `[data]`, `[optim]`, `[validate]`, `[output]`, with every
//! value checked and named by its key.

use crate::model::Arch;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DataConfig {
    /// Shard files, folders of `.tar` files, or file-name globs.
    pub shards: Vec<String>,
    /// Share of the source inputs (videos) held apart for validation.
    #[serde(default = "d_val_fraction")]
    pub val_fraction: f64,
    /// Samples held in the shuffle buffer.
    #[serde(default = "d_shuffle")]
    pub shuffle_buffer: usize,
    /// Random flips and 90-degree rotations.
    #[serde(default = "d_true")]
    pub augment: bool,
    /// Burst models: the share of samples trained at the first or the last time of their burst
    /// (half each); the rest at a time drawn uniformly, ends included. 0: uniform.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub burst_ends: f64,
}

pub(crate) fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LrSchedule {
    Constant,
    /// Linear warm-up, then cosine decay to `lr * lr_min_factor`.
    Cosine,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptimConfig {
    #[serde(default = "d_steps")]
    pub steps: usize,
    #[serde(default = "d_batch")]
    pub batch: usize,
    #[serde(default = "d_lr")]
    pub lr: f64,
    #[serde(default = "d_schedule")]
    pub schedule: LrSchedule,
    /// Steps of linear warm-up before the schedule; missing: 20, or a tenth of `steps` where
    /// that is fewer (a short test run still reaches its full rate).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warmup_steps: Option<usize>,
    #[serde(default = "d_lr_min")]
    pub lr_min_factor: f64,
    /// Huber delta on the [0, 1] scale of encoded values.
    #[serde(default = "d_delta")]
    pub huber_delta: f64,
    /// Adam's epsilon. PyTorch's 1e-8; burn's default of 1e-5 is larger than most of these
    /// networks' gradients (RMS 1e-7 to 1e-6 with the mean-reduced loss), which then train at a
    /// few percent of the rate (docs/notebook/models.md).
    #[serde(default = "d_adam_eps")]
    pub adam_epsilon: f64,
    /// Start from the identity: the last layer zeroed, so the residual passes the input.
    #[serde(default = "d_true")]
    pub zero_init: bool,
    /// `fast`: the CPU path of `src/model/fast/` (shifted copies + gemm on all cores); `burn`: burn's
    /// autodiff on its flex CPU backend (the reference; with the `wgpu`/`cuda` features the
    /// path a GPU build takes).
    #[serde(default)]
    pub engine: EngineKind,
}

/// Which implementation runs a training step.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EngineKind {
    #[default]
    Fast,
    Burn,
}

impl Default for OptimConfig {
    fn default() -> Self {
        OptimConfig {
            steps: d_steps(),
            batch: d_batch(),
            lr: d_lr(),
            schedule: d_schedule(),
            warmup_steps: None,
            lr_min_factor: d_lr_min(),
            huber_delta: d_delta(),
            adam_epsilon: d_adam_eps(),
            zero_init: true,
            engine: EngineKind::Fast,
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValidateConfig {
    #[serde(default = "d_every")]
    pub every: usize,
    #[serde(default = "d_val_max")]
    pub max_samples: usize,
    /// Before each validation and checkpoint, BatchNorm's running statistics are recomputed as
    /// the exact mean over this many of the latest training batches ("precise BatchNorm"; 0
    /// keeps the momentum averages). The fast engine only.
    #[serde(default = "d_bn_batches")]
    pub bn_batches: usize,
}

impl Default for ValidateConfig {
    fn default() -> Self {
        ValidateConfig { every: d_every(), max_samples: d_val_max(), bn_batches: d_bn_batches() }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputConfig {
    pub dir: String,
    /// Steps between checkpoints (the last step is always saved).
    #[serde(default = "d_ckpt")]
    pub checkpoint_every: usize,
    /// At the end, `model.safetensors` is the mean of the weights of the last this many
    /// checkpoints (BatchNorm recalibrated on it), scored on the validation set in the report;
    /// 1 writes no such file. Averaging evens out the checkpoint-to-checkpoint swings of a run
    /// (docs/notebook/models.md). The fast engine only.
    #[serde(default = "d_one")]
    pub average_last: usize,
}

/// A training file (`pipelines/train.toml`).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    #[serde(default)]
    pub seed: u64,
    pub model: Arch,
    /// Start from the weights of this model (a model folder as shipped in `models/`, or a
    /// `.safetensors` file) instead of fresh ones, with a fresh optimizer: fine-tuning. The run
    /// is one of its own: `optim.steps` new steps on a new schedule peaking at `optim.lr`
    /// (warm-up included). A folder's `report.json` history is kept in the report (`before`)
    /// and drawn before step 0 in the curves.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init: Option<String>,
    pub data: DataConfig,
    #[serde(default)]
    pub optim: OptimConfig,
    #[serde(default)]
    pub validate: ValidateConfig,
    pub output: OutputConfig,
}

pub(crate) fn d_val_fraction() -> f64 {
    0.2
}
pub(crate) fn d_shuffle() -> usize {
    256
}
pub(crate) fn d_true() -> bool {
    true
}
fn d_steps() -> usize {
    200
}
fn d_batch() -> usize {
    8
}
fn d_lr() -> f64 {
    1e-3
}
fn d_schedule() -> LrSchedule {
    LrSchedule::Cosine
}
fn d_lr_min() -> f64 {
    0.1
}
fn d_delta() -> f64 {
    0.02
}
fn d_every() -> usize {
    50
}
fn d_one() -> usize {
    1
}
fn d_adam_eps() -> f64 {
    1e-8
}
fn d_bn_batches() -> usize {
    50
}
fn d_val_max() -> usize {
    64
}
pub(crate) fn d_ckpt() -> usize {
    100
}

impl OptimConfig {
    /// The warm-up steps: `warmup_steps`, or 20 (a tenth of `steps` where that is fewer).
    pub fn warmup(&self) -> usize {
        self.warmup_steps.unwrap_or((self.steps / 10).min(20))
    }
}

impl TrainConfig {
    /// Every value error, each naming its key.
    pub fn validate(&self) -> Vec<crate::checks::ConfigError> {
        let mut c = crate::checks::Checker::new("");
        match self.model {
            Arch::Unet { base } => c.range_usize("model.base", base, 1, 256),
            Arch::BurstUnet { base, levels } => {
                c.range_usize("model.base", base, 1, 256);
                c.range_usize("model.levels", levels, 1, crate::model::DECODER_LEVELS);
            }
            Arch::Shallow { width } => c.range_usize("model.width", width, 1, 1024),
        }
        if self.data.shards.is_empty() {
            c.fail("data.shards", "names no shard");
        }
        c.range("data.val_fraction", self.data.val_fraction, 0.0, 0.9);
        c.range("data.burst_ends", self.data.burst_ends, 0.0, 1.0);
        c.range_usize("data.shuffle_buffer", self.data.shuffle_buffer, 1, 1_000_000);
        c.range_usize("optim.steps", self.optim.steps, 1, 100_000_000);
        c.range_usize("optim.batch", self.optim.batch, 1, 4096);
        c.range("optim.lr", self.optim.lr, 1e-8, 1.0);
        if let Some(w) = self.optim.warmup_steps {
            if w > 0 && w >= self.optim.steps {
                c.fail(
                    "optim.warmup_steps",
                    format!("is {w}, not below optim.steps ({}): the run would end before its full learning rate", self.optim.steps),
                );
            }
        }
        c.range("optim.lr_min_factor", self.optim.lr_min_factor, 0.0, 1.0);
        c.range("optim.huber_delta", self.optim.huber_delta, 1e-6, 10.0);
        c.range("optim.adam_epsilon", self.optim.adam_epsilon, 1e-12, 1.0);
        c.range_usize("validate.every", self.validate.every, 1, 100_000_000);
        if self.output.dir.trim().is_empty() {
            c.fail("output.dir", "is empty; name the run's own folder (it is made if missing)");
        }
        c.range_usize("output.checkpoint_every", self.output.checkpoint_every, 1, 100_000_000);
        c.range_usize("output.average_last", self.output.average_last, 1, 10_000);
        if self.output.average_last > 1 && self.optim.engine != EngineKind::Fast {
            c.fail("output.average_last", "averaging needs optim.engine = \"fast\" (BatchNorm is recalibrated on the mean)");
        }
        c.errors
    }

    /// The learning-rate schedule in words, for the report.
    pub fn schedule_words(&self) -> String {
        let o = &self.optim;
        let shape = match o.schedule {
            LrSchedule::Constant => format!("constant {:e}", o.lr),
            LrSchedule::Cosine => format!("cosine from {:e} to {:e}", o.lr, o.lr * o.lr_min_factor),
        };
        let from = self.init.as_ref().map_or(String::from("fresh weights"), |i| format!("fine-tuning {i}"));
        format!("{shape} over steps 1 to {} after {} warm-up steps; {from}", o.steps, o.warmup())
    }

    /// Learning rate at `step` (0-based).
    pub fn lr_at(&self, step: usize) -> f64 {
        let o = &self.optim;
        let warmup = o.warmup();
        if step < warmup {
            return o.lr * (step + 1) as f64 / warmup as f64;
        }
        match o.schedule {
            LrSchedule::Constant => o.lr,
            LrSchedule::Cosine => {
                let t = (step - warmup) as f64 / (o.steps.saturating_sub(warmup)).max(1) as f64;
                let min = o.lr * o.lr_min_factor;
                min + 0.5 * (o.lr - min) * (1.0 + (std::f64::consts::PI * t.min(1.0)).cos())
            }
        }
    }
}
