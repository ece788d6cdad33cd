// Volume context (SEEDS.md section 2): direct volume rendering of a scalar 3D texture, by GPU ray casting
// (front to back, early termination, jittered start, post-classified or pre-integrated) or by one of the
// object-order methods, blended back to front: view-aligned 3D-texture slicing (Cabral et al.: planes facing
// the camera), 2D-texture slicing (the voxel planes of the axis nearest the view direction), voxel splatting
// (Westover's sheet buffer: Gaussian footprints summed per voxel plane) and cell projection (Shirley-Tuchman:
// six tetrahedra per cell in a per-view visibility order, pre-integrated). All
// stop at the depth of the opaque layers (a copy of the depth buffer taken after the opaque pass), so
// glyphs inside the volume hide what lies behind them and are tinted by what lies in front.
// The f64 reference is `fascicle_core::dvr`; keep `VolumeParams` in sync with `VolumeUniform` in
// `plugins/volume/src/lib.rs`.

#import bevy_pbr::mesh_view_bindings::view
#import fascicle::ray::{Ray, view_ray}

struct VolumeParams {
    voxel_from_world: mat4x4<f32>,
    world_from_voxel: mat4x4<f32>,
    // xyz: dimensions (voxels); w: method (0 ray casting, 1 slicing, 2 2D slicing, 3 splatting, 4 tetrahedra).
    dims: vec4<f32>,
    // World bounding sphere of the volume: centre, radius.
    sphere: vec4<f32>,
    // The clip box in voxel coordinates (xyz): what is drawn of the volume.
    clip_lo: vec4<f32>,
    clip_hi: vec4<f32>,
    // Cell projection: cells per voxel axis.
    cells: vec4<u32>,
    // Empty-space skipping: cells per voxel axis (xyz) of w voxels a side.
    grid: vec4<u32>,
    range: vec2<f32>,
    step: f32,
    termination: f32,
    jitter: u32,
    shading: u32,
    preintegrated: u32,
    n_slices: u32,
    table_n: u32,
    ambient: f32,
    // Splatting: the kernel's standard deviation (voxels). Cell projection: cell edge (voxels).
    kernel: f32,
    cell: u32,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: VolumeParams;
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var volume: texture_3d<f32>;
// 256 entries: linear rgb, opacity per mm.
@group(#{MATERIAL_BIND_GROUP}) @binding(2) var<storage, read> lut: array<vec4<f32>>;
// table_n x table_n pre-integrated segments (front value major), premultiplied.
@group(#{MATERIAL_BIND_GROUP}) @binding(3) var<storage, read> table: array<vec4<f32>>;
@group(#{MATERIAL_BIND_GROUP}) @binding(4) var opaque_depth: texture_depth_2d;
// Shear-warp: the intermediate image its compute pass wrote (`shear_warp.wgsl`), and where it lies.
@group(#{MATERIAL_BIND_GROUP}) @binding(5) var intermediate: texture_2d<f32>;
struct Warp {
    axis: u32,
    base: f32,
    size: vec2<u32>,
    origin: vec2<f32>,
    spacing: vec2<f32>,
};
@group(#{MATERIAL_BIND_GROUP}) @binding(6) var<storage, read> warp: Warp;
// Empty-space skipping: per cell of params.grid (x fastest), 0 where no sample or segment gathers anything
// (`fascicle_volume::empty_space`).
@group(#{MATERIAL_BIND_GROUP}) @binding(7) var<storage, read> occupancy: array<u32>;

const LUT_N: u32 = 256u;
const UNIT_MM: f32 = 1.0;
const MAX_STEPS: u32 = 8192u;

struct VolumeVertex {
    // Ray casting: a corner of the volume's box in world space. Slicing: (corner x, corner y, slice).
    @location(0) position: vec3<f32>,
};

struct VolumeVertexOutput {
    @builtin(position) clip_position: vec4<f32>,
    @location(0) world_position: vec3<f32>,
    // (0 ray casting, 1 view-aligned slices, 2 + k voxel planes of axis k, 5 + k splatting's sheets of axis k,
    // 8 tetrahedra; jitter; z and w unused: shading and pre-integration are shader defs, `VolumeKey`), flat: the
    // fragment stage branches on these, never on the uniform (the rule in `fascicle::ray`).
    @location(1) @interpolate(flat) modes: vec4<u32>,
    // Tetrahedra: the cell's low corner and size (voxels); the tetrahedron's axes (x_a >= x_b >= x_c inside
    // the cell) and splatting's kernel radius (voxels); the field at its four corners.
    @location(2) @interpolate(flat) cell_lo: vec4<f32>,
    @location(3) @interpolate(flat) cell_size: vec4<f32>,
    @location(4) @interpolate(flat) tet: vec4<u32>,
    @location(5) @interpolate(flat) corners: vec4<f32>,
};

// Lattice line j of an axis of d voxels in the tetrahedral grid: -0.5, 0, cell, 2 cell, ..., d - 1, d - 0.5
// (`tet_cells` in `plugins/volume/src/lib.rs`); n: cells on the axis.
fn lattice(j: u32, d: f32, n: u32) -> f32 {
    let inner = min((f32(j) - 1.0) * f32(params.cell), d - 1.0);
    return select(select(inner, d - 0.5, j >= n), -0.5, j == 0u);
}

// The cell of the axis (n cells) that holds voxel coordinate x.
fn lattice_cell(x: f32, d: f32, n: u32) -> u32 {
    let inner = min(1u + u32(max(floor(x / f32(params.cell)), 0.0)), max(n - 2u, 1u));
    return select(select(inner, n - 1u, x >= d - 1.0), 0u, x < 0.0);
}

// Position p of an axis' visibility order (n cells, the eye in cell e): the cells beyond the eye from the far
// end inwards, then those before it from the far end inwards, the eye's cell last. A ray from the eye moves
// away from it on every axis, so the nested order of the three axes draws every cell after those it hides.
fn far_to_near(p: u32, n: u32, e: u32) -> u32 {
    let above = n - 1u - e;
    return select(select(e, p - above, p < above + e), n - 1u - p, p < above);
}

// Orders of the three axes within a cell for the six tetrahedra, back to front: the tetrahedron x_a >= x_b
// >= x_c is on the eye's side of as many of the planes x_i = x_j as its order of the axes agrees with the
// eye's, and a ray crossing such a plane leaves the eye's side; so the tetrahedra are drawn in decreasing
// number of inversions from the eye's order.
const TET_ORDER = array<vec3<u32>, 6>(
    vec3<u32>(2u, 1u, 0u), vec3<u32>(1u, 2u, 0u), vec3<u32>(2u, 0u, 1u),
    vec3<u32>(0u, 2u, 1u), vec3<u32>(1u, 0u, 2u), vec3<u32>(0u, 1u, 2u),
);

struct TetQuad {
    clip: vec4<f32>,
    world: vec3<f32>,
    lo: vec3<f32>,
    size: vec3<f32>,
    axes: vec3<u32>,
    corners: vec4<f32>,
};

// The tetrahedron drawn in slot `slot` for this view, and corner `c` (0..3, counter-clockwise) of a quad over
// its projection: the convex hull of its four projected corners (a triangle when one falls inside the others,
// one corner then doubled). A tetrahedron reaching behind the eye's plane covers the whole view instead.
fn tet_quad(slot: u32, c: u32, forward: vec3<f32>) -> TetQuad {
    var out: TetQuad;
    let n = params.cells.xyz;
    let cell_slot = slot / 6u;
    let p = vec3<u32>(cell_slot % n.x, (cell_slot / n.x) % n.y, cell_slot / (n.x * n.y));
    let ortho = view.clip_from_view[3].w == 1.0;
    let eye = (params.voxel_from_world * vec4<f32>(view.world_position, 1.0)).xyz;
    let fwd = (params.voxel_from_world * vec4<f32>(forward, 0.0)).xyz;
    var cell = vec3<u32>(0u);
    var lo = vec3<f32>(0.0);
    var hi = vec3<f32>(0.0);
    for (var i = 0u; i < 3u; i++) {
        let e = select(lattice_cell(eye[i], params.dims[i], n[i]), select(n[i] - 1u, 0u, fwd[i] > 0.0), ortho);
        cell[i] = far_to_near(p[i], n[i], e);
        lo[i] = lattice(cell[i], params.dims[i], n[i]);
        hi[i] = lattice(cell[i] + 1u, params.dims[i], n[i]);
    }
    let size = hi - lo;
    // The eye in the cell's unit coordinates (orthographic: where the rays come from).
    let l = select((eye - lo) / size, -fwd / size, ortho);
    // The eye's order of the axes (largest coordinate first).
    var o = vec3<u32>(0u, 1u, 2u);
    if l[o.x] < l[o.y] { o = o.yxz; }
    if l[o.y] < l[o.z] { o = o.xzy; }
    if l[o.x] < l[o.y] { o = o.yxz; }
    var order = TET_ORDER;
    let tau = order[slot % 6u];
    let axes = vec3<u32>(o[tau.x], o[tau.y], o[tau.z]);
    var unit = array<vec3<f32>, 4>(vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(0.0), vec3<f32>(1.0));
    unit[1][axes.x] = 1.0;
    unit[2] = unit[1];
    unit[2][axes.y] = 1.0;
    var clip: array<vec4<f32>, 4>;
    var world: array<vec3<f32>, 4>;
    var behind = false;
    let top = params.dims.xyz - vec3<f32>(1.0);
    for (var i = 0u; i < 4u; i++) {
        let q = lo + unit[i] * size;
        out.corners[i] = voxel(vec3<i32>(round(clamp(q, vec3<f32>(0.0), top))));
        world[i] = (params.world_from_voxel * vec4<f32>(q, 1.0)).xyz;
        clip[i] = view.clip_from_world * vec4<f32>(world[i], 1.0);
        behind = behind || clip[i].w <= 1e-4;
    }
    // Hull: the corners sorted by angle about their centroid (counter-clockwise), then a reflex corner (one
    // inside the triangle of the others) moved onto its successor.
    var ndc: array<vec2<f32>, 4>;
    var ang: array<f32, 4>;
    var idx = array<u32, 4>(0u, 1u, 2u, 3u);
    var m = vec2<f32>(0.0);
    for (var i = 0u; i < 4u; i++) {
        ndc[i] = clip[i].xy / max(clip[i].w, 1e-4);
        m += 0.25 * ndc[i];
    }
    for (var i = 0u; i < 4u; i++) {
        ang[i] = atan2(ndc[i].y - m.y, ndc[i].x - m.x);
    }
    for (var sweep = 0u; sweep < 3u; sweep++) {
        for (var i = 0u; i < 3u; i++) {
            if ang[idx[i]] > ang[idx[i + 1u]] {
                let t = idx[i];
                idx[i] = idx[i + 1u];
                idx[i + 1u] = t;
            }
        }
    }
    var hull = idx;
    for (var i = 0u; i < 4u; i++) {
        let a = ndc[idx[(i + 3u) % 4u]];
        let b = ndc[idx[i]];
        let d = ndc[idx[(i + 1u) % 4u]];
        let e1 = b - a;
        let e2 = d - b;
        if e1.x * e2.y - e1.y * e2.x < 0.0 {
            hull[i] = idx[(i + 1u) % 4u];
        }
    }
    let k = hull[c];
    let corner = vec2<f32>(select(-1.0, 1.0, c == 1u || c == 2u), select(-1.0, 1.0, c >= 2u));
    let screen = view.world_from_clip * vec4<f32>(corner, 0.5, 1.0);
    out.clip = select(clip[k], vec4<f32>(corner, 0.5, 1.0), behind);
    out.world = select(world[k], screen.xyz / screen.w, behind);
    out.lo = lo;
    out.size = size;
    out.axes = axes;
    return out;
}

@vertex
fn vertex(v: VolumeVertex) -> VolumeVertexOutput {
    var out: VolumeVertexOutput;
    // Slicing: slice k of n, far to near, facing the camera, covering the bounding sphere.
    let right = view.world_from_view[0].xyz;
    let up = view.world_from_view[1].xyz;
    let forward = -view.world_from_view[2].xyz;
    let r = params.sphere.w;
    let spacing = 2.0 * r / f32(max(params.n_slices, 1u));
    let offset = r - (v.position.z + 0.5) * spacing;
    let sliced = params.sphere.xyz + r * (v.position.x * right + v.position.y * up) + offset * forward;
    let slicing = params.dims.w == 1.0;
    // 2D slicing (method 2): the axis whose planes face the view most, planes far to near. Computed always and
    // chosen by `select`: no branch on the uniform.
    let m = params.voxel_from_world;
    var rows = array<vec3<f32>, 3>(
        vec3<f32>(m[0].x, m[1].x, m[2].x),
        vec3<f32>(m[0].y, m[1].y, m[2].y),
        vec3<f32>(m[0].z, m[1].z, m[2].z),
    );
    let c0 = abs(dot(forward, normalize(rows[0])));
    let c1 = abs(dot(forward, normalize(rows[1])));
    let c2 = abs(dot(forward, normalize(rows[2])));
    let k = select(select(2u, 1u, c1 >= c2), 0u, c0 >= max(c1, c2));
    let dk = max(u32(params.dims[k]), 1u);
    let slot = u32(v.position.z);
    // Voxel coordinate k grows away from the eye: draw its high planes first.
    let index = select(min(slot, dk - 1u), dk - 1u - min(slot, dk - 1u), dot(forward, rows[k]) > 0.0);
    let u = (k + 1u) % 3u;
    let w = (k + 2u) % 3u;
    // Wound to face the camera (back faces are culled): mirror the quad when its normal points away.
    let wm = params.world_from_voxel;
    let away = dot(cross(wm[u].xyz, wm[w].xyz), forward) > 0.0;
    let cx = select(v.position.x, -v.position.x, away);
    var q = vec3<f32>(0.0);
    q[k] = f32(index);
    q[u] = mix(-0.5, params.dims[u] - 0.5, 0.5 * (cx + 1.0));
    q[w] = mix(-0.5, params.dims[w] - 0.5, 0.5 * (v.position.y + 1.0));
    let planes = params.dims.w == 2.0 || params.dims.w == 3.0;
    let p = select(select(v.position, sliced, slicing), (params.world_from_voxel * vec4<f32>(q, 1.0)).xyz, planes);
    let mode = select(select(u32(slicing), 2u + k, planes), 5u + k, params.dims.w == 3.0);
    // Planes beyond the stack's depth collapse outside the view.
    let folded = planes && slot >= dk;
    // Cell projection: corner c of the quad over tetrahedron `slot` (computed always, chosen by `select`).
    let c = select(select(0u, 3u, v.position.y > 0.0), select(1u, 2u, v.position.y > 0.0), v.position.x > 0.0);
    let tq = tet_quad(slot, c, forward);
    let tets = params.dims.w == 4.0;
    // Splatting's kernel radius in voxels: three standard deviations, stretched by up to 1.8 in a plane the ray
    // crosses obliquely, at most 3 (a 7 x 7 neighbourhood).
    let radius = u32(clamp(ceil(3.0 * 1.8 * params.kernel), 1.0, 3.0));
    let modes = select(select(mode, 8u, tets), 9u, params.dims.w == 5.0);
    out.modes = vec4<u32>(modes, params.jitter, 0u, 0u);
    out.world_position = select(p, tq.world, tets);
    let clip = select(view.clip_from_world * vec4<f32>(p, 1.0), vec4<f32>(2.0, 2.0, 2.0, 1.0), folded);
    out.clip_position = select(clip, tq.clip, tets);
    out.cell_lo = vec4<f32>(tq.lo, 0.0);
    out.cell_size = vec4<f32>(tq.size, 0.0);
    out.tet = vec4<u32>(tq.axes, radius);
    out.corners = tq.corners;
    return out;
}

fn voxel(p: vec3<i32>) -> f32 {
    let hi = vec3<i32>(params.dims.xyz) - vec3<i32>(1);
    return textureLoad(volume, clamp(p, vec3<i32>(0), hi), 0).r;
}

// Trilinear, clamped to the edge voxels' centres (as `fascicle_core::dvr::sample`).
fn sample_volume(q: vec3<f32>) -> f32 {
    let p = clamp(q, vec3<f32>(0.0), params.dims.xyz - vec3<f32>(1.0));
    let i = vec3<i32>(floor(p));
    let f = p - floor(p);
    let c00 = mix(voxel(i), voxel(i + vec3<i32>(1, 0, 0)), f.x);
    let c10 = mix(voxel(i + vec3<i32>(0, 1, 0)), voxel(i + vec3<i32>(1, 1, 0)), f.x);
    let c01 = mix(voxel(i + vec3<i32>(0, 0, 1)), voxel(i + vec3<i32>(1, 0, 1)), f.x);
    let c11 = mix(voxel(i + vec3<i32>(0, 1, 1)), voxel(i + vec3<i32>(1, 1, 1)), f.x);
    return mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z);
}

fn normalised(v: f32) -> f32 {
    let span = params.range.y - params.range.x;
    return select(0.0, clamp((v - params.range.x) / span, 0.0, 1.0), span > 0.0);
}

fn classify(v: f32) -> vec4<f32> {
    let x = normalised(v) * f32(LUT_N - 1u);
    let i = min(u32(floor(x)), LUT_N - 2u);
    return mix(lut[i], lut[i + 1u], x - f32(i));
}

// Premultiplied colour and opacity of `length` mm at value v (post-classified).
fn segment(v: f32, length: f32) -> vec4<f32> {
    let c = classify(v);
    let a = 1.0 - pow(1.0 - clamp(c.a, 0.0, 1.0), length / UNIT_MM);
    return vec4<f32>(c.rgb * a, a);
}

// `segment(v, step)` for a whole step of the ray caster. With the `PRODUCT_STEPS` def (`VolumeKey`: the step is a
// power of two from 0.25 to 16 mm) the opacity correction is made of products and square roots: on lavapipe `pow`
// (exp2 and log2) cost about a tenth of the default scene's full-scale frame, and a branch around it would not
// save it (lanes run both sides under a mask).
fn segment_step(v: f32, step: f32) -> vec4<f32> {
#ifdef PRODUCT_STEPS
    let c = classify(v);
    let b = 1.0 - clamp(c.a, 0.0, 1.0);
    let e = step / UNIT_MM;
    let h = sqrt(b);
    let b2 = b * b;
    let b4 = b2 * b2;
    let b8 = b4 * b4;
    let up = select(select(select(select(b, b2, e == 2.0), b4, e == 4.0), b8, e == 8.0), b8 * b8, e == 16.0);
    let a = 1.0 - select(select(up, h, e == 0.5), sqrt(h), e == 0.25);
    return vec4<f32>(c.rgb * a, a);
#else
    return segment(v, step);
#endif
}

fn preintegrated(front: f32, back: f32) -> vec4<f32> {
    let n = params.table_n;
    let x = normalised(front) * f32(n - 1u);
    let y = normalised(back) * f32(n - 1u);
    let i = min(u32(floor(x)), n - 2u);
    let j = min(u32(floor(y)), n - 2u);
    let fx = x - f32(i);
    let fy = y - f32(j);
    let a = mix(table[i * n + j], table[i * n + j + 1u], fy);
    let b = mix(table[(i + 1u) * n + j], table[(i + 1u) * n + j + 1u], fy);
    return mix(a, b, fx);
}

// How many whole steps from t (voxel coordinates o + d t) add nothing: their samples, and the segments between
// them, lie in the empty cell of the sample at t (the cell's box, the edge cells reaching past the volume as
// clamped samples do). 0 when that cell is occupied. Samples are filed under the cell floor(p / edge) of their
// clamped position p, whose values `empty_space::cell_value_ranges` bounds.
fn empty_steps(o: vec3<f32>, d: vec3<f32>, t: f32, t_end: f32, step: f32) -> u32 {
    let g = params.grid;
    let edge = f32(g.w);
    let p = clamp(o + d * t, vec3<f32>(0.0), params.dims.xyz - vec3<f32>(1.0));
    let c = min(vec3<u32>(floor(p / edge)), g.xyz - vec3<u32>(1u));
    if occupancy[c.x + g.x * (c.y + g.y * c.z)] != 0u {
        return 0u;
    }
    let lo = select(vec3<f32>(c) * edge, vec3<f32>(-1e30), c == vec3<u32>(0u));
    let hi = select(vec3<f32>(c + vec3<u32>(1u)) * edge, vec3<f32>(1e30), c + vec3<u32>(1u) >= g.xyz);
    // A direction component of 0 never leaves its slab (no 0 * inf).
    let dd = select(d, vec3<f32>(1e-30), abs(d) < vec3<f32>(1e-30));
    let a = (lo - o) / dd;
    let b = (hi - o) / dd;
    let t_exit = min(min(max(a.x, b.x), max(a.y, b.y)), max(a.z, b.z));
    // The sample reached, the last in the cell, is marched as usual (the segment from it may leave the cell).
    return u32(max(floor((min(t_exit, t_end) - t) / step), 0.0));
}

// Lambert with a headlight on the value gradient (voxel frame), with the `SHADING` def (`VolumeKey`: shading on).
// Without it `c` as it is, and its six extra samples are not compiled: lavapipe runs a branch's code for every
// lane whichever way the lanes go.
fn shade(c: vec4<f32>, q: vec3<f32>, d: vec3<f32>) -> vec4<f32> {
#ifndef SHADING
    return c;
#else
    let g = vec3<f32>(
        sample_volume(q + vec3<f32>(1.0, 0.0, 0.0)) - sample_volume(q - vec3<f32>(1.0, 0.0, 0.0)),
        sample_volume(q + vec3<f32>(0.0, 1.0, 0.0)) - sample_volume(q - vec3<f32>(0.0, 1.0, 0.0)),
        sample_volume(q + vec3<f32>(0.0, 0.0, 1.0)) - sample_volume(q - vec3<f32>(0.0, 0.0, 1.0)),
    );
    let len = length(g);
    let lambert = select(1.0, abs(dot(g / len, normalize(d))), len > 1e-6);
    return vec4<f32>(c.rgb * (params.ambient + (1.0 - params.ambient) * lambert), c.a);
#endif
}

// Distance along the ray to the opaque surface under this pixel (infinity when none).
fn opaque_distance(frag: vec4<f32>, r: Ray) -> f32 {
    let z = textureLoad(opaque_depth, vec2<i32>(floor(frag.xy)), 0);
    if z <= 0.0 {
        return 1e30;
    }
    let uv = (frag.xy - view.main_pass_viewport.xy) / view.main_pass_viewport.zw;
    let ndc = vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, z, 1.0);
    let pv = view.view_from_clip * ndc;
    let pw = (view.world_from_view * vec4<f32>(pv.xyz / pv.w, 1.0)).xyz;
    return dot(pw - r.origin, r.dir);
}

// Interleaved gradient noise (Jimenez 2014) in [0, 1): the start offset against wood-grain artefacts.
fn jitter(frag: vec2<f32>) -> f32 {
    return fract(52.9829189 * fract(dot(frag, vec2<f32>(0.06711056, 0.00583715))));
}

// Slicing's dither: an offset in [-0.5, 0.5) of the spacing, per pixel, when jitter is on.
fn dither(in: VolumeVertexOutput) -> f32 {
    return select(0.0, jitter(in.clip_position.xy) - 0.5, in.modes.y == 1u);
}

// One sheet of voxel splatting: the voxels of plane k nearest the ray, each classified (pre-classification)
// and weighted by its Gaussian kernel's integral along the ray (a function of its distance to the ray in voxel
// space), summed into the sheet's extinction and colour (normalised by the weights: a constant field gives
// its own value at any kernel size) over the planes' spacing along the ray.
fn splat_sheet(in: VolumeVertexOutput, r: Ray, o: vec3<f32>, d: vec3<f32>, t_stop: f32) -> vec4<f32> {
    let k = in.modes.x - 5u;
    let u = (k + 1u) % 3u;
    let w = (k + 2u) % 3u;
    var q = (params.voxel_from_world * vec4<f32>(in.world_position, 1.0)).xyz;
    q[k] = round(q[k]);
    let t = dot(in.world_position - r.origin, r.dir);
    if t >= t_stop || any(q < params.clip_lo.xyz) || any(q > params.clip_hi.xyz) {
        discard;
    }
    let dn = normalize(d);
    let inv2s2 = 0.5 / (params.kernel * params.kernel);
    let radius = i32(in.tet.w);
    let cu = round(q[u]);
    let cw = round(q[w]);
    var tau = 0.0;
    var rgb = vec3<f32>(0.0);
    var weight = 0.0;
    for (var i = -radius; i <= radius; i++) {
        for (var j = -radius; j <= radius; j++) {
            var v = q;
            v[u] = cu + f32(i);
            v[w] = cw + f32(j);
            if v[u] < 0.0 || v[w] < 0.0 || v[u] > params.dims[u] - 1.0 || v[w] > params.dims[w] - 1.0 {
                continue;
            }
            let rel = v - q;
            let along = dot(rel, dn);
            let f = exp(-(dot(rel, rel) - along * along) * inv2s2);
            let c = classify(voxel(vec3<i32>(v)));
            let e = -log(1.0 - min(c.a, 0.999999)) / UNIT_MM;
            tau += f * e;
            rgb += f * e * c.rgb;
            weight += f;
        }
    }
    if weight <= 0.0 || tau <= 0.0 {
        discard;
    }
    let alpha = 1.0 - exp(-(tau / weight) / max(abs(d[k]), 1e-6));
    return shade(vec4<f32>(rgb / tau * alpha, alpha), q, d);
}

// One tetrahedron of cell projection: the ray's exact entry and exit (the four faces x_a = 1, x_a = x_b,
// x_b = x_c, x_c = 0 of the Kuhn tetrahedron x_a >= x_b >= x_c in the cell's unit coordinates), within the
// clip box and before the opaque surface; the field is linear inside, so each piece of at most one step is
// looked up in the pre-integrated table by its two ends, its opacity corrected to its length.
fn tetrahedron(in: VolumeVertexOutput, o: vec3<f32>, d: vec3<f32>, t_lo: f32, t_hi: f32) -> vec4<f32> {
    let lo = in.cell_lo.xyz;
    let size = in.cell_size.xyz;
    let ax = in.tet.xyz;
    let ol = (o - lo) / size;
    let dl = d / size;
    // Half-spaces f0 + t f1 >= 0.
    let f0 = vec4<f32>(1.0 - ol[ax.x], ol[ax.x] - ol[ax.y], ol[ax.y] - ol[ax.z], ol[ax.z]);
    let f1 = vec4<f32>(-dl[ax.x], dl[ax.x] - dl[ax.y], dl[ax.y] - dl[ax.z], dl[ax.z]);
    var t0 = t_lo;
    var t1 = t_hi;
    for (var i = 0u; i < 4u; i++) {
        let h = -f0[i] / f1[i];
        if f1[i] > 0.0 {
            t0 = max(t0, h);
        } else if f1[i] < 0.0 {
            t1 = min(t1, h);
        } else if f0[i] < 0.0 {
            discard;
        }
    }
    if t0 >= t1 {
        discard;
    }
    let v = in.corners;
    let grad = vec3<f32>(v.y - v.x, v.z - v.y, v.w - v.z);
    let s0 = v.x + grad.x * (ol[ax.x] + t0 * dl[ax.x]) + grad.y * (ol[ax.y] + t0 * dl[ax.y]) + grad.z * (ol[ax.z] + t0 * dl[ax.z]);
    let slope = grad.x * dl[ax.x] + grad.y * dl[ax.y] + grad.z * dl[ax.z];
    let step = max(params.step, 1e-4);
    let n = u32(clamp(ceil((t1 - t0) / step), 1.0, 64.0));
    let dt = (t1 - t0) / f32(n);
    var acc = vec4<f32>(0.0);
    for (var i = 0u; i < n; i++) {
        let ta = t0 + f32(i) * dt;
        var seg = preintegrated(s0 + slope * (ta - t0), s0 + slope * (ta + dt - t0));
        let a2 = 1.0 - pow(1.0 - min(seg.a, 0.999999), dt / step);
        seg = select(vec4<f32>(0.0), vec4<f32>(seg.rgb * (a2 / seg.a), a2), seg.a > 0.0);
        acc += (1.0 - acc.a) * shade(seg, o + d * (ta + 0.5 * dt), d);
    }
    return acc;
}

// Shear-warp's warp: the intermediate image read bilinearly where the ray meets its plane (transparent off
// the image).
fn warped(o: vec3<f32>, d: vec3<f32>) -> vec4<f32> {
    let k = warp.axis;
    let u = (k + 1u) % 3u;
    let w = (k + 2u) % 3u;
    let b = o + d * ((warp.base - o[k]) / d[k]);
    let x = (b[u] - warp.origin.x) / warp.spacing.x - 0.5;
    let y = (b[w] - warp.origin.y) / warp.spacing.y - 0.5;
    let s = vec2<f32>(warp.size);
    let off = warp.size.x == 0u || abs(d[k]) < 1e-12 || x < -0.5 || y < -0.5 || x > s.x - 0.5 || y > s.y - 0.5;
    let x0 = floor(x);
    let y0 = floor(y);
    let hi = vec2<i32>(warp.size) - vec2<i32>(1);
    let i0 = clamp(vec2<i32>(i32(x0), i32(y0)), vec2<i32>(0), hi);
    let i1 = clamp(vec2<i32>(i32(x0) + 1, i32(y0) + 1), vec2<i32>(0), hi);
    let top = mix(textureLoad(intermediate, i0, 0), textureLoad(intermediate, vec2<i32>(i1.x, i0.y), 0), x - x0);
    let bottom = mix(textureLoad(intermediate, vec2<i32>(i0.x, i1.y), 0), textureLoad(intermediate, i1, 0), x - x0);
    return select(mix(top, bottom, y - y0), vec4<f32>(0.0), off);
}

@fragment
fn fragment(in: VolumeVertexOutput) -> @location(0) vec4<f32> {
    let r = view_ray(in.world_position, view.world_position, view.world_from_view, view.clip_from_view);
    let o = (params.voxel_from_world * vec4<f32>(r.origin, 1.0)).xyz;
    let d = (params.voxel_from_world * vec4<f32>(r.dir, 0.0)).xyz;
    let t_stop = opaque_distance(in.clip_position, r);
    let lo = params.clip_lo.xyz;
    let hi = params.clip_hi.xyz;
    // The ray's interval in the clip box (voxel coordinates), up to the opaque surface.
    let inv = 1.0 / d;
    let a = (lo - o) * inv;
    let b = (hi - o) * inv;
    let tmin = min(a, b);
    let tmax = max(a, b);
    let t0 = max(max(tmin.x, tmin.y), max(tmin.z, 0.0));
    let t1 = min(min(min(tmax.x, tmax.y), tmax.z), t_stop);
    // With the `RAY_CAST` def (`VolumeKey`: the material ray casts) the other methods' code is not compiled.
#ifndef RAY_CAST
    if in.modes.x == 1u {
        // One slice: the sample where the plane meets this ray (dithered: moved along the ray by up to half the
        // spacing, a per-pixel fraction: interleaved sampling).
        let forward = -view.world_from_view[2].xyz;
        let spacing = 2.0 * params.sphere.w / f32(params.n_slices);
        let along = spacing / max(dot(r.dir, forward), 1e-3);
        let t = dot(in.world_position - r.origin, r.dir) + dither(in) * along;
        let q = o + d * t;
        if t >= t_stop || any(q < lo) || any(q > hi) {
            discard;
        }
        return shade(segment(sample_volume(q), along), q, d);
    }
    if in.modes.x >= 2u && in.modes.x < 5u {
        // One voxel plane of axis k, sampled where this fragment lies on it; the planes are 1 / |d_k| apart
        // along the ray (d in voxels per mm). Dithered: the sample moved along the ray as for slices.
        let k = in.modes.x - 2u;
        let along = 1.0 / max(abs(d[k]), 1e-6);
        var q = (params.voxel_from_world * vec4<f32>(in.world_position, 1.0)).xyz;
        q[k] = round(q[k]);
        let t = dot(in.world_position - r.origin, r.dir) + dither(in) * along;
        q += d * dither(in) * along;
        if t >= t_stop || any(q < lo) || any(q > hi) {
            discard;
        }
        return shade(segment(sample_volume(q), along), q, d);
    }
    if in.modes.x >= 5u && in.modes.x < 8u {
        return splat_sheet(in, r, o, d, t_stop);
    }
    if in.modes.x == 8u {
        return tetrahedron(in, o, d, t0, t1);
    }
    // Shear-warp: the intermediate image composited whole rays; where an opaque surface lies inside the
    // volume on this pixel's ray, the pixel is marched up to it instead (below), so small opaque objects
    // neither darken their neighbours through the warp's resampling nor show what lies behind them.
    if in.modes.x == 9u && t_stop >= min(min(tmax.x, tmax.y), tmax.z) {
        return warped(o, d);
    }
#endif
    if t0 >= t1 {
        discard;
    }
    let step = max(params.step, 1e-4);
    var t = t0;
    if in.modes.y == 1u {
        t += jitter(in.clip_position.xy) * step;
    }
    var acc = vec4<f32>(0.0);
    // Pre-integrated (the `PREINTEGRATED` def, `VolumeKey`) or post-classified, chosen when the pipeline is
    // compiled.
#ifdef PREINTEGRATED
    var prev = sample_volume(o + d * t);
#endif
    // Whole steps in the loop; the last, shorter one after it, the only one whose opacity needs `pow`.
    var k = 0u;
    for (; k < MAX_STEPS && t < t1 && t1 - t >= step; k++) {
        // Empty space: the steps that add nothing are stepped over one addition at a time, so the samples
        // after them lie where they would have (the same image, bit for bit, without their sampling).
        let skip = min(empty_steps(o, d, t, t1, step), MAX_STEPS - k);
        if skip > 0u {
            for (var i = 0u; i < skip; i++) {
                t += step;
            }
            k += skip - 1u;
#ifdef PREINTEGRATED
            prev = sample_volume(o + d * t);
#endif
            continue;
        }
#ifdef PREINTEGRATED
        let next = sample_volume(o + d * (t + step));
        let c = preintegrated(prev, next);
        prev = next;
#else
        let c = segment_step(sample_volume(o + d * t), step);
#endif
        acc += (1.0 - acc.a) * shade(c, o + d * t, d);
        if acc.a >= params.termination {
            break;
        }
        t += step;
    }
    // The last step, shorter than the others (the loop ended neither by termination nor by its step count).
    if k < MAX_STEPS && t < t1 && acc.a < params.termination {
        let dt = t1 - t;
#ifdef PREINTEGRATED
        let seg = preintegrated(prev, sample_volume(o + d * (t + dt)));
        let a2 = 1.0 - pow(1.0 - min(seg.a, 0.999999), dt / step);
        let c = select(vec4<f32>(0.0), vec4<f32>(seg.rgb * (a2 / seg.a), a2), seg.a > 0.0);
#else
        let c = segment(sample_volume(o + d * t), dt);
#endif
        acc += (1.0 - acc.a) * shade(c, o + d * t, d);
    }
    return acc;
}
