//! Video decoding through FFmpeg's libraries (ffmpeg-next): whatever FFmpeg reads, 8 or more
//! bits, frame-threaded, converted to 16-bit RGB with the stream's own matrix and range.

use crate::frame::{Frame, FrameData, InputInfo};
use ffmpeg_next as ff;
use std::path::Path;

/// Initialises FFmpeg once and keeps its logging to errors.
pub fn init() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let _ = ff::init();
        ff::util::log::set_level(ff::util::log::Level::Fatal);
    });
}

pub struct VideoReader {
    ictx: ff::format::context::Input,
    decoder: ff::decoder::Video,
    scaler: Option<ff::software::scaling::Context>,
    stream: usize,
    pub info: InputInfo,
    decoded: ff::frame::Video,
    rgb: ff::frame::Video,
    flushed: bool,
    done: bool,
    pub frames_decoded: u64,
    /// Bits per component of the source; up to 8 gives 8-bit planes, deeper 16-bit planes.
    pub bit_depth: u32,
    /// Average frame rate as a fraction (numerator, denominator).
    pub rate: (i32, i32),
    /// The source is floating point (OpenEXR, float TIFF): frames come as linear-light
    /// `FrameData::Planar` floats, not clipped or encoded.
    pub float: bool,
    /// The source has an alpha channel (frames come without it).
    pub alpha: bool,
    /// The source is grey (frames come as RGB with three equal channels).
    pub grey: bool,
    /// The largest distance, in seconds, between a decoded frame's timestamp and its place on
    /// the constant-rate grid of [`VideoReader::rate`] (from the first frame's time): what a
    /// variable-frame-rate source is re-timed by when read as frames at one rate.
    pub retimed_s: f64,
    /// The stream's time base in seconds, and the first frame's time.
    time_base: f64,
    first_time: Option<f64>,
    /// Convert every frame with swscale, also the 8-bit Y'CbCr formats [`crate::io::yuv`]
    /// converts by default (the reference the tests compare that path with).
    pub force_swscale: bool,
    /// Convert only these rectangles (x0, y0, w, h) of the next frame, which then comes as
    /// `FrameData::Regions8`: what the blur will read in patch mode. Only the 8-bit Y'CbCr path
    /// honours it; others convert whole frames. Set before each [`VideoReader::next_frame`].
    pub regions: Option<Vec<(usize, usize, usize, usize)>>,
}

/// The 8-bit planar Y'CbCr formats [`crate::io::yuv`] converts: chroma subsampling (log2 per
/// axis) and whether the format itself says full range.
fn fast_yuv(p: ff::format::Pixel) -> Option<(u32, u32, bool)> {
    use ff::format::Pixel as P;
    match p {
        P::YUV420P => Some((1, 1, false)),
        P::YUVJ420P => Some((1, 1, true)),
        P::YUV422P => Some((1, 0, false)),
        P::YUVJ422P => Some((1, 0, true)),
        P::YUV444P => Some((0, 0, false)),
        P::YUVJ444P => Some((0, 0, true)),
        _ => None,
    }
}

/// The Y'CbCr matrix a frame says it uses (BT.601 when it says nothing), as [`set_colorspace`]
/// tells swscale.
fn matrix_of(frame: &ff::frame::Video) -> crate::io::yuv::Matrix {
    use crate::io::yuv::Matrix;
    match frame.color_space() {
        ff::color::Space::BT709 => Matrix::BT709,
        ff::color::Space::BT2020NCL | ff::color::Space::BT2020CL => Matrix::BT2020,
        ff::color::Space::SMPTE240M => Matrix::SMPTE240M,
        ff::color::Space::FCC => Matrix::FCC,
        _ => Matrix::BT601,
    }
}

/// Whether a pixel format stores floats.
fn is_float(p: ff::format::Pixel) -> bool {
    // SAFETY: av_pix_fmt_desc_get returns null or a pointer to a static descriptor.
    unsafe {
        let d = ff::ffi::av_pix_fmt_desc_get(p.into());
        !d.is_null() && (*d).flags & ff::ffi::AV_PIX_FMT_FLAG_FLOAT as u64 != 0
    }
}

/// Whether a pixel format has an alpha channel, and whether it is grey (one colour component).
fn alpha_grey(p: ff::format::Pixel) -> (bool, bool) {
    // SAFETY: av_pix_fmt_desc_get returns null or a pointer to a static descriptor.
    unsafe {
        let d = ff::ffi::av_pix_fmt_desc_get(p.into());
        if d.is_null() {
            return (false, false);
        }
        let alpha = (*d).flags & ff::ffi::AV_PIX_FMT_FLAG_ALPHA as u64 != 0;
        (alpha, (*d).nb_components as usize - usize::from(alpha) == 1)
    }
}

/// Bits of the first component of a pixel format.
fn depth_of(p: ff::format::Pixel) -> u32 {
    // SAFETY: av_pix_fmt_desc_get returns null or a pointer to a static descriptor.
    unsafe {
        let d = ff::ffi::av_pix_fmt_desc_get(p.into());
        if d.is_null() {
            8
        } else {
            (*d).comp[0].depth as u32
        }
    }
}

/// Why a video could not be read or written; the caller names the file ([`crate::Error::Video`]).
#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    /// FFmpeg refused: what was being done, and FFmpeg's own error as the source.
    #[error("{what}")]
    Ffmpeg {
        what: String,
        #[source]
        source: ff::Error,
    },
    /// The file is not what a video must be (no size, damaged, too short...).
    #[error("{0}")]
    Invalid(String),
}

impl VideoError {
    fn ffmpeg(what: impl Into<String>) -> impl FnOnce(ff::Error) -> VideoError {
        let what = what.into();
        move |source| VideoError::Ffmpeg { what, source }
    }

    /// The message with its causes, one line (for reports that keep text).
    pub fn chain(&self) -> String {
        match self {
            VideoError::Ffmpeg { what, source } => format!("{what}: {source}"),
            VideoError::Invalid(m) => m.clone(),
        }
    }
}

impl From<ff::Error> for VideoError {
    fn from(source: ff::Error) -> Self {
        VideoError::Ffmpeg { what: "FFmpeg failed".into(), source }
    }
}

impl From<String> for VideoError {
    fn from(m: String) -> Self {
        VideoError::Invalid(m)
    }
}

impl From<&str> for VideoError {
    fn from(m: &str) -> Self {
        VideoError::Invalid(m.into())
    }
}

impl VideoReader {
    /// Opens `path` (or standard input for `-`) and its best video stream.
    ///
    /// # Errors
    /// A message without the path (the caller names the file): missing, not a video, no decoder.
    pub fn open(path: &Path) -> Result<VideoReader, VideoError> {
        init();
        // `-` or `pipe:0`: a stream on standard input (`ffmpeg ... -f nut - | pipeline generate -`).
        let stdin = path.as_os_str() == "-" || path.as_os_str() == "pipe:0";
        let path = if stdin { Path::new("pipe:0") } else { path };
        if !stdin && !path.exists() {
            return Err("no such file".into());
        }
        // FFmpeg takes UTF-8 names only (ffmpeg-next would panic on any other).
        if path.to_str().is_none() {
            return Err("the file name is not valid UTF-8, which FFmpeg cannot open; rename the file".into());
        }
        let ictx = ff::format::input(&path).map_err(VideoError::ffmpeg("not a readable video"))?;
        let st = ictx.streams().best(ff::media::Type::Video).ok_or("no video stream")?;
        let stream = st.index();
        let rate = st.avg_frame_rate();
        let time_base = f64::from(st.time_base());
        let fps = if rate.denominator() != 0 { rate.numerator() as f64 / rate.denominator() as f64 } else { 0.0 };
        let announced = st.frames();
        let mut ctx = ff::codec::context::Context::from_parameters(st.parameters())?;
        ctx.set_threading(ff::codec::threading::Config::kind(ff::codec::threading::Type::Frame));
        let decoder = ctx.decoder().video().map_err(VideoError::ffmpeg("no decoder"))?;
        let codec = decoder.codec().map(|c| c.name().to_string()).unwrap_or_default();
        let info = InputInfo {
            width: decoder.width() as usize,
            height: decoder.height() as usize,
            fps,
            frames_announced: (announced > 0).then_some(announced as u64),
            codec,
            pixel_format: format!("{:?} ({} bit)", decoder.format(), depth_of(decoder.format())).to_lowercase(),
        };
        let bit_depth = depth_of(decoder.format());
        let float = is_float(decoder.format());
        let (alpha, grey) = alpha_grey(decoder.format());
        if info.width == 0 || info.height == 0 {
            return Err("video stream has no size".into());
        }
        Ok(VideoReader {
            ictx,
            decoder,
            scaler: None,
            stream,
            info,
            decoded: ff::frame::Video::empty(),
            rgb: ff::frame::Video::empty(),
            flushed: false,
            done: false,
            frames_decoded: 0,
            bit_depth,
            rate: (rate.numerator(), rate.denominator()),
            float,
            alpha,
            grey,
            force_swscale: false,
            regions: None,
            retimed_s: 0.0,
            time_base,
            first_time: None,
        })
    }

    /// Updates [`VideoReader::retimed_s`] with the frame just decoded.
    fn track_time(&mut self) {
        let (Some(ts), true) = (self.decoded.timestamp(), self.info.fps > 0.0) else { return };
        let t = ts as f64 * self.time_base;
        let first = *self.first_time.get_or_insert(t);
        let on_grid = first + (self.frames_decoded - 1) as f64 / self.info.fps;
        self.retimed_s = self.retimed_s.max((t - on_grid).abs());
    }

    fn convert(&mut self) -> Result<Frame, VideoError> {
        let (w, h) = (self.decoded.width(), self.decoded.height());
        let deep = self.bit_depth > 8;
        if let Some((sx, sy, full)) = fast_yuv(self.decoded.format()).filter(|_| !self.force_swscale) {
            // 8-bit Y'CbCr: converted here, straight into the frame's planes.
            use crate::io::yuv::{Converter, Plane, Source};
            let full = full || self.decoded.color_range() == ff::color::Range::JPEG;
            let conv = Converter::new(matrix_of(&self.decoded), full, sx, sy);
            let (w, h) = (w as usize, h as usize);
            let d = &self.decoded;
            let plane = |i: usize| Plane { data: d.data(i), stride: d.stride(i) };
            let src = Source { y: plane(0), cb: plane(1), cr: plane(2), w, h };
            if let Some(rects) = &self.regions {
                let regions = rects
                    .iter()
                    .filter(|r| r.2 > 0 && r.3 > 0 && r.0 + r.2 <= w && r.1 + r.3 <= h)
                    .map(|&(x0, y0, rw, rh)| {
                        let mut planes: [Vec<u8>; 3] = std::array::from_fn(|_| vec![0u8; rw * rh]);
                        let [r, g, b] = &mut planes;
                        conv.convert_rect(&src, (x0, y0, rw, rh), [r, g, b]);
                        crate::frame::Region8 { x0, y0, w: rw, h: rh, planes }
                    })
                    .collect();
                return Ok(Frame::new(w, h, FrameData::Regions8(regions)));
            }
            let mut planes: [Vec<u8>; 3] = std::array::from_fn(|_| vec![0u8; w * h]);
            let [r, g, b] = &mut planes;
            conv.convert(&src, [r, g, b]);
            return Ok(Frame::new(w, h, FrameData::Planar8(planes)));
        }
        // Planar G, B, R straight from swscale: no interleaving to undo later.
        let target = if self.float {
            ff::format::Pixel::GBRPF32LE
        } else if deep {
            ff::format::Pixel::GBRP16LE
        } else {
            ff::format::Pixel::GBRP
        };
        // Float planes already in G, B, R order are read as they are: swscale's float-to-float
        // path flushes small values (below ~0.007) to zero.
        let direct = self.float && matches!(self.decoded.format(), ff::format::Pixel::GBRPF32LE | ff::format::Pixel::GBRAPF32LE);
        if !direct {
            if self.scaler.is_none() {
                let flags = ff::software::scaling::Flags::BILINEAR
                    | ff::software::scaling::Flags::ACCURATE_RND
                    | ff::software::scaling::Flags::FULL_CHR_H_INT;
                let mut sc = ff::software::scaling::Context::get(self.decoded.format(), w, h, target, w, h, flags)?;
                set_colorspace(&mut sc, &self.decoded);
                self.scaler = Some(sc);
            }
            self.scaler.as_mut().expect("scaler set").run(&self.decoded, &mut self.rgb)?;
        }
        let (w, h) = (w as usize, h as usize);
        let rgb = if direct { &self.decoded } else { &self.rgb };
        // GBRP plane order is G (0), B (1), R (2).
        let plane = |i: usize, bytes_per: usize| -> Vec<u8> {
            let (stride, data) = (rgb.stride(i), rgb.data(i));
            let mut v = Vec::with_capacity(w * h * bytes_per);
            for y in 0..h {
                v.extend_from_slice(&data[y * stride..y * stride + w * bytes_per]);
            }
            v
        };
        let data = if self.float {
            let tof = |b: Vec<u8>| b.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect::<Vec<f32>>();
            FrameData::Planar([tof(plane(2, 4)), tof(plane(0, 4)), tof(plane(1, 4))])
        } else if deep {
            let to16 = |b: Vec<u8>| b.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect::<Vec<u16>>();
            FrameData::Planar16([to16(plane(2, 2)), to16(plane(0, 2)), to16(plane(1, 2))])
        } else {
            FrameData::Planar8([plane(2, 1), plane(0, 1), plane(1, 1)])
        };
        Ok(Frame::new(w, h, data))
    }

    /// The next frame, `None` at the end.
    ///
    /// # Errors
    /// A damaged stream, naming the frame number where decoding failed.
    pub fn next_frame(&mut self) -> Result<Option<Frame>, VideoError> {
        if self.done {
            return Ok(None);
        }
        loop {
            match self.decoder.receive_frame(&mut self.decoded) {
                Ok(()) => {
                    self.frames_decoded += 1;
                    // Every reader (generate's windows and patch rectangles, deblur's encoder,
                    // eval's windows) takes the stream's size for all of its frames.
                    let (w, h) = (self.decoded.width() as usize, self.decoded.height() as usize);
                    if (w, h) != (self.info.width, self.info.height) {
                        self.done = true;
                        return Err(format!(
                            "frame {} is {w}x{h} but the stream is {}x{}: resolution changes mid-stream are not supported (split the video where it changes)",
                            self.frames_decoded - 1,
                            self.info.width,
                            self.info.height
                        )
                        .into());
                    }
                    self.track_time();
                    return self.convert().map(Some);
                }
                Err(ff::Error::Eof) => {
                    self.done = true;
                    return Ok(None);
                }
                Err(ff::Error::Other { errno }) if errno == ff::util::error::EAGAIN => {}
                Err(e) => return Err(VideoError::ffmpeg(format!("decoding failed after frame {}", self.frames_decoded))(e)),
            }
            if self.flushed {
                self.done = true;
                return Ok(None);
            }
            let mut packet = ff::Packet::empty();
            match packet.read(&mut self.ictx) {
                Ok(()) => {
                    if packet.stream() == self.stream {
                        if let Err(e) = self.decoder.send_packet(&packet) {
                            return Err(VideoError::ffmpeg(format!("damaged data after frame {}", self.frames_decoded))(e));
                        }
                    }
                }
                Err(ff::Error::Eof) => {
                    self.decoder.send_eof()?;
                    self.flushed = true;
                }
                Err(e) => return Err(VideoError::ffmpeg(format!("reading failed after frame {}", self.frames_decoded))(e)),
            }
        }
    }
}

/// Tells swscale which YUV matrix and range the source uses (BT.709 for HD streams that say so,
/// BT.601 otherwise) and asks for full-range RGB.
fn set_colorspace(sc: &mut ff::software::scaling::Context, frame: &ff::frame::Video) {
    use ff::ffi;
    // SAFETY: av_pix_fmt_desc_get returns null or a pointer to a static descriptor.
    let rgb = unsafe {
        let d = ffi::av_pix_fmt_desc_get(frame.format().into());
        !d.is_null() && (*d).flags & ffi::AV_PIX_FMT_FLAG_RGB as u64 != 0
    };
    if rgb {
        // RGB sources are full range and need no matrix.
        return;
    }
    let cs = match frame.color_space() {
        ff::color::Space::BT709 => ffi::SWS_CS_ITU709,
        ff::color::Space::BT2020NCL | ff::color::Space::BT2020CL => ffi::SWS_CS_BT2020,
        ff::color::Space::SMPTE240M => ffi::SWS_CS_SMPTE240M,
        ff::color::Space::FCC => ffi::SWS_CS_FCC,
        _ => ffi::SWS_CS_DEFAULT,
    };
    let src_full = i32::from(frame.color_range() == ff::color::Range::JPEG || is_full_range_yuv(frame.format()));
    // SAFETY: the context pointer is valid for the scaler's lifetime; the coefficient tables are
    // static arrays owned by libswscale.
    unsafe {
        let table = ffi::sws_getCoefficients(cs);
        ffi::sws_setColorspaceDetails(
            sc.as_mut_ptr(),
            table,
            src_full,
            ffi::sws_getCoefficients(ffi::SWS_CS_DEFAULT),
            1,
            0,
            1 << 16,
            1 << 16,
        );
    }
}

fn is_full_range_yuv(p: ff::format::Pixel) -> bool {
    use ff::format::Pixel::*;
    matches!(p, YUVJ420P | YUVJ422P | YUVJ444P)
}

/// What [`VideoWriter`] encodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Codec {
    /// libx264, CRF 18 (4:2:0, or 4:4:4 for odd sizes).
    H264,
    /// FFV1, lossless RGB (needs .mkv).
    Ffv1,
    /// One JPEG image (quality 2 of 31, 4:4:4).
    Jpeg,
    /// One TIFF image (8-bit RGB).
    Tiff,
}

/// Video encoding: H.264 (libx264, CRF 18) by default, or FFV1 (lossless, RGB) for `.mkv`
/// with `lossless`, or a single JPEG or TIFF image. Frames are interleaved 8-bit RGB.
pub struct VideoWriter {
    octx: ff::format::context::Output,
    enc: ff::encoder::Video,
    scaler: ff::software::scaling::Context,
    enc_tb: ff::Rational,
    stream_tb: ff::Rational,
    rgb: ff::frame::Video,
    out: ff::frame::Video,
    next_pts: i64,
    w: usize,
    h: usize,
}

impl VideoWriter {
    /// Opens `path` for `w x h` frames at `fps` (numerator, denominator).
    ///
    /// # Errors
    /// No encoder, a container that does not fit, or the file cannot be created (message without
    /// the path; the caller names it).
    pub fn create(path: &Path, w: usize, h: usize, fps: (i32, i32), lossless: bool) -> Result<VideoWriter, VideoError> {
        VideoWriter::create_as(path, w, h, fps, if lossless { Codec::Ffv1 } else { Codec::H264 })
    }

    /// As [`VideoWriter::create`], with the codec named.
    ///
    /// # Errors
    /// As [`VideoWriter::create`].
    pub fn create_as(path: &Path, w: usize, h: usize, fps: (i32, i32), codec: Codec) -> Result<VideoWriter, VideoError> {
        init();
        let mut octx = match codec {
            Codec::Jpeg | Codec::Tiff => ff::format::output_as(&path, "image2"),
            _ => ff::format::output(&path),
        }
        .map_err(VideoError::ffmpeg("cannot create"))?;
        let global = octx.format().flags().contains(ff::format::Flags::GLOBAL_HEADER);
        let (id, pix) = match codec {
            Codec::Ffv1 => (ff::codec::Id::FFV1, ff::format::Pixel::BGRZ),
            Codec::H264 if w.is_multiple_of(2) && h.is_multiple_of(2) => (ff::codec::Id::H264, ff::format::Pixel::YUV420P),
            Codec::H264 => (ff::codec::Id::H264, ff::format::Pixel::YUV444P),
            Codec::Jpeg => (ff::codec::Id::MJPEG, ff::format::Pixel::YUVJ444P),
            Codec::Tiff => (ff::codec::Id::TIFF, ff::format::Pixel::RGB24),
        };
        let kind = codec;
        let codec = ff::encoder::find(id).ok_or_else(|| format!("no {id:?} encoder in this FFmpeg"))?;
        let mut enc = ff::codec::context::Context::new_with_codec(codec).encoder().video()?;
        let rate = ff::Rational::new(fps.0.max(1), fps.1.max(1));
        let tb = ff::Rational::new(fps.1.max(1), fps.0.max(1));
        enc.set_width(w as u32);
        enc.set_height(h as u32);
        enc.set_format(pix);
        enc.set_time_base(tb);
        enc.set_frame_rate(Some(rate));
        if global {
            enc.set_flags(ff::codec::Flags::GLOBAL_HEADER);
        }
        let mut opts = ff::Dictionary::new();
        match kind {
            Codec::H264 => {
                opts.set("crf", "18");
                opts.set("preset", "medium");
            }
            Codec::Jpeg => {
                // -q:v 2: global_quality is in lambda units (FF_QP2LAMBDA = 118).
                opts.set("flags", "+qscale");
                opts.set("global_quality", "236");
            }
            Codec::Ffv1 | Codec::Tiff => {}
        }
        let enc = enc.open_with(opts).map_err(VideoError::ffmpeg(format!("cannot open the {id:?} encoder")))?;
        let mut ost = octx.add_stream(codec)?;
        ost.set_parameters(&enc);
        ost.set_time_base(tb);
        octx.write_header().map_err(VideoError::ffmpeg("cannot write the header"))?;
        let stream_tb = octx.stream(0).map(|s| s.time_base()).unwrap_or(tb);
        let scaler = ff::software::scaling::Context::get(
            ff::format::Pixel::RGB24,
            w as u32,
            h as u32,
            pix,
            w as u32,
            h as u32,
            ff::software::scaling::Flags::BILINEAR | ff::software::scaling::Flags::ACCURATE_RND,
        )?;
        Ok(VideoWriter {
            octx,
            enc,
            scaler,
            enc_tb: tb,
            stream_tb,
            rgb: ff::frame::Video::new(ff::format::Pixel::RGB24, w as u32, h as u32),
            out: ff::frame::Video::empty(),
            next_pts: 0,
            w,
            h,
        })
    }

    fn drain(&mut self) -> Result<(), VideoError> {
        let mut packet = ff::Packet::empty();
        while self.enc.receive_packet(&mut packet).is_ok() {
            packet.set_stream(0);
            // One frame's duration, so the container's duration counts the last frame too.
            if packet.duration() == 0 {
                packet.set_duration(1);
            }
            packet.rescale_ts(self.enc_tb, self.stream_tb);
            packet.write_interleaved(&mut self.octx)?;
        }
        Ok(())
    }

    /// Appends one interleaved 8-bit RGB frame.
    ///
    /// # Errors
    /// Encoding or writing fails.
    pub fn write_rgb8(&mut self, rgb: &[u8]) -> Result<(), VideoError> {
        assert_eq!(rgb.len(), self.w * self.h * 3);
        let stride = self.rgb.stride(0);
        let data = self.rgb.data_mut(0);
        for y in 0..self.h {
            data[y * stride..y * stride + self.w * 3].copy_from_slice(&rgb[y * self.w * 3..(y + 1) * self.w * 3]);
        }
        self.scaler.run(&self.rgb, &mut self.out)?;
        self.out.set_pts(Some(self.next_pts));
        self.next_pts += 1;
        self.enc.send_frame(&self.out)?;
        self.drain()
    }

    /// Flushes the encoder and writes the trailer.
    ///
    /// # Errors
    /// Writing fails.
    pub fn finish(mut self) -> Result<u64, VideoError> {
        self.enc.send_eof()?;
        self.drain()?;
        self.octx.write_trailer()?;
        Ok(self.next_pts as u64)
    }
}

/// Reads one image (any format FFmpeg decodes: JPEG, TIFF, OpenEXR, PNG, ...): its first frame.
///
/// # Errors
/// Unreadable or empty (message without the path).
pub fn read_image(path: &Path) -> Result<(Frame, bool), VideoError> {
    read_image_with(path).map(|(f, r)| (f, r.float))
}

/// [`read_image`], with the reader (its source's depth, alpha and grey).
///
/// # Errors
/// As [`read_image`].
pub fn read_image_with(path: &Path) -> Result<(Frame, VideoReader), VideoError> {
    let mut r = VideoReader::open(path)?;
    let f = r.next_frame()?.ok_or("no image in the file")?;
    Ok((f, r))
}

/// Writes one 8-bit RGB image as JPEG or TIFF, chosen by `codec`.
///
/// # Errors
/// No encoder or the file cannot be written (message without the path).
pub fn write_image(path: &Path, w: usize, h: usize, rgb: &[u8], codec: Codec) -> Result<(), VideoError> {
    let mut wr = VideoWriter::create_as(path, w, h, (1, 1), codec)?;
    wr.write_rgb8(rgb)?;
    wr.finish().map(|_| ())
}
