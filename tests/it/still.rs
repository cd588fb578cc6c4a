//! No shipped model makes a still frame worse (issue 28): a textured photograph that does not
//! move, through each camera with noise of sigma 3, then through the model trained for that
//! camera. The conventional camera's still frame is nearly sharp, so its U-Net must leave it
//! alone (within 0.5 dB of its input); the coded camera's still frame carries the focus sweep's
//! blur, which its U-Net must reduce.

use crate::common::*;
use pipeline::model::infer::{run_frame, Tiling};
use std::path::Path;

/// Still windows of the fixture photo through `camera`: (input, sharp) pairs of 128 px.
fn still_pairs(camera: &str) -> Vec<pipeline::train::Pair> {
    let d = scratch(&format!("still_{camera}"));
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let photo = root.join("fixtures/chelsea-160x128.png");
    let text = format!(
        r#"seed = 5
[sources.stills]
type = "stills"
paths = [{photo:?}]
frames = 36
fps = 240.0
size = [128, 128]
[sources.stills.motion]
weights = {{ still = 1.0, pan = 0.0, shake = 0.0, objects = 0.0, rotate = 0.0, zoom = 0.0 }}
[transforms.linear]
type = "linearize"
inputs = ["stills"]
curve = "srgb"
[transforms.blur]
type = "coded_blur"
inputs = ["linear"]
window = 9
[transforms.blur.camera]
type = "{camera}"
[transforms.noise]
type = "noise"
inputs = ["blur"]
sigma = 3.0
[transforms.patches]
type = "patches"
inputs = ["noise"]
size = 128
per_window = 1
[sinks.shards]
type = "shards"
inputs = ["patches"]
dir = {dir:?}
prefix = "still"
"#,
        photo = photo.display().to_string(),
        dir = d.display().to_string()
    );
    let table = pipeline::config::parse(&text, "still test", &[]).unwrap();
    pipeline::graph::run(&pipeline::config::plan(table, "still").unwrap(), &Default::default()).unwrap();
    let mut pairs = Vec::new();
    for f in files(&d).into_iter().filter(|f| f.ends_with(".tar")) {
        pairs.extend(pipeline::train::read_shard(&d.join(f), None).unwrap());
    }
    assert_eq!(pairs.len(), 4, "four still windows");
    pairs
}

/// Mean PSNR (RGB) of the input and of the model's output against the sharp frame.
fn scores(model: &str, pairs: &[pipeline::train::Pair]) -> (f64, f64) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("models").join(model);
    let (net, _) = pipeline::model::infer::load(Some(&path)).unwrap();
    let (mut i, mut o) = (0.0, 0.0);
    for p in pairs {
        let out = run_frame(&net, &p.lq, p.w, p.h, Tiling { tile: 1280, overlap: 64 });
        i += pipeline::metrics::quality(&p.lq, &p.gt, p.w, p.h).psnr_rgb;
        o += pipeline::metrics::quality(&out, &p.gt, p.w, p.h).psnr_rgb;
    }
    (i / pairs.len() as f64, o / pairs.len() as f64)
}

#[test]
fn no_shipped_model_makes_a_still_frame_worse() {
    let (coded, conv) = (still_pairs("phase_coded"), still_pairs("conventional"));
    let mut table = Vec::new();
    // The burst U-Nets at the middle of the exposure, as `deblur` without --burst runs them.
    for net in ["unet32", "burst-unet32"] {
        let (ci, co) = scores(&format!("{net}-coded"), &coded);
        let (vi, vo) = scores(&format!("{net}-conventional"), &conv);
        table.push(format!("{net}: coded {ci:.2} -> {co:.2}, conventional {vi:.2} -> {vo:.2}"));
        assert!(vo > vi - 0.5, "the conventional {net} smooths a still frame: {table:?}");
        assert!(co > ci, "the coded {net} does not gain on a still frame: {table:?}");
    }
    let (si, so) = scores("shallow32-coded", &coded);
    table.push(format!("shallow coded {si:.2} -> {so:.2}"));
    assert!(so > si, "the shallow coded model does not gain on a still frame: {table:?}");
    eprintln!("{}", table.join("; "));
}
