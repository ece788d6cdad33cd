//! Peak images in the two layouts users have:
//! - **MRtrix** (`sh2peaks`, `fixel2peaks`; what mrview's fixel/peaks tool opens): one 4D image of `3N` volumes,
//!   peak `k` in volumes `3k..3k+3` as a vector whose length is its amplitude, in scanner (world) coordinates,
//!   NaN where a voxel has fewer peaks.
//! - **DIPY** (`peaks_from_model`, `dipy_fit_csa --out_peaks_*`): `PREFIX_dirs` (X,Y,Z,N,3) unit vectors in the
//!   voxel-array frame the gradients were given in, `PREFIX_values` (X,Y,Z,N), `PREFIX_indices` (X,Y,Z,N, -1 where
//!   absent), and `PREFIX_gfa` (X,Y,Z).
//!
//! Directions move between the frames through the image's linear part with its columns normalised (`M`):
//! `world = M voxel`. Reading either layout gives unit directions in the voxel frame, what the tracker uses.

use std::path::{Path, PathBuf};

use glam::{DMat3, DMat4, DVec3};

use super::nifti::{self, WriteType};
use crate::error::{Error, Result};
use crate::sh::PeakVolume;
use crate::volume::Volume;

/// Which file layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PeaksLayout {
    /// One image of `3N` volumes, amplitude-scaled vectors in world axes (FSL's `_V1` eigenvectors, in voxel
    /// axes, are reported as this layout too).
    Mrtrix,
    /// DIPY's `PREFIX_dirs` (X,Y,Z,N,3) unit vectors in voxel axes, amplitudes from `PREFIX_values`.
    Dipy,
}

/// Peaks read from a file: per voxel `npeaks` unit directions in the voxel frame (zero where absent) and
/// their amplitudes (0 where absent).
#[derive(Clone, Debug, PartialEq)]
pub struct PeakImage {
    /// Spatial size in voxels, `[nx, ny, nz]`.
    pub dims: [usize; 3],
    /// Peak slots per voxel (N).
    pub npeaks: usize,
    /// Unit directions in voxel axes, voxel-major: peak `p` of flat voxel `v` (x fastest) at `v * npeaks + p`.
    pub dirs: Vec<[f32; 3]>,
    /// Amplitude of each entry of `dirs`, same indexing: the MRtrix vector length, DIPY's `_values` (1 when
    /// absent), or the FA beside an FSL eigenvector (1 without).
    pub amplitudes: Vec<f32>,
    /// The image's voxel indices to world RAS+ mm.
    pub world_from_voxel: DMat4,
    /// The layout the file was read in.
    pub layout: PeaksLayout,
}

/// `M`: the affine's linear part with unit columns (rotation and reflection; scaling removed).
pub fn direction_frame(world_from_voxel: DMat4) -> DMat3 {
    let m = DMat3::from_mat4(world_from_voxel);
    DMat3::from_cols(m.x_axis.normalize_or_zero(), m.y_axis.normalize_or_zero(), m.z_axis.normalize_or_zero())
}

/// Writes the MRtrix layout (one image, `3 npeaks` volumes, amplitude-scaled, world frame, NaN where absent).
pub fn write_mrtrix(path: impl AsRef<Path>, peaks: &PeakVolume, world_from_voxel: DMat4) -> Result<()> {
    let [x, y, z] = peaks.dims;
    let n = x * y * z;
    let k = peaks.npeaks;
    let m = direction_frame(world_from_voxel);
    let mut vol = Volume::<f32>::zeros(&[x, y, z, 3 * k], world_from_voxel);
    for v in 0..n {
        for p in 0..k {
            let s = v * k + p;
            let w = if peaks.indices[s] >= 0 {
                (m * DVec3::from(peaks.dirs[s].map(f64::from))) * f64::from(peaks.values[s])
            } else {
                DVec3::NAN
            };
            for c in 0..3 {
                vol.data[v + n * (3 * p + c)] = w[c] as f32;
            }
        }
    }
    nifti::write(path, &vol, WriteType::F32)
}

/// Writes the DIPY layout: `PREFIX_dirs.nii.gz`, `_values`, `_indices`, `_gfa`. Returns the paths written.
pub fn write_dipy(prefix: impl AsRef<Path>, peaks: &PeakVolume, world_from_voxel: DMat4) -> Result<Vec<PathBuf>> {
    let prefix = prefix.as_ref().to_string_lossy().into_owned();
    let [x, y, z] = peaks.dims;
    let n = x * y * z;
    let k = peaks.npeaks;
    let mut dirs = Volume::<f32>::zeros(&[x, y, z, k, 3], world_from_voxel);
    let mut values = Volume::<f32>::zeros(&[x, y, z, k], world_from_voxel);
    let mut indices = Volume::<f32>::zeros(&[x, y, z, k], world_from_voxel);
    for v in 0..n {
        for p in 0..k {
            let s = v * k + p;
            for c in 0..3 {
                dirs.data[v + n * (p + k * c)] = peaks.dirs[s][c];
            }
            values.data[v + n * p] = peaks.values[s];
            indices.data[v + n * p] = peaks.indices[s] as f32;
        }
    }
    let gfa = Volume { shape: vec![x, y, z], data: peaks.gfa.clone(), world_from_voxel };
    let mut out = Vec::new();
    for (name, vol) in [("dirs", dirs), ("values", values), ("indices", indices), ("gfa", gfa)] {
        let path = PathBuf::from(format!("{prefix}_{name}.nii.gz"));
        nifti::write(&path, &vol, WriteType::F32)?;
        out.push(path);
    }
    Ok(out)
}

/// Whether an image of this shape and file name holds peaks: DIPY's (X,Y,Z,N,3) directions, or MRtrix's 3N
/// volumes in a file whose name says peaks (a 15-volume peaks image is otherwise indistinguishable from l_max 4
/// SH coefficients).
pub fn is_peaks_image(shape: &[usize], file_name: &str) -> bool {
    (shape.len() == 5 && shape[4] == 3)
        || (shape.len() == 4
            && shape[3] > 0
            && shape[3].is_multiple_of(3)
            && file_name.to_ascii_lowercase().contains("peak"))
}

/// Reads a peaks image, telling the layout by its shape: (X,Y,Z,3N) is MRtrix's, (X,Y,Z,N,3) DIPY's `_dirs`
/// (whose `_values` beside it, when present, give the amplitudes; else 1).
pub fn read(path: impl AsRef<Path>) -> Result<PeakImage> {
    let path = path.as_ref();
    let (vol, _) = nifti::read::<f32>(path)?;
    let dims = vol.dims3();
    let n = vol.n_voxels();
    let m_inv = direction_frame(vol.world_from_voxel).inverse();
    let shape = &vol.shape;
    let bad = || {
        Error::Shape(format!(
            "{}: a peaks image is (X,Y,Z,3N) as MRtrix writes it or (X,Y,Z,N,3) as DIPY does; this one is {shape:?}",
            path.display()
        ))
    };
    if shape.len() == 4 && shape[3] == 3 && fsl_eigenvector(path) {
        // FSL dtifit's eigenvector: in the b-vectors' axes (as Fascicle's and DIPY's fits give theirs), the
        // length from the FA beside it (PREFIX_FA), 1 without.
        let fa = beside_fa(path).and_then(|p| nifti::read::<f32>(p).ok()).map(|(v, _)| v).filter(|f| f.dims3() == dims);
        let (mut dirs, mut amplitudes) = (vec![[0.0f32; 3]; n], vec![0.0f32; n]);
        for v in 0..n {
            let d = DVec3::from(std::array::from_fn(|c| f64::from(vol.data[v + n * c])));
            let len = d.length();
            if len.is_finite() && len > 0.0 {
                let u = d / len;
                dirs[v] = [u.x as f32, u.y as f32, u.z as f32];
                amplitudes[v] = fa.as_ref().map_or(1.0, |f| f.data[v].max(0.0));
            }
        }
        return Ok(PeakImage {
            dims,
            npeaks: 1,
            dirs,
            amplitudes,
            world_from_voxel: vol.world_from_voxel,
            layout: PeaksLayout::Mrtrix,
        });
    }
    if shape.len() == 4 && shape[3] % 3 == 0 && shape[3] > 0 {
        let k = shape[3] / 3;
        let (mut dirs, mut amplitudes) = (vec![[0.0f32; 3]; n * k], vec![0.0f32; n * k]);
        for v in 0..n {
            for p in 0..k {
                let w = DVec3::from(std::array::from_fn(|c| f64::from(vol.data[v + n * (3 * p + c)])));
                let len = w.length();
                if len.is_finite() && len > 0.0 {
                    let d = (m_inv * w).normalize();
                    dirs[v * k + p] = [d.x as f32, d.y as f32, d.z as f32];
                    amplitudes[v * k + p] = len as f32;
                }
            }
        }
        return Ok(PeakImage {
            dims,
            npeaks: k,
            dirs,
            amplitudes,
            world_from_voxel: vol.world_from_voxel,
            layout: PeaksLayout::Mrtrix,
        });
    }
    if shape.len() == 5 && shape[4] == 3 && shape[3] > 0 {
        let k = shape[3];
        let values = dipy_values_beside(path, dims, k)?;
        let (mut dirs, mut amplitudes) = (vec![[0.0f32; 3]; n * k], vec![0.0f32; n * k]);
        for v in 0..n {
            for p in 0..k {
                let d = DVec3::from(std::array::from_fn(|c| f64::from(vol.data[v + n * (p + k * c)])));
                let len = d.length();
                if len.is_finite() && len > 0.0 {
                    let u = d / len;
                    dirs[v * k + p] = [u.x as f32, u.y as f32, u.z as f32];
                    amplitudes[v * k + p] = values.as_ref().map_or(1.0, |a| a[v * k + p]);
                }
            }
        }
        return Ok(PeakImage {
            dims,
            npeaks: k,
            dirs,
            amplitudes,
            world_from_voxel: vol.world_from_voxel,
            layout: PeaksLayout::Dipy,
        });
    }
    Err(bad())
}

/// Whether `path` is named as FSL dtifit names its eigenvectors: `PREFIX_V1.nii[.gz]` (or `_V2`, `_V3`).
pub fn fsl_eigenvector(path: &Path) -> bool {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let stem = name.strip_suffix(".gz").unwrap_or(&name);
    let stem = stem.strip_suffix(".nii").unwrap_or(stem);
    ["_V1", "_V2", "_V3"].iter().any(|s| stem.ends_with(s))
}

/// `PREFIX_FA.nii.gz` (or `.nii`) beside `PREFIX_V1.nii.gz`, if it exists.
fn beside_fa(v1: &Path) -> Option<std::path::PathBuf> {
    let name = v1.file_name()?.to_string_lossy().into_owned();
    let prefix = name.rsplit_once("_V")?.0.to_string();
    ["_FA.nii.gz", "_FA.nii"].iter().map(|e| v1.with_file_name(format!("{prefix}{e}"))).find(|p| p.is_file())
}

/// `PREFIX_values.nii.gz` beside `PREFIX_dirs.nii.gz`, voxel-major, if it exists and fits.
fn dipy_values_beside(dirs: &Path, dims: [usize; 3], k: usize) -> Result<Option<Vec<f32>>> {
    let name = dirs.to_string_lossy();
    let Some(stem) = name.strip_suffix(".nii.gz").or_else(|| name.strip_suffix(".nii")) else { return Ok(None) };
    let Some(prefix) = stem.strip_suffix("_dirs") else { return Ok(None) };
    let path = PathBuf::from(format!("{prefix}_values.nii.gz"));
    if !path.exists() {
        return Ok(None);
    }
    let (v, _) = nifti::read::<f32>(&path)?;
    if v.dims3() != dims || v.n_channels() != k {
        return Err(Error::Shape(format!(
            "{}: {:?} does not fit its directions' {dims:?} x {k}",
            path.display(),
            v.shape
        )));
    }
    let n = v.n_voxels();
    Ok(Some((0..n * k).map(|s| v.data[s / k + n * (s % k)]).collect()))
}
