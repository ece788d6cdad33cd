//! The runner of the plugins' examples: the same scene in a window, or offscreen to a PNG with
//! `--headless OUT.png` (or `FASCICLE_HEADLESS=OUT.png`), which is how the examples' tests render them.
//!
//! Offscreen, every camera the example spawns renders into one image; the runner steps frames until no
//! layer is still loading its data ([`LayerStatus::Loading`]) and every pipeline is compiled, then reads the
//! image back.

use std::path::PathBuf;

use bevy::camera::RenderTarget;
use bevy::prelude::*;

use crate::headless::{self, Capture, HeadlessError};
use crate::layer::LayerStatus;

/// An example's App and where its frame goes.
pub struct ExampleApp {
    /// The Bevy App: the example adds its plugins, systems and scene to it before [`ExampleApp::run`].
    pub app: App,
    /// Offscreen: the PNG to write (if any) and the image every camera renders into.
    offscreen: Option<(Option<PathBuf>, Handle<Image>)>,
}

/// Offscreen frame size.
pub const WIDTH: u32 = 640;
/// Offscreen frame height, pixels ([`WIDTH`] is the width).
pub const HEIGHT: u32 = 480;

impl ExampleApp {
    /// From the command line: `--headless OUT.png` (or `FASCICLE_HEADLESS`) renders offscreen, otherwise a
    /// window titled `title` opens. Assets are read from `asset_root`.
    pub fn from_args(title: &str, asset_root: &str) -> Self {
        let args: Vec<String> = std::env::args().collect();
        let out = args
            .iter()
            .position(|a| a == "--headless")
            .and_then(|i| args.get(i + 1).map(PathBuf::from))
            .or_else(|| std::env::var_os("FASCICLE_HEADLESS").map(PathBuf::from));
        match out {
            Some(out) => Self::offscreen(asset_root, Some(out)),
            None => Self::windowed(title, asset_root),
        }
    }

    /// A window with Bevy's default plugins.
    pub fn windowed(title: &str, asset_root: &str) -> Self {
        let mut app = App::new();
        app.add_plugins(
            crate::batching::default_plugins()
                .set(WindowPlugin { primary_window: Some(Window { title: title.into(), ..default() }), ..default() })
                .set(AssetPlugin { file_path: asset_root.into(), ..default() }),
        );
        Self { app, offscreen: None }
    }

    /// Offscreen, into a [`WIDTH`] x [`HEIGHT`] image (written to `out` by [`ExampleApp::run`]).
    pub fn offscreen(asset_root: &str, out: Option<PathBuf>) -> Self {
        let mut app = headless::headless_app_with_assets(Some(asset_root));
        let target = headless::add_target_image(&mut app, WIDTH, HEIGHT);
        let image = target.clone();
        app.add_systems(PreUpdate, move |mut commands: Commands, cameras: Query<Entity, Added<Camera>>| {
            for camera in &cameras {
                commands.entity(camera).insert(RenderTarget::Image(image.clone().into()));
            }
        });
        Self { app, offscreen: Some((out, target)) }
    }

    /// Runs the window, or renders offscreen and writes the PNG.
    pub fn run(mut self) -> AppExit {
        if self.offscreen.is_none() {
            return self.app.run();
        }
        let out = self.offscreen.as_ref().and_then(|(o, _)| o.clone());
        match self.render().and_then(|c| {
            let png = c.to_png().map_err(HeadlessError::Timeout)?;
            if let Some(out) = &out {
                std::fs::write(out, png).map_err(|e| HeadlessError::Timeout(format!("{}: {e}", out.display())))?;
                println!("wrote {}", out.display());
            }
            Ok(())
        }) {
            Ok(()) => AppExit::Success,
            Err(e) => {
                eprintln!("error: {e}");
                AppExit::error()
            }
        }
    }

    /// Renders offscreen once every layer has loaded: the frame. A layer that failed is an error naming it.
    /// The App stays, for a test to read its world.
    pub fn render(&mut self) -> Result<Capture, HeadlessError> {
        let Some((_, target)) = self.offscreen.clone() else {
            return Err(HeadlessError::Timeout("a windowed example cannot be captured".into()));
        };
        let app = &mut self.app;
        headless::initialise(app)?;
        headless::wait_for_layers(app)?;
        let world = app.world_mut();
        if let Some(LayerStatus::Failed(e)) =
            world.query::<&LayerStatus>().iter(world).find(|s| matches!(s, LayerStatus::Failed(_)))
        {
            return Err(HeadlessError::Timeout(format!("a layer failed: {e}")));
        }
        headless::capture(app, target)
    }
}
