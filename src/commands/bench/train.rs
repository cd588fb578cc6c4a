use super::*;

/// One model's speed in `bench train`.
#[derive(Debug, serde::Serialize)]
pub struct ModelSpeed {
    pub model: String,
    pub engine: &'static str,
    pub parameters: usize,
    pub batch: usize,
    pub threads: usize,
    /// Alternating rounds with PyTorch (1 without it); speeds are medians over the rounds.
    pub rounds: usize,
    pub train_patches_per_s_median: f64,
    pub forward_ms_per_patch_median: f64,
    /// PyTorch's figures of the first round.
    pub torch: Option<serde_json::Value>,
    /// Our time per patch over PyTorch's (training step; forward of one patch), the median of
    /// the rounds' own ratios: 1.0 is parity.
    pub train_time_ratio_vs_torch: Option<f64>,
    pub forward_time_ratio_vs_torch: Option<f64>,
    /// Convolution FLOPs per 128x128 patch (2 per multiply-add): forward; a training step
    /// counts 3 times that (forward, input gradient, weight gradient).
    pub forward_gflop_per_patch: f64,
    /// What that makes per core (FLOP/s over the threads) for training and forward. The
    /// forward pass takes Winograd's F(2x2, 3x3) on most 3 x 3 layers, which does 16 of every 36
    /// multiplications of the direct convolution: its figure is the direct convolution's FLOPs
    /// over its time (effective), and can pass the core's peak.
    pub train_gflops_per_core: f64,
    pub forward_gflops_per_core: f64,
    /// One core's f32 FMA peak, measured in the same run (see [`fma_peak_gflops`]).
    pub fma_peak_gflops_per_core: Option<f64>,
}

/// Accumulators of the peak loop: more than FMA latency x units (4 x 2) keeps every unit busy.
const PEAK_ACC: usize = 12;

/// One core's f32 fused multiply-add peak, measured: GFLOP/s of a loop of independent FMAs on the
/// widest vectors this CPU has (AVX-512, else AVX2), best of 5, with the vector width's name.
/// `None` on other CPUs. It is what gemm's microkernels can at most reach on one core.
pub fn fma_peak_gflops() -> Option<(f64, &'static str)> {
    #[cfg(target_arch = "x86_64")]
    {
        let iters = 20_000_000;
        // The loop for the widest vectors this CPU has, their lanes and their name.
        let (f, width, name): (unsafe fn(usize) -> f32, usize, &str) = if is_x86_feature_detected!("avx512f") {
            (fma_loop_512, 16, "AVX-512")
        } else if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            (fma_loop_256, 8, "AVX2")
        } else {
            return None;
        };
        let mut best = 0.0f64;
        for _ in 0..5 {
            let t = Instant::now();
            // SAFETY: the CPU has the features `f` is compiled for (detected above).
            std::hint::black_box(unsafe { f(iters) });
            best = best.max((iters * PEAK_ACC * width * 2) as f64 / t.elapsed().as_secs_f64() / 1e9);
        }
        Some((best, name))
    }
    #[cfg(not(target_arch = "x86_64"))]
    None
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn fma_loop_512(iters: usize) -> f32 {
    use std::arch::x86_64::*;
    let (a, b) = (_mm512_set1_ps(0.999_999), _mm512_set1_ps(1e-7));
    let mut acc = [_mm512_set1_ps(1.0); PEAK_ACC];
    for _ in 0..iters {
        for r in acc.iter_mut() {
            *r = _mm512_fmadd_ps(*r, a, b);
        }
    }
    _mm512_reduce_add_ps(acc.into_iter().fold(_mm512_setzero_ps(), |s, r| _mm512_add_ps(s, r)))
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn fma_loop_256(iters: usize) -> f32 {
    use std::arch::x86_64::*;
    let (a, b) = (_mm256_set1_ps(0.999_999), _mm256_set1_ps(1e-7));
    let mut acc = [_mm256_set1_ps(1.0); PEAK_ACC];
    for _ in 0..iters {
        for r in acc.iter_mut() {
            *r = _mm256_fmadd_ps(*r, a, b);
        }
    }
    let mut out = [0.0f32; 8];
    // SAFETY: `out` holds the 8 floats the unaligned store writes.
    unsafe { _mm256_storeu_ps(out.as_mut_ptr(), acc.into_iter().fold(_mm256_setzero_ps(), |s, r| _mm256_add_ps(s, r))) };
    out.iter().sum()
}

pub(super) fn bench_data(n: usize, salt: usize) -> crate::model::fast::T4 {
    let v: Vec<f32> = (0..n * 3 * 128 * 128).map(|i| (((i + salt) * 7919) % 1000) as f32 / 1000.0).collect();
    crate::model::fast::T4::new(n, 3, 128, 128, v)
}

/// Seconds per training step and ms per 128x128 forward with burn's autodiff on flex.
pub(super) fn time_burn(arch: crate::model::Arch, batch: usize, repeats: usize) -> (Vec<f64>, Vec<f64>) {
    use burn::module::Module;
    use burn::nn::loss::{HuberLossConfig, Reduction};
    use burn::optim::{AdamConfig, GradientsParams};
    use burn::tensor::Device;
    let device = Device::flex().autodiff();
    let mut model = crate::model::Net::seeded(arch, &device, 7);
    let mut optim = AdamConfig::new().with_epsilon(1e-8).init();
    let huber = HuberLossConfig::new(0.02).init();
    let (x, y) = (bench_data(batch, 0), bench_data(batch, 1));
    let mut steps = Vec::new();
    for r in 0..repeats + 1 {
        let t = Instant::now();
        let loss = huber.forward(model.forward(x.to_tensor(&device)), y.to_tensor(&device), Reduction::Mean);
        let grads = GradientsParams::from_grads(loss.backward(), &model);
        model = optim.step(1e-4, model, grads);
        if r > 0 {
            steps.push(t.elapsed().as_secs_f64());
        }
    }
    let valid = model.valid();
    let dev = device.clone().inner();
    let one = bench_data(1, 2);
    let mut fwd = Vec::new();
    for r in 0..repeats + 1 {
        let t = Instant::now();
        std::hint::black_box(valid.forward(one.to_tensor(&dev)).into_data());
        if r > 0 {
            fwd.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    (steps, fwd)
}

/// The same with the CPU fast path (`src/model/fast/`).
pub(super) fn time_fast(arch: crate::model::Arch, batch: usize, repeats: usize) -> (Vec<f64>, Vec<f64>) {
    use crate::model::fast::{train_step, Adam, FastNet};
    let mut net = FastNet::from_net(&crate::model::Net::seeded(arch, &burn::tensor::Device::flex(), 7));
    let mut adam = Adam::default();
    let (x, y) = (bench_data(batch, 0), bench_data(batch, 1));
    let mut steps = Vec::new();
    for r in 0..repeats + 1 {
        let t = Instant::now();
        train_step(&mut net, &mut adam, &x, &[], &y, 1e-4, 0.02, 1e-8);
        if r > 0 {
            steps.push(t.elapsed().as_secs_f64());
        }
    }
    let one = bench_data(1, 2);
    let mut fwd = Vec::new();
    // One patch is short (10-100 ms) and its median noisy: ten times the repeats, as
    // benches/torch_models.py.
    for r in 0..10 * repeats + 1 {
        let t = Instant::now();
        std::hint::black_box(net.forward(&one));
        if r > 0 {
            fwd.push(t.elapsed().as_secs_f64() * 1e3);
        }
    }
    (steps, fwd)
}

/// `bench train`: training step and forward speed per 128x128 patch of the given
/// architectures with the fast path (and burn's path with `with_burn`), beside PyTorch on the
/// same architectures with the same number of threads when torch is installed
/// (`benches/torch_models.py`). With PyTorch, `rounds` alternate the two engines (PyTorch,
/// then ours, `repeats` steps each) and each ratio is the median of the rounds' own ratios:
/// on a shared machine PyTorch alone moved from 8 to 14 patches/s between two runs, and a
/// ratio of two runs minutes apart said more about the neighbours than about either engine.
pub fn train(archs: &[crate::model::Arch], batch: usize, repeats: usize, rounds: usize, with_burn: bool) -> crate::Result<Vec<ModelSpeed>> {
    let script = torch_script();
    let threads = rayon::current_num_threads();
    let peak = fma_peak_gflops();
    if let Some((p, name)) = peak {
        eprintln!("bench: one core's f32 FMA peak ({name}, measured): {p:.1} GFLOP/s");
    }
    let mut out = Vec::new();
    for &arch in archs {
        let parameters = crate::model::Net::new(arch, &burn::tensor::Device::flex()).trainable_params();
        let torch_once = || -> Option<serde_json::Value> {
            let (kind, width) = match arch {
                crate::model::Arch::Unet { base } => ("unet", base),
                crate::model::Arch::BurstUnet { base, .. } => ("burst_unet", base),
                crate::model::Arch::Shallow { width } => ("shallow", width),
            };
            torch_json(script.as_ref()?, &[kind, &width.to_string(), &batch.to_string(), &repeats.to_string()])
        };
        let mut engines: Vec<(&'static str, fn(crate::model::Arch, usize, usize) -> (Vec<f64>, Vec<f64>))> = vec![("fast", time_fast)];
        if with_burn {
            engines.push(("burn", time_burn));
        }
        for (engine, f) in engines {
            // Per round: (our step s, our forward ms, PyTorch's row). Only the fast path
            // alternates with PyTorch; burn's own path is slow and timed once.
            let n_rounds = if engine == "fast" && script.is_some() { rounds.max(1) } else { 1 };
            let mut per_round = Vec::new();
            for _ in 0..n_rounds {
                let torch = if engine == "fast" { torch_once() } else { None };
                let (mut steps, mut fwd) = f(arch, batch, repeats);
                per_round.push((median(&mut steps), median(&mut fwd), torch));
            }
            let col = |g: &dyn Fn(&(f64, f64, Option<serde_json::Value>)) -> Option<f64>| {
                let mut v: Vec<f64> = per_round.iter().filter_map(g).collect();
                (!v.is_empty()).then(|| median(&mut v))
            };
            let step = col(&|r| Some(r.0)).unwrap_or(f64::NAN);
            let fwd = col(&|r| Some(r.1)).unwrap_or(f64::NAN);
            let tt = col(&|r| r.2.as_ref()?["train_patches_per_s_median"].as_f64());
            let tf = col(&|r| r.2.as_ref()?["forward_ms_per_patch_median"].as_f64());
            // Each round's own ratio, then their median.
            let train_ratio = col(&|r| Some(r.2.as_ref()?["train_patches_per_s_median"].as_f64()? * r.0 / batch as f64));
            let fwd_ratio = col(&|r| Some(r.1 / r.2.as_ref()?["forward_ms_per_patch_median"].as_f64()?));
            let gflop = 2.0 * arch.conv_macs(128, 128).0 as f64 / 1e9;
            let per_core = |gflop_per_s: f64| gflop_per_s / threads as f64;
            let row = ModelSpeed {
                model: arch.name(),
                engine,
                parameters,
                batch,
                threads,
                rounds: per_round.len(),
                train_patches_per_s_median: batch as f64 / step,
                forward_ms_per_patch_median: fwd,
                torch: per_round.iter().find_map(|r| r.2.clone()),
                train_time_ratio_vs_torch: train_ratio,
                forward_time_ratio_vs_torch: fwd_ratio,
                forward_gflop_per_patch: gflop,
                train_gflops_per_core: per_core(3.0 * gflop * batch as f64 / step),
                forward_gflops_per_core: per_core(gflop / (fwd / 1e3)),
                fma_peak_gflops_per_core: peak.map(|p| p.0),
            };
            print_row(&row, tt, tf, peak, per_core(3.0 * gflop * tt.unwrap_or(f64::NAN)));
            out.push(row);
        }
    }
    Ok(out)
}

/// The two lines `bench train` prints per row: speed beside PyTorch's (`tt` patches/s, `tf` ms
/// per patch forward), and GFLOP/s per core against the core's peak (`torch_gflops`: PyTorch's
/// training GFLOP/s per core).
fn print_row(row: &ModelSpeed, tt: Option<f64>, tf: Option<f64>, peak: Option<(f64, &'static str)>, torch_gflops: f64) {
    let (engine, threads, batch) = (row.engine, row.threads, row.batch);
    let versus = match (tt, tf) {
        (Some(tt), Some(tf)) => format!(
            "; PyTorch {tt:.2} patches/s, {tf:.1} ms: our time {:.2}x training, {:.2}x forward (medians of {} alternating rounds)",
            row.train_time_ratio_vs_torch.unwrap_or(f64::NAN),
            row.forward_time_ratio_vs_torch.unwrap_or(f64::NAN),
            row.rounds
        ),
        _ if engine == "fast" => "; torch not installed, no comparison".into(),
        _ => String::new(),
    };
    eprintln!(
        "bench: {} ({engine}, {threads} threads): {:.2} patches/s training (batch {batch}), forward {:.1} ms per 128x128 patch{versus}",
        row.model, row.train_patches_per_s_median, row.forward_ms_per_patch_median,
    );
    let share = |g: f64| peak.map_or(String::new(), |(p, _)| format!(", {:.0}% of peak", 100.0 * g / p));
    eprintln!(
        "bench: {} ({engine}): {:.1} GFLOP/s per core training{}, {:.1} forward{} (effective: direct-convolution FLOPs; Winograd does fewer){}",
        row.model,
        row.train_gflops_per_core,
        share(row.train_gflops_per_core),
        row.forward_gflops_per_core,
        share(row.forward_gflops_per_core),
        tt.map_or(String::new(), |_| format!("; PyTorch {torch_gflops:.1} training"))
    );
}
