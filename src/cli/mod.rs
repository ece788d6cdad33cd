//! The command line: `view`, `render`, `fit`, `track`, `peaks`, `select`, `convert`, `info` (benchmarks and the soak run are
//! the separate `fascicle-bench` binary). Names and outputs here are an interface that other
//! tools call; change them only with care.

pub mod convert;
pub mod fit;
pub mod info;
pub mod peaks;
pub mod select;
pub mod track;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

/// The parsed command line: an optional subcommand (none opens the viewer) and the global options.
#[derive(Parser, Debug)]
#[command(name = "fascicle", version, about = "Interactive GPU visualisation of diffusion MRI")]
pub struct Cli {
    /// The subcommand; `None` opens the viewer on the default phantom scene.
    #[command(subcommand)]
    pub command: Option<Command>,
    /// Overwrite output files that already exist (refused otherwise).
    #[arg(long, global = true)]
    pub force: bool,
    /// No progress bars or summaries on stderr (errors still print).
    #[arg(long, short, global = true)]
    pub quiet: bool,
    /// Worker threads for fitting and tracking (default: all cores).
    #[arg(long, global = true)]
    pub threads: Option<usize>,
}

/// The options every subcommand shares, set once from the command line.
#[derive(Clone, Copy, Debug, Default)]
pub struct Globals {
    /// Overwrite output files that already exist (`--force`); default false.
    pub force: bool,
    /// No progress bars or summaries on stderr (`--quiet`); default false.
    pub quiet: bool,
}

static GLOBALS: std::sync::OnceLock<Globals> = std::sync::OnceLock::new();

/// Records the shared options and sizes the thread pool.
pub fn set_globals(cli: &Cli) -> Result<(), String> {
    let _ = GLOBALS.set(Globals { force: cli.force, quiet: cli.quiet });
    if let Some(n) = cli.threads {
        if n == 0 {
            return Err("--threads must be at least 1".into());
        }
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().map_err(|e| format!("--threads {n}: {e}"))?;
    }
    Ok(())
}

/// The shared options [`set_globals`] recorded (all false before it is called).
pub fn globals() -> Globals {
    GLOBALS.get().copied().unwrap_or_default()
}

/// Refuses to overwrite an existing output unless `--force` was given.
pub fn check_output(path: &std::path::Path) -> Result<(), fascicle_core::Error> {
    if path.exists() && !globals().force {
        return Err(fascicle_core::Error::Param(format!("{} exists; pass --force to overwrite it", path.display())));
    }
    Ok(())
}

/// A DTI fit's estimator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum FitMethodArg {
    /// Weighted least squares (DIPY's default).
    Wls,
    /// Ordinary least squares on the log signal.
    Ols,
}

impl From<FitMethodArg> for fascicle_core::dti::FitMethod {
    fn from(m: FitMethodArg) -> Self {
        match m {
            FitMethodArg::Wls => Self::Wls,
            FitMethodArg::Ols => Self::Ols,
        }
    }
}

/// An integration scheme.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum IntegratorArg {
    /// Classical fourth-order Runge-Kutta.
    Rk4,
    /// Midpoint rule, second order.
    Rk2,
    /// Explicit Euler, first order (DIPY's EuDX).
    Euler,
}

impl From<IntegratorArg> for fascicle_core::tracking::Integrator {
    fn from(i: IntegratorArg) -> Self {
        match i {
            IntegratorArg::Rk4 => Self::Rk4,
            IntegratorArg::Rk2 => Self::Rk2,
            IntegratorArg::Euler => Self::Euler,
        }
    }
}

/// A real SH basis family (with --legacy / --sh-legacy for the variant).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BasisArg {
    /// DIPY's (Descoteaux 2007).
    Descoteaux07,
    /// MRtrix3's (Tournier 2007); coefficients in scanner coordinates.
    Tournier07,
}

impl BasisArg {
    /// The basis of this family, in its legacy variant when `legacy` is true.
    pub fn with_legacy(self, legacy: bool) -> fascicle_core::sh::ShBasis {
        match self {
            BasisArg::Descoteaux07 => fascicle_core::sh::ShBasis::Descoteaux07 { legacy },
            BasisArg::Tournier07 => fascicle_core::sh::ShBasis::Tournier07 { legacy },
        }
    }
}

/// An SH basis by its full name, for `convert --sh-basis`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ShBasisName {
    /// DIPY's basis (legacy=False), in voxel axes.
    Descoteaux07,
    /// DIPY's default basis (legacy=True), in voxel axes.
    Descoteaux07Legacy,
    /// MRtrix3's basis, in scanner axes.
    Tournier07,
    /// MRtrix3's basis as DIPY's legacy variant, in scanner axes.
    Tournier07Legacy,
}

impl From<ShBasisName> for fascicle_core::sh::ShBasis {
    fn from(b: ShBasisName) -> Self {
        use fascicle_core::sh::ShBasis;
        match b {
            ShBasisName::Descoteaux07 => ShBasis::Descoteaux07 { legacy: false },
            ShBasisName::Descoteaux07Legacy => ShBasis::Descoteaux07 { legacy: true },
            ShBasisName::Tournier07 => ShBasis::Tournier07 { legacy: false },
            ShBasisName::Tournier07Legacy => ShBasis::Tournier07 { legacy: true },
        }
    }
}

/// The subcommands of `fascicle`.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Open the viewer with files (NIfTI, .trk/.tck, scene .ron); the default phantom scene without any.
    View {
        /// NIfTI images, .trk/.tck tractograms, peaks images or a scene .ron to open.
        files: Vec<PathBuf>,
        /// Save a screenshot of the window to this PNG after the scene has drawn, then exit (scripted
        /// screenshots, and a check that the window path works).
        #[arg(long)]
        screenshot: Option<PathBuf>,
    },
    /// Render a scene headless to PNG (the default scene when none is given).
    Render {
        /// Scene file (.ron); the default phantom scene when absent.
        scene: Option<PathBuf>,
        /// Output PNG.
        #[arg(long, default_value = "render.png")]
        out: PathBuf,
        /// Image size, WxH.
        #[arg(long, default_value = "800x600")]
        size: String,
        /// Also write the depth buffer: .png (16-bit reverse-Z NDC depth, 0 = background) or .npy (float32
        /// distance along the view axis in mm, inf = background). Turns MSAA off.
        #[arg(long)]
        depth: Option<PathBuf>,
        /// The four-view layout: sagittal, coronal and axial 2D views at the scene's crosshair beside the 3D
        /// view (as the viewer's "orthogonal 2D views").
        #[arg(long)]
        ortho: bool,
        /// The crosshair (world mm, RAS+), "X,Y,Z"; the images' centre when absent.
        #[arg(long, allow_hyphen_values = true)]
        crosshair: Option<String>,
    },
    /// Fit a model to a DWI.
    Fit {
        /// The model to fit.
        #[command(subcommand)]
        model: fit::FitCommand,
    },
    /// Track streamlines (Euler/RK2/RK4) along tensors or ODF peaks, from a DWI, tensor, SH or peaks image,
    /// into .trk/.tck.
    Track(track::TrackArgs),
    /// ODF peaks of a DWI (CSA/Q-ball) or SH image, as DIPY's peaks_from_model, in MRtrix or DIPY layout.
    Peaks(peaks::PeaksArgs),
    /// Keep the streamlines that meet every include ROI and no exclude ROI; write .trk/.tck.
    Select(select::SelectArgs),
    /// Convert images between NIfTI and MRtrix (.nii[.gz] <-> .mif[.gz]) and tractograms between .trk and .tck
    /// (either gzipped), by the names.
    Convert {
        /// The file to read: .nii, .nii.gz, .mif, .mif.gz, .trk, .tck (or gzipped tractograms).
        input: PathBuf,
        /// The file to write, of the same family; its name picks the format.
        output: PathBuf,
        /// For an SH image, the basis to write (default: MRtrix3's, tournier07, into a .mif; the input's
        /// otherwise). DIPY's bases are in voxel axes and MRtrix3's in scanner axes: between the two the
        /// coefficients are also turned through the image's affine.
        #[arg(long, value_enum)]
        sh_basis: Option<ShBasisName>,
    },
    /// Print what a NIfTI image or tractogram holds.
    Info {
        /// A NIfTI image (.nii, .nii.gz) or a tractogram (.trk, .tck, or gzipped).
        file: PathBuf,
        /// Print one JSON object (for scripts) instead of text.
        #[arg(long)]
        json: bool,
    },
}
