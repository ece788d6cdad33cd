// The vertex stage shared by ray-cast glyphs. A set's proxies are one mesh
// (`fascicle_render::meshes::slot_boxes`): a box per glyph, each vertex (glyph index, corner 0..7, 0), the
// corner's bits 0, 1, 2 set on its +x, +y, +z side. The glyph's shader reads the box (centre and half
// extents) from its own storage buffer; `proxy_vertex` places the corner and passes the index flat to the
// fragment stage (`tag`), which indexes the same buffers.
//
// `knobs` carries the material's integer settings (loop counts, modes) flat to the fragment stage, which
// branches on them and never on the uniform (the rule in `fascicle::ray`).
#define_import_path fascicle::proxy

#import bevy_pbr::mesh_functions
#import bevy_pbr::view_transformations::position_world_to_clip

struct ProxyVertex {
    @builtin(instance_index) instance_index: u32,
    // (glyph index, corner, 0)
    @location(0) position: vec3<f32>,
};

struct ProxyVertexOutput {
    @builtin(position) clip_position: vec4<f32>,
    @location(0) world_position: vec3<f32>,
    @location(1) @interpolate(flat) tag: u32,
    @location(2) @interpolate(flat) knobs: vec4<u32>,
};

// The index of the glyph whose box this vertex is a corner of.
fn proxy_glyph(v: ProxyVertex) -> u32 {
    return u32(v.position.x);
}

// The corner of the box `centre ± half` (in the mesh's space) this vertex stands for.
fn proxy_vertex(v: ProxyVertex, centre: vec3<f32>, half: vec3<f32>, knobs: vec4<u32>) -> ProxyVertexOutput {
    var out: ProxyVertexOutput;
    let c = u32(v.position.y);
    let corner = vec3<f32>(vec3<u32>(c & 1u, (c >> 1u) & 1u, (c >> 2u) & 1u)) * 2.0 - 1.0;
    let world_from_local = mesh_functions::get_world_from_local(v.instance_index);
    let w = mesh_functions::mesh_position_local_to_world(world_from_local, vec4<f32>(centre + corner * half, 1.0));
    out.clip_position = position_world_to_clip(w.xyz);
    out.world_position = w.xyz;
    out.tag = proxy_glyph(v);
    out.knobs = knobs;
    return out;
}
