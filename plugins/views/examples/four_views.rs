//! The four views from a plain Bevy app: add `ViewsPlugin`, mark the 3D camera `MainView`, spawn a
//! `SliceLayer` and turn the layout on in the `Views` resource. The 2D views (coronal, sagittal, axial) show
//! the image through the crosshair, the 3D view its axial slice under a slice of SH glyphs, and the colour bars
//! give the slice's window (made by the plugin) and the glyphs' GFA scale (a `ColourBar` put on their layer).
//!
//! The image is DIPY's `small_64D` FA; the glyphs the same data fitted with `fascicle fit csa --lmax 6`.
//!
//! Run: `cargo run --release -p fascicle-views --example four_views [-- --headless out.png]`

use bevy::prelude::*;
use fascicle_render::example::ExampleApp;
use fascicle_sh_glyphs::{GlyphColour, RayCastSettings, Selection, ShGlyphPlugin, ShGlyphs, SliceAxis};
use fascicle_views::{ColourBar, ColourMap, LayerOrder, MainView, SliceLayer, SliceSettings, Views, ViewsPlugin};

/// The repository's data folder: under the package's folder as cargo gives it at run time, else as it was
/// when built.
pub fn data() -> String {
    format!("{}/../../data", std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
}

/// The FA window shown: FA 0 black, 1 white.
pub const WINDOW: (f32, f32) = (0.0, 1.0);
/// The crosshair, world mm (RAS+): inside the 10 x 10 x 10 grid of 2 mm voxels.
pub const CROSSHAIR: [f32; 3] = [11.0, 14.0, 18.0];

fn main() -> AppExit {
    app(ExampleApp::from_args("Fascicle: four views", &data())).run()
}

pub fn app(mut example: ExampleApp) -> ExampleApp {
    example
        .app
        .add_plugins((ViewsPlugin, ShGlyphPlugin))
        .insert_resource(Views { ortho: true, crosshair: Some(CROSSHAIR), ..default() })
        .add_systems(Startup, setup);
    example
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    commands.spawn((
        SliceLayer { volume: assets.load("dti/small_64D_fa.nii.gz") },
        SliceSettings { index: Some(4), window: Some(WINDOW), ..default() },
        Name::new("FA"),
    ));
    commands.spawn((
        ShGlyphs { field: assets.load("sh/small_64D_csa_l6.nii.gz") },
        Selection::Slice { axis: SliceAxis::Z, index: Some(5), spacing: 1 },
        RayCastSettings { colour: GlyphColour::Gfa, ..default() },
        ColourBar { label: "GFA".into(), map: ColourMap::Viridis, range: (0.0, 1.0) },
        LayerOrder(1),
    ));
    // Above the oblique axial slices (14 degrees from axial), centred near (11, 14, 20) mm: look down.
    // Exact output (no tone mapping), shared by the 2D views' cameras: the slices show their window's greys.
    commands.spawn((
        Camera3d::default(),
        MainView,
        fascicle_views::exact_output(),
        Transform::from_xyz(11.0, 14.0, 46.0).looking_at(Vec3::new(11.0, 14.0, 20.0), Vec3::Y),
    ));
}
