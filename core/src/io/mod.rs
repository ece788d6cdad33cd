//! File formats: NIfTI-1/2 images, FSL gradient tables, peak images (MRtrix and DIPY layouts), TrackVis `.trk`, MRtrix `.tck` and TRX `.trx` tractograms, MRtrix `.tsf` track scalars, streamline weights.

pub mod classify;
pub mod gradients;
pub mod mif;
pub mod nifti;
pub mod peaks;
pub mod stream;
pub mod tck;
pub mod tractogram;
pub mod trk;
pub mod trx;
pub mod tsf;
pub mod weights;

pub use gradients::{BvecConvention, GradientTable};
pub use tractogram::Tractogram;
