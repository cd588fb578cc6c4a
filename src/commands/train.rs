//! `pipeline train`: the command line of [`crate::train`].

use crate::progress::ProgressMode;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct TrainArgs {
    /// Training file (TOML): [model], [data], [optim], [validate], [output].
    #[allow(rustdoc::broken_intra_doc_links)] // `--help` text: the brackets are TOML tables
    #[arg(long)]
    pub config: PathBuf,
    /// Override one key: --set optim.steps=500 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
    /// Continue from output.dir/latest.json with the same data order.
    #[arg(long, conflicts_with = "overwrite")]
    pub resume: bool,
    /// Start afresh in an output.dir that holds a run, deleting its checkpoints and history
    /// (without it, such a folder is refused).
    #[arg(long)]
    pub overwrite: bool,
    /// Checkpoint and stop after this step, as if interrupted there (exit 0); `--resume`
    /// continues on the same schedule. For runs split across sessions or job slots.
    #[arg(long, value_name = "STEP")]
    pub stop_after: Option<usize>,
    /// Progress display on stderr.
    #[arg(long, value_enum, default_value_t = ProgressMode::Auto)]
    pub progress: ProgressMode,
}

/// Runs `pipeline train`.
///
/// # Errors
/// Whatever the command reports (exit codes in `main.rs`).
pub fn command(a: TrainArgs) -> anyhow::Result<()> {
    let TrainArgs { config, sets, resume, overwrite, stop_after, progress } = a;
    let table = crate::config::load(&config, &sets)?;
    let origin = crate::config::Origin::new(&config.display().to_string(), None, &sets);
    let cfg = match crate::config::deserialize_all::<crate::train::TrainConfig>(&table) {
        (Some(cfg), errs) if errs.is_empty() => cfg,
        (_, errs) => return Err(origin.errors(errs).into()),
    };
    let r = crate::train::train(&cfg, &crate::train::TrainOptions { resume, overwrite, progress, stop_after })?;
    let last = r.validation.last();
    // After a resume, the time and rate are this run's alone: say which steps they cover.
    let resumed = match r.resumed_from {
        Some(from) if from < r.steps => format!("resumed from step {from}; steps {} to {} ", from + 1, r.steps),
        Some(_) => "resumed when finished: no steps left; ".to_string(),
        None => String::new(),
    };
    eprintln!(
        "{}: {} steps ({resumed}in {:.0} s, {:.1} patches/s){} -> {}",
        r.arch,
        r.steps,
        r.seconds,
        r.patches_per_s,
        last.map_or(String::new(), |v| format!(
            ", validation PSNR {:.2} dB / SSIM {:.4} (blurred input {:.2} / {:.4})",
            v.model.psnr_rgb, v.model.ssim_rgb, v.input.psnr_rgb, v.input.ssim_rgb
        )),
        cfg.output.dir
    );
    Ok(())
}
