//! MRtrix track scalar files (`.tsf`): one value per point of a `.tck`'s streamlines, in its order, as
//! `tcksample` and `tsfmult` write them.
//!
//! The header is a `.tck`'s (first line `mrtrix track scalars`, `key: value` lines, `END`; `datatype` Float32 or
//! Float64, LE or BE; `file: . OFFSET`); the data are single values, a NaN after each streamline and an Inf at the
//! end. [`TrackScalars::check_against`] is `tsfvalidate`'s check: as many streamlines as the tractogram, each
//! with as many values as it has points.

use std::path::Path;

use super::tck::{self, TckHeader, TckLayout};
use super::tractogram::Tractogram;
use crate::error::{Error, Result};

const MAGIC: &str = "mrtrix track scalars";

/// The values of a `.tsf`: `values[offsets[i]..offsets[i + 1]]` belong to streamline `i`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TrackScalars {
    /// `n_streamlines + 1` offsets into `values`.
    pub offsets: Vec<usize>,
    /// One value per point, streamline after streamline.
    pub values: Vec<f32>,
    /// Header entries in file order (`timestamp`, `count`, ...).
    pub header: TckHeader,
}

impl TrackScalars {
    /// Values laid out as `t`'s points, from `value(streamline, point)`.
    pub fn for_tractogram(t: &Tractogram, value: impl Fn(usize, usize) -> f32) -> Self {
        let values = (0..t.n_streamlines())
            .flat_map(|s| (0..t.streamline(s).len()).map(move |k| (s, k)))
            .map(|(s, k)| value(s, k));
        Self { offsets: t.offsets.clone(), values: values.collect(), header: Vec::new() }
    }

    /// The number of streamlines.
    pub fn n_streamlines(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// The values of streamline `i`.
    pub fn streamline(&self, i: usize) -> &[f32] {
        &self.values[self.offsets[i]..self.offsets[i + 1]]
    }

    /// Fails (naming `path`, the `.tsf`) unless these values match `t` streamline for streamline and point for
    /// point.
    pub fn check_against(&self, t: &Tractogram, path: &Path) -> Result<()> {
        if self.n_streamlines() != t.n_streamlines() {
            return Err(Error::format(
                path,
                format!("{} streamlines of values, the tractogram has {}", self.n_streamlines(), t.n_streamlines()),
            ));
        }
        for i in 0..t.n_streamlines() {
            let (n, m) = (self.streamline(i).len(), t.streamline(i).len());
            if n != m {
                return Err(Error::format(path, format!("streamline {i} has {n} values but {m} points")));
            }
        }
        Ok(())
    }
}

/// Reads a `.tsf` file (gzipped too).
pub fn read(path: impl AsRef<Path>) -> Result<TrackScalars> {
    let path = path.as_ref();
    let raw = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let b = &super::tractogram::gunzipped(&raw, path)?[..];
    let TckLayout { header, offset, size, big_endian: be } = tck::parse_header_of(b, path, MAGIC)?;
    if offset > b.len() {
        return Err(Error::format(path, format!("data offset {offset} lies outside the data ({} bytes)", b.len())));
    }
    let mut out = TrackScalars { offsets: vec![0], values: Vec::new(), header };
    let mut o = offset;
    let mut ended = false;
    while o + size <= b.len() {
        let v = tck::value_at(b, o, size, be);
        o += size;
        if v.is_infinite() {
            ended = true;
            break;
        }
        if v.is_nan() {
            out.offsets.push(out.values.len());
        } else {
            out.values.push(v as f32);
        }
    }
    // `tcksample` (MRtrix3 3.0.3) ends its files after the last NaN, without an Inf: a file may end there. Values
    // after the last NaN are a streamline cut short.
    if out.values.len() > *out.offsets.last().unwrap_or(&0) {
        let why = if ended { "are not closed by a NaN" } else { "are cut short (no NaN, no closing Inf)" };
        return Err(Error::format(path, format!("the last streamline's values {why}")));
    }
    Ok(out)
}

/// Writes a `.tsf` (Float32LE) with the header entries of `s.header` (`file`, `datatype` and `count` are the
/// writer's); whole or not at all (`.part`, then renamed).
pub fn write(path: impl AsRef<Path>, s: &TrackScalars) -> Result<()> {
    let path = path.as_ref();
    let (mut out, _) = tck::header_bytes_of(MAGIC, &s.header, s.n_streamlines());
    out.reserve(4 * (s.values.len() + s.n_streamlines() + 1));
    for i in 0..s.n_streamlines() {
        for v in s.streamline(i) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&f32::NAN.to_le_bytes());
    }
    out.extend_from_slice(&f32::INFINITY.to_le_bytes());
    super::stream::write_whole(path, &out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn tractogram() -> Tractogram {
        let mut t = Tractogram::new();
        t.push(&[Vec3::ZERO, Vec3::X, Vec3::Y]);
        t.push(&[]);
        t.push(&[Vec3::Z; 4]);
        t
    }

    #[test]
    fn round_trip_and_validation() {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle_tsf-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let p = dir.join("v.tsf");
        let t = tractogram();
        let mut s = TrackScalars::for_tractogram(&t, |i, k| (10 * i + k) as f32 + 0.5);
        s.header.push(("timestamp".into(), "123.5".into()));
        write(&p, &s).unwrap();
        let back = read(&p).unwrap();
        assert_eq!((&back.offsets, &back.values), (&s.offsets, &s.values));
        assert_eq!(back.streamline(2), &[20.5, 21.5, 22.5, 23.5]);
        assert!(back.header.iter().any(|(k, v)| k == "timestamp" && v == "123.5"));
        back.check_against(&t, &p).unwrap();
        let mut other = t.clone();
        other.push(&[Vec3::ONE]);
        let e = back.check_against(&other, &p).unwrap_err().to_string();
        assert!(e.contains("v.tsf") && e.contains("3 streamlines of values, the tractogram has 4"), "{e}");
        let mut short = t.clone();
        short.points.pop();
        *short.offsets.last_mut().unwrap() -= 1;
        let e = back.check_against(&short, &p).unwrap_err().to_string();
        assert!(e.contains("streamline 2 has 4 values but 3 points"), "{e}");
    }

    #[test]
    fn malformed_files_are_errors_naming_them() {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle_tsf_bad-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let p = dir.join("bad.tsf");
        let good = {
            let mut s = TrackScalars::for_tractogram(&tractogram(), |_, _| 1.0);
            s.header.clear();
            write(&p, &s).unwrap();
            std::fs::read(&p).unwrap()
        };
        let cases: [(Vec<u8>, &str); 4] = [
            (b"mrtrix tracks\nEND\n".to_vec(), "not an MRtrix track scalars file"),
            (good[..good.len() - 8].to_vec(), "cut short"),
            (String::from_utf8_lossy(&good).replace("Float32LE", "Int16LE").into_bytes(), "datatype"),
            (good[..40].to_vec(), "no END line"),
        ];
        for (bytes, want) in cases {
            std::fs::write(&p, bytes).unwrap();
            let e = read(&p).unwrap_err().to_string();
            assert!(e.contains("bad.tsf") && e.contains(want), "{want}: {e}");
        }
    }
}
