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
    /// The FA map.
    pub fn fa(&self) -> Volume<f32> {
        let mut v = Volume::zeros(&self.dims, self.world_from_voxel);
        for (o, t) in v.data.iter_mut().zip(&self.tensors) {
            *o = crate::dti::eigh(t).map_or(0.0, |e| metrics::fa(&e.values) as f32);
        }
        v
    }
}
