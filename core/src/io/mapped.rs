//! A `.tck` file read in place: the file is mapped into memory and its streamlines are slices of the mapping, so
//! a tractogram larger than the memory a program can hold (10M streamlines, 12 GB) is addressed streamline by
//! streamline from the page cache, with 8 bytes per streamline of index. Float32LE data only (what `tckgen` and
//! every writer here produce); other files are read with [`crate::io::tck`] or streamed
//! ([`crate::io::stream::TractogramReader`]).

use std::path::Path;

use glam::Vec3;

use crate::error::{Error, Result};

/// A Float32LE `.tck` file mapped in memory, with the index of its streamlines.
pub struct MappedTck {
    map: memmap2::Mmap,
    /// Byte offset of the first point.
    data: usize,
    /// Per streamline, the index (in points from `data`) of its first point; one more entry ends the last.
    /// Streamline `s` spans `starts[s]..starts[s + 1] - 1` (its NaN terminator excluded).
    starts: Vec<u64>,
    bounds: Option<(Vec3, Vec3)>,
}

impl MappedTck {
    /// Maps `path` and indexes its streamlines in one pass over the points (a NaN triple ends a streamline,
    /// an Inf triple or the end of the data ends the file; a last streamline without its terminator is kept).
    /// Errors name the file: not a `.tck`, not Float32LE, data offset not a multiple of 4.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        // SAFETY: the mapping is read only; a file changed by another process while mapped can change what is
        // read (as with any reader), not memory safety of the slices handed out (plain f32 data).
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| Error::io(path, e))?;
        let layout = super::tck::parse_header(&map, path)?;
        if layout.size != 4 || layout.big_endian || cfg!(target_endian = "big") {
            return Err(Error::format(path, "a mapped .tck must be Float32LE (read it with fascicle_core::io::tck)"));
        }
        if layout.offset % 4 != 0 {
            return Err(Error::format(path, format!("data offset {} is not a multiple of 4", layout.offset)));
        }
        let points = points_of(&map, layout.offset);
        let mut starts = vec![0u64];
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let mut open = false;
        for (i, p) in points.iter().enumerate() {
            if p.x.is_nan() || p.y.is_nan() || p.z.is_nan() {
                starts.push(i as u64 + 1);
                open = false;
            } else if p.is_finite() {
                lo = lo.min(*p);
                hi = hi.max(*p);
                open = true;
            } else {
                // Inf: the end of the file. Its index is where a next streamline would start.
                if open {
                    starts.push(i as u64 + 1);
                }
                open = false;
                break;
            }
        }
        if open {
            // Cut short: the last streamline ends at the end of the data (one past, as if terminated).
            starts.push(points.len() as u64 + 1);
        }
        let bounds = (lo.x <= hi.x).then_some((lo, hi));
        Ok(Self { map, data: layout.offset, starts, bounds })
    }

    /// Streamlines in the file (empty ones included, as MRtrix counts them).
    pub fn n_streamlines(&self) -> usize {
        self.starts.len() - 1
    }

    /// Points of streamline `s`, in place (RAS+ mm). Panics if `s >= n_streamlines()`.
    #[inline]
    pub fn streamline(&self, s: usize) -> &[Vec3] {
        let points = points_of(&self.map, self.data);
        let (a, b) = (self.starts[s] as usize, self.starts[s + 1] as usize - 1);
        &points[a..b.min(points.len())]
    }

    /// Bounds of every point (RAS+ mm); None without points.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }
}

/// The whole triples of `map` from byte `offset`, as points.
#[inline]
fn points_of(map: &[u8], offset: usize) -> &[Vec3] {
    let bytes = map.get(offset..).unwrap_or_default();
    let n = bytes.len() / 12;
    // SAFETY: `Vec3` is three `f32` with `repr(C)`, alignment 4: the mapping starts on a page and `offset` is a
    // multiple of 4 (checked in `open`), every bit pattern is a valid f32, and `n` triples lie within `bytes`.
    unsafe { std::slice::from_raw_parts(bytes.as_ptr().cast::<Vec3>(), n) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::Tractogram;

    /// The mapped streamlines are the file's: an empty streamline, one of one point, and a file cut short.
    #[test]
    fn mapped_streamlines_are_those_read() {
        let mut t = Tractogram::new();
        t.push(&[Vec3::new(1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.0)]);
        t.push(&[]);
        t.push(&[Vec3::new(-7.0, 8.5, 0.25)]);
        t.push(&[Vec3::ZERO, Vec3::X, Vec3::Y]);
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-mapped-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let path = dir.join("t.tck");
        crate::io::tck::write(&path, &t, &[]).unwrap();
        let m = MappedTck::open(&path).unwrap();
        assert_eq!(m.n_streamlines(), 4);
        for s in 0..4 {
            assert_eq!(m.streamline(s), t.streamline(s), "streamline {s}");
        }
        assert_eq!(m.bounds(), Some((Vec3::new(-7.0, 0.0, 0.0), Vec3::new(4.0, 8.5, 6.0))));
        // Without the last terminator and the Inf triple: the last streamline is still whole.
        let bytes = std::fs::read(&path).unwrap();
        let cut = dir.join("cut.tck");
        std::fs::write(&cut, &bytes[..bytes.len() - 24]).unwrap();
        let c = MappedTck::open(&cut).unwrap();
        assert_eq!(c.n_streamlines(), 4);
        assert_eq!(c.streamline(3), t.streamline(3));
    }
}
