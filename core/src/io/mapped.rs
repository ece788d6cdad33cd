//! A `.tck` file read in place: the file is mapped into memory and its streamlines are slices of the mapping, so
//! a tractogram larger than the memory a program can hold (10M streamlines, 12 GB) is addressed streamline by
//! streamline from the page cache, with 8 bytes per streamline of index. Float32LE data only (what `tckgen` and
//! every writer here produce); other files are read with [`crate::io::tck`] or streamed
//! ([`crate::io::stream::TractogramReader`]). A TRX file's positions are read in place likewise when they are
//! float32, stored and on a 4-byte boundary (as `fascicle convert` writes them): [`MappedPoints::open_trx`].
//!
//! A run of consecutive streamlines whose lengths are known (read by a stream, for example) is addressed in
//! place without indexing the file: [`MappedRun`]. Pages read through a mapping count in the process's resident
//! memory until released ([`MappedPoints::release`]: the page cache keeps them, a later read maps them again).

use std::ops::Range;
use std::path::Path;
use std::sync::Arc;

use glam::Vec3;

use super::Streamlines;
use crate::error::{Error, Result};

/// The points of a Float32LE `.tck` file (every triple from the data offset on, terminators included) or of a
/// TRX file's positions, mapped in memory and not indexed.
pub struct MappedPoints {
    map: memmap2::Mmap,
    /// Byte offset of the first point.
    data: usize,
    /// How many points: in a `.tck` every whole triple after the data offset, in a TRX its positions.
    len: usize,
    /// Points between one streamline and the next: a `.tck`'s terminator (1); none in a TRX (0).
    gap: usize,
}

impl MappedPoints {
    /// Maps `path` and reads its header (nothing else is read). Errors name the file: not a `.tck`, not
    /// Float32LE, data offset not a multiple of 4.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let map = map_read_only(path)?;
        let layout = super::tck::parse_header(&map, path)?;
        if layout.size != 4 || layout.big_endian || cfg!(target_endian = "big") {
            return Err(Error::format(path, "a mapped .tck must be Float32LE (read it with fascicle_core::io::tck)"));
        }
        if layout.offset % 4 != 0 {
            return Err(Error::format(path, format!("data offset {} is not a multiple of 4", layout.offset)));
        }
        let len = (map.len() - layout.offset.min(map.len())) / 12;
        Ok(Self { map, data: layout.offset, len, gap: 1 })
    }

    /// Maps a TRX file and finds its positions (its header.json and central directory are read, no array).
    /// Errors name the file: not a TRX, positions not float32 or deflated (read those with
    /// [`crate::io::stream::TractogramReader`]), or not on a 4-byte boundary.
    pub fn open_trx(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        let (data, len) = super::stream::trx_positions(path)?;
        let map = map_read_only(path)?;
        if cfg!(target_endian = "big") {
            return Err(Error::format(path, "TRX positions are little-endian: not read in place on this machine"));
        }
        if data % 4 != 0 {
            return Err(Error::format(path, format!("positions at byte {data}, not on a 4-byte boundary")));
        }
        if data.saturating_add((len as u64).saturating_mul(12)) > map.len() as u64 {
            return Err(Error::format(path, format!("{len} positions run past the end of the file")));
        }
        Ok(Self { map, data: data as usize, len, gap: 0 })
    }

    /// [`MappedPoints::open`] for a `.tck`, [`MappedPoints::open_trx`] for a `.trx`; an error for other files.
    pub fn open_tractogram(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        match super::tractogram::extension(path).as_str() {
            "tck" => Self::open(path),
            "trx" => Self::open_trx(path),
            other => Err(Error::format(path, format!("a .{other} file is not read in place (.tck and .trx are)"))),
        }
    }

    /// Every whole triple from the data offset on (RAS+ mm; in a `.tck` terminators are NaN, the end Inf), or a
    /// TRX's positions.
    #[inline]
    pub fn points(&self) -> &[Vec3] {
        if self.len == 0 {
            // (A `.tck` whose data offset lies at or past its end.)
            return &[];
        }
        // SAFETY: `Vec3` is three `f32` with `repr(C)`, alignment 4: the mapping starts on a page and `data` is a
        // multiple of 4, every bit pattern is a valid f32, and `len` triples from `data` lie within the mapping
        // (all checked where the file was opened).
        unsafe { std::slice::from_raw_parts(self.map.as_ptr().add(self.data).cast::<Vec3>(), self.len) }
    }

    /// Where in [`MappedPoints::points`] the streamline lies that follows `streamlines` streamlines of
    /// `points` points in all (in a `.tck`, each followed by its terminator).
    pub fn start_after(&self, points: usize, streamlines: usize) -> usize {
        points + streamlines * self.gap
    }

    /// Lets the pages holding `points` (indices into [`MappedPoints::points`]) go from this process's resident
    /// memory (the kernel's page cache keeps them; reading them again maps them again, with the same data). A
    /// hint: where it cannot be given (not Unix), nothing happens.
    pub fn release(&self, points: Range<usize>) {
        let n = self.points().len();
        let (a, b) = (points.start.min(n), points.end.min(n));
        if a >= b {
            return;
        }
        #[cfg(unix)]
        {
            let (offset, len) = (self.data + a * 12, (b - a) * 12);
            // SAFETY: the mapping is shared and read only: dropping its pages loses nothing (nothing was
            // written), and a later read of them, through slices handed out before or after, finds the file's
            // data again. memmap2 widens the range to whole pages within the mapping.
            let _ = unsafe { self.map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, offset, len) };
        }
    }
}

/// Maps `path` read only, asking (on Linux) for its pages in huge folios: the pages a fault reads come in 2 MiB
/// folios, mapped a 2 MiB page at a time, so that reading streamlines scattered over a file of gigabytes (an ROI
/// drag) waits for far fewer page walks. On the generated 10M-streamline `.tck` (12 GB) a 1 mm drag step of a
/// 10 mm sphere took 74-76 ms with the file in the page cache in small 4 KiB folios, 56-57 ms in 2 MiB ones.
/// Pages already cached keep the folios they have (a sequential read's readahead also makes large ones; a first
/// touch at scattered places, without this, small ones).
fn map_read_only(path: &Path) -> Result<memmap2::Mmap> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    // SAFETY: the mapping is read only; a file changed by another process while mapped can change what is read
    // (as with any reader), not memory safety of the slices handed out (plain f32 data).
    let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|e| Error::io(path, e))?;
    // A hint: a kernel without transparent huge pages refuses it, and the pages come as they would.
    #[cfg(target_os = "linux")]
    let _ = map.advise(memmap2::Advice::HugePage);
    Ok(map)
}

/// A run of consecutive streamlines of a [`MappedPoints`], read in place: `starts[k]..starts[k + 1] - gap` are
/// streamline `k`'s points (the file's indices; in a `.tck` each streamline's terminator follows it). 8 bytes a
/// streamline.
pub struct MappedRun {
    file: Arc<MappedPoints>,
    starts: Starts,
}

/// A run's starts ([`MappedRun`]): when they fill a huge page or more, in anonymous memory advised into huge
/// pages (on Linux). A selection through the spatial index looks up the starts of streamlines scattered over the
/// whole run (80 MB at 10M streamlines): in 4 KiB pages each lookup was also a TLB miss and a page walk (those
/// lookups were 6 % of the samples of a 10M drag step along an arc under `perf`).
enum Starts {
    Heap(Vec<u64>),
    Mapped(memmap2::MmapMut),
}

impl Starts {
    /// Starts of at least this many bytes go to huge pages: 2 MiB, one huge page.
    const HUGE: usize = 2 << 20;

    /// The `len` starts `values` yields, written straight into their huge pages when they fill one (no copy
    /// of them made first: 80 MB at 10M streamlines); on the heap when they do not, or cannot be mapped.
    fn collect(len: usize, values: impl IntoIterator<Item = u64>) -> Self {
        let bytes = len * 8;
        let mapped = (bytes >= Self::HUGE).then(|| memmap2::MmapMut::map_anon(bytes).ok()).flatten();
        let Some(mut map) = mapped else { return Self::Heap(values.into_iter().take(len).collect()) };
        // A hint, given before the pages are first written so that they come as huge pages; refused by a kernel
        // without transparent huge pages.
        #[cfg(target_os = "linux")]
        let _ = map.advise(memmap2::Advice::HugePage);
        for (to, from) in map.chunks_exact_mut(8).zip(values) {
            to.copy_from_slice(&from.to_ne_bytes());
        }
        Self::Mapped(map)
    }
}

impl std::ops::Deref for Starts {
    type Target = [u64];

    #[inline]
    fn deref(&self) -> &[u64] {
        match self {
            Self::Heap(v) => v,
            // SAFETY: the map is page-aligned (a u64's alignment is), holds `len / 8` u64 written from a slice of
            // them, and lives as long as `self`; any bits are a valid u64.
            Self::Mapped(m) => unsafe { std::slice::from_raw_parts(m.as_ptr().cast::<u64>(), m.len() / 8) },
        }
    }
}

impl MappedRun {
    /// The streamlines of `check`, stored one after another from the file's point `at` (in a `.tck` each
    /// followed by its terminator: [`MappedPoints::start_after`]), read in place: the run takes their lengths
    /// from `check`. `None` when they would run past the file's points, or when their ends are not where the
    /// file has them (in a `.tck` a terminator after each; the first and last points as `check` has them, for
    /// its first, middle and last streamlines: cheap checks that `check` is this stretch of the file).
    pub fn consecutive(file: Arc<MappedPoints>, at: usize, check: &impl Streamlines) -> Option<Self> {
        let n = check.n_streamlines();
        let gap = file.gap;
        let ends = (0..n).scan(at as u64, |end, s| {
            *end += (check.streamline(s).len() + gap) as u64;
            Some(*end)
        });
        let run = MappedRun { file, starts: Starts::collect(n + 1, std::iter::once(at as u64).chain(ends)) };
        let points = run.file.points();
        if run.starts[n] as usize > points.len() {
            return None;
        }
        let terminated = |k: usize| run.file.gap == 0 || points[run.starts[k + 1] as usize - 1].is_nan();
        let same_ends = |k: usize| {
            let (a, b) = (run.streamline(k), check.streamline(k));
            a.first().map(|p| p.to_array()) == b.first().map(|p| p.to_array())
                && a.last().map(|p| p.to_array()) == b.last().map(|p| p.to_array())
        };
        let probes = [0, n / 2, n.saturating_sub(1)];
        let ok = n == 0 || probes.iter().all(|&k| terminated(k) && same_ends(k));
        run.release();
        ok.then_some(run)
    }

    /// The runs one after another as one run (the parts of a layer as the whole file): `None` unless they read
    /// the same mapping and each starts where the one before ends.
    pub fn join(runs: &[&MappedRun]) -> Option<MappedRun> {
        let (first, rest) = runs.split_first()?;
        let mut end = first.starts.last();
        for run in rest {
            if !Arc::ptr_eq(&run.file, &first.file) || end != run.starts.first() {
                return None;
            }
            end = run.starts.last();
        }
        // Written once, straight into the joined run's own pages.
        let len = 1 + runs.iter().map(|r| r.starts.len() - 1).sum::<usize>();
        let values = first.starts.iter().take(1).chain(runs.iter().flat_map(|r| &r.starts[1..])).copied();
        Some(MappedRun { file: first.file.clone(), starts: Starts::collect(len, values) })
    }

    /// Lets the run's pages go from this process's resident memory ([`MappedPoints::release`]).
    pub fn release(&self) {
        self.release_streamlines(0..self.n_streamlines());
    }

    /// Lets the pages of the run's streamlines `streamlines` go ([`MappedPoints::release`]).
    pub fn release_streamlines(&self, streamlines: Range<usize>) {
        let end = streamlines.end.min(self.n_streamlines());
        let start = streamlines.start.min(end);
        self.file.release(self.starts[start] as usize..self.starts[end] as usize);
    }

    /// Bytes the run holds (its starts; the points stay in the file).
    pub fn heap_bytes(&self) -> usize {
        self.starts.len() * 8
    }
}

impl Streamlines for MappedRun {
    fn n_streamlines(&self) -> usize {
        self.starts.len() - 1
    }

    #[inline]
    fn streamline(&self, s: usize) -> &[Vec3] {
        let (a, b) = (self.starts[s] as usize, self.starts[s + 1] as usize - self.file.gap);
        &self.file.points()[a..b]
    }
}

/// A Float32LE `.tck` file mapped in memory, with the index of its streamlines: the whole file as one
/// [`MappedRun`].
pub struct MappedTck {
    run: MappedRun,
    bounds: Option<(Vec3, Vec3)>,
}

impl MappedTck {
    /// Maps `path` and indexes its streamlines in one pass over the points (a NaN triple ends a streamline,
    /// an Inf triple or the end of the data ends the file; a last streamline without its terminator is kept).
    /// Errors name the file: not a `.tck`, not Float32LE, data offset not a multiple of 4.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let file = MappedPoints::open(path)?;
        let points = file.points();
        // Streamline `s` spans `starts[s]..starts[s + 1] - 1`: one past its last point is its terminator (or,
        // for a file cut short, the end of the data).
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
        // The pass read every page: they go from the process's memory until a streamline is read again.
        file.release(0..points.len());
        Ok(Self { run: MappedRun { file: Arc::new(file), starts: Starts::collect(starts.len(), starts) }, bounds })
    }

    /// Streamlines in the file (empty ones included, as MRtrix counts them).
    pub fn n_streamlines(&self) -> usize {
        self.run.n_streamlines()
    }

    /// Points of streamline `s`, in place (RAS+ mm). Panics if `s >= n_streamlines()`.
    #[inline]
    pub fn streamline(&self, s: usize) -> &[Vec3] {
        self.run.streamline(s)
    }

    /// Bounds of every point (RAS+ mm); None without points.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        self.bounds
    }
}

impl Streamlines for MappedTck {
    fn n_streamlines(&self) -> usize {
        MappedTck::n_streamlines(self)
    }

    fn streamline(&self, s: usize) -> &[Vec3] {
        MappedTck::streamline(self, s)
    }
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

    /// Starts too many for the heap's pages (over 2 MiB: 300k streamlines) go to a mapping of their own, and
    /// address every streamline as the file has it, in a file indexed whole, in runs and in the runs joined.
    #[test]
    fn long_runs_address_each_streamline() {
        let (mut t, mut a, mut b) = (Tractogram::new(), Tractogram::new(), Tractogram::new());
        let mut points_in_a = 0;
        for k in 0..300_000usize {
            let pts: Vec<Vec3> = (0..k % 3).map(|i| Vec3::new(k as f32, i as f32, -1.0)).collect();
            t.push(&pts);
            if k < 100_000 {
                a.push(&pts);
                points_in_a += pts.len();
            } else {
                b.push(&pts);
            }
        }
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-mapped-long-").tempdir().unwrap();
        let path = tmp_dir.path().join("t.tck");
        crate::io::tck::write(&path, &t, &[]).unwrap();
        let m = MappedTck::open(&path).unwrap();
        assert!(matches!(m.run.starts, Starts::Mapped(_)), "the starts of 300k streamlines are mapped");
        let file = m.run.file.clone();
        let first = MappedRun::consecutive(file.clone(), 0, &a).unwrap();
        let second = MappedRun::consecutive(file.clone(), file.start_after(points_in_a, 100_000), &b).unwrap();
        assert!(matches!(first.starts, Starts::Heap(_)), "the starts of 100k streamlines stay on the heap");
        let joined = MappedRun::join(&[&first, &second]).unwrap();
        assert!(matches!(joined.starts, Starts::Mapped(_)));
        for s in 0..300_000 {
            assert_eq!(m.streamline(s), t.streamline(s), "streamline {s}");
            assert_eq!(joined.streamline(s), t.streamline(s), "joined streamline {s}");
        }
        assert_eq!(second.streamline(199_999), t.streamline(299_999));
    }

    /// A run of consecutive streamlines read in place is the file's: the whole file, a run from its middle
    /// (the file's point index of its first streamline: the points and terminators before it), and an empty
    /// run; lengths that do not describe the file give none.
    #[test]
    fn a_run_of_streamlines_is_read_in_place() {
        let mut t = Tractogram::new();
        for k in 0..7 {
            let pts: Vec<Vec3> = (0..k % 4).map(|i| Vec3::new(k as f32, i as f32, 0.5)).collect();
            t.push(&pts);
        }
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-mapped-run-").tempdir().unwrap();
        let path = tmp_dir.path().join("t.tck");
        crate::io::tck::write(&path, &t, &[]).unwrap();
        let file = Arc::new(MappedPoints::open(&path).unwrap());
        let whole = MappedRun::consecutive(file.clone(), 0, &t).expect("the whole file");
        assert_eq!(whole.n_streamlines(), 7);
        (0..7).for_each(|s| assert_eq!(whole.streamline(s), t.streamline(s), "streamline {s}"));
        let part = t.subset(&[false, false, true, true, true, false, false]);
        let at = t.offsets[2] + 2;
        let middle = MappedRun::consecutive(file.clone(), at, &part).expect("a run from the middle");
        (0..3).for_each(|s| assert_eq!(middle.streamline(s), t.streamline(s + 2), "streamline {}", s + 2));
        whole.release();
        assert_eq!(middle.streamline(1), t.streamline(3), "read again after a release");
        let none = Tractogram::new();
        assert_eq!(MappedRun::consecutive(file.clone(), at, &none).map(|r| r.n_streamlines()), Some(0));
        // A start one off either way, past the end, or streamlines that are not these (one point longer; others
        // of the same count).
        assert!(MappedRun::consecutive(file.clone(), at + 1, &part).is_none());
        assert!(MappedRun::consecutive(file.clone(), at - 1, &part).is_none());
        assert!(MappedRun::consecutive(file.clone(), t.offsets[7] + 7, &part).is_none());
        let mut longer = Tractogram::new();
        for s in 0..3 {
            let mut pts = part.streamline(s).to_vec();
            if s == 0 {
                pts.push(pts[pts.len() - 1]);
            }
            longer.push(&pts);
        }
        assert!(MappedRun::consecutive(file.clone(), at, &longer).is_none());
        assert!(MappedRun::consecutive(file.clone(), 0, &t.subset(&[false, true, true, true])).is_none());
        // Runs that follow each other join into one, the file's streamlines in order; others do not.
        let head = MappedRun::consecutive(file.clone(), 0, &t.subset(&[true, true])).unwrap();
        let joined = MappedRun::join(&[&head, &middle]).expect("runs that follow each other");
        (0..5).for_each(|s| assert_eq!(joined.streamline(s), t.streamline(s), "joined streamline {s}"));
        assert!(MappedRun::join(&[&middle, &head]).is_none());
        assert!(MappedRun::join(&[&head, &whole]).is_none());
        assert!(MappedRun::join(&[]).is_none());
    }

    /// A TRX's float32 positions, written here (on a 64-byte boundary), are read in place: the whole file and a
    /// run from its middle are its streamlines (an empty one among them), a start one off is refused, and the
    /// streaming writer's files map as well. Positions that cannot be mapped name the file and why: float16,
    /// deflated (trx-python's files), or off a 4-byte boundary.
    #[test]
    fn a_trx_is_read_in_place() {
        use crate::io::trx::{PositionType, write};
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-mapped-trx-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        crate::phantom::write_whole_brain(&dir.join("brain.tck"), 300, 4).unwrap();
        let mut t = Tractogram::read(dir.join("brain.tck")).unwrap();
        t.push(&[]);
        t.push(&[Vec3::new(1.0, 2.0, 3.0)]);
        let path = dir.join("brain.trx");
        write(&path, &t, None, PositionType::F32).unwrap();
        let file = Arc::new(MappedPoints::open_tractogram(&path).unwrap());
        assert_eq!(file.points().len(), t.points.len());
        let whole = MappedRun::consecutive(file.clone(), 0, &t).expect("the whole file");
        assert_eq!(whole.n_streamlines(), t.n_streamlines());
        for s in 0..t.n_streamlines() {
            assert_eq!(whole.streamline(s), t.streamline(s), "streamline {s}");
        }
        let keep: Vec<bool> = (0..t.n_streamlines()).map(|s| (100..200).contains(&s)).collect();
        let part = t.subset(&keep);
        let at = file.start_after(t.offsets[100], 100);
        assert_eq!(at, t.offsets[100]);
        let middle = MappedRun::consecutive(file.clone(), at, &part).expect("a run from the middle");
        assert_eq!(middle.streamline(99), t.streamline(199));
        assert!(MappedRun::consecutive(file.clone(), at + 1, &part).is_none());
        assert!(MappedRun::consecutive(file.clone(), at - 1, &part).is_none());
        // The streaming writer's positions map too.
        let streamed = dir.join("streamed.trx");
        let mut writer = crate::io::stream::TractogramWriter::create(&streamed, &Default::default()).unwrap();
        writer.write_chunk(&t).unwrap();
        writer.finish().unwrap();
        let file = Arc::new(MappedPoints::open_trx(&streamed).unwrap());
        let run = MappedRun::consecutive(file, 0, &t).expect("the streamed file");
        assert_eq!(run.streamline(7), t.streamline(7));
        // What cannot be mapped.
        let data = |name: &str| std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/tracts").join(name);
        let why = |path: &std::path::Path| MappedPoints::open_tractogram(path).err().map(|e| e.to_string()).unwrap();
        let f16 = why(&data("tracks300_f16.trx"));
        assert!(f16.contains("tracks300_f16.trx") && f16.contains("F16"), "{f16}");
        let deflated = why(&data("tracks300_f32_deflate.trx"));
        assert!(deflated.contains("deflated"), "{deflated}");
        assert!(why(&data("tracks300.trk")).contains(".trk file is not read in place"));
        // Positions one byte off their boundary: the header and central directory shifted by one byte.
        let bytes = std::fs::read(&path).unwrap();
        let shifted = dir.join("shifted.trx");
        std::fs::write(&shifted, [&[0u8][..], &bytes].concat()).unwrap();
        let e = MappedPoints::open_trx(&shifted).err().expect("positions off their boundary mapped");
        assert!(e.to_string().contains("shifted.trx"), "{e}");
    }
}
