//! Tensor splatting (SEEDS.md §1): each tensor sample a 3D Gaussian with covariance `scale² · T / l1`
//! (its largest standard deviation is `scale`), projected to a 2D Gaussian footprint with the local affine
//! approximation of the perspective projection (EWA, Zwicker et al. 2001), composited back to front with the
//! "over" operator. This module is the f64 reference of `shaders/tensor_splat.wgsl`.
//!
//! - View-space covariance `V = W Σ Wᵀ` (W the view rotation); footprint covariance in pixels
//!   `V2 = J V Jᵀ + ε I`, with J the Jacobian of the pixel projection at the centre and ε = [`DILATION_PX2`]
//!   (a small screen-space low-pass so needle-thin splats still cover a pixel, as EWA does).
//! - Opacity at pixel offset d: `α = α0 · exp(-½ dᵀ V2⁻¹ d)`, zero beyond 3 standard deviations
//!   (`dᵀ V2⁻¹ d > 9`), with `α0 = opacity · exp(-2 K sqrt(V_zz))` when depth attenuation is on
//!   (`K = -ln 0.25`) and `opacity` otherwise.
//! - Compositing: splats sorted by the view depth of their centres, far to near; `C = α c + (1 - α) C`.

use glam::{DMat3, DMat4, DVec2, DVec3};

/// Screen-space dilation added to every footprint, pixels².
pub const DILATION_PX2: f64 = 0.3;
/// The seed's depth-attenuation constant, `-ln 0.25`.
pub const ATTENUATION_K: f64 = 1.3862943611198906;

/// One splat in world space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Splat {
    pub centre: DVec3,
    /// World covariance (mm²).
    pub cov: DMat3,
    /// Linear RGB.
    pub colour: DVec3,
    pub opacity: f64,
}

/// A splat of tensor `t` (world frame): covariance `scale² · t / l1`; `None` for a tensor with no positive
/// eigenvalue or non-finite input.
pub fn tensor_splat(centre: DVec3, t: &super::LowerTri, scale: f64, colour: DVec3, opacity: f64) -> Option<Splat> {
    let e = super::eigh(t)?;
    let l1 = e.values[0];
    if !(l1 > 0.0 && centre.is_finite()) {
        return None;
    }
    let k = scale * scale / l1;
    let m = DMat3::from_cols_array(&[t[0], t[1], t[3], t[1], t[2], t[4], t[3], t[4], t[5]]) * k;
    Some(Splat { centre, cov: m, colour, opacity })
}

/// A pinhole camera as Bevy's: looks down -z of its view frame, vertical field of view `fov_y`, pixel
/// (0, 0) at the top left.
#[derive(Clone, Copy, Debug)]
pub struct SplatCamera {
    pub view_from_world: DMat4,
    pub fov_y: f64,
    pub width: u32,
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
    pub alpha0: f64,
}

impl SplatCamera {
    /// Focal length in pixels.
    pub fn focal(&self) -> f64 {
        self.height as f64 / 2.0 / (self.fov_y / 2.0).tan()
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
        let alpha0 =
            if attenuation { s.opacity * (-2.0 * ATTENUATION_K * v.z_axis.z.max(0.0).sqrt()).exp() } else { s.opacity };
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
}

/// The reference image: linear RGB per pixel (row-major, top row first) of the splats composited far to
/// near over `background`, sampled at pixel centres.
pub fn composite(splats: &[Splat], cam: &SplatCamera, attenuation: bool, background: DVec3) -> Vec<DVec3> {
    let mut fp: Vec<(Footprint, DVec3)> =
        splats.iter().filter_map(|s| cam.project(s, attenuation).map(|f| (f, s.colour))).collect();
    fp.sort_by(|a, b| b.0.depth.total_cmp(&a.0.depth));
    let mut out = vec![background; (cam.width * cam.height) as usize];
    for (i, px) in out.iter_mut().enumerate() {
        let q = DVec2::new((i as u32 % cam.width) as f64 + 0.5, (i as u32 / cam.width) as f64 + 0.5);
        for (f, c) in &fp {
            let a = f.alpha(q);
            if a > 0.0 {
                *px = a * *c + (1.0 - a) * *px;
            }
        }
    }
    out
}
