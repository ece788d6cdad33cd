//! SH glyphs hit exactly: the ray's plane through the glyph centre cuts the glyph along a trigonometric
//! polynomial (after Peters, Patel, Usher, Johnson, "Ray Tracing Spherical Harmonics Glyphs", VMV 2023), and
//! tight per-glyph boxes.
//!
//! A ray `x(t) = oc + t d` (relative to the centre) lies in the plane spanned by `e` (towards the ray's
//! closest point to the centre, at distance `b`) and `d`. In that plane the ray is the polar line
//! `r = b / cos θ`, and the glyph's section is `r = s(ψ(θ))` with `ψ(θ) = ψ(cos θ e + sin θ d)`. For an
//! order-`k` glyph, ψ on a great circle is a trigonometric polynomial of degree `k`, with only even
//! frequencies (even orders are antipodally symmetric): `k + 1` samples at `θ_j = jπ/(k+1)` give its
//! coefficients exactly (a discrete Fourier transform). The hits are the roots of
//! `g(θ) = s(ψ(θ)) cos θ - b` (positive inside), a trigonometric polynomial of degree `k + 1`: the paper's
//! intersection polynomial of degree `2k + 2` in `e^{iθ}`. This form has no radial powers, so it keeps its
//! precision in f32 for every order (the paper's `|x|^(2k+2)` spans many decades across a box at `k = 12`).
//! `g` costs `O(k)` per evaluation and no ψ evaluation. From the span's entry into the box, steps of `-g / Λ`
//! (`Λ`, a Lipschitz constant of `g` from its coefficients: no root lies closer), at least `span / (4 samples)`,
//! bracket the first root; bisection in `t` refines it (there `cos 2θ`, `sin 2θ` are rational in `t`: no
//! trigonometry). Only a pair of roots closer than the smallest step can be missed. The GPU shader
//! (`sh_glyph.wgsl`, method exact) does the same in f32; [`cast_poly`] with 4,096 samples is its f64
//! reference (fast enough to render whole benchmark frames).
//!
//! [`glyph_box`] finds each glyph's extent along the three axes, `max |ψ(u)| |u_a|` (even orders are
//! antipodally symmetric, so the box is symmetric about the centre; `|ψ|` covers both lobe rules), by local
//! ascent from the best of 2,562 directions: a box hugging the glyph instead of its bounding sphere's cube.

pub use super::glyph::glyph_box;
use glam::DVec3;

use super::glyph::{Glyph, Hit, Lobes, eval_cartesian};

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

/// A glyph's section by the plane of a ray: `ψ(θ)` as a trigonometric polynomial in `φ = 2θ`.
#[derive(Clone, Debug)]
pub struct RayPlane {
    /// The ray's distance from the centre, the parameter of its closest point, and the unit vector to it.
    pub b: f64,
    /// The ray parameter `t` of its closest point to the centre (`-oc · d`).
    pub tc: f64,
    /// The unit vector from the centre towards that closest point; any unit vector orthogonal to `d` when `b = 0`.
    pub e: DVec3,
    /// `ψ(θ) = Σ_n a_n cos nφ + b_n sin nφ`, `n = 0..=k/2`.
    pub cos: Vec<f64>,
    /// The sine coefficients `b_n`, `n = 0..=k/2` (`b_0 = 0`).
    pub sin: Vec<f64>,
}

impl RayPlane {
    /// The section of the glyph `coeffs` (order `k`, [`super::glyph::GLYPH_BASIS`]) by the plane of the ray
    /// `oc + t d` (`oc` relative to the centre, `d` unit).
    pub fn new(coeffs: &[f64], k: usize, oc: DVec3, d: DVec3) -> Self {
        let tc = -oc.dot(d);
        let foot = oc + tc * d;
        let b = foot.length();
        let e = if b > 0.0 { foot / b } else { d.any_orthonormal_vector() };
        let n = k + 1;
        let half = k / 2;
        let samples: Vec<f64> = (0..n)
            .map(|j| {
                let th = std::f64::consts::PI * j as f64 / n as f64;
                eval_cartesian(coeffs, k, th.cos() * e + th.sin() * d).0
            })
            .collect();
        let (mut cos, mut sin) = (vec![0.0; half + 1], vec![0.0; half + 1]);
        for (j, v) in samples.iter().enumerate() {
            let phi = 2.0 * std::f64::consts::PI * j as f64 / n as f64;
            for m in 0..=half {
                let w = if m == 0 { 1.0 } else { 2.0 } / n as f64;
                cos[m] += w * v * (m as f64 * phi).cos();
                sin[m] += w * v * (m as f64 * phi).sin();
            }
        }
        Self { b, tc, e, cos, sin }
    }

    /// ψ at the ray's point `t`: with `τ = t - tc` and `r² = τ² + b²`, `cos 2θ = (b² - τ²) / r²` and
    /// `sin 2θ = 2bτ / r²` (no trigonometry, nothing singular when the ray meets the centre).
    pub fn psi_at(&self, t: f64) -> f64 {
        let tau = t - self.tc;
        let r2 = tau * tau + self.b * self.b;
        if r2 == 0.0 {
            return self.psi_phi(1.0, 0.0);
        }
        self.psi_phi((self.b * self.b - tau * tau) / r2, 2.0 * self.b * tau / r2)
    }

    /// ψ at `φ = 2θ` given `(cos φ, sin φ)`, by the angle-addition recurrence.
    pub fn psi_phi(&self, c1: f64, s1: f64) -> f64 {
        let (mut c, mut s) = (1.0, 0.0);
        let mut v = self.cos[0];
        for m in 1..self.cos.len() {
            (c, s) = (c * c1 - s * s1, s * c1 + c * s1);
            v += self.cos[m] * c + self.sin[m] * s;
        }
        v
    }

    /// A Lipschitz constant of `g(θ) = s(ψ(θ)) cos θ - b` in θ: `|ψ| + |dψ/dθ|`, bounded by
    /// `Σ (1 + 2m)(|a_m| + |b_m|)` (each term of ψ in `φ = 2θ` changes at most `2m` times its size per radian).
    pub fn lipschitz(&self) -> f64 {
        (0..self.cos.len()).map(|m| (1.0 + 2.0 * m as f64) * (self.cos[m].abs() + self.sin[m].abs())).sum()
    }

    /// `g(θ) = s(ψ(θ)) cos θ - b`: positive inside the glyph.
    pub fn section(&self, theta: f64, lobes: Lobes) -> f64 {
        let (s, c) = theta.sin_cos();
        let p = self.psi_phi(c * c - s * s, 2.0 * s * c);
        let v = match lobes {
            Lobes::Clamp => p.max(0.0),
            Lobes::Abs => p.abs(),
        };
        v * c - self.b
    }

    /// The angle of the ray's point `t`, and the point of an angle.
    pub fn theta(&self, t: f64) -> f64 {
        (t - self.tc).atan2(self.b)
    }
    /// The ray parameter of angle `theta`: `tc + b tan θ`.
    pub fn t_of(&self, theta: f64) -> f64 {
        self.tc + self.b * theta.tan()
    }

    /// `s(ψ) - r` at the ray's point `t`: positive inside the glyph (there `r < s(ψ)`; with `r = b / cos θ`
    /// this is the sign of the trigonometric polynomial `s(ψ(θ)) cos θ - b`).
    pub fn inside(&self, t: f64, lobes: Lobes) -> f64 {
        let tau = t - self.tc;
        let p = self.psi_at(t);
        let s = match lobes {
            Lobes::Clamp => p.max(0.0),
            Lobes::Abs => p.abs(),
        };
        s - (tau * tau + self.b * self.b).sqrt()
    }
}

/// Knobs of the exact caster. From the span's entry, steps in θ of `-g / Λ` (no root can lie closer: `Λ` is
/// `g`'s Lipschitz constant), at least `span / (4 samples)` (and at most `64 samples` of them; about 15 on
/// average), bracket the first root; `refine` bisections (in `t`) refine it. Only a pair of roots closer than
/// the smallest step, where `|g| < Λ · span / (4 samples)`, can be missed. A ray through the centre (θ is
/// ±π/2 on all of it) is sampled uniformly in `t` at `samples` points instead.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PolyCast {
    /// Sets the smallest θ step, `span / (4 samples)`, and the step cap, `64 samples`; a ray through the centre is
    /// sampled at this many points in `t`. 4,096 in [`PolyCast::REFERENCE`].
    pub samples: u32,
    /// Bisections in `t` refining the bracketed root (60 in [`PolyCast::REFERENCE`]: to f64 rounding).
    pub refine: u32,
}

impl PolyCast {
    /// The f64 reference: 4,096 samples, bisection to rounding.
    pub const REFERENCE: PolyCast = PolyCast { samples: 4096, refine: 60 };
}

/// The first root's bracket in θ by certified steps (see [`PolyCast`]): `(outside, inside)`.
fn bracket_theta(plane: &RayPlane, th0: f64, th1: f64, samples: u32, lobes: Lobes) -> Option<(f64, f64)> {
    let lam = plane.lipschitz().max(1e-300);
    let dmin = (th1 - th0) / (4.0 * f64::from(samples));
    let mut th = th0;
    let mut lo = th0;
    for _ in 0..=64 * samples {
        let g = plane.section(th, lobes);
        if g > 0.0 {
            return Some((lo, th));
        }
        if th >= th1 {
            return None;
        }
        lo = th;
        th = (th + (-g / lam).max(dmin)).min(th1);
    }
    None
}

/// The first hit of the unit ray `o + t d` with the glyph, by its plane section, within the span
/// `(t0, t1)` of its box (or sphere). `None` if the ray leaves the span outside the glyph.
pub fn cast_poly(g: &Glyph, o: DVec3, d: DVec3, span: (f64, f64), knobs: PolyCast, lobes: Lobes) -> Option<Hit> {
    let plane = RayPlane::new(&g.coeffs, g.l_max, o - g.centre, d);
    let (t0, t1) = span;
    let n = knobs.samples.max(1);
    let inside = |t: f64| plane.inside(t, lobes) > 0.0;
    let (mut lo, mut hi);
    if plane.b > 1e-9 * g.rbound {
        let (a, b) = bracket_theta(&plane, plane.theta(t0), plane.theta(t1), n, lobes)?;
        (lo, hi) = (plane.t_of(a).max(t0), plane.t_of(b).min(t1));
        if inside(lo) || !inside(hi) {
            // The conversion to t rounded across the root (or θ0 was inside): the nearer end.
            hi = if inside(lo) { lo } else { hi };
            lo = hi;
        }
    } else {
        // The ray meets the centre: θ is ±π/2 on it; sample t uniformly instead.
        (lo, hi) = (t0, t0);
        let mut found = inside(t0);
        for i in 1..=n {
            if found {
                break;
            }
            let t = t0 + (t1 - t0) * i as f64 / n as f64;
            if inside(t) {
                hi = t;
                found = true;
            } else {
                lo = t;
            }
        }
        if !found {
            return None;
        }
    }
    for _ in 0..knobs.refine {
        let mid = 0.5 * (lo + hi);
        if inside(mid) {
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
