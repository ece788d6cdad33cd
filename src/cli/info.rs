//! `fascicle info FILE`: what a NIfTI image or tractogram holds.

use std::path::Path;

use fascicle_core::Error;
use fascicle_core::io::{nifti, tck, tractogram, trk};

pub fn run(path: &Path, json: bool) -> Result<(), Error> {
    if json {
        println!("{}", serde_json::to_string_pretty(&info_json(path)?).unwrap_or_default());
        return Ok(());
    }
    let name = path.to_string_lossy().to_ascii_lowercase();
    if fascicle_core::io::mif::is_mif(path) {
        let v = info_json(path)?;
        println!("{}: MRtrix image", path.display());
        println!("  kind        {} ({})", v["kind"].as_str().unwrap_or(""), v["reason"].as_str().unwrap_or(""));
        println!("  shape       {}", v["shape"]);
        println!("  datatype    {}", v["datatype"].as_str().unwrap_or(""));
        println!("  voxel size  {}", v["voxel_size"]);
        println!("  affine      {}", v["affine"]);
        return Ok(());
    }
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
        "trx" => {
            let (t, h) = fascicle_core::io::trx::read(path)?;
            println!("{}: TRX", path.display());
            print_tracts(&t);
            println!("  grid        {:?} voxels", h.dims);
            for (name, members) in &h.groups {
                println!("  group       {name} ({} streamlines)", members.len());
            }
        }
        other => {
            return Err(Error::Param(format!(
                "{}: unknown file type '{other}' (NIfTI, .mif, .trk, .tck or .trx)",
                path.display()
            )));
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

/// What `info --json` prints: `kind` (tractogram, or for images dwi / tensor / sh / peaks / rgb / scalar /
/// volume as far as the shape and the files beside it tell), `shape`, `voxel_size`, `affine` (rows), and for
/// tractograms `count` (streamlines), `points` and the header's `space`.
pub fn info_json(path: &Path) -> Result<serde_json::Value, Error> {
    use serde_json::json;
    let name = path.to_string_lossy().to_ascii_lowercase();
    if fascicle_core::io::mif::is_mif(path) {
        let (vol, h) = fascicle_core::io::mif::read::<f32>(path)?;
        let a = vol.world_from_voxel;
        let rows: Vec<[f64; 4]> = (0..4).map(|r| [a.x_axis[r], a.y_axis[r], a.z_axis[r], a.w_axis[r]]).collect();
        let class = fascicle_core::io::classify::classify_mif_image(&vol, &h);
        let vox = vol.voxel_size();
        let mut v = json!({
            "file": path.display().to_string(),
            "format": "MRtrix image",
            "kind": class.kind.name(),
            "reason": class.reason,
            "shape": vol.shape,
            "datatype": h.datatype,
            "voxel_size": [vox.x, vox.y, vox.z],
            "affine": rows,
            "axes": tractogram::axcodes(&a),
            "dw_scheme_rows": h.dw_scheme.len(),
        });
        if let fascicle_core::io::classify::ImageKind::Sh { basis: Some(b), l_max } = class.kind {
            v["sh_basis"] = json!({"convention": b.convention(), "legacy": b.legacy()});
            v["l_max"] = json!(l_max);
        }
        return Ok(v);
    }
    if name.ends_with(".nii") || name.ends_with(".nii.gz") {
        let h = nifti::read_header(path)?;
        let a = h.world_from_voxel;
        let rows: Vec<[f64; 4]> = (0..4).map(|r| [a.x_axis[r], a.y_axis[r], a.z_axis[r], a.w_axis[r]]).collect();
        // What it holds, by header, the files beside it and (where those are silent) its content.
        let class = fascicle_core::io::classify::classify_with(path, &h, || nifti::read::<f32>(path).map(|(v, _)| v))?;
        let kind = class.kind.name();
        let mut v = json!({
            "file": path.display().to_string(),
            "format": format!("NIfTI-{}", h.version),
            "kind": kind,
            "shape": h.shape,
            "datatype": nifti::datatype_name(h.datatype),
            "voxel_size": [h.pixdim[1], h.pixdim[2], h.pixdim[3]],
            "affine": rows,
            "axes": tractogram::axcodes(&a),
            "sform_code": h.sform_code,
            "qform_code": h.qform_code,
            "descrip": h.descrip,
        });
        v["reason"] = json!(class.reason);
        if !class.ambiguous.is_empty() {
            v["could_be"] = json!(class.ambiguous.iter().map(|k| k.name()).collect::<Vec<_>>());
        }
        if let fascicle_core::io::classify::ImageKind::Tensor { order } = class.kind {
            v["tensor_order"] = json!(format!("{order:?}").to_ascii_lowercase());
        }
        if let fascicle_core::io::classify::ImageKind::Sh { basis: recorded, l_max } = class.kind {
            // The basis recorded in the header or a sidecar; otherwise DIPY's default, which is what Fascicle
            // reads an unlabelled file as.
            let b = recorded.unwrap_or_default();
            v["sh_basis"] = json!({"convention": b.convention(), "legacy": b.legacy(), "recorded": recorded.is_some()});
            v["l_max"] = json!(l_max);
        }
        return Ok(v);
    }
    let (t, space, extra) = match tractogram::extension(path).as_str() {
        "trk" => {
            let (t, h) = trk::read(path)?;
            let space =
                json!({"voxel_order": h.voxel_order, "dims": h.dims, "voxel_size": h.voxel_size, "points": "RAS+ mm"});
            (t, space, json!({"format": format!("TrackVis v{}", h.version)}))
        }
        "tck" => {
            let (t, _) = tck::read(path)?;
            (t, json!({"points": "RAS+ mm (scanner)"}), json!({"format": "MRtrix tracks"}))
        }
        "trx" => {
            let (t, h) = fascicle_core::io::trx::read(path)?;
            let groups: serde_json::Map<String, serde_json::Value> =
                h.groups.iter().map(|(n, m)| (n.clone(), json!(m.len()))).collect();
            let space = json!({"dims": h.dims, "voxel_to_rasmm": h.voxel_to_rasmm.transpose().to_cols_array_2d(), "points": "RAS+ mm"});
            (t, space, json!({"format": "TRX", "groups": groups}))
        }
        other => {
            return Err(Error::Param(format!(
                "{}: unknown file type '{other}' (NIfTI, .mif, .trk, .tck or .trx)",
                path.display()
            )));
        }
    };
    let bounds =
        match (t.points.iter().copied().reduce(|a, b| a.min(b)), t.points.iter().copied().reduce(|a, b| a.max(b))) {
            (Some(lo), Some(hi)) => json!([lo.to_array(), hi.to_array()]),
            _ => serde_json::Value::Null,
        };
    Ok(json!({
        "file": path.display().to_string(),
        "format": extra["format"],
        "kind": "tractogram",
        "count": t.n_streamlines(),
        "points": t.points.len(),
        "space": space,
        "bounds": bounds,
        "scalars": t.scalars.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>(),
        "properties": t.properties.iter().map(|(n, _)| n.clone()).collect::<Vec<_>>(),
        "groups": extra.get("groups").cloned().unwrap_or(serde_json::Value::Null),
    }))
}
