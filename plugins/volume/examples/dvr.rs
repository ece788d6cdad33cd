//! A DVR volume composited with glyphs: add `VolumePlugin` and `TensorGlyphPlugin`, spawn one
//! `VolumeLayer` (FA, ray-cast with a transfer function) and one `TensorGlyphs` layer of the same fit. The
//! volume reads the depth the glyphs wrote: each ray stops at the glyph it meets, so the glyphs show inside
//! the volume, tinted by what lies in front of them.
//!
//! The files are DIPY's `small_64D` DWI fitted with `fascicle fit dti` (tensors and FA). Keys: `W`/`Q`
//! widen and narrow the window (the transfer function's range: two small tables and a uniform), `M`
//! cycles the methods (ray casting, 3D and 2D slicing, splatting, cell projection; the proxy mesh only).
//!
//! Run: `cargo run --release -p fascicle-volume --example dvr [-- --headless out.png]`

use bevy::prelude::*;
use fascicle_core::dvr::{TfPoint, TransferFunction};
use fascicle_render::example::ExampleApp;
use fascicle_tensors::{Selection, SliceAxis, TensorGlyphPlugin, TensorGlyphShape, TensorGlyphs};
use fascicle_volume::{VolumeLayer, VolumeMethod, VolumePlugin, VolumeSettings};

/// The repository's data folder: under the package's folder as cargo gives it at run time, else as it was
/// when built.
pub fn data() -> String {
    format!("{}/../../data", std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
}

/// FA from 0.1 (transparent) to 0.8: blue to orange, opacity growing with FA.
pub fn settings() -> VolumeSettings {
    let tf = TransferFunction {
        range: [0.1, 0.8],
        points: vec![
            TfPoint { x: 0.0, rgba: [0.1, 0.2, 0.9, 0.0] },
            TfPoint { x: 0.3, rgba: [0.2, 0.5, 1.0, 0.06] },
            TfPoint { x: 1.0, rgba: [1.0, 0.6, 0.1, 0.25] },
        ],
    };
    VolumeSettings { tf, step: 0.5, jitter: false, ..default() }
}

fn main() -> AppExit {
    app(ExampleApp::from_args("Fascicle: volume and glyphs", &data())).run()
}

pub fn app(mut example: ExampleApp) -> ExampleApp {
    example.app.add_plugins((VolumePlugin, TensorGlyphPlugin)).add_systems(Startup, setup).add_systems(Update, keys);
    example
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    commands.spawn((VolumeLayer { volume: assets.load("dti/small_64D_fa.nii.gz") }, settings()));
    commands.spawn((
        TensorGlyphs { field: assets.load("dti/small_64D_tensor.nii.gz") },
        Selection::Slice { axis: SliceAxis::Z, index: Some(5), spacing: 2 },
        TensorGlyphShape { min_fa: 0.2, ..default() },
    ));
    commands.insert_resource(ClearColor(Color::BLACK));
    // An oblique view of the 20 mm cube centred near (11, 14, 20) mm.
    commands.spawn((
        Camera3d::default(),
        Transform::from_xyz(-14.0, -16.0, 52.0).looking_at(Vec3::new(11.0, 14.0, 20.0), Vec3::Z),
    ));
}

fn keys(input: Res<ButtonInput<KeyCode>>, mut layers: Query<&mut VolumeSettings>) {
    let widen = [(KeyCode::KeyW, 0.05), (KeyCode::KeyQ, -0.05)].into_iter().find(|(k, _)| input.just_pressed(*k));
    for mut s in &mut layers {
        if let Some((_, d)) = widen {
            let r = &mut s.tf.range;
            *r = [(r[0] - d).clamp(0.0, 0.45), (r[1] + d).clamp(0.55, 1.0)];
        }
        if input.just_pressed(KeyCode::KeyM) {
            let all = VolumeMethod::ALL;
            let i = all.iter().position(|m| *m == s.method).unwrap_or(0);
            s.method = all[(i + 1) % all.len()];
        }
    }
}
