//! The four real SH bases, evaluation (with analytic gradient), conversion and the Cauchy-Schwarz bound.
//!
//! With `K = P̄_l^{|m|}(cos θ)` (normalised, Condon-Shortley phase), θ = arccos z, φ = atan2(y, x):
//!
//! | basis | m < 0 | m = 0 | m > 0 |
//! |---|---|---|---|
//! | descoteaux07 legacy (DIPY default) | √2 K cos(\|m\|φ) | K | √2 K sin(mφ) |
//! | descoteaux07 | (-1)^m √2 K cos(\|m\|φ) | K | √2 K sin(mφ) |
//! | tournier07 (MRtrix3) | √2 K sin(\|m\|φ) | K | √2 K cos(mφ) |
//! | tournier07 legacy (MRtrix 0.2) | K sin(\|m\|φ) | K | K cos(mφ) |
//!
//! Every basis function is `scale · C` with C one of the orthonormal functions `K`, `√2 K cos(|m|φ)`,
//! `√2 K sin(|m|φ)`; conversion maps coefficients through that common form.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use super::legendre::{dtheta, legendre_table, tri};
use super::{lm_of, n_coeffs};
use crate::error::{Error, Result};

/// A real symmetric SH basis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum ShBasis {
    /// DIPY's basis: `√2 K cos(|m|φ)` for m < 0, `√2 K sin(mφ)` for m > 0.
    Descoteaux07 {
        /// DIPY's legacy variant (its default), without the `(-1)^m` factor on m < 0.
        legacy: bool,
    },
    /// MRtrix's basis: `√2 K sin(|m|φ)` for m < 0, `√2 K cos(mφ)` for m > 0.
    Tournier07 {
        /// MRtrix 0.2's variant, without the `√2` on m ≠ 0 (so not orthonormal).
        legacy: bool,
    },
}

impl Default for ShBasis {
    /// DIPY's default: descoteaux07, legacy.
    fn default() -> Self {
        ShBasis::Descoteaux07 { legacy: true }
    }
}

impl ShBasis {
    /// The four bases: descoteaux07 legacy, descoteaux07, tournier07 legacy, tournier07.
    pub const ALL: [ShBasis; 4] = [
        ShBasis::Descoteaux07 { legacy: true },
        ShBasis::Descoteaux07 { legacy: false },
        ShBasis::Tournier07 { legacy: true },
        ShBasis::Tournier07 { legacy: false },
    ];

    /// Parses "descoteaux07" / "tournier07" with a legacy flag.
    pub fn parse(name: &str, legacy: bool) -> Result<Self> {
        match name.to_ascii_lowercase().as_str() {
            "descoteaux07" | "descoteaux" => Ok(ShBasis::Descoteaux07 { legacy }),
            "tournier07" | "tournier" | "mrtrix" => Ok(ShBasis::Tournier07 { legacy }),
            _ => Err(Error::Param(format!("unknown SH basis '{name}' (descoteaux07 or tournier07)"))),
        }
    }

    /// Display name, also written in SH image headers ([`super::sh_descrip`]): "descoteaux07", "descoteaux07 legacy",
    /// "tournier07" or "tournier07 legacy".
    pub fn name(&self) -> String {
        format!("{}{}", self.convention(), if self.legacy() { " legacy" } else { "" })
    }

    /// The convention's name, as DIPY and MRtrix call it: "descoteaux07" or "tournier07".
    pub fn convention(&self) -> &'static str {
        match self {
            ShBasis::Descoteaux07 { .. } => "descoteaux07",
            ShBasis::Tournier07 { .. } => "tournier07",
        }
    }

    /// Whether it is the convention's legacy variant.
    pub fn legacy(&self) -> bool {
        match self {
            ShBasis::Descoteaux07 { legacy } | ShBasis::Tournier07 { legacy } => *legacy,
        }
    }

    /// Which orthonormal function coefficient `m` multiplies, and by what factor.
    #[inline]
    fn form(&self, m: i64) -> (Trig, f64) {
        use std::f64::consts::SQRT_2;
        if m == 0 {
            return (Trig::Zero, 1.0);
        }
        match *self {
            ShBasis::Descoteaux07 { legacy } => {
                if m < 0 {
                    let s = if !legacy && m % 2 != 0 { -1.0 } else { 1.0 };
                    (Trig::Cos, s)
                } else {
                    (Trig::Sin, 1.0)
                }
            }
            ShBasis::Tournier07 { legacy } => {
                let s = if legacy { 1.0 / SQRT_2 } else { 1.0 };
                (if m < 0 { Trig::Sin } else { Trig::Cos }, s)
            }
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Trig {
    Zero,
    Cos,
    Sin,
}

/// Angles of a direction: (cos θ, sin θ, φ). Non-unit input is normalised.
#[inline]
fn angles(d: DVec3) -> (f64, f64, f64) {
    let r = d.length();
    let (x, y, z) = (d.x / r, d.y / r, d.z / r);
    let rho = (x * x + y * y).sqrt();
    (z, rho, y.atan2(x))
}

/// Scratch space for evaluating bases of one order without allocating per call.
pub struct ShScratch {
    l_max: usize,
    p: Vec<f64>,
    q: Vec<f64>,
}

impl ShScratch {
    /// Scratch for the bases of even order `l_max` (`n_coeffs(l_max)` functions per evaluation).
    pub fn new(l_max: usize) -> Self {
        let n = tri(l_max, l_max) + 1;
        Self { l_max, p: vec![0.0; n], q: vec![0.0; n] }
    }

    /// Values of all `n_coeffs(l_max)` basis functions at `dir` into `out`.
    pub fn basis_at(&mut self, basis: ShBasis, dir: DVec3, out: &mut [f64]) {
        let (ct, st, phi) = angles(dir);
        legendre_table(self.l_max, ct, st, &mut self.p, &mut self.q);
        for (j, o) in out.iter_mut().enumerate().take(n_coeffs(self.l_max)) {
            let (l, m) = lm_of(j);
            let am = m.unsigned_abs() as usize;
            let k = self.p[tri(l, am)];
            let (trig, s) = basis.form(m);
            *o = match trig {
                Trig::Zero => k,
                Trig::Cos => s * std::f64::consts::SQRT_2 * k * (am as f64 * phi).cos(),
                Trig::Sin => s * std::f64::consts::SQRT_2 * k * (am as f64 * phi).sin(),
            };
        }
    }

    /// `ψ(dir)` and its gradient on the unit sphere (tangent, in Cartesian axes) for coefficients `c`.
    pub fn value_and_gradient(&mut self, basis: ShBasis, c: &[f64], dir: DVec3) -> (f64, DVec3) {
        let (ct, st, phi) = angles(dir);
        legendre_table(self.l_max, ct, st, &mut self.p, &mut self.q);
        let (mut f, mut df_dtheta, mut df_dphi_over_sin) = (0.0, 0.0, 0.0);
        for (j, &cj) in c.iter().enumerate().take(n_coeffs(self.l_max)) {
            let (l, m) = lm_of(j);
            let am = m.unsigned_abs() as usize;
            let (k, dk, k_over_sin) = (self.p[tri(l, am)], dtheta(&self.p, l, am), self.q[tri(l, am)]);
            let (trig, s) = basis.form(m);
            let (sn, cs) = (am as f64 * phi).sin_cos();
            let w = cj * s * std::f64::consts::SQRT_2;
            match trig {
                Trig::Zero => {
                    f += cj * k;
                    df_dtheta += cj * dk;
                }
                Trig::Cos => {
                    f += w * k * cs;
                    df_dtheta += w * dk * cs;
                    df_dphi_over_sin += -w * k_over_sin * am as f64 * sn;
                }
                Trig::Sin => {
                    f += w * k * sn;
                    df_dtheta += w * dk * sn;
                    df_dphi_over_sin += w * k_over_sin * am as f64 * cs;
                }
            }
        }
        let (sp, cp) = phi.sin_cos();
        let e_theta = DVec3::new(ct * cp, ct * sp, -st);
        let e_phi = DVec3::new(-sp, cp, 0.0);
        (f, df_dtheta * e_theta + df_dphi_over_sin * e_phi)
    }
}

/// The basis matrix (row-major, `dirs.len() x n_coeffs(l_max)`): entry (i, j) is basis function j at dir i.
pub fn sh_matrix(basis: ShBasis, l_max: usize, dirs: &[DVec3]) -> Vec<f64> {
    let n = n_coeffs(l_max);
    let mut out = vec![0.0; dirs.len() * n];
    let mut s = ShScratch::new(l_max);
    for (row, d) in out.chunks_exact_mut(n).zip(dirs) {
        s.basis_at(basis, *d, row);
    }
    out
}

/// `ψ(dir)` for coefficients `c` (their count fixes l_max).
pub fn eval(basis: ShBasis, c: &[f64], dir: DVec3) -> Result<f64> {
    Ok(eval_with_gradient(basis, c, dir)?.0)
}

/// `ψ(dir)` and its tangential gradient.
pub fn eval_with_gradient(basis: ShBasis, c: &[f64], dir: DVec3) -> Result<(f64, DVec3)> {
    let l_max = super::l_max_for(c.len())
        .ok_or_else(|| Error::Shape(format!("{} is not the coefficient count of an even SH order", c.len())))?;
    Ok(ShScratch::new(l_max).value_and_gradient(basis, c, dir))
}

/// Converts coefficients from one basis to another (same function, same l_max).
pub fn convert(c: &[f64], from: ShBasis, to: ShBasis) -> Vec<f64> {
    c.iter()
        .enumerate()
        .map(|(j, &cj)| {
            let (_, m) = lm_of(j);
            let (tf, sf) = from.form(m);
            // The target index holding the same orthonormal function: same l, same |m|, m's sign from
            // whichever side carries that trig function in the target.
            let (tt_same, st_same) = to.form(m);
            if tt_same == tf {
                return (j, cj * sf / st_same);
            }
            let j2 = (j as i64 - 2 * m) as usize;
            let (_, st_other) = to.form(-m);
            (j2, cj * sf / st_other)
        })
        .fold(vec![0.0; c.len()], |mut out, (j, v)| {
            out[j] = v;
            out
        })
}

/// Cauchy-Schwarz bound: `|ψ(u)| <= rmax` for every unit u, with
/// `rmax = ||c̃|| sqrt(Σ_{even l<=L} (2l+1)/4π) = ||c̃|| sqrt((L+1)(L+2)/8π)`, c̃ the coefficients in an
/// orthonormal basis (the addition theorem gives `Σ_m Y_lm(u)² = (2l+1)/4π`).
pub fn bound_rmax(basis: ShBasis, c: &[f64]) -> f64 {
    let l_max = super::l_max_for(c.len()).unwrap_or(0);
    let norm2: f64 = c
        .iter()
        .enumerate()
        .map(|(j, &cj)| {
            let s = basis.form(lm_of(j).1).1;
            (cj * s).powi(2)
        })
        .sum();
    (norm2 * ((l_max + 1) * (l_max + 2)) as f64 / (8.0 * std::f64::consts::PI)).sqrt()
}
