//! NIfTI-1 and NIfTI-2 (`.nii`, `.nii.gz`) reading and writing.
//!
//! Why not the `nifti` crate: version 0.18 reads NIfTI-1 only (it rejects `sizeof_hdr = 540`), and its
//! writer needs ndarray. Both header versions differ only in field widths and offsets, so one decoder
//! serves both here. The affine follows the standard's precedence: sform (code > 0), else qform
//! (code > 0), else the "method 1" diagonal of pixdim.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use glam::{DMat3, DMat4, DQuat, DVec3, DVec4};

use crate::error::{Error, Result};
use crate::volume::{Scalar, Volume};

/// Which header fields produced `world_from_voxel`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AffineSource {
    /// The sform rows (`srow_x/y/z`), taken when `sform_code > 0`.
    Sform,
    /// The qform (quaternion, offset and pixdim; the standard's method 2), taken when only `qform_code > 0`.
    Qform,
    /// Neither code set: the voxel sizes `pixdim[1..4]` on the diagonal, no rotation or translation (method 1).
    Pixdim,
}

/// The header fields a user or a writer needs; the rest of the header is not kept.
#[derive(Clone, Debug)]
pub struct NiftiHeader {
    /// 1 or 2.
    pub version: u8,
    /// Whether the file is big-endian (told by the byte order of `sizeof_hdr`).
    pub big_endian: bool,
    /// The NIfTI datatype code (2 uint8, 4 int16, 16 float32, 64 float64, 128 rgb24, ...: [`datatype_name`]).
    pub datatype: i16,
    /// `dim[1..=dim[0]]`: the size of each of the 1 to 7 axes, x first.
    pub shape: Vec<usize>,
    /// `pixdim` as stored: `[0]` qfac (negative flips the qform's third axis), `[1..4]` voxel sizes, `[4]` the
    /// time step, in the units of `xyzt_units`.
    pub pixdim: [f64; 8],
    /// Scaling of the stored values, `value = stored * scl_slope + scl_inter`; 0 or not finite means none.
    pub scl_slope: f64,
    /// Offset added after `scl_slope` (unused when the slope means no scaling).
    pub scl_inter: f64,
    /// The qform's space: 0 unknown, 1 scanner, 2 aligned, 3 Talairach, 4 MNI.
    pub qform_code: i32,
    /// The sform's space, coded as `qform_code`.
    pub sform_code: i32,
    /// Which fields gave `world_from_voxel` (sform, else qform, else pixdim).
    pub affine_source: AffineSource,
    /// Voxel indices (integer = voxel centre) to world RAS+ mm, in the space the sform or qform code names.
    pub world_from_voxel: DMat4,
    /// Units of `pixdim`: space in bits 0-2 (1 m, 2 mm, 3 µm), time in bits 3-5 (8 s, 16 ms, 24 µs).
    pub xyzt_units: i32,
    /// The free-text description (up to 80 bytes, trimmed); `fascicle fit` records the SH basis here.
    pub descrip: String,
    /// NIfTI intent (e.g. 1005 symmetric matrix, 1007 vector, 2003 RGB) and its 16-character name.
    pub intent_code: i32,
    /// The intent's name (up to 16 bytes, trimmed; e.g. one containing "peak" marks a peaks image).
    pub intent_name: String,
    /// Byte offset of the voxel data from the start of the (decompressed) file.
    pub vox_offset: u64,
}

/// Datatype codes of the NIfTI standard that can be decoded to a real scalar.
fn datatype_size(code: i16) -> Option<usize> {
    Some(match code {
        2 | 256 => 1,          // uint8, int8
        4 | 512 => 2,          // int16, uint16
        8 | 768 | 16 => 4,     // int32, uint32, float32
        64 | 1024 | 1280 => 8, // float64, int64, uint64
        128 => 3,              // rgb24
        2304 => 4,             // rgba32
        _ => return None,
    })
}

/// Human-readable datatype name, for `fascicle info` and error messages.
pub fn datatype_name(code: i16) -> &'static str {
    match code {
        2 => "uint8",
        4 => "int16",
        8 => "int32",
        16 => "float32",
        32 => "complex64",
        64 => "float64",
        128 => "rgb24",
        256 => "int8",
        512 => "uint16",
        768 => "uint32",
        1024 => "int64",
        1280 => "uint64",
        1536 => "float128",
        1792 => "complex128",
        2048 => "complex256",
        2304 => "rgba32",
        _ => "unknown",
    }
}

/// Reads a whole file, gunzipping it when it starts with the gzip magic (whatever its name says).
pub(crate) fn read_maybe_gz(path: &Path) -> Result<Vec<u8>> {
    let raw = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    gunzip_if_gz(raw, path)
}

/// `raw` itself, or its decompressed content when it starts with the gzip magic (`name` for errors).
fn gunzip_if_gz(raw: Vec<u8>, path: &Path) -> Result<Vec<u8>> {
    if raw.len() >= 2 && raw[0] == 0x1f && raw[1] == 0x8b {
        let mut out = Vec::with_capacity(raw.len() * 4);
        flate2::read::MultiGzDecoder::new(&raw[..])
            .read_to_end(&mut out)
            .map_err(|e| Error::format(path, format!("corrupt gzip stream: {e}")))?;
        Ok(out)
    } else {
        Ok(raw)
    }
}

/// Little helper reading fixed-offset fields of either endianness.
struct Fields<'a> {
    b: &'a [u8],
    be: bool,
}
impl Fields<'_> {
    fn arr<const N: usize>(&self, o: usize) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.b[o..o + N]);
        if self.be {
            a.reverse();
        }
        a
    }
    fn i16(&self, o: usize) -> i16 {
        i16::from_le_bytes(self.arr(o))
    }
    fn i32(&self, o: usize) -> i32 {
        i32::from_le_bytes(self.arr(o))
    }
    fn i64(&self, o: usize) -> i64 {
        i64::from_le_bytes(self.arr(o))
    }
    fn f32(&self, o: usize) -> f64 {
        f32::from_le_bytes(self.arr(o)) as f64
    }
    fn f64(&self, o: usize) -> f64 {
        f64::from_le_bytes(self.arr(o))
    }
    fn text(&self, o: usize, n: usize) -> String {
        let s = &self.b[o..o + n];
        let end = s.iter().position(|&c| c == 0).unwrap_or(n);
        String::from_utf8_lossy(&s[..end]).trim().to_string()
    }
}

/// Parses a NIfTI-1 or NIfTI-2 header from the start of `bytes`.
pub fn parse_header(bytes: &[u8], path: &Path) -> Result<NiftiHeader> {
    if bytes.len() < 4 {
        return Err(Error::format(path, "file too short for a NIfTI header"));
    }
    let le = i32::from_le_bytes(bytes[0..4].try_into().unwrap_or_default());
    let be = i32::from_be_bytes(bytes[0..4].try_into().unwrap_or_default());
    let (version, big_endian, hdr_len) = match (le, be) {
        (348, _) => (1u8, false, 348usize),
        (_, 348) => (1, true, 348),
        (540, _) => (2, false, 540),
        (_, 540) => (2, true, 540),
        _ => {
            return Err(Error::format(path, format!("not a NIfTI file: sizeof_hdr is {le}, expected 348 or 540")));
        }
    };
    if bytes.len() < hdr_len {
        return Err(Error::format(
            path,
            format!("truncated NIfTI-{version} header: {} of {hdr_len} bytes", bytes.len()),
        ));
    }
    let f = Fields { b: bytes, be: big_endian };
    let mut dim = [0i64; 8];
    let mut pixdim = [0f64; 8];
    let (datatype, vox_offset, scl_slope, scl_inter, qform_code, sform_code, quat, qoff, srow, xyzt, descrip);
    let (intent_code, intent_name);
    if version == 1 {
        let magic = &bytes[344..348];
        if magic != b"n+1\0" && magic != b"ni1\0" {
            return Err(Error::format(path, "NIfTI-1 magic is neither 'n+1' nor 'ni1' (Analyze files are not read)"));
        }
        if magic == b"ni1\0" {
            return Err(Error::format(
                path,
                "two-file NIfTI (.hdr/.img, magic 'ni1') is not supported; convert to .nii",
            ));
        }
        for (i, d) in dim.iter_mut().enumerate() {
            *d = f.i16(40 + 2 * i) as i64;
        }
        for (i, p) in pixdim.iter_mut().enumerate() {
            *p = f.f32(76 + 4 * i);
        }
        datatype = f.i16(70);
        let off = f.f32(108);
        vox_offset = if off.is_finite() && off >= 0.0 { off as u64 } else { u64::MAX };
        scl_slope = f.f32(112);
        scl_inter = f.f32(116);
        xyzt = bytes[123] as i32;
        descrip = f.text(148, 80);
        intent_code = f.i16(68) as i32;
        intent_name = f.text(328, 16);
        qform_code = f.i16(252) as i32;
        sform_code = f.i16(254) as i32;
        quat = [f.f32(256), f.f32(260), f.f32(264)];
        qoff = [f.f32(268), f.f32(272), f.f32(276)];
        srow = [0, 1, 2].map(|r| [0, 1, 2, 3].map(|c| f.f32(280 + 16 * r + 4 * c)));
    } else {
        if &bytes[4..8] != b"n+2\0" {
            return Err(Error::format(path, "NIfTI-2 magic is not 'n+2'"));
        }
        datatype = f.i16(12);
        for (i, d) in dim.iter_mut().enumerate() {
            *d = f.i64(16 + 8 * i);
        }
        for (i, p) in pixdim.iter_mut().enumerate() {
            *p = f.f64(104 + 8 * i);
        }
        let off = f.i64(168);
        vox_offset = if off >= 0 { off as u64 } else { u64::MAX };
        scl_slope = f.f64(176);
        scl_inter = f.f64(184);
        descrip = f.text(240, 80);
        intent_code = f.i32(504);
        intent_name = f.text(508, 16);
        qform_code = f.i32(344);
        sform_code = f.i32(348);
        quat = [f.f64(352), f.f64(360), f.f64(368)];
        qoff = [f.f64(376), f.f64(384), f.f64(392)];
        srow = [0, 1, 2].map(|r| [0, 1, 2, 3].map(|c| f.f64(400 + 32 * r + 8 * c)));
        xyzt = f.i32(500);
    }
    let ndim = dim[0];
    if !(1..=7).contains(&ndim) {
        return Err(Error::format(path, format!("dim[0] = {ndim}: a NIfTI image has 1 to 7 dimensions")));
    }
    let mut shape = Vec::with_capacity(ndim as usize);
    for (i, &d) in dim.iter().enumerate().skip(1).take(ndim as usize) {
        if d < 1 {
            return Err(Error::format(path, format!("dim[{i}] = {d}: every dimension must be at least 1")));
        }
        shape.push(d as usize);
    }
    if datatype_size(datatype).is_none() {
        return Err(Error::format(
            path,
            format!("datatype {datatype} ({}) cannot be read as a real scalar", datatype_name(datatype)),
        ));
    }
    if vox_offset == u64::MAX || vox_offset < hdr_len as u64 {
        return Err(Error::format(path, format!("vox_offset must be at least {hdr_len}")));
    }
    let (world_from_voxel, affine_source) = if sform_code > 0 {
        let m = srow;
        let a = DMat4::from_cols(
            DVec4::new(m[0][0], m[1][0], m[2][0], 0.0),
            DVec4::new(m[0][1], m[1][1], m[2][1], 0.0),
            DVec4::new(m[0][2], m[1][2], m[2][2], 0.0),
            DVec4::new(m[0][3], m[1][3], m[2][3], 1.0),
        );
        (a, AffineSource::Sform)
    } else if qform_code > 0 {
        (qform_affine(quat, qoff, &pixdim), AffineSource::Qform)
    } else {
        let z = |v: f64| if v > 0.0 && v.is_finite() { v } else { 1.0 };
        (DMat4::from_diagonal(DVec4::new(z(pixdim[1]), z(pixdim[2]), z(pixdim[3]), 1.0)), AffineSource::Pixdim)
    };
    if !world_from_voxel.is_finite() || world_from_voxel.determinant() == 0.0 {
        return Err(Error::format(path, format!("the {affine_source:?} affine is singular or not finite")));
    }
    Ok(NiftiHeader {
        version,
        big_endian,
        datatype,
        shape,
        pixdim,
        scl_slope,
        scl_inter,
        qform_code,
        sform_code,
        affine_source,
        world_from_voxel,
        xyzt_units: xyzt,
        descrip,
        intent_code,
        intent_name,
        vox_offset,
    })
}

/// The qform affine of the NIfTI standard (method 2): rotation from the quaternion (b, c, d), voxel sizes
/// from pixdim, and qfac = pixdim[0] flipping the third axis when negative.
fn qform_affine(q: [f64; 3], offset: [f64; 3], pixdim: &[f64; 8]) -> DMat4 {
    let [b, c, d] = q;
    let a2 = 1.0 - (b * b + c * c + d * d);
    let (a, b, c, d) = if a2 < 1e-7 {
        // The standard: a = 0 and (b, c, d) renormalised (a 180 degree rotation).
        let n = (b * b + c * c + d * d).sqrt().max(f64::MIN_POSITIVE);
        (0.0, b / n, c / n, d / n)
    } else {
        (a2.sqrt(), b, c, d)
    };
    let r = DMat3::from_quat(DQuat::from_xyzw(b, c, d, a));
    let qfac = if pixdim[0] < 0.0 { -1.0 } else { 1.0 };
    let s = DVec3::new(pixdim[1].abs(), pixdim[2].abs(), qfac * pixdim[3].abs());
    let m = r * DMat3::from_diagonal(s);
    DMat4::from_cols(
        m.x_axis.extend(0.0),
        m.y_axis.extend(0.0),
        m.z_axis.extend(0.0),
        DVec4::new(offset[0], offset[1], offset[2], 1.0),
    )
}

/// Reads only the header of a NIfTI file: the first 540 bytes (decompressing no more than that of a `.gz`).
pub fn read_header(path: impl AsRef<Path>) -> Result<NiftiHeader> {
    let path = path.as_ref();
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut magic = [0u8; 2];
    let n = file.read(&mut magic).map_err(|e| Error::io(path, e))?;
    use std::io::Seek;
    file.seek(std::io::SeekFrom::Start(0)).map_err(|e| Error::io(path, e))?;
    let mut bytes = Vec::with_capacity(540);
    let res = if n == 2 && magic == [0x1f, 0x8b] {
        flate2::read::MultiGzDecoder::new(file).take(540).read_to_end(&mut bytes)
    } else {
        file.take(540).read_to_end(&mut bytes)
    };
    res.map_err(|e| Error::format(path, format!("corrupt gzip stream: {e}")))?;
    parse_header(&bytes, path)
}

/// Reads a NIfTI-1/2 file into a volume of `T`, decoding any real datatype and applying scl_slope/inter.
pub fn read<T: Scalar>(path: impl AsRef<Path>) -> Result<(Volume<T>, NiftiHeader)> {
    let path = path.as_ref();
    decode(&read_maybe_gz(path)?, path)
}

/// [`read`] from the bytes of a `.nii` or `.nii.gz` file already in memory (an asset loader's reader);
/// `name` is the path errors name.
pub fn read_bytes<T: Scalar>(bytes: Vec<u8>, name: impl AsRef<Path>) -> Result<(Volume<T>, NiftiHeader)> {
    let name = name.as_ref();
    decode(&gunzip_if_gz(bytes, name)?, name)
}

fn decode<T: Scalar>(bytes: &[u8], path: &Path) -> Result<(Volume<T>, NiftiHeader)> {
    let h = parse_header(bytes, path)?;
    let elem = datatype_size(h.datatype).unwrap_or(1);
    let n: usize = h
        .shape
        .iter()
        .try_fold(1usize, |acc, &d| acc.checked_mul(d))
        .ok_or_else(|| Error::format(path, "image dimensions overflow"))?;
    let need = n.checked_mul(elem).ok_or_else(|| Error::format(path, "image size overflows"))?;
    let start = h.vox_offset as usize;
    let available = bytes.len().saturating_sub(start);
    if available < need {
        return Err(Error::format(
            path,
            format!(
                "truncated NIfTI: the header ({:?} {}) needs {need} bytes of voxel data after offset {start}, the file holds {available}",
                h.shape,
                datatype_name(h.datatype)
            ),
        ));
    }
    let raw = &bytes[start..start + need];
    let (slope, inter) = if h.scl_slope != 0.0 && h.scl_slope.is_finite() {
        (h.scl_slope, if h.scl_inter.is_finite() { h.scl_inter } else { 0.0 })
    } else {
        (1.0, 0.0)
    };
    let be = h.big_endian;
    macro_rules! decode {
        ($t:ty) => {{
            const S: usize = std::mem::size_of::<$t>();
            raw.chunks_exact(S)
                .map(|c| {
                    let mut a = [0u8; S];
                    a.copy_from_slice(c);
                    let v = if be { <$t>::from_be_bytes(a) } else { <$t>::from_le_bytes(a) };
                    T::from_f64(v as f64 * slope + inter)
                })
                .collect::<Vec<T>>()
        }};
    }
    if let 128 | 2304 = h.datatype {
        // Packed colour: r g b (a) bytes per voxel; read as 3 (or 4) volumes of 0..255 (the header's shape
        // plus a last axis of components).
        let k = elem;
        let data: Vec<T> = (0..k).flat_map(|c| raw.iter().skip(c).step_by(k).map(|&b| T::from_f64(b as f64))).collect();
        let mut shape = h.shape.clone();
        shape.truncate(3);
        shape.resize(3, 1);
        if h.shape.iter().skip(3).product::<usize>() > 1 {
            return Err(Error::format(path, "an RGB image with more than one volume is not supported"));
        }
        shape.push(k);
        return Ok((Volume { shape, data, world_from_voxel: h.world_from_voxel }, h));
    }
    let data = match h.datatype {
        2 => decode!(u8),
        256 => decode!(i8),
        4 => decode!(i16),
        512 => decode!(u16),
        8 => decode!(i32),
        768 => decode!(u32),
        16 => decode!(f32),
        64 => decode!(f64),
        1024 => decode!(i64),
        1280 => decode!(u64),
        other => return Err(Error::format(path, format!("unsupported datatype {other}"))),
    };
    Ok((Volume { shape: h.shape.clone(), data, world_from_voxel: h.world_from_voxel }, h))
}

/// On-disk element type for writing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WriteType {
    /// uint8 (datatype 2): values rounded and clamped to 0..=255.
    U8,
    /// float32 (datatype 16).
    F32,
    /// float64 (datatype 64).
    F64,
}

/// Writes a volume as NIfTI-1 (gzipped when the name ends in `.gz`), with the affine as sform and qform
/// (code 1, scanner anatomical). The qform carries the rotation part of the affine; where the affine has
/// shear, the qform is the nearest rigid approximation and readers use the sform, as the standard says.
pub fn write<T: Scalar>(path: impl AsRef<Path>, vol: &Volume<T>, ty: WriteType) -> Result<()> {
    write_with(path, vol, ty, &WriteMeta::default())
}

/// What a written header records beyond the data and affine.
#[derive(Clone, Debug, PartialEq)]
pub struct WriteMeta {
    /// 1 scanner, 2 aligned, 3 Talairach, 4 MNI (the codes of the input, to keep them).
    pub sform_code: i16,
    /// The qform's space, coded as `sform_code`. Defaults to 1 (scanner).
    pub qform_code: i16,
    /// NIfTI intent code (0 none, 1005 symmetric matrix, 1007 vector, 2003 RGB vector). Defaults to 0.
    pub intent_code: i16,
    /// Up to 15 characters.
    pub intent_name: String,
    /// Up to 79 characters.
    pub descrip: String,
}

impl Default for WriteMeta {
    fn default() -> Self {
        Self { sform_code: 1, qform_code: 1, intent_code: 0, intent_name: String::new(), descrip: "fascicle".into() }
    }
}

impl WriteMeta {
    /// The codes, intent and description of a header that was read (to write a derived image in its space).
    pub fn from_header(h: &NiftiHeader) -> Self {
        let code = |c: i32| if (1..=4).contains(&c) { c as i16 } else { 1 };
        Self {
            sform_code: code(h.sform_code),
            qform_code: code(h.qform_code),
            intent_code: i16::try_from(h.intent_code).unwrap_or(0),
            intent_name: h.intent_name.clone(),
            descrip: h.descrip.clone(),
        }
    }
}

/// [`write()`] with the header's codes, intent and description given.
pub fn write_with<T: Scalar>(path: impl AsRef<Path>, vol: &Volume<T>, ty: WriteType, meta: &WriteMeta) -> Result<()> {
    let path = path.as_ref();
    if vol.shape.is_empty() || vol.shape.len() > 7 {
        return Err(Error::Shape(format!("cannot write a {}-dimensional NIfTI image", vol.shape.len())));
    }
    if vol.shape.iter().any(|&d| d > i16::MAX as usize) {
        return Err(Error::Shape(format!("dimensions {:?} exceed NIfTI-1's 32767 limit", vol.shape)));
    }
    if vol.shape.iter().product::<usize>() != vol.data.len() {
        return Err(Error::Shape(format!("shape {:?} does not match {} values", vol.shape, vol.data.len())));
    }
    let mut h = vec![0u8; 352];
    let put = |h: &mut Vec<u8>, o: usize, b: &[u8]| h[o..o + b.len()].copy_from_slice(b);
    put(&mut h, 0, &348i32.to_le_bytes());
    put(&mut h, 40, &(vol.shape.len() as i16).to_le_bytes());
    for (i, &d) in vol.shape.iter().enumerate() {
        put(&mut h, 42 + 2 * i, &(d as i16).to_le_bytes());
    }
    for i in vol.shape.len()..7 {
        put(&mut h, 42 + 2 * i, &1i16.to_le_bytes());
    }
    let (code, bitpix): (i16, i16) = match ty {
        WriteType::U8 => (2, 8),
        WriteType::F32 => (16, 32),
        WriteType::F64 => (64, 64),
    };
    put(&mut h, 70, &code.to_le_bytes());
    put(&mut h, 72, &bitpix.to_le_bytes());
    let a = vol.world_from_voxel;
    let cols = [a.x_axis.truncate(), a.y_axis.truncate(), a.z_axis.truncate()];
    let zooms = cols.map(|c| c.length());
    // qform: rotation of the polar decomposition (columns normalised, made proper by qfac).
    let mut r = DMat3::from_cols(cols[0] / zooms[0], cols[1] / zooms[1], cols[2] / zooms[2]);
    let qfac = if r.determinant() < 0.0 {
        r.z_axis = -r.z_axis;
        -1.0f32
    } else {
        1.0
    };
    let q = DQuat::from_mat3(&crate::linalg::polar_rotation(r));
    let q = if q.w < 0.0 { -q } else { q };
    put(&mut h, 76, &qfac.to_le_bytes());
    for (i, z) in zooms.iter().enumerate() {
        put(&mut h, 80 + 4 * i, &(*z as f32).to_le_bytes());
    }
    for i in 4..8 {
        put(&mut h, 76 + 4 * i, &1f32.to_le_bytes());
    }
    put(&mut h, 108, &352f32.to_le_bytes());
    put(&mut h, 112, &1f32.to_le_bytes());
    h[123] = 2 | 8; // mm, seconds
    let text = |t: &str, n: usize| t.as_bytes()[..t.len().min(n)].to_vec();
    put(&mut h, 148, &text(&meta.descrip, 79));
    put(&mut h, 68, &meta.intent_code.to_le_bytes());
    put(&mut h, 328, &text(&meta.intent_name, 15));
    put(&mut h, 252, &meta.qform_code.to_le_bytes());
    put(&mut h, 254, &meta.sform_code.to_le_bytes());
    for (i, v) in [q.x, q.y, q.z, a.w_axis.x, a.w_axis.y, a.w_axis.z].iter().enumerate() {
        put(&mut h, 256 + 4 * i, &(*v as f32).to_le_bytes());
    }
    for r in 0..3 {
        for c in 0..4 {
            put(&mut h, 280 + 16 * r + 4 * c, &(a.col(c)[r] as f32).to_le_bytes());
        }
    }
    put(&mut h, 344, b"n+1\0");
    let mut out = h;
    out.reserve(vol.data.len() * 8);
    for v in &vol.data {
        let x = v.to_f64();
        match ty {
            WriteType::U8 => out.push(x.round().clamp(0.0, 255.0) as u8),
            WriteType::F32 => out.extend_from_slice(&(x as f32).to_le_bytes()),
            WriteType::F64 => out.extend_from_slice(&x.to_le_bytes()),
        }
    }
    let gz = path.extension().is_some_and(|e| e == "gz");
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut w = std::io::BufWriter::new(file);
    let res = if gz {
        let mut enc = flate2::write::GzEncoder::new(w, flate2::Compression::fast());
        enc.write_all(&out).and_then(|_| enc.finish().map(|_| ()))
    } else {
        w.write_all(&out).and_then(|_| w.flush())
    };
    res.map_err(|e| Error::io(PathBuf::from(path), e))
}
