//! Track-density imaging (Calamante et al., NeuroImage 2010; MRtrix3's `tckmap`): per voxel, the number of
//! streamlines that pass through it, each streamline counted once per voxel however many of its points or
//! segments lie there. Voxels are found exactly by walking each segment through the grid (Amanatides and Woo's
//! traversal), not by sampling points, so no voxel a segment crosses is missed at any voxel size.

use glam::{DMat4, DVec3};
use rayon::prelude::*;

use crate::Volume;
use crate::error::{Error, Result};
use crate::io::Tractogram;

/// The grid a density map is counted on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TdiGrid {
    /// Grid size in voxels (x, y, z).
    pub dims: [usize; 3],
    /// Voxel indices (integer = voxel centre) to world RAS+ mm, the tractogram's space.
    pub world_from_voxel: DMat4,
}

impl TdiGrid {
    /// An axis-aligned grid of `voxel_mm` voxels covering the streamlines' points, with one voxel to spare on
    /// every side.
    pub fn covering(t: &Tractogram, voxel_mm: f64) -> Result<TdiGrid> {
        if !(voxel_mm.is_finite() && voxel_mm > 0.0) {
            return Err(Error::Param(format!(
                "the density map's voxel size must be a positive number of mm, not {voxel_mm}"
            )));
        }
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in t.points.iter().filter(|p| p.is_finite()) {
            lo = lo.min(p.as_dvec3());
            hi = hi.max(p.as_dvec3());
        }
        if !lo.is_finite() {
            return Err(Error::Param("the tractogram holds no finite points".into()));
        }
        let origin = (lo / voxel_mm).floor() * voxel_mm - DVec3::splat(voxel_mm);
        let span = ((hi - origin) / voxel_mm).ceil() + DVec3::splat(2.0);
        let dims = [span.x as usize, span.y as usize, span.z as usize];
        if dims.iter().product::<usize>() > 1 << 30 {
            return Err(Error::Param(format!(
                "a density map of {dims:?} voxels at {voxel_mm} mm is too large; choose larger voxels"
            )));
        }
        let world_from_voxel = DMat4::from_translation(origin) * DMat4::from_scale(DVec3::splat(voxel_mm));
        Ok(TdiGrid { dims, world_from_voxel })
    }
}

/// The track-density map of `t` on `grid` (streamlines per voxel).
pub fn track_density(t: &Tractogram, grid: &TdiGrid) -> Result<Volume<f32>> {
    let det = grid.world_from_voxel.determinant();
    if !(det.is_finite() && det != 0.0) {
        return Err(Error::Param("the density map's affine is singular".into()));
    }
    let inv = grid.world_from_voxel.inverse();
    let d = grid.dims;
    let n = d.iter().product::<usize>();
    let counts = (0..t.n_streamlines())
        .into_par_iter()
        .fold(
            || (vec![0u32; n], Vec::new()),
            |(mut counts, mut visited): (Vec<u32>, Vec<usize>), s| {
                visited.clear();
                for w in t.streamline(s).windows(2) {
                    let (a, b) = (inv.transform_point3(w[0].as_dvec3()), inv.transform_point3(w[1].as_dvec3()));
                    walk(a, b, d, &mut visited);
                }
                if let [p] = t.streamline(s) {
                    walk(inv.transform_point3(p.as_dvec3()), inv.transform_point3(p.as_dvec3()), d, &mut visited);
                }
                visited.sort_unstable();
                visited.dedup();
                for &v in &visited {
                    counts[v] += 1;
                }
                (counts, visited)
            },
        )
        .map(|(c, _)| c)
        .reduce(
            || vec![0u32; n],
            |mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            },
        );
    let mut vol = Volume::zeros(&d, grid.world_from_voxel);
    vol.data.iter_mut().zip(&counts).for_each(|(o, c)| *o = *c as f32);
    Ok(vol)
}

/// Pushes the index of every voxel of `dims` that the segment `a`-`b` (voxel coordinates, voxel `k` spanning
/// `[k - 0.5, k + 0.5)`) passes through.
fn walk(a: DVec3, b: DVec3, dims: [usize; 3], out: &mut Vec<usize>) {
    if !(a.is_finite() && b.is_finite()) {
        return;
    }
    // Shift so that voxel k spans [k, k + 1), and clip the segment to the grid's box.
    let (a, b) = (a + DVec3::splat(0.5), b + DVec3::splat(0.5));
    let size = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
    let dir = b - a;
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for k in 0..3 {
        if dir[k].abs() < 1e-300 {
            if a[k] < 0.0 || a[k] >= size[k] {
                return;
            }
        } else {
            let (u, v) = ((0.0 - a[k]) / dir[k], (size[k] - a[k]) / dir[k]);
            t0 = t0.max(u.min(v));
            t1 = t1.min(u.max(v));
        }
    }
    if t0 > t1 {
        return;
    }
    let start = a + dir * t0;
    let mut cell = [0i64; 3];
    let (mut step, mut t_max, mut t_delta) = ([0i64; 3], [f64::INFINITY; 3], [f64::INFINITY; 3]);
    for k in 0..3 {
        cell[k] = (start[k].floor() as i64).clamp(0, dims[k] as i64 - 1);
        if dir[k] > 0.0 {
            step[k] = 1;
            t_max[k] = ((cell[k] + 1) as f64 - a[k]) / dir[k];
            t_delta[k] = 1.0 / dir[k];
        } else if dir[k] < 0.0 {
            step[k] = -1;
            t_max[k] = (cell[k] as f64 - a[k]) / dir[k];
            t_delta[k] = -1.0 / dir[k];
        }
    }
    loop {
        out.push(cell[0] as usize + dims[0] * (cell[1] as usize + dims[1] * cell[2] as usize));
        let k = if t_max[0] <= t_max[1] && t_max[0] <= t_max[2] {
            0
        } else if t_max[1] <= t_max[2] {
            1
        } else {
            2
        };
        if t_max[k] > t1 {
            return;
        }
        cell[k] += step[k];
        if cell[k] < 0 || cell[k] >= dims[k] as i64 {
            return;
        }
        t_max[k] += t_delta[k];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    fn grid(n: usize) -> TdiGrid {
        TdiGrid { dims: [n; 3], world_from_voxel: DMat4::IDENTITY }
    }

    /// A straight streamline along x through voxel row (y, z) = (5, 5) counts 1 there and 0 elsewhere; a
    /// streamline passing a voxel twice counts once; two streamlines count 2.
    #[test]
    fn straight_streamlines_count_once_per_voxel() {
        let mut t = Tractogram::new();
        t.push(&[Vec3::new(-0.4, 5.0, 5.0), Vec3::new(9.4, 5.0, 5.0)]);
        let v = track_density(&t, &grid(10)).unwrap();
        let at = |v: &Volume<f32>, x: usize, y: usize, z: usize| v.data[x + 10 * (y + 10 * z)];
        assert_eq!(v.data.iter().sum::<f32>(), 10.0);
        assert!((0..10).all(|x| at(&v, x, 5, 5) == 1.0));
        // There and back through the same row, and a second streamline: 2 per voxel of the row.
        t.push(&[Vec3::new(0.0, 5.0, 5.0), Vec3::new(9.0, 5.0, 5.0), Vec3::new(0.0, 5.1, 5.0)]);
        let v = track_density(&t, &grid(10)).unwrap();
        assert!((0..10).all(|x| at(&v, x, 5, 5) == 2.0), "{:?}", (0..10).map(|x| at(&v, x, 5, 5)).collect::<Vec<_>>());
    }

    /// Oblique segments: the voxels found by the exact walk are those a dense sampling of the segment finds
    /// (random segments; corner touches, of measure zero, excepted by keeping the samples off voxel faces).
    #[test]
    fn the_walk_finds_the_voxels_a_dense_sampling_finds() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
        let d = [12, 9, 7];
        for _ in 0..500 {
            let p = |rng: &mut rand_pcg::Pcg64| {
                DVec3::new(rng.random_range(-2.0..13.0), rng.random_range(-2.0..10.0), rng.random_range(-2.0..8.0))
            };
            let (a, b) = (p(&mut rng), p(&mut rng));
            let mut walked = Vec::new();
            walk(a, b, d, &mut walked);
            let mut sampled: Vec<usize> = (0..=200_000)
                .filter_map(|i| {
                    let q = a + (b - a) * (i as f64 / 200_000.0) + DVec3::splat(0.5);
                    let c = q.floor();
                    let inside = (0..3).all(|k| c[k] >= 0.0 && (c[k] as usize) < d[k]);
                    inside.then(|| c.x as usize + d[0] * (c.y as usize + d[1] * c.z as usize))
                })
                .collect();
            sampled.sort_unstable();
            sampled.dedup();
            let mut w = walked.clone();
            w.sort_unstable();
            w.dedup();
            assert_eq!(w.len(), walked.len(), "the walk visits each voxel once");
            // Every sampled voxel is walked; a walked voxel the samples missed is one the segment only grazes.
            assert!(sampled.iter().all(|v| w.contains(v)), "{a} {b}: sampled {sampled:?} walked {w:?}");
            assert!(w.len() <= sampled.len() + 2, "{a} {b}: sampled {sampled:?} walked {w:?}");
        }
    }

    /// The covering grid holds every point with a voxel to spare, at the asked voxel size; bad sizes and
    /// empty tractograms are errors.
    #[test]
    fn covering_grids_hold_every_point() {
        let mut t = Tractogram::new();
        t.push(&[Vec3::new(-10.3, 4.0, 7.0), Vec3::new(20.0, -3.0, 9.5)]);
        let g = TdiGrid::covering(&t, 2.0).unwrap();
        let inv = g.world_from_voxel.inverse();
        for p in &t.points {
            let v = inv.transform_point3(p.as_dvec3());
            assert!((0..3).all(|k| v[k] >= 0.5 && v[k] <= g.dims[k] as f64 - 1.5), "{v} in {:?}", g.dims);
        }
        let v = track_density(&t, &g).unwrap();
        assert!(v.data.iter().all(|c| *c <= 1.0) && v.data.iter().sum::<f32>() >= 16.0);
        assert!(TdiGrid::covering(&t, 0.0).is_err());
        assert!(TdiGrid::covering(&Tractogram::new(), 1.0).is_err());
    }
}
