//! Bad input: each a clear one-line error naming the file or key, exit code not 0, no panic,
//! and no shard or temporary file left behind.

use crate::common::*;

fn no_shards(dir: &std::path::Path) {
    let left: Vec<String> = files(dir).into_iter().filter(|f| f.ends_with(".tar") || f.ends_with(".tmp")).collect();
    assert!(left.is_empty(), "left behind: {left:?}");
}

fn fails_naming(o: &std::process::Output, what: &str) {
    let e = stderr(o);
    assert!(!o.status.success(), "should fail: {e}");
    assert!(!e.contains("panicked"), "{e}");
    assert!(e.contains(what), "error should name {what:?}: {e}");
}

#[test]
fn bad_videos_fail_their_input_and_name_the_file() {
    let d = scratch("bad_videos");
    let missing = d.join("missing.mp4");
    let text = d.join("notes.mp4");
    std::fs::write(&text, "this is not a video\n").unwrap();
    let full = std::fs::read(FIXTURE).unwrap();
    let truncated = d.join("truncated.mp4");
    std::fs::write(&truncated, &full[..full.len() / 2]).unwrap();
    let short = clip("short.mp4", &["-i", FIXTURE, "-frames:v", "5", "-c:v", "libx264", "-preset", "ultrafast"]);
    let small = clip("small.mp4", &["-i", FIXTURE, "-frames:v", "18", "-vf", "scale=96:64", "-c:v", "libx264", "-preset", "ultrafast"]);
    for (path, what) in [
        (missing.clone(), "no such file"),
        (text.clone(), "not a readable video"),
        (truncated.clone(), "truncated"),
        (short.clone(), "shorter than one window"),
        (small.clone(), "smaller than a 128x128 patch"),
    ] {
        let out = scratch("bad_videos_out");
        let o = generate(&out, &[path.to_str().unwrap()], &[]);
        fails_naming(&o, path.to_str().unwrap());
        fails_naming(&o, what);
        assert_eq!(o.status.code(), Some(1));
        no_shards(&out);
        let r: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
        assert_eq!(r["inputs_failed"].as_array().unwrap().len(), 1);
    }
    // A bad input next to a good one: the good one is written, the run still exits 1.
    let out = scratch("bad_videos_mixed");
    let o = generate(&out, &[text.to_str().unwrap(), FIXTURE], &["sources.video.max_frames=18"]);
    assert_eq!(o.status.code(), Some(1));
    assert_eq!(files(&out).iter().filter(|f| f.ends_with(".tar")).count(), 1);
}

#[test]
fn a_resolution_change_mid_stream_fails_the_input_naming_the_frame() {
    // MPEG-TS streams concatenate byte by byte: 18 frames at the fixture's size, then 18 at
    // another. Windows would mix sizes, and patch mode picked its rectangles by the first.
    let d = scratch("resolution_change");
    let a = clip("size_a.ts", &["-i", FIXTURE, "-frames:v", "18", "-c:v", "libx264", "-preset", "ultrafast"]);
    let b = clip("size_b.ts", &["-i", FIXTURE, "-frames:v", "18", "-vf", "scale=176:144", "-c:v", "libx264", "-preset", "ultrafast"]);
    let both = d.join("changes.ts");
    std::fs::write(&both, [std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap()].concat()).unwrap();
    for sets in [&[][..], &["transforms.patches.crop_first=false"][..]] {
        let out = scratch("resolution_change_out");
        let o = generate(&out, &[both.to_str().unwrap()], sets);
        fails_naming(&o, both.to_str().unwrap());
        fails_naming(&o, "frame 18 is 176x144");
        fails_naming(&o, "resolution changes mid-stream are not supported");
        assert_eq!(o.status.code(), Some(1), "{sets:?}");
        no_shards(&out);
    }
    // The reader refuses the frame, so deblur (which encodes at the stream's size) does too,
    // and leaves no output behind.
    let sharp = d.join("sharp.mp4");
    let o = run(&["deblur", both.to_str().unwrap(), "-o", sharp.to_str().unwrap(), "--progress", "never"]);
    fails_naming(&o, "frame 18 is 176x144");
    assert!(!sharp.exists() && !files(&d).iter().any(|f| f.contains("sharp")), "{:?}", files(&d));
}

#[test]
fn config_errors_name_the_key_and_write_nothing() {
    let out = scratch("bad_config");
    let o = generate(&out, &[FIXTURE], &["transforms.blur.windw=9"]);
    fails_naming(&o, "windw");
    assert_eq!(o.status.code(), Some(2));
    let o = generate(&out, &[FIXTURE], &["transforms.noise.sigma=300", "transforms.blur.window=0"]);
    fails_naming(&o, "transforms.noise.sigma");
    fails_naming(&o, "transforms.blur.window");
    assert_eq!(o.status.code(), Some(2));
    // Type errors too, all at once, each with its full key and the --set that gave it.
    let o = generate(&out, &[FIXTURE], &["transforms.blur.window=\"x\"", "sinks.shards.max_samples_per_shard=-3"]);
    assert_eq!(o.status.code(), Some(2));
    fails_naming(&o, "transforms.blur.window: invalid type: string \"x\", expected usize (--set transforms.blur.window=\"x\")");
    fails_naming(
        &o,
        "sinks.shards.max_samples_per_shard: invalid value: integer `-3`, expected usize (--set sinks.shards.max_samples_per_shard=-3)",
    );
    assert!(files(&out).is_empty(), "{:?}", files(&out));
}

#[test]
fn an_unwritable_output_folder_is_named() {
    let d = scratch("bad_out");
    let file = d.join("a-file");
    std::fs::write(&file, "x").unwrap();
    let target = file.join("out");
    let o = generate(&target, &[FIXTURE], &[]);
    fails_naming(&o, target.to_str().unwrap());
}

#[test]
fn every_shipped_pipeline_validates() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines");
    let tomls: Vec<String> = files(&dir).into_iter().filter(|f| f.ends_with(".toml")).collect();
    assert!(tomls.len() >= 2, "{tomls:?}");
    for t in tomls {
        let o = run(&["validate", dir.join(&t).to_str().unwrap()]);
        assert!(o.status.success(), "{t}: {}", String::from_utf8_lossy(&o.stdout));
    }
    let d = scratch("validate_bad");
    let bad = d.join("bad.toml");
    std::fs::write(
        &bad,
        pipeline::cli::GENERATE_TOML.replace("inputs = [\"linear\"]", "inputs = [\"linaer\"]").replace("size = 128", "size = 2"),
    )
    .unwrap();
    let o = run(&["validate", bad.to_str().unwrap()]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(2));
    assert!(out.contains("did you mean \"linear\"") && out.contains("transforms.patches.size"), "all errors in one pass: {out}");
}

#[test]
fn ctrl_c_and_sigterm_stop_cleanly_and_leave_no_half_written_shard() {
    // SIGTERM is what Slurm and Kubernetes send: the same clean stop as Ctrl-C. Four inputs so the
    // signal lands mid-run; a shard finished before it may stay, but only if the manifest lists it.
    let src = scratch("ctrl_c_inputs");
    for n in ["a", "b", "c", "d"] {
        std::fs::copy(FIXTURE, src.join(format!("{n}.mp4"))).unwrap();
    }
    for sig in ["-INT", "-TERM"] {
        let out = scratch(&format!("ctrl_c{sig}"));
        let child = bin()
            .args(["generate", src.to_str().unwrap(), "-o", out.to_str().unwrap(), "--progress", "never"])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        std::thread::sleep(std::time::Duration::from_millis(700));
        let st = std::process::Command::new("kill").args([sig, &child.id().to_string()]).status().unwrap();
        assert!(st.success());
        let o = child.wait_with_output().unwrap();
        let e = stderr(&o);
        // Exit 130 (issue 29), a hint how to go on, and a report that says it was interrupted.
        assert_eq!(o.status.code(), Some(130), "{sig}: {e}");
        assert!(e.contains("interrupted") && e.contains("run the same command again"), "{sig}: {e}");
        let r: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).expect("a report")).unwrap();
        assert_eq!(r["interrupted"], true, "{sig}");
        let manifest = std::fs::read_to_string(out.join("manifest.json")).unwrap_or_default();
        let left: Vec<String> =
            files(&out).into_iter().filter(|f| f.ends_with(".tmp") || (f.ends_with(".tar") && !manifest.contains(f.as_str()))).collect();
        assert!(left.is_empty(), "{sig}: left behind: {left:?}");
        assert!(files(&out).iter().filter(|f| f.ends_with(".tar")).count() < 4, "{sig}: the run was not interrupted mid-way");
    }
}

#[test]
fn doing_nothing_is_a_usage_error_and_writes_nothing() {
    let d = scratch("nothing_to_do");
    let empty = d.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    for args in [vec!["generate", "-o"], vec!["generate", empty.to_str().unwrap(), "-o"], vec!["deblur", empty.to_str().unwrap(), "-o"]] {
        let out = d.join("out");
        let mut a = args.clone();
        a.push(out.to_str().unwrap());
        let o = run(&a);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", stderr(&o));
        let e = stderr(&o);
        assert!(e.contains("no input") || e.contains("no image found") || e.contains("no file to read in it"), "{args:?}: {e}");
        assert!(!out.exists(), "{args:?} wrote {}", out.display());
    }
}

#[cfg(feature = "train")]
#[test]
fn a_trainer_sink_names_the_keys_written_under_it() {
    let cfg = concat!(env!("CARGO_MANIFEST_DIR"), "/pipelines/train-stream.toml");
    let o = run(&["validate", cfg, "--set", "sinks.train.val_fraction=5", "--set", "sinks.train.checkpoint_every=0"]);
    assert_eq!(o.status.code(), Some(2));
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(out.contains("sinks.train.val_fraction") && out.contains("sinks.train.checkpoint_every"), "{out}");
    assert!(!out.contains("data.val_fraction") && !out.contains("output.checkpoint_every"), "{out}");
}

/// Every command's `--help` teaches by example (issue 31), and the top level lists exit codes.
#[test]
fn every_command_help_has_examples() {
    let mut cmds = vec!["psf", "generate", "run", "validate", "bench"];
    if cfg!(feature = "train") {
        cmds.extend(["train", "deblur", "eval", "figure", "export"]);
    }
    for c in cmds {
        let o = run(&[c, "--help"]);
        let out = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success() && (out.contains("Examples:") || out.contains("Examples\n")), "{c} --help:\n{out}");
    }
    let o = run(&["--help"]);
    assert!(String::from_utf8_lossy(&o.stdout).contains("130 interrupted"));
}
