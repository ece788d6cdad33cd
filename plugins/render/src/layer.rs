//! What every data layer shares: its [`LayerStatus`] (loading, ready, failed: a load or build error is a
//! state of the entity, never a panic), which voxels of a grid it draws ([`Selection`]), and counters of the
//! work each stage did ([`StageCounts`]), which tests read to check that an edit costs what it changes.

use bevy::prelude::*;
use glam::DVec3;

/// The state of a layer entity, kept by its plugin.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub enum LayerStatus {
    /// The data asset is still loading.
    #[default]
    Loading,
    /// Drawn: `items` glyphs (or streamlines, or voxels).
    Ready {
        /// How many glyphs (or streamlines, or voxels) are drawn.
        items: usize,
    },
    /// The data could not be loaded or turned into glyphs; the message names the file and the problem.
    Failed(String),
}

/// Where a layer stacks among the others, for what draws layers in turn (the 2D views' slices, the colour bars):
/// a higher order is drawn over a lower one and its bar above theirs. Default 0; ties keep no fixed order.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Deref, DerefMut)]
pub struct LayerOrder(pub u32);

impl LayerStatus {
    /// The status of a layer whose data asset is `handle`, while it is not (yet) in its `Assets`.
    pub fn of_pending<A: Asset>(server: &AssetServer, handle: &Handle<A>) -> Self {
        match server.load_state(handle.id()) {
            bevy::asset::LoadState::Failed(e) => LayerStatus::Failed(e.to_string()),
            _ if handle.path().is_none() && !server.is_managed(handle.id()) => {
                LayerStatus::Failed("the layer's data handle points at no asset".into())
            }
            _ => LayerStatus::Loading,
        }
    }
}

/// Despawns the children (`children`, a layer entity's) for which `drawn` holds: what a plugin drew under a
/// layer whose data component went; the other children (an app's) stay.
pub fn despawn_drawn(commands: &mut Commands, children: Option<&Children>, drawn: impl Fn(Entity) -> bool) {
    for c in children.into_iter().flat_map(|c| c.iter()) {
        if drawn(c) {
            commands.entity(c).try_despawn();
        }
    }
}

/// A layer's data asset once loaded; until then (or if its load failed) `None`, with `status` set to what
/// [`LayerStatus::of_pending`] says (written only when it differs, so an unchanged status is not marked
/// changed).
pub fn loaded_or_pending<'a, A: Asset>(
    assets: &'a Assets<A>,
    server: &AssetServer,
    handle: &Handle<A>,
    status: &mut Mut<LayerStatus>,
) -> Option<&'a A> {
    let asset = assets.get(handle.id());
    if asset.is_none() {
        let pending = LayerStatus::of_pending(server, handle);
        if **status != pending {
            **status = pending;
        }
    }
    asset
}

/// The assets of type `A` loaded or modified since the reader last read: a layer built from one of them is
/// rebuilt.
pub fn changed_assets<A: Asset>(events: &mut MessageReader<AssetEvent<A>>) -> std::collections::HashSet<AssetId<A>> {
    events
        .read()
        .filter_map(|e| match e {
            AssetEvent::Modified { id } | AssetEvent::LoadedWithDependencies { id } => Some(*id),
            _ => None,
        })
        .collect()
}

/// A voxel axis.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub enum SliceAxis {
    /// The first voxel axis (i); sagittal slices for data stored near RAS+.
    X,
    /// The second voxel axis (j); coronal slices for data stored near RAS+.
    Y,
    /// Axial: the default.
    #[default]
    Z,
}

impl SliceAxis {
    /// The axis' position in a voxel index `[i, j, k]`: 0, 1 or 2.
    pub fn index(self) -> usize {
        match self {
            SliceAxis::X => 0,
            SliceAxis::Y => 1,
            SliceAxis::Z => 2,
        }
    }
}

/// Which voxels of a grid a glyph layer draws.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Selection {
    /// One slice (`index` `None`: the middle one), every `spacing`-th voxel along the two in-plane axes.
    Slice {
        /// The axis normal to the slice.
        axis: SliceAxis,
        /// The slice's voxel index along `axis`; `None`: the middle one (`dims[axis] / 2`).
        index: Option<usize>,
        /// Every `spacing`-th voxel along each in-plane axis, from 0 (at least 1; the default is 1).
        spacing: usize,
    },
    /// Every `spacing`-th voxel along each axis.
    Volume {
        /// Every `spacing`-th voxel along each axis, from 0 (at least 1).
        spacing: usize,
    },
    /// Every voxel of `thickness` neighbouring slices centred on one (`index` `None`: the middle one), as
    /// splats are drawn.
    Slab {
        /// The axis normal to the slab.
        axis: SliceAxis,
        /// The centre slice's voxel index along `axis`; `None`: the middle one (`dims[axis] / 2`).
        index: Option<usize>,
        /// Slices in the slab (at least 1): `(thickness - 1) / 2` before the centre one and `thickness / 2`
        /// after it, clipped to the grid.
        thickness: usize,
    },
}

impl Default for Selection {
    fn default() -> Self {
        Selection::Slice { axis: SliceAxis::Z, index: None, spacing: 1 }
    }
}

impl Selection {
    /// The selected voxels of a `dims` grid, x fastest; an error names a slice outside the grid or a zero
    /// spacing.
    pub fn voxels(&self, dims: [usize; 3]) -> Result<Vec<[usize; 3]>, String> {
        let spacing = match *self {
            Selection::Slice { spacing, .. } | Selection::Volume { spacing } => spacing,
            Selection::Slab { thickness: 0, .. } => {
                return Err("a slab must be at least 1 slice thick".into());
            }
            Selection::Slab { .. } => 1,
        };
        if spacing == 0 {
            return Err("glyph spacing must be at least 1 voxel".into());
        }
        // The range of slices kept along one axis, if any.
        let slab = match *self {
            Selection::Slice { axis, index, .. } | Selection::Slab { axis, index, .. } => {
                let a = axis.index();
                let k = index.unwrap_or(dims[a] / 2);
                if k >= dims[a] {
                    return Err(format!("slice {k} is outside the grid's {} slices along {axis:?}", dims[a]));
                }
                let t = match *self {
                    Selection::Slab { thickness, .. } => thickness,
                    _ => 1,
                };
                Some((a, k.saturating_sub((t - 1) / 2), (k + t / 2).min(dims[a] - 1)))
            }
            Selection::Volume { .. } => None,
        };
        let keep = |p: [usize; 3]| match slab {
            Some((a, lo, hi)) => (lo..=hi).contains(&p[a]) && (0..3).all(|b| b == a || p[b].is_multiple_of(spacing)),
            None => p.iter().all(|c| c.is_multiple_of(spacing)),
        };
        let mut out = Vec::new();
        for z in 0..dims[2] {
            for y in 0..dims[1] {
                for x in 0..dims[0] {
                    if keep([x, y, z]) {
                        out.push([x, y, z]);
                    }
                }
            }
        }
        Ok(out)
    }

    /// The distance between neighbouring glyphs in mm, for a grid of `voxel_size`: the smallest in-plane
    /// (or any) voxel edge times the spacing.
    pub fn cell_mm(&self, voxel_size: DVec3) -> f64 {
        let vs = voxel_size.to_array();
        match *self {
            Selection::Slice { axis, spacing, .. } => {
                (0..3).filter(|&a| a != axis.index()).map(|a| vs[a]).fold(f64::INFINITY, f64::min) * spacing as f64
            }
            Selection::Slab { axis, .. } => {
                (0..3).filter(|&a| a != axis.index()).map(|a| vs[a]).fold(f64::INFINITY, f64::min)
            }
            Selection::Volume { spacing } => voxel_size.min_element() * spacing as f64,
        }
    }
}

/// Work done by a plugin's stages since start-up, summed over its layers: what tests read to check that an
/// edit touched only what it must.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StageCounts {
    /// Layer data read and uploaded anew (a data asset changed or was swapped).
    pub uploads: u32,
    /// A layer's instances repacked from data already held (its selection or shape changed).
    pub repacks: u32,
    /// A layer's uniform rewritten alone (a style change).
    pub uniform_writes: u32,
    /// A layer's per-item colours and opacities rewritten, its geometry untouched (a colouring change).
    pub restyles: u32,
}

/// An asset loader's error: the message names the file and the problem (it reaches the layer's
/// [`LayerStatus::Failed`]).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LoadError(pub String);

impl std::fmt::Display for LoadError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for LoadError {}

/// Reads an asset's bytes to the end (`path` names it in the error).
pub async fn read_all(reader: &mut dyn bevy::asset::io::Reader, path: &std::path::Path) -> Result<Vec<u8>, LoadError> {
    let mut bytes = Vec::new();
    reader.read_to_end(&mut bytes).await.map_err(|e| LoadError(format!("{}: {e}", path.display())))?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn selections_keep_the_voxels_they_name() {
        let dims = [4, 5, 6];
        let slice = Selection::Slice { axis: SliceAxis::Y, index: Some(2), spacing: 2 }.voxels(dims).unwrap();
        assert_eq!(slice.len(), 2 * 3);
        assert!(slice.iter().all(|p| p[1] == 2 && p[0] % 2 == 0 && p[2] % 2 == 0));
        // A slab of 3 around the middle z (3): slices 2..=4, every voxel.
        let slab = Selection::Slab { axis: SliceAxis::Z, index: None, thickness: 3 }.voxels(dims).unwrap();
        assert_eq!(slab.len(), 4 * 5 * 3);
        assert!(slab.iter().all(|p| (2..=4).contains(&p[2])));
        // Even thickness: one more slice above; clipped at the grid's edge.
        let top = Selection::Slab { axis: SliceAxis::Z, index: Some(5), thickness: 4 }.voxels(dims).unwrap();
        assert!(top.iter().all(|p| (4..=5).contains(&p[2])) && top.len() == 2 * 20);
        assert_eq!(Selection::Volume { spacing: 3 }.voxels(dims).unwrap().len(), 2 * 2 * 2);
        let err = Selection::Slab { axis: SliceAxis::X, index: Some(4), thickness: 1 }.voxels(dims).unwrap_err();
        assert!(err.contains("slice 4") && err.contains("4 slices along X"), "{err}");
        assert!(Selection::Slab { axis: SliceAxis::X, index: None, thickness: 0 }.voxels(dims).is_err());
        assert!(Selection::Volume { spacing: 0 }.voxels(dims).is_err());
        let mm = DVec3::new(1.0, 2.0, 3.0);
        assert_eq!(Selection::Slab { axis: SliceAxis::X, index: None, thickness: 3 }.cell_mm(mm), 2.0);
        assert_eq!(Selection::Slice { axis: SliceAxis::Z, index: None, spacing: 2 }.cell_mm(mm), 2.0);
    }
}
