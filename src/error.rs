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
    /// A program a command runs (the ffmpeg CLI, a child `pipeline`) could not start (the OS
    /// error kept) or exited with a failure (its status in `why`).
    #[error("{program}: {why}")]
    Program { program: String, why: String, source: Option<std::io::Error> },
    /// A file that is not what it must be (a model, checkpoint, optimizer state, shard or image
    /// that does not parse or does not fit), named, with why.
    #[error("{}: {why}", path.display())]
    File { path: PathBuf, why: String },
    /// A file a library refused (burn's record of a network or optimizer, a manifest's JSON):
    /// what the file was wanted as, and the library's error, kept as the source.
    #[error("{}: {why}", path.display())]
    Unloadable { path: PathBuf, why: String, source: Box<dyn std::error::Error + Send + Sync> },
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
    /// A settings file that is not TOML, or whose TOML does not fit (an unknown key, a value
    /// of the wrong type): where (`origin`), the located message (the line quoted, when the text
    /// is at hand), and the `toml` crate's error. Exit code 2.
    #[error("{origin}: {located}")]
    Toml { origin: String, located: String, cause: Box<toml::de::Error> },
    /// A `--set` that cannot be applied. Exit code 2.
    #[error(transparent)]
    Set(#[from] SetError),
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
    /// A network, optimizer state or settings table could not be serialised (`what` names which);
    /// the serialiser's error (burn's, the toml crate's) is kept.
    #[error("{what}: could not be serialised")]
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

/// Why a `--set key.path=value` cannot be applied.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SetError {
    #[error("--set {set:?}: expected key.path=value")]
    NoEquals { set: String },
    /// Starts like a number, array, table or quoted string but is not one.
    #[error("--set {key}: {value:?} is not a TOML value: {}{}", first_line(cause.message()), int_hint(value))]
    NotValue { key: String, value: String, cause: Box<toml::de::Error> },
    #[error("--set {set:?}: {key:?} is not a key (keys are letters, digits, _ and -, joined by dots)")]
    NotKey { set: String, key: String },
    /// A dotted path through a value that is not a table.
    #[error("--set {key}: {part} is not a table")]
    NotTable { key: String, part: String },
}

fn first_line(s: &str) -> &str {
    s.lines().next().unwrap_or("")
}

/// A hint for a value of digits only that is not a TOML integer (too large).
fn int_hint(value: &str) -> &'static str {
    if value.trim_start_matches(['+', '-']).chars().all(|c| c.is_ascii_digit()) {
        " (integers are at most 9223372036854775807)"
    } else {
        ""
    }
}

/// A TOML syntax error as the `toml` crate words it, with the line it quotes cut to 80
/// characters around the error: a file of one 600 KB line (deeply nested arrays, say) is
/// reported in a few lines, not echoed whole.
pub fn toml_error(e: &toml::de::Error, text: &str) -> String {
    const HALF: usize = 40;
    let Some(span) = e.span().filter(|s| s.start <= text.len() && text.is_char_boundary(s.start)) else {
        return e.to_string().trim().to_string();
    };
    let before = &text[..span.start];
    let line_no = before.matches('\n').count() + 1;
    let start = before.rfind('\n').map_or(0, |i| i + 1);
    let end = text[start..].find('\n').map_or(text.len(), |i| start + i);
    let line: Vec<char> = text[start..end].trim_end_matches('\r').chars().collect();
    let col = text[start..span.start].chars().count();
    let (from, to) = (col.saturating_sub(HALF), (col + HALF).min(line.len()));
    let pre = if from > 0 { "..." } else { "" };
    let post = if to < line.len() { "..." } else { "" };
    let snippet: String = line[from.min(to)..to].iter().collect();
    let gutter = " ".repeat(line_no.to_string().len());
    format!(
        "TOML parse error at line {line_no}, column {}\n{gutter} |\n{line_no} | {pre}{snippet}{post}\n{gutter} | {}^\n{}",
        col + 1,
        " ".repeat(pre.len() + col - from.min(col)),
        e.message().trim()
    )
}

impl Error {
    /// A TOML error of the settings named `origin`: `.map_err(Error::toml(origin, Some(text)))`;
    /// with the text, the message quotes the line (see [`toml_error`]).
    pub fn toml<'a>(origin: &'a str, text: Option<&'a str>) -> impl FnOnce(toml::de::Error) -> Error + 'a {
        move |e| {
            let located = match text {
                Some(t) => toml_error(&e, t),
                None => e.to_string().trim().to_string(),
            };
            Error::Toml { origin: origin.into(), located, cause: Box::new(e) }
        }
    }

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
