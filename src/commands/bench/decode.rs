#[cfg_attr(not(feature = "ffmpeg"), allow(unused_imports))]
use super::*;

#[derive(Debug, serde::Serialize)]
pub struct DecodeBench {
    pub clip: String,
    pub frames: u64,
    pub repeats: usize,
    pub ffmpeg_decode_fps_median: f64,
    pub own_decode_fps_median: f64,
    pub own_decode_swscale_fps_median: f64,
    /// Medians of the per-round ratios (each round times all three back to back).
    pub ratio_own_to_ffmpeg: f64,
    pub ratio_swscale_to_ffmpeg: f64,
}

/// `bench decode`: the pipeline's decoder (decode + RGB planes, with its own conversion and
/// with swscale's) beside FFmpeg's decode-only speed of the same clip, in alternating rounds.
///
/// # Errors
/// The ffmpeg CLI is missing, or decoding fails.
#[cfg(feature = "ffmpeg")]
pub fn decode(w: usize, h: usize, fps: u32, seconds: f64, repeats: usize) -> crate::Result<DecodeBench> {
    let dir = std::env::temp_dir().join(format!("pipeline-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| crate::Error::Io { path: dir.clone(), cause: e })?;
    let clip = dir.join(format!("bench-{w}x{h}-{fps}fps.mp4"));
    make_clip(&clip, w, h, fps, seconds)?;
    let b = decode_rounds(&clip, &format!("testsrc2 {w}x{h} {fps} fps H.264 (x264 veryfast), {seconds} s"), repeats)?;
    let _ = std::fs::remove_dir_all(&dir);
    eprintln!(
        "bench: decode {w}x{h}: ffmpeg decode-only {:.0} frames/s; pipeline decoder {:.0} ({:.2}x); with swscale's conversion {:.0} ({:.2}x) (medians of {})",
        b.ffmpeg_decode_fps_median, b.own_decode_fps_median, b.ratio_own_to_ffmpeg, b.own_decode_swscale_fps_median, b.ratio_swscale_to_ffmpeg, b.repeats
    );
    Ok(b)
}

/// Rounds of: the decoder with its own conversion, with swscale's, then FFmpeg decode-only.
#[cfg(feature = "ffmpeg")]
pub(super) fn decode_rounds(clip: &std::path::Path, name: &str, repeats: usize) -> crate::Result<DecodeBench> {
    let repeats = repeats.max(1);
    let (mut ff, mut own, mut sws, mut r_own, mut r_sws) = (vec![], vec![], vec![], vec![], vec![]);
    let mut frames = 0;
    for _ in 0..repeats {
        let (o, n) = own_decode_fps_with(clip, false)?;
        let (s, _) = own_decode_fps_with(clip, true)?;
        let f = ffmpeg_decode_fps(clip, n)?;
        frames = n;
        r_own.push(o / f);
        r_sws.push(s / f);
        own.push(o);
        sws.push(s);
        ff.push(f);
    }
    Ok(DecodeBench {
        clip: name.into(),
        frames,
        repeats,
        ffmpeg_decode_fps_median: median(&mut ff),
        own_decode_fps_median: median(&mut own),
        own_decode_swscale_fps_median: median(&mut sws),
        ratio_own_to_ffmpeg: median(&mut r_own),
        ratio_swscale_to_ffmpeg: median(&mut r_sws),
    })
}
