//! Low-rank factorisation of a window's kernels: `K_k ~ sum_r a_kr B_r` with orthonormal
//! `B_r`, so that `sum_k K_k * S_k = sum_r B_r * (sum_k a_kr S_k)` needs R forward transforms
//! instead of N.
//!
//! Computed from the eigen-decomposition of the N x N Gram matrix (cyclic Jacobi). Each kernel's
//! coefficients are then moved along the kept directions' sums so that its total (the blur's
//! response to a flat region, its DC) is kept exactly: the dropped part `E_k = K_k - sum_r a_kr B_r`
//! sums to zero, so flat regions blur without error, and the error only sees each sub-frame's
//! variation about its mean, whose energy for values in [0, 1] is at most a quarter (var(S) <=
//! m(1 - m) <= 1/4). The rank is chosen from an error budget in 8-bit levels
//! ([`factorise_within`]): the smallest R whose dropped part provably changes the blurred window
//! by at most that much RMS for any sub-frames with values in [0, 1] (linear light, 1 level =
//! 1/255):
//!
//! `RMS(sum_k E_k * S_k) <= 1/2 min( sum_k max_f |E^_k(f)|, sqrt(N max_f sum_k |E^_k(f)|^2) )`
//!
//! (Parseval with the triangle inequality over k, or with Cauchy-Schwarz over k per frequency;
//! `E^_k(0) = 0`, so only the sub-frames' variance enters; spectra sampled on a grid twice the
//! kernel's side). A budget of 0 keeps every direction: exact up to rounding.
use num_complex::Complex64;

/// Eigenvalues (descending) and eigenvectors (columns, `v[i][r]`) of a symmetric matrix.
pub fn symmetric_eigen(a: &[Vec<f64>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = a.len();
    let mut m: Vec<Vec<f64>> = a.to_vec();
    let mut v: Vec<Vec<f64>> = (0..n).map(|i| (0..n).map(|j| f64::from(u8::from(i == j))).collect()).collect();
    for _sweep in 0..100 {
        let off: f64 = (0..n).flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j))).map(|(i, j)| m[i][j] * m[i][j]).sum();
        let diag: f64 = (0..n).map(|i| m[i][i] * m[i][i]).sum();
        if off <= 1e-30 * diag.max(1e-300) {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                if m[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (m[q][q] - m[p][p]) / (2.0 * m[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (mkp, mkq) = (m[k][p], m[k][q]);
                    m[k][p] = c * mkp - s * mkq;
                    m[k][q] = s * mkp + c * mkq;
                }
                for k in 0..n {
                    let (mpk, mqk) = (m[p][k], m[q][k]);
                    m[p][k] = c * mpk - s * mqk;
                    m[q][k] = s * mpk + c * mqk;
                }
                for row in v.iter_mut() {
                    let (vp, vq) = (row[p], row[q]);
                    row[p] = c * vp - s * vq;
                    row[q] = s * vp + c * vq;
                }
            }
        }
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&i, &j| m[j][j].total_cmp(&m[i][i]));
    let vals = order.iter().map(|&i| m[i][i]).collect();
    let vecs = (0..n).map(|i| order.iter().map(|&r| v[i][r]).collect()).collect();
    (vals, vecs)
}

/// `kernels[k]` (equal lengths) as `sum_r coeffs[k][r] basis[r]`.
#[derive(Debug, Clone)]
pub struct LowRank {
    pub basis: Vec<Vec<f32>>,
    pub coeffs: Vec<Vec<f64>>,
    /// Upper bound on the RMS error of the blurred window, in 8-bit levels of linear light, for
    /// sub-frames in [0, 1] (see the module docs). 0 when every direction is kept.
    pub bound_levels: f64,
}

/// Eigen-decomposition of the kernels' Gram matrix.
fn gram_eigen(kernels: &[Vec<f32>]) -> (Vec<f64>, Vec<Vec<f64>>) {
    let n = kernels.len();
    let gram: Vec<Vec<f64>> =
        (0..n).map(|i| (0..n).map(|j| kernels[i].iter().zip(&kernels[j]).map(|(a, b)| *a as f64 * *b as f64).sum()).collect()).collect();
    symmetric_eigen(&gram)
}

/// Directions worth keeping at all: eigenvalues above rounding.
fn useful(vals: &[f64]) -> usize {
    let floor = 1e-14 * vals[0].max(1e-300);
    vals.iter().take_while(|v| **v > floor).count().max(1)
}

/// The factorisation keeping the first `r` eigen-directions, each kernel's coefficients moved
/// along the kept directions' sums so that its total is kept exactly (module docs; not when
/// every useful direction is kept: nothing is dropped then).
fn keep(kernels: &[Vec<f32>], vals: &[f64], vecs: &[Vec<f64>], r: usize, exact: bool, bound_levels: f64) -> LowRank {
    let n = kernels.len();
    let len = kernels[0].len();
    let basis: Vec<Vec<f32>> = (0..r)
        .map(|q| {
            let s = vals[q].max(1e-300).sqrt();
            (0..len).map(|p| ((0..n).map(|i| vecs[i][q] * kernels[i][p] as f64).sum::<f64>() / s) as f32).collect()
        })
        .collect();
    let mut coeffs: Vec<Vec<f64>> = (0..n).map(|k| (0..r).map(|q| vecs[k][q] * vals[q].max(0.0).sqrt()).collect()).collect();
    if !exact {
        // In f64 from the kernels, not from the f32 basis: sum(B_q) = sum_i v_iq sum(K_i) / sqrt(l_q).
        let totals: Vec<f64> = kernels.iter().map(|k| k.iter().map(|v| *v as f64).sum()).collect();
        let sums: Vec<f64> = (0..r).map(|q| (0..n).map(|i| vecs[i][q] * totals[i]).sum::<f64>() / vals[q].max(1e-300).sqrt()).collect();
        let norm: f64 = sums.iter().map(|c| c * c).sum();
        if norm > 1e-300 {
            for (ck, total) in coeffs.iter_mut().zip(&totals) {
                let delta = (total - ck.iter().zip(&sums).map(|(a, c)| a * c).sum::<f64>()) / norm;
                ck.iter_mut().zip(&sums).for_each(|(a, c)| *a += delta * c);
            }
        }
    }
    LowRank { basis, coeffs, bound_levels }
}

/// Factorises square kernels (`side x side`, row-major) keeping the smallest rank whose error
/// bound is at most `max_error` 8-bit levels RMS (see the module docs); 0 keeps every useful
/// direction.
pub fn factorise_within(kernels: &[Vec<f32>], max_error: f64) -> LowRank {
    let (vals, vecs) = gram_eigen(kernels);
    let most = useful(&vals);
    if max_error <= 0.0 {
        return keep(kernels, &vals, &vecs, most, true, 0.0);
    }
    let bounds = error_bounds(kernels, &vals, &vecs);
    let r = (1..=most).find(|&r| bounds[r] <= max_error).unwrap_or(most);
    keep(kernels, &vals, &vecs, r, r == most, if r == most { 0.0 } else { bounds[r] })
}

/// `bounds[r]` for r = 0..=N: the RMS error bound in 8-bit levels of keeping r directions with
/// the kernels' totals kept exactly (module docs; r = 0 keeps nothing, so no total either).
fn error_bounds(kernels: &[Vec<f32>], vals: &[f64], vecs: &[Vec<f64>]) -> Vec<f64> {
    let n = kernels.len();
    let side = (kernels[0].len() as f64).sqrt().round() as usize;
    assert_eq!(side * side, kernels[0].len(), "square kernels");
    // Spectra of the eigen-directions' kernel combinations U_q = sum_i v_iq K_i (= sqrt(l_q) B_q).
    // The dropped part of K_k past rank r is sum_{q >= r} v_kq U_q, before the totals are kept.
    let m = 2 * side;
    let spectrum = |img: &[f64]| -> Vec<Complex64> {
        let mut a = vec![Complex64::new(0.0, 0.0); m * m];
        for y in 0..side {
            for x in 0..side {
                a[y * m + x].re = img[y * side + x];
            }
        }
        crate::optics::fft::fft2_f64(&mut a, m, m);
        a
    };
    let u: Vec<Vec<Complex64>> = (0..n)
        .map(|q| {
            let img: Vec<f64> = (0..side * side).map(|p| (0..n).map(|i| vecs[i][q] * kernels[i][p] as f64).sum()).collect();
            spectrum(&img)
        })
        .collect();
    // Keeping the totals adds delta_k sum_{q < r} c_q B_q to kernel k's approximation, where
    // c_q = sum(B_q) and delta_k = (dropped total) / sum_{q < r} c_q^2 (`keep`). In spectra:
    // g[r](f) = sum_{q < r} c_q B^_q(f) = sum_{q < r} U^_q(0) U^_q(f) / l_q, norms[r] its c^2 sum.
    let most = useful(vals);
    let mut g = vec![vec![Complex64::new(0.0, 0.0); m * m]; n + 1];
    let mut norms = vec![0.0f64; n + 1];
    for q in 0..n {
        let (head, tail) = g.split_at_mut(q + 1);
        tail[0].copy_from_slice(&head[q]);
        norms[q + 1] = norms[q];
        if q < most {
            let w = u[q][0].re / vals[q];
            tail[0].iter_mut().zip(&u[q]).for_each(|(a, b)| *a += w * b);
            norms[q + 1] += u[q][0].re * w;
        }
    }
    let mut bounds = vec![0.0; n + 1];
    // e[k][f] = sum_{q >= r} v_kq U_q(f), built from r = N down to 0.
    let mut e = vec![vec![Complex64::new(0.0, 0.0); m * m]; n];
    for r in (0..n).rev() {
        for (k, ek) in e.iter_mut().enumerate() {
            let v = vecs[k][r];
            for (a, b) in ek.iter_mut().zip(&u[r]) {
                *a += v * b;
            }
        }
        let kept_totals = norms[r] > 1e-300;
        // One pass over the values: each kernel's largest |E|^2 (one square root each, not one
        // `hypot` per value: those were 2 million calls per channel, a tenth of a second of a
        // run's start) and, per frequency, the sum over the kernels in kernel order.
        let mut per_f_sum = vec![0.0f64; m * m];
        let mut triangle = 0.0;
        for ek in &e {
            let delta = if kept_totals { ek[0].re / norms[r] } else { 0.0 };
            let mut most = 0.0f64;
            for ((s, z), gf) in per_f_sum.iter_mut().zip(ek).zip(&g[r]) {
                let q = (z - delta * gf).norm_sqr();
                *s += q;
                most = most.max(q);
            }
            triangle += most.sqrt();
        }
        let per_f = per_f_sum.into_iter().fold(0.0, f64::max);
        // With the totals kept only the sub-frames' variance (at most 1/4) meets the error.
        let std_bound = if kept_totals { 0.5 } else { 1.0 };
        bounds[r] = 255.0 * std_bound * triangle.min((n as f64 * per_f).sqrt());
    }
    bounds
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_rank_reconstructs_exactly_and_rank_one_is_found() {
        let k: Vec<Vec<f32>> = (0..5).map(|i| (0..25).map(|p| ((i * 31 + p * 17) % 11) as f32).collect()).collect();
        let f = factorise_within(&k, 0.0);
        for (i, ki) in k.iter().enumerate() {
            for p in 0..25 {
                let rec: f64 = (0..f.basis.len()).map(|r| f.coeffs[i][r] * f.basis[r][p] as f64).sum();
                assert!((rec - ki[p] as f64).abs() < 1e-4, "{rec} vs {}", ki[p]);
            }
        }
        let same: Vec<Vec<f32>> = (0..4).map(|i| k[0].iter().map(|v| v * (i + 1) as f32).collect()).collect();
        assert_eq!(factorise_within(&same, 1e-6).basis.len(), 1);
    }

    #[test]
    fn a_reduced_rank_keeps_every_kernels_total() {
        // Nine smooth, overlapping blobs along a path, each summing to 1/9 as a window's kernels
        // do: low rank but not exactly. At a rank below the full one, the eigen-directions alone
        // drop part of each kernel's total; the kept coefficients restore it, so a flat region
        // blurs without error.
        let side = 9;
        let k: Vec<Vec<f32>> = (0..9)
            .map(|i| {
                let (cx, cy) = (2.0 + 0.5 * i as f64, 4.0 + 0.3 * (i as f64).sin());
                let blob: Vec<f64> = (0..side * side)
                    .map(|p| {
                        let (x, y) = ((p % side) as f64, (p / side) as f64);
                        (-((x - cx).powi(2) + (y - cy).powi(2)) / (1.0 + 0.2 * i as f64)).exp()
                    })
                    .collect();
                let sum: f64 = blob.iter().sum();
                blob.iter().map(|v| (v / sum / 9.0) as f32).collect()
            })
            .collect();
        let f = factorise_within(&k, 1.0);
        assert!(f.basis.len() < 9 && f.bound_levels > 0.0, "rank {} bound {}", f.basis.len(), f.bound_levels);
        let (vals, vecs) = gram_eigen(&k);
        let plain = keep(&k, &vals, &vecs, f.basis.len(), true, 0.0);
        let total = |lr: &LowRank, i: usize| -> f64 {
            (0..lr.basis.len()).map(|r| lr.coeffs[i][r] * lr.basis[r].iter().map(|v| *v as f64).sum::<f64>()).sum()
        };
        let mut plain_worst = 0.0f64;
        for (i, ki) in k.iter().enumerate() {
            let want: f64 = ki.iter().map(|v| *v as f64).sum();
            assert!((total(&f, i) - want).abs() < 1e-5 * want, "kernel {i}: {} vs {want}", total(&f, i));
            plain_worst = plain_worst.max((total(&plain, i) - want).abs() / want);
        }
        assert!(plain_worst > 1e-4, "the eigen-directions alone already kept the totals ({plain_worst})");
    }
}
