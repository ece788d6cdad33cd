//! Diffusion gradient tables from FSL `bval`/`bvec` text files.
//!
//! As DIPY's `gradient_table`: volumes with b <= `b0_threshold` (default 50) are b0s, the b-vectors of
//! diffusion-weighted volumes must be unit length within 0.01 and are used as given (DIPY does not
//! renormalise them; [`GradientTable::normalized`] does, on request). NaN components are read as 0.
//!
//! The frame of a `.bvec` file is a [`BvecConvention`]: FSL defines b-vectors in the image's voxel axes with
//! x negated when the affine's determinant is positive (as FSL, MRtrix3's `-fslgrad` and dcm2niix write and
//! read them; the default here); DIPY reads them in the voxel axes as given. The two agree on images with a
//! negative determinant (FSL's radiological storage, most scanner conversions) and mirror each other in x on
//! the others.

use std::path::Path;

use glam::DVec3;

use crate::error::{Error, Result};

/// Default b0 threshold in s/mm^2 (DIPY's).
pub const DEFAULT_B0_THRESHOLD: f64 = 50.0;
/// Tolerance on |‖g‖ - 1| for diffusion-weighted directions (DIPY's `atol`).
pub const BVEC_NORM_TOLERANCE: f64 = 1e-2;

/// The frame in which an FSL `.bvec` file gives its directions.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BvecConvention {
    /// FSL's definition (FSL, MRtrix3's `-fslgrad`/`-export_grad_fsl`, dcm2niix): the image's voxel axes, with x
    /// negated when the 3x3 part of the image's affine has a positive determinant. The default.
    #[default]
    Fsl,
    /// DIPY's reading (`read_bvals_bvecs` + `gradient_table`): the voxel axes as given, whatever the affine.
    Dipy,
}

impl BvecConvention {
    /// `"fsl"` or `"dipy"`, as on the command line and in sidecars.
    pub fn name(self) -> &'static str {
        match self {
            BvecConvention::Fsl => "fsl",
            BvecConvention::Dipy => "dipy",
        }
    }

    /// Whether, for an image with `world_from_voxel`, a file's x component is the negated voxel-axis x.
    pub fn flips_x(self, world_from_voxel: glam::DMat4) -> bool {
        self == BvecConvention::Fsl && glam::DMat3::from_mat4(world_from_voxel).determinant() > 0.0
    }
}

impl std::str::FromStr for BvecConvention {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "fsl" => Ok(BvecConvention::Fsl),
            "dipy" => Ok(BvecConvention::Dipy),
            _ => Err(Error::Param(format!("b-vector convention '{s}': expected fsl or dipy"))),
        }
    }
}

/// b-values and unit gradient directions, one per volume.
#[derive(Clone, Debug)]
pub struct GradientTable {
    /// b-values in s/mm^2, one per volume.
    pub bvals: Vec<f64>,
    /// Unit gradient directions in the image's voxel axes (zero for b0 volumes).
    pub bvecs: Vec<DVec3>,
    /// b-value in s/mm^2 at or below which a volume is a b0 (callers usually pass [`DEFAULT_B0_THRESHOLD`], 50).
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

    /// The gradient table of the DWI at `path` (with `world_from_voxel` as read): FSL `.bval`/`.bvec` beside it
    /// (read in `convention`'s frame), else the `dw_scheme` of a `.mif`; None when it has neither.
    pub fn of_image(
        path: &Path,
        world_from_voxel: glam::DMat4,
        convention: BvecConvention,
        b0_threshold: f64,
    ) -> Option<Result<Self>> {
        if let Some((bval, bvec)) = super::classify::gradients_beside(path) {
            return Some(GradientTable::from_fsl_for_image(bval, bvec, world_from_voxel, convention, b0_threshold));
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

    /// [`GradientTable::from_fsl`] for the image with `world_from_voxel`, the directions taken from the file's
    /// frame (`convention`) into the image's voxel axes: with [`BvecConvention::Fsl`], x is negated when the
    /// affine's determinant is positive.
    pub fn from_fsl_for_image(
        bval: impl AsRef<Path>,
        bvec: impl AsRef<Path>,
        world_from_voxel: glam::DMat4,
        convention: BvecConvention,
        b0_threshold: f64,
    ) -> Result<Self> {
        let mut table = Self::from_fsl(bval, bvec, b0_threshold)?;
        if convention.flips_x(world_from_voxel) {
            table.bvecs.iter_mut().for_each(|g| g.x = if g.x == 0.0 { 0.0 } else { -g.x });
        }
        Ok(table)
    }

    /// The directions in world (scanner) axes for an image with `world_from_voxel` (its affine's rotation,
    /// as MRtrix3's `dw_scheme` holds them).
    pub fn world_bvecs(&self, world_from_voxel: glam::DMat4) -> Vec<DVec3> {
        let m = crate::sh::world_from_voxel_axes(world_from_voxel);
        self.bvecs.iter().map(|g| m * *g).collect()
    }

    /// Writes `bval` (one row) and `bvec` (3 rows) as FSL text for the image with `world_from_voxel`, the
    /// directions in `convention`'s frame (the inverse of [`GradientTable::from_fsl_for_image`]). Each file is
    /// written whole or not at all (`.part`, then renamed).
    pub fn write_fsl(
        &self,
        bval: impl AsRef<Path>,
        bvec: impl AsRef<Path>,
        world_from_voxel: glam::DMat4,
        convention: BvecConvention,
    ) -> Result<()> {
        let sign = if convention.flips_x(world_from_voxel) { -1.0 } else { 1.0 };
        let row = |f: &dyn Fn(usize) -> f64| (0..self.len()).map(|i| format!("{}", f(i))).collect::<Vec<_>>().join(" ");
        let bvals = row(&|i| self.bvals[i]) + "\n";
        let bvecs = [
            row(&|i| if self.bvecs[i].x == 0.0 { 0.0 } else { sign * self.bvecs[i].x }),
            row(&|i| self.bvecs[i].y),
            row(&|i| self.bvecs[i].z),
        ]
        .join("\n")
            + "\n";
        super::stream::write_whole(bval.as_ref(), bvals.as_bytes())?;
        super::stream::write_whole(bvec.as_ref(), bvecs.as_bytes())
    }

    /// Reads FSL text files in the files' own axes (DIPY's reading; [`GradientTable::from_fsl_for_image`] reads
    /// them in FSL's frame): `bval` is one row (or column) of N numbers; `bvec` is 3 rows of N (FSL) or N
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

    /// Number of volumes (b0s included).
    pub fn len(&self) -> usize {
        self.bvals.len()
    }
    /// Whether the table has no volumes (never, for a table built by [`GradientTable::new`]).
    pub fn is_empty(&self) -> bool {
        self.bvals.is_empty()
    }
    /// Whether volume `i` is a b0: its b-value is at most `b0_threshold`. Panics if `i >= len()`.
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

#[cfg(test)]
mod convention_tests {
    use super::*;
    use glam::{DMat4, DVec4};

    fn table() -> GradientTable {
        let dirs = [DVec3::ZERO, DVec3::new(0.6, 0.8, 0.0), DVec3::new(0.0, -0.6, 0.8), DVec3::new(-0.48, 0.6, 0.64)];
        GradientTable::new(vec![0.0, 1000.0, 1000.0, 2000.0], dirs.to_vec(), DEFAULT_B0_THRESHOLD).unwrap()
    }

    /// An oblique affine with a negative determinant, and the same image stored with x reversed (first column
    /// negated, origin moved to the last column): a positive determinant, the same voxels in world space.
    fn affines() -> (DMat4, DMat4) {
        let r = glam::DMat3::from_rotation_z(0.3) * glam::DMat3::from_rotation_x(-0.2);
        let a = DMat4::from_mat3(r * glam::DMat3::from_diagonal(DVec3::new(-2.0, 2.0, 2.5)));
        let a = DMat4::from_cols(a.x_axis, a.y_axis, a.z_axis, DVec4::new(10.0, -20.0, 5.0, 1.0));
        let nx = 9.0;
        let flipped = DMat4::from_cols(-a.x_axis, a.y_axis, a.z_axis, a.w_axis + nx * a.x_axis);
        (a, flipped)
    }

    #[test]
    fn fsl_frame_negates_x_on_positive_determinants_only() {
        let (neg, pos) = affines();
        assert!(glam::DMat3::from_mat4(neg).determinant() < 0.0 && glam::DMat3::from_mat4(pos).determinant() > 0.0);
        assert!(!BvecConvention::Fsl.flips_x(neg) && BvecConvention::Fsl.flips_x(pos));
        assert!(!BvecConvention::Dipy.flips_x(neg) && !BvecConvention::Dipy.flips_x(pos));
        assert_eq!("FSL".parse::<BvecConvention>().unwrap(), BvecConvention::Fsl);
        assert!("mrtrix".parse::<BvecConvention>().unwrap_err().to_string().contains("fsl or dipy"));
    }

    /// FSL's frame does not depend on how the image is stored: one bvec file read for an image and for its
    /// x-reversed copy gives the same directions in world space (DIPY's reading mirrors them).
    #[test]
    fn one_fsl_file_gives_the_same_world_directions_for_either_storage() {
        let (neg, pos) = affines();
        let tmp_dir = tempfile::Builder::new().prefix("fascicle_bvec-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let (bval, bvec) = (dir.join("g.bval"), dir.join("g.bvec"));
        table().write_fsl(&bval, &bvec, neg, BvecConvention::Fsl).unwrap();
        let read = |a, c| GradientTable::from_fsl_for_image(&bval, &bvec, a, c, 50.0).unwrap().world_bvecs(a);
        let expected = table().world_bvecs(neg);
        for (c, same) in [(BvecConvention::Fsl, true), (BvecConvention::Dipy, false)] {
            let (a, b) = (read(neg, c), read(pos, c));
            let worst = a.iter().zip(&b).map(|(u, v)| (*u - *v).length()).fold(0.0, f64::max);
            assert_eq!(worst < 1e-12, same, "{c:?}: worst {worst}");
            let worst = a.iter().zip(&expected).map(|(u, v)| (*u - *v).length()).fold(0.0, f64::max);
            assert!(worst < 1e-12, "{c:?}: the negative-determinant image reads as written ({worst})");
        }
        // Round trip in the positive-determinant frame: the file holds x negated, and reads back as written.
        table().write_fsl(&bval, &bvec, pos, BvecConvention::Fsl).unwrap();
        let raw = GradientTable::from_fsl(&bval, &bvec, 50.0).unwrap();
        assert_eq!(raw.bvecs[1], DVec3::new(-0.6, 0.8, 0.0));
        let back = GradientTable::from_fsl_for_image(&bval, &bvec, pos, BvecConvention::Fsl, 50.0).unwrap();
        assert_eq!(back.bvecs, table().bvecs);
        assert_eq!(back.bvals, table().bvals);
    }
}
