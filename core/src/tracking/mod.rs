//! Deterministic streamline tracking: a direction field ([`field`]), an integrator (Euler, RK2, RK4) at a
//! fixed step in mm, stops on FA, volume, mask, curvature and length, seeds from a mask or a file
//! ([`seeds`]). Parallel over seeds with an output order that does not depend on the thread count.
//!
//! Conventions (DIPY's): points are voxel coordinates while tracking (integer = voxel centre); directions
//! are unit vectors in the voxel-aligned mm frame (the frame the gradients, hence the tensors, are in), so a
//! step of `h` mm along `d` moves `h d / voxel_size` voxels, which handles anisotropic voxels; output points
//! go through the full affine (oblique included) to world RAS+ mm.
//!
//! ```no_run
//! use fascicle_core::{dti, io, tracking::{PeakField, TrackParams, Tracker, seeds_from_mask}};
//! # fn main() -> fascicle_core::Result<()> {
//! let (dwi, _) = io::nifti::read::<f32>("dwi.nii.gz")?;
//! let gtab = io::GradientTable::from_fsl_for_image("dwi.bval", "dwi.bvec", dwi.world_from_voxel, io::BvecConvention::Fsl, 50.0)?;
//! let fit = dti::fit_volume(&dwi, &gtab, dti::FitMethod::Wls, None)?;
//! let field = PeakField::from_fit(&fit, dwi.voxel_size())?;
//! let mask: Vec<bool> = (0..dwi.n_voxels()).map(|v| field.scalar_at(v) > 0.2).collect();
//! let tracks = Tracker::new(&field, dwi.world_from_voxel, TrackParams::default())?.run(&seeds_from_mask(&mask, fit.dims, 1)?);
//! # let _ = tracks;
//! # Ok(())
//! # }
//! ```

pub mod field;
pub mod seeds;
mod tracker;

pub use field::{
    CircleField, DirectionField, FieldSample, PeakField, TensorField, TensorInterpolation, principal_direction,
    trilinear,
};
pub use seeds::{read_seeds, seeds_from_mask, to_voxel};
pub use tracker::{Integrator, Rejection, StopReason, TrackParams, Tracker, Tracks, tensors_at};
