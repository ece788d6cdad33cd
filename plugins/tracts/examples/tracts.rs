//! Tracts from a TrackVis file, with an ROI you drag: add `TractPlugin`, spawn one `Tracts` entity and an
//! include ROI as its child; the plugin loads the file off the main thread, draws the streamlines as
//! hyperstreamlines (ray-cast tubelets, true depth) and shows only those that pass through the ROI.
//!
//! Drag the ROI (the green sphere) with the left mouse button: each move is a component write, and only
//! the selection flags are re-evaluated and re-sent. `E` switches include / exclude; `L` switches lines
//! and tubelets (that layer's set is rebuilt; the ROI stays).
//!
//! The file is DIPY's `tracks300.trk` (300 streamlines of a real brain).
//!
//! Run: `cargo run --release -p fascicle-tracts --example tracts [-- --headless out.png]`

use bevy::prelude::*;
use fascicle_core::roi::{Roi, RoiMode, RoiShape};
use fascicle_render::example::ExampleApp;
use fascicle_tracts::{TractPlugin, TractRoi, TractStyle, Tracts};

/// The repository's data folder: under the package's folder as cargo gives it at run time, else as it was
/// when built.
pub fn data() -> String {
    format!("{}/../../data", std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
}
/// The streamlines span (64..116, 78..121, 61..92) mm (RAS+, `fascicle info`).
pub const CENTRE: Vec3 = Vec3::new(90.0, 100.0, 77.0);
/// Where the ROI starts: on the bundle, a fifth of the streamlines pass through.
pub const ROI_START: Vec3 = Vec3::new(94.0, 96.0, 84.0);
pub const ROI_RADIUS: f32 = 6.0;

fn main() -> AppExit {
    app(ExampleApp::from_args("Fascicle: tracts and a draggable ROI", &data())).run()
}

pub fn app(mut example: ExampleApp) -> ExampleApp {
    example.app.add_plugins(TractPlugin).add_systems(Startup, setup).add_systems(Update, (drag, keys));
    example
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    let layer = commands.spawn(Tracts { tractogram: assets.load("tracts/tracks300.trk") }).id();
    let sphere = RoiShape::Sphere { centre: ROI_START.to_array(), radius: ROI_RADIUS };
    commands.spawn((TractRoi(Roi { shape: sphere, mode: RoiMode::Include }), ChildOf(layer)));
    commands
        .spawn((Camera3d::default(), Transform::from_translation(CENTRE + 90.0 * Vec3::Z).looking_at(CENTRE, Vec3::Y)));
}

/// Grabs a sphere ROI under the cursor and moves it in the plane through its centre facing the camera.
fn drag(
    buttons: Res<ButtonInput<MouseButton>>,
    windows: Query<&Window>,
    cameras: Query<(&Camera, &GlobalTransform)>,
    mut rois: Query<&mut TractRoi>,
    mut grabbed: Local<bool>,
) {
    let (Ok(window), Ok((camera, at))) = (windows.single(), cameras.single()) else { return };
    let Some(ray) = window.cursor_position().and_then(|c| camera.viewport_to_world(at, c).ok()) else { return };
    if !buttons.pressed(MouseButton::Left) {
        *grabbed = false;
        return;
    }
    for mut roi in &mut rois {
        let RoiShape::Sphere { centre, radius } = roi.0.shape else { continue };
        let c = Vec3::from(centre);
        if buttons.just_pressed(MouseButton::Left) {
            *grabbed = (c - ray.origin).cross(*ray.direction).length() <= radius;
        }
        let Some(t) = ray.intersect_plane(c, InfinitePlane3d::new(at.forward().as_vec3())) else { continue };
        let p = ray.get_point(t);
        if *grabbed && p != c {
            roi.0.shape = RoiShape::Sphere { centre: p.to_array(), radius };
        }
    }
}

fn keys(input: Res<ButtonInput<KeyCode>>, mut styles: Query<&mut TractStyle>, mut rois: Query<&mut TractRoi>) {
    if input.just_pressed(KeyCode::KeyL) {
        for mut style in &mut styles {
            *style = match *style {
                TractStyle::Lines { .. } => TractStyle::default(),
                _ => TractStyle::Lines { opacity: 1.0 },
            };
        }
    }
    if input.just_pressed(KeyCode::KeyE) {
        for mut roi in &mut rois {
            roi.0.mode = match roi.0.mode {
                RoiMode::Include => RoiMode::Exclude,
                RoiMode::Exclude => RoiMode::Include,
            };
        }
    }
}
