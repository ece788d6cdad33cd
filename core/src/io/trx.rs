//! TRX tractograms (`.trx`): a zip archive of little-endian arrays named by their shape and type, as
//! trx-python and the TRX specification write them.
//!
//! - `header.json`: `DIMENSIONS`, `VOXEL_TO_RASMM` (4x4), `NB_VERTICES`, `NB_STREAMLINES`;
//! - `positions.3.{float16,float32,float64}`: every point in RAS+ mm (voxel centres at integers);
//! - `offsets.{uint32,uint64}`: the first point of each streamline (`NB_STREAMLINES` entries, or one more
//!   ending with `NB_VERTICES`, as trx-python writes them);
//! - `dpv/NAME[.K].TYPE`, `dps/NAME[.K].TYPE`: values per point and per streamline (`K` components);
//! - `groups/NAME.uint32`: streamline indices; `dpg/` (values per group) is read past.
//!
//! Entries may be stored or deflated. Values per point and per streamline become the tractogram's scalars and
//! properties (as f32; a `K`-component array gives `NAME_0` .. `NAME_{K-1}`).

use std::io::{Read, Write};
use std::path::Path;

use glam::{DMat4, Vec3};

use super::Tractogram;
use crate::error::{Error, Result};

/// A TRX file's content besides the streamlines.
#[derive(Clone, Debug, PartialEq)]
pub struct TrxHeader {
    /// The reference grid: dimensions and voxel-to-RAS+ affine.
    pub dims: [usize; 3],
    /// `VOXEL_TO_RASMM`: the reference grid's voxel indices (integer = voxel centre) to RAS+ mm.
    pub voxel_to_rasmm: DMat4,
    /// Named groups of streamline indices.
    pub groups: Vec<(String, Vec<u32>)>,
}

/// The precision positions are written in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PositionType {
    /// `positions.3.float16`: half the size, steps of 1/16 mm at 64-128 mm from the origin.
    F16,
    /// `positions.3.float32` (the stream writer's default).
    F32,
    /// `positions.3.float64`.
    F64,
}

/// Reads a `.trx` file.
pub fn read(path: impl AsRef<Path>) -> Result<(Tractogram, TrxHeader)> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    read_bytes(&bytes, path)
}

/// One array of the archive: its name without type, components, element type.
struct Entry {
    base: String,
    components: usize,
    dtype: String,
    bytes: Vec<u8>,
}

/// Splits `dps/length.3.float32` into (`dps/length`, 3, `float32`).
pub(crate) fn parse_name(name: &str) -> Option<(String, usize, String)> {
    let (rest, dtype) = name.rsplit_once('.')?;
    match rest.rsplit_once('.') {
        Some((base, k)) if !base.ends_with('/') && k.parse::<usize>().is_ok() => {
            Some((base.to_string(), k.parse().ok()?, dtype.to_string()))
        }
        _ => Some((rest.to_string(), 1, dtype.to_string())),
    }
}

/// An element type of a TRX array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Dtype {
    I8,
    U8,
    I16,
    U16,
    F16,
    I32,
    U32,
    F32,
    I64,
    U64,
    F64,
}

impl Dtype {
    pub(crate) fn parse(s: &str) -> Option<Dtype> {
        Some(match s {
            "int8" => Dtype::I8,
            "uint8" | "bool" => Dtype::U8,
            "int16" => Dtype::I16,
            "uint16" => Dtype::U16,
            "float16" => Dtype::F16,
            "int32" => Dtype::I32,
            "uint32" => Dtype::U32,
            "float32" => Dtype::F32,
            "int64" => Dtype::I64,
            "uint64" => Dtype::U64,
            "float64" => Dtype::F64,
            _ => return None,
        })
    }

    pub(crate) fn size(self) -> usize {
        match self {
            Dtype::I8 | Dtype::U8 => 1,
            Dtype::I16 | Dtype::U16 | Dtype::F16 => 2,
            Dtype::I32 | Dtype::U32 | Dtype::F32 => 4,
            Dtype::I64 | Dtype::U64 | Dtype::F64 => 8,
        }
    }

    pub(crate) fn value(self, c: &[u8]) -> f64 {
        let a4 = || <[u8; 4]>::try_from(&c[..4]).unwrap_or_default();
        let a8 = || <[u8; 8]>::try_from(&c[..8]).unwrap_or_default();
        match self {
            Dtype::I8 => c[0] as i8 as f64,
            Dtype::U8 => c[0] as f64,
            Dtype::I16 => i16::from_le_bytes([c[0], c[1]]) as f64,
            Dtype::U16 => u16::from_le_bytes([c[0], c[1]]) as f64,
            Dtype::F16 => f16_to_f32(u16::from_le_bytes([c[0], c[1]])) as f64,
            Dtype::I32 => i32::from_le_bytes(a4()) as f64,
            Dtype::U32 => u32::from_le_bytes(a4()) as f64,
            Dtype::F32 => f32::from_le_bytes(a4()) as f64,
            Dtype::I64 => i64::from_le_bytes(a8()) as f64,
            Dtype::U64 => u64::from_le_bytes(a8()) as f64,
            Dtype::F64 => f64::from_le_bytes(a8()),
        }
    }
}

/// The values of a little-endian array of `dtype` as f64.
fn values(bytes: &[u8], dtype: &str) -> Option<Vec<f64>> {
    let dtype = Dtype::parse(dtype)?;
    let size = dtype.size();
    if !bytes.len().is_multiple_of(size) {
        return None;
    }
    Some(bytes.chunks_exact(size).map(|c| dtype.value(c)).collect())
}

/// The counts and grid of a TRX's header.json.
pub(crate) struct HeaderJson {
    pub n_vertices: usize,
    pub n_streamlines: usize,
    pub dims: [usize; 3],
    pub voxel_to_rasmm: DMat4,
}

/// Reads `NB_VERTICES`, `NB_STREAMLINES`, `DIMENSIONS` and `VOXEL_TO_RASMM` from a parsed header.json.
pub(crate) fn parse_header_json(header: &serde_json::Value, path: &Path) -> Result<HeaderJson> {
    let bad = |reason: String| Error::format(path, reason);
    let count = |key: &str| {
        header[key].as_u64().map(|n| n as usize).ok_or_else(|| bad(format!("header.json has no {key} count")))
    };
    let (n_vertices, n_streamlines) = (count("NB_VERTICES")?, count("NB_STREAMLINES")?);
    let dims: Vec<usize> = header["DIMENSIONS"]
        .as_array()
        .map(|a| a.iter().filter_map(|d| d.as_u64()).map(|d| d as usize).collect())
        .unwrap_or_default();
    let rows: Vec<Vec<f64>> = header["VOXEL_TO_RASMM"]
        .as_array()
        .map(|r| {
            r.iter()
                .map(|row| row.as_array().map_or(vec![], |c| c.iter().filter_map(|x| x.as_f64()).collect()))
                .collect()
        })
        .unwrap_or_default();
    if dims.len() != 3 || rows.len() != 4 || rows.iter().any(|r| r.len() != 4) {
        return Err(bad("header.json needs DIMENSIONS (3 numbers) and VOXEL_TO_RASMM (4x4)".into()));
    }
    let voxel_to_rasmm = DMat4::from_cols_array_2d(&std::array::from_fn(|c| std::array::from_fn(|r| rows[r][c])));
    Ok(HeaderJson { n_vertices, n_streamlines, dims: [dims[0], dims[1], dims[2]], voxel_to_rasmm })
}

/// [`read`] from a file's bytes (`path` names it in errors).
pub fn read_bytes(bytes: &[u8], path: &Path) -> Result<(Tractogram, TrxHeader)> {
    let bad = |reason: String| Error::format(path, reason);
    let mut archive = zip::ZipArchive::new(std::io::Cursor::new(bytes))
        .map_err(|e| bad(format!("not a TRX file (a zip archive of arrays): {e}")))?;
    let mut header_text = None;
    let mut entries = vec![];
    for i in 0..archive.len() {
        let mut f = archive.by_index(i).map_err(|e| bad(format!("entry {i} of the archive: {e}")))?;
        if f.is_dir() {
            continue;
        }
        let name = f.name().map_err(|e| bad(format!("entry {i}'s name: {e}")))?.trim_start_matches("./").to_string();
        // The declared size bounds what is read: a lying header cannot make us allocate more.
        let mut data = Vec::with_capacity((f.size() as usize).min(1 << 30));
        f.read_to_end(&mut data).map_err(|e| bad(format!("{name}: {e}")))?;
        if name == "header.json" {
            header_text = Some(String::from_utf8(data).map_err(|_| bad("header.json is not UTF-8 text".into()))?);
        } else if let Some((base, components, dtype)) = parse_name(&name) {
            entries.push(Entry { base, components, dtype, bytes: data });
        }
    }
    let header_text = header_text.ok_or_else(|| bad("no header.json in the archive".into()))?;
    let header: serde_json::Value =
        serde_json::from_str(&header_text).map_err(|e| bad(format!("header.json is not JSON: {e}")))?;
    let HeaderJson { n_vertices, n_streamlines, dims, voxel_to_rasmm } = parse_header_json(&header, path)?;

    let take = |base: &str| entries.iter().find(|e| e.base == base);
    let positions = take("positions").ok_or_else(|| bad("no positions array".into()))?;
    if positions.components != 3 || !matches!(positions.dtype.as_str(), "float16" | "float32" | "float64") {
        return Err(bad(format!(
            "positions must be 3 floats per point, not {} of {}",
            positions.components, positions.dtype
        )));
    }
    let p = values(&positions.bytes, &positions.dtype).ok_or_else(|| bad("positions: truncated array".into()))?;
    if p.len() != 3 * n_vertices {
        return Err(bad(format!("positions hold {} points, the header says {n_vertices}", p.len() / 3)));
    }
    let offsets = take("offsets").ok_or_else(|| bad("no offsets array".into()))?;
    if !matches!(offsets.dtype.as_str(), "uint32" | "uint64" | "int32" | "int64") {
        return Err(bad(format!("offsets must be integers, not {}", offsets.dtype)));
    }
    let mut o: Vec<usize> = values(&offsets.bytes, &offsets.dtype)
        .ok_or_else(|| bad("offsets: truncated array".into()))?
        .into_iter()
        .map(|x| x as usize)
        .collect();
    if o.len() == n_streamlines {
        o.push(n_vertices);
    }
    if o.len() != n_streamlines + 1
        || o.first().is_some_and(|f| *f != 0) && n_streamlines > 0
        || o.last() != Some(&n_vertices)
        || o.windows(2).any(|w| w[0] > w[1])
    {
        return Err(bad(format!(
            "offsets ({} entries) do not cut {n_vertices} points into {n_streamlines} streamlines in order",
            o.len()
        )));
    }
    let mut t = Tractogram::new();
    t.points = p.chunks_exact(3).map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32)).collect();
    t.offsets = o;
    let mut groups = vec![];
    for e in &entries {
        let (folder, name) = e.base.split_once('/').unwrap_or(("", &e.base));
        let expected = match folder {
            "dpv" => n_vertices,
            "dps" => n_streamlines,
            "groups" => 0,
            _ => continue,
        };
        let v = values(&e.bytes, &e.dtype).ok_or_else(|| bad(format!("{}: not an array of {}", e.base, e.dtype)))?;
        if folder == "groups" {
            if v.iter().any(|&i| i < 0.0 || i >= n_streamlines as f64) {
                return Err(bad(format!("group {name} names a streamline past {n_streamlines}")));
            }
            groups.push((name.to_string(), v.into_iter().map(|i| i as u32).collect()));
            continue;
        }
        if v.len() != expected * e.components {
            return Err(bad(format!("{}: {} values, expected {expected} x {}", e.base, v.len(), e.components)));
        }
        let target = if folder == "dpv" { &mut t.scalars } else { &mut t.properties };
        for k in 0..e.components {
            let label = if e.components == 1 { name.to_string() } else { format!("{name}_{k}") };
            target.push((label, v.iter().skip(k).step_by(e.components).map(|x| *x as f32).collect()));
        }
    }
    let header = TrxHeader { dims, voxel_to_rasmm, groups };
    Ok((t, header))
}

/// Writes `t` as `.trx` (entries stored, each on a 64-byte boundary, positions in `positions`, offsets as uint64
/// with the closing entry), with its scalars as `dpv/` and properties as `dps/` (float32), and `header`'s grid
/// and groups (a 1 mm grid covering the points without one).
pub fn write(
    path: impl AsRef<Path>,
    t: &Tractogram,
    header: Option<&TrxHeader>,
    positions: PositionType,
) -> Result<()> {
    let path = path.as_ref();
    let n = t.n_streamlines();
    if t.offsets.len() != n + 1 || t.offsets.last() != Some(&t.points.len()) {
        return Err(Error::Shape(format!("{}: offsets do not end at the {} points", path.display(), t.points.len())));
    }
    let (dims, affine) = match header {
        Some(h) => (h.dims, h.voxel_to_rasmm),
        None => {
            let lo = t.points.iter().copied().reduce(Vec3::min).unwrap_or(Vec3::ZERO).floor();
            let hi = t.points.iter().copied().reduce(Vec3::max).unwrap_or(Vec3::ZERO).ceil();
            ((hi - lo + 1.0).to_array().map(|v| v as usize), DMat4::from_translation(lo.as_dvec3()))
        }
    };
    let cols = affine.to_cols_array_2d();
    let rows: Vec<Vec<f64>> = (0..4).map(|r| (0..4).map(|c| cols[c][r]).collect()).collect();
    let json = serde_json::json!({
        "DIMENSIONS": dims,
        "VOXEL_TO_RASMM": rows,
        "NB_VERTICES": t.points.len(),
        "NB_STREAMLINES": n,
    });
    let mut files: Vec<(String, Vec<u8>)> = vec![("header.json".into(), json.to_string().into_bytes())];
    let coords = t.points.iter().flat_map(|p| p.to_array());
    let (suffix, bytes): (&str, Vec<u8>) = match positions {
        PositionType::F16 => ("float16", coords.flat_map(|x| f32_to_f16(x).to_le_bytes()).collect()),
        PositionType::F32 => ("float32", coords.flat_map(|x| x.to_le_bytes()).collect()),
        PositionType::F64 => ("float64", coords.flat_map(|x| f64::from(x).to_le_bytes()).collect()),
    };
    files.push((format!("positions.3.{suffix}"), bytes));
    files.push(("offsets.uint64".into(), t.offsets.iter().flat_map(|o| (*o as u64).to_le_bytes()).collect()));
    let arrays = |folder: &str, list: &[(String, Vec<f32>)], len: usize| -> Result<Vec<(String, Vec<u8>)>> {
        list.iter()
            .map(|(name, v)| {
                if v.len() != len || name.is_empty() || name.contains(['/', '\\']) {
                    return Err(Error::Shape(format!("{folder} '{name}': {} values for {len}", v.len())));
                }
                Ok((format!("{folder}/{name}.float32"), v.iter().flat_map(|x| x.to_le_bytes()).collect()))
            })
            .collect()
    };
    files.extend(arrays("dpv", &t.scalars, t.points.len())?);
    files.extend(arrays("dps", &t.properties, n)?);
    for (name, members) in header.map_or(&[][..], |h| &h.groups[..]) {
        if members.iter().any(|&i| i as usize >= n) {
            return Err(Error::Shape(format!("group {name} names a streamline past {n}")));
        }
        files.push((format!("groups/{name}.uint32"), members.iter().flat_map(|i| i.to_le_bytes()).collect()));
    }
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut zip = zip::ZipWriter::new(std::io::BufWriter::new(file));
    let options = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Stored)
        .large_file(t.points.len() * 24 > u32::MAX as usize);
    let zerr = |e: zip::result::ZipError| Error::io(path, std::io::Error::other(e));
    for (name, bytes) in files {
        // Arrays on a cache line's boundary, so that a reader can map them in place.
        zip.start_file(name, options.with_alignment(64)).map_err(zerr)?;
        zip.write_all(&bytes).map_err(|e| Error::io(path, e))?;
    }
    zip.finish().map_err(zerr)?.flush().map_err(|e| Error::io(path, e))?;
    Ok(())
}

/// IEEE half to single precision (subnormals, infinities and NaN included).
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0f32 } else { 1.0 };
    let exp = ((h >> 10) & 0x1f) as i32;
    let frac = (h & 0x3ff) as f32;
    sign * match exp {
        0 => frac * 2f32.powi(-24),
        31 if frac == 0.0 => f32::INFINITY,
        31 => f32::NAN,
        e => (1.0 + frac / 1024.0) * 2f32.powi(e - 15),
    }
}

/// Single to half precision, rounded to nearest with ties to even (as numpy's `astype(float16)`); beyond
/// the half range, infinity.
pub fn f32_to_f16(x: f32) -> u16 {
    let bits = x.to_bits();
    let sign = ((bits >> 16) & 0x8000) as u16;
    let exp = ((bits >> 23) & 0xff) as i32;
    let mant = bits & 0x7f_ffff;
    if exp == 0xff {
        return sign | 0x7c00 | if mant != 0 { 0x200 } else { 0 };
    }
    let e = exp - 127 + 15;
    if e >= 31 {
        return sign | 0x7c00;
    }
    if e <= 0 {
        // Subnormal half (or zero): the significand with its implicit bit, shifted into place, rounded.
        if e < -10 {
            return sign;
        }
        let m = mant | 0x80_0000;
        let shift = (14 - e) as u32;
        let half = m >> shift;
        let rest = m & ((1 << shift) - 1);
        let mid = 1 << (shift - 1);
        let round = rest > mid || (rest == mid && half & 1 == 1);
        return sign | (half + u32::from(round)) as u16;
    }
    let half = ((e as u32) << 10) | (mant >> 13);
    let rest = mant & 0x1fff;
    let round = rest > 0x1000 || (rest == 0x1000 && half & 1 == 1);
    // A carry out of the significand moves into the exponent, up to infinity: the bit layout does it.
    sign | (half + u32::from(round)) as u16
}
