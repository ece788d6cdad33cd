//! ROI selection on tractograms too large for a [`crate::roi::SegmentGrid`]: per cell of a uniform grid, the
//! streamlines that pass through it, each once (4 bytes per streamline and cell; about 1.2 GB for 10M
//! whole-brain streamlines at 4 mm cells, where a segment grid holds 4 bytes per segment and cell plus the
//! owner of every point, 8 GB). The streamlines' points stay where they are (a mapped file:
//! [`crate::io::mapped::MappedTck`]); a query tests the candidates' own points with the rules of
//! [`crate::roi::select`], so it keeps the same streamlines.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::roi::{Cells, Ray, Roi, RoiMode, RoiShape};

/// Per grid cell, the streamlines with a point in it or a segment whose bounding box meets it.
pub struct StreamlineCells {
    cells: Cells,
    /// CSR over cells: `starts[c]..starts[c + 1]` in `ids`.
    starts: Vec<u64>,
    /// Streamline indices, each at most once per cell; below [`MASKED_BELOW`] streamlines, each with the mask of
    /// the cell's eighths the streamline passes through in its top 8 bits ([`Cells::spanned_eighths`]), so that
    /// a query takes only those in the eighths that meet it.
    ids: Vec<u32>,
    /// Streamlines indexed.
    n: usize,
    /// The bounds of their finite points (none without any).
    extent: Option<(Vec3, Vec3)>,
}

/// Up to this many streamlines, an index entry holds the cell's eighths the streamline passes through beside
/// its index (24 bits).
const MASKED_BELOW: usize = 1 << 24;

/// The streamline index of an index entry.
#[inline]
fn id_of(entry: u32, masked: bool) -> u32 {
    if masked { entry & (MASKED_BELOW as u32 - 1) } else { entry }
}

impl StreamlineCells {
    /// Indexes `n` streamlines (`streamline(s)`: the points of streamline `s`) whose points lie within `bounds`
    /// (points outside go to the nearest border cell), in cells of about `cell` mm (at most 1024 per axis).
    /// Two parallel passes over the points: count, then fill.
    pub fn build<'a>(
        n: usize,
        streamline: impl Fn(usize) -> &'a [Vec3] + Sync,
        bounds: (Vec3, Vec3),
        cell: f32,
    ) -> Self {
        Self::build_in_blocks(n, streamline, bounds, cell, |_| {})
    }

    /// [`StreamlineCells::build`], each pass going over the streamlines a block at a time and calling
    /// `done(block)` after each block (for streamlines read in place: let the block's pages go, so that a pass
    /// over a large file holds a block of it in memory, not the file).
    pub fn build_in_blocks<'a>(
        n: usize,
        streamline: impl Fn(usize) -> &'a [Vec3] + Sync,
        bounds: (Vec3, Vec3),
        cell: f32,
        done: impl Fn(std::ops::Range<usize>),
    ) -> Self {
        let cells = Cells::over(bounds.0, bounds.1, cell);
        let n_cells = cells.count();
        let counts: Vec<AtomicU64> = (0..n_cells).map(|_| AtomicU64::new(0)).collect();
        let none = || (Vec3::INFINITY, Vec3::NEG_INFINITY);
        let (mut lo, mut hi) = none();
        for block in blocks(n) {
            let (l, h) = block
                .clone()
                .into_par_iter()
                .fold(
                    || (Vec::new(), none()),
                    |(mut buf, (lo, hi)), s| {
                        let pts = streamline(s);
                        cells_of(&cells, pts, &mut buf);
                        for &(c, _) in buf.iter() {
                            counts[c as usize].fetch_add(1, Ordering::Relaxed);
                        }
                        (buf, finite_bounds(pts, (lo, hi)))
                    },
                )
                .map(|(_, b)| b)
                .reduce(none, |a, b| (a.0.min(b.0), a.1.max(b.1)));
            (lo, hi) = (lo.min(l), hi.max(h));
            done(block);
        }
        let extent = lo.cmple(hi).all().then_some((lo, hi));
        let mut starts = Vec::with_capacity(n_cells + 1);
        starts.push(0u64);
        for c in &counts {
            starts.push(starts.last().copied().unwrap_or(0) + c.load(Ordering::Relaxed));
        }
        let fill: Vec<AtomicU64> = starts[..n_cells].iter().map(|&s| AtomicU64::new(s)).collect();
        let total = starts[n_cells] as usize;
        let ids: Vec<AtomicU32> = (0..total).map(|_| AtomicU32::new(0)).collect();
        for block in blocks(n) {
            block.clone().into_par_iter().for_each_init(Vec::new, |buf, s| {
                cells_of(&cells, streamline(s), buf);
                for &(c, eighths) in buf.iter() {
                    let at = fill[c as usize].fetch_add(1, Ordering::Relaxed);
                    let entry = if n < MASKED_BELOW { s as u32 | u32::from(eighths) << 24 } else { s as u32 };
                    ids[at as usize].store(entry, Ordering::Relaxed);
                }
            });
            done(block);
        }
        let ids = ids.into_iter().map(AtomicU32::into_inner).collect();
        Self { cells, starts, ids, n, extent }
    }

    /// [`StreamlineCells::build`] over the bounds of the streamlines' own finite points (found in one parallel
    /// pass first; a zero box without any).
    pub fn build_fitted<'a>(n: usize, streamline: impl Fn(usize) -> &'a [Vec3] + Sync, cell: f32) -> Self {
        Self::build_fitted_in_blocks(n, streamline, cell, |_| {})
    }

    /// [`StreamlineCells::build_fitted`] a block at a time, as [`StreamlineCells::build_in_blocks`].
    pub fn build_fitted_in_blocks<'a>(
        n: usize,
        streamline: impl Fn(usize) -> &'a [Vec3] + Sync,
        cell: f32,
        done: impl Fn(std::ops::Range<usize>),
    ) -> Self {
        let none = || (Vec3::INFINITY, Vec3::NEG_INFINITY);
        let (mut lo, mut hi) = none();
        for block in blocks(n) {
            let (l, h) = block
                .clone()
                .into_par_iter()
                .map(|s| finite_bounds(streamline(s), none()))
                .reduce(none, |a, b| (a.0.min(b.0), a.1.max(b.1)));
            (lo, hi) = (lo.min(l), hi.max(h));
            done(block);
        }
        let bounds = if lo.cmple(hi).all() { (lo, hi) } else { (Vec3::ZERO, Vec3::ZERO) };
        Self::build_in_blocks(n, streamline, bounds, cell, done)
    }

    /// Bytes the index holds.
    pub fn heap_bytes(&self) -> usize {
        self.starts.len() * 8 + self.ids.len() * 4
    }

    /// The streamlines indexed in the cells that meet `shape` (ascending, each once), in the cells' eighths
    /// that do: a superset of those that meet it. Deduplicated in a bit set of all streamlines (no sort), so the
    /// candidates come in file order, which is also the order their points lie in memory.
    pub fn candidates(&self, shape: &RoiShape) -> Vec<u32> {
        let masked = self.n < MASKED_BELOW;
        let cells: Vec<(usize, u8)> = self.cells.meeting_with_eighths(shape).flatten().collect();
        let entries = |&(c, _): &(usize, u8)| self.starts[c + 1] - self.starts[c];
        // Each thread sets the bits of a share of the cells (about as many entries each) in a set of its own;
        // the sets are OR-ed (a whole brain's 10 mm sphere at 10M: 700k entries in 1.25 MB sets).
        let bits = shares(&cells, entries, rayon::current_num_threads())
            .into_par_iter()
            .map(|cells| {
                let mut bits = vec![0u64; self.n.div_ceil(64)];
                for &(c, eighths) in cells {
                    // Without a branch: a third of the entries are in eighths the shape does not meet.
                    for &entry in &self.ids[self.starts[c] as usize..self.starts[c + 1] as usize] {
                        let s = id_of(entry, masked);
                        let hit = u64::from(!masked || (entry >> 24) as u8 & eighths != 0);
                        bits[s as usize / 64] |= hit << (s % 64);
                    }
                }
                bits
            })
            .reduce_with(|mut a, b| {
                a.iter_mut().zip(&b).for_each(|(a, b)| *a |= b);
                a
            })
            .unwrap_or_default();
        // Each set bit in turn (the lowest first), not each of a word's 64 bits: a whole brain's 10 mm sphere
        // sets bits in nearly every word of 10M, one in 14 of them. In parallel over runs of words, in order.
        let run = bits.len().div_ceil(rayon::current_num_threads()).max(1);
        let runs: Vec<Vec<u32>> = bits
            .par_chunks(run)
            .enumerate()
            .map(|(k, words)| {
                let mut out = Vec::new();
                for (i, &word) in words.iter().enumerate() {
                    let mut w = word;
                    while w != 0 {
                        out.push(((k * run + i) * 64) as u32 + w.trailing_zeros());
                        w &= w - 1;
                    }
                }
                out
            })
            .collect();
        runs.concat()
    }

    /// The streamline a ray picks, as [`crate::roi::pick_streamline`] picks it (of those `shown`, the one
    /// with a step within the cone of half-angle `atan(tolerance)` around the ray from `o` along the unit `d`,
    /// nearest along the ray; ties to the lower index), with its distance along the ray; testing only the
    /// streamlines near the ray, front to back. The ray is cut into pieces of one cell's length; each piece's
    /// box, widened by the cone's radius at its far end, gathers the streamlines of the cells it meets (a
    /// step's point nearest the ray lies in its bounding box, which its cells cover), which are tested whole;
    /// once the nearest hit lies within the pieces gathered, no untested streamline can come nearer.
    pub fn pick<'a>(
        &self,
        streamline: impl Fn(usize) -> &'a [Vec3] + Sync,
        shown: impl Fn(usize) -> bool + Sync,
        o: Vec3,
        d: Vec3,
        tolerance: f32,
    ) -> Option<(usize, f32)> {
        let (lo, hi) = self.extent?;
        let ray = Ray::new(o, d, tolerance);
        // No hit lies farther along the ray than the farthest corner of the points' bounds, nor where the
        // ray is farther from those bounds than the cone's radius there.
        let far = (lo - o).abs().max((hi - o).abs()).length();
        let slack = |t: f32| tolerance.abs() * t + 1e-3 + 1e-5 * t.abs();
        let grow = Vec3::splat(slack(far));
        let (a, b) = slab_span(o, d, lo - grow, hi + grow);
        let (start, end) = (a.max(0.0), b.min(far));
        if start.partial_cmp(&end).is_none_or(|o| o.is_gt()) {
            return None;
        }
        let step = self.cells.cell();
        let mut seen = vec![0u64; self.n.div_ceil(64)];
        let mut best: Option<(usize, f32)> = None;
        let mut t0 = start;
        while t0 <= end {
            // (A step lost to rounding far from the origin ends the walk at once.)
            let t1 = if t0 + step > t0 { (t0 + step).min(end) } else { end };
            let (p0, p1) = (o + d * t0, o + d * t1);
            let r = Vec3::splat(slack(t1));
            let piece = RoiShape::Box { min: (p0.min(p1) - r).to_array(), max: (p0.max(p1) + r).to_array() };
            let mut fresh = Vec::new();
            for c in self.cells.meeting(&piece).flatten() {
                for &entry in &self.ids[self.starts[c] as usize..self.starts[c + 1] as usize] {
                    let s = id_of(entry, self.n < MASKED_BELOW);
                    let (w, bit) = (s as usize / 64, 1u64 << (s % 64));
                    if seen[w] & bit == 0 {
                        seen[w] |= bit;
                        fresh.push(s);
                    }
                }
            }
            let nearer = |a: &(usize, f32), b: &(usize, f32)| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0));
            let nearest = fresh
                .par_iter()
                .filter(|&&s| shown(s as usize))
                .filter_map(|&s| ray.hit(streamline(s as usize)).map(|t| (s as usize, t)))
                .min_by(nearer);
            best = best.into_iter().chain(nearest).min_by(nearer);
            if best.is_some_and(|(_, t)| t <= t1) || t1 >= end {
                break;
            }
            t0 = t1;
        }
        best
    }

    /// Which of the indexed streamlines the ROIs select, as [`crate::roi::select`] decides (every include
    /// met, no exclude met; with no include, every streamline not excluded), testing only candidates' points.
    pub fn select<'a>(&self, streamline: impl Fn(usize) -> &'a [Vec3] + Sync, rois: &[Roi]) -> Vec<bool> {
        self.select_with(&streamline, rois, None).flags(0..self.n)
    }

    /// [`StreamlineCells::select`] for a drag: the same selection, but each streamline tested for an ROI
    /// leaves in `drag` a witness (one of its points: inside the ROI, the one that stays inside longest as the
    /// drag goes on; else for a sphere, the one it comes over first), how far outside it was, and how far from
    /// the sphere swept on along the drag (8 steps like its last, at most its radius); the next call decides
    /// without reading the streamline where it can: it meets the ROI while its witness is inside; it does not
    /// while its distance exceeds how far the ROI moved since (for spheres and boxes: the signed distance to a
    /// convex region moves by at most the regions' Hausdorff distance), or its distance from the swept sphere
    /// how far the sphere is from it. A sphere also leaves the streamline's span along the drag's path (the
    /// circle through its last three centres, a line when they are in line), where the sphere grown by
    /// a tenth of the step holds one of its points (outside it, the streamline is out), and its cover, where the
    /// sphere shrunk so holds one (inside it, in); both valid while the centre keeps within that tenth of the
    /// path, within three radii of where they were measured. On the generated 1M-streamline brain,
    /// 40 steps of 1 mm of a 10 mm sphere read 5.4k of its 50k candidates a step along a line (the first step
    /// reads all 51k, the others 4.2k), 5.9k, 5.6k and 5.6k along arcs of 20, 40 and 100 mm radius (7.8k, 7.1k and
    /// 6.8k with spans along a line aimed at the arc's chord, 9.4k, 8.5k and 7.7k along the last step's line).
    /// Keep one `drag` per set of ROIs: a change in their number, modes or kinds starts it afresh.
    pub fn select_dragging<'a>(
        &self,
        streamline: impl Fn(usize) -> &'a [Vec3] + Sync,
        rois: &[Roi],
        drag: &mut DragMargins,
    ) -> Vec<bool> {
        self.select_kept_dragging(streamline, rois, drag).flags(0..self.n)
    }

    /// [`StreamlineCells::select_dragging`] as the ids it names ([`Kept`]): no flag per streamline is made
    /// (at 10M streamlines, 10 MB of fresh pages a step; a 10 mm sphere's ids take 1.3 MB).
    pub fn select_kept_dragging<'a>(
        &self,
        streamline: impl Fn(usize) -> &'a [Vec3] + Sync,
        rois: &[Roi],
        drag: &mut DragMargins,
    ) -> Kept {
        drag.fit(self.n, rois);
        self.select_with(&streamline, rois, Some(drag))
    }

    fn select_with<'a>(
        &self,
        streamline: &(impl Fn(usize) -> &'a [Vec3] + Sync),
        rois: &[Roi],
        mut drag: Option<&mut DragMargins>,
    ) -> Kept {
        let mut meets = |k: usize, ids: &[u32]| -> Vec<u32> {
            let shape = &rois[k].shape;
            match drag.as_deref_mut().and_then(|d| d.slots.get_mut(k)) {
                Some(slot) => slot.meets(shape, ids, streamline),
                None => meets_exactly(shape, ids, streamline),
            }
        };
        let includes: Vec<usize> = (0..rois.len()).filter(|&k| rois[k].mode == RoiMode::Include).collect();
        // Without an include every streamline is kept but those an exclude meets: the selection names those.
        let mut kept = match includes.split_first() {
            None => Kept { ids: Vec::new(), complement: true },
            Some((&first, rest)) => {
                let mut ids = meets(first, &self.candidates(&rois[first].shape));
                for &k in rest {
                    ids = meets(k, &ids);
                }
                Kept { ids, complement: false }
            }
        };
        for k in (0..rois.len()).filter(|&k| rois[k].mode == RoiMode::Exclude) {
            let candidates = self.candidates(&rois[k].shape);
            // The candidates still kept, tested; those it meets are left out.
            let still = sorted_filter(&candidates, &kept.ids, !kept.complement);
            let out = meets(k, &still);
            kept.ids = if kept.complement { merged(&kept.ids, &out) } else { sorted_filter(&kept.ids, &out, false) };
        }
        kept
    }
}

/// A selection of streamlines `0..n` named by ids (ascending, each once): the streamlines kept, or with
/// `complement`, those left out. What [`StreamlineCells::select_kept_dragging`] returns: a whole brain's 10 mm
/// sphere keeps about 3 % of 10M streamlines, 1.3 MB of ids where a flag per streamline takes 10 MB.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Kept {
    /// The ids named, ascending, each once.
    pub ids: Vec<u32>,
    /// Whether `ids` are the streamlines left out (default false: those kept).
    pub complement: bool,
}

impl Kept {
    /// The selection `flags` keeps (`flags[s]`: whether streamline `s` is), naming whichever side is smaller.
    pub fn of_flags(flags: &[bool]) -> Self {
        let kept = count_set(flags);
        let complement = kept > flags.len() / 2;
        let ids = (0..flags.len() as u32).filter(|&s| flags[s as usize] != complement).collect();
        Self { ids, complement }
    }

    /// The ids named within `range` (a slice of [`Kept::ids`]).
    pub fn ids_in(&self, range: std::ops::Range<usize>) -> &[u32] {
        let lo = self.ids.partition_point(|&s| (s as usize) < range.start);
        let hi = self.ids.partition_point(|&s| (s as usize) < range.end);
        &self.ids[lo..hi]
    }

    /// How many streamlines of `range` are kept.
    pub fn count_in(&self, range: std::ops::Range<usize>) -> usize {
        let named = self.ids_in(range.clone()).len();
        if self.complement { range.len() - named } else { named }
    }

    /// The flags of the streamlines of `range` (element `i`: whether streamline `range.start + i` is kept).
    pub fn flags(&self, range: std::ops::Range<usize>) -> Vec<bool> {
        let mut flags = vec![self.complement; range.len()];
        for &s in self.ids_in(range.clone()) {
            flags[s as usize - range.start] = !self.complement;
        }
        flags
    }

    /// Whether `flags` are the flags of `range` ([`Kept::flags`]), reading each flag once (no flags made):
    /// as many set as kept, and each id named set (or clear, for a complement).
    pub fn same_flags(&self, range: std::ops::Range<usize>, flags: &[bool]) -> bool {
        flags.len() == range.len()
            && count_set(flags) == self.count_in(range.clone())
            && self.ids_in(range.clone()).iter().all(|&s| flags[s as usize - range.start] != self.complement)
    }
}

/// How many of `flags` are set.
fn count_set(flags: &[bool]) -> usize {
    flags.iter().map(|&f| usize::from(f)).sum()
}

/// The ids of ascending `a` that are in ascending `b` (`shared`), or that are not.
fn sorted_filter(a: &[u32], b: &[u32], shared: bool) -> Vec<u32> {
    let mut j = 0;
    a.iter()
        .copied()
        .filter(|&s| {
            while j < b.len() && b[j] < s {
                j += 1;
            }
            (j < b.len() && b[j] == s) == shared
        })
        .collect()
}

/// What [`StreamlineCells::select_dragging`] remembers between the steps of a drag: per ROI (spheres and
/// boxes; planes are always tested) and per streamline tested, its signed distance to the ROI (the least over
/// its points; negative inside), its distance to the sphere swept on along the drag's last step (8 steps on), a
/// witness point, its span and cover along the drag's path, and which of the ROI's past shapes they were
/// measured against. 32 bytes per streamline and ROI.
#[derive(Default)]
pub struct DragMargins {
    slots: Vec<Slot>,
}

/// One ROI's memory: its shapes so far with what margins were measured against (`epochs[e - 1]` is epoch `e`),
/// and per streamline the margins and the epoch they were measured in (0: never).
struct Slot {
    mode: RoiMode,
    kind: std::mem::Discriminant<RoiShape>,
    epochs: Vec<Epoch>,
    margins: Option<Margins>,
}

/// A shape of a [`Slot`]'s ROI and what its margins were measured against, made once, when the ROI took it.
#[derive(Clone, Copy)]
struct Epoch {
    shape: RoiShape,
    /// The far end of the segment a sphere's centre is swept along: [`SWEEP`] steps like its last one, at most
    /// the radius long; `None` without such a step (the first shape, not a sphere after a sphere, or no move).
    sweep: Option<Vec3>,
    /// The path its spans are measured along: through its centre and the two before ([`Path::through`]); a
    /// path of no direction when it is not a sphere after a sphere.
    path: Path,
}

impl Epoch {
    /// The epoch of `shape` taken after `before` (oldest first).
    fn after(before: &[Epoch], shape: RoiShape) -> Epoch {
        let centre = |s: &RoiShape| match *s {
            RoiShape::Sphere { centre, .. } => Some(Vec3::from(centre)),
            _ => None,
        };
        let mut back = before.iter().rev().map(|e| centre(&e.shape));
        let (b, a) = (back.next().flatten(), back.next().flatten());
        let sweep = match (shape, b) {
            (RoiShape::Sphere { centre, radius }, Some(b)) => {
                let c = Vec3::from(centre);
                let v = c - b;
                let len = (v.length() * SWEEP).min(radius.abs());
                (len > 0.0).then(|| c + v.normalize_or_zero() * len)
            }
            _ => None,
        };
        let path = match centre(&shape) {
            Some(c) => Path::through(a, b, c),
            None => Path::through(None, None, Vec3::ZERO),
        };
        Epoch { shape, sweep, path }
    }
}

/// Per streamline, read together: the margin's bits, its epoch, the witness (its bits), the swept margin's bits,
/// its span and its cover ([`Measured`], [`pack_span`]); an entry is half a cache line.
///
/// Held in anonymous memory mapped zero-filled (an entry of zeros is "never measured") and advised into huge
/// pages: a step reads the entries of half a million candidates scattered over 305 MiB at 10M streamlines, and
/// in 4 KiB pages nearly each of those reads also missed the TLB. Nothing is written at the drag's start (a
/// `Vec` was 305 MiB of zeros written before the first step); a page takes memory when first touched.
struct Margins(memmap2::MmapMut);

impl Margins {
    /// `n` entries of zeros; `None` when the memory cannot be mapped.
    fn zeroed(n: usize) -> Option<Self> {
        let map = memmap2::MmapMut::map_anon((n * std::mem::size_of::<Entry>()).max(1)).ok()?;
        // A hint: a kernel without transparent huge pages refuses it, and the pages come as they would.
        #[cfg(target_os = "linux")]
        let _ = map.advise(memmap2::Advice::HugePage);
        Some(Self(map))
    }

    fn entries(&self) -> &[Entry] {
        // SAFETY: the map is page-aligned (an entry's 32 bytes are), holds the entries it was made for (its length
        // over an entry's size) and lives as long as `self`; its bytes start as zeros and change only through the
        // atomics, for which any bits are valid.
        unsafe {
            std::slice::from_raw_parts(self.0.as_ptr().cast::<Entry>(), self.0.len() / std::mem::size_of::<Entry>())
        }
    }
}

/// One streamline's [`Margins`], aligned so that it never straddles two cache lines.
#[repr(align(32))]
struct Entry([AtomicU32; 8]);

/// Where each value lies in a [`Margins`] entry.
const MARGIN: usize = 0;
const EPOCH: usize = 1;
const WITNESS: usize = 2;
const SWEPT: usize = 5;
const SPAN: usize = 6;
const COVER: usize = 7;

/// How far on a moved sphere is swept when its margins are measured, in steps like its last: a streamline
/// clear of the whole swept sphere (a capsule) stays out while the centre keeps near that segment, so the
/// streamlines beside a drag's path are not read again at every step (only those ahead and behind); the
/// sweep's direction also picks the witnesses and measures the spans ([`measure`]). The sweep is at most the
/// radius long.
const SWEEP: f32 = 8.0;

/// A margin within this of the boundary (mm) is not trusted: the streamline is tested. Far above the f32
/// rounding of distances in a brain (about 1e-5 mm at 100 mm).
const MARGIN_SLACK: f32 = 1e-3;

/// How many shapes a slot remembers before it starts afresh.
const MAX_EPOCHS: usize = 1 << 16;

impl DragMargins {
    /// Bytes held.
    pub fn heap_bytes(&self) -> usize {
        self.slots.iter().filter_map(|s| s.margins.as_ref()).map(|m| std::mem::size_of_val(m.entries())).sum()
    }

    /// One slot per ROI, reset where the ROI's mode or kind differs from the slot's.
    fn fit(&mut self, n: usize, rois: &[Roi]) {
        self.slots.truncate(rois.len());
        for (k, roi) in rois.iter().enumerate() {
            let kind = std::mem::discriminant(&roi.shape);
            let fresh = || Slot {
                mode: roi.mode,
                kind,
                epochs: vec![],
                margins: (!matches!(roi.shape, RoiShape::Plane { .. })).then(|| Margins::zeroed(n)).flatten(),
            };
            match self.slots.get_mut(k) {
                Some(s) if s.mode == roi.mode && s.kind == kind && s.epochs.len() < MAX_EPOCHS => {}
                Some(s) => *s = fresh(),
                None => self.slots.push(fresh()),
            }
        }
    }
}

/// How a shape lies from one of its slot's past shapes, in the terms each kind of margin measured against that
/// shape is compared with ([`Slot::meets`]).
struct Since {
    /// How far any point's signed distance can have moved (mm): [`hausdorff`].
    shift: f32,
    /// How far the shape's sphere lies from the past one swept on (mm: its centre from the swept segment, plus
    /// the change of radius); `shift` when there was no sweep.
    swept: f32,
    /// Where along the past path the centre's foot lies (its place, [`Path`]), when the shape lies within the
    /// past sphere grown ([`grown_and_shrunk`]) and moved there; NaN otherwise. A streamline whose entry lies
    /// beyond it or whose exit lies before it does not meet the shape.
    along: f32,
    /// The same foot, when the shape holds the past sphere shrunk and moved there; NaN
    /// otherwise. A streamline whose cover holds it meets the shape.
    covered: f32,
}

impl Slot {
    /// How `shape` lies from the shape of epoch `e + 1`.
    fn since(&self, e: usize, shape: &RoiShape) -> Since {
        let Epoch { shape: old, sweep, path } = self.epochs[e];
        let shift = hausdorff(&old, shape);
        match (old, *shape, sweep) {
            (RoiShape::Sphere { centre: c0, radius: r0 }, RoiShape::Sphere { centre, radius }, Some(end)) => {
                let (c0, c) = (Vec3::from(c0), Vec3::from(centre));
                let swept = segment_distance(c, c0, end) + (radius - r0).abs();
                // A point within `radius` of `c` is within `radius + off` of `c`'s foot on the path, `t` along
                // it: within the grown sphere there, so `t` lies between the streamline's entry and exit; and a
                // point within the shrunk sphere there is within `radius`.
                // The spans hold only the points within reach of the path's first `WINDOW` radii each way.
                let (t, off) = path.foot((c - c0).as_dvec3());
                let (grown, shrunk) = grown_and_shrunk(r0, c0, end);
                let (r, slack) = (f64::from(radius.abs()), f64::from(MARGIN_SLACK));
                let inside = path.arc(t).abs() <= WINDOW * f64::from(r0.abs());
                let within = inside && r + off <= grown - slack;
                let holds = inside && shrunk + off <= r - slack;
                let t = t as f32;
                let at = |yes: bool| if yes { t } else { f32::NAN };
                Since { shift, swept, along: at(within), covered: at(holds) }
            }
            _ => Since { shift, swept: shift, along: f32::NAN, covered: f32::NAN },
        }
    }

    /// The streamlines of `ids` (ascending) that meet `shape`, deciding from the margins where they are
    /// clear of the boundary and testing the rest (whose margins are then measured against `shape`).
    fn meets<'a>(
        &mut self,
        shape: &RoiShape,
        ids: &[u32],
        streamline: &(impl Fn(usize) -> &'a [Vec3] + Sync),
    ) -> Vec<u32> {
        let Some(mem) = self.margins.as_ref().map(Margins::entries) else {
            return meets_exactly(shape, ids, streamline);
        };
        let since: Vec<Since> = (0..self.epochs.len()).map(|e| self.since(e, shape)).collect();
        let epoch = Epoch::after(&self.epochs, *shape);
        let Epoch { sweep: ahead, path, .. } = epoch;
        self.epochs.push(epoch);
        let now = self.epochs.len() as u32;
        // Decided from the margins where they can be; the rest tested one after another, each streamline's
        // first cache lines asked for two before while this one is tested (in a mapped file, a streamline is
        // a cache and TLB miss away from the one before: that wait, not the arithmetic, was most of a step).
        ids.par_chunks(512)
            .flat_map_iter(|chunk| {
                let mut kept = Vec::new();
                let mut undecided = Vec::new();
                for (i, &s) in chunk.iter().enumerate() {
                    if let Some(&ahead) = chunk.get(i + MARGIN_PREFETCH_AHEAD) {
                        prefetch_entry(&mem[ahead as usize]);
                    }
                    let m = &mem[s as usize].0;
                    let e = m[EPOCH].load(Ordering::Relaxed);
                    if e > 0 {
                        // A streamline meets the ROI while its witness (one of its points) is inside, tested as
                        // any point is; it does not while its margin exceeds the shift since, or its swept
                        // margin the distance from the swept sphere. Then, near the boundary (most candidates
                        // are decided before), it meets it while the drag is within its cover, and does not
                        // while it is outside its span.
                        let w = Vec3::from([0, 1, 2].map(|k| f32::from_bits(m[WITNESS + k].load(Ordering::Relaxed))));
                        if shape.contains(w) {
                            kept.push(s);
                            continue;
                        }
                        let since = &since[e as usize - 1];
                        let [margin, swept] = [MARGIN, SWEPT].map(|k| f32::from_bits(m[k].load(Ordering::Relaxed)));
                        if margin - (since.shift + MARGIN_SLACK) > 0.0 || swept - (since.swept + MARGIN_SLACK) > 0.0 {
                            continue;
                        }
                        if !(since.along.is_nan() && since.covered.is_nan()) {
                            let cover = unpack_span(m[COVER].load(Ordering::Relaxed));
                            if cover.0 <= since.covered && since.covered <= cover.1 {
                                kept.push(s);
                                continue;
                            }
                            let (entry, exit) = unpack_span(m[SPAN].load(Ordering::Relaxed));
                            if entry - MARGIN_SLACK > since.along || exit + MARGIN_SLACK < since.along {
                                continue;
                            }
                        }
                    }
                    undecided.push(s);
                }
                let points: Vec<&[Vec3]> = undecided.iter().map(|&s| streamline(s as usize)).collect();
                let mut tested = Vec::new();
                for (k, &s) in undecided.iter().enumerate() {
                    if let Some(next) = points.get(k + PREFETCH_AHEAD) {
                        prefetch(next);
                    }
                    let measured = measure(shape, ahead, &path, points[k]);
                    let m = &mem[s as usize].0;
                    m[MARGIN].store(measured.margin.to_bits(), Ordering::Relaxed);
                    m[SWEPT].store(measured.swept.to_bits(), Ordering::Relaxed);
                    m[SPAN].store(pack_span(measured.entry, measured.exit, true), Ordering::Relaxed);
                    m[COVER].store(pack_span(measured.cover.0, measured.cover.1, false), Ordering::Relaxed);
                    m[EPOCH].store(now, Ordering::Relaxed);
                    for (k, v) in measured.witness.to_array().into_iter().enumerate() {
                        m[WITNESS + k].store(v.to_bits(), Ordering::Relaxed);
                    }
                    if measured.meets {
                        tested.push(s);
                    }
                }
                merged(&kept, &tested)
            })
            .collect()
    }
}

/// The ids of two ascending lists, in one ascending list (no id is in both).
fn merged(a: &[u32], b: &[u32]) -> Vec<u32> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    let (mut i, mut j) = (0, 0);
    while i < a.len() && j < b.len() {
        if a[i] < b[j] {
            out.push(a[i]);
            i += 1;
        } else {
            out.push(b[j]);
            j += 1;
        }
    }
    out.extend_from_slice(&a[i..]);
    out.extend_from_slice(&b[j..]);
    out
}

/// Asks the CPU for the first cache lines of `pts` (a hint: no effect on other targets, never a fault).
#[inline]
fn prefetch(pts: &[Vec3]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let (p, n) = (pts.as_ptr().cast::<i8>(), std::mem::size_of_val(pts).min(PREFETCH_BYTES));
        for offset in (0..n).step_by(64) {
            // SAFETY: SSE is part of x86_64's baseline; a prefetch reads nothing the program sees and never
            // faults, whatever the address (this one lies within `pts`).
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.wrapping_add(offset)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = pts;
}

/// Asks the CPU for the cache line of a margins entry (a hint, as [`prefetch`]).
#[inline]
fn prefetch_entry(entry: &Entry) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        // SAFETY: as in `prefetch`: a hint that reads nothing the program sees (the entry lies in one line).
        unsafe { _mm_prefetch::<_MM_HINT_T0>((entry as *const Entry).cast::<i8>()) };
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = entry;
}

/// How many candidates ahead of the one decided [`prefetch_entry`] asks for.
const MARGIN_PREFETCH_AHEAD: usize = 16;

/// How much of a streamline [`prefetch`] asks for: the hardware's own prefetcher follows a streamline once its
/// first lines are read.
const PREFETCH_BYTES: usize = 1024;

/// How many streamlines ahead of the one tested [`prefetch`] asks for (on the 10M-streamline brain mapped, a
/// 1 mm drag step: 115 ms without, 95-100 ms at 1 or 2 ahead, no better farther).
const PREFETCH_AHEAD: usize = 2;

/// The streamlines of `ids` that meet `shape`, each tested.
fn meets_exactly<'a>(shape: &RoiShape, ids: &[u32], streamline: &(impl Fn(usize) -> &'a [Vec3] + Sync)) -> Vec<u32> {
    ids.par_iter().copied().filter(|&s| shape.meets_streamline(streamline(s as usize))).collect()
}

/// What a test of one streamline against a sphere or a box leaves in its [`Margins`] entry.
struct Measured {
    /// Whether it meets the shape ([`RoiShape::meets_streamline`]: a point inside, boundary included).
    meets: bool,
    /// The least signed distance of its points to the shape (mm, negative inside; NaN without finite points,
    /// which is never trusted).
    margin: f32,
    /// The least signed distance of its points to the sphere swept from its centre to the sweep's end (mm; the
    /// margin itself without a sweep, and for boxes).
    swept: f32,
    /// Where along the path (a place, [`Path`]; backward negative) the sphere grown ([`grown_and_shrunk`])
    /// first has a point within it: infinite when none ever does (NaN for boxes and without finite points).
    entry: f32,
    /// Where along that path it last has one (negative infinity when none ever does, NaN as above).
    exit: f32,
    /// A span of that path over which the sphere shrunk always holds one of the streamline's points
    /// (mm; the span of successive points whose own spans overlap: the one that holds the centre, or else the
    /// first ahead; empty (NaN) when none).
    cover: (f32, f32),
    /// For a sphere, the point inside that stays inside longest as the sphere goes on along the path, or (not
    /// meeting it) the point it comes over first (NaN without one); for a box, the point of the least signed
    /// distance.
    witness: Vec3,
}

/// Tests a streamline against a sphere or a box (a sphere swept on to `ahead`, when given, its spans measured
/// along `path`) and measures its margins; a plane is tested only.
fn measure(shape: &RoiShape, ahead: Option<Vec3>, path: &Path, pts: &[Vec3]) -> Measured {
    match *shape {
        RoiShape::Sphere { centre, radius } => {
            // The squared distance as `contains` computes it, so that "the least is within the radius" is
            // "a point is inside"; a square root only for the points near the path.
            let c = Vec3::from(centre);
            let end = ahead.unwrap_or(c);
            let d = end - c;
            let (u, len) = (d.normalize_or_zero(), d.length());
            let (r2, r) = (radius * radius, f64::from(radius.abs()));
            let (grown, shrunk) = grown_and_shrunk(radius, c, end);
            let near2 = (grown * grown) as f32 + NEAR_SLACK;
            // Points farther from the centre than this are farther than `grown` from the path's first `WINDOW`
            // radii each way (its points there are within that arc length of the centre): left out of the spans.
            let window2 = ((WINDOW * r + grown).powi(2)) as f32 + NEAR_SLACK;
            let (mut entry, mut exit_grown) = (f32::INFINITY, f32::NEG_INFINITY);
            // Along the path, point `p` is inside the sphere centred `t` along it for `t` in a span
            // ([`Path::span`]): the witness of a streamline that meets the sphere is its point inside that stays
            // inside the longest (the span reaching farthest); of one that does not, its point ahead that comes
            // inside first (the least start ahead). Its entry and exit are where the grown sphere first and last
            // holds a point.
            let (mut exit, mut exiting) = (f32::NEG_INFINITY, usize::MAX);
            let (mut first, mut entering) = (f32::INFINITY, usize::MAX);
            // Spans of successive points over which the shrunk sphere holds one of them: the one growing, and
            // the best so far (holding the centre, the one that holds it longest; else the first ahead).
            let none = (f32::NAN, f32::NAN);
            let (mut run, mut cover) = (none, none);
            // Eight points at a time, each lane with its own least distances (vectorised); the few points near
            // the path in point order after them (a point not held by the shrunk sphere ends a run).
            let (mut least8, mut swept8) = ([f32::INFINITY; LANES], [f32::INFINITY; LANES]);
            let k = path.kappa as f32;
            let kernel = Kernel { c, u, len, tangent: path.u.as_vec3(), out: path.out.as_vec3(), k, near2, window2 };
            let bent = k > 0.0;
            for (at, chunk) in pts.chunks(LANES).enumerate() {
                // A whole chunk as an array (a copy the compiler inlines; `copy_from_slice` of a slice's length
                // was a call to `memmove` for every eight points, a third of a 10M drag step's samples).
                let lanes: [Vec3; LANES] = chunk.try_into().unwrap_or_else(|_| {
                    let mut lanes = [Vec3::NAN; LANES];
                    chunk.iter().enumerate().for_each(|(i, p)| lanes[i] = *p);
                    lanes
                });
                let mut q8 = [0.0f32; LANES];
                // (One loop for each kind of path, each vectorised.)
                let near8 = match bent {
                    true => lanes8::<true>(&lanes, &kernel, &mut least8, &mut swept8, &mut q8),
                    false => lanes8::<false>(&lanes, &kernel, &mut least8, &mut swept8, &mut q8),
                };
                if !near8.contains(&true) {
                    cover = better_cover(cover, run);
                    run = none;
                    continue;
                }
                for (i, p) in chunk.iter().enumerate() {
                    let mut held = false;
                    if near8[i] {
                        // Exactly, in f64 (the f32 distances from the path cancel near its tangents).
                        let w = path.coordinates(p.as_dvec3() - c.as_dvec3());
                        if let Some((lo, hi)) = path.span(grown, w, true) {
                            (entry, exit_grown) = (entry.min(lo as f32), exit_grown.max(hi as f32));
                            if let Some((lo, hi)) = path.span(r, w, true) {
                                let (lo, hi) = (lo as f32, hi as f32);
                                if q8[i] <= r2 {
                                    if hi > exit {
                                        (exit, exiting) = (hi, at * LANES + i);
                                    }
                                } else if lo > 0.0 && lo < first {
                                    (first, entering) = (lo, at * LANES + i);
                                }
                            }
                            if let Some((lo, hi)) = path.span(shrunk, w, false) {
                                let (lo, hi) = (lo as f32, hi as f32);
                                // (No run yet, NaN, overlaps nothing.)
                                if lo <= run.1 && run.0 <= hi {
                                    run = (run.0.min(lo), run.1.max(hi));
                                } else {
                                    cover = better_cover(cover, run);
                                    run = (lo, hi);
                                }
                                held = true;
                            }
                        }
                    }
                    if !held {
                        cover = better_cover(cover, run);
                        run = none;
                    }
                }
            }
            let least = least8.into_iter().fold(f32::INFINITY, f32::min);
            let least_swept = swept8.into_iter().fold(f32::INFINITY, f32::min);
            let cover = better_cover(cover, run);
            let meets = least <= r2;
            let witness = pts.get(if meets { exiting } else { entering }).copied().unwrap_or(Vec3::NAN);
            if least.is_finite() {
                let margin = least.sqrt() - radius;
                let swept = least_swept.max(0.0).sqrt() - radius;
                Measured { meets, margin, swept, entry, exit: exit_grown, cover, witness }
            } else {
                let nan = f32::NAN;
                let (entry, exit, cover) = (nan, nan, (nan, nan));
                Measured { meets: false, margin: nan, swept: nan, entry, exit, cover, witness: Vec3::NAN }
            }
        }
        RoiShape::Box { min, max } => {
            let (lo, hi) = (Vec3::from(min), Vec3::from(max));
            let mut meets = false;
            let (mut least, mut at) = (f32::INFINITY, Vec3::NAN);
            for p in pts {
                meets |= shape.contains(*p);
                let q = (lo - *p).max(*p - hi);
                let sd = q.max(Vec3::ZERO).length() + q.max_element().min(0.0);
                if sd < least {
                    (least, at) = (sd, *p);
                }
            }
            let margin = if at.is_finite() { least } else { f32::NAN };
            let nan = f32::NAN;
            Measured { meets, margin, swept: margin, entry: nan, exit: nan, cover: (nan, nan), witness: at }
        }
        RoiShape::Plane { .. } => Measured {
            meets: shape.meets_streamline(pts),
            margin: f32::NAN,
            swept: f32::NAN,
            entry: f32::NAN,
            exit: f32::NAN,
            cover: (f32::NAN, f32::NAN),
            witness: Vec3::NAN,
        },
    }
}

/// What [`measure`] needs of a sphere and its path for [`lanes8`].
struct Kernel {
    /// The sphere's centre.
    c: Vec3,
    /// The unit direction of its sweep and the sweep's length (mm).
    u: Vec3,
    len: f32,
    /// The path's tangent, the direction out from its circle's centre, its curvature ([`Path`]).
    tangent: Vec3,
    out: Vec3,
    k: f32,
    /// How near the path a point is near it, and the window's reach, squared (mm²).
    near2: f32,
    window2: f32,
}

/// For eight points, the squared distance from the sphere's centre (into `q8`; the least so far in `least8`)
/// and from its sweep (`swept8`), and whether each is near the path (a line, or a circle when `BENT`) within
/// the window: at most its squared distance to the path is within `near2`.
#[inline(always)]
fn lanes8<const BENT: bool>(
    lanes: &[Vec3; LANES],
    kernel: &Kernel,
    least8: &mut [f32; LANES],
    swept8: &mut [f32; LANES],
    q8: &mut [f32; LANES],
) -> [bool; LANES] {
    let Kernel { c, u, len, tangent, out, k, near2, window2 } = *kernel;
    // The lanes' coordinates apart (x, y, z of each), so that the arithmetic below is on whole vectors; the
    // least kept by comparisons, which the compiler makes a vector's minimum (`f32::min` it did not: its NaN
    // rule is not the instruction's). NaN padding compares false and is passed over as `min` would.
    let mut w8 = [[0.0f32; LANES]; 3];
    for (i, p) in lanes.iter().enumerate() {
        let w = *p - c;
        (w8[0][i], w8[1][i], w8[2][i]) = (w.x, w.y, w.z);
    }
    let mut near8 = [false; LANES];
    for i in 0..LANES {
        let (x, y, z) = (w8[0][i], w8[1][i], w8[2][i]);
        // As `contains` and `Vec3::dot` compute them.
        let q = x * x + (y * y + z * z);
        let a = x * u.x + y * u.y + z * u.z;
        // The squared distance to the swept centre's segment, from `q` and `a` (`a` clamped to the segment).
        let along = if a > 0.0 { if a < len { a } else { len } } else { 0.0 };
        let swept = q - along * (2.0 * a - along);
        least8[i] = if q < least8[i] { q } else { least8[i] };
        swept8[i] = if swept < swept8[i] { swept } else { swept8[i] };
        q8[i] = q;
        let near = if BENT {
            // Off the plane `h`, and radially in it: `(rho - R)^2 + h^2 <= near2` for the distance `rho` from
            // the circle's centre, squared twice over (no root) and over `R^2`.
            let ox = x * out.x + y * out.y + z * out.z;
            let ty = x * tangent.x + y * tangent.y + z * tangent.z;
            let g = near2 - (q - ox * ox - ty * ty);
            let m = 2.0 * ox + k * (ox * ox + ty * ty) - k * g;
            (g >= 0.0) & (m * m <= 4.0 * g)
        } else {
            // Off the line (the sweep's, the path's).
            q - a * a <= near2
        };
        near8[i] = (q <= window2) & near;
    }
    near8
}

/// Of the span kept so far and a new one along a drag's path (places; NaN: none), the one a drag along it is held
/// by longest: one that holds the centre (0), the one reaching farther ahead; else the first ahead.
fn better_cover(kept: (f32, f32), new: (f32, f32)) -> (f32, f32) {
    let holds = |s: (f32, f32)| s.0 <= 0.0 && 0.0 <= s.1;
    let better = match (holds(new), holds(kept)) {
        (true, true) => new.1 > kept.1,
        (true, false) => true,
        (false, true) => false,
        (false, false) => new.0 > 0.0 && !(kept.0 > 0.0 && kept.0 <= new.0),
    };
    if better { new } else { kept }
}

/// The path a moved sphere's spans are measured along ([`measure`]) and its later centres placed on
/// ([`Slot::since`]): the circle through its last three centres, or the line of its last step (curvature 0).
/// A place on it is given by `2 tan(kappa t / 2) / kappa` for the arc length `t` from the sphere's centre
/// (forward positive): on a line the length itself, on a circle the same near the centre (mm) and growing
/// without bound half a turn away; in it a sphere's places along the path are a quadratic's roots (no
/// trigonometry), and it orders them as the arc length does.
#[derive(Clone, Copy, Debug)]
struct Path {
    /// Unit tangent at the centre, forward (zero before a first step).
    u: DVec3,
    /// Unit, in the circle's plane, from the circle's centre out through the sphere's (zero for a line).
    out: DVec3,
    /// Curvature (1/mm; 0 for a line).
    kappa: f64,
}

impl Path {
    /// The path of a sphere at `c` whose centre was at `b` the step before and at `a` the one before that:
    /// the circle through the three while both steps go forward (a line when they are in line), else the line
    /// from `b`; none (no direction) without `b`.
    fn through(a: Option<Vec3>, b: Option<Vec3>, c: Vec3) -> Path {
        let c = c.as_dvec3();
        let Some(b) = b.map(Vec3::as_dvec3) else { return Path { u: DVec3::ZERO, out: DVec3::ZERO, kappa: 0.0 } };
        let step = c - b;
        let line = Path { u: step.normalize_or_zero(), out: DVec3::ZERO, kappa: 0.0 };
        let Some(a) = a.map(Vec3::as_dvec3).filter(|a| (b - a).dot(step) > 0.0) else { return line };
        // The circumcentre, from `c`.
        let (p, q) = (a - c, b - c);
        let n = p.cross(q);
        let centre = (q * p.length_squared() - p * q.length_squared()).cross(n) / (2.0 * n.length_squared());
        let radius = centre.length();
        let out = -centre / radius;
        let u = (step - out * step.dot(out)).normalize_or_zero();
        if radius.is_finite() && out.is_finite() && u != DVec3::ZERO {
            Path { u, out, kappa: 1.0 / radius }
        } else {
            line
        }
    }

    /// The place on the path of the foot of the point `w` from the centre (the path's point nearest it), and
    /// how far `w` is from the path there (mm).
    fn foot(&self, w: DVec3) -> (f64, f64) {
        let (x, y, k) = (w.dot(self.out), w.dot(self.u), self.kappa);
        if k > 0.0 {
            // Off the circle radially in its plane (its distance from the circle's centre less the radius,
            // without the cancellation) and off the plane; `2 tan(theta / 2) / kappa` from the foot's angle's
            // sine and cosine.
            let far = ((1.0 + k * x).powi(2) + (k * y).powi(2)).sqrt();
            let radial = (2.0 * x + k * (x * x + y * y)) / (1.0 + far);
            let plane = (w.length_squared() - x * x - y * y).max(0.0);
            (2.0 * y / (1.0 + k * x + far), (radial * radial + plane).sqrt())
        } else {
            (y, (w - self.u * y).length())
        }
    }

    /// The arc length (mm) to a place on the path.
    fn arc(&self, place: f64) -> f64 {
        let k = self.kappa;
        if k > 0.0 { 2.0 * (k * place / 2.0).atan() / k } else { place }
    }

    /// A point `w` from the centre as [`Path::span`] takes it: its squared distance from the centre, its
    /// distance out from the circle's centre (0 for a line) and along the tangent (mm).
    fn coordinates(&self, w: DVec3) -> [f64; 3] {
        [w.length_squared(), w.dot(self.out), w.dot(self.u)]
    }

    /// The places on the path where a sphere of radius `rho` centred there holds the point of `coordinates`
    /// ([`Path::coordinates`]): a span, or none. Where the path curls round the point so that the places are
    /// not one span of it, the whole path when `outward` (a span that must hold the true places), none otherwise.
    fn span(&self, rho: f64, [q, x, y]: [f64; 3], outward: bool) -> Option<(f64, f64)> {
        let k = self.kappa;
        let d = rho * rho - q;
        if k == 0.0 {
            let disc = y * y + d;
            return (disc >= 0.0).then(|| (y - disc.sqrt(), y + disc.sqrt()));
        }
        // The sphere at place `tau` holds `w` where `a tau^2 - 2 y tau - d <= 0` (on a line:
        // `|w - tau u|^2 <= rho^2`).
        let a = 1.0 + k * x - k * k * d / 4.0;
        if a.is_nan() || a <= 0.0 {
            return outward.then_some((f64::NEG_INFINITY, f64::INFINITY));
        }
        let disc = y * y + a * d;
        if disc.is_nan() || disc < 0.0 {
            return None;
        }
        // The roots without cancellation: the larger in size from `y` and the root, the other from their product.
        let big = y + disc.sqrt().copysign(y);
        let (r0, r1) = if big == 0.0 { (0.0, 0.0) } else { (big / a, -d / big) };
        Some((r0.min(r1), r0.max(r1)))
    }
}

/// The radii a sphere of `radius` at `centre`, swept on to `end`, is measured with: grown (a streamline is out
/// while the drag keeps within it, away from its span) and shrunk (one it holds is in while the drag keeps
/// within that), by [`REACH`] of the drag's step, so that a drag a little off its path still finds them
/// decided. Without a sweep, both are the radius itself.
fn grown_and_shrunk(radius: f32, centre: Vec3, end: Vec3) -> (f64, f64) {
    let (r, reach) = (f64::from(radius.abs()), f64::from(centre.distance(end) / SWEEP * REACH));
    (r + reach, (r - reach).max(0.0))
}

/// How far a sphere is grown or shrunk for its streamlines' spans, as a part of the drag's step: the drag's
/// centre may stray that far off its path ([`Path`]) and still find them valid. On the generated 1M
/// brain (before the cells' eighths), a straight 1 mm drag read 6.4k streamlines a step at 0.1, 7.5k at 0.3,
/// 9.4k at 1.
const REACH: f32 = 0.1;

/// How far along a path its spans reach, in radii of the sphere each way: a drag that goes on farther reads
/// the streamlines near the sphere again. On a circle wider than the sphere (radius above 3/π of the sphere's),
/// 3 radii of arc stay short of a half turn, where a place grows without bound. On
/// the 1M brain's arcs of 20 to 100 mm, 2 radii read 8 % more a step, 5 radii 1 % less.
const WINDOW: f64 = 3.0;

/// How many points [`measure`] takes at a time.
const LANES: usize = 8;

/// Added to a squared distance from the line before a point is passed over as far from it (mm²): f32's
/// cancellation in `q - a²` at a brain's distances is far below it.
const NEAR_SLACK: f32 = 1.0;

/// A span along a drag's path (places, [`Path`]: mm near the centre) in 32 bits: each end in 1/32 mm as an
/// `i16`, rounded `outward` (a span that must hold the true one: where a streamline may meet a sphere) or inward
/// (one the true one must hold: where it surely does); past about ±1 m an end is infinite or the last finite
/// value, whichever lies that way. A span with a NaN end is everything outward and nothing inward.
fn pack_span(lo: f32, hi: f32, outward: bool) -> u32 {
    let (lo, hi) = match (lo.is_nan() || hi.is_nan(), outward) {
        (true, true) => (f32::NEG_INFINITY, f32::INFINITY),
        (true, false) => (f32::INFINITY, f32::NEG_INFINITY),
        (false, _) => (lo, hi),
    };
    let fixed = |v: f32, up: bool| {
        let x = if up { (v * SPAN_UNITS).ceil() } else { (v * SPAN_UNITS).floor() };
        // Past the range, an end rounded up is infinite or the least finite one, rounded down the greatest
        // finite one or infinite.
        if x >= i16::MAX as f32 {
            if up { i16::MAX } else { i16::MAX - 1 }
        } else if x <= i16::MIN as f32 {
            if up { i16::MIN + 1 } else { i16::MIN }
        } else {
            x as i16
        }
    };
    let (a, b) = (fixed(lo, !outward), fixed(hi, outward));
    (a as u16 as u32) | ((b as u16 as u32) << 16)
}

/// The span [`pack_span`] packed (`i16::MIN` and `i16::MAX` are the infinities).
fn unpack_span(bits: u32) -> (f32, f32) {
    let end = |v: i16| match v {
        i16::MIN => f32::NEG_INFINITY,
        i16::MAX => f32::INFINITY,
        v => v as f32 / SPAN_UNITS,
    };
    (end(bits as u16 as i16), end((bits >> 16) as u16 as i16))
}

/// Steps of a packed span per mm.
const SPAN_UNITS: f32 = 32.0;

/// The distance from `p` to the segment `a`-`b` (mm).
fn segment_distance(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let d = b - a;
    let t = if d.length_squared() > 0.0 { ((p - a).dot(d) / d.length_squared()).clamp(0.0, 1.0) } else { 0.0 };
    (a + d * t).distance(p)
}

/// An upper bound on the Hausdorff distance between two spheres or two boxes (mm; infinite otherwise): for
/// convex regions, how far any point's signed distance can move from one to the other.
fn hausdorff(a: &RoiShape, b: &RoiShape) -> f32 {
    match (*a, *b) {
        (RoiShape::Sphere { centre: c0, radius: r0 }, RoiShape::Sphere { centre: c1, radius: r1 }) => {
            Vec3::from(c0).distance(Vec3::from(c1)) + (r0 - r1).abs()
        }
        (RoiShape::Box { min: l0, max: h0 }, RoiShape::Box { min: l1, max: h1 }) => {
            let dl = (Vec3::from(l0) - Vec3::from(l1)).abs();
            let dh = (Vec3::from(h0) - Vec3::from(h1)).abs();
            dl.max(dh).length()
        }
        _ => f32::INFINITY,
    }
}

/// The streamlines `0..n` in blocks of [`BLOCK`], in order.
fn blocks(n: usize) -> impl Iterator<Item = std::ops::Range<usize>> {
    (0..n.div_ceil(BLOCK)).map(move |b| b * BLOCK..((b + 1) * BLOCK).min(n))
}

/// `items` cut into at most `k` consecutive shares of about equal `weight` (each but the last closed once it
/// holds a `k`th of the whole).
fn shares<T>(items: &[T], weight: impl Fn(&T) -> u64, k: usize) -> Vec<&[T]> {
    let each = items.iter().map(&weight).sum::<u64>().div_ceil(k.max(1) as u64).max(1);
    let mut starts = vec![0];
    let mut sum = 0;
    for (i, item) in items.iter().enumerate() {
        sum += weight(item);
        if sum >= each && starts.len() < k {
            starts.push(i + 1);
            sum = 0;
        }
    }
    starts.push(items.len());
    starts.windows(2).map(|w| &items[w[0]..w[1]]).filter(|share| !share.is_empty()).collect()
}

/// Streamlines a block of an index build's pass holds (about 80 MB of a whole-brain `.tck`).
const BLOCK: usize = 1 << 16;

/// `(lo, hi)` grown to the finite points of `pts`.
fn finite_bounds(pts: &[Vec3], (lo, hi): (Vec3, Vec3)) -> (Vec3, Vec3) {
    pts.iter().filter(|p| p.is_finite()).fold((lo, hi), |(lo, hi), p| (lo.min(*p), hi.max(*p)))
}

/// The span of the ray from `o` along `d` inside the box `lo`..`hi` (the slab method; empty when the first
/// exceeds the second).
fn slab_span(o: Vec3, d: Vec3, lo: Vec3, hi: Vec3) -> (f32, f32) {
    let (mut a, mut b) = (f32::NEG_INFINITY, f32::INFINITY);
    for k in 0..3 {
        if d[k] == 0.0 {
            if o[k] < lo[k] || o[k] > hi[k] {
                return (1.0, 0.0);
            }
        } else {
            let (u, v) = ((lo[k] - o[k]) / d[k], (hi[k] - o[k]) / d[k]);
            a = a.max(u.min(v));
            b = b.min(u.max(v));
        }
    }
    (a, b)
}

/// The distinct cells of a streamline's points and of its segments' bounding boxes, each with the mask of its
/// eighths they meet ([`Cells::spanned_eighths`]), into `out` (by cell).
fn cells_of(cells: &Cells, pts: &[Vec3], out: &mut Vec<(u32, u8)>) {
    out.clear();
    for (k, p) in pts.iter().enumerate().filter(|(_, p)| p.is_finite()) {
        let q = pts.get(k + 1).filter(|q| q.is_finite()).unwrap_or(p);
        cells.spanned_eighths(*p, *q, |c, eighths| out.push((c as u32, eighths)));
    }
    out.sort_unstable_by_key(|&(c, _)| c);
    out.dedup_by(|later, kept| {
        let same = later.0 == kept.0;
        if same {
            kept.1 |= later.1;
        }
        same
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::roi::{SegmentGrid, select};

    /// The index keeps what the segment grid keeps, for spheres, boxes and planes, includes and excludes,
    /// on a generated whole brain with streamlines leaving the grid's bounds.
    #[test]
    fn the_index_selects_as_the_segment_grid() {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-roi-index-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        let path = dir.join("brain.tck");
        crate::phantom::write_whole_brain(&path, 3000, 7).unwrap();
        let t = crate::io::Tractogram::read(&path).unwrap();
        let grid = SegmentGrid::new(&t.points, &t.offsets, 4.0);
        // Bounds tighter than the points: border cells hold the rest.
        let (lo, hi) = (Vec3::splat(-40.0), Vec3::splat(40.0));
        let index = StreamlineCells::build(t.n_streamlines(), |s| t.streamline(s), (lo, hi), 4.0);
        let sphere = |c: [f32; 3], r: f32| RoiShape::Sphere { centre: c, radius: r };
        let include = |shape| Roi { shape, mode: RoiMode::Include };
        let exclude = |shape| Roi { shape, mode: RoiMode::Exclude };
        let cases: Vec<Vec<Roi>> = vec![
            vec![include(sphere([0.0, 0.0, 0.0], 10.0))],
            vec![include(sphere([30.0, -50.0, 10.0], 6.0))],
            vec![include(sphere([-60.0, 0.0, 0.0], 8.0))],
            vec![include(RoiShape::Box { min: [-5.0, -20.0, -5.0], max: [5.0, 20.0, 5.0] })],
            vec![include(RoiShape::Plane { point: [0.0, 0.0, 0.0], normal: [1.0, 0.0, 0.0] })],
            vec![include(sphere([0.0, 0.0, 0.0], 15.0)), exclude(sphere([0.0, 10.0, 0.0], 5.0))],
            vec![exclude(sphere([10.0, 0.0, -10.0], 12.0))],
            vec![include(sphere([-20.0, 0.0, 0.0], 12.0)), include(sphere([20.0, 0.0, 0.0], 12.0))],
            vec![],
        ];
        for rois in &cases {
            let want = select(&t.points, &t.offsets, &grid, rois);
            let got = index.select(|s| t.streamline(s), rois);
            let kept = want.iter().filter(|k| **k).count();
            assert_eq!(got, want, "{rois:?}: {kept} kept by the segment grid");
        }
        // The cases select something and not everything, or the test shows little.
        let kept = |rois: &[Roi]| select(&t.points, &t.offsets, &grid, rois).iter().filter(|k| **k).count();
        assert!((1..t.n_streamlines()).contains(&kept(&cases[0])), "{}", kept(&cases[0]));
        assert!((1..t.n_streamlines()).contains(&kept(&cases[5])), "{}", kept(&cases[5]));
    }

    /// A query takes only the streamlines in the eighths of its cells that meet it: every streamline that meets
    /// a sphere or a box is a candidate, and the candidates are fewer than the cells alone give (about three
    /// quarters for a 10 mm sphere in 4 mm cells).
    #[test]
    fn the_eighths_of_a_cell_narrow_the_candidates() {
        let (t, index) = indexed_brain(3000, 9);
        let grid = SegmentGrid::new(&t.points, &t.offsets, 4.0);
        let (mut narrowed, mut whole) = (0, 0);
        for shape in [
            RoiShape::Sphere { centre: [0.0, 0.0, 0.0], radius: 10.0 },
            RoiShape::Sphere { centre: [13.0, -21.0, 5.5], radius: 7.0 },
            RoiShape::Box { min: [-9.0, -3.0, -9.0], max: [9.5, 3.0, 9.5] },
        ] {
            let candidates = index.candidates(&shape);
            let rois = [Roi { shape, mode: RoiMode::Include }];
            for (s, kept) in select(&t.points, &t.offsets, &grid, &rois).into_iter().enumerate() {
                assert!(!kept || candidates.binary_search(&(s as u32)).is_ok(), "{shape:?}: streamline {s} missed");
            }
            let mut cells: Vec<u32> = index
                .cells
                .meeting(&shape)
                .flatten()
                .flat_map(|c| &index.ids[index.starts[c] as usize..index.starts[c + 1] as usize])
                .map(|&entry| id_of(entry, true))
                .collect();
            cells.sort_unstable();
            cells.dedup();
            (narrowed, whole) = (narrowed + candidates.len(), whole + cells.len());
        }
        assert!(narrowed * 10 < whole * 9, "{narrowed} candidates against {whole} in the cells");
    }

    /// A pick through the index picks what the brute-force pick picks, streamline and distance, for rays from
    /// every side through the brain (aimed at points of its streamlines, and at random), from inside it and
    /// from far away, with hidden streamlines, on an index whose bounds are tighter than the points; and it
    /// tests few streamlines when the nearest hit is near the ray's start.
    #[test]
    fn a_pick_through_the_index_picks_as_brute_force() {
        let (t, _) = indexed_brain(3000, 3);
        let tight = StreamlineCells::build(
            t.n_streamlines(),
            |s| t.streamline(s),
            (Vec3::splat(-30.0), Vec3::splat(30.0)),
            4.0,
        );
        let mut rng = 99u64;
        let mut next = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (rng >> 33) as f32 / (1u64 << 31) as f32
        };
        let (mut hits, mut tested_all) = (0, 0usize);
        for k in 0..200 {
            let s = (next() * t.n_streamlines() as f32) as usize % t.n_streamlines();
            let pts = t.streamline(s);
            let target = if k % 4 == 3 {
                Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 160.0
            } else {
                pts[(next() * pts.len() as f32) as usize % pts.len()]
            };
            let dir = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5).normalize();
            let dist = [5.0, 80.0, 400.0][k % 3];
            let o = target - dir * dist;
            let tol = [0.002, 0.01, 0.05][k % 3];
            let shown = |s: usize| !k.is_multiple_of(5) || !s.is_multiple_of(3);
            let want = crate::roi::pick_streamline(&t, shown, o, dir, tol);
            let tested = AtomicU64::new(0);
            let counted = |s: usize| {
                tested.fetch_add(1, Ordering::Relaxed);
                t.streamline(s)
            };
            let got = tight.pick(counted, shown, o, dir, tol);
            assert_eq!(got, want, "ray {k} from {o} along {dir}, tolerance {tol}");
            hits += usize::from(want.is_some());
            tested_all += tested.load(Ordering::Relaxed) as usize;
        }
        assert!(hits > 150, "{hits} of 200 rays hit");
        // Far fewer streamlines tested than the brute force's 200 x 3000.
        assert!(tested_all * 5 < 200 * t.n_streamlines(), "{tested_all} streamlines tested");
        // Nothing indexed, or a ray that misses the points' bounds: nothing picked.
        let empty = StreamlineCells::build(0, |_| &[][..], (Vec3::ZERO, Vec3::ONE), 4.0);
        assert_eq!(empty.pick(|s| t.streamline(s), |_| true, Vec3::ZERO, Vec3::X, 0.01), None);
        let away = Vec3::new(0.0, 500.0, 0.0);
        assert_eq!(tight.pick(|s| t.streamline(s), |_| true, away, Vec3::Y, 0.01), None);
    }

    /// A generated whole brain of `n` streamlines (read back from the .tck written) and its index.
    fn indexed_brain(n: usize, seed: u64) -> (crate::io::Tractogram, StreamlineCells) {
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-roi-drag-").tempdir().unwrap();
        let path = tmp_dir.path().join("brain.tck");
        crate::phantom::write_whole_brain(&path, n, seed).unwrap();
        let t = crate::io::Tractogram::read(&path).unwrap();
        let bounds = (Vec3::splat(-70.0), Vec3::splat(70.0));
        let index = StreamlineCells::build(t.n_streamlines(), |s| t.streamline(s), bounds, 4.0);
        (t, index)
    }

    /// A drag keeps at every step what a fresh selection keeps: spheres and boxes moved and resized along a
    /// walk (steps of 0 to 3 mm, through the brain and out of it), with a second include, an exclude and a
    /// plane beside them, and a change of kind or mode that starts the slot afresh.
    #[test]
    fn a_drag_keeps_what_a_fresh_selection_keeps() {
        let (t, index) = indexed_brain(3000, 11);
        let mut drag = DragMargins::default();
        let mut rng = 12345u64;
        let mut next = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (rng >> 33) as f32 / (1u64 << 31) as f32
        };
        let (mut c, mut r) = (Vec3::new(-40.0, 0.0, 0.0), 10.0f32);
        let (mut lo, mut hi) = (Vec3::new(-5.0, -20.0, -5.0), Vec3::new(5.0, 20.0, 5.0));
        let (mut decided, mut steps) = (0usize, 0usize);
        for step in 0..150 {
            c += Vec3::new(next() * 3.0 - 0.5, next() * 2.0 - 1.0, next() * 2.0 - 1.0);
            r = (r + next() - 0.5).clamp(2.0, 20.0);
            let shift = Vec3::new(next() - 0.5, next() - 0.5, next() - 0.5) * 4.0;
            (lo, hi) = (lo + shift, hi + shift + Vec3::splat(next() - 0.5));
            let sphere = RoiShape::Sphere { centre: c.to_array(), radius: r };
            let boxed = RoiShape::Box { min: lo.to_array(), max: hi.to_array() };
            let plane = RoiShape::Plane { point: [c.x, 0.0, 0.0], normal: [1.0, 0.2, 0.0] };
            let roi = |shape, mode| Roi { shape, mode };
            let rois: Vec<Roi> = match step / 30 {
                0 => vec![roi(sphere, RoiMode::Include)],
                1 => vec![roi(sphere, RoiMode::Include), roi(boxed, RoiMode::Exclude)],
                2 => vec![roi(boxed, RoiMode::Include), roi(sphere, RoiMode::Include), roi(plane, RoiMode::Exclude)],
                3 => vec![roi(sphere, RoiMode::Exclude), roi(boxed, RoiMode::Include)],
                // Without an include: the selection names the streamlines left out.
                _ => vec![roi(sphere, RoiMode::Exclude)],
            };
            let want = index.select(|s| t.streamline(s), &rois);
            let got = index.select_dragging(|s| t.streamline(s), &rois, &mut drag);
            let kept = want.iter().filter(|k| **k).count();
            assert_eq!(got, want, "step {step}: {rois:?}, {kept} kept");
            decided += usize::from(kept > 0 && kept < t.n_streamlines());
            steps += 1;
        }
        // Most steps select something and not everything, or the test shows little.
        assert!(decided * 2 > steps, "{decided} of {steps} steps select a part");
        assert!(drag.heap_bytes() >= 8 * t.n_streamlines());
    }

    /// A selection named by ids gives the flags it was made from, on any range, whichever side it names; and
    /// flags that differ in one place, or in none but their count, are told apart from its own.
    #[test]
    fn kept_ids_name_the_flags() {
        let mut rng = 99u64;
        let mut next = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (rng >> 33) as u32
        };
        for share in [0u32, 3, 50, 97, 100] {
            let flags: Vec<bool> = (0..1001).map(|_| next() % 100 < share).collect();
            let kept = Kept::of_flags(&flags);
            assert_eq!(kept.complement, share > 50, "the smaller side is named ({share} %)");
            assert!(kept.ids.len() <= flags.len() / 2 + 1 && kept.ids.windows(2).all(|w| w[0] < w[1]));
            for range in [0..1001, 0..0, 17..18, 100..613, 999..1001] {
                let part = &flags[range.clone()];
                assert_eq!(kept.flags(range.clone()), part, "{range:?} at {share} %");
                assert_eq!(kept.count_in(range.clone()), part.iter().filter(|f| **f).count());
                assert!(kept.same_flags(range.clone(), part));
                if let Some(first) = part.first() {
                    let mut flipped = part.to_vec();
                    flipped[part.len() / 2] = !flipped[part.len() / 2];
                    assert!(!kept.same_flags(range.clone(), &flipped), "one flag flipped in {range:?}");
                    assert!(!kept.same_flags(range.clone(), &[*first]) || part.len() == 1, "another length");
                }
            }
        }
    }

    /// Streamlines clear of the moved sphere's boundary are decided without a test: after the first step the
    /// margins answer for more than two thirds of the candidates.
    #[test]
    fn a_small_step_tests_few_streamlines() {
        let (t, index) = indexed_brain(20000, 5);
        let tested = std::sync::atomic::AtomicUsize::new(0);
        let counted = |s: usize| {
            tested.fetch_add(1, Ordering::Relaxed);
            t.streamline(s)
        };
        let mut drag = DragMargins::default();
        let sphere =
            |x: f32| [Roi { shape: RoiShape::Sphere { centre: [x, 0.0, 0.0], radius: 10.0 }, mode: RoiMode::Include }];
        index.select_dragging(counted, &sphere(0.0), &mut drag);
        let first = tested.swap(0, Ordering::Relaxed);
        index.select_dragging(counted, &sphere(1.0), &mut drag);
        let second = tested.load(Ordering::Relaxed);
        assert!(first > 1000, "{first} candidates");
        assert!(second * 3 < first, "a 1 mm step tested {second} of {first}");
    }

    /// A drag along a straight line reads little beyond the streamlines it must: the sphere swept on along the
    /// drag decides the streamlines beside its path, and a streamline's span and cover along the drag's line
    /// decide it until the sphere reaches it and while the sphere holds it. From the fifth step of 1 mm steps,
    /// under a tenth of the candidates are read (8.7 %). Then it turns back, and bends along an arc: every step
    /// keeps what a fresh selection keeps. Along an arc of 40 mm radius, under a tenth are read too (the spans
    /// along the circle the drag follows). Each streamline read is counted once a step (a prefetch asks for it
    /// too).
    #[test]
    fn a_straight_drag_reads_few_streamlines() {
        use std::sync::atomic::AtomicBool;
        let (t, index) = indexed_brain(20000, 5);
        let read: Vec<AtomicBool> = (0..t.n_streamlines()).map(|_| AtomicBool::new(false)).collect();
        let counted = |s: usize| {
            read[s].store(true, Ordering::Relaxed);
            t.streamline(s)
        };
        let mut drag = DragMargins::default();
        let (mut tested, mut candidates) = (0, 0);
        // Forward 20 steps, back 8 (what the sweep remembers must not decide wrongly when the drag turns), then
        // along an arc of radius 12 mm (each step off the line of the one before).
        let path = (0..20)
            .map(|k| Vec3::new(k as f32 - 10.0, 0.0, 0.0))
            .chain((0..8).map(|k| Vec3::new(8.0 - k as f32, 0.0, 0.0)))
            .chain((0..16).map(|k| {
                let angle = k as f32 / 12.0;
                Vec3::new(1.0 + 12.0 * angle.sin(), 12.0 * (1.0 - angle.cos()), 0.0)
            }));
        for (step, centre) in path.enumerate() {
            let shape = RoiShape::Sphere { centre: centre.to_array(), radius: 10.0 };
            let rois = [Roi { shape, mode: RoiMode::Include }];
            let got = index.select_dragging(counted, &rois, &mut drag);
            assert_eq!(got, index.select(|s| t.streamline(s), &rois), "step {step} at {centre}");
            let this_step = read.iter().filter(|r| r.swap(false, Ordering::Relaxed)).count();
            if (4..20).contains(&step) {
                tested += this_step;
                candidates += index.candidates(&shape).len();
            }
        }
        assert!(candidates > 10_000, "{candidates} candidates");
        assert!(tested * 10 < candidates, "a straight drag read {tested} of {candidates} candidates");

        // Along an arc of 40 mm radius (a hand's drag bends), from its fifth step.
        let (mut drag, mut tested, mut candidates) = (DragMargins::default(), 0, 0);
        for step in 0..24 {
            let angle = step as f32 / 40.0;
            let centre = Vec3::new(-10.0 + 40.0 * angle.sin(), 40.0 * (1.0 - angle.cos()), 0.0);
            let shape = RoiShape::Sphere { centre: centre.to_array(), radius: 10.0 };
            let rois = [Roi { shape, mode: RoiMode::Include }];
            let got = index.select_dragging(counted, &rois, &mut drag);
            assert_eq!(got, index.select(|s| t.streamline(s), &rois), "arc step {step} at {centre}");
            let this_step = read.iter().filter(|r| r.swap(false, Ordering::Relaxed)).count();
            if step >= 4 {
                tested += this_step;
                candidates += index.candidates(&shape).len();
            }
        }
        // 9.0 %; 10.9 % with spans along a line aimed at the arc's chord, 13.9 % along the last step's line.
        assert!(tested * 10 < candidates, "a drag along an arc read {tested} of {candidates} candidates");
    }

    /// A packed span holds the true one when rounded outward and lies within it (or is empty) when rounded
    /// inward, at a brain's distances and beyond them (past about ±1 m an end is infinite, the safe way), to
    /// within 1/32 mm.
    #[test]
    fn a_packed_span_errs_on_the_safe_side() {
        let ends = [
            0.0,
            1e-4,
            -1e-4,
            0.03125,
            -0.03125,
            0.05,
            -7.3,
            12.345,
            250.0,
            -250.0,
            1023.9,
            1024.5,
            -1024.5,
            5e3,
            f32::INFINITY,
            f32::NEG_INFINITY,
        ];
        let unit = 1.0 / SPAN_UNITS;
        for &lo in &ends {
            for &hi in &ends {
                let (a, b) = unpack_span(pack_span(lo, hi, true));
                assert!(a <= lo && hi <= b, "outward ({lo}, {hi}) -> ({a}, {b})");
                if lo.abs() < 1000.0 && hi.abs() < 1000.0 {
                    assert!(lo - a <= unit && b - hi <= unit, "outward ({lo}, {hi}) -> ({a}, {b})");
                }
                let (a, b) = unpack_span(pack_span(lo, hi, false));
                assert!(a > b || (lo <= a && b <= hi), "inward ({lo}, {hi}) -> ({a}, {b})");
                if lo <= hi && hi - lo > unit && lo.abs() < 1000.0 && hi.abs() < 1000.0 {
                    assert!(a - lo <= unit && hi - b <= unit, "inward ({lo}, {hi}) -> ({a}, {b})");
                }
            }
        }
        let (a, b) = unpack_span(pack_span(f32::NAN, 1.0, true));
        assert_eq!((a, b), (f32::NEG_INFINITY, f32::INFINITY));
        let (a, b) = unpack_span(pack_span(0.0, f32::NAN, false));
        assert!(a > b, "a NaN span packed inward holds ({a}, {b})");
    }

    /// Two ascending lists merge into the ascending list of both, whichever runs out first.
    #[test]
    fn merged_lists_ascend() {
        assert_eq!(merged(&[1, 4, 9], &[2, 3, 10, 11]), [1, 2, 3, 4, 9, 10, 11]);
        assert_eq!(merged(&[5, 6, 7], &[0]), [0, 5, 6, 7]);
        assert_eq!(merged(&[], &[3]), [3]);
    }

    /// Shares cover the items in order, never more than asked for, weightless items at the end included.
    #[test]
    fn shares_cover_the_items_in_at_most_k() {
        let items = [3u64, 1, 0, 2, 2, 0, 0];
        for k in 1..=8 {
            let got = shares(&items, |&w| w, k);
            assert!(!got.is_empty() && got.len() <= k, "{k}: {got:?}");
            assert_eq!(got.concat(), items, "{k}");
        }
        assert_eq!(shares(&[1u64, 1, 0], |&w| w, 2), vec![&[1u64][..], &[1, 0][..]]);
        assert!(shares::<u64>(&[], |&w| w, 2).is_empty());
    }

    /// A path through three centres on a circle is that circle; its spans hold the places where a sphere holds a
    /// point, and only those, and its foot is the place nearest a point: against each path sampled every 0.01 mm
    /// (circles of 12 mm to 10 m radius in three planes, lines; points near and far, on either side).
    #[test]
    fn a_path_places_spheres_as_its_samples_do() {
        let mut rng = 4242u64;
        let mut uniform = |lo: f64, hi: f64| {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            lo + (hi - lo) * ((rng >> 11) as f64 / (1u64 << 53) as f64)
        };
        let frames = [
            (DVec3::X, DVec3::Y),
            (DVec3::new(0.6, 0.0, 0.8), DVec3::new(0.0, 1.0, 0.0)),
            (DVec3::new(0.0, 0.6, -0.8), DVec3::new(0.48, 0.64, 0.48).normalize()),
        ];
        let mut checked = 0;
        for (f, &(out, tangent)) in frames.iter().enumerate() {
            let tangent = (tangent - out * tangent.dot(out)).normalize();
            let c = DVec3::new(10.0 * f as f64, -5.0, 3.0);
            for radius in [12.0, 40.0, 300.0, 1e4, f64::INFINITY] {
                // Along the circle (or line) through `c`, `s` mm of arc on.
                let at = |s: f64| {
                    if radius.is_finite() {
                        let th = s / radius;
                        c + (out * (th.cos() - 1.0) + tangent * th.sin()) * radius
                    } else {
                        c + tangent * s
                    }
                };
                let step = 3.0;
                let f32s = |p: DVec3| p.as_vec3();
                let path = Path::through(Some(f32s(at(-2.0 * step))), Some(f32s(at(-step))), f32s(c));
                let k = if radius.is_finite() { 1.0 / radius } else { 0.0 };
                assert!((path.kappa - k).abs() <= 1e-2 * k + 1e-6, "radius {radius}: curvature {}", path.kappa);
                assert!(path.u.dot(tangent) > 0.999, "radius {radius}: tangent {}", path.u);
                for back in [step, 2.0 * step] {
                    let (place, off) = path.foot(at(-back) - c);
                    assert!(
                        off < 1e-3 && (path.arc(place) + back).abs() < 1e-3,
                        "radius {radius}: foot of {back} back"
                    );
                }
                // The path's own places and positions, sampled (a line, or its circle but the far side).
                let k = path.kappa;
                let reach = if k > 0.0 { (std::f64::consts::PI / k - 1.0).min(200.0) } else { 200.0 };
                let samples: Vec<(f64, DVec3)> = (-(reach * 100.0) as i64..=(reach * 100.0) as i64)
                    .map(|i| i as f64 / 100.0)
                    .map(|s| match k > 0.0 {
                        true => (
                            2.0 * (k * s / 2.0).tan() / k,
                            c + (path.out * ((k * s).cos() - 1.0) + path.u * (k * s).sin()) / k,
                        ),
                        false => (s, c + path.u * s),
                    })
                    .collect();
                for _ in 0..40 {
                    let w = DVec3::new(uniform(-30.0, 30.0), uniform(-30.0, 30.0), uniform(-30.0, 30.0));
                    let p = c + w;
                    // The foot: the nearest sample, as near as the sampling allows.
                    let (place, off) = path.foot(w);
                    let nearest = samples.iter().map(|(_, q)| q.distance(p)).fold(f64::INFINITY, f64::min);
                    if path.arc(place).abs() < reach - 0.1 {
                        assert!(
                            off <= nearest + 1e-8 * (1.0 + off) && nearest - off < 1e-3,
                            "radius {radius}, {w}: foot {off} vs {nearest}"
                        );
                        let s = path.arc(place);
                        let foot = match k > 0.0 {
                            true => c + (path.out * ((k * s).cos() - 1.0) + path.u * (k * s).sin()) / k,
                            false => c + path.u * s,
                        };
                        assert!(
                            (foot.distance(p) - off).abs() < 1e-8 * (1.0 + off),
                            "radius {radius}, {w}: foot at {s}"
                        );
                    }
                    for rho in [3.0, 10.0, 10.1, 25.0] {
                        let coordinates = path.coordinates(w);
                        let Some((lo, hi)) = path.span(rho, coordinates, true) else {
                            assert!(samples.iter().all(|(_, q)| q.distance(p) > rho - 1e-9), "radius {radius}: none");
                            assert_eq!(path.span(rho, coordinates, false), None);
                            continue;
                        };
                        if lo.is_infinite() {
                            // The places are not one span (the circle curls round the point): none inward.
                            assert_eq!(path.span(rho, coordinates, false), None);
                            continue;
                        }
                        assert_eq!(path.span(rho, coordinates, false), Some((lo, hi)));
                        for (place, q) in &samples {
                            let d = q.distance(p);
                            let spanned = (lo..=hi).contains(place);
                            assert!(
                                spanned || d > rho - 1e-7,
                                "radius {radius}, {w}, {rho}: {place} outside ({lo}, {hi}) at {d}"
                            );
                            assert!(
                                !spanned || d <= rho + 1e-7,
                                "radius {radius}, {w}, {rho}: {place} inside ({lo}, {hi}) at {d}"
                            );
                        }
                        checked += 1;
                    }
                }
            }
        }
        assert!(checked > 300, "{checked} spans checked");
    }
}
