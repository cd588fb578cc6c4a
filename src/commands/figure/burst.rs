//! `pipeline figure burst`: one capture and its burst as a strip. Nine sub-frames of a clip are
//! imaged through the coded and the conventional camera (AWGN of `--sigma`); each capture goes
//! through its camera's burst model for the nine sub-frames' times. Rows: the coded capture and
//! its nine outputs, the conventional capture and its nine outputs, the nine true sub-frames.
//! Beside the PNG, `OUT.mp4` shows the three rows' frames one time after another (coded |
//! conventional | true), looping well as a GIF (`ffmpeg -i OUT.mp4 OUT.gif`).

use super::{compose, FigureOptions, Score};
use crate::imaging::blur::Blurrer;
use crate::imaging::{read_out, to_8bit};
use crate::metrics::quality;
use crate::model::infer::{run_frame_burst, Tiling};
use crate::optics::transfer::{Curve, Encoder};
use crate::optics::{Camera, CameraConfig, CameraKind, OpticsConfig};
use crate::plot::Panel;
use crate::{Error, Result};
use std::path::Path;
use std::sync::Arc;

/// Sub-frames per capture in the figure.
const N: usize = 9;

/// Draws the strip into `out` (and `OUT.mp4`); returns each camera's burst scored at its first,
/// middle and last sub-frame.
pub fn burst_strip(o: &FigureOptions, clip: &Path, out: &Path) -> Result<Vec<Score>> {
    let frames = crate::commands::eval::read_frames(clip, 0, N as u64 - 1, Curve::Srgb)?;
    if frames.len() < N {
        return Err(Error::File { path: clip.to_path_buf(), why: format!("{} frames, the figure needs {N}", frames.len()) });
    }
    let (fw, fh) = (frames[0].width, frames[0].height);
    let s = o.size.min(fw).min(fh);
    let (x0, y0) = ((fw - s) / 2, (fh - s) / 2);
    let sharp: Vec<Vec<u8>> = frames.iter().map(|f| to_8bit(&f.linear_crop(x0, y0, s, s), s, s, Curve::Srgb)).collect();
    let times: Vec<f32> = (0..N).map(|k| (k as f32 + 0.5) / N as f32).collect();
    let mut rows: Vec<Vec<Panel>> = Vec::new();
    let mut outputs: Vec<Vec<Vec<u8>>> = Vec::new();
    let mut scores = Vec::new();
    for (kind, name, short) in [(CameraKind::PhaseCoded, "coded", "CODED"), (CameraKind::Conventional, "conventional", "CONVENTIONAL")] {
        let model = o.models.join(format!("burst-unet32-{name}"));
        let (net, _) = crate::model::infer::load_burst(Some(&model))?;
        let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(kind)));
        let mut b = Blurrer::new(cam.clone(), N, 0, crate::stage::coded_blur::DEFAULT_MAX_ERROR)?;
        let blur = b.blur_region(&frames, x0 as isize, y0 as isize, s, s);
        let cap = read_out(&blur, (x0, y0, s, s), &Encoder::new(Curve::Srgb), o.sigma, cam.light_throughput(), o.seed);
        let outs = run_frame_burst(&net, &cap, s, s, Tiling::default(), &times);
        let q = |k: usize, img: &[u8]| quality(img, &sharp[k], s, s);
        for (k, what) in [(0, "first"), (N / 2, "middle"), (N - 1, "last")] {
            scores.push(Score {
                camera: name.into(),
                method: format!("burst, {what} sub-frame"),
                sigma: o.sigma,
                captured: q(k, &cap),
                reconstructed: q(k, &outs[k]),
            });
        }
        let mut row = vec![Panel::from_rgb8(format!("{short} CAPTURE"), s, s, &cap)];
        row.extend(outs.iter().enumerate().map(|(k, img)| Panel::from_rgb8(format!("T{k} {:.1} DB", q(k, img).psnr_rgb), s, s, img)));
        rows.push(row);
        outputs.push(outs);
    }
    let mut truth = vec![Panel::from_rgb8("", s, s, &vec![255u8; s * s * 3])];
    truth.extend(sharp.iter().enumerate().map(|(k, img)| Panel::from_rgb8(format!("TRUE SUB-FRAME {k}"), s, s, img)));
    rows.push(truth);
    let title = format!("ONE CAPTURE, NINE SHARP FRAMES: CODED, CONVENTIONAL, TRUE (SIGMA {})", o.sigma);
    compose(out, &title, &rows.into_iter().flatten().collect::<Vec<_>>(), N + 1, 1)?;
    animation(&out.with_extension("mp4"), s, &outputs, &sharp)?;
    Ok(scores)
}

/// `coded | conventional | true` for each time, one frame each at 4 frames/s.
fn animation(path: &Path, s: usize, outputs: &[Vec<Vec<u8>>], sharp: &[Vec<u8>]) -> Result<()> {
    let (w, h) = (3 * s + 8, s + (s % 2));
    let tmp = path.with_file_name(crate::io::temp_name(&path.file_name().unwrap_or_default().to_string_lossy(), Some("mp4")));
    let mut wr = crate::io::video::VideoWriter::create(&tmp, w + (w % 2), h, (4, 1), false).map_err(Error::video(path))?;
    for k in 0..sharp.len() {
        let mut frame = vec![255u8; (w + (w % 2)) * h * 3];
        for (i, img) in [&outputs[0][k], &outputs[1][k], &sharp[k]].into_iter().enumerate() {
            for y in 0..s {
                let at = (y * (w + (w % 2)) + i * (s + 4)) * 3;
                frame[at..at + s * 3].copy_from_slice(&img[y * s * 3..(y + 1) * s * 3]);
            }
        }
        wr.write_rgb8(&frame).map_err(Error::video(path))?;
    }
    wr.finish().map_err(Error::video(path))?;
    std::fs::rename(&tmp, path).map_err(|e| Error::Io { path: path.to_path_buf(), cause: e })
}
