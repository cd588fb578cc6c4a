//! `pipeline generate` on real decoded video: determinism, WebDataset layout, crop-first
//! equivalence, identity through the conventional camera, 10-bit input, sharded runs.

use crate::common::*;
use std::collections::BTreeMap;

const SHORT: &str = "sources.video.max_frames=27";

fn ok(o: &std::process::Output) {
    assert!(o.status.success(), "exit {:?}: {}", o.status.code(), stderr(o));
}

#[test]
fn same_seed_gives_identical_shards_and_another_seed_other_noise() {
    let (a, b, c) = (scratch("gen_seed_a"), scratch("gen_seed_b"), scratch("gen_seed_c"));
    ok(&generate(&a, &[FIXTURE], &[SHORT, "seed=5"]));
    ok(&generate(&b, &[FIXTURE], &[SHORT, "seed=5"]));
    ok(&generate(&c, &[FIXTURE], &[SHORT, "seed=6", "transforms.patches.placement=\"grid\""]));
    let tars: Vec<String> = files(&a).into_iter().filter(|f| f.ends_with(".tar")).collect();
    assert!(!tars.is_empty());
    for t in &tars {
        assert!(std::fs::read(a.join(t)).unwrap() == std::fs::read(b.join(t)).unwrap(), "{t} differs between runs");
    }
    assert!(std::fs::read(a.join("manifest.json")).unwrap() == std::fs::read(b.join("manifest.json")).unwrap());
    // Seed 6 on a grid: the same patch positions as each other; compare with seed 7 on a grid.
    let d = scratch("gen_seed_d");
    ok(&generate(&d, &[FIXTURE], &[SHORT, "seed=7", "transforms.patches.placement=\"grid\""]));
    let (mc, md) = (shard_members(&c), shard_members(&d));
    assert_eq!(mc.len(), md.len());
    let mut lq_differs = false;
    for ((nc, bc), (nd, bd)) in mc.iter().zip(&md) {
        assert_eq!(nc, nd);
        if nc.ends_with(".gt.png") {
            assert!(bc == bd, "targets do not depend on the seed: {nc}");
        }
        if nc.ends_with(".lq.png") && bc != bd {
            lq_differs = true;
        }
    }
    assert!(lq_differs, "another seed must give other noise");
}

#[test]
fn shards_read_as_webdataset_samples_of_128px_pngs() {
    let d = scratch("gen_wds");
    ok(&generate(&d, &[FIXTURE], &[SHORT, "sinks.shards.max_samples_per_shard=10"]));
    let tars: Vec<String> = files(&d).into_iter().filter(|f| f.ends_with(".tar")).collect();
    assert_eq!(tars.len(), 3, "24 samples rotated at 10 per shard: {tars:?}");
    assert!(tars.iter().all(|t| t.starts_with("train-mandelbrot-pan-240fps_")), "{tars:?}");
    // WebDataset grouping: members sharing the part of the name before the first dot are one
    // sample and stand next to each other.
    let mut samples: Vec<(String, Vec<String>)> = Vec::new();
    for (name, bytes) in shard_members(&d) {
        let (key, ext) = name.split_once('.').unwrap();
        match samples.last_mut() {
            Some((k, exts)) if k == key => exts.push(ext.to_string()),
            _ => {
                assert!(!samples.iter().any(|(k, _)| k == key), "key {key} is split");
                samples.push((key.to_string(), vec![ext.to_string()]));
            }
        }
        if ext.ends_with("png") {
            let (w, h, _) = pipeline::io::png::read_rgb8(&bytes).unwrap();
            assert_eq!((w, h), (128, 128), "{name}");
        }
        if ext == "json" {
            let v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
            assert_eq!(v["camera"], "phase_coded");
            assert_eq!(v["psi"].as_array().unwrap().len(), 9);
            assert!(v["sigma"].as_f64().unwrap() <= 9.0);
            assert!(v["patch"]["x"].as_u64().unwrap() <= 320 - 128);
        }
    }
    assert_eq!(samples.len(), 24);
    for (_, exts) in &samples {
        assert_eq!(exts, &["lq.png", "gt.png", "json"]);
    }
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["samples"], 24);
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("report.json")).unwrap()).unwrap();
    assert_eq!((r["frames"].as_u64(), r["windows"].as_u64()), (Some(27), Some(3)));
    assert_eq!(r["inputs"][0]["fps"], 240.0);
    assert_eq!(r["inputs"][0]["frames_announced"], 360);
    assert_eq!(r["inputs"][0]["frames_read"], 27);
    assert_eq!(r["inputs"][0]["codec"], "h264");
    assert!(r["stages"].as_array().unwrap().len() == 6);
}

/// Pixels of the PNG members of two runs: (values compared, values differing, largest difference).
fn png_diff(a: &[(String, Vec<u8>)], b: &[(String, Vec<u8>)]) -> (usize, usize, u8) {
    assert_eq!(a.len(), b.len());
    let (mut n, mut diff, mut worst) = (0, 0, 0u8);
    for ((na, ba), (nb, bb)) in a.iter().zip(b) {
        assert_eq!(na, nb);
        if na.ends_with(".png") {
            let (_, _, pa) = pipeline::io::png::read_rgb8(ba).unwrap();
            let (_, _, pb) = pipeline::io::png::read_rgb8(bb).unwrap();
            for (x, y) in pa.iter().zip(&pb) {
                n += 1;
                if x != y {
                    diff += 1;
                    worst = worst.max(x.abs_diff(*y));
                }
            }
        } else {
            assert!(ba == bb, "{na}");
        }
    }
    (n, diff, worst)
}

#[test]
fn crop_then_blur_matches_blur_then_crop_to_one_level() {
    // The float images agree to 2e-5 (unit test); after 8-bit rounding a value that sits on a
    // rounding boundary can land one level apart, since the FFT sizes differ.
    let (a, b) = (scratch("gen_crop_a"), scratch("gen_crop_b"));
    ok(&generate(&a, &[FIXTURE], &[SHORT, "transforms.patches.crop_first=true", "transforms.noise.sigma=0.0"]));
    ok(&generate(&b, &[FIXTURE], &[SHORT, "transforms.patches.crop_first=false", "transforms.noise.sigma=0.0"]));
    let (n, diff, worst) = png_diff(&shard_members(&a), &shard_members(&b));
    assert!(worst <= 1 && (diff as f64) < 0.01 * n as f64, "{diff} of {n} values differ, by up to {worst}");
    // With noise too: the noise is keyed on absolute pixel positions.
    let (c, d) = (scratch("gen_crop_c"), scratch("gen_crop_d"));
    ok(&generate(&c, &[FIXTURE], &[SHORT, "transforms.patches.crop_first=true", "transforms.noise.sigma=5.0"]));
    ok(&generate(&d, &[FIXTURE], &[SHORT, "transforms.patches.crop_first=false", "transforms.noise.sigma=5.0"]));
    let (n, diff, worst) = png_diff(&shard_members(&c), &shard_members(&d));
    assert!(worst <= 1 && (diff as f64) < 0.01 * n as f64, "with noise: {diff} of {n} values differ, by up to {worst}");
}

#[test]
fn identical_frames_through_the_conventional_camera_give_the_frame_back() {
    let still = clip("still.png", &["-f", "lavfi", "-i", "mandelbrot=size=160x128:start_scale=1.5:end_scale=1.5", "-frames:v", "1"]);
    let video =
        clip("still-ffv1.mkv", &["-loop", "1", "-i", still.to_str().unwrap(), "-frames:v", "9", "-c:v", "ffv1", "-pix_fmt", "bgr0"]);
    let d = scratch("gen_identity");
    ok(&generate(
        &d,
        &[video.to_str().unwrap()],
        &[
            "transforms.blur.camera.type=\"conventional\"",
            "transforms.noise.sigma=0.0",
            "transforms.patches.size=64",
            "transforms.patches.per_window=3",
        ],
    ));
    let (sw, _, still_px) = pipeline::io::png::read_rgb8(&std::fs::read(&still).unwrap()).unwrap();
    let m = shard_members(&d);
    assert_eq!(m.len(), 9);
    for s in m.chunks(3) {
        let (_, _, lq) = pipeline::io::png::read_rgb8(&s[0].1).unwrap();
        let (_, _, gt) = pipeline::io::png::read_rgb8(&s[1].1).unwrap();
        assert!(lq == gt, "{}: the average of identical frames is the frame", s[0].0);
        // And it is the still itself, cut at the patch position.
        let meta: serde_json::Value = serde_json::from_slice(&s[2].1).unwrap();
        let (x, y) = (meta["patch"]["x"].as_u64().unwrap() as usize, meta["patch"]["y"].as_u64().unwrap() as usize);
        let want: Vec<u8> = (0..64).flat_map(|r| still_px[((y + r) * sw + x) * 3..((y + r) * sw + x + 64) * 3].to_vec()).collect();
        assert!(gt == want, "{}: target differs from the decoded still", s[1].0);
    }
}

#[test]
fn ten_bit_input_is_decoded_with_its_depth() {
    let v = clip(
        "ten-bit.mkv",
        &[
            "-f",
            "lavfi",
            "-i",
            "mandelbrot=size=160x144:rate=240:start_scale=1.5:end_scale=1.5,crop=144:128:x='8*t*10':y=4",
            "-frames:v",
            "18",
            "-c:v",
            "ffv1",
            "-pix_fmt",
            "yuv444p10le",
        ],
    );
    let d = scratch("gen_10bit");
    ok(&generate(&d, &[v.to_str().unwrap()], &["transforms.patches.per_window=2"]));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("report.json")).unwrap()).unwrap();
    assert_eq!(r["samples"], 4);
    let m = shard_members(&d);
    let (w, h, px) = pipeline::io::png::read_rgb8(&m[1].1).unwrap();
    assert_eq!((w, h), (128, 128));
    assert!(px.iter().any(|&v| v > 40), "a real image, not black");
}

#[test]
fn two_tasks_give_the_same_samples_as_one_run_and_reruns_skip_finished_inputs() {
    let a = clip("part-a.mp4", &["-i", FIXTURE, "-frames:v", "18", "-c:v", "libx264", "-preset", "ultrafast"]);
    let b = clip("part-b.mp4", &["-ss", "0.5", "-i", FIXTURE, "-frames:v", "18", "-c:v", "libx264", "-preset", "ultrafast"]);
    let c = clip("part-c.mp4", &["-ss", "1.0", "-i", FIXTURE, "-frames:v", "18", "-c:v", "libx264", "-preset", "ultrafast"]);
    let inputs = [a.to_str().unwrap(), b.to_str().unwrap(), c.to_str().unwrap()];
    let one = scratch("gen_tasks_one");
    ok(&generate(&one, &inputs, &[]));
    let split = scratch("gen_tasks_split");
    for i in ["0", "1"] {
        let o = bin()
            .arg("generate")
            .args(inputs)
            .args(["-o", split.to_str().unwrap(), "--progress", "never", "--shard-index", i, "--shard-count", "2"])
            .output()
            .unwrap();
        ok(&o);
    }
    let names = files(&split);
    assert!(
        names.contains(&"manifest-00000-of-00002.json".to_string()) && names.contains(&"manifest-00001-of-00002.json".to_string()),
        "{names:?}"
    );
    let mut m1: BTreeMap<String, Vec<u8>> = shard_members(&one).into_iter().collect();
    let m2: BTreeMap<String, Vec<u8>> = shard_members(&split).into_iter().collect();
    assert_eq!(m1.len(), 3 * 2 * 8 * 3);
    assert_eq!(m1.keys().collect::<Vec<_>>(), m2.keys().collect::<Vec<_>>());
    for (k, v) in &m2 {
        assert!(m1.remove(k).unwrap() == *v, "{k} differs");
    }
    // A rerun skips every input the manifest lists and rewrites nothing.
    let b_shard = files(&one).into_iter().find(|f| f.starts_with("train-part-b_")).unwrap();
    let before = std::fs::metadata(one.join(&b_shard)).unwrap().modified().unwrap();
    let o = generate(&one, &inputs, &[]);
    ok(&o);
    assert!(stderr(&o).contains("3 skipped"), "{}", stderr(&o));
    assert_eq!(std::fs::metadata(one.join(&b_shard)).unwrap().modified().unwrap(), before);
    // The Slurm variables pick the task when no flag is given.
    let slurm = scratch("gen_tasks_slurm");
    let o = bin()
        .arg("generate")
        .args(inputs)
        .args(["-o", slurm.to_str().unwrap(), "--progress", "never"])
        .env("SLURM_ARRAY_TASK_ID", "1")
        .env("SLURM_ARRAY_TASK_COUNT", "2")
        .output()
        .unwrap();
    ok(&o);
    assert_eq!(files(&slurm).iter().filter(|f| f.ends_with(".tar")).cloned().collect::<Vec<_>>(), vec![b_shard]);
}

#[test]
fn a_video_on_standard_input_is_read_with_dash() {
    // `ffmpeg ... -f nut - | pipeline generate - -o out`: each piped stream is an input of its
    // own (a second one adds shards, it is not skipped as done).
    let d = scratch("gen_stdin");
    for round in 1..=2 {
        let mut child = bin()
            .args(["generate", "-", "-o", d.to_str().unwrap(), "--progress", "never", "--set", SHORT])
            .stdin(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let bytes = std::fs::read(FIXTURE).unwrap();
        let mut stdin = child.stdin.take().unwrap();
        std::thread::spawn(move || std::io::Write::write_all(&mut stdin, &bytes));
        ok(&child.wait_with_output().unwrap());
        let tars: Vec<String> = files(&d).into_iter().filter(|f| f.ends_with(".tar")).collect();
        assert_eq!(tars.len(), round, "{tars:?}");
        assert!(tars.iter().all(|t| t.starts_with("train-stdin_")), "{tars:?}");
    }
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(m["samples"], 2 * 3 * 8, "27 frames: 3 windows of 9, 8 patches each, twice");
}

#[test]
fn gopro_and_basicsr_layouts_split_by_video_and_pair_by_name() {
    let ins: Vec<std::path::PathBuf> = ["a", "b", "c", "d"]
        .iter()
        .enumerate()
        .map(|(k, n)| {
            let ss = format!("{}", k as f64 * 0.3);
            clip(&format!("layout-{n}.mp4"), &["-ss", &ss, "-i", FIXTURE, "-frames:v", "18", "-c:v", "libx264", "-preset", "ultrafast"])
        })
        .collect();
    let inputs: Vec<&str> = ins.iter().map(|p| p.to_str().unwrap()).collect();
    let cfg = concat!(env!("CARGO_MANIFEST_DIR"), "/pipelines/frames.toml");
    let paths = format!("sources.video.paths={:?}", inputs);
    let run_layout = |layout: &str| {
        let d = scratch(&format!("gen_layout_{layout}"));
        let o = bin()
            .args(["run", cfg, "-o", d.to_str().unwrap(), "--progress", "never", "--set", &paths])
            .args(["--set", &format!("sinks.frames.layout=\"{layout}\""), "--set", "sinks.frames.test_fraction=0.5"])
            .output()
            .unwrap();
        ok(&o);
        d
    };
    // GoPro: {train,test}/<clip>/{blur,blur_gamma,sharp}/NNNNNN.png, each clip in one split.
    let g = run_layout("gopro");
    let mut clips = Vec::new();
    for split in ["train", "test"] {
        // Which clips go to test depends on their paths' hash (so on where the repository lies):
        // one split can be empty, and then it has no folder.
        if !g.join(split).exists() {
            continue;
        }
        for c in files(&g.join(split)) {
            assert_eq!(files(&g.join(split).join(&c)), vec!["blur", "blur_gamma", "sharp"]);
            let names = files(&g.join(split).join(&c).join("sharp"));
            assert_eq!(names, vec!["000000.png", "000001.png"], "18 frames: two windows of 9");
            for n in &names {
                let read = |sub: &str| std::fs::read(g.join(split).join(&c).join(sub).join(n)).unwrap();
                assert!(read("blur") == read("blur_gamma"));
            }
            clips.push(c);
        }
    }
    clips.sort();
    clips.dedup();
    assert_eq!(clips.len(), 4, "every clip in exactly one split: {clips:?}");
    // BasicSR: lq/ and gt/ with the same names, listed in meta_info.txt.
    let b = run_layout("basicsr");
    let mut total = 0;
    for split in files(&b).into_iter().filter(|f| f == "train" || f == "test") {
        let (lq, gt) = (files(&b.join(&split).join("lq")), files(&b.join(&split).join("gt")));
        assert_eq!(lq, gt);
        let meta = std::fs::read_to_string(b.join(&split).join("meta_info.txt")).unwrap();
        let mut listed: Vec<String> = meta.lines().map(|l| l.split(' ').next().unwrap().to_string()).collect();
        listed.sort();
        assert_eq!(listed, lq);
        assert!(meta.lines().all(|l| l.ends_with("(240,320,3)")), "{meta}");
        total += lq.len();
    }
    assert_eq!(total, 4 * 2);
}

/// The `stills` source with a `[motion]` table: every sample's key.json names the window's
/// motion and its extent, within the configured range (scaled to the window's length).
#[test]
fn stills_motion_is_drawn_per_window_and_recorded_in_key_json() {
    let d = scratch("stills_motion");
    let o = run_pipeline(
        "train-data.toml",
        &d,
        &[
            "sources.stills.paths=[]",
            "sources.stills.clips=3",
            "sources.stills.size=[96, 80]",
            "sources.stills.frames=63",
            "sources.stills.motion.object_paths=[]",
            "transforms.blur.window=7",
            "transforms.patches.size=32",
            "transforms.patches.per_window=1",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let mut kinds = std::collections::BTreeSet::new();
    let members = shard_members(&d);
    let metas: Vec<serde_json::Value> =
        members.iter().filter(|(n, _)| n.ends_with(".json")).map(|(_, b)| serde_json::from_slice(b).unwrap()).collect();
    assert_eq!(metas.len(), 3 * 9);
    for m in &metas {
        let kind = m["motion"]["kind"].as_str().unwrap_or_else(|| panic!("no motion in {m}")).to_string();
        let e = m["motion"]["extent_px"].as_f64().unwrap();
        // 0 to 40 px over 9 frames is 0 to 30 px over 7.
        assert!((0.0..=30.0).contains(&e), "{kind}: extent {e}");
        assert_eq!(kind == "still", e == 0.0, "{m}");
        kinds.insert(kind);
    }
    assert!(kinds.len() >= 4, "27 windows drew only {kinds:?}");
}

#[test]
fn the_realistic_capture_chain_is_seeded_recorded_and_noisier_at_high_iso() {
    let cfg = concat!(env!("CARGO_MANIFEST_DIR"), "/pipelines/realistic.toml");
    let run_with = |name: &str, sets: &[&str]| {
        let out = scratch(name);
        let mut args = vec!["generate", FIXTURE, "-o", out.to_str().unwrap(), "--config", cfg, "--progress", "never"];
        for s in sets {
            args.extend(["--set", s]);
        }
        args.extend(["--set", "sources.video.max_frames=27"]);
        let o = run(&args);
        assert!(o.status.success(), "{}", stderr(&o));
        shard_members(&out)
    };
    let a = run_with("realistic_a", &[]);
    let b = run_with("realistic_b", &[]);
    assert_eq!(a, b, "the same seed gives the same bytes");
    // The first sample's key.json.
    let key_json = |m: &[(String, Vec<u8>)]| -> serde_json::Value {
        serde_json::from_slice(&m.iter().find(|(n, _)| n.ends_with(".json")).unwrap().1).unwrap()
    };
    let json = key_json(&a);
    let s = &json["capture"]["sensor"];
    assert_eq!(s["bayer"], "rggb");
    assert!((100.0..=1600.0).contains(&s["iso"].as_f64().unwrap()), "{s}");
    // The same patches (a grid: not drawn from the seed) at ISO 100 with two seeds and at ISO
    // 3200: two low-ISO draws differ by their noise, far less than the high-ISO one does.
    let lq = |m: &[(String, Vec<u8>)]| image_rgb(&m.iter().find(|(n, _)| n.ends_with(".lq.png")).unwrap().1);
    let mse = |a: &[u8], b: &[u8]| a.iter().zip(b).map(|(x, y)| (f64::from(*x) - f64::from(*y)).powi(2)).sum::<f64>() / a.len() as f64;
    let grid = "transforms.patches.placement=grid";
    let low = lq(&run_with("realistic_low", &[grid, "transforms.sensor.iso=[100.0, 100.0]"]));
    let low2 = lq(&run_with("realistic_low2", &[grid, "transforms.sensor.iso=[100.0, 100.0]", "seed=5"]));
    let high = lq(&run_with("realistic_high", &[grid, "transforms.sensor.iso=[3200.0, 3200.0]"]));
    assert!(mse(&low, &low2) > 0.0, "the seed draws the noise");
    assert!(mse(&high, &low) > 4.0 * mse(&low, &low2), "{} vs {}", mse(&high, &low), mse(&low, &low2));
    // The camera response: a power law of gamma 1 and the table [0, 1] are the identity curve,
    // byte for byte; the default (the input's sRGB) is not; key.json names each.
    let iso = "transforms.sensor.iso=[100.0, 100.0]";
    let with = |name: &str, response: &str| run_with(name, &[grid, iso, &format!("transforms.sensor.response={response}")]);
    let ident = with("response_identity", "identity");
    for (name, response, said) in [("response_gamma", "{gamma = 1.0}", "gamma 1"), ("response_table", "[0.0, 1.0]", "table of 2")] {
        let m = with(name, response);
        assert_eq!(lq(&m), lq(&ident), "{response}");
        assert_eq!(key_json(&m)["capture"]["sensor"]["response"], said);
    }
    assert!(mse(&lq(&ident), &low) > 4.0 * mse(&low, &low2), "the response changes the capture");
    // Highlights made bright again: the capture gains light (the streaks of the clipped pixels),
    // the targets at the top code stay there, and key.json records the gain.
    let base = with("response_srgb", "srgb");
    let bright = run_with("highlights", &[grid, iso, "transforms.linear.highlights={gain=[4.0, 4.0]}"]);
    let sum = |m: &[(String, Vec<u8>)], ext: &str| -> Vec<u64> {
        m.iter().filter(|(n, _)| n.ends_with(ext)).map(|(_, b)| image_rgb(b).iter().map(|&v| u64::from(v)).sum()).collect()
    };
    assert!(sum(&bright, ".lq.png").iter().zip(sum(&base, ".lq.png")).all(|(a, b)| *a >= b));
    assert!(sum(&bright, ".lq.png").iter().sum::<u64>() > sum(&base, ".lq.png").iter().sum::<u64>());
    assert_eq!(sum(&bright, ".gt.png"), sum(&base, ".gt.png"));
    let json = key_json(&bright);
    assert_eq!(json["capture"]["highlights"]["gain"], 4.0);
    assert_eq!(json["capture"]["sensor"]["iso"].as_f64().map(f64::round), Some(100.0));
    // A response that decreases is refused by its key.
    let out = scratch("response_bad");
    let o = run(&[
        "generate",
        FIXTURE,
        "-o",
        out.to_str().unwrap(),
        "--config",
        cfg,
        "--set",
        "transforms.sensor.response=[0.0, 0.6, 0.5, 1.0]",
    ]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("transforms.sensor.response") && stderr(&o).contains("never decreases"), "{}", stderr(&o));
}

/// The RGB bytes of a PNG.
fn image_rgb(png: &[u8]) -> Vec<u8> {
    let mut d = png::Decoder::new(std::io::Cursor::new(png)).read_info().unwrap();
    let mut buf = vec![0; d.output_buffer_size().unwrap()];
    let info = d.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    buf
}
