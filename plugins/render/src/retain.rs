//! A retained 3D picture: a camera marked [`RetainPicture`] keeps its last complete picture, and a frame in
//! which nothing the cameras show has changed puts the pictures back instead of drawing the scene again (all
//! retaining cameras or none: an overlay drawn over another camera stores that camera's picture too). In a
//! window drawn on demand every pointer move is a frame (egui needs it for hover); with a whole-brain scene
//! on a software adapter a full frame takes seconds, and a retained one a copy.
//!
//! - **Stored**: after the main pass of a full-scale frame (no [`crate::budget::RenderScale`] below 1), the
//!   camera's viewport is copied out of its main texture. The copy is complete when no pipeline was still
//!   compiling when the frame was drawn (an item whose pipeline is not ready is left out of that frame).
//! - **Unchanged** since the last frame, read at extraction from the main world's change ticks:
//!   - every component of every entity, except resources, windows, observers, screenshot and readback
//!     requests (they read the picture), cameras that do not retain, and what Bevy rebuilds every frame from
//!     what is scanned (`VisibleEntities`, `Clusters`, `PreviousViewData`, the lights' cascades, frusta and
//!     visible entities);
//!   - the archetypes' sizes (an entity despawned, a component removed);
//!   - the windows' sizes and scale factors (a window's component changes with every pointer move);
//!   - the resources registered with [`watch`] (by default `ClearColor` and [`crate::Unsettled`]) and the
//!     asset types registered with [`watch_asset`] (by default meshes, images but those in
//!     [`ImagesOutsidePicture`], standard materials and shader buffers); each Fascicle plugin registers its
//!     materials, data assets and settings resources;
//!   - the gizmos' vertices and line configs (immediate mode: rebuilt every frame, compared by content).
//! - **Put back**: in a frame where both hold, the cameras' prepass and main pass do not run (Bevy's
//!   `Core3dSystems::{Prepass, MainPass}`, where Fascicle's own passes run too), and each stored picture is
//!   blitted into its viewport (with MSAA, into the multisampled texture, which later cameras on the target
//!   load and resolve); post-processing and the cameras that do not retain run as usual.
//!
//! An app whose own resources or asset types change the 3D picture registers them with [`watch`] and
//! [`watch_asset`]; a change the plugin cannot see (a resource not registered) shows at the next change it
//! sees. The frame budget ([`crate::budget`]) does not measure frames that put a picture back.

use std::any::TypeId;
use std::hash::{Hash, Hasher};

use bevy::asset::AssetEvent;
use bevy::camera::visibility::VisibleEntities;
use bevy::core_pipeline::blit::{BlitPipeline, BlitPipelineKey};
use bevy::core_pipeline::{Core3dSystems, schedule::Core3d};
use bevy::ecs::change_detection::Tick;
use bevy::ecs::component::ComponentId;
use bevy::ecs::message::Messages;
use bevy::ecs::observer::Observer;
use bevy::ecs::resource::IsResource;
use bevy::gizmos::GizmoAsset;
use bevy::gizmos::retained::Gizmo;
use bevy::prelude::*;
use bevy::render::camera::ExtractedCamera;
use bevy::render::render_resource::{
    BindGroup, CachedRenderPipelineId, PipelineCache, SpecializedRenderPipelines, Texture, TextureFormat,
};
use bevy::render::renderer::{CurrentView, RenderContext, RenderDevice, ViewQuery};
use bevy::render::sync_world::RenderEntity;
use bevy::render::view::ViewTarget;
use bevy::render::{Extract, ExtractSchedule, MainWorld, Render, RenderApp, RenderSystems};

use crate::RecentlyRetained;
use crate::viewport::physical_viewport;

/// Adds the retained picture (see the module docs).
pub struct RetainedPicturePlugin;

/// Marks a 3D camera whose picture is kept and put back while nothing it shows changes.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct RetainPicture;

/// Whether a watched input changed between two ticks of the main world.
type ChangedSince = fn(&World, Tick, Tick) -> bool;

/// The resources and asset types whose changes change the 3D picture; see [`watch`] and [`watch_asset`].
#[derive(Resource, Default)]
struct PictureInputs(Vec<(TypeId, &'static str, ChangedSince)>);

impl PictureInputs {
    fn add<T: 'static>(&mut self, changed: ChangedSince) {
        if !self.0.iter().any(|(t, ..)| *t == TypeId::of::<T>()) {
            self.0.push((TypeId::of::<T>(), std::any::type_name::<T>(), changed));
        }
    }
}

/// Registers a resource whose changes change the 3D picture (its change ticks are read): a frame after it
/// changed draws the scene again. Any plugin may call it, before or after [`RetainedPicturePlugin`] is added.
pub fn watch<R: Resource>(app: &mut App) {
    app.world_mut().get_resource_or_init::<PictureInputs>().add::<R>(|world, last, now| {
        world.get_resource_ref::<R>().is_some_and(|r| r.last_changed().is_newer_than(last, now))
    });
}

/// Registers an asset type whose assets change the 3D picture (a material, mesh or data asset): a frame in
/// which one is added, modified or removed draws the scene again. Read from the frame's asset events, not the
/// `Assets` resource's change ticks, which any `get_mut` marks whether or not it writes.
pub fn watch_asset<A: Asset>(app: &mut App) {
    app.world_mut().get_resource_or_init::<PictureInputs>().add::<A>(|world, _, _| {
        world
            .get_resource::<Messages<AssetEvent<A>>>()
            .is_some_and(|m| m.iter_current_update_messages().next().is_some())
    });
}

/// Images the 3D picture does not show (a UI's textures, such as egui's font atlas, which egui writes as
/// text appears): their changes do not redraw the scene. An app keeps it up to date; empty by default.
#[derive(Resource, Default, Debug)]
pub struct ImagesOutsidePicture(pub bevy::platform::collections::HashSet<AssetId<Image>>);

/// Render world: what the last scan of the main world saw.
#[derive(Resource, Default)]
struct SceneScan {
    last: Option<Tick>,
    layout: u64,
    windows: u64,
    gizmos: u64,
    /// Nothing the 3D picture shows changed since the frame before.
    clean: bool,
}

/// Render world, on a retaining camera's view: this frame puts the stored picture back.
#[derive(Component)]
pub struct RetainedFrame;

/// Render world, on a retaining camera's view: the blit pipeline for its main texture, and the stored picture.
#[derive(Component)]
struct Retaining {
    pipeline: Option<CachedRenderPipelineId>,
}

/// Render world: a camera's stored picture (its viewport, in its main texture's format).
#[derive(Component)]
struct StoredPicture {
    texture: Texture,
    bind_group: BindGroup,
    size: UVec2,
    format: TextureFormat,
    /// Drawn with every pipeline ready, at full scale.
    complete: bool,
}

impl Plugin for RetainedPicturePlugin {
    fn build(&self, app: &mut App) {
        watch::<ClearColor>(app);
        watch_asset::<Mesh>(app);
        app.init_resource::<ImagesOutsidePicture>();
        app.world_mut().get_resource_or_init::<PictureInputs>().add::<Image>(|world, _, _| {
            let outside = world.get_resource::<ImagesOutsidePicture>();
            world.get_resource::<Messages<AssetEvent<Image>>>().is_some_and(|m| {
                m.iter_current_update_messages().any(|e| {
                    let id = match e {
                        AssetEvent::Added { id }
                        | AssetEvent::Modified { id }
                        | AssetEvent::Removed { id }
                        | AssetEvent::Unused { id }
                        | AssetEvent::LoadedWithDependencies { id } => id,
                    };
                    !outside.is_some_and(|o| o.0.contains(id))
                })
            })
        });
        watch_asset::<StandardMaterial>(app);
        watch_asset::<bevy::render::storage::ShaderBuffer>(app);
        watch::<crate::Unsettled>(app);
        let recent = RecentlyRetained::default();
        app.insert_resource(recent.clone());
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app
                .insert_resource(recent)
                .init_resource::<SceneScan>()
                .add_systems(ExtractSchedule, (scan_main_world, mark_retained_frames).chain())
                .add_systems(Render, prepare_retaining.in_set(RenderSystems::PrepareResources))
                .configure_sets(Core3d, (Core3dSystems::Prepass, Core3dSystems::MainPass).run_if(drawing_the_scene))
                .add_systems(
                    Core3d,
                    (store_picture, put_back_picture)
                        .after(Core3dSystems::MainPass)
                        .after(crate::budget::upscale)
                        .before(Core3dSystems::PostProcess)
                        .before(crate::OverlaySystems),
                );
        }
    }
}

/// A run condition for a camera's passes: false for a view that puts its stored picture back this frame.
pub fn drawing_the_scene(view: Option<Res<CurrentView>>, retained: Query<(), With<RetainedFrame>>) -> bool {
    view.is_none_or(|v| !retained.contains(v.entity()))
}

/// Component ids the scan treats specially.
struct ScanIds {
    resource: Option<ComponentId>,
    window: Option<ComponentId>,
    observer: Option<ComponentId>,
    capture: [Option<ComponentId>; 2],
    camera: Option<ComponentId>,
    retain: Option<ComponentId>,
    gizmo: Option<ComponentId>,
    ignored: Vec<ComponentId>,
}

impl ScanIds {
    fn of(world: &World) -> Self {
        Self {
            resource: world.component_id::<IsResource>(),
            window: world.component_id::<Window>(),
            observer: world.component_id::<Observer>(),
            capture: [
                world.component_id::<bevy::render::view::screenshot::Screenshot>(),
                world.component_id::<bevy::render::gpu_readback::Readback>(),
            ],
            camera: world.component_id::<Camera>(),
            retain: world.component_id::<RetainPicture>(),
            gizmo: world.component_id::<Gizmo>(),
            // Rebuilt every frame from what is scanned (the entities, the lights and the camera): a camera's
            // VisibleEntities, light Clusters and PreviousViewData, the lights' shadow cascades and frusta
            // and what they see; an immediate-mode gizmo's component
            // from its config (compared by content below, with its vertices).
            ignored: [
                world.component_id::<VisibleEntities>(),
                world.component_id::<bevy::light::cluster::Clusters>(),
                world.component_id::<bevy::core_pipeline::prepass::PreviousViewData>(),
                world.component_id::<bevy::light::Cascades>(),
                world.component_id::<bevy::camera::primitives::CascadesFrusta>(),
                world.component_id::<bevy::camera::primitives::CubemapFrusta>(),
                world.component_id::<bevy::camera::visibility::CascadesVisibleEntities>(),
                world.component_id::<bevy::camera::visibility::CubemapVisibleEntities>(),
                world.component_id::<bevy::camera::visibility::VisibleMeshEntities>(),
                world.component_id::<Gizmo>(),
            ]
            .into_iter()
            .flatten()
            .collect(),
        }
    }
}

/// Reads what changed in the main world since the last extraction (see the module docs).
fn scan_main_world(main: Res<MainWorld>, mut scan: ResMut<SceneScan>, inputs: Extract<Option<Res<PictureInputs>>>) {
    let world: &World = &main;
    let now = world.read_change_tick();
    let last = scan.last.replace(now);
    let ids = ScanIds::of(world);
    let has = |arch: &bevy::ecs::archetype::Archetype, id: Option<ComponentId>| id.is_some_and(|c| arch.contains(c));
    let mut layout = std::collections::hash_map::DefaultHasher::new();
    let mut windows = std::collections::hash_map::DefaultHasher::new();
    let mut changed: Option<(ComponentId, Entity)> = None;
    let mut gizmos = std::collections::hash_map::DefaultHasher::new();
    for arch in world.archetypes().iter() {
        if arch.is_empty()
            || has(arch, ids.resource)
            || has(arch, ids.observer)
            || ids.capture.iter().any(|&c| has(arch, c))
        {
            continue;
        }
        if has(arch, ids.window) {
            for e in arch.entities() {
                if let Some(w) = world.entity(e.id()).get::<Window>() {
                    (w.resolution.physical_width(), w.resolution.physical_height()).hash(&mut windows);
                    w.resolution.scale_factor().to_bits().hash(&mut windows);
                }
            }
            continue;
        }
        if has(arch, ids.camera) && !has(arch, ids.retain) {
            continue;
        }
        (arch.id().index(), arch.len()).hash(&mut layout);
        if has(arch, ids.gizmo) {
            for e in arch.entities() {
                if let Some(g) = world.entity(e.id()).get::<Gizmo>() {
                    format!("{:?} {:?} {}", g.handle.id(), g.line_config, g.depth_bias).hash(&mut gizmos);
                }
            }
        }
        let Some(last) = last else { continue };
        if changed.is_some() {
            continue;
        }
        'components: for &c in arch.components() {
            if ids.ignored.contains(&c) {
                continue;
            }
            for e in arch.entities() {
                if world.entity(e.id()).get_change_ticks_by_id(c).is_some_and(|t| t.is_changed(last, now)) {
                    changed = Some((c, e.id()));
                    break 'components;
                }
            }
        }
    }
    let resource_changed = last.is_some_and(|last| {
        inputs.as_ref().is_some_and(|inputs| inputs.0.iter().any(|(.., changed)| changed(world, last, now)))
    });
    if let Some(assets) = world.get_resource::<Assets<GizmoAsset>>() {
        for (id, gizmo) in assets.iter() {
            id.hash(&mut gizmos);
            let buffer = gizmo.buffer();
            for v in buffer.list_positions.iter().chain(&buffer.strip_positions) {
                v.to_array().map(f32::to_bits).hash(&mut gizmos);
            }
            for c in buffer.list_colors.iter().chain(&buffer.strip_colors) {
                c.to_f32_array().map(f32::to_bits).hash(&mut gizmos);
            }
        }
    }
    let (layout, windows, gizmos) = (layout.finish(), windows.finish(), gizmos.finish());
    if let Some((c, e)) = changed
        && bevy::log::tracing::enabled!(bevy::log::Level::TRACE)
    {
        let all: Vec<String> = world
            .entity(e)
            .archetype()
            .components()
            .iter()
            .map(|&c| format!("{}:{}", c.index(), known_name(world, c)))
            .collect();
        let name = (world.entity(e).get::<Name>().map(|n| n.as_str().to_owned()), all);
        trace!("retained picture: component {c:?} ({}) of {e:?} ({name:?}) changed", known_name(world, c));
    }
    if let (Some(last), Some(inputs)) = (last, inputs.as_ref())
        && bevy::log::tracing::enabled!(bevy::log::Level::TRACE)
    {
        for (_, name, changed) in &inputs.0 {
            if changed(world, last, now) {
                trace!("retained picture: {name} changed");
            }
        }
    }
    scan.clean = last.is_some()
        && changed.is_none()
        && !resource_changed
        && layout == scan.layout
        && windows == scan.windows
        && gizmos == scan.gizmos;
    trace!(
        "retained picture: clean {} (component {changed:?}, resource {resource_changed}, layout {}, windows {}, gizmos {})",
        scan.clean,
        layout != scan.layout,
        windows != scan.windows,
        gizmos != scan.gizmos
    );
    (scan.layout, scan.windows, scan.gizmos) = (layout, windows, gizmos);
}

/// Marks the views that put their stored picture back this frame: the scene is unchanged, no pipeline is
/// compiling, and every active retaining camera draws at full scale and has a complete stored picture of its
/// viewport's size.
#[allow(clippy::type_complexity, reason = "a Bevy system's query")]
fn mark_retained_frames(
    mut commands: Commands,
    cameras: Extract<Query<(RenderEntity, &Camera, Option<&crate::budget::RenderScale>), With<RetainPicture>>>,
    scan: Res<SceneScan>,
    stored: Query<&StoredPicture>,
    cache: Res<PipelineCache>,
    recent: Res<RecentlyRetained>,
) {
    let compiling = cache.waiting_pipelines().next().is_some();
    // All or none: a camera drawn over an earlier one on the same target (an overlay that does not clear)
    // stores that one's picture under its own, so one camera drawing means all do.
    let retained = scan.clean
        && !compiling
        && cameras.iter().all(|(entity, camera, scale)| {
            !camera.is_active
                || (scale.is_none_or(|s| s.0 >= 1.0)
                    && stored.get(entity).is_ok_and(|s| s.complete && Some(s.size) == camera.physical_viewport_size()))
        });
    let any = retained && cameras.iter().any(|(_, camera, _)| camera.is_active);
    for (entity, ..) in &cameras {
        let mut view = commands.entity(entity);
        if retained {
            view.insert(RetainedFrame);
        } else {
            view.remove::<RetainedFrame>();
        }
        view.insert(Retaining { pipeline: None });
    }
    recent.push(any);
}

/// Specialises the blit pipeline for each retaining view's main texture, and makes its stored picture's texture
/// (again when the viewport's size or the format changes).
#[allow(clippy::type_complexity, reason = "a Bevy system's query")]
fn prepare_retaining(
    mut commands: Commands,
    mut views: Query<(Entity, &ViewTarget, &ExtractedCamera, &Msaa, &mut Retaining, Option<&StoredPicture>)>,
    blit: Option<Res<BlitPipeline>>,
    mut pipelines: ResMut<SpecializedRenderPipelines<BlitPipeline>>,
    cache: Res<PipelineCache>,
    device: Res<RenderDevice>,
) {
    let Some(blit) = blit else { return };
    for (entity, target, camera, msaa, mut retaining, stored) in &mut views {
        let format = target.main_texture_format();
        // Drawn into the multisampled texture when there is one (resolved into the main texture): cameras
        // drawn later on the same target load that texture and resolve it over the main one again.
        let key =
            BlitPipelineKey { target_format: format, blend_state: None, samples: msaa.samples(), source_space: None };
        retaining.pipeline = Some(pipelines.specialize(&cache, &blit, key));
        let size = physical_viewport(camera).physical_size;
        if size.x == 0 || size.y == 0 || stored.is_some_and(|s| s.size == size && s.format == format) {
            continue;
        }
        let texture =
            device.create_texture(&crate::viewport::picture_texture("fascicle_retained_picture", size, format));
        let view = texture.create_view(&default());
        let bind_group = blit.create_bind_group(&device, &view, &cache);
        commands.entity(entity).insert(StoredPicture { texture, bind_group, size, format, complete: false });
    }
}

/// After the main pass of a full-scale frame, copies the camera's viewport out of the main texture; the copy
/// is complete when no pipeline was waiting as the frame was drawn (the pipeline cache processes its queue
/// right before the render graph runs).
#[allow(clippy::type_complexity, reason = "a Bevy system's query")]
fn store_picture(
    view: ViewQuery<
        (Entity, &ViewTarget, &ExtractedCamera),
        (With<Retaining>, Without<RetainedFrame>, Without<crate::budget::ScaledMainPass>),
    >,
    mut stored: Query<&mut StoredPicture>,
    cache: Res<PipelineCache>,
    mut ctx: RenderContext,
) {
    let (entity, target, camera) = view.into_inner();
    let Ok(mut picture) = stored.get_mut(entity) else { return };
    let viewport = physical_viewport(camera);
    if picture.size != viewport.physical_size || picture.format != target.main_texture_format() {
        picture.complete = false;
        return;
    }
    picture.complete = cache.waiting_pipelines().next().is_none();
    crate::viewport::copy_out(&mut ctx, target, &viewport, picture.size, &picture.texture);
}

/// In a frame that draws no scene, puts the stored picture back into the camera's viewport, as the skipped
/// main pass would have drawn it: into the multisampled texture with MSAA (every sample the stored colour,
/// resolved into the main texture), cleared first when this camera is the target's first.
fn put_back_picture(
    view: ViewQuery<(Entity, &ViewTarget, &ExtractedCamera, &Retaining), With<RetainedFrame>>,
    stored: Query<&StoredPicture>,
    cache: Res<PipelineCache>,
    mut ctx: RenderContext,
) {
    let (entity, target, camera, retaining) = view.into_inner();
    let (Ok(picture), Some(pipeline)) =
        (stored.get(entity), retaining.pipeline.and_then(|p| cache.get_render_pipeline(p)))
    else {
        return;
    };
    let viewport = physical_viewport(camera);
    let attachment = target.get_color_attachment();
    crate::viewport::blit_over(
        &mut ctx,
        "fascicle_retained_picture",
        attachment,
        &viewport,
        pipeline,
        &picture.bind_group,
    );
}

/// A name for a component id, for trace logs (Bevy keeps type names only with its `debug` feature).
fn known_name(world: &World, c: ComponentId) -> String {
    let reflected = world.components().get_info(c).and_then(|i| i.type_id()).and_then(|t| {
        let registry = world.get_resource::<AppTypeRegistry>()?;
        let registry = registry.read();
        registry.get(t).map(|r| r.type_info().type_path().to_owned())
    });
    if let Some(name) = reflected {
        return name;
    }
    macro_rules! names {
        ($($t:ty),*) => {
            $(if world.component_id::<$t>() == Some(c) { return stringify!($t).to_owned(); })*
        };
    }
    use bevy::camera::primitives::{Aabb, Frustum};
    names!(
        Transform,
        GlobalTransform,
        Visibility,
        InheritedVisibility,
        ViewVisibility,
        Aabb,
        Frustum,
        Camera,
        Projection,
        Mesh3d,
        MeshMaterial3d<StandardMaterial>,
        ChildOf,
        Children,
        crate::budget::RenderScale,
        Gizmo,
        bevy::light::PointLight,
        bevy::camera::visibility::NoFrustumCulling,
        bevy::camera::visibility::VisibilityClass,
        bevy::ecs::system::SystemIdMarker,
        bevy::render::sync_world::RenderEntity,
        bevy::render::sync_world::SyncToRenderWorld,
        Msaa,
        Camera3d,
        bevy::camera::Hdr,
        bevy::core_pipeline::tonemapping::Tonemapping,
        bevy::core_pipeline::tonemapping::DebandDither,
        bevy::camera::CameraMainTextureUsages,
        bevy::light::cluster::ClusterConfig,
        bevy::light::cluster::Clusters,
        bevy::render::view::ColorGrading,
        bevy::camera::Exposure,
        bevy::camera::visibility::VisibleEntities,
        RetainPicture,
        Name,
        crate::layer::LayerStatus,
        bevy::camera::visibility::RenderLayers,
        bevy::light::DirectionalLight
    );
    world.components().get_info(c).map_or("?".to_owned(), |i| format!("?{}b", i.layout().size()))
}
