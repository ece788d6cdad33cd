//! A camera's viewport in its main texture: copied out into a texture of its own, and a texture blitted back
//! over it (Bevy's blit pipeline). Shared by the frame budget's upscale, the retained picture and the colour
//! bars drawn over a view (`fascicle_views`, in [`crate::OverlaySystems`]).

use bevy::camera::Viewport;
use bevy::prelude::*;
use bevy::render::camera::ExtractedCamera;
use bevy::render::render_resource::{
    BindGroup, Extent3d, LoadOp, Operations, Origin3d, RenderPassColorAttachment, RenderPassDescriptor, RenderPipeline,
    StoreOp, TexelCopyTextureInfo, Texture, TextureAspect, TextureDescriptor, TextureDimension, TextureFormat,
    TextureUsages,
};
use bevy::render::renderer::RenderContext;
use bevy::render::view::ViewTarget;

/// The camera's viewport in physical pixels of its target (the whole target when it sets none).
pub fn physical_viewport(camera: &ExtractedCamera) -> Viewport {
    camera
        .viewport
        .clone()
        .unwrap_or_else(|| Viewport { physical_size: camera.physical_viewport_size.unwrap_or_default(), ..default() })
}

/// A texture that holds a viewport's picture copied out of a main texture of `format`, and is sampled by the
/// blit.
pub(crate) fn picture_texture(label: &'static str, size: UVec2, format: TextureFormat) -> TextureDescriptor<'static> {
    TextureDescriptor {
        label: Some(label),
        size: Extent3d { width: size.x, height: size.y, depth_or_array_layers: 1 },
        mip_level_count: 1,
        sample_count: 1,
        dimension: TextureDimension::D2,
        format,
        usage: TextureUsages::TEXTURE_BINDING | TextureUsages::COPY_DST,
        view_formats: &[],
    }
}

/// Copies the `size` pixels at the viewport's origin out of the view's main texture into `to` (at its origin).
pub(crate) fn copy_out(ctx: &mut RenderContext, target: &ViewTarget, viewport: &Viewport, size: UVec2, to: &Texture) {
    let origin = viewport.physical_position;
    ctx.command_encoder().copy_texture_to_texture(
        TexelCopyTextureInfo {
            texture: target.main_texture(),
            mip_level: 0,
            origin: Origin3d { x: origin.x, y: origin.y, z: 0 },
            aspect: TextureAspect::All,
        },
        TexelCopyTextureInfo { texture: to, mip_level: 0, origin: Origin3d::ZERO, aspect: TextureAspect::All },
        Extent3d { width: size.x, height: size.y, depth_or_array_layers: 1 },
    );
}

/// The view's unsampled main texture as a colour attachment that keeps what is there (loaded, not cleared as
/// wgpu's default operations do): for blits over part of it, the stretched scaled picture or a colour bar.
pub fn loaded_main_attachment(target: &ViewTarget) -> RenderPassColorAttachment<'_> {
    let mut attachment = target.get_unsampled_color_attachment();
    attachment.ops = Operations { load: LoadOp::Load, store: StoreOp::Store };
    attachment
}

/// Draws the texture of `bind_group` (Bevy's blit layout) over `viewport` (physical pixels of the target) into
/// `attachment` with `pipeline` (a `BlitPipeline` specialisation: its blend state decides whether the texture
/// replaces or blends over what is there), stretched to the viewport's size.
pub fn blit_over(
    ctx: &mut RenderContext,
    label: &'static str,
    attachment: RenderPassColorAttachment,
    viewport: &Viewport,
    pipeline: &RenderPipeline,
    bind_group: &BindGroup,
) {
    let mut pass = ctx.command_encoder().begin_render_pass(&RenderPassDescriptor {
        label: Some(label),
        color_attachments: &[Some(attachment)],
        depth_stencil_attachment: None,
        timestamp_writes: None,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    let (p, s) = (viewport.physical_position.as_vec2(), viewport.physical_size.as_vec2());
    pass.set_viewport(p.x, p.y, s.x, s.y, 0.0, 1.0);
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, bind_group, &[]);
    pass.draw(0..3, 0..1);
}
