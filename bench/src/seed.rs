//! The repository's ring/cross phantom DWI (`data/phantom`, 48x48x24 x 65 volumes, b = 1000) and seed 000's
//! DWI input made from it: "5 central slices" of a diffusion-weighted acquisition, 48x48x5 x 65.

use std::path::Path;

use fascicle_core::Volume;
use fascicle_core::io::{GradientTable, gradients::DEFAULT_B0_THRESHOLD, nifti};

/// The phantom DWI and its gradient table, from `data/phantom` under the working directory (a binary carried to
/// another machine and run in a checkout there), else from the checkout this binary was built in.
pub fn phantom_dwi() -> fascicle_core::Result<(Volume<f32>, GradientTable)> {
    let here = Path::new("data/phantom");
    let dir = if here.join("phantom_ring_cross.nii.gz").is_file() {
        here.to_path_buf()
    } else {
        Path::new(&std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
            .join("../data/phantom")
    };
    let (dwi, _) = nifti::read::<f32>(dir.join("phantom_ring_cross.nii.gz"))?;
    let gtab = GradientTable::from_fsl(
        dir.join("phantom_ring_cross.bval"),
        dir.join("phantom_ring_cross.bvec"),
        DEFAULT_B0_THRESHOLD,
    )?;
    Ok((dwi, gtab))
}

/// The 5 central axial slices of the phantom DWI and its gradient table.
pub fn five_slice_dwi() -> fascicle_core::Result<(Volume<f32>, GradientTable)> {
    let (dwi, gtab) = phantom_dwi()?;
    let z = dwi.dims3()[2];
    Ok((dwi.z_slab(z.saturating_sub(5) / 2, 5), gtab))
}
