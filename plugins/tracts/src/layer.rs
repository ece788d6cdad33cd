//! Tract layers driven by components: spawn an entity with [`Tracts`] (a [`TractogramAsset`], loaded from
//! `.trk` / `.tck` off the main thread) and a [`TractStyle`]; the plugin spawns the drawn set as a child and
//! rebuilds it, for that layer only, when the asset or the style changes. [`LayerStatus`] on the entity says
//! loading, ready (with the streamline count) or why the file could not be read. ROIs spawned as children of
//! the layer (`ChildOf(layer)`) act on that layer and survive its rebuilds; ROIs without a parent act on
//! every set (see [`crate::TractRoi`]).

use std::sync::Arc;

use bevy::asset::io::Reader;
use bevy::asset::{AssetLoader, LoadContext};
use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::io::Tractogram;
use fascicle_render::layer::{LayerStatus, LoadError, StageCounts, changed_assets, loaded_or_pending, read_all};

use crate::{TractMeshMaterial, TubeSettings, TubeletMaterial, spawn_lines, spawn_polygon_tubes, spawn_tubes};

/// Streamlines in RAS+ mm, as read from a `.trk` or `.tck` file.
#[derive(Asset, TypePath, Clone, Debug, Deref)]
pub struct TractogramAsset(pub Arc<Tractogram>);

/// Loads `.trk` and `.tck` files (and their `.gz`) as [`TractogramAsset`]s.
#[derive(Default, TypePath)]
pub struct TractogramLoader;

impl AssetLoader for TractogramLoader {
    type Asset = TractogramAsset;
    type Settings = ();
    type Error = LoadError;

    async fn load(
        &self,
        reader: &mut dyn Reader,
        _: &(),
        ctx: &mut LoadContext<'_>,
    ) -> Result<TractogramAsset, LoadError> {
        let path = ctx.path().path().to_path_buf();
        let bytes = read_all(reader, &path).await?;
        let t = Tractogram::read_bytes(&bytes, &path).map_err(|e| LoadError(e.to_string()))?;
        Ok(TractogramAsset(Arc::new(t)))
    }

    fn extensions(&self) -> &[&str] {
        &["trk", "tck", "trk.gz", "tck.gz", "trx"]
    }
}

/// How a tract layer is drawn.
#[derive(Component, Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum TractStyle {
    /// Hyperstreamlines: ray-cast tubelets (round without per-point tensors).
    Tubelets(TubeSettings),
    /// Line segments coloured by direction.
    Lines {
        /// Alpha of the lines, 0..1 (clamped); below 1 they are blended.
        opacity: f32,
    },
    /// Polygon tubes of `scale` mm radius, 16 sides.
    PolygonTubes {
        /// Cross-section scale, mm, as [`TubeSettings::scale`]; drawn without tensors, so the tubes are round
        /// with radius `scale / 4`.
        scale: f64,
        /// Alpha of the tubes, 0..1 (clamped); below 1 they are blended.
        opacity: f32,
    },
}

impl Default for TractStyle {
    fn default() -> Self {
        TractStyle::Tubelets(TubeSettings { scale: 0.5, ..TubeSettings::default() })
    }
}

/// The data component of a tract layer.
#[derive(Component, Clone, Debug, Default)]
#[require(TractStyle, LayerStatus, Transform, Visibility)]
pub struct Tracts {
    /// The streamlines to draw (a `.trk`, `.tck` or `.trx` file loaded by [`TractogramLoader`]).
    pub tractogram: Handle<TractogramAsset>,
}

/// The work of the tract layers' stages (see [`StageCounts`]; a style change rebuilds the drawn set).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq, Deref)]
pub struct TractCounts(pub StageCounts);

/// The plugin's systems (`PostUpdate`): [`TractSystems::Prepare`] builds the layers that changed, before
/// [`TractSystems::Select`] re-evaluates ROIs.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum TractSystems {
    /// Spawns (or respawns) the drawn set of each layer whose asset or style changed.
    Prepare,
    /// Re-evaluates ROI selections and rewrites the sets' flag buffers ([`crate::apply_rois`]).
    Select,
}

pub(crate) fn build(app: &mut App) {
    app.init_asset::<TractogramAsset>()
        .register_asset_loader(TractogramLoader)
        .init_resource::<TractCounts>()
        .configure_sets(
            PostUpdate,
            (TractSystems::Prepare, TractSystems::Select)
                .chain()
                .after(bevy::asset::AssetEventSystems)
                .before(bevy::transform::TransformSystems::Propagate),
        )
        .add_systems(PostUpdate, sync_layers.in_set(TractSystems::Prepare));
}

/// A layer's drawn set (its child) and the asset it was built from. The layer's other children (its ROIs)
/// survive a rebuild.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
struct Drawn {
    set: Entity,
    tractogram: AssetId<TractogramAsset>,
}

type Layer<'a> = (Entity, Ref<'a, Tracts>, Ref<'a, TractStyle>, &'a mut LayerStatus, Option<&'a Drawn>);

#[allow(clippy::too_many_arguments)]
fn sync_layers(
    mut commands: Commands,
    mut layers: Query<Layer>,
    assets: Res<Assets<TractogramAsset>>,
    mut events: MessageReader<AssetEvent<TractogramAsset>>,
    server: Res<AssetServer>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut tube_materials: ResMut<Assets<TubeletMaterial>>,
    mut mesh_materials: ResMut<Assets<TractMeshMaterial>>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
    mut counts: ResMut<TractCounts>,
) {
    let modified = changed_assets(&mut events);
    for (entity, layer, style, mut status, drawn) in &mut layers {
        let id = layer.tractogram.id();
        let Some(t) = loaded_or_pending(&assets, &server, &layer.tractogram, &mut status) else { continue };
        let new_data = drawn.is_none_or(|d| d.tractogram != id) || modified.contains(&id);
        if !(new_data || style.is_changed()) {
            continue;
        }
        if let Some(d) = drawn {
            commands.entity(d.set).despawn();
        }
        let t = t.0.clone();
        let n = t.n_streamlines();
        let set = match *style {
            TractStyle::Tubelets(s) => {
                spawn_tubes(&mut commands, &mut meshes, &mut tube_materials, &mut buffers, t, None, &s)
            }
            TractStyle::Lines { opacity } => {
                spawn_lines(&mut commands, &mut meshes, &mut mesh_materials, &mut buffers, t, opacity)
            }
            TractStyle::PolygonTubes { scale, opacity } => spawn_polygon_tubes(
                &mut commands,
                &mut meshes,
                &mut mesh_materials,
                &mut buffers,
                t,
                None,
                scale,
                opacity,
            ),
        };
        commands.entity(set).insert(ChildOf(entity));
        commands.entity(entity).insert(Drawn { set, tractogram: id });
        *status = LayerStatus::Ready { items: n };
        if new_data {
            counts.0.uploads += 1;
        } else {
            counts.0.repacks += 1;
        }
    }
}
