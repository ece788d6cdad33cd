// Tensor splatting (SEEDS.md section 1): each splat a 3D Gaussian whose footprint is projected with the
// local affine approximation of the perspective projection (EWA), drawn as a camera-facing quad bounding the
// footprint at 3 standard deviations, with an elliptical Gaussian opacity, premultiplied alpha, composited
// in Bevy's sorted transparent phase (far to near, by the splat centre's depth) against the opaque depth.
// The f64 reference is `fascicle_core::dti::splat`; keep `SplatParams` in sync with `SplatUniform` in
// `plugins/tensors/src/splat.rs`.

#import bevy_pbr::mesh_functions
#import bevy_pbr::mesh_view_bindings::view

struct SplatParams {
    attenuation: u32,
    k: f32,
    dilation: f32,
    opacity_scale: f32,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: SplatParams;
// Four vec4 per splat: (centre, opacity), (xx, xy, xz, yy), (yz, zz, 0, 0), (linear rgb, 0).
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var<storage, read> splats: array<vec4<f32>>;

struct SplatVertex {
    @builtin(instance_index) instance_index: u32,
    @location(0) position: vec3<f32>,
};

struct SplatVertexOutput {
    @builtin(position) clip_position: vec4<f32>,
    // Offset from the footprint's centre in pixels (y down).
    @location(0) offset: vec2<f32>,
    @location(1) @interpolate(flat) conic: vec3<f32>,
    @location(2) @interpolate(flat) colour_alpha: vec4<f32>,
};

@vertex
fn vertex(v: SplatVertex) -> SplatVertexOutput {
    var out: SplatVertexOutput;
    let b = 4u * mesh_functions::get_tag(v.instance_index);
    let s0 = splats[b];
    let s1 = splats[b + 1u];
    let s2 = splats[b + 2u];
    let cov = mat3x3<f32>(
        vec3<f32>(s1.x, s1.y, s1.z),
        vec3<f32>(s1.y, s1.w, s2.x),
        vec3<f32>(s1.z, s2.x, s2.y),
    );
    let p = (view.view_from_world * vec4<f32>(s0.xyz, 1.0)).xyz;
    let z = -p.z;
    if z <= 1e-6 {
        // Behind the camera: outside the clip volume.
        out.clip_position = vec4<f32>(2.0, 2.0, 2.0, 1.0);
        return out;
    }
    let w = mat3x3<f32>(view.view_from_world[0].xyz, view.view_from_world[1].xyz, view.view_from_world[2].xyz);
    let vc = w * cov * transpose(w);
    let f = view.clip_from_view[1][1] * view.viewport.w * 0.5;
    let j0 = vec3<f32>(f / z, 0.0, f * p.x / (z * z));
    let j1 = vec3<f32>(0.0, -f / z, -f * p.y / (z * z));
    let a = dot(j0, vc * j0) + params.dilation;
    let bb = dot(j0, vc * j1);
    let c = dot(j1, vc * j1) + params.dilation;
    let det = a * c - bb * bb;
    // Principal axes of the footprint.
    let mid = 0.5 * (a + c);
    let disc = sqrt(max(mid * mid - det, 0.0));
    let l1 = mid + disc;
    let l2 = max(mid - disc, 1e-6);
    var e1 = vec2<f32>(1.0, 0.0);
    if abs(bb) > 1e-12 * (a + c) {
        e1 = normalize(vec2<f32>(bb, l1 - a));
    } else if c > a {
        e1 = vec2<f32>(0.0, 1.0);
    }
    let e2 = vec2<f32>(-e1.y, e1.x);
    let offset = v.position.x * 3.0 * sqrt(l1) * e1 + v.position.y * 3.0 * sqrt(l2) * e2;
    let centre = view.clip_from_view * vec4<f32>(p, 1.0);
    out.clip_position = centre + vec4<f32>(
        offset.x * 2.0 / view.viewport.z * centre.w,
        -offset.y * 2.0 / view.viewport.w * centre.w,
        0.0,
        0.0,
    );
    out.offset = offset;
    out.conic = vec3<f32>(c / det, -bb / det, a / det);
    var alpha0 = s0.w * params.opacity_scale;
    if params.attenuation == 1u {
        alpha0 *= exp(-2.0 * params.k * sqrt(max(vc[2][2], 0.0)));
    }
    out.colour_alpha = vec4<f32>(splats[b + 3u].xyz, alpha0);
    return out;
}

@fragment
fn fragment(in: SplatVertexOutput) -> @location(0) vec4<f32> {
    let d = in.offset;
    let m = in.conic.x * d.x * d.x + 2.0 * in.conic.y * d.x * d.y + in.conic.z * d.y * d.y;
    if m > 9.0 {
        discard;
    }
    let a = in.colour_alpha.a * exp(-0.5 * m);
    return vec4<f32>(in.colour_alpha.rgb * a, a);
}
