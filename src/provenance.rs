//! Where a result came from: version, commit, machine, time and command line, recorded in every
//! report so that a file found later can be traced to the run that made it.

use serde::Serialize;
use std::time::{SystemTime, UNIX_EPOCH};

#[derive(Debug, Clone, Serialize)]
pub struct Provenance {
    pub version: &'static str,
    /// Short git commit of the build, if it was built from a checkout.
    pub git_commit: Option<&'static str>,
    pub command: String,
    pub host: String,
    pub pid: u32,
    /// UTC, ISO 8601.
    pub started: String,
    /// SIMD the CPU offers (the fast paths pick kernels by it; results are bit-identical only on
    /// one kind of CPU).
    pub cpu_features: Vec<&'static str>,
    pub threads: usize,
}

impl Provenance {
    /// Now, for this process.
    /// The provenance of a command that started `ago` before now.
    pub fn started_ago(ago: std::time::Duration) -> Provenance {
        Provenance { started: utc(SystemTime::now().checked_sub(ago).unwrap_or(SystemTime::now())), ..Provenance::now() }
    }

    pub fn now() -> Provenance {
        let commit = env!("PIPELINE_GIT_COMMIT");
        Provenance {
            version: env!("CARGO_PKG_VERSION"),
            git_commit: (!commit.is_empty()).then_some(commit),
            command: std::env::args_os().map(|a| a.to_string_lossy().into_owned()).collect::<Vec<_>>().join(" "),
            host: crate::io::host().to_string(),
            pid: std::process::id(),
            started: utc(SystemTime::now()),
            cpu_features: cpu_features(),
            threads: rayon::current_num_threads(),
        }
    }

    /// `{stem}-{YYYYMMDDTHHMMSSZ}-{pid}.json`: a report name no other run takes.
    pub fn file_name(&self, stem: &str) -> String {
        let compact: String = self.started.chars().filter(|c| c.is_ascii_alphanumeric()).collect();
        format!("{stem}-{compact}-{}.json", self.pid)
    }
}

/// `YYYY-MM-DDTHH:MM:SSZ` of a time (proleptic Gregorian, UTC).
pub fn utc(t: SystemTime) -> String {
    let secs = t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z", rem / 3600, rem % 3600 / 60, rem % 60)
}

fn cpu_features() -> Vec<&'static str> {
    let mut v = Vec::new();
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            v.push("avx2");
        }
        if std::arch::is_x86_feature_detected!("fma") {
            v.push("fma");
        }
        if std::arch::is_x86_feature_detected!("avx512f") {
            v.push("avx512f");
        }
    }
    #[cfg(target_arch = "aarch64")]
    v.push("neon");
    v
}

/// This process's peak resident memory in KiB (Linux `VmHWM`: since the start, or since the
/// last reset through `/proc/self/clear_refs`); None elsewhere.
pub fn peak_rss_kb() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    s.lines().find(|l| l.starts_with("VmHWM:"))?.split_whitespace().nth(1)?.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn utc_dates_match_known_instants() {
        assert_eq!(utc(UNIX_EPOCH), "1970-01-01T00:00:00Z");
        // `date -u -d @951782400`: the leap day of 2000; `@1796083199`: the last second of 2026-11-30.
        assert_eq!(utc(UNIX_EPOCH + Duration::from_secs(951_782_400)), "2000-02-29T00:00:00Z");
        assert_eq!(utc(UNIX_EPOCH + Duration::from_secs(1_796_083_199)), "2026-11-30T23:59:59Z");
    }
}
