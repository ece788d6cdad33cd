//! Diffusion tensor imaging: log-linear fits, the eigen-system, and the scalar maps.

pub mod barycentric;
pub mod eigen;
pub mod fit;
pub mod glyph;
pub mod metrics;
pub mod splat;

use glam::DVec3;
use rayon::prelude::*;

pub use eigen::{Eigen, LowerTri, eigh};
pub use fit::{FitFailure, FitMethod, TensorFit, TensorModel};

use crate::error::{Error, Result};
use crate::io::GradientTable;
use crate::volume::{PROGRESS_BLOCK, Scalar, Volume};

/// A fitted tensor field: one entry per spatial voxel, in the DWI's voxel order and grid.
#[derive(Clone, Debug)]
pub struct TensorVolume {
    /// Grid size in voxels (x, y, z); `voxels` is indexed x fastest.
    pub dims: [usize; 3],
    /// Voxel indices (integer = voxel centre) to world RAS+ mm, the DWI's affine.
    pub world_from_voxel: glam::DMat4,
    /// `None` outside the mask; `Some(Err(..))` where the fit failed (NaN signal, singular system).
    pub voxels: Vec<Option<Result<TensorFit, FitFailure>>>,
}

impl TensorVolume {
    /// The fit at a voxel if it is inside the mask and succeeded.
    pub fn fit_at(&self, v: usize) -> Option<&TensorFit> {
        self.voxels[v].as_ref().and_then(|r| r.as_ref().ok())
    }
    /// Number of voxels whose fit failed, by reason.
    pub fn failures(&self) -> (usize, usize) {
        let count = |f: FitFailure| self.voxels.iter().filter(|v| matches!(v, Some(Err(e)) if *e == f)).count();
        (count(FitFailure::NonFiniteSignal), count(FitFailure::Singular))
    }

    /// A map of one value per voxel (0 outside the mask and where the fit failed, as DIPY stores NaN).
    pub fn map(&self, f: impl Fn(&TensorFit) -> f64 + Sync) -> Volume<f32> {
        self.map_n(1, |t, out| out[0] = f(t))
    }

    /// A map of `k` values per voxel (shape X,Y,Z,k).
    pub fn map_n(&self, k: usize, f: impl Fn(&TensorFit, &mut [f64]) + Sync) -> Volume<f32> {
        let n = self.voxels.len();
        let mut vol = Volume::<f32>::zeros(&[self.dims[0], self.dims[1], self.dims[2], k], self.world_from_voxel);
        if k == 1 {
            vol.shape.truncate(3);
        }
        let mut buf = vec![0.0f64; k];
        for v in 0..n {
            if let Some(t) = self.fit_at(v) {
                buf.iter_mut().for_each(|b| *b = 0.0);
                f(t, &mut buf);
                for (c, val) in buf.iter().enumerate() {
                    vol.data[v + n * c] = if val.is_finite() { *val as f32 } else { 0.0 };
                }
            }
        }
        vol
    }
}

/// Fits every voxel of a 4D DWI (X,Y,Z,N) in parallel. `mask`, if given, has one entry per voxel.
pub fn fit_volume<T: Scalar>(
    dwi: &Volume<T>,
    gtab: &GradientTable,
    method: FitMethod,
    mask: Option<&[bool]>,
) -> Result<TensorVolume> {
    fit_volume_with_progress(dwi, gtab, method, mask, &|_| {})
}

/// [`fit_volume`], calling `progress(n)` from worker threads as each block of `n` voxels is done.
pub fn fit_volume_with_progress<T: Scalar>(
    dwi: &Volume<T>,
    gtab: &GradientTable,
    method: FitMethod,
    mask: Option<&[bool]>,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<TensorVolume> {
    if dwi.shape.len() != 4 {
        return Err(Error::Shape(format!("a DWI must be 4D (X,Y,Z,N); this image is {:?}", dwi.shape)));
    }
    gtab.check_volumes(dwi.shape[3])?;
    let nvox = dwi.n_voxels();
    if let Some(m) = mask
        && m.len() != nvox
    {
        return Err(Error::Shape(format!("the mask has {} voxels, the DWI {nvox}", m.len())));
    }
    let model = TensorModel::new(gtab, method)?;
    let nvol = model.n_volumes();
    let mut voxels = vec![None; nvox];
    voxels.par_chunks_mut(PROGRESS_BLOCK).enumerate().for_each_init(
        || (vec![0.0f64; nvol], vec![0.0f64; nvol]),
        |(sig, scratch), (block, outs)| {
            for (k, out) in outs.iter_mut().enumerate() {
                let v = block * PROGRESS_BLOCK + k;
                if mask.is_some_and(|m| !m[v]) {
                    continue;
                }
                dwi.voxel_signal(v, sig);
                *out = Some(model.fit_voxel(sig, scratch));
            }
            progress(outs.len());
        },
    );
    Ok(TensorVolume { dims: dwi.dims3(), world_from_voxel: dwi.world_from_voxel, voxels })
}

/// The principal eigenvector (unit, voxel axes) of a fit.
pub fn principal_direction(t: &TensorFit) -> DVec3 {
    t.eigen.vectors[0]
}
