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
