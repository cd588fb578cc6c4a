//! `pipeline eval`: the Table-1 numbers are the PSNR a hand computation gives on the frames it
//! shows, the sharp panel is the right frame of the video, and bad keys are named.

use crate::common::*;
use pipeline::commands::eval::{GAP, LABEL_H};
use std::path::Path;

/// PSNR of two equally long 8-bit buffers, written out here rather than taken from the crate.
fn psnr_by_hand(a: &[u8], b: &[u8]) -> f64 {
    let mse: f64 = a.iter().zip(b).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum::<f64>() / a.len() as f64;
    10.0 * (255.0f64 * 255.0 / mse).log10()
}

/// Panel `i` (0 blurred, 1 deblurred, 2 sharp) of a side-by-side PNG of panels `w x h`.
fn panel(png: &(usize, usize, Vec<u8>), i: usize, w: usize, h: usize) -> Vec<u8> {
    let (tw, _, rgb) = png;
    let x0 = i * (w + GAP);
    (0..h).flat_map(|y| rgb[((LABEL_H + y) * tw + x0) * 3..((LABEL_H + y) * tw + x0 + w) * 3].to_vec()).collect()
}

#[test]
fn eval_numbers_match_a_hand_computation_on_one_frame() {
    let d = scratch("eval_fixture");
    let o = run(&[
        "eval",
        FIXTURE,
        "-o",
        d.to_str().unwrap(),
        "--progress",
        "never",
        "--set",
        "eval.windows=[7, 9]",
        "--set",
        "eval.sigmas=[0, 3]",
        "--set",
        "eval.windows_per_video=1",
        "--set",
        "eval.skip=40",
        "--set",
        "eval.crop=64",
        "--set",
        "eval.examples=2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("eval.json")).unwrap()).unwrap();
    let records = r["records"].as_array().unwrap();
    assert_eq!(records.len(), 4, "2 windows x 2 sigmas x 1 centre");
    assert_eq!(r["region"], serde_json::json!([128, 88, 64, 64]));
    let ex: Vec<&serde_json::Value> = records.iter().filter(|x| !x["example"].is_null()).collect();
    assert_eq!(ex.len(), 2, "examples at the largest sigma");
    for rec in &ex {
        assert_eq!(rec["sigma"], 3.0);
        let png = pipeline::io::png::read_rgb8(&std::fs::read(d.join(rec["example"].as_str().unwrap())).unwrap()).unwrap();
        assert_eq!((png.0, png.1), (3 * 64 + 2 * GAP, LABEL_H + 64));
        let (blurred, deblurred, sharp) = (panel(&png, 0, 64, 64), panel(&png, 1, 64, 64), panel(&png, 2, 64, 64));
        let pb = psnr_by_hand(&blurred, &sharp);
        let pd = psnr_by_hand(&deblurred, &sharp);
        assert!((pb - rec["blurred"]["psnr_rgb"].as_f64().unwrap()).abs() < 1e-9, "{pb} vs {}", rec["blurred"]);
        assert!((pd - rec["deblurred"]["psnr_rgb"].as_f64().unwrap()).abs() < 1e-9, "{pd} vs {}", rec["deblurred"]);
        // Blur costs something: the input is not the sharp frame.
        assert!(pb < 40.0, "{pb}");
    }
    // The sharp panel is frame 40 + 4 (skip + half the longest window, 9) of the video: the
    // ffmpeg CLI's own decode of that frame (same swscale flags) agrees within
    // chroma-upsampling differences, and
    // frames 4 away do not (this pan moves the crop by at most one pixel per frame, so
    // direct neighbours can be identical).
    let sharp =
        panel(&pipeline::io::png::read_rgb8(&std::fs::read(d.join(ex[0]["example"].as_str().unwrap())).unwrap()).unwrap(), 2, 64, 64);
    assert_eq!(ex[0]["frame"], 44);
    let mean_diff = |frame: u32| {
        let f = d.join(format!("f{frame}.png"));
        ffmpeg(&[
            "-sws_flags",
            "bilinear+accurate_rnd+full_chroma_int",
            "-i",
            FIXTURE,
            "-vf",
            &format!("select=eq(n\\,{frame}),crop=64:64:128:88"),
            "-frames:v",
            "1",
            "-pix_fmt",
            "rgb24",
            f.to_str().unwrap(),
        ]);
        let (_, _, rgb) = pipeline::io::png::read_rgb8(&std::fs::read(&f).unwrap()).unwrap();
        rgb.iter().zip(&sharp).map(|(&a, &b)| (a as f64 - b as f64).abs()).sum::<f64>() / rgb.len() as f64
    };
    let (here, before, after) = (mean_diff(44), mean_diff(40), mean_diff(48));
    assert!(here < 4.0 && here * 3.0 < before.min(after), "frame 44 differs by {here}, 40 by {before}, 48 by {after}");
    // Our own decoder's frame 44 is the sharp panel up to the sRGB round trip (linear and back).
    let mut reader = pipeline::io::video::VideoReader::open(std::path::Path::new(FIXTURE)).unwrap();
    let mut frame = None;
    for _ in 0..=44 {
        frame = reader.next_frame().unwrap();
    }
    let frame = frame.unwrap();
    let pipeline::frame::FrameData::Planar8(p) = &*frame.data else { panic!("8-bit fixture") };
    let ours: Vec<u8> = (0..64 * 64).flat_map(|i| [0, 1, 2].map(|c| p[c][(88 + i / 64) * 320 + 128 + i % 64])).collect();
    let worst = ours.iter().zip(&sharp).map(|(&a, &b)| (a as i32 - b as i32).abs()).max().unwrap();
    assert!(worst <= 1, "sharp panel differs from the decoded frame 44 by up to {worst} levels");
    // The table averages the records of each N over sigma.
    let table = r["table"].as_array().unwrap();
    let want: f64 = records.iter().filter(|x| x["window"] == 7).map(|x| x["deblurred"]["psnr_y"].as_f64().unwrap()).sum::<f64>() / 2.0;
    assert!((table[0]["deblurred"]["psnr_y"].as_f64().unwrap() - want).abs() < 1e-9);
    // One video: its per-video rows are the table's, named by the file.
    let per_video = r["per_video"].as_array().unwrap();
    assert_eq!(per_video.len(), 2, "1 video x 2 N");
    assert!(per_video[0]["video"].as_str().unwrap().ends_with(Path::new(FIXTURE).file_name().unwrap().to_str().unwrap()));
    assert_eq!(per_video[1]["deblurred"], table[1]["deblurred"]);
    assert_eq!(per_video[0]["count"], 2);
    let md = std::fs::read_to_string(d.join("eval.md")).unwrap();
    assert!(md.contains("| N=7 ") && md.contains("| N=9 ") && md.contains("blurred input (RGB)"), "{md}");
    let name = Path::new(FIXTURE).file_name().unwrap().to_str().unwrap();
    assert!(md.contains("## Per video") && md.contains(&format!("| {name} | N=9 ")), "{md}");
    // The same command again does not replace that run's tables (exit 2, naming --overwrite).
    let before = std::fs::read(d.join("eval.json")).unwrap();
    let o = run(&["eval", FIXTURE, "-o", d.to_str().unwrap(), "--progress", "never", "--set", "eval.windows=[7]"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("eval.json") && stderr(&o).contains("--overwrite"), "{}", stderr(&o));
    assert_eq!(std::fs::read(d.join("eval.json")).unwrap(), before);
}

#[test]
fn eval_refuses_bad_keys_and_short_videos_by_name() {
    let d = scratch("eval_bad");
    let o = run(&["eval", FIXTURE, "-o", d.to_str().unwrap(), "--set", "eval.windows=[8]"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("eval.windows"), "{}", stderr(&o));
    let o = run(&["eval", FIXTURE, "-o", d.to_str().unwrap(), "--set", "eval.crops=64"]);
    assert!(!o.status.success() && stderr(&o).contains("crops"), "{}", stderr(&o));
    let short = clip("eval-short.mp4", &["-i", FIXTURE, "-frames:v", "5", "-c:v", "libx264", "-preset", "ultrafast"]);
    let o = run(&["eval", short.to_str().unwrap(), "-o", d.to_str().unwrap(), "--set", "eval.windows=[7]"]);
    assert!(!o.status.success() && stderr(&o).contains("eval-short.mp4") && stderr(&o).contains("fewer than one window"), "{}", stderr(&o));
}

#[test]
fn eval_tables_shake_by_spread_and_reads_out_through_a_sensor() {
    let d = scratch("eval_spread");
    // The fixture labelled as camera shake: frames 39 to 51 (a segment of 13) moved 2 px a frame
    // to the right, so the window of 9 around frame 44 spreads 16 px.
    let clip = d.join("shaky.mp4");
    std::fs::copy(FIXTURE, &clip).unwrap();
    let shift: Vec<[f64; 2]> = (0..13).map(|j| [2.0 * j as f64, 0.0]).collect();
    let label = serde_json::json!({ "kind": "shake", "extent_px": 24.0, "shift": shift });
    let log: String = (39..52).map(|f| format!("{}\n", serde_json::json!({ "window": f, "motion": label }))).collect();
    std::fs::write(d.join("shaky.motion.jsonl"), log).unwrap();
    let eval = |out: &str, extra: &[&str]| {
        let mut args = vec!["eval", clip.to_str().unwrap(), "--progress", "never", "--set", "eval.windows=[9]"];
        args.extend(["--set", "eval.sigmas=[0]", "--set", "eval.windows_per_video=1", "--set", "eval.skip=40"]);
        args.extend(["--set", "eval.crop=64", "--set", "eval.examples=0"]);
        let o = d.join(out);
        args.extend(["-o", o.to_str().unwrap()]);
        args.extend(extra);
        let r = run(&args);
        assert!(r.status.success(), "{}", stderr(&r));
        let json: serde_json::Value = serde_json::from_slice(&std::fs::read(o.join("eval.json")).unwrap()).unwrap();
        (json, std::fs::read_to_string(o.join("eval.md")).unwrap())
    };
    let (ideal, md) = eval("ideal", &[]);
    assert_eq!(ideal["records"][0]["spread_px"], 16.0);
    let cells = ideal["per_spread"].as_array().unwrap();
    assert_eq!(cells.len(), 1, "{cells:?}");
    assert_eq!(
        (cells[0]["motion"].as_str(), cells[0]["spread_px"][0].as_f64(), cells[0]["count"].as_u64()),
        (Some("shake"), Some(10.0), Some(1))
    );
    assert!(md.contains("## Camera shake by spread") && md.contains("| shake | N=9 | 10-20 | 1 |"), "{md}");
    // Through a sensor at ISO 3200 with a Bayer mosaic the same window reads out noisier.
    let (sensor, md) = eval("sensor", &["--set", "eval.sensor.iso=3200", "--set", "eval.sensor.bayer=\"rggb\""]);
    let psnr = |j: &serde_json::Value| j["records"][0]["blurred"]["psnr_rgb"].as_f64().unwrap();
    assert!(psnr(&sensor) < psnr(&ideal) - 1.0, "sensor {} ideal {}", psnr(&sensor), psnr(&ideal));
    assert!(md.contains("Read-out: a sensor at ISO 3200") && md.contains("RGGB MOSAIC"), "{md}");
}
