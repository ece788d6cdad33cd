// Sphere impostor: the reference opaque ray-cast primitive of the framework.
//
// How it works: the material is drawn on a cube mesh that bounds the sphere. Each fragment casts the
// view ray against the sphere analytically, discards misses, shades with the headlight, and writes the
// true depth of the hit (frag_depth), so the sphere intersects meshes and other glyphs correctly in the
// main opaque pass. The prepass is disabled for this material (see `impostor.rs`), otherwise the prepass
// would write the proxy cube's depth.
// Keep the uniform in sync with `ImpostorUniform` in `plugins/render/src/impostor.rs`.

#import bevy_pbr::forward_io::VertexOutput
#import bevy_pbr::mesh_view_bindings::view
#import fascicle::ray::{Ray, view_ray, ray_sphere, depth_of}
#import fascicle::lighting::headlight

struct ImpostorUniform {
    center_radius: vec4<f32>,
    color_ambient: vec4<f32>,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: ImpostorUniform;

struct FragmentOutput {
    @location(0) color: vec4<f32>,
    @builtin(frag_depth) depth: f32,
};

@fragment
fn fragment(in: VertexOutput) -> FragmentOutput {
    let ray = view_ray(in.world_position.xyz, view.world_position, view.world_from_view, view.clip_from_view);
    let t = ray_sphere(ray, params.center_radius.xyz, params.center_radius.w);
    if t < 0.0 {
        discard;
    }
    let p = ray.origin + t * ray.dir;
    let n = (p - params.center_radius.xyz) / params.center_radius.w;
    var out: FragmentOutput;
    out.color = vec4<f32>(headlight(params.color_ambient.rgb, n, ray.dir, params.color_ambient.a), 1.0);
    out.depth = depth_of(view.clip_from_world, p);
    return out;
}
