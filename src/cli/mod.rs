//! The command line: `view`, `render`, `fit`, `track`, `peaks`, `select`, `info` (benchmarks and the soak run are
//! the separate `fascicle-bench` binary). Names and outputs here are an interface that other
//! tools call; change them only with care.

pub mod fit;
pub mod info;
pub mod peaks;
pub mod select;
pub mod track;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[derive(Parser, Debug)]
#[command(name = "fascicle", version, about = "Interactive GPU visualisation of diffusion MRI")]
pub struct Cli {
    #[command(subcommand)]
    pub command: Option<Command>,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Open the viewer with files (NIfTI, .trk/.tck, scene .ron); the default phantom scene without any.
    View {
        files: Vec<PathBuf>,
        /// Save a screenshot of the window to this PNG after the scene has drawn, then exit (scripted
        /// screenshots, and a check that the window path works).
        #[arg(long)]
        screenshot: Option<PathBuf>,
    },
    /// Render a scene headless to PNG (the default scene when none is given).
    Render {
        scene: Option<PathBuf>,
        #[arg(long, default_value = "render.png")]
        out: PathBuf,
        /// Image size, WxH.
        #[arg(long, default_value = "800x600")]
        size: String,
        /// Also write the depth buffer: .png (16-bit reverse-Z NDC depth, 0 = background) or .npy (float32
        /// distance along the view axis in mm, inf = background). Turns MSAA off.
        #[arg(long)]
        depth: Option<PathBuf>,
    },
    /// Fit a model to a DWI.
    Fit {
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
    /// Print what a NIfTI image or tractogram holds.
    Info { file: PathBuf },
}

/// Parses "WxH".
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("size '{s}' is not WxH"))?;
    let w: u32 = w.trim().parse().map_err(|_| format!("width '{w}' is not a number"))?;
    let h: u32 = h.trim().parse().map_err(|_| format!("height '{h}' is not a number"))?;
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(format!("size {w}x{h} must be within 1..16384 on each side"));
    }
    Ok((w, h))
}
