//! Tensor splatting (SEEDS.md §1): each tensor sample a 3D Gaussian with covariance `scale² · T / l1`
//! (its largest standard deviation is `scale`), projected to a 2D Gaussian footprint with the local affine
//! approximation of the perspective projection (EWA, Zwicker et al. 2001), composited back to front with the
//! "over" operator. This module is the f64 reference of `plugins/tensors/src/shaders/tensor_splat.wgsl`.
//!
//! - View-space covariance `V = W Σ Wᵀ` (W the view rotation); footprint covariance in pixels
//!   `V2 = J V Jᵀ + ε I`, with J the Jacobian of the pixel projection at the centre and ε = [`DILATION_PX2`]
//!   (a small screen-space low-pass so needle-thin splats still cover a pixel, as EWA does).
//! - Opacity at pixel offset d: `α = α0 · exp(-½ dᵀ V2⁻¹ d)`, zero beyond 3 standard deviations
//!   (`dᵀ V2⁻¹ d > 9`), with `α0 = opacity · exp(-2 K sqrt(V_zz / s²))` when depth attenuation is on
//!   (`K = -ln 0.25`; `s` the splat's largest standard deviation, so `V_zz / s²` is the view-space zz of
//!   the tensor normalised to `l1 = 1`: a needle seen end-on keeps 1/16 of its opacity, side-on all of
//!   it, whatever its size) and `opacity` otherwise.
//! - Compositing: splats sorted by the view depth of their centres, far to near; `C = α c + (1 - α) C`.

use glam::{DMat3, DMat4, DVec2, DVec3};

use super::barycentric::{BarycentricTf, Ranges, ranges};
use super::metrics::{WestinDenominator, fa, westin};

/// Screen-space dilation added to every footprint, pixels².
pub const DILATION_PX2: f64 = 0.3;
/// The seed's depth-attenuation constant, `-ln 0.25`.
pub const ATTENUATION_K: f64 = 1.3862943611198906;

/// One splat in world space: its Gaussian, the tensor's shape (for colour and lit-tensor shading) and its
/// current colour and opacity (from a [`SplatColouring`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Splat {
    /// Centre in world space (mm).
    pub centre: DVec3,
    /// World covariance (mm²).
    pub cov: DMat3,
    /// Linear RGB.
    pub colour: DVec3,
    /// Peak opacity in [0, 1], before depth attenuation.
    pub opacity: f64,
    /// The tensor's eigenvalues, largest first.
    pub values: [f64; 3],
    /// Unit major and minor eigenvectors (world frame).
    pub e1: DVec3,
    /// Unit minor eigenvector (world frame), of the smallest eigenvalue.
    pub e3: DVec3,
    /// The largest variance of `cov` (mm²): depth attenuation measures depth extent in units of the
    /// splat's largest standard deviation, so it does not depend on the splat's size.
    pub size2: f64,
}

impl Splat {
    /// Fractional anisotropy of `values`, in [0, 1].
    pub fn fa(&self) -> f64 {
        fa(&self.values)
    }

    /// Westin's (cl, cp, cs) with the trace denominator (they sum to 1).
    pub fn shape(&self) -> [f64; 3] {
        westin(&self.values, WestinDenominator::Trace)
    }
}

/// A splat of tensor `t` (world frame): covariance `scale² · t / l1`; `None` for a tensor with no positive
/// eigenvalue or non-finite input. Negative eigenvalues (noise) are clamped to 0 for the shape measures.
pub fn tensor_splat(centre: DVec3, t: &super::LowerTri, scale: f64, colour: DVec3, opacity: f64) -> Option<Splat> {
    let e = super::eigh(t)?;
    let l1 = e.values[0];
    if !(l1 > 0.0 && centre.is_finite() && scale.is_finite()) {
        return None;
    }
    let k = scale * scale / l1;
    let m = DMat3::from_cols_array(&[t[0], t[1], t[3], t[1], t[2], t[4], t[3], t[4], t[5]]) * k;
    Some(Splat {
        centre,
        cov: m,
        colour,
        opacity,
        values: e.values.map(|v| v.max(0.0)),
        e1: e.vectors[0],
        e3: e.vectors[2],
        size2: scale * scale,
    })
}

/// Viridis through five stops (the same as `plugins/render/src/shaders/lib/colormap.wgsl`), linear RGB.
pub fn viridis(v: f64) -> DVec3 {
    const STOPS: [[f64; 3]; 5] = [
        [0.0578, 0.0, 0.0844],
        [0.0423, 0.0865, 0.2582],
        [0.0152, 0.2831, 0.2623],
        [0.1119, 0.5841, 0.1221],
        [0.9823, 0.7913, 0.0194],
    ];
    let x = if v.is_finite() { v.clamp(0.0, 1.0) * 4.0 } else { 0.0 };
    let i = (x as usize).min(3);
    DVec3::from_array(STOPS[i]).lerp(DVec3::from_array(STOPS[i + 1]), x - i as f64)
}

/// Where splat colour and opacity come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum SplatColourMode {
    /// FA through viridis, opacity FA (at least 0.05).
    #[default]
    Fa,
    /// |e1| as RGB, opacity FA (at least 0.05).
    Direction,
    /// The barycentric transfer function over (cl, cp, cs).
    Barycentric,
}

/// A colouring: the mode and the barycentric function it uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SplatColouring {
    /// Where colour and opacity come from. Defaults to [`SplatColourMode::Fa`].
    pub mode: SplatColourMode,
    /// The transfer function of [`SplatColourMode::Barycentric`] (unused by the other modes); defaults to
    /// [`BarycentricTf::default`].
    #[serde(default)]
    pub tf: BarycentricTf,
}

impl SplatColouring {
    /// Colour and opacity of a splat; `ranges` are the data ranges of (cl, cp, cs) under the function's
    /// denominator (for stretching).
    pub fn style(&self, s: &Splat, ranges: Option<&Ranges>) -> (DVec3, f64) {
        let f = s.fa();
        match self.mode {
            SplatColourMode::Fa => (viridis(f), f.max(0.05)),
            SplatColourMode::Direction => (s.e1.abs() * f.max(0.2), f.max(0.05)),
            SplatColourMode::Barycentric => self.tf.eval(self.tf.measures(&s.values), ranges),
        }
    }

    /// Sets every splat's colour and opacity.
    pub fn apply(&self, splats: &mut [Splat]) {
        let r = self.ranges(splats);
        for s in splats {
            (s.colour, s.opacity) = self.style(s, Some(&r));
        }
    }

    /// The data ranges of the measures this colouring's function uses.
    pub fn ranges(&self, splats: &[Splat]) -> Ranges {
        ranges(&splats.iter().map(|s| self.tf.measures(&s.values)).collect::<Vec<_>>())
    }
}

/// Lit-tensor shading (Kindlmann): Blinn-Phong with the normal following the tensor's shape, flat per
/// splat, with a headlight (light and half vector both towards the eye). For a planar tensor `n = e3`; for
/// a linear one `n` is the unit vector orthogonal to `e1` closest to the light, so `l·n = sqrt(1 - (l·e1)²)`;
/// a spherical tensor has no preferred normal and is lit fully. The three terms are blended by (cl, cp, cs):
/// `d = cl·sqrt(1-(l·e1)²) + cp·|l·e3| + cs`, `s = cl·sqrt(1-(l·e1)²)^N + cp·|l·e3|^N`, and
/// `colour · (ambient + diffuse·d) + specular·s`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct LitTensor {
    /// Weight of the unlit colour. Defaults to 0.3.
    pub ambient: f64,
    /// Weight of the diffuse term `d`. Defaults to 0.7.
    pub diffuse: f64,
    /// Weight of the white specular term `s`. Defaults to 0.3.
    pub specular: f64,
    /// Blinn-Phong exponent `N`. Defaults to 20.
    pub shininess: f64,
}

impl Default for LitTensor {
    fn default() -> Self {
        Self { ambient: 0.3, diffuse: 0.7, specular: 0.3, shininess: 20.0 }
    }
}

impl LitTensor {
    /// The diffuse and specular factors for a splat seen along unit `to_eye` (from the splat to the eye).
    pub fn factors(&self, s: &Splat, to_eye: DVec3) -> (f64, f64) {
        let [cl, cp, cs] = s.shape();
        let dl = (1.0 - to_eye.dot(s.e1).powi(2)).max(0.0).sqrt();
        let dp = to_eye.dot(s.e3).abs();
        let d = cl * dl + cp * dp + cs;
        let sp = cl * dl.powf(self.shininess) + cp * dp.powf(self.shininess);
        (d, sp)
    }

    /// The shaded colour.
    pub fn shade(&self, s: &Splat, to_eye: DVec3) -> DVec3 {
        let (d, sp) = self.factors(s, to_eye);
        s.colour * (self.ambient + self.diffuse * d) + DVec3::splat(self.specular * sp)
    }
}

/// How splats are drawn (the reference's and the shader's shared knobs).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SplatRender {
    /// The seed's depth attenuation `exp(-2K sqrt(T'zz))`.
    pub attenuation: bool,
    /// Lit-tensor shading, `None` for flat colour.
    pub lighting: Option<LitTensor>,
}

/// A pinhole camera as Bevy's: looks down -z of its view frame, vertical field of view `fov_y`, pixel
/// (0, 0) at the top left.
#[derive(Clone, Copy, Debug)]
pub struct SplatCamera {
    /// World (mm) to the camera's view frame: rigid, the camera at the origin looking down -z.
    pub view_from_world: DMat4,
    /// Vertical field of view (radians).
    pub fov_y: f64,
    /// Image width (pixels).
    pub width: u32,
    /// Image height (pixels).
    pub height: u32,
}

/// A splat's footprint on the screen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    /// Pixel coordinates of the projected centre.
    pub centre: DVec2,
    /// Inverse of the 2D covariance (pixels⁻²), as (a, b, c) of `[[a, b], [b, c]]`.
    pub conic: [f64; 3],
    /// Distance of the centre in front of the camera (mm).
    pub depth: f64,
    /// Peak opacity at the centre: the splat's opacity, depth-attenuated when attenuation is on.
    pub alpha0: f64,
}

impl SplatCamera {
    /// Focal length in pixels.
    pub fn focal(&self) -> f64 {
        self.height as f64 / 2.0 / (self.fov_y / 2.0).tan()
    }

    /// The eye in world space.
    pub fn eye(&self) -> DVec3 {
        self.view_from_world.inverse().transform_point3(DVec3::ZERO)
    }

    /// The footprint of a splat, `None` behind the camera or degenerate.
    pub fn project(&self, s: &Splat, attenuation: bool) -> Option<Footprint> {
        let p = self.view_from_world.transform_point3(s.centre);
        let z = -p.z;
        if z <= 1e-6 {
            return None;
        }
        let f = self.focal();
        let (cx, cy) = (self.width as f64 / 2.0, self.height as f64 / 2.0);
        let w = DMat3::from_mat4(self.view_from_world);
        let v = w * s.cov * w.transpose();
        // Pixel u = cx + f x / z, v = cy - f y / z with z = -p.z.
        let j0 = DVec3::new(f / z, 0.0, f * p.x / (z * z));
        let j1 = DVec3::new(0.0, -f / z, -f * p.y / (z * z));
        let a = j0.dot(v * j0) + DILATION_PX2;
        let b = j0.dot(v * j1);
        let c = j1.dot(v * j1) + DILATION_PX2;
        let det = a * c - b * b;
        if !(det > 0.0 && det.is_finite()) {
            return None;
        }
        let alpha0 = if attenuation {
            s.opacity * (-2.0 * ATTENUATION_K * (v.z_axis.z / s.size2).max(0.0).sqrt()).exp()
        } else {
            s.opacity
        };
        Some(Footprint {
            centre: DVec2::new(cx + f * p.x / z, cy - f * p.y / z),
            conic: [c / det, -b / det, a / det],
            depth: z,
            alpha0,
        })
    }
}

impl Footprint {
    /// Opacity at pixel position `q`.
    pub fn alpha(&self, q: DVec2) -> f64 {
        let d = q - self.centre;
        let m = self.conic[0] * d.x * d.x + 2.0 * self.conic[1] * d.x * d.y + self.conic[2] * d.y * d.y;
        if m > 9.0 { 0.0 } else { self.alpha0 * (-0.5 * m).exp() }
    }

    /// Half extents (pixels) of the box around the 3-sigma ellipse.
    pub fn half_extent(&self) -> DVec2 {
        let [a, b, c] = self.conic;
        let det = a * c - b * b;
        DVec2::new(3.0 * (c / det).max(0.0).sqrt(), 3.0 * (a / det).max(0.0).sqrt())
    }
}

/// The reference image: linear RGB per pixel (row-major, top row first) of the splats composited far to
/// near over `background`, sampled at pixel centres. Each splat touches only the pixels of its 3-sigma box
/// (outside it its opacity is 0), so this costs the splats' total footprint area.
pub fn composite(splats: &[Splat], cam: &SplatCamera, render: &SplatRender, background: DVec3) -> Vec<DVec3> {
    let eye = cam.eye();
    let mut fp: Vec<(Footprint, DVec3)> = splats
        .iter()
        .filter_map(|s| {
            let colour = match &render.lighting {
                Some(l) => l.shade(s, (eye - s.centre).normalize_or_zero()),
                None => s.colour,
            };
            cam.project(s, render.attenuation).map(|f| (f, colour))
        })
        .collect();
    fp.sort_by(|a, b| b.0.depth.total_cmp(&a.0.depth));
    let (w, h) = (cam.width as i64, cam.height as i64);
    let mut out = vec![background; (w * h) as usize];
    for (f, c) in &fp {
        let e = f.half_extent();
        let x0 = ((f.centre.x - e.x - 0.5).floor() as i64).max(0);
        let x1 = ((f.centre.x + e.x - 0.5).ceil() as i64).min(w - 1);
        let y0 = ((f.centre.y - e.y - 0.5).floor() as i64).max(0);
        let y1 = ((f.centre.y + e.y - 0.5).ceil() as i64).min(h - 1);
        for y in y0..=y1 {
            for x in x0..=x1 {
                let a = f.alpha(DVec2::new(x as f64 + 0.5, y as f64 + 0.5));
                if a > 0.0 {
                    let px = &mut out[(y * w + x) as usize];
                    *px = a * *c + (1.0 - a) * *px;
                }
            }
        }
    }
    out
}

/// Depth-sort keys of splat centres for a view direction `forward` (unit, world or set-local frame):
/// `dot(centre, forward)` grows with the distance in front of the camera, so sorting the keys in
/// decreasing order is far to near for any camera position.
pub fn depth_keys(centres: impl Iterator<Item = [f32; 3]>, forward: [f32; 3]) -> Vec<f32> {
    centres.map(|c| c[0] * forward[0] + c[1] * forward[1] + c[2] * forward[2]).collect()
}

/// Indices of `keys` in decreasing order (stable: equal keys keep their index order; NaN last), by an LSD
/// radix sort of the keys' order-preserving bit patterns in three 11-bit passes: O(n), about 3x faster
/// than a comparison sort at 1M keys.
pub fn argsort_desc(keys: &[f32]) -> Vec<u32> {
    const BITS: u32 = 11;
    const BUCKETS: usize = 1 << BITS;
    // Order-preserving map of f32 to u32 (ascending), inverted for a descending sort. NaN sorts last.
    let code = |k: f32| -> u32 {
        if k.is_nan() {
            return u32::MAX;
        }
        let b = k.to_bits();
        let asc = if b & 0x8000_0000 != 0 { !b } else { b | 0x8000_0000 };
        !asc
    };
    let n = keys.len();
    let mut codes: Vec<u32> = keys.iter().map(|&k| code(k)).collect();
    let mut idx: Vec<u32> = (0..n as u32).collect();
    let (mut codes2, mut idx2) = (vec![0u32; n], vec![0u32; n]);
    for pass in 0..3 {
        let shift = pass * BITS;
        let mut count = [0usize; BUCKETS];
        for &c in &codes {
            count[((c >> shift) as usize) & (BUCKETS - 1)] += 1;
        }
        if count.contains(&n) {
            continue; // every key has the same digit: nothing moves
        }
        let mut sum = 0;
        for c in count.iter_mut() {
            (*c, sum) = (sum, sum + *c);
        }
        for i in 0..n {
            let d = ((codes[i] >> shift) as usize) & (BUCKETS - 1);
            codes2[count[d]] = codes[i];
            idx2[count[d]] = idx[i];
            count[d] += 1;
        }
        std::mem::swap(&mut codes, &mut codes2);
        std::mem::swap(&mut idx, &mut idx2);
    }
    idx
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dti::eigen::{Eigen, from_eigen};

    fn lcg(state: &mut u64) -> f64 {
        *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (*state >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn radix_argsort_matches_a_stable_comparison_sort() {
        let mut st = 7;
        let mut keys: Vec<f32> = (0..50_000).map(|_| ((lcg(&mut st) - 0.5) * 1e4) as f32).collect();
        keys.extend([0.0, -0.0, f32::INFINITY, f32::NEG_INFINITY, f32::NAN, 1e-40, -1e-40, 3.0, 3.0]);
        let got = argsort_desc(&keys);
        let mut want: Vec<u32> = (0..keys.len() as u32).collect();
        // -0.0 and 0.0 differ in bits: the radix sort orders +0 before -0, as total_cmp does.
        want.sort_by(|&a, &b| {
            let (x, y) = (keys[a as usize], keys[b as usize]);
            match (x.is_nan(), y.is_nan()) {
                (true, true) => std::cmp::Ordering::Equal,
                (true, false) => std::cmp::Ordering::Greater,
                (false, true) => std::cmp::Ordering::Less,
                _ => y.total_cmp(&x),
            }
        });
        assert_eq!(got, want);
        assert!(argsort_desc(&[]).is_empty());
    }

    #[test]
    fn lit_tensor_closed_forms() {
        let lit = LitTensor { ambient: 0.0, diffuse: 1.0, specular: 1.0, shininess: 4.0 };
        let linear = tensor_splat(DVec3::ZERO, &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], 1.0, DVec3::ONE, 1.0).unwrap();
        assert_eq!(linear.shape(), [1.0, 0.0, 0.0]);
        // Seen side-on a line is fully lit; along its axis, dark; at 60 degrees, sin 60.
        assert!((lit.factors(&linear, DVec3::Y).0 - 1.0).abs() < 1e-15);
        assert!(lit.factors(&linear, DVec3::X).0.abs() < 1e-15);
        let v = DVec3::new(0.5, 0.75f64.sqrt(), 0.0);
        let (d, s) = lit.factors(&linear, v);
        assert!((d - 0.75f64.sqrt()).abs() < 1e-15 && (s - 0.75f64.powi(2)).abs() < 1e-15);
        // A planar tensor (disc in xy) is lit by |l . e3| = |l . z|.
        let planar = tensor_splat(DVec3::ZERO, &[1.0, 0.0, 1.0, 0.0, 0.0, 0.0], 1.0, DVec3::ONE, 1.0).unwrap();
        assert!((planar.shape()[1] - 1.0).abs() < 1e-15);
        let v = DVec3::new(0.6, 0.0, 0.8);
        assert!((lit.factors(&planar, v).0 - 0.8).abs() < 1e-12);
        // A sphere is lit fully from anywhere, without a highlight.
        let sphere = tensor_splat(DVec3::ZERO, &[1.0, 0.0, 1.0, 0.0, 0.0, 1.0], 1.0, DVec3::ONE, 1.0).unwrap();
        assert_eq!(lit.factors(&sphere, v), (1.0, 0.0));
    }

    #[test]
    fn boxed_compositor_equals_the_per_pixel_sum() {
        let mut st = 11;
        let splats: Vec<Splat> = (0..60)
            .filter_map(|_| {
                let a = DVec3::new(lcg(&mut st), lcg(&mut st), lcg(&mut st)).normalize();
                let b = a.any_orthonormal_vector();
                let t =
                    from_eigen(&Eigen { values: [1.0, lcg(&mut st), 0.1 * lcg(&mut st)], vectors: [a, b, a.cross(b)] });
                let c = DVec3::new(lcg(&mut st) * 4.0 - 2.0, lcg(&mut st) * 3.0 - 1.5, lcg(&mut st) - 0.5);
                tensor_splat(c, &t, 0.4, DVec3::new(lcg(&mut st), lcg(&mut st), 0.5), 0.8)
            })
            .collect();
        let cam = SplatCamera {
            view_from_world: DMat4::look_at_rh(DVec3::new(0.3, -1.0, 6.0), DVec3::ZERO, DVec3::Y),
            fov_y: 0.8,
            width: 64,
            height: 48,
        };
        for render in [SplatRender::default(), SplatRender { attenuation: true, lighting: Some(LitTensor::default()) }]
        {
            let got = composite(&splats, &cam, &render, DVec3::splat(0.1));
            // Brute force: every splat at every pixel, far to near.
            let eye = cam.eye();
            let mut fp: Vec<_> = splats
                .iter()
                .filter_map(|s| {
                    let c = render.lighting.map_or(s.colour, |l| l.shade(s, (eye - s.centre).normalize()));
                    cam.project(s, render.attenuation).map(|f| (f, c))
                })
                .collect();
            fp.sort_by(|a, b| b.0.depth.total_cmp(&a.0.depth));
            for (i, px) in got.iter().enumerate() {
                let q = DVec2::new((i % 64) as f64 + 0.5, (i / 64) as f64 + 0.5);
                let want = fp.iter().fold(DVec3::splat(0.1), |acc, (f, c)| {
                    let a = f.alpha(q);
                    a * *c + (1.0 - a) * acc
                });
                assert!((want - *px).length() < 1e-12, "pixel {i}");
            }
            assert!(got.iter().filter(|p| (**p - DVec3::splat(0.1)).length() > 1e-3).count() > 300);
        }
    }

    #[test]
    fn colourings() {
        let mut s = tensor_splat(DVec3::ZERO, &[1.0, 0.0, 0.2, 0.0, 0.0, 0.1], 1.0, DVec3::ZERO, 0.0).unwrap();
        let fa = s.fa();
        SplatColouring { mode: SplatColourMode::Direction, ..Default::default() }.apply(std::slice::from_mut(&mut s));
        assert!((s.colour - DVec3::X * fa).length() < 1e-12 && (s.opacity - fa).abs() < 1e-12);
        let c = SplatColouring { mode: SplatColourMode::Barycentric, ..Default::default() };
        let want = c.tf.eval(westin(&s.values, WestinDenominator::Trace), None);
        assert_eq!(c.style(&s, None), want);
    }
}
