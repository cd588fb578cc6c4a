//! The paper's networks (section 4 and supplementary B).
//!
//! - U-Net: CONV_in 3 -> b; DOWN b -> 2b -> 4b -> 8b -> 8b (2x2 max-pool, then a double
//!   3x3 conv + BatchNorm + LeakyReLU without bias); UP with a x2 transposed convolution,
//!   concatenation with the skip of the same scale, then a double conv (16b -> 4b, 8b -> 2b,
//!   4b -> b, 2b -> b); CONV_out b -> 3 (1x1). The input is added to the output: the network
//!   predicts a residual. `base = 64` is the paper's (about 14.8 M parameters).
//! - Shallow: 10 blocks of 3x3 conv + BatchNorm + ReLU of `width` filters (32 in the paper),
//!   the last a plain conv to 3 channels, with the same residual.
//!
//! Images are `[batch, 3, h, w]`, encoded sRGB values in [0, 1]. Any size works: the U-Net pads
//! to a multiple of 16 (edge replication) and crops back.
//!
//! Two implementations share the weights' names: [`fast`] (the CPU path: inference, which
//! every build has, and training) and `nets` (burn modules, feature `train`: checkpoints, the
//! reference the fast path is tested against, GPUs). [`weights`] reads a model file without
//! burn; `checkpoint` writes and reads them through burn.

#[cfg(feature = "train")]
pub mod checkpoint;
pub mod fast;
pub mod infer;
#[cfg(feature = "train")]
mod nets;
pub mod torch;
pub mod weights;

#[cfg(feature = "train")]
pub use nets::*;
use serde::{Deserialize, Serialize};

/// Which network, and its width.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum Arch {
    /// The paper's U-Net; `base` filters at full resolution (64 in the paper).
    Unet { base: usize },
    /// The shallow ablation model; `width` filters per block (32 in the paper).
    Shallow { width: usize },
    /// The U-Net told the time: the sharp image at any time t of the exposure (a fraction in
    /// [0, 1]) from one capture. The input of each of the last `levels` decoder levels (1 to 4)
    /// is scaled and shifted per channel from t (FiLM); the rest runs once per capture.
    BurstUnet {
        base: usize,
        #[serde(default = "last_level", skip_serializing_if = "is_last_level")]
        levels: usize,
    },
}

fn last_level() -> usize {
    1
}

fn is_last_level(levels: &usize) -> bool {
    *levels == 1
}

/// The decoder levels of the U-Net (the burst U-Net's `levels` is at most this).
pub const DECODER_LEVELS: usize = 4;

impl Arch {
    /// The burst U-Net told the time on its last level only (the first burst models).
    pub fn burst(base: usize) -> Arch {
        Arch::BurstUnet { base, levels: 1 }
    }

    /// How many decoder levels, counted from the last, are told the time (0: not a burst model).
    pub fn timed_levels(&self) -> usize {
        match *self {
            Arch::BurstUnet { levels, .. } => levels,
            _ => 0,
        }
    }

    /// Whether the network takes the time (a burst model).
    pub fn is_burst(&self) -> bool {
        matches!(self, Arch::BurstUnet { .. })
    }

    /// The U-Net's or shallow model's width.
    pub fn width(&self) -> usize {
        match *self {
            Arch::Unet { base } | Arch::BurstUnet { base, .. } => base,
            Arch::Shallow { width } => width,
        }
    }

    pub fn name(&self) -> String {
        match self {
            Arch::Unet { base } => format!("unet-{base}"),
            Arch::BurstUnet { base, levels: 1 } => format!("burst-unet-{base}"),
            Arch::BurstUnet { base, levels } => format!("burst-unet-{base}-film{levels}"),
            Arch::Shallow { width } => format!("shallow-{width}"),
        }
    }

    /// Multiply-adds of one forward pass over an `h x w` patch, and the weights they use:
    /// `(macs, weights)`, each convolution's (transposed ones included) `weights x pixels it
    /// produces`. BatchNorm, activations, pooling and biases are left out (under 1% here).
    pub fn conv_macs(&self, h: usize, w: usize) -> (usize, usize) {
        // (cin, cout, kernel side, output pixels) of every convolution, in order.
        let mut convs: Vec<(usize, usize, usize, usize)> = Vec::new();
        let px = |level: usize| (h >> level) * (w >> level);
        match *self {
            Arch::Unet { base: b } | Arch::BurstUnet { base: b, .. } => {
                let double = |convs: &mut Vec<_>, cin: usize, cout: usize, level: usize| {
                    convs.push((cin, cout, 3, px(level)));
                    convs.push((cout, cout, 3, px(level)));
                };
                double(&mut convs, 3, b, 0);
                for (l, (i, o)) in [(b, 2 * b), (2 * b, 4 * b), (4 * b, 8 * b), (8 * b, 8 * b)].into_iter().enumerate() {
                    double(&mut convs, i, o, l + 1);
                }
                // Up(cin, skip, cout) at level l: a 2x2 stride-2 transposed conv (cin -> cin), whose
                // MACs are its weights x its input pixels (a quarter of the level's), then a double
                // conv of the concatenation.
                let ups = [(8 * b, 8 * b, 4 * b, 3), (4 * b, 4 * b, 2 * b, 2), (2 * b, 2 * b, b, 1), (b, b, b, 0)];
                for (cin, skip, cout, l) in ups {
                    convs.push((cin, cin, 2, px(l) / 4));
                    double(&mut convs, cin + skip, cout, l);
                }
                convs.push((b, 3, 1, px(0)));
            }
            Arch::Shallow { width: c } => {
                convs.push((3, c, 3, px(0)));
                convs.extend(std::iter::repeat_n((c, c, 3, px(0)), 8));
                convs.push((c, 3, 3, px(0)));
            }
        }
        convs.iter().fold((0, 0), |(m, n), &(ci, co, k, p)| (m + ci * co * k * k * p, n + ci * co * k * k))
    }
}

/// How many features of the time [`time_features`] gives.
pub const TIME_FEATURES: usize = 9;

/// The features of a time t in [0, 1] the burst U-Net is conditioned on: with s = 2t - 1, s itself
/// and sin, cos of (j pi s) for j = 1 to 4.
pub fn time_features(t: f32) -> [f32; TIME_FEATURES] {
    let s = 2.0 * t - 1.0;
    let mut f = [0.0; TIME_FEATURES];
    f[0] = s;
    for j in 1..=4 {
        let a = std::f32::consts::PI * j as f32 * s;
        f[2 * j - 1] = a.sin();
        f[2 * j] = a.cos();
    }
    f
}

/// The burn name of the time conditioning of decoder level `i` (0 the coarsest): `Unet.film` for
/// the last level (the first burst models had only it), `Unet.up{i + 1}.film` for the others.
pub fn film_name(i: usize) -> String {
    if i + 1 == DECODER_LEVELS {
        "Unet.film".into()
    } else {
        format!("Unet.up{}.film", i + 1)
    }
}

/// The time of a single-frame model's target: the middle of the exposure.
pub const MIDDLE: f32 = 0.5;
