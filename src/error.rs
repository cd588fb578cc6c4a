//! The library's error type. Messages are lower case and name the file, key or frame.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The OS error is part of the message, not a `source`, so a printed chain says it once.
    #[error("{}: {cause}", path.display())]
    Io { path: PathBuf, cause: std::io::Error },
    #[error("{}", .0.iter().map(|e| e.to_string()).collect::<Vec<_>>().join("\n"))]
    Config(Vec<crate::checks::ConfigError>),
    #[error("{0}")]
    Invalid(String),
    /// A file that is not what it must be (a model, checkpoint, optimizer state, shard or image
    /// that does not parse or does not fit), named, with why.
    #[error("{}: {why}", path.display())]
    File { path: PathBuf, why: String },
    /// A file one of the format readers refused (PNG, tar, `.npy`, safetensors, JSON), named (a
    /// shard's member as `shard.tar/member`);
    /// the reader's own error is kept, typed, in `cause` and is part of the message (as in `Io`).
    #[error("{}: {cause}", path.display())]
    Format { path: PathBuf, cause: Box<FormatError> },
    /// A stage of a pipeline failed; the cause is kept (and printed after it).
    #[error("stage {stage}")]
    Stage { stage: String, source: Box<Error> },
    /// What was being done (`init`, say) when its cause failed; the cause is kept.
    #[error("{what}")]
    Context { what: String, source: Box<Error> },
    /// A pipeline file that does not parse or has an unknown key.
    #[error("{0}")]
    ConfigText(String),
    /// Some inputs failed (each already named on stderr); the rest were done: exit code 1.
    #[error("{n} input(s) failed; {} lists them", report.display())]
    InputsFailed { n: usize, report: PathBuf },
    /// The command as given cannot do anything (no input found, say): exit code 2.
    #[error("{0}")]
    Usage(String),
    /// A video or image FFmpeg could not read or write; the cause is kept as the source.
    #[cfg(feature = "ffmpeg")]
    #[error("{}", path.display())]
    Video {
        path: PathBuf,
        #[source]
        source: crate::io::video::VideoError,
    },
    /// Stopped by SIGINT or SIGTERM at a safe point: what was kept and how to continue. Exit
    /// code 130, the shell's for SIGINT.
    #[error("interrupted: {0}")]
    Interrupted(String),
    /// burn could not serialise a network or optimizer state (`what` names which); the cause is kept.
    #[error("{what}: burn could not serialise it")]
    Serialise { what: String, source: Box<dyn std::error::Error + Send + Sync> },
    /// A stage panicked (a bug): the run stopped, its sink removed what it had not finished and
    /// the report says which stage. Exit code 1.
    #[error("panicked (a bug; please report it with the report.json): {0}")]
    Panicked(String),
    /// The worker threads could not be started (the OS refused them).
    #[error("could not start {what} threads")]
    Threads { what: &'static str, source: rayon::ThreadPoolBuildError },
    /// Training diverged: the loss of a step was not finite. Nothing after the last checkpoint is
    /// kept; `latest` names the last good one (resume from it with a lower learning rate).
    #[error("step {step}: the loss is {loss}; stopped. The last good checkpoint is listed in {}", latest.display())]
    Diverged { step: usize, loss: f64, latest: PathBuf },
    /// A file name read from a file in a folder the tool works in (a manifest's shard, a run's
    /// `latest.json`) that would lead outside that folder: refused, nothing opened through it.
    #[error("{}: {field} = {name:?} is {why}; refusing to follow it", file.display())]
    Untrusted { file: PathBuf, field: String, name: String, why: &'static str },
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

/// What a format reader said about a file's bytes: one variant per reader, each its own typed
/// error (match on it to tell a truncated shard from a damaged one, say).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum FormatError {
    #[error("{0}")]
    Png(#[from] crate::io::png::PngError),
    #[error("{0}")]
    Tar(#[from] crate::io::tar::TarError),
    #[error("{0}")]
    Npy(#[from] crate::io::npy::NpyError),
    #[cfg(feature = "infer")]
    #[error("{0}")]
    Weights(#[from] crate::model::weights::WeightsError),
    #[error("{0}")]
    Json(#[from] serde_json::Error),
}

impl Error {
    /// The message with its causes, one line (`stage shards: manifest.json: No space left`), for
    /// reports that keep text.
    pub fn chain(&self) -> String {
        let mut text = self.to_string();
        let mut cause = std::error::Error::source(self);
        while let Some(c) = cause {
            text = format!("{text}: {c}");
            cause = c.source();
        }
        text
    }

    /// A format reader's error, naming its file: `.map_err(Error::format(path))`.
    pub fn format<E: Into<FormatError>>(path: &std::path::Path) -> impl FnOnce(E) -> Error + '_ {
        move |e| Error::Format { path: path.to_path_buf(), cause: Box::new(e.into()) }
    }

    /// A video error, naming its file.
    #[cfg(feature = "ffmpeg")]
    pub fn video(path: &std::path::Path) -> impl FnOnce(crate::io::video::VideoError) -> Error + '_ {
        move |source| Error::Video { path: path.to_path_buf(), source }
    }
}

impl From<crate::checks::ConfigError> for Error {
    fn from(e: crate::checks::ConfigError) -> Self {
        Error::Config(vec![e])
    }
}
