//! Dense image volumes in NIfTI storage order (x fastest), with the affine that places them in the world.

use glam::{DMat4, DVec3};

/// Voxels per parallel work item of the voxel-wise fits (tensors, SH, peaks), and per progress report.
pub const PROGRESS_BLOCK: usize = 256;

/// A scalar type a volume can hold after decoding: the on-disk type is converted (and scaled by
/// `scl_slope`/`scl_inter`) into this one.
pub trait Scalar: Copy + Send + Sync + Default + PartialOrd + std::fmt::Debug + 'static {
    /// Converts from `f64` (to the nearest representable value for `f32`).
    fn from_f64(v: f64) -> Self;
    /// Converts to `f64` exactly.
    fn to_f64(self) -> f64;
}
impl Scalar for f32 {
    fn from_f64(v: f64) -> Self {
        v as f32
    }
    fn to_f64(self) -> f64 {
        self as f64
    }
}
impl Scalar for f64 {
    fn from_f64(v: f64) -> Self {
        v
    }
    fn to_f64(self) -> f64 {
        self
    }
}

/// An N-dimensional volume (N = 1..7). `data[x + nx*(y + ny*(z + nz*t))]`; `world_from_voxel` maps voxel
/// indices (integer = voxel centre) to RAS+ millimetres.
#[derive(Clone, Debug)]
pub struct Volume<T = f32> {
    /// Size along each of the 1 to 7 axes: x, y, z, then any further axes (volumes, components).
    pub shape: Vec<usize>,
    /// The values, x fastest (NIfTI order); `shape.iter().product()` long.
    pub data: Vec<T>,
    /// Voxel indices (integer = voxel centre) to world RAS+ mm.
    pub world_from_voxel: DMat4,
}

impl<T: Scalar> Volume<T> {
    /// A volume of zeros. Fails if `shape` is empty or longer than 7.
    pub fn zeros(shape: &[usize], world_from_voxel: DMat4) -> Self {
        let n = shape.iter().product();
        Self { shape: shape.to_vec(), data: vec![T::default(); n], world_from_voxel }
    }

    /// Number of spatial voxels (product of the first three dimensions, 1 where absent).
    pub fn n_voxels(&self) -> usize {
        self.dims3().iter().product()
    }

    /// The three spatial dimensions (1 where the volume has fewer).
    pub fn dims3(&self) -> [usize; 3] {
        [0, 1, 2].map(|i| self.shape.get(i).copied().unwrap_or(1))
    }

    /// Length of everything past the spatial dimensions (the "4th dimension" folded): 1 for a 3D volume.
    pub fn n_channels(&self) -> usize {
        self.shape.iter().skip(3).product()
    }

    /// The axial slab of `n` slices from slice `z0` (all channels), its affine moved so each voxel keeps its
    /// world position. Slices past the end are left out.
    pub fn z_slab(&self, z0: usize, n: usize) -> Self {
        let d = self.dims3();
        let z0 = z0.min(d[2]);
        let n = n.min(d[2] - z0);
        let mut shape = self.shape.clone();
        if shape.len() < 3 {
            shape.resize(3, 1);
        }
        shape[2] = n;
        let plane = d[0] * d[1];
        let mut data = Vec::with_capacity(plane * n * self.n_channels());
        for c in 0..self.n_channels() {
            let start = self.n_voxels() * c + plane * z0;
            data.extend_from_slice(&self.data[start..start + plane * n]);
        }
        let world_from_voxel = self.world_from_voxel * DMat4::from_translation(DVec3::new(0.0, 0.0, z0 as f64));
        Self { shape, data, world_from_voxel }
    }

    /// Value at spatial voxel index `v` (flat) and channel `c`.
    #[inline]
    pub fn at(&self, v: usize, c: usize) -> T {
        self.data[v + self.n_voxels() * c]
    }

    /// Copies the values of spatial voxel `v` across all channels (a DWI's signal) into `out` as f64.
    #[inline]
    pub fn voxel_signal(&self, v: usize, out: &mut [f64]) {
        let n = self.n_voxels();
        for (c, s) in out.iter_mut().enumerate() {
            *s = self.data[v + n * c].to_f64();
        }
    }

    /// Voxel edge lengths in mm, from the columns of the affine.
    pub fn voxel_size(&self) -> DVec3 {
        voxel_size(self.world_from_voxel)
    }

    /// Converts the element type.
    pub fn cast<U: Scalar>(&self) -> Volume<U> {
        Volume {
            shape: self.shape.clone(),
            data: self.data.iter().map(|v| U::from_f64(v.to_f64())).collect(),
            world_from_voxel: self.world_from_voxel,
        }
    }
}

/// Voxel edge lengths in mm of a voxel-to-world affine: the lengths of its first three columns.
pub fn voxel_size(world_from_voxel: glam::DMat4) -> DVec3 {
    let m = world_from_voxel;
    DVec3::new(m.x_axis.truncate().length(), m.y_axis.truncate().length(), m.z_axis.truncate().length())
}

/// Flat index of voxel (x, y, z) in a volume of spatial size `dims`.
#[inline]
pub fn flat_index(dims: [usize; 3], x: usize, y: usize, z: usize) -> usize {
    x + dims[0] * (y + dims[1] * z)
}

#[cfg(test)]
mod tests {
    use glam::{DMat4, DVec3};

    #[test]
    fn a_z_slab_keeps_values_and_world_positions() {
        let aff = DMat4::from_translation(DVec3::new(5.0, -3.0, 2.0)) * DMat4::from_scale(DVec3::new(2.0, 2.0, 3.0));
        let mut v = super::Volume::<f32>::zeros(&[3, 2, 6, 2], aff);
        v.data.iter_mut().enumerate().for_each(|(i, x)| *x = i as f32);
        let s = v.z_slab(2, 3);
        assert_eq!(s.shape, vec![3, 2, 3, 2]);
        for c in 0..2 {
            for z in 0..3 {
                for i in 0..6 {
                    assert_eq!(s.at(i + 6 * z, c), v.at(i + 6 * (z + 2), c));
                }
            }
        }
        let p = DVec3::new(1.0, 1.0, 0.0);
        assert_eq!(s.world_from_voxel.transform_point3(p), aff.transform_point3(p + DVec3::Z * 2.0));
        assert_eq!(v.z_slab(5, 4).shape[2], 1);
    }
}
