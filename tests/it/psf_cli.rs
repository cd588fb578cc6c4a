//! `pipeline psf`: outputs other tools read, and errors that name the flag or key.

use crate::common::*;
use pipeline::io::npy;

fn read_npy(p: &std::path::Path) -> (Vec<usize>, Vec<f32>) {
    npy::read_f32(&std::fs::read(p).unwrap()).unwrap()
}

fn channel_sum(data: &[f32], shape: &[usize], k: usize, c: usize) -> f64 {
    let (h, w) = (shape[1], shape[2]);
    (0..h * w).map(|i| data[(k * h * w + i) * 3 + c] as f64).sum()
}

fn peak(data: &[f32], shape: &[usize], k: usize, c: usize) -> f32 {
    let (h, w) = (shape[1], shape[2]);
    (0..h * w).map(|i| data[(k * h * w + i) * 3 + c]).fold(0.0, f32::max)
}

#[test]
fn npy_has_shape_k_h_w_3_and_unit_sum_channels_that_go_blue_green_red() {
    let d = scratch("psf_npy");
    let out = d.join("psfs.npy");
    let o = run(&["psf", "--camera", "phase_coded", "--psi", "0:8:33", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (shape, data) = read_npy(&out);
    assert_eq!(shape.len(), 4);
    assert_eq!((shape[0], shape[3]), (33, 3));
    assert_eq!(shape[1], shape[2]);
    assert_eq!(shape[1] % 2, 1);
    for k in 0..33 {
        for c in 0..3 {
            assert!((channel_sum(&data, &shape, k, c) - 1.0).abs() < 1e-4);
        }
    }
    let sharpest = |k| (0..3).max_by(|&a, &b| peak(&data, &shape, k, a).total_cmp(&peak(&data, &shape, k, b))).unwrap();
    assert_eq!((sharpest(0), sharpest(16), sharpest(32)), (2, 1, 0));
    // The table is printed too.
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("sharpest") && table.lines().count() >= 34, "{table}");
    assert!(table.contains("B -> G") && table.contains("G -> R"));
}

#[test]
fn window_writes_one_kernel_per_subframe_for_every_camera() {
    let d = scratch("psf_window");
    for cam in ["conventional", "focus_sweep", "phase_coded", "flutter", "parabolic"] {
        let out = d.join(format!("{cam}.npy"));
        let o = run(&["psf", "--camera", cam, "--window", "9", "--out", out.to_str().unwrap()]);
        assert!(o.status.success(), "{cam}: {}", stderr(&o));
        let (shape, data) = read_npy(&out);
        assert_eq!(shape[0], 9, "{cam}");
        for k in 0..9 {
            assert!((channel_sum(&data, &shape, k, 1) - 1.0).abs() < 1e-4, "{cam} k {k}");
        }
    }
}

#[test]
fn exr_decodes_with_ffmpeg_to_the_same_linear_values_as_npy() {
    let d = scratch("psf_exr");
    let (exr, npyp) = (d.join("p.exr"), d.join("p.npy"));
    for out in [&exr, &npyp] {
        let o = run(&["psf", "--psi", "0,8", "--out", out.to_str().unwrap()]);
        assert!(o.status.success(), "{}", stderr(&o));
    }
    let (shape, data) = read_npy(&npyp);
    let (n, k) = (shape[1], shape[0]);
    // FFmpeg's own EXR decoder: planar G, B, R float32.
    let raw = d.join("p.raw");
    let st = std::process::Command::new("ffmpeg")
        .args(["-v", "error", "-y", "-i", exr.to_str().unwrap(), "-f", "rawvideo", "-pix_fmt", "gbrpf32le", raw.to_str().unwrap()])
        .status()
        .expect("ffmpeg CLI (installed by .ci/setup.sh)");
    assert!(st.success());
    let bytes = std::fs::read(&raw).unwrap();
    let vals: Vec<f32> = bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    let (w, h) = (n * k, n);
    assert_eq!(vals.len(), 3 * w * h);
    let plane = |c: usize| &vals[c * w * h..(c + 1) * w * h];
    let (g, b, r) = (plane(0), plane(1), plane(2));
    for t in 0..k {
        for y in 0..n {
            for x in 0..n {
                let i = y * w + t * n + x;
                let j = ((t * n + y) * n + x) * 3;
                assert_eq!([r[i], g[i], b[i]], [data[j], data[j + 1], data[j + 2]]);
            }
        }
    }
}

#[test]
fn png_strip_is_a_readable_colour_image() {
    let d = scratch("psf_png");
    let out = d.join("strip.png");
    let o = run(&["psf", "--psi", "0:8:5", "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let (w, h, rgb) = pipeline::io::png::read_rgb8(&std::fs::read(&out).unwrap()).unwrap();
    assert!(w > 5 * h / 2, "a strip is wide: {w}x{h}");
    // Blue dominates the brightest pixel of the first tile, red that of the last.
    let tile = |x0: usize, x1: usize| {
        let mut best = (0u32, [0u8; 3]);
        for y in 0..h {
            for x in x0..x1 {
                let p = &rgb[(y * w + x) * 3..(y * w + x) * 3 + 3];
                let s = p.iter().map(|&v| v as u32).sum::<u32>();
                if s > best.0 && p.contains(&255) {
                    best = (s, [p[0], p[1], p[2]]);
                }
            }
        }
        best.1
    };
    let first = tile(0, w / 5);
    let last = tile(4 * w / 5, w);
    assert!(first[2] > first[0], "first tile {first:?}");
    assert!(last[0] > last[2], "last tile {last:?}");
}

#[test]
fn wrong_flag_values_are_one_line_errors_naming_the_flag() {
    for (args, flag) in [
        (vec!["psf", "--psi", "0:8"], "--psi"),
        (vec!["psf", "--window", "0"], "--window"),
        (vec!["psf", "--camera", "pinhole"], "--camera"),
        (vec!["psf", "--airy-radius-px", "-1"], "--airy-radius-px"),
        (vec!["psf", "--defocus-sign", "2"], "--defocus-sign"),
    ] {
        let o = run(&args);
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        let first = stderr(&o).lines().next().unwrap_or("").to_string();
        assert!(first.starts_with("error:") && first.contains(flag), "{args:?}: {first}");
    }
}

#[test]
fn config_typos_and_bad_values_name_the_key_and_write_nothing() {
    let d = scratch("psf_config");
    let out = d.join("p.npy");
    let typo = d.join("typo.toml");
    std::fs::write(&typo, "[optics]\nairy_radius = 3.0\n").unwrap();
    let o = run(&["psf", "--config", typo.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("airy_radius") && stderr(&o).contains("typo.toml"), "{}", stderr(&o));
    let bad = d.join("bad.toml");
    std::fs::write(&bad, "[optics]\npupil_samples = 4\n[camera]\ntype = \"flutter\"\nflutter_code = \"10x1\"\n").unwrap();
    let o = run(&["psf", "--config", bad.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2));
    let e = stderr(&o);
    assert!(e.contains("optics.pupil_samples") && e.contains("camera.flutter_code"), "both errors in one pass: {e}");
    assert!(!out.exists());
}

#[test]
fn unwritable_output_and_unknown_extension_are_clear_errors() {
    let d = scratch("psf_out");
    let o = run(&["psf", "--psi", "0", "--out", "/nonexistent-dir/p.npy"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(stderr(&o).contains("/nonexistent-dir/p.npy"), "{}", stderr(&o));
    let o = run(&["psf", "--psi", "0", "--out", d.join("p.tiff").to_str().unwrap()]);
    assert!(!o.status.success() && stderr(&o).contains("p.tiff"));
    assert!(files(&d).is_empty(), "nothing half-written: {:?}", files(&d));
}
