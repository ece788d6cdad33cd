//! Fully normalised associated Legendre functions with the Condon-Shortley phase,
//! `P̄_l^m(cos θ) = N_lm P_l^m(cos θ)`, `N_lm = sqrt((2l+1)/4π (l-m)!/(l+m)!)`, for 0 <= m <= l <= l_max.
//!
//! Computed by the standard three-term recurrence in l of the normalised functions (no factorials, so no
//! overflow at any order; stable in the forward direction):
//! `P̄_m^m = (-1)^m sqrt((2m+1)/4π Π_{k<=m} (2k-1)/2k) sin^m θ`, `P̄_{m+1}^m = sqrt(2m+3) cos θ P̄_m^m`,
//! `P̄_l^m = a_lm (cos θ P̄_{l-1}^m - b_lm P̄_{l-2}^m)`,
//! `a_lm = sqrt((4l²-1)/(l²-m²))`, `b_lm = sqrt(((l-1)²-m²)/(4(l-1)²-1))`.

/// Index of (l, m >= 0) in the triangular tables below.
#[inline]
pub const fn tri(l: usize, m: usize) -> usize {
    l * (l + 1) / 2 + m
}

/// Fills `p[tri(l, m)] = P̄_l^m(cos θ)` and, for m >= 1, `q[tri(l, m)] = P̄_l^m(cos θ) / sin θ` (finite at the
/// poles, which the gradient needs). Both slices need `tri(l_max, l_max) + 1` entries.
pub fn legendre_table(l_max: usize, cos_t: f64, sin_t: f64, p: &mut [f64], q: &mut [f64]) {
    let inv4pi = 1.0 / (4.0 * std::f64::consts::PI);
    // c_m = (-1)^m sqrt((2m+1)/4π Π (2k-1)/2k); p_mm = c_m sin^m, q_mm = c_m sin^(m-1)
    let mut prod = 1.0f64; // Π_{k<=m} (2k-1)/(2k)
    let mut sin_pow = 1.0f64; // sin^m
    let mut sin_pow_m1 = 0.0f64; // sin^(m-1), for m >= 1
    for m in 0..=l_max {
        if m > 0 {
            prod *= (2 * m - 1) as f64 / (2 * m) as f64;
            sin_pow_m1 = sin_pow;
            sin_pow *= sin_t;
        }
        let sign = if m % 2 == 0 { 1.0 } else { -1.0 };
        let c = sign * ((2 * m + 1) as f64 * inv4pi * prod).sqrt();
        let (pmm, qmm) = (c * sin_pow, c * sin_pow_m1);
        p[tri(m, m)] = pmm;
        q[tri(m, m)] = if m > 0 { qmm } else { 0.0 };
        if m < l_max {
            let f = ((2 * m + 3) as f64).sqrt() * cos_t;
            p[tri(m + 1, m)] = f * pmm;
            q[tri(m + 1, m)] = if m > 0 { f * qmm } else { 0.0 };
        }
        for l in m + 2..=l_max {
            let (lf, mf) = (l as f64, m as f64);
            let a = ((4.0 * lf * lf - 1.0) / (lf * lf - mf * mf)).sqrt();
            let b = (((lf - 1.0).powi(2) - mf * mf) / (4.0 * (lf - 1.0).powi(2) - 1.0)).sqrt();
            p[tri(l, m)] = a * (cos_t * p[tri(l - 1, m)] - b * p[tri(l - 2, m)]);
            q[tri(l, m)] = if m > 0 { a * (cos_t * q[tri(l - 1, m)] - b * q[tri(l - 2, m)]) } else { 0.0 };
        }
    }
}

/// `d/dθ P̄_l^m(cos θ)` from the table, by the ladder relation
/// `dP̄_l^m/dθ = ½ [sqrt((l+m+1)(l-m)) P̄_l^{m+1} - sqrt((l+m)(l-m+1)) P̄_l^{m-1}]` (m >= 1) and
/// `dP̄_l^0/dθ = sqrt(l(l+1)) P̄_l^1` (with the Condon-Shortley phase included in P̄).
pub fn dtheta(p: &[f64], l: usize, m: usize) -> f64 {
    let (lf, mf) = (l as f64, m as f64);
    let up = if m < l { p[tri(l, m + 1)] } else { 0.0 };
    if m == 0 {
        return (lf * (lf + 1.0)).sqrt() * up;
    }
    0.5 * (((lf + mf + 1.0) * (lf - mf)).sqrt() * up - ((lf + mf) * (lf - mf + 1.0)).sqrt() * p[tri(l, m - 1)])
}
