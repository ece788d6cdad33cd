//! Goal: use a Fascicle render plugin inside a plain Bevy app with its own meshes and lights.
//! A depth-writing ray-cast sphere (the framework's reference glyph) intersects an ordinary lit cube.
//! Run: `cargo run --release --example embed_in_app`

use bevy::prelude::*;
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::impostor::SphereImpostorMaterial;

fn main() {
    App::new().add_plugins((DefaultPlugins, FascicleRenderPlugin)).add_systems(Startup, setup).run();
}

fn setup(
    mut commands: Commands,
    mut meshes: ResMut<Assets<Mesh>>,
    mut std_materials: ResMut<Assets<StandardMaterial>>,
    mut glyphs: ResMut<Assets<SphereImpostorMaterial>>,
) {
    let sphere = SphereImpostorMaterial::new(Vec3::new(0.5, 0.0, 0.0), 1.0, LinearRgba::rgb(0.9, 0.4, 0.2), 0.2);
    commands.spawn((
        Mesh3d(meshes.add(Cuboid::default())),
        sphere.proxy_transform(),
        MeshMaterial3d(glyphs.add(sphere)),
    ));
    commands.spawn((
        Mesh3d(meshes.add(Cuboid::new(1.2, 1.2, 1.2))),
        MeshMaterial3d(std_materials.add(Color::srgb(0.3, 0.5, 0.9))),
        Transform::from_xyz(-0.5, 0.0, 0.3),
    ));
    commands.spawn((PointLight::default(), Transform::from_xyz(3.0, 4.0, 5.0)));
    commands.spawn((Camera3d::default(), Transform::from_xyz(0.0, 1.5, 6.0).looking_at(Vec3::ZERO, Vec3::Y)));
}
