//! `fascicle fit dti|csa|qball`: reads a DWI and its gradient table, fits every voxel in parallel, writes
//! NIfTI maps with the input's affine.

use std::path::{Path, PathBuf};

use clap::{Args, Subcommand};
use fascicle_core::dti::{self, FitMethod, metrics};
use fascicle_core::io::{BvecConvention, GradientTable, gradients::DEFAULT_B0_THRESHOLD, nifti};
use fascicle_core::sh::{self, OdfKind, OdfModel};
use fascicle_core::{Error, Volume};
use indicatif::{ProgressBar, ProgressStyle};

/// The DWI input of `fit`: the image, its gradient table (b-values, b-vectors and their frame), a mask and
/// the b0 threshold.
#[derive(Args, Debug)]
pub struct DwiArgs {
    /// 4D diffusion-weighted image (.nii/.nii.gz, or .mif/.mif.gz with its dw_scheme).
    pub dwi: PathBuf,
    /// FSL b-values (one row, or one per line); default: the .bval beside the image, or a .mif's dw_scheme.
    #[arg(long)]
    pub bval: Option<PathBuf>,
    /// FSL b-vectors (3 rows or 3 columns, in the frame --bvec-convention names); default: the .bvec beside the
    /// image, or a .mif's dw_scheme (turned from scanner into voxel axes).
    #[arg(long)]
    pub bvec: Option<PathBuf>,
    /// Frame of the .bvec file: `fsl` (FSL's definition, as FSL, MRtrix3's -fslgrad and dcm2niix use it: the
    /// image's voxel axes with x negated when the affine's determinant is positive) or `dipy` (the voxel axes as
    /// given, as DIPY reads them). The two differ only on images with a positive determinant.
    #[arg(long, default_value = "fsl")]
    pub bvec_convention: BvecConvention,
    /// 3D mask: voxels > 0 are fitted.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// b-values at or below this are b0s.
    #[arg(long, default_value_t = DEFAULT_B0_THRESHOLD)]
    pub b0_threshold: f64,
}

/// The models `fascicle fit` fits.
#[derive(Subcommand, Debug)]
pub enum FitCommand {
    /// Diffusion tensor: writes PREFIX_tensor, _evals, _evecs, _fa, _md, _ad, _rd, _rgb, _cl, _cp, _cs, _mode
    /// (.nii.gz); a PREFIX that is a directory (or ends in /) gets tensor.nii.gz, fa.nii.gz, ... inside it.
    Dti {
        /// The DWI, its gradients and mask.
        #[command(flatten)]
        input: DwiArgs,
        /// Estimator.
        #[arg(long, value_enum, default_value_t = super::FitMethodArg::Wls)]
        method: super::FitMethodArg,
        /// Output prefix (or directory).
        #[arg(long)]
        out: PathBuf,
    },
    /// Constant-solid-angle ODF (Aganj 2010) SH coefficients, as DIPY's CsaOdfModel.
    Csa(OdfArgs),
    /// Q-ball ODF (Descoteaux 2007) SH coefficients, as DIPY's QballModel.
    Qball(OdfArgs),
}

/// The options of `fit csa` and `fit qball`.
#[derive(Args, Debug)]
pub struct OdfArgs {
    /// The DWI, its gradients and mask.
    #[command(flatten)]
    pub input: DwiArgs,
    /// Maximum (even) SH order.
    #[arg(long)]
    pub lmax: usize,
    /// SH basis of the written coefficients.
    #[arg(long, value_enum, default_value_t = super::BasisArg::Descoteaux07)]
    pub basis: super::BasisArg,
    /// Legacy variant of the basis: `--legacy true` (the default: DIPY's default basis is descoteaux07 legacy)
    /// or `--legacy false` (DIPY's `legacy=False`; with `--basis tournier07`, MRtrix3's basis).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub legacy: bool,
    /// Laplace-Beltrami regularisation.
    #[arg(long, default_value_t = 0.006)]
    pub smooth: f64,
    /// Output coefficients, (X,Y,Z,n) .nii.gz.
    #[arg(long)]
    pub out: PathBuf,
}

pub(crate) struct Loaded {
    pub dwi: Volume<f32>,
    pub gtab: GradientTable,
    pub mask: Option<Vec<bool>>,
}

pub(crate) fn load(a: &DwiArgs) -> Result<Loaded, Error> {
    let dwi = fascicle_core::io::mif::read_image::<f32>(&a.dwi)?;
    if dwi.shape.len() != 4 {
        return Err(Error::Shape(format!("{}: a DWI must be 4D, this image is {:?}", a.dwi.display(), dwi.shape)));
    }
    let (gtab, source) = match (&a.bval, &a.bvec) {
        (Some(bval), Some(bvec)) => (
            GradientTable::from_fsl_for_image(bval, bvec, dwi.world_from_voxel, a.bvec_convention, a.b0_threshold)?,
            bval.display().to_string(),
        ),
        (None, None) => {
            let of_image = GradientTable::of_image(&a.dwi, dwi.world_from_voxel, a.bvec_convention, a.b0_threshold);
            let gtab = of_image.ok_or_else(|| {
                Error::Param(format!(
                    "{}: no gradients: give --bval and --bvec (or put them beside the image, or use a .mif with a dw_scheme)",
                    a.dwi.display()
                ))
            })??;
            (gtab, format!("the gradients of {}", a.dwi.display()))
        }
        _ => return Err(Error::Param("give both --bval and --bvec, or neither".into())),
    };
    if gtab.len() != dwi.shape[3] {
        return Err(Error::Shape(format!(
            "{source} has {} b-values but {} has {} volumes",
            gtab.len(),
            a.dwi.display(),
            dwi.shape[3]
        )));
    }
    let mask = match &a.mask {
        None => None,
        Some(p) => Some(read_mask(p, dwi.dims3())?),
    };
    Ok(Loaded { dwi, gtab, mask })
}

/// A 3D mask image on a given voxel grid: voxels > 0 are in.
pub(crate) fn read_mask(p: &Path, dims: [usize; 3]) -> Result<Vec<bool>, Error> {
    let (m, _) = nifti::read::<f32>(p)?;
    if m.dims3() != dims || m.n_channels() != 1 {
        return Err(Error::Shape(format!("mask {} is {:?}, the data's voxel grid is {dims:?}", p.display(), m.shape)));
    }
    Ok(m.data.iter().map(|&v| v > 0.0).collect())
}

/// A progress bar counting `unit`s (voxels, seeds).
pub(crate) fn progress_bar(n: usize, what: &str, unit: &str) -> ProgressBar {
    if super::globals().quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(n as u64);
    pb.set_style(
        ProgressStyle::with_template(&format!(
            "{{msg}} [{{bar:40}}] {{pos}}/{{len}} {unit} ({{per_sec}}, eta {{eta}})"
        ))
        .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb.set_message(what.to_string());
    pb
}

/// Runs `fascicle fit`: fits the chosen model to every voxel (in the mask) and writes its NIfTI maps and JSON
/// sidecar.
pub fn run(cmd: FitCommand) -> Result<(), Error> {
    match cmd {
        FitCommand::Dti { input, method, out } => fit_dti(&input, method.into(), &out),
        FitCommand::Csa(a) => fit_odf(&a, OdfKind::Csa),
        FitCommand::Qball(a) => fit_odf(&a, OdfKind::Qball),
    }
}

fn fit_dti(input: &DwiArgs, method: FitMethod, out: &Path) -> Result<(), Error> {
    let l = load(input)?;
    // A directory (existing, or named with a trailing /) takes plain names; anything else is a prefix.
    let as_dir = out.is_dir() || out.to_string_lossy().ends_with('/');
    let file = |name: &str| -> PathBuf {
        if as_dir { out.join(name) } else { PathBuf::from(format!("{}_{name}", out.display())) }
    };
    let names = ["tensor", "evals", "evecs", "fa", "md", "ad", "rd", "mode", "rgb", "cl", "cp", "cs"];
    for n in names {
        super::check_output(&file(&format!("{n}.nii.gz")))?;
    }
    super::check_output(&file("tensor.json"))?;
    let parent = if as_dir { out.to_path_buf() } else { out.parent().map(Path::to_path_buf).unwrap_or_default() };
    if !parent.as_os_str().is_empty() {
        std::fs::create_dir_all(&parent).map_err(|e| Error::Io { path: parent.clone(), source: e })?;
    }
    let pb = progress_bar(l.dwi.n_voxels(), "DTI", "voxels");
    let tv = dti::fit_volume_with_progress(&l.dwi, &l.gtab, method, l.mask.as_deref(), &|n| pb.inc(n as u64))?;
    pb.finish_and_clear();
    let (nonfinite, singular) = tv.failures();
    if nonfinite + singular > 0 {
        eprintln!("warning: {nonfinite} voxels with NaN/Inf signal and {singular} singular fits were written as 0");
    }
    let write = |name: &str, v: Volume<f32>| nifti::write(file(name), &v, nifti::WriteType::F32);
    write("tensor.nii.gz", tv.map_n(6, |t, o| o.copy_from_slice(&t.tensor())))?;
    write("evals.nii.gz", tv.map_n(3, |t, o| o.copy_from_slice(&t.eigen.values)))?;
    let mut evecs = tv.map_n(9, |t, o| {
        for j in 0..3 {
            for i in 0..3 {
                o[i + 3 * j] = t.eigen.vectors[j][i];
            }
        }
    });
    evecs.shape = vec![tv.dims[0], tv.dims[1], tv.dims[2], 3, 3];
    write("evecs.nii.gz", evecs)?;
    write("fa.nii.gz", tv.map(|t| metrics::fa(&t.eigen.values)))?;
    write("md.nii.gz", tv.map(|t| metrics::md(&t.eigen.values)))?;
    write("ad.nii.gz", tv.map(|t| metrics::ad(&t.eigen.values)))?;
    write("rd.nii.gz", tv.map(|t| metrics::rd(&t.eigen.values)))?;
    write("mode.nii.gz", tv.map(|t| metrics::mode(&t.eigen.values)))?;
    write(
        "rgb.nii.gz",
        tv.map_n(3, |t, o| o.copy_from_slice(&metrics::color_fa(&t.eigen.values, t.eigen.vectors[0]))),
    )?;
    let westin =
        |k: usize| move |t: &dti::TensorFit| metrics::westin(&t.eigen.values, metrics::WestinDenominator::Trace)[k];
    write("cl.nii.gz", tv.map(westin(0)))?;
    write("cp.nii.gz", tv.map(westin(1)))?;
    write("cs.nii.gz", tv.map(westin(2)))?;
    let json = serde_json::json!({
        "model": "dti",
        "method": format!("{method:?}").to_lowercase(),
        "tensor_order": "dipy",
        "gradients": gradient_record(input),
    });
    write_sidecar(&file("tensor.json"), &json)?;
    if !super::globals().quiet {
        eprintln!("wrote {} maps: {}", names.len(), file("{tensor,fa,...}.nii.gz").display());
    }
    Ok(())
}

fn fit_odf(a: &OdfArgs, kind: OdfKind) -> Result<(), Error> {
    let l = load(&a.input)?;
    let basis = a.basis.with_legacy(a.legacy);
    super::check_output(&a.out)?;
    super::check_output(&sidecar_path(&a.out))?;
    let model = OdfModel::new(&l.gtab, kind, a.lmax, a.smooth, basis)?;
    let pb = progress_bar(l.dwi.n_voxels(), if kind == OdfKind::Csa { "CSA" } else { "Q-ball" }, "voxels");
    let mut coeffs = sh::fit_odf_volume_with_progress(&l.dwi, &model, l.mask.as_deref(), &|n| pb.inc(n as u64))?;
    pb.finish_and_clear();
    // The fit follows the b-vectors, in voxel axes: MRtrix3's basis is written in scanner axes, as its own
    // programs write it.
    if basis.frame() == sh::Frame::World
        && let Some(t) = sh::frame::turning(basis, a.lmax, sh::world_from_voxel_axes(coeffs.world_from_voxel))?
    {
        sh::frame::reorient_volume(&mut coeffs, &t)?;
    }
    // The basis goes into the header (descrip), so that readers need not be told it.
    let meta = nifti::WriteMeta { descrip: sh_descrip(basis, a.lmax), ..Default::default() };
    nifti::write_with(&a.out, &coeffs, nifti::WriteType::F32, &meta)?;
    // And a JSON sidecar (as BIDS derivatives carry metadata), for tools that do not read `descrip`.
    let sidecar = sidecar_path(&a.out);
    let json = serde_json::json!({
        "model": if kind == OdfKind::Csa { "csa" } else { "qball" },
        "sh_basis": { "convention": basis.convention(), "legacy": basis.legacy() },
        "l_max": a.lmax,
        "smooth": a.smooth,
        "gradients": gradient_record(&a.input),
    });
    write_sidecar(&sidecar, &json)?;
    if !super::globals().quiet {
        eprintln!(
            "wrote {} ({} coefficients, {}) and {}",
            a.out.display(),
            sh::n_coeffs(a.lmax),
            basis.name(),
            sidecar.display()
        );
    }
    Ok(())
}

/// Where a fit's gradients came from and in which frame its `.bvec` was read, for its sidecar.
fn gradient_record(a: &DwiArgs) -> serde_json::Value {
    let bvec = a.bvec.clone().or_else(|| fascicle_core::io::classify::gradients_beside(&a.dwi).map(|(_, v)| v));
    match bvec {
        Some(bvec) => serde_json::json!({ "bvec": bvec, "bvec_convention": a.bvec_convention.name() }),
        None => serde_json::json!({ "dw_scheme": a.dwi }),
    }
}

fn write_sidecar(path: &Path, json: &serde_json::Value) -> Result<(), Error> {
    std::fs::write(path, serde_json::to_string_pretty(json).unwrap_or_default() + "\n")
        .map_err(|e| Error::Io { path: path.to_path_buf(), source: e })
}

/// `x.nii.gz` / `x.nii` -> `x.json`.
pub fn sidecar_path(out: &std::path::Path) -> std::path::PathBuf {
    let name = out.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let stem = name.strip_suffix(".nii.gz").or_else(|| name.strip_suffix(".nii")).unwrap_or(&name);
    out.with_file_name(format!("{stem}.json"))
}

pub use fascicle_core::sh::{recorded_basis as recorded_sh_basis, sh_descrip};
