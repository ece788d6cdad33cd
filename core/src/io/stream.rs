//! Tractograms as streams: `.tck`, `.trk` (either gzipped) and `.trx` read and written in chunks of whole
//! streamlines, so that memory is bounded by the chunk, not by the file (whole-brain tractograms hold 1-10M
//! streamlines, 1-12 GB).
//!
//! [`TractogramReader`] reads a file's header, then hands out [`Tractogram`] chunks (points in RAS+ mm, with
//! their values per point and per streamline) until the file ends; [`TractogramWriter`] writes chunks to a
//! temporary file beside the output and moves it into place when [`TractogramWriter::finish`] succeeds, so a
//! failed run leaves no half-written output. A TRX archive is read in place: each array (positions, offsets,
//! values) is its own stream from the archive's stored (or deflated) entry, and nothing is unpacked.
//! [`scan`] counts a file's streamlines and points and bounds them in one bounded pass, reading only the
//! header of a TRX.

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::{DMat4, DVec3, Vec3};

use super::tractogram::{Tractogram, extension};
use super::trx::Dtype;
use super::{tck, trk, trx};
use crate::error::{Error, Result};

/// Points per chunk that [`TractogramReader::next_chunk`] callers use by default: about 3 MB of positions.
pub const DEFAULT_CHUNK_POINTS: usize = 1 << 18;

/// Points one `.trk` streamline may claim (a 1 mm tractogram's longest streamlines hold a few hundred); a larger
/// count is a corrupt file, refused before its bytes are asked for.
const MAX_STREAMLINE_POINTS: usize = 1 << 24;

/// Bytes read from the file at a time.
const BLOCK: usize = 4 << 20;

/// A tractogram file format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// MRtrix `.tck`.
    Tck,
    /// TrackVis `.trk`.
    Trk,
    /// TRX `.trx` (a zip archive of arrays).
    Trx,
}

impl Format {
    /// The format a file name asks for (`.tck`, `.trk`, `.trx`, or `.tck.gz` / `.trk.gz`).
    pub fn of(path: &Path) -> Result<Format> {
        match extension(path).as_str() {
            "tck" => Ok(Format::Tck),
            "trk" => Ok(Format::Trk),
            "trx" => Ok(Format::Trx),
            other => Err(Error::format(
                path,
                format!("unknown tractogram extension '{other}' (expected .trk, .tck, .trx, or .gz)"),
            )),
        }
    }

    /// A name for messages: "MRtrix tracks", "TrackVis", "TRX".
    pub fn name(self) -> &'static str {
        match self {
            Format::Tck => "MRtrix tracks",
            Format::Trk => "TrackVis",
            Format::Trx => "TRX",
        }
    }
}

/// What a tractogram's header says, before any streamline is read.
#[derive(Clone, Debug)]
pub struct StreamHeader {
    /// The file's format, told by its extension.
    pub format: Format,
    /// Streamlines the header promises: `n_count` of a `.trk` (when not 0), `NB_STREAMLINES` of a TRX; None for
    /// a `.tck`, whose `count` is advisory (MRtrix writes it when a run ends; other tools get it wrong).
    pub count: Option<usize>,
    /// Points the header promises (`NB_VERTICES` of a TRX).
    pub points: Option<usize>,
    /// Names of the values per point, in the order of [`Tractogram::scalars`].
    pub scalars: Vec<String>,
    /// Names of the values per streamline, in the order of [`Tractogram::properties`].
    pub properties: Vec<String>,
    /// The `.tck` header's entries.
    pub tck: Option<tck::TckHeader>,
    /// The `.trk` header.
    pub trk: Option<trk::TrkHeader>,
    /// The TRX reference grid and groups.
    pub trx: Option<trx::TrxHeader>,
    /// Size of the file on disk (bytes; compressed for gzipped files).
    pub file_bytes: u64,
}

/// Counts the bytes read from a file, for progress.
struct Counted<R> {
    inner: R,
    count: Arc<AtomicU64>,
}

impl<R: Read> Read for Counted<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.count.fetch_add(n as u64, Ordering::Relaxed);
        Ok(n)
    }
}

/// A byte stream read in large blocks, with what is not yet consumed kept in front.
struct Blocks {
    src: Box<dyn Read + Send>,
    buf: Vec<u8>,
    start: usize,
    end: usize,
    eof: bool,
}

impl Blocks {
    fn new(src: Box<dyn Read + Send>) -> Self {
        Self { src, buf: Vec::new(), start: 0, end: 0, eof: false }
    }

    /// Makes at least `need` bytes available (fewer only where the stream ends) and returns what is available.
    fn fill(&mut self, need: usize) -> std::io::Result<&[u8]> {
        if self.end - self.start < need && !self.eof {
            if self.start > 0 {
                self.buf.copy_within(self.start..self.end, 0);
                self.end -= self.start;
                self.start = 0;
            }
            if self.buf.len() < need {
                self.buf.resize(need.max(BLOCK), 0);
            }
            while self.end < need && !self.eof {
                match self.src.read(&mut self.buf[self.end..]) {
                    Ok(0) => self.eof = true,
                    Ok(n) => self.end += n,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                    Err(e) => return Err(e),
                }
            }
        }
        Ok(&self.buf[self.start..self.end])
    }

    fn consume(&mut self, n: usize) {
        self.start = (self.start + n).min(self.end);
    }

    /// Skips `n` bytes; how many there were.
    fn skip(&mut self, mut n: u64) -> std::io::Result<u64> {
        let mut skipped = 0;
        while n > 0 {
            let avail = self.fill(1)?.len() as u64;
            if avail == 0 {
                break;
            }
            let k = avail.min(n);
            self.consume(k as usize);
            n -= k;
            skipped += k;
        }
        Ok(skipped)
    }
}

/// Opens a file for streaming: its bytes (decompressed when they are gzip data), the counter of bytes read
/// from disk, and its size.
fn open_source(path: &Path) -> Result<(Box<dyn Read + Send>, Arc<AtomicU64>, u64)> {
    let mut f = File::open(path).map_err(|e| Error::io(path, e))?;
    let len = f.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut magic = [0u8; 2];
    let got = f.read(&mut magic).map_err(|e| Error::io(path, e))?;
    f.seek(SeekFrom::Start(0)).map_err(|e| Error::io(path, e))?;
    let count = Arc::new(AtomicU64::new(0));
    let counted = Counted { inner: f, count: count.clone() };
    let src: Box<dyn Read + Send> = if got == 2 && magic == [0x1f, 0x8b] {
        Box::new(flate2::read::MultiGzDecoder::new(BufReader::with_capacity(1 << 20, counted)))
    } else {
        Box::new(counted)
    };
    Ok((src, count, len))
}

/// Reads a tractogram file chunk by chunk. See the module documentation.
pub struct TractogramReader {
    path: PathBuf,
    header: StreamHeader,
    inner: Inner,
    read_bytes: Arc<AtomicU64>,
    streamlines: usize,
}

enum Inner {
    Tck(TckStream),
    Trk(TrkStream),
    Trx(Box<TrxStream>),
}

impl TractogramReader {
    /// Opens a `.tck`, `.trk` (either gzipped) or `.trx` file and reads its header.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let format = Format::of(&path)?;
        let (header, inner, read_bytes) = match format {
            Format::Tck => {
                let (src, count, len) = open_source(&path)?;
                let (stream, h) = TckStream::open(Blocks::new(src), &path)?;
                let header = StreamHeader {
                    format,
                    count: None,
                    points: None,
                    scalars: vec![],
                    properties: vec![],
                    tck: Some(h),
                    trk: None,
                    trx: None,
                    file_bytes: len,
                };
                (header, Inner::Tck(stream), count)
            }
            Format::Trk => {
                let (src, count, len) = open_source(&path)?;
                let (stream, layout) = TrkStream::open(Blocks::new(src), &path)?;
                let header = StreamHeader {
                    format,
                    count: (layout.header.n_count > 0).then_some(layout.header.n_count as usize),
                    points: None,
                    scalars: layout.scalars,
                    properties: layout.properties,
                    tck: None,
                    trk: Some(layout.header),
                    trx: None,
                    file_bytes: len,
                };
                (header, Inner::Trk(stream), count)
            }
            Format::Trx => {
                let (stream, header, count) = TrxStream::open(&path)?;
                (header, Inner::Trx(Box::new(stream)), count)
            }
        };
        Ok(Self { path, header, inner, read_bytes, streamlines: 0 })
    }

    /// What the header says.
    pub fn header(&self) -> &StreamHeader {
        &self.header
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Bytes read from the file so far (compressed bytes for a gzipped file; a TRX's positions), for progress
    /// against [`StreamHeader::file_bytes`].
    pub fn bytes_read(&self) -> u64 {
        self.read_bytes.load(Ordering::Relaxed)
    }

    /// Streamlines handed out so far.
    pub fn streamlines_read(&self) -> usize {
        self.streamlines
    }

    /// The next whole streamlines, about `max_points` points (one streamline more than that at most), with their
    /// values per point and per streamline; None once the file has ended.
    pub fn next_chunk(&mut self, max_points: usize) -> Result<Option<Tractogram>> {
        let max_points = max_points.max(1);
        let mut t = Tractogram::new();
        t.scalars = self.header.scalars.iter().map(|n| (n.clone(), Vec::new())).collect();
        t.properties = self.header.properties.iter().map(|n| (n.clone(), Vec::new())).collect();
        let path = &self.path;
        match &mut self.inner {
            Inner::Tck(s) => s.next(&mut t, max_points).map_err(|e| e.at(path))?,
            Inner::Trk(s) => s.next(&mut t, max_points, self.streamlines).map_err(|e| e.at(path))?,
            Inner::Trx(s) => s.next(&mut t, max_points).map_err(|e| e.at(path))?,
        }
        self.streamlines += t.n_streamlines();
        Ok((t.n_streamlines() > 0).then_some(t))
    }
}

/// A reading error before the path is known: an I/O error or a reason.
enum ReadError {
    Io(std::io::Error),
    Format(String),
}

impl ReadError {
    fn at(self, path: &Path) -> Error {
        match self {
            ReadError::Io(e) => Error::io(path, e),
            ReadError::Format(reason) => Error::format(path, reason),
        }
    }
}

impl From<std::io::Error> for ReadError {
    fn from(e: std::io::Error) -> Self {
        ReadError::Io(e)
    }
}

type ReadResult<T> = std::result::Result<T, ReadError>;

struct TckStream {
    blocks: Blocks,
    size: usize,
    big_endian: bool,
    done: bool,
}

impl TckStream {
    fn open(mut blocks: Blocks, path: &Path) -> Result<(Self, tck::TckHeader)> {
        // The header ends at its END line; it is small, but may be long (a command history).
        let mut need = 64 << 10;
        loop {
            let b = blocks.fill(need).map_err(|e| Error::io(path, e))?;
            let full = b.len() < need;
            if find(b, b"\nEND\n").is_some() || find(b, b"\nEND\r\n").is_some() || full || need >= 64 << 20 {
                break;
            }
            need *= 4;
        }
        let layout = tck::parse_header(blocks.fill(0).map_err(|e| Error::io(path, e))?, path)?;
        let skipped = blocks.skip(layout.offset as u64).map_err(|e| Error::io(path, e))?;
        if skipped < layout.offset as u64 {
            return Err(Error::format(
                path,
                format!("data offset {} lies outside the data (the file is {skipped} bytes)", layout.offset),
            ));
        }
        let stream = Self { blocks, size: layout.size, big_endian: layout.big_endian, done: false };
        Ok((stream, layout.header))
    }

    fn next(&mut self, t: &mut Tractogram, max_points: usize) -> ReadResult<()> {
        let (size, be) = (self.size, self.big_endian);
        let triple = 3 * size;
        let coord = |c: &[u8]| -> f32 {
            match (size, be) {
                (4, false) => f32::from_le_bytes(<[u8; 4]>::try_from(c).unwrap_or_default()),
                (4, true) => f32::from_be_bytes(<[u8; 4]>::try_from(c).unwrap_or_default()),
                (_, false) => f64::from_le_bytes(<[u8; 8]>::try_from(c).unwrap_or_default()) as f32,
                (_, true) => f64::from_be_bytes(<[u8; 8]>::try_from(c).unwrap_or_default()) as f32,
            }
        };
        while !self.done {
            let b = self.blocks.fill(BLOCK)?;
            let usable = b.len() / triple * triple;
            if usable == 0 {
                // The data end (a trailing partial triple is ignored, as MRtrix does).
                self.done = true;
                break;
            }
            let mut used = 0;
            let mut full = false;
            for c in b[..usable].chunks_exact(triple) {
                used += triple;
                let p = Vec3::new(coord(&c[..size]), coord(&c[size..2 * size]), coord(&c[2 * size..]));
                if p.x.is_infinite() || p.y.is_infinite() || p.z.is_infinite() {
                    self.done = true;
                    break;
                }
                if p.x.is_nan() || p.y.is_nan() || p.z.is_nan() {
                    // Every NaN triplet ends a streamline, an empty one too (as MRtrix counts them).
                    t.offsets.push(t.points.len());
                    if t.points.len() >= max_points {
                        full = true;
                        break;
                    }
                    continue;
                }
                t.points.push(p);
            }
            self.blocks.consume(used);
            if full {
                return Ok(());
            }
        }
        if t.points.len() > t.offsets.last().copied().unwrap_or(0) {
            // A last streamline without its NaN terminator (file cut short): keep what is there.
            t.offsets.push(t.points.len());
        }
        Ok(())
    }
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

struct TrkStream {
    blocks: Blocks,
    big_endian: bool,
    to_ras: DMat4,
    n_count: usize,
    ns: usize,
    np: usize,
}

impl TrkStream {
    fn open(mut blocks: Blocks, path: &Path) -> Result<(Self, trk::TrkLayout)> {
        let b = blocks.fill(trk::HEADER_BYTES).map_err(|e| Error::io(path, e))?;
        let layout = trk::parse_header(b, path)?;
        blocks.consume(trk::HEADER_BYTES);
        let h = &layout.header;
        let stream = Self {
            blocks,
            big_endian: h.big_endian,
            to_ras: h.rasmm_from_voxmm(),
            n_count: h.n_count.max(0) as usize,
            ns: layout.scalars.len(),
            np: layout.properties.len(),
        };
        Ok((stream, layout))
    }

    fn next(&mut self, t: &mut Tractogram, max_points: usize, before: usize) -> ReadResult<()> {
        let be = self.big_endian;
        let f32_at = |b: &[u8], o: usize| -> f32 {
            let a = <[u8; 4]>::try_from(&b[o..o + 4]).unwrap_or_default();
            if be { f32::from_be_bytes(a) } else { f32::from_le_bytes(a) }
        };
        let (ns, np) = (self.ns, self.np);
        loop {
            let index = before + t.n_streamlines();
            if self.n_count > 0 && index == self.n_count {
                return Ok(());
            }
            let b = self.blocks.fill(4)?;
            if b.is_empty() {
                if self.n_count > 0 && index != self.n_count {
                    return Err(ReadError::Format(format!(
                        "header promises {} streamlines, the file holds {index}",
                        self.n_count
                    )));
                }
                return Ok(());
            }
            if b.len() < 4 {
                return Err(ReadError::Format(format!("truncated point count of streamline {index}")));
            }
            let a = <[u8; 4]>::try_from(&b[..4]).unwrap_or_default();
            let n = if be { i32::from_be_bytes(a) } else { i32::from_le_bytes(a) };
            if n < 0 {
                return Err(ReadError::Format(format!("streamline {index} has a negative point count {n}")));
            }
            let n = n as usize;
            if n > MAX_STREAMLINE_POINTS {
                return Err(ReadError::Format(format!(
                    "streamline {index} claims {n} points (more than {MAX_STREAMLINE_POINTS}): a corrupt count"
                )));
            }
            let need = 4 + (n * (3 + ns) + np) * 4;
            let b = self.blocks.fill(need)?;
            if b.len() < need {
                return Err(ReadError::Format(format!(
                    "streamline {index} is truncated: needs {} bytes, {} remain",
                    need - 4,
                    b.len().saturating_sub(4)
                )));
            }
            let mut o = 4;
            for _ in 0..n {
                let p = DVec3::new(f32_at(b, o) as f64, f32_at(b, o + 4) as f64, f32_at(b, o + 8) as f64);
                t.points.push(self.to_ras.transform_point3(p).as_vec3());
                o += 12;
                for s in t.scalars.iter_mut() {
                    s.1.push(f32_at(b, o));
                    o += 4;
                }
            }
            for p in t.properties.iter_mut() {
                p.1.push(f32_at(b, o));
                o += 4;
            }
            self.blocks.consume(need);
            t.offsets.push(t.points.len());
            if t.points.len() >= max_points {
                return Ok(());
            }
        }
    }
}

/// One array of a TRX archive, located in the file.
struct TrxEntry {
    /// Name without components and type (`positions`, `dpv/fa`).
    base: String,
    components: usize,
    dtype: Dtype,
    /// Uncompressed size in bytes.
    size: u64,
    data_start: u64,
    compressed: u64,
    deflated: bool,
}

impl TrxEntry {
    /// A stream of the entry's bytes, read from the file in place (inflated when deflated).
    fn open(&self, path: &Path, count: Option<Arc<AtomicU64>>) -> Result<Blocks> {
        let mut f = File::open(path).map_err(|e| Error::io(path, e))?;
        f.seek(SeekFrom::Start(self.data_start)).map_err(|e| Error::io(path, e))?;
        let raw: Box<dyn Read + Send> = match count {
            Some(count) => Box::new(Counted { inner: f, count }.take(self.compressed)),
            None => Box::new(f.take(self.compressed)),
        };
        let src: Box<dyn Read + Send> = if self.deflated {
            Box::new(flate2::read::DeflateDecoder::new(BufReader::with_capacity(1 << 20, raw)))
        } else {
            raw
        };
        Ok(Blocks::new(src))
    }

    /// Every value of a small array (groups), as f64.
    fn read_all(&self, path: &Path) -> Result<Vec<f64>> {
        let file = std::fs::metadata(path).map_err(|e| Error::io(path, e))?.len();
        if self.size > file.saturating_mul(1032) || self.size > 1 << 32 {
            // Deflate expands at most 1032:1; a larger size is a lying directory.
            return Err(Error::format(
                path,
                format!("{}: {} bytes claimed by a {file}-byte file", self.base, self.size),
            ));
        }
        let mut blocks = self.open(path, None)?;
        let size = self.dtype.size();
        let b = blocks.fill(self.size as usize).map_err(|e| Error::io(path, e))?;
        if (b.len() as u64) < self.size {
            return Err(Error::format(path, format!("{}: truncated array", self.base)));
        }
        Ok(b[..self.size as usize].chunks_exact(size).map(|c| self.dtype.value(c)).collect())
    }
}

/// A TRX array read in order: `per` values of `dtype` per item.
struct ArrayStream {
    blocks: Blocks,
    dtype: Dtype,
    name: String,
}

impl ArrayStream {
    /// Appends the next `n` values to `out` (as f32).
    fn read_into(&mut self, n: usize, out: &mut Vec<f32>) -> ReadResult<()> {
        let size = self.dtype.size();
        let mut left = n;
        while left > 0 {
            let want = (left * size).min(BLOCK);
            let b = self.blocks.fill(want)?;
            let k = (b.len() / size).min(left);
            if k == 0 {
                return Err(ReadError::Format(format!("{}: the array ends early", self.name)));
            }
            match self.dtype {
                Dtype::F32 => out.extend(
                    b[..k * 4].chunks_exact(4).map(|c| f32::from_le_bytes(<[u8; 4]>::try_from(c).unwrap_or_default())),
                ),
                d => out.extend(b[..k * size].chunks_exact(size).map(|c| d.value(c) as f32)),
            }
            self.blocks.consume(k * size);
            left -= k;
        }
        Ok(())
    }

    /// The next value as an integer.
    fn next_index(&mut self) -> ReadResult<u64> {
        let size = self.dtype.size();
        let b = self.blocks.fill(size)?;
        if b.len() < size {
            return Err(ReadError::Format(format!("{}: the array ends early", self.name)));
        }
        let v = match self.dtype {
            Dtype::U64 | Dtype::I64 => u64::from_le_bytes(<[u8; 8]>::try_from(&b[..8]).unwrap_or_default()),
            Dtype::U32 | Dtype::I32 => u32::from_le_bytes(<[u8; 4]>::try_from(&b[..4]).unwrap_or_default()) as u64,
            d => d.value(b) as u64,
        };
        self.blocks.consume(size);
        Ok(v)
    }
}

struct TrxStream {
    positions: ArrayStream,
    offsets: ArrayStream,
    /// Values per point: stream, components, the scalar index of its first component.
    dpv: Vec<(ArrayStream, usize, usize)>,
    dps: Vec<(ArrayStream, usize, usize)>,
    n_vertices: u64,
    n_streamlines: usize,
    offset_entries: usize,
    /// Streamlines read, and the first point of the next one.
    next: usize,
    start: u64,
    /// Values of one item, reused.
    scratch: Vec<f32>,
}

/// The arrays of a TRX archive and its header.json, from the central directory (no array is read).
fn trx_entries(path: &Path) -> Result<(serde_json::Value, Vec<TrxEntry>)> {
    let bad = |reason: String| Error::format(path, reason);
    let file = File::open(path).map_err(|e| Error::io(path, e))?;
    let mut archive = zip::ZipArchive::new(BufReader::new(file))
        .map_err(|e| bad(format!("not a TRX file (a zip archive of arrays): {e}")))?;
    let mut header_text = None;
    let mut entries = vec![];
    for i in 0..archive.len() {
        let f = archive.by_index_raw(i).map_err(|e| bad(format!("entry {i} of the archive: {e}")))?;
        if f.is_dir() {
            continue;
        }
        let name = f.name().map_err(|e| bad(format!("entry {i}'s name: {e}")))?.trim_start_matches("./").to_string();
        let deflated = match f.compression() {
            zip::CompressionMethod::Stored => false,
            zip::CompressionMethod::Deflated => true,
            other => return Err(bad(format!("{name}: compression {other:?} (TRX entries are stored or deflated)"))),
        };
        if name == "header.json" {
            drop(f);
            let mut f = archive.by_index(i).map_err(|e| bad(format!("header.json: {e}")))?;
            let mut text = String::new();
            f.by_ref()
                .take(16 << 20)
                .read_to_string(&mut text)
                .map_err(|_| bad("header.json is not UTF-8 text".into()))?;
            header_text = Some(text);
            continue;
        }
        let Some((base, components, dtype)) = trx::parse_name(&name) else { continue };
        let Some(dtype) = Dtype::parse(&dtype) else {
            // Arrays of an unknown type outside the ones read (dpg/, unknown folders) are passed over.
            if base == "positions" || base == "offsets" || base.starts_with("dpv/") || base.starts_with("dps/") {
                return Err(bad(format!("{name}: unknown element type '{dtype}'")));
            }
            continue;
        };
        let data_start = f.data_start().ok_or_else(|| bad(format!("{name}: no data offset in the archive")))?;
        entries.push(TrxEntry {
            base,
            components,
            dtype,
            size: f.size(),
            data_start,
            compressed: f.compressed_size(),
            deflated,
        });
    }
    let header_text = header_text.ok_or_else(|| bad("no header.json in the archive".into()))?;
    let header: serde_json::Value =
        serde_json::from_str(&header_text).map_err(|e| bad(format!("header.json is not JSON: {e}")))?;
    Ok((header, entries))
}

/// A TRX file's header (counts, grid, groups, names of its values) from header.json and the central directory.
fn trx_header(path: &Path) -> Result<(StreamHeader, Vec<TrxEntry>)> {
    let bad = |reason: String| Error::format(path, reason);
    let (json, entries) = trx_entries(path)?;
    let trx::HeaderJson { n_vertices, n_streamlines, dims, voxel_to_rasmm } = trx::parse_header_json(&json, path)?;
    let mut groups = vec![];
    let (mut scalars, mut properties) = (vec![], vec![]);
    for e in &entries {
        let (folder, name) = e.base.split_once('/').unwrap_or(("", &e.base));
        let expected = match folder {
            "dpv" => n_vertices,
            "dps" => n_streamlines,
            "groups" => {
                let members = e.read_all(path)?;
                if members.iter().any(|&i| i < 0.0 || i >= n_streamlines as f64) {
                    return Err(bad(format!("group {name} names a streamline past {n_streamlines}")));
                }
                groups.push((name.to_string(), members.into_iter().map(|i| i as u32).collect()));
                continue;
            }
            _ => continue,
        };
        if e.size != (expected * e.components * e.dtype.size()) as u64 {
            return Err(bad(format!(
                "{}: {} values, expected {expected} x {}",
                e.base,
                e.size / e.dtype.size() as u64,
                e.components
            )));
        }
        let target = if folder == "dpv" { &mut scalars } else { &mut properties };
        for k in 0..e.components {
            target.push(if e.components == 1 { name.to_string() } else { format!("{name}_{k}") });
        }
    }
    let file_bytes = std::fs::metadata(path).map_err(|e| Error::io(path, e))?.len();
    let header = StreamHeader {
        format: Format::Trx,
        count: Some(n_streamlines),
        points: Some(n_vertices),
        scalars,
        properties,
        tck: None,
        trk: None,
        trx: Some(trx::TrxHeader { dims, voxel_to_rasmm, groups }),
        file_bytes,
    };
    Ok((header, entries))
}

/// Where a TRX file's positions lie, to be read in place ([`crate::io::mapped::MappedPoints::open_trx`]): the
/// byte offset of their data in the file and how many points the header says. An error naming the file unless
/// they are three float32 per point, stored (not deflated), and as many as the header says.
pub(crate) fn trx_positions(path: &Path) -> Result<(u64, usize)> {
    let bad = |reason: String| Error::format(path, reason);
    let (header, entries) = trx_header(path)?;
    let n = header.points.unwrap_or(0);
    let pos = entries.iter().find(|e| e.base == "positions").ok_or_else(|| bad("no positions array".into()))?;
    if pos.components != 3 || pos.dtype != Dtype::F32 || pos.deflated {
        return Err(bad(format!(
            "positions are {} x {:?}{}: only stored float32 positions are read in place",
            pos.components,
            pos.dtype,
            if pos.deflated { ", deflated" } else { "" }
        )));
    }
    if pos.size != n as u64 * 12 {
        return Err(bad(format!("positions hold {} points, the header says {n}", pos.size / 12)));
    }
    Ok((pos.data_start, n))
}

impl TrxStream {
    fn open(path: &Path) -> Result<(Self, StreamHeader, Arc<AtomicU64>)> {
        let bad = |reason: String| Error::format(path, reason);
        let (header, entries) = trx_header(path)?;
        let (n_vertices, n_streamlines) = (header.points.unwrap_or(0), header.count.unwrap_or(0));
        let find = |base: &str| entries.iter().find(|e| e.base == base);
        let pos = find("positions").ok_or_else(|| bad("no positions array".into()))?;
        if pos.components != 3 || !matches!(pos.dtype, Dtype::F16 | Dtype::F32 | Dtype::F64) {
            return Err(bad(format!(
                "positions must be 3 floats per point, not {} of {:?}",
                pos.components, pos.dtype
            )));
        }
        if pos.size != (3 * n_vertices * pos.dtype.size()) as u64 {
            return Err(bad(format!(
                "positions hold {} points, the header says {n_vertices}",
                pos.size / (3 * pos.dtype.size()) as u64
            )));
        }
        let off = find("offsets").ok_or_else(|| bad("no offsets array".into()))?;
        if !matches!(off.dtype, Dtype::U32 | Dtype::U64 | Dtype::I32 | Dtype::I64) {
            return Err(bad(format!("offsets must be integers, not {:?}", off.dtype)));
        }
        let offset_entries = (off.size / off.dtype.size() as u64) as usize;
        if offset_entries != n_streamlines && offset_entries != n_streamlines + 1 {
            return Err(bad(format!(
                "offsets ({offset_entries} entries) do not cut {n_vertices} points into {n_streamlines} streamlines in order"
            )));
        }
        let count = Arc::new(AtomicU64::new(0));
        let stream = |e: &TrxEntry, c: Option<Arc<AtomicU64>>| -> Result<ArrayStream> {
            Ok(ArrayStream { blocks: e.open(path, c)?, dtype: e.dtype, name: e.base.clone() })
        };
        let mut dpv = vec![];
        let mut dps = vec![];
        let (mut ks, mut kp) = (0, 0);
        for e in &entries {
            match e.base.split_once('/') {
                Some(("dpv", _)) => {
                    dpv.push((stream(e, None)?, e.components, ks));
                    ks += e.components;
                }
                Some(("dps", _)) => {
                    dps.push((stream(e, None)?, e.components, kp));
                    kp += e.components;
                }
                _ => {}
            }
        }
        let s = TrxStream {
            positions: stream(pos, Some(count.clone()))?,
            offsets: stream(off, None)?,
            dpv,
            dps,
            n_vertices: n_vertices as u64,
            n_streamlines,
            offset_entries,
            next: 0,
            start: 0,
            scratch: vec![],
        };
        Ok((s, header, count))
    }

    fn next(&mut self, t: &mut Tractogram, max_points: usize) -> ReadResult<()> {
        let first = self.next;
        let mut ends = vec![];
        while self.next < self.n_streamlines && (ends.is_empty() || t.points.len() < max_points) {
            if self.next == 0 {
                let v = self.offsets.next_index()?;
                if v != 0 {
                    return Err(ReadError::Format(format!("offsets start at {v}, not 0")));
                }
            }
            let end = if self.next + 1 < self.offset_entries { self.offsets.next_index()? } else { self.n_vertices };
            if end < self.start || end > self.n_vertices {
                return Err(ReadError::Format(format!(
                    "offsets do not cut {} points into {} streamlines in order (streamline {} ends at {end})",
                    self.n_vertices, self.n_streamlines, self.next
                )));
            }
            let n = (end - self.start) as usize;
            ends.push(n);
            // Positions are read below for the whole chunk; count points here.
            let len = t.points.len() + n;
            t.points.resize(len, Vec3::ZERO);
            self.start = end;
            self.next += 1;
        }
        if self.next == self.n_streamlines
            && self.offset_entries == self.n_streamlines + 1
            && self.start != self.n_vertices
        {
            return Err(ReadError::Format(format!(
                "offsets end at {}, the header says {} points",
                self.start, self.n_vertices
            )));
        }
        let n_points = t.points.len();
        self.scratch.clear();
        self.positions.read_into(3 * n_points, &mut self.scratch)?;
        for (p, c) in t.points.iter_mut().zip(self.scratch.chunks_exact(3)) {
            *p = Vec3::new(c[0], c[1], c[2]);
        }
        let mut acc = 0;
        for n in &ends {
            acc += n;
            t.offsets.push(acc);
        }
        let n_streamlines = self.next - first;
        for (stream, k, at) in &mut self.dpv {
            self.scratch.clear();
            stream.read_into(n_points * *k, &mut self.scratch)?;
            for c in 0..*k {
                t.scalars[*at + c].1.extend(self.scratch.iter().skip(c).step_by(*k));
            }
        }
        for (stream, k, at) in &mut self.dps {
            self.scratch.clear();
            stream.read_into(n_streamlines * *k, &mut self.scratch)?;
            for c in 0..*k {
                t.properties[*at + c].1.extend(self.scratch.iter().skip(c).step_by(*k));
            }
        }
        Ok(())
    }
}

/// What one pass over a tractogram finds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Summary {
    /// Streamlines (empty ones included, as MRtrix counts them).
    pub streamlines: usize,
    /// Points.
    pub points: usize,
    /// Bounds of the points (RAS+ mm); None when not read (a TRX's header only) or when there is no point.
    pub bounds: Option<(Vec3, Vec3)>,
}

/// Counts a tractogram's streamlines and points and bounds its points in one pass of bounded memory; for a TRX,
/// reads the header only (counts from header.json, no bounds). `progress` is called with the bytes read after
/// each chunk.
pub fn scan(reader: &mut TractogramReader, mut progress: impl FnMut(u64)) -> Result<Summary> {
    if reader.header().format == Format::Trx {
        let h = reader.header();
        return Ok(Summary { streamlines: h.count.unwrap_or(0), points: h.points.unwrap_or(0), bounds: None });
    }
    let mut s = Summary::default();
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    while let Some(t) = reader.next_chunk(DEFAULT_CHUNK_POINTS)? {
        s.streamlines += t.n_streamlines();
        s.points += t.points.len();
        let (a, b) = bounds(&t.points);
        lo = lo.min(a);
        hi = hi.max(b);
        progress(reader.bytes_read());
    }
    s.bounds = (s.points > 0 && lo.cmple(hi).all()).then_some((lo, hi));
    Ok(s)
}

/// Bounds of finite points (infinite box when there are none).
fn bounds(points: &[Vec3]) -> (Vec3, Vec3) {
    let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
    for p in points {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    (lo, hi)
}

/// Where and how a [`TractogramWriter`] places streamlines.
#[derive(Clone, Debug, Default)]
pub struct WriteOptions {
    /// The reference grid of a `.trk` (voxel-to-RAS+ affine, dimensions): required for `.trk`.
    pub trk_space: Option<(DMat4, [usize; 3])>,
    /// The reference grid and groups of a `.trx`; without it, a 1 mm grid covering the points written.
    pub trx: Option<trx::TrxHeader>,
    /// Extra `.tck` header entries (`count`, `file` and `datatype` are the writer's own).
    pub tck_header: Vec<(String, String)>,
    /// Names of the values per point and per streamline that chunks carry, to be written where the format
    /// holds them (`.trk`: at most 10 each; `.trx`: `dpv/`, `dps/`; `.tck`: none).
    pub scalars: Vec<String>,
    /// Names of the values per streamline, in the order chunks carry them (`.trk`: at most 10). Defaults to none.
    pub properties: Vec<String>,
    /// Precision of TRX positions (default float32).
    pub trx_positions: Option<trx::PositionType>,
}

/// Writes a tractogram chunk by chunk. See the module documentation.
pub struct TractogramWriter {
    path: PathBuf,
    /// Where the data go until [`Self::finish`] moves them to `path`.
    part: PathBuf,
    gzip: bool,
    inner: Writer,
    /// Removes the part file and the TRX spool files when the writer is dropped unfinished (an error, a
    /// cancel), and whatever is left after [`Self::finish`].
    _leftovers: Leftovers,
    streamlines: usize,
    points: u64,
    lo: Vec3,
    hi: Vec3,
}

enum Writer {
    Tck { out: BufWriter<File>, count_at: u64 },
    Trk { out: BufWriter<File>, voxmm_from_ras: DMat4, ns: usize, np: usize, buf: Vec<u8> },
    Trx(Box<TrxWriter>),
}

struct TrxWriter {
    zip: zip::ZipWriter<BufWriter<File>>,
    positions: trx::PositionType,
    offsets: (PathBuf, BufWriter<File>),
    dpv: Vec<(String, PathBuf, BufWriter<File>)>,
    dps: Vec<(String, PathBuf, BufWriter<File>)>,
    header: Option<trx::TrxHeader>,
    buf: Vec<u8>,
}

/// Where an output is written until it is complete: `OUT.part` beside it.
pub(crate) fn part_path(path: &Path) -> PathBuf {
    let mut part = path.as_os_str().to_os_string();
    part.push(".part");
    PathBuf::from(part)
}

/// Writes `bytes` to `path` whole or not at all: into [`part_path`], then renamed.
pub(crate) fn write_whole(path: &Path, bytes: &[u8]) -> Result<()> {
    let part = part_path(path);
    let leftover = Leftovers(vec![part.clone()]);
    std::fs::write(&part, bytes).map_err(|e| Error::io(&part, e))?;
    std::fs::rename(&part, path).map_err(|e| Error::io(path, e))?;
    drop(leftover);
    Ok(())
}

/// Files removed when dropped (those that no longer exist are skipped).
pub(crate) struct Leftovers(pub(crate) Vec<PathBuf>);

impl Drop for Leftovers {
    fn drop(&mut self) {
        for p in &self.0 {
            std::fs::remove_file(p).ok();
        }
    }
}

fn spool(path: &Path) -> Result<BufWriter<File>> {
    Ok(BufWriter::with_capacity(1 << 20, File::create(path).map_err(|e| Error::io(path, e))?))
}

impl TractogramWriter {
    /// Starts writing `path` (`.tck`, `.trk`, gzipped or not, or `.trx`; the name picks the format).
    pub fn create(path: impl AsRef<Path>, options: &WriteOptions) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let format = Format::of(&path)?;
        let gzip = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("gz"));
        if gzip && format == Format::Trx {
            return Err(Error::Param(format!("{}: a TRX is not gzipped (it is a zip archive)", path.display())));
        }
        let part = part_path(&path);
        let side_file = |what: String| -> PathBuf {
            let mut p = part.clone().into_os_string();
            p.push(format!(".{what}"));
            PathBuf::from(p)
        };
        let mut leftovers = vec![part.clone(), side_file("offsets".into())];
        leftovers.extend((0..options.scalars.len()).map(|i| side_file(format!("dpv{i}"))));
        leftovers.extend((0..options.properties.len()).map(|i| side_file(format!("dps{i}"))));
        let leftovers = Leftovers(leftovers);
        let io = |e| Error::io(&part, e);
        let inner = match format {
            Format::Tck => {
                let (bytes, count_at) = tck::header_bytes(&options.tck_header, 0);
                let mut out = spool(&part)?;
                out.write_all(&bytes).map_err(io)?;
                Writer::Tck { out, count_at }
            }
            Format::Trk => {
                let Some((affine, dims)) = options.trk_space else {
                    return Err(Error::Param(format!(
                        "{}: writing a .trk needs a reference grid (an affine and dimensions)",
                        path.display()
                    )));
                };
                if options.scalars.len() > 10 || options.properties.len() > 10 {
                    return Err(Error::Param("TrackVis stores at most 10 scalars and 10 properties".into()));
                }
                let s: Vec<&str> = options.scalars.iter().map(String::as_str).collect();
                let p: Vec<&str> = options.properties.iter().map(String::as_str).collect();
                let (header, bytes) = trk::encode_header(affine, dims, &s, &p, 0);
                let mut out = spool(&part)?;
                out.write_all(&bytes).map_err(io)?;
                let voxmm_from_ras = header.rasmm_from_voxmm().inverse();
                Writer::Trk { out, voxmm_from_ras, ns: s.len(), np: p.len(), buf: Vec::new() }
            }
            Format::Trx => {
                let file = File::create(&part).map_err(io)?;
                let mut zip = zip::ZipWriter::new(BufWriter::with_capacity(1 << 20, file));
                let positions = options.trx_positions.unwrap_or(trx::PositionType::F32);
                let suffix = match positions {
                    trx::PositionType::F16 => "float16",
                    trx::PositionType::F32 => "float32",
                    trx::PositionType::F64 => "float64",
                };
                let opts = zip::write::SimpleFileOptions::default()
                    .compression_method(zip::CompressionMethod::Stored)
                    .large_file(true);
                // Positions on a cache line's boundary, so that a reader can map them in place.
                zip.start_file(format!("positions.3.{suffix}"), opts.with_alignment(64))
                    .map_err(|e| zip_error(&part, e))?;
                let side = |what: &str| side_file(what.to_string());
                let arrays = |folder: &str, names: &[String]| -> Result<Vec<(String, PathBuf, BufWriter<File>)>> {
                    names
                        .iter()
                        .enumerate()
                        .map(|(i, n)| {
                            if n.is_empty() || n.contains(['/', '\\']) {
                                return Err(Error::Param(format!("{folder} name '{n}' cannot be a TRX array name")));
                            }
                            let p = side(&format!("{folder}{i}"));
                            let w = spool(&p)?;
                            Ok((format!("{folder}/{n}.float32"), p, w))
                        })
                        .collect()
                };
                let offsets_path = side("offsets");
                let offsets = spool(&offsets_path)?;
                let dpv = arrays("dpv", &options.scalars)?;
                let dps = arrays("dps", &options.properties)?;
                Writer::Trx(Box::new(TrxWriter {
                    zip,
                    positions,
                    offsets: (offsets_path, offsets),
                    dpv,
                    dps,
                    header: options.trx.clone(),
                    buf: Vec::new(),
                }))
            }
        };
        Ok(Self {
            path,
            part,
            gzip,
            inner,
            _leftovers: leftovers,
            streamlines: 0,
            points: 0,
            lo: Vec3::splat(f32::INFINITY),
            hi: Vec3::splat(f32::NEG_INFINITY),
        })
    }

    /// Streamlines written so far.
    pub fn streamlines(&self) -> usize {
        self.streamlines
    }

    /// Appends the streamlines of `t` (its values per point and per streamline must be those named in the
    /// options, in that order, where the format holds them).
    pub fn write_chunk(&mut self, t: &Tractogram) -> Result<()> {
        let part = self.part.clone();
        let io = |e| Error::io(&part, e);
        let n = t.n_streamlines();
        let (lo, hi) = bounds(&t.points);
        self.lo = self.lo.min(lo);
        self.hi = self.hi.max(hi);
        match &mut self.inner {
            Writer::Tck { out, .. } => {
                let mut buf = Vec::new();
                tck::encode_streamlines(&mut buf, t);
                out.write_all(&buf).map_err(io)?;
            }
            Writer::Trk { out, voxmm_from_ras, ns, np, buf } => {
                if t.scalars.len() < *ns || t.properties.len() < *np {
                    return Err(Error::Shape(format!(
                        "{}: a chunk carries {} scalars and {} properties, the header names {ns} and {np}",
                        self.path.display(),
                        t.scalars.len(),
                        t.properties.len()
                    )));
                }
                buf.clear();
                for i in 0..n {
                    let (a, z) = (t.offsets[i], t.offsets[i + 1]);
                    buf.extend_from_slice(&((z - a) as i32).to_le_bytes());
                    for k in a..z {
                        let p = voxmm_from_ras.transform_point3(t.points[k].as_dvec3());
                        for c in p.to_array() {
                            buf.extend_from_slice(&(c as f32).to_le_bytes());
                        }
                        for (_, s) in &t.scalars[..*ns] {
                            buf.extend_from_slice(&s.get(k).copied().unwrap_or(0.0).to_le_bytes());
                        }
                    }
                    for (_, p) in &t.properties[..*np] {
                        buf.extend_from_slice(&p.get(i).copied().unwrap_or(0.0).to_le_bytes());
                    }
                }
                out.write_all(buf).map_err(io)?;
            }
            Writer::Trx(w) => {
                if t.scalars.len() < w.dpv.len() || t.properties.len() < w.dps.len() {
                    return Err(Error::Shape(format!(
                        "{}: a chunk carries {} scalars and {} properties, the writer expects {} and {}",
                        self.path.display(),
                        t.scalars.len(),
                        t.properties.len(),
                        w.dpv.len(),
                        w.dps.len()
                    )));
                }
                w.buf.clear();
                let coords = t.points.iter().flat_map(|p| p.to_array());
                match w.positions {
                    trx::PositionType::F16 => coords.for_each(|x| w.buf.extend(trx::f32_to_f16(x).to_le_bytes())),
                    trx::PositionType::F32 => coords.for_each(|x| w.buf.extend(x.to_le_bytes())),
                    trx::PositionType::F64 => coords.for_each(|x| w.buf.extend(f64::from(x).to_le_bytes())),
                }
                w.zip.write_all(&w.buf).map_err(io)?;
                w.buf.clear();
                for i in 0..n {
                    w.buf.extend((self.points + t.offsets[i] as u64).to_le_bytes());
                }
                w.offsets.1.write_all(&w.buf).map_err(io)?;
                for ((_, _, out), (_, v)) in w.dpv.iter_mut().zip(&t.scalars) {
                    w.buf.clear();
                    (0..t.points.len()).for_each(|k| w.buf.extend(v.get(k).copied().unwrap_or(0.0).to_le_bytes()));
                    out.write_all(&w.buf).map_err(io)?;
                }
                for ((_, _, out), (_, v)) in w.dps.iter_mut().zip(&t.properties) {
                    w.buf.clear();
                    (0..n).for_each(|k| w.buf.extend(v.get(k).copied().unwrap_or(0.0).to_le_bytes()));
                    out.write_all(&w.buf).map_err(io)?;
                }
            }
        }
        self.streamlines += n;
        self.points += t.points.len() as u64;
        Ok(())
    }

    /// Ends the file (counts, closing entries) and moves it into place; the number of streamlines written.
    pub fn finish(self) -> Result<usize> {
        let part = self.part.clone();
        let result = self.finish_inner();
        if result.is_err() {
            std::fs::remove_file(&part).ok();
        }
        result
    }

    fn finish_inner(self) -> Result<usize> {
        let part = &self.part;
        let io = |e| Error::io(part, e);
        match self.inner {
            Writer::Tck { mut out, count_at } => {
                for _ in 0..3 {
                    out.write_all(&f32::INFINITY.to_le_bytes()).map_err(io)?;
                }
                let mut f = out.into_inner().map_err(|e| io(e.into_error()))?;
                f.seek(SeekFrom::Start(count_at)).map_err(io)?;
                f.write_all(format!("{:010}", self.streamlines).as_bytes()).map_err(io)?;
                f.sync_data().ok();
            }
            Writer::Trk { out, .. } => {
                let mut f = out.into_inner().map_err(|e| io(e.into_error()))?;
                let n = i32::try_from(self.streamlines).unwrap_or(0);
                f.seek(SeekFrom::Start(trk::N_COUNT_OFFSET)).map_err(io)?;
                f.write_all(&n.to_le_bytes()).map_err(io)?;
            }
            Writer::Trx(w) => {
                let TrxWriter { mut zip, mut offsets, dpv, dps, header, .. } = *w;
                // The closing entry (NB_STREAMLINES + 1 offsets, ending at NB_VERTICES), as trx-python requires.
                offsets.1.write_all(&self.points.to_le_bytes()).map_err(io)?;
                let copy = |zip: &mut zip::ZipWriter<BufWriter<File>>,
                            name: &str,
                            (p, out): (PathBuf, BufWriter<File>)|
                 -> Result<()> {
                    drop(out.into_inner().map_err(|e| Error::io(&p, e.into_error()))?);
                    let size = std::fs::metadata(&p).map_err(|e| Error::io(&p, e))?.len();
                    let opts = zip::write::SimpleFileOptions::default()
                        .compression_method(zip::CompressionMethod::Stored)
                        .large_file(size >= u32::MAX as u64);
                    zip.start_file(name, opts).map_err(|e| zip_error(&p, e))?;
                    let mut f = File::open(&p).map_err(|e| Error::io(&p, e))?;
                    std::io::copy(&mut f, zip).map_err(|e| Error::io(&p, e))?;
                    std::fs::remove_file(&p).ok();
                    Ok(())
                };
                copy(&mut zip, "offsets.uint64", offsets)?;
                for (name, p, out) in dpv.into_iter().chain(dps) {
                    copy(&mut zip, &name, (p, out))?;
                }
                let (dims, affine, groups) = match header {
                    Some(h) => (h.dims, h.voxel_to_rasmm, h.groups),
                    None => {
                        let ok = self.lo.cmple(self.hi).all();
                        let lo = if ok { self.lo.floor() } else { Vec3::ZERO };
                        let hi = if ok { self.hi.ceil() } else { Vec3::ZERO };
                        ((hi - lo + 1.0).to_array().map(|v| v as usize), DMat4::from_translation(lo.as_dvec3()), vec![])
                    }
                };
                let opts = zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
                for (name, members) in &groups {
                    if members.iter().any(|&i| i as usize >= self.streamlines) {
                        return Err(Error::Shape(format!("group {name} names a streamline past {}", self.streamlines)));
                    }
                    zip.start_file(format!("groups/{name}.uint32"), opts).map_err(|e| zip_error(part, e))?;
                    let bytes: Vec<u8> = members.iter().flat_map(|i| i.to_le_bytes()).collect();
                    zip.write_all(&bytes).map_err(io)?;
                }
                let cols = affine.to_cols_array_2d();
                let rows: Vec<Vec<f64>> = (0..4).map(|r| (0..4).map(|c| cols[c][r]).collect()).collect();
                let json = serde_json::json!({
                    "DIMENSIONS": dims,
                    "VOXEL_TO_RASMM": rows,
                    "NB_VERTICES": self.points,
                    "NB_STREAMLINES": self.streamlines,
                });
                zip.start_file("header.json", opts).map_err(|e| zip_error(part, e))?;
                zip.write_all(json.to_string().as_bytes()).map_err(io)?;
                zip.finish().map_err(|e| zip_error(part, e))?.flush().map_err(io)?;
            }
        }
        if self.gzip {
            let mut src = File::open(part).map_err(io)?;
            let dst = File::create(&self.path).map_err(|e| Error::io(&self.path, e))?;
            let mut enc = flate2::write::GzEncoder::new(BufWriter::new(dst), flate2::Compression::fast());
            std::io::copy(&mut src, &mut enc).map_err(|e| Error::io(&self.path, e))?;
            enc.finish().and_then(|mut w| w.flush()).map_err(|e| Error::io(&self.path, e))?;
            std::fs::remove_file(part).ok();
        } else {
            std::fs::rename(part, &self.path).map_err(|e| Error::io(&self.path, e))?;
        }
        Ok(self.streamlines)
    }
}

fn zip_error(path: &Path, e: zip::result::ZipError) -> Error {
    Error::io(path, std::io::Error::other(e))
}

/// The reference grid a `.trk` written from this input uses: the input's own (a `.trk`'s or a TRX's), else a
/// 1 mm grid covering `bounds` (for a `.tck`, which has none).
pub fn trk_space(header: &StreamHeader, bounds: Option<(Vec3, Vec3)>) -> (DMat4, [usize; 3]) {
    if let Some(h) = header.trk.as_ref().filter(|h| h.vox_to_ras != DMat4::ZERO && h.dims.iter().all(|d| *d > 0)) {
        return (h.vox_to_ras, h.dims.map(|d| d as usize));
    }
    if let Some(h) = header.trx.as_ref().filter(|h| h.dims.iter().all(|d| *d > 0)) {
        return (h.voxel_to_rasmm, h.dims);
    }
    grid_over(bounds)
}

/// A 1 mm grid from `bounds`' lower corner covering them (a single voxel without bounds): the reference grid of a
/// `.trk` written from streamlines that have none.
pub fn grid_over(bounds: Option<(Vec3, Vec3)>) -> (DMat4, [usize; 3]) {
    let (lo, hi) = bounds.map_or((DVec3::ZERO, DVec3::ZERO), |(a, b)| (a.as_dvec3(), b.as_dvec3()));
    let dims = ((hi - lo).ceil() + 1.0).to_array().map(|v| v.max(1.0) as usize);
    (DMat4::from_translation(lo), dims)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Tractogram {
        let mut t = Tractogram::new();
        for s in 0..1000 {
            let n = 1 + s % 37;
            let pts: Vec<Vec3> =
                (0..n).map(|k| Vec3::new(s as f32 * 0.5 - 100.0, k as f32 * 1.25, (s % 7) as f32 - 3.0)).collect();
            t.push(&pts);
        }
        t
    }

    fn read_all(path: &Path, chunk: usize) -> Tractogram {
        let mut r = TractogramReader::open(path).unwrap();
        let mut all = Tractogram::new();
        while let Some(c) = r.next_chunk(chunk).unwrap() {
            assert!(c.n_streamlines() > 0);
            for s in c.iter() {
                all.push(s);
            }
        }
        all
    }

    /// Every format written chunk by chunk reads back the same streamlines as the whole-file readers, in any
    /// chunk size, gzipped or not.
    #[test]
    fn chunks_round_trip_in_every_format() {
        let t = sample();
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-stream-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        for name in ["a.tck", "a.tck.gz", "a.trk", "a.trk.gz", "a.trx"] {
            let path = dir.join(name);
            let mut options = WriteOptions::default();
            let (lo, hi) = bounds(&t.points);
            options.trk_space = Some(trk_space(
                &StreamHeader {
                    format: Format::Tck,
                    count: None,
                    points: None,
                    scalars: vec![],
                    properties: vec![],
                    tck: None,
                    trk: None,
                    trx: None,
                    file_bytes: 0,
                },
                Some((lo, hi)),
            ));
            let mut w = TractogramWriter::create(&path, &options).unwrap();
            for part in [0..10, 10..11, 11..600, 600..1000] {
                let keep: Vec<bool> = (0..1000).map(|i| part.contains(&i)).collect();
                w.write_chunk(&t.subset(&keep)).unwrap();
            }
            assert_eq!(w.finish().unwrap(), 1000);
            let whole = Tractogram::read(&path).unwrap();
            assert_eq!(whole.offsets, t.offsets, "{name}");
            let worst =
                whole.points.iter().zip(&t.points).map(|(a, b)| (*a - *b).abs().max_element()).fold(0.0, f32::max);
            assert!(worst < 1e-4, "{name}: {worst}");
            for chunk in [1, 50, 1 << 20] {
                let s = read_all(&path, chunk);
                assert_eq!((&s.offsets, &s.points), (&whole.offsets, &whole.points), "{name} in chunks of {chunk}");
            }
            if name.ends_with(".trx") {
                // NB_STREAMLINES + 1 offsets ending at NB_VERTICES, as trx-python requires.
                let mut zip = zip::ZipArchive::new(File::open(&path).unwrap()).unwrap();
                let mut offsets = vec![];
                zip.by_name("offsets.uint64").unwrap().read_to_end(&mut offsets).unwrap();
                assert_eq!(offsets.len(), 8 * 1001);
                assert_eq!(offsets[8000..], (t.points.len() as u64).to_le_bytes());
            }
            let mut r = TractogramReader::open(&path).unwrap();
            let summary = scan(&mut r, |_| {}).unwrap();
            assert_eq!((summary.streamlines, summary.points), (1000, t.points.len()), "{name}");
            assert!(!dir.join(format!("{name}.part")).exists());
        }
    }
}
