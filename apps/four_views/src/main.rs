//! The four views from a plain Bevy app outside the Fascicle workspace: the FA of DIPY's `small_64D` as a slice
//! layer, its CSA ODFs as SH glyphs read from an MRtrix3 `.mif` (tournier07, scanner axes), streamlines tracked
//! on it (`.tck`) with an include ROI, and a colour bar for the slice and for the glyphs' GFA.
//!
//! Run: `cargo run --release --manifest-path apps/four_views/Cargo.toml [-- --headless out.png]`

use bevy::prelude::*;
use fascicle_core::roi::{Roi, RoiMode, RoiShape};
use fascicle_render::example::ExampleApp;
use fascicle_sh_glyphs::{GlyphColour, RayCastSettings, Selection, ShGlyphPlugin, ShGlyphs, SliceAxis};
use fascicle_tracts::{TractPlugin, TractRoi, TractStyle, Tracts};
use fascicle_views::{ColourBar, ColourMap, LayerOrder, MainView, SliceLayer, SliceSettings, Views, ViewsPlugin};

/// The repository's data folder.
pub fn data() -> String {
    format!("{}/../../data", std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
}

/// The crosshair (world mm, RAS+), inside the image's 10 x 10 x 10 grid of 2 mm voxels.
pub const CROSSHAIR: [f32; 3] = [11.0, 14.0, 18.0];
/// The include ROI: a sphere of 3 mm radius on the crosshair.
pub const ROI: RoiShape = RoiShape::Sphere { centre: CROSSHAIR, radius: 3.0 };

fn main() -> AppExit {
    app(ExampleApp::from_args("Four views", &data())).run()
}

/// The app: plugins, the layout and the layers.
pub fn app(mut example: ExampleApp) -> ExampleApp {
    example
        .app
        .add_plugins((ViewsPlugin, ShGlyphPlugin, TractPlugin))
        .insert_resource(Views { ortho: true, crosshair: Some(CROSSHAIR), ..default() })
        .add_systems(Startup, setup);
    example
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    commands.spawn((
        SliceLayer { volume: assets.load("dti/small_64D_fa.nii.gz") },
        SliceSettings { index: Some(4), window: Some((0.0, 1.0)), ..default() },
        Name::new("FA"),
    ));
    commands.spawn((
        ShGlyphs { field: assets.load("sh/small_64D_csa_l6.mif") },
        Selection::Slice { axis: SliceAxis::Z, index: Some(5), spacing: 1 },
        RayCastSettings { colour: GlyphColour::Gfa, ..default() },
        ColourBar { label: "GFA".into(), map: ColourMap::Viridis, range: (0.0, 1.0) },
        LayerOrder(1),
    ));
    let tracts = commands
        .spawn((Tracts { tractogram: assets.load("tracts/small_64D_dti.tck") }, TractStyle::Lines { opacity: 1.0 }))
        .id();
    commands.spawn((TractRoi(Roi { shape: ROI, mode: RoiMode::Include }), ChildOf(tracts)));
    commands.spawn((
        Camera3d::default(),
        MainView,
        fascicle_views::exact_output(),
        Transform::from_xyz(11.0, -10.0, 50.0).looking_at(Vec3::new(11.0, 14.0, 18.0), Vec3::Z),
    ));
}
