//! Each operation against burn's own implementation on the same inputs (forward and both
//! gradients), then whole networks and training runs.
use super::*;
use burn::module::Module;
use burn::nn::conv::{Conv2dConfig, ConvTranspose2dConfig};
use burn::nn::PaddingConfig2d;
use burn::optim::GradientsParams;
use burn::tensor::Device;

fn ad() -> Device {
    Device::flex().autodiff()
}

fn rand(n: usize, c: usize, h: usize, w: usize, seed: u64) -> T4 {
    let v = (0..n * c * h * w).map(|i| crate::rng::unit(crate::rng::hash(&[seed, i as u64])) as f32 * 2.0 - 1.0).collect();
    T4::new(n, c, h, w, v)
}

/// Largest |a - b| relative to the largest |b| (1e-30 floor).
fn rel(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    let scale = b.iter().fold(0.0f32, |m, v| m.max(v.abs())).max(1e-30);
    a.iter().zip(b).fold(0.0f32, |m, (x, y)| m.max((x - y).abs())) / scale
}

fn vecf<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().unwrap()
}

/// burn: y = conv(x), loss = sum(y * g); returns y, dx, dw, db.
fn burn_conv(conv: &Conv2d, x: &T4, g: &T4) -> (Vec<f32>, Vec<f32>, Vec<f32>, Option<Vec<f32>>) {
    let xt = x.to_tensor(&ad()).require_grad();
    let y = conv.forward(xt.clone());
    let loss = (y.clone() * g.to_tensor(&ad())).sum();
    let grads = loss.backward();
    let dx = vecf(xt.grad(&grads).unwrap());
    let gp = GradientsParams::from_grads(grads, conv);
    let dw = vecf(gp.get::<4>(conv.weight.id).unwrap());
    let db = conv.bias.as_ref().map(|b| vecf(gp.get::<1>(b.id).unwrap()));
    (vecf(y), dx, dw, db)
}

#[test]
fn convolution_matches_burn_forward_and_both_gradients() {
    // (batch, cin, cout, h, w, kernel, bias): odd sizes, batch 1 and 5; the last is wide enough
    // (256 channels in and out) that the forward pass and the input gradient take the im2col path.
    for (i, &(n, cin, cout, h, w, k, bias)) in [
        (1, 3, 16, 17, 23, 3, false),
        (5, 32, 16, 9, 14, 3, false),
        (2, 16, 3, 12, 7, 1, true),
        (1, 8, 3, 5, 6, 3, true),
        (2, 256, 256, 7, 9, 3, true),
    ]
    .iter()
    .enumerate()
    {
        let mut cfg = Conv2dConfig::new([cin, cout], [k, k]).with_bias(bias);
        if k == 3 {
            cfg = cfg.with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1));
        }
        let conv = cfg.init(&ad());
        let x = rand(n, cin, h, w, 1 + i as u64);
        let g = rand(n, cout, h, w, 100 + i as u64);
        let (y, dx, dw, db) = burn_conv(&conv, &x, &g);
        let mut f = Conv::from_burn(&conv);
        let fy = f.forward_train(Arc::new(x.clone()));
        let fdx = f.backward(&g, true).unwrap();
        assert!(rel(&fy.d, &y) < 1e-4, "case {i} forward {}", rel(&fy.d, &y));
        assert!(rel(&fdx.d, &dx) < 1e-4, "case {i} input gradient {}", rel(&fdx.d, &dx));
        assert!(rel(&f.gw, &dw) < 1e-4, "case {i} weight gradient {}", rel(&f.gw, &dw));
        if let Some(db) = db {
            assert!(rel(&f.gb, &db) < 1e-4, "case {i} bias gradient");
        }
        // The check catches a wrong gradient: one weight's gradient off by 1e-3 of the largest.
        let scale = dw.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        f.gw[dw.len() / 2] += 1e-3 * scale;
        assert!(rel(&f.gw, &dw) > 1e-4, "case {i}: a perturbed weight gradient passes ({})", rel(&f.gw, &dw));
    }
}

#[test]
fn a_band_transposes_pixel_major_at_any_size() {
    // Sizes that are not multiples of the 8 x 8 tile, a row stride wider than the band, and a
    // buffer that holds old values longer than the band (they must be left alone or overwritten).
    for (c, npx, rs) in [(1, 1, 1), (3, 13, 20), (16, 64, 64), (11, 9, 9)] {
        let src: Vec<f32> = (0..c * rs).map(|i| i as f32).collect();
        let mut dst = vec![-1.0; c * npx + 5];
        kernels::transpose_band(&src, c, rs, npx, &mut dst);
        for p in 0..npx {
            for ch in 0..c {
                assert_eq!(dst[p * c + ch], src[ch * rs + p], "c {c} npx {npx} pixel {p} channel {ch}");
            }
        }
        assert_eq!(&dst[c * npx..], &[-1.0; 5], "past the band");
    }
}

#[test]
fn transposed_convolution_matches_burn() {
    for (i, &(n, cin, cout, h, w)) in [(1, 8, 8, 5, 7), (3, 16, 4, 4, 4)].iter().enumerate() {
        let up = ConvTranspose2dConfig::new([cin, cout], [2, 2]).with_stride([2, 2]).init(&ad());
        let x = rand(n, cin, h, w, 7 + i as u64);
        let g = rand(n, cout, 2 * h, 2 * w, 70 + i as u64);
        let xt = x.to_tensor(&ad()).require_grad();
        let y = up.forward(xt.clone());
        let grads = (y.clone() * g.to_tensor(&ad())).sum().backward();
        let dx = vecf(xt.grad(&grads).unwrap());
        let gp = GradientsParams::from_grads(grads, &up);
        let (dw, db) = (vecf(gp.get::<4>(up.weight.id).unwrap()), vecf(gp.get::<1>(up.bias.as_ref().unwrap().id).unwrap()));
        let mut f = UpConv::from_burn(&up);
        let fy = f.forward_train(Arc::new(x));
        let fdx = f.backward(&g);
        assert!(rel(&fy.d, &vecf(y)) < 1e-4, "case {i} forward");
        assert!(rel(&fdx.d, &dx) < 1e-4, "case {i} input gradient");
        assert!(rel(&f.gw, &dw) < 1e-4, "case {i} weight gradient");
        assert!(rel(&f.gb, &db) < 1e-4, "case {i} bias gradient");
    }
}

/// Every parameter gradient of a whole network against burn's autodiff.
fn network_gradients_match(arch: crate::model::Arch, n: usize, h: usize, w: usize) {
    network_gradients_match_at(Net::seeded(arch, &ad(), 11), &[], n, h, w);
}

/// [`network_gradients_match`] for `net`, sample i at time `ts[i]` (empty: the middle).
fn network_gradients_match_at(net: Net, ts: &[f32], n: usize, h: usize, w: usize) {
    let arch = if net.is_burst() { "burst" } else { "single" };
    let x = rand(n, 3, h, w, 5);
    let y = rand(n, 3, h, w, 6);
    let mid = vec![crate::model::MIDDLE; n];
    let bts = if ts.is_empty() { &mid[..] } else { ts };
    // burn
    let out = net.forward_at(x.to_tensor(&ad()), bts);
    let loss = burn::nn::loss::HuberLossConfig::new(0.02).init().forward(out.clone(), y.to_tensor(&ad()), burn::nn::loss::Reduction::Mean);
    let gp = GradientsParams::from_grads(loss.backward(), &net);
    // ours
    let mut f = FastNet::from_net(&net);
    let fo = f.forward_train_at(&x, ts);
    assert!(rel(&fo.d, &vecf(out)) < 1e-4, "{arch:?} forward");
    let (fl, d) = huber(&fo, &y, 0.02);
    assert!((fl - loss.into_scalar::<f32>() as f64).abs() < 1e-6 * fl.abs().max(1e-3), "{arch:?} loss");
    f.backward(&d);
    let mut ours = Vec::new();
    f.params(&mut |_, g| ours.push(g.to_vec()));
    // burn's gradients in the same order: visit the module's trainable parameters.
    struct Grads<'a>(&'a GradientsParams, Vec<Vec<f32>>);
    impl burn::module::ModuleVisitor for Grads<'_> {
        fn visit_float<const D: usize>(&mut self, p: &burn::module::Param<Tensor<D>>) {
            if let Some(g) = self.0.get::<D>(p.id) {
                self.1.push(g.into_data().try_to_vec::<f32>().unwrap());
            }
        }
    }
    let mut theirs = Grads(&gp, Vec::new());
    net.visit(&mut theirs);
    // burn visits conv weight before its BatchNorm: the same order as ours.
    assert_eq!(ours.len(), theirs.1.len(), "{arch:?} parameter count");
    for (i, (a, b)) in ours.iter().zip(&theirs.1).enumerate() {
        assert!(rel(a, b) < 1e-3, "{arch:?} parameter {i} ({} values): {}", a.len(), rel(a, b));
    }
}

#[test]
fn shallow_gradients_match_burn() {
    network_gradients_match(crate::model::Arch::Shallow { width: 8 }, 2, 13, 11);
}

#[test]
fn gradients_match_burn_where_winograd_takes_the_forward_and_input_gradient() {
    // 16 channels on at least 8 x 8 blocks: the layers take `winograd::conv3x3` (odd sides too).
    assert!(winograd::worth_it(16, 16, 17, 18) && winograd::worth_it(16, 16, 32, 32));
    network_gradients_match(crate::model::Arch::Shallow { width: 16 }, 1, 17, 18);
    // Two samples: with one, the 2 x 2 level's BatchNorm sees 4 values per channel, and the
    // comparison failed once (6.6e-3) among the other tests while it passed alone.
    network_gradients_match(crate::model::Arch::Unet { base: 16 }, 2, 32, 32);
}

/// Every time conditioning of a burst U-Net set off zero (its start), so that the output
/// depends on the time at every timed level.
fn films_off_zero(net: &mut Net, dev: &Device, seed: u64) {
    let Net::Unet(u) = net else { unreachable!() };
    let films = [u.up1.film.as_mut(), u.up2.film.as_mut(), u.up3.film.as_mut(), u.film.as_mut()];
    for (k, film) in films.into_iter().enumerate() {
        let Some(film) = film else { continue };
        let shape = film.gamma.val().dims();
        let r = |s: u64| {
            let v = rand(1, 1, shape[0], shape[1], s).d.iter().map(|v| v * 0.3).collect::<Vec<f32>>();
            burn::module::Param::from_tensor(Tensor::<2>::from_data(TensorData::new(v, shape), dev))
        };
        (film.gamma, film.beta) = (r(seed + 2 * k as u64), r(seed + 2 * k as u64 + 1));
    }
}

#[test]
fn burst_unet_gradients_match_burn_at_other_times_for_each_sample() {
    let dev = ad();
    for levels in [1, 4] {
        let mut net = Net::seeded(crate::model::Arch::BurstUnet { base: 4, levels }, &dev, 11);
        films_off_zero(&mut net, &dev, 7);
        let f = FastNet::from_net(&net);
        let x = rand(2, 3, 20, 24, 1);
        let (a, b) = (f.forward_at(&x, &[0.1, 0.9]), f.forward_at(&x, &[0.9, 0.1]));
        assert!(rel(&a.d, &b.d) > 1e-3, "the time changes nothing ({levels} levels)");
        network_gradients_match_at(net, &[0.05, 0.95], 2, 20, 24);
    }
}

#[test]
fn a_burst_units_trunk_runs_once_and_gives_what_each_time_alone_gives() {
    let dev = Device::flex();
    let x = rand(1, 3, 21, 30, 2);
    let ts = [0.0625, 0.5, 0.9375];
    for levels in [1, 2, 4] {
        let arch = crate::model::Arch::BurstUnet { base: 4, levels };
        let mut net = Net::seeded(arch, &dev, 3);
        films_off_zero(&mut net, &dev, 9);
        let f = FastNet::from_net(&net);
        let burst = f.forward_burst(&x, &ts);
        for (t, y) in ts.iter().zip(&burst) {
            assert_eq!(y.d, f.forward_at(&x, &[*t]).d, "t = {t}, {levels} levels");
        }
        assert!(rel(&burst[0].d, &burst[2].d) > 1e-3, "the time changes nothing ({levels} levels)");
        let theirs = vecf(f.write_into(Net::seeded(arch, &dev, 4)).forward_at(x.to_tensor(&dev), &[0.0625]));
        assert!(rel(&burst[0].d, &theirs) < 1e-4, "{levels} levels");
    }
    // At the middle, a burst U-Net made from a U-Net is that U-Net; and one told the time on
    // more levels, made from a burst U-Net, is that burst U-Net at every time.
    let unet = Net::seeded(crate::model::Arch::Unet { base: 4 }, &dev, 5);
    let want = FastNet::from_net(&unet).forward(&x);
    let burst1 = unet.into_burst(1, &dev);
    let got = FastNet::from_net(&burst1).forward_burst(&x, &ts);
    assert!(got.iter().all(|y| y.d == want.d));
    let mut burst1 = burst1;
    films_off_zero(&mut burst1, &dev, 13);
    let want = FastNet::from_net(&burst1).forward_burst(&x, &ts);
    // The same in the fast path.
    let fast4 = FastNet::from_net(&burst1).into_burst(4);
    let burst4 = burst1.into_burst(4, &dev);
    for got in [FastNet::from_net(&burst4).forward_burst(&x, &ts), fast4.forward_burst(&x, &ts)] {
        assert!(got.iter().zip(&want).all(|(a, b)| a.d == b.d));
    }
}

#[test]
fn unet_gradients_match_burn_including_padding() {
    network_gradients_match(crate::model::Arch::Unet { base: 4 }, 2, 32, 32);
    network_gradients_match(crate::model::Arch::Unet { base: 4 }, 1, 20, 35);
}

#[test]
fn inference_matches_burn_and_round_trips_through_the_module() {
    for arch in [crate::model::Arch::Unet { base: 4 }, crate::model::Arch::Shallow { width: 6 }] {
        let dev = Device::flex();
        let mut f = FastNet::from_net(&Net::seeded(arch, &dev, 3));
        // A few training steps move the weights and running statistics off their init.
        let mut adam = Adam::default();
        for s in 0..3 {
            f.zero_grad();
            let o = f.forward_train(&rand(2, 3, 16, 16, s));
            let (_, d) = huber(&o, &rand(2, 3, 16, 16, 50 + s), 0.02);
            f.backward(&d);
            adam.step(&mut f, 1e-2, Adam::BURN_EPS);
        }
        let net = f.write_into(Net::seeded(arch, &dev, 4));
        let x = rand(1, 3, 21, 30, 9);
        let theirs = vecf(net.forward(x.to_tensor(&dev)));
        let e = rel(&f.forward(&x).d, &theirs);
        assert!(e < 1e-4, "{arch:?}: {e}");
        let back = FastNet::from_net(&net);
        assert_eq!(back.forward(&x).d, f.forward(&x).d, "{arch:?} round trip");
    }
}

#[test]
fn recalibrated_batchnorm_makes_inference_equal_training_mode_on_that_batch() {
    for arch in [crate::model::Arch::Unet { base: 4 }, crate::model::Arch::Shallow { width: 6 }] {
        let dev = Device::flex();
        // Seeded weights (the last layer not zeroed, so BatchNorm shows in the output).
        let mut f = FastNet::from_net(&Net::seeded(arch, &dev, 5));
        let (a, b) = (rand(4, 3, 16, 16, 61), rand(4, 3, 16, 16, 62));
        let train_a = f.clone().forward_train(&a);
        let worst = |p: &T4, q: &T4| p.d.iter().zip(&q.d).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        // The initial running statistics (mean 0, variance 1) are far from the batch's.
        assert!(worst(&f.forward(&a), &train_a) > 1e-2, "{arch:?}: the test needs stats that differ");
        // Over one batch (or the same batch twice) the running statistics are that batch's.
        f.recalibrate_bn(std::slice::from_ref(&a));
        assert!(worst(&f.forward(&a), &train_a) < 1e-4, "{arch:?}: {}", worst(&f.forward(&a), &train_a));
        f.recalibrate_bn(&[a.clone(), a.clone()]);
        assert!(worst(&f.forward(&a), &train_a) < 1e-4, "{arch:?}: twice");
        // Over two batches they are the mean of both, not the last one's (momentum 0.1 would
        // leave 0.9 of the first batch's).
        f.recalibrate_bn(&[a.clone(), b.clone()]);
        let mut g = FastNet::from_net(&Net::seeded(arch, &dev, 5));
        g.recalibrate_bn(&[b.clone(), a.clone()]);
        assert!(worst(&f.forward(&a), &g.forward(&a)) < 1e-4, "{arch:?}: the order of the batches matters");
        assert!(worst(&f.forward(&a), &train_a) > 1e-3, "{arch:?}: b left no trace");
        // The momentum is restored: a training step moves the statistics by 0.1 of the way.
        let mut rm = Vec::new();
        f.bn_layers(&mut |l| rm.push((l.momentum, l.rmean[0])));
        assert!(rm.iter().all(|&(m, _)| (m - 0.1).abs() < 1e-6), "{rm:?}");
    }
}

/// The initial network of the training tests: built once per test, so that burn's shared
/// random generator (drawn lazily by other tests' modules) cannot differ between two runs.
fn initial(arch: crate::model::Arch, dev: &Device) -> Net {
    Net::seeded(arch, dev, 21).zero_last_layer(dev)
}

fn train_steps(mut f: FastNet, steps: usize) -> (Vec<f64>, FastNet) {
    let mut adam = Adam::default();
    let mut losses = Vec::new();
    for s in 0..steps as u64 {
        let (x, y) = (rand(4, 3, 16, 16, 200 + s % 3), rand(4, 3, 16, 16, 300 + s % 3));
        losses.push(train_step(&mut f, &mut adam, &x, &[], &y, 1e-3, 0.02, 1e-8));
    }
    (losses, f)
}

#[test]
fn twenty_steps_give_burns_loss_curve() {
    use burn::optim::AdamConfig;
    for arch in [crate::model::Arch::Shallow { width: 4 }, crate::model::Arch::Unet { base: 4 }] {
        let mut net = initial(arch, &ad());
        let (ours, _) = train_steps(FastNet::from_net(&net), 20);
        let mut optim = AdamConfig::new().with_epsilon(1e-8).init();
        let huber_b = burn::nn::loss::HuberLossConfig::new(0.02).init();
        for (s, l) in ours.iter().enumerate() {
            let s = s as u64;
            let (x, y) = (rand(4, 3, 16, 16, 200 + s % 3), rand(4, 3, 16, 16, 300 + s % 3));
            let loss = huber_b.forward(net.forward(x.to_tensor(&ad())), y.to_tensor(&ad()), burn::nn::loss::Reduction::Mean);
            let lb = loss.clone().into_scalar::<f32>() as f64;
            assert!((lb - l).abs() <= 1e-4 * lb.abs(), "{arch:?} step {s}: burn {lb} ours {l}");
            let grads = GradientsParams::from_grads(loss.backward(), &net);
            net = optim.step(1e-3, net, grads);
        }
        // Steps 0 and 18 see the same batch.
        assert!(ours[18] < ours[0], "{arch:?} the loss falls: {ours:?}");
    }
}

#[test]
fn the_same_seed_gives_the_same_weights_with_any_thread_count() {
    // Base 16: its 16 x 16 level takes Winograd (forward and input gradient).
    for arch in [crate::model::Arch::Unet { base: 4 }, crate::model::Arch::Unet { base: 16 }] {
        let init = FastNet::from_net(&initial(arch, &Device::flex()));
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
                let (_, mut f) = train_steps(init.clone(), 4);
                let mut w = Vec::new();
                f.params(&mut |p, _| w.extend_from_slice(p));
                w
            })
        };
        let (a, b, c) = (run(1), run(2), run(2));
        assert_eq!(b, c, "{arch:?}: two runs, one seed");
        assert_eq!(a, b, "{arch:?}: 1 and 2 threads");
    }
}

#[test]
fn adam_state_round_trips() {
    let mut f = FastNet::from_net(&initial(crate::model::Arch::Shallow { width: 4 }, &Device::flex()));
    let mut a = Adam::default();
    f.zero_grad();
    a.step(&mut f, 1e-3, 1e-8);
    let b = Adam::from_bytes(&a.to_bytes()).unwrap();
    assert_eq!((a.time, &a.m, &a.v), (b.time, &b.m, &b.v));
    assert!(Adam::from_bytes(b"{}\n").is_err());
}

/// A tensor of the PyTorch golden fixtures (`fixtures/pytorch/make.py`).
fn golden(name: &str) -> (Vec<usize>, Vec<f32>) {
    let p = format!("{}/fixtures/pytorch/{name}.npy", env!("CARGO_MANIFEST_DIR"));
    crate::io::npy::read_f32(&std::fs::read(&p).unwrap_or_else(|e| panic!("{p}: {e}"))).unwrap()
}

#[test]
fn a_convolution_and_a_whole_unet_match_outputs_pytorch_made() {
    // PyTorch 2.15 CPU made these once; the same numbers must come out here without torch.
    let (s, x) = golden("conv_in");
    let ((_, w), (_, b), (so, want)) = (golden("conv_weight"), golden("conv_bias"), golden("conv_out"));
    let y = kernels::conv_forward(&T4::new(s[0], s[1], s[2], s[3], x), &w, Some(&b), so[1], 3);
    assert_eq!((y.n, y.c, y.h, y.w), (so[0], so[1], so[2], so[3]));
    assert!(rel(&y.d, &want) < 1e-6, "conv: relative error {}", rel(&y.d, &want));

    // A U-Net of base 4 with random weights and BatchNorm statistics, in PyTorch's names.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/pytorch/unet4.safetensors");
    let (net, arch) = crate::model::checkpoint::load_model(&path, &Device::flex()).unwrap();
    assert_eq!(arch, crate::model::Arch::Unet { base: 4 });
    let (s, x) = golden("unet4_in");
    let (so, want) = golden("unet4_out");
    let y = FastNet::from_net(&net).forward(&T4::new(s[0], s[1], s[2], s[3], x));
    assert_eq!(vec![y.n, y.c, y.h, y.w], so);
    assert!(rel(&y.d, &want) < 1e-5, "U-Net: relative error {}", rel(&y.d, &want));
}
