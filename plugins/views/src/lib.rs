//! Slice layers, orthogonal views and colour bars as a Bevy plugin: the 3D view and three 2D views (sagittal,
//! coronal, axial) of the slice layers' images at a crosshair, as mrview's and FSLeyes' ortho layouts, and the
//! colour bars of the 3D view. Fascicle's viewer and its headless renderer use this plugin as any Bevy app
//! can: add [`ViewsPlugin`], mark the 3D camera [`MainView`], spawn [`SliceLayer`]s, set [`Views`].
//!
//! - Every camera marked [`MainView`] gets three orthographic cameras ([`OrthoView`], each on its own render
//!   layer) drawing into its target, and the colour bars drawn over its viewport ([`BarOverlay`]). They are
//!   laid out in [`ViewRegion`] (the target minus a side panel): with [`Views::ortho`] in a 2x2 grid (coronal,
//!   sagittal / axial, 3D), without it the 3D view takes the region alone.
//! - Each 2D view looks along a world axis (RAS+) in the neurological convention (the subject's right on the
//!   screen's right; sagittal views from the subject's left, anterior to the left). For every visible slice
//!   layer it shows the slice of that image through the crosshair, cut along the image's voxel axis closest to
//!   the view's axis (so permuted or flipped images show the right plane), with the layer's window and
//!   opacity, later [`LayerOrder`]s over earlier ones. Two lines mark the crosshair. Tract sets drawn as lines
//!   or polygon tubes show cropped to a slab around the view's plane ([`Views::slab_mm`]), over the image.
//! - Input stays with the app; [`pick_in_view`] gives the crosshair's new place under a click in a 2D view,
//!   [`window_level`] a window after a right drag (as mrview's), [`cursor_ray`] the ray under the cursor.
//! - Every layer entity carrying a [`ColourBar`] and not hidden shows its bar over the 3D view (bottom right,
//!   stacked by [`LayerOrder`]) while [`Views::colour_bars`] is on; slice layers of one channel get theirs from
//!   the plugin.
//!
//! All systems run in `Update`, in [`ViewSystems`]: an app that makes its layers in `Update` orders them
//! before it.

#![warn(missing_docs)]

use bevy::camera::visibility::RenderLayers;
use bevy::camera::{RenderTarget, ScalingMode, Viewport};
use bevy::core_pipeline::tonemapping::{DebandDither, Tonemapping};
use bevy::math::{DMat4, DVec3};
use bevy::prelude::*;
use fascicle_core::Volume;
use serde::{Deserialize, Serialize};

pub mod colourbar;
pub mod overlay;
pub mod slice;

pub use colourbar::{ColourBar, ColourMap};
pub use fascicle_render::layer::{LayerOrder, LayerStatus, SliceAxis};
pub use overlay::BarOverlay;
pub use slice::{Channels, SliceBar, SliceCounts, SliceLayer, SliceSettings, SliceSource, auto_window, slice_image};

use slice::{quad_mesh, set_opacity, unlit};

/// The layout and crosshair, as a resource the plugin's systems follow (an app's scene file may save it).
#[derive(Resource, Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Views {
    /// Three orthogonal 2D views beside the 3D view.
    pub ortho: bool,
    /// The crosshair in world mm (RAS+); the centre of the images when absent.
    pub crosshair: Option<[f32; 3]>,
    /// The slices of slice, glyph and tensor layers follow the crosshair (for the app to apply: the layers'
    /// settings are its own).
    pub follow: bool,
    /// A colour bar for every colour-mapped layer, in the 3D view.
    pub colour_bars: bool,
    /// Thickness of the slab around each 2D view's slice within which streamlines are drawn, mm; default
    /// (None): one voxel of the top slice layer along the view's axis, else 2 mm.
    pub slab_mm: Option<f32>,
}

impl Default for Views {
    fn default() -> Self {
        Self { ortho: false, crosshair: None, follow: false, colour_bars: true, slab_mm: None }
    }
}

/// Render layers of the 2D views (index: the world axis a view looks along).
pub const VIEW_LAYERS: [usize; 3] = [1, 2, 3];

/// The 3D camera the views belong to (one per app): it gets the three 2D cameras on its target, the colour
/// bars over its viewport ([`BarOverlay`]), and the 3D cell of the layout.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct MainView;

/// A 2D view looking along world axis `.0` (0 sagittal, 1 coronal, 2 axial).
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct OrthoView(pub usize);

/// The part of the target the views share (physical pixels): what a side panel leaves.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ViewRegion {
    /// Pixels taken at the left.
    pub left: u32,
}

/// The crosshair in world mm, resolved ([`Views::crosshair`], or the images' centre), and the box the 2D views
/// frame.
#[derive(Resource, Clone, Copy, Debug, PartialEq)]
pub struct Crosshair {
    /// The crosshair, world mm (RAS+).
    pub world: Vec3,
    /// Lowest corner of the framed box, world mm: the visible slice layers' voxels, else 50 mm below the crosshair.
    pub lo: Vec3,
    /// Highest corner of the framed box, world mm: the visible slice layers' voxels, else 50 mm above the crosshair.
    pub hi: Vec3,
}

impl Default for Crosshair {
    fn default() -> Self {
        Self { world: Vec3::ZERO, lo: Vec3::splat(-50.0), hi: Vec3::splat(50.0) }
    }
}

/// The voxel grid a layer's content comes from (slice layers get theirs from the plugin; an app may give any
/// layer one): the crosshair's voxel on it.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct VoxelGrid {
    /// The affine from voxel indices to world mm (RAS+).
    pub world_from_voxel: DMat4,
    /// Voxels along each voxel axis.
    pub dims: [usize; 3],
}

impl VoxelGrid {
    /// The grid of volume `v`: its affine and its three spatial dimensions.
    pub fn of<T: fascicle_core::volume::Scalar>(v: &Volume<T>) -> Self {
        Self { world_from_voxel: v.world_from_voxel, dims: v.dims3() }
    }

    /// The voxel axis most nearly along world axis `a`.
    pub fn axis_along(&self, a: usize) -> usize {
        let m = self.world_from_voxel;
        let along = |k: usize| m.col(k).truncate().normalize_or_zero()[a].abs();
        (0..3).max_by(|&i, &j| along(i).total_cmp(&along(j))).unwrap_or(a)
    }

    /// The voxel index along voxel axis `k` nearest to world point `p`, if inside the grid.
    pub fn index_at(&self, p: Vec3, k: usize) -> Option<usize> {
        let v = self.world_from_voxel.inverse().transform_point3(p.as_dvec3())[k].round();
        (v >= 0.0 && v < self.dims[k] as f64).then_some(v as usize)
    }

    /// The world box of the voxels' outer corners.
    pub fn world_box(&self) -> (Vec3, Vec3) {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for c in 0..8 {
            let p = DVec3::from_array(std::array::from_fn(|k| {
                if c & (1 << k) == 0 { -0.5 } else { self.dims[k] as f64 - 0.5 }
            }));
            let w = self.world_from_voxel.transform_point3(p);
            lo = lo.min(w);
            hi = hi.max(w);
        }
        (lo.as_vec3(), hi.as_vec3())
    }
}

/// The camera of a 2D view: where it looks from (unit vector from the crosshair to the eye) and its up.
pub fn view_axes(a: usize) -> (Vec3, Vec3) {
    match a {
        0 => (Vec3::NEG_X, Vec3::Z),
        1 => (Vec3::NEG_Y, Vec3::Z),
        _ => (Vec3::Z, Vec3::Y),
    }
}

/// The four cells of the ortho layout in `region` (physical pixels): sagittal, coronal, axial, 3D, as
/// rectangles. Coronal top left, sagittal top right, axial bottom left, 3D bottom right.
pub fn cells(region: URect) -> [URect; 4] {
    let mid = region.min + region.size() / 2;
    let cell = |right: bool, bottom: bool| {
        let (x0, x1) = if right { (mid.x, region.max.x) } else { (region.min.x, mid.x) };
        let (y0, y1) = if bottom { (mid.y, region.max.y) } else { (region.min.y, mid.y) };
        URect::new(x0, y0, x1, y1)
    };
    [cell(true, false), cell(false, false), cell(false, true), cell(true, true)]
}

/// The plugin's systems, in `Update`.
#[derive(SystemSet, Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ViewSystems;

/// Slice layers, the 2D views and colour bars: the [`Views`], [`ViewRegion`], [`Crosshair`] and
/// [`SliceCounts`] resources and the systems ([`ViewSystems`]) that sync slice layers and lay out, place and
/// fill the views.
pub struct ViewsPlugin;

use fascicle_render::headless::PipelineWarmup;

impl Plugin for ViewsPlugin {
    fn build(&self, app: &mut App) {
        fascicle_volume::layer::init_scalar_volumes(app);
        app.init_resource::<Views>()
            .init_resource::<ViewRegion>()
            .init_resource::<Crosshair>()
            .init_resource::<SliceCounts>()
            .add_observer(slice::forget_slice)
            .add_systems(
                Update,
                (
                    slice::sync_slices,
                    spawn_view_cameras,
                    // Not while a headless render warms its pipelines up: the cameras then draw into one
                    // pixel (`PipelineWarmup`), and the layout would give them their whole viewports back.
                    layout_views.run_if(not(resource_exists::<PipelineWarmup>)),
                    resolve_crosshair,
                    spawn_view_marks,
                    place_ortho_cameras,
                    view_slices,
                    view_tract_slabs,
                    bars,
                )
                    .chain()
                    .in_set(ViewSystems),
            );
        overlay::build(app);
    }
}

/// What every camera drawing into the scene's target shares, so that they share its textures and write exact
/// colours: no tone mapping or dithering, blending in a float (f16) target, rounded to 8 bits once.
pub fn exact_output() -> impl Bundle {
    (Tonemapping::None, DebandDither::Disabled, bevy::camera::Hdr)
}

fn view_camera_bundle(order: isize, layer: usize, clear_color: ClearColorConfig) -> impl Bundle {
    (
        Camera3d::default(),
        Camera { order, is_active: false, clear_color, ..default() },
        Tonemapping::None,
        DebandDither::Disabled,
        RenderLayers::layer(layer),
    )
}

/// A new main camera: its clear colour, target, MSAA and whether it is HDR.
type NewMain = (
    &'static Camera,
    Option<&'static RenderTarget>,
    Option<&'static Msaa>,
    Has<bevy::camera::Hdr>,
    Has<fascicle_render::retain::RetainPicture>,
);

/// Gives every new main camera its 2D views (cleared as it is), on the same target (and retaining their pictures when it retains its own: [`fascicle_render::retain`]).
/// They are HDR when it is: cameras sharing a target must share its intermediate textures, or a later camera
/// writes over the earlier ones' pixels.
fn spawn_view_cameras(mut commands: Commands, mains: Query<NewMain, Added<MainView>>) {
    for (main, target, msaa, hdr, retain) in &mains {
        let msaa = msaa.copied().unwrap_or_default();
        let clear = match &main.clear_color {
            ClearColorConfig::None => ClearColorConfig::Default,
            other => *other,
        };
        for a in 0..3 {
            let mut e = commands.spawn((
                view_camera_bundle(-3 + a as isize, VIEW_LAYERS[a], clear),
                OrthoView(a),
                Projection::Orthographic(OrthographicProjection::default_3d()),
                msaa,
            ));
            if let Some(t) = target {
                e.insert(t.clone());
            }
            if hdr {
                e.insert(bevy::camera::Hdr);
            }
            if retain {
                e.insert(fascicle_render::retain::RetainPicture);
            }
        }
    }
}

fn viewport(r: URect) -> Viewport {
    Viewport { physical_position: r.min, physical_size: r.size().max(UVec2::ONE), ..default() }
}

/// Sets a camera's viewport when it differs (through `Mut`: a `&mut Camera` taken from it marks the camera
/// changed every frame, and a retained picture is then never put back).
fn set_viewport(camera: &mut Mut<Camera>, r: URect) {
    let v = viewport(r);
    let same = camera
        .viewport
        .as_ref()
        .is_some_and(|o| o.physical_position == v.physical_position && o.physical_size == v.physical_size);
    if !same {
        camera.viewport = Some(v);
    }
}

/// Lays the views out in the region and keeps their MSAA the main camera's (cameras sharing a target share
/// its textures).
#[allow(clippy::type_complexity, reason = "a Bevy system's queries")]
fn layout_views(
    mut commands: Commands,
    views: Res<Views>,
    region: Res<ViewRegion>,
    mut main: Query<(&mut Camera, Option<&Msaa>), With<MainView>>,
    mut others: Query<(Entity, &mut Camera, &OrthoView, Option<&Msaa>), Without<MainView>>,
) {
    let Ok((mut main, msaa)) = main.single_mut() else { return };
    let Some(size) = main.physical_target_size() else { return };
    let left = region.left.min(size.x.saturating_sub(1));
    let region = URect::new(left, 0, size.x, size.y.max(1));
    let grid = cells(region);
    let ortho = views.ortho;
    let main_rect = if ortho { grid[3] } else { region };
    if region.min == UVec2::ZERO && region.size() == size && !ortho {
        if main.viewport.is_some() {
            main.viewport = None;
        }
    } else {
        set_viewport(&mut main, main_rect);
    }
    let msaa = msaa.copied().unwrap_or_default();
    for (e, mut cam, view, m) in &mut others {
        // A 2D view is on with the layout.
        if cam.is_active != ortho {
            cam.is_active = ortho;
        }
        set_viewport(&mut cam, grid[view.0]);
        if m.copied().unwrap_or_default() != msaa {
            commands.entity(e).insert(msaa);
        }
    }
}

/// The crosshair of [`Views`] (or the middle of the slice layers' images) and the box the 2D views frame.
fn resolve_crosshair(
    views: Res<Views>,
    grids: Query<(&VoxelGrid, &Visibility), With<SliceLayer>>,
    mut crosshair: ResMut<Crosshair>,
) {
    let mut lo = Vec3::splat(f32::INFINITY);
    let mut hi = Vec3::splat(f32::NEG_INFINITY);
    for (g, _) in grids.iter().filter(|(_, v)| **v != Visibility::Hidden) {
        let (a, b) = g.world_box();
        lo = lo.min(a);
        hi = hi.max(b);
    }
    let world = views.crosshair.map(Vec3::from_array);
    let new = if lo.x.is_finite() {
        Crosshair { world: world.unwrap_or((lo + hi) / 2.0), lo, hi }
    } else {
        let w = world.unwrap_or(Vec3::ZERO);
        Crosshair { world: w, lo: w - 50.0, hi: w + 50.0 }
    };
    if *crosshair != new {
        *crosshair = new;
    }
}

/// Marks the two crosshair lines of 2D view `.0`: `.1` is 0 for the line along the screen's x, 1 along y.
#[derive(Component, Clone, Copy, Debug)]
struct CrosshairLine(usize, usize);

/// An orientation letter at edge `.1` (0 right, 1 left, 2 top, 3 bottom) of 2D view `.0`.
#[derive(Component, Clone, Copy, Debug)]
struct ViewLabel(usize, usize, UVec2);

/// The letters at the right, left, top and bottom edges of 2D view `a` (RAS+: the subject's right, left,
/// anterior, posterior, superior, inferior).
pub fn edge_letters(a: usize) -> [&'static str; 4] {
    match a {
        0 => ["P", "A", "S", "I"],
        1 => ["R", "L", "S", "I"],
        _ => ["R", "L", "A", "P"],
    }
}

/// The crosshair lines' colour (linear).
pub const CROSSHAIR: Color = Color::linear_rgb(1.0, 0.6, 0.0);

/// The crosshair lines and orientation letters of the 2D views, made once.
fn spawn_view_marks(
    mut commands: Commands,
    existing: Query<(), With<CrosshairLine>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    mut images: ResMut<Assets<Image>>,
) {
    if !existing.is_empty() {
        return;
    }
    let mesh = meshes.add(Cuboid::from_length(1.0));
    let material = materials.add(StandardMaterial { base_color: CROSSHAIR, unlit: true, ..default() });
    let quad = meshes.add(Rectangle::new(1.0, 1.0));
    for a in 0..3 {
        for k in 0..2 {
            commands.spawn((
                CrosshairLine(a, k),
                Mesh3d(mesh.clone()),
                MeshMaterial3d(material.clone()),
                RenderLayers::layer(VIEW_LAYERS[a]),
                Transform::default(),
            ));
        }
        for (edge, letter) in edge_letters(a).into_iter().enumerate() {
            let image = colourbar::text_image(letter);
            let size = UVec2::new(image.width(), image.height());
            let mut m = unlit(1.0);
            m.alpha_mode = AlphaMode::Blend;
            m.base_color_texture = Some(images.add(image));
            commands.spawn((
                ViewLabel(a, edge, size),
                Mesh3d(quad.clone()),
                MeshMaterial3d(materials.add(m)),
                RenderLayers::layer(VIEW_LAYERS[a]),
                Transform::default(),
            ));
        }
    }
}

/// Puts each 2D camera on its axis through the crosshair, framing the images' box, and its crosshair lines.
#[allow(clippy::type_complexity, reason = "a Bevy system's queries")]
fn place_ortho_cameras(
    crosshair: Res<Crosshair>,
    mut cams: Query<(&OrthoView, &Camera, &mut Transform, &mut Projection), Without<CrosshairLine>>,
    mut lines: Query<(&CrosshairLine, &mut Transform), (Without<OrthoView>, Without<ViewLabel>)>,
    mut labels: Query<(&ViewLabel, &mut Transform), (Without<OrthoView>, Without<CrosshairLine>)>,
) {
    let c = *crosshair;
    let extent = (c.hi - c.lo).max(Vec3::splat(1.0));
    let reach = extent.max_element() * 2.0 + 10.0;
    let mut pixel = [1.0f32; 3];
    let mut centres = [Vec3::ZERO; 3];
    let mut sizes = [UVec2::ONE; 3];
    for (view, cam, mut tf, mut proj) in &mut cams {
        let a = view.0;
        let (from, up) = view_axes(a);
        let right = (-from).cross(up);
        // Centred on the images' box; the crosshair's depth only (the image does not move under a click).
        let mut target = (c.lo + c.hi) / 2.0;
        target[a] = c.world[a];
        centres[a] = target;
        let new_tf = Transform::from_translation(target + from * reach).looking_at(target, up);
        if *tf != new_tf {
            *tf = new_tf;
        }
        let (w, h) = (extent.dot(right.abs()) * 1.04, extent.dot(up.abs()) * 1.04);
        // Written only when the framing changes (a projection change recomputes the camera's matrices).
        let framed = match &*proj {
            Projection::Orthographic(p) => match p.scaling_mode {
                ScalingMode::AutoMin { min_width, min_height } => {
                    p.far == reach * 2.0 && min_width == w && min_height == h
                }
                _ => false,
            },
            _ => false,
        };
        if !framed {
            *proj = Projection::Orthographic(OrthographicProjection {
                near: 0.0,
                far: reach * 2.0,
                scaling_mode: ScalingMode::AutoMin { min_width: w, min_height: h },
                ..OrthographicProjection::default_3d()
            });
        }
        // World mm per pixel: the larger of the two fits.
        if let Some(size) = cam.physical_viewport_size() {
            pixel[a] = (w / size.x.max(1) as f32).max(h / size.y.max(1) as f32);
            sizes[a] = size.max(UVec2::ONE);
        }
    }
    for (label, mut tf) in &mut labels {
        let ViewLabel(a, edge, px) = *label;
        let (from, up) = view_axes(a);
        let right = (-from).cross(up);
        let mm = pixel[a];
        // Pixel for pixel, 4 pixels in from the edge's middle.
        let half = sizes[a].as_vec2() / 2.0 - px.as_vec2() / 2.0 - 4.0;
        let offset = match edge {
            0 => right * half.x,
            1 => -right * half.x,
            2 => up * half.y,
            _ => -up * half.y,
        };
        let new = Transform {
            translation: centres[a] + offset * mm + from * reach * 0.6,
            rotation: Transform::IDENTITY.looking_at(-from, up).rotation,
            scale: Vec3::new(px.x as f32 * mm, px.y as f32 * mm, 1.0),
        };
        if *tf != new {
            *tf = new;
        }
    }
    for (line, mut tf) in &mut lines {
        let (from, up) = view_axes(line.0);
        let rot = Transform::IDENTITY.looking_at(-from, up).rotation;
        let thick = pixel[line.0] * 1.5;
        let long = reach * 2.0;
        let scale = if line.1 == 0 { Vec3::new(long, thick, thick) } else { Vec3::new(thick, long, thick) };
        // In front of every slice: halfway to the eye.
        let new = Transform { translation: c.world + from * reach * 0.5, rotation: rot, scale };
        if *tf != new {
            *tf = new;
        }
    }
}

/// A layer's slice in 2D view `axis`, and what it was cut with.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct ViewSlice {
    /// The world axis the 2D view looks along (0 sagittal, 1 coronal, 2 axial).
    pub axis: usize,
    /// The voxel axis and index of the slice.
    pub voxel_axis: usize,
    /// The slice's voxel index along `voxel_axis`.
    pub index: usize,
    /// The values shown black and white.
    pub window: (f32, f32),
    /// The layer's opacity, 0..1.
    pub opacity: f32,
}

/// Keeps, under every slice layer, its slice through the crosshair in each 2D view.
#[allow(clippy::type_complexity, clippy::too_many_arguments, reason = "a Bevy system's queries and data")]
fn view_slices(
    mut commands: Commands,
    views: Res<Views>,
    crosshair: Res<Crosshair>,
    layers: Query<(Entity, Option<&LayerOrder>, &SliceSettings, &SliceSource, &VoxelGrid), With<SliceLayer>>,
    slices: Query<(Entity, &ViewSlice, &ChildOf, &Mesh3d, &MeshMaterial3d<StandardMaterial>)>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut images: ResMut<Assets<Image>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    if !views.ortho {
        for (e, ..) in &slices {
            commands.entity(e).despawn();
        }
        return;
    }
    for (layer, order, settings, source, grid) in &layers {
        let window = source.window(settings.window);
        let order = order.copied().unwrap_or_default().0;
        for a in 0..3 {
            let existing = slices.iter().find(|(_, v, parent, ..)| parent.parent() == layer && v.axis == a);
            let k = grid.axis_along(a);
            let Some(index) = grid.index_at(crosshair.world, k) else {
                if let Some((e, ..)) = existing {
                    commands.entity(e).despawn();
                }
                continue;
            };
            let want = ViewSlice { axis: a, voxel_axis: k, index, window, opacity: settings.opacity };
            if existing.is_some_and(|(_, v, ..)| *v == want) {
                continue;
            }
            let axis = [SliceAxis::X, SliceAxis::Y, SliceAxis::Z][k];
            let Ok((image, corners)) = source.cut(axis, Some(index), window) else {
                continue;
            };
            // Later layers over earlier ones: a small step towards the eye per layer.
            let (from, _) = view_axes(a);
            let corners = corners.map(|p| p + from * 0.01 * order as f32);
            let mesh = quad_mesh(corners);
            match existing {
                Some((e, _, _, mesh3d, mat)) => {
                    if let Some(mut m) = meshes.get_mut(&mesh3d.0) {
                        *m = mesh;
                    }
                    if let Some(mut m) = materials.get_mut(&mat.0) {
                        set_opacity(&mut m, want.opacity);
                        m.base_color_texture = Some(images.add(image));
                    }
                    commands.entity(e).insert(want);
                }
                None => {
                    let mut m = unlit(want.opacity);
                    m.base_color_texture = Some(images.add(image));
                    commands.spawn((
                        want,
                        Mesh3d(meshes.add(mesh)),
                        MeshMaterial3d(materials.add(m)),
                        RenderLayers::layer(VIEW_LAYERS[a]),
                        ChildOf(layer),
                    ));
                }
            }
        }
    }
}

/// A 2D view's crop of a tract layer's mesh (`fascicle_tracts::TractSlab`), for view `.0`.
#[derive(Component, Clone, Copy, Debug)]
struct ViewSlab(usize);

/// The slab thickness of 2D view `a`: [`Views::slab_mm`], else one voxel of the top slice layer along the view's axis,
/// else 2 mm.
pub fn slab_thickness(views: &Views, top: Option<&VoxelGrid>, a: usize) -> f32 {
    if let Some(t) = views.slab_mm.filter(|t| *t > 0.0) {
        return t;
    }
    top.map_or(2.0, |g| g.world_from_voxel.col(g.axis_along(a)).truncate().length() as f32)
}

/// With the 2D views on, each tract layer drawn as lines or polygon tubes shows in every 2D view cropped to a
/// slab around the crosshair's plane, in its own colours, over the image (mrview's "crop to slab"): one
/// `TractSlab` per set and view, whose move with the crosshair is a uniform write. Hyperstreamlines are not
/// cropped (not drawn in the 2D views).
fn view_tract_slabs(
    mut commands: Commands,
    views: Res<Views>,
    crosshair: Res<Crosshair>,
    sets: Query<Entity, With<fascicle_tracts::MeshSet>>,
    mut slabs: Query<(Entity, &ViewSlab, &mut fascicle_tracts::TractSlab)>,
    slice_layers: Query<(Option<&LayerOrder>, &VoxelGrid), With<SliceLayer>>,
) {
    if !views.ortho {
        for (e, ..) in &slabs {
            commands.entity(e).despawn();
        }
        return;
    }
    let top = slice_layers.iter().max_by_key(|(order, _)| order.copied().unwrap_or_default()).map(|(_, g)| *g);
    for set in &sets {
        for a in 0..3 {
            let want = fascicle_tracts::TractSlab {
                set,
                normal: Vec3::AXES[a],
                offset: crosshair.world[a],
                half_thickness: 0.5 * slab_thickness(&views, top.as_ref(), a),
            };
            match slabs.iter_mut().find(|(_, v, s)| v.0 == a && s.set == set) {
                Some((_, _, mut slab)) => {
                    slab.set_if_neq(want);
                }
                None => {
                    commands.spawn((want, ViewSlab(a), RenderLayers::layer(VIEW_LAYERS[a])));
                }
            }
        }
    }
}

/// What moves the bars: on a layer with a bar, the bar, its order or its visibility changed (not any entity's
/// visibility: a scene holds tens of thousands of glyph entities).
type BarsMoved = (With<ColourBar>, Or<(Changed<ColourBar>, Changed<LayerOrder>, Changed<Visibility>)>);

/// A layer's bar, and whether it is shown.
type BarOf = (&'static ColourBar, Option<&'static LayerOrder>, &'static Visibility);

/// Shows the layers' colour bars over the 3D view (bottom right, stacked upwards by [`LayerOrder`]): each main
/// camera's [`BarOverlay`] holds the images of those that fit its viewport, one made for each bar not shown
/// before.
#[allow(clippy::type_complexity, clippy::too_many_arguments, reason = "a Bevy system's parameters")]
fn bars(
    mut commands: Commands,
    views: Res<Views>,
    layers: Query<BarOf>,
    changed: Query<(), BarsMoved>,
    mut removed: RemovedComponents<ColourBar>,
    mains: Query<(Entity, &Camera, Option<&BarOverlay>), With<MainView>>,
    mut images: ResMut<Assets<Image>>,
    mut shown: Local<(Vec<ColourBar>, BarOverlay, UVec2)>,
) {
    // The bars follow the layers' bars, their order and visibility, the switch and the view's size.
    let removed = removed.read().count() > 0;
    let new_camera = mains.iter().any(|(.., o)| o.is_none());
    let size = mains.iter().next().and_then(|(_, c, _)| c.physical_viewport_size()).unwrap_or_default();
    if !views.is_changed() && changed.is_empty() && !removed && !new_camera && size == shown.2 {
        return;
    }
    let bars: Vec<ColourBar> = if views.colour_bars {
        let mut shown: Vec<(LayerOrder, &ColourBar)> = layers
            .iter()
            .filter(|(.., v)| **v != Visibility::Hidden)
            .map(|(bar, order, _)| (order.copied().unwrap_or_default(), bar))
            .collect();
        shown.sort_by_key(|(order, _)| *order);
        let fit = (0..).take_while(|&i| colourbar::bar_rect(size, i).is_some()).count();
        shown.into_iter().take(fit).map(|(_, bar)| bar.clone()).collect()
    } else {
        vec![]
    };
    if bars != shown.0 {
        // A bar shown before keeps its image (hiding one layer makes no new image for the others).
        let before = |bar: &ColourBar| shown.0.iter().position(|b| b == bar).map(|i| shown.1.0[i].clone());
        let images = bars.iter().map(|bar| before(bar).unwrap_or_else(|| images.add(colourbar::bar_image(bar))));
        let overlay = BarOverlay(images.collect());
        *shown = (bars, overlay, size);
    }
    shown.2 = size;
    for (e, _, overlay) in &mains {
        if overlay != Some(&shown.1) {
            commands.entity(e).insert(shown.1.clone());
        }
    }
}

/// A window after a right drag of `delta` pixels: right widens it (less contrast), up lowers its centre
/// (brighter), each by 0.5 % of its width per pixel, as mrview's window/level drag.
pub fn window_level((lo, hi): (f32, f32), delta: Vec2) -> (f32, f32) {
    let width = (hi - lo).abs().max(1e-6);
    let centre = (lo + hi) / 2.0 + delta.y * width * 0.005;
    let width = width * (delta.x * 0.005).exp();
    (centre - width / 2.0, centre + width / 2.0)
}

/// The world ray under a cursor position (logical pixels in the window). Bevy's `viewport_to_world` takes
/// window positions and subtracts the camera's viewport itself.
pub fn cursor_ray(camera: &Camera, tf: &GlobalTransform, cursor: Vec2) -> Option<Ray3d> {
    camera.viewport_to_world(tf, cursor).ok()
}

/// The world point a cursor position (logical pixels in the window) picks in a 2D view, on the plane through
/// `crosshair`: the crosshair's new place after a click there.
pub fn pick_in_view(
    camera: &Camera,
    tf: &GlobalTransform,
    view: OrthoView,
    cursor: Vec2,
    crosshair: Vec3,
) -> Option<Vec3> {
    let rect = camera.logical_viewport_rect()?;
    if !rect.contains(cursor) {
        return None;
    }
    let mut p = cursor_ray(camera, tf, cursor)?.origin;
    p[view.0] = crosshair[view.0];
    Some(p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_splits_the_region_into_four_cells() {
        let c = cells(URect::new(300, 0, 1301, 801));
        // Coronal top left, sagittal top right, axial bottom left, 3D bottom right; nothing overlaps or is lost.
        assert_eq!(c[1], URect::new(300, 0, 800, 400));
        assert_eq!(c[0], URect::new(800, 0, 1301, 400));
        assert_eq!(c[2], URect::new(300, 400, 800, 801));
        assert_eq!(c[3], URect::new(800, 400, 1301, 801));
    }

    #[test]
    fn a_right_drag_sets_contrast_and_brightness() {
        let (lo, hi) = window_level((0.0, 1.0), Vec2::new(200.0, 0.0));
        assert!((hi - lo - 1f32.exp()).abs() < 1e-5 && ((lo + hi) / 2.0 - 0.5).abs() < 1e-6);
        let (lo, hi) = window_level((0.0, 1.0), Vec2::new(0.0, -100.0));
        assert!((hi - lo - 1.0).abs() < 1e-6 && ((lo + hi) / 2.0 - 0.0).abs() < 1e-6);
    }

    #[test]
    fn views_are_neurological() {
        // The screen's right (forward x up) is the subject's right in axial and coronal views and anterior
        // is on the left of the sagittal view.
        let right = |a| {
            let (from, up) = view_axes(a);
            (-from).cross(up)
        };
        assert_eq!(right(2), Vec3::X);
        assert_eq!(right(1), Vec3::X);
        assert_eq!(right(0), Vec3::NEG_Y);
    }

    #[test]
    fn a_permuted_flipped_grid_cuts_along_its_own_axes() {
        // Voxel x runs along world -y, voxel y along world z, voxel z along world x (2 mm).
        let m = DMat4::from_cols(
            glam::DVec4::new(0.0, -1.0, 0.0, 0.0),
            glam::DVec4::new(0.0, 0.0, 1.0, 0.0),
            glam::DVec4::new(2.0, 0.0, 0.0, 0.0),
            glam::DVec4::new(-10.0, 20.0, 0.0, 1.0),
        );
        let g = VoxelGrid { world_from_voxel: m, dims: [30, 40, 10] };
        assert_eq!([g.axis_along(0), g.axis_along(1), g.axis_along(2)], [2, 0, 1]);
        // World (-4, 15, 7) is voxel (5, 7, 3).
        let p = Vec3::new(-4.0, 15.0, 7.0);
        assert_eq!([g.index_at(p, 0), g.index_at(p, 1), g.index_at(p, 2)], [Some(5), Some(7), Some(3)]);
        assert_eq!(g.index_at(Vec3::new(30.0, 0.0, 0.0), 2), None);
        let (lo, hi) = g.world_box();
        assert_eq!(lo, Vec3::new(-11.0, -9.5, -0.5));
        assert_eq!(hi, Vec3::new(9.0, 20.5, 39.5));
    }
}
