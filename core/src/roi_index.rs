//! ROI selection on tractograms too large for a [`crate::roi::SegmentGrid`]: per cell of a uniform grid, the
//! streamlines that pass through it, each once (4 bytes per streamline and cell; about 1.2 GB for 10M
//! whole-brain streamlines at 4 mm cells, where a segment grid holds 4 bytes per segment and cell plus the
//! owner of every point, 8 GB). The streamlines' points stay where they are (a mapped file:
//! [`crate::io::mapped::MappedTck`]); a query tests the candidates' own points with the rules of
//! [`crate::roi::select`], so it keeps the same streamlines.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};

use glam::Vec3;
use rayon::prelude::*;

use crate::roi::{Cells, Roi, RoiMode, RoiShape};

/// Per grid cell, the streamlines with a point in it or a segment whose bounding box meets it.
pub struct StreamlineCells {
    cells: Cells,
    /// CSR over cells: `starts[c]..starts[c + 1]` in `ids`.
    starts: Vec<u64>,
    /// Streamline indices, each at most once per cell.
    ids: Vec<u32>,
    /// Streamlines indexed.
    n: usize,
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
        let cells = Cells::over(bounds.0, bounds.1, cell);
        let n_cells = cells.count();
        let counts: Vec<AtomicU64> = (0..n_cells).map(|_| AtomicU64::new(0)).collect();
        (0..n).into_par_iter().for_each_init(Vec::new, |buf, s| {
            cells_of(&cells, streamline(s), buf);
            for &c in buf.iter() {
                counts[c as usize].fetch_add(1, Ordering::Relaxed);
            }
        });
        let mut starts = Vec::with_capacity(n_cells + 1);
        starts.push(0u64);
        for c in &counts {
            starts.push(starts.last().copied().unwrap_or(0) + c.load(Ordering::Relaxed));
        }
        let fill: Vec<AtomicU64> = starts[..n_cells].iter().map(|&s| AtomicU64::new(s)).collect();
        let total = starts[n_cells] as usize;
        let ids: Vec<AtomicU32> = (0..total).map(|_| AtomicU32::new(0)).collect();
        (0..n).into_par_iter().for_each_init(Vec::new, |buf, s| {
            cells_of(&cells, streamline(s), buf);
            for &c in buf.iter() {
                let at = fill[c as usize].fetch_add(1, Ordering::Relaxed);
                ids[at as usize].store(s as u32, Ordering::Relaxed);
            }
        });
        let ids = ids.into_iter().map(AtomicU32::into_inner).collect();
        Self { cells, starts, ids, n }
    }

    /// Bytes the index holds.
    pub fn heap_bytes(&self) -> usize {
        self.starts.len() * 8 + self.ids.len() * 4
    }

    /// The streamlines indexed in the cells that meet `shape` (ascending, each once): a superset of those
    /// that meet it. Deduplicated in a bit set of all streamlines (no sort), so the candidates come in file
    /// order, which is also the order their points lie in memory.
    pub fn candidates(&self, shape: &RoiShape) -> Vec<u32> {
        let mut bits = vec![0u64; self.n.div_ceil(64)];
        for c in self.cells.meeting(shape).flatten() {
            for &s in &self.ids[self.starts[c] as usize..self.starts[c + 1] as usize] {
                bits[s as usize / 64] |= 1 << (s % 64);
            }
        }
        bits.iter()
            .enumerate()
            .filter(|(_, w)| **w != 0)
            .flat_map(|(i, &w)| (0..64).filter(move |k| w >> k & 1 == 1).map(move |k| (i * 64 + k) as u32))
            .collect()
    }

    /// Which of the indexed streamlines the ROIs select, as [`crate::roi::select`] decides (every include
    /// met, no exclude met; with no include, every streamline not excluded), testing only candidates' points.
    pub fn select<'a>(&self, streamline: impl Fn(usize) -> &'a [Vec3] + Sync, rois: &[Roi]) -> Vec<bool> {
        let n = self.n;
        let meets = |shape: &RoiShape, ids: &[u32]| -> Vec<u32> {
            ids.par_iter().copied().filter(|&s| shape.meets_streamline(streamline(s as usize))).collect()
        };
        let includes: Vec<&Roi> = rois.iter().filter(|r| r.mode == RoiMode::Include).collect();
        let mut keep = match includes.split_first() {
            None => vec![true; n],
            Some((first, rest)) => {
                let mut kept = meets(&first.shape, &self.candidates(&first.shape));
                for r in rest {
                    kept = meets(&r.shape, &kept);
                }
                let mut keep = vec![false; n];
                kept.iter().for_each(|&s| keep[s as usize] = true);
                keep
            }
        };
        for r in rois.iter().filter(|r| r.mode == RoiMode::Exclude) {
            let still: Vec<u32> = self.candidates(&r.shape).into_iter().filter(|&s| keep[s as usize]).collect();
            for s in meets(&r.shape, &still) {
                keep[s as usize] = false;
            }
        }
        keep
    }
}

/// The distinct cells of a streamline's points and of its segments' bounding boxes, into `out`.
fn cells_of(cells: &Cells, pts: &[Vec3], out: &mut Vec<u32>) {
    out.clear();
    for (k, p) in pts.iter().enumerate().filter(|(_, p)| p.is_finite()) {
        match pts.get(k + 1).filter(|q| q.is_finite()) {
            Some(q) => cells.spanned(*p, *q, |c| out.push(c as u32)),
            None => out.push(cells.linear(cells.index(*p)) as u32),
        }
    }
    out.sort_unstable();
    out.dedup();
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
}
