//! `pipeline export`: a trained model as a safetensors file with PyTorch `state_dict` names
//! ([`crate::model::torch`]).

use crate::model::torch::to_torch;
use crate::Error;
use clap::Args;
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct ExportArgs {
    /// A model written by `pipeline train` (a `.safetensors` file or a model folder).
    pub model: PathBuf,
    /// Output `.safetensors` file.
    #[arg(short, long)]
    pub out: PathBuf,
    /// Target naming: torch (PyTorch `state_dict` keys of python/pipeline/models.py).
    #[arg(long, value_enum, default_value_t = ExportFormat::Torch)]
    pub format: ExportFormat,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    Torch,
}

/// Runs `pipeline export`.
///
/// # Errors
/// The model cannot be read or is not ours; the output cannot be written.
pub fn command(a: ExportArgs) -> anyhow::Result<()> {
    let ExportFormat::Torch = a.format;
    let path = if a.model.is_dir() { crate::model::checkpoint::model_in(&a.model)? } else { a.model.clone() };
    let bytes = std::fs::read(&path).map_err(|e| Error::Io { path: path.clone(), cause: e })?;
    // Refuse what `deblur` would refuse (wrong architecture, non-finite weights).
    crate::model::checkpoint::load_model_bytes(&bytes, &path.display().to_string(), &burn::tensor::Device::flex())?;
    let (names, out) = to_torch(&bytes, &path.display().to_string())?;
    crate::io::write_atomic(&a.out, |w| w.write_all(&out))?;
    eprintln!("{} tensors with PyTorch names -> {}", names.len(), a.out.display());
    Ok(())
}
