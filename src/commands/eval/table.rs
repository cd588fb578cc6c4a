//! The markdown tables of `eval.md`: Table 1 (N by sigma) and the per-sigma tables.

use super::*;

fn pair(q: &Quality, y: bool) -> String {
    if y {
        format!("{:.2} / {:.4}", q.psnr_y, q.ssim_y)
    } else {
        format!("{:.2} / {:.4}", q.psnr_rgb, q.ssim_rgb)
    }
}

fn rows(cells: &[Cell], with_sigma: bool, versus: Option<&Versus>) -> String {
    let with_video = cells.iter().any(|c| c.video.is_some());
    let with_bound = cells.iter().any(|c| c.bound.is_some());
    let mut s = String::new();
    s.push_str(if with_video { "| video " } else { "" });
    s.push_str(if with_sigma { "| N | sigma " } else { "| N " });
    s.push_str("| blurred input (RGB) | deblurred (RGB) | gain dB | blurred input (Y) | deblurred (Y) | gain dB | windows ");
    if with_bound {
        s.push_str("| Wiener, true kernel (RGB) | its gain dB | share of it reached ");
    }
    if let Some(v) = versus {
        s.push_str(&format!("| output minus {} output dB ", v.camera));
    }
    s.push_str("|\n");
    s.push_str(if with_video { "|---" } else { "" });
    s.push_str(if with_sigma { "|---|---" } else { "|---" });
    s.push_str("|---|---|---|---|---|---|---");
    s.push_str(if with_bound { "|---|---|---" } else { "" });
    s.push_str(if versus.is_some() { "|---" } else { "" });
    s.push_str("|\n");
    for c in cells {
        if let Some(v) = &c.video {
            s.push_str(&format!("| {} ", Path::new(v).file_name().map_or(v.clone(), |f| f.to_string_lossy().into_owned())));
        }
        s.push_str(&format!("| N={} ", c.window));
        if with_sigma {
            s.push_str(&format!("| {} ", c.sigma.unwrap_or(f64::NAN)));
        }
        s.push_str(&format!(
            "| {} | {} | {:+.2} | {} | {} | {:+.2} | {} ",
            pair(&c.blurred, false),
            pair(&c.deblurred, false),
            c.deblurred.psnr_rgb - c.blurred.psnr_rgb,
            pair(&c.blurred, true),
            pair(&c.deblurred, true),
            c.deblurred.psnr_y - c.blurred.psnr_y,
            c.count
        ));
        if with_bound {
            match &c.bound {
                Some((b, n)) => {
                    let (gain, got) = (b.psnr_rgb - c.blurred.psnr_rgb, c.deblurred.psnr_rgb - c.blurred.psnr_rgb);
                    let share = if gain > 0.05 { format!("{:.0}%", 100.0 * got / gain) } else { "-".into() };
                    s.push_str(&format!("| {} ({n}) | {gain:+.2} | {share} ", pair(b, false)));
                }
                None => s.push_str("| - | - | - "),
            }
        }
        if let Some(v) = versus {
            match v.psnr_rgb.iter().find(|(n, _)| *n == c.window).filter(|_| c.video.is_none() && c.sigma.is_none()) {
                Some((_, o)) => s.push_str(&format!("| {:+.2} ", c.deblurred.psnr_rgb - o)),
                None => s.push_str("| "),
            }
        }
        s.push_str("|\n");
    }
    s
}

/// The shake table: per motion, N and spread bin, PSNR dB / SSIM (RGB) and the gain.
fn spread_rows(cells: &[SpreadCell]) -> String {
    let mut s = String::from(
        "| motion | N | spread px | windows | blurred input (RGB) | deblurred (RGB) | gain dB | Wiener, true kernel: gain dB |\n|---|---|---|---|---|---|---|---|\n",
    );
    for c in cells {
        let range = if c.spread_px[1].is_finite() {
            format!("{}-{}", c.spread_px[0], c.spread_px[1])
        } else {
            format!("{} and more", c.spread_px[0])
        };
        s.push_str(&format!(
            "| {} | N={} | {range} | {} | {} | {} | {:+.2} | {} |\n",
            c.motion,
            c.window,
            c.count,
            pair(&c.blurred, false),
            pair(&c.deblurred, false),
            c.deblurred.psnr_rgb - c.blurred.psnr_rgb,
            c.bound.as_ref().map_or("-".into(), |b| format!("{:+.2}", b.psnr_rgb - c.blurred.psnr_rgb))
        ));
    }
    s
}

/// `eval.md`: Table 1 (mean over sigma) and the per-sigma tables, PSNR dB / SSIM.
pub fn markdown(r: &EvalReport) -> String {
    let sig: Vec<String> = r.config.eval.sigmas.iter().map(|s| s.to_string()).collect();
    let mut s = format!(
        "# pipeline eval\n\nModel: {}  \nCamera: {}  \nVideos: {}  \nScored region: {}x{} at ({}, {})  \nMetrics: {}\n\n",
        r.model,
        r.camera,
        r.videos.join(", "),
        r.region[2],
        r.region[3],
        r.region[0],
        r.region[1],
        r.convention
    );
    if let Some(sn) = &r.config.eval.sensor {
        s.push_str(&format!(
            "Read-out: a sensor at ISO {} (full well {} e-, read noise {} e-, {}), then sigma\n\n",
            sn.iso,
            sn.full_well,
            sn.read_noise,
            sn.bayer.map_or("no mosaic".to_string(), |b| format!("{b:?} mosaic, {:?} demosaicing", sn.demosaic).to_uppercase())
        ));
    }
    s.push_str(&format!("## Table 1 layout: PSNR dB / SSIM, mean over sigma in {{{}}}\n\n", sig.join(", ")));
    s.push_str(&rows(&r.table, false, r.versus.as_ref()));
    s.push_str("\n## Per noise level\n\n");
    s.push_str(&rows(&r.per_sigma, true, None));
    s.push_str(&format!("\n## Per video: mean over sigma in {{{}}}\n\n", sig.join(", ")));
    s.push_str(&rows(&r.per_video, false, None));
    if !r.per_spread.is_empty() {
        s.push_str(&format!("\n## Camera shake by spread of the path: mean over sigma in {{{}}}\n\n", sig.join(", ")));
        s.push_str(&spread_rows(&r.per_spread));
    }
    let ex: Vec<&str> = r.records.iter().filter_map(|x| x.example.as_deref()).collect();
    if !ex.is_empty() {
        s.push_str("\n## Examples (blurred | deblurred | sharp)\n\n");
        for e in ex {
            s.push_str(&format!("![{e}]({e})\n"));
        }
    }
    s
}
