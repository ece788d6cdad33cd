// Tensor splatting (SEEDS.md section 1): each splat a 3D Gaussian whose footprint is projected with the
// local affine approximation of the perspective projection (EWA), drawn as a camera-facing quad bounding the
// footprint at 3 standard deviations, with an elliptical Gaussian opacity, premultiplied alpha.
//
// A splat set is one draw: a static mesh of N quads whose vertices carry their quad's slot (position.z);
// `order[slot]` names the splat drawn there. The CPU re-sorts `order` far to near only when the view
// direction changes, so quads are rasterised, and blended, in depth order within the single draw.
// Colour and opacity come from `styles` (rewritten alone when the transfer function changes).
// The f64 reference is `fascicle_core::dti::splat`; keep `SplatParams` in sync with `SplatUniform` in
// `plugins/tensors/src/splat.rs`.

#import bevy_pbr::mesh_functions
#import bevy_pbr::mesh_view_bindings::view

struct SplatParams {
    attenuation: u32,
    k: f32,
    dilation: f32,
    opacity_scale: f32,
    lit: u32,
    ambient: f32,
    diffuse: f32,
    specular: f32,
    shininess: f32,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: SplatParams;
// Five vec4 per splat: (centre, cl), (xx, xy, xz, yy), (yz, zz, cp, cs), (e1, 1/s^2), (e3, 0), s the
// splat's largest standard deviation (depth attenuation is measured in units of it).
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var<storage, read> splats: array<vec4<f32>>;
// One vec4 per splat: linear rgb, opacity.
@group(#{MATERIAL_BIND_GROUP}) @binding(2) var<storage, read> styles: array<vec4<f32>>;
// Splat index per quad slot, far to near.
@group(#{MATERIAL_BIND_GROUP}) @binding(3) var<storage, read> order: array<u32>;

struct SplatVertex {
    @builtin(instance_index) instance_index: u32,
    // (corner x, corner y, slot)
    @location(0) position: vec3<f32>,
};

struct SplatVertexOutput {
    @builtin(position) clip_position: vec4<f32>,
    // Offset from the footprint's centre in pixels (y down).
    @location(0) offset: vec2<f32>,
    @location(1) @interpolate(flat) conic: vec3<f32>,
    @location(2) @interpolate(flat) colour_alpha: vec4<f32>,
};

// Lit-tensor shading (Kindlmann), headlight; `fascicle_core::dti::splat::LitTensor` is the reference.
fn lit_colour(colour: vec3<f32>, to_eye: vec3<f32>, e1: vec3<f32>, e3: vec3<f32>, shape: vec3<f32>) -> vec3<f32> {
    let le = dot(to_eye, e1);
    let dl = sqrt(max(1.0 - le * le, 0.0));
    let dp = abs(dot(to_eye, e3));
    let d = shape.x * dl + shape.y * dp + shape.z;
    let s = shape.x * pow(dl, params.shininess) + shape.y * pow(dp, params.shininess);
    return colour * (params.ambient + params.diffuse * d) + vec3<f32>(params.specular * s);
}

@vertex
fn vertex(v: SplatVertex) -> SplatVertexOutput {
    var out: SplatVertexOutput;
    let id = order[u32(v.position.z)];
    let b = 5u * id;
    let s0 = splats[b];
    let s1 = splats[b + 1u];
    let s2 = splats[b + 2u];
    let world_from_local = mesh_functions::get_world_from_local(v.instance_index);
    let m = mat3x3<f32>(world_from_local[0].xyz, world_from_local[1].xyz, world_from_local[2].xyz);
    let cov_local = mat3x3<f32>(
        vec3<f32>(s1.x, s1.y, s1.z),
        vec3<f32>(s1.y, s1.w, s2.x),
        vec3<f32>(s1.z, s2.x, s2.y),
    );
    let centre = (world_from_local * vec4<f32>(s0.xyz, 1.0)).xyz;
    let style = styles[id];
    let p = (view.view_from_world * vec4<f32>(centre, 1.0)).xyz;
    let z = -p.z;
    if z <= 1e-6 || style.w <= 0.0 {
        // Behind the camera, or transparent: outside the clip volume.
        out.clip_position = vec4<f32>(2.0, 2.0, 2.0, 1.0);
        return out;
    }
    let w = mat3x3<f32>(view.view_from_world[0].xyz, view.view_from_world[1].xyz, view.view_from_world[2].xyz) * m;
    let vc = w * cov_local * transpose(w);
    let f = view.clip_from_view[1][1] * view.main_pass_viewport.w * 0.5;
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
    let clip = view.clip_from_view * vec4<f32>(p, 1.0);
    out.clip_position = clip + vec4<f32>(
        offset.x * 2.0 / view.main_pass_viewport.z * clip.w,
        -offset.y * 2.0 / view.main_pass_viewport.w * clip.w,
        0.0,
        0.0,
    );
    out.offset = offset;
    out.conic = vec3<f32>(c / det, -bb / det, a / det);
    // Both toggles by `select`, not `if`: no branch on a uniform alone (the rule in `fascicle::ray`).
    let attenuation = exp(-2.0 * params.k * sqrt(max(vc[2][2] * splats[b + 3u].w, 0.0)));
    let alpha0 = style.w * params.opacity_scale * select(1.0, attenuation, params.attenuation == 1u);
    let to_eye = normalize(view.world_position - centre);
    let a1 = normalize(m * splats[b + 3u].xyz);
    let a3 = normalize(m * splats[b + 4u].xyz);
    let lit = lit_colour(style.xyz, to_eye, a1, a3, vec3<f32>(s0.w, s2.z, s2.w));
    out.colour_alpha = vec4<f32>(select(style.xyz, lit, params.lit == 1u), alpha0);
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
