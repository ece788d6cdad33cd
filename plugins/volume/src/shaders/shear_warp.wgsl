// Shear-warp (Lacroute and Levoy 1994; SEEDS.md section 2), the compositing half: one invocation per pixel of
// the intermediate image, which lies on the voxel plane `base` of the principal axis k (the axis whose planes
// face the view most). Its ray (through the eye in perspective, along the view in orthographic) crosses the
// voxel planes of k in order, front to back; each plane is resampled bilinearly where the ray crosses it (the
// shear: with the eye's projection fixed, the planes slide and scale against each other) and composited,
// whole: pixels whose ray meets an opaque surface inside the volume are marched by the warp instead (a ray
// stopped here would darken its neighbours through the warp's resampling). Intermediate pixels off the view
// (each intermediate ray is a pixel ray) are skipped. The warp half is `volume.wgsl`'s method 5.
// The f64 twin is `fascicle_core::dvr::shear_warp_march`; keep `ShearWarpParams` in sync with
// `ShearWarpUniform` in `plugins/volume/src/shear_warp.rs`.

struct ShearWarpParams {
    voxel_from_world: mat4x4<f32>,
    world_from_voxel: mat4x4<f32>,
    clip_from_world: mat4x4<f32>,
    // Pixel origin and size of the view.
    viewport: vec4<f32>,
    // Perspective: the eye (voxel coordinates, w = 1). Orthographic: the rays' direction (w = 0).
    eye: vec4<f32>,
    // xyz: dimensions; w unused.
    dims: vec4<f32>,
    clip_lo: vec4<f32>,
    clip_hi: vec4<f32>,
    // The intermediate image on plane `base` of axis k: (u, w) of its first pixel's corner, pixel size.
    origin: vec2<f32>,
    spacing: vec2<f32>,
    range: vec2<f32>,
    // Pixels of the intermediate image in use.
    size: vec2<u32>,
    axis: u32,
    base: f32,
    // Planes from front to back: first index, step (+1 or -1), count.
    first: f32,
    dir: f32,
    planes: u32,
    termination: f32,
};

// What the warp reads (written by invocation (0, 0), in the same command stream as the image, so every view's
// warp reads its own): axis, base, origin, spacing, size.
struct Warp {
    axis: u32,
    base: f32,
    size: vec2<u32>,
    origin: vec2<f32>,
    spacing: vec2<f32>,
};

@group(0) @binding(0) var<uniform> params: ShearWarpParams;
@group(0) @binding(1) var volume: texture_3d<f32>;
@group(0) @binding(2) var<storage, read> lut: array<vec4<f32>>;
@group(0) @binding(3) var image: texture_storage_2d<rgba16float, write>;
@group(0) @binding(4) var<storage, read_write> warp: Warp;

const LUT_N: u32 = 256u;

fn voxel(p: vec3<i32>) -> f32 {
    let hi = vec3<i32>(params.dims.xyz) - vec3<i32>(1);
    return textureLoad(volume, clamp(p, vec3<i32>(0), hi), 0).r;
}

fn classify(v: f32) -> vec4<f32> {
    let span = params.range.y - params.range.x;
    let x = select(0.0, clamp((v - params.range.x) / span, 0.0, 1.0), span > 0.0) * f32(LUT_N - 1u);
    let i = min(u32(floor(x)), LUT_N - 2u);
    return mix(lut[i], lut[i + 1u], x - f32(i));
}

@compute @workgroup_size(8, 8, 1)
fn composite(@builtin(global_invocation_id) id: vec3<u32>) {
    let k = params.axis;
    let u = (k + 1u) % 3u;
    let w = (k + 2u) % 3u;
    if id.x == 0u && id.y == 0u {
        warp.axis = k;
        warp.base = params.base;
        warp.size = params.size;
        warp.origin = params.origin;
        warp.spacing = params.spacing;
    }
    if id.x >= params.size.x || id.y >= params.size.y {
        return;
    }
    var b = vec3<f32>(0.0);
    b[k] = params.base;
    b[u] = params.origin.x + (f32(id.x) + 0.5) * params.spacing.x;
    b[w] = params.origin.y + (f32(id.y) + 0.5) * params.spacing.y;
    let perspective = params.eye.w == 1.0;
    let e = params.eye.xyz;
    // The ray's direction with a unit step along k (from one plane to the next).
    let d = select(e, b - e, perspective);
    let per_plane = d / abs(d[k]);
    // Its screen pixel: off the view, nothing to composite.
    let wb = params.world_from_voxel * vec4<f32>(b, 1.0);
    let cb = params.clip_from_world * wb;
    let ndc = cb.xyz / cb.w;
    let px = params.viewport.xy + vec2<f32>(0.5 * ndc.x + 0.5, 0.5 - 0.5 * ndc.y) * params.viewport.zw;
    let inside = all(px >= params.viewport.xy) && all(px < params.viewport.xy + params.viewport.zw) && cb.w > 0.0;
    var acc = vec4<f32>(0.0);
    if inside {
        // Step length in mm between planes along this ray.
        let mm = length((params.world_from_voxel * vec4<f32>(per_plane, 0.0)).xyz);
        for (var i = 0u; i < params.planes; i++) {
            let c = params.first + params.dir * f32(i);
            let p = b + per_plane * (c - params.base) * sign(d[k]);
            if any(p < params.clip_lo.xyz) || any(p > params.clip_hi.xyz) {
                continue;
            }
            // Bilinear within plane c.
            let fu = clamp(p[u], 0.0, params.dims[u] - 1.0);
            let fw = clamp(p[w], 0.0, params.dims[w] - 1.0);
            let iu = floor(fu);
            let iw = floor(fw);
            var q = vec3<i32>(0);
            q[k] = i32(c);
            q[u] = i32(iu);
            q[w] = i32(iw);
            var du = vec3<i32>(0);
            du[u] = 1;
            var dw = vec3<i32>(0);
            dw[w] = 1;
            let v0 = mix(voxel(q), voxel(q + du), fu - iu);
            let v1 = mix(voxel(q + dw), voxel(q + du + dw), fu - iu);
            let cl = classify(mix(v0, v1, fw - iw));
            let a = 1.0 - pow(1.0 - clamp(cl.a, 0.0, 1.0), mm);
            acc += (1.0 - acc.a) * vec4<f32>(cl.rgb * a, a);
            if acc.a >= params.termination {
                break;
            }
        }
    }
    textureStore(image, vec2<i32>(id.xy), acc);
}
