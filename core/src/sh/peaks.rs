//! ODF peaks: the discrete local maxima of an ODF sampled on a sphere, as DIPY's `peak_directions` and
//! `peaks_from_model` find them, so that peak counts and directions agree with DIPY voxel for voxel.
//!
//! Per voxel (DIPY 1.12.1, `dirspeed.pyx` / `recspeed.pyx`):
//! 1. Local maxima over the sphere's edges: a vertex greater than at least one neighbour and not less than
//!    any (two equal neighbouring maxima are both peaks; a constant ODF has none).
//! 2. Sorted by value, largest first, ties in vertex order. DIPY sorts the maxima together with zero-valued
//!    padding, so a maximum with a negative value is replaced by (vertex 0, value 0): reproduced here.
//! 3. One peak is returned as is. Otherwise peaks with `value - m < t (max - m)` are dropped, `m` the ODF's
//!    minimum floored at 0 and `t` the relative threshold.
//! 4. Greedy separation in that order: a peak within `min_separation_angle` of a kept one, either sign
//!    (`|cos| > cos angle`), is dropped.
//! 5. The first `npeaks` are kept.
//!
//! The default sphere is DIPY's `default_sphere`: the 362-vertex hemisphere of `repulsion724` with its
//! edges (some pass through the antipode), copied from DIPY so the neighbourhoods are the same.

use glam::DVec3;
use rayon::prelude::*;

use super::basis::{ShBasis, sh_matrix};
use super::n_coeffs;
use crate::error::{Error, Result};

const DEFAULT_VERTICES: &str = include_str!("../../data/spheres/default_sphere_vertices.txt");
const DEFAULT_EDGES: &str = include_str!("../../data/spheres/default_sphere_edges.txt");

/// Unit vertices and the edges between neighbours.
#[derive(Clone, Debug)]
pub struct Sphere {
    /// Unit directions (DIPY's default: one hemisphere, 362).
    pub vertices: Vec<DVec3>,
    /// Pairs of neighbouring vertices, as indices into `vertices`.
    pub edges: Vec<[u32; 2]>,
}

impl Sphere {
    /// DIPY's `default_sphere` (362 vertices of the `repulsion724` hemisphere, 1,083 edges).
    pub fn dipy_default() -> Self {
        let vertices = DEFAULT_VERTICES
            .lines()
            .filter_map(|l| {
                let v: Vec<f64> = l.split_whitespace().filter_map(|t| t.parse().ok()).collect();
                (v.len() == 3).then(|| DVec3::new(v[0], v[1], v[2]))
            })
            .collect();
        let edges = DEFAULT_EDGES
            .lines()
            .filter_map(|l| {
                let v: Vec<u32> = l.split_whitespace().filter_map(|t| t.parse().ok()).collect();
                (v.len() == 2).then(|| [v[0], v[1]])
            })
            .collect();
        Self { vertices, edges }
    }
}

/// Peak-finding parameters; defaults as DIPY's `peak_directions` (0.5, 25°) and `peaks_from_model` (5 peaks).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct PeakParams {
    /// Drop peaks below this fraction of the largest (above the ODF's minimum, floored at 0).
    pub relative_peak_threshold: f64,
    /// Of two peaks closer than this (degrees, either sign), keep the larger.
    pub min_separation_angle: f64,
    /// Keep at most this many per voxel.
    pub npeaks: usize,
}

impl Default for PeakParams {
    fn default() -> Self {
        Self { relative_peak_threshold: 0.5, min_separation_angle: 25.0, npeaks: 5 }
    }
}

impl PeakParams {
    /// Checks the ranges: threshold in [0, 1], separation angle in [0, 90] degrees, `npeaks` >= 1.
    pub fn validate(&self) -> Result<()> {
        if !(0.0..=1.0).contains(&self.relative_peak_threshold) {
            return Err(Error::Param(format!(
                "relative peak threshold {} must be in [0, 1]",
                self.relative_peak_threshold
            )));
        }
        if !(0.0..=90.0).contains(&self.min_separation_angle) {
            return Err(Error::Param(format!(
                "minimum separation angle {} must be in [0, 90] degrees",
                self.min_separation_angle
            )));
        }
        if self.npeaks == 0 {
            return Err(Error::Param("npeaks must be at least 1".into()));
        }
        Ok(())
    }
}

/// The peaks of one ODF sampled on `sphere` (`odf[i]` at `sphere.vertices[i]`): (vertex, value) pairs,
/// largest first, at most `params.npeaks`. An ODF with a non-finite value has no peaks.
pub fn peak_directions(odf: &[f64], sphere: &Sphere, params: &PeakParams) -> Vec<(usize, f64)> {
    if odf.len() != sphere.vertices.len() || odf.iter().any(|v| !v.is_finite()) {
        return Vec::new();
    }
    // 1. Local maxima: -1 once smaller than a neighbour, 1 once larger than one.
    let mut state = vec![0i8; odf.len()];
    for &[a, b] in &sphere.edges {
        let (a, b) = (a as usize, b as usize);
        if odf[a] < odf[b] {
            state[a] = -1;
            state[b] |= 1;
        } else if odf[a] > odf[b] {
            state[a] |= 1;
            state[b] = -1;
        }
    }
    let peaks: Vec<(usize, f64)> = (0..odf.len()).filter(|&i| state[i] > 0).map(|i| (i, odf[i])).collect();
    let count = peaks.len();
    if count == 0 {
        return peaks;
    }
    // 2. DIPY's stable descending sort runs over the maxima followed by zero padding (vertex 0): negative
    //    maxima fall behind the padding and are replaced by it.
    // Real zero-valued peaks precede the padding; the stable sort keeps vertex order among other ties.
    let mut sorted: Vec<(usize, f64, bool)> =
        peaks.iter().map(|&(i, v)| if v < 0.0 { (0, 0.0, true) } else { (i, v, false) }).collect();
    sorted.sort_by(|x, y| y.1.total_cmp(&x.1).then(x.2.cmp(&y.2)));
    let mut peaks: Vec<(usize, f64)> = sorted.into_iter().map(|(i, v, _)| (i, v)).collect();
    if count == 1 {
        return peaks;
    }
    // 3. Relative threshold above the floored minimum.
    let m = odf.iter().copied().fold(f64::INFINITY, f64::min).max(0.0);
    let top = peaks[0].1 - m;
    let n = peaks.iter().take_while(|p| p.1 - m >= params.relative_peak_threshold * top).count();
    peaks.truncate(n);
    // 4. Greedy separation, either sign.
    let cos_sep = params.min_separation_angle.to_radians().cos();
    let mut kept: Vec<(usize, f64)> = Vec::with_capacity(params.npeaks);
    for p in peaks {
        let v = sphere.vertices[p.0];
        if kept.iter().all(|k| sphere.vertices[k.0].dot(v).abs() <= cos_sep) {
            kept.push(p);
        }
    }
    // 5.
    kept.truncate(params.npeaks);
    kept
}

/// DIPY's generalised fractional anisotropy of a sampled ODF: `sqrt(n Σ(ψ - ψ̄)² / ((n - 1) Σψ²))`, 0 where
/// the ODF is zero (DIPY: NaN).
pub fn gfa_sampled(odf: &[f64]) -> f64 {
    let n = odf.len() as f64;
    let sq: f64 = odf.iter().map(|v| v * v).sum();
    if sq.is_nan() || sq <= 0.0 || n < 2.0 {
        return 0.0;
    }
    let mean = odf.iter().sum::<f64>() / n;
    let var: f64 = odf.iter().map(|v| (v - mean) * (v - mean)).sum();
    (n * var / ((n - 1.0) * sq)).sqrt()
}

/// Peaks of every voxel of an SH field.
#[derive(Clone, Debug, PartialEq)]
pub struct PeakVolume {
    /// Grid size in voxels, (X, Y, Z); voxels in NIfTI order.
    pub dims: [usize; 3],
    /// Peak slots per voxel ([`PeakParams::npeaks`]); voxel `v`'s slots are `v npeaks .. (v + 1) npeaks`.
    pub npeaks: usize,
    /// Per voxel, `npeaks` unit directions in the frame of the SH coefficients (zero where absent).
    pub dirs: Vec<[f32; 3]>,
    /// Per voxel, `npeaks` ODF values at the peaks (0 where absent).
    pub values: Vec<f32>,
    /// Per voxel, `npeaks` sphere vertex indices (-1 where absent).
    pub indices: Vec<i32>,
    /// Per voxel, the GFA of the sampled ODF.
    pub gfa: Vec<f32>,
}

impl PeakVolume {
    /// Number of peaks of voxel `v`.
    pub fn count(&self, v: usize) -> usize {
        self.indices[v * self.npeaks..(v + 1) * self.npeaks].iter().filter(|&&i| i >= 0).count()
    }
}

/// SH coefficients of a grid, voxel-major (`n_coeffs(l_max)` per voxel, NIfTI voxel order, in `basis`).
#[derive(Clone, Copy, Debug)]
pub struct ShGrid<'a> {
    /// Grid size in voxels, (X, Y, Z).
    pub dims: [usize; 3],
    /// `X·Y·Z·n_coeffs(l_max)` coefficients: voxel `v`'s are `coeffs[v n .. (v + 1) n]`.
    pub coeffs: &'a [f64],
    /// The even maximum SH order.
    pub l_max: usize,
    /// The basis of `coeffs`.
    pub basis: ShBasis,
}

/// Peaks of every voxel of `sh`, its ODFs sampled on `sphere`. Voxels outside `mask`, all-zero and
/// non-finite ones get no peaks.
pub fn peaks_from_sh(
    sh: ShGrid<'_>,
    sphere: &Sphere,
    params: &PeakParams,
    mask: Option<&[bool]>,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<PeakVolume> {
    let ShGrid { dims, coeffs, l_max, basis } = sh;
    params.validate()?;
    let nvox: usize = dims.iter().product();
    let nc = n_coeffs(l_max);
    if coeffs.len() != nvox * nc {
        return Err(Error::Shape(format!(
            "{} SH coefficients for {dims:?} voxels of {nc} (l_max {l_max})",
            coeffs.len()
        )));
    }
    if mask.is_some_and(|m| m.len() != nvox) {
        return Err(Error::Shape(format!("the peak mask does not have {nvox} voxels")));
    }
    let b = sh_matrix(basis, l_max, &sphere.vertices);
    let nv = sphere.vertices.len();
    let k = params.npeaks;
    let mut out = PeakVolume {
        dims,
        npeaks: k,
        dirs: vec![[0.0; 3]; nvox * k],
        values: vec![0.0; nvox * k],
        indices: vec![-1; nvox * k],
        gfa: vec![0.0; nvox],
    };
    const BLOCK: usize = crate::volume::PROGRESS_BLOCK;
    out.dirs
        .par_chunks_mut(k * BLOCK)
        .zip(out.values.par_chunks_mut(k * BLOCK))
        .zip(out.indices.par_chunks_mut(k * BLOCK))
        .zip(out.gfa.par_chunks_mut(BLOCK))
        .enumerate()
        .for_each_init(
            || vec![0.0f64; nv],
            |odf, (block, (((dirs, values), indices), gfa))| {
                for (j, g) in gfa.iter_mut().enumerate() {
                    let v = block * BLOCK + j;
                    let c = &coeffs[v * nc..(v + 1) * nc];
                    if mask.is_some_and(|m| !m[v]) || c.iter().all(|x| *x == 0.0) || c.iter().any(|x| !x.is_finite()) {
                        continue;
                    }
                    for (o, row) in odf.iter_mut().zip(b.chunks_exact(nc)) {
                        *o = row.iter().zip(c).map(|(a, b)| a * b).sum();
                    }
                    *g = gfa_sampled(odf) as f32;
                    for (slot, (i, val)) in peak_directions(odf, sphere, params).into_iter().enumerate() {
                        let d = sphere.vertices[i];
                        dirs[j * k + slot] = [d.x as f32, d.y as f32, d.z as f32];
                        values[j * k + slot] = val as f32;
                        indices[j * k + slot] = i as i32;
                    }
                }
                progress(gfa.len());
            },
        );
    Ok(out)
}
