//! Nothing a user does by mistake costs them a file (issue 50): an input is never replaced,
//! `--overwrite` or not; a command deletes only its own temporaries, by their exact name; no
//! write goes through a link planted in an output folder; a folder holds one kind of output.

use crate::common::*;
use std::path::{Path, PathBuf};

fn png(path: &Path, seed: u64) -> Vec<u8> {
    let rgb: Vec<u8> = (0..40 * 30 * 3).map(|i| (pipeline::rng::hash(&[seed, i as u64]) % 256) as u8).collect();
    let mut buf = Vec::new();
    pipeline::io::png::write_rgb8(&mut buf, 40, 30, &rgb).unwrap();
    std::fs::write(path, &buf).unwrap();
    buf
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A process id that is certainly not running: one that has just exited.
fn dead_pid() -> u32 {
    let mut child = std::process::Command::new("true").spawn().unwrap();
    let id = child.id();
    child.wait().unwrap();
    id
}

#[cfg(feature = "train")]
#[test]
fn deblur_never_replaces_its_input_even_with_overwrite() {
    let d = scratch("user_files_deblur_input");
    let f1 = png(&d.join("f1.png"), 1);
    let f2 = png(&d.join("f2.png"), 2);
    // The output folder holds the input: the advice must not be "add --overwrite".
    let o = run(&["deblur", s(&d.join("f2.png")), "-o", s(&d), "--progress", "never"]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.contains("would replace the input") && !e.contains("add --overwrite"), "{e}");
    let f1_path = d.join("f1.png");
    for extra in [&[][..], &["--overwrite"][..]] {
        let mut args = vec!["deblur", s(&f1_path), "-o", s(&d), "--progress", "never"];
        args.extend_from_slice(extra);
        let o = run(&args);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {}", stderr(&o));
    }
    // A glob whose folder is the output: every image is an input.
    let o = run(&["deblur", &format!("{}/*.png", d.display()), "-o", s(&d), "--overwrite", "--progress", "never"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert_eq!(std::fs::read(d.join("f1.png")).unwrap(), f1);
    assert_eq!(std::fs::read(d.join("f2.png")).unwrap(), f2);
    assert_eq!(files(&d), vec!["f1.png", "f2.png"], "nothing else was written");
}

#[cfg(feature = "train")]
#[test]
fn deblur_removes_only_its_own_temporaries_in_a_folder_it_does_not_own() {
    let d = scratch("user_files_deblur_sweep");
    png(&d.join("f1.png"), 3);
    let dir = d.join("dir");
    std::fs::create_dir_all(&dir).unwrap();
    let pid = dead_pid();
    let host = pipeline::io::host();
    let users = [
        dir.join(".notes.txt.999999.tmp"),
        dir.join(format!(".draft~{host}~999998.tmp")),
        dir.join(format!(".draft~{host}~{pid}.tmp")),
        dir.join(".out.tmp-99.png"),
    ];
    for u in &users {
        std::fs::write(u, b"mine").unwrap();
    }
    let ours = dir.join(format!(".out.png~{host}~{pid}.tmp"));
    std::fs::write(&ours, b"left by a killed run").unwrap();
    let o = run(&["deblur", s(&d.join("f1.png")), "-o", s(&dir.join("out.png")), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    for u in &users {
        assert_eq!(std::fs::read(u).unwrap(), b"mine", "{} was touched", u.display());
    }
    assert!(!ours.exists(), "the killed run's temporary of out.png stays");
}

#[cfg(feature = "train")]
#[test]
fn export_never_replaces_its_input_and_replaces_other_files_only_with_overwrite() {
    let d = scratch("user_files_export");
    let m = d.join("m.safetensors");
    let o = run(&["export", concat!(env!("CARGO_MANIFEST_DIR"), "/models/shallow32-coded"), "--format", "burn", "-o", s(&m)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let before = std::fs::read(&m).unwrap();
    for extra in [&[][..], &["--overwrite"][..]] {
        let mut args = vec!["export", s(&m), "--half", "-o", s(&m)];
        args.extend_from_slice(extra);
        let o = run(&args);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {e}");
        assert!(e.contains("would replace the input"), "{e}");
    }
    assert_eq!(std::fs::read(&m).unwrap(), before);
    let other = d.join("other.safetensors");
    std::fs::write(&other, b"keep").unwrap();
    let o = run(&["export", s(&m), "--half", "-o", s(&other)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--overwrite"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&other).unwrap(), b"keep");
    let o = run(&["export", s(&m), "--half", "-o", s(&other), "--overwrite"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(std::fs::read(&other).unwrap().len() < before.len(), "F16 is smaller");
    // A missing parent folder is made, as deblur does.
    let o = run(&["export", s(&m), "-o", s(&d.join("new/dir/m.safetensors"))]);
    assert!(o.status.success(), "{}", stderr(&o));
}

fn tiny_input() -> PathBuf {
    clip("user-files.mp4", &["-i", FIXTURE, "-frames:v", "9", "-vf", "crop=160:128", "-c:v", "libx264", "-preset", "ultrafast"])
}

#[cfg(feature = "train")]
#[test]
fn train_refuses_a_folder_that_holds_other_output_and_an_empty_output_dir() {
    let d = scratch("user_files_train_folder");
    let shards = d.join("shards");
    let o = generate(&shards, &[s(&tiny_input())], &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let before = files(&shards);
    let report = std::fs::read(shards.join("report.json")).unwrap();
    let cfg = tiny_train_config(&shards, &d, 2);
    let into_shards = format!("output.dir={:?}", s(&shards));
    for extra in [&[][..], &["--overwrite"][..]] {
        let mut args = vec!["train", "--config", s(&cfg), "--set", &into_shards, "--progress", "never"];
        args.extend_from_slice(extra);
        let o = run(&args);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{extra:?}: {e}");
        assert!(e.contains("does not write") && e.contains("manifest.json") && !e.contains("a training run ("), "{e}");
    }
    assert_eq!(files(&shards), before, "a lock or a checkpoint was left");
    assert_eq!(std::fs::read(shards.join("report.json")).unwrap(), report);
    // An existing file as the run's folder: a usage error.
    let o = run(&["train", "--config", s(&cfg), "--set", &format!("output.dir={:?}", s(&cfg)), "--progress", "never"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    // An empty output.dir would train into the current folder.
    let cwd = d.join("cwd");
    std::fs::create_dir_all(&cwd).unwrap();
    let o =
        bin().current_dir(&cwd).args(["train", "--config", s(&cfg), "--set", "output.dir=\"\"", "--progress", "never"]).output().unwrap();
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.contains("output.dir"), "{e}");
    assert!(files(&cwd).is_empty(), "{:?}", files(&cwd));
    // An init model that is not there is a usage error too.
    let o = run(&[
        "train",
        "--config",
        s(&cfg),
        "--set",
        "init=\"no/such/model\"",
        "--set",
        &format!("output.dir={:?}", s(&d.join("x"))),
        "--progress",
        "never",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("no/such/model"), "{}", stderr(&o));
    // A killed run's temporary in its own folder goes at the next start, a user's file stays.
    let o = run(&["train", "--config", s(&cfg), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let run_dir = d.join("run");
    let left = run_dir.join(format!(".curves.png~{}~{}.tmp", pipeline::io::host(), dead_pid()));
    std::fs::write(&left, b"half").unwrap();
    let o = run(&["train", "--config", s(&cfg), "--resume", "--set", "optim.steps=2", "--progress", "never"]);
    assert!(!left.exists(), "{}", stderr(&o));
}

#[test]
fn one_folder_holds_one_split_into_tasks() {
    let d = scratch("user_files_split");
    let input = tiny_input();
    let o = generate(&d, &[s(&input)], &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    let before = files(&d);
    let o = bin()
        .args(["generate", s(&input), "-o", s(&d), "--progress", "never", "--shard-index", "0", "--shard-count", "2"])
        .output()
        .unwrap();
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.contains("manifest.json") && e.contains("split"), "{e}");
    let after: Vec<String> = files(&d).into_iter().filter(|f| f != "reports").collect();
    assert!(after.iter().all(|f| before.contains(f)), "{after:?} against {before:?}");
    assert!(!after.iter().any(|f| f.starts_with("manifest-")), "{after:?}");
}

#[test]
fn links_planted_in_the_output_folder_are_not_followed() {
    let d = scratch("user_files_links");
    let (out, outside) = (d.join("out"), d.join("outside"));
    std::fs::create_dir_all(&out).unwrap();
    std::fs::create_dir_all(&outside).unwrap();
    std::os::unix::fs::symlink(outside.join("x"), out.join(".manifest.json.lock")).unwrap();
    std::os::unix::fs::symlink(&outside, out.join("reports")).unwrap();
    let o = generate(&out, &[s(&tiny_input())], &[]);
    let e = stderr(&o);
    assert!(!o.status.success(), "{e}");
    assert!(e.contains("symbolic link"), "{e}");
    assert!(files(&outside).is_empty(), "written outside: {:?}", files(&outside));
    // With the lock's link gone, the reports link still keeps the reports inside.
    std::fs::remove_file(out.join(".manifest.json.lock")).unwrap();
    let o = generate(&out, &[s(&tiny_input())], &[]);
    assert!(!o.status.success() && stderr(&o).contains("reports"), "{}", stderr(&o));
    assert!(files(&outside).is_empty(), "written outside: {:?}", files(&outside));
}

#[cfg(feature = "train")]
#[test]
fn flags_obey_the_rules_of_their_keys_and_devices_are_not_read() {
    let d = scratch("user_files_flags");
    png(&d.join("a.png"), 5);
    for (flag, v) in [("--tile", "0"), ("--tile", "15"), ("--tile", "100000"), ("--overlap", "10000")] {
        let o = run(&["deblur", s(&d.join("a.png")), "-o", s(&d.join("o.png")), flag, v]);
        assert_eq!(o.status.code(), Some(2), "{flag} {v}: {}", stderr(&o));
        assert!(stderr(&o).contains(flag), "{}", stderr(&o));
    }
    assert!(!d.join("o.png").exists());
    // A device is refused before a byte is read (it used to read /dev/zero without end).
    let o = run(&["deblur", s(&d.join("a.png")), "-o", s(&d.join("o.png")), "--model", "/dev/zero"]);
    assert!(!o.status.success() && stderr(&o).contains("not a regular file"), "{}", stderr(&o));
    let o = run(&["train", "--config", "/dev/zero"]);
    assert!(!o.status.success() && stderr(&o).contains("not a regular file"), "{}", stderr(&o));
}

#[test]
fn a_fifo_an_empty_folder_and_a_file_as_the_output_are_named_not_waited_on() {
    let d = scratch("user_files_fifo");
    let clips = d.join("clips");
    std::fs::create_dir_all(&clips).unwrap();
    let fifo = clips.join("x.mp4");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o644) }, 0);
    // The FIFO is not listed (it would block the decoder forever): the folder has nothing to read.
    let o = generate(&d.join("o1"), &[s(&clips)], &[]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("no file to read"), "{}", stderr(&o));
    let o = generate(&d.join("o2"), &[s(&fifo)], &[]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("not a regular file"), "{}", stderr(&o));
    // An empty folder among the inputs is named, not skipped.
    let empty = d.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let o = generate(&d.join("o3"), &[FIXTURE, s(&empty)], &[]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    // A file as the output folder: a usage error (it was exit 1 "File exists").
    let file = d.join("file");
    std::fs::write(&file, b"x").unwrap();
    let o = generate(&file, &[FIXTURE], &[]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert_eq!(std::fs::read(&file).unwrap(), b"x");
}

#[test]
fn a_closed_stderr_or_stdout_ends_nothing_in_a_panic() {
    use std::io::Read;
    let d = scratch("user_files_pipes");
    // stderr closed after its first byte: the run goes on and finishes (no panic, exit 0).
    let mut child = bin()
        .args(["generate", FIXTURE, "-o", s(&d.join("o")), "--progress", "lines", "--set", "sources.video.max_frames=27"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut first = [0u8; 1];
    child.stderr.take().unwrap().read_exact(&mut first).unwrap();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(0));
    assert!(d.join("o/manifest.json").exists());
    // stdout closed after one line (`pipeline psf | head -1`): exit 0.
    let mut child = bin().args(["psf"]).stdout(std::process::Stdio::piped()).stderr(std::process::Stdio::null()).spawn().unwrap();
    let mut out = child.stdout.take().unwrap();
    out.read_exact(&mut first).unwrap();
    drop(out);
    assert_eq!(child.wait().unwrap().code(), Some(0));
}
