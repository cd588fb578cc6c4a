//! Bursts (issue 51): the sharp image at each time of the exposure from one capture. Shards hold
//! `key.gt.00.png` ... with the times in `key.json`; a burst U-Net trains on them through the CLI;
//! `deblur --burst K` writes K frames per capture in time order.

use crate::common::*;
use std::path::{Path, PathBuf};

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Burst shards from the fixture: 2 windows of 9, 8 patches each.
fn burst_shards(name: &str, extra: &[&str]) -> PathBuf {
    let d = scratch(name);
    let mut sets = vec!["sources.video.max_frames=18", "transforms.blur.burst=true"];
    sets.extend_from_slice(extra);
    let o = generate(&d, &[FIXTURE], &sets);
    assert!(o.status.success(), "{}", stderr(&o));
    d
}

#[test]
fn burst_shards_hold_each_sub_frame_in_time_order_with_its_time() {
    let d = burst_shards("burst_shards", &[]);
    let members = shard_members(&d);
    let key = members[0].0.split('.').next().unwrap().to_string();
    let names: Vec<&str> = members.iter().filter(|(n, _)| n.starts_with(&format!("{key}."))).map(|(n, _)| &n[key.len() + 1..]).collect();
    let want: Vec<String> =
        ["lq.png".to_string()].into_iter().chain((0..9).map(|k| format!("gt.{k:02}.png"))).chain(["json".to_string()]).collect();
    assert_eq!(names, want);
    let json: serde_json::Value = serde_json::from_slice(&members.iter().find(|(n, _)| *n == format!("{key}.json")).unwrap().1).unwrap();
    let times: Vec<f64> = serde_json::from_value(json["times"].clone()).unwrap();
    assert_eq!(times.len(), 9);
    assert!(times.iter().enumerate().all(|(k, t)| (t - (k as f64 + 0.5) / 9.0).abs() < 1e-12), "{times:?}");
    // The middle target is the single-frame shards' gt, byte for byte (same seed, same patch).
    let single = scratch("burst_shards_single");
    assert!(generate(&single, &[FIXTURE], &["sources.video.max_frames=18"]).status.success());
    let one = shard_members(&single);
    let gt = &one.iter().find(|(n, _)| *n == format!("{key}.gt.png")).unwrap().1;
    assert_eq!(&members.iter().find(|(n, _)| *n == format!("{key}.gt.04.png")).unwrap().1, gt);
    // The first and last sub-frames differ from the middle: the fixture pans.
    let at = |k: usize| members.iter().find(|(n, _)| *n == format!("{key}.gt.{k:02}.png")).unwrap().1.clone();
    assert!(at(0) != at(4) && at(8) != at(4));
    // The reader takes them in order, with their times.
    let pairs = pipeline::io::wds::read_shard(&d.join(files(&d).into_iter().find(|f| f.ends_with(".tar")).unwrap()), None).unwrap();
    assert_eq!(pairs[0].burst.len(), 9);
    assert_eq!(pairs[0].gt, pairs[0].burst[4]);
    assert!((pairs[0].times[0] - 1.0 / 18.0).abs() < 1e-6);
}

#[test]
fn other_burst_counts_mix_neighbouring_sub_frames() {
    let d = burst_shards("burst_shards_k3", &["transforms.blur.burst=3"]);
    let members = shard_members(&d);
    let gts = members.iter().filter(|(n, _)| n.contains(".gt.")).count();
    let samples = members.iter().filter(|(n, _)| n.ends_with(".json")).count();
    assert_eq!(gts, 3 * samples);
    // K = 3 on N = 9: t = 1/6, 1/2, 5/6 fall on sub-frames 1, 4 and 7 exactly.
    let full = burst_shards("burst_shards_k9", &[]);
    let nine = shard_members(&full);
    let get = |m: &[(String, Vec<u8>)], suffix: &str| m.iter().find(|(n, _)| n.ends_with(suffix)).unwrap().1.clone();
    assert_eq!(get(&members, "_000000_000.gt.00.png"), get(&nine, "_000000_000.gt.01.png"));
    assert_eq!(get(&members, "_000000_000.gt.02.png"), get(&nine, "_000000_000.gt.07.png"));
    let o = generate(&scratch("burst_bad_k"), &[FIXTURE], &["transforms.blur.burst=1"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("burst"), "{}", stderr(&o));
}

#[cfg(feature = "train")]
#[test]
fn a_tiny_burst_model_trained_through_the_cli_deblurs_into_k_frames_in_order() {
    let shards = burst_shards("burst_train_shards", &[]);
    let root = scratch("burst_train");
    let cfg = root.join("train.toml");
    std::fs::write(
        &cfg,
        format!(
            "seed = 1\n[model]\ntype = \"burst_unet\"\nbase = 4\n[data]\nshards = [{:?}]\nval_fraction = 0.0\nshuffle_buffer = 16\n[optim]\nsteps = 4\nbatch = 2\nwarmup_steps = 1\n[validate]\nevery = 4\nmax_samples = 4\n[output]\ndir = {:?}\ncheckpoint_every = 2\n",
            shards.display().to_string(),
            root.join("run").display().to_string()
        ),
    )
    .unwrap();
    let o = run(&["train", "--config", s(&cfg), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(root.join("run/report.json")).unwrap()).unwrap();
    assert_eq!(report["arch"], "burst-unet-4");
    // One capture in: a 40 x 30 image (sizes that are not multiples of 16).
    let img = root.join("cap.png");
    let rgb: Vec<u8> = (0..40 * 30 * 3).map(|i| (pipeline::rng::hash(&[3, i as u64]) % 256) as u8).collect();
    let mut buf = Vec::new();
    pipeline::io::png::write_rgb8(&mut buf, 40, 30, &rgb).unwrap();
    std::fs::write(&img, buf).unwrap();
    let out = root.join("out");
    let model = root.join("run");
    let o = run(&["deblur", s(&img), "-o", s(&out), "--burst", "5", "--model", s(&model), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(files(&out.join("cap")), vec!["00.png", "01.png", "02.png", "03.png", "04.png"]);
    let frames: Vec<Vec<u8>> = (0..5)
        .map(|k| {
            let (w, h, px) = pipeline::io::png::read_rgb8(&std::fs::read(out.join(format!("cap/{k:02}.png"))).unwrap()).unwrap();
            assert_eq!((w, h), (40, 30));
            px
        })
        .collect();
    // In time order: each frame is the model's output at its time, (k + 0.5) / 5.
    let (net, _) = pipeline::model::infer::load_burst(Some(&model)).unwrap();
    for (k, f) in frames.iter().enumerate() {
        let want = pipeline::model::infer::run_frame_burst(&net, &rgb, 40, 30, Default::default(), &[(k as f32 + 0.5) / 5.0]);
        assert_eq!(&want[0], f, "frame {k}");
    }
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(r["burst_times"].as_array().unwrap().len(), 5);
    // A video comes back at K times the frame rate, K frames per capture.
    let video = clip("burst-in.mp4", &["-i", FIXTURE, "-frames:v", "2", "-vf", "crop=48:32", "-c:v", "libx264", "-preset", "ultrafast"]);
    let vout = root.join("v.mp4");
    let o = run(&["deblur", s(&video), "-o", s(&vout), "--burst", "3", "--model", s(&model), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let probe = std::process::Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-count_frames",
            "-show_entries",
            "stream=nb_read_frames,r_frame_rate",
            "-of",
            "csv=p=0",
        ])
        .arg(&vout)
        .output()
        .unwrap();
    assert_eq!(String::from_utf8_lossy(&probe.stdout).trim(), "720/1,6");
    // eval --burst: every window scored at every sub-frame, the baseline beside it.
    let ev = root.join("eval");
    let o = run(&[
        "eval",
        FIXTURE,
        "--burst",
        "--model",
        s(&model),
        "-o",
        s(&ev),
        "--set",
        "eval.windows=[9]",
        "--set",
        "eval.sigmas=[3.0]",
        "--set",
        "eval.windows_per_video=2",
        "--set",
        "eval.crop=64",
        "--progress",
        "never",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(ev.join("burst.json")).unwrap()).unwrap();
    assert_eq!(r["records"].as_array().unwrap().len(), 2);
    let rec = &r["records"][0];
    // The pan moves the content: the capture matches its first and last sub-frames worse than
    // its middle, and the single-frame baseline was run.
    assert!(rec["blurred"]["middle"].as_f64().unwrap() > rec["blurred"]["first"].as_f64().unwrap(), "{rec}");
    assert!(rec["single"]["all"].as_f64().is_some() && rec["right_order"].is_boolean(), "{rec}");
    // The true middle sub-frame is itself at the middle, and differs from the moved ends.
    let m = &rec["sharp_middle"];
    assert_eq!(m["middle"].as_f64(), Some(99.0), "{rec}");
    assert!(m["first"].as_f64().unwrap() < 60.0 && m["last"].as_f64().unwrap() < 60.0, "{rec}");
    assert!(std::fs::read_to_string(ev.join("burst.md")).unwrap().contains("right order"));
    // A single-frame model is refused by name; so is a burst into one image file.
    let o = run(&[
        "deblur",
        s(&img),
        "-o",
        s(&root.join("x")),
        "--burst",
        "5",
        "--model",
        concat!(env!("CARGO_MANIFEST_DIR"), "/models/unet32-coded"),
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("unet32-coded") && stderr(&o).contains("single-frame"), "{}", stderr(&o));
    let o = run(&["deblur", s(&img), "-o", s(&root.join("x.png")), "--burst", "5", "--model", s(&model)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
}
