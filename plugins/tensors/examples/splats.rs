//! Tensor splats with the barycentric transfer function: add `TensorGlyphPlugin`, spawn one `TensorSplats`
//! entity; the plugin loads the tensors, turns each voxel of a slab into a Gaussian footprint (EWA), colours
//! it and sets its opacity from where its Westin measures (cl, cp, cs) fall in the barycentric triangle,
//! sorts the splats by depth and composites them in one draw.
//!
//! The transfer function here shows linear tensors (fibres) in red and planar ones in green, and fades
//! spherical ones (grey matter, CSF) to near transparency. Keys: `P` moves the opacity bump to the planar corner and back (the
//! colour buffer alone is rewritten), `A` toggles depth attenuation (a uniform write).
//!
//! Run: `cargo run --release -p fascicle-tensors --example splats [-- --headless out.png]`

use bevy::prelude::*;
use fascicle_core::dti::barycentric::BarycentricTf;
use fascicle_core::dti::splat::{SplatColourMode, SplatColouring};
use fascicle_render::example::ExampleApp;
use fascicle_tensors::{Selection, SliceAxis, SplatSettings, SplatShape, TensorGlyphPlugin, TensorSplats};

/// The repository's data folder: under the package's folder as cargo gives it at run time, else as it was
/// when built.
pub fn data() -> String {
    format!("{}/../../data", std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
}

/// Red fibres, green sheets, grey spheres; opacity peaks at the linear corner and fades towards the others.
pub fn colouring() -> SplatColouring {
    let tf = BarycentricTf {
        corners: [[0.9, 0.1, 0.05], [0.1, 0.8, 0.1], [0.2, 0.2, 0.2]],
        width: 0.45,
        ..BarycentricTf::default()
    };
    SplatColouring { mode: SplatColourMode::Barycentric, tf }
}

fn main() -> AppExit {
    app(ExampleApp::from_args("Fascicle: tensor splats", &data())).run()
}

pub fn app(mut example: ExampleApp) -> ExampleApp {
    example.app.add_plugins(TensorGlyphPlugin).add_systems(Startup, setup).add_systems(Update, keys);
    example
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    commands.spawn((
        TensorSplats { field: assets.load("dti/small_64D_tensor.nii.gz") },
        Selection::Slab { axis: SliceAxis::Z, index: Some(5), thickness: 5 },
        SplatShape { size: 0.35, ..default() },
        SplatSettings { colouring: colouring(), ..default() },
    ));
    commands.insert_resource(ClearColor(Color::BLACK));
    commands.spawn((
        Camera3d::default(),
        Transform::from_xyz(11.0, 14.0, 50.0).looking_at(Vec3::new(11.0, 14.0, 20.0), Vec3::Y),
    ));
}

fn keys(input: Res<ButtonInput<KeyCode>>, mut layers: Query<&mut SplatSettings>) {
    for mut settings in &mut layers {
        if input.just_pressed(KeyCode::KeyP) {
            let c = &mut settings.colouring.tf.centre;
            *c = if c[0] == 1.0 { [0.0, 1.0, 0.0] } else { [1.0, 0.0, 0.0] };
        }
        if input.just_pressed(KeyCode::KeyA) {
            settings.attenuation = !settings.attenuation;
        }
    }
}
