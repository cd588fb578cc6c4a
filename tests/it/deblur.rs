//! `pipeline deblur`: videos keep count, size and rate; folders keep names; tiles match the
//! whole frame; an identity model gives the input back; bad paths are refused by name.

use crate::common::*;
use burn::tensor::Device;
use pipeline::model::fast::FastNet;
use pipeline::model::infer::{run_frame, Tiling};
use pipeline::model::{Arch, Net};

fn probe(path: &std::path::Path) -> String {
    let o = std::process::Command::new("ffprobe")
        .args(["-v", "error", "-select_streams", "v", "-show_entries", "stream=width,height,r_frame_rate,nb_frames", "-of", "default=nw=1"])
        .arg(path)
        .output()
        .unwrap();
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn a_video_keeps_frame_count_size_and_rate() {
    let input = clip("deblur-in.mp4", &["-i", FIXTURE, "-frames:v", "6", "-vf", "crop=96:64", "-c:v", "libx264", "-preset", "ultrafast"]);
    let d = scratch("deblur_video");
    let out = d.join("out.mp4");
    let o = run(&["deblur", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(probe(&out), probe(&input));
    assert!(probe(&out).contains("nb_frames=6") && probe(&out).contains("r_frame_rate=240/1"), "{}", probe(&out));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("out.mp4.report.json")).unwrap()).unwrap();
    assert_eq!(r["frames"], 6);
    assert!(r["audio"].as_str().unwrap().contains("not copied"));
    // Lossless needs .mkv, and says so.
    let o = run(&["deblur", input.to_str().unwrap(), "-o", d.join("l.mp4").to_str().unwrap(), "--lossless"]);
    assert!(!o.status.success() && stderr(&o).contains(".mkv"));
}

#[test]
fn a_folder_of_images_keeps_the_names() {
    let d = scratch("deblur_images");
    let (src, dst) = (d.join("in"), d.join("out"));
    std::fs::create_dir_all(&src).unwrap();
    for (name, seed) in [("a.png", 1u64), ("frame_0002.png", 2)] {
        let rgb: Vec<u8> = (0..40 * 30 * 3).map(|i| (pipeline::rng::hash(&[seed, i as u64]) % 256) as u8).collect();
        let mut buf = Vec::new();
        pipeline::io::png::write_rgb8(&mut buf, 40, 30, &rgb).unwrap();
        std::fs::write(src.join(name), buf).unwrap();
    }
    let o = run(&["deblur", src.to_str().unwrap(), "-o", dst.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let names: Vec<String> = files(&dst).into_iter().filter(|f| f.ends_with(".png")).collect();
    assert_eq!(names, vec!["a.png", "frame_0002.png"]);
    let (w, h, folder_out) = pipeline::io::png::read_rgb8(&std::fs::read(dst.join("a.png")).unwrap()).unwrap();
    assert_eq!((w, h), (40, 30));
    // One image to an image file: that file, a real PNG with the pixels the folder run made
    // (it was an H.264 stream named .png before), and to a folder: the same name inside it.
    let one = d.join("single/b.png");
    let o = run(&["deblur", src.join("a.png").to_str().unwrap(), "-o", one.to_str().unwrap(), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(pipeline::io::png::read_rgb8(&std::fs::read(&one).unwrap()).unwrap(), (40, 30, folder_out.clone()));
    let o = run(&["deblur", src.join("a.png").to_str().unwrap(), "-o", d.join("into").to_str().unwrap(), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(pipeline::io::png::read_rgb8(&std::fs::read(d.join("into/a.png")).unwrap()).unwrap().2, folder_out);
    // An output an earlier run wrote is not replaced without --overwrite (exit 2, nothing touched):
    // one image, and a folder of the same names.
    std::fs::write(&one, b"kept").unwrap();
    std::fs::write(dst.join("a.png"), b"kept").unwrap();
    for (from, to) in [(src.join("a.png"), &one), (src.clone(), &dst)] {
        let o = run(&["deblur", from.to_str().unwrap(), "-o", to.to_str().unwrap(), "--progress", "never"]);
        assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
        assert!(stderr(&o).contains("--overwrite") && stderr(&o).contains("an earlier run"), "{}", stderr(&o));
    }
    assert_eq!((std::fs::read(&one).unwrap(), std::fs::read(dst.join("a.png")).unwrap()), (b"kept".to_vec(), b"kept".to_vec()));
    // A folder run that was interrupted is finished by running it again, without --overwrite.
    let report = dst.join("report.json");
    let mut r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    r["interrupted"] = serde_json::json!(true);
    std::fs::write(&report, serde_json::to_vec(&r).unwrap()).unwrap();
    let o = run(&["deblur", src.to_str().unwrap(), "-o", dst.to_str().unwrap(), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(pipeline::io::png::read_rgb8(&std::fs::read(dst.join("a.png")).unwrap()).unwrap().2, folder_out);
    let o = run(&["deblur", src.join("a.png").to_str().unwrap(), "-o", one.to_str().unwrap(), "--overwrite", "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(pipeline::io::png::read_rgb8(&std::fs::read(&one).unwrap()).unwrap().2, folder_out);
}

#[test]
fn tiles_match_the_whole_frame_and_an_identity_model_gives_the_input_back() {
    let dev = Device::flex();
    let (w, h) = (150, 110);
    let rgb: Vec<u8> =
        (0..w * h * 3).map(|i| ((i / 3 % w) as f64 * 1.7 + (i / 3 / w) as f64 * 0.9 + (i % 3) as f64 * 40.0) as u8).collect();
    let identity = FastNet::from_net(&Net::new(Arch::Shallow { width: 8 }, &dev).zero_last_layer(&dev));
    assert!(run_frame(&identity, &rgb, w, h, Tiling { tile: 64, overlap: 16 }) == rgb);
    let (net, _) = pipeline::model::infer::load(None).unwrap();
    let whole = run_frame(&net, &rgb, w, h, Tiling { tile: 256, overlap: 0 });
    // The default model is a U-Net (receptive field over 100 px): tiles with a wide overlap.
    let tiled = run_frame(&net, &rgb, w, h, Tiling { tile: 112, overlap: 48 });
    let diffs: Vec<i32> = whole.iter().zip(&tiled).map(|(a, b)| (*a as i32 - *b as i32).abs()).collect();
    let mean = diffs.iter().sum::<i32>() as f64 / diffs.len() as f64;
    let worst = *diffs.iter().max().unwrap();
    assert!(mean < 0.25 && worst <= 6, "tiled vs whole: mean {mean} levels, worst {worst}");
}

#[test]
fn bad_paths_are_refused_and_the_input_is_untouched() {
    let input =
        clip("deblur-bad-in.mp4", &["-i", FIXTURE, "-frames:v", "3", "-vf", "crop=64:48", "-c:v", "libx264", "-preset", "ultrafast"]);
    let before = std::fs::read(&input).unwrap();
    let o = run(&["deblur", input.to_str().unwrap(), "-o", input.to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("the output is the input"), "{}", stderr(&o));
    let d = scratch("deblur_bad");
    let file = d.join("a-file");
    std::fs::write(&file, "x").unwrap();
    let o = run(&["deblur", input.to_str().unwrap(), "-o", file.join("out.mp4").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("out.mp4") && stderr(&o).contains("a-file is a file, not a folder"), "{}", stderr(&o));
    let o = run(&["deblur", input.to_str().unwrap(), "-o", d.join("o.mp4").to_str().unwrap(), "--model", file.to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("a-file"), "{}", stderr(&o));
    // A typo in the deblur file's keys, and a bad value, are named.
    let o = run(&["deblur", input.to_str().unwrap(), "-o", d.join("o.mp4").to_str().unwrap(), "--set", "deblur.tyle=512"]);
    assert!(!o.status.success() && stderr(&o).contains("tyle"), "{}", stderr(&o));
    let o = run(&["deblur", input.to_str().unwrap(), "-o", d.join("o.mp4").to_str().unwrap(), "--set", "deblur.overlap=700"]);
    assert!(!o.status.success() && stderr(&o).contains("deblur.overlap"), "{}", stderr(&o));
    assert!(std::fs::read(&input).unwrap() == before);
    assert!(!d.join("o.mp4").exists());
    // An input that does not exist: a usage error naming it, and nothing made (it used to leave
    // an empty folder named like the output image and say "0 frames of 0x0").
    let o = run(&["deblur", d.join("missing.png").to_str().unwrap(), "-o", d.join("m.png").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("missing.png: no such file or folder"), "{}", stderr(&o));
    assert!(!d.join("m.png").exists() && !d.join("m.png.report.json").exists());
    // A 68-byte PNG declaring 100000x100000 pixels is refused by name before any allocation
    // (exit 1, the report named); inside a folder the other images are still done.
    let huge = d.join("huge.png");
    let chunk = |t: &[u8], data: &[u8]| {
        let mut c = (data.len() as u32).to_be_bytes().to_vec();
        let body = [t, data].concat();
        c.extend_from_slice(&body);
        c.extend_from_slice(&crc32(&body).to_be_bytes());
        c
    };
    let mut ihdr = [100_000u32.to_be_bytes(), 100_000u32.to_be_bytes()].concat();
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    std::fs::write(
        &huge,
        [
            &b"\x89PNG\r\n\x1a\n"[..],
            &chunk(b"IHDR", &ihdr),
            &chunk(b"IDAT", &[0x78, 0x9c, 0x63, 0x60, 0x80, 0x01, 0x00, 0x00, 0x0a, 0x00, 0x01]),
            &chunk(b"IEND", &[]),
        ]
        .concat(),
    )
    .unwrap();
    let o = run(&["deblur", huge.to_str().unwrap(), "-o", d.join("h.png").to_str().unwrap()]);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains("huge.png: declares 100000x100000 pixels")
            && e.contains("nothing deblurred")
            && e.contains("h.png.report.json lists them"),
        "{e}"
    );
    let folder = d.join("folder");
    std::fs::create_dir_all(&folder).unwrap();
    std::fs::copy(&huge, folder.join("a.png")).unwrap();
    std::fs::copy(concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/chelsea-160x128.png"), folder.join("b.png")).unwrap();
    let o = run(&["deblur", folder.to_str().unwrap(), "-o", d.join("fo").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(d.join("fo/b.png").exists() && !d.join("fo/a.png").exists() && d.join("fo/report.json").exists());
}

/// CRC-32 (PNG's polynomial), for hand-made PNG chunks.
fn crc32(b: &[u8]) -> u32 {
    let mut c = !0u32;
    for &x in b {
        c ^= x as u32;
        for _ in 0..8 {
            c = if c & 1 == 1 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
        }
    }
    !c
}

#[test]
fn png_jpeg_tiff_and_exr_keep_names_and_formats_and_an_identity_model_keeps_the_pixels() {
    let d = scratch("deblur_formats");
    let (src, dst) = (d.join("in"), d.join("out"));
    std::fs::create_dir_all(&src).unwrap();
    // JPEG and TIFF by the ffmpeg CLI, PNG and EXR (linear light) by our writers, same picture.
    for name in ["a.jpg", "b.tif", "c.png"] {
        ffmpeg(&["-i", FIXTURE, "-frames:v", "1", "-vf", "crop=72:40:100:60", "-pix_fmt", "rgb24", src.join(name).to_str().unwrap()]);
    }
    let (w, h, rgb) = pipeline::io::png::read_rgb8(&std::fs::read(src.join("c.png")).unwrap()).unwrap();
    let curve = pipeline::optics::transfer::Curve::Srgb;
    let lin: [Vec<f32>; 3] = std::array::from_fn(|c| (0..w * h).map(|i| curve.to_linear(rgb[i * 3 + c] as f64 / 255.0) as f32).collect());
    let mut exr = Vec::new();
    pipeline::io::exr::write_rgb_f32(&mut exr, w, h, [&lin[0], &lin[1], &lin[2]]).unwrap();
    std::fs::write(src.join("d.exr"), exr).unwrap();

    let dev = Device::flex();
    let identity = FastNet::from_net(&Net::new(Arch::Shallow { width: 8 }, &dev).zero_last_layer(&dev));
    let r = pipeline::commands::deblur::images(
        &identity,
        "identity",
        &src,
        &dst,
        Tiling { tile: 64, overlap: 16 },
        pipeline::progress::ProgressMode::Never,
    )
    .unwrap();
    assert_eq!(r.frames, 4);
    assert_eq!(files(&dst), vec!["a.jpg", "b.tif", "c.png", "d.exr"]);
    let magic = |n: &str| std::fs::read(dst.join(n)).unwrap()[..4].to_vec();
    assert_eq!(magic("a.jpg")[..2], [0xFF, 0xD8]);
    assert!(magic("b.tif") == b"II*\0" || magic("b.tif") == b"MM\0*");
    assert_eq!(magic("c.png"), [0x89, b'P', b'N', b'G']);
    assert_eq!(magic("d.exr"), [0x76, 0x2f, 0x31, 0x01]);
    // Every output read back (through FFmpeg's decoders for JPEG, TIFF and EXR) against its input.
    let read = |p: std::path::PathBuf| {
        let (f, float) = pipeline::io::video::read_image(&p).unwrap();
        assert_eq!((f.width, f.height), (w, h));
        pipeline::commands::deblur::to_rgb8(&f, float)
    };
    let worst = |a: &[u8], b: &[u8]| a.iter().zip(b).map(|(x, y)| (*x as i32 - *y as i32).abs()).max().unwrap();
    for name in ["b.tif", "c.png", "d.exr"] {
        let (i, o) = (read(src.join(name)), read(dst.join(name)));
        assert!(worst(&i, &rgb) <= 1, "{name}: input read as {} levels off", worst(&i, &rgb));
        assert!(worst(&o, &i) <= 1, "{name}: identity moved pixels by {} levels", worst(&o, &i));
    }
    // JPEG is lossy once more on the way out: small mean change only.
    let (i, o) = (read(src.join("a.jpg")), read(dst.join("a.jpg")));
    let mean = i.iter().zip(&o).map(|(x, y)| (*x as f64 - *y as f64).abs()).sum::<f64>() / i.len() as f64;
    assert!(mean < 2.0, "jpeg re-encode changed pixels by {mean} levels on average");
}

/// The output's kind follows its extension, checked against the input's, the same way for every
/// input (issue 31): a mismatch or an unknown extension is a usage error that writes nothing;
/// parent folders are made for videos as for images; the report lands where `--help` says.
#[test]
fn the_output_kind_follows_its_extension_and_a_mismatch_is_a_usage_error() {
    let d = scratch("deblur_kinds");
    let frames = d.join("frames");
    std::fs::create_dir_all(&frames).unwrap();
    let rgb: Vec<u8> = (0..32 * 24 * 3).map(|i| (i * 7 % 251) as u8).collect();
    let mut buf = Vec::new();
    pipeline::io::png::write_rgb8(&mut buf, 32, 24, &rgb).unwrap();
    std::fs::write(frames.join("a.png"), &buf).unwrap();
    let video =
        clip("deblur-kinds.mp4", &["-i", FIXTURE, "-frames:v", "2", "-vf", "crop=48:32", "-c:v", "libx264", "-preset", "ultrafast"]);
    let (f, v, img) = (frames.to_str().unwrap(), video.to_str().unwrap(), frames.join("a.png"));
    for (input, out, says) in [
        (f, d.join("out.mp4"), "the input is a folder of images"),
        (f, d.join("out.png"), "the input is a folder of images"),
        (v, d.join("x.xyz"), ".xyz is neither"),
        (v, d.join("sharp"), "the input is a video"),
        (v, d.join("sharp.png"), "the input is a video"),
        (img.to_str().unwrap(), d.join("one.mkv"), "the input is an image"),
    ] {
        let o = run(&["deblur", input, "-o", out.to_str().unwrap(), "--progress", "never"]);
        assert_eq!(o.status.code(), Some(2), "{}: {}", out.display(), stderr(&o));
        assert!(stderr(&o).contains(says) && stderr(&o).contains(out.file_name().unwrap().to_str().unwrap()), "{}", stderr(&o));
        assert!(!out.exists(), "{} was written", out.display());
    }
    // A video into folders that do not exist yet: made, as for images; the report beside it.
    let nested = d.join("new/deeper/sharp.mp4");
    let o = run(&["deblur", v, "-o", nested.to_str().unwrap(), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(nested.exists() && d.join("new/deeper/sharp.mp4.report.json").exists());
    // A folder output's report is inside it.
    let o = run(&["deblur", f, "-o", d.join("out").to_str().unwrap(), "--progress", "never"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(d.join("out/a.png").exists() && d.join("out/report.json").exists());
}

#[test]
fn grey_alpha_and_16_bit_pngs_come_back_in_their_own_layout_and_what_a_format_cannot_keep_is_said() {
    let d = scratch("deblur_layouts");
    let (src, dst) = (d.join("in"), d.join("out"));
    std::fs::create_dir_all(&src).unwrap();
    let (w, h) = (40, 30);
    let mut written = Vec::new();
    for (name, channels, sixteen) in [("g8.png", 1, false), ("ga16.png", 2, true), ("rgba8.png", 4, false), ("rgb16.png", 3, true)] {
        let n = w * h * channels * if sixteen { 2 } else { 1 };
        // Grey-ish colour samples (three equal values would hide a channel mix-up) and a ramp of alpha.
        let data: Vec<u8> = (0..n).map(|i| (pipeline::rng::hash(&[channels as u64, i as u64]) % 256) as u8).collect();
        let s = pipeline::io::png::Samples { width: w, height: h, channels, sixteen, data, expanded: None };
        let mut buf = Vec::new();
        pipeline::io::png::write_samples(&mut buf, &s).unwrap();
        std::fs::write(src.join(name), buf).unwrap();
        written.push((name, s));
    }
    let dev = Device::flex();
    let identity = FastNet::from_net(&Net::new(Arch::Shallow { width: 8 }, &dev).zero_last_layer(&dev));
    let tiling = Tiling { tile: 32, overlap: 8 };
    let never = pipeline::progress::ProgressMode::Never;
    let r = pipeline::commands::deblur::images(&identity, "identity", &src, &dst, tiling, never).unwrap();
    assert_eq!(r.frames, 4);
    assert!(r.changed.is_empty(), "{:?}", r.changed);
    for (name, s) in &written {
        let back = pipeline::io::png::read_samples(&std::fs::read(dst.join(name)).unwrap()).unwrap();
        assert_eq!((back.channels, back.sixteen), (s.channels, s.sixteen), "{name}");
        // The identity model gives every sample back, alpha included, at its own depth.
        assert!(back.data == s.data, "{name}: samples changed");
    }
    // A format that cannot hold what the source had: the image is written, and the report says what changed.
    let one = d.join("one.jpg");
    let r = pipeline::commands::deblur::images(&identity, "identity", &src.join("rgba8.png"), &one, tiling, never).unwrap();
    assert!(one.exists());
    assert_eq!(r.changed.len(), 1);
    assert!(r.changed[0].path.ends_with("rgba8.png") && r.changed[0].what == "alpha dropped", "{:?}", r.changed);
    let r = pipeline::commands::deblur::images(&identity, "identity", &src.join("ga16.png"), &d.join("two.tif"), tiling, never).unwrap();
    assert_eq!(r.changed[0].what, "alpha dropped, grey written as RGB, 16-bit samples written as 8 bits");
}
