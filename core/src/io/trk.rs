//! TrackVis `.trk` (versions 1 and 2, either endianness) reading and writing.
//!
//! Points on disk are in "voxmm" space: voxel indices times voxel size, with the origin at the *corner* of
//! the first voxel. As nibabel does, a point goes to RAS+ mm by: divide by voxel size, subtract 0.5 (corner
//! to centre), reorder/flip axes where `voxel_order` disagrees with the orientation of `vox_to_ras`, then
//! apply `vox_to_ras`. A zero `vox_to_ras` (version 1 files) is read as the identity and an empty
//! `voxel_order` as "LPS" (TrackVis' default), also as nibabel.
//!
//! Why not `trk-io`: 0.32 panics on truncated streamline data (`read_f32().unwrap()`), and a reader here
//! must return an error instead.

use std::path::Path;

use glam::{DMat4, DVec3, DVec4};
use rayon::prelude::*;

use super::tractogram::{Tractogram, axcodes, io_orientation};
use crate::error::{Error, Result};

const HDR: usize = 1000;

/// The header fields that place the streamlines in space.
#[derive(Clone, Debug, PartialEq)]
pub struct TrkHeader {
    /// The header's `version` (1 or 2; this crate writes 2).
    pub version: i32,
    /// Whether the file is big-endian (told by the byte order of `hdr_size`).
    pub big_endian: bool,
    /// Size of the reference grid in voxels, x, y, z.
    pub dims: [i16; 3],
    /// Voxel edge lengths in mm, x, y, z (checked positive).
    pub voxel_size: [f32; 3],
    /// Orientation of the voxel axes as three letters of R/L A/P S/I, upper case (e.g. "LAS"; "LPS" when empty).
    pub voxel_order: String,
    /// Row-major 4x4 as stored; see [`TrkHeader::rasmm_from_voxmm`].
    pub vox_to_ras: DMat4,
    /// Number of streamlines the header promises; 0 when not recorded (the file is read to its end).
    pub n_count: i32,
}

impl TrkHeader {
    /// The affine taking on-disk points to RAS+ mm (nibabel's `get_affine_trackvis_to_rasmm`).
    pub fn rasmm_from_voxmm(&self) -> DMat4 {
        let vs = DVec3::from_array(self.voxel_size.map(|v| v as f64));
        let voxel_from_voxmm = DMat4::from_translation(DVec3::splat(-0.5)) * DMat4::from_scale(1.0 / vs);
        let header_ornt = axcodes_to_ornt(&self.voxel_order);
        let affine_ornt = io_orientation(&self.vox_to_ras);
        // ornt_transform(header, affine) then inv_ornt_aff with the header's dims.
        let mut m = DMat4::ZERO;
        for (i, &(h_ax, h_flip)) in header_ornt.iter().enumerate() {
            let Some(j) = affine_ornt.iter().position(|&(a_ax, _)| a_ax == h_ax) else { continue };
            let flip = if h_flip == affine_ornt[j].1 { 1.0 } else { -1.0 };
            // output coordinate i reads input coordinate j (nibabel's undo_reorder row selection)
            let mut row = DVec4::ZERO;
            row[j] = flip;
            row[3] = if flip < 0.0 { self.dims[i] as f64 - 1.0 } else { 0.0 };
            set_row(&mut m, i, row);
        }
        set_row(&mut m, 3, DVec4::new(0.0, 0.0, 0.0, 1.0));
        self.vox_to_ras * m * voxel_from_voxmm
    }
}

fn set_row(m: &mut DMat4, r: usize, v: DVec4) {
    for c in 0..4 {
        m.col_mut(c)[r] = v[c];
    }
}

/// "LPS" -> [(0,-1),(1,-1),(2,1)]; unknown letters fall back to RAS for that axis.
fn axcodes_to_ornt(codes: &str) -> [(usize, f64); 3] {
    let mut out = [(0, 1.0), (1, 1.0), (2, 1.0)];
    for (i, c) in codes.chars().take(3).enumerate() {
        out[i] = match c.to_ascii_uppercase() {
            'R' => (0, 1.0),
            'L' => (0, -1.0),
            'A' => (1, 1.0),
            'P' => (1, -1.0),
            'S' => (2, 1.0),
            'I' => (2, -1.0),
            _ => out[i],
        };
    }
    out
}

struct Rd<'a> {
    b: &'a [u8],
    be: bool,
}
impl Rd<'_> {
    fn a<const N: usize>(&self, o: usize) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.b[o..o + N]);
        if self.be {
            a.reverse();
        }
        a
    }
    fn i16(&self, o: usize) -> i16 {
        i16::from_le_bytes(self.a(o))
    }
    fn i32(&self, o: usize) -> i32 {
        i32::from_le_bytes(self.a(o))
    }
    fn f32(&self, o: usize) -> f32 {
        f32::from_le_bytes(self.a(o))
    }
    /// Names of `n` values from the 10 name slots at `o`. A slot may read "name\0K" (nibabel's encoding
    /// of a K-valued scalar such as RGB colours): it then names K consecutive values `name_0..name_K-1`.
    fn names(&self, o: usize, n: usize) -> Vec<String> {
        let mut out = Vec::with_capacity(n);
        for slot in 0..10 {
            if out.len() >= n {
                break;
            }
            let s = &self.b[o + 20 * slot..o + 20 * slot + 20];
            let end = s.iter().position(|&c| c == 0).unwrap_or(20);
            let name = String::from_utf8_lossy(&s[..end]).into_owned();
            let rest = s.get(end + 1..).unwrap_or(&[]);
            let rend = rest.iter().position(|&c| c == 0).unwrap_or(rest.len());
            let count = std::str::from_utf8(&rest[..rend]).ok().and_then(|t| t.parse::<usize>().ok()).unwrap_or(1);
            if name.is_empty() {
                break;
            }
            if count > 1 {
                out.extend((0..count).map(|k| format!("{name}_{k}")));
            } else {
                out.push(name);
            }
        }
        out.truncate(n);
        while out.len() < n {
            out.push(format!("value_{}", out.len()));
        }
        out
    }
}

/// Reads a `.trk` file into RAS+ mm.
pub fn read(path: impl AsRef<Path>) -> Result<(Tractogram, TrkHeader)> {
    let path = path.as_ref();
    read_bytes(&std::fs::read(path).map_err(|e| Error::io(path, e))?, path)
}

/// A `.trk` header and the names of its values per point (scalars) and per streamline (properties).
#[derive(Clone, Debug, PartialEq)]
pub struct TrkLayout {
    /// The fields that place the streamlines in space.
    pub header: TrkHeader,
    /// Names of the values stored after each point.
    pub scalars: Vec<String>,
    /// Names of the values stored after each streamline.
    pub properties: Vec<String>,
}

/// Size of a `.trk` header in bytes; the streamlines follow it.
pub const HEADER_BYTES: usize = HDR;

/// Parses the 1000-byte header at the start of `b`; `path` names the file in errors.
pub fn parse_header(b: &[u8], path: &Path) -> Result<TrkLayout> {
    if b.len() < HDR {
        return Err(Error::format(path, format!("truncated TrackVis header: {} of 1000 bytes", b.len())));
    }
    if &b[0..5] != b"TRACK" {
        return Err(Error::format(path, "not a TrackVis file: it does not start with 'TRACK'"));
    }
    let le = i32::from_le_bytes(b[996..1000].try_into().unwrap_or_default());
    let be = i32::from_be_bytes(b[996..1000].try_into().unwrap_or_default());
    let big_endian = match (le, be) {
        (1000, _) => false,
        (_, 1000) => true,
        _ => return Err(Error::format(path, format!("hdr_size is {le}, not 1000: corrupt TrackVis header"))),
    };
    let r = Rd { b, be: big_endian };
    let dims = [r.i16(6), r.i16(8), r.i16(10)];
    let voxel_size = [r.f32(12), r.f32(16), r.f32(20)];
    if voxel_size.iter().any(|v| !v.is_finite() || *v <= 0.0) {
        return Err(Error::format(path, format!("voxel_size {voxel_size:?} must be positive")));
    }
    let n_scalars = r.i16(36);
    let n_props = r.i16(238);
    if !(0..=10).contains(&n_scalars) || !(0..=10).contains(&n_props) {
        return Err(Error::format(path, format!("n_scalars {n_scalars} / n_properties {n_props} outside 0..10")));
    }
    let mut m = [[0f64; 4]; 4];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = r.f32(440 + 16 * i + 4 * j) as f64;
        }
    }
    let mut vox_to_ras = DMat4::from_cols_array_2d(&m).transpose();
    if m[3][3] == 0.0 {
        vox_to_ras = DMat4::IDENTITY;
    }
    if !vox_to_ras.is_finite()
        || DMat4::from_cols(vox_to_ras.x_axis, vox_to_ras.y_axis, vox_to_ras.z_axis, DVec4::W).determinant() == 0.0
    {
        return Err(Error::format(path, "vox_to_ras is singular or not finite"));
    }
    let order_raw = &b[948..952];
    let end = order_raw.iter().position(|&c| c == 0).unwrap_or(4);
    let mut voxel_order = String::from_utf8_lossy(&order_raw[..end]).trim().to_uppercase();
    if voxel_order.is_empty() {
        voxel_order = "LPS".into();
    }
    if voxel_order.len() != 3 || !voxel_order.chars().all(|c| "RLAPSI".contains(c)) {
        return Err(Error::format(path, format!("voxel_order '{voxel_order}' is not three of R/L A/P S/I")));
    }
    let header =
        TrkHeader { version: r.i32(992), big_endian, dims, voxel_size, voxel_order, vox_to_ras, n_count: r.i32(988) };
    let scalars = r.names(38, n_scalars as usize);
    let properties = r.names(240, n_props as usize);
    Ok(TrkLayout { header, scalars, properties })
}

/// [`read`] from the file's bytes in memory (gzipped or not); `path` is the name errors use.
pub fn read_bytes(b: &[u8], path: &Path) -> Result<(Tractogram, TrkHeader)> {
    let b = &super::tractogram::gunzipped(b, path)?[..];
    let TrkLayout { header, scalars, properties } = parse_header(b, path)?;
    let r = Rd { b, be: header.big_endian };
    let to_ras = header.rasmm_from_voxmm();
    let (ns, np) = (scalars.len(), properties.len());
    let mut t = Tractogram::new();
    t.scalars = scalars.into_iter().map(|n| (n, Vec::new())).collect();
    t.properties = properties.into_iter().map(|n| (n, Vec::new())).collect();
    let mut o = HDR;
    let limit = if header.n_count > 0 { header.n_count as usize } else { usize::MAX };
    while o < b.len() && t.n_streamlines() < limit {
        if o + 4 > b.len() {
            return Err(Error::format(path, format!("truncated streamline count at byte {o}")));
        }
        let n = r.i32(o);
        if n < 0 {
            return Err(Error::format(
                path,
                format!("streamline {} has a negative point count {n}", t.n_streamlines()),
            ));
        }
        let n = n as usize;
        o += 4;
        let need = (n * (3 + ns) + np) * 4;
        if o + need > b.len() {
            return Err(Error::format(
                path,
                format!("streamline {} is truncated: needs {need} bytes, {} remain", t.n_streamlines(), b.len() - o),
            ));
        }
        for _ in 0..n {
            let p = DVec3::new(r.f32(o) as f64, r.f32(o + 4) as f64, r.f32(o + 8) as f64);
            t.points.push(to_ras.transform_point3(p).as_vec3());
            o += 12;
            for s in t.scalars.iter_mut() {
                s.1.push(r.f32(o));
                o += 4;
            }
        }
        for p in t.properties.iter_mut() {
            p.1.push(r.f32(o));
            o += 4;
        }
        t.offsets.push(t.points.len());
    }
    if header.n_count > 0 && t.n_streamlines() != header.n_count as usize {
        return Err(Error::format(
            path,
            format!("header promises {} streamlines, the file holds {}", header.n_count, t.n_streamlines()),
        ));
    }
    Ok((t, header))
}

/// The header of a version-2 little-endian `.trk` in the voxel grid of a reference image
/// (`world_from_voxel`, `dims`; the voxel order is the affine's), with the names of the values per point and
/// per streamline (at most 10 each, names cut to 19 bytes) and the streamline count: the header and its
/// 1000 bytes.
pub fn encode_header(
    world_from_voxel: DMat4,
    dims: [usize; 3],
    scalars: &[&str],
    properties: &[&str],
    n_count: i32,
) -> (TrkHeader, Vec<u8>) {
    let vs = DVec3::new(
        world_from_voxel.x_axis.truncate().length(),
        world_from_voxel.y_axis.truncate().length(),
        world_from_voxel.z_axis.truncate().length(),
    );
    let header = TrkHeader {
        version: 2,
        big_endian: false,
        dims: dims.map(|d| d.min(i16::MAX as usize) as i16),
        voxel_size: vs.to_array().map(|v| v as f32),
        voxel_order: axcodes(&world_from_voxel),
        vox_to_ras: world_from_voxel,
        n_count,
    };
    let mut h = vec![0u8; HDR];
    let put = |h: &mut Vec<u8>, o: usize, b: &[u8]| h[o..o + b.len()].copy_from_slice(b);
    put(&mut h, 0, b"TRACK\0");
    for i in 0..3 {
        put(&mut h, 6 + 2 * i, &header.dims[i].to_le_bytes());
        put(&mut h, 12 + 4 * i, &header.voxel_size[i].to_le_bytes());
    }
    put(&mut h, 36, &(scalars.len().min(10) as i16).to_le_bytes());
    for (i, n) in scalars.iter().take(10).enumerate() {
        put(&mut h, 38 + 20 * i, &n.as_bytes()[..n.len().min(19)]);
    }
    put(&mut h, 238, &(properties.len().min(10) as i16).to_le_bytes());
    for (i, n) in properties.iter().take(10).enumerate() {
        put(&mut h, 240 + 20 * i, &n.as_bytes()[..n.len().min(19)]);
    }
    let rows = header.vox_to_ras.transpose().to_cols_array();
    for (k, v) in rows.iter().enumerate() {
        put(&mut h, 440 + 4 * k, &(*v as f32).to_le_bytes());
    }
    put(&mut h, 948, header.voxel_order.as_bytes());
    put(&mut h, 988, &header.n_count.to_le_bytes());
    put(&mut h, 992, &2i32.to_le_bytes());
    put(&mut h, 996, &1000i32.to_le_bytes());
    (header, h)
}

/// Byte offset of `n_count` (i32) in a `.trk` header.
pub const N_COUNT_OFFSET: u64 = 988;

/// Writes a version-2 `.trk` (little endian) for streamlines in RAS+ mm, in the voxel grid of a reference
/// image (`world_from_voxel`, `dims`); the header's voxel order is the reference affine's.
pub fn write(path: impl AsRef<Path>, t: &Tractogram, world_from_voxel: DMat4, dims: [usize; 3]) -> Result<()> {
    let path = path.as_ref();
    if t.scalars.len() > 10 || t.properties.len() > 10 {
        return Err(Error::Param("TrackVis stores at most 10 scalars and 10 properties".into()));
    }
    let scalars: Vec<&str> = t.scalars.iter().map(|(n, _)| n.as_str()).collect();
    let properties: Vec<&str> = t.properties.iter().map(|(n, _)| n.as_str()).collect();
    let (header, h) = encode_header(world_from_voxel, dims, &scalars, &properties, t.n_streamlines() as i32);
    let voxmm_from_ras = header.rasmm_from_voxmm().inverse();
    // The body is laid out in parallel: every streamline's byte range is known in advance.
    let (ns, np) = (t.scalars.len(), t.properties.len());
    let per_point = 4 * (3 + ns);
    let bytes_of = |i: usize| 4 + per_point * (t.offsets[i + 1] - t.offsets[i]) + 4 * np;
    let n = t.n_streamlines();
    let mut out = h;
    out.resize(HDR + (0..n).map(bytes_of).sum::<usize>(), 0);
    let write_one = |i: usize, dst: &mut [u8]| {
        let (a, z) = (t.offsets[i], t.offsets[i + 1]);
        let mut w = 0;
        let mut put = |b: [u8; 4]| {
            dst[w..w + 4].copy_from_slice(&b);
            w += 4;
        };
        put(((z - a) as i32).to_le_bytes());
        for k in a..z {
            let p = voxmm_from_ras.transform_point3(t.points[k].as_dvec3());
            for c in p.to_array() {
                put((c as f32).to_le_bytes());
            }
            for (_, s) in &t.scalars {
                put(s.get(k).copied().unwrap_or(0.0).to_le_bytes());
            }
        }
        for (_, p) in &t.properties {
            put(p.get(i).copied().unwrap_or(0.0).to_le_bytes());
        }
    };
    // Blocks of streamlines, each a contiguous slice of the output.
    const BLOCK: usize = 256;
    let mut slices = Vec::with_capacity(n.div_ceil(BLOCK));
    let mut rest = &mut out[HDR..];
    for b in (0..n).step_by(BLOCK) {
        let len: usize = (b..(b + BLOCK).min(n)).map(bytes_of).sum();
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(len);
        slices.push((b, head));
        rest = tail;
    }
    slices.into_par_iter().for_each(|(b, mut dst)| {
        for i in b..(b + BLOCK).min(n) {
            let (head, tail) = std::mem::take(&mut dst).split_at_mut(bytes_of(i));
            write_one(i, head);
            dst = tail;
        }
    });
    super::tractogram::write_file(path, out)
}
