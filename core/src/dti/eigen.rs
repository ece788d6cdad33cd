//! Eigen-decomposition of symmetric 3x3 tensors: cyclic Jacobi in f64 on the tensor scaled to unit
//! magnitude.
//!
//! Why Jacobi rather than the closed-form (trigonometric) solution: the closed form loses all accuracy in
//! the eigenvectors when two eigenvalues nearly coincide (prolate and oblate tensors, common in white
//! matter and background), while Jacobi keeps the residual `||T v - l v||` at rounding level for every
//! input and always returns an orthonormal basis. Scaling by the largest entry first makes inputs from
//! 1e-30 to 1e30 behave alike (no overflow or underflow in the rotations).

use glam::DVec3;

/// A symmetric tensor in DIPY's lower-triangular order: Dxx, Dxy, Dyy, Dxz, Dyz, Dzz.
pub type LowerTri = [f64; 6];

/// Eigenvalues sorted largest first, with unit eigenvectors forming a right-handed frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Eigen {
    /// Eigenvalues `[l1, l2, l3]`, `l1 >= l2 >= l3`, in the tensor's units (mm²/s for a fitted tensor).
    pub values: [f64; 3],
    /// Unit eigenvectors `[e1, e2, e3]`, `vectors[i]` belonging to `values[i]`, in the tensor's frame;
    /// `e1 × e2 = e3`.
    pub vectors: [DVec3; 3],
}

/// The full matrix of a lower-triangular tensor.
pub fn to_matrix(t: &LowerTri) -> [[f64; 3]; 3] {
    [[t[0], t[1], t[3]], [t[1], t[2], t[4]], [t[3], t[4], t[5]]]
}

/// Decomposes `t`; `None` when any component is NaN or infinite.
pub fn eigh(t: &LowerTri) -> Option<Eigen> {
    if t.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let scale = t.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if scale == 0.0 {
        return Some(Eigen { values: [0.0; 3], vectors: [DVec3::X, DVec3::Y, DVec3::Z] });
    }
    let mut a = to_matrix(t);
    for row in a.iter_mut() {
        for v in row.iter_mut() {
            *v /= scale;
        }
    }
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    for _sweep in 0..32 {
        let off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
        // Converged when the off-diagonal norm is below rounding of the (unit-scaled) matrix: further
        // rotations would change nothing beyond the last bit. The scaled matrix has max |entry| = 1, so
        // this is relative to ||T||; the stress test checks the residual this leaves.
        if off <= 1e-34 {
            break;
        }
        for (p, q) in [(0usize, 1usize), (0, 2), (1, 2)] {
            let apq = a[p][q];
            // Skip rotations that no longer change the diagonal at working precision.
            if apq.abs() <= f64::EPSILON * 1e-3 * (a[p][p].abs() + a[q][q].abs()) {
                a[p][q] = 0.0;
                a[q][p] = 0.0;
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * apq);
            let t = if theta.abs() > 1e150 {
                0.5 / theta
            } else {
                let s = if theta >= 0.0 { 1.0 } else { -1.0 };
                s / (theta.abs() + (theta * theta + 1.0).sqrt())
            };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for k in 0..3 {
                let (akp, akq) = (a[k][p], a[k][q]);
                a[k][p] = c * akp - s * akq;
                a[k][q] = s * akp + c * akq;
            }
            for k in 0..3 {
                let (apk, aqk) = (a[p][k], a[q][k]);
                a[p][k] = c * apk - s * aqk;
                a[q][k] = s * apk + c * aqk;
            }
            for row in v.iter_mut() {
                let (vkp, vkq) = (row[p], row[q]);
                row[p] = c * vkp - s * vkq;
                row[q] = s * vkp + c * vkq;
            }
        }
    }
    let mut idx = [0usize, 1, 2];
    idx.sort_by(|&i, &j| a[j][j].total_cmp(&a[i][i]));
    let values = idx.map(|i| a[i][i] * scale);
    let mut vectors = idx.map(|i| DVec3::new(v[0][i], v[1][i], v[2][i]).normalize());
    if vectors[0].cross(vectors[1]).dot(vectors[2]) < 0.0 {
        vectors[2] = -vectors[2];
    }
    Some(Eigen { values, vectors })
}

/// Largest residual `||T v_i - l_i v_i||` over the three pairs, relative to the largest |entry| of `T`.
pub fn relative_residual(t: &LowerTri, e: &Eigen) -> f64 {
    let m = to_matrix(t);
    let scale = t.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(f64::MIN_POSITIVE);
    (0..3)
        .map(|i| {
            let v = e.vectors[i];
            let tv = DVec3::new(
                m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z,
                m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
                m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z,
            );
            (tv - e.values[i] * v).length() / scale
        })
        .fold(0.0, f64::max)
}

/// Rebuilds the tensor `sum l_i v_i v_iᵀ`.
pub fn from_eigen(e: &Eigen) -> LowerTri {
    let mut t = [0.0; 6];
    for i in 0..3 {
        let (l, v) = (e.values[i], e.vectors[i]);
        t[0] += l * v.x * v.x;
        t[1] += l * v.x * v.y;
        t[2] += l * v.y * v.y;
        t[3] += l * v.x * v.z;
        t[4] += l * v.y * v.z;
        t[5] += l * v.z * v.z;
    }
    t
}
