// Tract meshes: lines (`fascicle_tracts::line_mesh`) or polygon tubes (`polygon_tube_mesh`) in direction
// colours, tubes with headlight shading. The vertex stage looks up the streamline's selection bit (the vertex
// carries its index) and moves the vertices of unselected streamlines outside the clip volume, so an ROI edit
// uploads a bit per streamline and nothing else. Keep `TractMeshParams` in sync with `TractMeshUniform` in
// `plugins/tracts/src/lib.rs`.

#import bevy_pbr::mesh_functions
#import bevy_pbr::mesh_view_bindings::view
#import bevy_pbr::view_transformations::position_world_to_clip

struct TractMeshParams {
    opacity: f32,
    ambient: f32,
    // > 0: crop to |dot(slab.xyz, p) - slab.w| <= slab_half and draw over the scene's depth.
    slab_half: f32,
    slab: vec4<f32>,
};

@group(#{MATERIAL_BIND_GROUP}) @binding(0) var<uniform> params: TractMeshParams;
// One bit per streamline, set when selected: bit s % 32 of word s / 32 (`selection_words`).
@group(#{MATERIAL_BIND_GROUP}) @binding(1) var<storage, read> selected: array<u32>;

// The compact vertex (`TractMeshMaterial::specialize`): position 0, normal 1 (tubes only: VERTEX_NORMALS),
// streamline index 2, colour 5 (8 bits a channel).
struct TractVertex {
    @builtin(instance_index) instance_index: u32,
    @location(0) position: vec3<f32>,
#ifdef VERTEX_NORMALS
    @location(1) normal: vec3<f32>,
#endif
    @location(2) streamline: u32,
    @location(5) color: vec4<f32>,
};

// Lines that do not crop pass the colour alone: every varying is interpolated per fragment and stored with each
// primitive lavapipe bins (WORLD_POSITION: cropping or shaded tubes).
struct TractVertexOutput {
    @builtin(position) clip_position: vec4<f32>,
    @location(0) color: vec4<f32>,
#ifdef WORLD_POSITION
    @location(1) world_position: vec3<f32>,
#endif
#ifdef VERTEX_NORMALS
    @location(2) world_normal: vec3<f32>,
#endif
};

@vertex
fn vertex(v: TractVertex) -> TractVertexOutput {
    var out: TractVertexOutput;
    let world_from_local = mesh_functions::get_world_from_local(v.instance_index);
    let w = mesh_functions::mesh_position_local_to_world(world_from_local, vec4<f32>(v.position, 1.0));
    // A narrowed preview's vertices (`UNFLAGGED`) are shown whatever the flags: it holds selected streamlines only.
    let hidden = v.streamline != 0xffffffffu && ((selected[v.streamline >> 5u] >> (v.streamline & 31u)) & 1u) == 0u;
    // Cropped to a slab: drawn on the slab's centre plane, 1 mm towards the eye, so that a 2D view looking along
    // the normal shows it where it is, over its images (within 1 mm of the plane) and under its crosshair. The
    // fragment stage crops by the true position. A select, not an `if` on a uniform alone (lavapipe, see
    // lib/ray.wgsl).
    let n = params.slab.xyz;
    let eye_side = sign(dot(n, view.world_position) - params.slab.w);
    let on_plane = w.xyz - (dot(n, w.xyz) - params.slab.w - eye_side) * n;
    let drawn_at = select(w.xyz, on_plane, params.slab_half > 0.0);
    out.clip_position = select(position_world_to_clip(drawn_at), vec4<f32>(2.0, 2.0, 2.0, 1.0), hidden);
    out.color = v.color;
#ifdef WORLD_POSITION
    out.world_position = w.xyz;
#endif
#ifdef VERTEX_NORMALS
    out.world_normal = mesh_functions::mesh_normal_local_to_world(v.normal, v.instance_index);
#endif
    return out;
}

@fragment
fn fragment(in: TractVertexOutput) -> @location(0) vec4<f32> {
    // Only materials that crop can discard (`TractMeshKey`): a fragment stage that can is depth-tested after
    // it runs, which on lavapipe costs a sixth of a whole-brain frame.
#ifdef SLAB_CROP
    let from_plane = abs(dot(params.slab.xyz, in.world_position) - params.slab.w);
    if from_plane > select(3.0e38, params.slab_half, params.slab_half > 0.0) {
        discard;
    }
#endif
#ifdef VERTEX_NORMALS
    let to_eye = normalize(view.world_position - in.world_position);
    let k = params.ambient + (1.0 - params.ambient) * abs(dot(normalize(in.world_normal), to_eye));
#else
    let k = 1.0;
#endif
    return vec4<f32>(in.color.rgb * k, params.opacity);
}
