//! Layers whose glyphs or splats are placed already: an app that selects and shapes them itself (off the main
//! thread, from a cache, or from tensors that lie on no grid) hands them over as the data component
//! ([`PlacedTensorGlyphs`], [`PlacedSplats`]) with the same settings components as the field-driven layers. The
//! plugin uploads a new placement and applies each settings edit as it does for [`crate::TensorGlyphs`] and
//! [`crate::TensorSplats`]:
//!
//! | change | cost |
//! |---|---|
//! | the placement (the component replaced) | the set rebuilt and uploaded |
//! | glyphs' shape family (ellipsoid <-> superquadric: other bounds) | the instances repacked |
//! | glyphs' gamma, knobs, colour; splats' attenuation, opacity, lighting | one uniform write |
//! | splats' colouring | the style buffer rewritten |

use std::sync::Arc;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::dti::glyph::{TensorGlyph, TensorShape};
use fascicle_core::dti::splat::Splat;
use fascicle_render::layer::{LayerStatus, despawn_drawn};

use crate::layer::{SplatCounts, TensorGlyphCounts, restyle_splats};
use crate::splat::{SplatMaterial, SplatSet, SplatSettings, spawn_splats};
use crate::{TensorGlyphMaterial, TensorGlyphProxies, TensorGlyphSet, TensorGlyphSettings, TensorGlyphStores};

/// The data component of a tensor glyph layer whose glyphs are placed: drawn as they are, with the layer's
/// [`TensorGlyphSettings`] (added with its default when absent).
#[derive(Component, Clone, Debug, Default)]
#[require(TensorGlyphSettings, LayerStatus, Transform, Visibility)]
pub struct PlacedTensorGlyphs {
    /// The glyphs (centres in RAS+ mm, world-frame tensors).
    pub glyphs: Arc<Vec<TensorGlyph>>,
    /// The voxel each glyph stands for (picking reports it), when they come from a grid.
    pub voxels: Option<Arc<Vec<[u32; 3]>>>,
}

/// The data component of a splat layer whose splats are placed: coloured, sorted and composited with the
/// layer's [`SplatSettings`] (added with its default when absent).
#[derive(Component, Clone, Debug, Default)]
#[require(SplatSettings, LayerStatus, Transform, Visibility)]
pub struct PlacedSplats {
    /// The splats (centres in RAS+ mm, world covariances); their colour and opacity come from the settings'
    /// colouring.
    pub splats: Arc<Vec<Splat>>,
}

/// Registers the placed layers' systems (in [`crate::TensorSystems::Prepare`]) and their cleanup.
pub(crate) fn build(app: &mut App) {
    app.add_observer(forget_placed_glyphs)
        .add_observer(forget_placed_splats)
        .add_systems(PostUpdate, (sync_placed_glyphs, sync_placed_splats).in_set(crate::TensorSystems::Prepare));
}

/// The settings a placed layer's set was built or last styled with.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
struct Styled<S>(S);

/// The splat set drawn for a placed splat layer (its child).
#[derive(Component, Clone, Copy, Debug)]
struct DrawnPlaced(Entity);

type PlacedGlyphLayer<'a> = (
    Entity,
    Ref<'a, PlacedTensorGlyphs>,
    Ref<'a, TensorGlyphSettings>,
    &'a mut LayerStatus,
    Option<&'a TensorGlyphSet>,
    Option<&'a Styled<TensorGlyphSettings>>,
);

/// Uploads new placements of glyph layers and applies their settings edits.
fn sync_placed_glyphs(
    mut commands: Commands,
    mut layers: Query<PlacedGlyphLayer>,
    mut stores: TensorGlyphStores,
    mut counts: ResMut<TensorGlyphCounts>,
) {
    for (entity, placed, settings, mut status, set, styled) in &mut layers {
        let family = |s: &TensorGlyphSettings| matches!(s.shape, TensorShape::Ellipsoid);
        let new_shape = styled.is_some_and(|b| family(&b.0) != family(&settings));
        if placed.is_changed() || new_shape || set.is_none() {
            let glyphs = (&placed.glyphs[..], placed.voxels.as_deref().map(|v| &v[..]));
            let filled = stores.refill(&mut commands, entity, set, glyphs, &settings);
            commands.entity(entity).insert((filled, Styled(*settings)));
            *status = LayerStatus::Ready { items: placed.glyphs.len() };
            let c = &mut counts.0;
            if placed.is_changed() { c.uploads += 1 } else { c.repacks += 1 }
        } else if settings.is_changed()
            && styled.is_none_or(|b| b.0 != *settings)
            && let Some(set) = set
            && let Some(mut m) = stores.materials.get_mut(&set.material)
        {
            m.params = (&*settings).into();
            commands.entity(entity).insert(Styled(*settings));
            counts.0.uniform_writes += 1;
        }
    }
}

type PlacedSplatLayer<'a> = (
    Entity,
    Ref<'a, PlacedSplats>,
    Ref<'a, SplatSettings>,
    &'a mut LayerStatus,
    Option<&'a DrawnPlaced>,
    Option<&'a Styled<SplatSettings>>,
);

/// Uploads new placements of splat layers and applies their settings edits.
#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters are its data dependencies")]
fn sync_placed_splats(
    mut commands: Commands,
    mut layers: Query<PlacedSplatLayer>,
    mut sets: Query<&mut SplatSet>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<SplatMaterial>>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
    mut counts: ResMut<SplatCounts>,
) {
    for (entity, placed, settings, mut status, drawn, styled) in &mut layers {
        let live = drawn.and_then(|d| sets.get(d.0).ok()).is_some();
        if placed.is_changed() || !live {
            if let Some(d) = drawn {
                if let Ok(old) = sets.get(d.0) {
                    materials.remove(&old.material);
                }
                commands.entity(d.0).try_despawn();
            }
            let mut splats = placed.splats.to_vec();
            settings.colouring.apply(&mut splats);
            let set = spawn_splats(&mut commands, &mut meshes, &mut materials, &mut buffers, &splats, &settings);
            commands.entity(set).insert(ChildOf(entity));
            commands.entity(entity).insert((DrawnPlaced(set), Styled(*settings)));
            *status = LayerStatus::Ready { items: splats.len() };
            counts.0.uploads += 1;
        } else if settings.is_changed()
            && let (Some(d), Some(before)) = (drawn, styled)
            && before.0 != *settings
            && let Ok(mut set) = sets.get_mut(d.0)
        {
            restyle_splats(&mut set, (&before.0, &settings), &mut materials, &mut buffers, &mut counts.0);
            commands.entity(entity).insert(Styled(*settings));
        }
    }
}

/// A layer that stops being a placed glyph layer loses its set and its glyph entities (its children).
fn forget_placed_glyphs(
    removed: On<Remove, PlacedTensorGlyphs>,
    mut commands: Commands,
    mut materials: ResMut<Assets<TensorGlyphMaterial>>,
    sets: Query<&TensorGlyphSet>,
    children: Query<&Children>,
    drawn: Query<(), With<TensorGlyphProxies>>,
) {
    let e = removed.entity;
    if let Ok(set) = sets.get(e) {
        materials.remove(&set.material);
    }
    despawn_drawn(&mut commands, children.get(e).ok(), |c| drawn.contains(c));
    commands.entity(e).try_remove::<(TensorGlyphSet, Styled<TensorGlyphSettings>)>();
}

/// A layer that stops being a placed splat layer loses its splat set.
fn forget_placed_splats(removed: On<Remove, PlacedSplats>, mut commands: Commands, drawn: Query<&DrawnPlaced>) {
    let e = removed.entity;
    if let Ok(d) = drawn.get(e) {
        commands.entity(d.0).try_despawn();
    }
    commands.entity(e).try_remove::<(DrawnPlaced, Styled<SplatSettings>)>();
}
