//! Turns the active [`Scene`] into entities, for the viewer and the headless renderer alike.
//!
//! Each scene layer is one entity ([`SceneLayer`], tagged [`LayerEntity`] with its index, carrying its
//! [`LayerStatus`] and visibility); what it draws (the plugins' glyph sets, splats, tubes, volumes, meshes) are
//! its children. A scene edit touches only the layers it changed, and for each only the stage it changed:
//! - visibility, opacity and draw settings update the existing entities and materials (a uniform write);
//! - a change of what a layer is (its source, slice, shape) starts a background job ([`LayerJob`]: a thread of
//!   its own, awaited on Bevy's async compute pool) that reads and fits through the [`DataCache`]; the old content stays until the new
//!   content swaps in, and the other layers are not touched;
//! - reordering moves the tags, nothing is rebuilt; a removed layer's entity goes with its content.
//!
//! A job that fails (a bad file, a wrong shape) leaves its message in the layer's status, listed in
//! [`LayerErrors`]; the other layers still show.

use std::collections::HashMap;
use std::sync::Arc;

use bevy::prelude::*;
use bevy::tasks::{Task, futures::check_ready};
use fascicle_render::layer::LayerStatus;
use fascicle_sh_glyphs::{PlacedShGlyphs, RayCastSettings, ShGlyphPlugin};
use fascicle_tensors::splat::{SplatSet, SplatSettings};
use fascicle_tensors::{PlacedSplats, PlacedTensorGlyphs, TensorGlyphPlugin, TensorGlyphSettings};
use fascicle_tracts::{PlacedTractStyle, PlacedTracts, TractPlugin, TractRoi};
use fascicle_views::slice::{set_opacity, unlit};
use fascicle_views::{
    ColourBar, ColourMap, LayerOrder, MainView, SliceLayer, SliceSettings, SliceSource, ViewSystems, Views,
    ViewsPlugin, VoxelGrid,
};
use fascicle_volume::{ScalarVolume, VolumeLayer, VolumePlugin, VolumeSet, VolumeSettings};

use crate::cache::DataCache;
use crate::jobs::{CANCELLED, Content, JobProgress, ValueHistogram, build, spawn_job, spawn_light_job};
use crate::model::{LayerKind, LayerSpec, MaskRoi, Scene, TractColouring};

/// What a spawned layer reports to the viewer's layer panel.
#[derive(Clone, Debug, Default)]
pub struct LayerData {
    /// Eigenvalues (largest first) of up to [`SCATTER_SAMPLES`] of the layer's tensor samples, evenly
    /// strided over all of them.
    pub eigenvalues: Arc<Vec<[f64; 3]>>,
    /// A volume layer's histogram over its transfer function's range.
    pub histogram: Arc<Vec<u32>>,
    /// A tract layer coloured by values per streamline or per point: how the values are distributed (all of
    /// them, those of streamlines a threshold or mask hides included).
    pub values: Option<Arc<ValueHistogram>>,
}

/// On a tract layer's entity coloured by values per streamline or per point: the values' histogram its last job
/// found.
#[derive(Component, Clone, Debug)]
pub struct TractValueHistogram(pub Arc<ValueHistogram>);

/// Per layer index, its [`LayerData`].
#[derive(Resource, Clone, Debug, Default)]
pub struct LayerDataMap(pub HashMap<usize, LayerData>);

/// Most samples a scattergram draws.
pub const SCATTER_SAMPLES: usize = 4000;

/// The scene being shown.
#[derive(Resource, Clone, Debug)]
pub struct ActiveScene(pub Scene);

/// Errors of the current scene's layers (`layer 'name': message`, in layer order), shown by the viewer and
/// returned by the headless renderer.
#[derive(Resource, Default, Debug)]
pub struct LayerErrors(pub Vec<String>);

/// Marks a layer entity and what it draws with the layer's index in the scene.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct LayerEntity(pub usize);

/// A scene layer's entity: the spec it shows now and the structure its content was built from.
#[derive(Component, Debug)]
#[require(LayerStatus, Transform, Visibility)]
pub struct SceneLayer {
    spec: LayerSpec,
    /// The structure of the content it holds.
    built: Option<LayerKind>,
    /// The structure of the last job started for it (failed, cancelled, running or done): an unrelated edit
    /// does not start it again; the panel's retry does.
    tried: Option<LayerKind>,
}

impl SceneLayer {
    /// The spec it was last synced to.
    pub fn spec(&self) -> &LayerSpec {
        &self.spec
    }
}

/// A layer's content being built in the background.
#[derive(Component)]
pub struct LayerJob {
    /// Its stage, progress, cancel flag and delivered parts, shared with the running job.
    pub progress: Arc<JobProgress>,
    structure: LayerKind,
    task: Task<Result<Content, String>>,
    /// Parts of its content shown so far (`stream_parts`): the layer's old content is gone.
    pub parts_shown: usize,
}

/// Background tasks placing glyphs of neighbouring slices ([`crate::jobs::prefetch_neighbours`]) still
/// running.
#[derive(Resource, Default, Clone)]
pub struct Prefetches(pub Arc<std::sync::atomic::AtomicUsize>);

impl Prefetches {
    /// Number of prefetch tasks still running.
    pub fn running(&self) -> usize {
        self.0.load(std::sync::atomic::Ordering::Relaxed)
    }
}

/// Requests from the panels: rebuild these layers (after a failure or a cancel).
#[derive(Resource, Default, Debug)]
pub struct RetryLayers(pub Vec<usize>);

/// What layer syncing did since the app started: `jobs` builds started, `restyles` in-place updates of a
/// layer's settings, `reindexed` layers moved without a rebuild, `parts` parts of content shown as they came.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LayerSyncCounts {
    /// Background builds started.
    pub jobs: u64,
    /// Settings edits applied in place, to content that stays.
    pub restyles: u64,
    /// Layers moved to another index without a rebuild.
    pub reindexed: u64,
    /// Parts of content shown while their jobs ran ([`crate::jobs::Parts`]).
    pub parts: u64,
}

/// Settings edits of layers whose content stays, for [`restyle_layers`]: (index, before, after).
#[derive(Resource, Default)]
struct Restyles(Vec<(usize, LayerSpec, LayerSpec)>);

/// Ordering of the scene systems within `Update`.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum SceneSystems {
    /// Match layers to entities, start jobs, apply settings edits.
    Sync,
    /// Swap in finished jobs' content.
    Finish,
}

/// Shows the [`ActiveScene`]: adds the render plugins and the views, the layer resources ([`DataCache`],
/// [`LayerErrors`], ...) and the [`SceneSystems`] that sync layers to entities.
pub struct ScenePlugin;

impl Plugin for ScenePlugin {
    fn build(&self, app: &mut App) {
        if !app.is_plugin_added::<ShGlyphPlugin>() {
            app.add_plugins(ShGlyphPlugin);
        }
        if !app.is_plugin_added::<TensorGlyphPlugin>() {
            app.add_plugins(TensorGlyphPlugin);
        }
        if !app.is_plugin_added::<VolumePlugin>() {
            app.add_plugins(VolumePlugin);
        }
        if !app.is_plugin_added::<TractPlugin>() {
            app.add_plugins(TractPlugin);
        }
        // Meshes over 4 MiB (the parts of a large tract layer) get buffers of their own: in Bevy's shared
        // slabs each part would grow the slab by half and copy all of it (on a 1M-streamline layer, frames of
        // 40 to 250 ms as the parts arrived, growing with what was already shown).
        if let Some(render) = app.get_sub_app_mut(bevy::render::RenderApp)
            && let Some(mut s) =
                render.world_mut().get_resource_mut::<bevy::render::mesh::allocator::MeshAllocatorSettings>()
        {
            s.large_threshold = s.large_threshold.min(4 << 20);
        }
        if !app.is_plugin_added::<ViewsPlugin>() {
            app.add_plugins(ViewsPlugin);
        }
        app.init_resource::<LayerErrors>()
            .init_resource::<DataCache>()
            .init_resource::<RetryLayers>()
            .init_resource::<Prefetches>()
            .init_resource::<Restyles>()
            .init_resource::<LayerSyncCounts>()
            .init_resource::<LayerDataMap>()
            .configure_sets(Update, (SceneSystems::Sync, SceneSystems::Finish, ViewSystems).chain())
            .add_systems(
                Update,
                (
                    (follow_crosshair, sync_layers.run_if(scene_or_retries_changed), restyle_layers, sync_views)
                        .chain()
                        .in_set(SceneSystems::Sync),
                    (
                        stream_parts,
                        finish_jobs,
                        request_masks,
                        finish_mask_jobs,
                        mark_layers,
                        report_errors,
                        report_layer_data,
                    )
                        .chain()
                        .in_set(SceneSystems::Finish),
                ),
            );
    }

    // Lights are clustered on the CPU: no Fascicle layer is lit by Bevy's clustered lights (each material shades
    // itself, the slices are unlit), and Bevy's GPU clustering runs its compute and raster passes every frame
    // for each 3D camera, lights or none (on lavapipe 2-4 ms of a frame of the empty viewer). Set after Bevy's
    // renderer chose it (`PbrPlugin::finish`, which runs first).
    fn finish(&self, app: &mut App) {
        if let Some(mut clusters) = app.world_mut().get_resource_mut::<bevy::light::cluster::GlobalClusterSettings>() {
            clusters.gpu_clustering = None;
        }
    }
}

fn scene_or_retries_changed(scene: Option<Res<ActiveScene>>, retries: Res<RetryLayers>) -> bool {
    scene.is_some_and(|s| s.is_changed()) || !retries.0.is_empty()
}

/// Runs `app` until no layer is loading (every job done and swapped in), as the headless renderer does before
/// a capture.
pub fn settle(app: &mut App) -> Result<(), String> {
    use fascicle_render::headless;
    headless::initialise(app).and_then(|()| headless::wait_for_layers(app)).map_err(|e| e.to_string())
}

/// A tract layer's include and exclude masks being read ([`crate::jobs::mask_regions`]), on an entity of its
/// own, `Loading` while it runs (a headless capture waits for it); the layer keeps the masks it had until
/// these are read.
#[derive(Component)]
struct MaskJob {
    layer: Entity,
    task: Task<Result<fascicle_tracts::TractMasks, String>>,
}

/// The include and exclude masks last asked for, on a tract layer's entity.
#[derive(Component)]
struct MasksAsked(Vec<MaskRoi>);

/// Reads a tract layer's include and exclude masks in the background when they change (the layer is not
/// rebuilt: the tract plugin re-selects when [`fascicle_tracts::TractMasks`] arrive). Until a layer's first
/// masks are read it shows nothing; after an edit it shows the masks it had until the new ones are read. Only
/// layers whose spec changed are looked at.
#[allow(clippy::type_complexity, reason = "a Bevy system's query")]
fn request_masks(
    mut commands: Commands,
    cache: Res<DataCache>,
    layers: Query<(Entity, &SceneLayer, Option<&MasksAsked>, Has<fascicle_tracts::TractMasks>), Changed<SceneLayer>>,
    jobs: Query<(Entity, &MaskJob)>,
) {
    for (e, layer, asked, has_masks) in &layers {
        let want: Vec<&MaskRoi> = match &layer.spec.kind {
            LayerKind::Tracts { masks, .. } => masks.iter().filter(|m| !m.crop).collect(),
            _ => vec![],
        };
        if asked.map_or(want.is_empty(), |a| a.0.iter().eq(want.iter().copied())) {
            continue;
        }
        // A read of older masks is dropped.
        for (j, _) in jobs.iter().filter(|(_, job)| job.layer == e) {
            commands.entity(j).despawn();
        }
        if want.is_empty() {
            commands.entity(e).remove::<(MasksAsked, fascicle_tracts::TractMasks)>();
            continue;
        }
        if !has_masks {
            commands.entity(e).insert(fascicle_tracts::TractMasks { waiting: true, ..default() });
        }
        let want: Vec<MaskRoi> = want.into_iter().cloned().collect();
        let (cache, masks) = (cache.clone(), want.clone());
        let task = spawn_light_job(move || crate::jobs::mask_regions(&cache, &masks));
        commands.spawn((MaskJob { layer: e, task }, LayerStatus::Loading));
        commands.entity(e).insert(MasksAsked(want));
    }
}

/// On a tract layer whose masks could not be read: its status before (put back once they are read, if it
/// was drawn).
#[derive(Component)]
struct MaskFailure(Option<LayerStatus>);

/// Gives each tract layer the masks its finished read found; a read that failed (an image missing, unreadable
/// or empty) leaves the layer showing nothing, failed with the message, until masks are read again.
fn finish_mask_jobs(
    mut commands: Commands,
    mut jobs: Query<(Entity, &mut MaskJob)>,
    layers: Query<(Option<&LayerStatus>, Option<&MaskFailure>)>,
) {
    for (j, mut job) in &mut jobs {
        let Some(result) = check_ready(&mut job.task) else { continue };
        commands.entity(j).despawn();
        let (Ok((status, failure)), Ok(mut layer)) = (layers.get(job.layer), commands.get_entity(job.layer)) else {
            continue;
        };
        match (result, failure) {
            (Ok(masks), Some(MaskFailure(before))) => {
                layer.try_insert(masks).try_remove::<MaskFailure>();
                // Still failed by its masks (a rebuild since has a status of its own): drawn as before.
                if let (Some(LayerStatus::Failed(_)), Some(before @ LayerStatus::Ready { .. })) = (status, before) {
                    layer.try_insert(before.clone());
                }
            }
            (Ok(masks), None) => {
                layer.try_insert(masks);
            }
            (Err(message), _) => {
                let before = failure.map_or_else(|| status.cloned(), |f| f.0.clone());
                let waiting = fascicle_tracts::TractMasks { waiting: true, ..default() };
                layer.try_insert((waiting, LayerStatus::Failed(message), MaskFailure(before)));
            }
        }
    }
}

/// A rule matching scene layer `i` to an entity at index `j` showing structure `s`.
type Claim<'a> = &'a dyn Fn(usize, usize, &LayerKind) -> bool;

/// Matches the scene's layers to the layer entities: the same structure at the same index first, then the
/// same structure anywhere (a reorder), then the same index (a rebuild); what is left is spawned or despawned.
fn sync_layers(
    mut commands: Commands,
    scene: Res<ActiveScene>,
    cache: Res<DataCache>,
    mut retries: ResMut<RetryLayers>,
    mut restyles: ResMut<Restyles>,
    mut counts: ResMut<LayerSyncCounts>,
    mut layers: Query<(Entity, &mut LayerEntity, Option<&mut SceneLayer>, Option<&LayerJob>)>,
) {
    let retry = std::mem::take(&mut retries.0);
    let specs = &scene.0.layers;
    let existing: Vec<(Entity, usize, LayerKind)> =
        layers.iter().filter_map(|(e, le, layer, _)| layer.map(|l| (e, le.0, l.spec.kind.structure()))).collect();
    let structures: Vec<LayerKind> = specs.iter().map(|s| s.kind.structure()).collect();
    let mut claimed: Vec<Option<(Entity, usize)>> = vec![None; specs.len()];
    let mut taken = std::collections::HashSet::new();
    let passes: [Claim; 3] =
        [&|i, j, s| i == j && *s == structures[i], &|i, _, s| *s == structures[i], &|i, j, _| i == j];
    for pass in passes {
        for i in 0..specs.len() {
            if claimed[i].is_some() {
                continue;
            }
            if let Some((e, j, _)) = existing.iter().find(|(e, j, s)| !taken.contains(e) && pass(i, *j, s)) {
                claimed[i] = Some((*e, *j));
                taken.insert(*e);
            }
        }
    }
    for (e, _, _) in &existing {
        if !taken.contains(e) {
            commands.entity(*e).despawn();
        }
    }
    // Indices that moved: the layer entity, its content and its ROIs carry the new one.
    let moved: std::collections::HashMap<usize, usize> =
        claimed.iter().enumerate().filter_map(|(i, c)| c.filter(|(_, j)| *j != i).map(|(_, j)| (j, i))).collect();
    if !moved.is_empty() {
        let leaving: std::collections::HashSet<Entity> =
            existing.iter().map(|(e, _, _)| *e).filter(|e| !taken.contains(e)).collect();
        for (e, mut le, _, _) in &mut layers {
            if let Some(&i) = moved.get(&le.0)
                && !leaving.contains(&e)
            {
                le.0 = i;
            }
        }
        counts.reindexed += moved.len() as u64;
    }
    restyles.0.clear();
    for (i, spec) in specs.iter().enumerate() {
        let visibility = if spec.visible { Visibility::Inherited } else { Visibility::Hidden };
        let Some((e, _)) = claimed[i] else {
            let e = commands
                .spawn((
                    SceneLayer { spec: spec.clone(), built: None, tried: Some(structures[i].clone()) },
                    LayerEntity(i),
                    visibility,
                ))
                .id();
            start_job(&mut commands, e, structures[i].clone(), &cache, &mut counts);
            continue;
        };
        let Ok((_, _, Some(mut layer), job)) = layers.get_mut(e) else { continue };
        if layer.tried.as_ref() != Some(&structures[i]) || retry.contains(&i) {
            if let Some(j) = job {
                j.progress.cancel();
            }
            start_job(&mut commands, e, structures[i].clone(), &cache, &mut counts);
            layer.tried = Some(structures[i].clone());
        } else if layer.spec != *spec && layer.built.as_ref() == Some(&structures[i]) {
            restyles.0.push((i, layer.spec.clone(), spec.clone()));
            counts.restyles += 1;
        }
        if layer.spec.visible != spec.visible {
            commands.entity(e).insert(visibility);
        }
        if layer.spec != *spec {
            layer.spec = spec.clone();
        }
    }
}

fn start_job(
    commands: &mut Commands,
    layer: Entity,
    structure: LayerKind,
    cache: &DataCache,
    counts: &mut LayerSyncCounts,
) {
    let progress = Arc::new(JobProgress::default());
    let (p, c, kind) = (progress.clone(), cache.clone(), structure.clone());
    let job = move || build(&kind, &c, &p);
    // The axes are made at once, not after the jobs holding the jobs' threads (a whole-brain read).
    let task = if matches!(structure, LayerKind::Axes { .. }) { spawn_light_job(job) } else { spawn_job(job) };
    if let Some(segments) = expected_line_segments(&structure) {
        commands.entity(layer).insert(fascicle_tracts::ExpectedLineSegments(segments));
    }
    commands.entity(layer).insert((LayerJob { progress, structure, task, parts_shown: 0 }, LayerStatus::Loading));
    counts.jobs += 1;
}

/// The line segments a tractogram layer will draw, estimated from its file's size before it is read (about 12
/// bytes a point; at whole-brain detail about one segment is kept per eight points: 13M of 104M), so that the
/// cameras drop MSAA for it before its first part ([`fascicle_tracts::ExpectedLineSegments`]). None for other
/// layers and unreadable files (the job reports those).
fn expected_line_segments(kind: &LayerKind) -> Option<usize> {
    let LayerKind::Tractogram { path } = kind else { return None };
    let bytes = std::fs::metadata(path).ok()?.len();
    Some((bytes / 12 / 8) as usize)
}

/// Shows the parts that running jobs delivered ([`crate::jobs::Parts`]: streamlines as they are tracked, a
/// large tractogram part by part): each frame takes what arrived, for up to [`PART_BUDGET`] of the main thread
/// (at least one part). Parts arrive as fast as the job builds them, so a quick frame uploads about one; a slow
/// frame (a dense scene on a software rasteriser) takes all that arrived while it drew, and a file loads in a
/// few frames, not one frame per part with every frame drawing all so far. The first part of a job replaces
/// the layer's old content. With a frame budget, a frame that takes a part counts as an interaction (the scene
/// changed): while parts arrive the 3D view draws at the scale the budget affords, and the full-quality frame
/// comes once they stop, not once per part (30 s a part for the large bench scene on lavapipe).
fn stream_parts(
    mut commands: Commands,
    mut layers: Query<(Entity, &LayerEntity, &SceneLayer, &mut LayerJob)>,
    mut counts: ResMut<LayerSyncCounts>,
    mut upload: Uploads,
    interacting: Option<ResMut<fascicle_render::budget::Interacting>>,
) {
    let before = counts.parts;
    for (e, le, layer, mut job) in &mut layers {
        if job.progress.is_cancelled() {
            continue;
        }
        // The parts waiting, up to a few milliseconds of this frame: a slow frame (a dense scene on a software
        // rasteriser) takes all that arrived while it drew, so loading needs fewer frames, not one per part.
        let start = std::time::Instant::now();
        while start.elapsed() < PART_BUDGET
            && let Some(part) = job.progress.parts.pop()
        {
            if job.parts_shown == 0 {
                clear_content(&mut commands, e, le.0, &layer.spec);
            }
            job.parts_shown += 1;
            counts.parts += 1;
            if let Err(message) = upload.spawn(&mut commands, e, le.0, &layer.spec, part) {
                commands.entity(e).insert(LayerStatus::Failed(message));
                break;
            }
        }
    }
    if counts.parts != before
        && let Some(mut interacting) = interacting
    {
        interacting.mark();
    }
}

/// The main thread's time a frame spends taking a layer's delivered parts (at least one part a frame).
const PART_BUDGET: std::time::Duration = std::time::Duration::from_millis(8);

/// Removes what layer `e` shows and, for a tract layer, gives it its ROIs again (children of the layer: they
/// act on all its tract sets).
fn clear_content(commands: &mut Commands, e: Entity, index: usize, spec: &LayerSpec) {
    // A slice layer's image goes with it (new slice content brings its own).
    commands.entity(e).despawn_related::<Children>().remove::<(SliceLayer, VolumeLayer)>();
    if let LayerKind::Tracts { rois, ends_only, deleted, .. } = &spec.kind {
        commands.entity(e).insert((
            fascicle_tracts::RoiRules { ends_only: *ends_only },
            fascicle_tracts::DeletedStreamlines(Arc::new(deleted.clone())),
        ));
        spawn_rois(commands, rois, index, e);
    }
}

/// Swaps finished jobs' content in: the layer's old content goes, the new is uploaded with the layer's current
/// settings. A cancelled job's layer shows that it was cancelled and keeps nothing.
fn finish_jobs(
    mut commands: Commands,
    cache: Res<DataCache>,
    prefetch: Res<Prefetches>,
    mut layers: Query<(Entity, &LayerEntity, &mut SceneLayer, &mut LayerJob)>,
    mut upload: Uploads,
) {
    for (e, le, mut layer, mut job) in &mut layers {
        let result = if job.progress.is_cancelled() {
            Err(CANCELLED.to_string())
        } else {
            // A finished job has delivered all its parts: it ends when they are all shown.
            if !job.task.is_finished() || !job.progress.parts.is_empty() {
                continue;
            }
            match check_ready(&mut job.task) {
                Some(r) => r,
                None => continue,
            }
        };
        commands.entity(e).remove::<(LayerJob, fascicle_tracts::ExpectedLineSegments)>();
        // The grid of the new content, or none (a rebuilt layer of another kind keeps no stale grid).
        match job.progress.grid() {
            Some(grid) => commands.entity(e).insert(grid),
            None => commands.entity(e).remove::<VoxelGrid>(),
        };
        match job.progress.values() {
            Some(values) => commands.entity(e).insert(TractValueHistogram(values)),
            None => commands.entity(e).remove::<TractValueHistogram>(),
        };
        // Streamed content is in place already (its first part cleared the old); anything else replaces it.
        if !matches!(result, Ok(Content::Streamed { .. })) || job.parts_shown == 0 {
            clear_content(&mut commands, e, le.0, &layer.spec);
        }
        // The layer's status: ready with the content's items, unless the plugin whose data component the content
        // went into keeps the layer entity's status itself (slices, volumes).
        let status = match result.and_then(|content| {
            let items = content.items();
            match content {
                Content::Streamed { .. } => Ok(Some(items)),
                content => upload.spawn(&mut commands, e, le.0, &layer.spec, content).map(|ours| ours.then_some(items)),
            }
        }) {
            Ok(items) => {
                layer.built = Some(job.structure.clone());
                crate::jobs::prefetch_neighbours(&job.structure, &cache, &prefetch.0);
                items.map(|items| LayerStatus::Ready { items })
            }
            Err(message) => {
                layer.built = None;
                Some(LayerStatus::Failed(message))
            }
        };
        if let Some(status) = status {
            commands.entity(e).insert(status);
        }
    }
}

/// The asset stores a layer's content is uploaded into.
#[derive(bevy::ecs::system::SystemParam)]
struct Uploads<'w> {
    meshes: ResMut<'w, Assets<Mesh>>,
    materials: ResMut<'w, Assets<StandardMaterial>>,
    volumes: ResMut<'w, Assets<ScalarVolume>>,
}

impl Uploads<'_> {
    /// Uploads `content` as children of `layer` (or as a plugin's data component on it), drawn with `spec`'s
    /// settings. Ok(true): the layer's `LayerStatus` is the caller's to set; Ok(false): the plugin keeps it.
    fn spawn(
        &mut self,
        commands: &mut Commands,
        layer: Entity,
        index: usize,
        spec: &LayerSpec,
        content: Content,
    ) -> Result<bool, String> {
        let (c, m) = (&mut *commands, &mut *self.meshes);
        let root = match (content, &spec.kind) {
            // Glyphs and splats placed by the job: a child entity per part with the plugin's data component and
            // the layer's settings component; the plugin uploads and restyles them.
            (Content::ShGlyphs(glyphs, voxels), LayerKind::ShGlyphs { render, .. }) => {
                let data = PlacedShGlyphs { glyphs, voxels: Some(voxels) };
                c.spawn((data, *render)).id()
            }
            (Content::TensorGlyphs { glyphs, voxels }, LayerKind::TensorGlyphs { render, .. }) => {
                let data = PlacedTensorGlyphs { glyphs: Arc::new(glyphs), voxels: Some(Arc::new(voxels)) };
                c.spawn((data, *render)).id()
            }
            (Content::Splats(splats), LayerKind::TensorSplats { render, .. }) => {
                c.spawn((PlacedSplats { splats: Arc::new(splats) }, *render)).id()
            }
            (Content::Tracts(prepared), LayerKind::Tracts { .. } | LayerKind::Tractogram { .. }) => {
                // The job built the geometry from the layer's structure (scale, colour); the per-pixel knobs and
                // the opacity are the layer's settings, the tract plugin's to apply.
                c.spawn((PlacedTracts(Some(prepared)), tract_style(spec))).id()
            }
            (Content::Volume { volume }, LayerKind::Volume { render, .. }) => {
                // A volume layer of the volume plugin: it makes the texture and reacts to each setting.
                let handle = self.volumes.add(ScalarVolume(volume));
                c.entity(layer).insert((VolumeLayer { volume: handle }, render.clone()));
                return Ok(false);
            }
            (Content::Slice { volume, channels, auto_window }, LayerKind::Slice { .. }) => {
                // A slice layer of the views plugin, with the window found by the job.
                let handle = self.volumes.add(ScalarVolume(volume.clone()));
                let source = SliceSource { asset: handle.id(), volume, channels, auto_window };
                let settings = SliceSettings { channels, ..slice_settings(spec) };
                c.entity(layer).insert((SliceLayer { volume: handle }, settings, source));
                return Ok(false);
            }
            (Content::Axes { length_mm: l }, _) => {
                let w = l / 40.0;
                let root = c.spawn((Transform::IDENTITY, Visibility::Inherited)).id();
                for (size, dir, colour) in [
                    (Vec3::new(l, w, w), Vec3::X, Color::linear_rgb(1.0, 0.1, 0.1)),
                    (Vec3::new(w, l, w), Vec3::Y, Color::linear_rgb(0.1, 1.0, 0.1)),
                    (Vec3::new(w, w, l), Vec3::Z, Color::linear_rgb(0.2, 0.3, 1.0)),
                ] {
                    let mut mat = unlit(spec.opacity);
                    mat.base_color = colour.with_alpha(spec.opacity);
                    c.spawn((
                        Mesh3d(m.add(Cuboid::from_size(size))),
                        MeshMaterial3d(self.materials.add(mat)),
                        Transform::from_translation(dir * l * 0.5),
                        LayerEntity(index),
                        ChildOf(root),
                    ));
                }
                root
            }
            _ => return Err("the layer's kind changed while it was built".into()),
        };
        c.entity(root).insert((LayerEntity(index), ChildOf(layer)));
        Ok(true)
    }
}

/// A tract layer's ROIs, as children of the layer's entity: they act on its tract sets only (every part of
/// its streamlines) and go when it goes.
fn spawn_rois(commands: &mut Commands, rois: &[fascicle_core::roi::Roi], index: usize, layer: Entity) {
    for r in rois {
        commands.spawn((TractRoi(*r), LayerEntity(index), ChildOf(layer)));
    }
}

/// The plugins' settings components of the layers' content, by layer index: what a settings edit writes.
#[derive(bevy::ecs::system::SystemParam)]
struct PluginSettings<'w, 's> {
    slices: Query<'w, 's, (&'static mut SliceSettings, &'static LayerEntity)>,
    volume_settings: Query<'w, 's, (&'static mut VolumeSettings, &'static LayerEntity)>,
    glyph_settings: Query<'w, 's, (&'static mut RayCastSettings, &'static LayerEntity)>,
    tensor_settings: Query<'w, 's, (&'static mut TensorGlyphSettings, &'static LayerEntity)>,
    splat_settings: Query<'w, 's, (&'static mut SplatSettings, &'static LayerEntity)>,
    tract_styles: Query<'w, 's, (&'static mut PlacedTractStyle, &'static LayerEntity)>,
}

/// A tract layer's style: its tubelets' knobs (a tractogram layer has the defaults) and its opacity.
fn tract_style(spec: &LayerSpec) -> PlacedTractStyle {
    let tubes = match &spec.kind {
        LayerKind::Tracts { render, .. } => *render,
        _ => default(),
    };
    PlacedTractStyle { tubes, opacity: spec.opacity.clamp(0.0, 1.0) }
}

/// Settings edits of layers whose content stays: uniform writes, style buffers, ROI entities, opacity.
#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters are its data dependencies")]
fn restyle_layers(
    mut commands: Commands,
    mut restyles: ResMut<Restyles>,
    rois: Query<(Entity, &LayerEntity), With<TractRoi>>,
    layer_entities: Query<(Entity, &LayerEntity), With<SceneLayer>>,
    parts: Query<(&MeshMaterial3d<StandardMaterial>, &LayerEntity)>,
    mut plugin: PluginSettings,
    mut upload: Uploads,
) {
    let Uploads { materials, .. } = &mut upload;
    for (i, before, after) in std::mem::take(&mut restyles.0) {
        match (&before.kind, &after.kind) {
            // The plugins apply a settings edit as it costs: a uniform write, the splats' style buffer.
            (LayerKind::ShGlyphs { render: a, .. }, LayerKind::ShGlyphs { render, .. }) if a != render => {
                for (mut settings, _) in plugin.glyph_settings.iter_mut().filter(|(_, le)| le.0 == i) {
                    settings.set_if_neq(*render);
                }
            }
            (LayerKind::TensorSplats { render: a, .. }, LayerKind::TensorSplats { render, .. }) if a != render => {
                for (mut settings, _) in plugin.splat_settings.iter_mut().filter(|(_, le)| le.0 == i) {
                    settings.set_if_neq(*render);
                }
            }
            (LayerKind::TensorGlyphs { render: a, .. }, LayerKind::TensorGlyphs { render, .. }) if a != render => {
                for (mut settings, _) in plugin.tensor_settings.iter_mut().filter(|(_, le)| le.0 == i) {
                    settings.set_if_neq(*render);
                }
            }
            (LayerKind::Volume { render: a, .. }, LayerKind::Volume { render, .. }) if a != render => {
                // The volume plugin writes what changed: the uniform, the tables or the proxy mesh.
                for (mut settings, _) in plugin.volume_settings.iter_mut().filter(|(_, le)| le.0 == i) {
                    settings.set_if_neq(render.clone());
                }
            }
            (LayerKind::Slice { .. }, LayerKind::Slice { .. }) => {
                // Axis, index, window, opacity: the views plugin cuts the slice again from the image in memory.
                for (mut settings, _) in plugin.slices.iter_mut().filter(|(_, le)| le.0 == i) {
                    let want = SliceSettings { channels: settings.channels, ..slice_settings(&after) };
                    settings.set_if_neq(want);
                }
            }
            (
                LayerKind::Tracts { rois: ra, ends_only: ea, deleted: da, .. },
                LayerKind::Tracts { rois: rb, ends_only: eb, deleted: db, .. },
            ) => {
                // The rule (tckedit's -ends_only) and the streamlines deleted by hand: the tract plugin
                // re-selects, nothing is rebuilt.
                if (ea != eb || da != db)
                    && let Some((layer, _)) = layer_entities.iter().find(|(_, le)| le.0 == i)
                {
                    commands.entity(layer).insert((
                        fascicle_tracts::RoiRules { ends_only: *eb },
                        fascicle_tracts::DeletedStreamlines(Arc::new(db.clone())),
                    ));
                }
                if ra != rb
                    && let Some((layer, _)) = layer_entities.iter().find(|(_, le)| le.0 == i)
                {
                    for (e, _) in rois.iter().filter(|(_, le)| le.0 == i) {
                        commands.entity(e).despawn();
                    }
                    spawn_rois(&mut commands, rb, i, layer);
                }
            }
            _ => {}
        }
        // A tract set's knobs and opacity: the tract plugin writes what changed.
        for (mut style, _) in plugin.tract_styles.iter_mut().filter(|(_, le)| le.0 == i) {
            style.set_if_neq(tract_style(&after));
        }
        if before.opacity != after.opacity {
            for (mat, _) in parts.iter().filter(|(_, le)| le.0 == i) {
                if let Some(mut m) = materials.get_mut(&mat.0) {
                    set_opacity(&mut m, after.opacity);
                }
            }
        }
    }
}

/// [`LayerErrors`] from the layers' statuses, when one changed.
fn report_errors(
    changed: Query<(), (Changed<LayerStatus>, With<SceneLayer>)>,
    mut removed: RemovedComponents<SceneLayer>,
    layers: Query<(&LayerEntity, &SceneLayer, &LayerStatus)>,
    mut errors: ResMut<LayerErrors>,
) {
    if changed.is_empty() && removed.read().next().is_none() {
        return;
    }
    let mut failed: Vec<(usize, String)> = layers
        .iter()
        .filter_map(|(le, l, s)| match s {
            LayerStatus::Failed(m) => Some((le.0, format!("layer '{}': {m}", l.spec.name))),
            _ => None,
        })
        .collect();
    failed.sort();
    errors.0 = failed.into_iter().map(|(_, m)| m).collect();
}

/// What refreshes the panels' layer data: content (re)spawned, a volume's histogram redone, a tract layer's
/// values read again.
type LayerDataMoved = Or<(Added<LayerEntity>, Added<SplatSet>, Changed<VolumeSet>, Changed<TractValueHistogram>)>;

/// Refreshes what spawned layers report to their panels when a layer's content was (re)spawned.
fn report_layer_data(
    added: Query<(), LayerDataMoved>,
    sets: Query<(&SplatSet, &ChildOf)>,
    volumes: Query<(&VolumeSet, &ChildOf)>,
    layers: Query<&LayerEntity>,
    values: Query<(&LayerEntity, &TractValueHistogram)>,
    mut removed_values: RemovedComponents<TractValueHistogram>,
    mut map: ResMut<LayerDataMap>,
) {
    // Read every frame, so a removal is seen once, in the frame it happened.
    let removed = removed_values.read().count() > 0;
    if added.is_empty() && !removed {
        return;
    }
    map.0.clear();
    // A splat set is the tensor plugin's child of the layer's placed-splats entity.
    for (set, parent) in &sets {
        let Ok(le) = layers.get(parent.parent()) else { continue };
        let stride = set.len().div_ceil(SCATTER_SAMPLES).max(1);
        let values = set.splats.iter().step_by(stride).map(|s| s.values).collect();
        map.0.insert(le.0, LayerData { eigenvalues: Arc::new(values), ..default() });
    }
    // A volume layer's set is the volume plugin's child of the layer entity.
    for (set, parent) in &volumes {
        if let Ok(le) = layers.get(parent.parent()) {
            map.0.insert(le.0, LayerData { histogram: set.histogram.clone(), ..default() });
        }
    }
    for (le, v) in &values {
        map.0.insert(le.0, LayerData { values: Some(v.0.clone()), ..default() });
    }
}

/// A slice layer's settings from its spec (channels: the first volume; the job knows the image's).
fn slice_settings(spec: &LayerSpec) -> SliceSettings {
    match &spec.kind {
        LayerKind::Slice { axis, index, window, .. } => {
            SliceSettings { axis: *axis, index: *index, window: *window, opacity: spec.opacity, ..default() }
        }
        _ => SliceSettings { opacity: spec.opacity, ..default() },
    }
}

/// The [`Views`] resource of the views plugin, from the scene's.
fn sync_views(scene: Res<ActiveScene>, mut views: ResMut<Views>) {
    if scene.is_changed() {
        views.set_if_neq(scene.0.views);
    }
}

/// What the views plugin reads from a layer entity: its [`LayerOrder`] (the layer's index), its [`Name`] (the
/// layer's, the label of its bar) and, for layers other than slices (whose bars the plugin makes), its
/// [`ColourBar`].
#[allow(clippy::type_complexity, reason = "a Bevy system's query")]
fn mark_layers(
    mut commands: Commands,
    layers: Query<
        (Entity, &LayerEntity, &SceneLayer, Option<&ColourBar>, Option<&Name>),
        Or<(Changed<LayerEntity>, Changed<SceneLayer>)>,
    >,
) {
    for (e, le, layer, bar, name) in &layers {
        let spec = layer.spec();
        let mut entity = commands.entity(e);
        entity.insert(LayerOrder(le.0 as u32));
        if name.is_none_or(|n| n.as_str() != spec.name) {
            entity.insert(Name::new(spec.name.clone()));
        }
        if matches!(spec.kind, LayerKind::Slice { .. }) {
            continue;
        }
        let want = colour_bar(spec);
        if want.as_ref() != bar {
            match want {
                Some(b) => entity.insert(b),
                None => entity.remove::<ColourBar>(),
            };
        }
    }
}

/// The colour bar of a colour-mapped layer other than a slice: a volume's transfer function over its range,
/// FA/GFA-coloured glyphs and splats and scalar-coloured tracts on viridis.
pub fn colour_bar(layer: &LayerSpec) -> Option<ColourBar> {
    use fascicle_core::dti::splat::SplatColourMode;
    let bar = |map, range: (f64, f64)| Some(ColourBar { label: layer.name.clone(), map, range });
    match &layer.kind {
        LayerKind::Volume { render, .. } => {
            let [lo, hi] = render.tf.range;
            bar(ColourMap::Transfer(Box::new(render.tf.clone())), (lo, hi))
        }
        LayerKind::ShGlyphs { render, .. } if render.colour == fascicle_sh_glyphs::GlyphColour::Gfa => {
            bar(ColourMap::Viridis, (0.0, 1.0))
        }
        LayerKind::TensorGlyphs { render, .. } if render.colour == fascicle_tensors::TensorColour::Fa => {
            bar(ColourMap::Viridis, (0.0, 1.0))
        }
        LayerKind::TensorSplats { render, .. } if render.colouring.mode == SplatColourMode::Fa => {
            bar(ColourMap::Viridis, (0.0, 1.0))
        }
        LayerKind::Tracts {
            colouring:
                TractColouring::Scalar { window: (lo, hi), .. }
                | TractColouring::Value { window: (lo, hi), .. }
                | TractColouring::PointValue { window: (lo, hi), .. },
            ..
        } => bar(ColourMap::Viridis, (f64::from(*lo), f64::from(*hi))),
        _ => None,
    }
}

/// With [`Views::follow`], moves the slice of every slice, glyph and tensor layer to the crosshair's voxel
/// (on the layer's own grid, along its own axis).
fn follow_crosshair(
    mut scene: ResMut<ActiveScene>,
    grids: Query<(&LayerEntity, &VoxelGrid)>,
    mut last: Local<Option<Vec3>>,
) {
    let views = scene.0.views;
    let Some(world) = views.crosshair.map(Vec3::from_array).filter(|_| views.follow) else {
        *last = None;
        return;
    };
    if *last == Some(world) {
        return;
    }
    *last = Some(world);
    let mut edited = scene.0.layers.clone();
    for (le, grid) in &grids {
        let Some(layer) = edited.get_mut(le.0) else { continue };
        let (axis, index) = match &mut layer.kind {
            LayerKind::Slice { axis, index, .. }
            | LayerKind::ShGlyphs { axis, index, plane: None, full_volume: false, .. }
            | LayerKind::TensorGlyphs { axis, index, .. }
            | LayerKind::TensorSplats { axis, index, .. } => (*axis, index),
            _ => continue,
        };
        let k = axis.index();
        if let Some(i) = grid.index_at(world, k) {
            *index = Some(i);
        }
    }
    if edited != scene.0.layers {
        scene.0.layers = edited;
    }
}

/// The clear colour of viewer and renderer.
pub const BACKGROUND: Color = Color::linear_rgb(0.02, 0.02, 0.025);

/// The near plane of the scene camera ([`camera_from_spec`]), world mm.
pub const NEAR: f32 = 0.5;

/// Camera components shared by viewer and headless renderer, so both produce the same image: no tone mapping
/// or dithering, and blending in a float target (rounded to 8 bits once, at the end).
pub fn view_camera() -> impl Bundle {
    (
        Camera3d::default(),
        Camera { clear_color: ClearColorConfig::Custom(BACKGROUND), ..default() },
        // A float (f16) target: slices, splats and glyph layers blend without 8-bit banding.
        fascicle_views::exact_output(),
        MainView,
    )
}

/// Camera transform and projection for a scene's camera spec.
pub fn camera_from_spec(spec: &crate::model::CameraSpec) -> (Transform, Projection) {
    let eye = Vec3::from_array(spec.eye);
    let tf = Transform::from_translation(eye).looking_at(Vec3::from_array(spec.target), Vec3::from_array(spec.up));
    let proj =
        Projection::Perspective(PerspectiveProjection { fov: spec.fov_y_deg.to_radians(), near: NEAR, ..default() });
    (tf, proj)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tractogram layer expects the segments its file's size suggests (12 bytes a point, one segment kept
    /// per eight points); other layers and missing files expect none.
    #[test]
    fn a_tractogram_layer_expects_segments_from_its_file_size() {
        let path = crate::repo_path("data/tracts/small_64D_dti.tck");
        let bytes = std::fs::metadata(&path).unwrap().len() as usize;
        assert_eq!(expected_line_segments(&LayerKind::Tractogram { path }), Some(bytes / 96));
        let missing = LayerKind::Tractogram { path: "/nonexistent/t.tck".into() };
        assert_eq!(expected_line_segments(&missing), None);
        assert_eq!(expected_line_segments(&LayerKind::Axes { length_mm: 30.0 }), None);
    }
}
