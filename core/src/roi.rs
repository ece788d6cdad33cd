//! Regions of interest for tractogram selection, as TrackVis and DSI Studio use them: spheres, boxes and
//! planes, each an *include* (a streamline must pass through it) or an *exclude* (it must not); a
//! streamline is selected when it meets every include and no exclude (AND semantics).
//!
//! "Passes through" is defined as MRtrix3's `tckedit` defines it, so that a selection here keeps exactly the
//! streamlines `tckedit` keeps: a streamline meets a sphere, a box or a mask when one of its *points* lies in
//! it ([`RoiShape::contains`], evaluated in f32 in `tckedit`'s order of operations; the segments between
//! points are not tested, so a streamline whose steps jump over a small region misses it, in both tools). A
//! plane (which `tckedit` has not) is met by a segment whose ends lie on both sides of it, or on it.
//! [`RoiShape::meets_segment`] is the exact geometric test of a segment, for picking and drawing.
//! [`select`] is parallel over streamlines and uses a uniform grid of segments, so a small ROI only tests
//! the streamlines near it; [`Criteria`] tests one streamline at a time, for streams of any length.

use glam::{Vec2, Vec3};
use rayon::prelude::*;

use crate::io::Streamlines;

/// A region's shape, in the tractogram's world space (RAS+ mm).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum RoiShape {
    /// A ball: the points within `radius` of `centre`, boundary included.
    Sphere {
        /// Centre, RAS+ mm.
        centre: [f32; 3],
        /// Radius, mm.
        radius: f32,
    },
    /// Axis-aligned box.
    Box {
        /// The corner of least coordinates, RAS+ mm.
        min: [f32; 3],
        /// The corner of greatest coordinates, RAS+ mm (faces included).
        max: [f32; 3],
    },
    /// The infinite plane through `point` with normal `normal`.
    Plane {
        /// A point of the plane, RAS+ mm.
        point: [f32; 3],
        /// The plane's normal, any non-zero length (only the side of a point is tested).
        normal: [f32; 3],
    },
}

/// What a region does to the streamlines that meet it (`tckedit -include` / `-exclude`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum RoiMode {
    /// Kept streamlines meet the region (every include region, when there are several). The default.
    #[default]
    Include,
    /// Streamlines that meet the region are dropped.
    Exclude,
}

/// A region of interest: a shape and what it does.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Roi {
    /// Where the region is (RAS+ mm).
    pub shape: RoiShape,
    /// Include (the default) or exclude.
    pub mode: RoiMode,
}

/// Half the side of the square by which a plane ROI is drawn and picked (mm).
pub const PLANE_HANDLE_HALF: f32 = 30.0;

impl RoiShape {
    /// Where a ray (`origin`, unit `dir`) first meets the region's drawn outline, as a distance along it (0
    /// when it starts inside a sphere or box); None on a miss. A plane counts within its drawn square
    /// ([`PLANE_HANDLE_HALF`] around `point`). For picking an ROI under the cursor.
    pub fn ray_hit(&self, origin: Vec3, dir: Vec3) -> Option<f32> {
        match *self {
            RoiShape::Sphere { centre, radius } => {
                let oc = origin - Vec3::from(centre);
                let b = oc.dot(dir);
                let disc = b * b - (oc.length_squared() - radius * radius);
                if disc < 0.0 {
                    return None;
                }
                let far = -b + disc.sqrt();
                (far >= 0.0).then(|| (-b - disc.sqrt()).max(0.0))
            }
            RoiShape::Box { min, max } => {
                let (lo, hi) = (Vec3::from(min).min(Vec3::from(max)), Vec3::from(min).max(Vec3::from(max)));
                let inv = dir.recip();
                let (a, b) = ((lo - origin) * inv, (hi - origin) * inv);
                let t0 = a.min(b).max_element().max(0.0);
                let t1 = a.max(b).min_element();
                (t0 <= t1).then_some(t0)
            }
            RoiShape::Plane { point, normal } => {
                let (p, n) = (Vec3::from(point), Vec3::from(normal).normalize_or(Vec3::Z));
                let denom = dir.dot(n);
                if denom.abs() < 1e-9 {
                    return None;
                }
                let t = (p - origin).dot(n) / denom;
                // Within the drawn square: the square's axes are those of the gizmo (Z rotated onto n).
                let q = origin + dir * t - p;
                let rot = glam::Quat::from_rotation_arc(Vec3::Z, n).inverse();
                let local = rot * q;
                (t >= 0.0 && local.x.abs() <= PLANE_HANDLE_HALF && local.y.abs() <= PLANE_HANDLE_HALF).then_some(t)
            }
        }
    }

    /// Whether the region may meet the axis-aligned box `lo..hi` (exact for spheres, boxes and planes).
    pub fn meets_box(&self, lo: Vec3, hi: Vec3) -> bool {
        match *self {
            RoiShape::Sphere { centre, radius } => {
                let c = Vec3::from(centre);
                (c.clamp(lo, hi) - c).length_squared() <= radius * radius
            }
            RoiShape::Box { min, max } => {
                let (a, b) = (Vec3::from(min).min(Vec3::from(max)), Vec3::from(min).max(Vec3::from(max)));
                a.cmple(hi).all() && b.cmpge(lo).all()
            }
            RoiShape::Plane { point, normal } => {
                let (p, n) = (Vec3::from(point), Vec3::from(normal));
                let (centre, half) = ((lo + hi) * 0.5, (hi - lo) * 0.5);
                (centre - p).dot(n).abs() <= half.dot(n.abs())
            }
        }
    }

    /// The region moved by `delta` (mm).
    pub fn translated(&self, delta: Vec3) -> RoiShape {
        let add = |p: [f32; 3]| (Vec3::from(p) + delta).to_array();
        match *self {
            RoiShape::Sphere { centre, radius } => RoiShape::Sphere { centre: add(centre), radius },
            RoiShape::Box { min, max } => RoiShape::Box { min: add(min), max: add(max) },
            RoiShape::Plane { point, normal } => RoiShape::Plane { point: add(point), normal },
        }
    }

    /// The region's reference point: a sphere's centre, a box's centre, a plane's point.
    pub fn anchor(&self) -> Vec3 {
        match *self {
            RoiShape::Sphere { centre, .. } => Vec3::from(centre),
            RoiShape::Box { min, max } => (Vec3::from(min) + Vec3::from(max)) * 0.5,
            RoiShape::Plane { point, .. } => Vec3::from(point),
        }
    }

    /// Whether point `p` lies in the region, as `tckedit` decides it for a sphere (`|c - p|² <= r²`, in f32,
    /// summed as Eigen sums three squares); a box holds its faces; a plane holds nothing (it is met by
    /// crossing it, [`Self::meets_step`]).
    #[inline]
    pub fn contains(&self, p: Vec3) -> bool {
        match *self {
            RoiShape::Sphere { centre, radius } => {
                let d = Vec3::from(centre) - p;
                d.x * d.x + (d.y * d.y + d.z * d.z) <= radius * radius
            }
            RoiShape::Box { min, max } => p.cmpge(Vec3::from(min)).all() && p.cmple(Vec3::from(max)).all(),
            RoiShape::Plane { .. } => false,
        }
    }

    /// Whether the step `a`-`b` of a streamline meets the region under the selection rule (module
    /// documentation): an end in a sphere or box, the two ends on both sides of a plane (or one on it).
    #[inline]
    pub fn meets_step(&self, a: Vec3, b: Vec3) -> bool {
        match *self {
            RoiShape::Plane { .. } => self.meets_segment(a, b),
            _ => self.contains(a) || self.contains(b),
        }
    }

    /// Whether a streamline meets the region under the selection rule (a single point: whether it lies in it;
    /// on a plane when exactly on it).
    pub fn meets_streamline(&self, pts: &[Vec3]) -> bool {
        match (pts, self) {
            ([], _) => false,
            ([p], _) => self.meets_step(*p, *p),
            (_, RoiShape::Plane { .. }) => pts.windows(2).any(|w| self.meets_segment(w[0], w[1])),
            _ => pts.iter().any(|p| self.contains(*p)),
        }
    }

    /// Whether the segment `a`-`b` meets the region (exact geometry: the segment's closest point to a sphere's
    /// centre, the slab test of a box, a sign change across a plane).
    pub fn meets_segment(&self, a: Vec3, b: Vec3) -> bool {
        match *self {
            RoiShape::Sphere { centre, radius } => {
                let c = Vec3::from(centre);
                let ab = b - a;
                let len2 = ab.length_squared();
                let t = if len2 > 0.0 { ((c - a).dot(ab) / len2).clamp(0.0, 1.0) } else { 0.0 };
                (a + ab * t - c).length_squared() <= radius * radius
            }
            RoiShape::Box { min, max } => {
                let (lo, hi) = (Vec3::from(min), Vec3::from(max));
                let d = b - a;
                let (mut t0, mut t1) = (0.0f32, 1.0f32);
                for k in 0..3 {
                    if d[k].abs() < 1e-12 {
                        if a[k] < lo[k] || a[k] > hi[k] {
                            return false;
                        }
                    } else {
                        let (u, v) = ((lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]);
                        t0 = t0.max(u.min(v));
                        t1 = t1.min(u.max(v));
                        if t0 > t1 {
                            return false;
                        }
                    }
                }
                true
            }
            RoiShape::Plane { point, normal } => {
                let (p, n) = (Vec3::from(point), Vec3::from(normal));
                let (sa, sb) = ((a - p).dot(n), (b - p).dot(n));
                sa * sb <= 0.0
            }
        }
    }

    /// World bounding box, `None` for an unbounded plane.
    pub fn bounds(&self) -> Option<(Vec3, Vec3)> {
        match *self {
            RoiShape::Sphere { centre, radius } => {
                Some((Vec3::from(centre) - radius.abs(), Vec3::from(centre) + radius.abs()))
            }
            RoiShape::Box { min, max } => Some((Vec3::from(min), Vec3::from(max))),
            RoiShape::Plane { .. } => None,
        }
    }
}

/// Per axis, the eighths of a cell (bit `x + 2 y + 4 z`) in its lower half (index 1), its upper half (2), both
/// (3) or neither (0) along that axis.
const EIGHTHS: [[u8; 4]; 3] =
    [[0, 0b0101_0101, 0b1010_1010, 0xff], [0, 0b0011_0011, 0b1100_1100, 0xff], [0, 0x0f, 0xf0, 0xff]];

/// The cells of a uniform grid over a box, at most 1024 an axis: the frame [`SegmentGrid`] and
/// [`crate::roi_index::StreamlineCells`] bin into. Points beyond the box fall in the border cells, which
/// therefore reach to infinity when a region is tested against them.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Cells {
    lo: Vec3,
    cell: f32,
    dims: [usize; 3],
}

impl Cells {
    /// Cells of about `cell` mm (at least 1 µm) from `lo` to `hi`.
    pub(crate) fn over(lo: Vec3, hi: Vec3, cell: f32) -> Self {
        let cell = cell.max(1e-3);
        let dims = ((hi - lo) / cell).floor().to_array().map(|v| (v as usize + 1).min(1024));
        Self { lo, cell, dims }
    }

    /// A cell's side (mm).
    pub(crate) fn cell(&self) -> f32 {
        self.cell
    }

    /// How many cells there are.
    pub(crate) fn count(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    /// The cell of `p`, clamped to the grid.
    pub(crate) fn index(&self, p: Vec3) -> [usize; 3] {
        let q = ((p - self.lo) / self.cell).floor();
        [0, 1, 2].map(|k| (q[k].max(0.0) as usize).min(self.dims[k] - 1))
    }

    /// The cell's position in x-fastest order.
    pub(crate) fn linear(&self, [x, y, z]: [usize; 3]) -> usize {
        x + self.dims[0] * (y + self.dims[1] * z)
    }

    /// The cell range (inclusive) under a region's bounds; the whole grid for a plane.
    pub(crate) fn under(&self, shape: &RoiShape) -> ([usize; 3], [usize; 3]) {
        match shape.bounds() {
            Some((blo, bhi)) => (self.index(blo), self.index(bhi)),
            None => ([0; 3], self.dims.map(|d| d - 1)),
        }
    }

    /// The box cell `k` holds: its own, but the outermost cells also hold what the index clamp puts there
    /// (beyond a grid capped at 1024 cells per axis), so their outer sides lie far away (large but finite, so
    /// that a plane's test stays finite).
    fn extent(&self, k: [usize; 3]) -> (Vec3, Vec3) {
        let mut lo = self.lo + self.cell * Vec3::new(k[0] as f32, k[1] as f32, k[2] as f32);
        let mut hi = lo + Vec3::splat(self.cell);
        for a in 0..3 {
            if k[a] == 0 {
                lo[a] = -1e30;
            }
            if k[a] + 1 == self.dims[a] {
                hi[a] = 1e30;
            }
        }
        (lo, hi)
    }

    /// Whether cell `k` may hold what meets `shape` there. A segment meeting the region does so at a point of
    /// its bounding box, so in some cell that meets the region: the cells that do not can be skipped.
    pub(crate) fn meets(&self, shape: &RoiShape, k: [usize; 3]) -> bool {
        let (lo, hi) = self.extent(k);
        shape.meets_box(lo, hi)
    }

    /// The cells meeting `shape`, as the linear positions of those in each z layer of [`Self::under`].
    pub(crate) fn meeting(&self, shape: &RoiShape) -> impl Iterator<Item = Vec<usize>> + '_ {
        let shape = *shape;
        self.under_by_layer(self.under(&shape), move |k| self.meets(&shape, k).then_some(()))
            .map(|layer| layer.into_iter().map(|(c, ())| c).collect())
    }

    /// For each z layer of the cells `a..=b` (a region's [`Self::under`]), the linear positions of those for which
    /// `f` gives something, with it.
    fn under_by_layer<'a, T>(
        &'a self,
        (a, b): ([usize; 3], [usize; 3]),
        f: impl Fn([usize; 3]) -> Option<T> + 'a,
    ) -> impl Iterator<Item = Vec<(usize, T)>> + 'a {
        (a[2]..=b[2]).map(move |z| {
            let mut cells = Vec::new();
            for y in a[1]..=b[1] {
                for x in a[0]..=b[0] {
                    if let Some(v) = f([x, y, z]) {
                        cells.push((self.linear([x, y, z]), v));
                    }
                }
            }
            cells
        })
    }

    /// The halves of cell `k`'s side along `axis` that the span `lo..=hi` (mm; in cells `first..=last`) reaches:
    /// bit 0 the lower, bit 1 the upper. A value within a thousandth of a cell of the middle reaches both, so
    /// that the eighths a region is tested against ([`Self::meeting_eighths`]) hold it whatever the rounding.
    fn halves(&self, axis: usize, k: usize, (lo, hi): (f32, f32), (first, last): (usize, usize)) -> u8 {
        let (mid, eps) = (self.middle(axis, k), self.cell * 1e-3);
        u8::from(k > first || lo <= mid + eps) | (u8::from(k < last || hi >= mid - eps) << 1)
    }

    /// The middle of cell `k` along `axis` (mm).
    fn middle(&self, axis: usize, k: usize) -> f32 {
        self.lo[axis] + self.cell * k as f32 + self.cell * 0.5
    }

    /// Calls `f` with the linear position of every cell that the bounding box of the segment `a`-`b` meets, and
    /// the mask of the cell's eighths the box meets (bit `x + 2 y + 4 z` for the eighth in the lower (0) or
    /// upper (1) half along each axis).
    pub(crate) fn spanned_eighths(&self, a: Vec3, b: Vec3, mut f: impl FnMut(usize, u8)) {
        let (blo, bhi) = (a.min(b), a.max(b));
        let (lo, hi) = (self.index(blo), self.index(bhi));
        let halves = |axis: usize, k: usize| self.halves(axis, k, (blo[axis], bhi[axis]), (lo[axis], hi[axis]));
        for z in lo[2]..=hi[2] {
            let mz = EIGHTHS[2][halves(2, z) as usize];
            for y in lo[1]..=hi[1] {
                let my = mz & EIGHTHS[1][halves(1, y) as usize];
                for x in lo[0]..=hi[0] {
                    f(self.linear([x, y, z]), my & EIGHTHS[0][halves(0, x) as usize]);
                }
            }
        }
    }

    /// The mask of cell `k`'s eighths (as [`Self::spanned_eighths`] numbers them) that may hold what meets
    /// `shape` there ([`Self::meets`] for each eighth: the cell's box ([`Self::extent`]) cut at its middle).
    pub(crate) fn meeting_eighths(&self, shape: &RoiShape, k: [usize; 3]) -> u8 {
        let (cell_lo, cell_hi) = self.extent(k);
        let mid = Vec3::from([0, 1, 2].map(|a| self.middle(a, k[a])));
        let mut mask = 0;
        for e in 0..8 {
            let upper = |a: usize| (e >> a) & 1 == 1;
            let lo = Vec3::from([0, 1, 2].map(|a| if upper(a) { mid[a] } else { cell_lo[a] }));
            let hi = Vec3::from([0, 1, 2].map(|a| if upper(a) { cell_hi[a] } else { mid[a] }));
            if shape.meets_box(lo, hi) {
                mask |= 1 << e;
            }
        }
        mask
    }

    /// The cells meeting `shape` with the masks of their eighths that do ([`Self::meeting_eighths`]), as
    /// [`Self::meeting`] gives them.
    pub(crate) fn meeting_with_eighths(&self, shape: &RoiShape) -> impl Iterator<Item = Vec<(usize, u8)>> + '_ {
        let shape = *shape;
        self.under_by_layer(self.under(&shape), move |k| {
            Some(self.meeting_eighths(&shape, k)).filter(|&mask| mask != 0)
        })
    }

    /// Calls `f` with the linear position of every cell that the bounding box of the segment `a`-`b` meets.
    pub(crate) fn spanned(&self, a: Vec3, b: Vec3, mut f: impl FnMut(usize)) {
        let (lo, hi) = (self.index(a.min(b)), self.index(a.max(b)));
        for z in lo[2]..=hi[2] {
            for y in lo[1]..=hi[1] {
                for x in lo[0]..=hi[0] {
                    f(self.linear([x, y, z]));
                }
            }
        }
    }
}

/// A uniform grid over a tractogram's segments: per cell, the segments whose bounding box overlaps it.
pub struct SegmentGrid {
    cells: Cells,
    /// CSR over cells: `starts[c]..starts[c + 1]` in `segments`.
    starts: Vec<u32>,
    /// Index of a segment's first point.
    segments: Vec<u32>,
    /// Streamline of each point.
    owner: Vec<u32>,
}

impl SegmentGrid {
    /// Builds the grid for a tractogram (points flat, CSR `offsets`), cells about `cell` mm.
    pub fn new(points: &[Vec3], offsets: &[usize], cell: f32) -> Self {
        let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
        for p in points.iter().filter(|p| p.is_finite()) {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        if lo.x > hi.x {
            (lo, hi) = (Vec3::ZERO, Vec3::ZERO);
        }
        let cells = Cells::over(lo, hi, cell);
        let mut owner = vec![0u32; points.len()];
        for s in 0..offsets.len().saturating_sub(1) {
            owner[offsets[s]..offsets[s + 1]].fill(s as u32);
        }
        let segs: Vec<usize> = (0..offsets.len().saturating_sub(1))
            .flat_map(|s| offsets[s]..offsets[s + 1].saturating_sub(1).max(offsets[s]))
            .filter(|&i| points[i].is_finite() && points[i + 1].is_finite())
            .collect();
        let n_cells = cells.count();
        let mut count = vec![0u32; n_cells + 1];
        let visit = |i: usize, f: &mut dyn FnMut(usize)| cells.spanned(points[i], points[i + 1], f);
        for &i in &segs {
            visit(i, &mut |c| count[c + 1] += 1);
        }
        for c in 0..n_cells {
            count[c + 1] += count[c];
        }
        let mut fill = count.clone();
        let mut segments = vec![0u32; count[n_cells] as usize];
        for &i in &segs {
            visit(i, &mut |c| {
                segments[fill[c] as usize] = i as u32;
                fill[c] += 1;
            });
        }
        Self { cells, starts: count, segments, owner }
    }

    /// How many segment entries the cells that meet a region hold (what [`Self::meeting_mask_among`] scans).
    pub fn segments_under(&self, shape: &RoiShape) -> usize {
        self.cells.meeting(shape).flatten().map(|c| (self.starts[c + 1] - self.starts[c]) as usize).sum()
    }

    /// Per streamline, whether a segment meets `shape`, testing only streamlines with `candidates[s]` (the
    /// others are false). Parallel over the grid's z layers; a streamline already found is not tested again.
    pub fn meeting_mask_among(&self, points: &[Vec3], shape: &RoiShape, candidates: &[bool]) -> Vec<bool> {
        use std::sync::atomic::{AtomicBool, Ordering};
        let n = candidates.len();
        let marks: Vec<AtomicBool> = (0..n).map(|_| AtomicBool::new(false)).collect();
        let layers: Vec<Vec<usize>> = self.cells.meeting(shape).collect();
        layers.into_par_iter().for_each(|layer| {
            for c in layer {
                for &i in &self.segments[self.starts[c] as usize..self.starts[c + 1] as usize] {
                    let i = i as usize;
                    let s = self.owner[i] as usize;
                    if s < n
                        && candidates[s]
                        && !marks[s].load(Ordering::Relaxed)
                        && shape.meets_step(points[i], points[i + 1])
                    {
                        marks[s].store(true, Ordering::Relaxed);
                    }
                }
            }
        });
        marks.into_iter().map(AtomicBool::into_inner).collect()
    }
}

/// Which streamlines the ROIs select (every include met, no exclude met); with no include, every
/// streamline not excluded. One-point streamlines meet a region when their point lies in it.
///
/// The regions are applied one after the other, includes first, the smallest first, each to the streamlines
/// still selected: by scanning the grid cells under the region (skipping streamlines already out), or, once
/// few streamlines remain, by testing those streamlines' own segments, whichever touches fewer segments.
pub fn select(points: &[Vec3], offsets: &[usize], grid: &SegmentGrid, rois: &[Roi]) -> Vec<bool> {
    let n = offsets.len().saturating_sub(1);
    let mut alive = vec![true; n];
    let volume = |r: &Roi| r.shape.bounds().map_or(f32::INFINITY, |(lo, hi)| (hi - lo).abs().element_product());
    let mut order: Vec<&Roi> = rois.iter().collect();
    order.sort_by(|a, b| {
        (a.mode != RoiMode::Include).cmp(&(b.mode != RoiMode::Include)).then(volume(a).total_cmp(&volume(b)))
    });
    for r in order {
        let alive_segments: usize = (0..n).filter(|&s| alive[s]).map(|s| offsets[s + 1] - offsets[s]).sum();
        let meets: Vec<bool> = if alive_segments < grid.segments_under(&r.shape) {
            (0..n)
                .into_par_iter()
                .map(|s| alive[s] && streamline_meets(&points[offsets[s]..offsets[s + 1]], &r.shape))
                .collect()
        } else {
            let mut m = grid.meeting_mask_among(points, &r.shape, &alive);
            // Single-point streamlines have no segment in the grid.
            for s in (0..n).filter(|&s| alive[s] && offsets[s + 1] - offsets[s] == 1) {
                m[s] = r.shape.meets_step(points[offsets[s]], points[offsets[s]]);
            }
            m
        };
        let include = r.mode == RoiMode::Include;
        for (a, m) in alive.iter_mut().zip(meets) {
            *a &= m == include;
        }
    }
    alive
}

/// Which streamlines the ROIs select when only their end points count (`tckedit -ends_only`): every include
/// region holds the first or the last point, no exclude region holds either (with no include, every
/// streamline not excluded; a streamline without points meets nothing). Planes, which have no inside, are met
/// by a step crossing them anywhere along the streamline, as [`Criteria::keeps`] has them.
pub fn select_ends(t: &(impl Streamlines + ?Sized), rois: &[Roi]) -> Vec<bool> {
    (0..t.n_streamlines())
        .into_par_iter()
        .map(|s| {
            let pts = t.streamline(s);
            rois.iter().all(|r| {
                let met = match (&r.shape, pts) {
                    (_, []) => false,
                    (RoiShape::Plane { .. }, _) => r.shape.meets_streamline(pts),
                    (shape, [first, .., last]) => shape.contains(*first) || shape.contains(*last),
                    (shape, [only]) => shape.contains(*only),
                };
                met == (r.mode == RoiMode::Include)
            })
        })
        .collect()
}

/// The streamline a ray picks (a click in a view): of the streamlines `shown`, the one with a step that comes
/// within the cone of half-angle `atan(tolerance)` around the ray (origin `o`, unit direction `d`; a click's
/// tolerance in pixels over the focal length in pixels), nearest along the ray; with its distance along the
/// ray. A one-point streamline is a point. Brute force over every step, in parallel; an indexed set picks the
/// same streamline by [`crate::roi_index::StreamlineCells::pick`], testing only those near the ray.
pub fn pick_streamline(
    t: &(impl Streamlines + ?Sized),
    shown: impl Fn(usize) -> bool + Sync,
    o: Vec3,
    d: Vec3,
    tolerance: f32,
) -> Option<(usize, f32)> {
    let ray = Ray::new(o, d, tolerance);
    (0..t.n_streamlines())
        .into_par_iter()
        .filter(|&s| shown(s))
        .filter_map(|s| ray.hit(t.streamline(s)).map(|d| (s, d)))
        .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
}

/// The streamlines a lasso picks: of the streamlines `shown`, those with a point whose screen position
/// (`project`, pixels; `None` for a point that cannot be picked: behind the camera, outside a 2D view's slab)
/// lies inside `polygon` (screen positions, pixels; closed from its last vertex to its first; the even-odd
/// rule, so a lasso that crosses itself leaves out what it circles twice). The points are tested, not the steps
/// between them, as the ROIs test them (see the module). Parallel over streamlines; in increasing order.
pub fn lasso_streamlines(
    t: &(impl Streamlines + ?Sized),
    shown: impl Fn(usize) -> bool + Sync,
    project: impl Fn(Vec3) -> Option<Vec2> + Sync,
    polygon: &[Vec2],
) -> Vec<usize> {
    if polygon.len() < 3 {
        return vec![];
    }
    let (lo, hi) = polygon.iter().fold((Vec2::MAX, Vec2::MIN), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
    let inside = |q: Vec2| q.cmpge(lo).all() && q.cmple(hi).all() && in_polygon(polygon, q);
    (0..t.n_streamlines())
        .into_par_iter()
        .filter(|&s| shown(s) && t.streamline(s).iter().any(|p| project(*p).is_some_and(inside)))
        .collect()
}

/// Whether `q` lies inside the closed polygon (even-odd rule: a ray from `q` towards +x crosses its edges an
/// odd number of times; a point on a left or bottom edge is inside, on a right or top edge outside).
pub fn in_polygon(polygon: &[Vec2], q: Vec2) -> bool {
    let mut inside = false;
    let mut j = polygon.len().wrapping_sub(1);
    for (i, a) in polygon.iter().enumerate() {
        let b = polygon[j];
        if (a.y > q.y) != (b.y > q.y) && q.x < a.x + (q.y - a.y) * (b.x - a.x) / (b.y - a.y) {
            inside = !inside;
        }
        j = i;
    }
    inside
}

/// The streamline a click picks in a projected view (a 2D view): of the streamlines `shown`, the one with a
/// step whose screen image (`project` of its two points, pixels; a step with a point `None` is left out, as a
/// step leaving a 2D view's slab) comes nearest `at`, within `radius` pixels; with that distance. A one-point
/// streamline is a point. Ties go to the lower index. Brute force over every step, in parallel.
pub fn pick_projected(
    t: &(impl Streamlines + ?Sized),
    shown: impl Fn(usize) -> bool + Sync,
    project: impl Fn(Vec3) -> Option<Vec2> + Sync,
    at: Vec2,
    radius: f32,
) -> Option<(usize, f32)> {
    let near = |a: Vec2, b: Vec2| {
        let u = b - a;
        let t = if u.length_squared() <= f32::EPSILON { 0.0 } else { ((at - a).dot(u) / u.dot(u)).clamp(0.0, 1.0) };
        (a + u * t).distance(at)
    };
    (0..t.n_streamlines())
        .into_par_iter()
        .filter(|&s| shown(s))
        .filter_map(|s| {
            let pts = t.streamline(s);
            let screen: Vec<Option<Vec2>> = pts.iter().map(|p| project(*p)).collect();
            let steps: Box<dyn Iterator<Item = (Option<Vec2>, Option<Vec2>)>> = match &screen[..] {
                [p] => Box::new(std::iter::once((*p, *p))),
                _ => Box::new(screen.windows(2).map(|w| (w[0], w[1]))),
            };
            steps
                .filter_map(|(a, b)| Some(near(a?, b?)))
                .filter(|d| *d <= radius)
                .min_by(f32::total_cmp)
                .map(|d| (s, d))
        })
        .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
}

/// A picking ray: origin `o`, unit direction `d`, and the cone of half-angle `atan(tolerance)` around it that a
/// step must come within (see [`pick_streamline`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Ray {
    pub(crate) o: Vec3,
    pub(crate) d: Vec3,
    pub(crate) tolerance: f32,
    e1: Vec3,
    e2: Vec3,
}

impl Ray {
    pub(crate) fn new(o: Vec3, d: Vec3, tolerance: f32) -> Self {
        let (e1, e2) = d.any_orthonormal_pair();
        Self { o, d, tolerance, e1, e2 }
    }

    /// How far along the ray a streamline's nearest step within the cone comes (a one-point streamline is a
    /// point), if one does. A step whose two points lie beyond the cone's widest radius on the step (its
    /// larger distance along the ray times the tolerance, with a margin for rounding) on the same side of an
    /// axis across the ray cannot come within the cone, and is not tested (the others are, exactly).
    pub(crate) fn hit(&self, pts: &[Vec3]) -> Option<f32> {
        let Self { o, d, tolerance, e1, e2 } = *self;
        let local = |p: Vec3| {
            let w = p - o;
            Vec3::new(w.dot(d), w.dot(e1), w.dot(e2))
        };
        let may_meet = |a: Vec3, b: Vec3| {
            let far = a.x.max(b.x);
            let r = tolerance * far * 1.001 + 1e-4;
            let beyond = |x: f32, y: f32| (x > r && y > r) || (x < -r && y < -r);
            far > 0.0 && !beyond(a.y, b.y) && !beyond(a.z, b.z)
        };
        let hit = |a: Vec3, b: Vec3| {
            let (t, dist) = ray_step_approach(o, d, a, b);
            (t > 0.0 && dist <= tolerance * t).then_some(t)
        };
        let mut best: Option<f32> = None;
        if let [p] = pts {
            best = hit(*p, *p);
        }
        let mut prev = pts.first().map(|p| local(*p));
        for k in 1..pts.len() {
            let cur = local(pts[k]);
            if prev.is_some_and(|a| may_meet(a, cur))
                && let Some(t) = hit(pts[k - 1], pts[k])
            {
                best = Some(best.map_or(t, |b: f32| b.min(t)));
            }
            prev = Some(cur);
        }
        best
    }
}

/// The closest approach of a ray (origin `o`, unit direction `d`) and the step `a`-`b`: the distance along the
/// ray of its closest point, and the distance between the two closest points.
fn ray_step_approach(o: Vec3, d: Vec3, a: Vec3, b: Vec3) -> (f32, f32) {
    let u = b - a;
    let w = a - o;
    let (uu, ud, uw, dw) = (u.dot(u), u.dot(d), u.dot(w), d.dot(w));
    let denom = uu - ud * ud;
    // The step's parameter of the closest approach, clamped to the step (a point, or parallel: its start).
    let s = if uu <= f32::EPSILON || denom <= 1e-9 * uu { 0.0 } else { ((ud * dw - uw) / denom).clamp(0.0, 1.0) };
    let p = a + u * s;
    let t = (p - o).dot(d);
    (t, (o + d * t - p).length())
}

/// Whether a polyline meets a region under the selection rule.
fn streamline_meets(pts: &[Vec3], shape: &RoiShape) -> bool {
    shape.meets_streamline(pts)
}

/// A mask image as a region: the voxels whose value is not zero (NaN counts as set, as in a C++ cast to
/// bool). A point meets it when the voxel nearest to it (each voxel coordinate rounded half away from zero, as
/// `tckedit` rounds) is set; points outside the image meet nothing.
#[derive(Clone, Debug)]
pub struct MaskRegion {
    dims: [usize; 3],
    set: Vec<bool>,
    /// World to voxel, rows of a 3x4 affine in f32 (as `tckedit` casts it).
    voxel_from_world: [[f32; 4]; 3],
}

impl MaskRegion {
    /// The region of a volume's first channel.
    pub fn new(volume: &crate::Volume<f32>) -> Self {
        let dims = volume.dims3();
        let n = dims.iter().product::<usize>();
        let set = (0..n).map(|v| volume.at(v, 0) != 0.0).collect();
        let m = volume.world_from_voxel.inverse();
        let voxel_from_world = std::array::from_fn(|r| std::array::from_fn(|c| m.col(c)[r] as f32));
        Self { dims, set, voxel_from_world }
    }

    /// Voxels set.
    pub fn count(&self) -> usize {
        self.set.iter().filter(|s| **s).count()
    }

    /// Whether `p` (RAS+ mm) falls in a set voxel.
    #[inline]
    pub fn contains(&self, p: Vec3) -> bool {
        let mut flat = 0usize;
        let mut stride = 1usize;
        for k in 0..3 {
            let m = &self.voxel_from_world[k];
            // In f32, summed as Eigen sums a 3-vector product, then the translation.
            let v = (m[0] * p.x + (m[1] * p.y + m[2] * p.z)) + m[3];
            let i = v.round();
            if !(i >= 0.0 && i < self.dims[k] as f32) {
                return false;
            }
            flat += i as usize * stride;
            stride *= self.dims[k];
        }
        self.set[flat]
    }
}

/// A region of a [`Criteria`]: a shape, or a mask image.
#[derive(Clone, Debug)]
pub enum Region {
    /// A sphere, box or plane.
    Shape(RoiShape),
    /// The non-zero voxels of a mask image (`tckedit` with an image as the region).
    Mask(std::sync::Arc<MaskRegion>),
}

impl Region {
    #[inline]
    fn contains(&self, p: Vec3) -> bool {
        match self {
            Region::Shape(s) => s.contains(p),
            Region::Mask(m) => m.contains(p),
        }
    }

    fn is_plane(&self) -> bool {
        matches!(self, Region::Shape(RoiShape::Plane { .. }))
    }
}

/// `tckedit`'s selection of one streamline at a time: it is kept when it meets every include region and no
/// exclude region (a streamline without points meets nothing); with `ends_only`, only its first and last
/// points are tested (`-ends_only`). Planes, which `tckedit` has not, are met by a step crossing them and
/// cannot be combined with `ends_only`.
#[derive(Clone, Debug, Default)]
pub struct Criteria {
    /// Regions a kept streamline meets, every one (default none).
    pub include: Vec<Region>,
    /// Regions a kept streamline meets none of (default none).
    pub exclude: Vec<Region>,
    /// Only the first and last points are tested (`-ends_only`; default false).
    pub ends_only: bool,
}

impl Criteria {
    /// The ROIs' shapes as regions, includes and excludes by their modes.
    pub fn from_rois(rois: &[Roi], ends_only: bool) -> Self {
        let regions = |mode| rois.iter().filter(|r| r.mode == mode).map(|r| Region::Shape(r.shape)).collect();
        Criteria { include: regions(RoiMode::Include), exclude: regions(RoiMode::Exclude), ends_only }
    }

    /// Whether there is anything to test.
    pub fn is_empty(&self) -> bool {
        self.include.is_empty() && self.exclude.is_empty()
    }

    /// Narrows a selection of the streamlines `t`: each still selected stays so when [`Criteria::keeps`] it
    /// (in parallel; the streamlines already out are not tested).
    pub fn narrow(&self, t: &(impl Streamlines + ?Sized), selected: &mut [bool]) {
        if self.is_empty() {
            return;
        }
        selected.par_iter_mut().enumerate().filter(|(_, k)| **k).for_each(|(s, k)| {
            *k = self.keeps(t.streamline(s));
        });
    }

    /// Whether the streamline `pts` is kept.
    pub fn keeps(&self, pts: &[Vec3]) -> bool {
        if self.is_empty() {
            return true;
        }
        if pts.is_empty() {
            return false;
        }
        let mut met = 0u64;
        let all = if self.include.len() >= 64 { u64::MAX } else { (1u64 << self.include.len()) - 1 };
        let visit = |p: Vec3, met: &mut u64| -> bool {
            for (k, r) in self.include.iter().enumerate() {
                if *met & (1 << k.min(63)) == 0 && !r.is_plane() && r.contains(p) {
                    *met |= 1 << k.min(63);
                }
            }
            self.exclude.iter().any(|r| !r.is_plane() && r.contains(p))
        };
        let ends = [pts[0], pts[pts.len() - 1]];
        let tested: &[Vec3] = if self.ends_only { &ends } else { pts };
        for p in tested {
            if visit(*p, &mut met) {
                return false;
            }
        }
        // Planes: crossed by a step.
        for (k, r) in self.include.iter().enumerate() {
            if let Region::Shape(s @ RoiShape::Plane { .. }) = r
                && s.meets_streamline(pts)
            {
                met |= 1 << k.min(63);
            }
        }
        if self
            .exclude
            .iter()
            .any(|r| matches!(r, Region::Shape(s @ RoiShape::Plane { .. }) if s.meets_streamline(pts)))
        {
            return false;
        }
        met & all == all
    }
}

/// The pieces of the streamline `pts` inside `masks` (`tckedit -mask`: streamlines leaving the mask are cut
/// there): the runs of consecutive points that lie in any of the regions (a point in a sphere, a box or a
/// mask's non-zero voxel, as [`Criteria`] tests it; planes contain no point), each of at least two points, in
/// order, as ranges of indices into `pts`. A streamline wholly inside is one piece; no masks: the streamline
/// whole.
pub fn pieces_inside(pts: &[Vec3], masks: &[Region]) -> Vec<std::ops::Range<usize>> {
    if masks.is_empty() {
        return std::iter::once(0..pts.len()).collect();
    }
    let inside = |p: &Vec3| masks.iter().any(|r| !r.is_plane() && r.contains(*p));
    let mut out = vec![];
    let mut start = None;
    for (i, p) in pts.iter().enumerate() {
        match (inside(p), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                if i - s >= 2 {
                    out.push(s..i);
                }
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start.filter(|s| pts.len() - s >= 2) {
        out.push(s..pts.len());
    }
    out
}
