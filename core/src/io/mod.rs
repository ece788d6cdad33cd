//! File formats: NIfTI-1/2 images, FSL gradient tables, TrackVis `.trk` and MRtrix `.tck` tractograms.

pub mod gradients;
pub mod nifti;
pub mod tck;
pub mod tractogram;
pub mod trk;

pub use gradients::GradientTable;
pub use tractogram::Tractogram;
