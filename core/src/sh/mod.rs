//! Real, symmetric (even-order) spherical harmonics in the four conventions of DIPY and MRtrix, their
//! analytic gradient, conversions between conventions, the Cauchy-Schwarz bound on |ψ|, spheres, and the
//! CSA / Q-ball ODF fits.
//!
//! Coefficient order, every basis: even l = 0, 2, 4, ...; m = -l..l; index `j = l(l+1)/2 + m`.

pub mod basis;
pub mod exact;
pub mod fit;
pub mod frame;
pub mod glyph;
pub mod legendre;
pub mod peaks;
pub mod sphere;

pub use basis::{ShBasis, bound_rmax, convert, eval, eval_with_gradient, sh_matrix};
pub use fit::{OdfKind, OdfModel, fit_odf_coefficients, fit_odf_volume, fit_odf_volume_with_progress};
pub use frame::{Frame, convert_image, reorientation, world_from_voxel_axes};
pub use peaks::{PeakParams, PeakVolume, ShGrid, Sphere, peak_directions, peaks_from_sh};

/// Number of coefficients of an even-order basis up to `l_max` (15 at 4, 45 at 8, 153 at 16).
pub const fn n_coeffs(l_max: usize) -> usize {
    (l_max + 1) * (l_max + 2) / 2
}

/// The header description recording an SH image's basis: `fascicle SH descoteaux07 legacy lmax 6`.
pub fn sh_descrip(basis: ShBasis, l_max: usize) -> String {
    format!("fascicle SH {} lmax {l_max}", basis.name())
}

/// The basis an SH image's header records ([`sh_descrip`]), if any.
pub fn recorded_basis(descrip: &str) -> Option<ShBasis> {
    let rest = descrip.strip_prefix("fascicle SH ")?;
    let name = rest.split(" lmax").next()?;
    let legacy = name.ends_with(" legacy");
    ShBasis::parse(name.trim_end_matches(" legacy"), legacy).ok()
}

/// The even `l_max` whose basis has exactly `n` coefficients, if any.
pub fn l_max_for(n: usize) -> Option<usize> {
    (0..=64).step_by(2).find(|&l| n_coeffs(l) == n)
}

/// `(l, m)` of coefficient `j`.
pub fn lm_of(j: usize) -> (usize, i64) {
    let mut l = 0;
    while n_coeffs(l) <= j {
        l += 2;
    }
    (l, j as i64 - (l * (l + 1) / 2) as i64)
}
