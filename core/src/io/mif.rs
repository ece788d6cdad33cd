//! MRtrix3 images (`.mif`, `.mif.gz`): a text header (`mrtrix image`, `key: value` lines, `END`) and the voxel
//! data in the same file at the offset `file: . OFFSET` names.
//!
//! Header keys read: `dim`, `vox`, `layout` (per axis the rank of its stride, 0 the fastest, and its sign: a
//! negative axis is stored from its last index down), `datatype` (`Int8`, `UInt8`, `(U)Int16/32`, `Float32/64`,
//! with `LE`/`BE`; no suffix means little endian), `transform` (three rows of a rigid 3x4 matrix in scanner
//! mm, applied to voxel index times voxel size), `scaling` (offset, scale) and `dw_scheme` (kept, as rows).
//! Images read into the NIfTI storage order of [`Volume`] (x fastest, then y, z, volumes), so a `.mif` and the
//! NIfTI `mrconvert` makes of it give the same volume and affine.

use std::io::{Read, Write};
use std::path::Path;

use glam::{DMat4, DVec3, DVec4};

use crate::error::{Error, Result};
use crate::volume::{Scalar, Volume};

/// What a `.mif` header holds beyond the data.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MifHeader {
    /// `dim`: the size of each axis in header order (x, y, z, then volumes; at least 3).
    pub dims: Vec<usize>,
    /// `vox`: the voxel size of each axis as written, in mm for the spatial ones (the affine takes 1 mm where a
    /// value is not finite and positive).
    pub vox: Vec<f64>,
    /// `datatype` as written, e.g. `Float32LE`, `UInt16BE`.
    pub datatype: String,
    /// The diffusion scheme (`dw_scheme`): x, y, z, b per volume, in scanner coordinates.
    pub dw_scheme: Vec<[f64; 4]>,
    /// Every other key, in order.
    pub other: Vec<(String, String)>,
}

/// Whether a path names a `.mif` or `.mif.gz` image.
pub fn is_mif(path: &Path) -> bool {
    let name = path.file_name().map(|n| n.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    name.ends_with(".mif") || name.ends_with(".mif.gz")
}

/// The `dw_scheme` rows of a `.mif` (x, y, z in scanner axes, b), read from its header alone (the file is read
/// up to the header's END line, through gzip when compressed).
pub fn read_dw_scheme(path: impl AsRef<Path>) -> Result<Vec<[f64; 4]>> {
    let path = path.as_ref();
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut reader = std::io::BufReader::new(file);
    let gz = std::io::BufRead::fill_buf(&mut reader).map_err(|e| Error::io(path, e))?.starts_with(&[0x1f, 0x8b]);
    let mut stream: Box<dyn Read> =
        if gz { Box::new(flate2::read::MultiGzDecoder::new(reader)) } else { Box::new(reader) };
    let mut bytes = Vec::new();
    let mut chunk = [0u8; 4096];
    loop {
        let n = stream.read(&mut chunk).map_err(|e| Error::format(path, format!("reading the header: {e}")))?;
        bytes.extend_from_slice(&chunk[..n]);
        if find(&bytes, b"\nEND\n").is_some() || n == 0 || bytes.len() > 64 << 20 {
            break;
        }
    }
    header_text(&bytes, path)?
        .lines()
        .filter_map(|l| l.split_once(':').filter(|(k, _)| k.trim() == "dw_scheme").map(|(_, v)| v.trim()))
        .map(|v| dw_scheme_row(v, path))
        .collect()
}

/// The header of a `.mif`'s (uncompressed) bytes, up to its END line, checked to start as MRtrix's do.
fn header_text<'a>(bytes: &'a [u8], path: &Path) -> Result<&'a str> {
    let bad = |m: &str| Error::format(path, m);
    if !bytes.starts_with(b"mrtrix image") {
        return Err(bad("not an MRtrix image: the first line is not 'mrtrix image'"));
    }
    let end = find(bytes, b"\nEND\n").ok_or_else(|| bad("the header has no END line"))?;
    std::str::from_utf8(&bytes[..end]).map_err(|_| bad("the header is not text"))
}

/// The comma-separated numbers of header key `key`'s value `v`.
fn numbers(key: &str, v: &str, path: &Path) -> Result<Vec<f64>> {
    v.split(',')
        .map(|x| {
            x.trim().parse::<f64>().map_err(|_| Error::format(path, format!("'{key}: {v}' is not a list of numbers")))
        })
        .collect()
}

/// One `dw_scheme` row: x, y, z, b.
fn dw_scheme_row(v: &str, path: &Path) -> Result<[f64; 4]> {
    <[f64; 4]>::try_from(numbers("dw_scheme", v, path)?)
        .map_err(|_| Error::format(path, format!("dw_scheme row '{v}' does not have 4 values")))
}

/// Reads a `.mif` or `.mif.gz` (gzip told by its bytes) into NIfTI storage order, values scaled by `scaling`,
/// the affine `transform` times the voxel sizes (voxel indices to scanner RAS+ mm), with its header.
pub fn read<T: Scalar>(path: impl AsRef<Path>) -> Result<(Volume<T>, MifHeader)> {
    let path = path.as_ref();
    let raw = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    read_bytes(raw, path)
}

/// [`read`] from a file's bytes (gzipped or not).
pub fn read_bytes<T: Scalar>(raw: Vec<u8>, path: &Path) -> Result<(Volume<T>, MifHeader)> {
    let bytes = if raw.starts_with(&[0x1f, 0x8b]) {
        let mut out = Vec::with_capacity(raw.len() * 4);
        flate2::read::MultiGzDecoder::new(&raw[..])
            .read_to_end(&mut out)
            .map_err(|e| Error::format(path, format!("corrupt gzip stream: {e}")))?;
        out
    } else {
        raw
    };
    let bad = |m: String| Error::format(path, m);
    let text = header_text(&bytes, path)?;
    let mut h = MifHeader::default();
    let (mut layout, mut rows, mut scaling, mut offset) = (None, Vec::new(), None, None);
    for line in text.lines().skip(1) {
        let Some((key, value)) = line.split_once(':') else { continue };
        let (key, value) = (key.trim(), value.trim());
        let numbers = |v: &str| numbers(key, v, path);
        match key {
            "dim" => h.dims = numbers(value)?.iter().map(|&d| d as usize).collect(),
            "vox" => h.vox = numbers(value)?,
            "layout" => layout = Some(value.to_string()),
            "datatype" => h.datatype = value.to_string(),
            "transform" => rows.push(numbers(value)?),
            "scaling" => scaling = Some(numbers(value)?),
            "dw_scheme" => h.dw_scheme.push(dw_scheme_row(value, path)?),
            "file" => {
                let mut parts = value.split_whitespace();
                if parts.next() != Some(".") {
                    return Err(bad(format!("the data is in another file ('{value}'): only single-file .mif is read")));
                }
                offset = Some(
                    parts
                        .next()
                        .and_then(|o| o.parse::<usize>().ok())
                        .ok_or_else(|| bad(format!("bad file offset in '{value}'")))?,
                );
            }
            _ => h.other.push((key.to_string(), value.to_string())),
        }
    }
    let nd = h.dims.len();
    if nd < 3 || h.dims.contains(&0) {
        return Err(bad(format!("dim {:?}: an image needs at least 3 non-zero dimensions", h.dims)));
    }
    let layout = layout.ok_or_else(|| bad("the header has no layout".into()))?;
    let axes: Vec<(usize, bool)> = layout
        .split(',')
        .map(|a| {
            let a = a.trim();
            let (neg, rank) = match a.as_bytes().first() {
                Some(b'-') => (true, &a[1..]),
                Some(b'+') => (false, &a[1..]),
                _ => (false, a),
            };
            rank.parse::<usize>().map(|r| (r, neg)).map_err(|_| bad(format!("bad layout '{layout}'")))
        })
        .collect::<Result<_>>()?;
    let mut ranks: Vec<usize> = axes.iter().map(|a| a.0).collect();
    ranks.sort_unstable();
    if axes.len() != nd || ranks != (0..nd).collect::<Vec<_>>() {
        return Err(bad(format!("layout '{layout}' does not order the {nd} axes")));
    }
    let (elem, decode) = datatype(&h.datatype).ok_or_else(|| bad(format!("unsupported datatype '{}'", h.datatype)))?;
    let n: usize = h.dims.iter().product();
    let offset = offset.ok_or_else(|| bad("the header has no 'file' entry".into()))?;
    if bytes.len() < offset + n * elem {
        return Err(bad(format!(
            "truncated: {:?} {} needs {} bytes after offset {offset}, the file holds {}",
            h.dims,
            h.datatype,
            n * elem,
            bytes.len().saturating_sub(offset)
        )));
    }
    // The storage stride of each axis, in elements: ranks order the axes, fastest first.
    let mut stride = vec![0usize; nd];
    let mut s = 1;
    for r in 0..nd {
        let a = axes.iter().position(|x| x.0 == r).unwrap_or(0);
        stride[a] = s;
        s *= h.dims[a];
    }
    let (off, scale) = match scaling.as_deref() {
        Some([o, k]) if k.is_finite() && *k != 0.0 => (*o, *k),
        _ => (0.0, 1.0),
    };
    let data_bytes = &bytes[offset..offset + n * elem];
    let mut data = Vec::with_capacity(n);
    let mut index = vec![0usize; nd];
    for _ in 0..n {
        let at: usize = (0..nd).map(|a| stride[a] * if axes[a].1 { h.dims[a] - 1 - index[a] } else { index[a] }).sum();
        data.push(T::from_f64(off + scale * decode(&data_bytes[at * elem..(at + 1) * elem])));
        for a in 0..nd {
            index[a] += 1;
            if index[a] < h.dims[a] {
                break;
            }
            index[a] = 0;
        }
    }
    let vox = |a: usize| h.vox.get(a).copied().filter(|v| v.is_finite() && *v > 0.0).unwrap_or(1.0);
    let mut m = DMat4::IDENTITY;
    if rows.len() >= 3 {
        if rows.iter().take(3).any(|r| r.len() != 4) {
            return Err(bad("a transform row does not have 4 values".into()));
        }
        let col = |c: usize| DVec4::new(rows[0][c], rows[1][c], rows[2][c], if c == 3 { 1.0 } else { 0.0 });
        m = DMat4::from_cols(col(0), col(1), col(2), col(3));
    }
    let world_from_voxel = m * DMat4::from_scale(DVec3::new(vox(0), vox(1), vox(2)));
    Ok((Volume { shape: h.dims.clone(), data, world_from_voxel }, h))
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

type Decode = fn(&[u8]) -> f64;

/// Bytes per element and the decoder of a `.mif` datatype.
fn datatype(name: &str) -> Option<(usize, Decode)> {
    macro_rules! le {
        ($t:ty) => {
            |b: &[u8]| <$t>::from_le_bytes(b.try_into().unwrap_or_default()) as f64
        };
    }
    macro_rules! be {
        ($t:ty) => {
            |b: &[u8]| <$t>::from_be_bytes(b.try_into().unwrap_or_default()) as f64
        };
    }
    Some(match name.trim() {
        "Int8" => (1, |b: &[u8]| b[0] as i8 as f64),
        "UInt8" => (1, |b: &[u8]| b[0] as f64),
        "Int16" | "Int16LE" => (2, le!(i16)),
        "Int16BE" => (2, be!(i16)),
        "UInt16" | "UInt16LE" => (2, le!(u16)),
        "UInt16BE" => (2, be!(u16)),
        "Int32" | "Int32LE" => (4, le!(i32)),
        "Int32BE" => (4, be!(i32)),
        "UInt32" | "UInt32LE" => (4, le!(u32)),
        "UInt32BE" => (4, be!(u32)),
        "Float32" | "Float32LE" => (4, le!(f32)),
        "Float32BE" => (4, be!(f32)),
        "Float64" | "Float64LE" => (8, le!(f64)),
        "Float64BE" => (8, be!(f64)),
        _ => return None,
    })
}

/// Writes a volume as `.mif` (gzipped when the name ends in `.gz`): Float32LE, layout `+0,+1,+2,...` (x
/// fastest, as the volume is stored), the affine split into voxel sizes and a transform whose rotation columns
/// are unit vectors, and `extra` header lines (`dw_scheme` rows, comments).
pub fn write<T: Scalar>(path: impl AsRef<Path>, vol: &Volume<T>, extra: &[(String, String)]) -> Result<()> {
    let path = path.as_ref();
    let nd = vol.shape.len();
    if nd < 3 || vol.shape.iter().product::<usize>() != vol.data.len() {
        return Err(Error::Shape(format!(
            "cannot write an image of shape {:?} and {} values",
            vol.shape,
            vol.data.len()
        )));
    }
    let a = vol.world_from_voxel;
    let cols = [a.x_axis.truncate(), a.y_axis.truncate(), a.z_axis.truncate()];
    let vox: Vec<f64> = cols.iter().map(|c| c.length()).collect();
    if vox.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
        return Err(Error::Shape("the affine has a zero or non-finite voxel axis".into()));
    }
    let mut header = String::from("mrtrix image\n");
    let list = |v: &[String]| v.join(",");
    header += &format!("dim: {}\n", list(&vol.shape.iter().map(|d| d.to_string()).collect::<Vec<_>>()));
    let mut voxes: Vec<String> = vox.iter().map(|v| format!("{v}")).collect();
    voxes.extend((3..nd).map(|_| "1".to_string()));
    header += &format!("vox: {}\n", list(&voxes));
    header += &format!("layout: {}\n", list(&(0..nd).map(|a| format!("+{a}")).collect::<Vec<_>>()));
    header += "datatype: Float32LE\n";
    for r in 0..3 {
        let row: Vec<String> =
            (0..3).map(|c| format!("{}", cols[c][r] / vox[c])).chain([format!("{}", a.w_axis[r])]).collect();
        header += &format!("transform: {}\n", list(&row));
    }
    for (k, v) in extra {
        header += &format!("{k}: {v}\n");
    }
    // "file: . OFFSET" with the offset counting this line itself, then END, padded to a multiple of 16.
    let fixed = header.len() + "file: . \nEND\n".len();
    let mut offset = (fixed + 8).div_ceil(16) * 16;
    loop {
        let len = fixed + offset.to_string().len();
        if len <= offset {
            break;
        }
        offset += 16;
    }
    header += &format!("file: . {offset}\nEND\n");
    let mut out = header.into_bytes();
    out.resize(offset, 0);
    out.reserve(vol.data.len() * 4);
    for v in &vol.data {
        out.extend_from_slice(&(v.to_f64() as f32).to_le_bytes());
    }
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut w = std::io::BufWriter::new(file);
    let res = if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("gz")) {
        let mut enc = flate2::write::GzEncoder::new(w, flate2::Compression::fast());
        enc.write_all(&out).and_then(|_| enc.finish().map(|_| ()))
    } else {
        w.write_all(&out).and_then(|_| w.flush())
    };
    res.map_err(|e| Error::io(path, e))
}

/// Reads an image by its name: `.mif` / `.mif.gz` as MRtrix, anything else as NIfTI.
pub fn read_image<T: Scalar>(path: impl AsRef<Path>) -> Result<Volume<T>> {
    let path = path.as_ref();
    if is_mif(path) { read(path).map(|(v, _)| v) } else { super::nifti::read(path).map(|(v, _)| v) }
}

/// [`read_image`] from a file's bytes, `path` naming it (for the format and for messages): what the asset
/// loaders use.
pub fn read_image_bytes<T: Scalar>(bytes: Vec<u8>, path: &Path) -> Result<Volume<T>> {
    if is_mif(path) {
        read_bytes(bytes, path).map(|(v, _)| v)
    } else {
        super::nifti::read_bytes(bytes, path).map(|(v, _)| v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn oblique() -> DMat4 {
        let r = DMat4::from_rotation_z(0.3) * DMat4::from_rotation_x(-0.2);
        DMat4::from_translation(DVec3::new(-40.0, 12.5, 7.0)) * r * DMat4::from_scale(DVec3::new(2.0, 2.5, 3.0))
    }

    /// A 4D image written and read back: the same shape, values and affine (oblique, anisotropic voxels), plain
    /// and gzipped, with its extra header lines kept.
    #[test]
    fn images_round_trip() {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-mif-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let mut v = Volume::<f32>::zeros(&[4, 3, 2, 5], oblique());
        v.data.iter_mut().enumerate().for_each(|(i, x)| *x = i as f32 * 0.25 - 7.0);
        let extra = vec![("dw_scheme".to_string(), "0,0,1,1000".to_string())];
        for name in ["a.mif", "a.mif.gz"] {
            let p = dir.join(name);
            write(&p, &v, &extra).unwrap();
            let (back, h) = read::<f32>(&p).unwrap();
            assert_eq!(back.shape, v.shape);
            assert_eq!(back.data, v.data);
            let worst = (0..16)
                .map(|i| (back.world_from_voxel.to_cols_array()[i] - v.world_from_voxel.to_cols_array()[i]).abs())
                .fold(0.0, f64::max);
            assert!(worst < 1e-12, "{worst}");
            assert_eq!(h.dw_scheme, vec![[0.0, 0.0, 1.0, 1000.0]]);
        }
    }

    /// Layouts other than x-fastest (MRtrix's own `-0,-1,+2,+3`, volumes fastest `+1,+2,+3,+0`), big-endian
    /// and integer data with scaling all read into the same volume.
    #[test]
    fn strides_signs_types_and_scaling() {
        let dims = [3usize, 2, 2, 2];
        let value = |i: [usize; 4]| (i[0] + 10 * i[1] + 100 * i[2] + 1000 * i[3]) as f64;
        let n: usize = dims.iter().product();
        let build = |layout: [(usize, bool); 4],
                     dtype: &str,
                     enc: &dyn Fn(f64) -> Vec<u8>,
                     scaling: Option<(f64, f64)>| {
            let mut stride = [0usize; 4];
            let mut s = 1;
            for r in 0..4 {
                let a = layout.iter().position(|x| x.0 == r).unwrap();
                stride[a] = s;
                s *= dims[a];
            }
            let mut data = vec![0u8; 0];
            let mut slots = vec![0f64; n];
            for x in 0..3 {
                for y in 0..2 {
                    for z in 0..2 {
                        for t in 0..2 {
                            let i = [x, y, z, t];
                            let at: usize =
                                (0..4).map(|a| stride[a] * if layout[a].1 { dims[a] - 1 - i[a] } else { i[a] }).sum();
                            let stored = match scaling {
                                Some((o, k)) => (value(i) - o) / k,
                                None => value(i),
                            };
                            slots[at] = stored;
                        }
                    }
                }
            }
            for v in slots {
                data.extend(enc(v));
            }
            let layout_s: Vec<String> =
                layout.iter().map(|(r, neg)| format!("{}{r}", if *neg { '-' } else { '+' })).collect();
            let mut h = format!(
                "mrtrix image\ndim: 3,2,2,2\nvox: 1,1,1,1\nlayout: {}\ndatatype: {dtype}\ntransform: 1,0,0,0\ntransform: 0,1,0,0\ntransform: 0,0,1,0\n",
                layout_s.join(",")
            );
            if let Some((o, k)) = scaling {
                h += &format!("scaling: {o},{k}\n");
            }
            h += "file: . 256\nEND\n";
            let mut out = h.into_bytes();
            out.resize(256, 0);
            out.extend(data);
            out
        };
        let f32le = |v: f64| (v as f32).to_le_bytes().to_vec();
        let f64be = |v: f64| v.to_be_bytes().to_vec();
        let i16le = |v: f64| (v.round() as i16).to_le_bytes().to_vec();
        let cases = [
            build([(0, true), (1, true), (2, false), (3, false)], "Float32LE", &f32le, None),
            build([(1, false), (2, false), (3, false), (0, false)], "Float64BE", &f64be, None),
            build([(0, false), (1, false), (2, true), (3, false)], "Int16LE", &i16le, Some((-500.0, 0.5))),
        ];
        for bytes in cases {
            let (v, _) = read_bytes::<f64>(bytes, Path::new("x.mif")).unwrap();
            for (k, got) in v.data.iter().enumerate() {
                let i = [k % 3, (k / 3) % 2, (k / 6) % 2, k / 12];
                assert_eq!(*got, value(i), "voxel {i:?}");
            }
        }
    }

    /// Bad files: a wrong magic line, a missing END, a truncated body, a layout that misses an axis, an
    /// unknown datatype, data in another file: each a clear error.
    #[test]
    fn malformed_headers_are_errors() {
        let ok = "mrtrix image\ndim: 2,2,2\nvox: 1,1,1\nlayout: +0,+1,+2\ndatatype: Float32LE\nfile: . 128\nEND\n";
        let body = |h: &str, n: usize| {
            let mut b = h.as_bytes().to_vec();
            b.resize(128, 0);
            b.extend(vec![0u8; n]);
            b
        };
        assert!(read_bytes::<f32>(body(ok, 32), Path::new("ok.mif")).is_ok());
        let cases = [
            (body(&ok.replace("mrtrix image", "nifti"), 32), "not an MRtrix image"),
            (body(&ok.replace("END\n", ""), 32), "no END"),
            (body(ok, 8), "truncated"),
            (body(&ok.replace("+0,+1,+2", "+0,+0,+2"), 32), "does not order"),
            (body(&ok.replace("Float32LE", "Bit"), 32), "unsupported datatype"),
            (body(&ok.replace("file: . 128", "file: other.dat 0"), 32), "another file"),
        ];
        for (bytes, want) in cases {
            let e = read_bytes::<f32>(bytes, Path::new("bad.mif")).unwrap_err().to_string();
            assert!(e.contains(want) && e.contains("bad.mif"), "{e}");
        }
    }
}
