//! Ellipsoid and superquadric tensor glyphs from a fitted NIfTI: add `TensorGlyphPlugin`, spawn one
//! `TensorGlyphs` entity; the plugin loads the tensors (off the main thread), rotates them into the world
//! frame and ray-casts one glyph per voxel of the selected slice, with true depth.
//!
//! The file is DIPY's `small_64D` DWI fitted with `fascicle fit dti` (lower-triangular tensors, as DIPY).
//! Keys: `S` switches superquadrics (Kindlmann, gamma 3) and ellipsoids (a repack: the bounds change),
//! `C` switches colouring by direction and by FA (a uniform write), Up/Down move the slice (a repack).
//!
//! Run: `cargo run --release -p fascicle-tensors --example tensor_glyphs [-- --headless out.png]`

use bevy::prelude::*;
use fascicle_core::dti::glyph::TensorShape;
use fascicle_render::example::ExampleApp;
use fascicle_tensors::{Selection, SliceAxis, TensorColour, TensorGlyphPlugin, TensorGlyphSettings, TensorGlyphs};

/// The repository's data folder: under the package's folder as cargo gives it at run time, else as it was
/// when built.
pub fn data() -> String {
    format!("{}/../../data", std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
}
pub const SUPERQUADRIC: TensorShape = TensorShape::Superquadric { gamma: 3.0 };

fn main() -> AppExit {
    app(ExampleApp::from_args("Fascicle: tensor glyphs", &data())).run()
}

pub fn app(mut example: ExampleApp) -> ExampleApp {
    example.app.add_plugins(TensorGlyphPlugin).add_systems(Startup, setup).add_systems(Update, keys);
    example
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    commands.spawn((
        TensorGlyphs { field: assets.load("dti/small_64D_tensor.nii.gz") },
        Selection::Slice { axis: SliceAxis::Z, index: Some(5), spacing: 1 },
        TensorGlyphSettings { shape: SUPERQUADRIC, ..default() },
    ));
    // Slice 5 of the 10 x 10 x 10 grid of 2 mm voxels (oblique, 14 degrees from axial) is centred near
    // (11, 14, 20) mm (RAS+): look down on it from above.
    commands.spawn((
        Camera3d::default(),
        Transform::from_xyz(11.0, 14.0, 46.0).looking_at(Vec3::new(11.0, 14.0, 20.0), Vec3::Y),
    ));
}

fn keys(input: Res<ButtonInput<KeyCode>>, mut layers: Query<(&mut Selection, &mut TensorGlyphSettings)>) {
    let step = input.just_pressed(KeyCode::ArrowUp) as isize - input.just_pressed(KeyCode::ArrowDown) as isize;
    for (mut selection, mut settings) in &mut layers {
        // Write only on a key press: a write marks the component changed, and the plugin reacts to that.
        if input.just_pressed(KeyCode::KeyS) {
            settings.shape = if settings.shape == SUPERQUADRIC { TensorShape::Ellipsoid } else { SUPERQUADRIC };
        }
        if input.just_pressed(KeyCode::KeyC) {
            settings.colour =
                if settings.colour == TensorColour::Fa { TensorColour::Direction } else { TensorColour::Fa };
        }
        if let (true, Selection::Slice { axis, index: Some(k), spacing }) = (step != 0, *selection) {
            *selection = Selection::Slice { axis, index: Some(k.saturating_add_signed(step).min(9)), spacing };
        }
    }
}
