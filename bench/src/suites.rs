//! The suites of `fascicle-bench`: measured tables for `docs/benchmarks.md` (run time, throughput, run time
//! against error). Suites print Markdown tables to stdout; timing lives here and in criterion benches, never in
//! tests.

use std::path::PathBuf;

use clap::Subcommand;
use fascicle_core::Error;

#[derive(Subcommand, Debug)]
pub enum BenchCommand {
    /// Tracking: Fascicle (Euler, RK4), DIPY's EuDX and MRtrix3's tckgen (Tensor_Det, Euler and RK4) on the
    /// phantom from the same seeds, each a whole process (1 thread and all): points/s, streamlines, density-map
    /// Dice; and run time against error on an analytic circle field.
    Tracking {
        /// Directory with phantom_ring_cross.{nii.gz,bval,bvec}.
        #[arg(long, default_value = "data/phantom")]
        phantom: PathBuf,
        /// A Python with dipy==1.12.1 (bench/install_peers.sh makes one): adds DIPY's rows.
        #[arg(long)]
        python: Option<PathBuf>,
        /// MRtrix3's tckgen (default: found on PATH; Debian package mrtrix3): adds MRtrix3's rows.
        #[arg(long)]
        tckgen: Option<PathBuf>,
        /// Runs per row; the best wall time is kept.
        #[arg(long, default_value_t = 3)]
        runs: usize,
    },
    /// SH glyphs: frame time and depth error of the exact ray caster (over its samples), the seed's linear
    /// search (over h) and deformed icosphere meshes (over subdivision order): 4,096 glyphs at 1280x960 for
    /// l_max 4, 6, 8, 12.
    Glyphs {
        /// 1k glyphs at 256x256 (l_max 4, 8) and 4,096 l_max-8 glyphs at 1280x960.
        #[arg(long)]
        quick: bool,
        /// Image size of the 4,096-glyph cases, WxH (default 1280x960; 1920x1080 on a real GPU).
        #[arg(long)]
        size: Option<String>,
        /// Also write the rows as CSV (method,n,param,frame_ms,error,l_max,width,height).
        #[arg(long)]
        csv: Option<PathBuf>,
    },
    /// Volume rendering: every method (ray casting, 3D and 2D slicing, splatting, cell projection) over its
    /// knob, on the phantom's FA map and a CT-like head (128³, and 256³ in the full run), frame time and error
    /// against the f64 marcher.
    Volume {
        /// 128x128 images, the FA map and the 128³ head, two steps.
        #[arg(long)]
        quick: bool,
        /// Image size, WxH (default 256x256, 128x128 with --quick; 1920x1080 on a real GPU).
        #[arg(long)]
        size: Option<String>,
        /// Also write the rows as CSV (method,n,param,frame_ms,error,width,height,volume).
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
        /// A suite's CSV (columns method,n,param,frame_ms,error).
        csv: PathBuf,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// Plot title.
        #[arg(long, default_value = "frame time against error")]
        title: String,
        /// Frame time against n (the size) instead of against error.
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
    /// What an edit costs the app (scene sync, background jobs, uploads; no drawing): the default scene and a
    /// large one (1M streamlines, 22.5k SH glyphs, a 256³ volume), one row per edit against the initial build.
    Edits {
        /// The default scene only.
        #[arg(long)]
        quick: bool,
        /// Also write the rows as CSV (scene,edit,ms,initial_build_ms,worst_frame_ms,frames).
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Where the large scene's files are written once (default: the system's temporary directory).
        #[arg(long)]
        data: Option<PathBuf>,
    },
    /// The real viewer window (on Xvfb when there is no display), driven by xdotool: per scene an orbit and an
    /// ROI drag (frames between press and release: median and 95th percentile of the frame time, the time
    /// from the release to the full-quality frame) and the idle window's CPU use.
    Interact {
        /// Scenes: `default`, `large` (bench edits' large scene) or files the viewer opens, comma-separated.
        #[arg(long, default_value = "default,large", value_delimiter = ',')]
        scenes: Vec<String>,
        /// Where the large scene's files are written once (default: the system's temporary directory).
        #[arg(long)]
        data: Option<PathBuf>,
        /// The window's size, WxH (the display's when the bench starts Xvfb).
        #[arg(long, default_value = "1280x720")]
        size: String,
        /// Also write the rows as CSV (scene,action,frames,median_ms,p95_ms,refine_ms,idle_cpu_pct).
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Seconds a scene may take to load and settle.
        #[arg(long, default_value_t = 600)]
        settle_timeout: u64,
        /// Milliseconds between two pointer moves of a drag (33: a mouse at 30 Hz). On a hardware GPU give a
        /// few, so that frames are paced by their cost rather than by the input.
        #[arg(long, default_value_t = 33.0)]
        move_ms: f64,
    },
    /// Whole-brain-sized tractograms (1M and 10M streamlines as .tck, .trk, .trx, made once in --dir): `info`,
    /// `select`, `convert` as whole processes with peak memory, beside tckinfo, tckedit, nibabel and trx-python
    /// (when installed: bench/install_peers.sh), and an ROI drag step.
    Scale {
        /// Sizes in streamlines, comma-separated.
        #[arg(long, default_value = "1000000,10000000", value_delimiter = ',')]
        sizes: Vec<usize>,
        /// Where the generated tractograms are kept (12.5 GB per format at 10M).
        #[arg(long, default_value = "/tmp/fascicle-scale")]
        dir: PathBuf,
        /// A Python with nibabel and trx-python, for their rows.
        #[arg(long)]
        python: Option<PathBuf>,
        /// Also write the rows as CSV (streamlines,format,task,tool,wall_s,peak_mib,result).
        #[arg(long)]
        csv: Option<PathBuf>,
        /// The largest size whose ROI drag step is measured (the tractogram held in memory).
        #[arg(long, default_value_t = 1_000_000)]
        drag_max: usize,
        /// Only write the missing tractograms, then exit (the bench runs itself so to keep its own memory small).
        #[arg(long, hide = true)]
        write_only: bool,
        /// Only time ROI drag steps on this `.tck`, read in place with the streamline-cell index, then exit (the
        /// bench runs itself so to measure that process's memory alone).
        #[arg(long, hide = true)]
        drag_mapped: Option<PathBuf>,
        /// Only time the viewer's picking (a click, a lasso) on this tractogram, read into memory, then exit.
        #[arg(long)]
        pick: Option<PathBuf>,
    },
    /// Draw the default scene headless for many frames, toggling layers and moving the ROI; print memory and
    /// asset counts (the soak test). Fails when a layer reports an error or the second half of the run grows:
    /// resident memory by more than the tolerance, or any asset or pipeline count beyond the first half's
    /// largest.
    Soak {
        /// Frames to draw.
        #[arg(long, default_value_t = 10_000)]
        frames: u32,
        /// Image size, WxH.
        #[arg(long, default_value = "320x200")]
        size: String,
        /// Write the samples (every 100 frames) as CSV.
        #[arg(long)]
        csv: Option<PathBuf>,
        /// Resident-memory growth allowed over the second half of the run, MiB per 10,000 frames (the
        /// least-squares slope of the curve).
        #[arg(long, default_value_t = 1.0)]
        max_growth: f64,
    },
}

pub fn run(cmd: BenchCommand) -> Result<(), Error> {
    match cmd {
        BenchCommand::Scale { drag_mapped: Some(file), .. } => crate::bench_scale::drag_mapped(&file),
        BenchCommand::Scale { pick: Some(file), .. } => crate::bench_scale::pick(&file),
        BenchCommand::Scale { sizes, dir, python, csv, drag_max, write_only, drag_mapped: None, pick: None } => {
            crate::bench_scale::run(crate::bench_scale::ScaleOptions {
                sizes: &sizes,
                dir: &dir,
                python: python.as_deref(),
                csv: csv.as_deref(),
                drag_max,
                write_only,
            })
        }
        BenchCommand::Soak { frames, size, csv, max_growth } => {
            crate::soak::run(frames, &size, csv.as_deref(), max_growth).map_err(Error::Param)
        }
        BenchCommand::Interact { scenes, data, size, csv, settle_timeout, move_ms } => {
            let size = fascicle_scene::headless::parse_size(&size).map_err(Error::Param)?;
            let data = data.unwrap_or_else(|| std::env::temp_dir().join("fascicle-bench-edits"));
            crate::bench_interact::run(crate::bench_interact::InteractOptions {
                scenes: &scenes,
                data: &data,
                size,
                csv: csv.as_deref(),
                settle_timeout: std::time::Duration::from_secs(settle_timeout),
                move_interval: std::time::Duration::from_secs_f64(move_ms.max(0.0) / 1e3),
            })
            .map_err(Error::Param)
        }
        BenchCommand::Edits { quick, csv, data } => {
            crate::bench_edits::run(quick, csv.as_deref(), data).map_err(Error::Param)
        }
        BenchCommand::Tracking { phantom, python, tckgen, runs } => {
            crate::bench_tracking::run(&phantom, python.as_deref(), tckgen.as_deref(), runs)
        }
        BenchCommand::Glyphs { quick, size, csv } => {
            let size = size.as_deref().map(fascicle_scene::headless::parse_size).transpose().map_err(Error::Param)?;
            crate::bench_glyphs::run(quick, size, csv.as_deref()).map_err(|e| Error::Param(e.to_string()))
        }
        BenchCommand::Plot { csv, out, title, by_n } => crate::bench_all::plot_csv(&csv, &out, &title, by_n),
        BenchCommand::All { quick, quick_suite, report, python } => {
            crate::bench_all::run(quick, &quick_suite, &report, python.as_deref())
        }
        BenchCommand::Fits { quick, csv, write_phantom } => {
            crate::bench_fits::run(quick, csv.as_deref(), write_phantom.as_deref())
        }
        BenchCommand::Tracts { quick, csv } => {
            crate::bench_tracts::run(quick, csv.as_deref()).map_err(|e| Error::Param(e.to_string()))
        }
        BenchCommand::Volume { quick, size, csv } => {
            let size = size.as_deref().map(fascicle_scene::headless::parse_size).transpose().map_err(Error::Param)?;
            crate::bench_volume::run(quick, size, csv.as_deref()).map_err(|e| Error::Param(e.to_string()))
        }
        BenchCommand::Splats { quick, csv } => {
            crate::bench_splats::run(quick, csv.as_deref()).map_err(|e| Error::Param(e.to_string()))
        }
    }
}
