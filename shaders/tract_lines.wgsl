// Tract lines: streamline segments in direction colours (`fascicle_tracts::line_mesh`). The vertex stage
// looks up the streamline's selection flag (UV x is its index) and moves the segments of unselected
// streamlines outside the clip volume, so an ROI edit uploads 4 bytes per streamline and nothing else.
// Keep `LineParams` in sync with `LineUniform` in `plugins/tracts/src/lib.rs`.

#import bevy_pbr::mesh_functions
#import bevy_pbr::view_transformations::position_world_to_clip

struct LineParams {
    opacity: f32,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: LineParams;
// One flag per streamline: 1 selected, 0 hidden.
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var<storage, read> selected: array<u32>;

// Bevy's mesh attribute locations: position 0, UV 2, colour 5.
struct LineVertex {
    @builtin(instance_index) instance_index: u32,
    @location(0) position: vec3<f32>,
    @location(2) uv: vec2<f32>,
    @location(5) color: vec4<f32>,
};

struct LineVertexOutput {
    @builtin(position) clip_position: vec4<f32>,
    @location(0) color: vec4<f32>,
};

@vertex
fn vertex(v: LineVertex) -> LineVertexOutput {
    var out: LineVertexOutput;
    let world_from_local = mesh_functions::get_world_from_local(v.instance_index);
    let w = mesh_functions::mesh_position_local_to_world(world_from_local, vec4<f32>(v.position, 1.0));
    let hidden = selected[u32(v.uv.x)] == 0u;
    out.clip_position = select(position_world_to_clip(w.xyz), vec4<f32>(2.0, 2.0, 2.0, 1.0), hidden);
    out.color = v.color;
    return out;
}

@fragment
fn fragment(in: LineVertexOutput) -> @location(0) vec4<f32> {
    return vec4<f32>(in.color.rgb, params.opacity);
}
