//! The library's error type. Messages are lower case and name the file, key or frame.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Error {
    /// The OS error is part of the message, not a `source`, so a printed chain says it once.
    #[error("{}: {cause}", path.display())]
    Io { path: PathBuf, cause: std::io::Error },
    #[error("{}", .0.iter().map(|e| e.to_string()).collect::<Vec<_>>().join("\n"))]
    Config(Vec<crate::optics::ConfigError>),
    #[error("{0}")]
    Invalid(String),
    /// A stage of a pipeline failed; the cause is kept (and printed after it).
    #[error("stage {stage}")]
    Stage { stage: String, source: Box<Error> },
    /// A pipeline file that does not parse or has an unknown key.
    #[error("{0}")]
    ConfigText(String),
    #[error("{0} input(s) failed; see report.json")]
    InputsFailed(usize),
    /// The command as given cannot do anything (no input found, say): exit code 2.
    #[error("{0}")]
    Usage(String),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;

impl From<crate::optics::ConfigError> for Error {
    fn from(e: crate::optics::ConfigError) -> Self {
        Error::Config(vec![e])
    }
}
