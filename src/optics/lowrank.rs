//! Low-rank factorisation of a window's kernels: `K_k ~ sum_r a_kr B_r` with orthonormal
//! `B_r`, so that `sum_k K_k * S_k = sum_r B_r * (sum_k a_kr S_k)` needs R forward transforms
//! instead of N. With `tol = 0` the factorisation keeps every non-zero direction and is exact up
//! to rounding; a tolerance drops the directions whose energy is below `tol^2` of the total.
//!
//! Computed from the eigen-decomposition of the N x N Gram matrix (cyclic Jacobi).

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
    /// Relative Frobenius error of the kept rank.
    pub rel_error: f64,
}

/// Factorises `kernels` keeping the smallest rank whose dropped energy is at most
/// `tol^2` of the total.
pub fn factorise(kernels: &[Vec<f32>], tol: f64) -> LowRank {
    let n = kernels.len();
    let gram: Vec<Vec<f64>> =
        (0..n).map(|i| (0..n).map(|j| kernels[i].iter().zip(&kernels[j]).map(|(a, b)| *a as f64 * *b as f64).sum()).collect()).collect();
    let (vals, vecs) = symmetric_eigen(&gram);
    let total: f64 = vals.iter().map(|v| v.max(0.0)).sum::<f64>().max(1e-300);
    let floor = 1e-14 * vals[0].max(1e-300);
    let mut r = 0;
    let mut dropped: f64 = vals.iter().map(|v| v.max(0.0)).sum();
    while r < n && vals[r] > floor && dropped > tol * tol * total {
        dropped -= vals[r].max(0.0);
        r += 1;
    }
    let r = r.max(1);
    let len = kernels[0].len();
    let basis: Vec<Vec<f32>> = (0..r)
        .map(|q| {
            let s = vals[q].max(1e-300).sqrt();
            (0..len).map(|p| ((0..n).map(|i| vecs[i][q] * kernels[i][p] as f64).sum::<f64>() / s) as f32).collect()
        })
        .collect();
    let coeffs = (0..n).map(|k| (0..r).map(|q| vecs[k][q] * vals[q].max(0.0).sqrt()).collect()).collect();
    LowRank { basis, coeffs, rel_error: (dropped.max(0.0) / total).sqrt() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn full_rank_reconstructs_exactly_and_rank_one_is_found() {
        let k: Vec<Vec<f32>> = (0..5).map(|i| (0..25).map(|p| ((i * 31 + p * 17) % 11) as f32).collect()).collect();
        let f = factorise(&k, 0.0);
        for (i, ki) in k.iter().enumerate() {
            for p in 0..25 {
                let rec: f64 = (0..f.basis.len()).map(|r| f.coeffs[i][r] * f.basis[r][p] as f64).sum();
                assert!((rec - ki[p] as f64).abs() < 1e-4, "{rec} vs {}", ki[p]);
            }
        }
        let same: Vec<Vec<f32>> = (0..4).map(|i| k[0].iter().map(|v| v * (i + 1) as f32).collect()).collect();
        assert_eq!(factorise(&same, 1e-6).basis.len(), 1);
    }
}
