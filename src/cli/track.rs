//! `fascicle track`: deterministic tracking from a DWI (fitted here: tensors, or CSA/Q-ball ODF peaks), a tensor
//! image, SH coefficients or a peaks image, writing a tractogram in the input's space.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use fascicle_core::dti::{self, FitMethod};
use fascicle_core::io::{Tractogram, gradients::DEFAULT_B0_THRESHOLD, nifti, tck, tractogram::extension, trk};
use fascicle_core::sh::{OdfKind, PeakVolume, ShGrid};
use fascicle_core::tracking::{
    DirectionField, PeakField, TensorField, TensorInterpolation, TrackParams, Tracker, Tracks, read_seeds,
    seeds_from_mask, to_voxel,
};
use fascicle_core::volume::voxel_size;
use fascicle_core::{Error, Volume};
use glam::DMat4;

use super::fit::{DwiArgs, load, progress_bar, read_mask};
use super::peaks::{dwi_odf_peaks, odf_peaks, sh_coefficients};

/// The model a DWI is fitted with before tracking.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum TrackModel {
    /// Diffusion tensor (--fit-method), tracked along its principal eigenvector.
    Dti,
    /// Constant-solid-angle ODF (--lmax), tracked along its peaks; stops on GFA.
    Csa,
    /// Q-ball ODF (--lmax), tracked along its peaks; stops on GFA.
    Qball,
}

/// How the direction between voxel centres is formed from a tensor field.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FieldInterpolation {
    /// The principal eigenvectors of the 8 voxels around the point, sign-aligned and blended (DIPY's EuDX;
    /// eigen-decompositions once per voxel: the fast one).
    Peak,
    /// The six tensor components blended, then the principal eigenvector of the blend.
    Componentwise,
    /// The matrix logarithms blended (no swelling between differently oriented tensors).
    LogEuclidean,
}

/// The options of `fascicle track`.
#[derive(Args, Debug)]
pub struct TrackArgs {
    /// 4D DWI to fit and track (--model); gradients: --bval and --bvec, the files beside it, or a .mif's dw_scheme.
    #[arg(long, conflicts_with_all = ["tensor", "sh", "peaks"], required_unless_present_any = ["tensor", "sh", "peaks"])]
    pub dwi: Option<PathBuf>,
    /// FSL b-values of --dwi.
    #[arg(long, requires = "dwi")]
    pub bval: Option<PathBuf>,
    /// FSL b-vectors of --dwi (in the frame --bvec-convention names).
    #[arg(long, requires = "dwi")]
    pub bvec: Option<PathBuf>,
    /// Frame of the .bvec file: `fsl` (FSL's definition: voxel axes, x negated when the affine's determinant
    /// is positive; as FSL, MRtrix3 and dcm2niix) or `dipy` (the voxel axes as given, as DIPY reads them).
    #[arg(long, requires = "dwi", default_value = "fsl")]
    pub bvec_convention: fascicle_core::io::BvecConvention,
    /// Model fitted to --dwi.
    #[arg(long, value_enum, default_value_t = TrackModel::Dti)]
    pub model: TrackModel,
    /// Tensor estimator for --model dti.
    #[arg(long, value_enum, default_value_t = super::FitMethodArg::Wls)]
    pub fit_method: super::FitMethodArg,
    /// Maximum SH order for --model csa|qball.
    #[arg(long, default_value_t = 6)]
    pub lmax: usize,
    /// Tensor image (X,Y,Z,6 lower-triangular, as `fascicle fit dti` and DIPY write it): tracked without fitting.
    #[arg(long, conflicts_with_all = ["sh", "peaks"])]
    pub tensor: Option<PathBuf>,
    /// SH coefficients (X,Y,Z,n, as `fascicle fit csa` writes them): peaks extracted, then tracked.
    #[arg(long, conflicts_with = "peaks")]
    pub sh: Option<PathBuf>,
    /// Basis of --sh (tournier07: MRtrix's, its coefficients in scanner coordinates).
    #[arg(long, value_enum, default_value_t = super::BasisArg::Descoteaux07)]
    pub sh_basis: super::BasisArg,
    /// --sh is in the legacy variant of its basis (DIPY's default: descoteaux07 legacy).
    #[arg(long, default_value_t = true, action = clap::ArgAction::Set)]
    pub sh_legacy: bool,
    /// Peaks image (MRtrix (X,Y,Z,3N) or DIPY (X,Y,Z,N,3) layout): tracked as is; needs --stop-map.
    #[arg(long, requires = "stop_map")]
    pub peaks: Option<PathBuf>,
    /// Scalar image whose value stops tracks below --fa-threshold (with --peaks; e.g. an FA or GFA map).
    #[arg(long)]
    pub stop_map: Option<PathBuf>,
    /// Tracking mask (3D, > 0 inside); with --dwi also the fit mask.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Seeds in world RAS mm: .npy (N x 3) or text (x y z per line).
    #[arg(long, conflicts_with = "seed_mask")]
    pub seeds: Option<PathBuf>,
    /// Seed in every voxel > 0 of this mask (default: every voxel whose stopping value is above the threshold).
    #[arg(long)]
    pub seed_mask: Option<PathBuf>,
    /// Seeds per voxel along each axis (N³ per voxel, DIPY's placement).
    #[arg(long, default_value_t = 1)]
    pub seed_density: usize,
    /// Tracks continue while the interpolated FA (GFA for ODF models, the --stop-map value for --peaks) is above this.
    #[arg(long, default_value_t = 0.2)]
    pub fa_threshold: f64,
    /// Step length in mm.
    #[arg(long, default_value_t = 0.5)]
    pub step_mm: f64,
    /// Largest turn per step, degrees; also the largest angle between the incoming direction and a voxel's peak
    /// for that voxel to count in the blend.
    #[arg(long, default_value_t = 60.0)]
    pub max_angle: f64,
    /// Integration scheme.
    #[arg(long, value_enum, default_value_t = super::IntegratorArg::Rk4)]
    pub integrator: super::IntegratorArg,
    /// Direction interpolation of a tensor field.
    #[arg(long, value_enum, default_value_t = FieldInterpolation::Peak)]
    pub interpolation: FieldInterpolation,
    /// ODF peaks (with --model csa|qball or --sh).
    #[command(flatten)]
    pub peak: super::peaks::PeakArgs,
    /// ODF peaks with a value at or below this are not followed (DIPY's EuDX default).
    #[arg(long, default_value_t = 0.0239)]
    pub min_peak_value: f32,
    /// Streamlines shorter than this (mm) are dropped.
    #[arg(long, default_value_t = 0.0)]
    pub min_length_mm: f64,
    /// Streamlines end at this length (mm; each half at most half of it).
    #[arg(long, default_value_t = 250.0)]
    pub max_length_mm: f64,
    /// Store the world-frame tensor at each point as six .trk scalars (Dxx Dxy Dyy Dxz Dyz Dzz, mm²/s).
    #[arg(long, default_value_t = false)]
    pub with_tensors: bool,
    /// Output tractogram (.trk or .tck).
    #[arg(long)]
    pub out: PathBuf,
}

/// A direction field ready to track, on its voxel grid.
pub(crate) enum Field {
    Tensor(TensorField),
    Peaks(PeakField),
}

impl Field {
    /// The stopping value at voxel centre `v`.
    pub fn scalar_at(&self, v: usize) -> f64 {
        match self {
            Field::Tensor(f) => f.fa_at(v),
            Field::Peaks(f) => f.scalar_at(v),
        }
    }
}

pub(crate) struct Prepared {
    pub field: Field,
    pub world_from_voxel: DMat4,
    pub dims: [usize; 3],
}

/// The chosen field of a tensor source: the peak field, or the tensor field with its interpolation.
fn tensor_field(
    interp: FieldInterpolation,
    max_angle: f64,
    peaks: impl FnOnce() -> fascicle_core::Result<PeakField>,
    tensors: impl FnOnce(TensorInterpolation) -> fascicle_core::Result<TensorField>,
) -> Result<Field, Error> {
    Ok(match interp {
        FieldInterpolation::Peak => Field::Peaks(peaks()?.with_max_angle(max_angle)),
        FieldInterpolation::Componentwise => Field::Tensor(tensors(TensorInterpolation::Componentwise)?),
        FieldInterpolation::LogEuclidean => Field::Tensor(tensors(TensorInterpolation::LogEuclidean)?),
    })
}

/// Fits a DWI with the tensor model into a field.
pub(crate) fn field_from_dwi(
    dwi: &Volume<f32>,
    gtab: &fascicle_core::io::GradientTable,
    method: FitMethod,
    mask: Option<&[bool]>,
    interp: FieldInterpolation,
    max_angle: f64,
) -> Result<Prepared, Error> {
    let pb = progress_bar(dwi.n_voxels(), "DTI", "voxels");
    let fit = dti::fit_volume_with_progress(dwi, gtab, method, mask, &|n| pb.inc(n as u64))?;
    pb.finish_and_clear();
    let vs = dwi.voxel_size();
    let field =
        tensor_field(interp, max_angle, || PeakField::from_fit(&fit, vs), |i| TensorField::from_fit(&fit, vs, i))?;
    Ok(Prepared { field, world_from_voxel: dwi.world_from_voxel, dims: fit.dims })
}

/// ODF peaks as a field: GFA stops, peaks at or below --min-peak-value left out, gated at --max-angle.
fn odf_peak_field(peaks: &PeakVolume, voxel_size: glam::DVec3, a: &TrackArgs) -> Result<Field, Error> {
    let field = PeakField::from_peaks(peaks, voxel_size, &peaks.gfa, a.min_peak_value)?;
    Ok(Field::Peaks(field.with_max_angle(a.max_angle)))
}

fn prepare(a: &TrackArgs) -> Result<(Prepared, Option<Vec<bool>>), Error> {
    let params = a.peak.params();
    if let Some(t) = &a.tensor {
        let (vol, _) = nifti::read::<f64>(t)?;
        let field = tensor_field(
            a.interpolation,
            a.max_angle,
            || PeakField::from_tensor_volume(&vol),
            |i| TensorField::from_volume(&vol, i),
        )?;
        let dims = vol.dims3();
        let mask = a.mask.as_deref().map(|m| read_mask(m, dims)).transpose()?;
        return Ok((Prepared { field, world_from_voxel: vol.world_from_voxel, dims }, mask));
    }
    if let Some(path) = &a.sh {
        let (vol, _) = nifti::read::<f32>(path)?;
        let (coeffs, l_max) = sh_coefficients(&vol)?;
        let dims = vol.dims3();
        let mask = a.mask.as_deref().map(|m| read_mask(m, dims)).transpose()?;
        let basis = a.sh_basis.with_legacy(a.sh_legacy);
        let sh = ShGrid { dims, coeffs: &coeffs, l_max, basis };
        let peaks = odf_peaks(sh, vol.world_from_voxel, &params, mask.as_deref())?;
        let field = odf_peak_field(&peaks, vol.voxel_size(), a)?;
        return Ok((Prepared { field, world_from_voxel: vol.world_from_voxel, dims }, mask));
    }
    if let Some(path) = &a.peaks {
        let img = fascicle_core::io::peaks::read(path)?;
        let stop = a.stop_map.as_deref().ok_or_else(|| Error::Param("--peaks needs --stop-map".into()))?;
        let (s, _) = nifti::read::<f32>(stop)?;
        if s.dims3() != img.dims || s.n_channels() != 1 {
            return Err(Error::Shape(format!(
                "stop map {} is {:?}, the peaks' grid is {:?}",
                stop.display(),
                s.shape,
                img.dims
            )));
        }
        let dirs: Vec<[f32; 3]> = img
            .dirs
            .iter()
            .zip(&img.amplitudes)
            .map(|(d, &amp)| if amp > a.min_peak_value { *d } else { [0.0; 3] })
            .collect();
        let field = PeakField::new(img.dims, voxel_size(img.world_from_voxel), img.npeaks, &dirs, &s.data)?
            .with_max_angle(a.max_angle);
        let mask = a.mask.as_deref().map(|m| read_mask(m, img.dims)).transpose()?;
        return Ok((
            Prepared { field: Field::Peaks(field), world_from_voxel: img.world_from_voxel, dims: img.dims },
            mask,
        ));
    }
    let Some(dwi) = &a.dwi else {
        return Err(Error::Param("give --dwi FILE (its gradients beside it, in a .mif, or --bval and --bvec), or --tensor, --sh or --peaks FILE".into()));
    };
    let args = DwiArgs {
        dwi: dwi.clone(),
        bval: a.bval.clone(),
        bvec: a.bvec.clone(),
        bvec_convention: a.bvec_convention,
        mask: a.mask.clone(),
        b0_threshold: DEFAULT_B0_THRESHOLD,
    };
    let l = load(&args)?;
    let prepared = match a.model {
        TrackModel::Dti => {
            field_from_dwi(&l.dwi, &l.gtab, a.fit_method.into(), l.mask.as_deref(), a.interpolation, a.max_angle)?
        }
        TrackModel::Csa | TrackModel::Qball => {
            let kind = if a.model == TrackModel::Csa { OdfKind::Csa } else { OdfKind::Qball };
            let peaks = dwi_odf_peaks(&l, kind, a.lmax, &params)?;
            let field = odf_peak_field(&peaks, l.dwi.voxel_size(), a)?;
            Prepared { field, world_from_voxel: l.dwi.world_from_voxel, dims: l.dwi.dims3() }
        }
    };
    Ok((prepared, l.mask))
}

/// Every voxel whose stopping value is above `threshold`.
pub(crate) fn fa_seed_mask(field: &Field, dims: [usize; 3], threshold: f64) -> Vec<bool> {
    (0..dims.iter().product()).map(|v| field.scalar_at(v) > threshold).collect()
}

/// Tracks `seeds` (voxel coordinates) through whichever field was prepared.
pub(crate) fn track(
    p: &Prepared,
    params: TrackParams,
    mask: Option<&[bool]>,
    seeds: &[glam::DVec3],
    with_tensors: bool,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Tracks, Error> {
    fn go<F: DirectionField>(
        f: &F,
        p: &Prepared,
        params: TrackParams,
        mask: Option<&[bool]>,
        seeds: &[glam::DVec3],
        with_tensors: bool,
        progress: &(dyn Fn(usize) + Sync),
    ) -> Result<Tracks, Error> {
        let mut t = Tracker::new(f, p.world_from_voxel, params)?.with_tensors(with_tensors);
        if let Some(m) = mask {
            t = t.with_mask(m)?;
        }
        Ok(t.run_with_progress(seeds, progress))
    }
    match &p.field {
        Field::Tensor(f) => go(f, p, params, mask, seeds, with_tensors, progress),
        Field::Peaks(f) => go(f, p, params, mask, seeds, with_tensors, progress),
    }
}

/// Writes `.trk` (optionally with per-point tensors as scalars) or `.tck`.
pub(crate) fn write_tracks(
    path: &Path,
    tracks: &Tracks,
    world_from_voxel: DMat4,
    dims: [usize; 3],
    with_tensors: bool,
) -> Result<(), Error> {
    match extension(path).as_str() {
        "trk" if with_tensors => {
            let mut t: Tractogram = tracks.tractogram.clone();
            for (k, name) in ["Dxx", "Dxy", "Dyy", "Dxz", "Dyz", "Dzz"].iter().enumerate() {
                t.scalars.push((name.to_string(), tracks.tensors.iter().map(|d| d[k]).collect()));
            }
            trk::write(path, &t, world_from_voxel, dims)
        }
        "trk" => trk::write(path, &tracks.tractogram, world_from_voxel, dims),
        "tck" if with_tensors => {
            Err(Error::Param("--with-tensors needs a .trk output (.tck has no per-point values)".into()))
        }
        "tck" => tck::write(path, &tracks.tractogram, &[]),
        other => {
            Err(Error::Param(format!("output '{}': unknown extension '{other}' (use .trk or .tck)", path.display())))
        }
    }
}

/// Runs `fascicle track`: prepares the direction field, seeds, tracks and writes the tractogram, with a summary
/// on stderr.
pub fn run(a: TrackArgs) -> Result<(), Error> {
    let params = TrackParams {
        step_mm: a.step_mm,
        fa_threshold: a.fa_threshold,
        max_angle_deg: a.max_angle,
        integrator: a.integrator.into(),
        min_length_mm: a.min_length_mm,
        max_length_mm: a.max_length_mm,
    };
    params.validate()?;
    a.peak.params().validate()?;
    if !matches!(extension(&a.out).as_str(), "trk" | "tck") {
        return Err(Error::Param(format!("output '{}' must end in .trk or .tck", a.out.display())));
    }
    super::check_output(&a.out)?;
    if a.with_tensors && (a.sh.is_some() || a.peaks.is_some() || (a.tensor.is_none() && a.model != TrackModel::Dti)) {
        return Err(Error::Param("--with-tensors needs a tensor model (--model dti or --tensor)".into()));
    }
    let t0 = Instant::now();
    let (p, mask) = prepare(&a)?;
    let t_fit = t0.elapsed();
    let seeds = match (&a.seeds, &a.seed_mask) {
        (Some(f), _) => to_voxel(p.world_from_voxel, &read_seeds(f)?),
        (None, Some(m)) => seeds_from_mask(&read_mask(m, p.dims)?, p.dims, a.seed_density)?,
        (None, None) => seeds_from_mask(&fa_seed_mask(&p.field, p.dims, a.fa_threshold), p.dims, a.seed_density)?,
    };
    if seeds.is_empty() {
        eprintln!(
            "warning: no seeds (empty seed mask, or no voxel above FA {}); writing an empty tractogram",
            a.fa_threshold
        );
    }
    let t1 = Instant::now();
    let pb = progress_bar(seeds.len(), "tracking", "seeds");
    let tracks = track(&p, params, mask.as_deref(), &seeds, a.with_tensors, &|n| pb.inc(n as u64))?;
    pb.finish_and_clear();
    let t_track = t1.elapsed();
    write_tracks(&a.out, &tracks, p.world_from_voxel, p.dims, a.with_tensors)?;
    print_summary(&a.out, &tracks, seeds.len(), t_fit.as_secs_f64(), t_track.as_secs_f64(), t0.elapsed().as_secs_f64());
    Ok(())
}

fn print_summary(out: &Path, t: &Tracks, n_seeds: usize, fit_s: f64, track_s: f64, total_s: f64) {
    if super::globals().quiet {
        return;
    }
    eprintln!(
        "wrote {}: {} streamlines, {} points from {n_seeds} seeds",
        out.display(),
        t.tractogram.n_streamlines(),
        t.n_points()
    );
    for (r, n) in t.stop_counts() {
        eprintln!("  {n:>8} ends: {}", r.name());
    }
    for (r, n) in t.rejection_counts() {
        eprintln!("  {n:>8} seeds gave none: {r:?}");
    }
    eprintln!(
        "  time: load+fit {fit_s:.2} s, tracking {track_s:.2} s ({:.2} M points/s), total {total_s:.2} s",
        t.n_points() as f64 / track_s.max(1e-9) / 1e6
    );
}
