//! Meshes whose vertices only index storage buffers: the shaders place them. Shared by splats, volume
//! slices and tubelets, each drawn as one mesh in one call.

use bevy::asset::RenderAssetUsages;
use bevy::mesh::{Indices, Mesh, PrimitiveTopology};

/// The 12 outward, counter-clockwise triangles of a box whose corner `i` has bit 0, 1, 2 of `i` set for
/// the +x, +y, +z side.
pub const BOX_TRIANGLES: [u32; 36] =
    [0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4, 2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6, 1, 3, 5, 3, 7, 5];

/// `n` quads (at least one); each vertex is (corner x, corner y, slot), corners at ±1, counter-clockwise
/// seen from +z. Slots are exact in f32 up to 2^24.
pub fn slot_quads(n: usize) -> Mesh {
    let mut pos = Vec::with_capacity(4 * n.max(1));
    let mut idx = Vec::with_capacity(6 * n.max(1));
    for i in 0..n.max(1) {
        let s = i as f32;
        pos.extend([[-1.0, -1.0, s], [1.0, -1.0, s], [1.0, 1.0, s], [-1.0, 1.0, s]]);
        let b = 4 * i as u32;
        idx.extend([b, b + 1, b + 2, b, b + 2, b + 3]);
    }
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, pos)
        .with_inserted_indices(Indices::U32(idx))
}
