//! SH glyph layers driven by components: spawn an entity with [`ShGlyphs`] (the data: an [`ShField`] asset)
//! and, optionally, its settings components ([`Selection`], [`GlyphShape`], [`RayCastSettings`]); the
//! plugin builds and updates everything on the GPU.
//!
//! Each stage reacts to its own component, for that layer only:
//! - the data (`ShGlyphs::field` swapped, or its asset modified): the glyphs are rebuilt and uploaded;
//! - the selection or the shape: the instances are repacked from the field already in memory;
//! - the [`RayCastSettings`] (quality, colouring, size): one uniform write, nothing else.
//!
//! [`ShGlyphCounts`] counts each stage's work; [`LayerStatus`] on the entity tells loading, ready (with the
//! glyph count) or the error (a file that is not an SH image, a slice outside the grid).

use std::collections::HashSet;
use std::path::Path;
use std::sync::Arc;

use bevy::asset::io::Reader;
use bevy::asset::{AssetLoader, LoadContext};
use bevy::prelude::*;
use fascicle_core::Volume;
use fascicle_core::sh::glyph::{Glyph, GlyphStyle, make_glyphs};
use fascicle_core::sh::{self, ShBasis};
use fascicle_render::layer::{LayerStatus, Selection, StageCounts, changed_assets, loaded_or_pending};

use crate::{GlyphStores, RayCastSettings, ShGlyphSet, update_settings};

/// An SH coefficient field: `X x Y x Z x n` coefficients (`n` = 1, 6, 15, 28, 45, ...), their basis and the
/// voxel-to-world affine (RAS+ mm).
#[derive(Asset, TypePath, Clone, Debug)]
pub struct ShField {
    /// The coefficients, `X x Y x Z x n` (`data[x + X*(y + Y*(z + Z*j))]` for coefficient `j`), with the
    /// image's `world_from_voxel` (voxel indices to RAS+ mm).
    pub coeffs: Arc<Volume<f32>>,
    /// The SH basis of `coeffs`. DIPY's bases follow the voxel axes; [`field_glyphs`] turns them into world
    /// axes through the affine.
    pub basis: ShBasis,
}

impl ShField {
    /// Checks that `coeffs` is a 4D image with an even-order SH coefficient count.
    pub fn new(coeffs: Volume<f32>, basis: ShBasis) -> Result<Self, String> {
        if coeffs.shape.len() < 4 || sh::l_max_for(coeffs.n_channels()).is_none() {
            return Err(format!(
                "{:?} is not an SH coefficient image (X,Y,Z,n with n = 1, 6, 15, 28, 45, ...)",
                coeffs.shape
            ));
        }
        Ok(Self { coeffs: Arc::new(coeffs), basis })
    }

    /// The maximum (even) SH order the coefficient count implies (45 coefficients: 8).
    pub fn l_max(&self) -> usize {
        sh::l_max_for(self.coeffs.n_channels()).unwrap_or(0)
    }
}

/// The data component of an SH glyph layer. Its settings components are added with their defaults when
/// absent: a middle axial slice, glyphs sized to fill 90 % of their cell, default ray casting.
#[derive(Component, Clone, Debug, Default)]
#[require(Selection, GlyphShape, RayCastSettings, LayerStatus, Transform, Visibility)]
pub struct ShGlyphs {
    /// The SH field drawn, usually `AssetServer::load("csa.nii.gz")`. Swapping it, or the asset being
    /// modified, rebuilds and re-uploads the layer's glyphs.
    pub field: Handle<ShField>,
}

/// How coefficients become glyph shapes on the CPU (sharpening, normalisation, size in mm). Changing it
/// repacks the layer's instances; for a size change that re-sends nothing use [`RayCastSettings::size`].
#[derive(Component, Clone, Copy, Debug, PartialEq, Deref, DerefMut, serde::Serialize, serde::Deserialize)]
pub struct GlyphShape(pub GlyphStyle);

impl Default for GlyphShape {
    fn default() -> Self {
        Self(GlyphStyle { fit_lobes: true, cell_fill: Some(0.9), ..GlyphStyle::default() })
    }
}

/// The work this plugin's stages did (see [`StageCounts`]).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq, Deref)]
pub struct ShGlyphCounts(pub StageCounts);

/// The plugin's systems, all in `PostUpdate`, after the asset events and before transform propagation, so
/// edits made in `Update` (or ordered before [`ShGlyphSystems::Prepare`]) show in the same frame.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ShGlyphSystems {
    /// Builds, repacks and restyles the [`ShGlyphs`] layers that changed.
    Prepare,
    /// Rewrites the header buffer of sets whose [`Highlighted`](crate::Highlighted) changed.
    Highlight,
}

/// Settings of the SH image loader: the basis when the file does not record one (a NIfTI written by
/// `fascicle fit csa` records it in its header description; a `.mif` is MRtrix3's).
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct ShFieldSettings {
    /// The basis assumed when the header records none. Defaults to `None`: for a NIfTI DIPY's default,
    /// descoteaux07 legacy (voxel axes); for a `.mif` MRtrix3's, tournier07 (world axes).
    pub basis: Option<ShBasis>,
}

/// Loads `.nii` / `.nii.gz` and MRtrix `.mif` / `.mif.gz` SH coefficient images as [`ShField`]s, off the
/// main thread.
#[derive(Default, TypePath)]
pub struct ShFieldLoader;

impl AssetLoader for ShFieldLoader {
    type Asset = ShField;
    type Settings = ShFieldSettings;
    type Error = fascicle_render::layer::LoadError;

    async fn load(
        &self,
        reader: &mut dyn Reader,
        settings: &ShFieldSettings,
        ctx: &mut LoadContext<'_>,
    ) -> Result<ShField, Self::Error> {
        let path = ctx.path().path().to_path_buf();
        let bytes = fascicle_render::layer::read_all(reader, &path).await?;
        read_field(bytes, &path, settings).map_err(fascicle_render::layer::LoadError)
    }

    fn extensions(&self) -> &[&str] {
        &["nii", "nii.gz", "mif", "mif.gz"]
    }
}

/// An [`ShField`] from a file's bytes (`path` names it: `.mif`/`.mif.gz` as MRtrix3's, else NIfTI). The basis:
/// for a NIfTI the one its header records, else `settings.basis`, else DIPY's default (descoteaux07 legacy);
/// for a `.mif` `settings.basis`, else MRtrix3's (tournier07).
pub fn read_field(bytes: Vec<u8>, path: &Path, settings: &ShFieldSettings) -> Result<ShField, String> {
    use fascicle_core::io::{mif, nifti};
    let (vol, basis) = if mif::is_mif(path) {
        // MRtrix3 writes its own basis, in world axes.
        let (vol, _) = mif::read_bytes::<f32>(bytes, path).map_err(|e| e.to_string())?;
        (vol, settings.basis.unwrap_or(ShBasis::Tournier07 { legacy: false }))
    } else {
        let (vol, header) = nifti::read_bytes::<f32>(bytes, path).map_err(|e| e.to_string())?;
        (vol, sh::recorded_basis(&header.descrip).or(settings.basis).unwrap_or_default())
    };
    ShField::new(vol, basis).map_err(|e| format!("{}: {e}", path.display()))
}

/// The glyphs of `selection` (voxels with signal, `c00 > 0`), shaped by `shape` (sized from the selection's
/// cell when `cell_fill` is set), and their voxels. Coefficients in voxel axes (DIPY's bases) are turned into
/// world axes through the affine first, so that a flipped or oblique image shows its ODFs where they point.
pub fn field_glyphs(
    field: &ShField,
    selection: &Selection,
    shape: GlyphStyle,
) -> Result<(Vec<Glyph>, Vec<[u32; 3]>), String> {
    let vol = &field.coeffs;
    let d = vol.dims3();
    let (n, nc) = (vol.n_voxels(), vol.n_channels());
    // DIPY's coefficients follow the voxel axes: turned into world axes (the affine's rotation or reflection).
    let turn = sh::frame::to_world_axes(field.basis, field.l_max(), vol.world_from_voxel).map_err(|e| e.to_string())?;
    let mut items = Vec::new();
    for [x, y, z] in selection.voxels(d)? {
        let v = x + d[0] * (y + d[1] * z);
        let c: Vec<f64> = (0..nc).map(|j| vol.data[v + n * j] as f64).collect();
        let c = turn.as_deref().map_or(c.clone(), |t| sh::frame::apply(t, &c));
        if c[0] > 0.0 {
            let centre = vol.world_from_voxel.transform_point3(glam::DVec3::new(x as f64, y as f64, z as f64));
            items.push((centre, c, [x as u32, y as u32, z as u32]));
        }
    }
    let style = shape.resolved(selection.cell_mm(vol.voxel_size()));
    let (glyphs, skipped) =
        make_glyphs(items.iter().map(|(c, co, _)| (*c, &co[..])), field.basis, style).map_err(|e| e.to_string())?;
    let skipped: HashSet<usize> = skipped.into_iter().collect();
    let voxels = items.iter().enumerate().filter(|(i, _)| !skipped.contains(i)).map(|(_, it)| it.2).collect();
    Ok((glyphs, voxels))
}

pub(crate) fn build(app: &mut App) {
    app.init_asset::<ShField>()
        .register_asset_loader(ShFieldLoader)
        .init_resource::<ShGlyphCounts>()
        .configure_sets(
            PostUpdate,
            (ShGlyphSystems::Prepare, ShGlyphSystems::Highlight)
                .chain()
                .after(bevy::asset::AssetEventSystems)
                .before(bevy::transform::TransformSystems::Propagate),
        )
        .add_systems(PostUpdate, sync_layers.in_set(ShGlyphSystems::Prepare));
}

/// The field the set on a layer was built from.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
struct BuiltFrom(AssetId<ShField>);

type Layer<'a> = (
    Entity,
    Ref<'a, ShGlyphs>,
    Ref<'a, Selection>,
    Ref<'a, GlyphShape>,
    Ref<'a, RayCastSettings>,
    &'a mut LayerStatus,
    Option<&'a mut ShGlyphSet>,
    Option<&'a BuiltFrom>,
);

fn sync_layers(
    mut commands: Commands,
    mut layers: Query<Layer>,
    fields: Res<Assets<ShField>>,
    mut events: MessageReader<AssetEvent<ShField>>,
    server: Res<AssetServer>,
    mut stores: GlyphStores,
    mut counts: ResMut<ShGlyphCounts>,
) {
    let modified = changed_assets(&mut events);
    for (entity, layer, selection, shape, settings, mut status, mut set, built) in &mut layers {
        let id = layer.field.id();
        let Some(field) = loaded_or_pending(&fields, &server, &layer.field, &mut status) else { continue };
        let new_data = built != Some(&BuiltFrom(id)) || modified.contains(&id);
        if new_data || selection.is_changed() || shape.is_changed() {
            match field_glyphs(field, &selection, shape.0) {
                Ok((glyphs, voxels)) => {
                    let placed = (&glyphs[..], Some(&voxels[..]));
                    let filled = stores.refill(&mut commands, entity, set.as_deref(), placed, &settings);
                    commands.entity(entity).insert((filled, BuiltFrom(id)));
                    *status = LayerStatus::Ready { items: glyphs.len() };
                }
                Err(e) => {
                    stores.clear(&mut commands, entity, set.as_deref());
                    commands.entity(entity).remove::<(ShGlyphSet, BuiltFrom)>();
                    *status = LayerStatus::Failed(e);
                }
            }
            let c = &mut counts.0;
            if new_data { c.uploads += 1 } else { c.repacks += 1 }
        } else if settings.is_changed()
            && let Some(set) = set.as_deref_mut()
        {
            update_settings(&mut stores.materials, set, &settings);
            counts.0.uniform_writes += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{DMat3, DMat4, DVec3};

    /// One voxel holding a sharp single-fibre ODF along `fibre` (voxel axes, DIPY's default basis), on an image
    /// with `affine`: the largest lobe of its glyph, in world axes.
    fn glyph_lobe(fibre: DVec3, affine: DMat4) -> DVec3 {
        let basis = ShBasis::default();
        let l_max = 8;
        let dirs = sh::sphere::fibonacci(600);
        let a = sh::sh_matrix(basis, l_max, &dirs);
        let k = sh::n_coeffs(l_max);
        let pinv = fascicle_core::linalg::pinv(&a, dirs.len(), k);
        let f: Vec<f64> = dirs.iter().map(|u| u.dot(fibre).powi(8) + 0.05).collect();
        let c: Vec<f64> = (0..k).map(|i| (0..dirs.len()).map(|r| pinv[i * dirs.len() + r] * f[r]).sum()).collect();
        let mut vol = Volume::<f32>::zeros(&[1, 1, 1, k], affine);
        for (j, x) in c.iter().enumerate() {
            vol.data[j] = *x as f32;
        }
        let field = ShField::new(vol, basis).unwrap();
        let selection = Selection::Slice { axis: crate::SliceAxis::Z, index: Some(0), spacing: 1 };
        let (glyphs, _) = field_glyphs(&field, &selection, GlyphStyle::default()).unwrap();
        let g = &glyphs[0];
        dirs.into_iter()
            .max_by(|p, q| {
                let v = |u: DVec3| sh::glyph::eval_cartesian(&g.coeffs, g.l_max, u).0;
                v(*p).total_cmp(&v(*q))
            })
            .unwrap()
    }

    /// DIPY's coefficients follow the voxel axes: on an x-flipped, rotated image, a fibre along voxel (1, 1, 0)
    /// shows along the world direction the affine maps it to, not along (1, 1, 0) read as world axes.
    #[test]
    fn voxel_axis_odfs_show_in_world_axes() {
        let fibre = DVec3::new(1.0, 1.0, 0.0).normalize();
        let plain = glyph_lobe(fibre, DMat4::from_scale(DVec3::splat(2.0)));
        assert!(plain.dot(fibre).abs() > 0.99, "{plain}");
        let m = DMat3::from_rotation_z(0.4) * DMat3::from_diagonal(DVec3::new(-2.0, 2.0, 2.0));
        let lobe = glyph_lobe(fibre, DMat4::from_mat3(m));
        let expected = (m * fibre).normalize();
        assert!(lobe.dot(expected).abs() > 0.99, "{lobe} vs {expected}");
        assert!(lobe.dot(fibre).abs() < 0.9, "the lobe stayed in voxel axes: {lobe}");
    }
}
