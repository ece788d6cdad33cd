//! Volume layers driven by components: spawn an entity with [`VolumeLayer`] (the data: a [`ScalarVolume`]
//! asset, loaded from a `.nii`/`.nii.gz` image off the main thread) and, optionally, [`VolumeSettings`]; the
//! plugin uploads the 3D texture once and reacts to each edit for that layer only:
//!
//! | change | cost |
//! |---|---|
//! | the data (handle swapped, asset modified) | texture rebuilt and uploaded |
//! | `VolumeSettings::method`, slicing's step, cell projection's cell, shear-warp's intermediate size | the proxy mesh or shear-warp's intermediate image swapped; the volume's texture stays |
//! | the transfer function (window/level is its `range`) | its two small tables and the uniform rewritten |
//! | step, termination, jitter, shading, clip, kernel | one uniform write |
//!
//! The drawn [`VolumeSet`] is a child of the layer entity and carries the layer's `RenderLayers`, so only
//! cameras that see it lose their MSAA (see the crate doc).

use std::collections::HashSet;
use std::sync::Arc;

use bevy::asset::io::Reader;
use bevy::asset::{AssetLoader, LoadContext};
use bevy::camera::visibility::RenderLayers;
use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::Volume;
use fascicle_render::layer::{LayerStatus, LoadError, StageCounts, changed_assets, loaded_or_pending, read_all};

use crate::{
    HISTOGRAM_BINS, OpaqueDepth, VolumeMaterial, VolumeMethod, VolumeSet, VolumeSettings, histogram, proxy_mesh,
    spawn_volume,
};

/// A 3D scalar image (T1, FA, MD, a b0) with its voxel-to-world affine (RAS+ mm).
#[derive(Asset, TypePath, Clone, Debug, Deref)]
pub struct ScalarVolume(pub Arc<Volume<f32>>);

/// Settings of the image loader: which 3D volume of a 4D image to take (0: the first, e.g. a
/// DWI's b0).
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct ScalarVolumeSettings {
    /// Which 3D volume of a 4D image to load (index along its fourth axis). Defaults to 0.
    pub volume: usize,
}

/// Loads `.nii` / `.nii.gz` and MRtrix `.mif` / `.mif.gz` images as [`ScalarVolume`]s, off the main thread.
#[derive(Default, TypePath)]
pub struct ScalarVolumeLoader;

impl AssetLoader for ScalarVolumeLoader {
    type Asset = ScalarVolume;
    type Settings = ScalarVolumeSettings;
    type Error = LoadError;

    async fn load(
        &self,
        reader: &mut dyn Reader,
        settings: &ScalarVolumeSettings,
        ctx: &mut LoadContext<'_>,
    ) -> Result<ScalarVolume, LoadError> {
        let path = ctx.path().path().to_path_buf();
        let bytes = read_all(reader, &path).await?;
        let vol =
            fascicle_core::io::mif::read_image_bytes::<f32>(bytes, &path).map_err(|e| LoadError(e.to_string()))?;
        let vol = volume_of(vol, settings.volume).map_err(|e| LoadError(format!("{}: {e}", path.display())))?;
        Ok(ScalarVolume(Arc::new(vol)))
    }

    fn extensions(&self) -> &[&str] {
        &["nii", "nii.gz", "mif", "mif.gz"]
    }
}

/// The `k`-th 3D volume of an image (a 3D image is its own volume 0).
pub fn volume_of(vol: Volume<f32>, k: usize) -> Result<Volume<f32>, String> {
    let (n, count) = (vol.n_voxels(), vol.n_channels().max(1));
    if k >= count {
        return Err(format!("volume {k} requested of an image with {count} ({:?})", vol.shape));
    }
    if count == 1 {
        return Ok(Volume { shape: vol.dims3().to_vec(), ..vol });
    }
    Ok(Volume {
        shape: vol.dims3().to_vec(),
        data: vol.data[k * n..(k + 1) * n].to_vec(),
        world_from_voxel: vol.world_from_voxel,
    })
}

/// The data component of a volume layer. Without [`VolumeSettings`] it gets the defaults: ray casting with
/// a transfer function for FA as context.
#[derive(Component, Clone, Debug, Default)]
#[require(VolumeSettings, LayerStatus, Transform, Visibility)]
pub struct VolumeLayer {
    /// The scalar volume drawn, usually `AssetServer::load("fa.nii.gz")`. Swapping it, or the asset being
    /// modified, rebuilds and re-uploads the 3D texture.
    pub volume: Handle<ScalarVolume>,
}

/// The work of the volume layers' stages (see [`StageCounts`]; a method change counts as a repack).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq, Deref)]
pub struct VolumeCounts(pub StageCounts);

/// The plugin's systems (`PostUpdate`, after the asset events, before transform propagation).
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum VolumeSystems {
    /// Builds and restyles the [`VolumeLayer`]s that changed.
    Prepare,
}

/// Registers the [`ScalarVolume`] asset and its loader, once: for the plugins that read scalar images (this
/// one, and the views plugin's slice layers) in whichever order an app adds them.
pub fn init_scalar_volumes(app: &mut App) {
    if !app.world().contains_resource::<Assets<ScalarVolume>>() {
        app.init_asset::<ScalarVolume>().register_asset_loader(ScalarVolumeLoader);
    }
}

pub(crate) fn build(app: &mut App) {
    init_scalar_volumes(app);
    app.init_resource::<VolumeCounts>()
        .configure_sets(
            PostUpdate,
            VolumeSystems::Prepare
                .after(bevy::asset::AssetEventSystems)
                .before(bevy::transform::TransformSystems::Propagate),
        )
        .add_observer(forget_layer)
        .add_systems(PostUpdate, sync_layers.in_set(VolumeSystems::Prepare));
}

/// A volume layer that stops being one (its [`VolumeLayer`] removed) loses its drawn set.
fn forget_layer(removed: On<Remove, VolumeLayer>, mut commands: Commands, drawn: Query<&Drawn>) {
    if let Ok(d) = drawn.get(removed.entity) {
        commands.entity(d.set).try_despawn();
        commands.entity(removed.entity).try_remove::<Drawn>();
    }
}

/// The drawn set of a layer and the asset it was built from.
#[derive(Component, Clone, Copy, Debug)]
struct Drawn {
    set: Entity,
    volume: AssetId<ScalarVolume>,
}

type Layer<'a> = (
    Entity,
    Ref<'a, VolumeLayer>,
    Ref<'a, VolumeSettings>,
    &'a mut LayerStatus,
    Option<&'a Drawn>,
    Option<&'a RenderLayers>,
);

#[allow(clippy::too_many_arguments)]
fn sync_layers(
    mut commands: Commands,
    mut layers: Query<Layer>,
    mut sets: Query<(&mut VolumeSet, &mut Mesh3d)>,
    volumes: Res<Assets<ScalarVolume>>,
    mut events: MessageReader<AssetEvent<ScalarVolume>>,
    server: Res<AssetServer>,
    depth: Option<Res<OpaqueDepth>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut images: ResMut<Assets<Image>>,
    mut materials: ResMut<Assets<VolumeMaterial>>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
    mut counts: ResMut<VolumeCounts>,
) {
    let Some(depth) = depth else { return };
    let modified: HashSet<_> = changed_assets(&mut events);
    for (entity, layer, settings, mut status, drawn, render_layers) in &mut layers {
        let id = layer.volume.id();
        let Some(vol) = loaded_or_pending(&volumes, &server, &layer.volume, &mut status) else { continue };
        if drawn.is_none_or(|d| d.volume != id) || modified.contains(&id) {
            if let Some(d) = drawn {
                if let Ok((old, _)) = sets.get(d.set) {
                    materials.remove(&old.material);
                }
                commands.entity(d.set).try_despawn();
            }
            let set = spawn_volume(
                &mut commands,
                &mut meshes,
                &mut images,
                &mut materials,
                &mut buffers,
                &depth,
                &vol.0,
                &settings,
            );
            commands.entity(set).insert(ChildOf(entity));
            if let Some(r) = render_layers {
                commands.entity(set).insert(r.clone());
            }
            commands.entity(entity).insert(Drawn { set, volume: id });
            *status = LayerStatus::Ready { items: vol.n_voxels() };
            counts.0.uploads += 1;
            continue;
        }
        if !settings.is_changed() {
            continue;
        }
        let Some(Ok((mut set, mut mesh))) = drawn.map(|d| sets.get_mut(d.set)) else { continue };
        if set.settings == *settings {
            continue;
        }
        let before = std::mem::replace(&mut set.settings, (*settings).clone());
        if before.method != settings.method
            || (settings.method == VolumeMethod::Slicing && before.step != settings.step)
            || (settings.method == VolumeMethod::Tetrahedra && before.cell != settings.cell)
        {
            // The number of slices follows the step, the number of tetrahedra the cell size.
            mesh.0 = meshes.add(proxy_mesh(set.dims, set.world_from_voxel, &settings));
            counts.0.repacks += 1;
        }
        if set.fit_intermediate(&settings, &mut materials, &mut images) {
            counts.0.repacks += 1;
        }
        let tables = before.tf != settings.tf || before.step != settings.step;
        if set.write_style(&settings, tables, &mut materials, &mut buffers) {
            counts.0.uniform_writes += 1;
        }
        if before.tf.range != settings.tf.range {
            set.histogram = Arc::new(histogram(&vol.data[..vol.n_voxels()], settings.tf.range, HISTOGRAM_BINS));
        }
    }
}
