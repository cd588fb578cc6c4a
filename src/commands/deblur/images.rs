//! Images and folders of images, each deblurred in blended tiles row by row and written back in
//! its own format (PNG grey, alpha and 16 bits kept; OpenEXR float), with what could not be
//! kept noted.

use super::{encoded_sample, image_ext, remove_stale, temp_for, Changed, DeblurReport, FailedImage};
use crate::io::{png as png_io, write_atomic};
use crate::model::fast::FastNet;
use crate::model::infer::{run_rows_at, Tiling};
use crate::progress::{Bar, ProgressMode};
use crate::{Error, Result};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Image formats `deblur` reads from a folder, and writes back in the same format.
pub const IMAGE_EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "tif", "tiff", "exr"];

/// An image as `deblur` reads it, in its own sample format, so that it can be written back in it.
enum Picture {
    /// A PNG: grey, grey + alpha, RGB or RGBA, 8 or 16 bits.
    Png(png_io::Samples),
    /// Read by FFmpeg (JPEG, TIFF, OpenEXR): 8-bit or 16-bit encoded, or linear float (`float`),
    /// as RGB; `alpha` and `grey` say what the file had. (Never made in a build without FFmpeg.)
    #[cfg_attr(not(feature = "ffmpeg"), allow(dead_code))]
    Decoded { frame: crate::frame::Frame, float: bool, alpha: bool, grey: bool },
}

impl Picture {
    fn size(&self) -> (usize, usize) {
        match self {
            Picture::Png(s) => (s.width, s.height),
            Picture::Decoded { frame, .. } => (frame.width, frame.height),
        }
    }

    /// The encoded value in [0, 1] of channel `c` (R, G, B) of pixel `i`, as the network sees it.
    fn encoded(&self, i: usize, c: usize) -> f32 {
        match self {
            Picture::Png(s) => s.get(i, if s.channels <= 2 { 0 } else { c }),
            Picture::Decoded { frame, float, .. } => encoded_sample(&frame.data, *float, i, c),
        }
    }

    /// (16-bit, float, alpha, grey) of the source.
    fn traits(&self) -> (bool, bool, bool, bool) {
        match self {
            Picture::Png(s) => (s.sixteen, false, s.channels % 2 == 0, s.channels <= 2),
            Picture::Decoded { frame, float, alpha, grey } => {
                (matches!(&*frame.data, crate::frame::FrameData::Planar16(_)), *float, *alpha, *grey)
            }
        }
    }
}

/// Reads one image: PNG by our own reader (its layout and depth kept), the others through
/// FFmpeg's decoders.
fn read_picture(f: &Path, ext: &str) -> Result<Picture> {
    if ext == "png" {
        let bytes = std::fs::read(f).map_err(|e| Error::Io { path: f.to_path_buf(), cause: e })?;
        return png_io::read_samples(&bytes).map(Picture::Png).map_err(Error::format(f));
    }
    #[cfg(feature = "ffmpeg")]
    {
        let (frame, r) = crate::io::video::read_image_with(f).map_err(Error::video(f))?;
        Ok(Picture::Decoded { frame, float: r.float, alpha: r.alpha, grey: r.grey })
    }
    #[cfg(not(feature = "ffmpeg"))]
    Err(Error::File { path: f.to_path_buf(), why: "only PNG is read without the ffmpeg feature".into() })
}

/// What deblurring is written into, chosen by the output's format: a PNG from a PNG keeps its
/// samples' layout (grey, alpha, 16 bits); OpenEXR gets linear float; the rest 8-bit RGB.
enum Canvas {
    Png(png_io::Samples),
    Linear([Vec<f32>; 3]),
    Rgb8(Vec<u8>),
}

/// Deblurs `src` (extension `src_ext`) into `dst` in the format of `dst_ext`. Returns the size and
/// what of the source's format the output could not keep (empty when it kept everything).
fn deblur_image(
    net: &FastNet,
    src: &Path,
    src_ext: &str,
    dst: &Path,
    dst_ext: &str,
    tiling: Tiling,
) -> Result<((usize, usize), Vec<String>)> {
    deblur_image_at(net, src, src_ext, &[dst.to_path_buf()], dst_ext, tiling, None)
}

/// [`deblur_image`] into `dsts`: one file, or with `times` a burst, the output at `times[k]`
/// into `dsts[k]`.
fn deblur_image_at(
    net: &FastNet,
    src: &Path,
    src_ext: &str,
    dsts: &[PathBuf],
    dst_ext: &str,
    tiling: Tiling,
    times: Option<&[f32]>,
) -> Result<((usize, usize), Vec<String>)> {
    let pic = read_picture(src, src_ext)?;
    let (w, h) = pic.size();
    let (sixteen, float, alpha, grey) = pic.traits();
    let blank = || match (&pic, dst_ext) {
        (Picture::Png(s), "png") => Canvas::Png(s.clone()),
        (_, "exr") => Canvas::Linear(std::array::from_fn(|_| vec![0.0; w * h])),
        _ => Canvas::Rgb8(vec![0; w * h * 3]),
    };
    let mut canvases: Vec<Canvas> = dsts.iter().map(|_| blank()).collect();
    let mut lost = Vec::new();
    let kept = matches!(canvases[0], Canvas::Png(_));
    if let (Picture::Png(s), true) = (&pic, kept) {
        lost.extend(s.expanded.clone());
    }
    if alpha && !kept {
        lost.push("alpha dropped".to_string());
    }
    if grey && !kept {
        lost.push("grey written as RGB".to_string());
    }
    if (sixteen || float) && matches!(canvases[0], Canvas::Rgb8(_)) {
        lost.push(format!("{} samples written as 8 bits", if float { "float" } else { "16-bit" }));
    }
    let curve = crate::optics::transfer::Curve::Srgb;
    let whole = run_rows_at(net, w, h, tiling, times, &|i, c| pic.encoded(i, c), &mut |k, y, row| {
        for x in 0..w {
            let (i, rgb) = (y * w + x, &row[x * 3..x * 3 + 3]);
            match &mut canvases[k] {
                Canvas::Png(s) if s.channels <= 2 => s.set(i, 0, (rgb[0] + rgb[1] + rgb[2]) / 3.0),
                Canvas::Png(s) => (0..3).for_each(|c| s.set(i, c, rgb[c])),
                Canvas::Linear(p) => (0..3).for_each(|c| p[c][i] = curve.to_linear(rgb[c] as f64) as f32),
                Canvas::Rgb8(o) => (0..3).for_each(|c| o[i * 3 + c] = (rgb[c] * 255.0).round() as u8),
            }
        }
    });
    drop(pic);
    if !whole {
        return Err(Error::Interrupted(format!("{}: stopped by a signal before its last tile; nothing written for it", src.display())));
    }
    for (dst, canvas) in dsts.iter().zip(&canvases) {
        write_canvas(dst, dst_ext, w, h, canvas)?;
    }
    Ok(((w, h), lost))
}

/// Writes a [`Canvas`] in the format its extension names: PNG and OpenEXR by our own writers,
/// JPEG and TIFF (8-bit RGB) through FFmpeg's encoders; atomically.
fn write_canvas(dst: &Path, ext: &str, w: usize, h: usize, canvas: &Canvas) -> Result<()> {
    match (canvas, ext) {
        (Canvas::Png(s), _) => write_atomic(dst, |wr| png_io::write_samples(wr, s)),
        (Canvas::Linear(p), _) => write_atomic(dst, |wr| crate::io::exr::write_rgb_f32(wr, w, h, [&p[0], &p[1], &p[2]])),
        (Canvas::Rgb8(rgb), "png") => write_atomic(dst, |wr| png_io::write_rgb8(wr, w, h, rgb)),
        #[cfg(feature = "ffmpeg")]
        (Canvas::Rgb8(rgb), _) => {
            use crate::io::video::Codec;
            let codec = if ext.starts_with("tif") { Codec::Tiff } else { Codec::Jpeg };
            let tmp = temp_for(dst);
            let res = crate::io::video::write_image(&tmp, w, h, rgb, codec)
                .map_err(Error::video(dst))
                .and_then(|()| std::fs::rename(&tmp, dst).map_err(|e| Error::Io { path: dst.to_path_buf(), cause: e }));
            if res.is_err() {
                let _ = std::fs::remove_file(&tmp);
            }
            res
        }
        #[cfg(not(feature = "ffmpeg"))]
        (Canvas::Rgb8(_), _) => Err(Error::File { path: dst.to_path_buf(), why: "JPEG and TIFF need the ffmpeg feature".into() }),
    }
}

/// Deblurs every image (PNG, JPEG, TIFF, OpenEXR) of a folder or glob into a folder, keeping
/// the names and formats. An image that cannot be read or written is reported in
/// [`DeblurReport::failed`] and the others are still done.
///
/// # Errors
/// No image found, an output folder that cannot be made, an interruption (SIGINT, SIGTERM;
/// finished images stay, each written whole).
pub fn images(
    net: &FastNet,
    model_name: &str,
    input: &Path,
    output: &Path,
    tiling: Tiling,
    progress: ProgressMode,
) -> Result<DeblurReport> {
    images_at(net, model_name, input, output, tiling, progress, None)
}

/// The files a burst of `k` from image `f` is written to in the folder `output`:
/// `output/{stem}/00.{ext}` ... (two digits), in the image's own format.
pub fn burst_files(output: &Path, f: &Path, k: usize) -> Vec<PathBuf> {
    let stem = f.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = f.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    (0..k).map(|i| output.join(&stem).join(format!("{i:02}.{ext}"))).collect()
}

/// [`images`], or with `times` a burst per image into a folder of its own
/// ([`burst_files`]).
///
/// # Errors
/// As [`images`].
pub fn images_at(
    net: &FastNet,
    model_name: &str,
    input: &Path,
    output: &Path,
    tiling: Tiling,
    progress: ProgressMode,
    times: Option<&[f32]>,
) -> Result<DeblurReport> {
    crate::signal::install();
    let t0 = Instant::now();
    let files = crate::io::paths::expand_paths(&[input.display().to_string()], &IMAGE_EXTENSIONS)?;
    if files.is_empty() {
        return Err(Error::Usage(format!("{}: no image found ({})", input.display(), IMAGE_EXTENSIONS.join(", "))));
    }
    // One image to a file named like an image (`deblur a.png -o b.png`): written there, in the
    // format of its own extension. Otherwise the output is a folder of the same names.
    let single = (input.is_file() && image_ext(output).is_some() && times.is_none()).then(|| image_ext(output).expect("checked"));
    let folder = if single.is_some() { output.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")) } else { output };
    std::fs::create_dir_all(folder).map_err(|e| Error::Io { path: folder.to_path_buf(), cause: e })?;
    let targets: Vec<PathBuf> = match (&single, times) {
        (Some(_), _) => vec![output.to_path_buf()],
        (None, Some(ts)) => files.iter().flat_map(|f| burst_files(output, f, ts.len())).collect(),
        (None, None) => files.iter().filter_map(|f| f.file_name()).map(|n| output.join(n)).collect(),
    };
    remove_stale(&targets);
    let bar = Bar::new(progress, "deblur", "images", Some(files.len() as u64));
    let (mut w, mut h, mut done) = (0, 0, 0);
    let mut failed = Vec::new();
    let mut changed = Vec::new();
    let mut interrupted = false;
    for f in &files {
        if crate::signal::interrupted() {
            interrupted = true;
            break;
        }
        let ext = f.extension().and_then(|e| e.to_str()).unwrap_or("").to_ascii_lowercase();
        let res = match (&single, times) {
            (Some(out_ext), _) => deblur_image(net, f, &ext, output, out_ext, tiling),
            (None, Some(ts)) => {
                let dsts = burst_files(output, f, ts.len());
                let sub = dsts[0].parent().expect("a folder per image").strip_prefix(output).expect("inside").to_path_buf();
                crate::io::make_dir_in(output, &sub).and_then(|_| deblur_image_at(net, f, &ext, &dsts, &ext, tiling, Some(ts)))
            }
            (None, None) => deblur_image(net, f, &ext, &output.join(f.file_name().expect("a file")), &ext, tiling),
        };
        match res {
            Ok((size, lost)) => {
                (w, h) = size;
                done += 1;
                if !lost.is_empty() {
                    let what = lost.join(", ");
                    bar.println(&format!("note: {}: {what}", f.display()));
                    changed.push(Changed { path: f.display().to_string(), what });
                }
            }
            Err(Error::Interrupted(_)) => {
                interrupted = true;
                break;
            }
            Err(e) => {
                let msg = e.to_string();
                let error = if msg.contains(&*f.to_string_lossy()) { msg } else { format!("{}: {msg}", f.display()) };
                eprintln!("failed: {error}");
                failed.push(FailedImage { path: f.display().to_string(), error });
            }
        }
        bar.inc(1);
    }
    bar.finish();
    let mut r = DeblurReport::new(input, output, model_name, done, (w, h), None, tiling, t0, "none (images)");
    r.failed = failed;
    r.changed = changed;
    r.interrupted = interrupted;
    Ok(r)
}
