//! The decoder's own Y'CbCr conversion against swscale's accurate path, on real encoded clips.

use crate::common::{clip, FIXTURE};
use pipeline::frame::FrameData;
use pipeline::io::video::VideoReader;
use std::path::Path;

fn planes(path: &Path, swscale: bool, frames: usize) -> (Vec<[Vec<u8>; 3]>, String) {
    let mut r = VideoReader::open(path).unwrap();
    r.force_swscale = swscale;
    let fmt = r.info.pixel_format.clone();
    let out = (0..frames)
        .map(|_| match &*r.next_frame().unwrap().expect("a frame").data {
            FrameData::Planar8(p) => p.clone(),
            _ => panic!("8-bit source gave no 8-bit planes"),
        })
        .collect();
    (out, fmt)
}

#[test]
fn own_conversion_equals_swscale_within_one_level() {
    // The fixture (4:2:0, BT.601 by default) and clips in the other matrices, ranges and
    // subsamplings the fast path takes, with odd sizes and saturated colours (testsrc2).
    let base = ["-f", "lavfi", "-i", "testsrc2=size=161x91:rate=24", "-frames:v", "3", "-c:v", "libx264", "-qp", "10"];
    let make = |name: &str, extra: &[&str]| {
        let mut a = base.to_vec();
        a.extend_from_slice(extra);
        clip(name, &a)
    };
    let cases = [
        (std::path::PathBuf::from(FIXTURE), "fixture"),
        (make("yuv-709.mp4", &["-pix_fmt", "yuv420p", "-colorspace", "bt709", "-color_range", "tv"]), "bt709 4:2:0 (odd size)"),
        (make("yuv-full.mp4", &["-pix_fmt", "yuvj420p"]), "full range 4:2:0"),
        (make("yuv-422.mp4", &["-pix_fmt", "yuv422p", "-colorspace", "bt709"]), "4:2:2"),
        (make("yuv-444.mp4", &["-pix_fmt", "yuv444p", "-colorspace", "bt2020nc"]), "4:4:4 bt2020"),
    ];
    for (path, what) in cases {
        let ((fast, fmt), (slow, _)) = (planes(&path, false, 3), planes(&path, true, 3));
        let (mut worst, mut sum, mut n, mut off) = (0i32, 0u64, 0u64, 0u64);
        for (a, b) in fast.iter().zip(&slow) {
            for c in 0..3 {
                for (x, y) in a[c].iter().zip(&b[c]) {
                    let d = (*x as i32 - *y as i32).abs();
                    worst = worst.max(d);
                    sum += d as u64;
                    off += u64::from(d > 0);
                    n += 1;
                }
            }
        }
        let mean = sum as f64 / n as f64;
        assert!(worst <= 1, "{what} ({fmt}): differs from swscale by up to {worst} levels");
        assert!(mean < 0.1, "{what} ({fmt}): mean difference {mean}");
        eprintln!("{what} ({fmt}): {off} of {n} values one level apart, mean {mean:.4}");
    }
}
