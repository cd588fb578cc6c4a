//! Frames and inputs: what sources make and stages read (the channel message is
//! [`crate::item::Item`]; a window's result, [`crate::sample::Sample`]).

use crate::optics::transfer::Curve;
use std::sync::Arc;

/// One frame. Sources make encoded frames (`curve: None`); `linearize` tags them with the
/// curve that maps them to linear light (`curve: Some`), without touching the pixels: readers
/// convert only the rows they use, through a table ([`Frame::linear_row`]).
#[derive(Debug, Clone)]
pub struct Frame {
    pub width: usize,
    pub height: usize,
    pub data: Arc<FrameData>,
    pub curve: Option<Curve>,
    /// What moved in this frame's window, as JSON for `key.json` (the `stills` source's
    /// per-window motion), or `None` (video).
    pub motion: Option<Arc<str>>,
    /// Highlights made bright again ([`Highlights`]), read through [`Frame::linear_row`].
    pub highlights: Option<Highlights>,
}

/// Clipped highlights made bright again before the blur (as RSBlur does): linear values at or
/// above `threshold` are multiplied by `gain`, so a light's streak is as bright as the light was,
/// and the capture saturates where a real one would.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Highlights {
    /// Linear light; 1 boosts only pixels at the top code value.
    pub threshold: f32,
    pub gain: f32,
}

/// Columns to read from a row: a contiguous run from `start`, explicit indices, or a run from
/// `start` (which may lie outside the frame) mirrored at the frame's borders
/// ([`crate::optics::fft::reflect`]).
#[derive(Debug, Clone, Copy)]
pub enum Cols<'a> {
    From(usize),
    Index(&'a [usize]),
    Mirror(isize),
}

/// `out[i] = t[src[i]]`: 16 values at a time from a table held in registers where the CPU has
/// AVX-512 (the same table, so the same bits), else one lookup at a time.
fn lut_row(t: &[f32; 256], src: &[u8], out: &mut [f32]) {
    assert_eq!(src.len(), out.len());
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx512f") {
        // SAFETY: the CPU has AVX-512F.
        let done = unsafe { lut_row_avx512(t, src, out) };
        out[done..].iter_mut().zip(&src[done..]).for_each(|(o, &v)| *o = t[v as usize]);
        return;
    }
    out.iter_mut().zip(src).for_each(|(o, &v)| *o = t[v as usize]);
}

/// [`lut_row`] over the whole vectors of 16; returns how many values it wrote. The table lives
/// in 16 registers: eight two-register permutes look up the low 5 bits of each index in every
/// block of 32 entries, and three rounds of blends pick the block by the top 3 bits (a gather
/// was no faster than one lookup at a time).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn lut_row_avx512(t: &[f32; 256], src: &[u8], out: &mut [f32]) -> usize {
    use std::arch::x86_64::{
        __m128i, __m512, _mm512_cvtepu8_epi32, _mm512_loadu_ps, _mm512_mask_blend_ps, _mm512_permutex2var_ps, _mm512_set1_epi32,
        _mm512_storeu_ps, _mm512_test_epi32_mask, _mm_loadu_si128,
    };
    // SAFETY: 16 x 16 = 256 values, inside the table.
    let tab: [__m512; 16] = std::array::from_fn(|i| unsafe { _mm512_loadu_ps(t.as_ptr().add(16 * i)) });
    let (b5, b6, b7) = (_mm512_set1_epi32(32), _mm512_set1_epi32(64), _mm512_set1_epi32(128));
    let n = src.len().min(out.len()) / 16 * 16;
    for i in (0..n).step_by(16) {
        // SAFETY: i + 16 <= n <= both lengths.
        let idx = _mm512_cvtepu8_epi32(unsafe { _mm_loadu_si128(src.as_ptr().add(i).cast::<__m128i>()) });
        let r: [__m512; 8] = std::array::from_fn(|j| _mm512_permutex2var_ps(tab[2 * j], idx, tab[2 * j + 1]));
        let (m5, m6, m7) = (_mm512_test_epi32_mask(idx, b5), _mm512_test_epi32_mask(idx, b6), _mm512_test_epi32_mask(idx, b7));
        let a: [__m512; 4] = std::array::from_fn(|j| _mm512_mask_blend_ps(m5, r[2 * j], r[2 * j + 1]));
        let b0 = _mm512_mask_blend_ps(m6, a[0], a[1]);
        let b1 = _mm512_mask_blend_ps(m6, a[2], a[3]);
        // SAFETY: as above.
        unsafe { _mm512_storeu_ps(out.as_mut_ptr().add(i), _mm512_mask_blend_ps(m7, b0, b1)) };
    }
    n
}

/// Tables as fixed-size arrays: a u8 (u16) index is always in range, so the lookups in
/// [`Frame::linear_row`] carry no bounds check (it was a sixth of patch mode's time).
fn lut8(curve: Curve) -> &'static [f32; 256] {
    static T: [std::sync::OnceLock<[f32; 256]>; 3] = [const { std::sync::OnceLock::new() }; 3];
    T[curve as usize].get_or_init(|| std::array::from_fn(|v| curve.to_linear(v as f64 / 255.0) as f32))
}

fn lut16(curve: Curve) -> &'static [f32; 65536] {
    static T: [std::sync::OnceLock<Box<[f32; 65536]>>; 3] = [const { std::sync::OnceLock::new() }; 3];
    T[curve as usize].get_or_init(|| curve.decode_lut16().into_boxed_slice().try_into().expect("65536 entries"))
}

impl Frame {
    pub fn new(width: usize, height: usize, data: FrameData) -> Frame {
        Frame { width, height, data: Arc::new(data), curve: None, motion: None, highlights: None }
    }

    /// Linear light of channel `c`, row `y`, at `cols`, into `out` (its length is the count).
    ///
    /// # Panics
    /// If the frame has not been through `linearize`.
    pub fn linear_row(&self, c: usize, y: usize, cols: Cols, out: &mut [f32]) {
        self.encoded_to_linear_row(c, y, cols, out);
        if let (Some(h), false) = (self.highlights, matches!(cols, Cols::Mirror(_))) {
            // (A mirrored row's columns came through this function already.)
            out.iter_mut().filter(|v| **v >= h.threshold).for_each(|v| *v *= h.gain);
        }
    }

    /// [`Frame::linear_row`] before the highlights.
    fn encoded_to_linear_row(&self, c: usize, y: usize, cols: Cols, out: &mut [f32]) {
        if let Cols::Mirror(start) = cols {
            // The columns inside the frame as one run through the fast path.
            let (n, w) = (out.len(), self.width as isize);
            let lo = (-start).clamp(0, n as isize) as usize;
            let hi = (w - start).clamp(lo as isize, n as isize) as usize;
            if hi > lo {
                self.linear_row(c, y, Cols::From((start + lo as isize) as usize), &mut out[lo..hi]);
            }
            // A mirrored column is usually one of the run's own (the margin is narrower than
            // the frame): copy it; otherwise (a frame narrower than the margin) read it.
            for x in (0..lo).chain(hi..n) {
                let sx = crate::optics::fft::reflect(start + x as isize, self.width) as isize - start;
                if (lo as isize..hi as isize).contains(&sx) {
                    out[x] = out[sx as usize];
                } else {
                    let ix = [(start + sx) as usize];
                    self.linear_row(c, y, Cols::Index(&ix), &mut out[x..x + 1]);
                }
            }
            return;
        }
        let curve = self.curve.expect("frame reached a linear stage without linearize");
        let base = y * self.width;
        macro_rules! fill {
            ($plane:expr, $map:expr) => {{
                let row = &$plane[base..base + self.width];
                match cols {
                    Cols::From(x0) => {
                        let n = out.len();
                        out.iter_mut().zip(&row[x0..x0 + n]).for_each(|(o, v)| *o = $map(*v))
                    }
                    Cols::Index(ix) => out.iter_mut().zip(ix).for_each(|(o, &i)| *o = $map(row[i])),
                    Cols::Mirror(_) => unreachable!("resolved above"),
                }
            }};
        }
        match &*self.data {
            FrameData::Planar8(p) => {
                let t = lut8(curve);
                match cols {
                    Cols::From(x0) => {
                        let n = out.len();
                        lut_row(t, &p[c][base + x0..base + x0 + n], out)
                    }
                    _ => fill!(p[c], |v: u8| t[v as usize]),
                }
            }
            FrameData::Regions8(regions) => {
                let t = lut8(curve);
                let (lo, hi) = match cols {
                    Cols::From(x0) => (x0, x0 + out.len()),
                    Cols::Index(ix) => (ix.iter().copied().min().unwrap_or(0), ix.iter().copied().max().map_or(0, |m| m + 1)),
                    Cols::Mirror(_) => unreachable!("resolved above"),
                };
                let r = regions
                    .iter()
                    .find(|r| r.holds(y, lo, hi))
                    .unwrap_or_else(|| panic!("row {y} columns {lo}..{hi} were not decoded (patch-mode regions)"));
                let row = &r.planes[c][(y - r.y0) * r.w..(y - r.y0 + 1) * r.w];
                match cols {
                    Cols::From(x0) => {
                        let n = out.len();
                        lut_row(t, &row[x0 - r.x0..x0 - r.x0 + n], out)
                    }
                    Cols::Index(ix) => out.iter_mut().zip(ix).for_each(|(o, &i)| *o = t[row[i - r.x0] as usize]),
                    Cols::Mirror(_) => unreachable!("resolved above"),
                }
            }
            FrameData::Planar16(p) => {
                let t = lut16(curve);
                fill!(p[c], |v: u16| t[v as usize])
            }
            FrameData::Planar(p) if curve == Curve::Identity => fill!(p[c], |v: f32| v),
            FrameData::Planar(p) => fill!(p[c], |v: f32| curve.to_linear(v as f64) as f32),
        }
    }

    /// Asks the CPU to bring the encoded bytes of channel `c`, row `y`, columns `lo..hi` into its
    /// caches ahead of a [`Frame::linear_row`] of them (columns outside the frame or the
    /// decoded regions are skipped). A hint only: it changes no value.
    pub fn prefetch_row(&self, c: usize, y: usize, lo: usize, hi: usize) {
        match &*self.data {
            FrameData::Planar8(p) => {
                let (lo, hi) = (lo.min(self.width), hi.min(self.width));
                prefetch(&p[c][y * self.width + lo..y * self.width + hi]);
            }
            FrameData::Regions8(regions) => {
                if let Some(r) = regions.iter().find(|r| r.holds(y, lo, hi)) {
                    let at = (y - r.y0) * r.w + lo - r.x0;
                    prefetch(&r.planes[c][at..at + hi - lo]);
                }
            }
            _ => {}
        }
    }

    /// The encoded 8-bit pixels of the `rw x rh` region at (x, y), interleaved RGB, if the
    /// frame holds 8-bit data there: what encoding its linear light with its own curve and
    /// quantising gives back exactly (the 8-bit round trip is the identity), without the
    /// round trip. `None` for 16-bit and float frames.
    pub fn encoded8_crop(&self, x: usize, y: usize, rw: usize, rh: usize) -> Option<Vec<u8>> {
        let (planes, pw, px, py): (&[Vec<u8>; 3], usize, usize, usize) = match &*self.data {
            FrameData::Planar8(p) => (p, self.width, 0, 0),
            FrameData::Regions8(regions) => {
                let r = regions.iter().find(|r| r.holds(y, x, x + rw) && r.holds(y + rh.max(1) - 1, x, x + rw))?;
                (&r.planes, r.w, r.x0, r.y0)
            }
            _ => return None,
        };
        let mut out = vec![0u8; rw * rh * 3];
        for (r, o) in out.chunks_exact_mut((rw * 3).max(1)).enumerate() {
            let at = (y + r - py) * pw + x - px;
            for (c, plane) in planes.iter().enumerate() {
                for (i, &v) in plane[at..at + rw].iter().enumerate() {
                    o[i * 3 + c] = v;
                }
            }
        }
        Some(out)
    }

    /// Linear planes of the `rw x rh` region at (x, y) (inside the frame).
    pub fn linear_crop(&self, x: usize, y: usize, rw: usize, rh: usize) -> [Vec<f32>; 3] {
        std::array::from_fn(|c| {
            let mut out = vec![0.0f32; rw * rh];
            for (r, o) in out.chunks_exact_mut(rw.max(1)).enumerate() {
                self.linear_row(c, y + r, Cols::From(x), o);
            }
            out
        })
    }
}

/// How many rows ahead the blur's row reads and the Y'CbCr conversion ask for their bytes.
pub const PREFETCH_ROWS: usize = 2;

/// Asks the CPU to bring `bytes` into its first-level cache (one hint per 64-byte line).
/// Blurs and conversions read frames in short rows (a tile's or a patch's width) at a stride the
/// hardware prefetchers miss: 40% of `linear_row`'s samples, and a third of converting patch
/// rows, sat on the loads of those bytes (perf). A hint only: it never faults and changes no value.
#[inline]
pub fn prefetch(bytes: &[u8]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let p = bytes.as_ptr();
        for i in (0..bytes.len()).step_by(64).chain(bytes.len().checked_sub(1)) {
            // SAFETY: an address inside `bytes`; a prefetch never faults.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.add(i).cast()) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = bytes;
}

#[derive(Debug, Clone)]
pub enum FrameData {
    /// Encoded 8-bit planes R, G, B (8-bit sources).
    Planar8([Vec<u8>; 3]),
    /// Only some rectangles of an 8-bit frame, each with its own planes: what a patch-mode
    /// blur reads (its patches plus the kernel margin). Reading outside them is a bug.
    Regions8(Vec<Region8>),
    /// Encoded 16-bit planes R, G, B (sources of more than 8 bits, scaled to the full range).
    Planar16([Vec<u16>; 3]),
    /// Planar RGB f32, values in [0, 1] (the `stills` source, and tests).
    Planar([Vec<f32>; 3]),
}

/// A rectangle of an 8-bit frame: `w x h` pixels at (x0, y0), planes R, G, B of `w x h`.
#[derive(Debug, Clone)]
pub struct Region8 {
    pub x0: usize,
    pub y0: usize,
    pub w: usize,
    pub h: usize,
    pub planes: [Vec<u8>; 3],
}

impl Region8 {
    fn holds(&self, y: usize, lo: usize, hi: usize) -> bool {
        y >= self.y0 && y < self.y0 + self.h && lo >= self.x0 && hi <= self.x0 + self.w
    }
}

/// One input (video or still) as the stages know it.
#[derive(Debug)]
pub struct Input {
    /// Position in the sorted list of all inputs (before sharding across tasks).
    pub index: usize,
    /// Hash of the input's identity (canonical path, or a procedural clip's number and seed):
    /// every random choice about the input derives from it, so an input gives the same samples
    /// whichever other inputs share its run.
    pub id: u64,
    pub path: String,
    /// File stem made safe for WebDataset keys (no dots).
    pub key: String,
}

/// Facts about an input, measured by the source.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct InputInfo {
    pub width: usize,
    pub height: usize,
    pub fps: f64,
    /// Frame count announced by the container, if any.
    pub frames_announced: Option<u64>,
    pub codec: String,
    pub pixel_format: String,
}

/// Why one input failed (its outputs are discarded; the run goes on with the others). Each
/// names the input.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum InputError {
    /// The file could not be read or decoded: its error (which names it), causes included in
    /// the message.
    #[error("{}", .0.chain())]
    Read(crate::Error),
    #[error("{path}: frames are {width}x{height}, smaller than a {}x{} patch", patch.0, patch.1)]
    TooSmall { path: String, width: usize, height: usize, patch: (usize, usize) },
    /// Fewer frames announced than one window.
    #[error("{path}: {frames} frames, shorter than one window of {window}")]
    TooShort { path: String, frames: u64, window: usize },
    /// Decoded to its end without filling one window.
    #[error("{path}: shorter than one window of {window} frames")]
    NoWindow { path: String, window: usize },
    #[error("{path}: truncated: decoded {decoded} of the {announced} frames the container announces")]
    Truncated { path: String, decoded: u64, announced: u64 },
}

impl InputError {
    /// As an [`crate::item::Item::End`] carries it.
    pub fn end(self) -> Result<(), Arc<InputError>> {
        Err(Arc::new(self))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn highlights_multiply_the_top_code_once_whatever_the_columns() {
        // One row of 6: 255 at columns 0 and 4, darker elsewhere.
        let row: Vec<u8> = vec![255, 200, 10, 254, 255, 0];
        let mut f = Frame::new(6, 1, FrameData::Planar8([row.clone(), row.clone(), row]));
        f.curve = Some(Curve::Srgb);
        f.highlights = Some(Highlights { threshold: Curve::Srgb.to_linear(254.5 / 255.0) as f32, gain: 3.0 });
        let lin = |v: u8| Curve::Srgb.to_linear(v as f64 / 255.0) as f32;
        let want = [3.0, lin(200), lin(10), lin(254), 3.0, 0.0];
        let mut out = [0.0f32; 6];
        f.linear_row(1, 0, Cols::From(0), &mut out);
        assert_eq!(out, want);
        let mut out = [0.0f32; 2];
        f.linear_row(0, 0, Cols::Index(&[4, 3]), &mut out);
        assert_eq!(out, [3.0, lin(254)]);
        // Mirrored at the left border (columns -2 and -1 reflect into the row): each value
        // boosted once.
        let mut out = [0.0f32; 4];
        f.linear_row(2, 0, Cols::Mirror(-2), &mut out);
        for (x, o) in out.iter().enumerate() {
            let sx = crate::optics::fft::reflect(x as isize - 2, 6);
            assert_eq!(*o, want[sx], "column {x}");
        }
    }

    #[test]
    fn table_rows_look_up_every_value_at_every_length() {
        // A table whose entries all differ, every byte value, lengths around the vector width.
        let t: [f32; 256] = std::array::from_fn(|v| (v as f32 * 0.37).sin() + v as f32);
        let src: Vec<u8> = (0..1000usize).map(|i| ((i * 97 + i / 256) % 256) as u8).collect();
        for len in [0, 1, 15, 16, 17, 33, 256, 1000] {
            let mut out = vec![f32::NAN; len];
            lut_row(&t, &src[..len], &mut out);
            for (i, (&o, &v)) in out.iter().zip(&src).enumerate() {
                assert_eq!(o.to_bits(), t[v as usize].to_bits(), "length {len}, value {i} ({v})");
            }
        }
    }

    #[test]
    fn an_8_bit_frames_own_bytes_are_its_re_encoded_linear_light() {
        // Every code value in every channel, through each curve: the shortcut the blur stage
        // takes for the sharp image equals encoding and quantising the linear light.
        let (w, h) = (40, 21);
        let planes: [Vec<u8>; 3] = std::array::from_fn(|c| (0..w * h).map(|i| ((i * 7 + c * 85) % 256) as u8).collect());
        for curve in [Curve::Srgb, Curve::Gamma22, Curve::Identity] {
            let full = Frame { curve: Some(curve), ..Frame::new(w, h, FrameData::Planar8(planes.clone())) };
            let (x, y, rw, rh) = (5, 3, 30, 17);
            let want = crate::imaging::to_8bit(&full.linear_crop(x, y, rw, rh), rw, rh, curve);
            assert_eq!(full.encoded8_crop(x, y, rw, rh).as_deref(), Some(&want[..]), "{curve:?}");
            // The same out of a patch-mode region that holds the rectangle.
            let (x0, y0, ww, hh) = (2, 1, 36, 20);
            let region = Region8 {
                x0,
                y0,
                w: ww,
                h: hh,
                planes: std::array::from_fn(|c| {
                    (0..hh).flat_map(|r| planes[c][(y0 + r) * w + x0..(y0 + r) * w + x0 + ww].to_vec()).collect()
                }),
            };
            let part = Frame { curve: Some(curve), ..Frame::new(w, h, FrameData::Regions8(vec![region])) };
            assert_eq!(part.encoded8_crop(x, y, rw, rh).as_deref(), Some(&want[..]), "{curve:?} region");
        }
        let float = Frame::new(2, 2, FrameData::Planar(std::array::from_fn(|_| vec![0.5; 4])));
        assert!(float.encoded8_crop(0, 0, 2, 2).is_none());
    }
}
