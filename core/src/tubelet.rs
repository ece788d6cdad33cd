//! Hyperstreamline tubelets (SEEDS.md §3): a streamline drawn as a chain of segments, each a tube whose
//! elliptical cross-section comes from the tensors at its two ends (semi-axes from the two minor eigenvalues
//! along e2 and e3), cut by planes shared with its neighbours so the chain is seamless. This module builds the
//! tubelets and is the f64 reference of `plugins/tracts/src/shaders/tubelet.wgsl`: the implicit surface, its exact intersection
//! with a ray (fine root finding) and the shader's sphere tracer.
//!
//! Local frame of a tubelet: x from the left end's centre to the right one's, y and z the left ellipse's
//! axes (the left eigensystem rotated so that e1 lies on x, about e1 × x by arccos(e1 · x)). Along x the
//! semi-axes and the ellipse's rotation `rho` about x are interpolated linearly from (ry_l, rz_l, 0) to
//! (ry_r, rz_r, twist), the interpolation parameter clamped to the tubelet's own slab. The right ellipse's
//! rotation is corrected by multiples of 180° (an ellipse's symmetry) into (-90°, 90°]. In the plane
//! x = const the polar radius is `r(phi) = r1 r2 / sqrt(r2² cos² phi + r1² sin² phi)`, and the implicit
//! function `f = sqrt(y² + z²) - r(atan2(z, y) - rho)` is negative inside.

use glam::{DQuat, DVec3};

use crate::dti::{LowerTri, eigh, metrics};

/// Smallest semi-axis as a fraction of the cross-section scale (an exactly linear tensor has l2 = 0).
pub const MIN_RADIUS_RATIO: f64 = 0.05;
/// Largest turn (radians) of a twisted section over one step of the ray intersection.
pub const TWIST_STEP: f64 = 0.15;
/// Largest angle (degrees) between a cut plane's normal and the tubelet's axis.
pub const MAX_CUT_ANGLE_DEG: f64 = 60.0;

/// One tubelet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tubelet {
    /// Midpoint of the segment (world mm).
    pub centre: DVec3,
    /// Local frame to world.
    pub rotation: DQuat,
    /// Half the segment's length (mm): the end centres lie at local x = ±`half_length`.
    pub half_length: f64,
    /// Semi-axes along local y and z at the left end, then at the right end (mm).
    pub radii: [f64; 4],
    /// Rotation about x of the right ellipse relative to the left (radians, in (-π/2, π/2]).
    pub twist: f64,
    /// Unit normals of the left and right cut planes in the local frame (positive x component); the left
    /// plane passes through (-h, 0, 0), the right through (h, 0, 0).
    pub cuts: [DVec3; 2],
    /// Linear RGB at the left and right ends.
    pub colours: [DVec3; 2],
    /// Index of the streamline.
    pub streamline: u32,
    /// Index in its streamline of the segment's first point (its left end; the right end is the next point).
    pub point: u32,
}

/// How tubelets are coloured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum TubeColour {
    /// |local direction| as RGB.
    #[default]
    Direction,
    /// Westin: linear green, planar yellow, isotropic red, blended by (cl, cp, cs).
    Westin,
    /// One colour per streamline (a hash of its index).
    Streamline,
}

impl Tubelet {
    /// Largest semi-axis.
    pub fn rmax(&self) -> f64 {
        self.radii.iter().fold(0.0, |m, r| m.max(*r))
    }

    /// Half extents of the local bounding box: x covers the cut planes' tilt at radius rmax; 1 % of margin
    /// so the widest point of the surface lies strictly inside.
    pub fn half_extents(&self) -> DVec3 {
        let r = self.rmax() * 1.01;
        let ext = |n: DVec3| r * (1.0 - n.x * n.x).max(0.0).sqrt() / n.x.max(1e-3);
        DVec3::new(self.half_length + ext(self.cuts[0]).max(ext(self.cuts[1])), r, r)
    }

    /// A world point (mm) in the tubelet's local frame (centre at the origin, x along the segment).
    pub fn to_local(&self, p: DVec3) -> DVec3 {
        self.rotation.inverse() * (p - self.centre)
    }

    /// (r1, r2, rho) at local x.
    pub fn section(&self, x: f64) -> (f64, f64, f64) {
        let s = if self.half_length > 0.0 {
            ((x + self.half_length) / (2.0 * self.half_length)).clamp(0.0, 1.0)
        } else {
            0.5
        };
        let r = self.radii;
        (r[0] + s * (r[2] - r[0]), r[1] + s * (r[3] - r[1]), s * self.twist)
    }

    /// The implicit function at a local point (negative inside).
    pub fn f(&self, p: DVec3) -> f64 {
        let (r1, r2, rho) = self.section(p.x);
        let phi = p.z.atan2(p.y) - rho;
        let (c, s) = (phi.cos(), phi.sin());
        let r = r1 * r2 / ((r2 * c).powi(2) + (r1 * s).powi(2)).sqrt().max(1e-300);
        (p.y * p.y + p.z * p.z).sqrt() - r
    }

    /// Whether a local point lies between the cut planes.
    pub fn between_cuts(&self, p: DVec3) -> bool {
        let h = self.half_length;
        (p - DVec3::new(-h, 0.0, 0.0)).dot(self.cuts[0]) >= 0.0
            && (p - DVec3::new(h, 0.0, 0.0)).dot(self.cuts[1]) <= 0.0
    }

    /// Unit outward normal (world) at a local surface point: the gradient of `f` by central differences.
    pub fn normal(&self, p: DVec3) -> DVec3 {
        let e = 1e-4 * self.rmax().max(1e-9);
        let g = DVec3::new(
            self.f(p + DVec3::X * e) - self.f(p - DVec3::X * e),
            self.f(p + DVec3::Y * e) - self.f(p - DVec3::Y * e),
            self.f(p + DVec3::Z * e) - self.f(p - DVec3::Z * e),
        );
        (self.rotation * g).normalize_or_zero()
    }

    /// The local ray's interval in the bounding box, `None` on a miss.
    fn box_interval(&self, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
        let hi = self.half_extents();
        let inv = d.recip();
        let (a, b) = ((-hi - o) * inv, (hi - o) * inv);
        let (t0, t1) = (a.min(b).max_element().max(0.0), a.max(b).min_element());
        (t0 < t1).then_some((t0, t1))
    }

    /// Exact first intersection (world ray, unit `d`): the first outside-to-inside crossing of the surface
    /// between the cut planes, found by marching `steps` samples over the bounding box and 60 bisections.
    pub fn intersect_exact(&self, o: DVec3, d: DVec3, steps: usize) -> Option<f64> {
        let (lo, ld) = (self.to_local(o), self.rotation.inverse() * d);
        let (t0, t1) = self.box_interval(lo, ld)?;
        let g = |t: f64| self.f(lo + ld * t);
        let mut prev_t = t0;
        let mut prev = g(t0);
        for k in 1..=steps {
            let t = t0 + (t1 - t0) * k as f64 / steps as f64;
            let v = g(t);
            if prev > 0.0 && v <= 0.0 {
                let (mut a, mut b) = (prev_t, t);
                for _ in 0..60 {
                    let m = 0.5 * (a + b);
                    if g(m) > 0.0 { a = m } else { b = m }
                }
                let th = 0.5 * (a + b);
                if self.between_cuts(lo + ld * th) {
                    return Some(th);
                }
            }
            (prev_t, prev) = (t, v);
        }
        None
    }

    /// The local ray's interval inside the bounding cylinder (radius rmax about x) and box.
    fn cylinder_interval(&self, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
        let (t0, t1) = self.box_interval(o, d)?;
        let r = self.rmax() * 1.01;
        let a = d.y * d.y + d.z * d.z;
        let b = o.y * d.y + o.z * d.z;
        let c = o.y * o.y + o.z * o.z - r * r;
        if a < 1e-12 {
            return (c <= 0.0).then_some((t0, t1));
        }
        let disc = b * b - a * c;
        if disc < 0.0 {
            return None;
        }
        let q = disc.sqrt();
        let (c0, c1) = ((-b - q) / a, (-b + q) / a);
        let (s0, s1) = (t0.max(c0), t1.min(c1));
        (s0 < s1).then_some((s0, s1))
    }

    /// The shader's intersection: from where the ray enters the bounding cylinder, each iteration
    /// evaluates the implicit function `f` once and moves:
    /// - outside (`f > 0`): to where the ray meets the elliptic cylinder whose section (semi-axes, rotation)
    ///   is frozen at the current point's x (a quadratic; the surface is its fixed point); if that lies
    ///   beyond the interval (a twisted or widening section, a near-axis ray), by a secant step on `f` from
    ///   the previous sample, or else by `1/iterations` of the interval;
    /// - inside (`f < 0`, the surface was crossed): by regula falsi in the bracket.
    ///
    /// A hit when `|f| < eps · rmax` between the cut planes; at most `iterations` evaluations. (The seed's
    /// sphere tracing, [`Tubelet::trace_sphere`], tunnels through or stalls short of part of the silhouette
    /// of flattened tubelets at 8-16 iterations: `core/tests/tubelet.rs`, `fascicle-bench tracts`.)
    pub fn trace_bracketed(&self, o: DVec3, d: DVec3, iterations: u32, eps: f64) -> Option<f64> {
        let (lo, ld) = (self.to_local(o), self.rotation.inverse() * d);
        let (t0, t1) = self.cylinder_interval(lo, ld)?;
        let tol = eps * self.rmax();
        // A twisted section turns by at most TWIST_STEP radians per step, so thin sections are not
        // stepped over by the frozen-section predictor.
        let max_step = if self.twist.abs() > 1e-6 {
            2.0 * self.half_length * (TWIST_STEP / self.twist.abs()) / ld.x.abs().max(1e-3)
        } else {
            f64::INFINITY
        };
        let mut t = t0;
        // Last sample outside (t, f) and first inside after it.
        let mut out_s: Option<(f64, f64)> = None;
        let mut in_s: Option<(f64, f64)> = None;
        for _ in 0..iterations {
            let p = lo + ld * t;
            let v = self.f(p);
            if v.abs() < tol {
                return self.between_cuts(p).then_some(t);
            }
            if v < 0.0 {
                in_s = Some((t, v));
            } else {
                let prev = out_s;
                out_s = Some((t, v));
                if in_s.is_none() {
                    let (r1, r2, rho) = self.section(p.x);
                    let (c, s) = (rho.cos(), rho.sin());
                    // The point and direction in the frozen ellipse's axes.
                    let (py, pz) = (p.y * c + p.z * s, -p.y * s + p.z * c);
                    let (dy, dz) = (ld.y * c + ld.z * s, -ld.y * s + ld.z * c);
                    let (a2, b2) = (r1 * r1, r2 * r2);
                    let qa = dy * dy / a2 + dz * dz / b2;
                    let qb = py * dy / a2 + pz * dz / b2;
                    let qc = py * py / a2 + pz * pz / b2 - 1.0;
                    let disc = qb * qb - qa * qc;
                    let frozen = if qa > 1e-300 && disc >= 0.0 { (-qb - disc.sqrt()) / qa } else { f64::NAN };
                    let secant =
                        prev.map_or(f64::NAN, |(tp, fp)| if fp > v { v * (t - tp) / (fp - v) } else { f64::NAN });
                    let step = if frozen >= 0.0 && t + frozen <= t1 {
                        frozen
                    } else if secant > 0.0 && t + secant <= t1 {
                        secant
                    } else {
                        (t1 - t0) / iterations as f64
                    };
                    t += step.min(max_step);
                    if t > t1 {
                        return None;
                    }
                    continue;
                }
            }
            // Bracketed: regula falsi between the last outside and the first inside sample.
            let (Some((ta, fa)), Some((tb, fb))) = (out_s, in_s) else { return None };
            t = ta + (tb - ta) * fa / (fa - fb);
            if (tb - ta).abs() < tol {
                break;
            }
        }
        let p = lo + ld * t;
        (self.f(p).abs() < tol && self.between_cuts(p)).then_some(t)
    }
}

impl Tubelet {
    /// The first hit by `method` (the shader's twin), at most `iterations` evaluations of `f`.
    pub fn trace(&self, method: TubeMethod, o: DVec3, d: DVec3, iterations: u32, eps: f64) -> Option<f64> {
        match method {
            TubeMethod::Bracketed => self.trace_bracketed(o, d, iterations, eps),
            TubeMethod::Sphere => self.trace_sphere(o, d, iterations, eps),
        }
    }

    /// The seed's sphere tracing (SEEDS.md §3, after Hart 1996): start midway between where the ray enters
    /// the two frustums through the major and through the minor semi-axes (the outer entry alone when it
    /// misses the inner one), then step by the signed in-plane radial gap `f` (back when negative); a hit when
    /// `|f| < eps · rmax` within `iterations` steps, inside the box and between the cut planes. The seed also
    /// scales steps by `(1 - cos) + 1` for near-axis rays; that is left out: read as the angle to the axis, it
    /// doubles the steps of rays across the tube, which then oscillate about the surface without converging.
    pub fn trace_sphere(&self, o: DVec3, d: DVec3, iterations: u32, eps: f64) -> Option<f64> {
        let (lo, ld) = (self.to_local(o), self.rotation.inverse() * d);
        let (t0, t1) = self.box_interval(lo, ld)?;
        let [ry_l, rz_l, ry_r, rz_r] = self.radii;
        let outer = self.frustum_entry(lo, ld, (t0, t1), ry_l.max(rz_l), ry_r.max(rz_r))?;
        let mut t = match self.frustum_entry(lo, ld, (t0, t1), ry_l.min(rz_l), ry_r.min(rz_r)) {
            Some(inner) => 0.5 * (outer + inner),
            None => outer,
        };
        let tol = eps * self.rmax();
        for _ in 0..iterations {
            let p = lo + ld * t;
            let v = self.f(p);
            if v.abs() < tol {
                return (t >= t0 && t <= t1 && self.between_cuts(p)).then_some(t);
            }
            t += v;
        }
        None
    }

    /// Where the local ray first enters, within `span`, the frustum about x whose radius goes linearly from
    /// `r_l` at x = -h to `r_r` at x = h (`span.0` when it starts inside).
    fn frustum_entry(&self, o: DVec3, d: DVec3, span: (f64, f64), r_l: f64, r_r: f64) -> Option<f64> {
        let h = self.half_length;
        let slope = if h > 0.0 { (r_r - r_l) / (2.0 * h) } else { 0.0 };
        // The radius along the ray: ra + rb t.
        let (ra, rb) = (0.5 * (r_l + r_r) + slope * o.x, slope * d.x);
        let inside = |t: f64| {
            let p = o + d * t;
            (p.y * p.y + p.z * p.z).sqrt() <= ra + rb * t
        };
        if inside(span.0) {
            return Some(span.0);
        }
        let qa = d.y * d.y + d.z * d.z - rb * rb;
        let qb = o.y * d.y + o.z * d.z - ra * rb;
        let qc = o.y * o.y + o.z * o.z - ra * ra;
        let roots = if qa.abs() < 1e-12 {
            if qb.abs() < 1e-300 { vec![] } else { vec![-qc / (2.0 * qb)] }
        } else {
            let disc = qb * qb - qa * qc;
            if disc < 0.0 {
                return None;
            }
            let q = disc.sqrt();
            let (a, b) = ((-qb - q) / qa, (-qb + q) / qa);
            vec![a.min(b), a.max(b)]
        };
        roots.into_iter().find(|&t| t >= span.0 && t <= span.1 && ra + rb * t >= 0.0)
    }
}

/// How the tubelet shader finds a ray's first hit.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum TubeMethod {
    /// Frozen-section quadratic steps, then regula falsi in the bracket ([`Tubelet::trace_bracketed`]).
    #[default]
    Bracketed,
    /// The seed's sphere tracing ([`Tubelet::trace_sphere`]): the baseline.
    Sphere,
}

/// The ellipse frame at a point: eigen-system rotated so e1 lies on `axis`; returns (y, z, ry, rz) with
/// semi-axes `scale · max(l_k / l1, MIN_RADIUS_RATIO)` (circular with `scale · MIN_RADIUS_RATIO`... when no
/// tensor is given, radius `scale / 4`).
fn end_frame(axis: DVec3, tensor: Option<&LowerTri>, scale: f64) -> (DVec3, DVec3, f64, f64, [f64; 3]) {
    let fallback = || {
        let y = axis.any_orthonormal_vector();
        (y, axis.cross(y), scale / 4.0, scale / 4.0, [0.0, 0.0, 1.0])
    };
    let Some(e) = tensor.and_then(eigh) else { return fallback() };
    let l1 = e.values[0];
    if l1.is_nan() || l1 <= 0.0 {
        return fallback();
    }
    let mut e1 = e.vectors[0];
    if e1.dot(axis) < 0.0 {
        e1 = -e1;
    }
    let q = DQuat::from_rotation_arc(e1, axis);
    let y = (q * e.vectors[1]).reject_from(axis).normalize_or_zero();
    if y == DVec3::ZERO {
        return fallback();
    }
    let z = axis.cross(y);
    let r = |l: f64| scale * (l.max(0.0) / l1).max(MIN_RADIUS_RATIO);
    let l = e.values.map(|v| v.max(0.0));
    (y, z, r(e.values[1]), r(e.values[2]), metrics::westin(&l, metrics::WestinDenominator::Trace))
}

fn streamline_colour(i: u32) -> DVec3 {
    let mut h = (i as u64).wrapping_mul(0x9e3779b97f4a7c15);
    h ^= h >> 29;
    let f = |k: u32| 0.25 + 0.75 * (((h >> (k * 16)) & 0xffff) as f64 / 65535.0);
    DVec3::new(f(0), f(1), f(2))
}

/// Tubelets of one streamline (world points, optional per-point world tensors), cross-section `scale` mm.
pub fn tubelets(
    points: &[DVec3],
    tensors: Option<&[LowerTri]>,
    scale: f64,
    colour: TubeColour,
    streamline: u32,
) -> Vec<Tubelet> {
    let n = points.len();
    if n < 2 {
        return vec![];
    }
    let dirs: Vec<DVec3> = points.windows(2).map(|w| (w[1] - w[0]).normalize_or_zero()).collect();
    // Cut normal at each point: the bisector of the adjacent segments (the segment itself at the ends).
    let cut_at = |i: usize| -> DVec3 {
        let (a, b) = (dirs[i.saturating_sub(1)], dirs[i.min(n - 2)]);
        let s = (a + b).normalize_or_zero();
        if s == DVec3::ZERO { b } else { s }
    };
    let max_tilt = MAX_CUT_ANGLE_DEG.to_radians().cos();
    let mut out = Vec::with_capacity(n - 1);
    for i in 0..n - 1 {
        let (a, b) = (points[i], points[i + 1]);
        let len = (b - a).length();
        let x = dirs[i];
        if len.is_nan() || len <= 0.0 || !a.is_finite() || !b.is_finite() {
            continue;
        }
        let (yl, zl, ryl, rzl, wl) = end_frame(x, tensors.map(|t| &t[i]), scale);
        let (yr, _, ryr, rzr, wr) = end_frame(x, tensors.map(|t| &t[i + 1]), scale);
        let mut twist = yl.cross(yr).dot(x).atan2(yl.dot(yr));
        if twist > std::f64::consts::FRAC_PI_2 {
            twist -= std::f64::consts::PI;
        } else if twist <= -std::f64::consts::FRAC_PI_2 {
            twist += std::f64::consts::PI;
        }
        let rotation = DQuat::from_mat3(&glam::DMat3::from_cols(x, yl, zl));
        let local_cut = |c: DVec3| {
            let mut l = rotation.inverse() * c;
            if l.x < max_tilt {
                // Clamp the tilt: keep the direction of the tilt, raise x.
                let t = DVec3::new(0.0, l.y, l.z).normalize_or_zero();
                l = DVec3::new(max_tilt, 0.0, 0.0) + t * (1.0 - max_tilt * max_tilt).sqrt();
            }
            l.normalize()
        };
        let westin = |w: [f64; 3]| {
            DVec3::new(0.1, 0.8, 0.1) * w[0] + DVec3::new(0.9, 0.8, 0.1) * w[1] + DVec3::new(0.8, 0.1, 0.1) * w[2]
        };
        let colours = match colour {
            TubeColour::Direction => [cut_at(i).abs(), cut_at(i + 1).abs()],
            TubeColour::Westin => [westin(wl), westin(wr)],
            TubeColour::Streamline => [streamline_colour(streamline); 2],
        };
        out.push(Tubelet {
            centre: (a + b) / 2.0,
            rotation,
            half_length: len / 2.0,
            radii: [ryl, rzl, ryr, rzr],
            twist,
            cuts: [local_cut(cut_at(i)), local_cut(cut_at(i + 1))],
            colours,
            streamline,
            point: i as u32,
        });
    }
    out
}

/// The polygon-tube baseline (the seed's comparison: `sides` vertices per profile): at each point an
/// elliptical ring in the plane of the cut (the bisector of the adjacent segments), semi-axes as the
/// tubelets'; returns per ring vertex (position, unit normal), rings in point order, and per point the
/// colour. Consecutive rings are joined into quads by the caller.
pub fn polygon_rings(points: &[DVec3], tensors: Option<&[LowerTri]>, scale: f64, sides: usize) -> Vec<(DVec3, DVec3)> {
    let n = points.len();
    if n < 2 || sides < 3 {
        return vec![];
    }
    let dirs: Vec<DVec3> = points.windows(2).map(|w| (w[1] - w[0]).normalize_or_zero()).collect();
    let mut out = Vec::with_capacity(n * sides);
    for i in 0..n {
        let (a, b) = (dirs[i.saturating_sub(1)], dirs[i.min(n - 2)]);
        let axis = {
            let s = (a + b).normalize_or_zero();
            if s == DVec3::ZERO { if b == DVec3::ZERO { DVec3::X } else { b } } else { s }
        };
        let (y, z, ry, rz, _) = end_frame(axis, tensors.map(|t| &t[i]), scale);
        for k in 0..sides {
            let th = std::f64::consts::TAU * k as f64 / sides as f64;
            let (c, s) = (th.cos(), th.sin());
            let p = points[i] + y * (ry * c) + z * (rz * s);
            let nrm = (y * (c / ry) + z * (s / rz)).normalize_or_zero();
            out.push((p, nrm));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tensor(e1: DVec3, e2: DVec3, l: [f64; 3]) -> LowerTri {
        crate::dti::eigen::from_eigen(&crate::dti::Eigen { values: l, vectors: [e1, e2, e1.cross(e2)] })
    }

    #[test]
    fn straight_circular_tube_is_a_cylinder() {
        let t = tensor(DVec3::X, DVec3::Y, [1.0, 0.5, 0.5]);
        let tb = tubelets(&[DVec3::ZERO, DVec3::new(4.0, 0.0, 0.0)], Some(&[t, t]), 2.0, TubeColour::Direction, 0);
        assert_eq!(tb.len(), 1);
        let k = &tb[0];
        assert!((k.rmax() - 1.0).abs() < 1e-12 && k.twist.abs() < 1e-12);
        // A ray along -z from above hits the cylinder r = 1 at z = 1.
        let hit = k.intersect_exact(DVec3::new(2.5, 0.3, 10.0), -DVec3::Z, 20_000).unwrap();
        assert!((hit - (10.0 - (1.0f64 - 0.09).sqrt())).abs() < 1e-9, "{hit}");
        let st = k.trace_bracketed(DVec3::new(2.5, 0.3, 10.0), -DVec3::Z, 8, 1e-4).unwrap();
        assert!((st - hit).abs() < 1e-3);
        // Beyond the cut plane at x = 4: nothing.
        assert!(k.intersect_exact(DVec3::new(4.2, 0.0, 10.0), -DVec3::Z, 20_000).is_none());
    }

    #[test]
    fn elliptical_section_follows_the_minor_eigenvectors() {
        // e2 along z with l2 = 0.6, e3 along y with l3 = 0.2: semi-axis 0.6 s along z, 0.2 s along y.
        let t = tensor(DVec3::X, DVec3::Z, [1.0, 0.6, 0.2]);
        let tb = tubelets(&[DVec3::ZERO, DVec3::new(2.0, 0.0, 0.0)], Some(&[t, t]), 1.0, TubeColour::Westin, 0);
        let k = &tb[0];
        let from_top = k.intersect_exact(DVec3::new(1.0, 0.0, 5.0), -DVec3::Z, 20_000).unwrap();
        let from_side = k.intersect_exact(DVec3::new(1.0, 5.0, 0.0), -DVec3::Y, 20_000).unwrap();
        assert!((5.0 - from_top - 0.6).abs() < 1e-9 && (5.0 - from_side - 0.2).abs() < 1e-9);
        let n = k.normal(k.to_local(DVec3::new(1.0, 0.0, 0.6)));
        assert!((n - DVec3::Z).length() < 1e-6, "{n}");
    }

    #[test]
    fn twist_is_corrected_into_ninety_degrees() {
        let a = tensor(DVec3::X, DVec3::Y, [1.0, 0.6, 0.2]);
        // The right ellipse turned by 150 degrees is the same ellipse turned by -30.
        let r = DQuat::from_rotation_x(150f64.to_radians());
        let b = tensor(DVec3::X, r * DVec3::Y, [1.0, 0.6, 0.2]);
        let tb = tubelets(&[DVec3::ZERO, DVec3::X], Some(&[a, b]), 1.0, TubeColour::Direction, 0);
        assert!((tb[0].twist + 30f64.to_radians()).abs() < 1e-9, "{}", tb[0].twist.to_degrees());
    }

    #[test]
    fn joints_share_their_cut_plane() {
        let pts = [DVec3::ZERO, DVec3::new(2.0, 0.0, 0.0), DVec3::new(3.5, 1.5, 0.0)];
        let tb = tubelets(&pts, None, 1.0, TubeColour::Direction, 0);
        let (a, b) = (&tb[0], &tb[1]);
        let na = a.rotation * a.cuts[1];
        let nb = b.rotation * b.cuts[0];
        assert!((na - nb).length() < 1e-12);
        // A point on the joint plane, near the axis, is between the cuts of neither or both, never a gap.
        let p = pts[1] + na.any_orthonormal_vector() * 0.3;
        assert!(a.between_cuts(a.to_local(p - na * 1e-9)) && b.between_cuts(b.to_local(p + na * 1e-9)));
    }
}
