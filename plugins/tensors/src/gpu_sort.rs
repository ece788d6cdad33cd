//! Splats sorted on the GPU (`shaders/splat_sort.wgsl`): per view that sees a splat set, a compute pass
//! computes every centre's depth along the view direction and bitonic-sorts (depth, index) far to near into
//! the set's `order` buffer, which the splat shader already reads per quad slot. It runs in `Core3d` before
//! the transparent pass, so each view draws in its own order, and only when the view direction (or the set's
//! placement) changed since the buffer was last sorted. Nothing is uploaded per frame: the view comes from
//! Bevy's view uniform, the set's placement from a small buffer rewritten when the set moves, the sort's
//! steps from one buffer made once per set size.
//!
//! Ties (equal depths) keep the splats' index order, as the CPU's stable radix argsort does, so both give the
//! same order. The CPU sort ([`crate::splat::sort_splats`]) remains for [`SplatSortMode::Cpu`], for
//! adapters without compute shaders, and (by default, [`SplatSortMode::Auto`]) for software rasterisers.

use std::collections::HashMap;
use std::num::NonZeroU64;
use std::sync::atomic::Ordering;

use bevy::camera::visibility::RenderLayers;
use bevy::prelude::*;
use bevy::render::render_asset::RenderAssets;
use bevy::render::render_resource::binding_types::{
    storage_buffer_read_only_sized, storage_buffer_sized, uniform_buffer,
};
use bevy::render::render_resource::{
    BindGroupEntries, BindGroupLayoutDescriptor, BindGroupLayoutEntries, Buffer, BufferBinding, BufferDescriptor,
    BufferInitDescriptor, BufferUsages, CachedComputePipelineId, ComputePassDescriptor, ComputePipelineDescriptor,
    DownlevelFlags, PipelineCache, ShaderStages, ShaderType,
};
use bevy::render::renderer::{RenderAdapter, RenderContext, RenderDevice, RenderQueue, ViewQuery};
use bevy::render::storage::{GpuShaderBuffer, ShaderBuffer};
use bevy::render::view::{ExtractedView, ViewUniform, ViewUniformOffset, ViewUniforms};
use bevy::render::{Extract, RenderApp, RenderStartup};

use crate::shaders;
pub use crate::sort_order::{GpuSortStats, SplatSortMode, padded_len};
use crate::splat::{SplatMaterial, SplatSet};

/// GPU placement of a set. Keep in sync with `SetParams` in `shaders/splat_sort.wgsl`.
#[derive(Clone, Copy, Debug, PartialEq, ShaderType)]
struct SetUniform {
    row0: Vec4,
    row1: Vec4,
    row2: Vec4,
    n: u32,
    padded: u32,
}

/// One step of the network. Keep in sync with `Step` in `shaders/splat_sort.wgsl`.
#[derive(Clone, Copy, Debug, ShaderType)]
struct StepUniform {
    k: u32,
    j: u32,
}

/// Bytes between the steps in their buffer (the largest uniform offset alignment allowed).
const STEP_STRIDE: u64 = 256;

#[derive(Clone)]
pub(crate) struct Job {
    set: Entity,
    splats: AssetId<ShaderBuffer>,
    order: AssetId<ShaderBuffer>,
    placement: SetUniform,
    layers: RenderLayers,
}

#[derive(Resource, Default)]
pub(crate) struct Jobs(Vec<Job>);

/// The GPU resources of one set.
struct SetGpu {
    placement: SetUniform,
    params: Buffer,
    keys: Buffer,
    steps: Buffer,
    /// (entry point, step offset) in dispatch order.
    plan: Vec<(Kernel, u32)>,
    /// What the order buffer holds: sorted for this forward, this placement, in this buffer.
    sorted_for: Option<(Vec3, SetUniform, bevy::render::render_resource::BufferId)>,
}

#[derive(Resource, Default)]
pub(crate) struct SortState(HashMap<Entity, SetGpu>);

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Kernel {
    Depths,
    SortBlocks,
    MergeStep,
    MergeBlocks,
}

#[derive(Resource)]
pub(crate) struct Pipelines {
    layout: BindGroupLayoutDescriptor,
    ids: [CachedComputePipelineId; 4],
}

pub(crate) fn build(app: &mut App) {
    let stats = GpuSortStats::default();
    app.init_resource::<SplatSortMode>().insert_resource(stats.clone());
    let Some(render_app) = app.get_sub_app_mut(RenderApp) else { return };
    render_app
        .insert_resource(stats)
        .init_resource::<Jobs>()
        .init_resource::<SortState>()
        .add_systems(RenderStartup, init_pipelines)
        .add_systems(ExtractSchedule, extract);
}

fn init_pipelines(
    mut commands: Commands,
    cache: Res<PipelineCache>,
    assets: Res<AssetServer>,
    adapter: Res<RenderAdapter>,
    stats: Res<GpuSortStats>,
) {
    let compute = adapter.get_downlevel_capabilities().flags.contains(DownlevelFlags::COMPUTE_SHADERS);
    // wgpu's `DeviceType::Cpu` (Bevy does not re-export the type).
    let software = format!("{:?}", adapter.get_info().device_type) == "Cpu";
    stats.0.software.store(software, Ordering::Relaxed);
    info!(
        "fascicle-tensors: splats sorted on the {} by default (compute shaders: {compute}, software adapter: {software})",
        if compute && !software { "GPU" } else { "CPU" }
    );
    stats.0.compute.store(if compute { 1 } else { 2 }, Ordering::Relaxed);
    if !compute {
        return;
    }
    let layout = BindGroupLayoutDescriptor::new(
        "fascicle_splat_sort",
        &BindGroupLayoutEntries::sequential(
            ShaderStages::COMPUTE,
            (
                uniform_buffer::<ViewUniform>(true),
                uniform_buffer::<SetUniform>(false),
                storage_buffer_read_only_sized(false, None),
                storage_buffer_sized(false, None),
                storage_buffer_sized(false, None),
                uniform_buffer::<StepUniform>(true),
            ),
        ),
    );
    let shader = shaders::splat_sort(&assets);
    let ids = ["depths", "sort_blocks", "merge_step", "merge_blocks"].map(|entry| {
        cache.queue_compute_pipeline(ComputePipelineDescriptor {
            label: Some(format!("fascicle_splat_sort_{entry}").into()),
            layout: vec![layout.clone()],
            shader: shader.clone(),
            entry_point: Some(entry.into()),
            ..default()
        })
    });
    commands.insert_resource(Pipelines { layout, ids });
}

/// A splat set as the extraction reads it.
type SetQuery<'w> = (Entity, &'w SplatSet, &'w GlobalTransform, &'w InheritedVisibility, Option<&'w RenderLayers>);

fn extract(
    mut jobs: ResMut<Jobs>,
    mode: Extract<Res<SplatSortMode>>,
    stats: Res<GpuSortStats>,
    sets: Extract<Query<SetQuery>>,
    materials: Extract<Res<Assets<SplatMaterial>>>,
) {
    jobs.0.clear();
    if !stats.uses_gpu(**mode) {
        return;
    }
    for (set, splats, gt, visible, layers) in &sets {
        if !visible.get() || splats.is_empty() {
            continue;
        }
        let Some(m) = materials.get(&splats.material) else { continue };
        let a = gt.affine();
        let (m3, t) = (a.matrix3, a.translation);
        let row = |i: usize| Vec4::new(m3.x_axis[i], m3.y_axis[i], m3.z_axis[i], t[i]);
        jobs.0.push(Job {
            set,
            splats: m.splats.id(),
            order: m.order.id(),
            placement: SetUniform {
                row0: row(0),
                row1: row(1),
                row2: row(2),
                n: splats.len() as u32,
                padded: padded_len(splats.len()) as u32,
            },
            layers: layers.cloned().unwrap_or_default(),
        });
    }
}

/// The dispatches of a bitonic sort of `padded` keys, each with its step's offset in the steps buffer, and
/// the steps buffer's contents.
fn plan(padded: u32) -> (Vec<(Kernel, u32)>, Vec<u8>) {
    let mut steps: Vec<(u32, u32)> = vec![(0, 0)];
    let mut plan = vec![(Kernel::Depths, 0), (Kernel::SortBlocks, 0)];
    let mut k = 1024;
    while k <= padded {
        let mut j = k / 2;
        while j >= 512 {
            plan.push((Kernel::MergeStep, (steps.len() as u64 * STEP_STRIDE) as u32));
            steps.push((k, j));
            j /= 2;
        }
        plan.push((Kernel::MergeBlocks, (steps.len() as u64 * STEP_STRIDE) as u32));
        steps.push((k, 0));
        k *= 2;
    }
    let mut bytes = vec![0u8; steps.len() * STEP_STRIDE as usize];
    for (i, (k, j)) in steps.iter().enumerate() {
        let at = i * STEP_STRIDE as usize;
        bytes[at..at + 4].copy_from_slice(&k.to_le_bytes());
        bytes[at + 4..at + 8].copy_from_slice(&j.to_le_bytes());
    }
    (plan, bytes)
}

fn uniform_bytes<T: ShaderType + bevy::render::render_resource::encase::internal::WriteInto>(value: &T) -> Vec<u8> {
    let mut bytes = bevy::render::render_resource::encase::UniformBuffer::new(Vec::<u8>::new());
    // Writing a plain struct into a growable Vec cannot fail.
    let _ = bytes.write(value);
    bytes.into_inner()
}

/// The pass, per view (in `Core3d`, before the transparent pass).
#[allow(clippy::too_many_arguments, reason = "the render-world resources one compute pass reads")]
pub(crate) fn sort(
    view: ViewQuery<(&ExtractedView, &ViewUniformOffset, Option<&RenderLayers>)>,
    jobs: Res<Jobs>,
    mut state: ResMut<SortState>,
    pipelines: Option<Res<Pipelines>>,
    cache: Res<PipelineCache>,
    buffers: Res<RenderAssets<GpuShaderBuffer>>,
    view_uniforms: Res<ViewUniforms>,
    device: Res<RenderDevice>,
    queue: Res<RenderQueue>,
    stats: Res<GpuSortStats>,
    mut ctx: RenderContext,
) {
    state.0.retain(|set, _| jobs.0.iter().any(|j| j.set == *set));
    if jobs.0.is_empty() {
        return;
    }
    let Some(pipelines) = pipelines else { return };
    let Some(kernels) = pipelines.ids.map(|id| cache.get_compute_pipeline(id)).into_iter().collect::<Option<Vec<_>>>()
    else {
        return;
    };
    let Some(view_binding) = view_uniforms.uniforms.binding() else { return };
    let (view, view_offset, view_layers) = view.into_inner();
    let view_layers = view_layers.cloned().unwrap_or_default();
    let forward = view.world_from_view.forward().as_vec3();
    for job in &jobs.0 {
        if !job.layers.intersects(&view_layers) {
            continue;
        }
        let (Some(splats), Some(order)) = (buffers.get(job.splats), buffers.get(job.order)) else { continue };
        let padded = job.placement.padded;
        if order.buffer.size() < 4 * u64::from(padded) {
            continue;
        }
        let gpu = state.0.entry(job.set).or_insert_with(|| new_set(&device, &job.placement));
        if gpu.placement.padded != padded {
            *gpu = new_set(&device, &job.placement);
        } else if gpu.placement != job.placement {
            queue.write_buffer(&gpu.params, 0, &uniform_bytes(&job.placement));
            gpu.placement = job.placement;
        }
        let key = (forward, job.placement, order.buffer.id());
        if gpu.sorted_for == Some(key) {
            continue;
        }
        let bind_group = device.create_bind_group(
            "fascicle_splat_sort",
            &cache.get_bind_group_layout(&pipelines.layout),
            &BindGroupEntries::sequential((
                view_binding.clone(),
                gpu.params.as_entire_binding(),
                splats.buffer.as_entire_binding(),
                gpu.keys.as_entire_binding(),
                order.buffer.as_entire_binding(),
                bevy::render::render_resource::BindingResource::Buffer(BufferBinding {
                    buffer: &gpu.steps,
                    offset: 0,
                    size: NonZeroU64::new(16),
                }),
            )),
        );
        let mut pass = ctx
            .command_encoder()
            .begin_compute_pass(&ComputePassDescriptor { label: Some("fascicle_splat_sort"), ..default() });
        for (kernel, step) in &gpu.plan {
            let (pipeline, groups) = match kernel {
                Kernel::Depths => (kernels[0], padded / 256),
                Kernel::SortBlocks => (kernels[1], padded / 512),
                Kernel::MergeStep => (kernels[2], padded / 2 / 256),
                Kernel::MergeBlocks => (kernels[3], padded / 512),
            };
            pass.set_pipeline(pipeline);
            pass.set_bind_group(0, &bind_group, &[view_offset.offset, *step]);
            pass.dispatch_workgroups(groups.max(1), 1, 1);
        }
        drop(pass);
        gpu.sorted_for = Some(key);
        stats.0.sorts.fetch_add(1, Ordering::Relaxed);
        *stats.0.last_forward.lock().unwrap_or_else(|e| e.into_inner()) = Some(forward);
    }
}

fn new_set(device: &RenderDevice, placement: &SetUniform) -> SetGpu {
    let (plan, steps) = plan(placement.padded);
    SetGpu {
        placement: *placement,
        params: device.create_buffer_with_data(&BufferInitDescriptor {
            label: Some("fascicle_splat_sort_set"),
            contents: &uniform_bytes(placement),
            usage: BufferUsages::UNIFORM | BufferUsages::COPY_DST,
        }),
        keys: device.create_buffer(&BufferDescriptor {
            label: Some("fascicle_splat_sort_keys"),
            size: 4 * u64::from(placement.padded),
            usage: BufferUsages::STORAGE,
            mapped_at_creation: false,
        }),
        steps: device.create_buffer_with_data(&BufferInitDescriptor {
            label: Some("fascicle_splat_sort_steps"),
            contents: &steps,
            usage: BufferUsages::UNIFORM,
        }),
        plan,
        sorted_for: None,
    }
}
