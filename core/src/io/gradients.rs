//! Diffusion gradient tables from FSL `bval`/`bvec` text files.
//!
//! As DIPY's `gradient_table`: volumes with b <= `b0_threshold` (default 50) are b0s, the b-vectors of
//! diffusion-weighted volumes must be unit length within 0.01 and are used as given (DIPY does not
//! renormalise them; [`GradientTable::normalized`] does, on request). NaN components are read as 0.

use std::path::Path;

use glam::DVec3;

use crate::error::{Error, Result};

/// Default b0 threshold in s/mm^2 (DIPY's).
pub const DEFAULT_B0_THRESHOLD: f64 = 50.0;
/// Tolerance on |‖g‖ - 1| for diffusion-weighted directions (DIPY's `atol`).
pub const BVEC_NORM_TOLERANCE: f64 = 1e-2;

#[derive(Clone, Debug)]
pub struct GradientTable {
    /// b-values in s/mm^2, one per volume.
    pub bvals: Vec<f64>,
    /// Unit gradient directions in the image's voxel axes (zero for b0 volumes).
    pub bvecs: Vec<DVec3>,
    pub b0_threshold: f64,
}

impl GradientTable {
    /// Builds and validates a table from b-values and directions.
    pub fn new(bvals: Vec<f64>, bvecs: Vec<DVec3>, b0_threshold: f64) -> Result<Self> {
        if bvals.len() != bvecs.len() {
            return Err(Error::Shape(format!("{} b-values but {} b-vectors", bvals.len(), bvecs.len())));
        }
        if bvals.is_empty() {
            return Err(Error::Shape("empty gradient table".into()));
        }
        if let Some((i, b)) = bvals.iter().enumerate().find(|(_, b)| !b.is_finite() || **b < 0.0) {
            return Err(Error::Param(format!("b-value {i} is {b}: b-values must be finite and >= 0")));
        }
        let bvecs: Vec<DVec3> = bvecs
            .into_iter()
            .map(|v| DVec3::from_array(v.to_array().map(|c| if c.is_nan() { 0.0 } else { c })))
            .collect();
        for (i, (b, g)) in bvals.iter().zip(&bvecs).enumerate() {
            if *b > b0_threshold && (g.length() - 1.0).abs() > BVEC_NORM_TOLERANCE {
                return Err(Error::Param(format!(
                    "b-vector {i} ({:.4} {:.4} {:.4}, b = {b}) is not unit length (norm {:.4}); \
                     normalise it or check the bvec file",
                    g.x,
                    g.y,
                    g.z,
                    g.length()
                )));
            }
        }
        Ok(Self { bvals, bvecs, b0_threshold })
    }

    /// From an MRtrix `dw_scheme` (per volume x, y, z in scanner axes and b) of an image with
    /// `world_from_voxel`: directions turned into the image's voxel axes (the transpose of the affine's
    /// rotation; a reflection where it flips), as b-vectors are.
    pub fn from_dw_scheme(rows: &[[f64; 4]], world_from_voxel: glam::DMat4, b0_threshold: f64) -> Result<Self> {
        let m = crate::sh::world_from_voxel_axes(world_from_voxel);
        let bvecs = rows
            .iter()
            .map(|r| {
                let g = DVec3::new(r[0], r[1], r[2]);
                if g.length() > 0.0 { (m.transpose() * g).normalize() } else { DVec3::ZERO }
            })
            .collect();
        GradientTable::new(rows.iter().map(|r| r[3]).collect(), bvecs, b0_threshold)
    }

    /// The gradient table of the DWI at `path` (with `world_from_voxel` as read): FSL `.bval`/`.bvec` beside it,
    /// else the `dw_scheme` of a `.mif`; None when it has neither.
    pub fn of_image(path: &Path, world_from_voxel: glam::DMat4, b0_threshold: f64) -> Option<Result<Self>> {
        if let Some((bval, bvec)) = super::classify::gradients_beside(path) {
            return Some(GradientTable::from_fsl(bval, bvec, b0_threshold));
        }
        if !super::mif::is_mif(path) {
            return None;
        }
        match super::mif::read_dw_scheme(path) {
            Ok(rows) if rows.is_empty() => None,
            Ok(rows) => Some(GradientTable::from_dw_scheme(&rows, world_from_voxel, b0_threshold)),
            Err(e) => Some(Err(e)),
        }
    }

    /// Reads FSL text files: `bval` is one row (or column) of N numbers; `bvec` is 3 rows of N (FSL) or N
    /// rows of 3 (either orientation is accepted; 3x3 is read as FSL's 3 rows).
    pub fn from_fsl(bval: impl AsRef<Path>, bvec: impl AsRef<Path>, b0_threshold: f64) -> Result<Self> {
        let (bval, bvec) = (bval.as_ref(), bvec.as_ref());
        let bv = read_matrix(bval)?;
        let bvals: Vec<f64> = bv.iter().flatten().copied().collect();
        if bv.len() > 1 && bv.iter().any(|r| r.len() != 1) {
            return Err(Error::format(bval, "bval must be a single row or a single column of numbers"));
        }
        let rows = read_matrix(bvec)?;
        let n = bvals.len();
        let cols = rows.first().map_or(0, |r| r.len());
        if rows.iter().any(|r| r.len() != cols) {
            return Err(Error::format(bvec, "rows of the bvec file have different lengths"));
        }
        let bvecs: Vec<DVec3> = if rows.len() == 3 && cols == n {
            (0..n).map(|i| DVec3::new(rows[0][i], rows[1][i], rows[2][i])).collect()
        } else if rows.len() == n && cols == 3 {
            rows.iter().map(|r| DVec3::new(r[0], r[1], r[2])).collect()
        } else {
            return Err(Error::format(
                bvec,
                format!(
                    "bvec is {}x{cols}, but {} has {n} b-values: expected 3x{n} or {n}x3",
                    rows.len(),
                    bval.display()
                ),
            ));
        };
        Self::new(bvals, bvecs, b0_threshold)
    }

    pub fn len(&self) -> usize {
        self.bvals.len()
    }
    pub fn is_empty(&self) -> bool {
        self.bvals.is_empty()
    }
    pub fn is_b0(&self, i: usize) -> bool {
        self.bvals[i] <= self.b0_threshold
    }
    /// Indices of b0 volumes.
    pub fn b0_indices(&self) -> Vec<usize> {
        (0..self.len()).filter(|&i| self.is_b0(i)).collect()
    }
    /// Indices of diffusion-weighted volumes.
    pub fn dwi_indices(&self) -> Vec<usize> {
        (0..self.len()).filter(|&i| !self.is_b0(i)).collect()
    }

    /// The same table with every diffusion direction scaled to unit length.
    pub fn normalized(&self) -> Self {
        let bvecs = self.bvecs.iter().map(|g| if g.length() > 0.0 { g.normalize() } else { *g }).collect();
        Self { bvecs, ..self.clone() }
    }

    /// Fails unless the table has exactly `n_volumes` entries (the image's 4th dimension).
    pub fn check_volumes(&self, n_volumes: usize) -> Result<()> {
        if self.len() != n_volumes {
            return Err(Error::Shape(format!(
                "the gradient table has {} entries but the image has {n_volumes} volumes",
                self.len()
            )));
        }
        Ok(())
    }
}

/// Whitespace/comma separated numbers, one row per non-empty line.
fn read_matrix(path: &Path) -> Result<Vec<Vec<f64>>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut rows = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let row = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
            .map(|t| {
                t.parse::<f64>().map_err(|_| Error::format(path, format!("line {}: '{t}' is not a number", ln + 1)))
            })
            .collect::<Result<Vec<_>>>()?;
        rows.push(row);
    }
    if rows.is_empty() {
        return Err(Error::format(path, "no numbers in file"));
    }
    Ok(rows)
}
