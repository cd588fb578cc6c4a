//! Progress on stderr, the same way for every long command: a bar with rate and ETA on a
//! terminal (`--progress auto`), a plain status line every few seconds otherwise or with
//! `--progress lines` (logs, Slurm), nothing with `--progress never`.

use std::io::IsTerminal;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How progress is shown.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ProgressMode {
    /// Bars on a terminal, status lines otherwise.
    Auto,
    /// Status lines every few seconds.
    Lines,
    /// Nothing but the summary.
    Never,
}

impl ProgressMode {
    /// Auto resolved: bars on a terminal, lines otherwise.
    pub fn resolve(self) -> ProgressMode {
        match self {
            ProgressMode::Auto if !std::io::stderr().is_terminal() => ProgressMode::Lines,
            m => m,
        }
    }
}

/// Seconds between status lines.
const LINE_EVERY: Duration = Duration::from_secs(5);

/// Progress of `len` units of work (`None`: unknown, a spinner), named `what` (`deblur`).
pub struct Bar {
    mode: ProgressMode,
    what: String,
    unit: String,
    len: Option<u64>,
    pos: AtomicU64,
    start: Instant,
    last: Mutex<(Instant, String)>,
    bar: Option<indicatif::ProgressBar>,
}

impl Bar {
    pub fn new(mode: ProgressMode, what: &str, unit: &str, len: Option<u64>) -> Bar {
        let mode = mode.resolve();
        let bar = (mode == ProgressMode::Auto).then(|| {
            let (b, template) = match len.filter(|&n| n > 0) {
                Some(n) => {
                    (indicatif::ProgressBar::new(n), format!("{what} {{bar:30}} {{pos}}/{{len}} {unit} {{per_sec}} eta {{eta}} {{msg}}"))
                }
                None => (indicatif::ProgressBar::new_spinner(), format!("{what} {{spinner}} {{pos}} {unit} {{per_sec}} {{msg}}")),
            };
            b.set_style(indicatif::ProgressStyle::with_template(&template).expect("template"));
            b
        });
        let now = Instant::now();
        Bar {
            mode,
            what: what.into(),
            unit: unit.into(),
            len,
            pos: AtomicU64::new(0),
            start: now,
            last: Mutex::new((now, String::new())),
            bar,
        }
    }

    /// A bar that shows nothing.
    pub fn hidden() -> Bar {
        Bar::new(ProgressMode::Never, "", "", None)
    }

    /// `n` more units done.
    pub fn inc(&self, n: u64) {
        self.set_position(self.pos.load(Ordering::Relaxed) + n);
    }

    pub fn set_position(&self, p: u64) {
        self.pos.store(p, Ordering::Relaxed);
        match &self.bar {
            Some(b) => b.set_position(p),
            None => self.line(false),
        }
    }

    /// A note after the counts (the loss, a validation score).
    pub fn set_message(&self, msg: String) {
        match &self.bar {
            Some(b) => b.set_message(msg),
            None => self.last.lock().expect("progress").1 = msg,
        }
    }

    /// A line of its own above the bar (or on stderr when there is no bar), shown in every mode.
    pub fn println(&self, text: &str) {
        match &self.bar {
            Some(b) => b.println(text),
            None => eprintln!("{text}"),
        }
    }

    fn line(&self, force: bool) {
        if self.mode != ProgressMode::Lines {
            return;
        }
        let mut last = self.last.lock().expect("progress");
        if !force && last.0.elapsed() < LINE_EVERY {
            return;
        }
        last.0 = Instant::now();
        let p = self.pos.load(Ordering::Relaxed);
        let secs = self.start.elapsed().as_secs_f64().max(1e-9);
        let rate = p as f64 / secs;
        let of = self.len.map_or(String::new(), |n| format!("/{n}"));
        let eta = match self.len {
            Some(n) if rate > 0.0 && n > p => format!(", eta {}", eta_text((n - p) as f64 / rate)),
            _ => String::new(),
        };
        let msg = if last.1.is_empty() { String::new() } else { format!(" {}", last.1) };
        eprintln!("{}: {p}{of} {} ({rate:.2}/s{eta}){msg}", self.what, self.unit);
    }

    /// Clears the bar (or prints the last line).
    pub fn finish(&self) {
        match &self.bar {
            Some(b) => b.finish_and_clear(),
            None => self.line(true),
        }
    }
}

/// `1h02m`, `3m05s`, `12s`.
pub fn eta_text(secs: f64) -> String {
    let s = secs.round() as u64;
    match s {
        0..=59 => format!("{s}s"),
        60..=3599 => format!("{}m{:02}s", s / 60, s % 60),
        _ => format!("{}h{:02}m", s / 3600, s % 3600 / 60),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eta_reads_as_a_person_would_say_it() {
        assert_eq!(eta_text(12.4), "12s");
        assert_eq!(eta_text(185.0), "3m05s");
        assert_eq!(eta_text(3720.0), "1h02m");
    }
}
