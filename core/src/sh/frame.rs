//! The frame SH coefficients are written in, and turning them into another.
//!
//! DIPY fits its ODFs to b-vectors given along the image's voxel axes, so its coefficients (the descoteaux07
//! bases) describe directions in voxel axes. MRtrix3 defines its coefficients (the tournier07 bases) in scanner
//! (world) axes. The two agree only where the affine's rotation is the identity; on a flipped or oblique
//! image, reading one as the other mirrors or tilts every ODF. [`reorientation`] gives the linear map of the
//! coefficients under an orthogonal change of axes (a rotation, a reflection or both): every band maps onto
//! itself, so the map is exact.

use glam::{DMat3, DMat4, DVec3};
use rayon::prelude::*;

use super::{ShBasis, n_coeffs, sh_matrix, sphere};
use crate::Volume;
use crate::error::{Error, Result};

/// The axes a set of SH coefficients refers to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Frame {
    /// The image's voxel axes (DIPY).
    Voxel,
    /// Scanner (world, RAS+) axes (MRtrix3).
    World,
}

impl ShBasis {
    /// The frame of coefficients in this basis as their programs write them: descoteaux07 (DIPY) in voxel
    /// axes, tournier07 (MRtrix3) in world axes.
    pub fn frame(&self) -> Frame {
        match self {
            ShBasis::Descoteaux07 { .. } => Frame::Voxel,
            ShBasis::Tournier07 { .. } => Frame::World,
        }
    }
}

/// The orthogonal part of an affine's 3x3 block (polar decomposition): maps voxel-axis directions to world
/// directions, a reflection where the affine flips handedness.
pub fn world_from_voxel_axes(affine: DMat4) -> DMat3 {
    crate::linalg::polar_rotation(DMat3::from_mat4(affine))
}

/// The row-major `k x k` matrix `T` (`k` = coefficients of order `l_max`) with which `T c` (in `basis`)
/// describes the ODF of `c` carried by the orthogonal map `m`: `ψ'(m u) = ψ(u)` for every unit `u`.
/// Fitted by least squares on a sphere of `4k + 64` directions, where it is exact up to rounding (the rotated
/// functions lie in the same bands).
pub fn reorientation(basis: ShBasis, l_max: usize, m: DMat3) -> Result<Vec<f64>> {
    let orthogonal = (m * m.transpose()).abs_diff_eq(DMat3::IDENTITY, 1e-9);
    if !m.is_finite() || !orthogonal {
        return Err(Error::Param(format!("SH reorientation needs an orthogonal matrix, not {m:?}")));
    }
    let k = n_coeffs(l_max);
    let dirs = sphere::fibonacci(4 * k + 64);
    // ψ'(u) = ψ(mᵀ u): sampled at u, in the basis at u.
    let turned: Vec<DVec3> = dirs.iter().map(|u| m.transpose() * *u).collect();
    let a = sh_matrix(basis, l_max, &dirs);
    let b = sh_matrix(basis, l_max, &turned);
    let a_pinv = crate::linalg::pinv(&a, dirs.len(), k);
    let n = dirs.len();
    let mut t = vec![0.0; k * k];
    for i in 0..k {
        for j in 0..k {
            t[i * k + j] = (0..n).map(|r| a_pinv[i * n + r] * b[r * k + j]).sum();
        }
    }
    Ok(t)
}

/// [`reorientation`] for `m`, or None when `m` is the identity (nothing to turn).
pub fn turning(basis: ShBasis, l_max: usize, m: DMat3) -> Result<Option<Vec<f64>>> {
    if m.abs_diff_eq(DMat3::IDENTITY, 1e-12) {
        return Ok(None);
    }
    reorientation(basis, l_max, m).map(Some)
}

/// The reorientation taking coefficients in `basis` (of order `l_max`, on an image with `affine`) into world
/// axes, or None when they are in world axes already (MRtrix3's basis, or an affine without rotation or
/// reflection). What the glyphs of a voxel-axis field need before they are placed in the world.
pub fn to_world_axes(basis: ShBasis, l_max: usize, affine: DMat4) -> Result<Option<Vec<f64>>> {
    if basis.frame() == Frame::World {
        return Ok(None);
    }
    turning(basis, l_max, world_from_voxel_axes(affine))
}

/// `t c` for a row-major `k x k` matrix `t` and `k` coefficients `c`.
pub fn apply(t: &[f64], c: &[f64]) -> Vec<f64> {
    let k = c.len();
    (0..k).map(|i| (0..k).map(|j| t[i * k + j] * c[j]).sum()).collect()
}

/// Applies `t` (from [`reorientation`]) to every voxel of an (X,Y,Z,k) coefficient image.
pub fn reorient_volume(vol: &mut Volume<f32>, t: &[f64]) -> Result<()> {
    let (n, k) = (vol.n_voxels(), vol.n_channels());
    if t.len() != k * k {
        return Err(Error::Shape(format!("a {k}-coefficient image cannot take a {}-entry reorientation", t.len())));
    }
    let old = vol.data.clone();
    // Channel-major storage: gather a voxel's coefficients, turn them, scatter them back, per block of voxels.
    let out: Vec<Vec<f32>> = (0..n)
        .into_par_iter()
        .map(|v| {
            let c: Vec<f64> = (0..k).map(|j| old[v + n * j] as f64).collect();
            apply(t, &c).into_iter().map(|x| x as f32).collect()
        })
        .collect();
    for (v, c) in out.into_iter().enumerate() {
        for (j, x) in c.into_iter().enumerate() {
            vol.data[v + n * j] = x;
        }
    }
    Ok(())
}

/// An SH image in `from` (in that basis's [`Frame`]) rewritten in `to` (in its frame), through the image's
/// affine: the basis is converted and, where the frames differ, the coefficients turned between voxel and
/// world axes.
pub fn convert_image(vol: &Volume<f32>, from: ShBasis, to: ShBasis) -> Result<Volume<f32>> {
    let k = vol.n_channels();
    let l_max = super::l_max_for(k)
        .ok_or_else(|| Error::Shape(format!("{k} volumes is not an SH coefficient count (1, 6, 15, 28, 45, ...)")))?;
    let mut out = vol.clone();
    let n = vol.n_voxels();
    if from != to {
        for v in 0..n {
            let c: Vec<f64> = (0..k).map(|j| vol.data[v + n * j] as f64).collect();
            for (j, x) in super::convert(&c, from, to).into_iter().enumerate() {
                out.data[v + n * j] = x as f32;
            }
        }
    }
    let m = world_from_voxel_axes(vol.world_from_voxel);
    let turn = match (from.frame(), to.frame()) {
        (Frame::Voxel, Frame::World) => Some(m),
        (Frame::World, Frame::Voxel) => Some(m.transpose()),
        _ => None,
    };
    if let Some(t) = turn.map(|m| turning(to, l_max, m)).transpose()?.flatten() {
        reorient_volume(&mut out, &t)?;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sh::eval;

    /// A rotation (by 0.7 rad about an oblique axis) composed with a reflection.
    fn improper() -> DMat3 {
        let r = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, -0.5).normalize(), 0.7);
        r * DMat3::from_diagonal(DVec3::new(-1.0, 1.0, 1.0))
    }

    /// The turned coefficients take at `m u` the value the originals take at `u`, in every basis, for orders 2
    /// to 12, for a proper and an improper map; the identity maps to the identity.
    #[test]
    fn turned_coefficients_carry_the_function() {
        let dirs = sphere::fibonacci(97);
        for basis in ShBasis::ALL {
            for l_max in [2, 4, 8, 12] {
                let k = n_coeffs(l_max);
                let c: Vec<f64> = (0..k).map(|j| ((j * 37 % 11) as f64 - 5.0) / (1.0 + j as f64)).collect();
                for m in [DMat3::from_rotation_z(1.1), improper()] {
                    let t = reorientation(basis, l_max, m).unwrap();
                    let turned: Vec<f64> = (0..k).map(|i| (0..k).map(|j| t[i * k + j] * c[j]).sum()).collect();
                    for u in &dirs {
                        let (a, b) = (eval(basis, &turned, m * *u).unwrap(), eval(basis, &c, *u).unwrap());
                        assert!((a - b).abs() < 1e-10, "{basis:?} l{l_max}: {a} vs {b}");
                    }
                }
                let id = reorientation(basis, l_max, DMat3::IDENTITY).unwrap();
                for i in 0..k {
                    for j in 0..k {
                        assert!((id[i * k + j] - f64::from(u8::from(i == j))).abs() < 1e-10);
                    }
                }
            }
        }
        assert!(reorientation(ShBasis::default(), 4, DMat3::from_diagonal(DVec3::splat(2.0))).is_err());
    }

    /// DIPY coefficients on an x-flipped, oblique image, written as MRtrix's: the value at a world direction
    /// equals DIPY's value at the voxel direction that maps onto it; converting back gives the input.
    #[test]
    fn images_convert_between_voxel_and_world_frames() {
        let affine = DMat4::from_mat3_translation(
            DMat3::from_rotation_y(0.3) * DMat3::from_diagonal(DVec3::new(-2.0, 2.0, 2.5)),
            DVec3::new(10.0, -5.0, 3.0),
        );
        let (dims, l_max) = ([3usize, 2, 2], 6);
        let k = n_coeffs(l_max);
        let mut vol = Volume::<f32>::zeros(&[dims[0], dims[1], dims[2], k], affine);
        let n = vol.n_voxels();
        for v in 0..n {
            for j in 0..k {
                vol.data[v + n * j] = if j == 0 { 1.0 } else { (((v + 3) * (j + 1)) % 7) as f32 / 20.0 - 0.15 };
            }
        }
        let (dipy, mrtrix) = (ShBasis::Descoteaux07 { legacy: true }, ShBasis::Tournier07 { legacy: false });
        let world = convert_image(&vol, dipy, mrtrix).unwrap();
        let m = world_from_voxel_axes(affine);
        for v in [0, n - 1] {
            let c = |img: &Volume<f32>| (0..k).map(|j| img.data[v + n * j] as f64).collect::<Vec<f64>>();
            for u in sphere::fibonacci(40) {
                let (w, d) = (eval(mrtrix, &c(&world), m * u).unwrap(), eval(dipy, &c(&vol), u).unwrap());
                assert!((w - d).abs() < 1e-5, "{w} vs {d}");
            }
        }
        let back = convert_image(&world, mrtrix, dipy).unwrap();
        let worst = back.data.iter().zip(&vol.data).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-5, "{worst}");
    }
}
