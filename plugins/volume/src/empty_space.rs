//! Empty-space skipping for the ray caster: the volume is divided into cells of [`CELL`] voxels a side, and
//! a cell is empty for a transfer function when no sample the ray caster can take inside it gathers colour or
//! opacity. A ray in an empty cell steps over the whole steps whose samples (and, pre-integrated, whose
//! segments) all lie inside it, without sampling the volume (`empty_steps` in `shaders/volume.wgsl`).
//!
//! Skipping changes no pixel: a skipped sample would have added exactly zero (its classified opacity is 0,
//! so its premultiplied colour is 0 and `acc + (1 - acc.a) * 0` is `acc`), and the samples after a skip are
//! taken at the same positions (the step is added as many times as before). What it saves is the sampling:
//! the default scene's FA context is transparent below FA 0.15, which is most of its box.
//!
//! - [`cell_value_ranges`]: per cell, the least and greatest value trilinear sampling can give at a point the
//!   shader files under that cell (computed once per volume).
//! - [`occupancy`]: per cell, 1 where a ray may gather something, 0 where it cannot (computed whenever the
//!   transfer function's tables are written: the function, its range or the step changed).

use fascicle_core::Volume;
use fascicle_core::dvr::Lut;
use glam::DVec4;

/// Edge of an empty-space cell, voxels.
pub const CELL: usize = 4;

/// Cells per voxel axis over a `dims` volume ([`CELL`] voxels each; the last of an axis may be partial).
pub fn grid(dims: [usize; 3]) -> [u32; 3] {
    dims.map(|d| d.max(1).div_ceil(CELL) as u32)
}

/// The voxels of an axis of `n` voxels that samples filed under cell `c` can read: the shader files a sample
/// at voxel coordinate `p` (clamped to `0..=n - 1`) under cell `floor(p / CELL)`, and trilinear sampling there
/// reads voxels `floor(p)` and `floor(p) + 1`; a sample on the cell's upper face reads one voxel more.
fn voxels_of(c: usize, n: usize) -> std::ops::RangeInclusive<usize> {
    (c * CELL).min(n - 1)..=((c + 1) * CELL + 1).min(n - 1)
}

fn merge(a: &mut [f32; 2], b: [f32; 2]) {
    a[0] = a[0].min(b[0]);
    a[1] = a[1].max(b[1]);
}

/// Per cell ([`grid`], x fastest), `[least, greatest]` of the values trilinear sampling can give at a point
/// filed under that cell: the extremes of the voxels it reads (non-finite values as 0, as the texture holds
/// them). Separable: rows, then columns, then planes; about three reads per voxel.
pub fn cell_value_ranges(vol: &Volume<f32>) -> Vec<[f32; 2]> {
    let d = vol.dims3();
    let g = grid(d).map(|n| n as usize);
    let empty = [f32::INFINITY, f32::NEG_INFINITY];
    let value = |v: f32| if v.is_finite() { v } else { 0.0 };
    // Along x: per (cell x, y, z).
    let mut rows = vec![empty; g[0] * d[1] * d[2]];
    for (r, row) in vol.data[..d[0] * d[1] * d[2]].chunks_exact(d[0]).enumerate() {
        for cx in 0..g[0] {
            let out = &mut rows[r * g[0] + cx];
            for x in voxels_of(cx, d[0]) {
                let v = value(row[x]);
                merge(out, [v, v]);
            }
        }
    }
    // Along y: per (cell x, cell y, z).
    let mut columns = vec![empty; g[0] * g[1] * d[2]];
    for z in 0..d[2] {
        for cy in 0..g[1] {
            for y in voxels_of(cy, d[1]) {
                for cx in 0..g[0] {
                    merge(&mut columns[(z * g[1] + cy) * g[0] + cx], rows[(z * d[1] + y) * g[0] + cx]);
                }
            }
        }
    }
    // Along z.
    let mut cells = vec![empty; g[0] * g[1] * g[2]];
    for cz in 0..g[2] {
        for z in voxels_of(cz, d[2]) {
            for cy in 0..g[1] {
                for cx in 0..g[0] {
                    merge(&mut cells[(cz * g[1] + cy) * g[0] + cx], columns[(z * g[1] + cy) * g[0] + cx]);
                }
            }
        }
    }
    cells
}

/// Prefix counts of a predicate over `0..n`: `at(i)` is how many of `0..i` hold.
fn prefix(n: usize, holds: impl Fn(usize) -> bool) -> Vec<u32> {
    let mut out = Vec::with_capacity(n + 1);
    out.push(0);
    for i in 0..n {
        out.push(out[i] + u32::from(holds(i)));
    }
    out
}

/// The entries of a table of `n` over normalised positions `[u_lo, u_hi]` that the shader's lookup may read
/// (`floor(u (n - 1))` and the next), one more each side against the rounding of f32 against f64.
fn entries(u_lo: f64, u_hi: f64, n: usize) -> (usize, usize) {
    let top = (n - 1) as f64;
    let lo = ((u_lo * top).floor() as usize).saturating_sub(1);
    let hi = ((u_hi * top).floor() as usize + 2).min(n - 1);
    (lo.min(hi), hi)
}

/// Per cell, 1 where a ray may gather colour or opacity inside it, 0 where it cannot: every entry of the
/// transfer function's lookup table that a post-classified sample of the cell's values may read has zero
/// opacity, and every entry of the pre-integration table (`table_n` x `table_n`, front value major) that a
/// segment between two such values may read is zero. One occupancy serves both classifications.
pub fn occupancy(ranges: &[[f32; 2]], lut: &Lut, table: &[DVec4], table_n: usize) -> Vec<u32> {
    let n = lut.entries.len();
    let lut_opaque = prefix(n, |i| lut.entries[i][3] != 0.0);
    // Rows of the pre-integration table: prefix counts of non-zero entries along each row.
    let rows: Vec<Vec<u32>> =
        (0..table_n).map(|i| prefix(table_n, |j| table[i * table_n + j] != DVec4::ZERO)).collect();
    ranges
        .iter()
        .map(|&[lo, hi]| {
            let (u_lo, u_hi) = (lut.u(f64::from(lo)), lut.u(f64::from(hi)));
            let (a, b) = entries(u_lo, u_hi, n);
            if lut_opaque[b + 1] - lut_opaque[a] > 0 {
                return 1;
            }
            let (a, b) = entries(u_lo, u_hi, table_n);
            u32::from(rows[a..=b].iter().any(|row| row[b + 1] - row[a] > 0))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use fascicle_core::dvr::{TfPoint, TransferFunction, preintegrate, sample};
    use glam::{DMat4, DVec3};

    fn volume() -> Volume<f32> {
        let dims = [19usize, 13, 10];
        let mut v = Volume::zeros(&dims, DMat4::IDENTITY);
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    let p = DVec3::new(x as f64 - 12.0, y as f64 - 5.0, z as f64 - 4.0);
                    v.data[x + dims[0] * (y + dims[1] * z)] = (-(p.length_squared() / 18.0)).exp() as f32;
                }
            }
        }
        v.data[3] = f32::NAN;
        v
    }

    fn tf() -> TransferFunction {
        TransferFunction {
            range: [0.0, 1.0],
            points: vec![
                TfPoint { x: 0.0, rgba: [0.2, 0.2, 0.2, 0.0] },
                TfPoint { x: 0.3, rgba: [0.3, 0.3, 0.9, 0.0] },
                TfPoint { x: 0.6, rgba: [0.9, 0.5, 0.1, 0.2] },
                TfPoint { x: 1.0, rgba: [1.0, 1.0, 1.0, 0.5] },
            ],
        }
    }

    /// The ranges hold every value trilinear sampling gives anywhere a sample is filed under the cell
    /// (including outside the volume, where samples clamp to its edge), and are the voxels' own extremes.
    #[test]
    fn cell_ranges_hold_every_sample_filed_under_the_cell() {
        let vol = volume();
        let d = vol.dims3();
        let g = grid(d).map(|n| n as usize);
        let ranges = cell_value_ranges(&vol);
        assert_eq!(ranges.len(), g[0] * g[1] * g[2]);
        let mut clean = vol.clone();
        clean.data.iter_mut().filter(|v| !v.is_finite()).for_each(|v| *v = 0.0);
        let mut checked = 0;
        for k in 0..20_000u32 {
            // A quasi-random point over the volume's box and half a voxel beyond it.
            let f = |a: f64| (f64::from(k) * a).fract() * 1.2 - 0.1;
            let p =
                DVec3::new(f(0.7548776662) * d[0] as f64, f(0.5698402910) * d[1] as f64, f(0.3141592653) * d[2] as f64);
            let q = p.clamp(DVec3::ZERO, DVec3::new(d[0] as f64 - 1.0, d[1] as f64 - 1.0, d[2] as f64 - 1.0));
            let c = [0, 1, 2].map(|i| ((q[i] / CELL as f64).floor() as usize).min(g[i] - 1));
            let [lo, hi] = ranges[(c[2] * g[1] + c[1]) * g[0] + c[0]];
            let v = sample(&clean, p);
            assert!(
                f64::from(lo) <= v + 1e-6 && v <= f64::from(hi) + 1e-6,
                "{p} in cell {c:?}: {v} not in [{lo}, {hi}]"
            );
            checked += 1;
        }
        assert_eq!(checked, 20_000);
        // Cell (0, 0, 0) reads voxels 0..=5 of each axis: its extremes are theirs (the NaN read as 0).
        let mut want = [f32::INFINITY, f32::NEG_INFINITY];
        for z in 0..=5 {
            for y in 0..=5 {
                for x in 0..=5 {
                    let v = clean.data[x + d[0] * (y + d[1] * z)];
                    merge(&mut want, [v, v]);
                }
            }
        }
        assert_eq!(ranges[0], want);
    }

    /// An empty cell is one where the transfer function gives no opacity to any value sampling can find in it
    /// (post-classified) nor to any segment between two of them (pre-integrated): checked against the f64
    /// lookup and table over each empty cell's values. The bright centre's cell is occupied.
    #[test]
    fn empty_cells_gather_nothing_and_occupied_ones_are_kept() {
        let vol = volume();
        let d = vol.dims3();
        let g = grid(d).map(|n| n as usize);
        let lut = tf().lut();
        let n = 16;
        let table = preintegrate(&lut, n, 0.5, 16);
        let occ = occupancy(&cell_value_ranges(&vol), &lut, &table, n);
        let empty = occ.iter().filter(|o| **o == 0).count();
        assert!(empty > 0 && empty < occ.len(), "{empty} of {} cells empty", occ.len());
        let ranges = cell_value_ranges(&vol);
        for (i, o) in occ.iter().enumerate() {
            if *o == 0 {
                let [lo, hi] = ranges[i];
                let (u_lo, u_hi) = (lut.u(f64::from(lo)), lut.u(f64::from(hi)));
                for s in 0..=32 {
                    let v = f64::from(lo) + (f64::from(hi) - f64::from(lo)) * f64::from(s) / 32.0;
                    assert_eq!(lut.eval(v).w, 0.0, "cell {i}: value {v}");
                }
                let at = |u: f64| ((u * (n - 1) as f64).floor() as usize).min(n - 2);
                for a in at(u_lo)..=at(u_hi) + 1 {
                    for b in at(u_lo)..=at(u_hi) + 1 {
                        assert_eq!(table[a * n + b], DVec4::ZERO, "cell {i}: table ({a}, {b})");
                    }
                }
            }
        }
        // A cell over the bright centre is occupied; a corner far from it is empty.
        let at = |x: usize, y: usize, z: usize| occ[(z / CELL * g[1] + y / CELL) * g[0] + x / CELL];
        assert_eq!(at(12, 5, 4), 1);
        assert_eq!(at(0, 12, 9), 0);
    }
}
