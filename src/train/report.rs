use super::*;

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
    /// How the resumed run found its place in the data: "restored from stream-NNNNNNN.json" or
    /// "replayed N steps".
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resumed_data: Option<String>,
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

/// The trailing mean of log10 loss over 1% of the run (at least one step): its window, and the
/// points at each step less `offset`.
fn running_mean(loss: &[LossPoint], offset: f64) -> (usize, Vec<(f64, f64)>) {
    let k = (loss.len() / 100).max(1);
    let points = loss
        .windows(k)
        .map(|w| (w[k - 1].step as f64 - offset, (w.iter().map(|p| p.loss).sum::<f64>() / k as f64).max(1e-12).log10()))
        .collect();
    (k, points)
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
    let (k, points) = running_mean(&r.loss, 0.0);
    let mean_name = format!("MEAN OF {k} STEPS");
    let mean = crate::plot::Series { name: &mean_name, points, color: [1.0, 1.0, 1.0] };
    // A fine-tuning run draws the initial model's own training before its step 0, in grey (on
    // the initial run's own data, so its levels need not join this run's).
    let grey = [0.5, 0.5, 0.5];
    let offset = r.before.as_ref().map_or(0.0, |b| b.steps as f64);
    let earlier: Vec<crate::plot::Series> = r
        .before
        .iter()
        .map(|b| crate::plot::Series { name: "INITIAL MODEL'S RUN", points: running_mean(&b.loss, offset).1, color: grey })
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
        points: b.validation.iter().map(|v| (v.step as f64 - offset, v.model.psnr_rgb)).collect(),
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
