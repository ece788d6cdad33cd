//! Direct volume rendering (SEEDS.md §2, the context layer): the f64 reference of `plugins/volume/shaders/volume.wgsl`.
//!
//! - Sampling: trilinear in voxel coordinates, clamped to the edge voxels' centres.
//! - Classification: a 1D transfer function (piecewise linear control points over the normalised value
//!   `u = (v - lo) / (hi - lo)`), tabulated into a [`Lut`] of `LUT_SIZE` entries read with linear
//!   interpolation, as the shader reads it. Opacity is given per unit length (`UNIT_MM`) and corrected per
//!   step: `α = 1 - (1 - a)^(Δt / unit)`.
//! - Compositing: front to back, premultiplied, `C += (1 - A) α c`, `A += (1 - A) α`, the last step
//!   shortened to end exactly at the exit (or at an opaque surface), early termination when `A` reaches a
//!   threshold.
//! - Pre-integration (Engel et al. 2001): a table over (front, back) sample values of the colour and opacity
//!   of a segment of length Δt along which the value varies linearly, so a thin feature of the transfer
//!   function between two samples is not missed.

use glam::{DMat4, DVec3, DVec4};

use crate::Volume;

/// Entries in a transfer function's lookup table.
pub const LUT_SIZE: usize = 256;
/// The length (mm) an entry's opacity refers to.
pub const UNIT_MM: f64 = 1.0;

/// One control point: position in [0, 1] of the value range, linear RGB and opacity per `UNIT_MM`.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TfPoint {
    pub x: f64,
    pub rgba: [f64; 4],
}

/// A 1D transfer function over the value range `[lo, hi]`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TransferFunction {
    pub range: [f64; 2],
    pub points: Vec<TfPoint>,
}

impl Default for TransferFunction {
    /// For FA as context: transparent below 0.15, then blue to yellow-white with growing, light opacity.
    fn default() -> Self {
        Self {
            range: [0.0, 1.0],
            points: vec![
                TfPoint { x: 0.0, rgba: [0.0, 0.0, 0.0, 0.0] },
                TfPoint { x: 0.15, rgba: [0.05, 0.1, 0.4, 0.0] },
                TfPoint { x: 0.4, rgba: [0.1, 0.4, 0.8, 0.01] },
                TfPoint { x: 0.7, rgba: [0.9, 0.7, 0.2, 0.03] },
                TfPoint { x: 1.0, rgba: [1.0, 1.0, 0.9, 0.08] },
            ],
        }
    }
}

impl TransferFunction {
    /// Colour and opacity at normalised position `u` (clamped), piecewise linear between the points.
    pub fn eval_normalised(&self, u: f64) -> [f64; 4] {
        let u = if u.is_finite() { u.clamp(0.0, 1.0) } else { 0.0 };
        let mut pts = self.points.clone();
        pts.sort_by(|a, b| a.x.total_cmp(&b.x));
        match pts.iter().position(|p| p.x >= u) {
            None => pts.last().map_or([0.0; 4], |p| p.rgba),
            Some(0) => pts[0].rgba,
            Some(i) => {
                let (a, b) = (pts[i - 1], pts[i]);
                let w = if b.x > a.x { (u - a.x) / (b.x - a.x) } else { 1.0 };
                std::array::from_fn(|k| a.rgba[k] + w * (b.rgba[k] - a.rgba[k]))
            }
        }
    }

    /// The lookup table the shader reads.
    pub fn lut(&self) -> Lut {
        Lut {
            entries: (0..LUT_SIZE).map(|i| self.eval_normalised(i as f64 / (LUT_SIZE - 1) as f64)).collect(),
            range: self.range,
        }
    }
}

/// A tabulated transfer function.
#[derive(Clone, Debug, PartialEq)]
pub struct Lut {
    pub entries: Vec<[f64; 4]>,
    pub range: [f64; 2],
}

impl Lut {
    /// Normalised position of a value.
    pub fn u(&self, v: f64) -> f64 {
        let span = self.range[1] - self.range[0];
        if span > 0.0 && v.is_finite() { ((v - self.range[0]) / span).clamp(0.0, 1.0) } else { 0.0 }
    }

    /// Linear interpolation between entries.
    pub fn eval(&self, v: f64) -> DVec4 {
        let x = self.u(v) * (self.entries.len() - 1) as f64;
        let i = (x.floor() as usize).min(self.entries.len() - 2);
        let w = x - i as f64;
        DVec4::from_array(self.entries[i]).lerp(DVec4::from_array(self.entries[i + 1]), w)
    }

    /// f32 bytes, four per entry, for the GPU.
    pub fn to_bytes(&self) -> Vec<u8> {
        self.entries.iter().flatten().flat_map(|v| (*v as f32).to_le_bytes()).collect()
    }
}

/// Trilinear sample at voxel coordinates `p`, clamped to the edge voxels' centres.
pub fn sample(vol: &Volume<f32>, p: DVec3) -> f64 {
    let d = vol.dims3();
    let q = p.clamp(DVec3::ZERO, DVec3::new(d[0] as f64 - 1.0, d[1] as f64 - 1.0, d[2] as f64 - 1.0));
    let i = q.floor();
    let f = q - i;
    let i = [i.x as usize, i.y as usize, i.z as usize];
    let at = |x: usize, y: usize, z: usize| {
        let (x, y, z) = (x.min(d[0] - 1), y.min(d[1] - 1), z.min(d[2] - 1));
        vol.data[x + d[0] * (y + d[1] * z)] as f64
    };
    let mut v = 0.0;
    for (dz, wz) in [(0, 1.0 - f.z), (1, f.z)] {
        for (dy, wy) in [(0, 1.0 - f.y), (1, f.y)] {
            for (dx, wx) in [(0, 1.0 - f.x), (1, f.x)] {
                v += wx * wy * wz * at(i[0] + dx, i[1] + dy, i[2] + dz);
            }
        }
    }
    v
}

/// The part of a volume that is drawn: along each voxel axis, the fractions `min..max` of its extent
/// (`0..1` everything; `0..0.5` along x the first half of the columns).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct ClipBox {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Default for ClipBox {
    fn default() -> Self {
        Self { min: [0.0; 3], max: [1.0; 3] }
    }
}

impl ClipBox {
    /// The box in voxel coordinates: the volume `[-0.5, dim - 0.5]³` cut to the fractions.
    pub fn voxel_bounds(&self, dims: [usize; 3]) -> (DVec3, DVec3) {
        let d = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
        let (lo, hi) = (
            DVec3::from(self.min).clamp(DVec3::ZERO, DVec3::ONE),
            DVec3::from(self.max).clamp(DVec3::ZERO, DVec3::ONE),
        );
        (lo * d - 0.5, hi * d - 0.5)
    }
}

/// Ray-marching knobs (shared with the shader).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct MarchParams {
    /// Step length (mm).
    pub step: f64,
    /// Stop when the accumulated opacity reaches this (> 1: never).
    pub termination: f64,
    /// Pre-integrated classification instead of post-classification.
    pub preintegrated: bool,
    /// Only this part of the volume is marched.
    pub clip: ClipBox,
    /// Gradient shading: each sample's colour times `ambient + (1 - ambient) |ĝ · d̂|`, ĝ the value gradient by
    /// central differences one voxel apart and d̂ the ray direction (both in the voxel frame); 1 where the
    /// gradient vanishes.
    pub shading: Option<f64>,
}

impl Default for MarchParams {
    fn default() -> Self {
        Self { step: 0.5, termination: 0.99, preintegrated: false, clip: ClipBox::default(), shading: None }
    }
}

/// Entry and exit distances of a ray (voxel frame) through the clipped volume (with the default clip box,
/// the whole volume `[-0.5, dim - 0.5]³`); None on a miss.
pub fn clip_interval(dims: [usize; 3], clip: &ClipBox, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
    let (lo, hi) = clip.voxel_bounds(dims);
    let inv = d.recip();
    let (a, b) = ((lo - o) * inv, (hi - o) * inv);
    let (tmin, tmax) = (a.min(b), a.max(b));
    let t0 = tmin.max_element().max(0.0);
    let t1 = tmax.min_element();
    (t0 < t1).then_some((t0, t1))
}

/// Pre-integrated table: `n x n` entries (front value index major) of premultiplied (rgb, alpha) for a
/// segment of length `step` along which the normalised value goes linearly from `i/(n-1)` to `j/(n-1)`,
/// integrated with `sub` sub-steps.
pub fn preintegrate(lut: &Lut, n: usize, step: f64, sub: usize) -> Vec<DVec4> {
    let span = lut.range[1] - lut.range[0];
    let value = |u: f64| lut.range[0] + u * span;
    let mut out = Vec::with_capacity(n * n);
    for i in 0..n {
        for j in 0..n {
            let (uf, ub) = (i as f64 / (n - 1) as f64, j as f64 / (n - 1) as f64);
            let mut acc = DVec4::ZERO;
            for k in 0..sub {
                let u = uf + (ub - uf) * (k as f64 + 0.5) / sub as f64;
                let c = lut.eval(value(u));
                let a = 1.0 - (1.0 - c.w.clamp(0.0, 1.0)).powf(step / sub as f64 / UNIT_MM);
                acc += (1.0 - acc.w) * DVec4::new(c.x * a, c.y * a, c.z * a, a);
            }
            out.push(acc);
        }
    }
    out
}

/// Bilinear lookup in a pre-integrated table.
fn table_eval(table: &[DVec4], n: usize, uf: f64, ub: f64) -> DVec4 {
    let (x, y) = (uf * (n - 1) as f64, ub * (n - 1) as f64);
    let (i, j) = ((x.floor() as usize).min(n - 2), (y.floor() as usize).min(n - 2));
    let (fx, fy) = (x - i as f64, y - j as f64);
    let at = |a: usize, b: usize| table[a * n + b];
    at(i, j).lerp(at(i, j + 1), fy).lerp(at(i + 1, j).lerp(at(i + 1, j + 1), fy), fx)
}

/// `|ĝ · d̂|` at voxel position `q` (1 where the gradient vanishes): the headlight Lambert term of gradient
/// shading, as the shader computes it.
pub fn lambert(vol: &Volume<f32>, q: DVec3, d: DVec3) -> f64 {
    let g = DVec3::new(
        sample(vol, q + DVec3::X) - sample(vol, q - DVec3::X),
        sample(vol, q + DVec3::Y) - sample(vol, q - DVec3::Y),
        sample(vol, q + DVec3::Z) - sample(vol, q - DVec3::Z),
    );
    let len = g.length();
    if len > 1e-6 { (g / len).dot(d.normalize()).abs() } else { 1.0 }
}

/// What a ray marched through a volume accumulates: premultiplied linear RGB and opacity.
///
/// `voxel_from_world` maps world to voxel coordinates; the ray starts at `origin` with unit `dir` (world),
/// stops at the volume's exit or at `t_stop` (an opaque surface's distance), and its first sample is at
/// `jitter · step` past the entry. `table` is the pre-integrated table (with its size) when
/// `params.preintegrated`.
#[allow(
    clippy::too_many_arguments,
    reason = "the ray, its stop and the classification are all inputs of one sample loop"
)]
pub fn march(
    vol: &Volume<f32>,
    voxel_from_world: DMat4,
    lut: &Lut,
    table: Option<(&[DVec4], usize)>,
    origin: DVec3,
    dir: DVec3,
    t_stop: f64,
    params: &MarchParams,
    jitter: f64,
) -> DVec4 {
    let o = voxel_from_world.transform_point3(origin);
    let d = voxel_from_world.transform_vector3(dir);
    let Some((t0, t1)) = clip_interval(vol.dims3(), &params.clip, o, d) else { return DVec4::ZERO };
    let t1 = t1.min(t_stop);
    let step = params.step.max(1e-4);
    let mut acc = DVec4::ZERO;
    let mut t = t0 + jitter * step;
    let mut prev = sample(vol, o + d * t);
    while t < t1 {
        let dt = step.min(t1 - t);
        let c = match (params.preintegrated, table) {
            (true, Some((tab, n))) => {
                let next = sample(vol, o + d * (t + dt));
                let seg = table_eval(tab, n, lut.u(prev), lut.u(next));
                prev = next;
                // The table is for a full step; a shortened last step rescales its opacity.
                if dt < step {
                    let a = 1.0 - (1.0 - seg.w.min(1.0 - 1e-12)).powf(dt / step);
                    let s = if seg.w > 0.0 { a / seg.w } else { 0.0 };
                    DVec4::new(seg.x * s, seg.y * s, seg.z * s, a)
                } else {
                    seg
                }
            }
            _ => {
                let c = lut.eval(sample(vol, o + d * t));
                let a = 1.0 - (1.0 - c.w.clamp(0.0, 1.0)).powf(dt / UNIT_MM);
                DVec4::new(c.x * a, c.y * a, c.z * a, a)
            }
        };
        let c = match params.shading {
            Some(ambient) => {
                let k = ambient + (1.0 - ambient) * lambert(vol, o + d * t, d);
                DVec4::new(c.x * k, c.y * k, c.z * k, c.w)
            }
            None => c,
        };
        acc += (1.0 - acc.w) * c;
        if acc.w >= params.termination {
            break;
        }
        t += dt;
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;

    fn volume(dims: [usize; 3], f: impl Fn(usize, usize, usize) -> f32) -> Volume<f32> {
        let mut v = Volume::zeros(&dims, DMat4::IDENTITY);
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    v.data[x + dims[0] * (y + dims[1] * z)] = f(x, y, z);
                }
            }
        }
        v
    }

    #[test]
    fn trilinear_is_exact_on_linear_fields_and_clamps() {
        let v = volume([5, 6, 7], |x, y, z| (2 * x + 3 * y) as f32 - z as f32);
        for p in [DVec3::new(1.3, 2.7, 0.2), DVec3::new(3.99, 0.01, 5.5)] {
            assert!((sample(&v, p) - (2.0 * p.x + 3.0 * p.y - p.z)).abs() < 1e-5);
        }
        assert_eq!(sample(&v, DVec3::new(-3.0, -1.0, -2.0)), 0.0);
    }

    /// The same colour and opacity over the whole range.
    fn flat(range: [f64; 2], rgba: [f64; 4]) -> TransferFunction {
        TransferFunction { range, points: vec![TfPoint { x: range[0], rgba }, TfPoint { x: range[1], rgba }] }
    }

    #[test]
    fn constant_volume_matches_the_closed_form() {
        // A uniform slab: A = 1 - (1 - a)^(L / unit) for chord length L, colour c A, for any step.
        let v = volume([10, 10, 10], |_, _, _| 0.5);
        let lut = flat([0.0, 1.0], [0.2, 0.6, 0.4, 0.1]).lut();
        let origin = DVec3::new(-5.0, 4.2, 4.7);
        for step in [0.3, 0.77, 2.0] {
            let p = MarchParams { step, termination: 2.0, ..MarchParams::default() };
            let got = march(&v, DMat4::IDENTITY, &lut, None, origin, DVec3::X, f64::INFINITY, &p, 0.0);
            let a = 1.0 - 0.9f64.powf(10.0);
            assert!((got.w - a).abs() < 1e-12, "step {step}: {} vs {a}", got.w);
            assert!((got.y - 0.6 * a).abs() < 1e-12);
            // Stopping at an opaque surface 3 mm in: 3 mm of slab.
            let got = march(&v, DMat4::IDENTITY, &lut, None, origin, DVec3::X, 7.5, &p, 0.0);
            assert!((got.w - (1.0 - 0.9f64.powf(3.0))).abs() < 1e-12);
        }
    }

    #[test]
    fn clip_box_cuts_the_chord() {
        // The uniform slab cut to x in 0.2..0.7 of 10 voxels: a 5 mm chord instead of 10; cut away entirely
        // along y: nothing.
        let v = volume([10, 10, 10], |_, _, _| 0.5);
        let lut = flat([0.0, 1.0], [1.0, 1.0, 1.0, 0.1]).lut();
        let clip = ClipBox { min: [0.2, 0.0, 0.0], max: [0.7, 1.0, 1.0] };
        let p = MarchParams { step: 0.37, termination: 2.0, clip, ..MarchParams::default() };
        let origin = DVec3::new(-5.0, 4.2, 4.7);
        let got = march(&v, DMat4::IDENTITY, &lut, None, origin, DVec3::X, f64::INFINITY, &p, 0.0);
        assert!((got.w - (1.0 - 0.9f64.powf(5.0))).abs() < 1e-12, "{}", got.w);
        assert_eq!(clip_interval([10; 3], &clip, origin, DVec3::X), Some((6.5, 11.5)));
        let away = ClipBox { min: [0.0, 0.5, 0.0], max: [1.0, 1.0, 1.0] };
        assert_eq!(clip_interval([10; 3], &away, origin, DVec3::X), None);
        let p = MarchParams { clip: away, ..p };
        assert_eq!(march(&v, DMat4::IDENTITY, &lut, None, origin, DVec3::X, f64::INFINITY, &p, 0.0), DVec4::ZERO);
    }

    #[test]
    fn gradient_shading_is_the_headlight_lambert_term() {
        // A linear ramp along x: the gradient is +x everywhere inside (2 per two voxels), so a ray along x is
        // lit fully, one at 60 degrees by cos 60 = 0.5, one across the gradient only by the ambient term.
        let v = volume([12, 12, 12], |x, _, _| x as f32);
        let inside = DVec3::splat(5.5);
        assert!((lambert(&v, inside, DVec3::X) - 1.0).abs() < 1e-12);
        let d60 = DVec3::new(0.5, 0.75f64.sqrt(), 0.0);
        assert!((lambert(&v, inside, d60 * 3.0) - 0.5).abs() < 1e-12);
        assert!(lambert(&v, inside, DVec3::Y).abs() < 1e-12);
        // A constant volume has no gradient: unshaded.
        assert_eq!(lambert(&volume([4; 3], |_, _, _| 1.0), DVec3::splat(1.5), DVec3::Y), 1.0);
        // In the marcher: across the ramp, colour is ambient x unshaded colour; opacity is unchanged.
        let lut = flat([0.0, 11.0], [0.8, 0.4, 0.2, 0.05]).lut();
        let (o, d) = (DVec3::new(5.5, -3.0, 5.5), DVec3::Y);
        let plain = MarchParams { step: 0.5, termination: 2.0, ..MarchParams::default() };
        let lit = MarchParams { shading: Some(0.35), ..plain };
        let a = march(&v, DMat4::IDENTITY, &lut, None, o, d, f64::INFINITY, &plain, 0.0);
        let b = march(&v, DMat4::IDENTITY, &lut, None, o, d, f64::INFINITY, &lit, 0.0);
        assert!((b.w - a.w).abs() < 1e-15 && (b.x - 0.35 * a.x).abs() < 1e-12, "{a} {b}");
    }

    #[test]
    fn preintegration_beats_post_classification_as_the_step_grows() {
        // A thin opaque spike in the transfer function at u = 0.5, a value ramp along the ray: sparse
        // post-classified samples step over the spike; pre-integration does not.
        let v = volume([64, 4, 4], |x, _, _| x as f32 / 63.0);
        let tf = TransferFunction {
            range: [0.0, 1.0],
            points: vec![
                TfPoint { x: 0.0, rgba: [0.0; 4] },
                TfPoint { x: 0.49, rgba: [0.0; 4] },
                TfPoint { x: 0.5, rgba: [1.0, 0.5, 0.2, 0.9] },
                TfPoint { x: 0.51, rgba: [0.0; 4] },
                TfPoint { x: 1.0, rgba: [0.0; 4] },
            ],
        };
        let lut = tf.lut();
        let origin = DVec3::new(-3.0, 1.5, 1.5);
        let fine = MarchParams { step: 0.005, termination: 2.0, ..MarchParams::default() };
        let truth = march(&v, DMat4::IDENTITY, &lut, None, origin, DVec3::X, f64::INFINITY, &fine, 0.0);
        assert!(truth.w > 0.1);
        for step in [1.0, 2.0, 4.0] {
            let table = preintegrate(&lut, 128, step, 256);
            let mut worst = [0.0f64; 2];
            for j in 0..8 {
                let jitter = j as f64 / 8.0;
                for (k, pre) in [false, true].into_iter().enumerate() {
                    let p = MarchParams { step, termination: 2.0, preintegrated: pre, ..MarchParams::default() };
                    let got = march(
                        &v,
                        DMat4::IDENTITY,
                        &lut,
                        Some((&table, 128)),
                        origin,
                        DVec3::X,
                        f64::INFINITY,
                        &p,
                        jitter,
                    );
                    worst[k] = worst[k].max((got - truth).abs().max_element());
                }
            }
            assert!(worst[1] < 0.5 * worst[0] && worst[1] < 0.05, "step {step}: post {}, pre {}", worst[0], worst[1]);
        }
    }
}
