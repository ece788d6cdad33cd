//! The whole tracking process on the phantom, stage by stage (read, fit, seed, track, write), for profiling:
//! `cargo run --release -p fascicle-core --example track_phantom -- [euler|rk4] [threads]`.

use std::time::Instant;

use fascicle_core::dti::{self, FitMethod};
use fascicle_core::io::{GradientTable, gradients::DEFAULT_B0_THRESHOLD, nifti, trk};
use fascicle_core::tracking::{
    Integrator, PeakField, TensorField, TensorInterpolation, TrackParams, Tracker, seeds_from_mask,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let integrator: Integrator = args.get(1).map_or("rk4", |s| s.as_str()).parse()?;
    let threads: usize = args.get(2).map_or(Ok(0), |s| s.parse())?;
    rayon::ThreadPoolBuilder::new().num_threads(threads).build_global()?;
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/phantom");
    let t0 = Instant::now();
    let (dwi, _) = nifti::read::<f32>(dir.join("phantom_ring_cross.nii.gz"))?;
    let gtab = GradientTable::from_fsl(
        dir.join("phantom_ring_cross.bval"),
        dir.join("phantom_ring_cross.bvec"),
        DEFAULT_B0_THRESHOLD,
    )?;
    let t_read = t0.elapsed();
    let fit = dti::fit_volume(&dwi, &gtab, FitMethod::Wls, None)?;
    let dims = fit.dims;
    let params = TrackParams { integrator, ..Default::default() };
    let (t_fit, t1, seeds, tracks);
    if args.get(3).is_some_and(|s| s == "tensor") {
        let field = TensorField::from_fit(&fit, dwi.voxel_size(), TensorInterpolation::Componentwise)?;
        t_fit = t0.elapsed();
        let mask: Vec<bool> = (0..dims.iter().product()).map(|v| field.fa_at(v) > 0.2).collect();
        seeds = seeds_from_mask(&mask, dims, 1)?;
        t1 = Instant::now();
        tracks = Tracker::new(&field, dwi.world_from_voxel, params)?.with_tensors(false).run(&seeds);
    } else {
        let field = PeakField::from_fit(&fit, dwi.voxel_size())?;
        t_fit = t0.elapsed();
        let mask: Vec<bool> = (0..dims.iter().product()).map(|v| field.scalar_at(v) > 0.2).collect();
        seeds = seeds_from_mask(&mask, dims, 1)?;
        t1 = Instant::now();
        tracks = Tracker::new(&field, dwi.world_from_voxel, params)?.with_tensors(false).run(&seeds);
    }
    let t_track = t1.elapsed();
    let out = std::env::temp_dir().join("track_phantom.trk");
    trk::write(&out, &tracks.tractogram, dwi.world_from_voxel, dims)?;
    let total = t0.elapsed();
    let n = tracks.n_points() as f64;
    println!(
        "{integrator:?}: {} seeds, {} streamlines, {} points | read {:.3} s, fit {:.3} s, track {:.3} s ({:.2} M/s), write {:.3} s, whole {:.3} s ({:.2} M/s)",
        seeds.len(),
        tracks.tractogram.n_streamlines(),
        tracks.n_points(),
        t_read.as_secs_f64(),
        (t_fit - t_read).as_secs_f64(),
        t_track.as_secs_f64(),
        n / t_track.as_secs_f64() / 1e6,
        (total - (t1 - t0) - t_track).as_secs_f64(),
        total.as_secs_f64(),
        n / total.as_secs_f64() / 1e6
    );
    Ok(())
}
