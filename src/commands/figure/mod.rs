//! `pipeline figure`: the paper's comparison figures, computed from the optics, the scene
//! renderer, the classical reconstructions and the shipped networks.
//!
//! - `psf-strip` (Fig. 2): a point moving to the right, seen by a conventional camera, by a
//!   focus sweep without the mask, and by the coded camera.
//! - `dots` (Fig. 3): the moving-dots scene through all four cameras.
//! - `spectrum` (Fig. 4): the (x, t) slice of a moving point's PSF, its 2-D Fourier amplitude
//!   and phase per colour, for each camera.
//! - `spoke` (Fig. 5): a rotating spoke target captured by each camera and reconstructed by each
//!   method, with PSNR/SSIM in a table beside the figure.
//!
//! Every capture sums the scene's sub-frames through the camera's kernels in linear light,
//! re-encodes to sRGB and adds AWGN of `sigma` on the 0-255 scale; the fluttered shutter's image,
//! brought to the same brightness, gets `sigma / 0.5` (it collects half the light).

#[cfg(feature = "ffmpeg")]
mod burst;
use crate::frame::{Frame, FrameData};
use crate::imaging::blur::Blurrer;
use crate::io::write_atomic;
use crate::metrics::{quality, Quality};
use crate::optics::config::Axis;
use crate::optics::transfer::{Curve, Encoder};
use crate::optics::{Camera, CameraConfig, CameraKind, OpticsConfig};
use crate::plot::{Canvas, Panel};
use crate::recon::{lucy_richardson, Ends, FlutterSolver};
use crate::render::scene::{SceneKind, SceneParams};
use crate::rng::{hash, hash_str};
use crate::{Error, Result};
use rustfft::num_complex::Complex64;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Which figure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[value(rename_all = "kebab-case")]
pub enum FigureName {
    PsfStrip,
    Dots,
    Spectrum,
    Spoke,
    /// One capture and its burst (needs `burst-unet32-coded` and `-conventional` under --models).
    Burst,
}

/// Settings shared by the figures.
#[derive(Debug, Clone, serde::Serialize)]
pub struct FigureOptions {
    /// AWGN sigma on the 0-255 scale (doubled for the fluttered shutter).
    pub sigma: f64,
    pub seed: u64,
    /// Scene side in pixels.
    pub size: usize,
    /// Sub-frames per exposure (52: one per chop of the flutter code).
    pub frames: usize,
    /// Travel over the exposure of the fastest dot / the spoke target's rim, pixels.
    pub travel_px: f64,
    /// Folder of the shipped models (`unet32-coded`, `unet32-conventional`).
    pub models: PathBuf,
    /// Lucy-Richardson iterations for the parabolic camera.
    pub lr_iterations: usize,
    /// Regularisation of the flutter least squares.
    pub flutter_lambda: f64,
    /// The high-frame-rate clip whose first nine frames the burst figure captures.
    pub clip: PathBuf,
}

impl Default for FigureOptions {
    fn default() -> Self {
        FigureOptions {
            sigma: 3.0,
            seed: 0,
            size: 192,
            frames: 52,
            travel_px: 16.0,
            models: PathBuf::from("models"),
            lr_iterations: 30,
            flutter_lambda: 1e-2,
            clip: PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/mandelbrot-pan-240fps.mp4")),
        }
    }
}

/// What a figure reports beside its PNG.
#[derive(Debug, serde::Serialize)]
pub struct FigureReport {
    pub figure: FigureName,
    pub options: FigureOptions,
    pub png: String,
    /// Spoke figure: each captured and reconstructed image against the sharp mid-exposure frame.
    pub scores: Vec<Score>,
    pub convention: &'static str,
}

#[derive(Debug, serde::Serialize)]
pub struct Score {
    pub camera: String,
    pub method: String,
    pub sigma: f64,
    pub captured: Quality,
    pub reconstructed: Quality,
}

/// The cameras of the comparison: diffraction on for all (the coded camera has it anyway),
/// the parabolic sweep along x sized so that speeds up to 1.25 x `travel_px` are in its range.
fn camera(kind: CameraKind, travel_px: f64) -> Camera {
    let cfg = CameraConfig {
        kind,
        diffraction: true,
        parabolic_axis: Axis::X,
        parabolic_amplitude_px: (1.25 * travel_px / 4.0).max(1.0),
        ..CameraConfig::new(kind)
    };
    Camera::new(&OpticsConfig::default(), &cfg)
}

fn label(kind: CameraKind) -> &'static str {
    match kind {
        CameraKind::Conventional => "CONVENTIONAL",
        CameraKind::FocusSweep => "FOCUS SWEEP, NO MASK",
        CameraKind::PhaseCoded => "PHASE CODED (OURS)",
        CameraKind::Flutter => "FLUTTERED SHUTTER",
        CameraKind::Parabolic => "PARABOLIC MOTION",
        CameraKind::Measured => "MEASURED PSFS",
    }
}

const LABEL_BAR: usize = 16;
const MARGIN: usize = 8;

/// Lays panels out in a grid (`cols` wide), each scaled by `scale` (nearest), with its label
/// above and a title line on top; writes the PNG.
pub(crate) fn compose(path: &Path, title: &str, panels: &[Panel], cols: usize, scale: usize) -> Result<()> {
    let cw = panels.iter().map(|p| p.w * scale).max().unwrap_or(0).max(160);
    let ch = panels.iter().map(|p| p.h * scale).max().unwrap_or(0);
    let rows = panels.len().div_ceil(cols);
    let mut canvas = Canvas::new(MARGIN + cols * (cw + MARGIN), 2 * LABEL_BAR + rows * (ch + LABEL_BAR + MARGIN), [1.0; 3]);
    canvas.text(MARGIN, 4, title, [0.0, 0.0, 0.0]);
    for (i, p) in panels.iter().enumerate() {
        let (x0, y0) = (MARGIN + (i % cols) * (cw + MARGIN), 2 * LABEL_BAR + (i / cols) * (ch + LABEL_BAR + MARGIN));
        canvas.draw_panel((x0, y0), LABEL_BAR, cw, p, scale);
    }
    canvas.save(path)
}

/// Sums the sub-frames through a camera (linear light), re-encodes and adds noise: the 8-bit
/// capture and the sigma that reached it (scaled by the camera's light throughput).
fn capture(frames: &[[Vec<f32>; 3]], w: usize, h: usize, cam: &Arc<Camera>, sigma: f64, key: u64) -> Result<(Vec<u8>, f64)> {
    let lin: Vec<Arc<Frame>> =
        frames.iter().map(|p| Arc::new(Frame { curve: Some(Curve::Identity), ..Frame::new(w, h, FrameData::Planar(p.clone())) })).collect();
    let mut b = Blurrer::new(cam.clone(), frames.len(), 0, crate::stage::coded_blur::DEFAULT_MAX_ERROR)?;
    let rgb = crate::imaging::capture(&mut b, &lin, (0, 0, w, h), &Encoder::new(Curve::Srgb), sigma, key);
    Ok((rgb, crate::imaging::sensor_sigma(sigma, cam.light_throughput())))
}

fn encode(p: &[Vec<f32>; 3], w: usize, h: usize) -> Vec<u8> {
    crate::imaging::to_8bit(p, w, h, Curve::Srgb)
}

fn linear(rgb: &[u8]) -> [Vec<f32>; 3] {
    crate::imaging::from_8bit(rgb, rgb.len() / 3, 1, Curve::Srgb)
}

/// Fig. 2: a point moving right over the exposure, per camera.
fn psf_strip(o: &FigureOptions, out: &Path) -> Result<Vec<Score>> {
    let travel = 2.0 * o.travel_px;
    let half = (travel / 2.0) as usize + 14;
    let side = 2 * half + 1;
    let mut panels = Vec::new();
    for kind in [CameraKind::Conventional, CameraKind::FocusSweep, CameraKind::PhaseCoded] {
        let p = camera(kind, o.travel_px).moving_point(o.frames, [travel, 0.0], half)?;
        panels.push(Panel::from_linear_normalised(label(kind), side, side, &p));
    }
    let title = format!("MOVING POINT, {travel} PX TO THE RIGHT, PSI 0 TO 8 (SWEEPS)");
    compose(out, &title, &panels, 3, 4)?;
    Ok(Vec::new())
}

/// Fig. 3: moving dots through every camera.
fn dots(o: &FigureOptions, out: &Path) -> Result<Vec<Score>> {
    // Long traces (3.25 x travel: 52 px, one per flutter chop, at the default) so that the
    // shutter's code and the colour changes can be seen along them.
    let travel = 3.25 * o.travel_px;
    // Two dots per arm on a canvas of 5 x travel, so that no two paths overlap.
    let size = o.size.max((5.0 * travel) as usize);
    let s = SceneParams {
        kind: SceneKind::Dots,
        width: size,
        height: size,
        frames: o.frames,
        travel_px: travel,
        dots_per_arm: 2,
        ..Default::default()
    };
    // Dots bright enough that their smeared traces sit well above the noise (clipped when still).
    let gain = (travel / 4.0).max(1.0) as f32;
    let frames: Vec<[Vec<f32>; 3]> = s.render().into_iter().map(|p| p.map(|c| c.into_iter().map(|v| v * gain).collect())).collect();
    let (w, h) = (s.width, s.height);
    let show = |p: &[Vec<f32>; 3]| -> Vec<u8> { dilate(&encode(p, w, h), w, h) };
    // Panel (a) with each dot's path to its last position drawn in orange, as the paper's arrows.
    let mut first = show(&frames[0]);
    for d in s.dots() {
        let (a, b) = ([d.pos[0] - d.vel[0], d.pos[1] - d.vel[1]], [d.pos[0] + d.vel[0], d.pos[1] + d.vel[1]]);
        let steps = ((b[0] - a[0]).abs() + (b[1] - a[1]).abs()).ceil() as usize;
        for i in 2..steps {
            let f = i as f64 / steps as f64;
            let (x, y) = ((a[0] + (b[0] - a[0]) * f - 0.5).round() as usize, (a[1] + (b[1] - a[1]) * f - 0.5).round() as usize);
            if x < w && y < h && first[(y * w + x) * 3] < 128 {
                first[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&[230, 140, 0]);
            }
        }
    }
    let mut panels = vec![
        Panel::from_rgb8("(A) FIRST SUB-FRAME, PATHS", w, h, &first),
        Panel::from_rgb8("(B) LAST SUB-FRAME", w, h, &show(&frames[frames.len() - 1])),
    ];
    for (i, kind) in [CameraKind::Conventional, CameraKind::Flutter, CameraKind::Parabolic, CameraKind::PhaseCoded].into_iter().enumerate()
    {
        let key = hash(&[o.seed, i as u64, hash_str("figure-dots")]);
        let (img, sigma) = capture(&frames, w, h, &Arc::new(camera(kind, travel)), o.sigma, key)?;
        panels.push(Panel::from_rgb8(format!("({}) {} SIGMA {sigma}", (b'C' + i as u8) as char, label(kind)), w, h, &dilate(&img, w, h)));
    }
    let title = format!("MOVING DOTS, FASTEST {travel} PX PER EXPOSURE, 3X3 DILATION");
    compose(out, &title, &panels, 2, 2)?;
    Ok(Vec::new())
}

/// 3x3 maximum filter of interleaved 8-bit RGB, for seeing single-pixel dots.
fn dilate(rgb: &[u8], w: usize, h: usize) -> Vec<u8> {
    let mut out = rgb.to_vec();
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                let mut m = 0u8;
                for yy in y.saturating_sub(1)..(y + 2).min(h) {
                    for xx in x.saturating_sub(1)..(x + 2).min(w) {
                        m = m.max(rgb[(yy * w + xx) * 3 + c]);
                    }
                }
                out[(y * w + x) * 3 + c] = m;
            }
        }
    }
    out
}

/// The (x, t) slice of a point moving `travel` px along x: row k is sub-frame k's PSF through
/// y = 0, shifted to where the point is. Per channel, `x_len x n`.
pub fn xt_slice(cam: &Camera, n: usize, travel: f64, x_len: usize) -> Result<[Vec<f64>; 3]> {
    let half = x_len / 2;
    let side = 2 * half + 1;
    let mut out: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; x_len * n]);
    for (k, kern) in cam.moving_kernels(n, [travel, 0.0])?.into_iter().enumerate() {
        // Each row at the sub-frame's own brightness (not its share of the exposure).
        let kern = crate::optics::camera::SubframeKernel { weight: kern.weight * n as f64, ..kern };
        for (c, o) in out.iter_mut().enumerate() {
            let img = kern.render_cropped(c, half);
            for x in 0..x_len {
                o[k * x_len + x] = img[half * side + x] as f64;
            }
        }
    }
    Ok(out)
}

/// 2-D DFT of a row-major `w x h` real image whose origin is its centre pixel (w/2, h/2), with
/// zero frequency moved to the centre: a centred symmetric image has a real spectrum, so the
/// phase shows the image's asymmetries, not where it sits.
pub fn fft2_centred(img: &[f64], w: usize, h: usize) -> Vec<Complex64> {
    let mut a = vec![Complex64::new(0.0, 0.0); w * h];
    for y in 0..h {
        for x in 0..w {
            a[((y + h - h / 2) % h) * w + (x + w - w / 2) % w] = Complex64::new(img[y * w + x], 0.0);
        }
    }
    crate::optics::fft::fft2_f64(&mut a, w, h);
    let mut out = vec![Complex64::new(0.0, 0.0); w * h];
    for y in 0..h {
        for x in 0..w {
            out[((y + h / 2) % h) * w + (x + w / 2) % w] = a[y * w + x];
        }
    }
    out
}

/// Fig. 4: (x, t) PSF, Fourier amplitude (log) and phase, per colour, for each camera.
fn spectrum(o: &FigureOptions, out: &Path) -> Result<Vec<Score>> {
    let (x_len, n) = (96, 64);
    let travel = 2.0 * o.travel_px;
    let mut panels = Vec::new();
    for kind in [CameraKind::Conventional, CameraKind::Flutter, CameraKind::Parabolic, CameraKind::PhaseCoded] {
        let small = xt_slice(&camera(kind, o.travel_px), n, travel, x_len)?;
        // Zero-padded to twice the size in x and t: the spectrum is sampled twice as finely, so
        // the continuous transform (a sinc along the exposure's box) shows instead of the DFT's
        // sampling pattern of it.
        let (x_len, n) = (2 * x_len, 2 * n);
        let xt: [Vec<f64>; 3] = std::array::from_fn(|c| {
            let mut v = vec![0.0; x_len * n];
            for t in 0..n / 2 {
                v[(t + n / 4) * x_len + x_len / 4..(t + n / 4) * x_len + x_len / 4 + x_len / 2]
                    .copy_from_slice(&small[c][t * x_len / 2..(t + 1) * x_len / 2]);
            }
            v
        });
        let specs: Vec<Vec<Complex64>> = xt.iter().map(|p| fft2_centred(p, x_len, n)).collect();
        let xt32: [Vec<f32>; 3] = std::array::from_fn(|c| xt[c].iter().map(|&v| v as f32).collect());
        panels.push(Panel::from_linear_normalised(format!("{} (X,T)", label(kind)), x_len, n, &xt32));
        // log(1 + |F| / max |F|) per channel, scaled to [0, 1].
        let amp: [Vec<f32>; 3] = std::array::from_fn(|c| {
            let m = specs[c].iter().map(|z| z.norm()).fold(1e-300, f64::max);
            specs[c].iter().map(|z| ((1.0 + 1000.0 * z.norm() / m).ln() / 1001f64.ln()) as f32).collect()
        });
        panels.push(Panel { label: "FT AMPLITUDE (LOG)".into(), w: x_len, h: n, px: amp });
        // Phase where the amplitude is above 1% of its peak (elsewhere it is numerical noise):
        // -pi black ... +pi white per channel, so equal phases in R, G and B show grey.
        let phase: [Vec<f32>; 3] = std::array::from_fn(|c| {
            let m = specs[c].iter().map(|z| z.norm()).fold(1e-300, f64::max);
            specs[c]
                .iter()
                .map(|z| if z.norm() > 0.01 * m { ((z.arg() + std::f64::consts::PI) / std::f64::consts::TAU) as f32 } else { 0.5 })
                .collect()
        });
        panels.push(Panel { label: "FT PHASE, AMP OVER 1%".into(), w: x_len, h: n, px: phase });
    }
    let title = format!("(X,T) SLICE OF A POINT MOVING {travel} PX (ZERO-PADDED 2X); 2-D FT PER COLOUR (R,G,B = CHANNELS)");
    compose(out, &title, &panels, 3, 1)?;
    Ok(Vec::new())
}

/// Fig. 5: rotating spoke target, captures and reconstructions, scored.
fn spoke(o: &FigureOptions, out: &Path) -> Result<Vec<Score>> {
    let s = SceneParams {
        kind: SceneKind::Spoke,
        width: o.size,
        height: o.size,
        frames: o.frames,
        travel_px: o.travel_px,
        spokes: 12,
        ..Default::default()
    };
    let (w, h) = (s.width, s.height);
    let frames = s.render();
    let sharp = encode(&s.render_at(0.0), w, h);
    let model = |name: &str| -> Result<crate::model::fast::FastNet> {
        let p = o.models.join(name).join("model.safetensors");
        if !p.exists() {
            return Err(Error::Usage(format!("{}: no such model (run from the repository or pass --models DIR)", p.display())));
        }
        Ok(crate::model::infer::load(Some(&p))?.0)
    };
    let tiling = crate::model::infer::Tiling::default();
    let mut panels = vec![Panel::from_rgb8("(A) ROTATING TARGET, SHARP", w, h, &sharp)];
    let mut recon_panels = vec![Panel { label: String::new(), w, h, px: std::array::from_fn(|_| vec![1.0; w * h]) }];
    let mut scores = Vec::new();
    for (i, kind) in [CameraKind::Conventional, CameraKind::Flutter, CameraKind::Parabolic, CameraKind::PhaseCoded].into_iter().enumerate()
    {
        let cam = Arc::new(camera(kind, o.travel_px));
        let key = hash(&[o.seed, i as u64, hash_str("figure-spoke")]);
        let (img, sigma) = capture(&frames, w, h, &cam, o.sigma, key)?;
        let (method, rec) = match kind {
            CameraKind::Conventional => {
                ("U-Net 32 (conventional)", crate::model::infer::run_frame(&model("unet32-conventional")?, &img, w, h, tiling))
            }
            CameraKind::PhaseCoded => ("U-Net 32 (coded)", crate::model::infer::run_frame(&model("unet32-coded")?, &img, w, h, tiling)),
            CameraKind::Flutter => {
                // The code for motion to the right over the rim's extent, as in the paper.
                let solver = FlutterSolver::new(w, &cam.weights(o.frames), o.travel_px, Ends::Extend, o.flutter_lambda);
                ("least squares, right, rim extent", encode(&solver.solve_planes(&linear(&img), h), w, h))
            }
            _ => {
                // The parabolic camera's one kernel: a still point through the sweep.
                let kernel_half = 4
                    + (cam.config().parabolic_amplitude_px.ceil() as usize)
                    + cam.window(o.frames)?.iter().map(|k| k.psf.half()).max().unwrap_or(0);
                let still = cam.moving_point(o.frames, [0.0, 0.0], kernel_half)?;
                let lin = linear(&img);
                let rec: [Vec<f32>; 3] = std::array::from_fn(|c| lucy_richardson(&lin[c], w, h, &still[c], o.lr_iterations));
                ("Lucy-Richardson", encode(&rec, w, h))
            }
        };
        let (qc, qr) = (quality(&img, &sharp, w, h), quality(&rec, &sharp, w, h));
        panels.push(Panel::from_rgb8(format!("{} SIGMA {sigma}: {:.1} DB", label(kind), qc.psnr_rgb), w, h, &img));
        recon_panels.push(Panel::from_rgb8(format!("REC. {:.1} DB", qr.psnr_rgb), w, h, &rec));
        scores.push(Score { camera: kind.name().into(), method: method.into(), sigma, captured: qc, reconstructed: qr });
    }
    panels.extend(recon_panels);
    let title = format!(
        "ROTATING SPOKE TARGET, RIM {} PX PER EXPOSURE, SIGMA {} (FLUTTER X2); TOP CAPTURED, BOTTOM RECONSTRUCTED",
        o.travel_px, o.sigma
    );
    compose(out, &title, &panels, 5, 1)?;
    Ok(scores)
}

/// Markdown table of a spoke figure's scores.
pub fn scores_markdown(r: &FigureReport) -> String {
    let what = match r.figure {
        FigureName::Burst => format!(
            "The first nine frames of {} ({} px crop), each burst output against its own sub-frame",
            r.options.clip.display(),
            r.options.size
        ),
        _ => format!(
            "Spoke target {} px, rim travel {} px over {} sub-frames. Against the sharp mid-exposure frame",
            r.options.size, r.options.travel_px, r.options.frames
        ),
    };
    let mut s = format!("# pipeline figure {:?}\n\n![{}]({})\n\n{what}; {}.\n\n", r.figure, r.png, r.png, r.convention);
    s.push_str(
        "| camera | sigma | captured PSNR / SSIM | reconstruction | reconstructed PSNR / SSIM | gain dB |\n|---|---|---|---|---|---|\n",
    );
    for x in &r.scores {
        s.push_str(&format!(
            "| {} | {} | {:.2} / {:.4} | {} | {:.2} / {:.4} | {:+.2} |\n",
            x.camera,
            x.sigma,
            x.captured.psnr_rgb,
            x.captured.ssim_rgb,
            x.method,
            x.reconstructed.psnr_rgb,
            x.reconstructed.ssim_rgb,
            x.reconstructed.psnr_rgb - x.captured.psnr_rgb
        ));
    }
    s
}

/// Draws a figure into `out` (PNG); the spoke figure also writes `out` with `.md` and `.json`.
///
/// # Errors
/// A model that is missing (spoke), an output that cannot be written.
pub fn draw(name: FigureName, o: &FigureOptions, out: &Path) -> Result<FigureReport> {
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| Error::Io { path: dir.to_path_buf(), cause: e })?;
    }
    let scores = match name {
        FigureName::PsfStrip => psf_strip(o, out)?,
        FigureName::Dots => dots(o, out)?,
        FigureName::Spectrum => spectrum(o, out)?,
        FigureName::Spoke => spoke(o, out)?,
        #[cfg(feature = "ffmpeg")]
        FigureName::Burst => burst::burst_strip(o, &o.clip, out)?,
        #[cfg(not(feature = "ffmpeg"))]
        FigureName::Burst => return Err(Error::Usage("figure burst reads a video: it needs a build with the `ffmpeg` feature".into())),
    };
    let r = FigureReport {
        figure: name,
        options: o.clone(),
        png: out.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default(),
        scores,
        convention: crate::metrics::CONVENTION,
    };
    if matches!(name, FigureName::Spoke | FigureName::Burst) {
        let json = serde_json::to_vec_pretty(&r).expect("json");
        write_atomic(&out.with_extension("json"), |w| w.write_all(&json))?;
        let md = scores_markdown(&r);
        write_atomic(&out.with_extension("md"), |w| w.write_all(md.as_bytes()))?;
    }
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::scene::sub_time;

    #[test]
    fn flutter_capture_of_an_object_moving_right_is_undone_by_least_squares() {
        // A textured object 80 px wide on black, moving right 104 px (two per chop, so chops start
        // on whole pixels; half-pixel starts would add a [0.5, 0.5] smear with a zero at Nyquist)
        // over 52 sub-frames, so that its whole smear lies inside the 240-px row (Raskar's
        // setting); captured by the fluttered shutter through the same path as the figures, with
        // only 8-bit rounding as noise.
        let (w, h, n, travel) = (240, 6, 52, 104.0);
        let tex = |x: f64, y: usize, c: usize| -> f32 {
            if !(80.0..159.0).contains(&x) {
                return 0.0;
            }
            let x0 = x.floor();
            let v = |xi: f64| 0.2 + 0.6 * crate::rng::unit(hash(&[xi as u64, y as u64, c as u64])) as f32;
            let f = (x - x0) as f32;
            v(x0) * (1.0 - f) + v(x0 + 1.0) * f
        };
        let frames: Vec<[Vec<f32>; 3]> = (0..n)
            .map(|k| {
                let d = travel / 2.0 * sub_time(k, n);
                std::array::from_fn(|c| (0..w * h).map(|i| tex((i % w) as f64 - d, i / w, c)).collect())
            })
            .collect();
        let sharp: [Vec<f32>; 3] = std::array::from_fn(|c| (0..w * h).map(|i| tex((i % w) as f64, i / w, c)).collect());
        let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::Flutter)));
        let weights = cam.weights(n);
        let (img, sigma) = capture(&frames, w, h, &cam, 0.0, 1).unwrap();
        assert_eq!(sigma, 0.0);
        let rec = FlutterSolver::new(w, &weights, travel, Ends::Extend, 1e-6).solve_planes(&linear(&img), h);
        let rmse = |p: &[Vec<f32>; 3]| {
            let d: Vec<f64> = (0..3).flat_map(|c| p[c].iter().zip(&sharp[c]).map(|(a, b)| (a - b) as f64)).collect();
            (d.iter().map(|v| v * v).sum::<f64>() / d.len() as f64).sqrt()
        };
        let (before, after) = (rmse(&linear(&img)), rmse(&rec));
        // 8-bit rounding, amplified by the inverse, is what is left (measured: 0.169 -> 0.029).
        assert!(after < 0.25 * before, "rmse captured {before}, reconstructed {after}");
    }

    #[test]
    fn fft2_of_a_centred_delta_is_flat_and_the_xt_slice_is_a_line() {
        let (w, h) = (8, 6);
        let mut img = vec![0.0; w * h];
        img[(h / 2) * w + w / 2] = 1.0;
        // A delta at the origin: flat amplitude and zero phase everywhere.
        assert!(fft2_centred(&img, w, h).iter().all(|z| (z.re - 1.0).abs() < 1e-12 && z.im.abs() < 1e-12));
        // A conventional camera without diffraction: row k holds one pixel where the point is.
        let cam = Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::Conventional));
        let xt = xt_slice(&cam, 8, 14.0, 32).unwrap();
        for k in 0..8 {
            let row = &xt[1][k * 32..(k + 1) * 32];
            let x = 7.0 * sub_time(k, 8) + 16.0;
            let centroid = row.iter().enumerate().map(|(i, v)| i as f64 * v).sum::<f64>() / row.iter().sum::<f64>();
            assert!((centroid - x).abs() < 1e-9, "row {k}: {centroid} vs {x}");
        }
    }
}

#[derive(clap::Args, Debug)]
pub struct FigureArgs {
    /// Which figure.
    #[arg(value_enum)]
    pub name: FigureName,
    /// Output PNG.
    #[arg(short, long)]
    pub out: PathBuf,
    /// AWGN sigma on the 0-255 scale (the fluttered shutter gets twice: half the light).
    #[arg(long, default_value_t = 3.0)]
    pub sigma: f64,
    /// Pixels travelled over the exposure by the fastest dot / the spoke target's rim.
    #[arg(long, default_value_t = 16.0)]
    pub travel: f64,
    /// Scene side in pixels.
    #[arg(long, default_value_t = 192)]
    pub size: usize,
    /// Folder with the shipped models (unet32-coded, unet32-conventional).
    #[arg(long, default_value = "models")]
    pub models: PathBuf,
    /// Seed of the noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Lucy-Richardson iterations for the parabolic camera (spoke).
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub lr_iterations: u32,
    /// Tikhonov weight of the flutter least squares (spoke), above 0: an image row does not
    /// see the scene beyond the frame, so plain least squares is singular there.
    #[arg(long, default_value_t = 1e-2)]
    pub flutter_lambda: f64,
    /// burst: the high-frame-rate clip whose first nine frames are captured (default: the
    /// shipped 240 fps fixture).
    #[arg(long)]
    pub clip: Option<PathBuf>,
}

/// Runs `pipeline figure`.
///
/// # Errors
/// Whatever the command reports (exit codes in `main.rs`).
pub fn command(a: FigureArgs) -> anyhow::Result<()> {
    let FigureArgs { name, out, sigma, travel, size, models, seed, lr_iterations, flutter_lambda, clip } = a;
    if !(0.0..=50.0).contains(&sigma) || !(0.0..=200.0).contains(&travel) || !(32..=2048).contains(&size) {
        return Err(crate::Error::Usage("--sigma must be in 0..50, --travel in 0..200 and --size in 32..2048".into()).into());
    }
    if !(flutter_lambda > 0.0 && flutter_lambda <= 10.0) {
        return Err(crate::Error::Usage(format!("--flutter-lambda must be above 0 and at most 10 (got {flutter_lambda})")).into());
    }
    // The default names the repository's models: from another folder, the build's own checkout.
    let models = if models == Path::new("models") && !models.is_dir() {
        PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/models"))
    } else {
        models
    };
    let o = crate::commands::figure::FigureOptions {
        sigma,
        travel_px: travel,
        size,
        models,
        seed,
        lr_iterations: lr_iterations as usize,
        flutter_lambda,
        clip: clip.unwrap_or_else(|| crate::commands::figure::FigureOptions::default().clip),
        ..Default::default()
    };
    let r = crate::commands::figure::draw(name, &o, &out)?;
    if !r.scores.is_empty() {
        println!("{}", crate::commands::figure::scores_markdown(&r));
    }
    eprintln!("figure {:?} -> {}", name, out.display());
    Ok(())
}
