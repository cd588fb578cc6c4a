//! The blur against direct convolution: whole windows, crops, tiles and the low-rank bound.

use super::*;
use crate::frame::FrameData;
use crate::optics::fft::convolve_direct;
use crate::optics::{CameraConfig, CameraKind, OpticsConfig};

fn frames(n: usize, w: usize, h: usize, seed: u64) -> Vec<Arc<Frame>> {
    (0..n)
        .map(|k| {
            linear(
                w,
                h,
                std::array::from_fn(|c| {
                    (0..w * h).map(|i| crate::rng::unit(crate::rng::hash(&[seed, k as u64, c as u64, i as u64])) as f32).collect()
                }),
            )
        })
        .collect()
}

/// A frame of linear planes.
fn linear(w: usize, h: usize, p: [Vec<f32>; 3]) -> Arc<Frame> {
    Arc::new(Frame { curve: Some(crate::optics::transfer::Curve::Identity), ..Frame::new(w, h, FrameData::Planar(p)) })
}

/// Per channel, the sum of direct convolutions of the whole frames with the window's
/// (exact) kernels.
fn direct(b: &Blurrer, fr: &[Arc<Frame>]) -> [Vec<f32>; 3] {
    let (w, h) = (fr[0].width, fr[0].height);
    std::array::from_fn(|c| {
        let mut want = vec![0.0f32; w * h];
        for (k, f) in fr.iter().enumerate() {
            let d = convolve_direct(&f.linear_crop(0, 0, w, h)[c], h, w, &b.kernels()[k].render(c, b.margin));
            want.iter_mut().zip(d).for_each(|(a, v)| *a += v);
        }
        want
    })
}

/// Largest difference per channel between `got` and [`direct`].
fn worst_vs_direct(b: &Blurrer, fr: &[Arc<Frame>], got: &[Vec<f32>; 3]) -> [f32; 3] {
    let want = direct(b, fr);
    std::array::from_fn(|c| got[c].iter().zip(&want[c]).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max))
}

#[test]
fn window_blur_equals_sum_of_direct_convolutions() {
    let cam = Arc::new(Camera::new(
        &OpticsConfig { airy_radius_px: Some(0.8), ..Default::default() },
        &CameraConfig::new(CameraKind::PhaseCoded),
    ));
    let mut b = Blurrer::new(cam, 3, 2, 0.0).unwrap();
    let (w, h) = (40, 30);
    let fr = frames(3, w, h, 1);
    let got = b.blur_region(&fr, 0, 0, w, h);
    for (c, worst) in worst_vs_direct(&b, &fr, &got).into_iter().enumerate() {
        assert!(worst < 1e-4, "channel {c}: {worst}");
    }
}

/// RMS per channel of `got` minus [`direct`].
fn rms_vs_direct(b: &Blurrer, fr: &[Arc<Frame>], got: &[Vec<f32>; 3]) -> [f64; 3] {
    let want = direct(b, fr);
    std::array::from_fn(|c| (got[c].iter().zip(&want[c]).map(|(a, b)| f64::from(a - b).powi(2)).sum::<f64>() / want[c].len() as f64).sqrt())
}

const DEFAULT_BUDGET: f64 = crate::stage::coded_blur::DEFAULT_MAX_ERROR;

#[test]
fn the_low_rank_error_stays_within_its_reported_bound() {
    // The coded camera's 9 kernels at budgets that keep 3 to 5 directions, against the exact
    // sum of direct convolutions, on random frames in [0, 1] (white: the hardest case for
    // the dropped directions, which are high-frequency). The measured RMS error is not zero and
    // stays under the bound. The bound is a worst case (a grating at the dropped directions'
    // strongest frequency in every sub-frame): white and natural frames measure 20 to 100
    // times below it (docs/performance.md, the low-rank budget).
    let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::PhaseCoded)));
    let (w, h) = (64, 56);
    let fr = frames(9, w, h, 4);
    let mut seen = Vec::new();
    for budget in [DEFAULT_BUDGET, 0.6, 2.0] {
        let mut b = Blurrer::new(cam.clone(), 9, 2, budget).unwrap();
        let bounds = b.error_bounds();
        let got = b.blur_region(&fr, 0, 0, w, h);
        for (c, rms) in rms_vs_direct(&b, &fr, &got).into_iter().enumerate() {
            let levels = rms * 255.0;
            assert!(
                bounds[c] <= budget && levels <= bounds[c],
                "budget {budget}, channel {c}: measured {levels:.4} levels, bound {:.4}",
                bounds[c]
            );
            assert!(levels > 1e-5, "budget {budget}, channel {c}: no error at ranks {:?}", b.ranks());
        }
        seen.push(b.ranks());
    }
    assert_eq!(seen[0], [4, 4, 4], "the default budget keeps 4 of 9 directions");
    // A larger budget never keeps more directions and here keeps fewer in all.
    for pair in seen.windows(2) {
        assert!(pair[1].iter().zip(&pair[0]).all(|(a, b)| a <= b), "ranks {seen:?}");
        assert!(pair[1].iter().sum::<usize>() < pair[0].iter().sum::<usize>(), "ranks {seen:?}");
    }
    // Each kernel's total is kept, so sub-frames that are flat (a different level each) blur
    // without the low-rank error at any budget: only rounding is left.
    let flat: Vec<Arc<Frame>> =
        (0..9).map(|k| linear(w, h, std::array::from_fn(|c| vec![(0.1 + 0.1 * k as f32) * (1.0 - 0.2 * c as f32); w * h]))).collect();
    let mut coarse = Blurrer::new(cam.clone(), 9, 2, 2.0).unwrap();
    let got = coarse.blur_region(&flat, 0, 0, w, h);
    for (c, worst) in worst_vs_direct(&coarse, &flat, &got).into_iter().enumerate() {
        assert!(worst * 255.0 < 1e-3, "channel {c}: flat sub-frames changed by {} levels at ranks {:?}", worst * 255.0, coarse.ranks());
    }
    // Budget 0 keeps every direction: the bound is 0 and the blur exact up to rounding.
    let mut exact = Blurrer::new(cam, 9, 2, 0.0).unwrap();
    assert_eq!(exact.error_bounds(), [0.0; 3]);
    let got = exact.blur_region(&fr, 0, 0, w, h);
    for (c, worst) in worst_vs_direct(&exact, &fr, &got).into_iter().enumerate() {
        assert!(worst < 2e-6, "channel {c}: {worst}");
    }
}

#[test]
fn crop_then_blur_equals_blur_then_crop() {
    let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::PhaseCoded)));
    let mut b = Blurrer::new(cam, 5, 2, 0.25).unwrap();
    let (w, h) = (96, 80);
    let fr = frames(5, w, h, 2);
    let full = b.blur_region(&fr, 0, 0, w, h);
    // A patch at the corner (mirrored borders inside the margin) and one inside.
    let corners = [(0usize, 0usize), (41, 23)];
    let batch = b.blur_patches(&fr, &corners, 32);
    for (i, (x, y)) in corners.into_iter().enumerate() {
        let part = b.blur_region(&fr, x as isize, y as isize, 32, 32);
        // Patch mode (one worker per patch) computes exactly what all workers on one region do.
        assert!(batch[i] == part, "patch {i}: blur_patches differs from blur_region");
        let want = crop(&full, w, x, y, 32, 32);
        for c in 0..3 {
            let worst = part[c].iter().zip(&want[c]).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
            assert!(worst < 2e-5, "patch ({x},{y}) channel {c}: {worst}");
        }
    }
}

#[test]
fn tiled_blur_equals_direct_convolution_across_the_seams() {
    // Random frames (every pixel's neighbourhood non-trivial) and impulses on and beside
    // every seam, through the coded camera's exact kernels (rank tolerance 0), in tiles of
    // 32 px (several seams per axis, and smaller last tiles) on 1 and 2 workers.
    let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::PhaseCoded)));
    let (w, h, n, tile) = (100, 75, 3, 32);
    let mut fr = frames(n, w, h, 9);
    let mut impulses: Vec<Vec<f32>> = (0..3).map(|_| vec![0.0f32; w * h]).collect();
    for seam in [32usize, 64, 96] {
        for d in [-2isize, -1, 0, 1] {
            let x = (seam as isize + d) as usize;
            for y in (3..h).step_by(11) {
                if x < w {
                    impulses.iter_mut().for_each(|p| p[y * w + x] = 1.0);
                }
                if let Some(row) = (seam as isize + d).try_into().ok().filter(|&r: &usize| r < h) {
                    impulses.iter_mut().for_each(|p| p[row * w + (y % w)] = 1.0);
                }
            }
        }
    }
    fr[1] = linear(w, h, [impulses[0].clone(), impulses[1].clone(), impulses[2].clone()]);
    let mut outs = Vec::new();
    for threads in [1, 2] {
        let mut b = Blurrer::new(cam.clone(), n, threads, 0.0).unwrap();
        let got = b.blur_tiled(&fr, tile);
        for (c, worst) in worst_vs_direct(&b, &fr, &got).into_iter().enumerate() {
            assert!(worst < 1e-5, "channel {c} on {threads} workers: {worst}");
        }
        let whole = b.blur_region(&fr, 0, 0, w, h);
        for c in 0..3 {
            let d = got[c].iter().zip(&whole[c]).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
            assert!(d < 1e-5, "tiled vs whole frame, channel {c}: {d}");
        }
        outs.push(got);
    }
    assert!(outs[0] == outs[1], "tiles give the same bits on 1 and 2 workers");
}

#[test]
fn combined_rows_have_the_same_bits_in_the_vector_and_the_scalar_build() {
    // 9 frames, 5 and 11 ranks (one and two register blocks), a width with a scalar tail.
    let (n, ew, wp) = (9usize, 43usize, 48usize);
    let mut seed = 3u64;
    let mut next = || {
        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((seed >> 40) as f32 / (1u64 << 24) as f32) - 0.5
    };
    let rows: Vec<f32> = (0..n * ew).map(|_| next()).collect();
    for ranks in [5usize, 11] {
        let a: Vec<f32> = (0..n * ranks).map(|_| next()).collect();
        let mut fast: Vec<Vec<f32>> = vec![vec![7.0; 2 * wp]; ranks];
        let mut slow = fast.clone();
        combine_rows(&a, &rows, ew, &mut fast.iter_mut().map(|v| &mut v[..]).collect::<Vec<_>>(), wp, wp);
        combine_cols(&a, &rows, ew, &mut slow.iter_mut().map(|v| &mut v[..]).collect::<Vec<_>>(), wp, 0);
        for (r, (f, s)) in fast.iter().zip(&slow).enumerate() {
            assert_eq!(&f[..wp], &s[..wp], "rank {r}: the row before is untouched");
            assert!(f[wp..wp + ew].iter().zip(&s[wp..wp + ew]).all(|(x, y)| x.to_bits() == y.to_bits()), "rank {r}: bits differ");
            assert!(f[wp + ew..].iter().all(|&v| v == 0.0), "rank {r}: zeros after the region");
            let want: f32 = (0..n).map(|k| a[k * ranks + r] * rows[k * ew + 2]).sum();
            assert!((f[wp + 2] - want).abs() < 1e-5, "rank {r}: the sum itself");
        }
    }
}

#[test]
fn planned_tiles_keep_transforms_cache_sized_and_equal_one_plane() {
    // 720p with the default camera's margin of 27: six tiles in transforms of 432 x 512.
    assert_eq!(plan_tiles(1280, 720, 27), (427, 360));
    let (tw, th) = plan_tiles(3840, 2160, 27);
    assert!(fast_size(tw + 54) <= TILE_FFT_MAX && fast_size(th + 54) <= TILE_FFT_MAX, "4K tiles {tw}x{th}");
    // A frame that fits one transform is one plane; a margin no tile fits is one plane too.
    assert_eq!(plan_tiles(128, 96, 27), (128, 96));
    assert_eq!(plan_tiles(900, 700, 250), (900, 700));
    // A 700 x 60 frame needs two tiles across; planned tiles equal the one-plane blur.
    let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::PhaseCoded)));
    let (w, h, n) = (700, 60, 3);
    let fr = frames(n, w, h, 4);
    let mut b = Blurrer::new(cam, n, 2, 0.25).unwrap();
    assert_eq!(plan_tiles(w, h, b.margin).0, 350);
    let tiled = b.blur_tiled(&fr, 0);
    let whole = b.blur_tiled(&fr, 1 << 20);
    for c in 0..3 {
        let d = tiled[c].iter().zip(&whole[c]).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(d < 1e-5, "planned tiles vs one plane, channel {c}: {d}");
    }
}

#[test]
fn identical_frames_through_conventional_give_the_frame_back() {
    let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(CameraKind::Conventional)));
    let mut b = Blurrer::new(cam, 9, 2, 0.25).unwrap();
    let one = frames(1, 33, 21, 5).remove(0);
    let fr = vec![one.clone(); 9];
    let got = b.blur_region(&fr, 0, 0, 33, 21);
    for c in 0..3 {
        for (a, v) in got[c].iter().zip(&one.linear_crop(0, 0, 33, 21)[c]) {
            assert!((a - v).abs() < 1e-5);
        }
    }
}

#[test]
fn point_symmetric_kernels_take_the_real_product_and_moving_ones_the_complex() {
    let (w, h, n) = (70, 50, 5);
    let fr = frames(n, w, h, 4);
    for (kind, symmetric) in [(CameraKind::PhaseCoded, true), (CameraKind::Conventional, true), (CameraKind::Parabolic, false)] {
        let cam = Arc::new(Camera::new(&OpticsConfig::default(), &CameraConfig::new(kind)));
        let mut b = Blurrer::new(cam, n, 1, 0.0).unwrap();
        let s = b.prepare(64, 64);
        let real: Vec<bool> = s.real.iter().flatten().map(Option::is_some).collect();
        if symmetric {
            assert!(real.iter().all(|&r| r), "{kind:?}: every basis spectrum real, got {real:?}");
            assert!(s.full.iter().flatten().flatten().all(|v| v.im == 0.0), "{kind:?}: imaginary parts set to 0");
        } else {
            assert!(real.iter().any(|&r| !r), "{kind:?}: a moving kernel keeps its complex spectrum");
        }
        // Either product, tiles against direct convolution.
        let got = b.blur_tiled(&fr, 32);
        for (c, worst) in worst_vs_direct(&b, &fr, &got).into_iter().enumerate() {
            assert!(worst < 1e-5, "{kind:?} channel {c}: {worst}");
        }
    }
}

#[test]
fn the_real_product_equals_the_complex_one_with_a_zero_imaginary_part() {
    let v: Vec<Complex32> = (0..37).map(|i| Complex32::new(((i * 13) % 7) as f32 - 3.0, ((i * 5) % 11) as f32 * 0.37 - 1.5)).collect();
    let k: Vec<f32> = (0..37).map(|i| ((i * 3) % 5) as f32 * 0.61 - 1.1).collect();
    let start: Vec<Complex32> = (0..37).map(|i| Complex32::new(i as f32 * 0.25, -(i as f32))).collect();
    for add in [false, true] {
        let mut got = start.clone();
        mul_real(&mut got, &v, &k, add);
        let want: Vec<Complex32> = start
            .iter()
            .zip(&v)
            .zip(&k)
            .map(|((a, v), &k)| if add { a + v * Complex32::new(k, 0.0) } else { v * Complex32::new(k, 0.0) })
            .collect();
        assert_eq!(got, want, "add = {add}");
    }
}
