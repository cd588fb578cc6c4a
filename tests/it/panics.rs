//! A stage that panics (a bug) stops the run like a fatal error: exit 1, the report names the
//! stage, the sink removes what it had not finished. `PIPELINE_FAILPOINT=STAGE:N` is the hook.

use super::common::*;

/// Runs `generate` on the fixture into `out` with a panic at item `n` of `stage`.
fn generate_with_panic(out: &std::path::Path, stage: &str, n: u64) -> std::process::Output {
    bin()
        .args(["generate", FIXTURE, "-o", out.to_str().unwrap(), "--progress", "never"])
        .env("PIPELINE_FAILPOINT", format!("{stage}:{n}"))
        .output()
        .unwrap()
}

#[test]
fn a_panicking_stage_is_named_in_the_report_and_leaves_no_half_written_shard() {
    for stage in ["blur", "shards"] {
        let out = scratch(&format!("panics_{stage}"));
        let o = generate_with_panic(&out, stage, 3);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{stage}: {e}");
        assert!(e.contains(&format!("stage {stage:?}")) || e.contains(stage), "{e}");
        assert!(e.contains("panicked"), "{e}");
        let r: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).expect("a report")).unwrap();
        let why = r["error"].as_str().unwrap_or_default();
        assert!(why.contains(stage) && why.contains("panicked"), "{stage}: {why}");
        // No temporary and no shard the manifest does not list.
        let listed = std::fs::read_to_string(out.join("manifest.json")).unwrap_or_default();
        for f in files(&out) {
            assert!(!f.contains(".tmp") && !f.contains('~'), "{stage}: {f} left behind");
            if f.ends_with(".tar") {
                assert!(listed.contains(&f), "{stage}: {f} is not in the manifest");
            }
        }
        // The same command without the fault finishes the work.
        let o = bin().args(["generate", FIXTURE, "-o", out.to_str().unwrap(), "--progress", "never"]).output().unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
    }
}
