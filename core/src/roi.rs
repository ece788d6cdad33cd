//! Regions of interest for tractogram selection, as TrackVis and DSI Studio use them: spheres, boxes and
//! planes, each an *include* (a streamline must pass through it) or an *exclude* (it must not); a
//! streamline is selected when it meets every include and no exclude (AND semantics).
//!
//! "Passes through" is exact for the polyline, not only its vertices: a segment meets a sphere when its
//! closest point is within the radius, a box when the slab test finds an overlap, a plane when its ends lie
//! on both sides (or on it). Selection is parallel over streamlines and uses a uniform grid of segment
//! bounding boxes, so a small ROI only tests the segments near it.

use glam::Vec3;
use rayon::prelude::*;

/// A region's shape, in the tractogram's world space (RAS+ mm).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum RoiShape {
    Sphere {
        centre: [f32; 3],
        radius: f32,
    },
    /// Axis-aligned box.
    Box {
        min: [f32; 3],
        max: [f32; 3],
    },
    /// The infinite plane through `point` with normal `normal`.
    Plane {
        point: [f32; 3],
        normal: [f32; 3],
    },
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum RoiMode {
    #[default]
    Include,
    Exclude,
}

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Roi {
    pub shape: RoiShape,
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

    /// Whether the segment `a`-`b` meets the region.
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

/// A uniform grid over a tractogram's segments: per cell, the segments whose bounding box overlaps it.
pub struct SegmentGrid {
    lo: Vec3,
    cell: f32,
    dims: [usize; 3],
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
        let cell = cell.max(1e-3);
        let dims = ((hi - lo) / cell).floor().to_array().map(|v| (v as usize + 1).min(1024));
        let mut owner = vec![0u32; points.len()];
        for s in 0..offsets.len().saturating_sub(1) {
            owner[offsets[s]..offsets[s + 1]].fill(s as u32);
        }
        let index = |p: Vec3| -> [usize; 3] {
            let q = ((p - lo) / cell).floor();
            [0, 1, 2].map(|k| (q[k].max(0.0) as usize).min(dims[k] - 1))
        };
        let cells_of = |i: usize| {
            let (a, b) = (points[i], points[i + 1]);
            let (ia, ib) = (index(a.min(b)), index(a.max(b)));
            (ia, ib)
        };
        let segs: Vec<usize> = (0..offsets.len().saturating_sub(1))
            .flat_map(|s| offsets[s]..offsets[s + 1].saturating_sub(1).max(offsets[s]))
            .filter(|&i| points[i].is_finite() && points[i + 1].is_finite())
            .collect();
        let n_cells = dims[0] * dims[1] * dims[2];
        let mut count = vec![0u32; n_cells + 1];
        let visit = |i: usize, f: &mut dyn FnMut(usize)| {
            let (a, b) = cells_of(i);
            for z in a[2]..=b[2] {
                for y in a[1]..=b[1] {
                    for x in a[0]..=b[0] {
                        f(x + dims[0] * (y + dims[1] * z));
                    }
                }
            }
        };
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
        Self { lo, cell, dims, starts: count, segments, owner }
    }

    /// Streamlines with a segment meeting `shape` (sorted, unique).
    pub fn streamlines_meeting(&self, points: &[Vec3], shape: &RoiShape) -> Vec<u32> {
        let n = self.owner.last().map_or(0, |o| *o as usize + 1);
        self.meeting_mask(points, shape, n).iter().enumerate().filter(|(_, m)| **m).map(|(i, _)| i as u32).collect()
    }

    /// Per streamline (of `n`), whether a segment meets `shape`. Parallel over the grid's z layers; a
    /// streamline already found is not tested again.
    pub fn meeting_mask(&self, points: &[Vec3], shape: &RoiShape, n: usize) -> Vec<bool> {
        use std::sync::atomic::{AtomicBool, Ordering};
        let (blo, bhi) = match shape.bounds() {
            Some(b) => b,
            None => (
                self.lo,
                self.lo + self.cell * Vec3::new(self.dims[0] as f32, self.dims[1] as f32, self.dims[2] as f32),
            ),
        };
        let index = |p: Vec3| -> [usize; 3] {
            let q = ((p - self.lo) / self.cell).floor();
            [0, 1, 2].map(|k| (q[k].max(0.0) as usize).min(self.dims[k] - 1))
        };
        let (a, b) = (index(blo), index(bhi));
        let marks: Vec<AtomicBool> = (0..n).map(|_| AtomicBool::new(false)).collect();
        (a[2]..=b[2]).into_par_iter().for_each(|z| {
            for y in a[1]..=b[1] {
                for x in a[0]..=b[0] {
                    let c = x + self.dims[0] * (y + self.dims[1] * z);
                    for &i in &self.segments[self.starts[c] as usize..self.starts[c + 1] as usize] {
                        let i = i as usize;
                        let s = self.owner[i] as usize;
                        if s < n && !marks[s].load(Ordering::Relaxed) && shape.meets_segment(points[i], points[i + 1]) {
                            marks[s].store(true, Ordering::Relaxed);
                        }
                    }
                }
            }
        });
        marks.into_iter().map(AtomicBool::into_inner).collect()
    }
}

/// Which streamlines the ROIs select (every include met, no exclude met); with no include, every
/// streamline not excluded. One-point streamlines meet a region when their point lies in it.
pub fn select(points: &[Vec3], offsets: &[usize], grid: &SegmentGrid, rois: &[Roi]) -> Vec<bool> {
    let n = offsets.len().saturating_sub(1);
    let mut includes_met = vec![0u32; n];
    let mut excluded = vec![false; n];
    let n_include = rois.iter().filter(|r| r.mode == RoiMode::Include).count() as u32;
    let hits: Vec<(RoiMode, Vec<u32>)> =
        rois.par_iter().map(|r| (r.mode, grid.streamlines_meeting(points, &r.shape))).collect();
    for (mode, ids) in hits {
        for s in ids {
            match mode {
                RoiMode::Include => includes_met[s as usize] += 1,
                RoiMode::Exclude => excluded[s as usize] = true,
            }
        }
    }
    // Single-point streamlines have no segment.
    for s in 0..n {
        if offsets[s + 1] - offsets[s] == 1 {
            let p = points[offsets[s]];
            for r in rois {
                if r.shape.meets_segment(p, p) {
                    match r.mode {
                        RoiMode::Include => includes_met[s] += 1,
                        RoiMode::Exclude => excluded[s] = true,
                    }
                }
            }
        }
    }
    (0..n).map(|s| includes_met[s] == n_include && !excluded[s]).collect()
}
