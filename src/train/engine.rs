use super::*;

/// Mean quality of a model's outputs on validation pairs, and of the inputs themselves.
pub fn evaluate(model: &Net, val: &[Pair], device: &Device) -> (metrics::Quality, metrics::Quality) {
    evaluate_with(val, model.is_burst(), |x, ts, w, h| from_tensor(model.forward_at(to_tensor(x, w, h, device), ts)))
}

/// [`evaluate`] with the CPU fast path.
pub fn evaluate_fast(model: &FastNet, val: &[Pair]) -> (metrics::Quality, metrics::Quality) {
    evaluate_with(val, model.is_burst(), |x, ts, w, h| from_t4(&model.forward_at(&to_t4(x, w, h), ts)))
}

/// The time and target a pair is trained or scored at: for a burst model and a burst sample,
/// target `k` of its burst (`pick` gives k from the count); otherwise the middle and `gt`.
pub fn target(p: &Pair, burst_model: bool, pick: impl FnOnce(usize) -> usize) -> (f32, &[u8]) {
    if burst_model && !p.burst.is_empty() {
        let k = pick(p.burst.len()) % p.burst.len();
        (p.times[k], &p.burst[k])
    } else {
        (crate::model::MIDDLE, &p.gt)
    }
}

/// The target a validation pair is scored at: a time fixed by its key, so each validation has
/// the same times and the set covers them all.
pub fn val_target(p: &Pair, burst_model: bool) -> (f32, &[u8]) {
    target(p, burst_model, |k| (hash_str(&p.key) % k as u64) as usize)
}

/// Which of a burst's `k` times a training sample is learnt at, at `step` in batch place `i`:
/// uniform, except a share `ends` of samples at the first or the last time (half each).
pub fn burst_time(seed: u64, step: usize, i: usize, k: usize, ends: f64) -> usize {
    let uniform = (hash(&[seed, step as u64, i as u64, hash_str("time")]) % k as u64) as usize;
    if ends <= 0.0 {
        return uniform;
    }
    let h = hash(&[seed, step as u64, i as u64, hash_str("ends")]);
    if ((h >> 11) as f64 / (1u64 << 53) as f64) < ends {
        if h & 1 == 0 {
            0
        } else {
            k - 1
        }
    } else {
        uniform
    }
}

pub(super) fn evaluate_with(
    val: &[Pair],
    burst: bool,
    forward: impl Fn(&[&[u8]], &[f32], usize, usize) -> Vec<Vec<u8>>,
) -> (metrics::Quality, metrics::Quality) {
    let mut sums = [[0.0f64; 4]; 2];
    for chunk in val.chunks(8) {
        let (w, h) = (chunk[0].w, chunk[0].h);
        let targets: Vec<(f32, &[u8])> = chunk.iter().map(|p| val_target(p, burst)).collect();
        let ts: Vec<f32> = targets.iter().map(|t| t.0).collect();
        let outs = forward(&chunk.iter().map(|p| p.lq.as_slice()).collect::<Vec<_>>(), &ts, w, h);
        for ((p, o), (_, gt)) in chunk.iter().zip(outs).zip(&targets) {
            for (k, img) in [o.as_slice(), p.lq.as_slice()].iter().enumerate() {
                let q = metrics::quality(img, gt, w, h);
                let v = [q.psnr_rgb.min(99.0), q.ssim_rgb, q.psnr_y.min(99.0), q.ssim_y];
                for i in 0..4 {
                    sums[k][i] += v[i];
                }
            }
        }
    }
    let n = val.len().max(1) as f64;
    let q = |s: [f64; 4]| metrics::Quality { psnr_rgb: s[0] / n, ssim_rgb: s[1] / n, psnr_y: s[2] / n, ssim_y: s[3] / n };
    (q(sums[0]), q(sums[1]))
}

/// A model and its optimizer state, in one of the two implementations.
pub(super) enum Engine {
    /// burn's autodiff (the reference path; the GPU path with the `wgpu`/`cuda` features).
    Burn { device: Device, model: Net, optim: burn::optim::ModuleOptimizer, huber: burn::nn::loss::HuberLoss },
    /// `src/model/fast/`; `template` carries the parameter ids the checkpoints are written with.
    Fast { net: Box<FastNet>, adam: Adam, template: Net },
}

impl Engine {
    /// One optimisation step; returns the loss before it.
    pub(super) fn step(&mut self, x: &T4, ts: &[f32], y: &T4, lr: f64, delta: f64, eps: f64) -> f64 {
        match self {
            Engine::Burn { device, model, optim, huber } => {
                let loss = huber.forward(model.forward_at(x.to_tensor(device), ts), y.to_tensor(device), Reduction::Mean);
                let lv = loss.clone().into_scalar::<f32>() as f64;
                if lv.is_finite() {
                    let grads = GradientsParams::from_grads(loss.backward(), model);
                    // The module holds tensor handles: cloning it is cheap.
                    *model = optim.step(lr, model.clone(), grads);
                }
                lv
            }
            Engine::Fast { net, adam, .. } => fast::train_step(net, adam, x, ts, y, lr as f32, delta as f32, eps as f32),
        }
    }

    /// The network as a burn module on the CPU (for checkpoints and reports).
    pub(super) fn net(&self) -> Net {
        match self {
            Engine::Burn { model, .. } => model.valid(),
            Engine::Fast { net, template, .. } => net.write_into(template.clone()),
        }
    }

    pub(super) fn num_params(&self) -> usize {
        match self {
            Engine::Burn { model, .. } => model.trainable_params(),
            Engine::Fast { template, .. } => template.trainable_params(),
        }
    }

    pub(super) fn optim_bytes(&self) -> Result<Vec<u8>> {
        match self {
            Engine::Burn { optim, .. } => Ok(optim
                .clone()
                .into_bytes()
                .map_err(|e| Error::Serialise { what: "optimizer state".into(), source: Box::new(e) })?
                .to_vec()),
            Engine::Fast { adam, .. } => Ok(adam.to_bytes()),
        }
    }

    pub(super) fn evaluate(&self, val: &[Pair]) -> (metrics::Quality, metrics::Quality) {
        match self {
            Engine::Burn { model, device, .. } => evaluate(&model.valid(), val, &device.clone().inner()),
            Engine::Fast { net, .. } => evaluate_fast(net, val),
        }
    }
}
