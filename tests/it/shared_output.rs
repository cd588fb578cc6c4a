//! Output folders shared by runs and tasks, damaged or interrupted runs, and failing inputs
//! (issue 12): nothing already written is lost, nothing half-written stays, exit codes mean
//! something.

use crate::common::*;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

const SHORT: &str = "sources.video.max_frames=18";

/// Four short inputs of their own (distinct content), made once.
fn four_inputs() -> Vec<PathBuf> {
    ["a", "b", "c", "d"]
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let ss = format!("{}", k as f64 * 0.3);
            clip(&format!("shared-{n}.mp4"), &["-ss", &ss, "-i", FIXTURE, "-frames:v", "18", "-c:v", "libx264", "-preset", "ultrafast"])
        })
        .collect()
}

fn strs(p: &[PathBuf]) -> Vec<&str> {
    p.iter().map(|p| p.to_str().unwrap()).collect()
}

fn tars(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    files(dir).into_iter().filter(|f| f.ends_with(".tar")).map(|f| (f.clone(), std::fs::read(dir.join(&f)).unwrap())).collect()
}

/// Shard names the manifest lists.
fn listed(dir: &Path) -> BTreeSet<String> {
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("manifest.json")).unwrap()).unwrap();
    m["inputs"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|i| i["shards"].as_array().unwrap().iter().map(|s| s["name"].as_str().unwrap().to_string()))
        .collect()
}

/// Temporary files anywhere below `dir`.
fn temporaries(dir: &Path) -> Vec<String> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let n = e.file_name().to_string_lossy().into_owned();
        if e.file_type().unwrap().is_dir() {
            v.extend(temporaries(&e.path()));
        } else if n.contains(".tmp") {
            v.push(n);
        }
    }
    v
}

fn ok(o: &std::process::Output) {
    assert!(o.status.success(), "exit {:?}: {}", o.status.code(), stderr(o));
}

#[test]
fn runs_with_other_inputs_one_after_another_keep_each_others_shards() {
    let ins = four_inputs();
    let all = scratch("shared_all");
    ok(&generate(&all, &strs(&ins), &[SHORT]));
    let seq = scratch("shared_seq");
    ok(&generate(&seq, &strs(&ins[..2]), &[SHORT]));
    ok(&generate(&seq, &strs(&ins[2..]), &[SHORT]));
    let (want, got) = (tars(&all), tars(&seq));
    assert_eq!(want.len(), 4, "{:?}", want.keys());
    assert!(want == got, "two runs into one folder must hold what one run over all inputs writes");
    assert_eq!(listed(&seq), got.keys().cloned().collect::<BTreeSet<_>>(), "the manifest lists exactly what is on disk");
    // One report per run, kept; report.json is the latest and records the folder it wrote.
    let reports = files(&seq.join("reports"));
    assert_eq!(reports.len(), 2, "{reports:?}");
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(seq.join("report.json")).unwrap()).unwrap();
    assert_eq!(r["out_dir"], seq.display().to_string());
    assert_eq!(r["config"]["sinks"]["shards"]["dir"], seq.display().to_string(), "the recorded config shows -o");
    assert_eq!(r["samples"], 2 * 2 * 8, "this run's samples");
    assert_eq!(r["sink"]["manifest_totals"]["samples"], 4 * 2 * 8, "the folder's samples");
    assert!(r["version"].is_string() && r["host"].is_string() && r["started"].as_str().unwrap().ends_with('Z'));
}

#[test]
fn runs_at_the_same_time_into_one_folder_keep_both() {
    let ins = four_inputs();
    let all = scratch("shared_conc_all");
    ok(&generate(&all, &strs(&ins), &[SHORT]));
    let d = scratch("shared_conc");
    let spawn = |part: &[PathBuf]| {
        let mut c = bin();
        c.arg("generate").args(strs(part)).arg("-o").arg(&d).args(["--progress", "never", "--set", SHORT]);
        c.stderr(std::process::Stdio::piped()).spawn().unwrap()
    };
    // Interleaved inputs, so both runs commit to the manifest while the other is running.
    let (a, b) = (spawn(&[ins[0].clone(), ins[2].clone()]), spawn(&[ins[1].clone(), ins[3].clone()]));
    ok(&a.wait_with_output().unwrap());
    ok(&b.wait_with_output().unwrap());
    let got = tars(&d);
    assert!(tars(&all) == got);
    assert_eq!(listed(&d), got.keys().cloned().collect::<BTreeSet<_>>());
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["samples"], 4 * 2 * 8);
}

#[test]
fn a_deleted_truncated_or_altered_shard_is_redone_on_rerun() {
    let ins = four_inputs();
    let d = scratch("shared_damaged");
    ok(&generate(&d, &strs(&ins), &[SHORT]));
    let want = tars(&d);
    let names: Vec<&String> = want.keys().collect();
    std::fs::remove_file(d.join(names[0])).unwrap();
    let f = std::fs::OpenOptions::new().write(true).open(d.join(names[1])).unwrap();
    f.set_len(want[names[1]].len() as u64 / 2).unwrap();
    let mut altered = want[names[2]].clone();
    altered[700] ^= 1;
    std::fs::write(d.join(names[2]), altered).unwrap();
    let untouched = std::fs::metadata(d.join(names[3])).unwrap().modified().unwrap();
    let o = generate(&d, &strs(&ins), &[SHORT]);
    ok(&o);
    let e = stderr(&o);
    assert_eq!(e.matches("redoing").count(), 3, "{e}");
    assert!(e.contains("CRC-32") && e.contains("bytes"), "{e}");
    assert!(tars(&d) == want, "redone shards equal the originals");
    assert_eq!(std::fs::metadata(d.join(names[3])).unwrap().modified().unwrap(), untouched, "a whole shard is not rewritten");
    // Other settings for the same inputs: redone, not skipped.
    let o = generate(&d, &strs(&ins[..1]), &[SHORT, "seed=99"]);
    ok(&o);
    assert!(stderr(&o).contains("other settings"), "{}", stderr(&o));
}

#[test]
fn sigterm_and_sigkill_at_any_point_then_a_rerun_give_the_uninterrupted_bytes() {
    let ins = four_inputs();
    let t0 = std::time::Instant::now();
    let want = {
        let d = scratch("shared_kill_ref");
        ok(&generate(&d, &strs(&ins), &[SHORT]));
        tars(&d)
    };
    // Signals at fractions of an uninterrupted run's time (which varies with the machine's load),
    // both kinds.
    let whole = t0.elapsed().as_millis() as u64;
    let mut interrupted = 0;
    for (k, (sig, f)) in [("-TERM", 0.15), ("-KILL", 0.3), ("-KILL", 0.5), ("-TERM", 0.7), ("-KILL", 0.85)].into_iter().enumerate() {
        let ms = (whole as f64 * f) as u64;
        let d = scratch(&format!("shared_kill_{k}"));
        let child = bin()
            .arg("generate")
            .args(strs(&ins))
            .arg("-o")
            .arg(&d)
            .args(["--progress", "never", "--set", SHORT])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(ms));
        std::process::Command::new("kill").args([sig, &child.id().to_string()]).status().unwrap();
        let o = child.wait_with_output().unwrap();
        if o.status.success() {
            continue; // finished before the signal: nothing to check
        }
        interrupted += 1;
        let o = generate(&d, &strs(&ins), &[SHORT]);
        ok(&o);
        assert!(temporaries(&d).is_empty(), "{sig} at {ms} ms: left {:?}", temporaries(&d));
        assert!(tars(&d) == want, "{sig} at {ms} ms: shards differ from an uninterrupted run");
        assert_eq!(listed(&d), want.keys().cloned().collect::<BTreeSet<_>>());
    }
    assert!(interrupted >= 3, "only {interrupted} of 5 runs were stopped mid-way");
}

#[test]
fn a_file_name_ffmpeg_cannot_take_is_one_failed_input() {
    use std::os::unix::ffi::OsStrExt;
    let d = scratch("shared_non_utf8");
    let src = d.join("in");
    std::fs::create_dir_all(&src).unwrap();
    std::fs::copy(FIXTURE, src.join("good.mp4")).unwrap();
    std::fs::copy(FIXTURE, src.join(std::ffi::OsStr::from_bytes(b"bad\xff.mp4"))).unwrap();
    let out = d.join("out");
    let o = generate(&out, &[src.to_str().unwrap()], &[SHORT]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("UTF-8"), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(r["inputs_failed"].as_array().unwrap().len(), 1);
    assert_eq!(r["inputs_done"], 1);
    assert_eq!(listed(&out).len(), 1);
}

#[test]
fn a_retried_single_array_element_is_told_to_pass_the_task_count() {
    let d = scratch("shared_slurm");
    let o = bin()
        .args(["generate", FIXTURE, "-o", d.join("out").to_str().unwrap(), "--progress", "never"])
        .env("SLURM_ARRAY_TASK_ID", "17")
        .env("SLURM_ARRAY_TASK_COUNT", "1")
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("SLURM_ARRAY_TASK_ID") && e.contains("SLURM_ARRAY_TASK_COUNT") && e.contains("--shard-count"), "{e}");
    assert!(!d.join("out").exists());
}

#[cfg(feature = "train")]
#[test]
fn a_folder_with_one_corrupt_image_deblurs_the_rest_and_exits_1() {
    let d = scratch("shared_deblur_corrupt");
    let (src, dst) = (d.join("in"), d.join("out"));
    std::fs::create_dir_all(&src).unwrap();
    for (name, seed) in [("a.png", 1u64), ("c.png", 3)] {
        let rgb: Vec<u8> = (0..40 * 30 * 3).map(|i| (pipeline::rng::hash(&[seed, i as u64]) % 256) as u8).collect();
        let mut buf = Vec::new();
        pipeline::io::png::write_rgb8(&mut buf, 40, 30, &rgb).unwrap();
        std::fs::write(src.join(name), buf).unwrap();
    }
    std::fs::write(src.join("b.png"), b"\x89PNG\r\n\x1a\nnot really").unwrap();
    let o = run(&["deblur", src.to_str().unwrap(), "-o", dst.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("b.png"), "{}", stderr(&o));
    assert!(dst.join("a.png").exists() && dst.join("c.png").exists() && !dst.join("b.png").exists());
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(dst.join("report.json")).unwrap()).unwrap();
    assert_eq!(r["frames"], 2);
    assert!(r["failed"][0]["path"].as_str().unwrap().ends_with("b.png"));
    assert!(temporaries(&dst).is_empty());
}

#[cfg(feature = "train")]
#[test]
fn a_model_with_nan_weights_is_refused() {
    let d = scratch("shared_nan_model");
    let mut bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/models/shallow32-coded/model.safetensors")).unwrap();
    // safetensors: 8-byte header length, JSON header, then the tensors' data; poison the first
    // value of a convolution's weights.
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let (_, t) = header.as_object().unwrap().iter().find(|(k, v)| k.ends_with("weight") && v["dtype"] == "F32").expect("a weight");
    let start = 8 + n + t["data_offsets"][0].as_u64().unwrap() as usize;
    bytes[start..start + 4].copy_from_slice(&f32::NAN.to_le_bytes());
    let model = d.join("nan.safetensors");
    std::fs::write(&model, bytes).unwrap();
    let img = d.join("in");
    std::fs::create_dir_all(&img).unwrap();
    let mut buf = Vec::new();
    pipeline::io::png::write_rgb8(&mut buf, 8, 8, &[128; 8 * 8 * 3]).unwrap();
    std::fs::write(img.join("x.png"), buf).unwrap();
    let o = run(&["deblur", img.to_str().unwrap(), "-o", d.join("out").to_str().unwrap(), "--model", model.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("nan.safetensors") && stderr(&o).contains("finite"), "{}", stderr(&o));
    assert!(!d.join("out").join("x.png").exists());
}

#[test]
fn stale_temporaries_of_a_killed_run_are_removed_at_the_next_start() {
    let d = scratch("shared_stale");
    // A process that has exited stands for the killed run.
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let dead = child.id();
    child.wait().unwrap();
    let host = pipeline::io::host();
    let stale = [format!(".train-x_0123456789ab-0000.tar~{host}~{dead}.tmp"), format!(".manifest.json~{host}~{dead}.tmp")];
    for s in &stale {
        std::fs::write(d.join(s), b"half").unwrap();
    }
    // Names of another form are not the tool's (an older version's, or a user's): kept.
    let foreign = d.join(format!(".train-00000-0000.tar.{dead}.tmp"));
    std::fs::write(&foreign, b"not ours").unwrap();
    let o = generate(&d, &[FIXTURE], &[SHORT]);
    ok(&o);
    assert_eq!(temporaries(&d), vec![foreign.file_name().unwrap().to_string_lossy().into_owned()]);
    assert!(stderr(&o).contains("left by a run that was killed"), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("report.json")).unwrap()).unwrap();
    assert_eq!(r["stale_removed"].as_array().unwrap().len(), 2);
}

/// Starts `pipeline` with `args`, sends SIGTERM after `ms`, returns its output.
#[cfg(feature = "train")]
fn terminated(args: &[&str], ms: u64) -> std::process::Output {
    let child = bin().args(args).stderr(std::process::Stdio::piped()).spawn().unwrap();
    std::thread::sleep(std::time::Duration::from_millis(ms));
    std::process::Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap();
    child.wait_with_output().unwrap()
}

#[cfg(feature = "train")]
#[test]
fn sigterm_stops_deblur_without_leaving_a_partial_video() {
    let d = scratch("shared_deblur_term");
    let out = d.join("sharp.mp4");
    // The fixture takes many seconds to deblur; the signal lands early.
    let o = terminated(&["deblur", FIXTURE, "-o", out.to_str().unwrap(), "--progress", "never"], 1500);
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    assert!(stderr(&o).contains("interrupted") && stderr(&o).contains("run the same command again"), "{}", stderr(&o));
    assert!(!out.exists() && temporaries(&d).is_empty(), "{:?}", files(&d));
}

#[cfg(feature = "train")]
#[test]
fn sigterm_stops_training_with_a_checkpoint_to_resume_from() {
    let d = scratch("shared_train_term");
    let shards = d.join("shards");
    ok(&generate(&shards, &[FIXTURE], &[SHORT]));
    let run = d.join("run");
    let cfg = concat!(env!("CARGO_MANIFEST_DIR"), "/pipelines/train-shallow.toml");
    let sets = [
        format!("data.shards=[\"{}\"]", shards.display()),
        format!("output.dir=\"{}\"", run.display()),
        "optim.steps=1000000".into(),
        "output.checkpoint_every=1000000".into(),
        "validate.every=1000000".into(),
        "data.val_fraction=0.0".into(),
    ];
    let mut args = vec!["train", "--config", cfg, "--progress", "never"];
    for s in &sets {
        args.extend(["--set", s.as_str()]);
    }
    let o = terminated(&args, 3000);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(130), "{e}");
    assert!(e.contains("--resume"), "{e}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["interrupted"], true);
    let step: usize = e.split("interrupted: after step ").nth(1).and_then(|r| r.split(':').next()).and_then(|n| n.parse().ok()).expect(&e);
    let latest: serde_json::Value = serde_json::from_slice(&std::fs::read(run.join("latest.json")).unwrap()).unwrap();
    assert_eq!(latest["step"], step);
    assert!(run.join(latest["model"].as_str().unwrap()).exists() && temporaries(&run).is_empty());
}

#[test]
fn a_manifest_that_cannot_be_written_leaves_no_unlisted_shard_in_the_folder() {
    // The manifest's lock is a folder, so the manifest update fails the way a full disk makes it
    // fail: after the input's shards are finished. Those shards must not stay in the folder
    // unlisted, where the trainer's `*.tar` glob would take them.
    let d = scratch("shared_manifest_fails");
    std::fs::create_dir_all(d.join(".manifest.json.lock")).unwrap();
    let o = generate(&d, &[FIXTURE], &[SHORT]);
    assert!(!o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains(".manifest.json.lock"), "{}", stderr(&o));
    let tars: Vec<String> = files(&d).into_iter().filter(|n| n.ends_with(".tar")).collect();
    assert!(tars.is_empty(), "unlisted shards left: {tars:?}");
    assert!(temporaries(&d).is_empty(), "{:?}", temporaries(&d));
    // The run that failed still leaves its report, saying why.
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("report.json")).unwrap()).unwrap();
    assert!(r["error"].as_str().unwrap().contains(".manifest.json.lock"), "{}", r["error"]);
    assert_eq!(r["inputs_done"], 0);
    // Once the manifest can be written, the same command makes and lists them.
    std::fs::remove_dir(d.join(".manifest.json.lock")).unwrap();
    ok(&generate(&d, &[FIXTURE], &[SHORT]));
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("manifest.json")).unwrap()).unwrap();
    let listed = m["inputs"][0]["shards"].as_array().unwrap().len();
    assert!(listed > 0 && files(&d).iter().filter(|n| n.ends_with(".tar")).count() == listed);
}

#[test]
fn a_run_refused_over_a_damaged_manifest_leaves_a_report_saying_why() {
    let d = scratch("shared_manifest_refused");
    std::fs::write(d.join("manifest.json"), b"{ not json").unwrap();
    let o = generate(&d, &[FIXTURE], &[SHORT]);
    assert!(!o.status.success() && stderr(&o).contains("manifest.json"), "{}", stderr(&o));
    assert_eq!(std::fs::read(d.join("manifest.json")).unwrap(), b"{ not json", "the damaged manifest was changed");
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("report.json")).unwrap()).unwrap();
    assert!(r["error"].as_str().unwrap().contains("not a pipeline manifest"), "{}", r["error"]);
    assert_eq!((r["inputs_total"].as_u64(), r["inputs_done"].as_u64()), (Some(1), Some(0)));
}
