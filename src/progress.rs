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
    /// Units done before this run (a resumed training run): counted in the position, not in
    /// the rate.
    first: u64,
    pos: AtomicU64,
    start: Instant,
    last: Mutex<(Instant, String)>,
    bar: Option<indicatif::ProgressBar>,
}

impl Bar {
    pub fn new(mode: ProgressMode, what: &str, unit: &str, len: Option<u64>) -> Bar {
        Bar::from(mode, what, unit, 0, len)
    }

    /// A bar of `len` units whose first `first` were done by an earlier run: the position counts
    /// from `first`, rate and ETA only what this run does.
    pub fn from(mode: ProgressMode, what: &str, unit: &str, first: u64, len: Option<u64>) -> Bar {
        let mode = mode.resolve();
        let bar = (mode == ProgressMode::Auto).then(|| {
            let (b, template) = match len.filter(|&n| n > 0) {
                Some(n) => (
                    indicatif::ProgressBar::new(n),
                    format!("{what} {{bar:30}} {{pos}}/{{len}} {unit} {{mean_rate}} eta {{mean_eta}} {{msg}}"),
                ),
                None => (indicatif::ProgressBar::new_spinner(), format!("{what} {{spinner}} {{pos}} {unit} {{per_sec}} {{msg}}")),
            };
            // Rate and ETA from the mean over the whole run, not indicatif's recent-steps
            // estimate, which jumps after every slow step (a validation, a checkpoint).
            let style = indicatif::ProgressStyle::with_template(&template)
                .expect("template")
                .with_key("mean_rate", move |s: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
                    let _ = write!(w, "{:.2}/s", s.pos().saturating_sub(first) as f64 / s.elapsed().as_secs_f64().max(1e-9));
                })
                .with_key("mean_eta", move |s: &indicatif::ProgressState, w: &mut dyn std::fmt::Write| {
                    let eta = mean_eta(s.elapsed().as_secs_f64(), s.pos().saturating_sub(first), s.len().map(|n| n.saturating_sub(first)));
                    let _ = write!(w, "{}", eta.map_or("-".into(), eta_text));
                });
            b.set_style(style);
            b.set_position(first);
            b.reset_elapsed();
            b
        });
        let now = Instant::now();
        Bar {
            mode,
            what: what.into(),
            unit: unit.into(),
            len,
            first,
            pos: AtomicU64::new(first),
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
        eprintln!("{}", self.status(self.start.elapsed().as_secs_f64(), &last.1));
    }

    /// The status line after `secs` seconds, with the message `msg`.
    fn status(&self, secs: f64, msg: &str) -> String {
        let p = self.pos.load(Ordering::Relaxed);
        let secs = secs.max(1e-9);
        let (here, left) = (p.saturating_sub(self.first), self.len.map(|n| n.saturating_sub(self.first)));
        let rate = here as f64 / secs;
        let of = self.len.map_or(String::new(), |n| format!("/{n}"));
        let eta = mean_eta(secs, here, left).map_or(String::new(), |e| format!(", eta {}", eta_text(e)));
        let msg = if msg.is_empty() { String::new() } else { format!(" {msg}") };
        format!("{}: {p}{of} {} ({rate:.2}/s{eta}){msg}", self.what, self.unit)
    }

    /// Clears the bar (or prints the last line).
    pub fn finish(&self) {
        match &self.bar {
            Some(b) => b.finish_and_clear(),
            None => self.line(true),
        }
    }
}

/// Seconds left when `pos` of `len` units took `elapsed` seconds, at the mean rate so far (so a
/// slow unit moves it by its share of the run, not by its own rate); `None` before the first
/// unit, after the last, or without a length.
pub fn mean_eta(elapsed: f64, pos: u64, len: Option<u64>) -> Option<f64> {
    let n = len?;
    (pos > 0 && n > pos && elapsed > 0.0).then(|| elapsed / pos as f64 * (n - pos) as f64)
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

    #[test]
    fn the_eta_moves_by_a_slow_steps_share_of_the_run_not_by_its_rate() {
        // 1,000 steps of 1 s; step 500 also validates for 60 s.
        let before = mean_eta(499.0, 499, Some(1000)).unwrap();
        let after = mean_eta(560.0, 500, Some(1000)).unwrap();
        assert!((before - 501.0).abs() < 1e-9, "{before}");
        // The mean rate: 560 s for 500 steps, so 560 s for the rest (+12%); a recent-steps
        // estimate would say 60 s a step, 500 minutes.
        assert!((after - 560.0).abs() < 1e-9 && after < before * 1.2, "{after}");
        assert_eq!(mean_eta(10.0, 0, Some(5)), None);
        assert_eq!(mean_eta(10.0, 5, Some(5)), None);
        assert_eq!(mean_eta(10.0, 2, None), None);
    }

    #[test]
    fn a_resumed_run_counts_from_its_first_step_and_rates_only_its_own() {
        // Resumed at step 4 000 of 10 000: 1 000 steps in 500 s.
        let b = Bar::from(ProgressMode::Never, "train", "steps", 4000, Some(10_000));
        b.set_position(5000);
        assert_eq!(b.status(500.0, "loss 0.001"), "train: 5000/10000 steps (2.00/s, eta 41m40s) loss 0.001");
    }
}
