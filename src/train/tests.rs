use super::*;

/// A shallow model of 4 filters; data and output paths that are never read.
fn tiny_config() -> TrainConfig {
    toml::from_str("[model]\ntype = \"shallow\"\nwidth = 4\n[data]\nshards = [\"x\"]\n[output]\ndir = \"x\"\n").unwrap()
}

#[test]
fn the_loss_curve_carries_its_running_mean() {
    let cfg = tiny_config();
    // Losses alternating between 1e-4 and 1e-2: the raw series fills the band between them,
    // the mean of 20 steps (1% of 2000) is a flat line near log10(5e-3) in the middle.
    let loss = (1..=2000).map(|step| LossPoint { step, loss: if step % 2 == 0 { 1e-4 } else { 1e-2 }, lr: 1e-3 }).collect();
    let r = TrainReport {
        version: "test",
        arch: "shallow-4".into(),
        parameters: 1,
        steps: 2000,
        resumed_from: None,
        resumed_data: None,
        interrupted: false,
        seconds: 1.0,
        patches_per_s: 1.0,
        train_inputs: Vec::new(),
        val_inputs: Vec::new(),
        val_samples: 0,
        metrics_convention: "test",
        loss,
        validation: Vec::new(),
        schedule: String::new(),
        before: None,
        averaged: None,
        config: cfg,
    };
    let path = std::env::temp_dir().join(format!("pipeline-curves-{}.png", std::process::id()));
    training_curves(&path, &r).unwrap();
    let (w, _, rgb) = crate::io::png::read_rgb8(&std::fs::read(&path).unwrap()).unwrap();
    std::fs::remove_file(&path).ok();
    // Pure white (the mean's colour; axes and labels are 0.9 grey) along one row inside the
    // loss panel's plot area (rows 48 to 286 under the title and the legend's row, the axes at
    // its edges excluded).
    let px = |x: usize, y: usize| &rgb[(y * w + x) * 3..(y * w + x) * 3 + 3];
    let white: Vec<usize> = (50..284).filter(|&y| (200..800).filter(|&x| px(x, y) == [255, 255, 255]).count() > 300).collect();
    assert!(!white.is_empty(), "no running-mean line in the loss panel");
    // log10(5.05e-3) = -2.30 on an axis from -4 to -2: 85% of the way up the plot area.
    let want = 286.0 - 0.85 * 238.0;
    assert!(white.iter().all(|&y| (y as f64 - want).abs() < 4.0), "mean line at rows {white:?}, want about {want}");
}

#[test]
fn a_model_with_non_finite_weights_is_refused_by_name() {
    let dir = crate::io::paths::scratch_dir("nan");
    let cfg = tiny_config();
    let dev = Device::flex();
    let net = Net::seeded(cfg.model, &dev, 1);
    save_checkpoint(&dir, &net, Vec::new(), &cfg.model, cfg.seed, 1).unwrap();
    assert!(load_model(&dir.join("model-0000001.safetensors"), &dev).is_ok());
    let mut f = FastNet::from_net(&net);
    let mut first = true;
    f.params(&mut |p, _| {
        if std::mem::take(&mut first) {
            p[0] = f32::NAN;
        }
    });
    save_checkpoint(&dir, &f.write_into(net), Vec::new(), &cfg.model, cfg.seed, 2).unwrap();
    let e = load_model(&dir.join("model-0000002.safetensors"), &dev).expect_err("refused").to_string();
    assert!(e.contains("model-0000002.safetensors") && e.contains("1 weights are not finite"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn validation_samples_spread_over_the_held_out_inputs_whatever_their_order() {
    let pair = |src: u64, i: usize| Pair {
        key: format!("clip{src}_{i:06}"),
        source: src,
        w: 1,
        h: 1,
        lq: vec![0; 3],
        gt: vec![0; 3],
        burst: Vec::new(),
        times: Vec::new(),
    };
    let pick = |order: &mut dyn Iterator<Item = (u64, usize)>| {
        let mut v = ValPick::new(16, 0);
        order.for_each(|(s, i)| {
            let p = pair(s, i);
            v.push(&p.key.clone(), p)
        });
        v.finish().into_iter().map(|p| p.key).collect::<std::collections::BTreeSet<_>>()
    };
    // Four inputs of 100 samples each, in shard order: the first 16 would all be clip0's.
    let a = pick(&mut (0..4u64).flat_map(|s| (0..100).map(move |i| (s, i))));
    assert_eq!(a.len(), 16);
    for s in 0..4 {
        assert!(a.iter().any(|k| k.starts_with(&format!("clip{s}_"))), "no sample of clip{s}: {a:?}");
    }
    // The same samples in reverse order give the same set.
    assert_eq!(pick(&mut (0..4u64).rev().flat_map(|s| (0..100).rev().map(move |i| (s, i)))), a);
}

#[test]
fn lr_warms_up_then_decays_by_cosine() {
    let cfg: TrainConfig = toml::from_str("[model]\ntype = \"shallow\"\nwidth = 4\n[data]\nshards = [\"x\"]\n[optim]\nsteps = 100\nwarmup_steps = 10\nlr = 1e-3\n[output]\ndir = \"x\"\n").unwrap();
    assert!((cfg.lr_at(0) - 1e-4).abs() < 1e-12);
    assert!((cfg.lr_at(10) - 1e-3).abs() < 1e-9);
    assert!((cfg.lr_at(99) - 1e-4).abs() < 1e-6);
    assert!(cfg.lr_at(50) < cfg.lr_at(20));
}

#[test]
fn augmentations_are_the_eight_symmetries_of_the_square() {
    let img: Vec<u8> = (0..4 * 4 * 3).map(|i| i as u8).collect();
    let all: std::collections::BTreeSet<Vec<u8>> = (0..8).map(|t| augment(&img, 4, t)).collect();
    assert_eq!(all.len(), 8);
    assert_eq!(augment(&img, 4, 0), img);
}

#[test]
fn a_share_of_burst_samples_learns_at_the_ends_and_none_by_default() {
    let count = |ends: f64| {
        let mut at = [0usize; 9];
        for step in 0..400 {
            for i in 0..8 {
                at[engine::burst_time(7, step, i, 9, ends)] += 1;
            }
        }
        at
    };
    // Uniform: each of 9 times about 1/9 of 3,200 draws.
    let u = count(0.0);
    assert!(u.iter().all(|&n| (280..430).contains(&n)), "{u:?}");
    // Half at the ends: each end about 1/4 + 1/18 of the draws, each other time 1/18.
    let e = count(0.5);
    for (k, &n) in e.iter().enumerate() {
        let want = if k == 0 || k == 8 { 3200.0 * (0.25 + 0.5 / 9.0) } else { 3200.0 * 0.5 / 9.0 };
        assert!((n as f64 - want).abs() < 0.2 * want, "time {k}: {n} of 3200, want about {want:.0}: {e:?}");
    }
    // The default draws what the uniform rule drew before the key existed.
    for step in 0..50 {
        assert_eq!(engine::burst_time(3, step, 1, 9, 0.0), (hash(&[3, step as u64, 1, hash_str("time")]) % 9) as usize);
    }
}
