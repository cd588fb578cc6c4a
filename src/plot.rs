//! Small line charts as PNG (training curves), drawn without a plotting library.

use crate::io::{font, png as png_io, write_atomic};

/// A canvas of planar RGB in [0, 1].
pub struct Canvas {
    pub w: usize,
    pub h: usize,
    pub px: [Vec<f32>; 3],
}

impl Canvas {
    pub fn new(w: usize, h: usize, bg: [f32; 3]) -> Canvas {
        Canvas { w, h, px: std::array::from_fn(|c| vec![bg[c]; w * h]) }
    }

    pub fn dot(&mut self, x: i64, y: i64, col: [f32; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.w && (y as usize) < self.h {
            for c in 0..3 {
                self.px[c][y as usize * self.w + x as usize] = col[c];
            }
        }
    }

    /// A 2-pixel line from (x0, y0) to (x1, y1).
    pub fn line(&mut self, (x0, y0): (f64, f64), (x1, y1): (f64, f64), col: [f32; 3]) {
        let n = ((x1 - x0).abs().max((y1 - y0).abs()) * 2.0).ceil().max(1.0) as usize;
        for i in 0..=n {
            let t = i as f64 / n as f64;
            let (x, y) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
            self.dot(x.round() as i64, y.round() as i64, col);
            self.dot(x.round() as i64, y.round() as i64 + 1, col);
        }
    }

    pub fn text(&mut self, x: usize, y: usize, s: &str, col: [f32; 3]) {
        font::draw_text(&mut self.px, self.w, x, y, s, 2, col);
    }

    pub fn to_rgb8(&self) -> Vec<u8> {
        (0..self.w * self.h).flat_map(|i| [0, 1, 2].map(|c| (self.px[c][i].clamp(0.0, 1.0) * 255.0).round() as u8)).collect()
    }

    /// Writes the canvas as PNG (atomically).
    ///
    /// # Errors
    /// The file cannot be written.
    pub fn save(&self, path: &std::path::Path) -> crate::Result<()> {
        let rgb = self.to_rgb8();
        write_atomic(path, |w| png_io::write_rgb8(w, self.w, self.h, &rgb))
    }
}

/// One labelled picture for a figure: planar RGB display values in [0, 1].
pub struct Panel {
    pub label: String,
    pub w: usize,
    pub h: usize,
    pub px: [Vec<f32>; 3],
}

impl Panel {
    /// From interleaved 8-bit RGB.
    pub fn from_rgb8(label: impl Into<String>, w: usize, h: usize, rgb: &[u8]) -> Panel {
        Panel { label: label.into(), w, h, px: std::array::from_fn(|c| (0..w * h).map(|i| rgb[i * 3 + c] as f32 / 255.0).collect()) }
    }

    /// Linear planes shown with their own peak at 1, sRGB-encoded ("gamma correction").
    pub fn from_linear_normalised(label: impl Into<String>, w: usize, h: usize, p: &[Vec<f32>; 3]) -> Panel {
        let peak = p.iter().flat_map(|c| c.iter()).fold(1e-12f32, |m, v| m.max(*v));
        Panel { label: label.into(), w, h, px: std::array::from_fn(|c| p[c].iter().map(|v| png_io::srgb_encode(v / peak)).collect()) }
    }
}

impl Canvas {
    /// Draws `p` with its top-left at (x0, y0): its label in a bar `label_h` high (font scale 2
    /// when it fits `width`, else 1), then its pixels, each repeated `scale` times (nearest).
    pub fn draw_panel(&mut self, (x0, y0): (usize, usize), label_h: usize, width: usize, p: &Panel, scale: usize) {
        let s = if font::text_width(&p.label, 2) <= width { 2 } else { 1 };
        font::draw_text(&mut self.px, self.w, x0 + 1, y0 + 2, &p.label, s, [0.0, 0.0, 0.0]);
        for y in 0..p.h * scale {
            for x in 0..p.w * scale {
                for (c, plane) in self.px.iter_mut().enumerate() {
                    plane[(y0 + label_h + y) * self.w + x0 + x] = p.px[c][(y / scale) * p.w + x / scale].clamp(0.0, 1.0);
                }
            }
        }
    }
}

/// One series of (x, y) points with a name and a colour.
pub struct Series<'a> {
    pub name: &'a str,
    pub points: Vec<(f64, f64)>,
    pub color: [f32; 3],
}

fn fmt_tick(v: f64) -> String {
    if v.abs() >= 100.0 || v == v.round() {
        format!("{v:.0}")
    } else if v.abs() >= 1.0 {
        format!("{v:.1}")
    } else {
        format!("{v:.3}")
    }
}

/// Draws a panel of series into `canvas` at (ox, oy) of size (pw, ph), with a title (which names
/// the y axis), min/max labels on both axes and `x_label` under the x axis.
pub fn panel(canvas: &mut Canvas, (ox, oy, pw, ph): (usize, usize, usize, usize), title: &str, x_label: &str, series: &[Series]) {
    let fg = [0.9, 0.9, 0.9];
    let pts = series.iter().flat_map(|s| s.points.iter()).filter(|p| p.0.is_finite() && p.1.is_finite());
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in pts {
        x0 = x0.min(p.0);
        x1 = x1.max(p.0);
        y0 = y0.min(p.1);
        y1 = y1.max(p.1);
    }
    canvas.text(ox, oy, title, fg);
    if x0 > x1 {
        return;
    }
    if x1 == x0 {
        x1 = x0 + 1.0;
    }
    if y1 == y0 {
        y1 = y0 + 1.0;
    }
    let right = ox + pw - 10;
    let (left, bottom) = (ox + 80, oy + ph - 24);
    // The legend gets rows of its own under the title, so no curve runs under it.
    let names: Vec<&str> = series.iter().map(|s| s.name).collect();
    let (at, legend_end) = legend_layout(&names, left + 10, right, oy + 16);
    let top = legend_end + 8;
    let to = |x: f64, y: f64| {
        (left as f64 + (x - x0) / (x1 - x0) * (right - left) as f64, bottom as f64 - (y - y0) / (y1 - y0) * (bottom - top) as f64)
    };
    canvas.line((left as f64, top as f64), (left as f64, bottom as f64), fg);
    canvas.line((left as f64, bottom as f64), (right as f64, bottom as f64), fg);
    canvas.text(ox, top, &fmt_tick(y1), fg);
    canvas.text(ox, bottom - 10, &fmt_tick(y0), fg);
    canvas.text(left, bottom + 6, &fmt_tick(x0), fg);
    let xl = fmt_tick(x1);
    canvas.text(right.saturating_sub(font::text_width(&xl, 2)), bottom + 6, &xl, fg);
    canvas.text((left + right) / 2 - font::text_width(x_label, 2) / 2, bottom + 6, x_label, fg);
    for (i, s) in series.iter().enumerate() {
        for w in s.points.windows(2) {
            canvas.line(to(w[0].0, w[0].1), to(w[1].0, w[1].1), s.color);
        }
        if s.points.len() == 1 {
            let (x, y) = to(s.points[0].0, s.points[0].1);
            canvas.line((x - 3.0, y), (x + 3.0, y), s.color);
        }
        canvas.text(at[i].0, at[i].1, s.name, s.color);
    }
}

/// Height of a line of text at scale 2 (5 rows of glyph, 2 px each, and a gap).
const TEXT_ROW: usize = 14;

/// Places legend entries `names` left to right from `x0`, wrapping before `x1`, in rows from
/// `y0`: each entry's top-left, and the y where the last row ends.
fn legend_layout(names: &[&str], x0: usize, x1: usize, y0: usize) -> (Vec<(usize, usize)>, usize) {
    let (mut x, mut y) = (x0, y0);
    let mut at = Vec::with_capacity(names.len());
    for n in names {
        let w = font::text_width(n, 2);
        if x > x0 && x + w > x1 {
            (x, y) = (x0, y + TEXT_ROW);
        }
        at.push((x, y));
        x += w + 24;
    }
    (at, if names.is_empty() { y0 } else { y + TEXT_ROW })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_legend_sits_above_the_curves_and_its_entries_do_not_overlap() {
        // A flat curve at the very top of the plot, and names too long for one row.
        let (w, h, right) = (400, 200, 390);
        let mut c = Canvas::new(w, h, [0.0; 3]);
        let names = ["TRAINING LOSS (PER STEP)", "RUNNING MEAN OF 100", "INITIAL MODEL'S RUN"];
        let series: Vec<Series> = names
            .iter()
            .enumerate()
            .map(|(i, n)| Series {
                name: n,
                points: vec![(0.0, 1.0 - i as f64 * 0.5), (2.0, 1.0 - i as f64 * 0.5)],
                color: [1.0, 0.0, i as f32 * 0.1],
            })
            .collect();
        panel(&mut c, (0, 0, w, h), "T", "X", &series);
        let (at, end) = legend_layout(&names, 90, right, 16);
        assert!(at[1].1 > at[0].1, "the second name wraps to a row of its own: {at:?}");
        for (i, &(x, y)) in at.iter().enumerate() {
            assert!(x + font::text_width(names[i], 2) <= right && y + TEXT_ROW <= end, "{i}: {at:?}");
            if let Some(&(x2, y2)) = at.get(i + 1) {
                assert!(y2 > y || x2 >= x + font::text_width(names[i], 2), "{i} and {} overlap: {at:?}", i + 1);
            }
        }
        // The top curve, seen in the last column of the plot, runs below every row of the legend.
        let col = right - 1;
        let top_curve = (0..h).find(|&y| c.px[0][y * w + col] == 1.0 && c.px[2][y * w + col] == 0.0).expect("the top curve");
        assert!(top_curve >= end, "the top curve at row {top_curve} runs under the legend (rows to {end})");
    }
}
