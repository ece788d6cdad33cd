//! Meshes whose vertices only index storage buffers: the shaders place them. Shared by splats, volume
//! slices, tubelets and the ray-cast glyphs, each set drawn as one mesh in one call.

use bevy::asset::RenderAssetUsages;
use bevy::math::Vec3;
use bevy::mesh::{Indices, Mesh, PrimitiveTopology};

/// The 12 outward, counter-clockwise triangles of a box whose corner `i` has bit 0, 1, 2 of `i` set for
/// the +x, +y, +z side.
pub const BOX_TRIANGLES: [u32; 36] =
    [0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4, 2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6, 1, 3, 5, 3, 7, 5];

/// `n` quads (at least one); each vertex is (corner x, corner y, slot), corners at ±1, counter-clockwise
/// seen from +z. Slots are exact in f32 up to 2^24.
pub fn slot_quads(n: usize) -> Mesh {
    slot_quads_of(0..n.max(1) as u32)
}

/// One quad per slot of `slots`, as [`slot_quads`] makes them (4 vertices (corner x, corner y, slot), 2
/// triangles); slots are exact in f32 up to 2^24.
pub fn slot_quads_of(slots: impl ExactSizeIterator<Item = u32>) -> Mesh {
    let mut pos = Vec::with_capacity(4 * slots.len());
    let mut idx = Vec::with_capacity(6 * slots.len());
    for (i, slot) in slots.enumerate() {
        let s = slot as f32;
        pos.extend([[-1.0, -1.0, s], [1.0, -1.0, s], [1.0, 1.0, s], [-1.0, 1.0, s]]);
        let b = 4 * i as u32;
        idx.extend([b, b + 1, b + 2, b, b + 2, b + 3]);
    }
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, pos)
        .with_inserted_indices(Indices::U32(idx))
}

/// `n` boxes (at least one): [`slot_boxes_of`] the slots `0..n`.
pub fn slot_boxes(n: usize) -> Mesh {
    slot_boxes_of(&(0..n.max(1) as u32).collect::<Vec<_>>())
}

/// One box per entry of `slots` (indices into a set's storage buffer): 8 vertices (slot, corner, 0), the
/// corner numbered as in [`BOX_TRIANGLES`], and its 12 outward counter-clockwise triangles. The vertex
/// shader places each corner from the slot's buffer entry (`fascicle::proxy` for glyphs); slots are exact
/// in f32 up to 2^24.
pub fn slot_boxes_of(slots: &[u32]) -> Mesh {
    let mut pos = Vec::with_capacity(8 * slots.len());
    let mut idx = Vec::with_capacity(36 * slots.len());
    for (k, &slot) in slots.iter().enumerate() {
        for c in 0..8 {
            pos.push([slot as f32, c as f32, 0.0]);
        }
        idx.extend(BOX_TRIANGLES.iter().map(|i| i + 8 * k as u32));
    }
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, pos)
        .with_inserted_indices(Indices::U32(idx))
}

/// Glyph sets of more glyphs than this get a coarse preview ([`every_other_cell`]): 4,000.
pub const GLYPH_PREVIEW_MIN: usize = 4_000;

/// The items (indices into `centres`) of a preview that keeps every other cell of a grid: those at an even
/// rank along each axis on which the centres take more than one value (coordinates equal to 1 µm count as
/// one). A quarter of a slice's glyphs, an eighth of a volume's, spread evenly; for glyphs off the world axes
/// (an oblique plane) about an eighth, scattered. `None` for [`GLYPH_PREVIEW_MIN`] items or fewer.
pub fn every_other_cell(centres: &[Vec3]) -> Option<Vec<u32>> {
    if centres.len() <= GLYPH_PREVIEW_MIN {
        return None;
    }
    let key = |v: f32| (v as f64 * 1e3).round() as i64;
    let mut even = vec![true; centres.len()];
    for axis in 0..3 {
        let mut values: Vec<i64> = centres.iter().map(|c| key(c[axis])).collect();
        values.sort_unstable();
        values.dedup();
        if values.len() < 2 {
            continue;
        }
        for (keep, c) in even.iter_mut().zip(centres) {
            *keep &= values.binary_search(&key(c[axis])).is_ok_and(|rank| rank % 2 == 0);
        }
    }
    Some((0..centres.len() as u32).filter(|&i| even[i as usize]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_other_cell_keeps_a_quarter_of_a_slice_and_an_eighth_of_a_volume() {
        let grid = |nx: usize, ny: usize, nz: usize| -> Vec<Vec3> {
            let mut out = Vec::new();
            for z in 0..nz {
                for y in 0..ny {
                    for x in 0..nx {
                        out.push(Vec3::new(x as f32 * 1.5 - 40.0, y as f32 * 1.5, 7.0 + z as f32 * 1.5));
                    }
                }
            }
            out
        };
        let slice = grid(100, 60, 1);
        let kept = every_other_cell(&slice).expect("over the limit");
        assert_eq!(kept.len(), 50 * 30);
        // Cells (0, 0), (2, 0), ..., each at even x and y indices.
        assert!(kept.iter().all(|&i| (i % 100) % 2 == 0 && (i / 100) % 2 == 0));
        let volume = grid(20, 20, 20);
        assert_eq!(every_other_cell(&volume).expect("over the limit").len(), 1000);
        assert!(every_other_cell(&slice[..GLYPH_PREVIEW_MIN]).is_none());
    }
}
