//! Seed placement: DIPY's `seeds_from_mask` grid, and seed files of world coordinates.

use std::path::Path;

use glam::{DMat4, DVec3};

use crate::error::{Error, Result};

/// `density³` seeds in every voxel where `mask` is true, in voxel coordinates, in DIPY's order: voxels in C
/// order of (x, y, z) (x slowest, as `np.argwhere`), and within a voxel the offsets `(i + 0.5) / n - 0.5`
/// with x fastest (DIPY transposes its `mgrid`).
pub fn seeds_from_mask(mask: &[bool], dims: [usize; 3], density: usize) -> Result<Vec<DVec3>> {
    if mask.len() != dims.iter().product::<usize>() {
        return Err(Error::Shape(format!("the seed mask has {} voxels, the grid {dims:?}", mask.len())));
    }
    if density == 0 || density > 64 {
        return Err(Error::Param(format!("seed density {density} must be within 1..64 per axis")));
    }
    let off: Vec<f64> = (0..density).map(|i| (i as f64 + 0.5) / density as f64 - 0.5).collect();
    let mut out = Vec::new();
    for x in 0..dims[0] {
        for y in 0..dims[1] {
            for z in 0..dims[2] {
                if !mask[x + dims[0] * (y + dims[1] * z)] {
                    continue;
                }
                let c = DVec3::new(x as f64, y as f64, z as f64);
                for &k in &off {
                    for &j in &off {
                        for &i in &off {
                            out.push(c + DVec3::new(i, j, k));
                        }
                    }
                }
            }
        }
    }
    Ok(out)
}

/// Seeds in world coordinates (RAS+ mm) from a file: `.npy` (N x 3, float or integer) or text (three
/// numbers per line, separated by spaces, tabs or commas; `#` starts a comment).
pub fn read_seeds(path: impl AsRef<Path>) -> Result<Vec<DVec3>> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let values: Vec<f64> = if bytes.starts_with(b"\x93NUMPY") {
        let f = npyz::NpyFile::new(&bytes[..]).map_err(|e| Error::format(path, format!("bad .npy header: {e}")))?;
        let shape = f.shape().to_vec();
        if shape.len() != 2 || shape[1] != 3 {
            return Err(Error::format(path, format!("seeds must be an N x 3 array, this one is {shape:?}")));
        }
        if f.header().order() == npyz::Order::Fortran {
            return Err(Error::format(path, "Fortran-ordered .npy seeds are not supported; save with C order"));
        }
        npy_as_f64(f).map_err(|e| Error::format(path, e))?
    } else {
        let text = String::from_utf8(bytes).map_err(|_| Error::format(path, "neither .npy nor UTF-8 text"))?;
        let mut v = Vec::new();
        for (ln, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let nums: std::result::Result<Vec<f64>, _> =
                line.split(|c: char| c == ',' || c.is_whitespace()).filter(|s| !s.is_empty()).map(str::parse).collect();
            match nums {
                Ok(n) if n.len() == 3 => v.extend(n),
                _ => return Err(Error::format(path, format!("line {}: expected three numbers, got '{line}'", ln + 1))),
            }
        }
        v
    };
    let seeds: Vec<DVec3> = values.chunks_exact(3).map(|c| DVec3::new(c[0], c[1], c[2])).collect();
    if let Some(i) = seeds.iter().position(|s| !s.is_finite()) {
        return Err(Error::format(path, format!("seed {i} is not finite: {}", seeds[i])));
    }
    Ok(seeds)
}

fn npy_as_f64(f: npyz::NpyFile<&[u8]>) -> std::result::Result<Vec<f64>, String> {
    use npyz::{DType, TypeChar};
    let DType::Plain(ty) = f.dtype() else { return Err("seeds must be a plain numeric array".into()) };
    let err = |e: std::io::Error| e.to_string();
    match (ty.type_char(), ty.size_field()) {
        (TypeChar::Float, 8) => f.into_vec::<f64>().map_err(err),
        (TypeChar::Float, 4) => Ok(f.into_vec::<f32>().map_err(err)?.into_iter().map(f64::from).collect()),
        (TypeChar::Int, 8) => Ok(f.into_vec::<i64>().map_err(err)?.into_iter().map(|v| v as f64).collect()),
        (TypeChar::Int, 4) => Ok(f.into_vec::<i32>().map_err(err)?.into_iter().map(f64::from).collect()),
        (c, s) => Err(format!("unsupported .npy element type {c:?}{s}")),
    }
}

/// World coordinates to voxel coordinates.
pub fn to_voxel(world_from_voxel: DMat4, seeds_world: &[DVec3]) -> Vec<DVec3> {
    let inv = world_from_voxel.inverse();
    seeds_world.iter().map(|&p| inv.transform_point3(p)).collect()
}
