//! The `measured` camera: a PSF stack exported by `pipeline psf` reproduces the computed camera's
//! shards, and a corrupt or misshapen stack is refused with its file and the rule it breaks.

use crate::common::*;

fn ok(o: &std::process::Output) {
    assert!(o.status.success(), "exit {:?}: {}", o.status.code(), stderr(o));
}

#[test]
fn an_exported_stack_reproduces_the_computed_cameras_shards_byte_for_byte() {
    let d = scratch("measured_round_trip");
    let stack = d.join("coded-n9.npy");
    ok(&run(&["psf", "--camera", "phase_coded", "--window", "9", "--out", stack.to_str().unwrap()]));
    let (computed, measured) = (d.join("computed"), d.join("measured"));
    let short = "sources.video.max_frames=27";
    ok(&generate(&computed, &[FIXTURE], &[short, "seed=3"]));
    let path = format!("transforms.blur.camera.psf_path={:?}", stack.to_str().unwrap());
    ok(&generate(&measured, &[FIXTURE], &[short, "seed=3", "transforms.blur.camera.type=\"measured\"", &path]));
    let (a, b) = (shard_members(&computed), shard_members(&measured));
    assert!(a.len() >= 6 && a.len() == b.len(), "{} against {} members", a.len(), b.len());
    for ((na, da), (nb, db)) in a.iter().zip(&b) {
        assert_eq!(na, nb);
        if na.ends_with(".png") {
            assert!(da == db, "{na} differs");
        } else {
            // key.json names the camera, and a stack over instants knows no psi (0); everything
            // else in it is the same.
            let (mut ja, jb): (serde_json::Value, serde_json::Value) =
                (serde_json::from_slice(da).unwrap(), serde_json::from_slice(db).unwrap());
            assert_eq!(ja["camera"], "phase_coded");
            assert_eq!(jb["camera"], "measured");
            ja["camera"] = "measured".into();
            ja["psi"] = vec![0.0; 9].into();
            assert_eq!(ja, jb, "{na}");
        }
    }
}

#[test]
fn a_bad_stack_is_refused_naming_the_file_and_the_rule() {
    let d = scratch("measured_bad");
    let write = |name: &str, shape: &[usize], data: &[f32]| {
        let p = d.join(name);
        let mut f = std::fs::File::create(&p).unwrap();
        pipeline::io::npy::write_f32(&mut f, shape, data).unwrap();
        p
    };
    let even = write("even.npy", &[2, 4, 4, 3], &[1.0 / 16.0; 96]);
    let mut neg = vec![1.0 / 9.0; 54];
    neg[30] = -0.5;
    let negative = write("negative.npy", &[2, 3, 3, 3], &neg);
    let unnormalised = write("dim.npy", &[1, 3, 3, 3], &[0.05; 27]);
    let not_npy = d.join("text.npy");
    std::fs::write(&not_npy, "not an array").unwrap();
    for (file, rule) in [
        (&even, "odd sides"),
        (&negative, "entry 1, pixel (1, 0), channel R"),
        (&unnormalised, "sums to 0.4500, not 1"),
        (&not_npy, "not an .npy file"),
    ] {
        let path = format!("transforms.blur.camera.psf_path={:?}", file.to_str().unwrap());
        let o = generate(&d.join("out"), &[FIXTURE], &["transforms.blur.camera.type=\"measured\"", &path]);
        let e = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{e}");
        assert!(e.contains("camera.psf_path") && e.contains(file.to_str().unwrap()) && e.contains(rule), "{rule}: {e}");
    }
    assert!(!d.join("out").exists(), "a refused configuration wrote output");
    // The same stack with psf_normalise is taken.
    let path = format!("transforms.blur.camera.psf_path={:?}", unnormalised.to_str().unwrap());
    ok(&generate(
        &d.join("normalised"),
        &[FIXTURE],
        &["sources.video.max_frames=9", "transforms.blur.camera.type=\"measured\"", &path, "transforms.blur.camera.psf_normalise=true"],
    ));
}

/// Writes linear planes in [0, 1] as a 16-bit RGB PNG.
fn write_png16(path: &std::path::Path, w: usize, h: usize, rgb: &[Vec<f32>; 3]) {
    let mut s = pipeline::io::png::Samples { width: w, height: h, channels: 3, sixteen: true, data: vec![0; w * h * 6], expanded: None };
    for i in 0..w * h {
        for (c, plane) in rgb.iter().enumerate() {
            s.set(i, c, plane[i]);
        }
    }
    pipeline::io::png::write_samples(&mut std::fs::File::create(path).unwrap(), &s).unwrap();
}

#[test]
fn calibrate_recovers_a_known_stack_from_noisy_shifted_point_source_captures() {
    let d = scratch("calibrate");
    let reference = d.join("reference.npy");
    ok(&run(&["psf", "--camera", "phase_coded", "--window", "9", "--out", reference.to_str().unwrap()]));
    let (shape, truth) = pipeline::io::npy::read_f32(&std::fs::read(&reference).unwrap()).unwrap();
    let (k, side) = (shape[0], shape[1]);
    // Nine captures of 96x80: the PSF times 0.9 / its largest value, its centre at (52, 35), over
    // a dark level of 0.03, with Gaussian noise of 0.0001 (1/9000 of the peak: about a hundred
    // frames of a point source averaged); a dark frame with the same noise.
    let (w, h, (cx, cy), level, sigma) = (96, 80, (52usize, 35usize), 0.03f32, 0.0001f32);
    let peak = truth.iter().copied().fold(0.0f32, f32::max);
    let mut rng = pipeline::rng::Rng::new(9);
    let mut noisy = |v: f32| (v + sigma * rng.normal() as f32).clamp(0.0, 1.0);
    let caps = d.join("captures");
    std::fs::create_dir_all(&caps).unwrap();
    for e in 0..k {
        let rgb: [Vec<f32>; 3] = std::array::from_fn(|c| {
            let mut p = vec![level; w * h];
            for y in 0..side {
                for x in 0..side {
                    p[(cy + y - side / 2) * w + cx + x - side / 2] += 0.9 / peak * truth[((e * side + y) * side + x) * 3 + c];
                }
            }
            p.into_iter().map(&mut noisy).collect()
        });
        write_png16(&caps.join(format!("{e:02}.png")), w, h, &rgb);
    }
    let dark = d.join("dark.png");
    write_png16(&dark, w, h, &std::array::from_fn(|_| (0..w * h).map(|_| noisy(level)).collect()));
    let out = d.join("lens.npy");
    let size = side.to_string();
    let args = ["calibrate", caps.to_str().unwrap(), "--dark", dark.to_str().unwrap(), "--size", &size, "-o", out.to_str().unwrap()];
    ok(&run(&args));
    let (got_shape, got) = pipeline::io::npy::read_f32(&std::fs::read(&out).unwrap()).unwrap();
    assert_eq!(got_shape, shape);
    // Each entry and channel within 10% of its energy (L1) of the true PSF: the coded PSFs' faint
    // halo (a sixth of the energy of some, spread over thousands of pixels) sits near the noise.
    let mut worst = 0.0f64;
    for e in 0..k {
        for c in 0..3 {
            let l1: f64 = (0..side * side)
                .map(|i| (got[(e * side * side + i) * 3 + c] as f64 - truth[(e * side * side + i) * 3 + c] as f64).abs())
                .sum();
            worst = worst.max(l1);
        }
    }
    assert!(worst < 0.1, "worst L1 distance {worst}");
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("lens.json")).unwrap()).unwrap();
    assert_eq!(report["entries"].as_array().unwrap().len(), k);
    assert!(d.join("lens.png").is_file());
    // The stack feeds the measured camera; a second run does not replace it without --overwrite.
    let o = run(&args);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--overwrite"));
    let path = format!("transforms.blur.camera.psf_path={:?}", out.to_str().unwrap());
    ok(&generate(&d.join("shards"), &[FIXTURE], &["sources.video.max_frames=9", "transforms.blur.camera.type=\"measured\"", &path]));
    // A capture folder that is not there is a usage error naming it.
    let o = run(&["calibrate", d.join("nothing").to_str().unwrap(), "-o", d.join("x.npy").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("nothing: no such file or folder"), "{}", stderr(&o));
}
