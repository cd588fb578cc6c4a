//! `pipeline export`: a trained model as a safetensors file with PyTorch `state_dict` names
//! ([`crate::model::torch`]), or with the names `pipeline` itself writes (a model trained in
//! PyTorch brought home), optionally in half precision (how the shipped models are stored).

use crate::model::torch::{canonical, narrow, read_safetensors, to_torch};
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
    /// Target naming: torch (PyTorch `state_dict` keys of python/pipeline/models.py) or burn
    /// (the names `pipeline train` writes).
    #[arg(long, value_enum, default_value_t = ExportFormat::Torch)]
    pub format: ExportFormat,
    /// Store the weights as F16 (half the bytes; `pipeline` widens them when it loads them).
    #[arg(long)]
    pub half: bool,
    /// Replace an existing file at the output (refused otherwise; the input model is never replaced).
    #[arg(long)]
    pub overwrite: bool,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ExportFormat {
    Torch,
    Burn,
}

/// Runs `pipeline export`.
///
/// # Errors
/// The model cannot be read or is not ours; the output cannot be written.
pub fn command(a: ExportArgs) -> anyhow::Result<()> {
    let path = if a.model.is_dir() { crate::model::weights::model_in(&a.model)? } else { a.model.clone() };
    let name = path.display().to_string();
    crate::io::paths::refuse_replacing_inputs(std::slice::from_ref(&a.out), &[path.clone(), a.model.clone()])?;
    crate::io::paths::refuse_replacing(&a.out, std::slice::from_ref(&a.out), a.overwrite)?;
    let bytes = crate::io::paths::read_regular(&path, crate::io::paths::MAX_MODEL_BYTES, "safetensors model file")?;
    // F32 with pipeline's names, whatever the file holds; refuse what `deblur` would refuse
    // (wrong architecture, non-finite weights).
    let native = canonical(&bytes, &name)?;
    crate::model::weights::Weights::from_bytes(&native, &name)?;
    let (count, out, what) = match a.format {
        ExportFormat::Torch => {
            let (names, out) = to_torch(&native, &name)?;
            (names.len(), out, "PyTorch names")
        }
        ExportFormat::Burn => (read_safetensors(&native, &name)?.0.len(), native, "pipeline's names"),
    };
    let out = if a.half { narrow(&out, &name)? } else { out };
    if let Some(parent) = a.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|e| Error::Io { path: parent.to_path_buf(), cause: e })?;
    }
    crate::io::write_atomic(&a.out, |w| w.write_all(&out))?;
    eprintln!("{count} tensors with {what}{} -> {}", if a.half { ", F16" } else { "" }, a.out.display());
    Ok(())
}
