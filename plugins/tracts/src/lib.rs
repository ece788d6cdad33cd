//! Fibre tracts as a Bevy plugin: hyperstreamlines (ray-cast tubelets with elliptical cross-sections from
//! the tensors, `shaders/tubelet.wgsl`, reference `fascicle_core::tubelet`), the polygon-tube baseline and
//! ROI selection.
//!
//! A tract set ([`TractSet`]: the streamlines, their segment grid and a selection-flag buffer) is one entity
//! and one draw, as hyperstreamlines ([`TubeSet`]: tubelets in one storage buffer, 8 vertices per tubelet
//! carrying (slot, corner), each bounding box built in the vertex shader) or as a mesh ([`MeshSet`]: lines or
//! polygon tubes). ROIs are entities ([`TractRoi`]): a child of a tract set acts on that set, an ROI without a
//! parent on every set. [`apply_rois`] re-evaluates the selection (parallel, over a uniform segment grid) only
//! when an ROI or a tract set changes, and rewrites the 4-byte-per-streamline flag buffer that both vertex
//! shaders (tubelet, tract mesh) read; nothing else is re-uploaded.

#![warn(missing_docs)]

use std::collections::HashMap;
use std::sync::{Arc, OnceLock};
use std::time::Instant;

use bevy::asset::RenderAssetUsages;
use bevy::camera::primitives::{Aabb, MeshAabb};
use bevy::camera::visibility::{NoAutoAabb, NoFrustumCulling, RenderLayers};
use bevy::mesh::{
    Indices, MeshVertexAttribute, MeshVertexBufferLayoutRef, PrimitiveTopology, VertexAttributeValues, VertexFormat,
};
use bevy::pbr::{MaterialPipeline, MaterialPipelineKey};
use bevy::prelude::*;
use bevy::render::render_resource::{AsBindGroup, RenderPipelineDescriptor, ShaderType, SpecializedMeshPipelineError};
use bevy::render::storage::ShaderBuffer;
use fascicle_core::compress::{Compression, kept_points};
use fascicle_core::io::mapped::MappedRun;
use fascicle_core::io::{Streamlines, Tractogram};
use fascicle_core::roi::{Criteria, MaskRegion, Region, Roi};
use fascicle_core::roi_index::{DragMargins, Kept, StreamlineCells};
pub use fascicle_core::tubelet::TubeMethod;
use fascicle_core::tubelet::{TubeColour, Tubelet, polygon_rings, tubelets};

pub mod layer;
pub mod placed;
pub mod selected;
pub mod shaders;

pub use fascicle_render::layer::LayerStatus;
use fascicle_render::meshes::{slot_boxes, slot_boxes_of};
pub use layer::{TractCounts, TractStyle, TractSystems, TractogramAsset, TractogramLoader, Tracts};
pub use placed::{PlacedTractStyle, PlacedTracts};
pub use selected::{
    FlagsBehind, PreviewLines, SELECTED_LINES_BELOW, SelectedLines, UNFLAGGED, make_selected_lines, narrow_previews,
    upload_flags_behind,
};

/// Drawing options of hyperstreamlines.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TubeSettings {
    /// Cross-section scale (mm): a semi-axis is `scale · l_k / l1` (at least 5 % of it).
    pub scale: f64,
    /// How tubelets are coloured (default [`TubeColour::Direction`]).
    pub colour: TubeColour,
    /// How a pixel's ray finds the surface: the bracketed tracer, or the seed's sphere tracing (the baseline).
    pub method: TubeMethod,
    /// Iteration cap of the per-pixel intersection.
    pub iterations: u32,
    /// Convergence tolerance, in units of the tubelet's largest radius.
    pub eps: f32,
    /// Ambient fraction of the headlight shading, 0..1: `base · (ambient + (1 - ambient) · n·v)` (default 0.3).
    pub ambient: f32,
    /// Weight of the white highlight `specular · (n·v)^shininess` added to the shading (default 0.25).
    pub specular: f32,
    /// Exponent of the highlight (default 24).
    pub shininess: f32,
}

impl Default for TubeSettings {
    fn default() -> Self {
        Self {
            scale: 4.0,
            colour: TubeColour::Direction,
            method: TubeMethod::Bracketed,
            iterations: 8,
            eps: 1e-3,
            ambient: 0.3,
            specular: 0.25,
            shininess: 24.0,
        }
    }
}

/// GPU parameters. Keep in sync with `TubeParams` in `shaders/tubelet.wgsl`.
#[derive(Clone, Copy, Debug, ShaderType)]
pub struct TubeUniform {
    /// [`TubeSettings::iterations`], at least 1.
    pub iterations: u32,
    /// [`TubeSettings::eps`]: convergence tolerance, in units of the tubelet's largest radius.
    pub eps: f32,
    /// [`TubeSettings::ambient`]: ambient fraction of the headlight shading.
    pub ambient: f32,
    /// [`TubeSettings::specular`]: weight of the highlight.
    pub specular: f32,
    /// [`TubeSettings::shininess`]: exponent of the highlight.
    pub shininess: f32,
    /// 0 bracketed, 1 sphere tracing.
    pub method: u32,
}

impl From<&TubeSettings> for TubeUniform {
    fn from(s: &TubeSettings) -> Self {
        Self {
            iterations: s.iterations.max(1),
            eps: s.eps,
            ambient: s.ambient,
            specular: s.specular,
            shininess: s.shininess,
            method: match s.method {
                TubeMethod::Bracketed => 0,
                TubeMethod::Sphere => 1,
            },
        }
    }
}

/// Drawing material of a hyperstreamline set ([`TubeSet`], `shaders/tubelet.wgsl`): on the [`slot_boxes`] proxy
/// mesh, each tubelet ray cast per pixel, writing its true depth.
#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
pub struct TubeletMaterial {
    /// The ray caster's settings (uniform binding 0).
    #[uniform(0)]
    pub params: TubeUniform,
    /// The tubelets as [`pack`] lays them out, seven `vec4<f32>` (112 bytes) each (storage binding 1).
    #[storage(1, read_only)]
    pub tubes: Handle<ShaderBuffer>,
    /// One bit per streamline, set when selected ([`selection_words`]; storage binding 2; the set's
    /// [`TractSet::selected`]).
    #[storage(2, read_only)]
    pub selected: Handle<ShaderBuffer>,
}

// Back faces of each box: one fragment per pixel and tubelet, also with the camera inside a box; no
// prepass or shadows (the tubelets write their own depth).
fascicle_render::proxy_glyph_material!(TubeletMaterial, shaders::tubelet());

/// The streamlines of a tract layer and what the ROIs select of them, however they are drawn.
#[derive(Component, Clone)]
pub struct TractSet {
    /// The streamlines (world RAS+ mm): in memory, shared with the layer's asset, or read in place from the
    /// layer's file.
    pub tractogram: SetStreamlines,
    /// The spatial index ROIs and picks are tested through, built when first needed.
    pub index: LazyIndex,
    /// One bit per streamline, set when selected ([`selection_words`]); the vertex shaders hide the others.
    pub selected: Handle<ShaderBuffer>,
    /// The layer's index of the set's first streamline, for a layer shown in parts (default 0: a set alone).
    /// [`DeletedStreamlines`] on the layer index the layer's streamlines; this set hides those from `first` on.
    pub first: usize,
}

/// A tract set's streamlines: in memory, or read in place from a mapped `.tck` (a run of the file's
/// streamlines, 8 bytes each; the points stay in the page cache, and the pages a selection or an index build
/// read are let go again: [`SetStreamlines::release`]). What selection, picking and saving read.
#[derive(Clone)]
pub enum SetStreamlines {
    /// In memory.
    Owned(Arc<Tractogram>),
    /// Read in place.
    Mapped(Arc<MappedRun>),
}

impl SetStreamlines {
    /// How many streamlines.
    pub fn n_streamlines(&self) -> usize {
        Streamlines::n_streamlines(self)
    }

    /// The points of streamline `s` (RAS+ mm).
    pub fn streamline(&self, s: usize) -> &[Vec3] {
        Streamlines::streamline(self, s)
    }

    /// The streamlines with `keep[s]`, in order, as a tractogram of points (for saving).
    pub fn subset(&self, keep: &[bool]) -> Tractogram {
        Streamlines::subset(self, keep)
    }

    /// Lets pages read in place go from the process's resident memory (nothing for streamlines in memory):
    /// after a pass over every streamline (an index build, a selection or pick without the index).
    pub fn release(&self) {
        if let SetStreamlines::Mapped(run) = self {
            run.release();
        }
    }
}

impl Streamlines for SetStreamlines {
    fn n_streamlines(&self) -> usize {
        match self {
            SetStreamlines::Owned(t) => t.n_streamlines(),
            SetStreamlines::Mapped(run) => run.n_streamlines(),
        }
    }

    #[inline]
    fn streamline(&self, s: usize) -> &[Vec3] {
        match self {
            SetStreamlines::Owned(t) => t.streamline(s),
            SetStreamlines::Mapped(run) => run.streamline(s),
        }
    }
}

/// A tract set's spatial index ([`StreamlineCells`], 4 mm cells: about 160 MiB for 1M whole-brain streamlines)
/// and the margins of the ROI drag in progress ([`DragMargins`], 32 bytes per streamline and ROI), shared by
/// clones. Built where it is made ([`PreparedTracts::with_index`]), or in the background when an ROI or a
/// pick first needs it ([`LazyIndex::ready_or_build`]: a builder at the lowest priority), and until then ROIs
/// are tested on every streamline (the same selection: [`Criteria`]) and picks by brute force.
#[derive(Clone, Default)]
pub struct LazyIndex(Arc<IndexInner>);

#[derive(Default)]
struct IndexInner {
    cells: OnceLock<StreamlineCells>,
    building: std::sync::atomic::AtomicBool,
    drag: std::sync::Mutex<DragMargins>,
}

/// The side of an index cell (mm).
const INDEX_CELL_MM: f32 = 4.0;

impl LazyIndex {
    /// The index of `t` (the set's tractogram), built now if it was not.
    pub fn get(&self, t: &(impl Streamlines + ?Sized)) -> &StreamlineCells {
        self.0.cells.get_or_init(|| build_index(t))
    }

    /// The index when it is built; otherwise `None`, and it is queued (once) for the background builder: one
    /// thread at the lowest scheduling priority, with a rayon pool of its own at that priority, building the
    /// queued indexes one after another and skipping sets that are gone. The CPU that frames leave idle builds
    /// them: a whole-brain layer in 416 parts asks for 416 indexes at its first ROI (they were as many threads
    /// at normal priority, which took the cores from the frames and from the layer's other jobs).
    pub fn ready_or_build(&self, t: &SetStreamlines) -> Option<&StreamlineCells> {
        use std::sync::atomic::Ordering;
        if let Some(cells) = self.0.cells.get() {
            return Some(cells);
        }
        if !self.0.building.swap(true, Ordering::AcqRel)
            && let Err(e) = index_builder().and_then(|b| b.send((self.0.clone(), t.clone())).map_err(|e| e.to_string()))
        {
            warn!("the tract set's index is built when next needed: no thread for it ({e})");
            self.0.building.store(false, Ordering::Release);
        }
        None
    }

    /// Which streamlines of `t` the ROIs select (as [`fascicle_core::roi::select`]), through the index,
    /// remembering the drag's margins so that a moved ROI reads only the streamlines near its boundary; with
    /// no index yet, testing every streamline (and the index is started).
    pub fn select(&self, t: &SetStreamlines, rois: &[Roi]) -> Vec<bool> {
        match self.ready_or_build(t) {
            Some(cells) => {
                let mut drag = self.0.drag.lock().unwrap_or_else(|e| e.into_inner());
                cells.select_dragging(|s| t.streamline(s), rois, &mut drag)
            }
            None => select_every(t, rois),
        }
    }

    /// [`LazyIndex::select`] as the ids it names ([`Kept`]): through the index, no flag per streamline is made.
    pub fn select_kept(&self, t: &SetStreamlines, rois: &[Roi]) -> Kept {
        match self.ready_or_build(t) {
            Some(cells) => {
                let mut drag = self.0.drag.lock().unwrap_or_else(|e| e.into_inner());
                cells.select_kept_dragging(|s| t.streamline(s), rois, &mut drag)
            }
            None => Kept::of_flags(&select_every(t, rois)),
        }
    }

    /// The streamlines of `t` in the index's cells that meet `shape` (a superset of those with a point or a step
    /// there), when the index is built; otherwise `None` (and it is started).
    pub fn candidates(&self, t: &SetStreamlines, shape: &fascicle_core::roi::RoiShape) -> Option<Vec<u32>> {
        self.ready_or_build(t).map(|cells| cells.candidates(shape))
    }

    /// The shown streamline of `t` a ray picks (see [`fascicle_core::roi::pick_streamline`]): through the
    /// index when it is built, otherwise by brute force (and the index is started).
    pub fn pick(
        &self,
        t: &SetStreamlines,
        shown: impl Fn(usize) -> bool + Sync,
        o: Vec3,
        d: Vec3,
        tolerance: f32,
    ) -> Option<(usize, f32)> {
        match self.ready_or_build(t) {
            Some(cells) => cells.pick(|s| t.streamline(s), shown, o, d, tolerance),
            None => {
                let picked = fascicle_core::roi::pick_streamline(t, shown, o, d, tolerance);
                t.release();
                picked
            }
        }
    }
}

/// Which streamlines of `t` the ROIs select, every streamline tested without an index (the selection
/// [`LazyIndex::select`] makes through one); the pages the pass read in place go again after it.
fn select_every(t: &SetStreamlines, rois: &[Roi]) -> Vec<bool> {
    let mut keep = vec![true; t.n_streamlines()];
    Criteria::from_rois(rois, false).narrow(t, &mut keep);
    t.release();
    keep
}

/// A set's index and streamlines, queued for the background builder.
type IndexJob = (Arc<IndexInner>, SetStreamlines);

/// The rayon pool a layer's selection in the background runs on: all cores but one (at least one), so that the
/// frames drawn meanwhile (a window's ROI drag) keep a core; `None` when it cannot be made (the global pool then).
fn selection_pool() -> Option<&'static rayon::ThreadPool> {
    static POOL: OnceLock<Option<rayon::ThreadPool>> = OnceLock::new();
    POOL.get_or_init(|| {
        let cores = std::thread::available_parallelism().map_or(1, usize::from);
        rayon::ThreadPoolBuilder::new()
            .num_threads(cores.saturating_sub(1).max(1))
            .thread_name(|i| format!("tract-select-{i}"))
            .build()
            .ok()
    })
    .as_ref()
}

/// The queue of [`LazyIndex::ready_or_build`]'s background builder, its thread started with the first index.
fn index_builder() -> Result<&'static std::sync::mpsc::Sender<IndexJob>, String> {
    static BUILDER: OnceLock<Result<std::sync::mpsc::Sender<IndexJob>, String>> = OnceLock::new();
    BUILDER
        .get_or_init(|| {
            let (send, receive) = std::sync::mpsc::channel::<IndexJob>();
            std::thread::Builder::new()
                .name("tract index".into())
                .spawn(move || {
                    lowest_priority();
                    let pool = rayon::ThreadPoolBuilder::new()
                        .thread_name(|i| format!("tract-index-{i}"))
                        .start_handler(|_| lowest_priority())
                        .build()
                        .ok();
                    for (inner, t) in receive {
                        // Only the queue holds a set that went: nothing to build.
                        if Arc::strong_count(&inner) == 1 {
                            continue;
                        }
                        let build = || {
                            inner.cells.get_or_init(|| build_set_index(&t));
                            t.release();
                        };
                        match &pool {
                            Some(pool) => pool.install(build),
                            None => build(),
                        }
                    }
                })
                .map(|_| send)
                .map_err(|e| e.to_string())
        })
        .as_ref()
        .map_err(Clone::clone)
}

/// Lowers the calling thread to the lowest scheduling priority (nice 19), where the platform allows.
fn lowest_priority() {
    #[cfg(target_os = "linux")]
    // SAFETY: setpriority on the calling thread's own id changes nothing but that thread's scheduling.
    unsafe {
        libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 19);
    }
}

fn build_index(t: &(impl Streamlines + ?Sized)) -> StreamlineCells {
    StreamlineCells::build_fitted(t.n_streamlines(), |s| t.streamline(s), INDEX_CELL_MM)
}

/// A set's index; streamlines read in place let their pages go a block at a time as the build's passes go over
/// them (a layer's run: the whole file, which would otherwise stay resident until the build ends).
fn build_set_index(t: &SetStreamlines) -> StreamlineCells {
    match t {
        SetStreamlines::Owned(t) => build_index(&**t),
        SetStreamlines::Mapped(run) => StreamlineCells::build_fitted_in_blocks(
            run.n_streamlines(),
            |s| run.streamline(s),
            INDEX_CELL_MM,
            |block| run.release_streamlines(block),
        ),
    }
}

/// A tract set drawn as hyperstreamlines (tubelets): one entity, one draw.
#[derive(Component, Clone)]
pub struct TubeSet {
    /// The set's material: its settings, tubelet buffer and selection flags.
    pub material: Handle<TubeletMaterial>,
    /// How many tubelets the set draws (0: the entity has no mesh and draws nothing).
    pub n_tubelets: usize,
    /// The proxy boxes of every selected tubelet ([`slot_boxes_of`]: 8 vertices (slot, corner, 0) a tubelet; all of them until a selection hides some); the
    /// entity's [`Mesh3d`] holds it unless it draws the preview.
    pub full: Handle<Mesh>,
    /// The proxy boxes of every [`TUBE_PREVIEW_STRIDE`]-th streamline's selected tubelets (sets of more than
    /// [`TUBE_PREVIEW_MAX`] tubelets), drawn while the view moves and the frame budget cannot be held by render
    /// scale alone: the entity's [`CoarseMesh`](fascicle_render::budget::CoarseMesh) names it.
    pub preview: Option<Handle<Mesh>>,
    /// Per tubelet, its streamline's index in the set: which proxies a selection keeps
    /// ([`select_tube_boxes`]).
    pub streamline_of: Arc<[u32]>,
    /// The settings the tubelets were made and are drawn with.
    pub settings: TubeSettings,
}

/// A tract set drawn as a mesh in direction colours, lines or polygon tubes: one entity, one draw.
#[derive(Component, Clone)]
pub struct MeshSet {
    /// The set's material (opacity, selection flags), shared by the whole mesh and the preview.
    pub material: Handle<TractMeshMaterial>,
    /// The whole set's mesh; the entity's [`Mesh3d`] holds it unless [`TractDetail`] shows the preview.
    pub full: Handle<Mesh>,
    /// A sparser mesh of the same set ([`preview_mesh`]; lines only), drawn while the view moves or parts
    /// arrive when the whole scene is over [`TractDetail`]'s budget.
    pub preview: Option<Handle<Mesh>>,
}

/// Level of detail of line sets, a resource. While a camera moves or tract sets are still arriving (a file
/// streamed in parts), and the visible line sets hold more segments than the adapter's limit, every line set
/// draws its preview ([`preview_mesh`]: one streamline in [`PREVIEW_STRIDE`], compressed to
/// [`PREVIEW_TOLERANCE_MM`]); the whole sets return once the view has been still, and no set arrived, for
/// `still_after`. With the frame budget ([`fascicle_render::budget::FrameBudgetPlugin`]), the view moves while
/// its [`BudgetState`](fascicle_render::budget::BudgetState) says so: a drag's release draws the whole sets in
/// the frame it refines. Switching is a change of the entity's [`Mesh3d`] handle: nothing is rebuilt or
/// uploaded.
///
/// Off by default (every frame draws every streamline: headless renders, tests); the viewer turns it on.
#[derive(Resource, Clone, Debug, PartialEq)]
pub struct TractDetail {
    /// Whether previews are used at all (default false).
    pub enabled: bool,
    /// Visible line segments above which a software adapter draws previews while moving: default 1,000,000
    /// (about 0.3 s a frame on lavapipe with 2 cores, which draws about 3.7M segments a second).
    pub software_max_segments: usize,
    /// The same on a hardware GPU: default 200,000,000 (an H200 draws 22M segments in 36 ms).
    pub hardware_max_segments: usize,
    /// How long the view stays still, and no set arrives, before the whole sets return (default 300 ms).
    pub still_after: std::time::Duration,
}

impl Default for TractDetail {
    fn default() -> Self {
        Self {
            enabled: false,
            software_max_segments: 1_000_000,
            hardware_max_segments: 200_000_000,
            still_after: std::time::Duration::from_millis(300),
        }
    }
}

/// Whether line sets draw their previews: the view moved or a set arrived less than `still_after` ago, and
/// the whole sets hold more than `limit` segments.
pub fn use_previews(
    since_activity: Option<std::time::Duration>,
    still_after: std::time::Duration,
    segments: usize,
    limit: usize,
) -> bool {
    segments > limit && since_activity.is_some_and(|t| t < still_after)
}

/// Applies [`TractDetail`]: each mesh set with a preview draws it or its whole mesh. While the view moves, the
/// next frame is asked for ([`fascicle_render::Unsettled`]), so that a window drawn on demand reaches the frame
/// that finds the view still. That frame keeps the previews and asks for nothing; the frame after it (which a
/// window drawn on demand draws as it goes idle) draws the whole sets, their meshes uploaded already, and no
/// frame follows: on a software adapter a whole-brain frame takes seconds, and as much memory again while it is
/// drawn.
#[allow(clippy::type_complexity, clippy::too_many_arguments, reason = "a Bevy system's parameters")]
fn tract_detail(
    detail: Res<TractDetail>,
    adapter: Option<Res<fascicle_render::AdapterKind>>,
    time: Res<Time<bevy::time::Real>>,
    moved: Query<(), (With<Camera3d>, Changed<GlobalTransform>)>,
    added: Query<(), Added<MeshSet>>,
    mut sets: Query<(&MeshSet, &LineSegments, &InheritedVisibility, &mut Mesh3d, Option<&SelectedLines>)>,
    (mut last_activity, mut last_arrival, mut settling): (
        Local<Option<std::time::Duration>>,
        Local<Option<std::time::Duration>>,
        Local<bool>,
    ),
    unsettled: Option<ResMut<fascicle_render::Unsettled>>,
    budget: Option<Res<fascicle_render::budget::BudgetState>>,
) {
    let now = time.elapsed();
    if !moved.is_empty() || !added.is_empty() {
        *last_activity = Some(now);
    }
    if !added.is_empty() {
        *last_arrival = Some(now);
    }
    let software = adapter.is_some_and(|a| a.is_software());
    let limit = if software { detail.software_max_segments } else { detail.hardware_max_segments };
    // The whole meshes' segments, also where a selection's own lines are drawn when still: those cost their
    // segments, not pixels, and drawn while moving they would take the render scale to its smallest (0.7M
    // segments of a 1M layer's sphere: 80 ms frames at an eighth of the side, where its previews take 35 ms).
    let segments: usize = sets
        .iter()
        .filter(|(set, _, shown, _, _)| set.preview.is_some() && shown.get())
        .map(|(_, s, _, _, _)| s.0)
        .sum();
    let shown = sets.iter().any(|(set, _, _, mesh, _)| set.preview.as_ref() == Some(&mesh.0));
    let (moving, coarse) = match &budget {
        // With a frame budget, its view of the interaction decides (a drag's release refines at once, in the
        // frame the budget draws at full scale; a coarse frame draws previews whatever the segments), and sets
        // arriving keep the previews for `still_after`.
        Some(b) => {
            let arriving =
                use_previews(last_arrival.map(|t| now.saturating_sub(t)), detail.still_after, segments, limit);
            let moving = detail.enabled && (arriving || (b.moving && (segments > limit || b.coarse)));
            (moving, moving)
        }
        None => {
            let since = last_activity.map(|t| now.saturating_sub(t));
            let moving = detail.enabled && use_previews(since, detail.still_after, segments, limit);
            // The first still frame keeps the previews and asks for nothing: a window drawn on demand then draws
            // one more frame as it goes idle (its update mode changes), and that one, the last, draws the whole
            // sets.
            (moving, moving || (shown && !*settling))
        }
    };
    *settling = shown && !moving;
    trace!("tract detail: moving {moving}, previews shown {shown}, coarse {coarse}, {segments} segments");
    for (set, _, _, mut mesh, selected) in &mut sets {
        // In a viewer (previews on), a set whose selection's lines are being made keeps its preview until
        // they can be drawn, rather than a frame of the whole mesh (seconds at 10M on lavapipe).
        let awaiting = detail.enabled && selected.is_some_and(SelectedLines::pending);
        let want = match (&set.preview, coarse || awaiting) {
            (Some(preview), true) => preview,
            _ => selected.and_then(SelectedLines::mesh).unwrap_or(&set.full),
        };
        if mesh.0 != *want {
            mesh.0 = want.clone();
        }
    }
    if moving && let Some(mut unsettled) = unsettled {
        unsettled.request();
    }
}

/// The line segments an entity's mesh draws: what [`LineMsaa`] weighs. Line-mesh sets carry it; an app that
/// draws lines with a mesh of its own adds it there too.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LineSegments(pub usize);

/// The line segments a layer will draw once it has loaded, estimated before its first part arrives (an app
/// puts it on a layer whose file is being read, from the file's size, and removes it when the layer is in):
/// [`LineMsaa`] weighs it with the segments drawn, so a camera that will drop MSAA for a whole-brain file drops
/// it before the first line is drawn, and the render world specialises its pipelines once, not twice (on a
/// software adapter, compiling some forty pipelines again delayed the first streamlines).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ExpectedLineSegments(pub usize);

/// When cameras drop MSAA for lines: a 3D camera that sees more line segments than the limit renders without
/// MSAA (logged once). On a software rasteriser multisampled lines cost about ten times single-sampled ones
/// (20,000 streamlines at 1280x720 on lavapipe: 77 s against 7.4 s for a headless render), so a dense
/// tractogram would take minutes a frame; a hardware GPU keeps MSAA. The viewer and `fascicle render` follow
/// the same rule, so they draw the same image. A camera keeps MSAA off after the lines go.
#[derive(Resource, Clone, Copy, Debug, PartialEq, Eq)]
pub struct LineMsaa {
    /// Segments above which a camera on a software adapter drops MSAA. Default 1,000,000.
    pub software_max_segments: usize,
    /// The same on a hardware GPU. Default `usize::MAX` (never).
    pub hardware_max_segments: usize,
}

impl Default for LineMsaa {
    fn default() -> Self {
        Self { software_max_segments: 1_000_000, hardware_max_segments: usize::MAX }
    }
}

/// Applies [`LineMsaa`] to the 3D cameras, by the line segments of the visible mesh sets on their render layers.
#[allow(clippy::type_complexity, reason = "a Bevy system's queries")]
fn line_msaa(
    policy: Res<LineMsaa>,
    adapter: Option<Res<fascicle_render::AdapterKind>>,
    sets: Query<(&LineSegments, Option<&RenderLayers>, &InheritedVisibility)>,
    expected: Query<(&ExpectedLineSegments, Option<&RenderLayers>, &InheritedVisibility)>,
    cameras: Query<(Entity, Option<&Msaa>, Option<&RenderLayers>), With<Camera3d>>,
    mut commands: Commands,
) {
    let software = adapter.is_some_and(|a| a.is_software());
    let limit = if software { policy.software_max_segments } else { policy.hardware_max_segments };
    let default_layers = RenderLayers::default();
    for (e, msaa, layers) in &cameras {
        if msaa == Some(&Msaa::Off) {
            continue;
        }
        let layers = layers.unwrap_or(&default_layers);
        let seen = |l: Option<&RenderLayers>, v: &InheritedVisibility| {
            v.get() && l.unwrap_or(&default_layers).intersects(layers)
        };
        let drawn: usize = sets.iter().filter(|(_, l, v)| seen(*l, v)).map(|(s, _, _)| s.0).sum();
        let coming: usize = expected.iter().filter(|(_, l, v)| seen(*l, v)).map(|(s, _, _)| s.0).sum();
        let segments = drawn.saturating_add(coming);
        if segments > limit {
            info!(
                "fascicle-tracts: camera {e} sees {segments} line segments (over {limit} on a {} adapter); its MSAA is turned off",
                if software { "software" } else { "hardware" }
            );
            commands.entity(e).insert(Msaa::Off);
        }
    }
}

/// GPU parameters of tract meshes. Keep in sync with `TractMeshParams` in `shaders/tract_mesh.wgsl`.
#[derive(Clone, Copy, Debug, PartialEq, ShaderType)]
pub struct TractMeshUniform {
    /// Alpha of every fragment, 0..1; below 1 the material blends.
    pub opacity: f32,
    /// Ambient term of the tubes' headlight shading (lines are unshaded).
    pub ambient: f32,
    /// Half the thickness of the slab the mesh is cropped to, in mm; 0 (the default) draws it whole. A cropped
    /// mesh is drawn flattened onto the slab's centre plane, 1 mm towards the eye: a 2D view looking along the
    /// normal shows it over its images.
    pub slab_half: f32,
    /// The slab's centre plane: unit normal (xyz) and offset (w, mm): points with `normal . p = offset`.
    pub slab: Vec4,
}

impl TractMeshUniform {
    /// A whole mesh of `opacity` with the tubes' ambient term.
    pub fn whole(opacity: f32) -> Self {
        Self { opacity: opacity.clamp(0.0, 1.0), ambient: 0.3, slab_half: 0.0, slab: Vec4::ZERO }
    }
}

/// A tract set's mesh (lines or polygon tubes) cropped to a slab: what a 2D view shows of a tractogram
/// (mrview's "crop to slab"). Spawn it with the 2D view's `RenderLayers`: the plugin gives it the set's mesh
/// and a material of its own with the set's opacity and selection, keeps them in step with the set, and
/// despawns it with the set. Moving the slab (a write of this component) is a uniform write. A fragment is
/// drawn when its distance to the centre plane is at most half the thickness, flattened onto the centre plane
/// 1 mm towards the eye (a view along the normal shows it over images in that plane).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
#[require(Transform, Visibility)]
pub struct TractSlab {
    /// The tract set: an entity with [`MeshSet`].
    pub set: Entity,
    /// Unit normal of the slab, world axes.
    pub normal: Vec3,
    /// The centre plane's offset along the normal, mm.
    pub offset: f32,
    /// Half the slab's thickness, mm (> 0).
    pub half_thickness: f32,
}

/// The streamline a vertex of a tract mesh belongs to (its index in the set: the selection flag the vertex
/// shader reads).
pub const ATTRIBUTE_STREAMLINE: MeshVertexAttribute =
    MeshVertexAttribute::new("Fascicle_Streamline", 0x6661_7363_0001, VertexFormat::Uint32);

/// The colour of a vertex of a tract mesh, linear RGBA in 8 bits a channel (a quarter of Bevy's
/// `ATTRIBUTE_COLOR`; a direction colour is exact to 1/510).
pub const ATTRIBUTE_RGBA8: MeshVertexAttribute =
    MeshVertexAttribute::new("Fascicle_Rgba8", 0x6661_7363_0002, VertexFormat::Unorm8x4);

/// `rgb` (each in 0..1) as an [`ATTRIBUTE_RGBA8`] value, alpha 1.
pub fn rgba8([r, g, b]: [f32; 3]) -> [u8; 4] {
    let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    [q(r), q(g), q(b), 255]
}

/// Drawing material of tract meshes (lines and polygon tubes) with the compact vertex: `POSITION` (and
/// `NORMAL` for tubes), [`ATTRIBUTE_STREAMLINE`] and [`ATTRIBUTE_RGBA8`]: 20 bytes a line vertex.
#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
#[bind_group_data(TractMeshKey)]
pub struct TractMeshMaterial {
    /// Opacity, shading and slab crop (uniform binding 0).
    #[uniform(0)]
    pub params: TractMeshUniform,
    /// One bit per streamline, set when selected ([`selection_words`]; storage binding 1; the set's
    /// [`TractSet::selected`]).
    #[storage(1, read_only)]
    pub selected: Handle<ShaderBuffer>,
}

/// The pipeline key of [`TractMeshMaterial`]: whether it crops to a slab. Only a cropping material's fragment
/// stage can discard; one that can is depth-tested after it runs (on lavapipe and on hardware), so the 3D
/// view's lines, which never crop, skip its cost (a whole-brain frame of 1M streamlines on lavapipe: 5.0 s
/// instead of 6.0 s).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TractMeshKey {
    /// `params.slab_half > 0`: the `SLAB_CROP` shader def.
    pub slab_crop: bool,
}

impl From<&TractMeshMaterial> for TractMeshKey {
    fn from(material: &TractMeshMaterial) -> Self {
        Self { slab_crop: material.params.slab_half > 0.0 }
    }
}

impl Material for TractMeshMaterial {
    fn vertex_shader() -> bevy::shader::ShaderRef {
        shaders::tract_mesh()
    }
    fn fragment_shader() -> bevy::shader::ShaderRef {
        shaders::tract_mesh()
    }
    fn alpha_mode(&self) -> AlphaMode {
        if self.params.opacity < 1.0 { AlphaMode::Blend } else { AlphaMode::Opaque }
    }
    // The compact vertex: position, (normal,) streamline index and 8-bit colour.
    fn specialize(
        _pipeline: &MaterialPipeline,
        descriptor: &mut RenderPipelineDescriptor,
        layout: &MeshVertexBufferLayoutRef,
        key: MaterialPipelineKey<Self>,
    ) -> Result<(), SpecializedMeshPipelineError> {
        let normals = layout.0.contains(Mesh::ATTRIBUTE_NORMAL);
        let mut defs = Vec::new();
        if key.bind_group_data.slab_crop {
            defs.push("SLAB_CROP".into());
        }
        if key.bind_group_data.slab_crop || normals {
            defs.push("WORLD_POSITION".into());
        }
        descriptor.vertex.shader_defs.extend(defs.iter().cloned());
        if let Some(fragment) = descriptor.fragment.as_mut() {
            fragment.shader_defs.extend(defs);
        }
        let mut attributes = vec![Mesh::ATTRIBUTE_POSITION.at_shader_location(0)];
        if normals {
            attributes.push(Mesh::ATTRIBUTE_NORMAL.at_shader_location(1));
        }
        attributes.push(ATTRIBUTE_STREAMLINE.at_shader_location(2));
        attributes.push(ATTRIBUTE_RGBA8.at_shader_location(5));
        descriptor.vertex.buffers = vec![layout.0.get_layout(&attributes)?];
        Ok(())
    }
    // The prepass would draw every line with the default vertex shader, hidden ones included.
    fn enable_prepass() -> bool {
        false
    }
    fn enable_shadows() -> bool {
        false
    }
}

/// Per streamline of a tract set, whether the ROIs select it.
#[derive(Component, Clone, Debug, Default)]
pub struct TractSelection(pub Vec<bool>);

/// A region of interest: spawned as a child of a [`Tracts`] layer (or of a tract set) it acts on that
/// layer's set only; without a parent it acts on every set. Moving it (a component write) re-selects.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct TractRoi(pub Roi);

/// How the ROIs test a tract layer's streamlines, on the layer's entity (the parent of its tract sets) or on
/// a tract set: by default every point and the steps between them; with `ends_only`, the first and last points
/// only (`tckedit -ends_only`: a bundle that ends in a region, not one that passes through it).
#[derive(Component, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RoiRules {
    /// Test only each streamline's first and last points (default false).
    pub ends_only: bool,
}

/// Streamlines deleted by hand (picked in a view, then deleted or all others deleted), on a tract layer's
/// entity or on a tract set: indices into the layer's streamlines (each set hides those from its
/// [`TractSet::first`] on; a set alone: its own streamlines), sorted; they stay hidden whatever the ROIs select,
/// and "save selection" leaves them out. Default none.
#[derive(Component, Clone, Debug, Default, PartialEq, Eq)]
pub struct DeletedStreamlines(pub Arc<Vec<u32>>);

/// Mask images as regions of a tract layer's streamlines, beside its ROIs ([`TractRoi`]), on the layer's
/// entity (the parent of its tract sets) or on a tract set: a shown streamline meets every include mask and
/// no exclude mask (a point in a non-zero voxel, the nearest; with [`RoiRules::ends_only`], its first or last
/// point), as `tckedit` takes images as regions. A change re-selects; nothing is rebuilt. While `waiting` (an
/// app still reading the masks), the sets show nothing. Default: no masks, not waiting.
#[derive(Component, Clone, Debug, Default)]
pub struct TractMasks {
    /// Masks a shown streamline meets, every one.
    pub include: Vec<Arc<MaskRegion>>,
    /// Masks a shown streamline meets none of.
    pub exclude: Vec<Arc<MaskRegion>>,
    /// The masks are not known yet: nothing is shown (default false).
    pub waiting: bool,
}

impl TractMasks {
    /// Narrows a selection of `t`'s streamlines to those the masks keep (with `ends_only`, tested at their end
    /// points); while waiting, to none.
    pub fn narrow(&self, t: &(impl Streamlines + ?Sized), ends_only: bool, selected: &mut [bool]) {
        if self.waiting {
            selected.iter_mut().for_each(|s| *s = false);
            return;
        }
        let region = |m: &Arc<MaskRegion>| Region::Mask(m.clone());
        let criteria = Criteria {
            include: self.include.iter().map(region).collect(),
            exclude: self.exclude.iter().map(region).collect(),
            ends_only,
        };
        criteria.narrow(t, selected);
    }
}

/// The cost of the last ROI re-selection.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct RoiStats {
    /// How many re-selections have run since the App started.
    pub evaluations: u64,
    /// Wall-clock time of the last re-selection, ms.
    pub last_ms: f64,
    /// Streamlines selected after the last re-selection, summed over every tract set.
    pub selected: usize,
    /// Layers the last re-selection tested as one run of their parts read in place (one index each), not part
    /// by part.
    pub joined_layers: usize,
    /// Layers whose drawn selection waits for a selection in the background (their index not built yet):
    /// their parts keep the flags they had until it is done ([`RoiBackground`]).
    pub pending_layers: usize,
}

/// When a tract layer read in place is selected in the background: a layer of more streamlines than
/// `above_streamlines` whose index is not built yet (the first minute or so after a whole brain opens) is not
/// selected in the frame of an ROI edit, which would read every streamline (a 12 GB file at 10M streamlines,
/// seconds of a frozen window per step), but on a thread of its own; its parts keep their flags until the
/// selection is done, then take it. With the index built, a layer of more than `indexed_above_streamlines` is
/// still selected there, through the index: a window's drag step is the pointer's move between two frames,
/// several millimetres, and at 10M streamlines such a step read 0.5-2.6 s of streamlines in the frame. One
/// such selection at a time per layer: edits made meanwhile are selected when it is done, the ROI drawn where
/// it is meanwhile.
#[derive(Resource, Clone, Copy, Debug, PartialEq, Eq)]
pub struct RoiBackground {
    /// Streamlines above which a layer without its index is selected in the background (default 250,000:
    /// about 0.2 s of reading on two cores).
    pub above_streamlines: usize,
    /// Streamlines above which a layer with its index is selected in the background (default 4,000,000: a
    /// 1M whole brain's drag step through the index, 65 ms a frame in the window, stays in the frame).
    pub indexed_above_streamlines: usize,
}

impl Default for RoiBackground {
    fn default() -> Self {
        Self { above_streamlines: 250_000, indexed_above_streamlines: 4_000_000 }
    }
}

impl RoiBackground {
    /// Whether a layer of `n` streamlines, its index built or not, is selected in the frame.
    fn in_frame(&self, n: usize, built: bool) -> bool {
        n <= self.above_streamlines || (built && n <= self.indexed_above_streamlines)
    }
}

/// Tract layers ([`Tracts`]) and tract sets: their materials and shaders, ROI selection ([`apply_rois`]),
/// [`LineMsaa`], [`TractDetail`] and [`TractSlab`]s; adds [`fascicle_render::FascicleRenderPlugin`] if missing.
pub struct TractPlugin;

impl Plugin for TractPlugin {
    fn build(&self, app: &mut App) {
        shaders::register(app);
        use fascicle_render::retain::{watch, watch_asset};
        watch_asset::<TubeletMaterial>(app);
        watch_asset::<TractMeshMaterial>(app);
        watch_asset::<TractogramAsset>(app);
        watch::<LineMsaa>(app);
        watch::<TractDetail>(app);
        app.add_plugins((MaterialPlugin::<TubeletMaterial>::default(), MaterialPlugin::<TractMeshMaterial>::default()))
            .init_resource::<RoiStats>()
            .init_resource::<RoiBackground>()
            .init_resource::<LineMsaa>()
            .init_resource::<TractDetail>()
            .add_systems(
                PostUpdate,
                (
                    apply_rois.in_set(TractSystems::Select),
                    select_tube_boxes.in_set(TractSystems::Select).after(apply_rois),
                    narrow_previews.in_set(TractSystems::Select).after(apply_rois),
                    make_selected_lines.in_set(TractSystems::Select).after(apply_rois),
                    upload_flags_behind.after(narrow_previews).after(make_selected_lines).after(tract_detail),
                    line_msaa,
                    // The preview switches (a `Mesh3d` change) come before Bevy computes the meshes' bounds:
                    // a bound changed a frame later would keep the retained picture from being put back, and a
                    // window drawn on demand would draw one more full frame.
                    tract_detail
                        .after(bevy::transform::TransformSystems::Propagate)
                        .after(fascicle_render::budget::BudgetSystems)
                        .before(bevy::camera::visibility::VisibilitySystems::CalculateBounds)
                        .before(sync_slabs),
                    sync_slabs.before(bevy::camera::visibility::VisibilitySystems::CalculateBounds),
                    warm_up,
                ),
            );
        layer::build(app);
        placed::build(app);
        app.add_systems(Update, draw_rois.run_if(resource_exists::<bevy::gizmos::config::GizmoConfigStore>));
    }
}

/// The visibility a tract set had before [`warm_up`] hid it.
#[derive(Component, Clone, Copy, Debug)]
struct HiddenForWarmup(Visibility);

/// While a headless app warms its pipelines up ([`fascicle_render::headless::PipelineWarmup`]), every tract
/// set but the first of its layer (its parent; the parts of one tractogram share their pipelines) is hidden,
/// and shown again after.
#[allow(clippy::type_complexity, reason = "a Bevy system's queries")]
fn warm_up(
    mut commands: Commands,
    warming: Option<Res<fascicle_render::headless::PipelineWarmup>>,
    mut sets: Query<
        (Entity, &mut Visibility, Option<&ChildOf>, Option<&HiddenForWarmup>),
        Or<(With<MeshSet>, With<TubeSet>)>,
    >,
) {
    if warming.is_some() {
        let mut seen = std::collections::HashSet::new();
        for (e, mut visibility, parent, hidden) in &mut sets {
            if hidden.is_none() && !seen.insert(parent.map(ChildOf::parent)) {
                commands.entity(e).insert(HiddenForWarmup(*visibility));
                *visibility = Visibility::Hidden;
            }
        }
    } else {
        for (e, mut visibility, _, hidden) in &mut sets {
            if let Some(HiddenForWarmup(was)) = hidden {
                *visibility = *was;
                commands.entity(e).remove::<HiddenForWarmup>();
            }
        }
    }
}

/// What [`sync_slabs`] reads and writes of a slab.
type SlabItem<'a> =
    (Entity, &'a TractSlab, Option<&'a Mesh3d>, Option<&'a MeshMaterial3d<TractMeshMaterial>>, &'a mut Visibility);

/// Gives each [`TractSlab`] its set's mesh and a material of its own, and keeps both in step with the set
/// (opacity, selection buffer, mesh, visibility); despawns a slab whose set is gone. Assets are written only
/// when something differs.
fn sync_slabs(
    mut commands: Commands,
    mut slabs: Query<SlabItem>,
    sets: Query<(&Mesh3d, &MeshSet, &InheritedVisibility, Option<&Aabb>)>,
    mut materials: ResMut<Assets<TractMeshMaterial>>,
    mut material_events: MessageWriter<AssetEvent<TractMeshMaterial>>,
) {
    for (e, slab, mesh, material, mut visibility) in &mut slabs {
        let Ok((set_mesh, set, shown, bounds)) = sets.get(slab.set) else {
            commands.entity(e).despawn();
            continue;
        };
        let Some(source) = materials.get(&set.material).cloned() else { continue };
        let params = TractMeshUniform {
            slab_half: slab.half_thickness.max(f32::MIN_POSITIVE),
            slab: slab.normal.normalize_or_zero().extend(slab.offset),
            ..source.params
        };
        match material.and_then(|m| materials.get(&m.0).map(|mat| (m.0.clone(), mat))) {
            Some((handle, mat)) => {
                // Drawn in this frame (a crosshair move): this runs after the asset events' flush.
                if mat.params != params || mat.selected != source.selected {
                    fascicle_render::modify_now(&mut materials, &mut material_events, &handle, |mat| {
                        mat.params = params;
                        mat.selected = source.selected.clone();
                    });
                }
            }
            None => {
                let handle = materials.add(TractMeshMaterial { params, selected: source.selected.clone() });
                commands.entity(e).insert(MeshMaterial3d(handle));
            }
        }
        if mesh.map(|m| &m.0) != Some(&set_mesh.0) {
            commands.entity(e).insert(Mesh3d(set_mesh.0.clone()));
            // The set's kept bounds, as on the set's own entity ([`insert_mesh_set`]).
            if let Some(bounds) = bounds {
                commands.entity(e).insert((*bounds, NoAutoAabb));
            }
        }
        let want = if shown.get() { Visibility::Inherited } else { Visibility::Hidden };
        visibility.set_if_neq(want);
    }
}

/// Storage bytes: seven `vec4<f32>` per tubelet.
pub fn pack(tubes: &[Tubelet]) -> Vec<u8> {
    let mut out = Vec::with_capacity(tubes.len() * 112);
    for t in tubes {
        let q = t.rotation;
        let vals = [
            t.centre.x as f32,
            t.centre.y as f32,
            t.centre.z as f32,
            t.half_length as f32,
            q.x as f32,
            q.y as f32,
            q.z as f32,
            q.w as f32,
            t.radii[0] as f32,
            t.radii[1] as f32,
            t.radii[2] as f32,
            t.radii[3] as f32,
            t.cuts[0].x as f32,
            t.cuts[0].y as f32,
            t.cuts[0].z as f32,
            t.twist as f32,
            t.cuts[1].x as f32,
            t.cuts[1].y as f32,
            t.cuts[1].z as f32,
            f32::from_bits(t.streamline),
            t.colours[0].x as f32,
            t.colours[0].y as f32,
            t.colours[0].z as f32,
            0.0,
            t.colours[1].x as f32,
            t.colours[1].y as f32,
            t.colours[1].z as f32,
            0.0,
        ];
        for v in vals {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    if out.is_empty() {
        out = vec![0u8; 112];
    }
    out
}

/// Tubelets a hyperstreamline set may hold before it gets a preview: 4,000.
pub const TUBE_PREVIEW_MAX: usize = 4_000;

/// One streamline in this many is in a hyperstreamline preview: 16 (as [`PREVIEW_STRIDE`] for lines). A fixed
/// stride, not one per set's size: a tracked or streamed layer comes as many sets, and the preview of the
/// whole layer must be small.
pub const TUBE_PREVIEW_STRIDE: usize = 16;

/// The preview of a set of more than [`TUBE_PREVIEW_MAX`] tubelets: the tubelets of one streamline in
/// [`TUBE_PREVIEW_STRIDE`] (whole streamlines, so the preview shows fewer tracts, not broken ones), as the
/// indices of their slots; `None` for a smaller set.
pub fn tube_preview(tubes: &[Tubelet]) -> Option<Vec<u32>> {
    (tubes.len() > TUBE_PREVIEW_MAX)
        .then(|| (0..tubes.len() as u32).filter(|&i| in_tube_preview(tubes[i as usize].streamline)).collect())
}

/// Whether a set's streamline `s` is in its hyperstreamline preview: one in [`TUBE_PREVIEW_STRIDE`].
fn in_tube_preview(s: u32) -> bool {
    (s as usize).is_multiple_of(TUBE_PREVIEW_STRIDE)
}

/// The tubelets of a tractogram with optional per-point world tensors (lower-triangular, mm²/s).
pub fn tract_tubelets(t: &Tractogram, tensors: Option<&[[f32; 6]]>, settings: &TubeSettings) -> Vec<Tubelet> {
    let mut out = Vec::new();
    for s in 0..t.offsets.len().saturating_sub(1) {
        let r = t.offsets[s]..t.offsets[s + 1];
        let pts: Vec<glam::DVec3> = t.points[r.clone()].iter().map(|p| p.as_dvec3()).collect();
        let tens: Option<Vec<[f64; 6]>> = tensors.map(|ts| ts[r].iter().map(|v| v.map(f64::from)).collect());
        out.extend(tubelets(&pts, tens.as_deref(), settings.scale, settings.colour, s as u32));
    }
    out
}

/// A tract set's CPU work, done before it is spawned (on any thread: the app builds it in a background job):
/// for the chosen style, the packed tubelets or the mesh, and (with [`PreparedTracts::with_index`]) the spatial
/// index of the selection.
pub struct PreparedTracts {
    /// The streamlines, kept for ROI selection ([`TractSet`]); None once [`PreparedTracts::drawn_only`] let them
    /// go.
    pub tractogram: Option<SetStreamlines>,
    /// How many streamlines the set draws.
    pub n_streamlines: usize,
    /// The spatial index ROIs are tested through: built by [`PreparedTracts::with_index`], otherwise when first
    /// needed.
    pub index: LazyIndex,
    /// What is drawn: the packed tubelets or the mesh.
    pub geometry: PreparedGeometry,
    /// The layer's index of the first streamline ([`TractSet::first`]; default 0).
    pub first: usize,
}

/// The drawable part of [`PreparedTracts`].
pub enum PreparedGeometry {
    /// Hyperstreamlines: the packed tubelet buffer, their count, the settings they were made with, and the
    /// proxy boxes (8 vertices each; built here, off the main thread, not at spawn).
    Tubes {
        /// The tubelets as [`pack`] lays them out: seven `vec4<f32>` (112 bytes) each.
        packed: Vec<u8>,
        /// How many tubelets `packed` holds (0: the set draws nothing).
        n_tubelets: usize,
        /// The settings the tubelets were made with.
        settings: TubeSettings,
        /// The proxy mesh ([`slot_boxes`]): 8 vertices (slot, corner, 0) and 12 triangles per tubelet.
        boxes: Box<Mesh>,
        /// The preview's proxy mesh ([`tube_preview`]; sets of more than [`TUBE_PREVIEW_MAX`] tubelets).
        preview: Option<Box<Mesh>>,
    },
    /// Lines or polygon tubes, and for lines the preview [`TractDetail`] may draw instead.
    Mesh {
        /// The whole set: an indexed line list ([`line_mesh_coloured`]) or the triangles of polygon tubes
        /// ([`polygon_tube_mesh`]).
        mesh: Box<Mesh>,
        /// Lines only: every [`LineDetail::preview_stride`]-th streamline compressed to
        /// [`PREVIEW_TOLERANCE_MM`] (as [`preview_mesh`]); `None` for polygon tubes.
        preview: Option<Box<Mesh>>,
        /// Lines coloured by direction: the tolerance they were compressed to (mm), with which the lines of a
        /// selection are made again alike ([`SelectedLines`]); `None` for polygon tubes and lines coloured
        /// otherwise (their colours are not kept).
        lines_tolerance_mm: Option<f64>,
    },
}

impl PreparedTracts {
    fn with(tractogram: Arc<Tractogram>, geometry: PreparedGeometry) -> Self {
        let n_streamlines = tractogram.n_streamlines();
        let tractogram = Some(SetStreamlines::Owned(tractogram));
        PreparedTracts { index: LazyIndex::default(), tractogram, n_streamlines, geometry, first: 0 }
    }

    /// As the part of a layer whose first streamline is the layer's `first` ([`TractSet::first`]).
    pub fn starting_at(self, first: usize) -> Self {
        PreparedTracts { first, ..self }
    }

    /// With the spatial index built now (for a layer with ROIs: ready at the first selection).
    pub fn with_index(self) -> Self {
        if let Some(t) = &self.tractogram {
            self.index.get(t);
        }
        self
    }

    /// Without its streamlines: the set is drawn (and its opacity, colours and level of detail work as
    /// before) but spawns no [`TractSet`], so ROIs do not act on it, and the points are freed as soon as the
    /// geometry is made (a whole-brain tractogram's 1.2 GB per million streamlines, which a layer that only
    /// shows a file does not need).
    pub fn drawn_only(self) -> Self {
        PreparedTracts { tractogram: None, index: LazyIndex::default(), ..self }
    }

    /// Its streamlines read in place from `run` (the same streamlines, from the file they were read from:
    /// [`MappedRun::consecutive`]) instead of kept in memory, once the geometry is made; unchanged when `run`
    /// holds another number of streamlines.
    pub fn read_in_place(self, run: Arc<MappedRun>) -> Self {
        if run.n_streamlines() != self.n_streamlines {
            return self;
        }
        PreparedTracts { tractogram: Some(SetStreamlines::Mapped(run)), index: LazyIndex::default(), ..self }
    }

    /// Hyperstreamlines (optional per-point world tensors give the sections).
    pub fn tubes(tractogram: Arc<Tractogram>, tensors: Option<&[[f32; 6]]>, settings: &TubeSettings) -> Self {
        PreparedTracts::tubes_coloured(tractogram, tensors, settings, None)
    }

    /// [`PreparedTracts::tubes`], each tubelet's two ends coloured by `colour` (when given) at the points where
    /// its axis meets its cut planes, instead of the settings' colouring.
    pub fn tubes_coloured(
        tractogram: Arc<Tractogram>,
        tensors: Option<&[[f32; 6]]>,
        settings: &TubeSettings,
        colour: Option<PointColour>,
    ) -> Self {
        let mut tubes = tract_tubelets(&tractogram, tensors, settings);
        if let Some(colour) = colour {
            recolour(&mut tubes, colour);
        }
        let geometry = PreparedGeometry::Tubes {
            packed: pack(&tubes),
            n_tubelets: tubes.len(),
            settings: *settings,
            boxes: Box::new(slot_boxes(tubes.len())),
            preview: tube_preview(&tubes).map(|slots| Box::new(slot_boxes_of(&slots))),
        };
        PreparedTracts::with(tractogram, geometry)
    }

    /// Lines coloured by local direction ([`line_mesh`]).
    pub fn lines(tractogram: Arc<Tractogram>) -> Self {
        PreparedTracts::lines_coloured(tractogram, None)
    }

    /// Lines compressed to [`LINE_TOLERANCE_MM`], coloured by `colour` at each vertex when given
    /// ([`line_mesh_coloured`]), with their preview ([`preview_mesh`]).
    pub fn lines_coloured(tractogram: Arc<Tractogram>, colour: Option<PointColour>) -> Self {
        PreparedTracts::lines_in_detail(tractogram, colour, LineDetail::default())
    }

    /// [`PreparedTracts::lines_coloured`] at the tolerance and preview stride of `detail`.
    pub fn lines_in_detail(tractogram: Arc<Tractogram>, colour: Option<PointColour>, detail: LineDetail) -> Self {
        let mesh = Box::new(line_mesh_coloured(&tractogram, colour, detail.tolerance_mm));
        let preview = strided_line_mesh(&tractogram, colour, PREVIEW_TOLERANCE_MM, detail.preview_stride);
        let lines_tolerance_mm = (colour.is_none() && detail.selected_lines).then_some(detail.tolerance_mm);
        let geometry = PreparedGeometry::Mesh { mesh, preview: Some(Box::new(preview)), lines_tolerance_mm };
        PreparedTracts::with(tractogram, geometry)
    }

    /// Polygon tubes, 16 sides per ring ([`polygon_tube_mesh`]).
    pub fn polygon_tubes(tractogram: Arc<Tractogram>, tensors: Option<&[[f32; 6]]>, scale: f64) -> Self {
        let mesh = Box::new(polygon_tube_mesh(&tractogram, tensors, scale, 16));
        PreparedTracts::with(tractogram, PreparedGeometry::Mesh { mesh, preview: None, lines_tolerance_mm: None })
    }
}

/// The flag buffer of `n_streamlines` streamlines, every one selected.
fn all_selected(buffers: &mut Assets<ShaderBuffer>, n_streamlines: usize) -> Handle<ShaderBuffer> {
    let flags = selection_words(&vec![true; n_streamlines]);
    buffers.add(ShaderBuffer::new(&flags, RenderAssetUsages::default()))
}

/// A selection as the shaders read it: streamline `s` is bit `s % 32` of the little-endian `u32` word `s / 32`,
/// set when selected (at least one word: a storage buffer is never empty). A 10M-streamline layer's selection
/// is 1.25 MB, where a `u32` a streamline made every ROI drag step upload 40 MB.
pub fn selection_words(selected: &[bool]) -> Vec<u8> {
    let mut bytes = vec![0u8; 4 * selected.len().div_ceil(32).max(1)];
    // Eight flags a byte of bits: each flag is a byte of 0 or 1, and the product gathers bit 0 of byte i of
    // the little-endian u64 into bit 56 + i (a drag step of a 10M-streamline layer packs 10M flags a frame).
    for (byte, flags) in bytes.iter_mut().zip(selected.chunks(8)) {
        let mut eight = [0u8; 8];
        eight.iter_mut().zip(flags).for_each(|(b, &f)| *b = u8::from(f));
        *byte = (u64::from_le_bytes(eight).wrapping_mul(0x0102_0408_1020_4080) >> 56) as u8;
    }
    bytes
}

/// Writes `selected` into a set's flag buffer ([`selection_words`]), drawn in the frame that writes it
/// ([`fascicle_render::modify_now`]).
pub(crate) fn write_flags(
    buffers: &mut Assets<ShaderBuffer>,
    events: &mut MessageWriter<AssetEvent<ShaderBuffer>>,
    flags: &Handle<ShaderBuffer>,
    selected: &[bool],
) {
    let bytes = selection_words(selected);
    fascicle_render::modify_now(buffers, events, flags, |b| b.data = Some(bytes));
}

/// What a set's shaders read of its selection (the flag buffer) and, for a set that keeps its streamlines,
/// the selection target ROIs act on.
struct Selection {
    flags: Handle<ShaderBuffer>,
    target: Option<(TractSet, TractSelection)>,
}

/// The selection of a tractogram: every streamline selected, its spatial index `index`, its first streamline
/// the layer's `first`.
fn tract_set(
    buffers: &mut Assets<ShaderBuffer>,
    tractogram: SetStreamlines,
    index: LazyIndex,
    first: usize,
) -> Selection {
    let n_streamlines = tractogram.n_streamlines();
    let flags = all_selected(buffers, n_streamlines);
    let set = TractSet { tractogram, index, selected: flags.clone(), first };
    Selection { flags, target: Some((set, TractSelection(vec![true; n_streamlines]))) }
}

/// Makes `e` a tract set of prepared tracts (tubes, lines or polygon tubes; `opacity` applies to meshes): what
/// [`placed::PlacedTracts`] asks for.
pub(crate) fn insert_prepared(
    e: &mut EntityCommands,
    meshes: &mut Assets<Mesh>,
    (tube_materials, mesh_materials): (&mut Assets<TubeletMaterial>, &mut Assets<TractMeshMaterial>),
    buffers: &mut Assets<ShaderBuffer>,
    prepared: PreparedTracts,
    opacity: f32,
) {
    let PreparedTracts { tractogram, n_streamlines, index, geometry, first } = prepared;
    let target = match tractogram {
        Some(t) => tract_set(buffers, t, index, first),
        None => Selection { flags: all_selected(buffers, n_streamlines), target: None },
    };
    match geometry {
        PreparedGeometry::Tubes { packed, n_tubelets, settings, boxes, preview } => {
            let tubes = (&packed[..], n_tubelets, *boxes, preview.map(|p| *p));
            insert_tube_set(e, meshes, tube_materials, buffers, target, tubes, settings)
        }
        PreparedGeometry::Mesh { mesh, preview, lines_tolerance_mm } => {
            let mesh = (*mesh, preview.map(|p| *p), lines_tolerance_mm);
            insert_mesh_set(e, meshes, mesh_materials, target, mesh, opacity)
        }
    }
}

/// A tract set drawn as hyperstreamlines from its packed tubelets.
#[allow(clippy::too_many_arguments, reason = "the asset stores, the set and its tubelets")]
fn spawn_tube_set(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<TubeletMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    selection: Selection,
    tubes: (&[u8], usize, Mesh, Option<Mesh>),
    settings: TubeSettings,
) -> Entity {
    let mut e = commands.spawn_empty();
    insert_tube_set(&mut e, meshes, materials, buffers, selection, tubes, settings);
    e.id()
}

/// [`spawn_tube_set`]'s components, onto `e`.
#[allow(clippy::too_many_arguments, reason = "the asset stores, the set and its tubelets")]
fn insert_tube_set(
    e: &mut EntityCommands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<TubeletMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    selection: Selection,
    (packed, n_tubelets, proxies, preview): (&[u8], usize, Mesh, Option<Mesh>),
    settings: TubeSettings,
) {
    let material = materials.add(TubeletMaterial {
        params: (&settings).into(),
        tubes: buffers.add(ShaderBuffer::new(packed, RenderAssetUsages::RENDER_WORLD)),
        selected: selection.flags,
    });
    let full = meshes.add(proxies);
    let preview = preview.map(|p| meshes.add(p));
    // The streamline bits of each tubelet's fifth vec4 ([`pack`]).
    let streamline_of = (0..n_tubelets)
        .map(|k| packed.get(112 * k + 76..112 * k + 80).map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]])))
        .collect();
    e.insert((
        TubeSet {
            material: material.clone(),
            n_tubelets,
            full: full.clone(),
            preview: preview.clone(),
            settings,
            streamline_of,
        },
        Transform::default(),
        Visibility::default(),
    ));
    if let Some(target) = selection.target {
        e.insert(target);
    }
    if n_tubelets > 0 {
        e.insert((Mesh3d(full.clone()), MeshMaterial3d(material), NoFrustumCulling));
        // While the frame budget is coarse (a frame at the smallest render scale still over budget, the cost
        // being tubelet proxies and their overdraw, which render scale does not lower), the preview draws.
        if let Some(preview) = preview {
            e.insert(fascicle_render::budget::CoarseMesh { full, preview });
        }
    }
}

/// A tract set drawn as a mesh (lines or polygon tubes).
fn spawn_mesh_set(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<TractMeshMaterial>,
    selection: Selection,
    mesh: (Mesh, Option<Mesh>, Option<f64>),
    opacity: f32,
) -> Entity {
    let mut e = commands.spawn_empty();
    insert_mesh_set(&mut e, meshes, materials, selection, mesh, opacity);
    e.id()
}

/// [`spawn_mesh_set`]'s components, onto `e`: the whole mesh, its preview (lines: kept on the CPU too,
/// [`PreviewLines`]) and, for lines coloured by direction, the tolerance the lines of a selection are made
/// with ([`SelectedLines`]).
fn insert_mesh_set(
    e: &mut EntityCommands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<TractMeshMaterial>,
    selection: Selection,
    (mesh, preview, lines_tolerance_mm): (Mesh, Option<Mesh>, Option<f64>),
    opacity: f32,
) {
    if let Some(lines) = preview.as_ref().and_then(PreviewLines::of) {
        e.insert((lines, FlagsBehind::default()));
    }
    if let Some(tolerance) = lines_tolerance_mm {
        e.insert(SelectedLines::new(tolerance));
    }
    let preview = preview.map(|p| meshes.add(p));
    let params = TractMeshUniform::whole(opacity);
    let material = materials.add(TractMeshMaterial { params, selected: selection.flags });
    let line_segments = line_segments(&mesh);
    let bounds = mesh.compute_aabb();
    let full = meshes.add(mesh);
    e.insert((
        MeshSet { material: material.clone(), full: full.clone(), preview },
        LineSegments(line_segments),
        Mesh3d(full),
        MeshMaterial3d(material),
        Transform::default(),
        Visibility::default(),
    ));
    // The whole mesh's bounds, kept: they hold its preview too (narrowed or not), and Bevy would compute them
    // again from a narrowed preview, never again from the whole mesh (its data is in the render world alone).
    if let Some(bounds) = bounds {
        e.insert((bounds, NoAutoAabb));
    }
    if let Some(target) = selection.target {
        e.insert(target);
    }
}

/// Spawns a tractogram as hyperstreamlines (optional per-point world tensors give the sections); returns
/// the set's entity (parent of its ROIs).
pub fn spawn_tubes(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<TubeletMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    tractogram: Arc<Tractogram>,
    tensors: Option<&[[f32; 6]]>,
    settings: &TubeSettings,
) -> Entity {
    let tubes = tract_tubelets(&tractogram, tensors, settings);
    let target = tract_set(buffers, SetStreamlines::Owned(tractogram), LazyIndex::default(), 0);
    let preview = tube_preview(&tubes).map(|slots| slot_boxes_of(&slots));
    let proxies = (&pack(&tubes)[..], tubes.len(), slot_boxes(tubes.len()), preview);
    spawn_tube_set(commands, meshes, materials, buffers, target, proxies, *settings)
}

/// Spawns a tractogram as lines coloured by segment direction; returns the set's entity (parent of its
/// ROIs).
pub fn spawn_lines(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<TractMeshMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    tractogram: Arc<Tractogram>,
    opacity: f32,
) -> Entity {
    let lines = (line_mesh(&tractogram), Some(preview_mesh(&tractogram, None)), Some(LINE_TOLERANCE_MM));
    let target = tract_set(buffers, SetStreamlines::Owned(tractogram), LazyIndex::default(), 0);
    spawn_mesh_set(commands, meshes, materials, target, lines, opacity)
}

/// Spawns a tractogram as polygon tubes (16 sides per ring, sections from the optional per-point world
/// tensors, as [`polygon_tube_mesh`]) with headlight shading; returns the set's entity (parent of its ROIs).
#[allow(clippy::too_many_arguments, reason = "the asset stores, the tractogram and its drawing options")]
pub fn spawn_polygon_tubes(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<TractMeshMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    tractogram: Arc<Tractogram>,
    tensors: Option<&[[f32; 6]]>,
    scale: f64,
    opacity: f32,
) -> Entity {
    let mesh = polygon_tube_mesh(&tractogram, tensors, scale, 16);
    let target = tract_set(buffers, SetStreamlines::Owned(tractogram), LazyIndex::default(), 0);
    spawn_mesh_set(commands, meshes, materials, target, (mesh, None, None), opacity)
}

/// A colour for a point of a streamline: (the streamline's index in its set, the point's index in the streamline,
/// the world point) to linear RGB.
pub type PointColour<'a> = &'a (dyn Fn(usize, usize, Vec3) -> [f32; 3] + Sync);

/// Colours each tubelet's two ends by `colour` at the points where its axis meets its cut planes (the
/// streamline's points).
pub fn recolour(tubes: &mut [fascicle_core::tubelet::Tubelet], colour: PointColour) {
    for t in tubes {
        let axis = t.rotation * glam::DVec3::X * t.half_length;
        let at = |k: u32, p: glam::DVec3| {
            glam::DVec3::from(colour(t.streamline as usize, k as usize, p.as_vec3()).map(f64::from))
        };
        t.colours = [at(t.point, t.centre - axis), at(t.point + 1, t.centre + axis)];
    }
}

/// The default tolerance of line meshes, mm ([`Compression`]): a tenth of a millimetre, below a pixel at any
/// zoom that shows a whole brain.
pub const LINE_TOLERANCE_MM: f64 = 0.1;

/// Line segments of every streamline, compressed to [`LINE_TOLERANCE_MM`], coloured by local direction.
pub fn line_mesh(t: &Tractogram) -> Mesh {
    line_mesh_coloured(t, None, LINE_TOLERANCE_MM)
}

/// The lines of `t`: each streamline compressed to `tolerance_mm` ([`fascicle_core::compress`]; 0 keeps
/// every point but exactly collinear ones), its kept points coloured by `colour` when given, else by the
/// direction between their kept neighbours (the one neighbour at an end), |x y z| as RGB.
///
/// One vertex per kept point, shared by the two segments that meet there (an indexed line list), in the
/// compact format of [`TractMeshMaterial`]: 20 bytes a point and 8 a segment (36 and 8 uncompressed with
/// Bevy's standard attributes before).
pub fn line_mesh_coloured(t: &Tractogram, colour: Option<PointColour>, tolerance_mm: f64) -> Mesh {
    strided_line_mesh(t, colour, tolerance_mm, 1)
}

/// One streamline in this many is in a line set's preview ([`TractDetail`]).
pub const PREVIEW_STRIDE: usize = 16;
/// The compression tolerance of previews, mm: half a millimetre, about a pixel of a whole brain at 1080p.
pub const PREVIEW_TOLERANCE_MM: f64 = 0.5;

/// How finely a tractogram's lines are drawn: the compression tolerance of the whole lines and the stride of
/// their preview. A tractogram larger than this machine's memory allows at full detail is drawn coarser
/// ([`LineDetail::for_points`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LineDetail {
    /// Compression tolerance of the whole lines, mm (default [`LINE_TOLERANCE_MM`], 0.1).
    pub tolerance_mm: f64,
    /// One streamline in this many is in the preview (default [`PREVIEW_STRIDE`], 16).
    pub preview_stride: usize,
    /// Whether a selection of few streamlines draws lines of its own ([`SelectedLines`]; default true, false
    /// above [`COARSE_DETAIL_POINTS`]: a 10M-streamline layer's viewer then peaked at 7.0-7.9 GiB instead of
    /// 6.4-6.5, over #33's 8 GB in one run).
    pub selected_lines: bool,
}

impl Default for LineDetail {
    fn default() -> Self {
        Self { tolerance_mm: LINE_TOLERANCE_MM, preview_stride: PREVIEW_STRIDE, selected_lines: true }
    }
}

/// Points of a tractogram drawn at the default detail: 50M (500k streamlines of 100 points), about 11M line
/// segments at 0.1 mm, a whole frame of about 3 s on lavapipe with 2 cores. Above, lines are compressed to
/// [`WHOLE_BRAIN_TOLERANCE_MM`].
pub const FULL_DETAIL_POINTS: u64 = 50_000_000;
/// The compression tolerance of tractograms over [`FULL_DETAIL_POINTS`], mm: a quarter of a millimetre, a
/// pixel of a whole brain (about 180 mm) seen in a 720-pixel view. It keeps 13 % of the points of a
/// whole-brain tractogram at 1 mm steps where 0.1 mm keeps 22 %: 1M streamlines draw 13M segments instead of
/// 22M (a whole frame of about 4 s instead of 6.4 s on lavapipe).
pub const WHOLE_BRAIN_TOLERANCE_MM: f64 = 0.25;
/// Points above which lines are compressed to [`PREVIEW_TOLERANCE_MM`]: 230M (2.3M streamlines of 100
/// points), about 25M segments at 0.5 mm (0.7 GB of vertices and indices).
pub const COARSE_DETAIL_POINTS: u64 = 230_000_000;
/// Line segments a preview aims at, whatever the tractogram's size: 750k, about a 1M whole brain's preview
/// (every 16th streamline at 0.5 mm: 715k), whose moving frames keep within the 100 ms budget on lavapipe with
/// 2 cores; 10M streamlines with 1.5M took 144 ms a moving frame.
pub const PREVIEW_SEGMENTS: u64 = 750_000;

impl LineDetail {
    /// The detail for a tractogram of about `points` points (a header's count, or a file's size over 12
    /// bytes): the default up to [`FULL_DETAIL_POINTS`]; up to [`COARSE_DETAIL_POINTS`], whole lines
    /// compressed to [`WHOLE_BRAIN_TOLERANCE_MM`] and the default preview; above, whole lines compressed to
    /// [`PREVIEW_TOLERANCE_MM`] (about half the segments of 0.1 mm: 10M streamlines in about 3 GB) and a
    /// preview stride that keeps the preview near [`PREVIEW_SEGMENTS`] (0.5 mm keeps about 11 % of the points
    /// of a whole-brain tractogram at 1 mm steps), and no lines of a selection's own.
    pub fn for_points(points: u64) -> Self {
        if points <= FULL_DETAIL_POINTS {
            return Self::default();
        }
        if points <= COARSE_DETAIL_POINTS {
            return Self { tolerance_mm: WHOLE_BRAIN_TOLERANCE_MM, ..Self::default() };
        }
        let preview_stride = (points * 11 / 100).div_ceil(PREVIEW_SEGMENTS).max(PREVIEW_STRIDE as u64);
        Self { tolerance_mm: PREVIEW_TOLERANCE_MM, preview_stride: preview_stride as usize, selected_lines: false }
    }
}

/// The preview of `t`'s lines: every [`PREVIEW_STRIDE`]-th streamline (the first, then every 16th), compressed
/// to [`PREVIEW_TOLERANCE_MM`], in the format and colours of [`line_mesh_coloured`]; each vertex keeps its
/// streamline's index in `t`, so ROI selection and opacity act on it as on the whole mesh. About 3 % of the
/// whole mesh's segments (generated whole brain).
pub fn preview_mesh(t: &Tractogram, colour: Option<PointColour>) -> Mesh {
    strided_line_mesh(t, colour, PREVIEW_TOLERANCE_MM, PREVIEW_STRIDE)
}

/// [`line_mesh_coloured`] of every `stride`-th streamline.
fn strided_line_mesh(t: &Tractogram, colour: Option<PointColour>, tolerance_mm: f64, stride: usize) -> Mesh {
    line_list(t.iter().enumerate().step_by(stride.max(1)), colour, tolerance_mm)
}

/// [`line_mesh_coloured`] of the streamlines `of` yields (each its index in the set, which its vertices keep,
/// and its points): the one construction of whole lines, previews and the lines of a selection
/// ([`SelectedLines`]), so that each draws a streamline as the others do.
fn line_list<'a>(
    of: impl Iterator<Item = (usize, &'a [Vec3])>,
    colour: Option<PointColour>,
    tolerance_mm: f64,
) -> Mesh {
    let compression = Compression { tolerance_mm, ..Compression::default() };
    let (mut pos, mut col, mut ids) = (Vec::new(), Vec::new(), Vec::new());
    let mut idx: Vec<u32> = Vec::new();
    let mut kept = Vec::new();
    for (i, s) in of.filter(|(_, s)| s.len() >= 2) {
        kept.clear();
        kept_points(s, compression, &mut kept);
        let base = pos.len() as u32;
        for (k, &at) in kept.iter().enumerate() {
            let p = s[at as usize];
            let rgb = colour.map_or_else(
                || {
                    let (a, b) = (kept[k.saturating_sub(1)], kept[(k + 1).min(kept.len() - 1)]);
                    let d = (s[b as usize] - s[a as usize]).normalize_or_zero().abs();
                    [d.x, d.y, d.z]
                },
                |f| f(i, at as usize, p),
            );
            pos.push(p);
            col.push(rgba8(rgb));
            ids.push(i as u32);
        }
        idx.extend((0..kept.len() as u32 - 1).flat_map(|k| [base + k, base + k + 1]));
    }
    compact_line_list(pos, ids, col, idx)
}

/// An indexed line list in the compact format of [`TractMeshMaterial`] (main world's copy dropped once sent).
fn compact_line_list(pos: impl Into<VertexAttributeValues>, ids: Vec<u32>, col: Vec<[u8; 4]>, idx: Vec<u32>) -> Mesh {
    Mesh::new(PrimitiveTopology::LineList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, pos)
        .with_inserted_attribute(ATTRIBUTE_STREAMLINE, ids)
        .with_inserted_attribute(ATTRIBUTE_RGBA8, VertexAttributeValues::Unorm8x4(col))
        .with_inserted_indices(Indices::U32(idx))
}

/// The line segments a mesh draws: 0 unless it is a line list (indexed or not).
pub fn line_segments(mesh: &Mesh) -> usize {
    match mesh.primitive_topology() {
        PrimitiveTopology::LineList => mesh.indices().map_or(mesh.count_vertices(), |i| i.len()) / 2,
        _ => 0,
    }
}

/// The polygon-tube baseline mesh (`sides` per profile), coloured by local direction, in the compact format of
/// [`TractMeshMaterial`] (with normals).
pub fn polygon_tube_mesh(t: &Tractogram, tensors: Option<&[[f32; 6]]>, scale: f64, sides: usize) -> Mesh {
    let (mut pos, mut nrm, mut col, mut ids, mut idx) = (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for s in 0..t.offsets.len().saturating_sub(1) {
        let r = t.offsets[s]..t.offsets[s + 1];
        let pts: Vec<glam::DVec3> = t.points[r.clone()].iter().map(|p| p.as_dvec3()).collect();
        let tens: Option<Vec<[f64; 6]>> = tensors.map(|ts| ts[r].iter().map(|v| v.map(f64::from)).collect());
        let rings = polygon_rings(&pts, tens.as_deref(), scale, sides);
        if rings.is_empty() {
            continue;
        }
        let base = pos.len() as u32;
        for (i, (p, n)) in rings.iter().enumerate() {
            let k = (i / sides).min(pts.len() - 2);
            let d = (pts[k + 1] - pts[k]).normalize_or_zero().abs();
            pos.push(p.as_vec3().to_array());
            nrm.push(n.as_vec3().to_array());
            col.push(rgba8([d.x as f32, d.y as f32, d.z as f32]));
            ids.push(s as u32);
        }
        for ring in 0..pts.len() - 1 {
            for k in 0..sides {
                let a = base + (ring * sides + k) as u32;
                let b = base + (ring * sides + (k + 1) % sides) as u32;
                let (c, d) = (a + sides as u32, b + sides as u32);
                idx.extend([a, b, c, b, d, c]);
            }
        }
    }
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, pos)
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, nrm)
        .with_inserted_attribute(ATTRIBUTE_STREAMLINE, ids)
        .with_inserted_attribute(ATTRIBUTE_RGBA8, VertexAttributeValues::Unorm8x4(col))
        .with_inserted_indices(Indices::U32(idx))
}

/// What [`apply_rois`] reads and writes of a tract set: its selection, its layer, whether its flags wait.
type SelectedSet<'a> =
    (Entity, Ref<'a, TractSet>, &'a mut TractSelection, Option<&'a ChildOf>, Option<&'a mut FlagsBehind>);

/// Re-evaluates every tract set's selection when an ROI or a set changed (never otherwise), and rewrites
/// the sets' flag buffers (a line set's with a preview when it draws a mesh that reads them: [`FlagsBehind`]).
#[allow(clippy::type_complexity, clippy::too_many_arguments, reason = "a Bevy system's change filters")]
pub fn apply_rois(
    changed_rois: Query<
        (),
        Or<(Added<TractRoi>, Changed<TractRoi>, Changed<RoiRules>, Changed<DeletedStreamlines>, Changed<TractMasks>)>,
    >,
    roi_roster: Query<(), (With<TractRoi>, Or<(Added<TractRoi>, Changed<ChildOf>)>)>,
    (mut removed, mut removed_rules, mut removed_deletions, mut removed_masks, mut removed_sets): (
        RemovedComponents<TractRoi>,
        RemovedComponents<RoiRules>,
        RemovedComponents<DeletedStreamlines>,
        RemovedComponents<TractMasks>,
        RemovedComponents<TractSet>,
    ),
    rois: Query<(&TractRoi, Option<&ChildOf>)>,
    rules: Query<&RoiRules>,
    deleted: Query<&DeletedStreamlines>,
    masks: Query<&TractMasks>,
    mut sets: Query<SelectedSet>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
    mut buffer_events: MessageWriter<AssetEvent<ShaderBuffer>>,
    mut stats: ResMut<RoiStats>,
    (background, mut keep_awake, mut interacting): (
        Res<RoiBackground>,
        Option<ResMut<fascicle_render::KeepAwake>>,
        Option<ResMut<fascicle_render::budget::Interacting>>,
    ),
    (mut layer_runs, mut arrived_before): (Local<HashMap<Entity, LayerRun>>, Local<bool>),
) {
    let removed_rois = removed.read().count();
    let removed_any =
        removed_rois + removed_rules.read().count() + removed_deletions.read().count() + removed_masks.read().count()
            > 0;
    let arrived = sets.iter().any(|(_, s, _, _, _)| s.is_added());
    // The layers' runs change only when sets come or go, or ROIs do (or change layer); and in the frame after
    // sets arrived (a set is joined once no part of its layer arrives in the frame). A despawned layer's run and
    // index go at once.
    let sets_gone = removed_sets.read().count() > 0;
    if arrived || *arrived_before || sets_gone || removed_rois > 0 || !roi_roster.is_empty() {
        update_layer_runs(&mut layer_runs, &sets, &rois);
    }
    *arrived_before = arrived;
    // Layers selected in the background whose selection is done (or whose index is built meanwhile): their
    // sets take it in this frame.
    let layer_rois = |l: Entity| -> Vec<Roi> {
        rois.iter().filter(|(_, p)| p.is_none_or(|p| p.parent() == l)).map(|(r, _)| r.0).collect()
    };
    let mut news: HashMap<Entity, Kept> = HashMap::new();
    for (l, run) in layer_runs.iter_mut().filter(|(_, run)| run.background.is_some()) {
        if let Some(sel) = run.poll(&layer_rois(*l), &background) {
            news.insert(*l, sel);
        }
    }
    // A changed ROI re-selects every set; a new set (a layer's next part) only itself.
    let rois_changed = !changed_rois.is_empty() || removed_any;
    if !rois_changed && !arrived && news.is_empty() {
        note_pending(&layer_runs, &mut stats, (keep_awake.as_deref_mut(), interacting.as_deref_mut()));
        return;
    }
    let t0 = Instant::now();
    let mut selected = 0;
    // Per layer selected through its run: the whole layer's selection, made at its first set (`None`: made in
    // the background, the sets keep their flags meanwhile).
    let mut layer_selections: HashMap<Entity, Option<Kept>> = HashMap::new();
    for (entity, set, mut selection, layer, behind) in &mut sets {
        let news_for_layer = layer.is_some_and(|l| news.contains_key(&l.parent()));
        if !rois_changed && !set.is_added() && !news_for_layer {
            selected += selection.0.iter().filter(|s| **s).count();
            continue;
        }
        // An ROI acts on its parent set, on the sets of its parent layer, or (without a parent) on all.
        let owner = |p: &ChildOf| p.parent() == entity || layer.is_some_and(|l| l.parent() == p.parent());
        let list: Vec<Roi> = rois.iter().filter(|(_, parent)| parent.is_none_or(owner)).map(|(r, _)| r.0).collect();
        let ends_only = on_set_or_layer(&rules, entity, layer).is_some_and(|r| r.ends_only);
        let masked = on_set_or_layer(&masks, entity, layer);
        let deletions = on_set_or_layer(&deleted, entity, layer);
        let t = &set.tractogram;
        // The layer's run, when it was joined from this set among others and the ROIs are the layer's.
        let joined = layer.map(ChildOf::parent).filter(|l| {
            layer_runs.get(l).is_some_and(|run| {
                let part = run.parts.binary_search_by_key(&set.first, |p| p.1);
                part.is_ok_and(|k| run.parts[k].0 == entity) && layer_rois(*l) == list
            })
        });
        let mut sel = if list.is_empty() {
            vec![true; t.n_streamlines()]
        } else if ends_only {
            fascicle_core::roi::select_ends(t, &list)
        } else if let Some(l) = joined {
            let run = layer_runs.get_mut(&l).expect("a joined layer has its run");
            let whole = layer_selections.entry(l).or_insert_with(|| match news.remove(&l) {
                Some(done) => Some(done),
                None => run.select(&list, &background),
            });
            let Some(whole) = whole else {
                // Selected in the background: the set keeps its flags until then.
                selected += selection.0.iter().filter(|s| **s).count();
                continue;
            };
            let from = set.first - run.first;
            let part = from..from + t.n_streamlines();
            // A part the step left as it was is neither made again nor packed (most of a layer, away from the
            // ROI).
            if !set.is_changed()
                && masked.is_none()
                && deletions.is_none()
                && whole.same_flags(part.clone(), &selection.0)
            {
                selected += whole.count_in(part);
                continue;
            }
            whole.flags(part)
        } else if let SetStreamlines::Mapped(_) = t {
            // A part read in place whose layer has no run yet (its parts still arriving): every streamline
            // tested, and no index of the part's own (the layer's is made once its parts are in).
            select_every(t, &list)
        } else {
            set.index.select(t, &list)
        };
        if let Some(m) = masked {
            m.narrow(t, ends_only, &mut sel);
        }
        if (ends_only && !list.is_empty()) || masked.is_some() {
            // A pass over every streamline: what it read in place goes again.
            t.release();
        }
        for &s in deletions.iter().flat_map(|d| d.0.iter()) {
            if let Some(k) = (s as usize).checked_sub(set.first).and_then(|s| sel.get_mut(s)) {
                *k = false;
            }
        }
        selected += sel.iter().filter(|s| **s).count();
        // A set whose selection stays as it was keeps its flags: an ROI drag re-selects every part of a layer,
        // and the parts away from the ROI upload nothing and rebuild no tube proxies.
        if !set.is_changed() && selection.0 == sel {
            continue;
        }
        selection.0 = sel;
        // A line set with a preview takes its flags when it draws a mesh that reads them (upload_flags_behind).
        if let Some(mut behind) = behind {
            behind.bypass_change_detection().0 = true;
            continue;
        }
        // Drawn in this frame: the selection runs after the asset events' flush.
        write_flags(&mut buffers, &mut buffer_events, &set.selected, &selection.0);
    }
    stats.evaluations += 1;
    stats.last_ms = t0.elapsed().as_secs_f64() * 1e3;
    stats.selected = selected;
    stats.joined_layers = layer_selections.len();
    note_pending(&layer_runs, &mut stats, (keep_awake.as_deref_mut(), interacting.as_deref_mut()));
}

/// Counts the layers selected in the background into `stats`; while there are any, a window drawn on demand
/// looks again (without redrawing a picture that did not change) until they are done, and while one is
/// selected through its index (a drag's step, not a layer's first selection while it opens) the interaction
/// that moved its ROIs is not over ([`fascicle_render::budget::Interacting::pending`]).
fn note_pending(
    layer_runs: &HashMap<Entity, LayerRun>,
    stats: &mut RoiStats,
    (keep_awake, interacting): (
        Option<&mut fascicle_render::KeepAwake>,
        Option<&mut fascicle_render::budget::Interacting>,
    ),
) {
    let pending = || layer_runs.values().filter_map(|run| run.background.as_ref());
    let before = std::mem::replace(&mut stats.pending_layers, pending().count());
    if let Some(keep) = keep_awake {
        if stats.pending_layers > 0 {
            keep.busy();
        } else if before > 0 {
            // The last one landed (or went with its layer): the next frame finds none pending, and draws at full
            // quality after a drag.
            keep.redraw();
        }
    }
    if pending().any(|b| b.indexed)
        && let Some(interacting) = interacting
    {
        interacting.pending();
    }
}

/// One run over every part of a tract layer read in place from one file, and its index: an ROI is tested on the
/// whole layer through one index (and one drag's margins) instead of one per part, which a 10M-streamline layer
/// in 4,400 parts could not afford (each part's index and drag, and until built, every part's streamlines read).
/// Kept in [`apply_rois`] per layer entity; made once a layer with ROIs reads every part in place, one after
/// another from one file, and no part arrived in the frame; its index is then started in the background.
pub struct LayerRun {
    /// The parts it was joined from, in order: (set, the layer's index of its first streamline).
    parts: Vec<(Entity, usize)>,
    /// The layer's index of the run's first streamline.
    first: usize,
    /// The parts' streamlines, joined.
    streamlines: SetStreamlines,
    /// Its index and drag margins.
    index: LazyIndex,
    /// The selection made in the background ([`RoiBackground`]).
    background: Option<Background>,
}

/// A layer's selection on a thread of its own: the ROIs it selects for, and where it arrives.
struct Background {
    rois: Vec<Roi>,
    done: std::sync::mpsc::Receiver<Kept>,
    /// Made through the built index (a drag's step, a second or two at 10M streamlines), not by testing every
    /// streamline (minutes, while a layer opens).
    indexed: bool,
}

impl LayerRun {
    /// The run's selection for `rois`, at once when [`RoiBackground::in_frame`] says so (through its index
    /// when built); otherwise `None`, and the selection is made in the background (started now unless one is
    /// under way; [`LayerRun::poll`] hands it over).
    fn select(&mut self, rois: &[Roi], settings: &RoiBackground) -> Option<Kept> {
        let built = self.index.ready_or_build(&self.streamlines).is_some();
        if settings.in_frame(self.streamlines.n_streamlines(), built) {
            self.background = None;
            return Some(self.index.select_kept(&self.streamlines, rois));
        }
        if self.background.is_none() { self.start(rois, built) } else { None }
    }

    /// Starts the selection for `rois` on a thread of its own (`None`): through the index when built (keeping
    /// the drag's margins), else every streamline tested; without a thread, selects in the frame. `indexed`:
    /// whether the index is built (read by [`note_pending`]).
    fn start(&mut self, rois: &[Roi], indexed: bool) -> Option<Kept> {
        let (send, done) = std::sync::mpsc::channel();
        let (t, list, index) = (self.streamlines.clone(), rois.to_vec(), self.index.clone());
        let spawned = std::thread::Builder::new().name("tract selection".into()).spawn(move || {
            let select = || index.select_kept(&t, &list);
            _ = send.send(match selection_pool() {
                Some(pool) => pool.install(select),
                None => select(),
            })
        });
        match spawned {
            Ok(_) => {
                self.background = Some(Background { rois: rois.to_vec(), done, indexed });
                None
            }
            Err(e) => {
                warn!("a tract layer is selected in the frame: no thread for it ({e})");
                Some(self.index.select_kept(&self.streamlines, rois))
            }
        }
    }

    /// The selection made in the background, when it is done (a newer one is then started if the ROIs are no
    /// longer `rois`, the layer's now), or the index's for `rois` once the index is built and
    /// [`RoiBackground::in_frame`] lets it be made in the frame; `None` meanwhile.
    fn poll(&mut self, rois: &[Roi], settings: &RoiBackground) -> Option<Kept> {
        let background = self.background.as_ref()?;
        let built = self.index.ready_or_build(&self.streamlines).is_some();
        if built && settings.in_frame(self.streamlines.n_streamlines(), true) {
            self.background = None;
            return Some(self.index.select_kept(&self.streamlines, rois));
        }
        match background.done.try_recv() {
            Ok(sel) => {
                let stale = background.rois != rois;
                self.background = None;
                // Shown as it is, and the ROIs as they are now selected next.
                if stale && let Some(now) = self.start(rois, built) {
                    return Some(now);
                }
                Some(sel)
            }
            Err(std::sync::mpsc::TryRecvError::Empty) => None,
            Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                self.background = None;
                Some(self.index.select_kept(&self.streamlines, rois))
            }
        }
    }
}

/// Makes, remakes or forgets each layer's [`LayerRun`] from the sets as they are: a layer with ROIs (its own or
/// unparented) whose sets all read one file in place, one after another, and none of which arrived in this
/// frame, has its run; its index is asked for at once (the background builder).
fn update_layer_runs(
    layer_runs: &mut HashMap<Entity, LayerRun>,
    sets: &Query<SelectedSet>,
    rois: &Query<(&TractRoi, Option<&ChildOf>)>,
) {
    let mut parts: HashMap<Entity, Vec<(Entity, usize, Arc<MappedRun>)>> = HashMap::new();
    let mut not_joined: Vec<Entity> = vec![];
    for (e, set, _, layer, _) in sets {
        let Some(l) = layer.map(ChildOf::parent) else { continue };
        match &set.tractogram {
            SetStreamlines::Mapped(run) if !set.is_added() => {
                parts.entry(l).or_default().push((e, set.first, run.clone()))
            }
            _ => not_joined.push(l),
        }
    }
    not_joined.iter().for_each(|l| _ = parts.remove(l));
    layer_runs.retain(|l, _| parts.contains_key(l) || not_joined.contains(l));
    for (l, mut parts) in parts {
        if !rois.iter().any(|(_, p)| p.is_none_or(|p| p.parent() == l)) {
            layer_runs.remove(&l);
            continue;
        }
        parts.sort_unstable_by_key(|p| p.1);
        if layer_runs
            .get(&l)
            .is_some_and(|r| r.parts.len() == parts.len() && r.parts.iter().zip(&parts).all(|(a, b)| *a == (b.0, b.1)))
        {
            continue;
        }
        let follow = parts.windows(2).all(|w| w[0].1 + w[0].2.n_streamlines() == w[1].1);
        let runs: Vec<&MappedRun> = parts.iter().map(|p| &*p.2).collect();
        match MappedRun::join(&runs).filter(|_| follow) {
            Some(run) => {
                let run = LayerRun {
                    parts: parts.iter().map(|p| (p.0, p.1)).collect(),
                    first: parts[0].1,
                    streamlines: SetStreamlines::Mapped(Arc::new(run)),
                    index: LazyIndex::default(),
                    background: None,
                };
                run.index.ready_or_build(&run.streamlines);
                layer_runs.insert(l, run);
            }
            None => _ = layer_runs.remove(&l),
        }
    }
}

/// A tract set's own `T`, else its layer's (the set's parent).
fn on_set_or_layer<'a, T: Component>(q: &'a Query<&T>, set: Entity, layer: Option<&ChildOf>) -> Option<&'a T> {
    q.get(set).ok().or_else(|| layer.and_then(|l| q.get(l.parent()).ok()))
}

/// Hyperstreamline sets draw the proxies of their selected tubelets only: when a set's selection changes, its
/// proxy meshes (the whole set's and the preview's) are rebuilt from the selected tubelets, in the frame the
/// selection changed (as the flag buffer). A tubelet's proxy costs its vertices and triangles whether its
/// streamline is hidden or not (the vertex shader moves a hidden one off screen), so a set whose ROI keeps a
/// few streamlines draws that few; a selection of none keeps one hidden proxy. A new set whose selection keeps
/// every streamline keeps the proxies it was spawned with; one whose selection hides some is rebuilt in its
/// second frame.
pub fn select_tube_boxes(
    sets: Query<(Entity, Ref<TubeSet>, Ref<TractSelection>)>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut mesh_events: MessageWriter<AssetEvent<Mesh>>,
    mut deferred: Local<bevy::ecs::entity::EntityHashSet>,
) {
    let due = std::mem::take(&mut *deferred);
    for (entity, set, selection) in &sets {
        if !(selection.is_changed() || due.contains(&entity)) || set.n_tubelets == 0 {
            continue;
        }
        let sel = &selection.0;
        let kept = |k: &usize| sel.get(set.streamline_of[*k] as usize).copied().unwrap_or(true);
        let slots: Vec<u32> = (0..set.n_tubelets).filter(kept).map(|k| k as u32).collect();
        if selection.is_added() && slots.len() == set.n_tubelets {
            continue;
        }
        if set.is_added() {
            // Spawned this frame: its meshes' first upload may come after this frame's (a mesh replaced
            // before it would be extracted twice, the second time with no data), so the rebuild waits a frame;
            // meanwhile the flags hide the unselected proxies.
            deferred.insert(entity);
            continue;
        }
        let or_one = |s: &[u32]| if s.is_empty() { slot_boxes_of(&[0]) } else { slot_boxes_of(s) };
        let of = |k: &u32| in_tube_preview(set.streamline_of[*k as usize]);
        let preview = set.preview.as_ref().map(|p| (p, or_one(&slots.iter().copied().filter(of).collect::<Vec<_>>())));
        for (handle, mesh) in [(&set.full, or_one(&slots))].into_iter().chain(preview) {
            fascicle_render::modify_now(&mut meshes, &mut mesh_events, handle, |m| *m = mesh);
        }
    }
}

/// Outlines every ROI in the 3D view (where gizmos are available: the viewer): includes green, excludes red.
pub fn draw_rois(mut gizmos: Gizmos, rois: Query<&TractRoi>) {
    use fascicle_core::roi::{RoiMode, RoiShape};
    for r in &rois {
        let colour = match r.0.mode {
            RoiMode::Include => Color::linear_rgb(0.2, 1.0, 0.3),
            RoiMode::Exclude => Color::linear_rgb(1.0, 0.2, 0.2),
        };
        match r.0.shape {
            RoiShape::Sphere { centre, radius } => {
                gizmos.sphere(Isometry3d::from_translation(Vec3::from(centre)), radius, colour);
            }
            RoiShape::Box { min, max } => {
                let (lo, hi) = (Vec3::from(min), Vec3::from(max));
                gizmos.cube(Transform::from_translation((lo + hi) / 2.0).with_scale(hi - lo), colour);
            }
            RoiShape::Plane { point, normal } => {
                let n = Vec3::from(normal).normalize_or(Vec3::Z);
                let rot = Quat::from_rotation_arc(Vec3::Z, n);
                gizmos.rect(Isometry3d::new(Vec3::from(point), rot), Vec2::splat(60.0), colour);
            }
        }
    }
}

/// The selected streamlines of a set as a new tractogram (for saving as `.trk`/`.tck`).
pub fn selected_tractogram(set: &TractSet, selection: &TractSelection) -> Tractogram {
    set.tractogram.subset(&selection.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The detail coarsens with size, never finer for a larger file: 0.1 mm for the 33k-streamline bundle,
    /// 0.25 mm for 1M streamlines of 104 points, 0.5 mm for 10M with a preview stride keeping about
    /// [`PREVIEW_SEGMENTS`].
    #[test]
    fn detail_coarsens_with_the_tractogram_size() {
        assert_eq!(LineDetail::for_points(3_400_000), LineDetail::default());
        let whole_brain = LineDetail::for_points(104_000_000);
        assert_eq!((whole_brain.tolerance_mm, whole_brain.preview_stride), (0.25, PREVIEW_STRIDE));
        let huge = LineDetail::for_points(1_040_000_000);
        assert_eq!(huge.tolerance_mm, PREVIEW_TOLERANCE_MM);
        let preview_segments = 1_040_000_000.0 * 0.11 / huge.preview_stride as f64;
        assert!((0.65e6..=0.75e6).contains(&preview_segments), "{preview_segments}");
        let sizes = [0, FULL_DETAIL_POINTS, FULL_DETAIL_POINTS + 1, COARSE_DETAIL_POINTS, COARSE_DETAIL_POINTS + 1];
        for w in sizes.windows(2) {
            let (a, b) = (LineDetail::for_points(w[0]), LineDetail::for_points(w[1]));
            assert!(a.tolerance_mm <= b.tolerance_mm && a.preview_stride <= b.preview_stride, "{w:?}");
        }
    }

    /// A narrowed preview holds the selected streamlines' vertices, each with its streamline, position and
    /// colour as in the whole preview, joined only within a streamline; with none selected, the first.
    #[test]
    fn a_narrowed_preview_is_the_selected_streamlines_of_the_preview() {
        let mut t = Tractogram::new();
        for i in 0..5 {
            let s: Vec<Vec3> = (0..6 + i).map(|k| Vec3::new(k as f32, (k * k) as f32 * 0.3, i as f32)).collect();
            t.push(&s);
        }
        let whole = strided_line_mesh(&t, None, 0.0, 1);
        let lines = PreviewLines::of(&whole).expect("a line list in the compact format");
        type Attributes = (Vec<[f32; 3]>, Vec<u32>, Vec<[u8; 4]>, Vec<u32>);
        let attrs = |m: &Mesh| -> Attributes {
            match (
                m.attribute(Mesh::ATTRIBUTE_POSITION),
                m.attribute(ATTRIBUTE_STREAMLINE),
                m.attribute(ATTRIBUTE_RGBA8),
                m.indices(),
            ) {
                (
                    Some(VertexAttributeValues::Float32x3(p)),
                    Some(VertexAttributeValues::Uint32(ids)),
                    Some(VertexAttributeValues::Unorm8x4(c)),
                    Some(Indices::U32(idx)),
                ) => (p.clone(), ids.clone(), c.clone(), idx.clone()),
                _ => panic!("compact line mesh"),
            }
        };
        let (wp, wids, wc, _) = attrs(&whole);
        let keep = [true, false, false, true, false];
        let (narrowed, unflagged) = lines.selected(&keep);
        let (p, ids, c, idx) = attrs(&narrowed);
        let expect: Vec<usize> = (0..wids.len()).filter(|&v| keep[wids[v] as usize]).collect();
        // Drawn without the set's flags: every vertex shown.
        assert!(unflagged && ids.iter().all(|&id| id == UNFLAGGED), "{ids:?}");
        assert_eq!(p, expect.iter().map(|&v| wp[v]).collect::<Vec<_>>());
        assert_eq!(c, expect.iter().map(|&v| wc[v]).collect::<Vec<_>>());
        // Streamlines 0 and 3 keep their 6 and 9 points: 5 + 8 segments, none between the two.
        assert_eq!((ids.len(), idx.len()), (15, 26));
        let streamline = |v: u32| wids[expect[v as usize]];
        assert!(idx.chunks(2).all(|s| s[1] == s[0] + 1 && streamline(s[0]) == streamline(s[1])));
        // None kept: the first streamline with its index, hidden by the flags it then reads.
        let (none, unflagged) = lines.selected(&[false; 5]);
        let (_, none, _, none_idx) = attrs(&none);
        assert_eq!((none, none_idx.len(), unflagged), (vec![0; 6], 10, false));
        assert_eq!(attrs(&lines.selected(&[true; 5]).0).3, attrs(&whole).3);
    }

    /// A preview holds streamlines 0, 16, 32 of 40, each vertex one of that streamline's points, in fewer
    /// segments than the whole mesh (a coarser tolerance), its ends kept.
    #[test]
    fn a_preview_is_every_sixteenth_streamline_more_compressed() {
        let mut t = Tractogram::new();
        for i in 0..40 {
            let s: Vec<Vec3> = (0..60)
                .map(|k| {
                    let a = k as f32 * 0.1;
                    Vec3::new(10.0 * a.cos() + i as f32, 10.0 * a.sin(), 0.5 * k as f32)
                })
                .collect();
            t.push(&s);
        }
        let (full, preview) = (line_mesh(&t), preview_mesh(&t, None));
        let ids = |m: &Mesh| match m.attribute(ATTRIBUTE_STREAMLINE) {
            Some(VertexAttributeValues::Uint32(v)) => v.clone(),
            _ => panic!("streamline ids"),
        };
        let pos = match preview.attribute(Mesh::ATTRIBUTE_POSITION) {
            Some(VertexAttributeValues::Float32x3(v)) => v.clone(),
            _ => panic!("positions"),
        };
        let mut kept: Vec<u32> = ids(&preview);
        for (p, &i) in pos.iter().zip(&kept) {
            assert!(t.streamline(i as usize).contains(&Vec3::from_array(*p)), "vertex {p:?} not on streamline {i}");
        }
        kept.dedup();
        assert_eq!(kept, [0, 16, 32]);
        for i in [0usize, 16, 32] {
            let s = t.streamline(i);
            assert!(pos.contains(&s[0].to_array()) && pos.contains(&s[s.len() - 1].to_array()), "ends of {i}");
        }
        let per_full = line_segments(&full) as f64 / 40.0;
        let per_preview = line_segments(&preview) as f64 / 3.0;
        assert!(per_preview < per_full, "preview {per_preview} segments a streamline, whole {per_full}");
    }

    #[test]
    fn previews_only_while_active_and_over_the_limit() {
        let ms = std::time::Duration::from_millis;
        assert!(use_previews(Some(ms(100)), ms(300), 2_000_000, 1_000_000));
        assert!(!use_previews(Some(ms(300)), ms(300), 2_000_000, 1_000_000), "still for still_after");
        assert!(!use_previews(None, ms(300), 2_000_000, 1_000_000), "nothing ever moved");
        assert!(!use_previews(Some(ms(0)), ms(300), 1_000_000, 1_000_000), "within the limit");
    }

    /// `n` parallel streamlines of 11 points 1 mm apart (10 tubelets each), streamline `s` at x = `s` mm.
    fn parallel_tracts(n: usize) -> Tractogram {
        let mut t = Tractogram::new();
        for s in 0..n {
            t.push(&(0..11).map(|k| Vec3::new(s as f32, k as f32, 0.0)).collect::<Vec<_>>());
        }
        t
    }

    /// A layer's run without its index selects in the background: the first call hands nothing over (the
    /// parts keep their flags), `poll` hands over the selection every streamline tested would make; ROIs
    /// changed meanwhile are selected next (or through the index, once built); with the index built, the
    /// selection is made at once, through it.
    #[test]
    fn a_large_layer_without_its_index_is_selected_in_the_background() {
        use fascicle_core::io::mapped::{MappedPoints, MappedRun};
        use fascicle_core::roi::{RoiMode, RoiShape};
        let t = parallel_tracts(2000);
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("parallel.tck");
        fascicle_core::io::tck::write(&path, &t, &[]).unwrap();
        let file = Arc::new(MappedPoints::open(&path).unwrap());
        let streamlines = SetStreamlines::Mapped(Arc::new(MappedRun::consecutive(file, 0, &t).unwrap()));
        let sphere =
            |x: f32| [Roi { shape: RoiShape::Sphere { centre: [x, 5.0, 0.0], radius: 10.0 }, mode: RoiMode::Include }];
        let (a, b) = (sphere(100.0), sphere(1500.0));
        let want = |rois: &[Roi]| Kept::of_flags(&select_every(&streamlines, rois));
        let (want_a, want_b) = (want(&a), want(&b));
        assert_ne!(want_a, want_b);
        assert_eq!((want_a.count_in(0..2000), want_a.complement), (21, false));
        let mut run = LayerRun { parts: vec![], first: 0, streamlines, index: LazyIndex::default(), background: None };
        let settings = RoiBackground { above_streamlines: 1000, indexed_above_streamlines: 4000 };
        let poll_until = |run: &mut LayerRun, rois: &[Roi], settings: &RoiBackground| {
            let t0 = Instant::now();
            loop {
                if let Some(sel) = run.poll(rois, settings) {
                    return sel;
                }
                assert!(t0.elapsed().as_secs() < 60, "no selection after a minute");
                std::thread::sleep(std::time::Duration::from_millis(1));
            }
        };
        assert!(run.select(&a, &settings).is_none(), "selected in the frame without an index");
        // Not through the index: no interaction waits for it (`Interacting::pending`).
        assert!(run.background.as_ref().is_some_and(|b| !b.indexed));
        // The ROI moves to `b` before `a`'s selection is done.
        let first = poll_until(&mut run, &b, &settings);
        assert!(first == want_a || first == want_b, "neither a's selection nor b's");
        let last = if run.background.is_some() { poll_until(&mut run, &b, &settings) } else { first };
        assert_eq!(last, want_b, "b's selection did not follow a's");
        assert!(run.background.is_none());
        // Once the index is built: at once, through it.
        let t0 = Instant::now();
        while run.index.ready_or_build(&run.streamlines).is_none() {
            assert!(t0.elapsed().as_secs() < 60, "no index after a minute");
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        assert_eq!(run.select(&a, &settings), Some(want_a));
        assert!(run.background.is_none());
        // Above `indexed_above_streamlines`, built or not, in the background.
        let large = RoiBackground { indexed_above_streamlines: 1000, ..settings };
        assert!(run.select(&b, &large).is_none(), "selected in the frame above indexed_above_streamlines");
        assert!(run.background.as_ref().is_some_and(|b| b.indexed), "a drag's step waits for it");
        assert_eq!(poll_until(&mut run, &b, &large), want_b);
        // A run no larger than the setting is selected in the frame, built or not.
        let mut small = LayerRun { index: LazyIndex::default(), ..run };
        let at_most = RoiBackground { above_streamlines: 2000, indexed_above_streamlines: 2000 };
        assert_eq!(small.select(&b, &at_most), Some(want_b));
    }

    /// A [`TubeSet`] of `tubes` with every proxy, and its preview of `slots`, in `app`'s meshes.
    fn tube_set_with_preview(app: &mut App, tubes: &[Tubelet], slots: &[u32]) -> TubeSet {
        let mut meshes = app.world_mut().resource_mut::<Assets<Mesh>>();
        TubeSet {
            streamline_of: tubes.iter().map(|t| t.streamline).collect(),
            material: Handle::default(),
            n_tubelets: tubes.len(),
            full: meshes.add(slot_boxes(tubes.len())),
            preview: Some(meshes.add(slot_boxes_of(slots))),
            settings: TubeSettings::default(),
        }
    }

    /// A hyperstreamline set over the limit previews whole streamlines, one in 16; it draws the preview while
    /// the frame budget draws coarse (`BudgetState::coarse`, decided by `budget::next_coarse`: a frame at the
    /// smallest scale over budget) and the whole set otherwise.
    #[test]
    fn tube_previews_hold_whole_streamlines_and_follow_the_budget() {
        use fascicle_render::budget::BudgetState;
        let tubes = tract_tubelets(&parallel_tracts(2_500), None, &TubeSettings::default());
        assert_eq!(tubes.len(), 25_000);
        let slots = tube_preview(&tubes).expect("over the limit");
        // Streamlines 0, 16, 32, ..., 2,496, each with its 10 tubelets.
        assert_eq!(slots.len(), 157 * 10);
        assert!(slots.iter().all(|&i| tubes[i as usize].streamline.is_multiple_of(16)));
        assert!(tube_preview(&tubes[..TUBE_PREVIEW_MAX]).is_none());
        assert_eq!(slot_boxes_of(&slots).count_vertices(), 8 * slots.len());

        // Spawned, the set's entity draws its preview while the budget is coarse and the whole set otherwise.
        let mut app = App::new();
        app.add_plugins((MinimalPlugins, bevy::asset::AssetPlugin::default()))
            .init_asset::<Mesh>()
            .init_asset::<TubeletMaterial>()
            .init_asset::<ShaderBuffer>()
            .insert_resource(BudgetState::default())
            .add_systems(Update, fascicle_render::budget::coarse_meshes);
        let tracts = Arc::new(parallel_tracts(2_500));
        let spawn = move |mut commands: Commands,
                          mut meshes: ResMut<Assets<Mesh>>,
                          mut materials: ResMut<Assets<TubeletMaterial>>,
                          mut buffers: ResMut<Assets<ShaderBuffer>>| {
            let settings = TubeSettings::default();
            spawn_tubes(&mut commands, &mut meshes, &mut materials, &mut buffers, tracts.clone(), None, &settings)
        };
        let e = bevy::ecs::system::RunSystemOnce::run_system_once(app.world_mut(), spawn).expect("spawned");
        let set = app.world().get::<TubeSet>(e).expect("tube set").clone();
        let (full, preview) = (set.full.clone(), set.preview.clone().expect("preview"));
        let n = |app: &App, h: &Handle<Mesh>| app.world().resource::<Assets<Mesh>>().get(h).unwrap().count_vertices();
        assert_eq!((n(&app, &full), n(&app, &preview)), (8 * tubes.len(), 8 * slots.len()));
        let mut step = |moving: bool, coarse: bool| {
            let mut b = app.world_mut().resource_mut::<BudgetState>();
            (b.moving, b.coarse) = (moving, coarse);
            app.update();
            app.world().get::<Mesh3d>(e).expect("mesh").0.clone()
        };
        assert_eq!(step(true, false), full, "render scale holds the budget");
        assert_eq!(step(true, true), preview, "coarse");
        assert_eq!(step(false, false), full, "still: the whole set");
    }

    /// Streamline `s` is bit `s % 32` of word `s / 32`, as the vertex shaders read it; an empty selection is one
    /// word.
    #[test]
    fn selections_are_one_bit_a_streamline() {
        let sel: Vec<bool> = (0..70).map(|s| s % 3 == 0 || s == 69).collect();
        let bytes = selection_words(&sel);
        assert_eq!(bytes.len(), 12);
        let words: Vec<u32> = bytes.chunks(4).map(|b| u32::from_le_bytes(b.try_into().unwrap())).collect();
        for (s, &k) in sel.iter().enumerate() {
            assert_eq!((words[s >> 5] >> (s & 31)) & 1 == 1, k, "streamline {s}");
        }
        assert_eq!(words[2] >> 6, 0, "no bit past the last streamline");
        assert_eq!(selection_words(&[]), vec![0; 4]);
        // Flags in no pattern: each bit as the shaders read it.
        let sel: Vec<bool> = (0..1_001u64).map(|s| (s.wrapping_mul(2_654_435_761) >> 13) & 1 == 1).collect();
        let bytes = selection_words(&sel);
        assert_eq!(bytes.len(), 4 * 32);
        for (s, &k) in sel.iter().enumerate() {
            let word = u32::from_le_bytes(bytes[4 * (s >> 5)..4 * (s >> 5) + 4].try_into().unwrap());
            assert_eq!((word >> (s & 31)) & 1 == 1, k, "streamline {s}");
        }
    }

    /// An ROI move re-selects every set, but a set whose selection stays as it was keeps its flags: its
    /// `TractSelection` is not changed (so neither its flag buffer nor its tube proxies are rewritten), as the
    /// parts of a layer away from a dragged ROI.
    #[test]
    fn a_set_whose_selection_stays_keeps_its_flags() {
        use fascicle_core::roi::{RoiMode, RoiShape};
        let mut app = App::new();
        app.add_plugins((MinimalPlugins, bevy::asset::AssetPlugin::default()))
            .init_asset::<ShaderBuffer>()
            .init_resource::<RoiStats>()
            .init_resource::<RoiBackground>()
            .add_systems(Update, apply_rois);
        let spawn = |app: &mut App, x0: f32| {
            let mut t = Tractogram::new();
            for s in 0..20 {
                t.push(&(0..=10).map(|y| Vec3::new(x0 + s as f32, y as f32, 0.0)).collect::<Vec<_>>());
            }
            let mut buffers = app.world_mut().resource_mut::<Assets<ShaderBuffer>>();
            let (set, selection) =
                tract_set(&mut buffers, SetStreamlines::Owned(Arc::new(t)), LazyIndex::default(), 0).target.unwrap();
            app.world_mut().spawn((set, selection)).id()
        };
        let (near, far) = (spawn(&mut app, 0.0), spawn(&mut app, 1000.0));
        let roi = |x: f32| {
            TractRoi(Roi { shape: RoiShape::Sphere { centre: [x, 5.0, 0.0], radius: 1.5 }, mode: RoiMode::Include })
        };
        // Unparented: it acts on every set.
        let r = app.world_mut().spawn(roi(3.0)).id();
        app.update();
        let state = |app: &App| {
            [near, far].map(|e| {
                let s = app.world().entity(e).get_ref::<TractSelection>().expect("selection");
                (s.last_changed(), s.0.iter().enumerate().filter(|(_, k)| **k).map(|(i, _)| i).collect::<Vec<_>>())
            })
        };
        let before = state(&app);
        assert_eq!((before[0].1.clone(), before[1].1.clone()), (vec![2, 3, 4], vec![]));
        *app.world_mut().get_mut::<TractRoi>(r).expect("roi") = roi(6.0);
        app.update();
        let after = state(&app);
        assert_eq!((after[0].1.clone(), after[1].1.clone()), (vec![5, 6, 7], vec![]));
        assert_ne!(after[0].0, before[0].0, "the near set's selection changed");
        assert_eq!(after[1].0, before[1].0, "the far set's selection stayed: left as it was");
        assert_eq!(app.world().resource::<RoiStats>().evaluations, 2);
    }

    /// A selection rebuilds the set's proxies from the selected streamlines' tubelets (and the preview's from
    /// the selected ones among its streamlines); a selection of none keeps one (hidden) proxy; selecting all
    /// again restores every proxy.
    #[test]
    fn tube_proxies_follow_the_selection() {
        let tubes = tract_tubelets(&parallel_tracts(500), None, &TubeSettings::default());
        let slots = tube_preview(&tubes).expect("over the limit");
        let mut app = App::new();
        app.add_plugins((MinimalPlugins, bevy::asset::AssetPlugin::default()))
            .init_asset::<Mesh>()
            .add_systems(Update, select_tube_boxes);
        let set = tube_set_with_preview(&mut app, &tubes, &slots);
        let (full, preview) = (set.full.clone(), set.preview.clone().expect("preview"));
        let e = app.world_mut().spawn((set, TractSelection(vec![true; 500]))).id();
        app.update();
        let mut select = |keep: &dyn Fn(usize) -> bool| {
            app.world_mut().get_mut::<TractSelection>(e).expect("selection").0 = (0..500).map(keep).collect();
            app.update();
            let meshes = app.world().resource::<Assets<Mesh>>();
            let n = |h: &Handle<Mesh>| meshes.get(h).expect("mesh").count_vertices() / 8;
            (n(&full), n(&preview))
        };
        // Streamlines 100-139: 400 tubelets, of which streamlines 112 and 128 (20 tubelets) are in the preview.
        assert_eq!(select(&|s| (100..140).contains(&s)), (400, 20));
        assert_eq!(select(&|_| false), (1, 1), "one hidden proxy");
        assert_eq!(select(&|_| true), (5_000, 320), "all again");
    }

    /// A tubelet's end colours are the colour function at its streamline's two points (here the colour is
    /// the point itself and the streamline's index).
    #[test]
    fn tubelet_ends_take_the_colour_of_their_points() {
        let mut t = Tractogram::new();
        t.push(&[Vec3::new(0.0, 0.0, 0.0), Vec3::new(2.0, 1.0, 0.0), Vec3::new(3.0, 3.0, 1.0)]);
        t.push(&[Vec3::new(5.0, 0.0, 0.0), Vec3::new(5.0, 0.0, 4.0)]);
        let mut tubes = tract_tubelets(&t, None, &TubeSettings::default());
        assert_eq!(tubes.len(), 3);
        // The colour also carries the point's index: each end is told which point of its streamline it is.
        recolour(&mut tubes, &|s, k, p| [p.x + 100.0 * k as f32, p.y, p.z + 10.0 * s as f32]);
        for (tube, (s, k)) in tubes.iter().zip([(0, 0), (0, 1), (1, 0)]) {
            let pts = t.streamline(s);
            for (j, (end, p)) in tube.colours.iter().zip([pts[k], pts[k + 1]]).enumerate() {
                let x = p.x as f64 + 100.0 * (k + j) as f64;
                let want = glam::DVec3::new(x, p.y as f64, p.z as f64 + 10.0 * s as f64);
                assert!((*end - want).length() < 1e-5, "streamline {s} segment {k}: {end} vs {want}");
            }
        }
    }
}

#[cfg(test)]
mod line_msaa_tests {
    use super::*;

    /// A camera that sees more line segments than the software limit drops MSAA on a software adapter only;
    /// a camera on other render layers, and any camera on a hardware adapter, keep theirs.
    #[test]
    fn dense_lines_turn_msaa_off_on_software_adapters() {
        for software in [true, false] {
            let mut app = App::new();
            let adapter = fascicle_render::AdapterKind::default();
            adapter.set_software(software);
            app.insert_resource(adapter).insert_resource(LineMsaa::default()).add_systems(Update, line_msaa);
            let set = |n| (LineSegments(n), InheritedVisibility::VISIBLE);
            app.world_mut().spawn(set(600_000));
            app.world_mut().spawn(set(600_000));
            app.world_mut().spawn((set(5_000_000), RenderLayers::layer(3)));
            let main = app.world_mut().spawn((Camera3d::default(), Msaa::Sample4)).id();
            let other = app.world_mut().spawn((Camera3d::default(), Msaa::Sample4, RenderLayers::layer(2))).id();
            app.update();
            let msaa = |e| *app.world().get::<Msaa>(e).unwrap();
            assert_eq!(
                msaa(main),
                if software { Msaa::Off } else { Msaa::Sample4 },
                "1.2M segments, software {software}"
            );
            assert_eq!(msaa(other), Msaa::Sample4, "its layers see no line");
        }
        // Under the limit: MSAA stays.
        let mut app = App::new();
        let adapter = fascicle_render::AdapterKind::default();
        adapter.set_software(true);
        app.insert_resource(adapter).insert_resource(LineMsaa::default()).add_systems(Update, line_msaa);
        app.world_mut().spawn((LineSegments(900_000), InheritedVisibility::VISIBLE));
        let cam = app.world_mut().spawn((Camera3d::default(), Msaa::Sample4)).id();
        app.update();
        assert_eq!(*app.world().get::<Msaa>(cam).unwrap(), Msaa::Sample4);
        // A layer still loading that expects more than the limit: MSAA goes before any line is drawn.
        let layer = app.world_mut().spawn((ExpectedLineSegments(50_000), InheritedVisibility::VISIBLE)).id();
        app.update();
        assert_eq!(*app.world().get::<Msaa>(cam).unwrap(), Msaa::Sample4, "0.95M drawn and expected");
        app.world_mut().entity_mut(layer).insert(ExpectedLineSegments(5_000_000));
        app.update();
        assert_eq!(*app.world().get::<Msaa>(cam).unwrap(), Msaa::Off, "5.9M drawn and expected");
    }
}
