//! Tensor layers driven by components: spawn an entity with [`TensorGlyphs`] or [`TensorSplats`] (the data:
//! a [`TensorField`] asset, loaded from a `.nii`/`.nii.gz` tensor image off the main thread) and, optionally,
//! its settings components; the plugin builds and updates everything on the GPU.
//!
//! Each stage reacts to its own component, for that layer only:
//!
//! | change | glyphs | splats |
//! |---|---|---|
//! | the data (handle swapped, asset modified) | rebuilt and uploaded | rebuilt and uploaded |
//! | [`Selection`], [`TensorGlyphShape`] / [`SplatShape`] | instances repacked from the field in memory | same |
//! | [`TensorGlyphSettings`] | one uniform write (a new `shape` repacks: the glyphs' bounds change) | |
//! | [`SplatSettings`] | | one uniform write; a new `colouring` rewrites the colour buffer only |
//!
//! [`TensorGlyphCounts`] and [`SplatCounts`] count each stage's work; [`LayerStatus`] on the entity tells
//! loading, ready (with the glyph or splat count) or the error.

use std::collections::HashSet;
use std::path::Path;
use std::sync::Arc;

use bevy::asset::io::Reader;
use bevy::asset::{AssetLoader, LoadContext};
use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::Volume;
use fascicle_core::dti::glyph::{TensorGlyph, tensor_glyph};
use fascicle_core::dti::splat::{Splat, tensor_splat};
use fascicle_core::io::classify::TensorOrder;
use fascicle_render::layer::{
    LayerStatus, LoadError, Selection, SliceAxis, StageCounts, changed_assets, loaded_or_pending, read_all,
};
use glam::{DMat3, DVec3};

use crate::splat::{SplatMaterial, SplatSet, SplatSettings, spawn_splats};
use crate::{TensorGlyphSet, TensorGlyphSettings, TensorGlyphStores};

/// A diffusion tensor field: `X x Y x Z x 6` lower-triangular tensors in DIPY's order (Dxx, Dxy, Dyy, Dxz,
/// Dyz, Dzz), in the voxel frame, with the voxel-to-world affine (RAS+ mm), as `fascicle fit dti` and
/// DIPY's `TensorModel` write them.
#[derive(Asset, TypePath, Clone, Debug)]
pub struct TensorField {
    /// The tensors, `X x Y x Z x 6` (`data[x + X*(y + Y*(z + Z*c))]` for component `c` in DIPY's order), in
    /// the file's units, with the image's `world_from_voxel` (voxel indices to RAS+ mm).
    pub tensors: Arc<Volume<f32>>,
}

impl TensorField {
    /// Checks that `tensors` has 6 values per voxel.
    pub fn new(tensors: Volume<f32>) -> Result<Self, String> {
        if tensors.shape.len() < 4 || tensors.n_channels() != 6 {
            return Err(format!("{:?} is not a tensor image (X,Y,Z,6: Dxx, Dxy, Dyy, Dxz, Dyz, Dzz)", tensors.shape));
        }
        Ok(Self { tensors: Arc::new(tensors) })
    }

    /// The world centre and the world-frame tensor (lower-triangular) of each voxel: the tensor is rotated
    /// by the rotation of the affine's polar decomposition (shears and voxel sizes do not deform it).
    pub fn world_tensors(&self, voxels: &[[usize; 3]]) -> Vec<(DVec3, [f64; 6])> {
        let v = &self.tensors;
        let (d, n) = (v.dims3(), v.n_voxels());
        let rot = fascicle_core::linalg::polar_rotation(DMat3::from_mat4(v.world_from_voxel));
        voxels
            .iter()
            .map(|&[x, y, z]| {
                let i = x + d[0] * (y + d[1] * z);
                let t: [f64; 6] = std::array::from_fn(|c| v.data[i + n * c] as f64);
                let m = DMat3::from_cols_array(&[t[0], t[1], t[3], t[1], t[2], t[4], t[3], t[4], t[5]]);
                let w = rot * m * rot.transpose();
                let centre = v.world_from_voxel.transform_point3(DVec3::new(x as f64, y as f64, z as f64));
                (centre, [w.x_axis.x, w.x_axis.y, w.y_axis.y, w.x_axis.z, w.y_axis.z, w.z_axis.z])
            })
            .collect()
    }
}

/// Settings of the tensor image loader: the element order when it is not the format's own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct TensorFieldSettings {
    /// The order of the 6 volumes. Defaults to `None`: for a NIfTI DIPY's (Dxx Dxy Dyy Dxz Dyz Dzz), for a
    /// `.mif` MRtrix3's (D11 D22 D33 D12 D13 D23).
    pub order: Option<TensorOrder>,
}

/// Loads tensor images as [`TensorField`]s, off the main thread: `.nii` / `.nii.gz` (in the voxel frame, as
/// DIPY and FSL write them) and MRtrix `.mif` / `.mif.gz` (`dwi2tensor`'s, in the scanner frame: turned into
/// the voxel frame on load).
#[derive(Default, TypePath)]
pub struct TensorFieldLoader;

impl AssetLoader for TensorFieldLoader {
    type Asset = TensorField;
    type Settings = TensorFieldSettings;
    type Error = LoadError;

    async fn load(
        &self,
        reader: &mut dyn Reader,
        settings: &TensorFieldSettings,
        ctx: &mut LoadContext<'_>,
    ) -> Result<TensorField, LoadError> {
        let path = ctx.path().path().to_path_buf();
        let bytes = read_all(reader, &path).await?;
        read_field(bytes, &path, settings).map_err(LoadError)
    }

    fn extensions(&self) -> &[&str] {
        &["nii", "nii.gz", "mif", "mif.gz"]
    }
}

/// A [`TensorField`] from a file's bytes (`path` names it: `.mif`/`.mif.gz` as MRtrix3's, else NIfTI), its
/// volumes reordered into DIPY's order and, for a `.mif`, turned from the scanner frame into the voxel frame.
pub fn read_field(bytes: Vec<u8>, path: &Path, settings: &TensorFieldSettings) -> Result<TensorField, String> {
    use fascicle_core::io::mif;
    let is_mif = mif::is_mif(path);
    let mut vol = mif::read_image_bytes::<f32>(bytes, path).map_err(|e| e.to_string())?;
    if vol.shape.len() < 4 || vol.n_channels() != 6 {
        return Err(format!("{}: {:?} is not a tensor image (X,Y,Z,6 volumes)", path.display(), vol.shape));
    }
    let default = if is_mif { TensorOrder::Mrtrix } else { TensorOrder::Dipy };
    settings.order.unwrap_or(default).to_dipy(&mut vol);
    if is_mif {
        world_to_voxel_frame(&mut vol);
    }
    TensorField::new(vol).map_err(|e| format!("{}: {e}", path.display()))
}

/// Turns DIPY-ordered tensors from the world (scanner) frame into the voxel frame: `R^T D R`, with `R` the
/// rotation of the affine's polar decomposition (what [`TensorField::world_tensors`] applies the other way).
pub fn world_to_voxel_frame(vol: &mut Volume<f32>) {
    let rot = fascicle_core::linalg::polar_rotation(DMat3::from_mat4(vol.world_from_voxel));
    let n = vol.n_voxels();
    for i in 0..n {
        let t: [f64; 6] = std::array::from_fn(|c| f64::from(vol.data[i + n * c]));
        let m = DMat3::from_cols_array(&[t[0], t[1], t[3], t[1], t[2], t[4], t[3], t[4], t[5]]);
        let v = rot.transpose() * m * rot;
        let out = [v.x_axis.x, v.x_axis.y, v.y_axis.y, v.x_axis.z, v.y_axis.z, v.z_axis.z];
        for (c, x) in out.into_iter().enumerate() {
            vol.data[i + n * c] = x as f32;
        }
    }
}

/// The data component of a tensor glyph layer: ray-cast ellipsoids or superquadrics, one per selected voxel.
/// Settings components absent at spawn get their defaults: the middle axial slice, glyphs filling 90 % of
/// their cell, ellipsoids coloured by direction.
#[derive(Component, Clone, Debug, Default)]
#[require(Selection, TensorGlyphShape, TensorGlyphSettings, LayerStatus, Transform, Visibility)]
pub struct TensorGlyphs {
    /// The tensor field drawn, usually `AssetServer::load("dti_tensors.nii.gz")`. Swapping it, or the asset being
    /// modified, rebuilds and re-uploads the layer's glyphs.
    pub field: Handle<TensorField>,
}

/// Which tensors become glyphs and how large (changing it repacks the layer).
#[derive(Component, Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TensorGlyphShape {
    /// The largest diameter as a fraction of the selection's cell (the spacing of neighbouring glyphs).
    pub size: f64,
    /// Voxels with FA below this get no glyph.
    pub min_fa: f64,
    /// The smallest radius as a fraction of the largest (keeps planar and linear tensors visible).
    pub floor: f64,
}

impl Default for TensorGlyphShape {
    fn default() -> Self {
        Self { size: 0.9, min_fa: 0.0, floor: 0.1 }
    }
}

/// The data component of a splat layer: one Gaussian footprint per selected voxel, sorted and composited
/// (see [`crate::splat`]). Defaults: a 3-slice axial slab through the middle, splats of 0.5 voxel.
#[derive(Component, Clone, Debug, Default)]
#[require(
    Selection = Selection::Slab { axis: SliceAxis::Z, index: None, thickness: 3 },
    SplatShape,
    SplatSettings,
    LayerStatus,
    Transform,
    Visibility
)]
pub struct TensorSplats {
    /// The tensor field drawn, usually `AssetServer::load("dti_tensors.nii.gz")`. Swapping it, or the asset being
    /// modified, rebuilds and re-uploads the layer's splats.
    pub field: Handle<TensorField>,
}

/// Which tensors become splats and how large (changing it repacks the layer).
#[derive(Component, Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SplatShape {
    /// The largest standard deviation as a fraction of the selection's cell.
    pub size: f64,
    /// Voxels with FA below this get no splat. Defaults to 0.
    pub min_fa: f64,
}

impl Default for SplatShape {
    fn default() -> Self {
        Self { size: 0.5, min_fa: 0.0 }
    }
}

/// The work of the tensor glyph layers' stages (see [`StageCounts`]).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq, Deref)]
pub struct TensorGlyphCounts(pub StageCounts);

/// The work of the splat layers' stages (see [`StageCounts`]).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq, Deref)]
pub struct SplatCounts(pub StageCounts);

/// The plugin's systems, in `PostUpdate`: [`TensorSystems::Prepare`] builds and restyles the layers that
/// changed (after the asset events, before transform propagation, so edits made in `Update` show in the
/// same frame); [`TensorSystems::Sort`] re-sorts splat sets whose view direction changed (after
/// propagation: it needs the camera's and the sets' global transforms).
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TensorSystems {
    /// Builds, repacks and restyles the [`TensorGlyphs`] and [`TensorSplats`] layers that changed (before
    /// transform propagation).
    Prepare,
    /// Re-sorts on the CPU the splat sets whose view direction changed
    /// ([`sort_splats`](crate::splat::sort_splats); after transform propagation).
    Sort,
}

pub(crate) fn build(app: &mut App) {
    use bevy::transform::TransformSystems;
    app.init_asset::<TensorField>()
        .register_asset_loader(TensorFieldLoader)
        .init_resource::<TensorGlyphCounts>()
        .init_resource::<SplatCounts>()
        .configure_sets(
            PostUpdate,
            (
                TensorSystems::Prepare.after(bevy::asset::AssetEventSystems).before(TransformSystems::Propagate),
                TensorSystems::Sort.after(TransformSystems::Propagate),
            ),
        )
        .add_systems(PostUpdate, (sync_glyph_layers, sync_splat_layers).in_set(TensorSystems::Prepare));
}

/// The glyphs of `selection` with FA at least `shape.min_fa`, rotated into the world frame, and their voxels.
pub fn field_tensor_glyphs(
    field: &TensorField,
    selection: &Selection,
    shape: &TensorGlyphShape,
) -> Result<(Vec<TensorGlyph>, Vec<[u32; 3]>), String> {
    let voxels = selection.voxels(field.tensors.dims3())?;
    let radius = shape.size * selection.cell_mm(field.tensors.voxel_size()) / 2.0;
    let mut out = (Vec::new(), Vec::new());
    for (p, (centre, t)) in voxels.iter().zip(field.world_tensors(&voxels)) {
        if let Some(g) = tensor_glyph(centre, &t, radius, shape.floor)
            && g.fa >= shape.min_fa
        {
            out.0.push(g);
            out.1.push(p.map(|c| c as u32));
        }
    }
    Ok(out)
}

/// The splats of `selection` with FA at least `shape.min_fa`, uncoloured (apply a `SplatColouring`).
pub fn field_splats(field: &TensorField, selection: &Selection, shape: &SplatShape) -> Result<Vec<Splat>, String> {
    let voxels = selection.voxels(field.tensors.dims3())?;
    let scale = shape.size * selection.cell_mm(field.tensors.voxel_size());
    Ok(field
        .world_tensors(&voxels)
        .into_iter()
        .filter_map(|(c, t)| tensor_splat(c, &t, scale, DVec3::ONE, 1.0))
        .filter(|s| s.fa() >= shape.min_fa)
        .collect())
}

/// What a layer's drawn set was built from and styled with.
#[derive(Component, Clone, Debug, PartialEq)]
struct Built<S> {
    field: AssetId<TensorField>,
    settings: S,
}

type GlyphLayer<'a> = (
    Entity,
    Ref<'a, TensorGlyphs>,
    Ref<'a, Selection>,
    Ref<'a, TensorGlyphShape>,
    Ref<'a, TensorGlyphSettings>,
    &'a mut LayerStatus,
    Option<&'a TensorGlyphSet>,
    Option<&'a Built<TensorGlyphSettings>>,
);

fn sync_glyph_layers(
    mut commands: Commands,
    mut layers: Query<GlyphLayer>,
    fields: Res<Assets<TensorField>>,
    mut events: MessageReader<AssetEvent<TensorField>>,
    server: Res<AssetServer>,
    mut stores: TensorGlyphStores,
    mut counts: ResMut<TensorGlyphCounts>,
) {
    let modified: HashSet<_> = changed_assets(&mut events);
    for (entity, layer, selection, shape, settings, mut status, set, built) in &mut layers {
        let id = layer.field.id();
        let Some(field) = loaded_or_pending(&fields, &server, &layer.field, &mut status) else { continue };
        let new_data = built.is_none_or(|b| b.field != id) || modified.contains(&id);
        let new_shape = built.is_some_and(|b| b.settings.shape != settings.shape);
        if new_data || new_shape || selection.is_changed() || shape.is_changed() {
            match field_tensor_glyphs(field, &selection, &shape) {
                Ok((glyphs, voxels)) => {
                    let placed = (&glyphs[..], Some(&voxels[..]));
                    let filled = stores.refill(&mut commands, entity, set, placed, &settings);
                    commands.entity(entity).insert((filled, Built { field: id, settings: *settings }));
                    *status = LayerStatus::Ready { items: glyphs.len() };
                }
                Err(e) => {
                    stores.clear(&mut commands, entity, set);
                    commands.entity(entity).remove::<(TensorGlyphSet, Built<TensorGlyphSettings>)>();
                    *status = LayerStatus::Failed(e);
                }
            }
            let c = &mut counts.0;
            if new_data { c.uploads += 1 } else { c.repacks += 1 }
        } else if settings.is_changed()
            && let Some(set) = set
            && let Some(mut m) = stores.materials.get_mut(&set.material)
        {
            m.params = (&*settings).into();
            commands.entity(entity).insert(Built { field: id, settings: *settings });
            counts.0.uniform_writes += 1;
        }
    }
}

/// The splat set drawn for a splat layer (its child).
#[derive(Component, Clone, Copy, Debug)]
struct DrawnSplats(Entity);

type SplatLayer<'a> = (
    Entity,
    Ref<'a, TensorSplats>,
    Ref<'a, Selection>,
    Ref<'a, SplatShape>,
    Ref<'a, SplatSettings>,
    &'a mut LayerStatus,
    Option<&'a DrawnSplats>,
    Option<&'a Built<SplatSettings>>,
);

#[allow(clippy::too_many_arguments)]
fn sync_splat_layers(
    mut commands: Commands,
    mut layers: Query<SplatLayer>,
    mut sets: Query<&mut SplatSet>,
    fields: Res<Assets<TensorField>>,
    mut events: MessageReader<AssetEvent<TensorField>>,
    server: Res<AssetServer>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<SplatMaterial>>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
    mut counts: ResMut<SplatCounts>,
) {
    let modified: HashSet<_> = changed_assets(&mut events);
    for (entity, layer, selection, shape, settings, mut status, drawn, built) in &mut layers {
        let id = layer.field.id();
        let Some(field) = loaded_or_pending(&fields, &server, &layer.field, &mut status) else { continue };
        let new_data = built.is_none_or(|b| b.field != id) || modified.contains(&id);
        if new_data || selection.is_changed() || shape.is_changed() {
            if let Some(d) = drawn {
                if let Ok(old) = sets.get(d.0) {
                    materials.remove(&old.material);
                }
                commands.entity(d.0).despawn();
            }
            match field_splats(field, &selection, &shape) {
                Ok(mut splats) => {
                    settings.colouring.apply(&mut splats);
                    let set =
                        spawn_splats(&mut commands, &mut meshes, &mut materials, &mut buffers, &splats, &settings);
                    commands.entity(set).insert(ChildOf(entity));
                    commands.entity(entity).insert((DrawnSplats(set), Built { field: id, settings: *settings }));
                    *status = LayerStatus::Ready { items: splats.len() };
                }
                Err(e) => {
                    commands.entity(entity).remove::<(DrawnSplats, Built<SplatSettings>)>();
                    *status = LayerStatus::Failed(e);
                }
            }
            let c = &mut counts.0;
            if new_data { c.uploads += 1 } else { c.repacks += 1 }
        } else if settings.is_changed()
            && let (Some(d), Some(before)) = (drawn, built)
            && before.settings != *settings
            && let Ok(mut set) = sets.get_mut(d.0)
        {
            restyle_splats(&mut set, (&before.settings, &settings), &mut materials, &mut buffers, &mut counts.0);
            commands.entity(entity).insert(Built { field: id, settings: *settings });
        }
    }
}

/// A splat set's settings edit (`before` to `after`), as it costs: a new colouring rewrites the style buffer,
/// the other knobs the uniform.
pub(crate) fn restyle_splats(
    set: &mut SplatSet,
    (before, after): (&SplatSettings, &SplatSettings),
    materials: &mut Assets<SplatMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    counts: &mut StageCounts,
) {
    if before.colouring != after.colouring {
        set.restyle(&after.colouring, materials, buffers);
        counts.restyles += 1;
    }
    if SplatUniformKnobs::of(before) != SplatUniformKnobs::of(after)
        && let Some(mut m) = materials.get_mut(&set.material)
    {
        m.params = after.into();
        counts.uniform_writes += 1;
    }
}

/// The part of [`SplatSettings`] the uniform holds (the colouring lives in the style buffer).
#[derive(PartialEq)]
struct SplatUniformKnobs(bool, f32, bool, fascicle_core::dti::splat::LitTensor);

impl SplatUniformKnobs {
    fn of(s: &SplatSettings) -> Self {
        Self(s.attenuation, s.opacity, s.lit, s.lighting)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat4;

    /// A 3 x 2 x 2 field whose voxels hold a tensor along voxel x (3, 1, 1) x 1e-3 mm²/s, except voxel
    /// (1, 0, 0), isotropic; the affine turns voxel x into world y (90 degrees about z), 2 mm voxels.
    fn field() -> TensorField {
        let affine = DMat4::from_translation(DVec3::new(10.0, -5.0, 3.0))
            * DMat4::from_rotation_z(std::f64::consts::FRAC_PI_2)
            * DMat4::from_scale(DVec3::splat(2.0));
        let n = 12;
        let mut data = vec![0f32; 6 * n];
        for i in 0..n {
            let [xx, yy, zz] = if i == 1 { [1e-3, 1e-3, 1e-3] } else { [3e-3, 1e-3, 1e-3] };
            data[i] = xx; // Dxx
            data[2 * n + i] = yy; // Dyy
            data[5 * n + i] = zz; // Dzz
        }
        TensorField::new(Volume { shape: vec![3, 2, 2, 6], data, world_from_voxel: affine }).unwrap()
    }

    #[test]
    fn tensors_turn_with_the_affine_and_glyphs_fill_their_cell() {
        let f = field();
        let w = f.world_tensors(&[[2, 1, 0]]);
        // Voxel (2, 1, 0) -> 2 * (-1, 2, 0) + (10, -5, 3); Dxx along voxel x is Dyy in the world.
        assert!((w[0].0 - DVec3::new(8.0, -1.0, 3.0)).length() < 1e-12, "{:?}", w[0].0);
        let want = [1e-3, 0.0, 3e-3, 0.0, 0.0, 1e-3];
        assert!(w[0].1.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-9), "{:?}", w[0].1);

        let slice = Selection::Slice { axis: SliceAxis::Z, index: Some(0), spacing: 1 };
        let (glyphs, voxels) = field_tensor_glyphs(&f, &slice, &TensorGlyphShape::default()).unwrap();
        assert_eq!(glyphs.len(), 6);
        assert_eq!(voxels[1], [1, 0, 0]);
        // Largest radius: 0.9 of the 2 mm cell, halved; the axis along world y.
        let g = &glyphs[0];
        assert!((g.radii[0] - 0.9).abs() < 1e-9 && (g.radii[1] - 0.3).abs() < 1e-6, "{:?}", g.radii); // f32 tensors
        assert!(g.axes[0].y.abs() > 1.0 - 1e-9);
        // The isotropic voxel has FA 0: a minimum FA drops it alone.
        let some = TensorGlyphShape { min_fa: 0.1, ..TensorGlyphShape::default() };
        let (kept, kv) = field_tensor_glyphs(&f, &slice, &some).unwrap();
        assert_eq!(kept.len(), 5);
        assert!(!kv.contains(&[1, 0, 0]));

        // Splats of a one-slice slab: the largest standard deviation is 0.5 of the cell (1 mm).
        let slab = Selection::Slab { axis: SliceAxis::Z, index: Some(1), thickness: 1 };
        let splats = field_splats(&f, &slab, &SplatShape::default()).unwrap();
        assert_eq!(splats.len(), 6);
        assert!((splats[0].cov.y_axis.y - 1.0).abs() < 1e-9, "{:?}", splats[0].cov);
        assert!(
            field_splats(
                &f,
                &Selection::Slab { axis: SliceAxis::Z, index: Some(2), thickness: 1 },
                &SplatShape::default()
            )
            .is_err()
        );
    }

    #[test]
    fn images_that_are_not_tensors_are_refused_by_name() {
        let v = Volume { shape: vec![2, 2, 2, 28], data: vec![0.0; 8 * 28], world_from_voxel: DMat4::IDENTITY };
        let e = TensorField::new(v).unwrap_err();
        assert!(e.contains("[2, 2, 2, 28]") && e.contains("not a tensor image"), "{e}");
        let e = read_field(b"not a nifti".to_vec(), Path::new("x.nii"), &TensorFieldSettings::default()).unwrap_err();
        assert!(e.contains("x.nii"), "{e}");
    }
}
