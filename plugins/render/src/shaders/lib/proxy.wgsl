// The vertex stage shared by instanced ray-cast glyphs: a proxy mesh per glyph entity, placed by the mesh's
// transform, with the entity's `MeshTag` passed flat to the fragment stage to index the glyph buffers.
//
// `knobs` carries the material's integer settings (loop counts, modes) flat to the fragment stage, which
// branches on them and never on the uniform (the rule in `fascicle::ray`).
#define_import_path fascicle::proxy

#import bevy_pbr::mesh_functions
#import bevy_pbr::view_transformations::position_world_to_clip

struct ProxyVertex {
    @builtin(instance_index) instance_index: u32,
    @location(0) position: vec3<f32>,
};

struct ProxyVertexOutput {
    @builtin(position) clip_position: vec4<f32>,
    @location(0) world_position: vec3<f32>,
    @location(1) @interpolate(flat) tag: u32,
    @location(2) @interpolate(flat) knobs: vec4<u32>,
};

fn proxy_vertex(v: ProxyVertex, knobs: vec4<u32>) -> ProxyVertexOutput {
    return proxy_vertex_scaled(v, knobs, 1.0);
}

// `proxy_vertex` with the proxy scaled by `scale` about its mesh's origin (the glyph centre): a layer-wide
// size set by a uniform, no instance rewritten.
fn proxy_vertex_scaled(v: ProxyVertex, knobs: vec4<u32>, scale: f32) -> ProxyVertexOutput {
    var out: ProxyVertexOutput;
    let world_from_local = mesh_functions::get_world_from_local(v.instance_index);
    let w = mesh_functions::mesh_position_local_to_world(world_from_local, vec4<f32>(v.position * scale, 1.0));
    out.clip_position = position_world_to_clip(w.xyz);
    out.world_position = w.xyz;
    out.tag = mesh_functions::get_tag(v.instance_index);
    out.knobs = knobs;
    return out;
}
