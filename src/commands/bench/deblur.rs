use super::*;

/// One shipped model's speed in `bench deblur`.
#[derive(Debug, serde::Serialize)]
pub struct DeblurSpeed {
    pub model: String,
    pub arch: String,
    pub width: usize,
    pub height: usize,
    /// The whole frame in one forward pass.
    pub whole_frames_per_s_median: f64,
    /// As `pipeline deblur` runs by default (tiles of at most 384 px overlapping by 32, blended,
    /// on all cores).
    pub tiled_frames_per_s_median: f64,
    /// PyTorch CPU, the same architecture, whole frame, in the same run (when installed).
    pub torch: Option<serde_json::Value>,
    /// torch frames/s (whole frame, the same thread count) over ours as `deblur` runs by
    /// default: our time per frame over PyTorch's.
    pub torch_over_ours: Option<f64>,
    /// The same against our whole-frame pass.
    pub torch_over_ours_whole: Option<f64>,
    /// `--burst K`: the burst U-Net's K frames from one capture.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub burst: Option<BurstSpeed>,
}

/// The time of K frames from one capture (`bench deblur --burst K`), tiled as `deblur` runs.
#[derive(Debug, serde::Serialize)]
pub struct BurstSpeed {
    pub k: usize,
    /// K frames as `deblur --burst` makes them: the part of the network that does not depend
    /// on the time once, the rest K times (median seconds).
    pub burst_s_median: f64,
    /// K whole passes, one per time (median seconds).
    pub k_passes_s_median: f64,
    /// `burst_s_median / k_passes_s_median` (the goal: under 0.5).
    pub ratio: f64,
    /// PyTorch CPU, the same network, one forward per time, whole frame (when installed).
    pub torch: Option<serde_json::Value>,
}

/// `bench deblur`: frames/s of each shipped model on a `width x height` frame, whole and tiled,
/// beside PyTorch on the same architecture when torch is installed.
pub fn deblur(width: usize, height: usize, repeats: usize, burst: Option<usize>) -> crate::Result<Vec<DeblurSpeed>> {
    use crate::model::infer::{run_frame, Tiling};
    use crate::model::Arch;
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let script = torch_script();
    let frame: Vec<u8> = (0..width * height * 3).map(|i| (crate::rng::hash(&[i as u64 / 7]) % 256) as u8).collect();
    let mut out = Vec::new();
    let mut names: Vec<String> = std::fs::read_dir(root.join("models"))
        .map_err(|e| crate::Error::Io { path: root.join("models"), cause: e })?
        .filter_map(|e| e.ok())
        .filter(|e| e.path().join("model.safetensors").exists())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    for name in &names {
        let path = root.join("models").join(name).join("model.safetensors");
        let weights = crate::model::weights::Weights::read(&path)?;
        let arch = weights.arch;
        let net = crate::model::fast::FastNet::from_weights(weights);
        // With --burst, only U-Nets, each timed as a burst U-Net of its width (the weights do
        // not change the time; a single-frame U-Net becomes one with its time conditioning at zero).
        let (net, arch) = match (burst, arch) {
            (None, a) => (net, a),
            (Some(_), crate::model::Arch::BurstUnet { .. }) => (net, arch),
            (Some(_), crate::model::Arch::Unet { base }) => (net.into_burst(1), crate::model::Arch::burst(base)),
            (Some(_), _) => continue,
        };
        let time = |tiling: Tiling| {
            1.0 / median_time(repeats, &|| {
                std::hint::black_box(run_frame(&net, &frame, width, height, tiling));
            })
        };
        let whole = time(Tiling { tile: width.max(height), overlap: 0 });
        let tiled = time(Tiling::default());
        let torch_row: Option<serde_json::Value> = if let Some(script) = &script {
            let (kind, w) = match arch {
                Arch::Unet { base } => ("unet", base),
                Arch::BurstUnet { base, .. } => ("burst_unet", base),
                Arch::Shallow { width } => ("shallow", width),
            };
            torch_json(script, &["infer", kind, &w.to_string(), &height.to_string(), &width.to_string(), &repeats.to_string()])
        } else {
            None
        };
        let torch_fps = torch_row.as_ref().and_then(|t| t["frames_per_s_median"].as_f64());
        let ratio = torch_fps.map(|t| t / tiled);
        eprintln!(
            "bench: {name} ({}) {width}x{height}: {whole:.3} frames/s whole, {tiled:.3} tiled (default){}",
            arch.name(),
            match ratio {
                Some(r) => format!("; torch {:.3} frames/s = {r:.2}x ours", r * tiled),
                None => "; torch not installed, no comparison".into(),
            }
        );
        let burst = burst.map(|k| burst_speed(&net, arch, name, (&frame, width, height), k, repeats, script.as_deref()));
        out.push(DeblurSpeed {
            model: format!("models/{name}"),
            arch: arch.name(),
            width,
            height,
            whole_frames_per_s_median: whole,
            tiled_frames_per_s_median: tiled,
            torch: torch_row,
            torch_over_ours: ratio,
            torch_over_ours_whole: torch_fps.map(|t| t / whole),
            burst,
        });
    }
    Ok(out)
}

/// The median time of `repeats` runs of `f` after one warm-up run, seconds.
fn median_time(repeats: usize, f: &dyn Fn()) -> f64 {
    let mut t = Vec::new();
    for r in 0..repeats + 1 {
        let t0 = Instant::now();
        f();
        if r > 0 {
            t.push(t0.elapsed().as_secs_f64());
        }
    }
    median(&mut t)
}

/// `--burst k`: k frames of one capture against k single-frame passes of the same network, and
/// PyTorch's time for the same k frames when torch is installed.
fn burst_speed(
    net: &crate::model::fast::FastNet,
    arch: crate::model::Arch,
    name: &str,
    (frame, width, height): (&[u8], usize, usize),
    k: usize,
    repeats: usize,
    script: Option<&std::path::Path>,
) -> BurstSpeed {
    use crate::model::infer::{run_frame_burst, Tiling};
    let ts: Vec<f32> = (0..k).map(|i| (i as f32 + 0.5) / k as f32).collect();
    let once = median_time(repeats, &|| {
        std::hint::black_box(run_frame_burst(net, frame, width, height, Tiling::default(), &ts));
    });
    let passes = median_time(repeats, &|| {
        for t in &ts {
            std::hint::black_box(run_frame_burst(net, frame, width, height, Tiling::default(), std::slice::from_ref(t)));
        }
    });
    let args = [arch.width(), height, width, k, repeats].map(|v| v.to_string());
    let torch = script.and_then(|s| torch_json(s, &["burst", &args[0], &args[1], &args[2], &args[3], &args[4]]));
    eprintln!(
        "bench: {name} as {} --burst {k}: {once:.2} s for {k} frames, {passes:.2} s for {k} passes ({:.2}x)",
        arch.name(),
        once / passes
    );
    BurstSpeed { k, burst_s_median: once, k_passes_s_median: passes, ratio: once / passes, torch }
}
