//! Layers whose glyphs are placed already: an app that samples and shapes them itself (off the main thread, on
//! a free plane, from a cache, ahead of the next slice) hands them over as the data component
//! ([`PlacedShGlyphs`]) with the layer's [`RayCastSettings`]. A new placement is uploaded (the component
//! replaced); a settings edit is one uniform write, as for [`crate::ShGlyphs`].

use std::sync::Arc;

use bevy::prelude::*;
use fascicle_core::sh::glyph::Glyph;
use fascicle_render::layer::{LayerStatus, despawn_drawn};

use crate::layer::ShGlyphCounts;
use crate::{GlyphStores, RayCastSettings, ShGlyphMaterial, ShGlyphProxies, ShGlyphSet, update_settings};

/// The data component of an SH glyph layer whose glyphs are placed: drawn as they are, with the layer's
/// [`RayCastSettings`] (added with its default when absent).
#[derive(Component, Clone, Debug, Default)]
#[require(RayCastSettings, LayerStatus, Transform, Visibility)]
pub struct PlacedShGlyphs {
    /// The glyphs (centres in RAS+ mm, coefficients in the glyph basis scaled to mm).
    pub glyphs: Arc<Vec<Glyph>>,
    /// The voxel each glyph stands for (picking reports it), when they come from a grid.
    pub voxels: Option<Arc<Vec<[u32; 3]>>>,
}

/// Registers the placed layers' system (in [`crate::ShGlyphSystems::Prepare`]) and their cleanup.
pub(crate) fn build(app: &mut App) {
    app.add_observer(forget_placed).add_systems(PostUpdate, sync_placed.in_set(crate::ShGlyphSystems::Prepare));
}

type Layer<'a> =
    (Entity, Ref<'a, PlacedShGlyphs>, Ref<'a, RayCastSettings>, &'a mut LayerStatus, Option<&'a mut ShGlyphSet>);

/// Uploads new placements and applies settings edits.
fn sync_placed(
    mut commands: Commands,
    mut layers: Query<Layer>,
    mut stores: GlyphStores,
    mut counts: ResMut<ShGlyphCounts>,
) {
    for (entity, placed, settings, mut status, mut set) in &mut layers {
        if placed.is_changed() || set.is_none() {
            let glyphs = (&placed.glyphs[..], placed.voxels.as_deref().map(|v| &v[..]));
            let filled = stores.refill(&mut commands, entity, set.as_deref(), glyphs, &settings);
            commands.entity(entity).insert(filled);
            *status = LayerStatus::Ready { items: placed.glyphs.len() };
            counts.0.uploads += 1;
        } else if settings.is_changed()
            && let Some(set) = set.as_deref_mut()
        {
            update_settings(&mut stores.materials, set, &settings);
            counts.0.uniform_writes += 1;
        }
    }
}

/// A layer that stops being a placed glyph layer loses its set and its glyph entities (its children).
fn forget_placed(
    removed: On<Remove, PlacedShGlyphs>,
    mut commands: Commands,
    mut materials: ResMut<Assets<ShGlyphMaterial>>,
    sets: Query<&ShGlyphSet>,
    children: Query<&Children>,
    glyphs: Query<(), With<ShGlyphProxies>>,
) {
    let e = removed.entity;
    if let Ok(set) = sets.get(e) {
        materials.remove(&set.material);
    }
    despawn_drawn(&mut commands, children.get(e).ok(), |c| glyphs.contains(c));
    commands.entity(e).try_remove::<ShGlyphSet>();
}
