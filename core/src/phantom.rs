//! A deterministic synthetic tensor field: the ring + crossing bundle of `data/phantom` (a ring around the
//! volume's z axis crossing a straight bundle along z, isotropic background), built from the tensor model
//! without noise, so the viewer and `fascicle render` need no files.

use glam::{DMat4, DVec3, DVec4};

use crate::dti::eigen::{Eigen, LowerTri, from_eigen};
use crate::dti::metrics;
use crate::volume::Volume;

/// Fibre eigenvalues (mm²/s) and the isotropic background diffusivity.
pub const FIBRE_EVALS: [f64; 3] = [1.7e-3, 0.3e-3, 0.3e-3];
pub const BACKGROUND_MD: f64 = 0.8e-3;

/// The phantom's tensors and the true fibre directions per voxel (voxel axes).
pub struct Phantom {
    pub dims: [usize; 3],
    pub world_from_voxel: DMat4,
    pub tensors: Vec<LowerTri>,
    pub fibres: Vec<Vec<DVec3>>,
}

fn fibre_tensor(dir: DVec3) -> LowerTri {
    let e1 = dir.normalize();
    let e2 = e1.any_orthonormal_vector();
    from_eigen(&Eigen { values: FIBRE_EVALS, vectors: [e1, e2, e1.cross(e2)] })
}

/// The ring/cross phantom on a `dims` grid of 2 mm voxels (the shared data uses 48x48x24).
pub fn ring_cross(dims: [usize; 3]) -> Phantom {
    let (cx, cy) = ((dims[0] as f64 - 1.0) / 2.0, (dims[1] as f64 - 1.0) / 2.0);
    let scale = dims[0].min(dims[1]) as f64 / 48.0;
    let (r_in, r_out) = (10.0 * scale, 18.0 * scale);
    let (z_lo, z_hi) = ((4.0 * dims[2] as f64 / 24.0).round(), (19.0 * dims[2] as f64 / 24.0).round());
    let n = dims.iter().product();
    let mut tensors = Vec::with_capacity(n);
    let mut fibres = Vec::with_capacity(n);
    for z in 0..dims[2] {
        for y in 0..dims[1] {
            for x in 0..dims[0] {
                let (dx, dy) = (x as f64 - cx, y as f64 - cy);
                let r = (dx * dx + dy * dy).sqrt();
                let zf = z as f64;
                let mut dirs = Vec::new();
                if r >= r_in && r <= r_out && zf >= z_lo && zf <= z_hi {
                    dirs.push(DVec3::new(-dy, dx, 0.0).normalize());
                }
                if (dx - 14.0 * scale).abs() <= 3.0 * scale && dy.abs() <= 3.0 * scale {
                    dirs.push(DVec3::Z);
                }
                let t = if dirs.is_empty() {
                    [BACKGROUND_MD, 0.0, BACKGROUND_MD, 0.0, 0.0, BACKGROUND_MD]
                } else {
                    let mut acc = [0.0; 6];
                    for d in &dirs {
                        for (a, b) in acc.iter_mut().zip(fibre_tensor(*d)) {
                            *a += b / dirs.len() as f64;
                        }
                    }
                    acc
                };
                tensors.push(t);
                fibres.push(dirs);
            }
        }
    }
    let world_from_voxel = DMat4::from_cols(
        DVec4::new(2.0, 0.0, 0.0, 0.0),
        DVec4::new(0.0, 2.0, 0.0, 0.0),
        DVec4::new(0.0, 0.0, 2.0, 0.0),
        DVec4::new(-(dims[0] as f64 - 1.0), -(dims[1] as f64 - 1.0), -(dims[2] as f64 - 1.0), 1.0),
    );
    Phantom { dims, world_from_voxel, tensors, fibres }
}

impl Phantom {
    /// A noiseless DWI of the phantom: `S0 = 100`, one b0 then `n_dirs` Fibonacci directions at `b`
    /// (s/mm²). Each fibre of a voxel is an equal compartment with [`FIBRE_EVALS`] (a multi-tensor signal,
    /// so crossings show two ODF lobes); the background is isotropic with [`BACKGROUND_MD`]. For ODF glyphs
    /// in scenes that need no files.
    pub fn dwi(&self, n_dirs: usize, b: f64) -> crate::Result<(Volume<f32>, crate::io::GradientTable)> {
        let dirs = crate::sh::sphere::fibonacci(n_dirs);
        let mut bvals = vec![0.0];
        let mut bvecs = vec![glam::DVec3::ZERO];
        bvals.extend(std::iter::repeat_n(b, dirs.len()));
        bvecs.extend(dirs.iter().copied());
        let gtab = crate::io::GradientTable::new(bvals, bvecs, crate::io::gradients::DEFAULT_B0_THRESHOLD)?;
        let n = self.tensors.len();
        let mut vol = Volume::zeros(&[self.dims[0], self.dims[1], self.dims[2], gtab.len()], self.world_from_voxel);
        let compartments: Vec<Vec<LowerTri>> =
            self.fibres.iter().map(|f| f.iter().map(|d| fibre_tensor(*d)).collect()).collect();
        for v in 0..n {
            for (k, (bk, g)) in gtab.bvals.iter().zip(&gtab.bvecs).enumerate() {
                let adc = |t: &LowerTri| {
                    t[0] * g.x * g.x
                        + t[2] * g.y * g.y
                        + t[5] * g.z * g.z
                        + 2.0 * (t[1] * g.x * g.y + t[3] * g.x * g.z + t[4] * g.y * g.z)
                };
                let s = if compartments[v].is_empty() {
                    (-bk * BACKGROUND_MD).exp()
                } else {
                    compartments[v].iter().map(|t| (-bk * adc(t)).exp()).sum::<f64>() / compartments[v].len() as f64
                };
                vol.data[v + n * k] = (100.0 * s) as f32;
            }
        }
        Ok((vol, gtab))
    }

    /// The FA map.
    pub fn fa(&self) -> Volume<f32> {
        let mut v = Volume::zeros(&self.dims, self.world_from_voxel);
        for (o, t) in v.data.iter_mut().zip(&self.tensors) {
            *o = crate::dti::eigh(t).map_or(0.0, |e| metrics::fa(&e.values) as f32);
        }
        v
    }
}
