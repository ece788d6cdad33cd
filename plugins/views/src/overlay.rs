//! The colour bars drawn over a 3D view: no camera of their own, a pass of the 3D camera. After the camera's
//! picture is complete (the main pass, the frame budget's stretch of a scaled picture, the retained picture put
//! back: [`fascicle_render::OverlaySystems`]), each bar image is blended over its rectangle of the viewport
//! ([`crate::colourbar::bar_rect`]), pixel for pixel, with Bevy's blit pipeline. The bars are drawn at the
//! viewport's full resolution whatever scale the scene draws at, and the scene's retained picture holds no bar.
//!
//! An overlay camera drew them before: a second 3D camera on the target, with its own passes, and the bars as
//! quads through Bevy's PBR shader: about 18 ms of a coarse frame of the default scene on lavapipe (1280x720,
//! headless), for 30k pixels of bars.

use bevy::core_pipeline::blit::{BlitPipeline, BlitPipelineKey};
use bevy::core_pipeline::{Core3dSystems, schedule::Core3d};
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::camera::ExtractedCamera;
use bevy::render::extract_component::{ExtractComponent, ExtractComponentPlugin};
use bevy::render::render_asset::RenderAssets;
use bevy::render::render_resource::{
    BindGroup, BlendState, CachedRenderPipelineId, PipelineCache, SpecializedRenderPipelines, TextureViewId,
};
use bevy::render::renderer::{RenderContext, RenderDevice, ViewQuery};
use bevy::render::texture::GpuImage;
use bevy::render::view::ViewTarget;
use bevy::render::{Render, RenderApp, RenderSystems};

use crate::colourbar::bar_rect;

/// The colour bars drawn over a 3D camera's viewport, from the bottom up (bar `i` at
/// [`bar_rect`]`(viewport size, i)`; those that do not fit are not drawn): one
/// [`BAR_W`](crate::colourbar::BAR_W) x [`BAR_H`](crate::colourbar::BAR_H) sRGB image each
/// ([`crate::colourbar::bar_image`]), blended over the picture by its alpha. [`crate::ViewsPlugin`] keeps it on every
/// [`crate::MainView`] camera from the layers' [`crate::ColourBar`]s; an app may put its own on any 3D camera.
/// Default: no bar.
#[derive(Component, Clone, Debug, Default, PartialEq, ExtractComponent)]
pub struct BarOverlay(pub Vec<Handle<Image>>);

/// Render world, on a view with bars: the blending blit pipeline for its main texture and a bind group per bar
/// (none for an image not yet on the GPU).
#[derive(Component)]
struct PreparedBars {
    pipeline: CachedRenderPipelineId,
    groups: Vec<Option<BindGroup>>,
}

pub(crate) fn build(app: &mut App) {
    app.add_plugins(ExtractComponentPlugin::<BarOverlay>::default());
    if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
        render_app.add_systems(Render, prepare_bars.in_set(RenderSystems::PrepareBindGroups)).add_systems(
            Core3d,
            draw_bars
                .after(Core3dSystems::MainPass)
                .before(Core3dSystems::PostProcess)
                .in_set(fascicle_render::OverlaySystems),
        );
    }
}

#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters")]
fn prepare_bars(
    mut commands: Commands,
    views: Query<(Entity, &ViewTarget, &BarOverlay)>,
    blit: Option<Res<BlitPipeline>>,
    mut pipelines: ResMut<SpecializedRenderPipelines<BlitPipeline>>,
    cache: Res<PipelineCache>,
    images: Res<RenderAssets<GpuImage>>,
    device: Res<RenderDevice>,
    mut groups: Local<HashMap<AssetId<Image>, (TextureViewId, BindGroup)>>,
) {
    let Some(blit) = blit else { return };
    groups.retain(|id, _| views.iter().any(|(.., bars)| bars.0.iter().any(|h| h.id() == *id)));
    for (entity, target, bars) in &views {
        if bars.0.is_empty() {
            commands.entity(entity).remove::<PreparedBars>();
            continue;
        }
        // Drawn into the resolved main texture (after the main pass and the budget's stretch, which writes
        // there), blended by the bar's alpha as the quads' `AlphaMode::Blend` did.
        let key = BlitPipelineKey {
            target_format: target.main_texture_format(),
            blend_state: Some(BlendState::ALPHA_BLENDING),
            samples: 1,
            source_space: None,
        };
        let pipeline = pipelines.specialize(&cache, &blit, key);
        let prepared = bars
            .0
            .iter()
            .map(|bar| {
                let gpu = images.get(bar)?;
                let id = gpu.texture_view.id();
                Some(match groups.get(&bar.id()) {
                    Some((view, group)) if *view == id => group.clone(),
                    _ => {
                        let group = blit.create_bind_group(&device, &gpu.texture_view, &cache);
                        groups.insert(bar.id(), (id, group.clone()));
                        group
                    }
                })
            })
            .collect();
        commands.entity(entity).insert(PreparedBars { pipeline, groups: prepared });
    }
}

/// Blends each bar over its rectangle of the view's viewport.
fn draw_bars(
    view: ViewQuery<(&ViewTarget, &ExtractedCamera, &PreparedBars)>,
    cache: Res<PipelineCache>,
    mut ctx: RenderContext,
) {
    let (target, camera, bars) = view.into_inner();
    let Some(pipeline) = cache.get_render_pipeline(bars.pipeline) else { return };
    let viewport = fascicle_render::viewport::physical_viewport(camera);
    for (i, group) in bars.groups.iter().enumerate() {
        let Some(rect) = bar_rect(viewport.physical_size, i as u32) else { break };
        let Some(group) = group else { continue };
        let at = bevy::camera::Viewport {
            physical_position: viewport.physical_position + rect.min,
            physical_size: rect.size(),
            ..default()
        };
        // What the view drew stays under the bar.
        let attachment = fascicle_render::viewport::loaded_main_attachment(target);
        fascicle_render::viewport::blit_over(&mut ctx, "fascicle_colour_bar", attachment, &at, pipeline, group);
    }
}
