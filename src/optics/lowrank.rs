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
//! `RMS(sum_k E_k * S_k) <= 1/2 min( sum_k max_f |E^_k(f)|, sqrt(N max_f sum_k |E^_k(f)|^2) )
//!                          + sum_k |E^_k(0)|`
//!
//! (maxima over f != 0: Parseval with the triangle inequality over k, or with Cauchy-Schwarz over
//! k per frequency, applied to the sub-frames minus their means; the last term is the means'
//! part, zero up to rounding since the totals are kept; spectra sampled on a grid twice the
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

/// The eigen-directions' kernel combinations `U_q = sum_i v_iq K_i` (`= sqrt(l_q) B_q`), in f64.
fn directions(kernels: &[Vec<f32>], vecs: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = kernels.len();
    (0..n).map(|q| (0..kernels[0].len()).map(|p| (0..n).map(|i| vecs[i][q] * kernels[i][p] as f64).sum()).collect()).collect()
}

/// Each kernel's coefficients on the first `r` eigen-directions, `a_kq = v_kq sqrt(l_q)`; with
/// `keep_totals`, moved along the kept directions' sums `c_q = sum(B_q)` so that each kernel's
/// total is kept exactly (module docs). `totals`: the kernels' sums.
fn coefficients(vals: &[f64], vecs: &[Vec<f64>], totals: &[f64], r: usize, keep_totals: bool) -> Vec<Vec<f64>> {
    let mut coeffs: Vec<Vec<f64>> = vecs.iter().map(|v| (0..r).map(|q| v[q] * vals[q].max(0.0).sqrt()).collect()).collect();
    // sum(B_q) = sum_i v_iq sum(K_i) / sqrt(l_q), in f64 from the kernels (not the f32 basis).
    let sums: Vec<f64> = (0..r).map(|q| vecs.iter().zip(totals).map(|(v, t)| v[q] * t).sum::<f64>() / vals[q].max(1e-300).sqrt()).collect();
    let norm: f64 = sums.iter().map(|c| c * c).sum();
    if keep_totals && norm > 1e-300 {
        for (ck, total) in coeffs.iter_mut().zip(totals) {
            let delta = (total - ck.iter().zip(&sums).map(|(a, c)| a * c).sum::<f64>()) / norm;
            ck.iter_mut().zip(&sums).for_each(|(a, c)| *a += delta * c);
        }
    }
    coeffs
}

/// Factorises square kernels (`side x side`, row-major) keeping the smallest rank whose error
/// bound is at most `max_error` 8-bit levels RMS (see the module docs); 0 keeps every useful
/// direction.
pub fn factorise_within(kernels: &[Vec<f32>], max_error: f64) -> LowRank {
    let (vals, vecs) = gram_eigen(kernels);
    let most = useful(&vals);
    let u = directions(kernels, &vecs);
    let totals: Vec<f64> = kernels.iter().map(|k| k.iter().map(|v| *v as f64).sum()).collect();
    let basis =
        |r: usize| -> Vec<Vec<f32>> { (0..r).map(|q| u[q].iter().map(|v| (v / vals[q].max(1e-300).sqrt()) as f32).collect()).collect() };
    if max_error > 0.0 {
        let spectra = direction_spectra(&u);
        for r in 1..most {
            let coeffs = coefficients(&vals, &vecs, &totals, r, true);
            let bound_levels = error_bound(&spectra, &vals, &vecs, &coeffs);
            if bound_levels <= max_error {
                return LowRank { basis: basis(r), coeffs, bound_levels };
            }
        }
    }
    LowRank { basis: basis(most), coeffs: coefficients(&vals, &vecs, &totals, most, false), bound_levels: 0.0 }
}

/// Spectra of the directions `U_q` (square, `side x side`) on a grid twice the kernel's side.
fn direction_spectra(u: &[Vec<f64>]) -> Vec<Vec<Complex64>> {
    let side = (u[0].len() as f64).sqrt().round() as usize;
    assert_eq!(side * side, u[0].len(), "square kernels");
    let m = 2 * side;
    u.iter()
        .map(|img| {
            let mut a = vec![Complex64::new(0.0, 0.0); m * m];
            for y in 0..side {
                a[y * m..y * m + side].iter_mut().zip(&img[y * side..(y + 1) * side]).for_each(|(z, v)| z.re = *v);
            }
            crate::optics::fft::fft2_f64(&mut a, m, m);
            a
        })
        .collect()
}

/// The RMS error bound in 8-bit levels of the factorisation with coefficients `coeffs` (`[k][q]`
/// for the first `r` directions): `E_k = K_k - sum_{q < r} a_kq B_q = sum_q w_kq U_q` with
/// `w_kq = v_kq - a_kq / sqrt(l_q)` for q < r and `v_kq` past it. Over the non-zero frequencies
/// the module docs' bound with half (the sub-frames' variance is at most 1/4), plus the mean's
/// part `sum_k |E^_k(0)|` (a sub-frame's mean is in [0, 1]), which is rounding where the totals
/// are kept.
fn error_bound(spectra: &[Vec<Complex64>], vals: &[f64], vecs: &[Vec<f64>], coeffs: &[Vec<f64>]) -> f64 {
    let n = vecs.len();
    let mut per_f_sum = vec![0.0f64; spectra[0].len()];
    let mut e = vec![Complex64::new(0.0, 0.0); spectra[0].len()];
    let (mut triangle, mut mean_part) = (0.0, 0.0);
    for (v, a) in vecs.iter().zip(coeffs) {
        e.fill(Complex64::new(0.0, 0.0));
        for (q, uq) in spectra.iter().enumerate() {
            let w = v[q] - a.get(q).map_or(0.0, |a| a / vals[q].max(1e-300).sqrt());
            e.iter_mut().zip(uq).for_each(|(z, u)| *z += w * u);
        }
        mean_part += e[0].norm();
        // One pass over the values: the kernel's largest |E|^2 (one square root, not one `hypot`
        // per value: those were 2 million calls per channel, a tenth of a second of a run's
        // start) and, per frequency, the sum over the kernels in kernel order.
        let mut most = 0.0f64;
        for (s, z) in per_f_sum.iter_mut().zip(&e).skip(1) {
            let q = z.norm_sqr();
            *s += q;
            most = most.max(q);
        }
        triangle += most.sqrt();
    }
    let per_f = per_f_sum.into_iter().fold(0.0, f64::max);
    255.0 * (0.5 * f64::min(triangle, (n as f64 * per_f).sqrt()) + mean_part)
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
        let totals: Vec<f64> = k.iter().map(|ki| ki.iter().map(|v| *v as f64).sum()).collect();
        let plain = LowRank { coeffs: coefficients(&vals, &vecs, &totals, f.basis.len(), false), ..f.clone() };
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
