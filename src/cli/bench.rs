//! `fascicle bench SUITE`: measured tables for the README (run time, throughput, run time against error).
//! Suites print Markdown tables to stdout; timing lives here and in criterion benches, never in tests.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use clap::Subcommand;
use fascicle_core::Error;
use fascicle_core::io::{GradientTable, gradients::DEFAULT_B0_THRESHOLD, nifti};
use fascicle_core::tracking::{
    CircleField, Integrator, TensorInterpolation, TrackParams, Tracker, Tracks, seeds_from_mask,
};
use glam::DVec3;

use super::track::{Prepared, fa_seed_mask, field_from_dwi, write_tracks};

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Tracking: points/s (Euler, RK4; one thread and all) on the phantom, whole process included, and
    /// run time against error on an analytic circle field.
    Tracking {
        /// Directory with phantom_ring_cross.{nii.gz,bval,bvec}.
        #[arg(long, default_value = "data/phantom")]
        phantom: PathBuf,
        /// Seeds per voxel along each axis.
        #[arg(long, default_value_t = 1)]
        seed_density: usize,
    },
    /// SH glyphs: frame time and depth error of ray casting (over h and bisections) and of deformed
    /// icosphere meshes (over subdivision order), for 1k-64k glyphs at l_max 4 and 8.
    Glyphs {
        /// 1k glyphs at 256x256 only (under 2 minutes here).
        #[arg(long)]
        quick: bool,
        /// Also write the rows as CSV (method,n,l_max,param,frame_ms,error).
        #[arg(long)]
        csv: Option<PathBuf>,
    },
    /// Volume rendering: ray casting (early termination on/off, pre-integrated) and 3D-texture slicing of
    /// 128³ and 256³ volumes over the step, frame time and error against the f64 marcher.
    Volume {
        /// 128³ at 128x128, two steps (under 2 minutes here).
        #[arg(long)]
        quick: bool,
        /// Also write the rows as CSV (method,n,param,frame_ms,error).
        #[arg(long)]
        csv: Option<PathBuf>,
    },
    /// Tracts: ray-cast hyperstreamlines (over the iteration cap) vs polygon tubes (over the sides) at the
    /// seed's sizes and resolutions, error against exact intersection; lines for 100k / 1M streamlines with
    /// ROI re-selection.
    Tracts {
        /// 18,681 segments at 434x673 and 100k lines (under 2 minutes here).
        #[arg(long)]
        quick: bool,
        /// Also write the rows as CSV (method,n,param,frame_ms,error,load_ms).
        #[arg(long)]
        csv: Option<PathBuf>,
    },
    /// Every suite, one report: DIR/benchmarks.md (machine, build, adapter, date; each suite's tables; DIPY
    /// side by side) and a PNG plot per renderer of frame time against error.
    All {
        /// Each suite's --quick setting.
        #[arg(long)]
        quick: bool,
        /// Run this suite with --quick even in a full report (repeatable), e.g. `glyphs`, whose full run
        /// (up to 65,536 glyphs at 512x512, 14 settings per size) had not finished after 27 min on lavapipe
        /// with 2 cores.
        #[arg(long, value_name = "SUITE")]
        quick_suite: Vec<String>,
        /// Output directory.
        #[arg(long)]
        report: PathBuf,
        /// A Python with DIPY 1.12.1: also runs bench/compare_dipy.py on the same phantom.
        #[arg(long)]
        python: Option<PathBuf>,
    },
    /// Plot a suite's CSV (frame time against error, or against n with --by-n) to PNG.
    Plot {
        csv: PathBuf,
        #[arg(long)]
        out: PathBuf,
        #[arg(long, default_value = "frame time against error")]
        title: String,
        #[arg(long)]
        by_n: bool,
    },
    /// CPU: DTI (WLS, OLS) and CSA fits and Euler/RK4 tracking on a 128x128x64 phantom with four curved and
    /// crossing bundles at SNR 20 (the inputs `bench/compare_dipy.py` times DIPY on).
    Fits {
        /// A 64x64x32 phantom.
        #[arg(long)]
        quick: bool,
        /// Also write the rows as CSV (method,n,param,frame_ms,error).
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Write the phantom (phantom_large.nii.gz, .bval, .bvec) into this directory, for DIPY.
        #[arg(long)]
        write_phantom: Option<PathBuf>,
    },
    /// Tensor splats (10k, 100k, 1M) and ellipsoid/superquadric glyphs: static and orbiting frame time,
    /// CPU sort time, static CPU cost, colour error against the f64 compositor.
    Splats {
        /// 10k and 100k at 256x256 only (under 2 minutes here).
        #[arg(long)]
        quick: bool,
        /// Also write the rows as CSV (method,n,param,frame_ms,orbit_ms,sort_radix_ms,sort_rayon_ms,static_us,error).
        #[arg(long)]
        csv: Option<PathBuf>,
    },
}

pub fn run(cmd: BenchCommand) -> Result<(), Error> {
    match cmd {
        BenchCommand::Tracking { phantom, seed_density } => tracking(&phantom, seed_density),
        BenchCommand::Glyphs { quick, csv } => {
            super::bench_glyphs::run(quick, csv.as_deref()).map_err(|e| Error::Param(e.to_string()))
        }
        BenchCommand::Plot { csv, out, title, by_n } => super::bench_all::plot_csv(&csv, &out, &title, by_n),
        BenchCommand::All { quick, quick_suite, report, python } => {
            super::bench_all::run(quick, &quick_suite, &report, python.as_deref())
        }
        BenchCommand::Fits { quick, csv, write_phantom } => {
            super::bench_fits::run(quick, csv.as_deref(), write_phantom.as_deref())
        }
        BenchCommand::Tracts { quick, csv } => {
            super::bench_tracts::run(quick, csv.as_deref()).map_err(|e| Error::Param(e.to_string()))
        }
        BenchCommand::Volume { quick, csv } => {
            super::bench_volume::run(quick, csv.as_deref()).map_err(|e| Error::Param(e.to_string()))
        }
        BenchCommand::Splats { quick, csv } => {
            super::bench_splats::run(quick, csv.as_deref()).map_err(|e| Error::Param(e.to_string()))
        }
    }
}

fn pool(threads: usize) -> Result<rayon::ThreadPool, Error> {
    rayon::ThreadPoolBuilder::new().num_threads(threads).build().map_err(|e| Error::Param(format!("thread pool: {e}")))
}

/// Best of `n` runs of `f`, with its last output.
fn best_of<T>(n: usize, mut f: impl FnMut() -> Result<T, Error>) -> Result<(Duration, T), Error> {
    let mut best = Duration::MAX;
    let mut out = None;
    for _ in 0..n {
        let t = Instant::now();
        let v = f()?;
        best = best.min(t.elapsed());
        out = Some(v);
    }
    Ok((best, out.expect("n >= 1")))
}

fn tracking(dir: &std::path::Path, density: usize) -> Result<(), Error> {
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    let out_dir = std::env::temp_dir().join(format!("fascicle-bench-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir).map_err(|e| Error::Io { path: out_dir.clone(), source: e })?;
    println!(
        "## Tracking on the phantom (48x48x24, 2 mm), 0.5 mm steps, FA 0.2, {density}³ seeds per voxel of FA > 0.2\n"
    );
    println!("machine: {all} threads; build: release. Whole = read DWI + WLS fit + seeding + tracking + write .trk.\n");
    println!(
        "| integrator | threads | seeds | streamlines | points | tracking | M points/s | whole process | M points/s (whole) |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for integrator in [Integrator::Euler, Integrator::Rk4] {
        for threads in [1, all] {
            let pool = pool(threads)?;
            let mut stages = (Duration::ZERO, Duration::ZERO);
            let (whole, (tracks, n_seeds)) = best_of(2, || {
                pool.install(|| -> Result<(Tracks, usize), Error> {
                    let t0 = Instant::now();
                    let (dwi, _) = nifti::read::<f32>(dir.join("phantom_ring_cross.nii.gz"))?;
                    let gtab = GradientTable::from_fsl(
                        dir.join("phantom_ring_cross.bval"),
                        dir.join("phantom_ring_cross.bvec"),
                        DEFAULT_B0_THRESHOLD,
                    )?;
                    let Prepared { field, world_from_voxel, dims } =
                        field_from_dwi(&dwi, &gtab, None, TensorInterpolation::Componentwise)?;
                    let seeds = seeds_from_mask(&fa_seed_mask(&field, dims, 0.2), dims, density)?;
                    let params = TrackParams { integrator, ..Default::default() };
                    let t1 = Instant::now();
                    let tracks = Tracker::new(&field, world_from_voxel, params)?.run(&seeds);
                    let t_track = t1.elapsed();
                    write_tracks(&out_dir.join("bench.trk"), &tracks, world_from_voxel, dims, false)?;
                    if stages.1 == Duration::ZERO || t_track < stages.1 {
                        stages = (t0.elapsed(), t_track);
                    }
                    Ok((tracks, seeds.len()))
                })
            })?;
            let pts = tracks.n_points() as f64;
            println!(
                "| {integrator:?} | {threads} | {n_seeds} | {} | {} | {:.3} s | {:.2} | {:.3} s | {:.2} |",
                tracks.tractogram.n_streamlines(),
                tracks.n_points(),
                stages.1.as_secs_f64(),
                pts / stages.1.as_secs_f64() / 1e6,
                whole.as_secs_f64(),
                pts / whole.as_secs_f64() / 1e6
            );
        }
    }
    let _ = std::fs::remove_dir_all(&out_dir);

    println!("\n## Run time against error: circles of radius 20 mm (analytic field), one full turn, one thread\n");
    println!("| integrator | step (mm) | error after one turn (mm) | ns per point |");
    println!("|---|---|---|---|");
    let r = 20.0;
    let field = CircleField { dims: [128, 128, 8], centre: DVec3::new(64.0, 64.0, 4.0) };
    let pool1 = pool(1)?;
    for integrator in [Integrator::Euler, Integrator::Rk2, Integrator::Rk4] {
        for n_half in [16usize, 32, 64, 128, 256, 512] {
            let h = std::f64::consts::PI * r / n_half as f64;
            let (tracker, seed, exact) = field.one_turn(r, n_half, integrator)?;
            let reps = 20_000 / n_half + 1;
            let (t, err) = best_of(3, || {
                pool1.install(|| {
                    let mut err = 0.0f64;
                    for _ in 0..reps {
                        let (s, _) = tracker.track_one(seed).map_err(|r| Error::Param(format!("{r:?}")))?;
                        err = (s[0] - exact).length().max((s[s.len() - 1] - exact).length());
                    }
                    Ok(err)
                })
            })?;
            let ns = t.as_nanos() as f64 / (reps * (2 * n_half + 1)) as f64;
            println!("| {integrator:?} | {h:.3} | {err:.2e} | {ns:.0} |");
        }
    }
    Ok(())
}
