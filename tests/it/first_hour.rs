//! What a new user runs into in the first hour: every config error at once, the right model for
//! ordinary blur, and a note wherever an output differs from its input without an error.

use super::common::*;

#[test]
fn a_bad_top_level_value_does_not_hide_the_files_other_errors() {
    let dir = scratch("first_hour_seed");
    let f = dir.join("p.toml");
    std::fs::write(
        &f,
        "seed = -4\n[sources.v]\ntype = \"decode\"\npaths = [\"a.mp4\"]\nbogus = 1\n[transforms.blur]\ntype = \"coded_blur\"\ninputs = [\"v\"]\nwindow = 99\n[sinks.s]\ntype = \"shards\"\ninputs = [\"blur\"]\n",
    )
    .unwrap();
    let o = run(&["validate", f.to_str().unwrap()]);
    let e = format!("{}{}", String::from_utf8_lossy(&o.stdout), stderr(&o));
    assert_eq!(o.status.code(), Some(2), "{e}");
    for key in ["seed:", "sources.v.bogus:", "transforms.blur.window:"] {
        assert!(e.contains(key), "{key} not reported: {e}");
    }
}

#[test]
fn a_set_key_that_is_no_toml_key_is_the_flags_error() {
    let out = scratch("first_hour_set");
    let o = run(&["generate", FIXTURE, "-o", out.join("o").to_str().unwrap(), "--set", "trans forms.x=9"]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.contains("--set") && e.contains("\"trans forms\" is not a key") && !e.contains("embedded"), "{e}");
    assert!(!out.join("o").exists(), "nothing is made for a refused command");
}

#[test]
fn a_warmup_as_long_as_the_run_is_refused_by_its_key() {
    let dir = scratch("first_hour_warmup");
    let cfg = tiny_train_config(&dir.join("none*.tar"), &dir, 20);
    let text = std::fs::read_to_string(&cfg).unwrap().replace("[optim]\n", "[optim]\nwarmup_steps = 1000\n");
    std::fs::write(&cfg, text).unwrap();
    let o = run(&["train", "--config", cfg.to_str().unwrap()]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.contains("optim.warmup_steps") && e.contains("1000") && e.contains("optim.steps (20)"), "{e}");
    assert!(!dir.join("run").exists());
}

#[test]
fn camera_conventional_deblurs_with_the_conventional_model() {
    let dir = scratch("first_hour_camera");
    let img = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/chelsea-160x128.png");
    let (a, b) = (dir.join("conv.png"), dir.join("coded.png"));
    let o = run(&["deblur", img, "-o", a.to_str().unwrap(), "--camera", "conventional", "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("conv.png.report.json")).unwrap()).unwrap();
    assert!(r["model"].as_str().unwrap().contains("unet32-conventional"), "{}", r["model"]);
    let o = run(&["deblur", img, "-o", b.to_str().unwrap(), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_ne!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap(), "the two cameras' models differ");
    // The same as naming the model's folder.
    let c = dir.join("named.png");
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/models/unet32-conventional");
    let o = run(&["deblur", img, "-o", c.to_str().unwrap(), "--model", model, "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&c).unwrap());
    let o = run(&["deblur", img, "-o", dir.join("x.png").to_str().unwrap(), "--camera", "conventional", "--model", model]);
    assert_eq!(o.status.code(), Some(2));
    let o = run(&["deblur", img, "-o", dir.join("x.png").to_str().unwrap(), "--camera", "flutter"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn a_palette_png_is_noted_as_written_in_rgb() {
    let dir = scratch("first_hour_palette");
    let (src, out) = (dir.join("in"), dir.join("out"));
    std::fs::create_dir_all(&src).unwrap();
    let img = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/chelsea-160x128.png");
    ffmpeg(&[
        "-i",
        img,
        "-vf",
        "split[a][b];[a]palettegen=max_colors=16[p];[b][p]paletteuse",
        "-pix_fmt",
        "pal8",
        src.join("pal.png").to_str().unwrap(),
    ]);
    std::fs::copy(img, src.join("rgb.png")).unwrap();
    let o = run(&["deblur", src.to_str().unwrap(), "-o", out.to_str().unwrap(), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("palette written as RGB"), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap();
    let changed = r["changed"].as_array().unwrap();
    assert_eq!(changed.len(), 1, "{changed:?}");
    assert!(changed[0]["path"].as_str().unwrap().ends_with("pal.png") && changed[0]["what"] == "palette written as RGB");
}

#[test]
fn a_variable_frame_rate_video_is_noted_with_how_far_frames_moved() {
    let dir = scratch("first_hour_vfr");
    // Ten frames at 30 fps, the sixth 20 ms late (Matroska keeps millisecond timestamps).
    let cfr = dir.join("cfr.mkv");
    ffmpeg(&["-f", "lavfi", "-i", "testsrc=size=64x48:rate=30", "-frames:v", "10", "-c:v", "ffv1", cfr.to_str().unwrap()]);
    let vfr = dir.join("vfr.mkv");
    ffmpeg(&[
        "-i",
        cfr.to_str().unwrap(),
        "-vf",
        "settb=1/1000,setpts='PTS+if(eq(N,5),0.02/TB,0)'",
        "-fps_mode",
        "passthrough",
        "-enc_time_base:v",
        "1/1000",
        "-c:v",
        "ffv1",
        vfr.to_str().unwrap(),
    ]);
    for (input, late) in [(&cfr, false), (&vfr, true)] {
        let out = dir.join(format!("out-{}", input.file_name().unwrap().to_string_lossy()));
        let o = run(&["deblur", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "--progress", "never"]);
        assert!(o.status.success(), "{}", stderr(&o));
        let r: serde_json::Value = serde_json::from_slice(
            &std::fs::read(dir.join(format!("{}.report.json", out.file_name().unwrap().to_string_lossy()))).unwrap(),
        )
        .unwrap();
        if late {
            let ms = r["retimed_ms"].as_f64().expect("retimed_ms");
            assert!((15.0..=25.0).contains(&ms), "{ms} ms");
            assert!(stderr(&o).contains("variable frame rate"), "{}", stderr(&o));
        } else {
            assert!(r.get("retimed_ms").is_none(), "{r}");
            assert!(!stderr(&o).contains("variable frame rate"));
        }
    }
}
