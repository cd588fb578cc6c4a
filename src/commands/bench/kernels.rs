//! `pipeline bench kernels`: one 3 x 3 convolution layer of the fast path, the direct
//! convolution (shifted copies + matrix products) against Winograd F(2x2, 3x3), at the channel
//! counts and sizes of the U-Nets on a 128 px patch: where `winograd::worth_it` draws its line.

use super::median;
use crate::model::fast::{conv_forward, winograd_conv3x3, winograd_weights, winograd_worth_it, T4};
use std::time::Instant;

/// One layer shape timed both ways.
#[derive(Debug, serde::Serialize)]
pub struct KernelRow {
    pub channels: usize,
    pub size: usize,
    pub direct_ms_median: f64,
    pub winograd_ms_median: f64,
    /// Winograd's time over the direct one's (below 1: Winograd is faster).
    pub winograd_over_direct: f64,
    /// Whether the fast path takes Winograd for this layer.
    pub fast_path_takes_winograd: bool,
}

/// Result of `bench kernels`.
#[derive(Debug, serde::Serialize)]
pub struct KernelBench {
    pub repeats: usize,
    pub threads: usize,
    pub rows: Vec<KernelRow>,
}

/// The layers of the U-Nets on one 128 px patch (channels, side), and the deepest level's.
const SHAPES: [(usize, usize); 9] = [(16, 128), (32, 128), (32, 64), (64, 64), (64, 32), (128, 32), (128, 16), (256, 16), (512, 8)];

fn time(repeats: usize, f: &dyn Fn()) -> f64 {
    f();
    let mut v: Vec<f64> = (0..repeats)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    median(&mut v)
}

/// Times each shape of `SHAPES` `repeats` times each way (after one warm-up call), on one sample.
pub fn kernels(repeats: usize) -> KernelBench {
    let rows = SHAPES
        .iter()
        .map(|&(c, s)| {
            let x = T4::new(1, c, s, s, (0..c * s * s).map(|i| (i % 97) as f32 / 97.0).collect());
            let wt: Vec<f32> = (0..c * c * 9).map(|i| ((i % 13) as f32 - 6.0) * 1e-3).collect();
            let u = winograd_weights(&wt, c, c);
            let direct = time(repeats, &|| drop(std::hint::black_box(conv_forward(&x, &wt, None, c, 3))));
            let wino = time(repeats, &|| drop(std::hint::black_box(winograd_conv3x3(&x, &u, None, c, None))));
            let row = KernelRow {
                channels: c,
                size: s,
                direct_ms_median: direct,
                winograd_ms_median: wino,
                winograd_over_direct: wino / direct,
                fast_path_takes_winograd: winograd_worth_it(c, c, s, s),
            };
            eprintln!(
                "bench: {c} channels on {s}x{s}: direct {direct:.3} ms, Winograd {wino:.3} ms ({:.2}x){}",
                row.winograd_over_direct,
                if row.fast_path_takes_winograd { ", taken" } else { "" }
            );
            row
        })
        .collect();
    KernelBench { repeats, threads: rayon::current_num_threads(), rows }
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_shape_is_timed_both_ways_and_marked_as_the_fast_path_chooses() {
        let r = super::kernels(1);
        assert_eq!(r.rows.len(), super::SHAPES.len());
        for row in &r.rows {
            assert!(row.direct_ms_median > 0.0 && row.winograd_ms_median > 0.0, "{row:?}");
            assert!((row.winograd_over_direct - row.winograd_ms_median / row.direct_ms_median).abs() < 1e-12);
        }
        // 64 channels on 64 x 64 takes Winograd; 512 on 8 x 8 (16 blocks) does not.
        let at = |c, s| r.rows.iter().find(|x| x.channels == c && x.size == s).unwrap().fast_path_takes_winograd;
        assert!(at(64, 64) && !at(512, 8));
    }
}
