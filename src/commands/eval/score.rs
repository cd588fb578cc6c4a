//! The windows of each clip blurred, deblurred and scored, with the side-by-side examples.

use super::*;

/// Layout of the side-by-side PNGs: a label bar of `LABEL_H` pixels on top, then the blurred,
/// deblurred and sharp panels, each `GAP` pixels apart.
pub const LABEL_H: usize = 14;
pub const GAP: usize = 4;

fn mean_quality(q: &[&Quality]) -> Quality {
    let n = q.len().max(1) as f64;
    Quality {
        psnr_rgb: q.iter().map(|v| v.psnr_rgb).sum::<f64>() / n,
        ssim_rgb: q.iter().map(|v| v.ssim_rgb).sum::<f64>() / n,
        psnr_y: q.iter().map(|v| v.psnr_y).sum::<f64>() / n,
        ssim_y: q.iter().map(|v| v.ssim_y).sum::<f64>() / n,
    }
}

fn cell(records: &[Record], video: Option<&str>, window: usize, sigma: Option<f64>) -> Cell {
    let sel: Vec<&Record> =
        records.iter().filter(|r| r.window == window && sigma.is_none_or(|s| r.sigma == s) && video.is_none_or(|v| r.video == v)).collect();
    Cell {
        video: video.map(str::to_string),
        window,
        sigma,
        count: sel.len(),
        blurred: mean_quality(&sel.iter().map(|r| &r.blurred).collect::<Vec<_>>()),
        deblurred: mean_quality(&sel.iter().map(|r| &r.deblurred).collect::<Vec<_>>()),
        bound: {
            let b: Vec<&Quality> = sel.iter().filter_map(|r| r.bound.as_ref()).collect();
            (!b.is_empty()).then(|| (mean_quality(&b), b.len()))
        },
    }
}

/// The shaking windows (`shake`, `hand`) with a known spread, per motion, N and bin of
/// [`SPREAD_BINS`], the mean over every sigma; empty bins left out.
pub(crate) fn spread_cells(records: &[Record], windows: &[usize]) -> Vec<SpreadCell> {
    let mut out = Vec::new();
    for motion in ["shake", "hand"] {
        for &n in windows {
            for (i, &lo) in SPREAD_BINS.iter().enumerate() {
                let hi = SPREAD_BINS.get(i + 1).copied().unwrap_or(f64::INFINITY);
                let sel: Vec<&Record> = records
                    .iter()
                    .filter(|r| r.window == n && r.motion.as_deref() == Some(motion) && r.spread_px.is_some_and(|s| lo <= s && s < hi))
                    .collect();
                if sel.is_empty() {
                    continue;
                }
                out.push(SpreadCell {
                    motion: motion.into(),
                    window: n,
                    spread_px: [lo, hi],
                    count: sel.len(),
                    blurred: mean_quality(&sel.iter().map(|r| &r.blurred).collect::<Vec<_>>()),
                    deblurred: mean_quality(&sel.iter().map(|r| &r.deblurred).collect::<Vec<_>>()),
                    bound: sel.iter().map(|r| r.bound.as_ref()).collect::<Option<Vec<_>>>().map(|b| mean_quality(&b)),
                });
            }
        }
    }
    out
}

/// The region scored in a `w x h` frame: a centred square of `crop`, or the whole frame.
pub(crate) fn region(w: usize, h: usize, crop: usize) -> [usize; 4] {
    if crop == 0 || (crop >= w && crop >= h) {
        return [0, 0, w, h];
    }
    let (cw, ch) = (crop.min(w), crop.min(h));
    [(w - cw) / 2, (h - ch) / 2, cw, ch]
}

/// Draws blurred | deblurred | sharp with their PSNR above.
fn side_by_side(path: &Path, w: usize, h: usize, panels: [&[u8]; 3], labels: [String; 3]) -> Result<()> {
    let mut canvas = Canvas::new(3 * w + 2 * GAP, LABEL_H + h, [1.0; 3]);
    for (i, (rgb, label)) in panels.into_iter().zip(labels).enumerate() {
        canvas.draw_panel((i * (w + GAP), 0), LABEL_H, w, &Panel::from_rgb8(label, w, h, rgb), 1);
    }
    canvas.save(path)
}

/// Decodes the frames `first..=last` of a video (stopping early at its end), tagged linear.
pub(crate) fn read_frames(path: &Path, first: u64, last: u64, curve: Curve) -> Result<Vec<Arc<Frame>>> {
    let mut reader = VideoReader::open(path).map_err(Error::video(path))?;
    if reader.info.fps > 0.0 && reader.info.fps < crate::stage::decode::SLOW_FPS {
        eprintln!("warning: {}", crate::stage::decode::slow_footage(path, reader.info.fps));
    }
    let mut out = Vec::new();
    let mut i = 0u64;
    while i <= last {
        let Some(f) = reader.next_frame().map_err(Error::video(path))? else { break };
        if i >= first {
            out.push(Arc::new(Frame { curve: Some(curve), ..f }));
        }
        i += 1;
    }
    Ok(out)
}

/// What every window of an evaluation shares: the camera's light throughput, the longest window
/// and its half, the frames between centres, a blurrer per window length, the encoder and tiling.
pub(crate) struct Setup {
    pub throughput: f64,
    pub maxn: usize,
    pub half: u64,
    pub spacing: u64,
    pub blurrers: Vec<Blurrer>,
    pub enc: Encoder,
    pub tiling: Tiling,
}

impl Setup {
    /// # Errors
    /// A camera whose kernels cannot be made.
    pub(crate) fn new(f: &EvalFile) -> Result<Setup> {
        let e = &f.eval;
        let camera = Arc::new(Camera::new(&f.optics, &f.camera));
        let maxn = *e.windows.iter().max().expect("validated non-empty");
        Ok(Setup {
            throughput: camera.light_throughput(),
            maxn,
            half: (maxn / 2) as u64,
            spacing: if e.spacing == 0 { maxn } else { e.spacing } as u64,
            blurrers: e.windows.iter().map(|&n| Blurrer::new(camera.clone(), n, e.threads, e.max_error)).collect::<Result<Vec<_>>>()?,
            enc: Encoder::new(e.curve),
            tiling: Tiling { tile: e.tile, overlap: e.overlap },
        })
    }

    /// The frames of `path` every window of `e` reads, the region scored and the clip's motion
    /// log (if it has one).
    ///
    /// # Errors
    /// As [`Setup::frames`]; a frame too small to score.
    pub(crate) fn open(
        &self,
        path: &Path,
        e: &EvalConfig,
    ) -> Result<(Vec<Arc<Frame>>, [usize; 4], Option<crate::imaging::truth::MotionLog>)> {
        let frames = self.frames(path, e)?;
        let (w, h) = (frames[0].width, frames[0].height);
        let reg = region(w, h, e.crop);
        if reg[2] < 11 || reg[3] < 11 {
            return Err(Error::File { path: path.to_path_buf(), why: format!("{w}x{h} is too small to score (SSIM needs 11x11)") });
        }
        Ok((frames, reg, crate::imaging::truth::MotionLog::read(path)?))
    }

    /// The frames of `path` every window of `e` reads (after `e.skip`), tagged linear.
    ///
    /// # Errors
    /// The video cannot be read, or holds fewer frames than one window of the longest length.
    pub(crate) fn frames(&self, path: &Path, e: &EvalConfig) -> Result<Vec<Arc<Frame>>> {
        let first = e.skip as u64;
        let last = first + 2 * self.half + self.spacing * (e.windows_per_video as u64 - 1);
        let frames = read_frames(path, first, last, e.curve)?;
        if (frames.len() as u64) < 2 * self.half + 1 {
            return Err(Error::File {
                path: path.to_path_buf(),
                why: format!("{} frames after skipping {}, fewer than one window of {}", frames.len(), e.skip, self.maxn),
            });
        }
        Ok(frames)
    }
}

/// Runs the evaluation and writes `eval.json`, `eval.md` and `examples/` under `out`.
///
/// # Errors
/// A video that cannot be read or is too short for one window of the longest length (named),
/// an output that cannot be written.
pub fn run(
    f: &EvalFile,
    net: &FastNet,
    model: &str,
    videos: &[String],
    out: &Path,
    progress: crate::progress::ProgressMode,
) -> Result<EvalReport> {
    let t0 = Instant::now();
    let e = &f.eval;
    let paths = expand_paths(videos, crate::stage::input::VIDEO_EXTS)?;
    crate::io::make_dir_in(out, Path::new("examples"))?;
    let mut s = Setup::new(f)?;
    let (throughput, half, spacing, tiling) = (s.throughput, s.half, s.spacing, s.tiling);
    let bar = windows_bar(progress, "eval", e, paths.len());
    let top_sigma = e.sigmas.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let mut records = Vec::new();
    let example_slots = example_slots(e, paths.len());
    let mut reg = [0; 4];
    for (vi, path) in paths.iter().enumerate() {
        let first = e.skip as u64;
        let (frames, r, log) = s.open(path, e)?;
        reg = r;
        let [rx, ry, rw, rh] = reg;
        let video = path.display().to_string();
        let centres = (0..e.windows_per_video as u64).map(|k| half + k * spacing).take_while(|&c| c + half < frames.len() as u64);
        for (ci, c) in centres.enumerate() {
            let mid = &frames[c as usize];
            let sharp = to_8bit(&mid.linear_crop(rx, ry, rw, rh), rw, rh, e.curve);
            for (ni, &n) in e.windows.iter().enumerate() {
                let start = (c - (n / 2) as u64) as usize;
                let blur = s.blurrers[ni].blur_region(&frames[start..start + n], rx as isize, ry as isize, rw, rh);
                let key = hash(&[f.seed, vi as u64, first + c, n as u64, hash_str("eval-noise")]);
                let motion = log.as_ref().and_then(|l| l.kind(first + c)).map(str::to_string);
                // The window's true kernel, where its motion is a known translation of the frame.
                let shifts = log.as_ref().and_then(|l| l.shifts(first + start as u64, n, first + c));
                let spread_px = shifts.as_deref().map(|sh| (crate::render::hand::spread(sh) * 100.0).round() / 100.0);
                let truth =
                    shifts.map(|sh| (crate::imaging::truth::window_kernel(&mut s.blurrers[ni], &sh).0, mid.linear_crop(rx, ry, rw, rh)));
                for &sigma in &e.sigmas {
                    let blurred = e.read_out(&blur, (rx, ry, rw, rh), &s.enc, sigma, throughput, key);
                    let deblurred = run_frame(net, &blurred, rw, rh, tiling);
                    let (qb, qd) = (quality(&blurred, &sharp, rw, rh), quality(&deblurred, &sharp, rw, rh));
                    let bound = truth
                        .as_ref()
                        .map(|(k, lin)| wiener(k, lin, (rw, rh), e.curve, crate::imaging::sensor_sigma(sigma, throughput), key, &sharp));
                    let example = (ci == 0 && sigma == top_sigma && example_slots.contains(&(vi, n))).then(|| {
                        let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
                        format!("examples/{vi:02}-{stem}-f{:05}-n{n:02}-s{sigma}.png", first + c)
                    });
                    if let Some(name) = &example {
                        let labels = [
                            format!("N={n} SIGMA={sigma} IN {:.2} DB", qb.psnr_rgb),
                            format!("DEBLURRED {:.2} DB", qd.psnr_rgb),
                            format!("SHARP FRAME {}", first + c),
                        ];
                        side_by_side(&out.join(name), rw, rh, [&blurred, &deblurred, &sharp], labels)?;
                    }
                    records.push(Record {
                        video: video.clone(),
                        frame: first + c,
                        window: n,
                        sigma,
                        blurred: qb,
                        deblurred: qd,
                        motion: motion.clone(),
                        bound,
                        spread_px,
                        example,
                    });
                    bar.inc(1);
                    bar.set_message(format!("{} N={n} sigma={sigma}", path.file_name().unwrap_or_default().to_string_lossy()));
                }
            }
        }
    }
    bar.finish();
    let videos = paths.iter().map(|p| p.display().to_string()).collect();
    write_report(f, model, videos, reg, t0.elapsed().as_secs_f64(), records, out)
}

/// The quality of the Wiener reconstruction of `lin` (a `w x h` region, linear) told its true
/// kernels `k`, with the noise of `sigma` (8-bit levels, already scaled for the camera's light).
fn wiener(k: &[Vec<f32>; 3], lin: &[Vec<f32>; 3], (w, h): (usize, usize), curve: Curve, sigma: f64, key: u64, sharp: &[u8]) -> Quality {
    let var = crate::imaging::truth::linear_noise_var(lin, curve, sigma);
    let rec: [Vec<f32>; 3] = std::array::from_fn(|ch| crate::recon::wiener_bound(&lin[ch], w, h, &k[ch], var[ch], key ^ ch as u64).1);
    quality(&to_8bit(&rec, w, h, curve), sharp, w, h)
}

/// The progress bar of an eval over `videos` clips: one step per window and sigma.
pub(crate) fn windows_bar(progress: crate::progress::ProgressMode, name: &str, e: &EvalConfig, videos: usize) -> crate::progress::Bar {
    let total = (videos * e.windows_per_video * e.windows.len() * e.sigmas.len()) as u64;
    crate::progress::Bar::new(progress, name, "windows", Some(total))
}

/// Where the side-by-side examples go: spread evenly over the videos (different content, not N
/// after N of the first clip), each at its video's first sharp frame and the largest sigma: the
/// middle window length, then the next ones where a video gets more than one. (video, N) pairs.
fn example_slots(e: &EvalConfig, videos: usize) -> Vec<(usize, usize)> {
    let mut slots: Vec<(usize, usize)> = Vec::new();
    for i in 0..e.examples {
        let vi = i * videos / e.examples;
        let earlier = slots.iter().filter(|s| s.0 == vi).count();
        slots.push((vi, e.windows[(e.windows.len() / 2 + earlier) % e.windows.len()]));
    }
    slots
}

/// The tables of `records`, written as `eval.json` and `eval.md` under `out`.
fn write_report(
    f: &EvalFile,
    model: &str,
    videos: Vec<String>,
    region: [usize; 4],
    seconds: f64,
    records: Vec<Record>,
    out: &Path,
) -> Result<EvalReport> {
    let e = &f.eval;
    let table = e.windows.iter().map(|&n| cell(&records, None, n, None)).collect();
    let per_sigma =
        e.windows.iter().flat_map(|&n| e.sigmas.iter().map(move |&s| (n, s))).map(|(n, s)| cell(&records, None, n, Some(s))).collect();
    let mut seen: Vec<&str> = Vec::new();
    for r in &records {
        if !seen.contains(&r.video.as_str()) {
            seen.push(&r.video);
        }
    }
    let per_video = seen.iter().flat_map(|v| e.windows.iter().map(|&n| cell(&records, Some(v), n, None))).collect();
    let per_spread = spread_cells(&records, &e.windows);
    let report = EvalReport {
        version: env!("CARGO_PKG_VERSION"),
        model: model.into(),
        camera: f.camera.kind.name().into(),
        convention: crate::metrics::CONVENTION,
        config: f.clone(),
        videos,
        region,
        seconds,
        table,
        per_sigma,
        per_video,
        per_spread,
        records,
        versus: None,
    };
    let json = serde_json::to_vec_pretty(&report).expect("json");
    write_atomic(&out.join("eval.json"), |w| w.write_all(&json))?;
    let md = markdown(&report);
    write_atomic(&out.join("eval.md"), |w| w.write_all(md.as_bytes()))?;
    Ok(report)
}
