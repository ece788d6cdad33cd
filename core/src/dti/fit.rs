//! Log-linear DTI fits (OLS and WLS) exactly as DIPY's `TensorModel`.
//!
//! Model: `ln S_i = x_iᵀ β` with `x_i = (-b g_x², -2b g_x g_y, -b g_y², -2b g_x g_z, -2b g_y g_z, -b g_z², 1)`
//! and `β = (Dxx, Dxy, Dyy, Dxz, Dyz, Dzz, ln S0)`. Signals are clipped to `min_signal` (1e-4) first.
//! - OLS: `β = X⁺ ln S`, with `X⁺` computed once per gradient table.
//! - WLS (Chung 2006, DIPY's default): weights `w = exp(X β_ols)` (the predicted signal), then
//!   `β = (diag(w) X)⁺ (w ln S)`, solved here through the 7x7 normal equations `Xᵀ W² X β = Xᵀ W² ln S`
//!   in f64 with the columns of X equilibrated (entries ~b = 1000 against the ones column), which keeps the
//!   solve within rounding of DIPY's SVD pseudo-inverse. `Xᵀ W² X` is accumulated from the 28 distinct
//!   products `x_a x_b` of each row, precomputed once per table, so the per-voxel work is a 28-wide
//!   multiply-add over the volumes: no allocation and no branches in the loop.
//! - Eigenvalues are clipped to `1e-6 / -min(X)` (DIPY's `min_diffusivity`).

use super::eigen::{Eigen, LowerTri, eigh};
use crate::error::{Error, Result};
use crate::io::GradientTable;
use crate::linalg::{cholesky_solve, pinv};

/// Which estimator to use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum FitMethod {
    /// Ordinary least squares on the log signal.
    Ols,
    /// Weighted least squares, weights the OLS-predicted signal (Chung 2006); the default, as in DIPY.
    #[default]
    Wls,
}

impl std::str::FromStr for FitMethod {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "ols" => Ok(Self::Ols),
            "wls" => Ok(Self::Wls),
            _ => Err(Error::Param(format!("unknown DTI fit method '{s}' (use wls or ols)"))),
        }
    }
}

/// DIPY's default `min_signal` for tensor fits.
pub const MIN_SIGNAL: f64 = 1e-4;
const NPAIR: usize = 28;

/// A fitted voxel. `evecs[j]` is eigenvector j (DIPY's `evecs[..., :, j]`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TensorFit {
    /// The tensor as fitted, before eigenvalue clipping. DIPY's `lower_triangular(quadratic_form)` (what
    /// `tensor.nii.gz` holds) is [`TensorFit::tensor`], rebuilt from the clipped eigenvalues.
    pub lower_tri: LowerTri,
    /// Fitted non-diffusion-weighted signal `exp(ln S0)`, in the input signal's units.
    pub s0: f64,
    /// Eigen-system of `lower_tri`, eigenvalues clipped below to the model's `min_diffusivity`.
    pub eigen: Eigen,
}

impl TensorFit {
    /// The tensor rebuilt from the clipped eigen-system, as DIPY's `quadratic_form`.
    pub fn tensor(&self) -> LowerTri {
        super::eigen::from_eigen(&self.eigen)
    }
}

/// Why a voxel could not be fitted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FitFailure {
    /// The signal holds NaN or infinity.
    NonFiniteSignal,
    /// The (weighted) system is numerically singular and the fallback produced no finite tensor.
    Singular,
}

/// A gradient table turned into everything the per-voxel fit needs.
#[derive(Clone, Debug)]
pub struct TensorModel {
    /// The estimator, OLS or WLS.
    pub method: FitMethod,
    /// Design matrix, one row per volume.
    pub design: Vec<[f64; 7]>,
    /// Row-major 7 x n OLS pseudo-inverse.
    ols_pinv: Vec<f64>,
    /// Column equilibration: the solve uses `X diag(col_scale)`.
    col_scale: [f64; 7],
    /// Per row, the 28 products `xs_a xs_b` (a <= b) of the equilibrated row.
    pairs: Vec<[f64; NPAIR]>,
    /// Signals are clipped below to this before the logarithm; [`MIN_SIGNAL`] (1e-4), as DIPY.
    pub min_signal: f64,
    /// Fitted eigenvalues are clipped below to this (mm²/s for b in s/mm²): `1e-6 / -min(X)`, DIPY's
    /// `min_diffusivity`; 0 when the design has no negative entry.
    pub min_diffusivity: f64,
}

impl TensorModel {
    /// Builds the design matrix and its pseudo-inverse for `gtab`; an error when the table has fewer than 6
    /// diffusion-weighted volumes or 7 in all.
    pub fn new(gtab: &GradientTable, method: FitMethod) -> Result<Self> {
        let design: Vec<[f64; 7]> = gtab
            .bvals
            .iter()
            .zip(&gtab.bvecs)
            .map(|(&b, g)| {
                [
                    -b * g.x * g.x,
                    -b * 2.0 * g.x * g.y,
                    -b * g.y * g.y,
                    -b * 2.0 * g.x * g.z,
                    -b * 2.0 * g.y * g.z,
                    -b * g.z * g.z,
                    1.0,
                ]
            })
            .collect();
        let n = design.len();
        if gtab.dwi_indices().len() < 6 || n < 7 {
            return Err(Error::Param(format!(
                "a tensor fit needs at least 6 diffusion-weighted volumes and 7 in all; the table has {} and {n}",
                gtab.dwi_indices().len()
            )));
        }
        let flat: Vec<f64> = design.iter().flatten().copied().collect();
        let ols_pinv = pinv(&flat, n, 7);
        let mut col_scale = [1.0; 7];
        for (c, s) in col_scale.iter_mut().enumerate() {
            let m = design.iter().fold(0.0f64, |m, r| m.max(r[c].abs()));
            if m > 0.0 {
                *s = 1.0 / m;
            }
        }
        let pairs = design
            .iter()
            .map(|r| {
                let xs: [f64; 7] = std::array::from_fn(|i| r[i] * col_scale[i]);
                let mut p = [0.0; NPAIR];
                let mut k = 0;
                for a in 0..7 {
                    for b in a..7 {
                        p[k] = xs[a] * xs[b];
                        k += 1;
                    }
                }
                p
            })
            .collect();
        let min_x = flat.iter().cloned().fold(f64::INFINITY, f64::min);
        // DIPY: tol / -design_matrix.min(), tol = 1e-6.
        let min_diffusivity = if min_x < 0.0 { 1e-6 / -min_x } else { 0.0 };
        Ok(Self { method, design, ols_pinv, col_scale, pairs, min_signal: MIN_SIGNAL, min_diffusivity })
    }

    /// Volumes in the gradient table, the length `fit_voxel` expects of `signal` and `log_s`.
    pub fn n_volumes(&self) -> usize {
        self.design.len()
    }

    /// Fits one voxel. `log_s` is scratch of length `n_volumes` (no allocation here).
    pub fn fit_voxel(&self, signal: &[f64], log_s: &mut [f64]) -> Result<TensorFit, FitFailure> {
        let n = self.design.len();
        debug_assert_eq!(signal.len(), n);
        for (l, &s) in log_s.iter_mut().zip(signal) {
            if !s.is_finite() {
                return Err(FitFailure::NonFiniteSignal);
            }
            *l = s.max(self.min_signal).ln();
        }
        let mut beta = [0.0f64; 7];
        for (i, b) in beta.iter_mut().enumerate() {
            let row = &self.ols_pinv[i * n..(i + 1) * n];
            *b = row.iter().zip(log_s.iter()).map(|(p, l)| p * l).sum();
        }
        if self.method == FitMethod::Wls {
            beta = self.wls(&beta, log_s).ok_or(FitFailure::Singular)?;
        }
        let lower_tri: LowerTri = [beta[0], beta[1], beta[2], beta[3], beta[4], beta[5]];
        let mut eigen = eigh(&lower_tri).ok_or(FitFailure::Singular)?;
        for v in eigen.values.iter_mut() {
            *v = v.max(self.min_diffusivity);
        }
        Ok(TensorFit { lower_tri, s0: beta[6].exp(), eigen })
    }

    fn wls(&self, beta_ols: &[f64; 7], log_s: &[f64]) -> Option<[f64; 7]> {
        let mut nsum = [0.0f64; NPAIR];
        let mut rhs = [0.0f64; 7];
        for ((row, pairs), &l) in self.design.iter().zip(&self.pairs).zip(log_s) {
            let pred: f64 = row.iter().zip(beta_ols).map(|(x, b)| x * b).sum();
            let w2 = (2.0 * pred).exp();
            for (acc, p) in nsum.iter_mut().zip(pairs) {
                *acc += w2 * p;
            }
            let wl = w2 * l;
            for c in 0..7 {
                rhs[c] += wl * row[c] * self.col_scale[c];
            }
        }
        let mut a = [[0.0f64; 7]; 7];
        let mut k = 0;
        for i in 0..7 {
            for j in i..7 {
                a[i][j] = nsum[k];
                a[j][i] = nsum[k];
                k += 1;
            }
        }
        let xs = match cholesky_solve(&a, &rhs) {
            Some(x) => x,
            None => self.wls_pinv_fallback(beta_ols, log_s)?,
        };
        let beta: [f64; 7] = std::array::from_fn(|i| xs[i] * self.col_scale[i]);
        beta.iter().all(|v| v.is_finite()).then_some(beta)
    }

    /// Rank-deficient weighted systems (weights underflowing to zero): DIPY's pseudo-inverse, literally.
    /// Rare, so it may allocate.
    #[cold]
    fn wls_pinv_fallback(&self, beta_ols: &[f64; 7], log_s: &[f64]) -> Option<[f64; 7]> {
        let n = self.design.len();
        let mut wx = Vec::with_capacity(n * 7);
        let mut wy = Vec::with_capacity(n);
        for (row, &l) in self.design.iter().zip(log_s) {
            let w: f64 = row.iter().zip(beta_ols).map(|(x, b)| x * b).sum::<f64>().exp();
            wx.extend((0..7).map(|c| w * row[c] * self.col_scale[c]));
            wy.push(w * l);
        }
        let p = pinv(&wx, n, 7);
        let x: [f64; 7] = std::array::from_fn(|i| (0..n).map(|k| p[i * n + k] * wy[k]).sum());
        x.iter().all(|v| v.is_finite()).then_some(x)
    }

    /// The signal the model predicts for a tensor and S0: `S0 exp(-b gᵀ D g)` per volume.
    pub fn predict(&self, lower_tri: &LowerTri, s0: f64) -> Vec<f64> {
        self.design.iter().map(|r| s0 * (0..6).map(|c| r[c] * lower_tri[c]).sum::<f64>().exp()).collect()
    }
}
