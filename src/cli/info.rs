//! `fascicle info FILE`: what a NIfTI image or tractogram holds.

use std::path::Path;

use fascicle_core::Error;
use fascicle_core::io::{nifti, tck, tractogram, trk};

pub fn run(path: &Path) -> Result<(), Error> {
    let name = path.to_string_lossy().to_ascii_lowercase();
    if name.ends_with(".nii") || name.ends_with(".nii.gz") {
        let h = nifti::read_header(path)?;
        let a = h.world_from_voxel;
        println!("{}: NIfTI-{}{}", path.display(), h.version, if h.big_endian { " (big endian)" } else { "" });
        println!("  shape       {:?}", h.shape);
        println!("  datatype    {} ({})", nifti::datatype_name(h.datatype), h.datatype);
        println!("  voxel size  {:.4} x {:.4} x {:.4} mm", h.pixdim[1], h.pixdim[2], h.pixdim[3]);
        println!(
            "  affine from {:?} (sform_code {}, qform_code {}), axes {}",
            h.affine_source,
            h.sform_code,
            h.qform_code,
            tractogram::axcodes(&a)
        );
        for r in 0..4 {
            println!("    [{:>10.4} {:>10.4} {:>10.4} {:>10.4}]", a.x_axis[r], a.y_axis[r], a.z_axis[r], a.w_axis[r]);
        }
        if h.scl_slope != 0.0 && h.scl_slope.is_finite() && (h.scl_slope != 1.0 || h.scl_inter != 0.0) {
            println!("  scaling     x {} + {}", h.scl_slope, h.scl_inter);
        }
        if !h.descrip.is_empty() {
            println!("  descrip     {}", h.descrip);
        }
        return Ok(());
    }
    match tractogram::extension(path).as_str() {
        "trk" => {
            let (t, h) = trk::read(path)?;
            println!("{}: TrackVis v{}{}", path.display(), h.version, if h.big_endian { " (big endian)" } else { "" });
            print_tracts(&t);
            println!("  grid        {:?} voxels of {:?} mm, voxel order {}", h.dims, h.voxel_size, h.voxel_order);
        }
        "tck" => {
            let (t, h) = tck::read(path)?;
            println!("{}: MRtrix tracks", path.display());
            print_tracts(&t);
            for (k, v) in h {
                println!("  {k}: {}", v.replace('\n', "\n    "));
            }
        }
        other => {
            return Err(Error::Param(format!("{}: unknown file type '{other}' (NIfTI, .trk or .tck)", path.display())));
        }
    }
    Ok(())
}

fn print_tracts(t: &tractogram::Tractogram) {
    println!("  streamlines {}", t.n_streamlines());
    println!("  points      {}", t.points.len());
    if let (Some(lo), Some(hi)) =
        (t.points.iter().copied().reduce(|a, b| a.min(b)), t.points.iter().copied().reduce(|a, b| a.max(b)))
    {
        println!(
            "  bounds (RAS mm) [{:.2}, {:.2}, {:.2}] .. [{:.2}, {:.2}, {:.2}]",
            lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
        );
    }
    for (n, _) in &t.scalars {
        println!("  scalar      {n}");
    }
    for (n, _) in &t.properties {
        println!("  property    {n}");
    }
}
