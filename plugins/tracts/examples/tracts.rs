//! Tracts from a TrackVis file: add `TractPlugin`, spawn one `Tracts` entity; the plugin loads the file off
//! the main thread and draws its streamlines as hyperstreamlines (ray-cast tubelets, true depth). Key `L`
//! switches to lines and back (the layer's set is rebuilt; nothing else is touched).
//!
//! The file is DIPY's `tracks300.trk` (300 streamlines of a real brain).
//!
//! Run: `cargo run --release -p fascicle-tracts --example tracts [-- --headless out.png]`

use bevy::prelude::*;
use fascicle_render::example::ExampleApp;
use fascicle_tracts::{TractPlugin, TractStyle, Tracts};

pub const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data");

fn main() -> AppExit {
    app(ExampleApp::from_args("Fascicle: tracts", DATA)).run()
}

pub fn app(mut example: ExampleApp) -> ExampleApp {
    example.app.add_plugins(TractPlugin).add_systems(Startup, setup).add_systems(Update, toggle);
    example
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    commands.spawn(Tracts { tractogram: assets.load("tracts/tracks300.trk") });
    // The streamlines span (64..116, 78..121, 61..92) mm (RAS+, `fascicle info`): a view from above.
    let centre = Vec3::new(90.0, 100.0, 77.0);
    commands
        .spawn((Camera3d::default(), Transform::from_translation(centre + 90.0 * Vec3::Z).looking_at(centre, Vec3::Y)));
}

fn toggle(input: Res<ButtonInput<KeyCode>>, mut styles: Query<&mut TractStyle>) {
    if input.just_pressed(KeyCode::KeyL) {
        for mut style in &mut styles {
            *style = match *style {
                TractStyle::Lines { .. } => TractStyle::default(),
                _ => TractStyle::Lines { opacity: 1.0 },
            };
        }
    }
}
