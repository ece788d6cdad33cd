//! Per-mesh instance data built on the CPU where the adapter is a software rasteriser.
//!
//! Where compute shaders are available, Bevy 0.19 builds each frame's per-mesh instance data on the GPU
//! (`bevy::pbr::GpuMeshPreprocessPlugin`): a compute pass unpacks the bins of every batch set, one dispatch per
//! set, a second preprocesses the meshes, and the draws are indirect. On a software rasteriser each dispatch is
//! work for the CPU, with a fixed cost that does not depend on its size: a 10M-streamline tract layer in 255
//! parts (each with its own material, so a batch set of its own) cost lavapipe 5-15 ms a frame in bin
//! unpacking alone (16,512 invocations in 258 dispatches; Bevy's pass timings, `FASCICLE_PASS_TIMES=1` in the
//! viewer), every frame, still or moving. Built on the CPU, the same instance data is a few hundred structs
//! written into one buffer, and the draws are direct: the picture is the same.
//!
//! [`CpuBatchingOnSoftwarePlugin`] makes that choice once the adapter is known: it goes right after Bevy's
//! `RenderPlugin` (whose `finish` opens the device) and before `PbrPlugin` (whose mesh plugins read the choice in
//! their `finish`), as [`default_plugins`] places it.

use bevy::app::PluginGroupBuilder;
use bevy::prelude::*;
use bevy::render::batching::gpu_preprocessing::{GpuPreprocessingMode, GpuPreprocessingSupport};
use bevy::render::renderer::RenderAdapterInfo;
use bevy::render::{RenderApp, RenderPlugin, RenderStartup, init_gpu_resource};

/// On a software adapter (wgpu's device type `Cpu`: lavapipe, llvmpipe, WARP), turns Bevy's GPU mesh
/// preprocessing off, so instance data is built on the CPU and drawn directly (see the module docs); a hardware
/// GPU keeps Bevy's default. Must be added after `RenderPlugin` and before `PbrPlugin` ([`default_plugins`] places it);
/// added later it warns and does nothing. [`KEEP_GPU_PREPROCESSING`] in the environment turns it off.
pub struct CpuBatchingOnSoftwarePlugin;

impl Plugin for CpuBatchingOnSoftwarePlugin {
    fn build(&self, app: &mut App) {
        if gpu_preprocessing_kept() {
            debug!("fascicle-render: {KEEP_GPU_PREPROCESSING} set: Bevy's GPU mesh preprocessing kept");
            return;
        }
        // Added after `PbrPlugin`, its mesh plugins have chosen already: turning preprocessing off at the render
        // world's start would leave them building instance data for a GPU pass that no longer runs.
        if app.is_plugin_added::<bevy::pbr::PbrPlugin>() {
            warn!(
                "fascicle-render: CpuBatchingOnSoftwarePlugin added after PbrPlugin does nothing; use default_plugins()"
            );
            return;
        }
        app.init_resource::<CpuBatchingPlaced>();
        // Bevy makes the choice again at the render world's start (from the adapter's limits), after `finish`
        // made it for the mesh plugins: made there again, so every system reads the same one.
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app.add_systems(
                RenderStartup,
                cpu_batching_on_software.after(init_gpu_resource::<GpuPreprocessingSupport>),
            );
        }
    }

    fn finish(&self, app: &mut App) {
        if !app.world().contains_resource::<CpuBatchingPlaced>() {
            return;
        }
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            cpu_batching_on_software(render_app.world_mut());
        }
    }
}

/// An environment variable that, set (not to `0`), keeps Bevy's GPU mesh preprocessing on a software adapter
/// too: the test suite runs the GPU tests of mesh-drawn layers once more with it, so the path a hardware GPU
/// takes is tested on lavapipe as well.
pub const KEEP_GPU_PREPROCESSING: &str = "FASCICLE_GPU_PREPROCESSING";

/// Whether [`KEEP_GPU_PREPROCESSING`] is set (to anything but empty or `0`).
pub fn gpu_preprocessing_kept() -> bool {
    std::env::var_os(KEEP_GPU_PREPROCESSING).is_some_and(|v| !v.is_empty() && v != "0")
}

/// The plugin was added before `PbrPlugin`, so it acts.
#[derive(Resource, Default)]
struct CpuBatchingPlaced;

/// Render world: no GPU preprocessing where the adapter is a software rasteriser.
fn cpu_batching_on_software(world: &mut World) {
    if world.get_resource::<RenderAdapterInfo>().is_some_and(|info| crate::is_software(info)) {
        world.insert_resource(GpuPreprocessingSupport { max_supported_mode: GpuPreprocessingMode::None });
    }
}

/// Bevy's `DefaultPlugins` with [`CpuBatchingOnSoftwarePlugin`] in its place (right after `RenderPlugin`), for
/// every Fascicle app; set or disable Bevy's plugins on the returned group as on `DefaultPlugins`.
pub fn default_plugins() -> PluginGroupBuilder {
    DefaultPlugins.build().add_after::<RenderPlugin>(CpuBatchingOnSoftwarePlugin)
}
