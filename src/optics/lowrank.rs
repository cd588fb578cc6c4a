//! Low-rank factorisation of a window's kernels: `K_k ~ sum_r a_kr B_r` with orthonormal
//! `B_r`, so that `sum_k K_k * S_k = sum_r B_r * (sum_k a_kr S_k)` needs R forward transforms
//! instead of N.
//!
//! Computed from the eigen-decomposition of the N x N Gram matrix (cyclic Jacobi). The rank is
//! chosen from an error budget in 8-bit levels ([`factorise_within`]): the smallest R whose
//! dropped part `E_k = K_k - sum_r a_kr B_r` provably changes the blurred window by at most that
//! much RMS for any sub-frames with values in [0, 1] (linear light, 1 level = 1/255):
//!
//! `RMS(sum_k E_k * S_k) <= min( sum_k max_f |E^_k(f)|, sqrt(N max_f sum_k |E^_k(f)|^2) )`
//!
//! (Parseval with the triangle inequality over k, or with Cauchy-Schwarz over k per frequency;
//! spectra sampled on a grid twice the kernel's side). A budget of 0 keeps every direction:
//! exact up to rounding.
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

/// The factorisation keeping the first `r` eigen-directions.
fn keep(kernels: &[Vec<f32>], vals: &[f64], vecs: &[Vec<f64>], r: usize, bound_levels: f64) -> LowRank {
    let n = kernels.len();
    let len = kernels[0].len();
    let basis: Vec<Vec<f32>> = (0..r)
        .map(|q| {
            let s = vals[q].max(1e-300).sqrt();
            (0..len).map(|p| ((0..n).map(|i| vecs[i][q] * kernels[i][p] as f64).sum::<f64>() / s) as f32).collect()
        })
        .collect();
    let coeffs = (0..n).map(|k| (0..r).map(|q| vecs[k][q] * vals[q].max(0.0).sqrt()).collect()).collect();
    LowRank { basis, coeffs, bound_levels }
}

/// Factorises square kernels (`side x side`, row-major) keeping the smallest rank whose error
/// bound is at most `max_error` 8-bit levels RMS (see the module docs); 0 keeps every useful
/// direction.
pub fn factorise_within(kernels: &[Vec<f32>], max_error: f64) -> LowRank {
    let (vals, vecs) = gram_eigen(kernels);
    let most = useful(&vals);
    if max_error <= 0.0 {
        return keep(kernels, &vals, &vecs, most, 0.0);
    }
    let bounds = error_bounds(kernels, &vecs);
    let r = (1..=most).find(|&r| bounds[r] <= max_error).unwrap_or(most);
    keep(kernels, &vals, &vecs, r, if r == most { 0.0 } else { bounds[r] })
}

/// `bounds[r]` for r = 0..=N: the RMS error bound in 8-bit levels of keeping r directions.
fn error_bounds(kernels: &[Vec<f32>], vecs: &[Vec<f64>]) -> Vec<f64> {
    let n = kernels.len();
    let side = (kernels[0].len() as f64).sqrt().round() as usize;
    assert_eq!(side * side, kernels[0].len(), "square kernels");
    // Spectra of the eigen-directions' kernel combinations U_q = sum_i v_iq K_i (= sqrt(l_q) B_q).
    // The dropped part of K_k past rank r is sum_{q >= r} v_kq U_q.
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
        // One pass over the values: each kernel's largest |e|^2 (one square root each, not one
        // `hypot` per value: those were 2 million calls per channel, a tenth of a second of a
        // run's start) and, per frequency, the sum over the kernels in kernel order.
        let mut per_f_sum = vec![0.0f64; m * m];
        let mut triangle = 0.0;
        for ek in &e {
            let mut most = 0.0f64;
            for (s, z) in per_f_sum.iter_mut().zip(ek) {
                let q = z.norm_sqr();
                *s += q;
                most = most.max(q);
            }
            triangle += most.sqrt();
        }
        let per_f = per_f_sum.into_iter().fold(0.0, f64::max);
        bounds[r] = 255.0 * triangle.min((n as f64 * per_f).sqrt());
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
}
