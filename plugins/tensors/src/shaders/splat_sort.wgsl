// The GPU sort of a splat set (`plugins/tensors/src/gpu_sort.rs`): per view, the depth of every splat centre
// along the view direction, then a bitonic sort of (depth, index) pairs, far to near, into the set's `order`
// buffer, which the splat shader reads per quad slot. Nothing comes from the CPU per frame: the view is
// Bevy's view uniform, the set's placement a buffer written when the set moves, and the sort's steps one
// buffer of (k, j) pairs made once per set size, picked by dynamic offset.
//
// Blocks of 512 pairs are sorted, and every merge's last nine steps done, in workgroup memory; the longer
// steps of a merge are one dispatch each. The count is padded to a power of two with keys of -inf, which sort
// to the end: the draw reads only the first n slots.

#import bevy_render::view::View

struct SetParams {
    // Rows of the set's world-from-local affine (xyz: linear part, w: translation).
    row0: vec4<f32>,
    row1: vec4<f32>,
    row2: vec4<f32>,
    // Splats, and the padded count (a power of two, at least 512).
    n: u32,
    padded: u32,
};

struct Step {
    // The merge's size and the compare distance.
    k: u32,
    j: u32,
};

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var<uniform> placement: SetParams;
// Five vec4 per splat; the first holds the centre (`splat.rs`, `pack_geometry`).
@group(0) @binding(2) var<storage, read> splats: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> keys: array<f32>;
@group(0) @binding(4) var<storage, read_write> order: array<u32>;
@group(0) @binding(5) var<uniform> step: Step;

const BLOCK: u32 = 512u;
const FAR: f32 = -3.0e38;

var<workgroup> block_keys: array<f32, 512>;
var<workgroup> block_order: array<u32, 512>;

// The view depth of every centre (larger: farther); the padding gets -inf.
@compute @workgroup_size(256, 1, 1)
fn depths(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= placement.padded {
        return;
    }
    let forward = -view.world_from_view[2].xyz;
    var key = FAR;
    if i < placement.n {
        let c = splats[5u * i].xyz;
        let w = vec3<f32>(dot(placement.row0.xyz, c) + placement.row0.w, dot(placement.row1.xyz, c) + placement.row1.w, dot(placement.row2.xyz, c) + placement.row2.w);
        key = dot(w, forward);
    }
    keys[i] = key;
    order[i] = i;
}

// Whether (key a, index ia) comes before (b, ib) in the sorted order: farther first, ties by index (as the
// CPU's stable argsort).
fn before(a: f32, ia: u32, b: f32, ib: u32) -> bool {
    return a > b || (a == b && ia < ib);
}

// The pair (i, i + j) of compare-exchange t for a merge of size k: kept in descending order where bit k of the
// position is clear, ascending where it is set (the bitonic network; at k = padded all of it descends).
fn pair(t: u32, j: u32) -> u32 {
    return 2u * j * (t / j) + t % j;
}

fn exchange_local(t: u32, k: u32, j: u32, base: u32) {
    let i = pair(t, j);
    let l = i + j;
    let descending = ((base + i) & k) == 0u;
    let a = block_keys[i];
    let b = block_keys[l];
    let oa = block_order[i];
    let ob = block_order[l];
    // Where the network sorts in the final direction, (i, l) must be in order; elsewhere reversed.
    if select(before(a, oa, b, ob), before(b, ob, a, oa), descending) {
        block_keys[i] = b;
        block_keys[l] = a;
        block_order[i] = ob;
        block_order[l] = oa;
    }
}

fn load_block(base: u32, lid: u32) {
    block_keys[lid] = keys[base + lid];
    block_keys[lid + 256u] = keys[base + lid + 256u];
    block_order[lid] = order[base + lid];
    block_order[lid + 256u] = order[base + lid + 256u];
    workgroupBarrier();
}

fn store_block(base: u32, lid: u32) {
    workgroupBarrier();
    keys[base + lid] = block_keys[lid];
    keys[base + lid + 256u] = block_keys[lid + 256u];
    order[base + lid] = block_order[lid];
    order[base + lid + 256u] = block_order[lid + 256u];
}

// Every merge up to size 512, within each block.
@compute @workgroup_size(256, 1, 1)
fn sort_blocks(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_id) local: vec3<u32>) {
    let base = group.x * BLOCK;
    load_block(base, local.x);
    for (var k = 2u; k <= BLOCK; k = k << 1u) {
        for (var j = k >> 1u; j > 0u; j = j >> 1u) {
            exchange_local(local.x, k, j, base);
            workgroupBarrier();
        }
    }
    store_block(base, local.x);
}

// The steps j = 256 .. 1 of merge `step.k`, within each block.
@compute @workgroup_size(256, 1, 1)
fn merge_blocks(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_id) local: vec3<u32>) {
    let base = group.x * BLOCK;
    load_block(base, local.x);
    for (var j = BLOCK >> 1u; j > 0u; j = j >> 1u) {
        exchange_local(local.x, step.k, j, base);
        workgroupBarrier();
    }
    store_block(base, local.x);
}

// One step (k, j >= 512) of a merge, over the whole buffer.
@compute @workgroup_size(256, 1, 1)
fn merge_step(@builtin(global_invocation_id) id: vec3<u32>) {
    let t = id.x;
    if t >= placement.padded / 2u {
        return;
    }
    let i = pair(t, step.j);
    let l = i + step.j;
    let descending = (i & step.k) == 0u;
    let a = keys[i];
    let b = keys[l];
    let oa = order[i];
    let ob = order[l];
    if select(before(a, oa, b, ob), before(b, ob, a, oa), descending) {
        keys[i] = b;
        keys[l] = a;
        order[i] = ob;
        order[l] = oa;
    }
}
