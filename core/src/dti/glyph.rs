//! Tensor glyphs: ellipsoids and Kindlmann's superquadrics (2004), as the GPU ray caster draws them
//! (`plugins/tensors/src/shaders/tensor_glyph.wgsl`), with the f64 references its tests use.
//!
//! A glyph of tensor T at a centre: eigenvalues l1 >= l2 >= l3 (negative ones clipped to 0), eigenvectors
//! e1, e2, e3; radii `r_i = scale · max(l_i, floor · l1) / l1` (the largest radius is `scale`; `floor`
//! keeps linear and planar tensors visible). In the glyph frame `q_i = (p - c)·e_i / r_i`:
//! - ellipsoid: `|q|² = 1`, intersected in closed form;
//! - superquadric with sharpness γ (Kindlmann): if `cl >= cp`, `α = (1 - cp)^γ`, `β = (1 - cl)^γ` and the
//!   symmetry axis is e1: `(|q2|^(2/α) + |q3|^(2/α))^(α/β) + |q1|^(2/β) = 1`; otherwise `α = (1 - cl)^γ`,
//!   `β = (1 - cp)^γ`, symmetry axis e3: `(|q1|^(2/α) + |q2|^(2/α))^(α/β) + |q3|^(2/β) = 1`. Spheres for
//!   isotropic tensors, cylinders and boxes as anisotropy and γ grow. Drawn by the same linear search and
//!   bisection as the SH glyphs, inside the sphere of radius `|r|` (the superquadric fills at most its box).

use glam::DVec3;

use super::eigen::{LowerTri, eigh};
use super::metrics;

/// Smallest superquadric exponent (see [`TensorGlyph::exponents`]).
pub const MIN_EXPONENT: f64 = 0.02;

/// Which surface a tensor glyph is.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum TensorShape {
    /// The ellipsoid with the glyph's radii along its eigenvectors.
    Ellipsoid,
    /// Kindlmann's superquadric with sharpness γ (3 is his default; 0 gives ellipsoids).
    Superquadric {
        /// Sharpness γ, >= 0; the default shape has 3.
        gamma: f64,
    },
}

impl Default for TensorShape {
    fn default() -> Self {
        TensorShape::Superquadric { gamma: 3.0 }
    }
}

/// A tensor glyph in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TensorGlyph {
    /// Centre in world space.
    pub centre: DVec3,
    /// Unit eigenvectors e1, e2, e3 (right-handed).
    pub axes: [DVec3; 3],
    /// Semi-axes along `axes` (world units): `scale · max(l_i, floor · l1) / l1`, the largest `scale`.
    pub radii: [f64; 3],
    /// Westin measures (l1 denominator, as Kindlmann) and FA.
    pub cl: f64,
    /// Westin planarity `(l2 - l3) / l1`, in [0, 1].
    pub cp: f64,
    /// Fractional anisotropy of the clipped eigenvalues, in [0, 1].
    pub fa: f64,
}

/// The glyph of tensor `t` (world frame) at `centre`; `None` for a zero, negative or non-finite tensor.
pub fn tensor_glyph(centre: DVec3, t: &LowerTri, scale: f64, floor: f64) -> Option<TensorGlyph> {
    let e = eigh(t)?;
    let l = e.values.map(|v| v.max(0.0));
    if !(l[0] > 0.0 && centre.is_finite() && scale > 0.0) {
        return None;
    }
    let radii = l.map(|v| scale * v.max(floor * l[0]) / l[0]);
    let [cl, cp, _] = metrics::westin(&l, metrics::WestinDenominator::Largest);
    Some(TensorGlyph { centre, axes: e.vectors, radii, cl, cp, fa: metrics::fa(&l) })
}

/// A ray-glyph hit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TensorHit {
    /// Distance along the ray from its origin (world units, the ray's direction being unit).
    pub t: f64,
    /// Hit point in world space, `origin + t · dir`.
    pub point: DVec3,
    /// Unit outward surface normal at `point` (world space).
    pub normal: DVec3,
}

impl TensorGlyph {
    /// Radius of a sphere around the centre that holds the glyph.
    pub fn bound(&self, shape: TensorShape) -> f64 {
        match shape {
            TensorShape::Ellipsoid => self.radii[0].max(self.radii[1]).max(self.radii[2]),
            TensorShape::Superquadric { .. } => DVec3::from_array(self.radii).length(),
        }
    }

    fn local(&self, p: DVec3) -> DVec3 {
        let v = p - self.centre;
        DVec3::new(
            v.dot(self.axes[0]) / self.radii[0],
            v.dot(self.axes[1]) / self.radii[1],
            v.dot(self.axes[2]) / self.radii[2],
        )
    }

    /// (α, β, symmetry axis index) of the superquadric. Both are kept >= [`MIN_EXPONENT`], which rounds
    /// edges at about 2 % of the radius: the exponents 2/α, 2/β then stay <= 100, finite in f32, and the
    /// surface keeps a normal a renderer can sample.
    pub fn exponents(&self, gamma: f64) -> (f64, f64, usize) {
        let e = |c: f64| (1.0 - c).max(0.0).powf(gamma).max(MIN_EXPONENT);
        if self.cl >= self.cp { (e(self.cp), e(self.cl), 0) } else { (e(self.cl), e(self.cp), 2) }
    }

    /// The implicit function: < 0 inside.
    pub fn implicit(&self, p: DVec3, shape: TensorShape) -> f64 {
        let q = self.local(p);
        match shape {
            TensorShape::Ellipsoid => q.length_squared() - 1.0,
            TensorShape::Superquadric { gamma } => {
                let (a, b, sym) = self.exponents(gamma);
                let (u, v, w) = others(q, sym);
                let s = u.abs().powf(2.0 / a) + v.abs().powf(2.0 / a);
                s.powf(a / b) + w.abs().powf(2.0 / b) - 1.0
            }
        }
    }

    /// Unit outward normal at `p` on the surface.
    pub fn normal(&self, p: DVec3, shape: TensorShape) -> DVec3 {
        let q = self.local(p);
        let g_local = match shape {
            TensorShape::Ellipsoid => q,
            TensorShape::Superquadric { gamma } => {
                let (a, b, sym) = self.exponents(gamma);
                let (u, v, w) = others(q, sym);
                let s = u.abs().powf(2.0 / a) + v.abs().powf(2.0 / a);
                let k = if s > 0.0 { s.powf(a / b - 1.0) } else { 0.0 };
                let du = k * u.abs().powf(2.0 / a - 1.0) * u.signum();
                let dv = k * v.abs().powf(2.0 / a - 1.0) * v.signum();
                let dw = w.abs().powf(2.0 / b - 1.0) * w.signum();
                place(du, dv, dw, sym)
            }
        };
        let n = self.axes[0] * (g_local.x / self.radii[0])
            + self.axes[1] * (g_local.y / self.radii[1])
            + self.axes[2] * (g_local.z / self.radii[2]);
        n.normalize_or((p - self.centre).normalize_or(DVec3::Z))
    }
}

/// The two non-symmetry coordinates and the symmetry one.
fn others(q: DVec3, sym: usize) -> (f64, f64, f64) {
    if sym == 0 { (q.y, q.z, q.x) } else { (q.x, q.y, q.z) }
}

fn place(du: f64, dv: f64, dw: f64, sym: usize) -> DVec3 {
    if sym == 0 { DVec3::new(dw, du, dv) } else { DVec3::new(du, dv, dw) }
}

/// Closed-form ray-ellipsoid intersection (nearest hit ahead of the origin; `d` unit).
pub fn cast_ellipsoid(g: &TensorGlyph, o: DVec3, d: DVec3) -> Option<TensorHit> {
    let oq = g.local(o);
    let dq = DVec3::new(d.dot(g.axes[0]) / g.radii[0], d.dot(g.axes[1]) / g.radii[1], d.dot(g.axes[2]) / g.radii[2]);
    let a = dq.length_squared();
    let b = oq.dot(dq);
    let c = oq.length_squared() - 1.0;
    let disc = b * b - a * c;
    if disc < 0.0 || a == 0.0 {
        return None;
    }
    let s = disc.sqrt();
    // Stable roots.
    let qq = -(b + b.signum() * s);
    let (t0, t1) = if qq != 0.0 { (qq / a, c / qq) } else { (-b / a, -b / a) };
    let (t0, t1) = (t0.min(t1), t0.max(t1));
    let t = if t0 > 0.0 {
        t0
    } else if t1 > 0.0 {
        t1
    } else {
        return None;
    };
    let point = o + t * d;
    Some(TensorHit { t, point, normal: g.normal(point, TensorShape::Ellipsoid) })
}

/// The shader's march for any shape: steps of `h · bound` from the bounding sphere's entry, then `refine`
/// bisections. With `h` small and `refine` large it is the reference for superquadrics.
pub fn cast_marching(
    g: &TensorGlyph,
    shape: TensorShape,
    o: DVec3,
    d: DVec3,
    h: f64,
    refine: u32,
) -> Option<TensorHit> {
    let t = crate::sh::glyph::march(o, d, g.centre, g.bound(shape), h, refine, |p| g.implicit(p, shape) < 0.0)?;
    let point = o + t * d;
    Some(TensorHit { t, point, normal: g.normal(point, shape) })
}
