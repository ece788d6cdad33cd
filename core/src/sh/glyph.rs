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
/// Mirrors `sh_eval` in `shaders/lib/sh.wgsl` term by term.
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
}

/// Per-glyph CPU work before upload (SEEDS.md §4).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GlyphStyle {
    /// Target radius in mm (of each glyph, or of the largest).
    pub scale: f64,
    /// `a_00` is divided by this (>= 1) to weaken the isotropic part.
    pub sharpen: f64,
    pub normalise: Normalise,
}

impl Default for GlyphStyle {
    fn default() -> Self {
        Self { scale: 1.0, sharpen: 1.0, normalise: Normalise::PerGlyph }
    }
}

/// A glyph ready for the GPU: centre, coefficients in [`GLYPH_BASIS`], and the bound `|ψ| <= rmax`.
#[derive(Clone, Debug, PartialEq)]
pub struct Glyph {
    pub centre: DVec3,
    pub l_max: usize,
    pub coeffs: Vec<f64>,
    pub rmax: f64,
}

/// Converts coefficients to [`GLYPH_BASIS`] and applies sharpening: the unscaled glyph shape and its rmax.
/// `None` for an all-zero or non-finite set (nothing to draw).
pub fn shape(coeffs: &[f64], basis: ShBasis, sharpen: f64) -> Result<Option<(Vec<f64>, f64)>> {
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
    c[0] /= sharpen;
    let rmax = bound_rmax(GLYPH_BASIS, &c);
    Ok((rmax > 0.0).then_some((c, rmax)))
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
            Some((c, rmax)) if centre.is_finite() => shapes.push((centre, c, rmax)),
            _ => skipped.push(i),
        }
    }
    let global = shapes.iter().map(|s| s.2).fold(0.0f64, f64::max);
    let glyphs = shapes
        .into_iter()
        .map(|(centre, mut c, rmax)| {
            let k = style.scale / if style.normalise == Normalise::PerGlyph { rmax } else { global };
            c.iter_mut().for_each(|v| *v *= k);
            let l_max = l_max_for(c.len()).unwrap_or(0);
            Glyph { centre, l_max, coeffs: c, rmax: rmax * k }
        })
        .collect();
    Ok((glyphs, skipped))
}

/// A ray-glyph hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Distance along the (unit) ray.
    pub t: f64,
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

/// The shader's ray cast in f64: from the bounding sphere's entry, steps of `h · rmax` until inside, then
/// `refine` bisections between the last outside and first inside point. `d` must be unit.
pub fn cast(g: &Glyph, o: DVec3, d: DVec3, h: f64, refine: u32, lobes: Lobes) -> Option<Hit> {
    let (t0, t1) = ray_sphere_interval(o, d, g.centre, g.rmax)?;
    let step = (h * g.rmax).max(1e-12 * g.rmax);
    let (mut lo, mut t) = (t0, t0);
    loop {
        if g.implicit(o + t * d, lobes) < 0.0 {
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
        if g.implicit(o + mid * d, lobes) < 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let point = o + hi * d;
    let (normal, negative) = g.normal(point, lobes);
    Some(Hit { t: hi, point, normal, negative })
}

/// The reference: a search 100 times finer than the finest knob the renderer offers (1e-4 rmax) and
/// bisection to rounding.
pub fn cast_exact(g: &Glyph, o: DVec3, d: DVec3, lobes: Lobes) -> Option<Hit> {
    cast(g, o, d, 1e-4, 60, lobes)
}

/// Number of coefficients the shader reads per glyph at `l_max`.
pub fn glyph_stride(l_max: usize) -> usize {
    n_coeffs(l_max)
}
