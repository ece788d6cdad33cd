//! SH glyphs from a fitted NIfTI: add `ShGlyphPlugin`, spawn one `ShGlyphs` entity; the plugin loads the
//! file (off the main thread), builds the glyphs of the selected slice and ray-casts them on the GPU.
//!
//! The file is DIPY's `small_64D` DWI fitted with `fascicle fit csa --lmax 6` (the basis is recorded in
//! its header). Keys: Up/Down move the slice (a repack of this layer), `+`/`-` resize the glyphs (a uniform
//! write).
//!
//! Run: `cargo run --release -p fascicle-sh-glyphs --example sh_glyphs [-- --headless out.png]`

use bevy::prelude::*;
use fascicle_render::example::ExampleApp;
use fascicle_sh_glyphs::{RayCastSettings, Selection, ShGlyphPlugin, ShGlyphs, SliceAxis};

/// The repository's data folder: under the package's folder as cargo gives it at run time, else as it was
/// when built.
pub fn data() -> String {
    format!("{}/../../data", std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
}

fn main() -> AppExit {
    app(ExampleApp::from_args("Fascicle: SH glyphs", &data())).run()
}

pub fn app(mut example: ExampleApp) -> ExampleApp {
    example.app.add_plugins(ShGlyphPlugin).add_systems(Startup, setup).add_systems(Update, keys);
    example
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    commands.spawn((
        ShGlyphs { field: assets.load("sh/small_64D_csa_l6.nii.gz") },
        Selection::Slice { axis: SliceAxis::Z, index: Some(5), spacing: 1 },
    ));
    // Slice 5 of the 10 x 10 x 10 grid of 2 mm voxels (an oblique one, 14 degrees from axial) is centred
    // near (11, 14, 20) mm (RAS+): look down on it from above.
    commands.spawn((
        Camera3d::default(),
        Transform::from_xyz(11.0, 14.0, 46.0).looking_at(Vec3::new(11.0, 14.0, 20.0), Vec3::Y),
    ));
}

fn keys(input: Res<ButtonInput<KeyCode>>, mut layers: Query<(&mut Selection, &mut RayCastSettings)>) {
    let step = input.just_pressed(KeyCode::ArrowUp) as isize - input.just_pressed(KeyCode::ArrowDown) as isize;
    let zoom = [(KeyCode::Equal, 1.25), (KeyCode::Minus, 0.8)].iter().find(|(k, _)| input.just_pressed(*k));
    for (mut selection, mut settings) in &mut layers {
        // Write only on a key press: a write marks the component changed, and the plugin reacts to that.
        if let (true, Selection::Slice { axis, index: Some(k), spacing }) = (step != 0, *selection) {
            *selection = Selection::Slice { axis, index: Some(k.saturating_add_signed(step).min(9)), spacing };
        }
        if let Some((_, f)) = zoom {
            settings.size *= f;
        }
    }
}
