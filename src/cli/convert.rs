//! `fascicle convert IN OUT [--sh-basis B]`: images between NIfTI (`.nii`, `.nii.gz`) and MRtrix (`.mif`,
//! `.mif.gz`), and tractograms between `.trk` and `.tck` (either gzipped), chosen by the names. Values, affines
//! and streamlines are kept; the data are written as float32.
//!
//! An SH image is written in the basis asked (by default MRtrix3's into a `.mif`, else the input's; the input's
//! basis is the one it records, MRtrix3's for a `.mif`, DIPY's default otherwise). DIPY's coefficients refer to
//! the voxel axes and MRtrix3's to scanner axes: between the two families they are also turned through the
//! affine's rotation (and reflection), or ODFs would come out mirrored or tilted on flipped or oblique images.

use std::path::Path;

use fascicle_core::io::classify::{ImageKind, classify};
use fascicle_core::io::stream::{TractogramReader, TractogramWriter};
use fascicle_core::io::{mif, nifti, tractogram};
use fascicle_core::sh::{self, ShBasis};
use fascicle_core::{Error, Volume};

fn is_image(path: &Path) -> bool {
    let n = path.to_string_lossy().to_ascii_lowercase();
    [".nii", ".nii.gz", ".mif", ".mif.gz"].iter().any(|e| n.ends_with(e))
}

fn is_tractogram(path: &Path) -> bool {
    matches!(tractogram::extension(path).as_str(), "trk" | "tck" | "trx")
}

/// The bases an SH image goes between (None: not an SH image, nothing asked).
fn sh_bases(input: &Path, output: &Path, asked: Option<ShBasis>) -> Result<Option<(ShBasis, ShBasis)>, Error> {
    let c = classify(input)?;
    let recorded = match (&c.kind, c.ambiguous.iter().find(|k| matches!(k, ImageKind::Sh { .. }))) {
        (ImageKind::Sh { basis, .. }, _) => Some(*basis),
        // Content that could be SH or peaks: SH when a basis is asked for.
        (_, Some(ImageKind::Sh { basis, .. })) if asked.is_some() => Some(*basis),
        _ => None,
    };
    let Some(recorded) = recorded else {
        return match asked {
            Some(_) => Err(Error::Param(format!(
                "{}: --sh-basis given, but the image does not hold SH coefficients ({})",
                input.display(),
                c.reason
            ))),
            None => Ok(None),
        };
    };
    let mrtrix = ShBasis::Tournier07 { legacy: false };
    let from = recorded.unwrap_or(if mif::is_mif(input) { mrtrix } else { ShBasis::default() });
    let to = asked.unwrap_or(if mif::is_mif(output) { mrtrix } else { from });
    Ok(Some((from, to)))
}

/// Runs `fascicle convert`: `input` to `output`, images or tractograms by their names; an SH image into
/// `sh_basis` (None: MRtrix3's into a `.mif`, else the input's basis).
pub fn run(input: &Path, output: &Path, sh_basis: Option<ShBasis>) -> Result<(), Error> {
    super::check_output(output)?;
    if is_image(input) && is_image(output) {
        let mut vol: Volume<f32> = mif::read_image::<f32>(input)?;
        let bases = sh_bases(input, output, sh_basis)?;
        if let Some((from, to)) = bases {
            vol = sh::convert_image(&vol, from, to)?;
        }
        if mif::is_mif(output) {
            mif::write(output, &vol, &[])?;
        } else {
            // The header's codes, intent and description carry over from a NIfTI input; an SH image records
            // the basis it is written in.
            let mut meta = if mif::is_mif(input) {
                nifti::WriteMeta::default()
            } else {
                nifti::WriteMeta::from_header(&nifti::read_header(input)?)
            };
            if let Some((_, to)) = bases {
                meta.descrip = sh::sh_descrip(to, sh::l_max_for(vol.n_channels()).unwrap_or(0));
            }
            nifti::write_with(output, &vol, nifti::WriteType::F32, &meta)?;
        }
        if let Some((from, to)) = bases.filter(|_| !super::globals().quiet) {
            eprintln!("SH coefficients: {} -> {}", from.name(), to.name());
        }
    } else if is_tractogram(input) && is_tractogram(output) {
        if sh_basis.is_some() {
            return Err(Error::Param("--sh-basis applies to SH images, not tractograms".into()));
        }
        // Streamed chunk by chunk: memory stays bounded whatever the file's size.
        let reader = TractogramReader::open(input)?;
        let options = super::select::write_options(input, reader.header(), output, true)?;
        let mut writer = TractogramWriter::create(output, &options)?;
        super::select::pipe(reader, &mut writer, "convert", |_| Ok(None), &[], |_| Ok(()))?;
        writer.finish()?;
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
