//! A frame budget held by adaptive render scale: while the view moves, cameras marked [`RenderScale`] draw
//! their main pass at a fraction of their viewport, chosen from the measured frame times, and the picture is
//! stretched back over the viewport; when the view has been still for [`FrameBudget::refine_after`], the next
//! frame draws at full scale, the same image an app without the plugin draws.
//!
//! - **Budget**: [`FrameBudget`], a resource: 100 ms a frame on a software adapter, 16 ms on a hardware GPU.
//! - **Moving**: a camera marked [`RenderScale`] whose transform changed, or an app's [`Interacting::mark`]
//!   (a drag of an ROI changes the scene, not the camera); a button held still on the view
//!   ([`Interacting::hold`]) keeps the view moving but asks for no frame, and so does a result still being made
//!   ([`Interacting::pending`]), past the release, until it lands.
//! - **Measured**: a frame's time is the wall time between its update and the one before, counted only when
//!   that one asked for the next at once (in a window drawn on demand, [`crate::on_demand::NextFrame::Now`]; the
//!   first frame after an idle wait measures the wait). Beside the part of a frame scale does not lower
//!   ([`BudgetState::fixed`], measured on frames that draw no scene), the cost is taken as proportional to the
//!   pixels, so a frame `t` over budget `b` scales the side by `sqrt((b - f) / (t - f))` (at most 4x less a
//!   frame), and a frame under
//!   60 % of the budget raises it (at most 1.25x), in steps of 1/16. An interaction starts at the scale the
//!   most expensive frame measured since the last interaction affords (a still scene's refining and settling
//!   frames are measured too), and not above the scale the last interaction ended at, so its first frame is
//!   not the slow one.
//! - **Coarse**: when a frame at the smallest scale is still over budget, [`BudgetState::coarse`] tells the
//!   layers to lower what pixels do not pay for (previews, coarser steps) until the view is still.
//! - **Drawn**: the main pass renders into the top-left `scale` part of the camera's viewport (Bevy's
//!   `MainPassResolutionOverride`; shaders that need the viewport read `view.main_pass_viewport`), and a
//!   copy-and-blit pass, after the main pass and before post-processing, stretches it over the viewport with
//!   Bevy's blit pipeline (nearest texel).
//! - **Read**: [`BudgetState`] holds the current scale and the last moving frame's time, for readouts.
//!
//! A window drawn on demand ([`crate::on_demand`]) reaches the refining frame through [`crate::Unsettled`]:
//! while the scale is under 1 and the view is still, the plugin asks for frames at the busy rate; not while a
//! button is held still (its release or the next move is input, which draws a frame anyway).

use std::time::Duration;

use bevy::camera::MainPassResolutionOverride;
use bevy::core_pipeline::blit::{BlitPipeline, BlitPipelineKey};
use bevy::core_pipeline::{Core3dSystems, schedule::Core3d};
use bevy::platform::collections::HashMap;
use bevy::prelude::*;
use bevy::render::camera::ExtractedCamera;
use bevy::render::render_resource::{
    BindGroup, CachedRenderPipelineId, PipelineCache, SpecializedRenderPipelines, TextureViewId,
};
use bevy::render::renderer::{RenderContext, RenderDevice, ViewQuery};
use bevy::render::sync_world::RenderEntity;
use bevy::render::texture::{CachedTexture, TextureCache};
use bevy::render::view::ViewTarget;
use bevy::render::{Extract, ExtractSchedule, Render, RenderApp, RenderSystems};

/// Adds the frame budget (see the module docs). Needs [`crate::FascicleRenderPlugin`] (for [`crate::AdapterKind`]
/// and [`crate::Unsettled`]), which it adds when missing.
pub struct FrameBudgetPlugin;

/// The frame budget, a resource (defaults below).
#[derive(Resource, Clone, Debug, PartialEq)]
pub struct FrameBudget {
    /// Whether the scale adapts at all (default true); false draws every frame at full scale.
    pub enabled: bool,
    /// The budget on a software adapter (default 100 ms).
    pub software: Duration,
    /// The budget on a hardware GPU (default 16 ms).
    pub hardware: Duration,
    /// The smallest scale of a viewport's side (default 0.125: a 1280-pixel-wide view draws 160 pixels).
    pub min_scale: f32,
    /// How long the view stays still before the full-scale frame is drawn (default 150 ms).
    pub refine_after: Duration,
}

impl Default for FrameBudget {
    fn default() -> Self {
        Self {
            enabled: true,
            software: Duration::from_millis(100),
            hardware: Duration::from_millis(16),
            min_scale: 0.125,
            refine_after: Duration::from_millis(150),
        }
    }
}

impl FrameBudget {
    /// The budget for the adapter (software or not).
    pub fn for_adapter(&self, software: bool) -> Duration {
        if software { self.software } else { self.hardware }
    }
}

/// Marks a 3D camera whose main pass follows the frame budget; holds the scale of its viewport's side the
/// current frame draws with (1: full, written by the plugin).
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct RenderScale(pub f32);

impl Default for RenderScale {
    fn default() -> Self {
        RenderScale(1.0)
    }
}

/// Interaction an app reports: an ROI drag, a window/level drag (which move no camera), or a button held
/// down on the view (a drag whose frames may see no motion: a frame slower than
/// [`FrameBudget::refine_after`] must not end it). Frames while it is marked count as moving. Cleared every
/// frame.
#[derive(Resource, Default, Debug)]
pub struct Interacting {
    marked: bool,
    held: bool,
    released: bool,
    pending: bool,
}

impl Interacting {
    /// The user is interacting this frame: something moved (the pointer of a drag, an ROI, the view).
    pub fn mark(&mut self) {
        self.marked = true;
    }

    /// A button is held down on the view this frame, but nothing moved: the view counts as moving (the scale
    /// holds, and a slow frame cannot end the drag), but no frame is asked for, so a window drawn on demand
    /// waits for the next input instead of drawing the same coarse picture back to back. A frame that both
    /// marks and holds is marked.
    pub fn hold(&mut self) {
        self.held = true;
    }

    /// The interaction ended this frame (the button that dragged was released): the view is still at once,
    /// so this frame draws at full quality with no wait for [`FrameBudget::refine_after`] and no coarse settle
    /// frames before it.
    pub fn release(&mut self) {
        self.released = true;
    }

    /// What the interaction changes is still being made elsewhere this frame (an ROI drag's selection of a
    /// large tract layer, on a thread of its own). An interaction under way, or released while it is, goes on
    /// as a held button does (moving, at its scale, no frame asked for) through every frame that reports it;
    /// after a release, the first frame that no longer does draws at full quality at once, as a release does.
    /// So a drag's full-quality frame shows its last selection, once, instead of every selection that lands
    /// after the release. Reported while the view is still, it does nothing.
    pub fn pending(&mut self) {
        self.pending = true;
    }

    /// Whether [`Interacting::pending`] was reported since the budget last read it (each frame).
    pub fn is_pending(&self) -> bool {
        self.pending
    }
}

/// What the budget decided, for readouts and tests.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct BudgetState {
    /// The scale of the viewport's side this frame draws with (1: full).
    pub scale: f32,
    /// Whether the view is moving: it moved (camera or [`Interacting`]) less than
    /// [`FrameBudget::refine_after`] ago, or a window drawn on demand has settle frames left to draw at the
    /// lower scale before the full-quality one.
    pub moving: bool,
    /// The last measured frame (one drawn right after the one before) and the scale it was drawn at; while
    /// the view is still, the most expensive one (the smallest side it affords) since the last interaction
    /// ended, where the next interaction starts from.
    pub last_frame: Option<(Duration, f32)>,
    /// The budget in force (by the adapter).
    pub budget: Duration,
    /// When the view last moved (the wall clock at that frame's update: under pipelined rendering Bevy's
    /// real time is the render world's, a frame late).
    pub last_moved: Option<std::time::Instant>,
    /// What a window frame that draws no scene costs (a retained picture put back: the panel, the overlays, the
    /// passes over the whole target and the present), measured, a running mean: the part of every frame render
    /// scale does not lower. [`next_scale`] and [`start_scale`] take it out before they scale the rest with
    /// the pixels. Zero until such a frame is measured (an app without a retained picture has none).
    pub fixed: Duration,
    /// Render scale alone cannot hold the budget: the view is moving and a frame drawn at the smallest scale
    /// was over budget (measured), so layers also lower what pixels do not pay for (hyperstreamline, line
    /// and glyph previews: [`CoarseMesh`]; the volume's step) until the view is still. An interaction that starts
    /// at the smallest scale starts coarse when the last one ended so, or when the last measured frame
    /// affords under a quarter of the side (where [`start_scale`] stops trusting the pixel count); a coarse
    /// frame under a third of the budget ends it. Default false.
    pub coarse: bool,
}

impl Default for BudgetState {
    fn default() -> Self {
        Self {
            scale: 1.0,
            moving: false,
            last_frame: None,
            fixed: Duration::ZERO,
            budget: FrameBudget::default().software,
            last_moved: None,
            coarse: false,
        }
    }
}

/// Whether the next frame draws coarse ([`BudgetState::coarse`]), after a measured frame of `frame` drawn at
/// `drawn` (scale) and coarse or not (`drawn_coarse`), while the view moves: it was coarse and the frame drawn
/// coarse took a third of the budget or more, or that frame was drawn at the smallest scale `min` without
/// being coarse and went over budget. `coarse` is whether the frame before this one was.
pub fn next_coarse(
    coarse: bool,
    (frame, drawn, drawn_coarse): (Duration, f32, bool),
    budget: Duration,
    min: f32,
) -> bool {
    if drawn_coarse { coarse && frame * 3 >= budget } else { coarse || (drawn <= min && frame > budget) }
}

/// The system that sets the scale, in `PostUpdate` before the asset events are sent (it reads camera moves
/// as changes of their `Transform`, made in `Update`), so that plugins lowering their own quality while the view moves (the
/// volume's step) change their materials, `.after` it, in the frame that draws with them. Apps mark
/// [`Interacting`] in `Update`.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub struct BudgetSystems;

impl Plugin for FrameBudgetPlugin {
    fn build(&self, app: &mut App) {
        app.add_plugins(crate::FascicleRenderPlugin)
            .init_resource::<FrameBudget>()
            .init_resource::<Interacting>()
            .init_resource::<BudgetState>()
            .configure_sets(PostUpdate, BudgetSystems.before(bevy::asset::AssetEventSystems))
            .add_systems(PostUpdate, (hold_budget, coarse_meshes).chain().in_set(BudgetSystems));
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app
                .add_systems(ExtractSchedule, extract_scale)
                .add_systems(Render, prepare_upscale.in_set(RenderSystems::PrepareResources))
                .add_systems(
                    Core3d,
                    upscale
                        .after(Core3dSystems::MainPass)
                        .before(Core3dSystems::PostProcess)
                        .before(crate::OverlaySystems),
                );
        }
    }
}

/// A mesh entity's lighter stand-in while the budget is coarse ([`BudgetState::coarse`]): the entity draws
/// `preview` then and `full` otherwise, a change of its [`Mesh3d`] handle (nothing rebuilt or uploaded). For
/// layers whose cost at the smallest render scale is geometry, not pixels: a glyph set's proxies (every other
/// cell, [`crate::meshes::every_other_cell`]). Apps without [`FrameBudgetPlugin`] always draw `full`.
#[derive(Component, Clone, Debug, PartialEq, Eq)]
pub struct CoarseMesh {
    /// What the entity draws at full quality.
    pub full: Handle<Mesh>,
    /// What it draws while the budget is coarse.
    pub preview: Handle<Mesh>,
}

/// Swaps each [`CoarseMesh`] entity's mesh to follow [`BudgetState::coarse`] ([`FrameBudgetPlugin`] runs it in
/// [`BudgetSystems`], after the scale is set: before Bevy computes the meshes' bounds, so the retained picture
/// is not kept from coming back by a bound changed a frame late).
pub fn coarse_meshes(state: Res<BudgetState>, mut meshes: Query<(&CoarseMesh, &mut Mesh3d)>) {
    for (coarse, mut mesh) in &mut meshes {
        let want = if state.coarse { &coarse.preview } else { &coarse.full };
        if mesh.0 != *want {
            mesh.0 = want.clone();
        }
    }
}

/// The next scale of a viewport's side after a moving frame of `frame` at `scale` against `budget`, of which
/// `fixed` is what scale does not lower ([`BudgetState::fixed`]): the rest taken as proportional to the pixels;
/// lowered when over budget (the side at most 4x less), raised when under 60 % of it (at most 1.25x); in steps
/// of 1/16 between `min` and 1.
pub fn next_scale(scale: f32, frame: Duration, (budget, fixed): (Duration, Duration), min: f32) -> f32 {
    let t = frame.as_secs_f32().max(1e-6);
    let b = budget.as_secs_f32();
    let affordable = pixel_share(b, t, fixed).sqrt();
    let factor = if t > b {
        affordable.max(0.25)
    } else if t < 0.6 * b {
        affordable.min(1.25)
    } else {
        1.0
    };
    let next = (scale * factor * 16.0).floor() / 16.0;
    // Raising goes up a whole step at least (1.25x of a small scale is less than a step).
    let next = if factor > 1.0 { next.max(scale + 1.0 / 16.0) } else { next };
    next.clamp(min.min(1.0), 1.0)
}

/// How many times the pixels of a frame of `t` seconds may grow to cost a frame of `b`, when `fixed` of every
/// frame does not depend on them (counted as at most 90 % of `t`); 0 when `fixed` alone is over `b`.
fn pixel_share(b: f32, t: f32, fixed: Duration) -> f32 {
    let f = fixed.as_secs_f32().min(0.9 * t);
    (b - f).max(0.0) / (t - f).max(1e-6)
}

#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters")]
fn hold_budget(
    budget: Res<FrameBudget>,
    adapter: Option<Res<crate::AdapterKind>>,
    mut last_update: Local<Option<std::time::Instant>>,
    mut interacting: ResMut<Interacting>,
    moved: Query<(), (With<RenderScale>, Changed<Transform>)>,
    mut cameras: Query<&mut RenderScale>,
    mut state: ResMut<BudgetState>,
    mut unsettled: ResMut<crate::Unsettled>,
    pipelined: Option<Res<bevy::render::pipelined_rendering::RenderAppChannels>>,
    mut chosen: Local<Chosen>,
    mut awaiting: Local<bool>,
    retained: Option<Res<crate::RecentlyRetained>>,
    #[cfg(feature = "winit")] on_demand: (
        Option<Res<crate::on_demand::NextFrame>>,
        Option<Res<crate::on_demand::Settling>>,
    ),
) {
    let now = std::time::Instant::now();
    // The frame's time: the wall time since the last update, when this one followed it at once (then the two
    // are a frame apart, whatever the render thread does). Not Bevy's `Time<Real>`, which under pipelined
    // rendering comes from the render world a frame late: the first frames of an interaction read the time
    // of a frame that ended an idle wait (seconds on lavapipe), which made every interaction start coarse.
    let since_last = last_update.replace(now).map(|t| now.saturating_duration_since(t));
    let mut measured_coarse = None;
    // This frame followed the last one at once (a window drawn on demand may have waited for input).
    #[cfg(feature = "winit")]
    let (back_to_back, settling) =
        (on_demand.0.is_none_or(|n| *n == crate::on_demand::NextFrame::Now), on_demand.1.is_some_and(|s| s.0 > 0));
    #[cfg(not(feature = "winit"))]
    let (back_to_back, settling) = (true, false);
    // A frame that put a retained picture back drew no scene: its time says nothing of the scene's cost. The
    // time measured is the render world's last frame: with pipelined rendering the one extracted before the
    // newest (whose render this update waited for). Not "either of the last two": a full-quality frame followed
    // by frames that put it back was never measured, and the first interaction after launch started from a
    // cheap frame, above the smallest scale and not coarse (two frames of 105-125 ms on lavapipe).
    let drew_scene = retained.as_ref().is_none_or(|r| !r.was(u32::from(pipelined.is_some())));
    // Frames that put it back, one after the other, measure what render scale cannot lower.
    if back_to_back
        && retained.is_some_and(|r| r.all_of_last(2))
        && let Some(frame) = since_last
    {
        state.fixed = if state.fixed.is_zero() { frame } else { state.fixed.mul_f32(0.75) + frame.mul_f32(0.25) };
    }
    if back_to_back
        && drew_scene
        && let Some(frame) = since_last.filter(|t| *t > Duration::ZERO)
    {
        // The frame just measured was drawn at the scale the last update chose; with pipelined rendering
        // (an update runs while the render world draws the one before), the update before that.
        let drawn = if pipelined.is_some() { chosen.0[1] } else { chosen.0[0] };
        let measured = (frame, drawn.0);
        state.last_frame = Some(if state.moving {
            chosen.2 = None;
            measured
        } else {
            // Between interactions the most expensive frame decides where the next one starts: a refining
            // frame of a minute is followed by cheap ones (a pointer crossing the view, a pipeline compiling)
            // that say nothing of what moving the view will cost.
            let side = |(t, s): (Duration, f32)| affordable_side(s, t, state.budget, state.fixed);
            let worst = chosen.2.filter(|w| side(*w) <= side(measured)).unwrap_or(measured);
            chosen.2 = Some(worst);
            worst
        });
        measured_coarse = Some(drawn.1);
    }
    let mut released = std::mem::take(&mut interacting.released);
    let marked = std::mem::take(&mut interacting.marked) || !moved.is_empty();
    // A release while the interaction's result is pending is kept (`awaiting`) until the result has landed.
    let pending = std::mem::take(&mut interacting.pending) && (state.moving || marked || released);
    if marked {
        *awaiting = false;
    }
    if pending {
        *awaiting |= released;
        released = false;
    } else if std::mem::take(&mut *awaiting) {
        released = true;
    }
    let held = (std::mem::take(&mut interacting.held) && !marked && !released) || (pending && !marked);
    if marked {
        state.last_moved = Some(now);
    }
    if released {
        state.last_moved = None;
    }
    let was_moving = state.moving;
    let ended_at = (state.scale, state.coarse);
    // Still, but a window drawn on demand still has settle frames to draw (after a wheel turn, say): they stay
    // coarse, and the full-quality frame is the last one, drawn once. A release refines at once: the settle
    // frames after it put the refined picture back (the retained picture).
    let coarse_still = state.scale < 1.0 && settling && !released;
    state.moving = state.last_moved.is_some_and(|t| now.saturating_duration_since(t) < budget.refine_after)
        || coarse_still
        || held;
    state.budget = budget.for_adapter(adapter.is_some_and(|a| a.is_software()));
    let min = budget.min_scale;
    state.scale = match (budget.enabled, state.moving, state.last_frame) {
        (true, true, Some((frame, drawn))) if was_moving && back_to_back => {
            next_scale(state.scale.min(drawn), frame, (state.budget, state.fixed), min)
        }
        // An interaction starts at the scale the last measured frame affords, with no limit on the step, but
        // not above the scale the last interaction ended at (frames between interactions may put a retained
        // picture back, or draw while pipelines compile: cheap frames that say little of the scene's cost).
        (true, true, Some((frame, drawn))) if !was_moving => {
            start_scale(drawn, frame, (state.budget, state.fixed), min).min(chosen.1.map_or(1.0, |e| e.0))
        }
        (true, true, _) => state.scale,
        _ => 1.0,
    };
    state.coarse = match (budget.enabled && state.moving, state.last_frame, measured_coarse) {
        (false, ..) => false,
        (true, Some((frame, drawn)), Some(drawn_coarse)) if was_moving => {
            next_coarse(state.coarse, (frame, drawn, drawn_coarse), state.budget, min)
        }
        // An interaction at the smallest scale starts coarse when the last one ended so, or when the last
        // measured frame affords under a quarter of the side (`start_scale`: there the pixels no longer pay
        // for most of a frame).
        (true, Some((frame, drawn)), _) if !was_moving => {
            let side = affordable_side(drawn, frame, state.budget, state.fixed);
            state.scale <= min && (chosen.1.is_some_and(|e| e.1) || side < 0.25)
        }
        (true, None, _) if !was_moving => false,
        (true, ..) => state.coarse,
    };
    if was_moving && !state.moving {
        chosen.1 = Some(ended_at);
    }
    if state.moving && state.scale < 1.0 && !held {
        // Frames until the view is still: the one that finds it still draws at full scale. A held button
        // draws nothing new until the next input.
        unsettled.request();
    }
    chosen.0 = [(state.scale, state.coarse), chosen.0[0]];
    for mut camera in &mut cameras {
        if camera.0 != state.scale {
            camera.0 = state.scale;
        }
    }
}

/// The scales (and coarseness) the last two updates chose, newest first (full scale before any), those the
/// last interaction ended at (none before the first), and the most expensive frame measured since it ended.
struct Chosen([(f32, bool); 2], Option<(f32, bool)>, Option<(Duration, f32)>);

impl Default for Chosen {
    fn default() -> Self {
        Chosen([(1.0, false); 2], None, None)
    }
}

/// The scale an interaction starts at, after a frame of `frame` drawn at `drawn`: the side that frame's
/// pixels would have needed to meet `budget` beside the `fixed` part ([`BudgetState::fixed`]), in steps of 1/16
/// between `min` and 1; `min` when that side is under a quarter. Below a quarter of the side most of a frame's cost is what the pixels do not pay for (passes over
/// the whole target, geometry, the app's own work), so the pixel count promises more than it saves: on lavapipe the
/// default scene's first orbit frame at 3/16 took 214-368 ms against 90-120 ms at 1/8. The budget raises the
/// scale from there while frames stay well under it.
pub fn start_scale(drawn: f32, frame: Duration, (budget, fixed): (Duration, Duration), min: f32) -> f32 {
    let s = affordable_side(drawn, frame, budget, fixed);
    let s = if s < 0.25 { min } else { s };
    ((s * 16.0).floor() / 16.0).clamp(min.min(1.0), 1.0)
}

/// The side (a scale) whose pixels would have met `budget`, by a frame of `frame` drawn at `drawn`, the cost
/// but `fixed` taken as proportional to the pixels.
fn affordable_side(drawn: f32, frame: Duration, budget: Duration, fixed: Duration) -> f32 {
    drawn * pixel_share(budget.as_secs_f32(), frame.as_secs_f32().max(1e-6), fixed).sqrt()
}

/// On a camera in the render world: its main pass draws at a lower scale and is stretched back.
#[derive(Component)]
pub(crate) struct ScaledMainPass;

fn extract_scale(
    mut commands: Commands,
    cameras: Extract<Query<(RenderEntity, &RenderScale, &Camera)>>,
    scaled_views: Query<(), With<ScaledMainPass>>,
) {
    for (entity, scale, camera) in &cameras {
        let size = camera.physical_viewport_size().unwrap_or_default();
        let scaled = (size.as_vec2() * scale.0).round().as_uvec2().max(UVec2::ONE);
        if scale.0 < 1.0 && size.x > 1 && size.y > 1 && scaled != size {
            commands.entity(entity).insert((MainPassResolutionOverride(scaled), ScaledMainPass));
        } else if scaled_views.contains(entity) {
            commands.entity(entity).remove::<(MainPassResolutionOverride, ScaledMainPass)>();
        }
    }
}

/// The blit pipeline and the texture that holds the main pass's scaled picture, per scaled view.
#[derive(Component)]
pub(crate) struct Upscale {
    pipeline: CachedRenderPipelineId,
    texture: CachedTexture,
    bind_group: BindGroup,
}

#[allow(clippy::type_complexity, clippy::too_many_arguments, reason = "a Bevy system's parameters")]
fn prepare_upscale(
    mut commands: Commands,
    views: Query<(Entity, &ViewTarget, &MainPassResolutionOverride), With<ScaledMainPass>>,
    blit: Option<Res<BlitPipeline>>,
    mut pipelines: ResMut<SpecializedRenderPipelines<BlitPipeline>>,
    cache: Res<PipelineCache>,
    mut textures: ResMut<TextureCache>,
    device: Res<RenderDevice>,
    mut bind_groups: Local<HashMap<Entity, (TextureViewId, BindGroup)>>,
) {
    let Some(blit) = blit else { return };
    bind_groups.retain(|e, _| views.contains(*e));
    for (entity, target, size) in &views {
        let format = target.main_texture_format();
        let key = BlitPipelineKey { target_format: format, blend_state: None, samples: 1, source_space: None };
        let pipeline = pipelines.specialize(&cache, &blit, key);
        let texture =
            textures.get(&device, crate::viewport::picture_texture("fascicle_scaled_main_pass", size.0, format));
        // The texture cache hands back the same texture while the size holds: its bind group is kept, as
        // Bevy's own upscaling keeps its own.
        let bind_group = match bind_groups.get(&entity) {
            Some((id, group)) if *id == texture.default_view.id() => group.clone(),
            _ => {
                let group = blit.create_bind_group(&device, &texture.default_view, &cache);
                bind_groups.insert(entity, (texture.default_view.id(), group.clone()));
                group
            }
        };
        commands.entity(entity).insert(Upscale { pipeline, texture, bind_group });
    }
}

/// Copies the main pass's scaled picture out of the main texture and stretches it over the viewport.
pub(crate) fn upscale(
    view: ViewQuery<(&ViewTarget, &ExtractedCamera, &MainPassResolutionOverride, &Upscale), With<ScaledMainPass>>,
    cache: Res<PipelineCache>,
    mut ctx: RenderContext,
) {
    let (target, camera, size, upscale) = view.into_inner();
    let Some(pipeline) = cache.get_render_pipeline(upscale.pipeline) else { return };
    let viewport = crate::viewport::physical_viewport(camera);
    let texture = &upscale.texture.texture;
    if texture.width() != size.x || texture.height() != size.y {
        return;
    }
    crate::viewport::copy_out(&mut ctx, target, &viewport, size.0, texture);
    // Loaded, not cleared: the stretch covers the viewport, and this camera writes only its viewport out, so
    // clearing the rest of the main texture was a pass over it for nothing.
    let attachment = crate::viewport::loaded_main_attachment(target);
    crate::viewport::blit_over(&mut ctx, "fascicle_upscale", attachment, &viewport, pipeline, &upscale.bind_group);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scale_follows_the_measured_frame_time() {
        let ms = Duration::from_millis;
        // 4x over budget: pixels must drop 4x, the side 2x.
        assert_eq!(next_scale(1.0, ms(400), (ms(100), ms(0)), 0.25), 0.5);
        // Far over: the side at most 4x less a frame, never under the minimum.
        assert_eq!(next_scale(1.0, ms(5000), (ms(100), ms(0)), 0.1), 0.25);
        assert_eq!(next_scale(0.25, ms(5000), (ms(100), ms(0)), 0.25), 0.25);
        // Within 60-100 % of the budget: kept.
        assert_eq!(next_scale(0.5, ms(80), (ms(100), ms(0)), 0.25), 0.5);
        // Well under: raised, at most 1.25x, never over 1.
        assert_eq!(next_scale(0.5, ms(10), (ms(100), ms(0)), 0.25), 0.625);
        assert_eq!(next_scale(0.9375, ms(10), (ms(100), ms(0)), 0.25), 1.0);
        // From a small scale, a step at least.
        assert_eq!(next_scale(0.125, ms(10), (ms(100), ms(0)), 0.125), 0.1875);
        // Slightly over: lowered by at least a step.
        assert!(next_scale(0.5, ms(110), (ms(100), ms(0)), 0.25) < 0.5);
        // An interaction starts where the last frame says the budget is met, up or down.
        assert_eq!(start_scale(1.0, ms(1600), (ms(100), ms(0)), 0.1), 0.25);
        assert_eq!(start_scale(0.25, ms(10), (ms(100), ms(0)), 0.1), 0.75);
        assert_eq!(start_scale(1.0, ms(10), (ms(100), ms(0)), 0.1), 1.0);
        // Under a quarter of the side, the smallest scale (a 2.5 s frame: 0.2 by its pixels).
        assert_eq!(start_scale(1.0, ms(2500), (ms(100), ms(0)), 0.125), 0.125);
        assert_eq!(start_scale(0.5, ms(1000), (ms(100), ms(0)), 0.125), 0.125);
    }

    /// What render scale does not lower (a window frame that draws no scene) is taken out before the rest is
    /// scaled with the pixels: the default scene's refine of 1.1 s at full scale with 50 ms of window work
    /// affords a side of 0.22 (the smallest scale), not the 0.30 its pixel count alone promises.
    #[test]
    fn the_fixed_part_of_a_frame_is_not_scaled() {
        let ms = Duration::from_millis;
        assert_eq!(start_scale(1.0, ms(1100), (ms(100), ms(0)), 0.125), 0.25);
        assert_eq!(start_scale(1.0, ms(1100), (ms(100), ms(50)), 0.125), 0.125);
        assert!((affordable_side(1.0, ms(1100), ms(100), ms(50)) - (50.0f32 / 1050.0).sqrt()).abs() < 1e-4);
        // 160 ms at half scale, 60 of it fixed: the pixels may take 40 of the 100, so the side goes to
        // 0.5 * sqrt(40 / 100) = 0.316 (0.3125 in steps), not 0.5 * sqrt(100 / 160) = 0.395 (0.375).
        assert_eq!(next_scale(0.5, ms(160), (ms(100), ms(60)), 0.125), 0.3125);
        assert_eq!(next_scale(0.5, ms(160), (ms(100), ms(0)), 0.125), 0.375);
        // The fixed part alone over budget: the side drops as far as a step allows.
        assert_eq!(next_scale(0.5, ms(200), (ms(100), ms(150)), 0.125), 0.125);
        // Under budget with most of it fixed: raised by the most a step allows (1.25x).
        assert_eq!(next_scale(0.5, ms(55), (ms(100), ms(50)), 0.125), 0.625);
    }

    #[test]
    fn coarse_when_the_smallest_scale_is_over_budget() {
        let (ms, b, min) = (Duration::from_millis, Duration::from_millis(100), 0.125);
        // Over budget above the smallest scale: the scale goes down first.
        assert!(!next_coarse(false, (ms(300), 0.25, false), b, min));
        // Over budget at the smallest scale: coarse.
        assert!(next_coarse(false, (ms(300), 0.125, false), b, min));
        assert!(!next_coarse(false, (ms(90), 0.125, false), b, min));
        // Coarse stays while its frames take a third of the budget or more, whatever their scale.
        assert!(next_coarse(true, (ms(40), 0.125, true), b, min));
        assert!(next_coarse(true, (ms(40), 0.5, true), b, min));
        assert!(!next_coarse(true, (ms(30), 0.125, true), b, min));
        // A frame drawn before the switch (pipelined) says nothing of the coarse frames' cost.
        assert!(next_coarse(true, (ms(20), 0.125, false), b, min));
    }
}
