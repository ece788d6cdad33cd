//! Draw on demand: a window app redraws only when something changed, and an idle window costs nothing.
//!
//! [`DrawOnDemandPlugin`] puts winit in reactive mode and picks, every frame, when the next one is due:
//! - at once (a redraw is requested) while the render world has pipelines compiling, for [`DrawOnDemand::settle_frames`]
//!   frames after input or a [`KeepAwake::redraw`] request (a change shown in one frame can need the next, such
//!   as a mesh uploaded after the frame that spawned it);
//! - every [`DrawOnDemand::busy_wait`] while something progresses in the background: a plugin layer whose data
//!   is still loading ([`LayerStatus::Loading`]), a plugin's picture that has not settled
//!   ([`crate::Unsettled`]: tract previews), or whatever the app marks with [`KeepAwake::busy`] (a fit,
//!   tracking, a file dialog), so progress bars move and streamed parts appear;
//! - otherwise not until the next input event ([`IDLE_WAIT`], an hour, stands for never).
//!
//! Input events (pointer, keys, resizes) wake the app by themselves. Headless apps do not use this plugin.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use bevy::input::keyboard::KeyboardInput;
use bevy::input::mouse::{MouseButtonInput, MouseWheel};
use bevy::prelude::*;
use bevy::render::render_resource::PipelineCache;
use bevy::render::{Render, RenderApp, RenderSystems};
use bevy::window::{CursorMoved, RequestRedraw, WindowResized};
use bevy::winit::{UpdateMode, WinitSettings};

use crate::layer::LayerStatus;

/// Adds draw on demand to a window app (see the module docs).
pub struct DrawOnDemandPlugin;

/// When a window app draws; a resource (defaults below). Set `enabled` to false to draw continuously.
#[derive(Resource, Clone, Debug)]
pub struct DrawOnDemand {
    /// Draw on demand (default true); false: every frame, as winit's game mode.
    pub enabled: bool,
    /// Time between frames while something progresses in the background (default 100 ms).
    pub busy_wait: Duration,
    /// Frames drawn after an input event or a redraw request (default 2).
    pub settle_frames: u32,
}

impl Default for DrawOnDemand {
    fn default() -> Self {
        Self { enabled: true, busy_wait: Duration::from_millis(100), settle_frames: 2 }
    }
}

pub use crate::KeepAwake;

/// What the last frame decided, for readouts and tests.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum NextFrame {
    /// At once.
    #[default]
    Now,
    /// After [`DrawOnDemand::busy_wait`].
    Poll,
    /// At the next input event.
    Idle,
}

/// The settle frames still to be drawn after the current one ([`DrawOnDemand::settle_frames`] after input or
/// a redraw request), as the last frame left it: a system that wants its picture drawn once, when nothing
/// else is due, waits for 0 (the frame budget draws its full-quality frame then).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Settling(pub u32);

/// The system in `Last` that decides when the next frame is due: systems that call [`KeepAwake`] in `Last`
/// run before it.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub struct ScheduleNextFrame;

/// How long an idle window waits for input before it draws anyway: an hour. Not `Duration::MAX`, which
/// winit's docs offer as "forever": Bevy 0.19.1's runner then leaves the event loop's control flow as the last
/// frame set it, which is `Poll` after any frame slower than the busy wait, and the window never sleeps.
pub const IDLE_WAIT: Duration = Duration::from_secs(3600);

/// Pipelines the render world is still compiling (shared between the worlds).
#[derive(Resource, Clone, Default)]
struct PendingPipelines(Arc<AtomicUsize>);

impl Plugin for DrawOnDemandPlugin {
    fn build(&self, app: &mut App) {
        let pending = PendingPipelines::default();
        app.init_resource::<DrawOnDemand>()
            .init_resource::<KeepAwake>()
            .init_resource::<crate::Unsettled>()
            .init_resource::<NextFrame>()
            .init_resource::<Settling>()
            .insert_resource(pending.clone())
            .add_systems(First, forget_redraw_requests.after(bevy::ecs::message::MessageUpdateSystems))
            .add_systems(Last, schedule_next_frame.in_set(ScheduleNextFrame));
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app.insert_resource(pending).add_systems(Render, count_pending.in_set(RenderSystems::Cleanup));
        }
    }
}

/// Drops the last frame's `RequestRedraw` messages once winit has read them. Bevy's winit runner reads them
/// after each update with a new cursor, which also sees the frame before's (messages live two updates), so
/// every request drew two frames: on a software adapter with a whole-brain tractogram, 6 s each.
fn forget_redraw_requests(mut redraws: ResMut<Messages<RequestRedraw>>) {
    trace!("update begins");
    redraws.clear();
}

/// Counts the pipelines the render world is still compiling. At trace level it also names them and marks
/// the end of each render-world frame: a pipeline specialised late draws a whole frame more, which on a
/// software adapter with a whole brain costs seconds.
fn count_pending(cache: Option<Res<PipelineCache>>, pending: Res<PendingPipelines>) {
    let n = cache.as_ref().map_or(0, |c| c.waiting_pipelines().count());
    pending.0.store(n, Ordering::Relaxed);
    if n > 0
        && let Some(cache) = cache
        && bevy::log::tracing::enabled!(bevy::log::Level::TRACE)
    {
        use bevy::material::descriptor::PipelineDescriptor;
        let waiting: Vec<usize> = cache.waiting_pipelines().collect();
        let labels: Vec<String> = waiting
            .iter()
            .filter_map(|&id| cache.pipelines().nth(id))
            .map(|p| match &p.descriptor {
                PipelineDescriptor::RenderPipelineDescriptor(d) => {
                    format!("{:?} ({:?}, MSAA {})", d.label, d.primitive.topology, d.multisample.count)
                }
                PipelineDescriptor::ComputePipelineDescriptor(d) => format!("{:?}", d.label),
            })
            .collect();
        trace!("render world: pipelines waiting {labels:?}");
    }
    trace!("render world: frame queued");
}

/// Whether anything asks for a frame at once, soon, or not at all.
pub fn next_frame(pending_pipelines: usize, input: bool, redraw: bool, settling: bool, busy: bool) -> NextFrame {
    if pending_pipelines > 0 || input || redraw || settling {
        NextFrame::Now
    } else if busy {
        NextFrame::Poll
    } else {
        NextFrame::Idle
    }
}

/// The input messages that count as activity.
#[derive(bevy::ecs::system::SystemParam)]
struct Inputs<'w, 's> {
    keys: MessageReader<'w, 's, KeyboardInput>,
    buttons: MessageReader<'w, 's, MouseButtonInput>,
    wheel: MessageReader<'w, 's, MouseWheel>,
    cursor: MessageReader<'w, 's, CursorMoved>,
    resized: MessageReader<'w, 's, WindowResized>,
}

impl Inputs<'_, '_> {
    /// Whether any arrived since the last frame (all are read).
    fn any(&mut self) -> bool {
        let n = self.keys.read().count()
            + self.buttons.read().count()
            + self.wheel.read().count()
            + self.cursor.read().count()
            + self.resized.read().count();
        n > 0
    }
}

#[allow(clippy::too_many_arguments)] // a system: its parameters are what it reads
fn schedule_next_frame(
    settings: Res<DrawOnDemand>,
    mut keep: ResMut<KeepAwake>,
    pending: Res<PendingPipelines>,
    layers: Query<&LayerStatus>,
    mut inputs: Inputs,
    mut winit: ResMut<WinitSettings>,
    mut redraws: ResMut<Messages<RequestRedraw>>,
    mut state: ResMut<NextFrame>,
    mut settle: ResMut<Settling>,
    unsettled: Option<ResMut<crate::Unsettled>>,
) {
    let input = inputs.any();
    let request = std::mem::take(&mut keep.redraw);
    // Taken without marking it changed: a request marks it (the retained picture watches it).
    let unsettled = unsettled.is_some_and(|mut u| u.bypass_change_detection().take());
    let busy = std::mem::take(&mut keep.busy) || unsettled || layers.iter().any(|s| matches!(s, LayerStatus::Loading));
    if !settings.enabled {
        let game = WinitSettings::game();
        if winit.focused_mode != game.focused_mode {
            *winit = game;
        }
        return;
    }
    if input || request {
        settle.0 = settings.settle_frames;
    }
    let settling = settle.0 > 0;
    settle.0 = settle.0.saturating_sub(1);
    let pending = pending.0.load(Ordering::Relaxed);
    let next = next_frame(pending, input, request, settling, busy);
    trace!(
        "next frame {next:?}: {pending} pipelines pending, input {input}, redraw {request}, settling {settling}, \
         busy {busy}; redraws requested elsewhere: {}",
        redraws.iter_current_update_messages().count()
    );
    if next == NextFrame::Now {
        redraws.write(RequestRedraw);
    }
    let wait = if next == NextFrame::Poll { settings.busy_wait } else { IDLE_WAIT };
    let wanted = WinitSettings {
        focused_mode: UpdateMode::reactive(wait),
        unfocused_mode: UpdateMode::reactive_low_power(wait),
    };
    if winit.focused_mode != wanted.focused_mode || winit.unfocused_mode != wanted.unfocused_mode {
        *winit = wanted;
    }
    state.set_if_neq(next);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn idle_only_when_nothing_asks() {
        assert_eq!(next_frame(0, false, false, false, false), NextFrame::Idle);
        assert_eq!(next_frame(0, false, false, false, true), NextFrame::Poll);
        assert_eq!(next_frame(1, false, false, false, false), NextFrame::Now);
        assert_eq!(next_frame(0, true, false, false, true), NextFrame::Now);
        assert_eq!(next_frame(0, false, true, false, false), NextFrame::Now);
        assert_eq!(next_frame(0, false, false, true, false), NextFrame::Now);
    }

    fn app() -> App {
        let mut app = App::new();
        app.add_plugins((
            MinimalPlugins,
            bevy::input::InputPlugin,
            bevy::window::WindowPlugin { primary_window: None, ..default() },
        ))
        .insert_resource(WinitSettings::game())
        .add_plugins(DrawOnDemandPlugin);
        app
    }

    fn redraws(app: &App) -> usize {
        app.world().resource::<Messages<RequestRedraw>>().iter_current_update_messages().count()
    }

    /// A `RequestRedraw` is seen by winit's runner after the update that wrote it and not after the next (Bevy's
    /// runner reads every message still stored, and messages live two updates): one request, one frame. A
    /// plugin's `Unsettled` request makes the app poll for that frame only.
    #[test]
    fn a_redraw_request_draws_one_frame_and_unsettled_polls() {
        let mut app = app();
        app.update();
        let stored = |app: &App| {
            let mut cursor = bevy::ecs::message::MessageCursor::<RequestRedraw>::default();
            cursor.read(app.world().resource::<Messages<RequestRedraw>>()).count()
        };
        app.world_mut().write_message(RequestRedraw);
        assert_eq!(stored(&app), 1);
        app.update();
        assert_eq!(stored(&app), 0, "the last update's request is still there for the runner to read again");

        app.world_mut().resource_mut::<crate::Unsettled>().request();
        app.update();
        assert_eq!(*app.world().resource::<NextFrame>(), NextFrame::Poll);
        app.update();
        assert_eq!(*app.world().resource::<NextFrame>(), NextFrame::Idle, "a request lasts one frame");
    }

    /// An app with nothing to do asks for no frame and tells winit to wait for input; a loading layer makes it
    /// poll; input draws at once and settles for two frames; a `KeepAwake::redraw` likewise.
    #[test]
    fn an_idle_app_asks_for_no_frame() {
        let mut app = app();
        for _ in 0..4 {
            app.update();
        }
        assert_eq!(*app.world().resource::<NextFrame>(), NextFrame::Idle);
        assert_eq!(redraws(&app), 0);
        let idle = app.world().resource::<WinitSettings>().focused_mode;
        assert_eq!(idle, UpdateMode::reactive(IDLE_WAIT));

        let layer = app.world_mut().spawn(LayerStatus::Loading).id();
        app.update();
        assert_eq!(*app.world().resource::<NextFrame>(), NextFrame::Poll);
        assert_eq!(
            app.world().resource::<WinitSettings>().focused_mode,
            UpdateMode::reactive(Duration::from_millis(100))
        );
        *app.world_mut().get_mut::<LayerStatus>(layer).unwrap() = LayerStatus::Ready { items: 1 };
        app.update();
        assert_eq!(*app.world().resource::<NextFrame>(), NextFrame::Idle);

        app.world_mut().write_message(MouseWheel {
            unit: bevy::input::mouse::MouseScrollUnit::Line,
            x: 0.0,
            y: 1.0,
            window: Entity::PLACEHOLDER,
            phase: bevy::input::touch::TouchPhase::Moved,
        });
        let mut nows = 0;
        for _ in 0..5 {
            app.update();
            if *app.world().resource::<NextFrame>() == NextFrame::Now {
                nows += 1;
                assert!(redraws(&app) >= 1);
            }
        }
        assert_eq!(nows, 2, "the input's frame and one settle frame, then idle");
        assert_eq!(*app.world().resource::<NextFrame>(), NextFrame::Idle);

        app.world_mut().resource_mut::<KeepAwake>().redraw();
        app.update();
        assert_eq!(*app.world().resource::<NextFrame>(), NextFrame::Now);
        app.world_mut().resource_mut::<DrawOnDemand>().enabled = false;
        app.update();
        assert_eq!(app.world().resource::<WinitSettings>().focused_mode, UpdateMode::Continuous);
    }
}
