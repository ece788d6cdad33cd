//! File formats: NIfTI-1/2 images, FSL gradient tables, peak images (MRtrix and DIPY layouts), TrackVis `.trk`, MRtrix `.tck` and TRX `.trx` tractograms, MRtrix `.tsf` track scalars, streamline weights.

pub mod classify;
pub mod gradients;
pub mod mapped;
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
pub use tractogram::{Csr, Streamlines, Tractogram};

use std::path::Path;

use crate::error::{Error, Result};
use tractogram::extension;

/// Reading by extension lives here, beside the formats it picks from: each format's reader builds a
/// [`Tractogram`], so the type's own module does not name them.
impl Tractogram {
    /// Reads `.trk`, `.tck` (or `.trk.gz` / `.tck.gz`) or `.trx` by extension.
    pub fn read(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        match extension(path).as_str() {
            "trk" => Ok(trk::read(path)?.0),
            "tck" => Ok(tck::read(path)?.0),
            "trx" => Ok(trx::read(path)?.0),
            other => Err(Error::format(
                path,
                format!("unknown tractogram extension '{other}' (expected .trk, .tck, .trx, or .gz)"),
            )),
        }
    }

    /// [`Tractogram::read`] from a file's bytes in memory; `path` (its extension) picks the format.
    pub fn read_bytes(bytes: &[u8], path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        match extension(path).as_str() {
            "trk" => Ok(trk::read_bytes(bytes, path)?.0),
            "tck" => Ok(tck::read_bytes(bytes, path)?.0),
            "trx" => Ok(trx::read_bytes(bytes, path)?.0),
            other => Err(Error::format(
                path,
                format!("unknown tractogram extension '{other}' (expected .trk, .tck, .trx, or .gz)"),
            )),
        }
    }
}
