//! In-memory tractogram: streamlines as one flat point array with CSR offsets, in RAS+ millimetres.

use std::path::Path;

use glam::{DMat3, DMat4, Vec3};

use crate::error::{Error, Result};

/// Streamlines in world space (RAS+ mm), with optional per-point scalars and per-streamline properties.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tractogram {
    /// All points of all streamlines, streamline after streamline.
    pub points: Vec<Vec3>,
    /// `offsets[i]..offsets[i + 1]` are the points of streamline i; `offsets.len() == n_streamlines + 1`.
    pub offsets: Vec<usize>,
    /// Per-point values, each `points.len()` long, with their names.
    pub scalars: Vec<(String, Vec<f32>)>,
    /// Per-streamline values, each `n_streamlines` long, with their names.
    pub properties: Vec<(String, Vec<f32>)>,
}

/// Streamlines addressed one at a time, wherever their points are: in memory ([`Tractogram`], [`Csr`]) or
/// read in place from a mapped file ([`super::mapped::MappedTck`], [`super::mapped::MappedRun`]). What ROI
/// selection and picking ([`crate::roi`], [`crate::roi_index`]) take.
pub trait Streamlines: Sync {
    /// How many streamlines.
    fn n_streamlines(&self) -> usize;
    /// The points of streamline `s` (RAS+ mm). Panics if `s >= n_streamlines()`.
    fn streamline(&self, s: usize) -> &[Vec3];

    /// The streamlines with `keep[s]` (a selection), in order, as a tractogram of points only; streamlines
    /// past `keep`'s end are dropped.
    fn subset(&self, keep: &[bool]) -> Tractogram {
        let mut out = Tractogram::new();
        for (s, _) in keep.iter().enumerate().take(self.n_streamlines()).filter(|(_, k)| **k) {
            out.push(self.streamline(s));
        }
        out
    }
}

/// Points and the offsets that cut them into streamlines (`offsets[s]..offsets[s + 1]`), borrowed: a
/// [`Streamlines`] over arrays that are not a [`Tractogram`].
#[derive(Clone, Copy, Debug)]
pub struct Csr<'a>(pub &'a [Vec3], pub &'a [usize]);

impl Streamlines for Csr<'_> {
    fn n_streamlines(&self) -> usize {
        self.1.len().saturating_sub(1)
    }

    fn streamline(&self, s: usize) -> &[Vec3] {
        &self.0[self.1[s]..self.1[s + 1]]
    }
}

impl<T: Streamlines + Send + ?Sized> Streamlines for std::sync::Arc<T> {
    fn n_streamlines(&self) -> usize {
        (**self).n_streamlines()
    }

    fn streamline(&self, s: usize) -> &[Vec3] {
        (**self).streamline(s)
    }
}

impl Streamlines for Tractogram {
    fn n_streamlines(&self) -> usize {
        Tractogram::n_streamlines(self)
    }

    fn streamline(&self, s: usize) -> &[Vec3] {
        Tractogram::streamline(self, s)
    }
}

impl Tractogram {
    /// An empty tractogram, ready for `push`: `offsets` holds its leading 0 (which `Default` leaves out).
    pub fn new() -> Self {
        Self { offsets: vec![0], ..Default::default() }
    }

    /// Number of streamlines (0 for an empty `offsets`).
    pub fn n_streamlines(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// The points of streamline `i`.
    pub fn streamline(&self, i: usize) -> &[Vec3] {
        &self.points[self.offsets[i]..self.offsets[i + 1]]
    }

    /// The points of each streamline, in order.
    pub fn iter(&self) -> impl Iterator<Item = &[Vec3]> + '_ {
        (0..self.n_streamlines()).map(|i| self.streamline(i))
    }

    /// The streamlines with `keep[s]` (a selection), in order, points only (no scalars or properties);
    /// streamlines past `keep`'s end are dropped.
    pub fn subset(&self, keep: &[bool]) -> Tractogram {
        Streamlines::subset(self, keep)
    }

    /// The streamlines with `keep[s]`, in order, with their values per point and per streamline.
    pub fn subset_with_values(&self, keep: &[bool]) -> Tractogram {
        let n = self.n_streamlines();
        let kept = || (0..n).filter(|&s| keep.get(s).copied().unwrap_or(false));
        let mut out = Tractogram::new();
        let total: usize = kept().map(|s| self.offsets[s + 1] - self.offsets[s]).sum();
        out.points.reserve(total);
        for s in kept() {
            out.points.extend_from_slice(self.streamline(s));
            out.offsets.push(out.points.len());
        }
        out.scalars = self
            .scalars
            .iter()
            .map(|(name, v)| {
                let mut w = Vec::with_capacity(total);
                for s in kept() {
                    w.extend_from_slice(v.get(self.offsets[s]..self.offsets[s + 1]).unwrap_or(&[]));
                }
                (name.clone(), w)
            })
            .collect();
        out.properties = self
            .properties
            .iter()
            .map(|(name, v)| (name.clone(), kept().map(|s| v.get(s).copied().unwrap_or(0.0)).collect()))
            .collect();
        out
    }

    /// Appends a streamline (no scalars or properties: use only on tractograms without them).
    pub fn push(&mut self, pts: &[Vec3]) {
        if self.offsets.is_empty() {
            self.offsets.push(0);
        }
        self.points.extend_from_slice(pts);
        self.offsets.push(self.points.len());
    }
}

/// Lower-case file extension (empty when there is none); for a gzipped file the one before `.gz` (`trk` for
/// `x.trk.gz`).
pub fn extension(path: &Path) -> String {
    let ext = |p: &Path| p.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    match ext(path).as_str() {
        "gz" => path.file_stem().map_or_else(String::new, |stem| ext(Path::new(stem))),
        e => e.to_string(),
    }
}

/// A tractogram file's bytes, decompressed when they are gzip data (by content: `.trk.gz` / `.tck.gz`, or any
/// name).
pub(crate) fn gunzipped<'a>(bytes: &'a [u8], path: &Path) -> Result<std::borrow::Cow<'a, [u8]>> {
    if !bytes.starts_with(&[0x1f, 0x8b]) {
        return Ok(std::borrow::Cow::Borrowed(bytes));
    }
    let mut out = Vec::new();
    std::io::Read::read_to_end(&mut flate2::read::MultiGzDecoder::new(bytes), &mut out)
        .map_err(|e| Error::format(path, format!("bad gzip data: {e}")))?;
    Ok(std::borrow::Cow::Owned(out))
}

/// Writes a tractogram file's bytes, gzip-compressed when the name ends in `.gz`.
pub(crate) fn write_file(path: &Path, bytes: Vec<u8>) -> Result<()> {
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("gz")) {
        let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
        let mut enc = flate2::write::GzEncoder::new(std::io::BufWriter::new(file), flate2::Compression::default());
        std::io::Write::write_all(&mut enc, &bytes).map_err(|e| Error::io(path, e))?;
        let mut w = enc.finish().map_err(|e| Error::io(path, e))?;
        return std::io::Write::flush(&mut w).map_err(|e| Error::io(path, e));
    }
    std::fs::write(path, bytes).map_err(|e| Error::io(path, e))
}

/// Orientation of each voxel axis of an affine: `(world axis, sign)` per column, as nibabel's
/// `io_orientation`: the rotation of the polar decomposition, then for each voxel axis in turn the world
/// axis it is closest to, among those not yet taken.
pub fn io_orientation(affine: &DMat4) -> [(usize, f64); 3] {
    let m = DMat3::from_mat4(*affine);
    let mut r = crate::linalg::polar_rotation(m);
    let mut out = [(0usize, 1.0f64); 3];
    for (in_ax, o) in out.iter_mut().enumerate() {
        let col = r.col(in_ax);
        let (mut best, mut best_abs) = (0usize, -1.0f64);
        for w in 0..3 {
            if col[w].abs() > best_abs {
                best = w;
                best_abs = col[w].abs();
            }
        }
        *o = (best, if col[best] < 0.0 { -1.0 } else { 1.0 });
        for c in 0..3 {
            let mut cc = r.col(c);
            cc[best] = 0.0;
            *r.col_mut(c) = cc;
        }
    }
    out
}

/// Axis codes ("RAS", "LPS", ...) of an affine.
pub fn axcodes(affine: &DMat4) -> String {
    io_orientation(affine)
        .iter()
        .map(|&(ax, s)| match (ax, s > 0.0) {
            (0, true) => 'R',
            (0, false) => 'L',
            (1, true) => 'A',
            (1, false) => 'P',
            (2, true) => 'S',
            _ => 'I',
        })
        .collect()
}
