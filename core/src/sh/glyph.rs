//! SH glyphs: the surface `r = ψ(u)` around a centre, as the GPU ray caster draws it (SEEDS.md §4), with
//! the f64 references its shader is tested against.
//!
//! The shader evaluates one basis only, [`GLYPH_BASIS`] (tournier07, non-legacy: the plain orthonormal real
//! SH), in Cartesian form, with no trigonometry and nothing singular at the poles. With `u = (x, y, z)`
//! unit, `ρ = sin θ`, `P̄_l^m(z) = Q_l^m(z) ρ^m` (normalised, Condon-Shortley phase) and
//! `C_m + i S_m = (x + i y)^m = ρ^m e^{imφ}`:
//!
//! `ψ(u) = Σ_l [ c_l0 Q_l^0 + √2 Σ_{m>0} Q_l^m (c_lm C_m + c_l,-m S_m) ]`.
//!
//! `Q` follows the Legendre recurrence without the `ρ^m` factor (a polynomial in z), `C, S` the complex
//! power. The same polynomial `g(x, y, z)` extends ψ off the sphere, so the surface gradient is
//! `(I - u uᵀ) ∇g`, with `∂C_m/∂x = m C_{m-1}`, `∂C_m/∂y = -m S_{m-1}`, `∂S_m/∂x = m S_{m-1}`,
//! `∂S_m/∂y = m C_{m-1}` and `∂/∂z` from the differentiated recurrence. The implicit surface
//! `F(p) = |p - c| - s(ψ(u))` (s = max(·, 0) or |·|) has normal `∇F = u - s'(ψ) (I - u uᵀ) ∇g / r`.
//!
//! [`cast`] is the shader's ray caster in f64 (linear search with step `h · rmax` from the bounding sphere,
//! then bisection); [`cast_exact`] is the reference (a fine search and bisection to rounding).

use glam::DVec3;

use super::basis::{ShBasis, bound_rmax, convert};
use super::{l_max_for, n_coeffs};
use crate::error::{Error, Result};

/// The basis the glyph shader evaluates; coefficients in any other basis are converted on the CPU (exact).
pub const GLYPH_BASIS: ShBasis = ShBasis::Tournier07 { legacy: false };

/// Largest order the glyph shader supports.
pub const MAX_GLYPH_L: usize = 16;

/// ψ at unit `u` and the Cartesian gradient of its polynomial extension; `c` in [`GLYPH_BASIS`].
/// Mirrors `sh_value` in `plugins/sh_glyphs/src/shaders/sh_glyph.wgsl` term by term.
pub fn eval_cartesian(c: &[f64], l_max: usize, u: DVec3) -> (f64, DVec3) {
    let (x, y, z) = (u.x, u.y, u.z);
    let inv4pi = 1.0 / (4.0 * std::f64::consts::PI);
    let sqrt2 = std::f64::consts::SQRT_2;
    let (mut val, mut grad) = (0.0, DVec3::ZERO);
    // (C_m, S_m) and (C_{m-1}, S_{m-1}).
    let (mut cm, mut sm, mut cm1, mut sm1) = (1.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut prod = 1.0f64; // Π_{k<=m} (2k-1)/(2k)
    for m in 0..=l_max {
        if m > 0 {
            prod *= (2 * m - 1) as f64 / (2 * m) as f64;
            let (c_new, s_new) = (cm * x - sm * y, cm * y + sm * x);
            (cm1, sm1, cm, sm) = (cm, sm, c_new, s_new);
        }
        let sign = if m % 2 == 0 { 1.0 } else { -1.0 };
        let mf = m as f64;
        // Q_{l-2}, Q_{l-1} and their z-derivatives, starting at l = m.
        let (mut q2, mut q1, mut d2, mut d1) = (0.0f64, sign * ((2 * m + 1) as f64 * inv4pi * prod).sqrt(), 0.0, 0.0);
        for l in m..=l_max {
            let lf = l as f64;
            let (q, dq) = if l == m {
                (q1, 0.0)
            } else if l == m + 1 {
                let f = ((2 * m + 3) as f64).sqrt();
                (f * z * q1, f * q1)
            } else {
                let a = ((4.0 * lf * lf - 1.0) / (lf * lf - mf * mf)).sqrt();
                let b = (((lf - 1.0).powi(2) - mf * mf) / (4.0 * (lf - 1.0).powi(2) - 1.0)).sqrt();
                (a * (z * q1 - b * q2), a * (q1 + z * d1 - b * d2))
            };
            if l > m {
                (q2, q1, d2, d1) = (q1, q, d1, dq);
            }
            if l % 2 == 1 {
                continue;
            }
            let base = l * (l + 1) / 2;
            if m == 0 {
                let k = c[base];
                val += k * q;
                grad.z += k * dq;
            } else {
                let (kc, ks) = (sqrt2 * c[base + m], sqrt2 * c[base - m]);
                val += q * (kc * cm + ks * sm);
                grad.x += q * mf * (kc * cm1 + ks * sm1);
                grad.y += q * mf * (-kc * sm1 + ks * cm1);
                grad.z += dq * (kc * cm + ks * sm);
            }
        }
    }
    (val, grad)
}

/// Terms of each Chebyshev series of band `m` in the [`chebyshev_form`] of an even order `l_max`.
pub fn chebyshev_terms(l_max: usize, m: usize) -> usize {
    (l_max - m) / 2 + 1
}

/// The glyph shader's internal form of coefficients `c` (in [`GLYPH_BASIS`], even `l_max`), made once per
/// glyph on upload. ψ(u) = Σ_m Re((x + iy)^m) A_m(z) + Im((x + iy)^m) B_m(z) (the extension of
/// [`eval_cartesian`]); A_m and B_m are polynomials in z of degree `l_max - m` with the parity of m, so
/// `z^(m mod 2) g(w)` with `w = 2z² - 1`, and each `g` is stored as its Chebyshev series in w
/// ([`chebyshev_terms`] coefficients, from its values at the Chebyshev nodes: exact for its degree). Band by
/// band, A then B (B absent for m = 0): [`n_coeffs`]`(l_max)` numbers, as many as the coefficients.
/// Evaluated by Clenshaw's recurrence ([`eval_chebyshev_form`], the shader's `sh_value`): a few operations
/// per coefficient instead of the Legendre recurrence over every (l, m), and well conditioned in f32
/// (a power basis in z loses 4 digits at l_max 12). For many glyphs of one order, build a
/// [`ChebyshevForm`] once.
pub fn chebyshev_form(c: &[f64], l_max: usize) -> Vec<f64> {
    let mut out = Vec::with_capacity(n_coeffs(l_max));
    ChebyshevForm::new(l_max).apply(c, &mut out);
    out
}

/// The [`chebyshev_form`] of order `l_max` as the linear map it is: per band m, one square matrix from the
/// coefficients of the even orders l >= m to the Chebyshev terms (the same for A_m and B_m).
pub struct ChebyshevForm {
    l_max: usize,
    /// Band m's matrix, row-major: row j the Chebyshev term, column i the order `m + m mod 2 + 2i`.
    bands: Vec<Vec<f64>>,
}

impl ChebyshevForm {
    /// The map for even order `l_max`: one square matrix per band `m = 0..=l_max`.
    pub fn new(l_max: usize) -> Self {
        use super::legendre::{legendre_table, tri};
        use std::f64::consts::{PI, SQRT_2};
        let mut p = vec![0.0; tri(l_max, l_max) + 1];
        let mut q = p.clone();
        let bands = (0..=l_max)
            .map(|m| {
                let nt = chebyshev_terms(l_max, m);
                let norm = if m == 0 { 1.0 } else { SQRT_2 };
                let mut k = vec![0.0; nt * nt];
                for node in 0..nt {
                    let w = (PI * (node as f64 + 0.5) / nt as f64).cos();
                    let z = ((w + 1.0) / 2.0).sqrt();
                    // With sin θ set to 1 the table holds the polynomial parts P̄_l^m / sin^m θ.
                    legendre_table(l_max, z, 1.0, &mut p, &mut q);
                    let parity = if m % 2 == 1 { z } else { 1.0 };
                    for i in 0..nt {
                        let g = norm * p[tri(m + m % 2 + 2 * i, m)] / parity;
                        for j in 0..nt {
                            let weight = if j == 0 { 1.0 } else { 2.0 } / nt as f64;
                            k[j * nt + i] += weight * g * (PI * (j * (2 * node + 1)) as f64 / (2 * nt) as f64).cos();
                        }
                    }
                }
                k
            })
            .collect();
        Self { l_max, bands }
    }

    /// Appends the form of `c` (at least [`n_coeffs`]`(l_max)` coefficients) to `out`.
    pub fn apply(&self, c: &[f64], out: &mut Vec<f64>) {
        for (m, k) in self.bands.iter().enumerate() {
            let nt = chebyshev_terms(self.l_max, m);
            let parts: &[bool] = if m == 0 { &[true] } else { &[true, false] };
            for &cosine in parts {
                let coeff = |i: usize| {
                    let l = m + m % 2 + 2 * i;
                    let base = l * (l + 1) / 2;
                    if cosine { c[base + m] } else { c[base - m] }
                };
                out.extend((0..nt).map(|j| (0..nt).map(|i| k[j * nt + i] * coeff(i)).sum::<f64>()));
            }
        }
    }
}

/// `z^odd g(w)` and its derivative in z, `g` the Chebyshev series `c` in `w = 2z² - 1` (Clenshaw; g' as the
/// series Σ j c_j U_{j-1}).
fn chebyshev_series(c: &[f64], z: f64, odd: bool) -> (f64, f64) {
    let w = 2.0 * z * z - 1.0;
    let (mut b1, mut b2) = (0.0, 0.0);
    for j in (1..c.len()).rev() {
        (b1, b2) = (2.0 * w * b1 - b2 + c[j], b1);
    }
    let g = w * b1 - b2 + c[0];
    let (mut d1, mut d2) = (0.0, 0.0);
    for j in (1..c.len()).rev() {
        (d1, d2) = (2.0 * w * d1 - d2 + j as f64 * c[j], d1);
    }
    // dg/dz = g'(w) 4z.
    let dg = d1 * 4.0 * z;
    if odd { (z * g, g + z * dg) } else { (g, dg) }
}

/// ψ at unit `u` and the Cartesian gradient of its extension, from the [`chebyshev_form`] `f`: equal to
/// [`eval_cartesian`] (the same polynomial). Mirrors `sh_value_grad` in
/// `plugins/sh_glyphs/src/shaders/sh_glyph.wgsl` term by term.
pub fn eval_chebyshev_form(f: &[f64], l_max: usize, u: DVec3) -> (f64, DVec3) {
    let (mut val, mut grad) = (0.0, DVec3::ZERO);
    let (mut cm, mut sm, mut cm1, mut sm1) = (1.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut at = 0;
    for m in 0..=l_max {
        if m > 0 {
            let (c_new, s_new) = (cm * u.x - sm * u.y, cm * u.y + sm * u.x);
            (cm1, sm1, cm, sm) = (cm, sm, c_new, s_new);
        }
        let nt = chebyshev_terms(l_max, m);
        let (a, da) = chebyshev_series(&f[at..at + nt], u.z, m % 2 == 1);
        at += nt;
        let (b, db) = if m == 0 {
            (0.0, 0.0)
        } else {
            at += nt;
            chebyshev_series(&f[at - nt..at], u.z, m % 2 == 1)
        };
        let mf = m as f64;
        val += cm * a + sm * b;
        grad.x += mf * (a * cm1 + b * sm1);
        grad.y += mf * (b * cm1 - a * sm1);
        grad.z += cm * da + sm * db;
    }
    (val, grad)
}

/// How negative values of ψ are drawn (CSA and Q-ball ODFs can dip below zero).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Lobes {
    /// `r = max(ψ, 0)`: negative lobes are not drawn (the default).
    #[default]
    Clamp,
    /// `r = |ψ|`: negative lobes drawn too (marked by the renderer), as mrview does.
    Abs,
}

/// How glyph sizes are normalised.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Normalise {
    /// Each glyph scaled so its largest radius bound (rmax) is `scale`: shapes compare, sizes do not.
    #[default]
    PerGlyph,
    /// One factor for all glyphs (the largest rmax is `scale`): sizes compare.
    Global,
    /// Each glyph scaled so its mean radius (`a_00 Y_00`) is `scale` (the seed's "same a_00 for all"): sharper
    /// ODFs reach farther, so the anisotropy (GFA) shows in the size.
    A00,
    /// Each glyph's ψ mapped to `[0, scale]` by its minimum and maximum over the sphere (2,562 directions):
    /// `(ψ - min) / (max - min)`, the min-max normalisation of DIPY/FURY and DSI Studio: the isotropic part
    /// removed, every glyph's largest lobe `scale`.
    MinMax,
}

/// Per-glyph CPU work before upload (SEEDS.md §4).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct GlyphStyle {
    /// Target radius in mm (of each glyph, or of the largest).
    pub scale: f64,
    /// `a_00` is divided by this (>= 1) to weaken the isotropic part.
    pub sharpen: f64,
    /// What each glyph's size is normalised by. Defaults to [`Normalise::PerGlyph`].
    pub normalise: Normalise,
    /// Normalise by each glyph's largest lobe (the sampled bound [`render_bound`]) instead of the looser
    /// Cauchy-Schwarz bound `rmax`, so that the largest lobe reaches `scale`.
    pub fit_lobes: bool,
    /// When set, the layer derives `scale` from its grid: the largest lobe spans this fraction of the spacing
    /// between glyphs (as mrview and FURY size them). `scale` is then ignored.
    pub cell_fill: Option<f64>,
}

impl Default for GlyphStyle {
    fn default() -> Self {
        Self { scale: 1.0, sharpen: 1.0, normalise: Normalise::PerGlyph, fit_lobes: false, cell_fill: None }
    }
}

impl GlyphStyle {
    /// Sized to a grid of `cell_mm` between glyphs: lobes fitted, the largest spanning 90 % of a cell.
    pub fn for_grid(cell_mm: f64) -> Self {
        Self { fit_lobes: true, cell_fill: Some(0.9), ..Self::default() }.resolved(cell_mm)
    }

    /// This style with `scale` set from `cell_fill` for glyphs `cell_mm` apart (unchanged without `cell_fill`).
    pub fn resolved(self, cell_mm: f64) -> Self {
        match self.cell_fill {
            Some(f) if f > 0.0 && cell_mm > 0.0 && cell_mm.is_finite() => Self { scale: 0.5 * f * cell_mm, ..self },
            _ => self,
        }
    }
}

/// A glyph ready for the GPU: centre, coefficients in [`GLYPH_BASIS`], the Cauchy-Schwarz bound
/// `|ψ| <= rmax` (what sizes are normalised by), and the tighter bound `rbound <= rmax` the renderer uses
/// for the proxy and the ray's bounding sphere ([`render_bound`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Glyph {
    /// The glyph's centre, world mm.
    pub centre: DVec3,
    /// The even SH order of `coeffs` (at most [`MAX_GLYPH_L`]).
    pub l_max: usize,
    /// Coefficients in [`GLYPH_BASIS`], sharpened (shifted for [`Normalise::MinMax`]) and scaled so that ψ is
    /// the radius in mm.
    pub coeffs: Vec<f64>,
    /// The Cauchy-Schwarz bound on `|ψ|` of `coeffs` ([`bound_rmax`]), in mm.
    pub rmax: f64,
    /// The sampled bound on `|ψ|` ([`render_bound`], at most `rmax`), in mm: the ray's bounding sphere.
    pub rbound: f64,
    /// Half extents of the glyph's axis-aligned box about its centre ([`glyph_box`], at most
    /// `rbound` per axis): the renderer's proxy.
    pub half: DVec3,
    /// Generalised anisotropy of the ODF before sharpening ([`gfa`]), for colour maps.
    pub gfa: f64,
}

/// GFA of an ODF from its coefficients in an orthonormal basis: the ratio of the standard deviation to the
/// RMS of ψ over the sphere, `sqrt(1 - c00² / Σ c²)` (the continuous form of DIPY's sampled GFA).
pub fn gfa(c: &[f64]) -> f64 {
    let total: f64 = c.iter().map(|v| v * v).sum();
    if total > 0.0 { (1.0 - c[0] * c[0] / total).max(0.0).sqrt() } else { 0.0 }
}

/// Directions of an order-4 icosphere (2,562) and their covering radius (the largest angle from any point
/// of the sphere to the nearest direction), computed once.
pub(crate) fn bound_sample() -> &'static (Vec<DVec3>, f64) {
    static SAMPLE: std::sync::OnceLock<(Vec<DVec3>, f64)> = std::sync::OnceLock::new();
    SAMPLE.get_or_init(|| {
        let (v, f) = icosphere(4);
        // Each face's circumcentre is the point of the face farthest from its vertices.
        let cover = f
            .iter()
            .map(|&[a, b, c]| {
                let (a, b, c) = (v[a as usize], v[b as usize], v[c as usize]);
                let n = (b - a).cross(c - a).normalize();
                a.angle_between(n).max(b.angle_between(n)).max(c.angle_between(n))
            })
            .fold(0.0f64, f64::max);
        (v, cover)
    })
}

/// The basis matrix of [`bound_sample`] at `l_max`, computed once per order.
pub(crate) fn bound_matrix(l_max: usize) -> std::sync::Arc<Vec<f64>> {
    static CACHE: std::sync::Mutex<Vec<(usize, std::sync::Arc<Vec<f64>>)>> = std::sync::Mutex::new(Vec::new());
    let mut cache = CACHE.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, m)) = cache.iter().find(|(l, _)| *l == l_max) {
        return m.clone();
    }
    let m = std::sync::Arc::new(super::sh_matrix(GLYPH_BASIS, l_max, &bound_sample().0));
    cache.push((l_max, m.clone()));
    m
}

/// A bound on `max |ψ|` much tighter than Cauchy-Schwarz for peaked ODFs, and still guaranteed. Let the
/// maximum M of |ψ| be at u*, `m` the largest |ψ| over 2,562 directions of covering radius δ, and s the
/// sample nearest u*. Along the great circle from u* to s, ψ is a trigonometric polynomial of degree L
/// whose derivative vanishes at u*; Bernstein's inequality twice bounds its second derivative by L² M, so
/// `m >= |ψ(s)| >= M (1 - (L δ)² / 2)`, i.e. `M <= m / (1 - (L δ)² / 2)`. Falls back to `rmax` where
/// that is not smaller.
pub fn render_bound(c: &[f64], l_max: usize, rmax: f64) -> f64 {
    render_bound_from(&bound_psi(c, l_max), l_max, rmax)
}

/// [`render_bound`] from ψ at the directions of [`bound_sample`] ([`bound_psi`]).
pub(crate) fn render_bound_from(psi: &[f64], l_max: usize, rmax: f64) -> f64 {
    let (_, delta) = bound_sample();
    let shrink = 1.0 - 0.5 * (l_max as f64 * delta).powi(2);
    if shrink <= 0.05 {
        return rmax;
    }
    let m = psi.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    (m / shrink).min(rmax)
}

/// ψ at the 2,562 directions of [`bound_sample`].
pub(crate) fn bound_psi(c: &[f64], l_max: usize) -> Vec<f64> {
    let n = c.len();
    bound_matrix(l_max)
        .chunks_exact(n)
        .take(bound_sample().0.len())
        .map(|row| row.iter().zip(c).map(|(x, y)| x * y).sum::<f64>())
        .collect()
}

/// The smallest and largest ψ over the 2,562 directions of [`bound_sample`].
fn sampled_range(c: &[f64], l_max: usize) -> (f64, f64) {
    let n = c.len();
    bound_matrix(l_max)
        .chunks_exact(n)
        .take(bound_sample().0.len())
        .map(|row| row.iter().zip(c).map(|(x, y)| x * y).sum::<f64>())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)))
}

/// Converts coefficients to [`GLYPH_BASIS`] and applies sharpening: the unscaled glyph shape, its rmax and
/// its GFA (before sharpening).
/// `None` for an all-zero or non-finite set (nothing to draw).
pub fn shape(coeffs: &[f64], basis: ShBasis, sharpen: f64) -> Result<Option<(Vec<f64>, f64, f64)>> {
    let l_max = l_max_for(coeffs.len())
        .ok_or_else(|| Error::Shape(format!("{} SH coefficients is not a full even-order set", coeffs.len())))?;
    if l_max > MAX_GLYPH_L {
        return Err(Error::Param(format!("glyphs support l_max up to {MAX_GLYPH_L}, not {l_max}")));
    }
    if !(sharpen.is_finite() && sharpen >= 1.0) {
        return Err(Error::Param(format!("sharpening {sharpen} must be a finite number >= 1")));
    }
    if coeffs.iter().any(|c| !c.is_finite()) {
        return Ok(None);
    }
    let mut c = convert(coeffs, basis, GLYPH_BASIS);
    let anisotropy = gfa(&c);
    c[0] /= sharpen;
    let rmax = bound_rmax(GLYPH_BASIS, &c);
    Ok((rmax > 0.0).then_some((c, rmax, anisotropy)))
}

/// Glyphs from (centre, coefficients) pairs: converted, sharpened, normalised. Sets with nothing to draw
/// (zero or non-finite coefficients) are skipped; their indices are returned beside the glyphs.
pub fn make_glyphs<'a>(
    items: impl IntoIterator<Item = (DVec3, &'a [f64])>,
    basis: ShBasis,
    style: GlyphStyle,
) -> Result<(Vec<Glyph>, Vec<usize>)> {
    if !(style.scale.is_finite() && style.scale > 0.0) {
        return Err(Error::Param(format!("glyph scale {} must be a positive number of mm", style.scale)));
    }
    let mut shapes = Vec::new();
    let mut skipped = Vec::new();
    for (i, (centre, c)) in items.into_iter().enumerate() {
        match shape(c, basis, style.sharpen)? {
            Some((c, rmax, a)) if centre.is_finite() => shapes.push((centre, c, rmax, a)),
            _ => skipped.push(i),
        }
    }
    use rayon::prelude::*;
    if style.normalise == Normalise::MinMax {
        // ψ - min is the glyph plus a constant (a_00 += -min / Y_00); its bounds are recomputed below.
        shapes.par_iter_mut().for_each(|(_, c, rmax, _)| {
            let l_max = l_max_for(c.len()).unwrap_or(0);
            let (lo, _) = sampled_range(c, l_max);
            c[0] -= lo * 2.0 * std::f64::consts::PI.sqrt();
            *rmax = bound_rmax(GLYPH_BASIS, c);
        });
    }
    // What each glyph is normalised by: its Cauchy-Schwarz bound, or its largest lobe.
    let size: Vec<f64> = shapes
        .par_iter()
        .map(|(_, c, rmax, _)| {
            let l_max = l_max_for(c.len()).unwrap_or(0);
            match style.normalise {
                // The mean radius; a glyph with none is sized by its bound.
                Normalise::A00 if c[0] > 0.0 => c[0] / (2.0 * std::f64::consts::PI.sqrt()),
                Normalise::MinMax => sampled_range(c, l_max).1.max(1e-300),
                _ if style.fit_lobes => render_bound(c, l_max, *rmax),
                _ => *rmax,
            }
        })
        .collect();
    let global = size.iter().copied().fold(0.0f64, f64::max);
    let glyphs = shapes
        .into_par_iter()
        .zip(size)
        .map(|((centre, mut c, rmax, gfa), own)| {
            let k = style.scale / if style.normalise == Normalise::Global { global } else { own };
            c.iter_mut().for_each(|v| *v *= k);
            let l_max = l_max_for(c.len()).unwrap_or(0);
            // ψ at the sample directions once, for the render bound and the box.
            let psi = bound_psi(&c, l_max);
            let rbound = render_bound_from(&psi, l_max, rmax * k);
            let half = glyph_box_from(&c, l_max, &psi);
            // The sphere's cube where the box is not usable.
            let half = if half.is_finite() { half.min(DVec3::splat(rbound)) } else { DVec3::splat(rbound) };
            Glyph { centre, l_max, coeffs: c, rmax: rmax * k, rbound, half, gfa }
        })
        .collect();
    Ok((glyphs, skipped))
}

/// A ray-glyph hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray.
    pub t: f64,
    /// The hit point `o + t d`, in the ray's frame.
    pub point: DVec3,
    /// Unit outward normal.
    pub normal: DVec3,
    /// ψ < 0 at the hit (only with [`Lobes::Abs`]).
    pub negative: bool,
}

impl Glyph {
    /// `F(p) = |p - c| - s(ψ(u))`: negative inside the glyph.
    pub fn implicit(&self, p: DVec3, lobes: Lobes) -> f64 {
        let v = p - self.centre;
        let r = v.length();
        if r == 0.0 {
            return -1.0;
        }
        let (psi, _) = eval_cartesian(&self.coeffs, self.l_max, v / r);
        r - match lobes {
            Lobes::Clamp => psi.max(0.0),
            Lobes::Abs => psi.abs(),
        }
    }

    /// Unit normal of the surface at `p` (on or near it).
    pub fn normal(&self, p: DVec3, lobes: Lobes) -> (DVec3, bool) {
        let v = p - self.centre;
        let r = v.length().max(1e-300);
        let u = v / r;
        let (psi, g) = eval_cartesian(&self.coeffs, self.l_max, u);
        let s = match lobes {
            Lobes::Clamp => 1.0,
            Lobes::Abs => psi.signum(),
        };
        let tangential = g - g.dot(u) * u;
        let n = u - s * tangential / r;
        (n.normalize_or(u), lobes == Lobes::Abs && psi < 0.0)
    }
}

/// Entry and exit distances of a unit ray through a sphere, if it meets it ahead.
pub fn ray_sphere_interval(o: DVec3, d: DVec3, c: DVec3, r: f64) -> Option<(f64, f64)> {
    let oc = o - c;
    let b = oc.dot(d);
    let h = b * b - (oc.length_squared() - r * r);
    if h < 0.0 {
        return None;
    }
    let s = h.sqrt();
    let (t0, t1) = (-b - s, -b + s);
    (t1 > 0.0).then_some((t0.max(0.0), t1))
}

/// The shader's ray cast in f64: from the entry into the sphere of radius `rbound`, steps of `h · rbound`
/// until inside, then `refine` bisections between the last outside and first inside point. `d` unit.
pub fn cast(g: &Glyph, o: DVec3, d: DVec3, h: f64, refine: u32, lobes: Lobes) -> Option<Hit> {
    cast_within(g, g.rbound, o, d, h, refine, lobes)
}

/// [`cast`] inside a sphere of the given radius (steps `h · radius`).
pub fn cast_within(g: &Glyph, radius: f64, o: DVec3, d: DVec3, h: f64, refine: u32, lobes: Lobes) -> Option<Hit> {
    let t = march(o, d, g.centre, radius, h, refine, |p| g.implicit(p, lobes) < 0.0)?;
    let point = o + t * d;
    let (normal, negative) = g.normal(point, lobes);
    Some(Hit { t, point, normal, negative })
}

/// The glyph shaders' root search, in f64: from the entry into the sphere (`centre`, `radius`), steps of
/// `h · radius` along the unit ray until `inside`, then `refine` bisections between the last point outside
/// and the first inside. The distance of the hit, or `None` if the ray leaves the sphere first.
pub fn march(
    o: DVec3,
    d: DVec3,
    centre: DVec3,
    radius: f64,
    h: f64,
    refine: u32,
    inside: impl Fn(DVec3) -> bool,
) -> Option<f64> {
    let (t0, t1) = ray_sphere_interval(o, d, centre, radius)?;
    let step = (h * radius).max(1e-12 * radius);
    let (mut lo, mut t) = (t0, t0);
    loop {
        if inside(o + t * d) {
            break;
        }
        lo = t;
        if t >= t1 {
            return None;
        }
        t = (t + step).min(t1);
    }
    let mut hi = t;
    for _ in 0..refine {
        let mid = 0.5 * (lo + hi);
        if inside(o + mid * d) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Some(hi)
}

/// The glyph a ray hits first (index and hit), by the same caster as the shader (`h`, `refine`); glyphs
/// whose bounding sphere the ray misses cost one sphere test.
pub fn pick(glyphs: &[Glyph], o: DVec3, d: DVec3, h: f64, refine: u32, lobes: Lobes) -> Option<(usize, Hit)> {
    glyphs
        .iter()
        .enumerate()
        .filter(|(_, g)| ray_sphere_interval(o, d, g.centre, g.rbound).is_some())
        .filter_map(|(i, g)| cast(g, o, d, h, refine, lobes).map(|hit| (i, hit)))
        .min_by(|a, b| a.1.t.total_cmp(&b.1.t))
}

/// The reference: inside the guaranteed Cauchy-Schwarz sphere (not the renderer's tighter bound), a search
/// of 1e-4 rmax steps, and bisection to rounding.
pub fn cast_exact(g: &Glyph, o: DVec3, d: DVec3, lobes: Lobes) -> Option<Hit> {
    cast_within(g, g.rmax, o, d, 1e-4, 60, lobes)
}

/// Number of coefficients the shader reads per glyph at `l_max`.
pub fn glyph_stride(l_max: usize) -> usize {
    n_coeffs(l_max)
}

/// An icosphere: the icosahedron with each triangle split in four `order` times (order 0: 12 vertices;
/// order k: 10·4^k + 2). Unit vertices, counter-clockwise faces seen from outside.
pub fn icosphere(order: u32) -> (Vec<DVec3>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<DVec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| DVec3::new(x, y, z).normalize())
    .collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..order {
        let mut mid = std::collections::HashMap::new();
        let mut split = |a: u32, b: u32, v: &mut Vec<DVec3>| -> u32 {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                v.push((v[a as usize] + v[b as usize]).normalize());
                (v.len() - 1) as u32
            })
        };
        let mut next = Vec::with_capacity(f.len() * 4);
        for [a, b, c] in f {
            let (ab, bc, ca) = (split(a, b, &mut v), split(b, c, &mut v), split(c, a, &mut v));
            next.extend_from_slice(&[[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = next;
    }
    (v, f)
}

/// The mesh baseline (as FURY, mrview and DSI Studio draw ODFs): an icosphere of `order` deformed to
/// `r = s(ψ(u))` about the glyph centre. Returns world positions, unit vertex normals (area-weighted face
/// normals) and triangles.
pub fn glyph_mesh(g: &Glyph, order: u32, lobes: Lobes) -> (Vec<DVec3>, Vec<DVec3>, Vec<[u32; 3]>) {
    let (dirs, faces) = icosphere(order);
    let pos: Vec<DVec3> = dirs
        .iter()
        .map(|&u| {
            let (psi, _) = eval_cartesian(&g.coeffs, g.l_max, u);
            let r = match lobes {
                Lobes::Clamp => psi.max(0.0),
                Lobes::Abs => psi.abs(),
            };
            g.centre + r * u
        })
        .collect();
    let mut nrm = vec![DVec3::ZERO; pos.len()];
    for &[a, b, c] in &faces {
        let n = (pos[b as usize] - pos[a as usize]).cross(pos[c as usize] - pos[a as usize]);
        for i in [a, b, c] {
            nrm[i as usize] += n;
        }
    }
    let nrm = nrm.iter().zip(&dirs).map(|(n, u)| n.normalize_or(*u)).collect();
    (pos, nrm, faces)
}

/// A plane of interest in world coordinates: glyph positions on a grid of `spacing` mm over a
/// `2 half_size` square centred on `centre`, perpendicular to `normal` (any orientation).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GlyphPlane {
    /// The plane's centre, world mm; a grid point.
    pub centre: [f64; 3],
    /// The plane's normal in world axes (any non-zero length; normalised on use).
    pub normal: [f64; 3],
    /// Half the side of the square, in mm (at most 2,048 `spacing`s).
    pub half_size: f64,
    /// Distance between neighbouring glyph positions, in mm (> 0).
    pub spacing: f64,
}

/// How the field is read at a glyph position.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Sampling {
    /// The voxel containing the point (its coefficients unchanged); the glyph sits at the point.
    #[default]
    Nearest,
    /// Trilinear blend of the 8 surrounding voxels' coefficients (SH is linear, so this is the ODF blend).
    Trilinear,
}

/// A glyph position on a plane: world position, coefficients, nearest voxel.
pub type PlaneSample = (DVec3, Vec<f64>, [u32; 3]);

/// Where the glyphs of a plane go and what they show: `(world position, coefficients, nearest voxel)` for
/// every grid point of the plane inside the field whose coefficients are usable (finite, `c00 > 0`).
/// `field` is (X,Y,Z,n) with its affine.
pub fn sample_plane(field: &crate::Volume<f32>, plane: &GlyphPlane, sampling: Sampling) -> Result<Vec<PlaneSample>> {
    let n = DVec3::from_array(plane.normal);
    let c = DVec3::from_array(plane.centre);
    if !(n.is_finite() && n.length() > 0.0 && c.is_finite()) {
        return Err(Error::Param("the glyph plane needs a finite centre and a non-zero normal".into()));
    }
    if !(plane.spacing > 0.0 && plane.half_size >= 0.0 && plane.half_size / plane.spacing <= 2048.0) {
        return Err(Error::Param(format!(
            "glyph plane: spacing {} mm and half size {} mm must be positive, at most 4096 glyphs across",
            plane.spacing, plane.half_size
        )));
    }
    let nc = field.n_channels();
    if l_max_for(nc).is_none() || field.shape.len() < 4 {
        return Err(Error::Shape(format!("{:?} is not an SH coefficient image (X,Y,Z,n)", field.shape)));
    }
    let n = n.normalize();
    let u = n.any_orthonormal_vector();
    let v = n.cross(u);
    let inv = field.world_from_voxel.inverse();
    let d = field.dims3();
    let nvox = field.n_voxels();
    let k = (plane.half_size / plane.spacing).floor() as i64;
    let read = |x: usize, y: usize, z: usize, w: f64, out: &mut [f64]| {
        let vox = x + d[0] * (y + d[1] * z);
        for (j, o) in out.iter_mut().enumerate() {
            *o += w * field.data[vox + nvox * j] as f64;
        }
    };
    let mut out = Vec::new();
    for j in -k..=k {
        for i in -k..=k {
            let p = c + (i as f64 * u + j as f64 * v) * plane.spacing;
            let q = inv.transform_point3(p);
            if !(0..3).all(|a| q[a] >= -0.5 && q[a] < d[a] as f64 - 0.5) {
                continue;
            }
            let r = q.round();
            let near = [r.x.max(0.0) as usize, r.y.max(0.0) as usize, r.z.max(0.0) as usize];
            let mut coeffs = vec![0.0; nc];
            match sampling {
                Sampling::Nearest => read(near[0], near[1], near[2], 1.0, &mut coeffs),
                Sampling::Trilinear => {
                    let f = q.floor();
                    let w = q - f;
                    let lo = |a: usize| (f[a].max(0.0) as usize).min(d[a] - 1);
                    let hi = |a: usize| ((f[a] + 1.0).max(0.0) as usize).min(d[a] - 1);
                    for (z, wz) in [(lo(2), 1.0 - w.z), (hi(2), w.z)] {
                        for (y, wy) in [(lo(1), 1.0 - w.y), (hi(1), w.y)] {
                            for (x, wx) in [(lo(0), 1.0 - w.x), (hi(0), w.x)] {
                                read(x, y, z, wx * wy * wz, &mut coeffs);
                            }
                        }
                    }
                }
            }
            if coeffs.iter().all(|x| x.is_finite()) && coeffs[0] > 0.0 {
                out.push((p, coeffs, near.map(|x| x as u32)));
            }
        }
    }
    Ok(out)
}

/// How many of the best samples are considered as starts of the ascent in [`glyph_box`].
const STARTS_POOL: usize = 64;

/// Half extents of the glyph's axis-aligned box about its centre: for each axis `a`, the largest
/// `|ψ(u)| |u_a|`, found by projected gradient ascent on the sphere from the best of 2,562 directions, and
/// widened by `1e-6` of the largest radius for rounding.
pub fn glyph_box(coeffs: &[f64], l_max: usize) -> DVec3 {
    glyph_box_from(coeffs, l_max, &bound_psi(coeffs, l_max))
}

/// [`glyph_box`] with ψ at the sample directions given.
pub(crate) fn glyph_box_from(coeffs: &[f64], l_max: usize, psi: &[f64]) -> DVec3 {
    let (dirs, delta) = bound_sample();
    let shrink = 1.0 - 0.5 * ((l_max + 1) as f64 * delta).powi(2);
    let rmax = psi.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mut half = DVec3::ZERO;
    for a in 0..3 {
        let objective = |u: DVec3| {
            let (p, g) = eval_cartesian(coeffs, l_max, u);
            // h = (ψ u_a)², its Cartesian gradient, projected on the sphere below.
            let e = DVec3::AXES[a];
            (p * p * u[a] * u[a], 2.0 * p * u[a] * (u[a] * g + p * e))
        };
        // Start from the best samples of up to three distinct lobes (distinct lobes can be close in value;
        // antipodes and neighbours of a chosen start are the same lobe of h).
        let score = |i: usize| (psi[i] * dirs[i][a]).abs();
        let mut starts: Vec<usize> = Vec::with_capacity(3);
        let mut by_score: Vec<usize> = (0..dirs.len()).collect();
        let pool = STARTS_POOL.min(by_score.len());
        by_score.select_nth_unstable_by(pool - 1, |&i, &j| score(j).total_cmp(&score(i)));
        by_score.truncate(STARTS_POOL);
        by_score.sort_unstable_by(|&i, &j| score(j).total_cmp(&score(i)));
        for &i in &by_score {
            if starts.len() == 3 {
                break;
            }
            if starts.iter().all(|&k| dirs[k].dot(dirs[i]).abs() < 0.94) {
                starts.push(i);
            }
        }
        let mut best = 0.0f64;
        for &i in &starts {
            // ψ u_a has degree l_max + 1: by Bernstein's inequality (as in `render_bound`) no point of this
            // start's lobe exceeds its best sample by more than 1 / shrink. Skip lobes that cannot win.
            if best > 0.0 && shrink > 0.05 && (score(i) / shrink).powi(2) <= best {
                continue;
            }
            let mut u = dirs[i];
            let (mut h, mut grad) = objective(u);
            let mut step = 0.05;
            for _ in 0..60 {
                let tangent = grad - grad.dot(u) * u;
                if tangent.length() < 1e-14 * (1.0 + h) {
                    break;
                }
                let cand = (u + step * tangent / tangent.length()).normalize();
                let (hc, gc) = objective(cand);
                if hc > h {
                    (u, h, grad) = (cand, hc, gc);
                    step *= 1.5;
                } else {
                    step *= 0.3;
                    // 1e-7 rad from the maximum: h is within ~1e-14 of it (h is flat there).
                    if step < 1e-7 {
                        break;
                    }
                }
            }
            best = best.max(h);
        }
        half[a] = best.sqrt() + 1e-6 * rmax;
    }
    half
}
