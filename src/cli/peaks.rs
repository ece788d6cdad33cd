//! `fascicle peaks`: ODF peaks of a DWI (CSA or Q-ball fitted here) or of an SH image, as DIPY's
//! `peaks_from_model` finds them, written in MRtrix's or DIPY's layout.

use std::path::PathBuf;

use clap::Args;
use fascicle_core::io::{nifti, peaks};
use fascicle_core::sh::{self, OdfKind, OdfModel, PeakParams, PeakVolume, ShBasis, ShGrid, Sphere};
use fascicle_core::{Error, Volume};
use glam::DMat4;

use super::fit::{DwiArgs, Loaded, load, progress_bar, read_mask};

/// The file layout of `fascicle peaks`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Layout {
    /// One image of 3N volumes, amplitude-scaled vectors in scanner coordinates, NaN where absent (sh2peaks);
    /// --out is the file.
    Mrtrix,
    /// PREFIX_dirs (X,Y,Z,N,3, voxel axes), PREFIX_values, PREFIX_indices, PREFIX_gfa (.nii.gz); --out is PREFIX.
    Dipy,
}

/// An ODF model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OdfArg {
    /// Constant solid angle (Aganj 2010), DIPY's CsaOdfModel.
    Csa,
    /// Q-ball (Descoteaux 2007), DIPY's QballModel.
    Qball,
}

/// How peaks are found on each voxel's ODF (DIPY's `peak_directions` parameters).
#[derive(Args, Debug, Clone, Copy)]
pub struct PeakArgs {
    /// Drop peaks below this fraction of the largest.
    #[arg(long, default_value_t = 0.5)]
    pub relative_peak_threshold: f64,
    /// Of two peaks closer than this (degrees), keep the larger.
    #[arg(long, default_value_t = 25.0)]
    pub min_separation_angle: f64,
    /// At most this many peaks per voxel.
    #[arg(long, default_value_t = 5)]
    pub npeaks: usize,
}

impl PeakArgs {
    /// These settings as the core's peak-finding parameters.
    pub fn params(&self) -> PeakParams {
        PeakParams {
            relative_peak_threshold: self.relative_peak_threshold,
            min_separation_angle: self.min_separation_angle,
            npeaks: self.npeaks,
        }
    }
}

/// The options of `fascicle peaks`.
#[derive(Args, Debug)]
pub struct PeaksArgs {
    /// 4D DWI to fit (gradients: --bval and --bvec, the files beside it, or a .mif's dw_scheme).
    #[arg(long, conflicts_with = "sh", required_unless_present = "sh")]
    pub dwi: Option<PathBuf>,
    /// FSL b-values of --dwi.
    #[arg(long, requires = "dwi")]
    pub bval: Option<PathBuf>,
    /// FSL b-vectors of --dwi.
    #[arg(long, requires = "dwi")]
    pub bvec: Option<PathBuf>,
    /// Frame of the .bvec file: `fsl` (FSL's definition: voxel axes, x negated when the affine's determinant
    /// is positive; as FSL, MRtrix3 and dcm2niix) or `dipy` (the voxel axes as given, as DIPY reads them).
    #[arg(long, requires = "dwi", default_value = "fsl")]
    pub bvec_convention: fascicle_core::io::BvecConvention,
    /// ODF model fitted to --dwi.
    #[arg(long, value_enum, default_value_t = OdfArg::Csa)]
    pub model: OdfArg,
    /// Maximum SH order of the fit.
    #[arg(long, default_value_t = 6)]
    pub lmax: usize,
    /// SH coefficients (X,Y,Z,n) instead of a DWI.
    #[arg(long)]
    pub sh: Option<PathBuf>,
    /// Basis of --sh (tournier07: MRtrix's, in scanner coordinates).
    #[arg(long, value_enum, default_value_t = super::BasisArg::Descoteaux07)]
    pub sh_basis: super::BasisArg,
    /// --sh is in the legacy variant of its basis (DIPY's default: descoteaux07 legacy).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub sh_legacy: bool,
    /// 3D mask: voxels > 0 get peaks.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Peak-finding settings.
    #[command(flatten)]
    pub peak: PeakArgs,
    /// Output layout.
    #[arg(long, value_enum, default_value_t = Layout::Mrtrix)]
    pub layout: Layout,
    /// Output file (mrtrix layout) or prefix (dipy layout).
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs `fascicle peaks`: finds the ODF peaks of --dwi or --sh and writes them in the chosen layout.
pub fn run(a: PeaksArgs) -> Result<(), Error> {
    let params = a.peak.params();
    params.validate()?;
    match a.layout {
        Layout::Mrtrix => super::check_output(&a.out)?,
        Layout::Dipy => {
            for n in ["dirs", "values", "indices", "gfa"] {
                super::check_output(&PathBuf::from(format!("{}_{n}.nii.gz", a.out.display())))?;
            }
        }
    }
    let (peaks, affine) = if let Some(path) = &a.sh {
        let (vol, _) = nifti::read::<f32>(path)?;
        let (coeffs, l_max) = sh_coefficients(&vol)?;
        let dims = vol.dims3();
        let mask = a.mask.as_deref().map(|m| read_mask(m, dims)).transpose()?;
        let basis = a.sh_basis.with_legacy(a.sh_legacy);
        let sh = ShGrid { dims, coeffs: &coeffs, l_max, basis };
        (odf_peaks(sh, vol.world_from_voxel, &params, mask.as_deref())?, vol.world_from_voxel)
    } else {
        let Some(dwi) = &a.dwi else {
            return Err(Error::Param(
                "give --dwi FILE (its gradients beside it, in a .mif, or --bval and --bvec), or --sh FILE".into(),
            ));
        };
        let kind = match a.model {
            OdfArg::Csa => OdfKind::Csa,
            OdfArg::Qball => OdfKind::Qball,
        };
        let l = load(&DwiArgs {
            dwi: dwi.clone(),
            bval: a.bval.clone(),
            bvec: a.bvec.clone(),
            bvec_convention: a.bvec_convention,
            mask: a.mask.clone(),
            b0_threshold: fascicle_core::io::gradients::DEFAULT_B0_THRESHOLD,
        })?;
        (dwi_odf_peaks(&l, kind, a.lmax, &params)?, l.dwi.world_from_voxel)
    };
    let n = peaks.gfa.len();
    let with = (0..n).filter(|&v| peaks.count(v) > 0).count();
    let total: usize = (0..n).map(|v| peaks.count(v)).sum();
    let quiet = super::globals().quiet;
    match a.layout {
        Layout::Mrtrix => {
            peaks::write_mrtrix(&a.out, &peaks, affine)?;
            if !quiet {
                eprintln!("wrote {} ({} peaks in {with} of {n} voxels, MRtrix layout)", a.out.display(), total);
            }
        }
        Layout::Dipy => {
            let files = peaks::write_dipy(&a.out, &peaks, affine)?;
            let names: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
            if !quiet {
                eprintln!("wrote {} ({total} peaks in {with} of {n} voxels, DIPY layout)", names.join(", "));
            }
        }
    }
    Ok(())
}

/// ODF peaks of voxel-major SH coefficients, with directions in the voxel frame. MRtrix's tournier07
/// coefficients are in scanner coordinates, so their peaks are rotated back through the image's frame.
pub(crate) fn odf_peaks(
    sh: ShGrid<'_>,
    world_from_voxel: DMat4,
    params: &PeakParams,
    mask: Option<&[bool]>,
) -> Result<PeakVolume, Error> {
    let pb = progress_bar(sh.dims.iter().product(), "peaks", "voxels");
    let mut peaks = sh::peaks_from_sh(sh, &Sphere::dipy_default(), params, mask, &|n| pb.inc(n as u64))?;
    pb.finish_and_clear();
    if matches!(sh.basis, ShBasis::Tournier07 { .. }) {
        let to_voxel = fascicle_core::io::peaks::direction_frame(world_from_voxel).inverse();
        for d in peaks.dirs.iter_mut().filter(|d| **d != [0.0; 3]) {
            let v = (to_voxel * glam::Vec3::from(*d).as_dvec3()).normalize();
            *d = [v.x as f32, v.y as f32, v.z as f32];
        }
    }
    Ok(peaks)
}

/// The CSA or Q-ball peaks of a loaded DWI (fitted in DIPY's default basis, in f64).
pub(crate) fn dwi_odf_peaks(l: &Loaded, kind: OdfKind, l_max: usize, params: &PeakParams) -> Result<PeakVolume, Error> {
    let basis = ShBasis::Descoteaux07 { legacy: true };
    let model = OdfModel::new(&l.gtab, kind, l_max, sh::fit::DEFAULT_SMOOTH, basis)?;
    let pb = progress_bar(l.dwi.n_voxels(), if kind == OdfKind::Csa { "CSA" } else { "Q-ball" }, "voxels");
    let coeffs = sh::fit_odf_coefficients(&l.dwi, &model, l.mask.as_deref(), &|n| pb.inc(n as u64))?;
    pb.finish_and_clear();
    let sh = ShGrid { dims: l.dwi.dims3(), coeffs: &coeffs, l_max, basis };
    odf_peaks(sh, l.dwi.world_from_voxel, params, l.mask.as_deref())
}

/// The SH coefficients of an image (X,Y,Z,n), voxel-major in f64.
pub(crate) fn sh_coefficients(vol: &Volume<f32>) -> Result<(Vec<f64>, usize), Error> {
    let n = vol.n_channels();
    let l_max = sh::l_max_for(n).filter(|_| vol.shape.len() == 4).ok_or_else(|| {
        Error::Shape(format!("an SH image is (X,Y,Z,n) with n = 6, 15, 28, 45, ...; this one is {:?}", vol.shape))
    })?;
    let nv = vol.n_voxels();
    Ok(((0..nv * n).map(|s| f64::from(vol.data[s / n + nv * (s % n)])).collect(), l_max))
}
