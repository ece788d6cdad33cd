//! `fascicle track`: deterministic FA-thresholded tracking from a DWI (fitted here with WLS) or a tensor
//! image, writing a tractogram in the input's space.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;
use fascicle_core::dti::{self, FitMethod};
use fascicle_core::io::{Tractogram, gradients::DEFAULT_B0_THRESHOLD, nifti, tck, tractogram::extension, trk};
use fascicle_core::tracking::{
    Integrator, TensorField, TensorInterpolation, TrackParams, Tracker, Tracks, read_seeds, seeds_from_mask, to_voxel,
};
use fascicle_core::{Error, Volume};
use glam::DMat4;

use super::fit::{DwiArgs, load, progress_bar, read_mask};

#[derive(Args, Debug)]
pub struct TrackArgs {
    /// 4D DWI to fit (WLS) and track; needs --bval and --bvec.
    #[arg(long, conflicts_with = "tensor", required_unless_present = "tensor")]
    pub dwi: Option<PathBuf>,
    #[arg(long, requires = "dwi")]
    pub bval: Option<PathBuf>,
    #[arg(long, requires = "dwi")]
    pub bvec: Option<PathBuf>,
    /// Tensor image (X,Y,Z,6 lower-triangular, as `fascicle fit dti` and DIPY write it).
    #[arg(long)]
    pub tensor: Option<PathBuf>,
    /// Tracking mask (3D, > 0 inside); with --dwi also the fit mask.
    #[arg(long)]
    pub mask: Option<PathBuf>,
    /// Seeds in world RAS mm: .npy (N x 3) or text (x y z per line).
    #[arg(long, conflicts_with = "seed_mask")]
    pub seeds: Option<PathBuf>,
    /// Seed in every voxel > 0 of this mask (default: every voxel with FA above the threshold).
    #[arg(long)]
    pub seed_mask: Option<PathBuf>,
    /// Seeds per voxel along each axis (N³ per voxel, DIPY's placement).
    #[arg(long, default_value_t = 1)]
    pub seed_density: usize,
    #[arg(long, default_value_t = 0.2)]
    pub fa_threshold: f64,
    #[arg(long, default_value_t = 0.5)]
    pub step_mm: f64,
    /// Largest turn per step, degrees.
    #[arg(long, default_value_t = 60.0)]
    pub max_angle: f64,
    #[arg(long, default_value = "rk4")]
    pub integrator: Integrator,
    #[arg(long, default_value = "componentwise")]
    pub interpolation: TensorInterpolation,
    #[arg(long, default_value_t = 0.0)]
    pub min_length_mm: f64,
    #[arg(long, default_value_t = 250.0)]
    pub max_length_mm: f64,
    /// Store the world-frame tensor at each point as six .trk scalars (Dxx Dxy Dyy Dxz Dyz Dzz, mm²/s).
    #[arg(long, default_value_t = false)]
    pub with_tensors: bool,
    /// Output tractogram (.trk or .tck).
    #[arg(long)]
    pub out: PathBuf,
}

/// A tensor field ready to track, on its voxel grid.
pub(crate) struct Prepared {
    pub field: TensorField,
    pub world_from_voxel: DMat4,
    pub dims: [usize; 3],
}

/// Fits a DWI (WLS) into a field.
pub(crate) fn field_from_dwi(
    dwi: &Volume<f32>,
    gtab: &fascicle_core::io::GradientTable,
    mask: Option<&[bool]>,
    interpolation: TensorInterpolation,
) -> Result<Prepared, Error> {
    let pb = progress_bar(dwi.n_voxels(), "DTI", "voxels");
    let fit = dti::fit_volume_with_progress(dwi, gtab, FitMethod::Wls, mask, &|n| pb.inc(n as u64))?;
    pb.finish_and_clear();
    let field = TensorField::from_fit(&fit, dwi.voxel_size(), interpolation)?;
    Ok(Prepared { field, world_from_voxel: dwi.world_from_voxel, dims: fit.dims })
}

fn prepare(a: &TrackArgs) -> Result<(Prepared, Option<Vec<bool>>), Error> {
    if let Some(t) = &a.tensor {
        let (vol, _) = nifti::read::<f64>(t)?;
        let field = TensorField::from_volume(&vol, a.interpolation)?;
        let dims = vol.dims3();
        let mask = a.mask.as_deref().map(|m| read_mask(m, dims)).transpose()?;
        return Ok((Prepared { field, world_from_voxel: vol.world_from_voxel, dims }, mask));
    }
    let (Some(dwi), Some(bval), Some(bvec)) = (&a.dwi, &a.bval, &a.bvec) else {
        return Err(Error::Param("give --tensor FILE, or --dwi FILE with --bval and --bvec".into()));
    };
    let args = DwiArgs {
        dwi: dwi.clone(),
        bval: bval.clone(),
        bvec: bvec.clone(),
        mask: a.mask.clone(),
        b0_threshold: DEFAULT_B0_THRESHOLD,
    };
    let l = load(&args)?;
    Ok((field_from_dwi(&l.dwi, &l.gtab, l.mask.as_deref(), a.interpolation)?, l.mask))
}

/// Every voxel whose FA is above `threshold`.
pub(crate) fn fa_seed_mask(field: &TensorField, dims: [usize; 3], threshold: f64) -> Vec<bool> {
    (0..dims.iter().product()).map(|v| field.fa_at(v) > threshold).collect()
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

pub fn run(a: TrackArgs) -> Result<(), Error> {
    let params = TrackParams {
        step_mm: a.step_mm,
        fa_threshold: a.fa_threshold,
        max_angle_deg: a.max_angle,
        integrator: a.integrator,
        min_length_mm: a.min_length_mm,
        max_length_mm: a.max_length_mm,
    };
    params.validate()?;
    if !matches!(extension(&a.out).as_str(), "trk" | "tck") {
        return Err(Error::Param(format!("output '{}' must end in .trk or .tck", a.out.display())));
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
    let mut tracker = Tracker::new(&p.field, p.world_from_voxel, params)?;
    if let Some(m) = &mask {
        tracker = tracker.with_mask(m)?;
    }
    let t1 = Instant::now();
    let pb = progress_bar(seeds.len(), "tracking", "seeds");
    let tracks = tracker.run_with_progress(&seeds, &|n| pb.inc(n as u64));
    pb.finish_and_clear();
    let t_track = t1.elapsed();
    write_tracks(&a.out, &tracks, p.world_from_voxel, p.dims, a.with_tensors)?;
    print_summary(&a.out, &tracks, seeds.len(), t_fit.as_secs_f64(), t_track.as_secs_f64(), t0.elapsed().as_secs_f64());
    Ok(())
}

fn print_summary(out: &Path, t: &Tracks, n_seeds: usize, fit_s: f64, track_s: f64, total_s: f64) {
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
