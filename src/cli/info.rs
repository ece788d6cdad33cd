//! `fascicle info FILE`: what a NIfTI image or tractogram holds.

use std::path::Path;

use fascicle_core::Error;
use fascicle_core::io::stream::{self, Format, StreamHeader, Summary, TractogramReader};
use fascicle_core::io::{nifti, tractogram};

/// Runs `fascicle info`: prints what `path` holds on stdout, as text or (with `json`) as [`info_json`]'s object.
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
        "tsf" => {
            let v = info_json(path)?;
            println!("{}: {}", path.display(), v["format"].as_str().unwrap_or(""));
            println!("  streamlines {}", v["count"]);
            println!("  values      {} (one per point)", v["points"]);
            match (v["range"][0].as_f64(), v["range"][1].as_f64()) {
                (Some(lo), Some(hi)) => println!("  range       {lo} .. {hi}"),
                _ => println!("  range       no finite value"),
            }
            for (k, val) in v["header"].as_object().into_iter().flatten() {
                println!("  {k}: {}", val.as_str().unwrap_or("").replace('\n', "\n    "));
            }
        }
        "trk" | "tck" | "trx" => {
            let (h, s) = summary(path)?;
            println!("{}: {}", path.display(), h.format.name());
            println!("  streamlines {}", s.streamlines);
            println!("  points      {}", s.points);
            match s.bounds {
                Some((lo, hi)) => println!(
                    "  bounds (RAS mm) [{:.2}, {:.2}, {:.2}] .. [{:.2}, {:.2}, {:.2}]",
                    lo.x, lo.y, lo.z, hi.x, hi.y, hi.z
                ),
                None if h.format == Format::Trx => println!("  bounds      not read (a TRX's header and offsets only)"),
                None => {}
            }
            for n in &h.scalars {
                println!("  scalar      {n}");
            }
            for n in &h.properties {
                println!("  property    {n}");
            }
            if let Some(t) = &h.trk {
                let v = if t.big_endian { " (big endian)" } else { "" };
                println!("  version     {}{v}", t.version);
                println!("  grid        {:?} voxels of {:?} mm, voxel order {}", t.dims, t.voxel_size, t.voxel_order);
            }
            if let Some(t) = &h.trx {
                println!("  grid        {:?} voxels", t.dims);
                for (name, members) in &t.groups {
                    println!("  group       {name} ({} streamlines)", members.len());
                }
            }
            for (k, v) in h.tck.iter().flatten() {
                println!("  {k}: {}", v.replace('\n', "\n    "));
            }
        }
        other => {
            return Err(Error::Param(format!(
                "{}: unknown file type '{other}' (NIfTI, .mif, .trk, .tck, .trx or .tsf)",
                path.display()
            )));
        }
    }
    Ok(())
}

/// What `info --json` prints of an MRtrix track scalar file (`.tsf`: values per point of a tractogram, as
/// `tcksample` writes them): `count` (streamlines), `points` (values), `range` (the least and greatest value,
/// null when none) and the `header` entries (its `timestamp` matches the `.tck` it was made from).
fn tsf_json(path: &Path) -> Result<serde_json::Value, Error> {
    use serde_json::json;
    let s = fascicle_core::io::tsf::read(path)?;
    let range = s
        .values
        .iter()
        .copied()
        .fold(None, |r: Option<(f32, f32)>, v| Some(r.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v)))));
    let header: serde_json::Map<String, serde_json::Value> =
        s.header.iter().map(|(k, v)| (k.clone(), json!(v))).collect();
    Ok(json!({
        "file": path.display().to_string(),
        "format": "MRtrix track scalar file",
        "kind": "track_scalars",
        "count": s.n_streamlines(),
        "points": s.values.len(),
        "range": range.map_or(json!(null), |(lo, hi)| json!([lo, hi])),
        "header": header,
    }))
}

/// A tractogram's header and one streamed pass over it (the header only for a TRX), with a progress bar on
/// stderr.
fn summary(path: &Path) -> Result<(StreamHeader, Summary), Error> {
    let mut reader = TractogramReader::open(path)?;
    let pb = super::select::bytes_bar(reader.header().file_bytes, "reading");
    let s = stream::scan(&mut reader, |b| pb.set_position(b))?;
    pb.finish_and_clear();
    Ok((reader.header().clone(), s))
}

/// What `info --json` prints: `kind` (tractogram, track_scalars, or for images dwi / tensor / sh / peaks / rgb /
/// scalar / volume as far as the shape and the files beside it tell), `shape`, `voxel_size`, `affine` (rows), and
/// for tractograms `count` (streamlines), `points` and the header's `space`; for `.tsf` files `count`, `points`,
/// `range` and `header`.
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
    if tractogram::extension(path) == "tsf" {
        return tsf_json(path);
    }
    if !matches!(tractogram::extension(path).as_str(), "trk" | "tck" | "trx") {
        return Err(Error::Param(format!(
            "{}: unknown file type '{}' (NIfTI, .mif, .trk, .tck, .trx or .tsf)",
            path.display(),
            tractogram::extension(path)
        )));
    }
    let (h, s) = summary(path)?;
    let space = if let Some(t) = &h.trk {
        json!({"voxel_order": t.voxel_order, "dims": t.dims, "voxel_size": t.voxel_size, "points": "RAS+ mm"})
    } else if let Some(t) = &h.trx {
        json!({"dims": t.dims, "voxel_to_rasmm": t.voxel_to_rasmm.transpose().to_cols_array_2d(), "points": "RAS+ mm"})
    } else {
        json!({"points": "RAS+ mm (scanner)"})
    };
    let format = match &h.trk {
        Some(t) => format!("TrackVis v{}", t.version),
        None => h.format.name().to_string(),
    };
    let groups = h.trx.as_ref().map_or(serde_json::Value::Null, |t| {
        serde_json::Value::Object(t.groups.iter().map(|(n, m)| (n.clone(), json!(m.len()))).collect())
    });
    let bounds = match s.bounds {
        Some((lo, hi)) => json!([lo.to_array(), hi.to_array()]),
        None => serde_json::Value::Null,
    };
    Ok(json!({
        "file": path.display().to_string(),
        "format": format,
        "kind": "tractogram",
        "count": s.streamlines,
        "points": s.points,
        "space": space,
        "bounds": bounds,
        "scalars": h.scalars,
        "properties": h.properties,
        "groups": groups,
    }))
}
