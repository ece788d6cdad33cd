//! Offscreen rendering without a window: the App the `fascicle render` command and every GPU test use.
//!
//! How it works: `DefaultPlugins` without winit (no display needed), without pipelined rendering (so the
//! render world is stepped in lock-step with `App::update`), with synchronous pipeline compilation. The
//! caller adds its plugins and scene; [`capture`] steps frames until the render world's pipeline cache has
//! nothing waiting for several frames in a row (pipelines compiled, shaders and their imports loaded),
//! then takes a screenshot of the camera's target image. No frame count is guessed.

use std::sync::{Arc, Mutex};

use bevy::app::PluginsState;
use bevy::camera::RenderTarget;
use bevy::core_pipeline::tonemapping::Tonemapping;
use bevy::prelude::*;
use bevy::render::RenderApp;
use bevy::render::render_resource::{CachedPipelineState, PipelineCache, TextureFormat, TextureUsages};
use bevy::render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy::render::{RenderPlugin, pipelined_rendering::PipelinedRenderingPlugin};
use bevy::window::{ExitCondition, WindowPlugin};

/// An RGBA8 (sRGB-encoded) image read back from the GPU, rows top to bottom.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Capture {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<u8>,
}

impl Capture {
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = 4 * (y * self.width + x) as usize;
        [self.rgba[i], self.rgba[i + 1], self.rgba[i + 2], self.rgba[i + 3]]
    }

    /// Encodes as PNG.
    pub fn to_png(&self) -> Result<Vec<u8>, String> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Rgba);
            enc.set_depth(png::BitDepth::Eight);
            let mut w = enc.write_header().map_err(|e| e.to_string())?;
            w.write_image_data(&self.rgba).map_err(|e| e.to_string())?;
        }
        Ok(out)
    }
}

/// Everything that can stop a headless render.
#[derive(Debug)]
pub enum HeadlessError {
    /// No GPU adapter (not even a software one) could be created.
    NoAdapter(String),
    /// A render pipeline failed to compile (shader error).
    Pipeline(String),
    /// The scene did not become ready, or no screenshot arrived, within the frame budget.
    Timeout(String),
}

impl std::fmt::Display for HeadlessError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            HeadlessError::NoAdapter(why) => write!(
                f,
                "no GPU adapter could be created ({why}). On Debian install software Vulkan with \
                 `apt-get install mesa-vulkan-drivers libvulkan1` (lavapipe), or set FASCICLE_SKIP_GPU=1 \
                 to skip GPU tests explicitly"
            ),
            HeadlessError::Timeout(why) => write!(f, "headless render did not finish: {why}"),
            HeadlessError::Pipeline(why) => write!(f, "a render pipeline failed to compile: {why}"),
        }
    }
}

impl std::error::Error for HeadlessError {}

/// An App with Bevy's rendering and no window. Add plugins and entities, then call [`capture`].
pub fn headless_app() -> App {
    let mut app = App::new();
    app.add_plugins(
        DefaultPlugins
            .set(WindowPlugin {
                primary_window: None,
                exit_condition: ExitCondition::DontExit,
                close_when_requested: false,
                ..default()
            })
            .set(RenderPlugin { synchronous_pipeline_compilation: true, ..default() })
            .disable::<bevy::winit::WinitPlugin>()
            .disable::<PipelinedRenderingPlugin>()
            // Warnings and errors only (shader compile errors must be seen); B0006 on software adapters is expected.
            .set(bevy::log::LogPlugin {
                level: bevy::log::Level::WARN,
                filter: "wgpu=error,naga=warn".into(),
                ..default()
            }),
    );
    app
}

/// A render-target image of `width x height` that can be read back.
pub fn target_image(images: &mut Assets<Image>, width: u32, height: u32) -> Handle<Image> {
    let mut img = Image::new_target_texture(width, height, TextureFormat::Rgba8UnormSrgb, None);
    img.texture_descriptor.usage |= TextureUsages::COPY_SRC;
    images.add(img)
}

/// [`target_image`] added to the App's image assets.
pub fn add_target_image(app: &mut App, width: u32, height: u32) -> Handle<Image> {
    target_image(&mut app.world_mut().resource_mut::<Assets<Image>>(), width, height)
}

/// Camera components for exact offscreen tests: render into `target`, no tonemapping, no MSAA, so that a
/// shader's linear output maps to the image by the sRGB transfer function alone.
pub fn exact_camera(target: Handle<Image>) -> impl Bundle {
    (
        Camera3d::default(),
        RenderTarget::Image(target.into()),
        Tonemapping::None,
        bevy::core_pipeline::tonemapping::DebandDither::Disabled,
        Msaa::Off,
    )
}

/// Finishes plugin set-up (creating the GPU device). Fails with [`HeadlessError::NoAdapter`] when no
/// adapter exists instead of panicking.
pub fn initialise(app: &mut App) -> Result<(), HeadlessError> {
    if app.plugins_state() == PluginsState::Cleaned {
        return Ok(());
    }
    let res = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        while app.plugins_state() == PluginsState::Adding {
            bevy::tasks::tick_global_task_pools_on_main_thread();
        }
        app.finish();
        app.cleanup();
    }));
    res.map_err(|p| {
        let msg = p
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_else(|| "renderer initialisation panicked".into());
        HeadlessError::NoAdapter(msg)
    })
}

/// Pipelines queued but not yet compiled in the render world.
pub fn pending_pipelines(app: &App) -> usize {
    app.get_sub_app(RenderApp)
        .and_then(|s| s.world().get_resource::<PipelineCache>())
        .map_or(0, |c| c.waiting_pipelines().count())
}

/// Pipelines that failed to compile, with their errors.
pub fn failed_pipelines(app: &App) -> Vec<String> {
    app.get_sub_app(RenderApp)
        .and_then(|s| s.world().get_resource::<PipelineCache>())
        .map(|c| {
            c.pipelines()
                .filter_map(|p| match &p.state {
                    CachedPipelineState::Err(e) => Some(format!("{e}")),
                    _ => None,
                })
                .collect()
        })
        .unwrap_or_default()
}

/// Steps until nothing is pending for `STABLE_FRAMES` frames in a row. Fails if a pipeline failed.
pub fn run_until_ready(app: &mut App, max_frames: u32) -> Result<u32, HeadlessError> {
    const STABLE_FRAMES: u32 = 3;
    initialise(app)?;
    let mut stable = 0;
    for frame in 1..=max_frames {
        app.update();
        if pending_pipelines(app) == 0 {
            stable += 1;
        } else {
            stable = 0;
        }
        if stable >= STABLE_FRAMES {
            let failed = failed_pipelines(app);
            if !failed.is_empty() {
                return Err(HeadlessError::Pipeline(failed.join("\n")));
            }
            return Ok(frame);
        }
    }
    Err(HeadlessError::Timeout(format!(
        "{} pipelines still compiling after {max_frames} frames",
        pending_pipelines(app)
    )))
}

/// Renders until ready and reads `target` back.
pub fn capture(app: &mut App, target: Handle<Image>) -> Result<Capture, HeadlessError> {
    run_until_ready(app, 600)?;
    let slot: Arc<Mutex<Option<Image>>> = Arc::default();
    let sink = slot.clone();
    app.world_mut().spawn(Screenshot::image(target)).observe(move |ev: On<ScreenshotCaptured>| {
        if let Ok(mut s) = sink.lock() {
            *s = Some(ev.image.clone());
        }
    });
    for _ in 0..60 {
        app.update();
        let got = slot.lock().ok().and_then(|mut s| s.take());
        if let Some(img) = got {
            return to_capture(img);
        }
    }
    Err(HeadlessError::Timeout("no screenshot arrived within 60 frames".into()))
}

fn to_capture(img: Image) -> Result<Capture, HeadlessError> {
    let (w, h) = (img.width(), img.height());
    let format = img.texture_descriptor.format;
    let mut rgba = img.data.ok_or_else(|| HeadlessError::Timeout("screenshot had no data".into()))?;
    if rgba.len() != (w * h * 4) as usize {
        return Err(HeadlessError::Timeout(format!("screenshot of {w}x{h} had {} bytes", rgba.len())));
    }
    if matches!(format, TextureFormat::Bgra8Unorm | TextureFormat::Bgra8UnormSrgb) {
        for px in rgba.chunks_exact_mut(4) {
            px.swap(0, 2);
        }
    }
    Ok(Capture { width: w, height: h, rgba })
}

/// Whether GPU tests may be skipped: only when `FASCICLE_SKIP_GPU=1` is set explicitly (never in CI).
pub fn gpu_tests_skipped() -> bool {
    std::env::var("FASCICLE_SKIP_GPU").is_ok_and(|v| v == "1") && !std::env::var("CI").is_ok_and(|v| v == "true")
}
