//! My own Bevy app: its camera, light and meshes, plus one Fascicle plugin and one entity. The glyphs are
//! ray-cast and write true depth, so they intersect the app's own meshes (the bar through the slice).
//!
//! Run: `cargo run --release -p fascicle-sh-glyphs --example my_app [-- --headless out.png]`

use bevy::prelude::*;
use fascicle_render::example::ExampleApp;
use fascicle_sh_glyphs::{ShGlyphPlugin, ShGlyphs};

/// The repository's data folder: under the package's folder as cargo gives it at run time, else as it was
/// when built.
pub fn data() -> String {
    format!("{}/../../data", std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
}

fn main() -> AppExit {
    app(ExampleApp::from_args("My app with Fascicle glyphs", &data())).run()
}

pub fn app(mut example: ExampleApp) -> ExampleApp {
    example.app.add_plugins(ShGlyphPlugin).add_systems(Startup, setup);
    example
}

fn setup(
    mut commands: Commands,
    assets: Res<AssetServer>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    // The Fascicle part: one entity (the middle slice of the field, glyphs sized to their grid).
    commands.spawn(ShGlyphs { field: assets.load("sh/small_64D_csa_l6.nii.gz") });

    // The app's own scene: a red bar through the slice, a grey floor below it, a light and a camera.
    commands.spawn((
        Mesh3d(meshes.add(Cuboid::new(24.0, 1.5, 1.5))),
        MeshMaterial3d(materials.add(Color::srgb(0.9, 0.1, 0.1))),
        Transform::from_xyz(11.0, 14.0, 20.0),
    ));
    commands.spawn((
        Mesh3d(meshes.add(Plane3d::new(Vec3::Z, Vec2::splat(30.0)))),
        MeshMaterial3d(materials.add(Color::srgb(0.4, 0.4, 0.4))),
        Transform::from_xyz(11.0, 14.0, 5.0),
    ));
    commands.spawn((DirectionalLight::default(), Transform::from_xyz(0.0, 0.0, 1.0).looking_at(Vec3::ZERO, Vec3::Y)));
    commands.spawn((
        Camera3d::default(),
        Transform::from_xyz(11.0, 14.0, 46.0).looking_at(Vec3::new(11.0, 14.0, 20.0), Vec3::Y),
    ));
}
