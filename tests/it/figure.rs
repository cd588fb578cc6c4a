//! `pipeline figure` and the `scene` source: the figures are written with their tables, a
//! missing model is named, and the scene source's sharp frame is the rendered mid sub-frame.

use crate::common::*;

#[test]
fn the_scene_source_feeds_the_pipeline_and_its_sharp_frame_is_the_render() {
    let d = scratch("scene_source");
    let cfg = concat!(env!("CARGO_MANIFEST_DIR"), "/pipelines/scene.toml");
    let o = run(&["run", cfg, "-o", d.to_str().unwrap(), "--progress", "never", "--set", "sources.scene.size=[64, 48]"]);
    assert!(o.status.success(), "{}", stderr(&o));
    // The frames sink names the folder by the input's key: stem and a hash of the clip's identity.
    let key = files(&d).into_iter().find(|f| f.starts_with("procedural-00000_")).expect("the clip's folder");
    let read = |sub: &str| pipeline::io::png::read_rgb8(&std::fs::read(d.join(&key).join(sub).join("000000.png")).unwrap()).unwrap();
    let (w, h, sharp) = read("sharp");
    assert_eq!((w, h), (64, 48));
    // The window's target is sub-frame 26 of 52.
    let p = pipeline::render::scene::SceneParams { width: 64, height: 48, spokes: 12, ..Default::default() };
    let want = p.render_at(pipeline::render::scene::sub_time(26, 52));
    let curve = pipeline::optics::transfer::Curve::Srgb;
    let worst = (0..w * h * 3).map(|i| (sharp[i] as f64 - curve.encode(want[i % 3][i / 3] as f64) * 255.0).abs()).fold(0.0, f64::max);
    assert!(worst <= 1.0, "sharp frame differs from the render by {worst} levels");
    let (_, _, blurred) = read("blur_gamma");
    assert!(blurred != sharp);
}

#[test]
fn figures_are_drawn_with_their_tables_and_a_missing_model_is_named() {
    let d = scratch("figures");
    for name in ["psf-strip", "dots", "spectrum"] {
        let out = d.join(format!("{name}.png"));
        let o = run(&["figure", name, "-o", out.to_str().unwrap(), "--size", "96"]);
        assert!(o.status.success(), "{name}: {}", stderr(&o));
        let (w, h, _) = pipeline::io::png::read_rgb8(&std::fs::read(&out).unwrap()).unwrap();
        assert!(w > 300 && h > 150, "{name}: {w}x{h}");
    }
    let models = concat!(env!("CARGO_MANIFEST_DIR"), "/models");
    let out = d.join("spoke.png");
    let o = run(&["figure", "spoke", "-o", out.to_str().unwrap(), "--size", "96", "--models", models]);
    assert!(o.status.success(), "{}", stderr(&o));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("spoke.json")).unwrap()).unwrap();
    let scores = r["scores"].as_array().unwrap();
    let cams: Vec<&str> = scores.iter().map(|s| s["camera"].as_str().unwrap()).collect();
    assert_eq!(cams, ["conventional", "flutter", "parabolic", "phase_coded"]);
    for s in scores {
        let (c, rec) = (s["captured"]["psnr_rgb"].as_f64().unwrap(), s["reconstructed"]["psnr_rgb"].as_f64().unwrap());
        assert!(c.is_finite() && rec.is_finite() && c > 5.0 && c < 40.0, "{s}");
    }
    // The fluttered shutter's noise is doubled: half the light.
    assert_eq!(scores[1]["sigma"], 6.0);
    assert_eq!(scores[0]["sigma"], 3.0);
    assert!(std::fs::read_to_string(d.join("spoke.md")).unwrap().contains("| phase_coded | 3 |"));
    let o = run(&["figure", "spoke", "-o", d.join("x.png").to_str().unwrap(), "--models", d.join("nowhere").to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("nowhere"), "{}", stderr(&o));
    assert!(!d.join("x.png").exists());
    // Plain least squares on image rows is singular: refused by name, not a panic.
    let o = run(&["figure", "spoke", "-o", d.join("x.png").to_str().unwrap(), "--flutter-lambda", "0"]);
    assert!(!o.status.success() && stderr(&o).contains("--flutter-lambda"), "{}", stderr(&o));
    assert!(!d.join("x.png").exists());
}
