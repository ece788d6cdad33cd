//! Fascicle's Bevy-free core: diffusion MRI file I/O and numerics.
//!
//! - [`io`]: NIfTI-1/2 images, FSL gradient tables, TrackVis `.trk` and MRtrix `.tck` tractograms.
//! - [`dti`]: OLS/WLS tensor fits as DIPY's `TensorModel`, a robust 3x3 eigen-solver, scalar maps.
//! - [`sh`]: real spherical harmonics in the four DIPY/MRtrix conventions, CSA and Q-ball ODF fits.
//!
//! Everything is checked against DIPY's own arrays (see `tests/`); nothing here panics on bad input.

#![warn(missing_docs)]

pub mod compress;
pub mod dti;
pub mod dvr;
pub mod error;
pub mod io;
pub mod linalg;
pub mod phantom;
pub mod roi;
pub mod roi_index;
pub mod sh;
pub mod tdi;
pub mod tracking;
pub mod tubelet;
pub mod volume;

pub use error::{Error, Result};
pub use volume::Volume;
