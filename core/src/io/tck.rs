//! MRtrix `.tck` reading and writing.
//!
//! A text header (`mrtrix tracks`, then `key: value` lines, then `END`) names the data offset
//! (`file: . OFFSET`) and type (`datatype: Float32LE|Float32BE|Float64LE|Float64BE`). The data are point
//! triples in scanner RAS+ mm; a NaN triple ends a streamline, an Inf triple ends the file. A key repeated
//! over several lines (multi-line fields) keeps all its values, joined by newlines.

use std::path::Path;

use glam::Vec3;

use super::tractogram::Tractogram;
use crate::error::{Error, Result};

/// Header key-value pairs in file order (repeated keys merged).
pub type TckHeader = Vec<(String, String)>;

/// Reads a `.tck` file.
pub fn read(path: impl AsRef<Path>) -> Result<(Tractogram, TckHeader)> {
    let path = path.as_ref();
    read_bytes(&std::fs::read(path).map_err(|e| Error::io(path, e))?, path)
}

/// Where a `.tck` file's data lie and how they are stored, from its header.
#[derive(Clone, Debug)]
pub struct TckLayout {
    /// Header key-value pairs in file order.
    pub header: TckHeader,
    /// Byte offset of the first point (`file: . OFFSET`).
    pub offset: usize,
    /// Bytes per coordinate: 4 (Float32) or 8 (Float64).
    pub size: usize,
    /// Big-endian data.
    pub big_endian: bool,
}

/// Parses the header at the start of `b` (which must hold it whole, up to its `END` line); `path` names the
/// file in errors.
pub fn parse_header(b: &[u8], path: &Path) -> Result<TckLayout> {
    parse_header_of(b, path, "mrtrix tracks")
}

/// [`parse_header`] of a file of MRtrix's track family whose first line is `magic` (`mrtrix tracks`, or
/// `mrtrix track scalars` for a `.tsf`).
pub fn parse_header_of(b: &[u8], path: &Path, magic: &str) -> Result<TckLayout> {
    let what = if magic == "mrtrix tracks" { "tracks" } else { "track scalars" };
    let magic_bytes = magic.as_bytes();
    // MRtrix's own writers (tckgen) pad the first line with spaces, so that it can be rewritten in place.
    let first_eol = b.iter().take(4096).position(|&c| c == b'\n');
    let first_ok = first_eol.is_some_and(|e| {
        b[..e].starts_with(magic_bytes) && b[magic_bytes.len()..e].iter().all(|c| matches!(c, b' ' | b'\t' | b'\r'))
    });
    let Some(first_eol) = first_eol.filter(|_| first_ok) else {
        return Err(Error::format(path, format!("not an MRtrix {what} file: the first line is not '{magic}'")));
    };
    let mut header: TckHeader = Vec::new();
    let mut pos = first_eol + 1;
    let mut ended = false;
    while pos < b.len() {
        let eol = b[pos..].iter().position(|&c| c == b'\n').map(|i| pos + i);
        let Some(eol) = eol else { break };
        let line = String::from_utf8_lossy(&b[pos..eol]).trim().to_string();
        pos = eol + 1;
        if line == "END" {
            ended = true;
            break;
        }
        if line.is_empty() {
            continue;
        }
        let Some((k, v)) = line.split_once(':') else {
            // A line without a key continues the previous field (multi-line values, e.g. long commands).
            match header.last_mut() {
                Some((_, prev)) => {
                    prev.push('\n');
                    prev.push_str(&line);
                    continue;
                }
                None => return Err(Error::format(path, format!("header line '{line}' is not 'key: value'"))),
            }
        };
        let (k, v) = (k.trim().to_string(), v.trim().to_string());
        match header.iter_mut().find(|(hk, _)| *hk == k) {
            Some((_, hv)) => {
                hv.push('\n');
                hv.push_str(&v);
            }
            None => header.push((k, v)),
        }
    }
    if !ended {
        return Err(Error::format(path, "the header has no END line"));
    }
    let get = |k: &str| header.iter().find(|(hk, _)| hk == k).map(|(_, v)| v.as_str());
    let file = get("file").ok_or_else(|| Error::format(path, "the header has no 'file' entry"))?;
    let offset: usize = match file.split_whitespace().collect::<Vec<_>>().as_slice() {
        [".", off] => off.parse().map_err(|_| Error::format(path, format!("bad data offset in 'file: {file}'")))?,
        _ => return Err(Error::format(path, format!("'file: {file}': only data in the same file ('.') is supported"))),
    };
    let dtype = get("datatype").ok_or_else(|| Error::format(path, "the header has no 'datatype' entry"))?;
    let (size, be) = match dtype {
        "Float32LE" => (4, false),
        "Float32BE" => (4, true),
        "Float64LE" => (8, false),
        "Float64BE" => (8, true),
        other => return Err(Error::format(path, format!("datatype '{other}' is not one of Float32/64 LE/BE"))),
    };
    if offset < pos {
        return Err(Error::format(path, format!("data offset {offset} lies inside the header (it ends at {pos})")));
    }
    Ok(TckLayout { header, offset, size, big_endian: be })
}

/// The number at byte `o` of `b`, `size` bytes (4: Float32, 8: Float64) in the given byte order, as a file of
/// MRtrix's track family stores it (`.tck` coordinates, `.tsf` values). `b` must hold `o + size` bytes.
pub fn value_at(b: &[u8], o: usize, size: usize, big_endian: bool) -> f64 {
    if size == 4 {
        let a: [u8; 4] = b[o..o + 4].try_into().unwrap_or_default();
        f64::from(if big_endian { f32::from_be_bytes(a) } else { f32::from_le_bytes(a) })
    } else {
        let a: [u8; 8] = b[o..o + 8].try_into().unwrap_or_default();
        if big_endian { f64::from_be_bytes(a) } else { f64::from_le_bytes(a) }
    }
}

/// [`read`] from the file's bytes in memory (gzipped or not); `path` is the name errors use.
pub fn read_bytes(b: &[u8], path: &Path) -> Result<(Tractogram, TckHeader)> {
    let b = &super::tractogram::gunzipped(b, path)?[..];
    let TckLayout { header, offset, size, big_endian: be } = parse_header(b, path)?;
    if offset > b.len() {
        return Err(Error::format(
            path,
            format!("data offset {offset} lies outside the data (the file is {} bytes)", b.len()),
        ));
    }
    let read = |o: usize| value_at(b, o, size, be);
    let mut t = Tractogram::new();
    let mut o = offset;
    let mut cur = t.points.len();
    while o + 3 * size <= b.len() {
        let p = [read(o), read(o + size), read(o + 2 * size)];
        o += 3 * size;
        if p.iter().any(|v| v.is_infinite()) {
            break;
        }
        if p.iter().any(|v| v.is_nan()) {
            // Every NaN triplet ends a streamline, an empty one too (MRtrix counts those: `tckgen` writes
            // them for seeds that tracked nowhere).
            t.offsets.push(t.points.len());
            cur = t.points.len();
            continue;
        }
        t.points.push(Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32));
    }
    if t.points.len() > cur {
        // A last streamline without its NaN terminator (file cut short): keep what is there.
        t.offsets.push(t.points.len());
    }
    // `count` is advisory: MRtrix writes it when a run ends, and files from other tools (matlab_nan.tck
    // says 615000 and holds 1) get it wrong. The data decide; `fascicle info` shows both.
    Ok((t, header))
}

/// The bytes of a `.tck` header (Float32LE) with the given extra entries (`file`, `datatype`, `count` and
/// `total_count` are the writer's own) and `count`, padded to the data offset; and the byte offset of the count's
/// ten digits (so that a streaming writer can patch it).
pub fn header_bytes(extra: &[(String, String)], count: usize) -> (Vec<u8>, u64) {
    header_bytes_of("mrtrix tracks", extra, count)
}

/// [`header_bytes`] for a file of MRtrix's track family whose first line is `magic`.
pub fn header_bytes_of(magic: &str, extra: &[(String, String)], count: usize) -> (Vec<u8>, u64) {
    let mut head = format!("{magic}\n");
    for (k, v) in extra {
        if ["file", "datatype", "count", "total_count"].contains(&k.as_str()) {
            continue;
        }
        for line in v.lines() {
            head.push_str(&format!("{k}: {line}\n"));
        }
    }
    head.push_str("datatype: Float32LE\n");
    let count_at = (head.len() + "count: ".len()) as u64;
    head.push_str(&format!("count: {count:010}\n"));
    // The offset line contains its own length: iterate to a fixed point.
    let mut offset = head.len() + 20;
    loop {
        let total = head.len() + format!("file: . {offset}\n").len() + 4;
        if total <= offset {
            break;
        }
        offset = total;
    }
    let mut out = head.into_bytes();
    out.extend_from_slice(format!("file: . {offset}\nEND\n").as_bytes());
    out.resize(offset, 0);
    (out, count_at)
}

/// Appends the streamlines of `t` as `.tck` data (Float32LE points, a NaN triple after each streamline).
pub fn encode_streamlines(out: &mut Vec<u8>, t: &Tractogram) {
    out.reserve(12 * (t.points.len() + t.n_streamlines()));
    for s in t.iter() {
        for p in s {
            for c in p.to_array() {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
        for _ in 0..3 {
            out.extend_from_slice(&f32::NAN.to_le_bytes());
        }
    }
}

/// Writes a `.tck` file (Float32LE) with the given extra header entries.
pub fn write(path: impl AsRef<Path>, t: &Tractogram, extra: &[(String, String)]) -> Result<()> {
    let path = path.as_ref();
    let (mut out, _) = header_bytes(extra, t.n_streamlines());
    encode_streamlines(&mut out, t);
    for _ in 0..3 {
        out.extend_from_slice(&f32::INFINITY.to_le_bytes());
    }
    super::tractogram::write_file(path, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every NaN triplet ends a streamline: consecutive ones are empty streamlines, counted as MRtrix counts
    /// them, and they survive a write and read.
    #[test]
    fn empty_streamlines_are_kept() {
        let mut b = b"mrtrix tracks\ndatatype: Float32LE\nfile: . 64\nEND\n".to_vec();
        b.resize(64, 0);
        let nan = [f32::NAN; 3];
        for p in [[1.0, 2.0, 3.0], nan, nan, [4.0, 5.0, 6.0], [7.0, 8.0, 9.0], nan, nan, [f32::INFINITY; 3]] {
            p.iter().for_each(|v| b.extend(v.to_le_bytes()));
        }
        let (t, _) = read_bytes(&b, Path::new("empty.tck")).unwrap();
        assert_eq!(t.offsets, vec![0, 1, 1, 3, 3]);
        let tmp_path = tempfile::tempdir().unwrap();
        let path = tmp_path.path().join("fascicle-empty.tck");
        write(&path, &t, &[]).unwrap();
        assert_eq!(read(&path).unwrap().0, t);
        std::fs::remove_file(path).ok();
    }
}
