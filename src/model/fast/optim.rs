use super::*;

/// One optimisation step: forward (sample i at time `ts[i]`; empty: the middle), Huber loss,
/// backward, Adam. Returns the loss before the step; a non-finite loss leaves the network and the
/// optimizer untouched.
#[allow(clippy::too_many_arguments)]
pub fn train_step(net: &mut FastNet, adam: &mut Adam, x: &T4, ts: &[f32], y: &T4, lr: f32, delta: f32, eps: f32) -> f64 {
    net.zero_grad();
    let out = net.forward_train_at(x, ts);
    let (loss, dout) = huber(&out, y, delta);
    if loss.is_finite() {
        net.backward(&dout);
        adam.step(net, lr, eps);
    }
    loss
}

/// Huber loss (mean over every element) and its gradient with respect to `pred`.
pub fn huber(pred: &T4, target: &T4, delta: f32) -> (f64, T4) {
    let n = pred.d.len() as f64;
    let mut g = T4::zeros(pred.n, pred.c, pred.h, pred.w);
    let mut loss = 0.0f64;
    let inv = (1.0 / n) as f32;
    for ((gv, &p), &t) in g.d.iter_mut().zip(&pred.d).zip(&target.d) {
        let r = p - t;
        if r.abs() <= delta {
            loss += 0.5 * (r as f64) * (r as f64);
            *gv = r * inv;
        } else {
            loss += delta as f64 * (r.abs() as f64 - 0.5 * delta as f64);
            *gv = delta * r.signum() * inv;
        }
    }
    (loss / n, g)
}

/// Adam as burn 0.22 computes it (beta 0.9 / 0.999, the epsilon scaled by the bias
/// correction), with its state as plain vectors.
#[derive(Debug, Clone, Default)]
pub struct Adam {
    pub time: i32,
    pub m: Vec<Vec<f32>>,
    pub v: Vec<Vec<f32>>,
}

impl Adam {
    pub const BETA1: f32 = 0.9;
    pub const BETA2: f32 = 0.999;
    /// burn's default epsilon. Too large for these networks: the mean-reduced loss over
    /// `8 x 3 x 128 x 128` values gives most weights a gradient RMS of 1e-7 to 1e-6, so with
    /// 1e-5 in the denominator they move at a few percent of Adam's step. Training configs use
    /// `optim.adam_epsilon` (PyTorch's 1e-8 by default).
    pub const BURN_EPS: f32 = 1e-5;

    pub fn step(&mut self, net: &mut FastNet, lr: f32, eps: f32) {
        self.time += 1;
        let t = self.time;
        let bc2 = (1.0 - Self::BETA2.powi(t)).sqrt();
        let factor = bc2 / (1.0 - Self::BETA1.powi(t));
        let init = self.m.is_empty();
        let mut i = 0;
        let (ms, vs) = (&mut self.m, &mut self.v);
        net.params(&mut |p, g| {
            if init {
                ms.push(vec![0.0; p.len()]);
                vs.push(vec![0.0; p.len()]);
            }
            let (m, v) = (&mut ms[i], &mut vs[i]);
            p.par_iter_mut().zip(g.par_iter()).zip(m.par_iter_mut().zip(v.par_iter_mut())).for_each(|((p, &g), (m, v))| {
                *m = *m * Self::BETA1 + g * (1.0 - Self::BETA1);
                *v = *v * Self::BETA2 + g * g * (1.0 - Self::BETA2);
                *p -= lr * (*m * factor) / (v.sqrt() + eps * bc2);
            });
            i += 1;
        });
    }

    /// The state as bytes: a JSON header line, then the moments as little-endian f32.
    pub fn to_bytes(&self) -> Vec<u8> {
        let lens: Vec<usize> = self.m.iter().map(Vec::len).collect();
        let mut out = serde_json::to_vec(&serde_json::json!({"format": "pipeline-adam-1", "time": self.time, "lens": lens})).expect("json");
        out.push(b'\n');
        for v in self.m.iter().chain(&self.v) {
            for x in v {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        out
    }

    pub fn from_bytes(b: &[u8]) -> Result<Adam, AdamStateError> {
        let nl = b.iter().position(|&c| c == b'\n').ok_or(AdamStateError::NoHeader)?;
        let head: serde_json::Value = serde_json::from_slice(&b[..nl])?;
        if head["format"] != "pipeline-adam-1" {
            return Err(AdamStateError::Format(head["format"].to_string()));
        }
        let time = head["time"].as_i64().ok_or(AdamStateError::NoTime)? as i32;
        let lens: Vec<usize> = serde_json::from_value(head["lens"].clone())?;
        let body = &b[nl + 1..];
        let total = lens.iter().try_fold(0usize, |a, &n| a.checked_add(n)).and_then(|t| t.checked_mul(8));
        if total != Some(body.len()) {
            return Err(AdamStateError::Size { got: body.len(), lens: lens.len() });
        }
        let mut floats = body.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]));
        let mut take = |n: usize| -> Vec<f32> { floats.by_ref().take(n).collect() };
        let m = lens.iter().map(|&n| take(n)).collect();
        let v = lens.iter().map(|&n| take(n)).collect();
        Ok(Adam { time, m, v })
    }
}

/// Why bytes are not a fast-engine Adam state (`optim.state` of a checkpoint).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum AdamStateError {
    #[error("no header line")]
    NoHeader,
    #[error("header: {0}")]
    Json(#[from] serde_json::Error),
    #[error("not a pipeline Adam state (format {0})")]
    Format(String),
    #[error("no time in the header")]
    NoTime,
    #[error("{got} bytes of moments, not what the header's {lens} lengths need")]
    Size { got: usize, lens: usize },
}
