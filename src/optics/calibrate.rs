//! PSFs from captures of a point source (`pipeline calibrate`): each capture (one per instant of
//! the exposure or per psi) has the dark level taken off (a dark frame, else the median of the
//! capture's border per channel), values within `threshold` noise deviations of it set to zero
//! (the noise measured on the border, robustly: 1.4826 x the median absolute deviation), then
//! every capture is cropped to `size x size` around one centre (the centroid of all captures
//! together, so the shifts between instants, which are part of the code, are kept; or each
//! capture's own) and each channel is normalised to unit sum.

use super::psf::Psf;

/// A linear RGB image, planar.
#[derive(Debug, Clone)]
pub struct Planes {
    pub width: usize,
    pub height: usize,
    pub rgb: [Vec<f32>; 3],
}

/// How `calibrate` centres the crops.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
#[value(rename_all = "snake_case")]
pub enum Centre {
    /// One centre for the stack: the centroid of all captures (keeps the shifts between them).
    Common,
    /// Each capture on its own centroid.
    Each,
}

/// The settings of a calibration.
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Side of the PSFs, odd.
    pub size: usize,
    /// Noise deviations above the dark level below which a value is taken as zero.
    pub threshold: f64,
    pub centre: Centre,
    /// Border width (pixels) on which the dark level and the noise are measured.
    pub border: usize,
}

/// What was measured on one capture.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Entry {
    /// Dark level taken off, per channel (the dark frame's mean where one is given).
    pub dark: [f64; 3],
    /// Noise deviation on the border, per channel.
    pub noise: [f64; 3],
    /// The capture's centroid (x, y), pixels.
    pub centroid: [f64; 2],
    /// Top-left corner of its crop.
    pub crop: [usize; 2],
    /// Signal per channel (sum after the dark level and the threshold) before normalising.
    pub signal: [f64; 3],
    /// Share of that signal inside the crop.
    pub inside: [f64; 3],
}

fn median(mut v: Vec<f32>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let m = v.len() / 2;
    v.select_nth_unstable_by(m, f32::total_cmp);
    v[m] as f64
}

fn border(p: &[f32], w: usize, h: usize, b: usize) -> Vec<f32> {
    (0..w * h).filter(|i| i % w < b || i % w >= w - b || i / w < b || i / w >= h - b).map(|i| p[i]).collect()
}

/// The signal of one capture: dark level off, noise below the threshold zeroed. Returns the
/// planes, the dark level and the noise per channel.
fn signal(c: &Planes, dark: Option<&Planes>, o: &Options) -> ([Vec<f32>; 3], [f64; 3], [f64; 3]) {
    let (w, h) = (c.width, c.height);
    let b = o.border.min(w / 4).min(h / 4).max(1);
    let mut level = [0.0; 3];
    let mut noise = [0.0; 3];
    let planes = std::array::from_fn(|ch| {
        let mut p: Vec<f32> = match dark {
            Some(d) => c.rgb[ch].iter().zip(&d.rgb[ch]).map(|(a, z)| a - z).collect(),
            None => c.rgb[ch].clone(),
        };
        let base = if dark.is_some() { 0.0 } else { median(border(&p, w, h, b)) };
        p.iter_mut().for_each(|v| *v -= base as f32);
        let edge = border(&p, w, h, b);
        let sigma = 1.4826 * median(edge.iter().map(|v| v.abs()).collect());
        let cut = (o.threshold * sigma) as f32;
        p.iter_mut().for_each(|v| *v = if *v > cut { *v } else { 0.0 });
        level[ch] = dark.map_or(base, |d| d.rgb[ch].iter().map(|&v| v as f64).sum::<f64>() / d.rgb[ch].len() as f64);
        noise[ch] = sigma;
        p
    });
    (planes, level, noise)
}

fn centroid(planes: &[[Vec<f32>; 3]], w: usize) -> [f64; 2] {
    let (mut sx, mut sy, mut s) = (0.0, 0.0, 0.0);
    for p in planes {
        for ch in p {
            for (i, &v) in ch.iter().enumerate() {
                let v = v as f64;
                sx += v * (i % w) as f64;
                sy += v * (i / w) as f64;
                s += v;
            }
        }
    }
    if s > 0.0 {
        [sx / s, sy / s]
    } else {
        [0.0, 0.0]
    }
}

/// Why captures could not be calibrated.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[non_exhaustive]
pub enum CalibrateError {
    #[error("no captures")]
    NoCaptures,
    #[error("capture {index} is {width}x{height}, the first is {first_width}x{first_height}")]
    Size { index: usize, width: usize, height: usize, first_width: usize, first_height: usize },
    #[error("the dark frame is not {0}x{1} like the captures")]
    DarkSize(usize, usize),
    #[error("size {size} must be odd and at most the captures' {width}x{height}")]
    Crop { size: usize, width: usize, height: usize },
    #[error("capture {index}: no signal above the noise in channel {channel} inside the crop")]
    NoSignal { index: usize, channel: &'static str },
}

/// The PSF stack of `captures` (all of one size; `dark` of that size too).
///
/// # Errors
/// Captures of different sizes, a size larger than a capture, or a capture with no signal above
/// the noise in some channel (named by its index).
pub fn calibrate(captures: &[Planes], dark: Option<&Planes>, o: &Options) -> Result<(Vec<Psf>, Vec<Entry>), CalibrateError> {
    let first = captures.first().ok_or(CalibrateError::NoCaptures)?;
    let (w, h) = (first.width, first.height);
    if let Some((index, c)) = captures.iter().enumerate().find(|(_, c)| (c.width, c.height) != (w, h)) {
        return Err(CalibrateError::Size { index, width: c.width, height: c.height, first_width: w, first_height: h });
    }
    if dark.is_some_and(|d| (d.width, d.height) != (w, h)) {
        return Err(CalibrateError::DarkSize(w, h));
    }
    if o.size.is_multiple_of(2) || o.size > w || o.size > h {
        return Err(CalibrateError::Crop { size: o.size, width: w, height: h });
    }
    let signals: Vec<_> = captures.iter().map(|c| signal(c, dark, o)).collect();
    let planes: Vec<[Vec<f32>; 3]> = signals.iter().map(|s| s.0.clone()).collect();
    let common = centroid(&planes, w);
    let half = o.size / 2;
    let mut psfs = Vec::with_capacity(captures.len());
    let mut entries = Vec::with_capacity(captures.len());
    for (i, (p, level, noise)) in signals.into_iter().enumerate() {
        let own = centroid(std::slice::from_ref(&p), w);
        let c = if o.centre == Centre::Each { own } else { common };
        let x0 = (c[0].round() as usize).clamp(half, w - 1 - half) - half;
        let y0 = (c[1].round() as usize).clamp(half, h - 1 - half) - half;
        let mut signal = [0.0; 3];
        let mut inside = [0.0; 3];
        let channels: [Vec<f32>; 3] = std::array::from_fn(|ch| {
            let total: f64 = p[ch].iter().map(|&v| v as f64).sum();
            let crop: Vec<f32> = (0..o.size * o.size).map(|k| p[ch][(y0 + k / o.size) * w + x0 + k % o.size]).collect();
            let kept: f64 = crop.iter().map(|&v| v as f64).sum();
            signal[ch] = total;
            inside[ch] = if total > 0.0 { kept / total } else { 0.0 };
            crop.iter().map(|&v| if kept > 0.0 { (v as f64 / kept) as f32 } else { 0.0 }).collect()
        });
        if let Some(ch) = (0..3).find(|&ch| inside[ch] * signal[ch] <= 0.0) {
            return Err(CalibrateError::NoSignal { index: i, channel: ["R", "G", "B"][ch] });
        }
        psfs.push(Psf { size: o.size, channels });
        entries.push(Entry { dark: level, noise, centroid: own, crop: [x0, y0], signal, inside });
    }
    Ok((psfs, entries))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shifted_psf_over_a_dark_level_comes_back_centred_and_normalised() {
        // A 3x3 PSF (different per channel) at (20, 13) in a 32x24 capture over a level of 0.1.
        let k: [[f32; 9]; 3] = [
            [0.0, 0.1, 0.0, 0.1, 0.6, 0.1, 0.0, 0.1, 0.0],
            [0.05, 0.1, 0.05, 0.1, 0.4, 0.1, 0.05, 0.1, 0.05],
            [0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0],
        ];
        let (w, h) = (32, 24);
        let cap = Planes {
            width: w,
            height: h,
            rgb: std::array::from_fn(|c| {
                let mut p = vec![0.1f32; w * h];
                for j in 0..9 {
                    p[(12 + j / 3) * w + 19 + j % 3] += 0.5 * k[c][j];
                }
                p
            }),
        };
        let o = Options { size: 5, threshold: 3.0, centre: Centre::Common, border: 4 };
        let (psfs, e) = calibrate(&[cap.clone(), cap], None, &o).unwrap();
        assert_eq!(psfs.len(), 2);
        assert!((e[0].dark[0] - 0.1).abs() < 1e-6 && (e[0].centroid[0] - 20.0).abs() < 1e-4 && e[0].crop == [18, 11]);
        for c in 0..3 {
            for j in 0..9 {
                let got = psfs[0].channels[c][(1 + j / 3) * 5 + 1 + j % 3];
                assert!((got - k[c][j]).abs() < 1e-5, "channel {c} tap {j}: {got}");
            }
            assert!((psfs[0].channel_sum(c) - 1.0).abs() < 1e-5);
        }
        let err = calibrate(&[Planes { width: 4, height: 4, rgb: std::array::from_fn(|_| vec![0.0; 16]) }], None, &o).unwrap_err();
        assert_eq!(err, CalibrateError::Crop { size: 5, width: 4, height: 4 });
    }
}
