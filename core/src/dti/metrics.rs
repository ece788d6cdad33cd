//! Scalar maps of a tensor's eigenvalues, as DIPY defines them.

use glam::DVec3;

/// Fractional anisotropy `sqrt(1/2 Σ(li-lj)² / Σ li²)`; 0 when all eigenvalues are 0.
pub fn fa(l: &[f64; 3]) -> f64 {
    let den = l[0] * l[0] + l[1] * l[1] + l[2] * l[2];
    if den == 0.0 {
        return 0.0;
    }
    let num = (l[0] - l[1]).powi(2) + (l[1] - l[2]).powi(2) + (l[2] - l[0]).powi(2);
    (0.5 * num / den).sqrt()
}

/// Mean diffusivity.
pub fn md(l: &[f64; 3]) -> f64 {
    (l[0] + l[1] + l[2]) / 3.0
}

/// Axial diffusivity (largest eigenvalue).
pub fn ad(l: &[f64; 3]) -> f64 {
    l[0]
}

/// Radial diffusivity (mean of the two smaller eigenvalues).
pub fn rd(l: &[f64; 3]) -> f64 {
    0.5 * (l[1] + l[2])
}

/// Colour FA: `|e1| * clip(FA, 0, 1)` (RGB in voxel-array axes).
pub fn color_fa(l: &[f64; 3], e1: DVec3) -> [f64; 3] {
    let f = fa(l).clamp(0.0, 1.0);
    (e1.abs() * f).to_array()
}

/// Westin's linear, planar and spherical measures.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum WestinDenominator {
    /// `cl = (l1-l2)/tr, cp = 2(l2-l3)/tr, cs = 3 l3/tr`: they sum to 1 (DIPY's `linearity` etc.).
    #[default]
    Trace,
    /// Westin's original: `cl = (l1-l2)/l1, cp = (l2-l3)/l1, cs = l3/l1` (also sums to 1).
    Largest,
}

/// `[cl, cp, cs]`; all zero when the denominator is 0.
pub fn westin(l: &[f64; 3], den: WestinDenominator) -> [f64; 3] {
    match den {
        WestinDenominator::Trace => {
            let tr = l[0] + l[1] + l[2];
            if tr == 0.0 {
                return [0.0; 3];
            }
            [(l[0] - l[1]) / tr, 2.0 * (l[1] - l[2]) / tr, 3.0 * l[2] / tr]
        }
        WestinDenominator::Largest => {
            if l[0] == 0.0 {
                return [0.0; 3];
            }
            [(l[0] - l[1]) / l[0], (l[1] - l[2]) / l[0], l[2] / l[0]]
        }
    }
}

/// Tensor mode (Ennis & Kindlmann 2006): `3√6 det(Ã/‖Ã‖)` with `Ã` the deviatoric tensor; in [-1, 1],
/// -1 planar, +1 linear; 0 for an isotropic tensor.
pub fn mode(l: &[f64; 3]) -> f64 {
    let m = md(l);
    let d = [l[0] - m, l[1] - m, l[2] - m];
    let n2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    if n2 == 0.0 {
        return 0.0;
    }
    (3.0 * 6f64.sqrt() * d[0] * d[1] * d[2] / n2.powf(1.5)).clamp(-1.0, 1.0)
}
