//! 8-bit RGB PNG writing and reading (the `png` crate), plus tone mapping helpers.

use std::io::Write;

/// The largest image (pixels) read: 16384 x 16384, a 16K frame (3 GiB as 32-bit float RGB).
pub const MAX_PIXELS: u64 = 16384 * 16384;

/// Why PNG bytes were not read; the `png` crate's error is kept as the source.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PngError {
    #[error("not a readable PNG ({0})")]
    Decode(#[source] png::DecodingError),
    #[error("declares {width}x{height} pixels, more than the {MAX_PIXELS} this tool reads")]
    TooLarge { width: u64, height: u64 },
}

/// Writes interleaved 8-bit RGB.
pub fn write_rgb8(w: &mut dyn Write, width: usize, height: usize, rgb: &[u8]) -> std::io::Result<()> {
    assert_eq!(rgb.len(), width * height * 3);
    let mut enc = png::Encoder::new(w, width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let mut wr = enc.write_header().map_err(std::io::Error::other)?;
    wr.write_image_data(rgb).map_err(std::io::Error::other)?;
    wr.finish().map_err(std::io::Error::other)
}

/// Reads a PNG into interleaved 8-bit RGB: (width, height, data). Grey is converted, alpha
/// dropped; 16-bit samples are rounded to 8 bits.
pub fn read_rgb8(bytes: &[u8]) -> Result<(usize, usize, Vec<u8>), PngError> {
    let (w, h, color, px) = decode(bytes)?;
    let rgb = match color {
        png::ColorType::Rgb => px,
        png::ColorType::Rgba => px.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect(),
        png::ColorType::Grayscale => px.iter().flat_map(|&g| [g, g, g]).collect(),
        _ => px.chunks_exact(2).flat_map(|p| [p[0], p[0], p[0]]).collect(),
    };
    Ok((w, h, rgb))
}

/// Reads a PNG into interleaved 8-bit RGBA (opaque where the file has no alpha).
pub fn read_rgba8(bytes: &[u8]) -> Result<(usize, usize, Vec<u8>), PngError> {
    let (w, h, color, px) = decode(bytes)?;
    let rgba = match color {
        png::ColorType::Rgb => px.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect(),
        png::ColorType::Rgba => px,
        png::ColorType::Grayscale => px.iter().flat_map(|&g| [g, g, g, 255]).collect(),
        _ => px.chunks_exact(2).flat_map(|p| [p[0], p[0], p[0], p[1]]).collect(),
    };
    Ok((w, h, rgba))
}

/// Decodes a PNG to 8-bit samples of its own colour type (palettes expanded; grey, grey + alpha,
/// RGB or RGBA). Files that declare more than [`MAX_PIXELS`] pixels are refused before anything
/// is allocated for them.
fn decode(bytes: &[u8]) -> Result<(usize, usize, png::ColorType, Vec<u8>), PngError> {
    decode_as(bytes, png::Transformations::EXPAND | png::Transformations::STRIP_16)
}

/// A PNG's samples in its own layout, to be written back in it: `channels` per pixel (1 grey,
/// 2 grey + alpha, 3 RGB, 4 RGBA; palettes expanded to RGB or RGBA), 8 or 16 bits each
/// (`sixteen`; the samples then big-endian, as PNG stores them), interleaved.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Samples {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub sixteen: bool,
    pub data: Vec<u8>,
    /// What the file held that these samples do not: a palette, or samples of 1, 2 or 4 bits
    /// (expanded to 8), in words for a report.
    pub expanded: Option<String>,
}

impl Samples {
    /// Sample `c` of pixel `i`, scaled to [0, 1].
    pub fn get(&self, i: usize, c: usize) -> f32 {
        let k = i * self.channels + c;
        if self.sixteen {
            u16::from_be_bytes([self.data[2 * k], self.data[2 * k + 1]]) as f32 / 65535.0
        } else {
            self.data[k] as f32 / 255.0
        }
    }

    /// Sets sample `c` of pixel `i` from a value in [0, 1].
    pub fn set(&mut self, i: usize, c: usize, v: f32) {
        let k = i * self.channels + c;
        if self.sixteen {
            let q = (v.clamp(0.0, 1.0) * 65535.0).round() as u16;
            self.data[2 * k..2 * k + 2].copy_from_slice(&q.to_be_bytes());
        } else {
            self.data[k] = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        }
    }
}

/// Reads a PNG keeping its layout and depth ([`Samples`]); the same size limit as [`read_rgb8`].
pub fn read_samples(bytes: &[u8]) -> Result<Samples, PngError> {
    let (width, height, color, data) = decode_as(bytes, png::Transformations::EXPAND)?;
    let channels = color.samples();
    let sixteen = data.len() == width * height * channels * 2;
    let expanded = {
        let r = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().map_err(PngError::Decode)?;
        match (r.info().color_type, r.info().bit_depth as u8) {
            (png::ColorType::Indexed, _) => Some("palette written as RGB".to_string()),
            (_, d) if d < 8 => Some(format!("{d}-bit samples written as 8 bits")),
            _ => None,
        }
    };
    Ok(Samples { width, height, channels, sixteen, data, expanded })
}

/// Writes [`Samples`] as a PNG of their layout and depth.
pub fn write_samples(w: &mut dyn Write, s: &Samples) -> std::io::Result<()> {
    use png::ColorType::*;
    let color = [Grayscale, GrayscaleAlpha, Rgb, Rgba][s.channels - 1];
    let mut enc = png::Encoder::new(w, s.width as u32, s.height as u32);
    enc.set_color(color);
    enc.set_depth(if s.sixteen { png::BitDepth::Sixteen } else { png::BitDepth::Eight });
    enc.set_compression(png::Compression::Fast);
    let mut wr = enc.write_header().map_err(std::io::Error::other)?;
    wr.write_image_data(&s.data).map_err(std::io::Error::other)?;
    wr.finish().map_err(std::io::Error::other)
}

fn decode_as(bytes: &[u8], transformations: png::Transformations) -> Result<(usize, usize, png::ColorType, Vec<u8>), PngError> {
    let mut dec = png::Decoder::new(std::io::Cursor::new(bytes));
    dec.set_transformations(transformations);
    let mut r = dec.read_info().map_err(PngError::Decode)?;
    let (width, height) = (r.info().width as u64, r.info().height as u64);
    let too_large = PngError::TooLarge { width, height };
    if width * height > MAX_PIXELS {
        return Err(too_large);
    }
    let mut buf = vec![0; r.output_buffer_size().ok_or(too_large)?];
    let info = r.next_frame(&mut buf).map_err(PngError::Decode)?;
    buf.truncate(info.buffer_size());
    // EXPAND turns a palette into RGB or RGBA; the match arms of the readers rely on it.
    assert_ne!(info.color_type, png::ColorType::Indexed, "png::Transformations::EXPAND leaves no palette");
    Ok((info.width as usize, info.height as usize, info.color_type, buf))
}

/// sRGB encoding of linear light in [0, 1].
pub fn srgb_encode(v: f32) -> f32 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.003_130_8 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}
