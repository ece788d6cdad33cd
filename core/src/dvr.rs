//! Direct volume rendering (SEEDS.md §2, the context layer): the f64 reference of `plugins/volume/src/shaders/volume.wgsl`.
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
    /// Position in [0, 1] of the value range.
    pub x: f64,
    /// Linear RGB and opacity per `UNIT_MM`.
    pub rgba: [f64; 4],
}

/// A 1D transfer function over the value range `[lo, hi]`.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TransferFunction {
    /// The value range `[lo, hi]` mapped to `x` in [0, 1], in the volume's units. Defaults to `[0, 1]`.
    pub range: [f64; 2],
    /// Control points, in any order (sorted by `x` on evaluation); values outside them take the nearest
    /// point's. Defaults to the FA context ramp of five points.
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
    /// Linear RGB and opacity per `UNIT_MM` at evenly spaced normalised positions `i / (len - 1)`;
    /// [`LUT_SIZE`] of them from [`TransferFunction::lut`].
    pub entries: Vec<[f64; 4]>,
    /// The value range `[lo, hi]` the entries span, in the volume's units.
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
    /// Lower fractions per voxel axis (x, y, z), clamped to [0, 1]. Defaults to `[0, 0, 0]`.
    pub min: [f64; 3],
    /// Upper fractions per voxel axis (x, y, z), clamped to [0, 1]. Defaults to `[1, 1, 1]`.
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
    /// The field between voxels: trilinear (None), or linear on the tetrahedra of cell projection (cells of
    /// this many voxels, six Kuhn tetrahedra each; see [`sample_tetrahedral`]).
    pub tetrahedra: Option<usize>,
}

impl Default for MarchParams {
    fn default() -> Self {
        Self {
            step: 0.5,
            termination: 0.99,
            preintegrated: false,
            clip: ClipBox::default(),
            shading: None,
            tetrahedra: None,
        }
    }
}

/// The lattice of cell projection along an axis of `d` voxels at cell edge `cell`: -0.5, 0, cell, 2 cell, ...,
/// d - 1, d - 0.5 (voxel coordinates; the outer half voxels take the edge voxels' values, as [`sample`]'s
/// clamping).
pub fn tet_lattice(d: usize, cell: usize) -> Vec<f64> {
    let top = d.max(1) as f64 - 1.0;
    let mut lines = vec![-0.5];
    let mut x = 0.0;
    while x < top {
        lines.push(x);
        x += cell.max(1) as f64;
    }
    lines.push(top);
    lines.push(top + 0.5);
    lines
}

/// The field at `p` (voxel coordinates) linear on the tetrahedra of cell projection: the cell of the lattice
/// ([`tet_lattice`]) holding `p`, cut into the six Kuhn tetrahedra `u_a >= u_b >= u_c` (u the cell's unit
/// coordinates); in each, the linear function through its four corners' voxel values.
pub fn sample_tetrahedral(vol: &Volume<f32>, p: DVec3, cell: usize) -> f64 {
    let d = vol.dims3();
    let mut corner = [0usize; 3];
    let mut size = [0usize; 3];
    let mut u = [0.0; 3];
    let mut lines: [Vec<f64>; 3] = Default::default();
    for k in 0..3 {
        lines[k] = tet_lattice(d[k], cell);
        let l = &lines[k];
        let x = p[k].clamp(l[0], l[l.len() - 1]);
        let j = l.partition_point(|v| *v <= x).clamp(1, l.len() - 1) - 1;
        corner[k] = j;
        size[k] = 1;
        u[k] = (x - l[j]) / (l[j + 1] - l[j]);
    }
    let value = |o: [usize; 3]| {
        let idx: [usize; 3] =
            std::array::from_fn(|k| lines[k][corner[k] + o[k]].round().clamp(0.0, d[k] as f64 - 1.0) as usize);
        vol.data[idx[0] + d[0] * (idx[1] + d[1] * idx[2])] as f64
    };
    let mut axes = [0usize, 1, 2];
    axes.sort_by(|a, b| u[*b].total_cmp(&u[*a]));
    let mut o = [0usize; 3];
    let mut v = value(o);
    let mut out = v;
    for a in axes {
        o[a] = size[a];
        let next = value(o);
        out += (next - v) * u[a];
        v = next;
    }
    out
}

/// The voxel axis whose planes face the view direction `forward` (world) most: 2D slicing's and splatting's
/// stack (ties as the shader breaks them).
pub fn principal_axis(voxel_from_world: DMat4, forward: DVec3) -> usize {
    let m = voxel_from_world;
    let c: [f64; 3] = std::array::from_fn(|k| {
        let row = DVec3::new(m.x_axis[k], m.y_axis[k], m.z_axis[k]);
        forward.normalize().dot(row.normalize()).abs()
    });
    if c[0] >= c[1].max(c[2]) {
        0
    } else if c[1] >= c[2] {
        1
    } else {
        2
    }
}

/// Shear-warp's geometry for one view: the principal axis, the voxel planes in front of the eye in
/// compositing order, and the intermediate image on the first of them (the base plane). Shared by the GPU
/// pass (`fascicle-volume`) and its f64 twin ([`shear_warp_image`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShearWarpView {
    /// The axis whose planes face the view most ([`principal_axis`]).
    pub axis: usize,
    /// Perspective: the eye in voxel coordinates; orthographic: None.
    pub eye: Option<DVec3>,
    /// The view direction in voxel coordinates (the rays' direction when orthographic).
    pub direction: DVec3,
    /// The base plane (voxel coordinate along `axis`) the intermediate image lies on: the first plane.
    pub base: f64,
    /// First plane, step between planes (+1 or -1), number of planes.
    pub first: f64,
    /// Step from one composited plane to the next along `axis`: +1 or -1 (voxels), front to back.
    pub step: f64,
    /// Number of planes composited (0 when none is in front of the eye).
    pub planes: usize,
    /// The intermediate image: the in-plane coordinates (the axes after `axis`, cyclically) of its first
    /// pixel's corner, its pixel size (voxels), its size in pixels (0 when no plane is in front of the eye).
    pub origin: glam::DVec2,
    /// Size of an intermediate pixel along the two in-plane axes (voxels); 1 when no plane is in front.
    pub spacing: glam::DVec2,
    /// Intermediate image width and height (pixels), `[0, 0]` when no plane is in front of the eye.
    pub size: [u32; 2],
}

/// Shear-warp's geometry ([`ShearWarpView`]) for a volume of `dims` seen from `eye` (world; None:
/// orthographic) along `forward` (world), drawing the voxel box `clip` (lo, hi), at `per_voxel` intermediate
/// pixels per voxel on an image of at most `edge`² pixels (coarser when the sheared volume needs more). In
/// perspective only the planes at least half a voxel in front of the eye are composited.
pub fn shear_warp_view(
    dims: [usize; 3],
    voxel_from_world: DMat4,
    eye: Option<DVec3>,
    forward: DVec3,
    clip: (DVec3, DVec3),
    per_voxel: f64,
    edge: u32,
) -> ShearWarpView {
    let axis = principal_axis(voxel_from_world, forward);
    let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
    let direction = voxel_from_world.transform_vector3(forward);
    let eye = eye.map(|e| voxel_from_world.transform_point3(e));
    let step = if direction[axis] >= 0.0 { 1.0 } else { -1.0 };
    let top = dims[axis].max(1) as f64 - 1.0;
    let (mut first, last) = if step > 0.0 { (0.0, top) } else { (top, 0.0) };
    if let Some(e) = eye {
        first = if step > 0.0 { (e[axis] + 0.5).ceil().max(first) } else { (e[axis] - 0.5).floor().min(first) };
    }
    let planes = ((last - first) * step + 1.0).max(0.0) as usize;
    let mut view = ShearWarpView {
        axis,
        eye,
        direction,
        base: first,
        first,
        step,
        planes,
        origin: glam::DVec2::ZERO,
        spacing: glam::DVec2::ONE,
        size: [0, 0],
    };
    if planes == 0 {
        return view;
    }
    // The image covers the clip box's face on the base plane and the far plane's face projected onto it.
    let (lo, hi) = clip;
    let mut min = glam::DVec2::splat(f64::INFINITY);
    let mut max = glam::DVec2::splat(f64::NEG_INFINITY);
    for c in 0..4 {
        let uw = glam::DVec2::new(if c & 1 == 0 { lo[u] } else { hi[u] }, if c & 2 == 0 { lo[w] } else { hi[w] });
        let mut far = DVec3::ZERO;
        far[axis] = last;
        far[u] = uw.x;
        far[w] = uw.y;
        let on_base = view.to_base(far);
        for p in [uw, glam::DVec2::new(on_base[u], on_base[w])] {
            min = min.min(p);
            max = max.max(p);
        }
    }
    let extent = (max - min).max(glam::DVec2::splat(1e-6));
    let per_voxel = per_voxel.clamp(0.25, 4.0);
    let edge = f64::from(edge.max(1));
    let spacing = (extent / edge).max(glam::DVec2::splat(1.0 / per_voxel));
    let size = (extent / spacing).ceil();
    view.origin = min;
    view.spacing = spacing;
    view.size = [size.x.min(edge) as u32, size.y.min(edge) as u32];
    view
}

impl ShearWarpView {
    /// Where the ray through `p` (from the eye, or along the view) meets the base plane.
    pub fn to_base(&self, p: DVec3) -> DVec3 {
        let k = self.axis;
        match self.eye {
            Some(e) => e + (p - e) * ((self.base - e[k]) / (p[k] - e[k])),
            None => p + self.direction * ((self.base - p[k]) / self.direction[k]),
        }
    }
}

/// The f64 twin of shear-warp's compositing pass: the intermediate image (premultiplied RGBA, row major,
/// `view.size`), each pixel's ray crossing the planes front to back, each plane sampled bilinearly in its
/// plane (clamped to the edge voxels), post-classified over the planes' spacing along the ray, stopping at
/// `termination`; samples outside `clip` are skipped. Whole rays: opaque surfaces are the warp's business
/// (a pixel whose ray meets one inside the volume is marched instead of warped).
pub fn shear_warp_image(
    vol: &Volume<f32>,
    lut: &Lut,
    view: &ShearWarpView,
    clip: (DVec3, DVec3),
    termination: f64,
) -> Vec<DVec4> {
    let dims = vol.dims3();
    let k = view.axis;
    let (u, w) = ((k + 1) % 3, (k + 2) % 3);
    let at = |idx: [usize; 3]| vol.data[idx[0] + dims[0] * (idx[1] + dims[1] * idx[2])] as f64;
    let mm = vol.world_from_voxel;
    let [sx, sy] = view.size.map(|s| s as usize);
    let mut out = vec![DVec4::ZERO; sx * sy];
    for (i, px) in out.iter_mut().enumerate() {
        let mut b = DVec3::ZERO;
        b[k] = view.base;
        b[u] = view.origin.x + ((i % sx) as f64 + 0.5) * view.spacing.x;
        b[w] = view.origin.y + ((i / sx) as f64 + 0.5) * view.spacing.y;
        let d = match view.eye {
            Some(e) => b - e,
            None => view.direction,
        };
        let per_plane = d / d[k].abs();
        let length = mm.transform_vector3(per_plane).length();
        let mut acc = DVec4::ZERO;
        for n in 0..view.planes {
            let c = view.first + view.step * n as f64;
            let p = b + per_plane * (c - view.base) * d[k].signum();
            if p.cmplt(clip.0).any() || p.cmpgt(clip.1).any() {
                continue;
            }
            let fu = p[u].clamp(0.0, dims[u] as f64 - 1.0);
            let fw = p[w].clamp(0.0, dims[w] as f64 - 1.0);
            let (iu, iw) = (fu.floor() as usize, fw.floor() as usize);
            let (tu, tw) = (fu - iu as f64, fw - iw as f64);
            let voxel = |a: usize, b: usize| {
                let mut idx = [0usize; 3];
                idx[k] = c as usize;
                idx[u] = a.min(dims[u] - 1);
                idx[w] = b.min(dims[w] - 1);
                at(idx)
            };
            let v0 = voxel(iu, iw) * (1.0 - tu) + voxel(iu + 1, iw) * tu;
            let v1 = voxel(iu, iw + 1) * (1.0 - tu) + voxel(iu + 1, iw + 1) * tu;
            let cl = lut.eval(v0 * (1.0 - tw) + v1 * tw);
            let a = 1.0 - (1.0 - cl.w.clamp(0.0, 1.0)).powf(length / UNIT_MM);
            acc += (1.0 - acc.w) * (cl.truncate() * a).extend(a);
            if acc.w >= termination {
                break;
            }
        }
        *px = acc;
    }
    out
}

/// The warp: the intermediate `image` read bilinearly where the ray `origin + t dir` (world) meets the base
/// plane (zero off the image).
pub fn shear_warp_pixel(
    view: &ShearWarpView,
    image: &[DVec4],
    voxel_from_world: DMat4,
    origin: DVec3,
    dir: DVec3,
) -> DVec4 {
    let (o, d) = (voxel_from_world.transform_point3(origin), voxel_from_world.transform_vector3(dir));
    let k = view.axis;
    let (u, w) = ((k + 1) % 3, (k + 2) % 3);
    if d[k].abs() < 1e-12 || view.size[0] == 0 {
        return DVec4::ZERO;
    }
    let b = o + d * ((view.base - o[k]) / d[k]);
    let x = (b[u] - view.origin.x) / view.spacing.x - 0.5;
    let y = (b[w] - view.origin.y) / view.spacing.y - 0.5;
    let (sx, sy) = (view.size[0] as f64, view.size[1] as f64);
    if x < -0.5 || y < -0.5 || x > sx - 0.5 || y > sy - 0.5 {
        return DVec4::ZERO;
    }
    let (x0, y0) = (x.floor(), y.floor());
    let texel = |i: f64, j: f64| {
        let (i, j) = (i.clamp(0.0, sx - 1.0) as usize, j.clamp(0.0, sy - 1.0) as usize);
        image[i + view.size[0] as usize * j]
    };
    let (fx, fy) = (x - x0, y - y0);
    let top = texel(x0, y0) * (1.0 - fx) + texel(x0 + 1.0, y0) * fx;
    let bottom = texel(x0, y0 + 1.0) * (1.0 - fx) + texel(x0 + 1.0, y0 + 1.0) * fx;
    top * (1.0 - fy) + bottom * fy
}

/// The f64 twin of voxel splatting (the shader's sheets): along the ray, each voxel plane of `axis` in turn,
/// front to back; in each, the plane's voxels within the kernel's radius of the ray's crossing, classified
/// one by one and weighted by `exp(-r²/2σ²)` (r the voxel's distance to the ray in voxel space: its kernel's
/// integral along the ray, up to a constant the normalisation removes); the sheet's opacity
/// `1 - exp(-τ̄ / |d_axis|)` from the weighted mean extinction τ̄ over the planes' spacing along the ray, its
/// colour the extinction-weighted mean. No early termination or shading.
#[allow(clippy::too_many_arguments, reason = "the ray, its stop, and the method's knobs")]
pub fn splat_march(
    vol: &Volume<f32>,
    voxel_from_world: DMat4,
    lut: &Lut,
    origin: DVec3,
    dir: DVec3,
    t_stop: f64,
    axis: usize,
    sigma: f64,
    clip: &ClipBox,
) -> DVec4 {
    let dims = vol.dims3();
    let o = voxel_from_world.transform_point3(origin);
    let d = voxel_from_world.transform_vector3(dir);
    if d[axis].abs() < 1e-12 {
        return DVec4::ZERO;
    }
    let (lo, hi) = clip.voxel_bounds(dims);
    let (u, w) = ((axis + 1) % 3, (axis + 2) % 3);
    let radius = (3.0 * 1.8 * sigma).ceil().clamp(1.0, 3.0) as i64;
    let dn = d.normalize();
    let mut planes: Vec<usize> = (0..dims[axis]).collect();
    if d[axis] < 0.0 {
        planes.reverse();
    }
    let mut acc = DVec4::ZERO;
    for c in planes {
        let t = (c as f64 - o[axis]) / d[axis];
        let q = o + d * t;
        if t <= 0.0 || t >= t_stop || q.cmplt(lo).any() || q.cmpgt(hi).any() {
            continue;
        }
        let (cu, cw) = (q[u].round() as i64, q[w].round() as i64);
        let (mut tau, mut rgb, mut weight) = (0.0, DVec3::ZERO, 0.0);
        for i in -radius..=radius {
            for j in -radius..=radius {
                let (vu, vw) = (cu + i, cw + j);
                if vu < 0 || vw < 0 || vu > dims[u] as i64 - 1 || vw > dims[w] as i64 - 1 {
                    continue;
                }
                let mut v = q;
                v[u] = vu as f64;
                v[w] = vw as f64;
                let rel = v - q;
                let along = rel.dot(dn);
                let f = (-(rel.length_squared() - along * along) / (2.0 * sigma * sigma)).exp();
                let mut idx = [0usize; 3];
                idx[axis] = c;
                idx[u] = vu as usize;
                idx[w] = vw as usize;
                let cl = lut.eval(vol.data[idx[0] + dims[0] * (idx[1] + dims[1] * idx[2])] as f64);
                let e = -(1.0 - cl.w.min(0.999999)).ln() / UNIT_MM;
                tau += f * e;
                rgb += f * e * cl.truncate();
                weight += f;
            }
        }
        if weight <= 0.0 || tau <= 0.0 {
            continue;
        }
        let alpha = 1.0 - (-(tau / weight) / d[axis].abs()).exp();
        acc += (1.0 - acc.w) * (rgb / tau * alpha).extend(alpha);
    }
    acc
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
    let sample = |vol: &Volume<f32>, p: DVec3| match params.tetrahedra {
        Some(cell) => sample_tetrahedral(vol, p, cell),
        None => sample(vol, p),
    };
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
    #[test]
    fn tetrahedral_field_is_exact_on_linear_fields_and_interpolates_the_corners() {
        let dims = [7usize, 6, 5];
        let mut v = Volume::zeros(&dims, DMat4::IDENTITY);
        let f = |p: DVec3| 0.3 * p.x - 0.7 * p.y + 1.1 * p.z + 2.0;
        for z in 0..5 {
            for y in 0..6 {
                for x in 0..7 {
                    v.data[x + 7 * (y + 6 * z)] = f(DVec3::new(x as f64, y as f64, z as f64)) as f32;
                }
            }
        }
        for cell in [1, 2, 3] {
            for p in [DVec3::new(1.3, 2.7, 0.4), DVec3::new(5.9, 0.1, 3.6), DVec3::new(2.5, 4.25, 1.75)] {
                let t = sample_tetrahedral(&v, p, cell);
                assert!((t - f(p)).abs() < 1e-5, "cell {cell} at {p}: {t} against {}", f(p));
                assert!((t - sample(&v, p)).abs() < 1e-5);
            }
        }
        // A non-linear field: the corners are the voxels; inside, between the corners' extremes and away
        // from trilinear (they are different interpolants).
        for (i, x) in v.data.iter_mut().enumerate() {
            let p = [i % 7, (i / 7) % 6, i / 42].map(|c| c as f64);
            *x = (p[0] * p[1] * p[2]) as f32;
        }
        assert_eq!(sample_tetrahedral(&v, DVec3::new(2.0, 3.0, 4.0), 1), 24.0);
        assert_eq!(sample_tetrahedral(&v, DVec3::new(4.0, 4.0, 2.0), 2), 32.0);
        let p = DVec3::new(2.2, 3.7, 1.5);
        let t = sample_tetrahedral(&v, p, 1);
        assert!((2.0 * 3.0 * 1.0..=3.0 * 4.0 * 2.0).contains(&t), "{t}");
        assert!((t - sample(&v, p)).abs() > 0.05, "{t} against trilinear {}", sample(&v, p));
        // Beyond the last voxel centre the edge voxel's value holds (as the clamped trilinear sampler).
        assert_eq!(sample_tetrahedral(&v, DVec3::new(6.4, 5.3, 4.45), 2), sample(&v, DVec3::new(6.4, 5.3, 4.45)));
    }

    #[test]
    fn splatting_a_constant_field_gives_its_classified_value_at_any_kernel() {
        let dims = [12usize, 10, 9];
        let mut v = Volume::zeros(&dims, DMat4::from_scale(DVec3::new(1.5, 1.0, 2.0)));
        v.data.iter_mut().for_each(|x| *x = 0.6);
        let tf = TransferFunction {
            range: [0.0, 1.0],
            points: vec![
                TfPoint { x: 0.0, rgba: [0.0, 0.0, 0.0, 0.0] },
                TfPoint { x: 1.0, rgba: [1.0, 0.5, 0.25, 0.2] },
            ],
        };
        let lut = tf.lut();
        let inv = v.world_from_voxel.inverse();
        let (o, d) = (DVec3::new(-20.0, 4.0, 9.0), DVec3::new(1.0, 0.1, -0.05).normalize());
        let axis = principal_axis(inv, d);
        assert_eq!(axis, 0);
        // Exact: the sheets' spacing along the ray is 1 / |d_x| (1.5 mm of x per plane), 12 planes.
        let dv = inv.transform_vector3(d);
        let a = 1.0 - (1.0 - 0.12f64).powf(12.0 / dv.x.abs());
        for sigma in [0.3, 0.7, 1.5] {
            let c = splat_march(&v, inv, &lut, o, d, f64::INFINITY, axis, sigma, &ClipBox::default());
            assert!((c.w - a).abs() < 1e-6, "sigma {sigma}: alpha {} against {a}", c.w);
            assert!((c.x / c.w - 0.6).abs() < 1e-6 && (c.y / c.w - 0.3).abs() < 1e-6);
        }
    }

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
