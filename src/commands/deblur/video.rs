//! A video deblurred frame by frame into a video of the same size (at K times the rate with
//! `--burst K`), written to a temporary and renamed when whole.

use super::{remove_stale, temp_for, to_rgb8, DeblurReport};
use crate::model::fast::FastNet;
use crate::model::infer::Tiling;
use crate::progress::{Bar, ProgressMode};
use crate::{Error, Result};
use std::path::Path;
use std::time::Instant;

/// Deblurs a video into a video of the same size and frame rate; with `times`, a burst per frame:
/// the output at each time, in order, so the video comes back at `times.len()` times the frame
/// rate (a coded 26.7 fps clip of 240 fps footage deblurred into 9 frames each comes back at 240 fps).
///
/// # Errors
/// The input cannot be decoded, the output cannot be written (named); nothing is left at the
/// output path on failure.
#[allow(clippy::too_many_arguments)]
pub fn video(
    net: &FastNet,
    model_name: &str,
    input: &Path,
    output: &Path,
    tiling: Tiling,
    lossless: bool,
    progress: ProgressMode,
    times: Option<&[f32]>,
) -> Result<DeblurReport> {
    use crate::io::video::{VideoReader, VideoWriter};
    crate::signal::install();
    let t0 = Instant::now();
    remove_stale(&[output.to_path_buf()]);
    let mut reader = VideoReader::open(input).map_err(Error::video(input))?;
    let (w, h) = (reader.info.width, reader.info.height);
    if lossless && output.extension().and_then(|e| e.to_str()) != Some("mkv") {
        return Err(Error::Usage(format!("{}: --lossless writes FFV1, which needs a .mkv output", output.display())));
    }
    let tmp = temp_for(output);
    let k = times.map_or(1, <[f32]>::len);
    let rate = (reader.rate.0.saturating_mul(k as i32), reader.rate.1);
    let mut writer = VideoWriter::create(&tmp, w, h, rate, lossless).map_err(Error::video(output))?;
    let bar = Bar::new(progress, "deblur", "frames", reader.info.frames_announced);
    let result = (|| -> Result<u64> {
        let stopped = || Error::Interrupted(format!("{}: the unfinished video was removed; run the same command again", output.display()));
        while let Some(f) = reader.next_frame().map_err(Error::video(input))? {
            if crate::signal::interrupted() {
                return Err(stopped());
            }
            let rgb = to_rgb8(&f, reader.float);
            let outs = match times {
                Some(ts) => crate::model::infer::run_frame_burst(net, &rgb, w, h, tiling, ts),
                None => vec![crate::model::infer::run_frame(net, &rgb, w, h, tiling)],
            };
            // A signal between two tiles stops the frame; what came back is not written.
            if crate::signal::interrupted() {
                return Err(stopped());
            }
            for out in outs {
                writer.write_rgb8(&out).map_err(Error::video(output))?;
            }
            bar.inc(1);
        }
        bar.finish();
        let n = writer.finish().map_err(Error::video(output))?;
        std::fs::rename(&tmp, output).map_err(|e| Error::Io { path: output.to_path_buf(), cause: e })?;
        Ok(n)
    })();
    let frames = match result {
        Ok(n) => n,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
    };
    let mut r = DeblurReport::new(
        input,
        output,
        model_name,
        frames,
        (w, h),
        Some(reader.info.fps * k as f64),
        tiling,
        t0,
        "not copied: deblur writes the video stream only",
    );
    // A millisecond is beyond any constant-rate container's rounding of its timestamps.
    if reader.retimed_s > 1e-3 {
        let ms = (reader.retimed_s * 1e4).round() / 10.0;
        eprintln!(
            "note: {} has a variable frame rate: the output runs at a constant {:.3} fps, frames moved by up to {ms} ms from their own times",
            input.display(),
            reader.info.fps * k as f64
        );
        r.retimed_ms = Some(ms);
    }
    Ok(r)
}
