//! `fascicle convert IN OUT`: images between NIfTI (`.nii`, `.nii.gz`) and MRtrix (`.mif`, `.mif.gz`), and
//! tractograms between `.trk` and `.tck` (either gzipped), chosen by the names. Values, affines and streamlines
//! are kept; the data are written as float32. SH bases are not converted (an SH image keeps its coefficients).

use std::path::Path;

use fascicle_core::Error;
use fascicle_core::io::{Tractogram, mif, nifti, tractogram};

fn is_image(path: &Path) -> bool {
    let n = path.to_string_lossy().to_ascii_lowercase();
    [".nii", ".nii.gz", ".mif", ".mif.gz"].iter().any(|e| n.ends_with(e))
}

fn is_tractogram(path: &Path) -> bool {
    matches!(tractogram::extension(path).as_str(), "trk" | "tck")
}

pub fn run(input: &Path, output: &Path) -> Result<(), Error> {
    super::check_output(output)?;
    if is_image(input) && is_image(output) {
        let vol = mif::read_image::<f32>(input)?;
        if mif::is_mif(output) {
            mif::write(output, &vol, &[])?;
        } else {
            // The header's codes, intent and description carry over from a NIfTI input.
            let meta = if mif::is_mif(input) {
                nifti::WriteMeta::default()
            } else {
                nifti::WriteMeta::from_header(&nifti::read_header(input)?)
            };
            nifti::write_with(output, &vol, nifti::WriteType::F32, &meta)?;
        }
    } else if is_tractogram(input) && is_tractogram(output) {
        let t = Tractogram::read(input)?;
        let header = match tractogram::extension(input).as_str() {
            "trk" => Some(fascicle_core::io::trk::read(input)?.1),
            _ => None,
        };
        super::select::write(output, &t, header.as_ref())?;
    } else {
        return Err(Error::Param(format!(
            "cannot convert {} to {}: both must be images (.nii, .nii.gz, .mif, .mif.gz) or both tractograms (.trk, .tck, gzipped)",
            input.display(),
            output.display()
        )));
    }
    if !super::globals().quiet {
        eprintln!("wrote {}", output.display());
    }
    Ok(())
}
