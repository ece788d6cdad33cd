//! f64 CPU references of the shared shader math (`shaders/lib/ray.wgsl`, `lighting.wgsl`) and of the
//! camera projection, so tests compare GPU images with an independent computation.

use glam::{DMat4, DVec3, DVec4};

/// A perspective camera as Bevy builds it: `clip_from_view` is an infinite reverse-Z perspective.
#[derive(Clone, Copy, Debug)]
pub struct PinholeCamera {
    /// Camera position, world.
    pub eye: DVec3,
    /// The world point the camera looks at (centre of the image).
    pub target: DVec3,
    /// World direction that appears upwards in the image (need not be unit or orthogonal to the view axis).
    pub up: DVec3,
    /// Vertical field of view, radians.
    pub fov_y: f64,
    /// Image width, pixels (with `height`, the aspect ratio).
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
}

impl PinholeCamera {
    /// The camera's pose: view space (right-handed, looking down -z, y up) to world, as Bevy's
    /// `Transform::looking_at`.
    pub fn world_from_view(&self) -> DMat4 {
        DMat4::look_at_rh(self.eye, self.target, self.up).inverse()
    }

    /// The world-space ray through the centre of pixel (px, py) (py = 0 at the top).
    pub fn pixel_ray(&self, px: u32, py: u32) -> (DVec3, DVec3) {
        self.subpixel_ray(px as f64 + 0.5, py as f64 + 0.5)
    }

    /// The ray through image position (x, y) in pixels from the top-left corner.
    pub fn subpixel_ray(&self, x: f64, y: f64) -> (DVec3, DVec3) {
        let aspect = self.width as f64 / self.height as f64;
        let ndc_x = x / self.width as f64 * 2.0 - 1.0;
        let ndc_y = 1.0 - y / self.height as f64 * 2.0;
        let t = (self.fov_y * 0.5).tan();
        let dir_view = DVec3::new(ndc_x * t * aspect, ndc_y * t, -1.0);
        let dir = self.world_from_view().transform_vector3(dir_view).normalize();
        (self.eye, dir)
    }

    /// Bevy's reverse-Z depth of a world point (infinite far plane, near `near`): `near / z_view`.
    pub fn depth(&self, p: DVec3, near: f64) -> f64 {
        let v = self.world_from_view().inverse() * DVec4::new(p.x, p.y, p.z, 1.0);
        near / -v.z
    }
}

/// `ray_sphere` of `ray.wgsl`: nearest positive hit distance.
pub fn ray_sphere(o: DVec3, d: DVec3, center: DVec3, radius: f64) -> Option<f64> {
    let oc = o - center;
    let b = oc.dot(d);
    let c = oc.dot(oc) - radius * radius;
    let h = b * b - c;
    if h < 0.0 {
        return None;
    }
    let s = h.sqrt();
    [-b - s, -b + s].into_iter().find(|&t| t > 0.0)
}

/// `ray_box` of `ray.wgsl`: entry distance of a hit with an axis-aligned box.
pub fn ray_box(o: DVec3, d: DVec3, lo: DVec3, hi: DVec3) -> Option<f64> {
    let inv = d.recip();
    let (a, b) = ((lo - o) * inv, (hi - o) * inv);
    let (tmin, tmax) = (a.min(b), a.max(b));
    let t0 = tmin.max_element().max(0.0);
    let t1 = tmax.min_element();
    (t0 <= t1).then_some(t0)
}

/// `headlight` of `lighting.wgsl`.
pub fn headlight(base: DVec3, n: DVec3, view_dir: DVec3, ambient: f64) -> DVec3 {
    base * (ambient + (1.0 - ambient) * n.normalize().dot(-view_dir).max(0.0))
}

/// Linear to sRGB-encoded 8-bit, as the GPU writes to an `Rgba8UnormSrgb` target.
pub fn srgb8(linear: f64) -> f64 {
    let c = linear.clamp(0.0, 1.0);
    let s = if c <= 0.0031308 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
    s * 255.0
}

/// The inverse of [`srgb8`]: an 8-bit sRGB value to linear 0..1.
pub fn srgb8_to_linear(v: u8) -> f64 {
    let c = v as f64 / 255.0;
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// A unit normal written as colour `n / 2 + 1/2` (unlit) and read back as sRGB8.
pub fn decode_normal(rgba: [u8; 4]) -> DVec3 {
    (DVec3::new(srgb8_to_linear(rgba[0]), srgb8_to_linear(rgba[1]), srgb8_to_linear(rgba[2])) * 2.0 - 1.0).normalize()
}
