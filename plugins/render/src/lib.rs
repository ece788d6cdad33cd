//! Fascicle's shared render base, used by every glyph plugin.
//!
//! - [`shaders`]: the WGSL libraries of this crate's `src/shaders/lib/`, embedded and loaded under
//!   `#define_import_path fascicle::*` (ray helpers, lighting, colour maps, the proxy vertex stage), and
//!   [`shaders::embedded`], with which each plugin names the shaders it embeds, as Bevy's crates do.
//! - Depth rules: opaque ray-cast glyphs draw in the main opaque pass and write true fragment depth
//!   ([`impostor`] is the reference implementation); transparent layers (splats, volume) composite after
//!   them against that depth.
//! - [`headless`]: an offscreen App that renders a scene to an image without a window, waiting for every
//!   pipeline to compile; used by `fascicle render` and by every plugin's tests.
//! - [`layer`]: what every data layer shares: its status (loading, ready, failed), its voxel selection and
//!   the per-stage work counters.
//! - [`reference`](mod@reference): f64 CPU references of the shared shader math, for tests.
//! - [`budget`]: a frame budget held by adaptive render scale while the view moves ([`budget::FrameBudgetPlugin`]).
//! - [`retain`]: a retained 3D picture, put back while nothing it shows changes ([`retain::RetainedPicturePlugin`]).
//! - [`software`]: how many threads Mesa's software rasterizer gets ([`software::oversubscribe_software_rasterizer`]).
//! - [`batching`]: per-mesh instance data built on the CPU on a software adapter ([`batching::default_plugins`]).
//! - [`AdapterKind`]: whether the renderer is a software rasteriser, for plugins that lower their cost there.

#![warn(missing_docs)]

pub mod batching;
pub mod budget;
pub mod example;
pub mod headless;
pub mod impostor;
pub mod keep_awake;
pub mod layer;
pub mod meshes;
#[cfg(feature = "winit")]
pub mod on_demand;
pub mod reference;
pub mod retain;
pub mod shaders;
pub mod software;
pub mod viewport;

pub use keep_awake::KeepAwake;

use std::sync::Arc;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};

use bevy::prelude::*;

/// Registers the shared WGSL libraries and the sphere-impostor material.
pub struct FascicleRenderPlugin;

#[derive(Resource, Default)]
struct RenderBaseAdded;

impl Plugin for FascicleRenderPlugin {
    fn is_unique(&self) -> bool {
        false
    }

    fn build(&self, app: &mut App) {
        // Every glyph plugin adds this one if it is missing; an app may add it too, in any order.
        if app.world().contains_resource::<RenderBaseAdded>() {
            return;
        }
        app.init_resource::<RenderBaseAdded>().init_resource::<Unsettled>();
        let adapter = AdapterKind::default();
        app.insert_resource(adapter.clone());
        if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
            render_app.insert_resource(adapter).add_systems(bevy::render::RenderStartup, detect_adapter);
        }
        if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
            use bevy::core_pipeline::{Core3dSystems, schedule::Core3d};
            render_app.configure_sets(
                Core3d,
                OverlaySystems.after(Core3dSystems::MainPass).before(Core3dSystems::PostProcess),
            );
        }
        shaders::embed(app);
        retain::watch_asset::<impostor::SphereImpostorMaterial>(app);
        app.add_plugins((MaterialPlugin::<impostor::SphereImpostorMaterial>::default(), headless::DepthCopyPlugin));
    }
}

/// Render world, `Core3d`: systems that draw over a camera's finished 3D picture at the viewport's full
/// resolution (the colour bars), after the main pass, the frame budget's upscale ([`budget`]) and the retained
/// picture's store or put-back ([`retain`]: the stored picture holds the scene alone), and before
/// post-processing. They run in every frame, a retained one too.
#[derive(bevy::ecs::schedule::SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct OverlaySystems;

/// Requests for more frames from systems whose picture is transient and settles over the next frames (tract
/// previews while the view moves): a window drawn on demand keeps drawing at its busy rate while frames set it
/// ([`on_demand`] takes it every frame); other apps draw every frame anyway. Unlike a `RequestRedraw` message,
/// which Bevy's winit runner reads in the two updates after it is written, a request asks for no frame beyond
/// the next.
#[derive(Resource, Default, Debug)]
pub struct Unsettled(bool);

impl Unsettled {
    /// The picture is not settled: draw the next frame.
    pub fn request(&mut self) {
        self.0 = true;
    }
    /// Whether a frame asked since the last call (clearing it).
    pub fn take(&mut self) -> bool {
        std::mem::take(&mut self.0)
    }
}

/// The renderer's settings for every Fascicle app (the viewer, `fascicle render`, the headless apps of tests and
/// benchmarks): Bevy's defaults but wgpu's `MemoryHints::MemoryUsage`, which suballocates device memory in
/// blocks of 8-64 MiB instead of 128-256 MiB. Where device memory is the process's own (a software
/// rasterizer) the viewer with a million streamlines peaked about 0.1 GB lower (1.14-1.17 GiB against
/// 1.19-1.31).
pub fn wgpu_settings() -> bevy::render::settings::WgpuSettings {
    bevy::render::settings::WgpuSettings { memory_hints: bevy::render::settings::MemoryHints::MemoryUsage, ..default() }
}

/// What kind of adapter renders: set once the renderer has started (false until then, and without one).
/// Plugins lower what costs a software rasteriser most (MSAA on millions of lines, say) where it is one.
#[derive(Resource, Clone, Default, Debug)]
pub struct AdapterKind(std::sync::Arc<std::sync::atomic::AtomicBool>);

impl AdapterKind {
    /// Whether the adapter is a software rasteriser (wgpu's device type `Cpu`: lavapipe, llvmpipe, WARP).
    pub fn is_software(&self) -> bool {
        self.0.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// Records the adapter's kind (the renderer does it at start; tests may too).
    pub fn set_software(&self, software: bool) {
        self.0.store(software, std::sync::atomic::Ordering::Relaxed);
    }
}

fn detect_adapter(adapter: Res<bevy::render::renderer::RenderAdapter>, kind: Res<AdapterKind>) {
    kind.set_software(is_software(&adapter.get_info()));
}

/// Whether an adapter is a software rasteriser: wgpu's device type `Cpu` (Bevy does not re-export the type).
pub(crate) fn is_software(info: &bevy::render::render_resource::WgpuAdapterInfo) -> bool {
    format!("{:?}", info.device_type) == "Cpu"
}

/// Whether the last frames put the stored picture back, newest in bit 0 (shared between the worlds): a frame
/// time measured over such a frame is not the scene's ([`budget`] skips it); written by [`retain`].
#[derive(Resource, Clone, Default, Debug)]
pub struct RecentlyRetained(Arc<AtomicU32>, Arc<AtomicU64>);

impl RecentlyRetained {
    /// How many frames put a stored picture back since the app started.
    pub fn frames_put_back(&self) -> u64 {
        self.1.load(Ordering::Relaxed)
    }
    /// Whether every one of the last `frames` extracted frames (at most 32) put the stored picture back.
    pub fn all_of_last(&self, frames: u32) -> bool {
        let mask = if frames >= 32 { u32::MAX } else { (1u32 << frames) - 1 };
        self.0.load(Ordering::Relaxed) & mask == mask
    }
    /// Whether any of the last `frames` extracted frames (at most 32) put the stored picture back.
    pub fn any(&self, frames: u32) -> bool {
        let mask = if frames >= 32 { u32::MAX } else { (1u32 << frames) - 1 };
        self.0.load(Ordering::Relaxed) & mask != 0
    }
    /// Whether the extracted frame `frames_ago` before the newest (0: the newest; at most 31) put the stored
    /// picture back.
    pub fn was(&self, frames_ago: u32) -> bool {
        frames_ago < 32 && self.0.load(Ordering::Relaxed) >> frames_ago & 1 == 1
    }
    pub(crate) fn push(&self, retained: bool) {
        let bits = self.0.load(Ordering::Relaxed);
        self.0.store((bits << 1) | u32::from(retained), Ordering::Relaxed);
        self.1.fetch_add(u64::from(retained), Ordering::Relaxed);
    }
}

/// Changes the asset `id` with `f` and sends its [`AssetEvent::Modified`] at once, so that a system running
/// after Bevy's `AssetEventSystems` (in `PostUpdate`: where the layer plugins react to loaded assets and
/// propagated transforms) has its change drawn in this frame. `Assets::get_mut` queues the event until the
/// next frame's flush: the render world would extract the change a frame late, and a window drawn on demand
/// would draw one more full frame for it. Returns false (and sends nothing) when there is no such asset.
pub fn modify_now<A: Asset>(
    assets: &mut Assets<A>,
    events: &mut MessageWriter<AssetEvent<A>>,
    id: impl Into<AssetId<A>>,
    f: impl FnOnce(&mut A),
) -> bool {
    let id = id.into();
    let Some(asset) = assets.get_mut_untracked(id) else { return false };
    f(asset);
    events.write(AssetEvent::Modified { id });
    true
}

#[cfg(test)]
mod tests {
    use super::RecentlyRetained;

    /// The frames put back are read one by one, newest first: the frame budget reads the one its measured
    /// time belongs to (with pipelined rendering, the one before the newest).
    #[test]
    fn each_recent_frame_is_read_on_its_own() {
        let recent = RecentlyRetained::default();
        for retained in [true, false, false, true, false] {
            recent.push(retained);
        }
        // Newest first: false, true, false, false, true.
        let read: Vec<bool> = (0..5).map(|i| recent.was(i)).collect();
        assert_eq!(read, [false, true, false, false, true]);
        assert!(recent.any(2) && !recent.was(0), "either of the last two is not the one before the newest");
        assert!(!recent.was(40), "beyond what is kept");
        assert_eq!(recent.frames_put_back(), 2);
    }
}
