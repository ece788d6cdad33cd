//! Tract sets prepared already: an app that reads, colours and builds a tract set's geometry itself (off the
//! main thread, part by part for a whole-brain file) hands the [`PreparedTracts`] over in [`PlacedTracts`];
//! the plugin uploads it onto that entity, which becomes the tract set ([`crate::TractSet`], [`TubeSet`] or
//! [`MeshSet`]): ROIs that are its siblings or children select on it. Its [`PlacedTractStyle`] is applied as
//! it costs: the tubelets' per-pixel knobs and the meshes' opacity are one uniform write each.

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_render::layer::LayerStatus;

use crate::{
    MeshSet, PreparedGeometry, PreparedTracts, TractMeshMaterial, TractSystems, TubeSet, TubeSettings, TubeletMaterial,
    insert_prepared,
};

/// The data component of a prepared tract set: the geometry to upload, taken by the plugin (the component
/// stays, empty) when it makes the entity a tract set.
#[derive(Component, Default)]
#[require(PlacedTractStyle, LayerStatus, Transform, Visibility)]
pub struct PlacedTracts(pub Option<PreparedTracts>);

/// How a prepared tract set is drawn beyond its geometry. Defaults: the default tubelet knobs, opaque.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct PlacedTractStyle {
    /// The tubelets' per-pixel knobs (method, iterations, tolerance, shading); their `scale` and `colour` are
    /// the geometry's, made with it.
    pub tubes: TubeSettings,
    /// Alpha of line and polygon-tube meshes, 0..1 (clamped); below 1 they are blended. Default 1.
    pub opacity: f32,
}

impl Default for PlacedTractStyle {
    fn default() -> Self {
        Self { tubes: TubeSettings::default(), opacity: 1.0 }
    }
}

/// Registers the upload and restyle of prepared sets (in [`TractSystems::Prepare`]).
pub(crate) fn build(app: &mut App) {
    app.add_systems(PostUpdate, sync_placed.in_set(TractSystems::Prepare));
}

type Placed<'a> = (
    Entity,
    &'a mut PlacedTracts,
    Ref<'a, PlacedTractStyle>,
    &'a mut LayerStatus,
    Option<&'a mut TubeSet>,
    Option<&'a MeshSet>,
);

/// Uploads the geometry of new prepared sets and applies style edits to the others.
#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters are its data dependencies")]
fn sync_placed(
    mut commands: Commands,
    mut sets: Query<Placed>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut tube_materials: ResMut<Assets<TubeletMaterial>>,
    mut mesh_materials: ResMut<Assets<TractMeshMaterial>>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
) {
    for (entity, mut placed, style, mut status, tubes, mesh) in &mut sets {
        // Taken once, through a mutable borrow only when there is something to take.
        if placed.0.is_some()
            && let Some(mut prepared) = placed.0.take()
        {
            // The tubelets were made with the geometry's scale and colour; the per-pixel knobs are the style's.
            if let PreparedGeometry::Tubes { settings, .. } = &mut prepared.geometry {
                *settings = TubeSettings { scale: settings.scale, colour: settings.colour, ..style.tubes };
            }
            let items = prepared.n_streamlines;
            let stores = (&mut *tube_materials, &mut *mesh_materials);
            insert_prepared(&mut commands.entity(entity), &mut meshes, stores, &mut buffers, prepared, style.opacity);
            *status = LayerStatus::Ready { items };
            continue;
        }
        if !style.is_changed() {
            continue;
        }
        if let Some(mut tubes) = tubes {
            let knobs = TubeSettings { scale: tubes.settings.scale, colour: tubes.settings.colour, ..style.tubes };
            if tubes.settings != knobs
                && let Some(mut m) = tube_materials.get_mut(&tubes.material)
            {
                m.params = (&knobs).into();
                tubes.settings = knobs;
            }
        }
        if let Some(mesh) = mesh
            && let Some(mut m) = mesh_materials.get_mut(&mesh.material)
        {
            let opacity = style.opacity.clamp(0.0, 1.0);
            if m.params.opacity != opacity {
                m.params.opacity = opacity;
            }
        }
    }
}
