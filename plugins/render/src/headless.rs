//! Offscreen rendering without a window: the App the `fascicle render` command and every GPU test use.
//!
//! How it works: `DefaultPlugins` without winit (no display needed), without pipelined rendering (so the
//! render world is stepped in lock-step with `App::update`), with synchronous pipeline compilation. The
//! caller adds its plugins and scene; [`capture`] steps frames until the render world's pipeline cache has
//! nothing waiting for several frames in a row (pipelines compiled, shaders and their imports loaded),
//! then takes a screenshot of the camera's target image. No frame count is guessed.

use std::sync::{Arc, Mutex};

use bevy::app::PluginsState;
use bevy::asset::RenderAssetUsages;
use bevy::camera::RenderTarget;
use bevy::core_pipeline::tonemapping::Tonemapping;
use bevy::core_pipeline::{Core3dSystems, schedule::Core3d};
use bevy::prelude::*;
use bevy::render::RenderApp;
use bevy::render::extract_component::{ExtractComponent, ExtractComponentPlugin};
use bevy::render::gpu_readback::{Readback, ReadbackComplete};
use bevy::render::render_asset::RenderAssets;
use bevy::render::render_resource::{
    CachedPipelineState, Extent3d, Origin3d, PipelineCache, TexelCopyBufferInfo, TexelCopyBufferLayout,
    TexelCopyTextureInfo, TextureAspect, TextureFormat, TextureUsages,
};
use bevy::render::renderer::{RenderContext, ViewQuery};
use bevy::render::storage::{GpuShaderBuffer, ShaderBuffer};
use bevy::render::view::ViewDepthTexture;
use bevy::render::view::screenshot::{Screenshot, ScreenshotCaptured};
use bevy::render::{RenderPlugin, pipelined_rendering::PipelinedRenderingPlugin};
use bevy::window::{ExitCondition, WindowPlugin};

/// An RGBA8 (sRGB-encoded) image read back from the GPU, rows top to bottom.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Capture {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// R, G, B, A bytes of each pixel, rows top to bottom, each row left to right: `4 * width * height` bytes.
    pub rgba: Vec<u8>,
}

impl Capture {
    /// The RGBA bytes of pixel (x, y), y = 0 at the top; panics outside the image.
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

/// A camera's depth buffer read back from the GPU: Bevy's reverse-Z NDC depth per pixel, rows top to
/// bottom (1 at the near plane, falling towards 0 at infinity; 0 where nothing was drawn).
#[derive(Clone, Debug, PartialEq)]
pub struct DepthMap {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Reverse-Z NDC depth (0..1) of each pixel, rows top to bottom, each row left to right: `width * height`
    /// values.
    pub ndc: Vec<f32>,
}

impl DepthMap {
    /// The NDC depth of pixel (x, y), y = 0 at the top; panics outside the map.
    pub fn at(&self, x: u32, y: u32) -> f32 {
        self.ndc[(y * self.width + x) as usize]
    }

    /// Distance along the view axis for Bevy's infinite reverse-Z perspective (`z = near / ndc`): infinite
    /// where nothing was drawn.
    pub fn view_depth(&self, near: f32) -> Vec<f32> {
        self.ndc.iter().map(|&d| if d > 0.0 { near / d } else { f32::INFINITY }).collect()
    }

    /// A 16-bit greyscale PNG of the NDC depth (65535 at the near plane, 0 for the background).
    pub fn to_png16(&self) -> Result<Vec<u8>, String> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Grayscale);
            enc.set_depth(png::BitDepth::Sixteen);
            let mut w = enc.write_header().map_err(|e| e.to_string())?;
            let bytes: Vec<u8> =
                self.ndc.iter().flat_map(|d| ((d.clamp(0.0, 1.0) * 65535.0).round() as u16).to_be_bytes()).collect();
            w.write_image_data(&bytes).map_err(|e| e.to_string())?;
        }
        Ok(out)
    }

    /// A `.npy` (float32, shape height x width) of the view-space depth for a camera with near plane `near`.
    pub fn to_npy(&self, near: f32) -> Vec<u8> {
        let header =
            format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}), }}", self.height, self.width);
        let pad = 64 - (10 + header.len() + 1) % 64;
        let mut out = b"\x93NUMPY\x01\x00".to_vec();
        out.extend_from_slice(&((header.len() + pad + 1) as u16).to_le_bytes());
        out.extend_from_slice(header.as_bytes());
        out.extend(std::iter::repeat_n(b' ', pad));
        out.push(b'\n');
        for v in self.view_depth(near) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }
}

/// On a camera: copy its depth buffer into `buffer` after the main pass of every frame, for
/// [`capture_with_depth`]. The camera needs `Msaa::Off` (a multisampled depth buffer cannot be copied) and
/// a `Camera3d` whose depth usages include `COPY_SRC` ([`depth_copy_camera`]).
#[derive(Component, Clone, ExtractComponent)]
pub struct DepthCopy {
    /// The buffer the depth is copied into: `height` rows of [`DepthCopy::bytes_per_row`] bytes, one
    /// little-endian `f32` per pixel and rows padded to 256 bytes ([`add_depth_copy`] makes it).
    pub buffer: Handle<ShaderBuffer>,
    /// The camera's depth texture width, pixels; a texture of another size (or multisampled) is not copied.
    pub width: u32,
    /// The camera's depth texture height, pixels.
    pub height: u32,
}

impl DepthCopy {
    /// Bytes per row in the buffer: copies need rows aligned to 256 bytes.
    pub fn bytes_per_row(&self) -> u32 {
        (self.width * 4).div_ceil(256) * 256
    }
}

/// Copies depth for cameras with [`DepthCopy`].
pub struct DepthCopyPlugin;

impl Plugin for DepthCopyPlugin {
    fn build(&self, app: &mut App) {
        app.add_plugins(ExtractComponentPlugin::<DepthCopy>::default());
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app
                .add_systems(Core3d, copy_depth.after(Core3dSystems::MainPass).before(Core3dSystems::PostProcess));
        }
    }
}

fn copy_depth(
    view: ViewQuery<(&ViewDepthTexture, &DepthCopy)>,
    buffers: Res<RenderAssets<GpuShaderBuffer>>,
    mut ctx: RenderContext,
) {
    let (depth, copy) = view.into_inner();
    let Some(gpu) = buffers.get(&copy.buffer) else { return };
    let size = depth.texture.size();
    if size.width != copy.width || size.height != copy.height || depth.texture.sample_count() != 1 {
        return;
    }
    ctx.command_encoder().copy_texture_to_buffer(
        TexelCopyTextureInfo {
            texture: &depth.texture,
            mip_level: 0,
            origin: Origin3d::ZERO,
            aspect: TextureAspect::DepthOnly,
        },
        TexelCopyBufferInfo {
            buffer: &gpu.buffer,
            layout: TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(copy.bytes_per_row()),
                rows_per_image: None,
            },
        },
        Extent3d { width: copy.width, height: copy.height, depth_or_array_layers: 1 },
    );
}

/// A [`DepthCopy`] for a `width x height` camera, its buffer added to the App's assets.
pub fn add_depth_copy(app: &mut App, width: u32, height: u32) -> DepthCopy {
    let mut copy = DepthCopy { buffer: Handle::default(), width, height };
    let size = (copy.bytes_per_row() * height) as usize;
    let buffer = ShaderBuffer::with_size(size, RenderAssetUsages::RENDER_WORLD);
    copy.buffer = app.world_mut().resource_mut::<Assets<ShaderBuffer>>().add(buffer);
    copy
}

/// Camera components for a camera whose depth is copied: a `Camera3d` with `COPY_SRC` depth usage, no MSAA.
pub fn depth_copy_camera(copy: DepthCopy) -> impl Bundle {
    (
        Camera3d {
            depth_texture_usages: (TextureUsages::RENDER_ATTACHMENT | TextureUsages::COPY_SRC).into(),
            ..default()
        },
        Msaa::Off,
        copy,
    )
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
    headless_app_with_assets(None)
}

/// [`headless_app`] whose asset server reads from `asset_root` (default: Bevy's `assets`).
pub fn headless_app_with_assets(asset_root: Option<&str>) -> App {
    // The global logger can be set once per process; later apps (benchmarks render many) go without.
    static LOGGER_SET: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    let first = !LOGGER_SET.swap(true, std::sync::atomic::Ordering::SeqCst);
    let mut app = App::new();
    let plugins = crate::batching::default_plugins()
        .set(WindowPlugin {
            primary_window: None,
            exit_condition: ExitCondition::DontExit,
            close_when_requested: false,
            ..default()
        })
        .set(RenderPlugin {
            render_creation: shared_render_creation(),
            synchronous_pipeline_compilation: true,
            ..default()
        })
        .disable::<PipelinedRenderingPlugin>()
        .set(bevy::asset::AssetPlugin {
            // Relative to the crate (or executable) directory; an absolute path is taken as it is.
            file_path: asset_root.unwrap_or("assets").into(),
            ..default()
        })
        // Warnings and errors only (shader compile errors must be seen); B0006 on software adapters is expected.
        .set(bevy::log::LogPlugin {
            level: bevy::log::Level::WARN,
            filter: "wgpu=error,naga=warn".into(),
            ..default()
        });
    // Bevy's winit plugin opens an event loop when built (it needs a display): an app that enables
    // `bevy_winit` enables this crate's `winit` feature, and the plugin is left out here.
    #[cfg(feature = "winit")]
    let plugins = plugins.disable::<bevy::winit::WinitPlugin>();
    if first {
        app.add_plugins(plugins);
    } else {
        app.add_plugins(plugins.disable::<bevy::log::LogPlugin>());
    }
    if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
        render_app.add_systems(
            bevy::render::Render,
            (finish_frame, share_render_resources).in_set(bevy::render::RenderSystems::Cleanup),
        );
    }
    app
}

/// The GPU device (with its queue, adapter and instance) that the first headless app of the process opened;
/// every later headless app renders with it instead of opening its own. Benchmarks and test binaries make
/// hundreds of apps one after another: on an H200 (driver 580) opening a new device per app failed after 24-30
/// of them ("Unable to find a GPU!"), and each opening costs about half a second.
static SHARED_RENDER: Mutex<Option<bevy::render::settings::RenderResources>> = Mutex::new(None);

/// `Manual` with the process's shared device once one is open, else `Automatic` ([`crate::wgpu_settings`]).
fn shared_render_creation() -> bevy::render::settings::RenderCreation {
    match SHARED_RENDER.lock().unwrap_or_else(|e| e.into_inner()).clone() {
        Some(resources) => bevy::render::settings::RenderCreation::Manual(resources),
        None => crate::wgpu_settings().into(),
    }
}

/// Records the render world's device for [`shared_render_creation`] (the first app's, once).
fn share_render_resources(
    device: Res<bevy::render::renderer::RenderDevice>,
    queue: Res<bevy::render::renderer::RenderQueue>,
    info: Res<bevy::render::renderer::RenderAdapterInfo>,
    adapter: Res<bevy::render::renderer::RenderAdapter>,
    instance: Res<bevy::render::renderer::RenderInstance>,
    mut done: Local<bool>,
) {
    if std::mem::replace(&mut *done, true) {
        return;
    }
    let mut shared = SHARED_RENDER.lock().unwrap_or_else(|e| e.into_inner());
    if shared.is_none() {
        *shared = Some(bevy::render::settings::RenderResources(
            device.clone(),
            queue.clone(),
            info.clone(),
            adapter.clone(),
            instance.clone(),
        ));
    }
}

/// Ends each headless frame when the GPU has finished it. Without a window nothing presents, so nothing else
/// holds the CPU back: on a hardware GPU, `app.update()` returns as soon as the frame is submitted, frames
/// queue up without bound (memory grows with the submissions in flight, and frame times measure the CPU
/// alone), and dropping the app then waits at most 6.3 s in wgpu's `Queue::drop` before it panics ("timed out
/// while waiting on the last successful submission"), which is how `bench volume` and `bench tracts` stopped
/// on an H100. Waiting also lets wgpu reclaim finished submissions' resources (without a poll a long headless
/// run grows by megabytes a frame). On lavapipe a frame already took its whole time inside `app.update()`
/// (bench frame times follow the shaders' cost), so there the wait finds little or nothing left.
fn finish_frame(device: Res<bevy::render::renderer::RenderDevice>, mut reported: Local<bool>) {
    if let Err(e) = device.poll(bevy::render::render_resource::PollType::wait_indefinitely())
        && !std::mem::replace(&mut *reported, true)
    {
        error!("waiting for the GPU to finish a headless frame failed: {e}");
    }
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

/// The start of every offscreen GPU test: `None` (saying so) when GPU tests are skipped, else a headless app
/// with Fascicle's render plugin and an sRGB image target of `width` x `height`. Add the plugin under test.
pub fn gpu_test_app(width: u32, height: u32) -> Option<(App, Handle<Image>)> {
    if gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return None;
    }
    let mut app = headless_app();
    app.add_plugins(crate::FascicleRenderPlugin);
    let target = add_target_image(&mut app, width, height);
    Some((app, target))
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

/// The GPU tests' camera: an [`exact_camera`] into `target` with a black background, at `eye` looking at
/// `look_at` with +Y up.
pub fn spawn_test_camera(app: &mut App, target: Handle<Image>, eye: Vec3, look_at: Vec3) -> Entity {
    app.world_mut()
        .spawn((
            exact_camera(target),
            Camera { clear_color: ClearColorConfig::Custom(Color::BLACK), ..default() },
            Transform::from_translation(eye).looking_at(look_at, Vec3::Y),
        ))
        .id()
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

/// Pipelines the render world's cache holds (compiled, queued or failed).
pub fn pipeline_count(app: &App) -> usize {
    app.get_sub_app(RenderApp)
        .and_then(|s| s.world().get_resource::<PipelineCache>())
        .map_or(0, |c| c.pipelines().count())
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

/// Steps `app` until no pipeline has been waiting for three frames (all compiled, or failed: an error);
/// returns the frames it took. While it waits the active cameras draw into a single pixel of their viewports
/// (the same pipelines are specialised and compiled; on a software rasteriser a frame of a dense scene costs
/// seconds at full size), and get their viewports back before it returns.
pub fn run_until_ready(app: &mut App, max_frames: u32) -> Result<u32, HeadlessError> {
    const STABLE_FRAMES: u32 = 3;
    initialise(app)?;
    let start = std::time::Instant::now();
    let shrunk = begin_warmup(app);
    let mut stable = 0;
    let mut result = Err(HeadlessError::Timeout(String::new()));
    for frame in 1..=max_frames {
        app.update();
        if pending_pipelines(app) == 0 {
            stable += 1;
        } else {
            stable = 0;
        }
        if stable >= STABLE_FRAMES {
            let failed = failed_pipelines(app);
            result = if failed.is_empty() { Ok(frame) } else { Err(HeadlessError::Pipeline(failed.join("\n"))) };
            break;
        }
    }
    end_warmup(app, shrunk);
    debug!("fascicle-render: pipelines ready after {result:?} frames, {:.2} s", start.elapsed().as_secs_f64());
    if let Err(HeadlessError::Timeout(_)) = result {
        return Err(HeadlessError::Timeout(format!(
            "{} pipelines still compiling after {max_frames} frames",
            pending_pipelines(app)
        )));
    }
    result
}

/// The active cameras' viewports before [`shrink_viewports`].
type SavedViewports = Vec<(Entity, Option<bevy::camera::Viewport>)>;

/// Makes every active camera draw into the first pixel of its viewport; returns what to restore.
fn shrink_viewports(app: &mut App) -> SavedViewports {
    let world = app.world_mut();
    let mut cameras = world.query::<(Entity, &mut Camera)>();
    cameras
        .iter_mut(world)
        .filter(|(_, c)| c.is_active)
        .map(|(e, mut c)| {
            let saved = c.viewport.clone();
            let at = saved.as_ref().map_or(UVec2::ZERO, |v| v.physical_position);
            c.viewport = Some(bevy::camera::Viewport { physical_position: at, physical_size: UVec2::ONE, ..default() });
            (e, saved)
        })
        .collect()
}

fn restore_viewports(app: &mut App, saved: SavedViewports) {
    for (e, viewport) in saved {
        if let Some(mut c) = app.world_mut().get_mut::<Camera>(e) {
            c.viewport = viewport;
        }
    }
}

/// Sets `is_active` of the cameras listed, or of every active camera (returning them) when `cameras` is `None`.
fn set_cameras_active(app: &mut App, cameras: Option<&[Entity]>, active: bool) -> Vec<Entity> {
    let world = app.world_mut();
    let mut query = world.query::<(Entity, &mut Camera)>();
    let mut changed = Vec::new();
    for (e, mut c) in query.iter_mut(world) {
        let listed = cameras.map_or(c.is_active != active, |l| l.contains(&e));
        if listed && c.is_active != active {
            c.is_active = active;
            changed.push(e);
        }
    }
    changed
}

/// Renders until ready and reads `target` back.
pub fn capture(app: &mut App, target: Handle<Image>) -> Result<Capture, HeadlessError> {
    capture_with_depth(app, target, None).map(|(c, _)| c)
}

/// Renders until ready and reads `target` back, and with `depth` (the [`DepthCopy`] on the camera) the
/// depth buffer of the same frame.
pub fn capture_with_depth(
    app: &mut App,
    target: Handle<Image>,
    depth: Option<&DepthCopy>,
) -> Result<(Capture, Option<DepthMap>), HeadlessError> {
    run_until_ready(app, 600)?;
    let colour: Arc<Mutex<Option<Image>>> = Arc::default();
    let sink = colour.clone();
    app.world_mut().spawn(Screenshot::image(target)).observe(move |ev: On<ScreenshotCaptured>| {
        if let Ok(mut s) = sink.lock() {
            *s = Some(ev.image.clone());
        }
    });
    let depth_bytes: Arc<Mutex<Option<Vec<u8>>>> = Arc::default();
    let readback = depth.map(|d| {
        let sink = depth_bytes.clone();
        app.world_mut()
            .spawn(Readback::buffer(d.buffer.clone()))
            .observe(move |ev: On<ReadbackComplete>| {
                if let Ok(mut s) = sink.lock() {
                    s.get_or_insert_with(|| ev.data.clone());
                }
            })
            .id()
    });
    // One frame draws the image and copies it out; the cameras are then paused while its readback arrives
    // (each further frame of a dense scene would cost as much again on a software rasteriser), and resumed.
    let start = std::time::Instant::now();
    app.update();
    debug!("fascicle-render: the captured frame took {:.2} s", start.elapsed().as_secs_f64());
    let paused = set_cameras_active(app, None, false);
    let result = await_readback(app, (&colour, &depth_bytes), readback, depth);
    set_cameras_active(app, Some(&paused), true);
    result
}

/// Reads `target` back as the app's next frame draws it, as it is: no warm-up, no viewport shrinking, the
/// cameras not paused while the readback arrives (each frame until then is drawn, or put back by
/// [`crate::retain`]). For tests of what one frame draws; [`capture`] prepares the frame first.
pub fn capture_next_frame(app: &mut App, target: Handle<Image>) -> Result<Capture, HeadlessError> {
    initialise(app)?;
    let colour: Arc<Mutex<Option<Image>>> = Arc::default();
    let sink = colour.clone();
    app.world_mut().spawn(Screenshot::image(target)).observe(move |ev: On<ScreenshotCaptured>| {
        if let Ok(mut s) = sink.lock() {
            *s = Some(ev.image.clone());
        }
    });
    await_readback(app, (&colour, &Arc::default()), None, None).map(|(c, _)| c)
}

/// A captured colour image and depth bytes, as the observers leave them.
type Sinks<'a> = (&'a Arc<Mutex<Option<Image>>>, &'a Arc<Mutex<Option<Vec<u8>>>>);

fn await_readback(
    app: &mut App,
    (colour, depth_bytes): Sinks,
    readback: Option<Entity>,
    depth: Option<&DepthCopy>,
) -> Result<(Capture, Option<DepthMap>), HeadlessError> {
    let (mut got_colour, mut got_depth) = (None, None);
    // The readback arrives when the GPU has finished the frame and mapped the buffer: on a software rasteriser
    // sharing the CPU with other work that can take many quick frames, so the wait is bounded in time (at
    // least 60 frames and 60 seconds), not in frames alone.
    let start = std::time::Instant::now();
    let mut frames = 0;
    while frames < 60 || start.elapsed() < std::time::Duration::from_secs(60) {
        frames += 1;
        if frames > 60 {
            std::thread::sleep(std::time::Duration::from_millis(5));
        }
        app.update();
        if got_colour.is_none() {
            got_colour = colour.lock().ok().and_then(|mut s| s.take());
        }
        if got_depth.is_none() {
            got_depth = depth_bytes.lock().ok().and_then(|mut s| s.take());
        }
        if let Some(img) = got_colour.take_if(|_| depth.is_none() || got_depth.is_some()) {
            if let Some(e) = readback {
                app.world_mut().despawn(e);
            }
            let depth_map = match (depth, got_depth) {
                (Some(d), Some(bytes)) => Some(to_depth_map(d, &bytes)?),
                _ => None,
            };
            return Ok((to_capture(img)?, depth_map));
        }
    }
    Err(HeadlessError::Timeout(format!("no screenshot (or depth readback) arrived within {frames} frames (60 s)")))
}

fn to_depth_map(d: &DepthCopy, bytes: &[u8]) -> Result<DepthMap, HeadlessError> {
    let row = d.bytes_per_row() as usize;
    if bytes.len() < row * d.height as usize {
        return Err(HeadlessError::Timeout(format!("depth readback had {} bytes", bytes.len())));
    }
    let mut ndc = Vec::with_capacity((d.width * d.height) as usize);
    for y in 0..d.height as usize {
        for x in 0..d.width as usize {
            let o = y * row + 4 * x;
            ndc.push(f32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]));
        }
    }
    Ok(DepthMap { width: d.width, height: d.height, ndc })
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

/// Steps `app` until no layer is [`LayerStatus::Loading`](crate::layer::LayerStatus) (its data loaded or
/// failed), without drawing while they load, then one frame more so the layers' builds are applied; an error
/// after [`LOAD_TIMEOUT`].
pub fn wait_for_layers(app: &mut App) -> Result<(), HeadlessError> {
    use crate::layer::LayerStatus;
    fn loading(app: &mut App) -> bool {
        let world = app.world_mut();
        world.query::<&LayerStatus>().iter(world).any(|s| *s == LayerStatus::Loading)
    }
    app.update();
    if !loading(app) {
        app.update();
        return Ok(());
    }
    // Nothing is drawn while layers load: every frame would draw all that has arrived so far (a streamed
    // tractogram part by part, seconds a frame on a software rasteriser), taking the CPU from the loading it
    // waits for. The cameras are paused until the layers are in, however long their data take to read.
    let paused = set_cameras_active(app, None, false);
    let start = std::time::Instant::now();
    let result = loop {
        app.update();
        if !loading(app) {
            debug!("fascicle-render: layers loaded in {:.2} s", start.elapsed().as_secs_f64());
            break Ok(());
        }
        if start.elapsed() > LOAD_TIMEOUT {
            break Err(HeadlessError::Timeout(format!("layers still loading after {} s", LOAD_TIMEOUT.as_secs())));
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    };
    // One frame more applies what the last frame spawned, with the cameras on (what follows a camera, such as
    // a depth sort, is done) but drawing into one pixel, each layer's parts but one hidden.
    set_cameras_active(app, Some(&paused), true);
    let shrunk = begin_warmup(app);
    app.update();
    end_warmup(app, shrunk);
    result
}

/// Starts a warm-up: the active cameras draw into one pixel and [`PipelineWarmup`] is present.
fn begin_warmup(app: &mut App) -> SavedViewports {
    app.insert_resource(PipelineWarmup);
    shrink_viewports(app)
}

/// Ends a warm-up: the viewports back, and a frame without drawing in which the plugins show what they hid.
fn end_warmup(app: &mut App, shrunk: SavedViewports) {
    restore_viewports(app, shrunk);
    app.world_mut().remove_resource::<PipelineWarmup>();
    let paused = set_cameras_active(app, None, false);
    app.update();
    set_cameras_active(app, Some(&paused), true);
}

/// Present while [`run_until_ready`] waits for the pipelines: a plugin that draws many like entities (the
/// parts of a streamed tractogram) may hide all but one of each kind meanwhile, since the others would use
/// the same pipelines; each warm-up frame then costs what one part costs, not what the scene costs.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct PipelineWarmup;

/// How long [`wait_for_layers`] waits for data to load before it reports a timeout: an hour (a whole-brain
/// tractogram read from a slow disk takes minutes, not hours).
pub const LOAD_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(3600);

/// Whether GPU tests may be skipped: only when `FASCICLE_SKIP_GPU=1` is set explicitly (never in CI).
pub fn gpu_tests_skipped() -> bool {
    std::env::var("FASCICLE_SKIP_GPU").is_ok_and(|v| v == "1") && !std::env::var("CI").is_ok_and(|v| v == "true")
}
