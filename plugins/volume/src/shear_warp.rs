//! Shear-warp (Lacroute and Levoy 1994) on the GPU: per view, a compute pass composites the voxel planes of
//! the principal axis into an intermediate image lying on the front plane (`shaders/shear_warp.wgsl`: each
//! plane resampled bilinearly where the intermediate pixel's ray crosses it, front to back); then the
//! volume's box is drawn and each fragment warps, reading the intermediate image bilinearly where its ray
//! meets that plane (`shaders/volume.wgsl`, method 5). A pixel whose ray meets an opaque surface inside the
//! volume is ray-marched up to it instead (a few pixels: glyphs inside the volume). Compositing happens at the
//! volume's resolution ([`crate::VolumeSettings::intermediate`] pixels per voxel), not the screen's: that is
//! the method's speed and its blur.
//!
//! The pass runs in `Core3d` before the transparent pass, once per view
//! that sees the volume; the warp's parameters (axis, plane, the image's placement) are written by the pass
//! itself into a small buffer the warp reads, so each view warps its own image.

use bevy::camera::visibility::RenderLayers;
use bevy::prelude::*;
use bevy::render::render_asset::RenderAssets;
use bevy::render::render_resource::binding_types::{
    storage_buffer_read_only_sized, storage_buffer_sized, texture_3d, texture_storage_2d, uniform_buffer,
};
use bevy::render::render_resource::{
    BindGroupEntries, BindGroupLayoutDescriptor, BindGroupLayoutEntries, BufferUsages, CachedComputePipelineId,
    ComputePassDescriptor, ComputePipelineDescriptor, PipelineCache, ShaderStages, ShaderType, StorageTextureAccess,
    TextureFormat, TextureSampleType, encase,
};
use bevy::render::renderer::{RenderContext, RenderDevice, ViewQuery};
use bevy::render::storage::{GpuShaderBuffer, ShaderBuffer};
use bevy::render::texture::GpuImage;
use bevy::render::view::ExtractedView;
use bevy::render::{Extract, RenderApp, RenderStartup};
use fascicle_core::dvr::{ShearWarpView, shear_warp_view};
use glam::DMat4;

use crate::{VolumeMaterial, VolumeMethod, VolumeSet, shaders};

/// The intermediate image's format (written by the pass, read by the warp).
pub const IMAGE_FORMAT: TextureFormat = TextureFormat::Rgba16Float;

/// Edge of a volume's intermediate image (pixels): room for the volume's largest face seen obliquely
/// (sheared by up to its depth) at `per_voxel` pixels per voxel, at most 4096; 1 for other methods.
pub fn image_edge(dims: [usize; 3], per_voxel: f64, method: VolumeMethod) -> u32 {
    if method != VolumeMethod::ShearWarp {
        return 1;
    }
    let d = dims.into_iter().max().unwrap_or(1) as f64;
    ((2.0 * d * per_voxel.clamp(0.25, 4.0)).ceil() as u32).clamp(8, 4096)
}

/// GPU parameters of the pass. Keep in sync with `ShearWarpParams` in `shaders/shear_warp.wgsl`.
#[derive(Clone, Copy, Debug, ShaderType)]
struct ShearWarpUniform {
    voxel_from_world: Mat4,
    world_from_voxel: Mat4,
    clip_from_world: Mat4,
    viewport: Vec4,
    eye: Vec4,
    dims: Vec4,
    clip_lo: Vec4,
    clip_hi: Vec4,
    origin: Vec2,
    spacing: Vec2,
    range: Vec2,
    size: UVec2,
    axis: u32,
    base: f32,
    first: f32,
    dir: f32,
    planes: u32,
    termination: f32,
}

/// One shear-warp volume, as the render world sees it.
#[derive(Clone)]
pub(crate) struct Job {
    volume: AssetId<Image>,
    lut: AssetId<ShaderBuffer>,
    image: AssetId<Image>,
    warp: AssetId<ShaderBuffer>,
    dims: [usize; 3],
    world_from_voxel: DMat4,
    per_voxel: f64,
    edge: u32,
    clip_lo: Vec3,
    clip_hi: Vec3,
    range: Vec2,
    termination: f32,
    layers: RenderLayers,
}

#[derive(Resource, Default)]
pub(crate) struct Jobs(Vec<Job>);

#[derive(Resource)]
pub(crate) struct Pipeline {
    layout: BindGroupLayoutDescriptor,
    id: CachedComputePipelineId,
}

pub(crate) fn build(app: &mut App) {
    let Some(render_app) = app.get_sub_app_mut(RenderApp) else { return };
    render_app.init_resource::<Jobs>().add_systems(RenderStartup, init_pipeline).add_systems(ExtractSchedule, extract);
}

fn init_pipeline(mut commands: Commands, cache: Res<PipelineCache>, assets: Res<AssetServer>) {
    let layout = BindGroupLayoutDescriptor::new(
        "fascicle_shear_warp",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::COMPUTE,
            (
                uniform_buffer::<ShearWarpUniform>(false),
                texture_3d(TextureSampleType::Float { filterable: false }),
                storage_buffer_read_only_sized(false, None),
                texture_storage_2d(IMAGE_FORMAT, StorageTextureAccess::WriteOnly),
                storage_buffer_sized(false, None),
            ),
        ),
    );
    let id = cache.queue_compute_pipeline(ComputePipelineDescriptor {
        label: Some("fascicle_shear_warp".into()),
        layout: vec![layout.clone()],
        shader: shaders::shear_warp(&assets),
        entry_point: Some("composite".into()),
        ..default()
    });
    commands.insert_resource(Pipeline { layout, id });
}

fn extract(
    mut jobs: ResMut<Jobs>,
    sets: Extract<Query<(&VolumeSet, &InheritedVisibility, Option<&RenderLayers>)>>,
    materials: Extract<Res<Assets<VolumeMaterial>>>,
) {
    jobs.0.clear();
    for (set, visible, layers) in &sets {
        if set.settings.method != VolumeMethod::ShearWarp || !visible.get() {
            continue;
        }
        let Some(m) = materials.get(&set.material) else { continue };
        let (lo, hi) = set.settings.clip.voxel_bounds(set.dims);
        jobs.0.push(Job {
            volume: m.volume.id(),
            lut: m.lut.id(),
            image: m.intermediate.id(),
            warp: m.warp.id(),
            dims: set.dims,
            world_from_voxel: set.world_from_voxel,
            per_voxel: set.settings.intermediate,
            edge: image_edge(set.dims, set.settings.intermediate, VolumeMethod::ShearWarp),
            clip_lo: lo.as_vec3(),
            clip_hi: hi.as_vec3(),
            range: Vec2::new(set.settings.tf.range[0] as f32, set.settings.tf.range[1] as f32),
            termination: set.settings.termination as f32,
            layers: layers.cloned().unwrap_or_default(),
        });
    }
}

/// The pass, per view (in `Core3d`, ordered by the plugin).
#[allow(clippy::too_many_arguments, reason = "the render-world resources one compute pass reads")]
pub(crate) fn composite(
    view: ViewQuery<(&ExtractedView, Option<&RenderLayers>, Option<&bevy::camera::MainPassResolutionOverride>)>,
    jobs: Res<Jobs>,
    pipeline: Option<Res<Pipeline>>,
    cache: Res<PipelineCache>,
    images: Res<RenderAssets<GpuImage>>,
    buffers: Res<RenderAssets<GpuShaderBuffer>>,
    device: Res<RenderDevice>,
    mut ctx: RenderContext,
) {
    if jobs.0.is_empty() {
        return;
    }
    let Some(pipeline) = pipeline else { return };
    let Some(compute) = cache.get_compute_pipeline(pipeline.id) else { return };
    let (view, view_layers, scaled) = view.into_inner();
    // A main pass drawn at a lower scale (`fascicle_render::budget`) covers the top-left part of the viewport.
    let mut viewport = view.viewport.as_vec4();
    if let Some(size) = scaled {
        viewport.z = size.x as f32;
        viewport.w = size.y as f32;
    }
    let view_layers = view_layers.cloned().unwrap_or_default();
    let world_from_view = view.world_from_view.to_matrix();
    let clip_from_world = view.clip_from_world.unwrap_or(view.clip_from_view * world_from_view.inverse());
    let orthographic = view.clip_from_view.w_axis.w == 1.0;
    let eye = view.world_from_view.translation().as_dvec3();
    let forward = view.world_from_view.forward().as_dvec3();
    for job in &jobs.0 {
        if !job.layers.intersects(&view_layers) {
            continue;
        }
        let (Some(volume), Some(lut), Some(image), Some(warp)) =
            (images.get(job.volume), buffers.get(job.lut), images.get(job.image), buffers.get(job.warp))
        else {
            continue;
        };
        if image.texture.width() < job.edge {
            continue;
        }
        let voxel_from_world = job.world_from_voxel.inverse();
        let sw = shear_warp_view(
            job.dims,
            voxel_from_world,
            if orthographic { None } else { Some(eye) },
            forward,
            (job.clip_lo.as_dvec3(), job.clip_hi.as_dvec3()),
            job.per_voxel,
            job.edge,
        );
        let u = uniform(job, &sw, voxel_from_world, clip_from_world, viewport);
        let mut bytes = encase::UniformBuffer::new(Vec::<u8>::new());
        if bytes.write(&u).is_err() {
            continue;
        }
        let params = device.create_buffer_with_data(&bevy::render::render_resource::BufferInitDescriptor {
            label: Some("fascicle_shear_warp_params"),
            contents: &bytes.into_inner(),
            usage: BufferUsages::UNIFORM,
        });
        let bind_group = device.create_bind_group(
            "fascicle_shear_warp",
            &cache.get_bind_group_layout(&pipeline.layout),
            &BindGroupEntries::sequential((
                params.as_entire_binding(),
                &volume.texture_view,
                lut.buffer.as_entire_binding(),
                &image.texture_view,
                warp.buffer.as_entire_binding(),
            )),
        );
        let mut pass = ctx
            .command_encoder()
            .begin_compute_pass(&ComputePassDescriptor { label: Some("fascicle_shear_warp"), ..default() });
        pass.set_pipeline(compute);
        pass.set_bind_group(0, &bind_group, &[]);
        // At least one invocation: (0, 0) writes the warp's parameters even when no plane is in front.
        pass.dispatch_workgroups(sw.size[0].div_ceil(8).max(1), sw.size[1].div_ceil(8).max(1), 1);
    }
}

fn uniform(
    job: &Job,
    sw: &ShearWarpView,
    voxel_from_world: DMat4,
    clip_from_world: Mat4,
    viewport: Vec4,
) -> ShearWarpUniform {
    let eye = match sw.eye {
        Some(e) => e.as_vec3().extend(1.0),
        None => sw.direction.as_vec3().extend(0.0),
    };
    ShearWarpUniform {
        voxel_from_world: voxel_from_world.as_mat4(),
        world_from_voxel: job.world_from_voxel.as_mat4(),
        clip_from_world,
        viewport,
        eye,
        dims: Vec4::new(job.dims[0] as f32, job.dims[1] as f32, job.dims[2] as f32, 0.0),
        clip_lo: job.clip_lo.extend(0.0),
        clip_hi: job.clip_hi.extend(0.0),
        origin: sw.origin.as_vec2(),
        spacing: sw.spacing.as_vec2(),
        range: job.range,
        size: UVec2::new(sw.size[0], sw.size[1]),
        axis: sw.axis as u32,
        base: sw.base as f32,
        first: sw.first as f32,
        dir: sw.step as f32,
        planes: sw.planes as u32,
        termination: job.termination,
    }
}
