use super::*;

pub(super) fn ffmpeg_cli(args: &[&str]) -> crate::Result<()> {
    let st = std::process::Command::new("ffmpeg").args(["-v", "error", "-y"]).args(args).status().map_err(|e| crate::Error::Program {
        program: "ffmpeg".into(),
        why: "the CLI could not be started (.ci/setup.sh installs it)".into(),
        source: Some(e),
    })?;
    if !st.success() {
        return Err(crate::Error::Program { program: "ffmpeg".into(), why: format!("{args:?} failed ({st})"), source: None });
    }
    Ok(())
}

/// Makes a `w x h`, `fps` H.264 clip of `seconds` with FFmpeg's test pattern (fine detail,
/// moving objects, scrolling gradient).
pub(super) fn make_clip(path: &std::path::Path, w: usize, h: usize, fps: u32, seconds: f64) -> crate::Result<()> {
    let src = format!("testsrc2=size={w}x{h}:rate={fps}");
    ffmpeg_cli(&[
        "-f",
        "lavfi",
        "-i",
        &src,
        "-t",
        &format!("{seconds}"),
        "-c:v",
        "libx264",
        "-preset",
        "veryfast",
        "-pix_fmt",
        "yuv420p",
        path.to_str().unwrap_or_default(),
    ])
}

/// Frames/s of the pipeline's decoder (decode + RGB planes); `swscale`: with swscale's
/// conversion instead of its own (the path before it had one).
pub(super) fn own_decode_fps_with(path: &std::path::Path, swscale: bool) -> crate::Result<(f64, u64)> {
    let mut r = crate::io::video::VideoReader::open(path).map_err(crate::Error::video(path))?;
    r.force_swscale = swscale;
    let t = Instant::now();
    let mut n = 0u64;
    while r.next_frame().map_err(crate::Error::video(path))?.is_some() {
        n += 1;
    }
    Ok((n as f64 / t.elapsed().as_secs_f64(), n))
}

pub(super) fn ffmpeg_decode_fps(path: &std::path::Path, frames: u64) -> crate::Result<f64> {
    let t = Instant::now();
    ffmpeg_cli(&["-threads", "0", "-i", path.to_str().unwrap_or_default(), "-f", "null", "-"])?;
    Ok(frames as f64 / t.elapsed().as_secs_f64())
}
