//! SH glyphs by their polynomial form (Peters, Patel, Usher, Johnson, "Ray Tracing Spherical Harmonics
//! Glyphs", VMV 2023), and tight per-glyph boxes.
//!
//! For a glyph of even order `k`, `p(x) = |x|^k ψ(x/|x|)` is a polynomial of degree `k` in `x` (each band `l`
//! contributes `|x|^(k-l)` times a homogeneous harmonic polynomial of degree `l`, and `k - l` is even). On a ray
//! `x(t) = o + t d`, `p(x(t))` is a univariate polynomial of degree `k`: `k + 1` evaluations of ψ determine it.
//! They are taken at the Chebyshev points of the ray's span inside the glyph's box, and the polynomial is
//! evaluated anywhere on the span by the barycentric formula (stable at these nodes, `O(k)` per point), so
//! the surface `|x| = s(ψ)` becomes the roots of `f(t) = |x(t)|^(k+1) - s(p(t))` (`s` the lobe rule; `f < 0`
//! inside). `f` is cheap to evaluate: `samples` evaluations bracket its first sign change, bisection refines it.
//! A grazing pair of roots closer than `span / samples` can be missed, nothing else; the GPU shader
//! (`sh_glyph.wgsl`, method exact) does the same in f32, and [`cast_poly`] with many samples is its f64
//! reference (no ψ evaluation per sample: fast enough to render whole benchmark frames).
//!
//! [`glyph_box`] finds each glyph's extent along the three axes, `max |ψ(u)| |u_a|` (even orders are
//! antipodally symmetric, so the box is symmetric about the centre; `|ψ|` covers both lobe rules), by local
//! ascent from the best of 2,562 directions: a box hugging the glyph instead of its bounding sphere's cube.

use glam::DVec3;

use super::glyph::{Glyph, Hit, Lobes, eval_cartesian, icosphere};

/// The ray's span inside a box centred at `c` with half extents `e`: entry and exit distances along the unit
/// ray, if it meets the box ahead.
pub fn ray_box_interval(o: DVec3, d: DVec3, c: DVec3, e: DVec3) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
    for a in 0..3 {
        let (oa, da, ca, ea) = (o[a], d[a], c[a], e[a]);
        if da.abs() < 1e-300 {
            if (oa - ca).abs() > ea {
                return None;
            }
            continue;
        }
        let (mut lo, mut hi) = ((ca - ea - oa) / da, (ca + ea - oa) / da);
        if lo > hi {
            std::mem::swap(&mut lo, &mut hi);
        }
        t0 = t0.max(lo);
        t1 = t1.min(hi);
    }
    (t1 >= t0 && t1 > 0.0).then_some((t0.max(0.0), t1))
}

/// `p(x(t))` on a span `[t0, t1]` of a ray, as its values at the `k + 1` Chebyshev points (second kind).
#[derive(Clone, Debug)]
pub struct RayPolynomial {
    pub t0: f64,
    pub t1: f64,
    /// The nodes, from `t0` to `t1`.
    pub nodes: Vec<f64>,
    pub values: Vec<f64>,
}

impl RayPolynomial {
    /// Samples `p` for the glyph `coeffs` (order `k`, [`super::glyph::GLYPH_BASIS`]) on the ray `oc + t d`
    /// (`oc` the ray origin relative to the glyph centre).
    pub fn new(coeffs: &[f64], k: usize, oc: DVec3, d: DVec3, t0: f64, t1: f64) -> Self {
        let n = k.max(1);
        let nodes: Vec<f64> = (0..=n)
            .map(|j| {
                let c = (std::f64::consts::PI * j as f64 / n as f64).cos();
                0.5 * (t0 + t1) - 0.5 * (t1 - t0) * c
            })
            .collect();
        let values = nodes
            .iter()
            .map(|&t| {
                let x = oc + t * d;
                let r = x.length();
                if r == 0.0 {
                    return if k == 0 { eval_cartesian(coeffs, 0, DVec3::Z).0 } else { 0.0 };
                }
                r.powi(k as i32) * eval_cartesian(coeffs, k, x / r).0
            })
            .collect();
        Self { t0, t1, nodes, values }
    }

    /// `p(x(t))` by the barycentric formula (weights `(-1)^j`, halved at the ends).
    pub fn eval(&self, t: f64) -> f64 {
        let n = self.nodes.len() - 1;
        let (mut num, mut den) = (0.0, 0.0);
        for (j, (&tj, &vj)) in self.nodes.iter().zip(&self.values).enumerate() {
            let diff = t - tj;
            if diff == 0.0 {
                return vj;
            }
            let mut w = if j % 2 == 0 { 1.0 } else { -1.0 };
            if j == 0 || j == n {
                w *= 0.5;
            }
            let q = w / diff;
            num += q * vj;
            den += q;
        }
        num / den
    }
}

/// Knobs of the polynomial caster: `samples` evaluations of `f` bracket its first root, then `refine`
/// bisections.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PolyCast {
    pub samples: u32,
    pub refine: u32,
}

impl PolyCast {
    /// The f64 reference: 4,096 samples, bisection to rounding.
    pub const REFERENCE: PolyCast = PolyCast { samples: 4096, refine: 60 };
}

/// `f(t) = |x(t)|^(k+1) - s(p(t))`, negative inside the glyph.
fn implicit(poly: &RayPolynomial, k: usize, oc: DVec3, d: DVec3, t: f64, lobes: Lobes) -> f64 {
    let r = (oc + t * d).length();
    let p = poly.eval(t);
    let s = match lobes {
        Lobes::Clamp => p.max(0.0),
        Lobes::Abs => p.abs(),
    };
    r.powi(k as i32 + 1) - s
}

/// The first hit of the unit ray `o + t d` with the glyph, by its polynomial form, within the span `(t0, t1)`
/// of its box (or sphere). `None` if the ray leaves the span outside the glyph.
pub fn cast_poly(g: &Glyph, o: DVec3, d: DVec3, span: (f64, f64), knobs: PolyCast, lobes: Lobes) -> Option<Hit> {
    let k = g.l_max;
    let oc = o - g.centre;
    let (t0, t1) = span;
    let poly = RayPolynomial::new(&g.coeffs, k, oc, d, t0, t1);
    let n = knobs.samples.max(1);
    let f = |t: f64| implicit(&poly, k, oc, d, t, lobes);
    let (mut lo, mut hi) = (t0, t0);
    let mut found = f(t0) < 0.0;
    for i in 1..=n {
        if found {
            break;
        }
        let t = t0 + (t1 - t0) * i as f64 / n as f64;
        if f(t) < 0.0 {
            hi = t;
            found = true;
        } else {
            lo = t;
        }
    }
    if !found {
        return None;
    }
    for _ in 0..knobs.refine {
        let mid = 0.5 * (lo + hi);
        if f(mid) < 0.0 {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let point = o + hi * d;
    let (normal, negative) = g.normal(point, lobes);
    Some(Hit { t: hi, point, normal, negative })
}

/// The first hit inside the glyph's box ([`glyph_box`]), by [`cast_poly`].
pub fn cast_in_box(g: &Glyph, half: DVec3, o: DVec3, d: DVec3, knobs: PolyCast, lobes: Lobes) -> Option<Hit> {
    let span = ray_box_interval(o, d, g.centre, half)?;
    cast_poly(g, o, d, span, knobs, lobes)
}

/// Half extents of the glyph's axis-aligned box about its centre: for each axis `a`, the largest
/// `|ψ(u)| |u_a|`, found by projected gradient ascent on the sphere from the best of 2,562 directions, and
/// widened by `1e-6` of the largest radius for rounding.
pub fn glyph_box(coeffs: &[f64], l_max: usize) -> DVec3 {
    let dirs = box_directions();
    let psi: Vec<f64> = dirs.iter().map(|u| eval_cartesian(coeffs, l_max, *u).0).collect();
    let rmax = psi.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let mut half = DVec3::ZERO;
    for a in 0..3 {
        let objective = |u: DVec3| {
            let (p, g) = eval_cartesian(coeffs, l_max, u);
            // h = (ψ u_a)², its Cartesian gradient, projected on the sphere below.
            let e = DVec3::AXES[a];
            (p * p * u[a] * u[a], 2.0 * p * u[a] * (u[a] * g + p * e))
        };
        // Start from the best few samples (distinct lobes can be close in value).
        let mut order: Vec<usize> = (0..dirs.len()).collect();
        order.sort_by(|&i, &j| (psi[j] * dirs[j][a]).abs().total_cmp(&(psi[i] * dirs[i][a]).abs()));
        let mut best = 0.0f64;
        for &i in order.iter().take(4) {
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
                    if step < 1e-10 {
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

/// Directions of an order-4 icosphere, computed once.
fn box_directions() -> &'static [DVec3] {
    static DIRS: std::sync::OnceLock<Vec<DVec3>> = std::sync::OnceLock::new();
    DIRS.get_or_init(|| icosphere(4).0)
}
