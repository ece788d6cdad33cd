//! `fascicle select`: keep the streamlines of a tractogram that meet every include ROI and no exclude ROI
//! (TrackVis / DSI Studio AND semantics, `fascicle_core::roi`), and write them as `.trk` or `.tck`.

use std::path::{Path, PathBuf};

use fascicle_core::Error;
use fascicle_core::io::{Tractogram, tck, tractogram::extension, trk};
use fascicle_core::roi::{Roi, RoiMode, RoiShape, SegmentGrid, select};
use glam::{DMat4, DVec3};

#[derive(clap::Args, Debug)]
pub struct SelectArgs {
    /// Input tractogram (.trk or .tck).
    pub input: PathBuf,
    /// Include sphere, x,y,z,r in RAS+ mm (repeatable).
    #[arg(long, value_name = "X,Y,Z,R")]
    pub sphere: Vec<String>,
    /// Exclude sphere, x,y,z,r (repeatable).
    #[arg(long, value_name = "X,Y,Z,R")]
    pub exclude_sphere: Vec<String>,
    /// Include axis-aligned box, x0,y0,z0,x1,y1,z1 (repeatable).
    #[arg(long, value_name = "X0,Y0,Z0,X1,Y1,Z1", name = "box")]
    pub boxes: Vec<String>,
    /// Exclude box (repeatable).
    #[arg(long, value_name = "X0,Y0,Z0,X1,Y1,Z1")]
    pub exclude_box: Vec<String>,
    /// Include plane through a point with a normal, px,py,pz,nx,ny,nz (repeatable).
    #[arg(long, value_name = "PX,PY,PZ,NX,NY,NZ")]
    pub plane: Vec<String>,
    /// Exclude plane (repeatable).
    #[arg(long, value_name = "PX,PY,PZ,NX,NY,NZ")]
    pub exclude_plane: Vec<String>,
    /// Output (.trk or .tck).
    #[arg(long)]
    pub out: PathBuf,
}

fn numbers(s: &str, n: usize, what: &str) -> Result<Vec<f32>, Error> {
    let v: Vec<f32> = s
        .split(',')
        .map(|x| x.trim().parse::<f32>().map_err(|_| Error::Param(format!("{what} '{s}': '{x}' is not a number"))))
        .collect::<Result<_, _>>()?;
    if v.len() != n || v.iter().any(|x| !x.is_finite()) {
        return Err(Error::Param(format!("{what} '{s}' needs {n} finite comma-separated numbers")));
    }
    Ok(v)
}

/// The ROIs the arguments describe.
pub fn rois(a: &SelectArgs) -> Result<Vec<Roi>, Error> {
    let mut out = Vec::new();
    for (list, mode) in [(&a.sphere, RoiMode::Include), (&a.exclude_sphere, RoiMode::Exclude)] {
        for s in list {
            let v = numbers(s, 4, "sphere")?;
            if v[3] <= 0.0 {
                return Err(Error::Param(format!("sphere '{s}': the radius must be positive")));
            }
            out.push(Roi { shape: RoiShape::Sphere { centre: [v[0], v[1], v[2]], radius: v[3] }, mode });
        }
    }
    for (list, mode) in [(&a.boxes, RoiMode::Include), (&a.exclude_box, RoiMode::Exclude)] {
        for s in list {
            let v = numbers(s, 6, "box")?;
            let (lo, hi) = ([v[0], v[1], v[2]], [v[3], v[4], v[5]]);
            out.push(Roi {
                shape: RoiShape::Box {
                    min: std::array::from_fn(|k| lo[k].min(hi[k])),
                    max: std::array::from_fn(|k| lo[k].max(hi[k])),
                },
                mode,
            });
        }
    }
    for (list, mode) in [(&a.plane, RoiMode::Include), (&a.exclude_plane, RoiMode::Exclude)] {
        for s in list {
            let v = numbers(s, 6, "plane")?;
            if v[3..].iter().all(|x| *x == 0.0) {
                return Err(Error::Param(format!("plane '{s}': the normal must not be zero")));
            }
            out.push(Roi { shape: RoiShape::Plane { point: [v[0], v[1], v[2]], normal: [v[3], v[4], v[5]] }, mode });
        }
    }
    Ok(out)
}

/// Writes `t` to `.trk` (with the reference space of `header` when the input was a `.trk`, else a 1 mm grid
/// covering the points) or `.tck`, chosen by the extension.
pub fn write(path: &Path, t: &Tractogram, header: Option<&trk::TrkHeader>) -> Result<(), Error> {
    match extension(path).as_str() {
        "trk" => {
            let (affine, dims) = match header {
                Some(h) if h.vox_to_ras != DMat4::ZERO && h.dims.iter().all(|d| *d > 0) => {
                    (h.vox_to_ras, h.dims.map(|d| d as usize))
                }
                _ => {
                    let (mut lo, mut hi) = (DVec3::splat(f64::MAX), DVec3::splat(f64::MIN));
                    for p in &t.points {
                        lo = lo.min(p.as_dvec3());
                        hi = hi.max(p.as_dvec3());
                    }
                    if lo.x > hi.x {
                        (lo, hi) = (DVec3::ZERO, DVec3::ZERO);
                    }
                    let dims = ((hi - lo).ceil() + 1.0).to_array().map(|v| v as usize);
                    (DMat4::from_translation(lo), dims)
                }
            };
            trk::write(path, t, affine, dims)
        }
        "tck" => tck::write(path, t, &[]),
        "trx" => fascicle_core::io::trx::write(path, t, None, fascicle_core::io::trx::PositionType::F32),
        other => Err(Error::Param(format!(
            "output '{}': unknown extension '{other}' (use .trk, .tck or .trx)",
            path.display()
        ))),
    }
}

pub fn run(a: SelectArgs) -> Result<(), Error> {
    let rois = rois(&a)?;
    super::check_output(&a.out)?;
    let (t, header) = match extension(&a.input).as_str() {
        "trk" => {
            let (t, h) = trk::read(&a.input)?;
            (t, Some(h))
        }
        _ => (Tractogram::read(&a.input)?, None),
    };
    let t0 = std::time::Instant::now();
    let grid = SegmentGrid::new(&t.points, &t.offsets, 4.0);
    let keep = select(&t.points, &t.offsets, &grid, &rois);
    let ms = t0.elapsed().as_secs_f64() * 1e3;
    let out = t.subset(&keep);
    write(&a.out, &out, header.as_ref())?;
    if super::globals().quiet {
        return Ok(());
    }
    println!(
        "kept {} of {} streamlines ({} ROIs, {ms:.1} ms) -> {}",
        out.n_streamlines(),
        t.n_streamlines(),
        rois.len(),
        a.out.display()
    );
    Ok(())
}
