//! Constant solid angle (Aganj 2010) and Q-ball (Descoteaux 2007) ODF fits, as DIPY's `CsaOdfModel` and
//! `QballModel`.
//!
//! Both fit in DIPY's descoteaux07 legacy basis with Laplace-Beltrami regularisation (`smooth` = 0.006):
//! `B⁺_λ = pinv([B; diag(sqrt(smooth) L)])[:, :n]`, `L = -l(l+1)`, `F = P_l(0)` (Funk-Radon).
//! - CSA: `c = F L / 8π · B⁺_λ ln(-ln E)`, then `c_0 = 1/(2√π)`, with E clipped to [0.001, 0.999].
//! - Q-ball: `c = F · B⁺_λ E`.
//!
//! E is formed as DIPY does, in float32: signal clipped to >= 1e-5, divided by the mean b0 (and for CSA the
//! double log is taken in float32 too). The result may then be converted to any basis.

use glam::DVec3;
use rayon::prelude::*;

use super::basis::{ShBasis, convert, sh_matrix};
use super::{lm_of, n_coeffs};
use crate::error::{Error, Result};
use crate::io::GradientTable;
use crate::linalg::pinv;
use crate::volume::{Scalar, Volume};

/// Which ODF an [`OdfModel`] fits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum OdfKind {
    /// Constant solid angle (Aganj 2010): the fit of `ln(-ln E)`, then `c_0 = 1/(2√π)` (unit integral).
    Csa,
    /// Q-ball (Descoteaux 2007): the Funk-Radon transform of E.
    Qball,
}

/// DIPY's default Laplace-Beltrami regularisation weight.
pub const DEFAULT_SMOOTH: f64 = 0.006;
/// DIPY's `min_signal` for ODF models.
pub const MIN_SIGNAL: f32 = 1e-5;

/// A CSA or Q-ball ODF fit for one gradient table, as DIPY's `CsaOdfModel` / `QballModel`.
#[derive(Clone, Debug)]
pub struct OdfModel {
    /// Which ODF is fitted.
    pub kind: OdfKind,
    /// The even maximum SH order of the fit.
    pub l_max: usize,
    /// Basis of the returned coefficients.
    pub basis: ShBasis,
    /// Row-major `n_coeffs x n_dwi`, in descoteaux07 legacy.
    fit_matrix: Vec<f64>,
    b0: Vec<usize>,
    dwi: Vec<usize>,
}

/// `P_l(0)` for even l: `(-1)^(l/2) (l-1)!! / l!!`.
fn legendre_at_zero(l: usize) -> f64 {
    let mut v = 1.0;
    let mut k = 2;
    while k <= l {
        v *= -((k - 1) as f64) / k as f64;
        k += 2;
    }
    v
}

impl OdfModel {
    /// Precomputes the fit matrix for `gtab`'s diffusion-weighted directions: `l_max` even and >= 2, `smooth` the
    /// Laplace-Beltrami weight ([`DEFAULT_SMOOTH`]), `basis` that of the returned coefficients. Needs a b0 volume.
    pub fn new(gtab: &GradientTable, kind: OdfKind, l_max: usize, smooth: f64, basis: ShBasis) -> Result<Self> {
        if !l_max.is_multiple_of(2) || l_max == 0 {
            return Err(Error::Param(format!("l_max must be even and >= 2, got {l_max}")));
        }
        let (b0, dwi) = (gtab.b0_indices(), gtab.dwi_indices());
        if b0.is_empty() {
            return Err(Error::Param("an ODF fit needs at least one b0 volume to normalise the signal".into()));
        }
        let n = n_coeffs(l_max);
        // With smooth > 0 the stacked system [B; diag(sqrt(smooth) L)] has full rank for any number of
        // directions (DIPY fits l_max 6 from 25 directions); without regularisation it needs n of them.
        if smooth == 0.0 && dwi.len() < n {
            return Err(Error::Param(format!(
                "l_max {l_max} has {n} coefficients but there are only {} diffusion-weighted volumes (use smooth > 0)",
                dwi.len()
            )));
        }
        if dwi.is_empty() {
            return Err(Error::Param("an ODF fit needs diffusion-weighted volumes".into()));
        }
        if !(smooth >= 0.0 && smooth.is_finite()) {
            return Err(Error::Param(format!("smooth must be finite and >= 0, got {smooth}")));
        }
        let dirs: Vec<DVec3> = dwi.iter().map(|&i| gtab.bvecs[i]).collect();
        let b = sh_matrix(ShBasis::Descoteaux07 { legacy: true }, l_max, &dirs);
        let m = dirs.len();
        let lvals: Vec<f64> = (0..n).map(|j| lm_of(j).0 as f64).collect();
        let lap: Vec<f64> = lvals.iter().map(|l| -l * (l + 1.0)).collect();
        // Stack [B; diag(sqrt(smooth) L)] and take its pseudo-inverse's first m columns.
        let mut stacked = b.clone();
        for (j, lj) in lap.iter().enumerate() {
            let mut row = vec![0.0; n];
            row[j] = smooth.sqrt() * lj;
            stacked.extend(row);
        }
        let full = pinv(&stacked, m + n, n);
        let mut fit_matrix = vec![0.0; n * m];
        for j in 0..n {
            let f = legendre_at_zero(lvals[j] as usize);
            let factor = match kind {
                OdfKind::Csa => f * lap[j] / (8.0 * std::f64::consts::PI),
                OdfKind::Qball => f,
            };
            for k in 0..m {
                fit_matrix[j * m + k] = factor * full[j * (m + n) + k];
            }
        }
        Ok(Self { kind, l_max, basis, fit_matrix, b0, dwi })
    }

    /// Coefficients per voxel, `n_coeffs(l_max)` (15 at l_max 4, 45 at 8).
    pub fn n_coeffs(&self) -> usize {
        n_coeffs(self.l_max)
    }

    /// Fits one voxel's full signal (all volumes) into `out` (`n_coeffs` long). `scratch` holds `n_dwi`.
    pub fn fit_voxel(&self, signal: &[f64], scratch: &mut [f64], out: &mut [f64]) {
        // DIPY normalize_data: float32 copy, clip >= 1e-5, divide by the float32 mean of the b0s.
        let mut b0sum = 0f32;
        for &i in &self.b0 {
            b0sum += (signal[i] as f32).max(MIN_SIGNAL);
        }
        let b0 = b0sum / self.b0.len() as f32;
        for (s, &i) in scratch.iter_mut().zip(&self.dwi) {
            let e = (signal[i] as f32).max(MIN_SIGNAL) / b0;
            *s = match self.kind {
                OdfKind::Csa => {
                    let e = e.clamp(0.001, 0.999);
                    (-(e.ln())).ln() as f64
                }
                OdfKind::Qball => e as f64,
            };
        }
        let m = self.dwi.len();
        for (j, o) in out.iter_mut().enumerate() {
            *o = self.fit_matrix[j * m..(j + 1) * m].iter().zip(scratch.iter()).map(|(a, b)| a * b).sum();
        }
        if self.kind == OdfKind::Csa {
            out[0] = 0.5 / std::f64::consts::PI.sqrt();
        }
        if self.basis != (ShBasis::Descoteaux07 { legacy: true }) {
            let c = convert(out, ShBasis::Descoteaux07 { legacy: true }, self.basis);
            out.copy_from_slice(&c);
        }
    }
}

/// Fits an ODF model to every voxel of a 4D DWI; returns an (X,Y,Z,n_coeffs) volume. Voxels outside the
/// mask, and voxels whose signal is not finite, are zero.
pub fn fit_odf_volume<T: Scalar>(dwi: &Volume<T>, model: &OdfModel, mask: Option<&[bool]>) -> Result<Volume<f32>> {
    fit_odf_volume_with_progress(dwi, model, mask, &|_| {})
}

/// [`fit_odf_volume`], calling `progress(n)` as each block of `n` voxels is done.
pub fn fit_odf_volume_with_progress<T: Scalar>(
    dwi: &Volume<T>,
    model: &OdfModel,
    mask: Option<&[bool]>,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Volume<f32>> {
    let nvox = dwi.n_voxels();
    let n = model.n_coeffs();
    let d = dwi.dims3();
    let per_voxel = fit_odf_coefficients(dwi, model, mask, progress)?;
    let mut vol = Volume::<f32>::zeros(&[d[0], d[1], d[2], n], dwi.world_from_voxel);
    for v in 0..nvox {
        for c in 0..n {
            vol.data[v + nvox * c] = per_voxel[v * n + c] as f32;
        }
    }
    Ok(vol)
}

/// The fit in f64, voxel-major (`n_coeffs` per voxel, NIfTI voxel order): what peak extraction uses, so that
/// no f32 rounding moves a near-tie between two sphere vertices.
pub fn fit_odf_coefficients<T: Scalar>(
    dwi: &Volume<T>,
    model: &OdfModel,
    mask: Option<&[bool]>,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Vec<f64>> {
    if dwi.shape.len() != 4 {
        return Err(Error::Shape(format!("a DWI must be 4D (X,Y,Z,N); this image is {:?}", dwi.shape)));
    }
    let nvox = dwi.n_voxels();
    let nvol = dwi.shape[3];
    if model.b0.iter().chain(&model.dwi).any(|&i| i >= nvol) {
        return Err(Error::Shape(format!("the gradient table does not match the image's {nvol} volumes")));
    }
    if let Some(m) = mask
        && m.len() != nvox
    {
        return Err(Error::Shape(format!("the mask has {} voxels, the DWI {nvox}", m.len())));
    }
    let n = model.n_coeffs();
    let mut per_voxel = vec![0f64; nvox * n];
    const BLOCK: usize = crate::volume::PROGRESS_BLOCK;
    per_voxel.par_chunks_mut(n * BLOCK).enumerate().for_each_init(
        || (vec![0.0f64; nvol], vec![0.0f64; model.dwi.len()]),
        |(sig, scratch), (block, outs)| {
            for (k, out) in outs.chunks_exact_mut(n).enumerate() {
                let v = block * BLOCK + k;
                if mask.is_some_and(|m| !m[v]) {
                    continue;
                }
                dwi.voxel_signal(v, sig);
                if sig.iter().any(|s| !s.is_finite()) {
                    continue;
                }
                model.fit_voxel(sig, scratch, out);
            }
            progress(outs.len() / n);
        },
    );
    Ok(per_voxel)
}
