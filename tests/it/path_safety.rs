//! File names read from files in a folder the tool works in (a manifest's shard list, a run
//! folder's `latest.json`) never lead outside that folder: a name with `..`, an absolute path or
//! a symbolic link is refused by name (issue 31), and no file outside is opened, sized or removed.

use crate::common::*;
use std::path::{Path, PathBuf};

/// A file outside the tool's folders, with content a test can check afterwards.
fn victim(dir: &Path, name: &str, content: &[u8]) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, content).unwrap();
    p
}

fn set_json(path: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(path, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
}

#[test]
fn a_manifest_naming_shards_outside_its_folder_is_refused_and_nothing_outside_is_touched() {
    let input = clip("path-safety.mp4", &["-i", FIXTURE, "-frames:v", "9", "-c:v", "libx264", "-preset", "ultrafast"]);
    let root = scratch("path_safety_manifest");
    let out = root.join("out");
    let o = generate(&out, &[input.to_str().unwrap()], &["sources.video.max_frames=9"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let manifest = out.join("manifest.json");
    let good = std::fs::read(&manifest).unwrap();
    let abs = victim(&root, "absolute.txt", b"keep me");
    let rel = victim(&root, "relative.txt", b"keep me too");
    for (name, file) in [("../relative.txt", &rel), (abs.to_str().unwrap(), &abs)] {
        std::fs::write(&manifest, &good).unwrap();
        set_json(&manifest, |m| {
            let sh = &mut m["inputs"][0]["shards"][0];
            sh["name"] = name.into();
            sh["crc32"] = "00000000".into();
        });
        let o = generate(&out, &[input.to_str().unwrap()], &["sources.video.max_frames=9"]);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(1), "{e}");
        assert!(e.contains("manifest.json") && e.contains("inputs[0].shards[0].name") && e.contains(name), "{e}");
        assert!(!e.contains(&std::fs::metadata(file).unwrap().len().to_string()), "the size of the file outside is reported: {e}");
        assert!(file.exists() && std::fs::read(file).unwrap().starts_with(b"keep me"), "{name}: the file outside was touched");
    }
    // A shard replaced by a link to a file outside: not followed (not sized, read or removed),
    // the input redone, the link replaced by a real shard.
    std::fs::write(&manifest, &good).unwrap();
    let shard = out.join(files(&out).into_iter().find(|f| f.ends_with(".tar")).unwrap());
    let want = std::fs::read(&shard).unwrap();
    std::fs::remove_file(&shard).unwrap();
    std::os::unix::fs::symlink(&abs, &shard).unwrap();
    let o = generate(&out, &[input.to_str().unwrap()], &["sources.video.max_frames=9"]);
    let e = stderr(&o);
    assert!(o.status.success(), "{e}");
    assert!(e.contains("symbolic link") && e.contains("redoing"), "{e}");
    assert_eq!(std::fs::read(&abs).unwrap(), b"keep me", "written through the link");
    assert!(!std::fs::symlink_metadata(&shard).unwrap().file_type().is_symlink() && std::fs::read(&shard).unwrap() == want);
}

#[cfg(feature = "train")]
#[test]
fn a_latest_json_naming_files_outside_its_folder_is_refused_by_every_command() {
    let root = scratch("path_safety_latest");
    // A tiny finished run, and a loadable model elsewhere: if any command followed latest.json
    // there, it would succeed.
    let shards = root.join("shards");
    let o = run_pipeline(
        "stills.toml",
        &shards,
        &["sources.stills.clips=4", "sources.stills.size=[48, 48]", "sources.stills.frames=9", "transforms.patches.size=32"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let cfg = tiny_train_config(&shards, &root, 2);
    let cfg = cfg.to_str().unwrap();
    let run_dir = root.join("run");
    let o = run(&["train", "--config", cfg, "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let elsewhere = root.join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    std::fs::copy(run_dir.join("model-0000002.safetensors"), elsewhere.join("m.safetensors")).unwrap();
    std::fs::copy(run_dir.join("optim-0000002.bin"), elsewhere.join("o.bin")).unwrap();
    let latest = run_dir.join("latest.json");
    let good = std::fs::read(&latest).unwrap();
    std::os::unix::fs::symlink(elsewhere.join("m.safetensors"), run_dir.join("linked.safetensors")).unwrap();
    let abs = elsewhere.join("m.safetensors");
    let cases: Vec<(&str, String)> = vec![
        ("model", "../elsewhere/m.safetensors".into()),
        ("model", abs.display().to_string()),
        ("model", "linked.safetensors".into()),
        ("optimizer", "../elsewhere/o.bin".into()),
    ];
    let img = root.join("in.png");
    pipeline::io::png::write_rgb8(&mut std::fs::File::create(&img).unwrap(), 8, 8, &[128; 8 * 8 * 3]).unwrap();
    let (rd, ex) = (run_dir.to_str().unwrap(), root.join("x.safetensors"));
    let init = format!("init={rd:?}");
    let other_dir = format!("output.dir={:?}", root.join("ft").display().to_string());
    let out_png = root.join("o.png").display().to_string();
    let commands: Vec<(&str, Vec<&str>)> = vec![
        ("train --resume", vec!["train", "--config", cfg, "--progress", "never", "--resume", "--set", "optim.steps=3"]),
        (
            "train init",
            vec!["train", "--config", cfg, "--progress", "never", "--set", &init, "--set", "optim.steps=4", "--set", &other_dir],
        ),
        ("deblur", vec!["deblur", img.to_str().unwrap(), "-o", &out_png, "--model", rd]),
        ("export", vec!["export", rd, "-o", ex.to_str().unwrap()]),
    ];
    for (field, name) in &cases {
        std::fs::write(&latest, &good).unwrap();
        set_json(&latest, |l| l[*field] = name.as_str().into());
        for (what, args) in &commands {
            // The optimizer's name is read only by --resume; the others need not look at it, but
            // none may follow it.
            let o = run(args);
            let e = stderr(&o);
            assert!(!o.status.success(), "{what} followed latest.json's {field} = {name}: {e}");
            assert!(e.contains("latest.json") && e.contains(field) && e.contains(name.as_str()), "{what}: {e}");
        }
        assert!(!root.join("o.png").exists() && !ex.exists(), "an output was written from the file outside");
    }
    // The untampered folder still works, so the refusals above were for the names.
    std::fs::write(&latest, &good).unwrap();
    let o = run(&["export", rd, "-o", ex.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
}
