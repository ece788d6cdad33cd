//! Small dense linear algebra in f64, enough for least-squares fits: Cholesky solves of fixed-size normal
//! equations and a symmetric Jacobi eigen-solver used for pseudo-inverses of rank-deficient systems.

/// Solves `A x = b` for symmetric positive definite `A` (row-major N x N) by Cholesky. Returns `None` when
/// `A` is not numerically positive definite (a pivot <= `1e-13 * max diagonal`).
pub fn cholesky_solve<const N: usize>(a: &[[f64; N]; N], b: &[f64; N]) -> Option<[f64; N]> {
    let mut l = [[0.0f64; N]; N];
    let scale = (0..N).map(|i| a[i][i].abs()).fold(0.0, f64::max);
    if scale.is_nan() || scale <= 0.0 || !scale.is_finite() {
        return None;
    }
    for i in 0..N {
        for j in 0..=i {
            let mut s = a[i][j];
            for k in 0..j {
                s -= l[i][k] * l[j][k];
            }
            if i == j {
                if s.is_nan() || s <= 1e-13 * scale {
                    return None;
                }
                l[i][i] = s.sqrt();
            } else {
                l[i][j] = s / l[j][j];
            }
        }
    }
    let mut y = [0.0; N];
    for i in 0..N {
        let mut s = b[i];
        for k in 0..i {
            s -= l[i][k] * y[k];
        }
        y[i] = s / l[i][i];
    }
    let mut x = [0.0; N];
    for i in (0..N).rev() {
        let mut s = y[i];
        for k in i + 1..N {
            s -= l[k][i] * x[k];
        }
        x[i] = s / l[i][i];
    }
    Some(x)
}

/// Eigen-decomposition of a symmetric n x n matrix (row-major, `a.len() == n*n`) by cyclic Jacobi.
/// Returns eigenvalues (unsorted) and eigenvectors as the columns of a row-major matrix.
pub fn sym_eigen(a: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut a = a.to_vec();
    let mut v = vec![0.0; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    for _sweep in 0..100 {
        let off: f64 = (0..n).flat_map(|p| (p + 1..n).map(move |q| (p, q))).map(|(p, q)| a[p * n + q].powi(2)).sum();
        let diag: f64 = (0..n).map(|i| a[i * n + i].powi(2)).sum();
        if off <= 1e-32 * diag || off == 0.0 {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = a[p * n + q];
                if apq == 0.0 {
                    continue;
                }
                let theta = (a[q * n + q] - a[p * n + p]) / (2.0 * apq);
                let t = if theta.abs() > 1e150 {
                    0.5 / theta
                } else {
                    theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt())
                };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let (akp, akq) = (a[k * n + p], a[k * n + q]);
                    a[k * n + p] = c * akp - s * akq;
                    a[k * n + q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let (apk, aqk) = (a[p * n + k], a[q * n + k]);
                    a[p * n + k] = c * apk - s * aqk;
                    a[q * n + k] = s * apk + c * aqk;
                }
                for k in 0..n {
                    let (vkp, vkq) = (v[k * n + p], v[k * n + q]);
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    ((0..n).map(|i| a[i * n + i]).collect(), v)
}

/// Moore-Penrose pseudo-inverse of a row-major m x n matrix (m >= n typical), through the eigen-system of
/// `AᵀA` with numpy's cut-off (singular values below `1e-15 * max` are dropped). Returns n x m row-major.
pub fn pinv(a: &[f64], m: usize, n: usize) -> Vec<f64> {
    let mut ata = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            ata[i * n + j] = (0..m).map(|k| a[k * n + i] * a[k * n + j]).sum();
        }
    }
    let (w, v) = sym_eigen(&ata, n);
    let wmax = w.iter().cloned().fold(0.0, f64::max);
    // sigma^2 = w; cut sigma < 1e-15 sigma_max, i.e. w < 1e-30 wmax (numerically: relative to eps).
    let cut = wmax * 1e-26;
    // pinv = V diag(1/w) Vᵀ Aᵀ
    let mut inv = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..n {
            inv[i * n + j] = (0..n).filter(|&k| w[k] > cut).map(|k| v[i * n + k] * v[j * n + k] / w[k]).sum();
        }
    }
    let mut out = vec![0.0; n * m];
    for i in 0..n {
        for k in 0..m {
            out[i * m + k] = (0..n).map(|j| inv[i * n + j] * a[k * n + j]).sum();
        }
    }
    out
}

/// Nearest orthogonal matrix to `m` (rotation or reflection, as `m`'s determinant): Newton iteration of the
/// polar decomposition, `m <- (m + m⁻ᵀ) / 2`.
pub fn polar_rotation(mut m: glam::DMat3) -> glam::DMat3 {
    for _ in 0..30 {
        let inv_t = m.inverse().transpose();
        if !inv_t.is_finite() {
            break;
        }
        let next = (m + inv_t) * 0.5;
        let done = (next - m).abs_diff_eq(glam::DMat3::ZERO, 1e-15);
        m = next;
        if done {
            break;
        }
    }
    m
}
