//! The commands: each file owns its clap arguments, its embedded default settings file, what it
//! runs and the summary it prints. `cli.rs` only parses and dispatches.

pub mod bench;
pub mod calibrate;
#[cfg(feature = "infer")]
pub mod deblur;
#[cfg(all(feature = "infer", feature = "ffmpeg"))]
pub mod eval;
#[cfg(feature = "infer")]
pub mod export;
#[cfg(feature = "infer")]
pub mod figure;
pub mod generate;
pub mod psf;
#[cfg(feature = "train")]
pub mod train;
pub mod validate;

use crate::progress::ProgressMode;
use clap::Args;
use std::path::PathBuf;

/// `--config`, `--set` and `--progress` of the commands that read one settings file
/// (`deblur`: pipelines/deblur.toml, `eval`: pipelines/eval.toml).
#[derive(Args, Debug)]
pub struct ConfigArgs {
    /// The command's settings file; default: its pipelines/*.toml, embedded in the binary.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override one key of that file: --set deblur.tile=512, --set eval.crop=256 (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
    #[arg(long, value_enum, default_value_t = ProgressMode::Auto)]
    pub progress: ProgressMode,
}

impl ConfigArgs {
    /// The file, or the embedded default `name`, with the overrides applied; and its name.
    pub fn load(&self, embedded: &str, name: &str) -> crate::Result<(toml::Table, String)> {
        load_or_embedded(self.config.as_deref(), embedded, name, &self.sets)
    }
}

pub use crate::config::load_or_embedded;
