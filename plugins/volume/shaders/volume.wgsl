// Volume context (SEEDS.md section 2): direct volume rendering of a scalar 3D texture, by GPU ray casting
// (front to back, early termination, jittered start, post-classified or pre-integrated) or by
// view-aligned 3D-texture slicing (Cabral et al.: planes facing the camera, blended back to front), or by
// 2D-texture slicing (the voxel planes of the axis nearest the view direction, back to front). All
// stop at the depth of the opaque layers (a copy of the depth buffer taken after the opaque pass), so
// glyphs inside the volume hide what lies behind them and are tinted by what lies in front.
// The f64 reference is `fascicle_core::dvr`; keep `VolumeParams` in sync with `VolumeUniform` in
// `plugins/volume/src/lib.rs`.

#import bevy_pbr::mesh_view_bindings::view
#import fascicle::ray::{Ray, view_ray}

struct VolumeParams {
    voxel_from_world: mat4x4<f32>,
    world_from_voxel: mat4x4<f32>,
    // xyz: dimensions (voxels); w: method (0 ray casting, 1 slicing, 2 2D slicing).
    dims: vec4<f32>,
    // World bounding sphere of the volume: centre, radius.
    sphere: vec4<f32>,
    // The clip box in voxel coordinates (xyz): what is drawn of the volume.
    clip_lo: vec4<f32>,
    clip_hi: vec4<f32>,
    range: vec2<f32>,
    step: f32,
    termination: f32,
    jitter: u32,
    shading: u32,
    preintegrated: u32,
    n_slices: u32,
    table_n: u32,
    ambient: f32,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: VolumeParams;
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var volume: texture_3d<f32>;
// 256 entries: linear rgb, opacity per mm.
@group(#{MATERIAL_BIND_GROUP}) @binding(2) var<storage, read> lut: array<vec4<f32>>;
// table_n x table_n pre-integrated segments (front value major), premultiplied.
@group(#{MATERIAL_BIND_GROUP}) @binding(3) var<storage, read> table: array<vec4<f32>>;
@group(#{MATERIAL_BIND_GROUP}) @binding(4) var opaque_depth: texture_depth_2d;

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
    // (slicing: 0 none, 1 view-aligned, 2 + k voxel planes of axis k; jitter, shading, pre-integrated), flat:
    // the fragment stage branches on these, never on the uniform (the rule in `fascicle::ray`).
    @location(1) @interpolate(flat) modes: vec4<u32>,
};

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
    let planes = params.dims.w == 2.0;
    let p = select(select(v.position, sliced, slicing), (params.world_from_voxel * vec4<f32>(q, 1.0)).xyz, planes);
    let mode = select(u32(slicing), 2u + k, planes);
    // Planes beyond the stack's depth collapse outside the view.
    let folded = planes && slot >= dk;
    out.modes = vec4<u32>(mode, params.jitter, params.shading, params.preintegrated);
    out.world_position = p;
    out.clip_position = select(view.clip_from_world * vec4<f32>(p, 1.0), vec4<f32>(2.0, 2.0, 2.0, 1.0), folded);
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

// Lambert with a headlight on the value gradient (voxel frame), when shading is on.
fn shade(c: vec4<f32>, q: vec3<f32>, d: vec3<f32>, shading: u32) -> vec4<f32> {
    if shading == 0u {
        return c;
    }
    let g = vec3<f32>(
        sample_volume(q + vec3<f32>(1.0, 0.0, 0.0)) - sample_volume(q - vec3<f32>(1.0, 0.0, 0.0)),
        sample_volume(q + vec3<f32>(0.0, 1.0, 0.0)) - sample_volume(q - vec3<f32>(0.0, 1.0, 0.0)),
        sample_volume(q + vec3<f32>(0.0, 0.0, 1.0)) - sample_volume(q - vec3<f32>(0.0, 0.0, 1.0)),
    );
    let len = length(g);
    let lambert = select(1.0, abs(dot(g / len, normalize(d))), len > 1e-6);
    return vec4<f32>(c.rgb * (params.ambient + (1.0 - params.ambient) * lambert), c.a);
}

// Distance along the ray to the opaque surface under this pixel (infinity when none).
fn opaque_distance(frag: vec4<f32>, r: Ray) -> f32 {
    let z = textureLoad(opaque_depth, vec2<i32>(floor(frag.xy)), 0);
    if z <= 0.0 {
        return 1e30;
    }
    let uv = (frag.xy - view.viewport.xy) / view.viewport.zw;
    let ndc = vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, z, 1.0);
    let pv = view.view_from_clip * ndc;
    let pw = (view.world_from_view * vec4<f32>(pv.xyz / pv.w, 1.0)).xyz;
    return dot(pw - r.origin, r.dir);
}

// Interleaved gradient noise (Jimenez 2014) in [0, 1): the start offset against wood-grain artefacts.
fn jitter(frag: vec2<f32>) -> f32 {
    return fract(52.9829189 * fract(dot(frag, vec2<f32>(0.06711056, 0.00583715))));
}

@fragment
fn fragment(in: VolumeVertexOutput) -> @location(0) vec4<f32> {
    let r = view_ray(in.world_position, view.world_position, view.world_from_view, view.clip_from_view);
    let o = (params.voxel_from_world * vec4<f32>(r.origin, 1.0)).xyz;
    let d = (params.voxel_from_world * vec4<f32>(r.dir, 0.0)).xyz;
    let t_stop = opaque_distance(in.clip_position, r);
    let lo = params.clip_lo.xyz;
    let hi = params.clip_hi.xyz;
    if in.modes.x == 1u {
        // One slice: the sample where the plane meets this ray.
        let t = dot(in.world_position - r.origin, r.dir);
        let q = o + d * t;
        if t >= t_stop || any(q < lo) || any(q > hi) {
            discard;
        }
        let forward = -view.world_from_view[2].xyz;
        let spacing = 2.0 * params.sphere.w / f32(params.n_slices);
        let c = shade(segment(sample_volume(q), spacing / max(dot(r.dir, forward), 1e-3)), q, d, in.modes.z);
        return c;
    }
    if in.modes.x >= 2u {
        // One voxel plane of axis k, sampled where this fragment lies on it; the planes are 1 / |d_k| apart
        // along the ray (d in voxels per mm).
        let k = in.modes.x - 2u;
        let t = dot(in.world_position - r.origin, r.dir);
        var q = (params.voxel_from_world * vec4<f32>(in.world_position, 1.0)).xyz;
        q[k] = round(q[k]);
        if t >= t_stop || any(q < lo) || any(q > hi) {
            discard;
        }
        return shade(segment(sample_volume(q), 1.0 / max(abs(d[k]), 1e-6)), q, d, in.modes.z);
    }
    let inv = 1.0 / d;
    let a = (lo - o) * inv;
    let b = (hi - o) * inv;
    let tmin = min(a, b);
    let tmax = max(a, b);
    let t0 = max(max(tmin.x, tmin.y), max(tmin.z, 0.0));
    let t1 = min(min(min(tmax.x, tmax.y), tmax.z), t_stop);
    if t0 >= t1 {
        discard;
    }
    let step = max(params.step, 1e-4);
    var t = t0;
    if in.modes.y == 1u {
        t += jitter(in.clip_position.xy) * step;
    }
    var acc = vec4<f32>(0.0);
    var prev = sample_volume(o + d * t);
    for (var k = 0u; k < MAX_STEPS && t < t1; k++) {
        let dt = min(step, t1 - t);
        var c: vec4<f32>;
        if in.modes.w == 1u {
            let next = sample_volume(o + d * (t + dt));
            var seg = preintegrated(prev, next);
            prev = next;
            if dt < step {
                let a2 = 1.0 - pow(1.0 - min(seg.a, 0.999999), dt / step);
                seg = select(vec4<f32>(0.0), vec4<f32>(seg.rgb * (a2 / seg.a), a2), seg.a > 0.0);
            }
            c = seg;
        } else {
            c = segment(sample_volume(o + d * t), dt);
        }
        acc += (1.0 - acc.a) * shade(c, o + d * t, d, in.modes.z);
        if acc.a >= params.termination {
            break;
        }
        t += dt;
    }
    return acc;
}
