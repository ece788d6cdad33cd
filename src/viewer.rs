//! The interactive viewer: the scene plugin in a window, an orbit camera, and an egui side panel listing
//! the layers (visibility, opacity, each kind's parameter panel from [`LayerPanels`]), load errors, scene
//! save/load and frame time. The 3D camera's viewport is the window minus the panel (egui draws with its
//! own camera on top), so the panel never hides the scene.
//!
//! Mouse: left-drag orbits, right-drag pans, wheel zooms, a left click on an SH glyph highlights it and
//! reports its voxel, Shift + left-drag on a tract ROI, a seed sphere or a glyph plane's handle moves it (the
//! plane's normal handle tilts it), Ctrl + click picks a streamline and Ctrl + drag draws a lasso around
//! streamlines (in the 3D view and the 2D views; `pick_streamlines`). Keys: R resets the view, F12 saves a screenshot
//! (`fascicle-YYYYMMDD-HHMMSS.png`, never overwriting).
//! Files dropped on the window are added as layers; a file that fails to load shows an error and the
//! viewer keeps running.

use std::path::PathBuf;

use bevy::camera::CameraOutputMode;
use bevy::camera::visibility::RenderLayers;
use bevy::input::mouse::{AccumulatedMouseMotion, AccumulatedMouseScroll};
use bevy::prelude::*;
use bevy::render::RenderPlugin;
use bevy::render::render_resource::BlendState;
use bevy::render::view::screenshot::{Screenshot, save_to_disk};
use bevy::window::{FileDragAndDrop, PrimaryWindow};
use bevy_egui::input::{egui_wants_any_keyboard_input, egui_wants_any_pointer_input};
use bevy_egui::{EguiContexts, EguiGlobalSettings, EguiPlugin, EguiPrimaryContextPass, PrimaryEguiContext, egui};
use fascicle_render::FascicleRenderPlugin;
use fascicle_render::budget::{BudgetState, FrameBudget, FrameBudgetPlugin, RenderScale};
use fascicle_render::on_demand::{DrawOnDemand, DrawOnDemandPlugin, KeepAwake, NextFrame, ScheduleNextFrame};
use fascicle_render::retain::{RetainPicture, RetainedPicturePlugin};

use crate::history::{RecentFiles, SceneHistory};
use crate::panels::LayerPanels;
use fascicle_render::layer::LayerStatus;
use fascicle_scene::handles::{HandleSystems, HandlesPlugin, RoiDrag};
use fascicle_scene::layers::{ActiveScene, LayerEntity, LayerJob, RetryLayers, SceneLayer, ScenePlugin, view_camera};
use fascicle_scene::model::{CameraSpec, LayerKind, LayerSpec, MaskRoi, PaintedMask, Scene};
use fascicle_sh_glyphs::{Highlighted, ShGlyphSet};
use fascicle_tracts::{RoiStats, TractSelection, TractSet, selected_tractogram};
use fascicle_views::{Crosshair, MainView, OrthoView, SliceSource, ViewRegion, VoxelGrid, pick_in_view};

#[derive(Resource, Debug, PartialEq)]
struct Orbit {
    target: Vec3,
    distance: f32,
    yaw: f32,
    pitch: f32,
    fov_y_deg: f32,
}

impl Orbit {
    fn from_spec(s: &CameraSpec) -> Self {
        let (eye, target) = (Vec3::from_array(s.eye), Vec3::from_array(s.target));
        let d = eye - target;
        let distance = d.length().max(1e-3);
        Self {
            target,
            distance,
            yaw: d.y.atan2(d.x),
            pitch: (d.z / distance).clamp(-1.0, 1.0).asin(),
            fov_y_deg: s.fov_y_deg,
        }
    }
    fn eye(&self) -> Vec3 {
        self.target
            + self.distance
                * Vec3::new(self.pitch.cos() * self.yaw.cos(), self.pitch.cos() * self.yaw.sin(), self.pitch.sin())
    }
    fn spec(&self) -> CameraSpec {
        CameraSpec {
            eye: self.eye().to_array(),
            target: self.target.to_array(),
            up: [0.0, 0.0, 1.0],
            fov_y_deg: self.fov_y_deg,
        }
    }
}

#[derive(Resource, Default)]
struct UiState {
    scene_path: String,
    message: Option<String>,
    frame_ms: f32,
    screenshots: u32,
    /// Where "Save selection" writes (.trk or .tck).
    selection_path: String,
    /// The tract layer whose selection the panel asked to save.
    save_selection: Option<usize>,
    /// A dropped file whose content is ambiguous, and the layers it could open as: the panel asks.
    ask: Option<(PathBuf, Vec<LayerSpec>)>,
    /// The panel asked for the file dialog.
    open_dialog: bool,
    /// An undo (true) or redo (false) asked for.
    history_step: Option<bool>,
    /// A recent file the panel asked to open.
    open_recent: Option<PathBuf>,
    /// Streamlines picked by Ctrl + click or lasso (Ctrl + drag), for the panel's "delete" / "keep only".
    picked: Option<Picked>,
    /// The lasso being drawn (window positions, logical pixels).
    lasso: Vec<Vec2>,
    /// The brush of a tract layer's painted ROI, while the panel's "paint ROI" is on.
    brush: Option<Brush>,
    /// The brush stroke being drawn.
    stroke: Option<Stroke>,
}

/// Streamlines picked in one tract layer: indices into its streamlines (across its parts).
#[derive(Clone, Debug, Default, PartialEq)]
struct Picked {
    /// The layer's index in the scene.
    layer: usize,
    /// How many streamlines the layer's sets hold together.
    n_streamlines: usize,
    /// The picked streamlines.
    streamlines: std::collections::BTreeSet<u32>,
}

/// What the panel's "delete picked" (false) or "keep only the picked" (true) makes of a layer's deleted list.
fn deleted_after(deleted: &[u32], picked: &Picked, keep_only: bool) -> Vec<u32> {
    let mut out: std::collections::BTreeSet<u32> = deleted.iter().copied().collect();
    if keep_only {
        out.extend((0..picked.n_streamlines as u32).filter(|s| !picked.streamlines.contains(s)));
    } else {
        out.extend(picked.streamlines.iter().copied());
    }
    out.into_iter().collect()
}

/// Where a Ctrl + left press began: the 3D view (`None`) or 2D view `Some(a)`; with the pointer's travel since.
#[derive(Default)]
struct PickGesture {
    view: Option<Option<usize>>,
    dragged: f32,
}

/// The window position (logical pixels) of world points through a view's camera: `None` behind the camera.
fn screen_projection(cam: &Camera, tf: &GlobalTransform) -> Option<impl Fn(Vec3) -> Option<Vec2> + Sync + Copy> {
    let rect = cam.logical_viewport_rect()?;
    let clip_from_world = cam.clip_from_view() * tf.to_matrix().inverse();
    Some(move |p: Vec3| {
        let c = clip_from_world * p.extend(1.0);
        (c.w > 1e-6).then(|| {
            let ndc = c.truncate() / c.w;
            rect.min + Vec2::new(ndc.x + 1.0, 1.0 - ndc.y) * 0.5 * rect.size()
        })
    })
}

/// Picks streamlines of a visible tract layer (across its parts), in the 3D view or a 2D view; the picked are
/// outlined in white, and the layer's panel deletes them or keeps only them.
/// - Ctrl + click (press and release without dragging) picks the streamline under the cursor, or unpicks it: in
///   the 3D view within 4 pixels, the nearest along the ray (`fascicle_core::roi::pick_streamline`); in a 2D
///   view the step of the view's slab nearest the cursor on screen, within 4 pixels
///   (`fascicle_core::roi::pick_projected`).
/// - Ctrl + drag draws a lasso: on release the streamlines with a point inside it are picked (in a 2D view,
///   a point of the view's slab; `fascicle_core::roi::lasso_streamlines`), added to those already picked in
///   the same layer; of several layers, the one with the most.
///
/// Hidden streamlines (outside the ROIs, deleted) are never picked.
#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters")]
fn pick_streamlines(
    buttons: Res<ButtonInput<MouseButton>>,
    keys: Res<ButtonInput<KeyCode>>,
    motion: Res<AccumulatedMouseMotion>,
    mut gesture: Local<PickGesture>,
    pointer: Res<ViewPointer>,
    window: Single<&Window, With<PrimaryWindow>>,
    main: Single<(&Camera, &GlobalTransform), With<MainView>>,
    views: Query<(&Camera, &GlobalTransform, &OrthoView)>,
    sets: Query<(Entity, &TractSet, &TractSelection, &LayerEntity, &InheritedVisibility)>,
    slabs: Query<&fascicle_tracts::TractSlab>,
    scene: Res<ActiveScene>,
    mut ui: ResMut<UiState>,
) {
    let cursor = window.cursor_position();
    let ctrl = keys.any_pressed([KeyCode::ControlLeft, KeyCode::ControlRight]);
    if buttons.just_pressed(MouseButton::Left) {
        *gesture = PickGesture { view: ctrl.then_some(pointer.hovered), dragged: 0.0 };
        ui.lasso = cursor.filter(|_| ctrl).into_iter().collect();
    }
    if gesture.view.is_none() {
        return;
    }
    if buttons.pressed(MouseButton::Left) {
        // The travel from the press: the pointer's motion, or its window positions (which a pointer moved by
        // absolute positions, as a tablet or a remote display, gives alone).
        let from_start = match (ui.lasso.first(), cursor) {
            (Some(s), Some(c)) => s.distance(c),
            _ => 0.0,
        };
        gesture.dragged = (gesture.dragged + motion.delta.length()).max(from_start);
        if let Some(c) = cursor
            && ui.lasso.last().is_none_or(|l| l.distance(c) >= 2.0)
        {
            ui.lasso.push(c);
        }
    }
    if !buttons.just_released(MouseButton::Left) {
        return;
    }
    let Some(view) = gesture.view.take() else { return };
    let lasso = std::mem::take(&mut ui.lasso);
    let Some(at) = cursor else { return };
    let ((cam, tf), slab_axis) = match view {
        None => (*main, None),
        Some(a) => match views.iter().find(|(.., v)| v.0 == a) {
            Some((cam, tf, _)) => ((cam, tf), Some(a)),
            None => return,
        },
    };
    let Some(project) = screen_projection(cam, tf) else { return };
    // A layer in parts picks across them: indices are the layer's (each part's from its `first` on).
    let mut totals = std::collections::HashMap::new();
    for (_, set, _, le, _) in &sets {
        *totals.entry(le.0).or_insert(0) += set.tractogram.n_streamlines();
    }
    let eligible = sets.iter().filter(|(.., v)| v.get());
    // In a 2D view only the points of its slab around the set (as drawn) are picked.
    let slab_of = |set: Entity| {
        let a = slab_axis?;
        slabs.iter().find(|s| s.set == set && s.normal == Vec3::AXES[a]).copied()
    };
    let in_view = |slab: Option<fascicle_tracts::TractSlab>| {
        move |p: Vec3| {
            let inside = slab.is_none_or(|s| (p.dot(s.normal) - s.offset).abs() <= s.half_thickness);
            if inside { project(p) } else { None }
        }
    };
    if slab_axis.is_some() && slabs.is_empty() {
        ui.message = Some("the 2D views show no streamlines to pick".into());
        return;
    }
    let name = |layer: usize| scene.0.layers.get(layer).map_or("?", |l| l.name.as_str()).to_string();
    if gesture.dragged > 3.0 && lasso.len() >= 3 {
        let mut per_layer: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
        for (e, set, sel, le, _) in eligible {
            let t = &set.tractogram;
            let shown = |s: usize| sel.0.get(s).copied().unwrap_or(false);
            let inside = fascicle_core::roi::lasso_streamlines(t, shown, in_view(slab_of(e)), &lasso);
            per_layer.entry(le.0).or_default().extend(inside.into_iter().map(|s| set.first + s));
        }
        let best = per_layer.into_iter().max_by_key(|(_, inside)| inside.len());
        let best = best.map(|(layer, inside)| (layer, totals.get(&layer).copied().unwrap_or(0), inside));
        let Some((layer, n_streamlines, inside)) = best.filter(|b| !b.2.is_empty()) else {
            ui.message = Some("no streamline inside the lasso".into());
            return;
        };
        let picked = ui.picked.get_or_insert_with(Picked::default);
        if picked.layer != layer || picked.n_streamlines != n_streamlines {
            *picked = Picked { layer, n_streamlines, streamlines: Default::default() };
        }
        picked.streamlines.extend(inside.iter().map(|&s| s as u32));
        let n = picked.streamlines.len();
        ui.message = Some(format!(
            "{} streamlines of '{}' in the lasso: {n} picked; the layer's panel deletes them or keeps only them",
            inside.len(),
            name(layer)
        ));
        return;
    }
    if gesture.dragged > 3.0 {
        return;
    }
    let best = match slab_axis {
        None => {
            let (Some(ray), Some(beside)) = (
                fascicle_views::cursor_ray(cam, tf, at),
                fascicle_views::cursor_ray(cam, tf, at + Vec2::new(4.0, 0.0)),
            ) else {
                return;
            };
            let (o, d) = (ray.origin, ray.direction.as_vec3());
            // 4 pixels as an angle: the cone around the ray a step must come within.
            let tolerance = (beside.direction.as_vec3() - d).length().max(1e-6);
            eligible
                .filter_map(|(_, set, sel, le, _)| {
                    let t = &set.tractogram;
                    let shown = |s: usize| sel.0.get(s).copied().unwrap_or(false);
                    set.index.pick(t, shown, o, d, tolerance).map(|(s, dist)| (le.0, set.first + s, dist))
                })
                .min_by(|a, b| a.2.total_cmp(&b.2))
        }
        Some(a) => eligible
            .filter_map(|(e, set, sel, le, _)| {
                let shown = |s: usize| sel.0.get(s).copied().unwrap_or(false);
                let slab = slab_of(e);
                let near = slab.and_then(|s| click_box(project, at, 4.0, &s, a));
                pick_in_slab(set, shown, in_view(slab), at, 4.0, near.as_ref())
                    .map(|(s, dist)| (le.0, set.first + s, dist))
            })
            .min_by(|a, b| a.2.total_cmp(&b.2)),
    };
    let best = best.map(|(layer, s, dist)| (layer, totals.get(&layer).copied().unwrap_or(0), s as u32, dist));
    let Some((layer, n_streamlines, s, _)) = best else {
        ui.message = Some("no streamline under the cursor (Ctrl + click picks one, Ctrl + drag a lasso)".into());
        return;
    };
    let picked = ui.picked.get_or_insert_with(Picked::default);
    if picked.layer != layer || picked.n_streamlines != n_streamlines {
        *picked = Picked { layer, n_streamlines, streamlines: Default::default() };
    }
    if !picked.streamlines.remove(&s) {
        picked.streamlines.insert(s);
    }
    let n = picked.streamlines.len();
    ui.message = Some(format!(
        "streamline {s} of '{}' {}: {n} picked; the layer's panel deletes them or keeps only them",
        name(layer),
        if picked.streamlines.contains(&s) { "picked" } else { "unpicked" }
    ));
}

/// The brush of a tract layer's painted ROI (the layer panel's "paint ROI"): a left drag in a 2D view paints
/// the voxels of the top image's slice at the crosshair within `radius_mm` of the pointer (Shift + drag
/// erases); on release the stroke joins the layer's painted mask as one edit (undo takes it back; the layer
/// re-selects its streamlines once), and the mask is saved as NIfTI ([`save_painted_masks`]).
#[derive(Clone, Debug, PartialEq)]
struct Brush {
    /// The tract layer's index in the scene.
    layer: usize,
    /// The layer's name: the brush turns off when the layer at `layer` is another (a layer removed or moved).
    name: String,
    /// The brush's radius in the view's plane, mm; default 3.
    radius_mm: f32,
}

/// A brush stroke being drawn: the voxels it covered so far, of the grid it began on.
#[derive(Clone, Debug)]
struct Stroke {
    grid: VoxelGrid,
    voxels: std::collections::BTreeSet<u32>,
    erase: bool,
}

/// The voxels of `grid`'s slice through `at` seen in 2D view `a` whose centres lie within `radius` mm of `at`
/// in the view's plane: indices `x + nx * (y + ny * z)`; none when `at` is outside the grid.
fn brush_voxels(grid: &VoxelGrid, a: usize, at: Vec3, radius: f32) -> Vec<u32> {
    let k = grid.axis_along(a);
    let Some(slice) = grid.index_at(at, k) else { return vec![] };
    let q = grid.world_from_voxel.inverse().transform_point3(at.as_dvec3());
    let [nx, ny, _] = grid.dims;
    let mut out = vec![];
    let (i, j) = ((k + 1) % 3, (k + 2) % 3);
    let reach = |axis: usize| {
        let size = grid.world_from_voxel.col(axis).truncate().length().max(1e-6);
        (radius as f64 / size).ceil() as i64 + 1
    };
    let (ri, rj) = (reach(i), reach(j));
    let (ci, cj) = (q[i].round() as i64, q[j].round() as i64);
    for u in ci - ri..=ci + ri {
        for w in cj - rj..=cj + rj {
            if u < 0 || w < 0 || u as usize >= grid.dims[i] || w as usize >= grid.dims[j] {
                continue;
            }
            let mut v = [0usize; 3];
            (v[i], v[j], v[k]) = (u as usize, w as usize, slice);
            let centre =
                grid.world_from_voxel.transform_point3(glam::DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64));
            let mut d = centre.as_vec3() - at;
            d[a] = 0.0;
            if d.length() <= radius {
                out.push((v[0] + nx * (v[1] + ny * v[2])) as u32);
            }
        }
    }
    out
}

/// The top visible slice layer (the image the 2D views show on top): its index in the scene, grid and source.
fn top_slice<'a>(
    scene: &Scene,
    sources: &'a Query<(&LayerEntity, &VoxelGrid, &SliceSource)>,
) -> Option<(usize, &'a VoxelGrid, &'a SliceSource)> {
    scene.layers.iter().enumerate().rev().find_map(|(i, l)| {
        let (_, grid, source) = sources.iter().find(|(le, ..)| le.0 == i)?;
        (l.visible && matches!(l.kind, LayerKind::Slice { .. })).then_some((i, grid, source))
    })
}

/// The brush's input (see [`Brush`]): strokes in the 2D views; the stroke joins the layer's painted mask on
/// release (the layer's first painted mask, else a new include mask saved beside the working folder as
/// `<layer>_roi.nii.gz`).
#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters")]
fn paint_roi(
    buttons: Res<ButtonInput<MouseButton>>,
    keys: Res<ButtonInput<KeyCode>>,
    pointer: Res<ViewPointer>,
    window: Single<&Window, With<PrimaryWindow>>,
    views: Query<(&Camera, &GlobalTransform, &OrthoView)>,
    crosshair: Res<Crosshair>,
    sources: Query<(&LayerEntity, &VoxelGrid, &SliceSource)>,
    mut scene: ResMut<ActiveScene>,
    mut ui: ResMut<UiState>,
) {
    let Some(brush) = ui.brush.clone() else {
        ui.stroke = None;
        return;
    };
    let same = scene.0.layers.get(brush.layer).filter(|l| l.name == brush.name);
    if !matches!(same.map(|l| &l.kind), Some(LayerKind::Tracts { .. })) {
        ui.brush = None;
        return;
    }
    if let Some((a, MouseButton::Left)) = pointer.dragging
        && let Some(c) = window.cursor_position()
        && let Some((cam, tf, view)) = views.iter().find(|(.., v)| v.0 == a)
        && let Some(at) = pick_in_view(cam, tf, *view, c, crosshair.world)
    {
        if ui.stroke.is_none() {
            let Some((_, &grid, _)) = top_slice(&scene.0, &sources) else {
                ui.message = Some("the brush paints on an image: add a slice layer first".into());
                return;
            };
            let erase = keys.any_pressed([KeyCode::ShiftLeft, KeyCode::ShiftRight]);
            ui.stroke = Some(Stroke { grid, voxels: Default::default(), erase });
        }
        if let Some(stroke) = &mut ui.stroke {
            let voxels = brush_voxels(&stroke.grid, a, at, brush.radius_mm);
            stroke.voxels.extend(voxels);
        }
        return;
    }
    if pointer.dragging.is_some() || buttons.pressed(MouseButton::Left) {
        return;
    }
    let Some(stroke) = ui.stroke.take() else { return };
    let layer = &mut scene.0.layers[brush.layer];
    let name: String = layer.name.chars().map(|c| if c.is_alphanumeric() { c } else { '_' }).collect();
    let LayerKind::Tracts { masks, .. } = &mut layer.kind else { return };
    let grid = (stroke.grid.dims, stroke.grid.world_from_voxel.to_cols_array_2d());
    let painted = masks.iter_mut().filter_map(|m| m.painted.as_mut()).find(|p| (p.dims, p.world_from_voxel) == grid);
    let mut fresh = PaintedMask::on_grid(stroke.grid.dims, stroke.grid.world_from_voxel);
    let target = match painted {
        Some(p) => p,
        None => &mut fresh,
    };
    let before = target.voxels.len();
    target.paint(stroke.voxels.iter().copied(), stroke.erase);
    let after = target.voxels.len();
    if !fresh.voxels.is_empty() {
        let path = PathBuf::from(format!("{name}_roi.nii.gz"));
        masks.push(MaskRoi { path, mode: fascicle_core::roi::RoiMode::Include, crop: false, painted: Some(fresh) });
    }
    ui.message = Some(format!("painted ROI: {after} voxels ({:+})", after as i64 - before as i64));
}

/// Saves each painted mask as NIfTI (uint8, the grid's affine) at its path whenever its voxels change (a
/// stroke, undo, redo, a scene opened); a failed write is reported and the viewer keeps running.
fn save_painted_masks(
    scene: Res<ActiveScene>,
    mut saved: Local<std::collections::HashMap<PathBuf, PaintedMask>>,
    mut ui: ResMut<UiState>,
) {
    if !scene.is_changed() {
        return;
    }
    for layer in &scene.0.layers {
        let LayerKind::Tracts { masks, .. } = &layer.kind else { continue };
        for m in masks {
            let Some(p) = &m.painted else { continue };
            if saved.get(&m.path) == Some(p) {
                continue;
            }
            saved.insert(m.path.clone(), p.clone());
            if let Err(e) =
                fascicle_core::io::nifti::write(&m.path, &p.volume(), fascicle_core::io::nifti::WriteType::U8)
            {
                ui.message = Some(format!("{}: could not save the painted ROI: {e}", m.path.display()));
            }
        }
    }
}

/// Draws the painted masks and the stroke being drawn in the 2D views: the outline of each painted voxel of
/// the slice a view shows (the first 20,000), yellow, the stroke's cyan (red when it erases).
fn draw_painted(
    mut gizmos: Gizmos<ViewGizmos>,
    scene: Res<ActiveScene>,
    ui: Res<UiState>,
    crosshair: Res<Crosshair>,
    views: Res<fascicle_views::Views>,
) {
    if !views.ortho {
        return;
    }
    // Each mask's grid, voxels and colour: the painted masks as the scene holds them, then the stroke.
    let stroke: Option<(VoxelGrid, Vec<u32>, Color)> = ui.stroke.as_ref().map(|s| {
        let colour = if s.erase { Color::srgb(1.0, 0.2, 0.2) } else { Color::srgb(0.2, 0.9, 1.0) };
        (s.grid, s.voxels.iter().copied().collect(), colour)
    });
    let painted = scene.0.layers.iter().filter(|l| l.visible).flat_map(|l| match &l.kind {
        LayerKind::Tracts { masks, .. } => masks.iter().filter_map(|m| m.painted.as_ref()).collect(),
        _ => vec![],
    });
    let all: Vec<(VoxelGrid, &[u32], Color)> = painted
        .map(|p| {
            let grid =
                VoxelGrid { dims: p.dims, world_from_voxel: glam::DMat4::from_cols_array_2d(&p.world_from_voxel) };
            (grid, &p.voxels[..], Color::srgb(1.0, 0.85, 0.1))
        })
        .chain(stroke.iter().map(|(g, v, c)| (*g, &v[..], *c)))
        .collect();
    for a in 0..3 {
        let (from, _) = fascicle_views::view_axes(a);
        let mut drawn = 0;
        for &(grid, voxels, colour) in &all {
            let k = grid.axis_along(a);
            let Some(slice) = grid.index_at(crosshair.world, k) else { continue };
            let (i, j) = ((k + 1) % 3, (k + 2) % 3);
            let (ei, ej) = (
                grid.world_from_voxel.col(i).truncate().as_vec3() * 0.5,
                grid.world_from_voxel.col(j).truncate().as_vec3() * 0.5,
            );
            let [nx, ny, _] = grid.dims;
            for &v in voxels {
                let v = v as usize;
                let xyz = [v % nx, (v / nx) % ny, v / (nx * ny)];
                if xyz[k] != slice || drawn >= 20_000 {
                    continue;
                }
                drawn += 1;
                let mut c = grid
                    .world_from_voxel
                    .transform_point3(glam::DVec3::new(xyz[0] as f64, xyz[1] as f64, xyz[2] as f64))
                    .as_vec3();
                // On the view's plane, 1 mm towards the eye (over the image, as the tract slabs).
                c[a] = crosshair.world[a] + from[a].signum();
                let corners = [c - ei - ej, c + ei - ej, c + ei + ej, c - ei + ej].map(|mut p| {
                    p[a] = c[a];
                    p
                });
                gizmos.linestrip(corners.into_iter().chain([corners[0]]), colour);
            }
        }
    }
}

/// The world box a click at `at` in a 2D view can pick from: through the set's slab (axis `axis` across it), the
/// points of the slab's plane whose image under `project` (the view's orthographic projection, affine) lies
/// within `radius` pixels of the click, widened across the plane by the same distance (with a margin for
/// rounding). `None` when the projection flattens the plane.
fn click_box(
    project: impl Fn(Vec3) -> Option<Vec2>,
    at: Vec2,
    radius: f32,
    slab: &fascicle_tracts::TractSlab,
    axis: usize,
) -> Option<fascicle_core::roi::RoiShape> {
    let (u, v) = (Vec3::AXES[(axis + 1) % 3], Vec3::AXES[(axis + 2) % 3]);
    let o = Vec3::AXES[axis] * slab.offset;
    let p0 = project(o)?;
    let (pu, pv) = (project(o + u)? - p0, project(o + v)? - p0);
    let det = pu.perp_dot(pv);
    if det.abs() < 1e-9 {
        return None;
    }
    // The plane's point under the click, and the radius in mm: over the smallest stretch of the projection.
    let d = at - p0;
    let c = o + u * (d.perp_dot(pv) / det) + v * (pu.perp_dot(d) / det);
    let (uu, uv, vv) = (pu.dot(pu), pu.dot(pv), pv.dot(pv));
    let least = ((uu + vv - ((uu - vv).powi(2) + 4.0 * uv * uv).sqrt()) / 2.0).max(1e-12).sqrt();
    let r = radius / least * 1.01 + 1e-3;
    let (mut lo, mut hi) = (c - Vec3::splat(r), c + Vec3::splat(r));
    lo[axis] = slab.offset - slab.half_thickness - 1e-3;
    hi[axis] = slab.offset + slab.half_thickness + 1e-3;
    Some(fascicle_core::roi::RoiShape::Box { min: lo.to_array(), max: hi.to_array() })
}

/// A click's pick in a 2D view among one set's streamlines (`fascicle_core::roi::pick_projected`), testing
/// only those in the index's cells that meet `near` (the [`click_box`]: a step that comes within the radius on
/// screen comes within it in the plane, between two points in the slab) when the set's index is built; every
/// streamline otherwise (and the index is started).
fn pick_in_slab(
    set: &TractSet,
    shown: impl Fn(usize) -> bool + Sync,
    project: impl Fn(Vec3) -> Option<Vec2> + Sync,
    at: Vec2,
    radius: f32,
    near: Option<&fascicle_core::roi::RoiShape>,
) -> Option<(usize, f32)> {
    let t = &set.tractogram;
    let near_flags = near.and_then(|b| set.index.candidates(t, b)).map(|candidates| {
        let mut flags = vec![false; t.n_streamlines()];
        candidates.iter().for_each(|s| flags[*s as usize] = true);
        flags
    });
    let shown = |s: usize| near_flags.as_ref().is_none_or(|f| f[s]) && shown(s);
    fascicle_core::roi::pick_projected(t, shown, project, at, radius)
}

/// The gizmos of the 2D views (painted ROIs, picked streamlines in a view's slab): on the views' render layers.
#[derive(Default, Reflect, GizmoConfigGroup)]
struct ViewGizmos;

/// Outlines the picked streamlines in white (the first 2,000 of each part of the layer; in the 2D views their
/// runs in the view's slab);
/// forgets the picks when their layer no longer shows the set they index (removed, rebuilt, reordered), so that
/// no edit applies them to other streamlines.
fn draw_picked(
    mut gizmos: Gizmos,
    mut view_gizmos: Gizmos<ViewGizmos>,
    mut ui: ResMut<UiState>,
    sets: Query<(Entity, &TractSet, &LayerEntity)>,
    slabs: Query<&fascicle_tracts::TractSlab>,
) {
    let Some(picked) = &ui.picked else { return };
    let parts: Vec<(Entity, &TractSet)> =
        sets.iter().filter(|(_, _, le)| le.0 == picked.layer).map(|(e, s, _)| (e, s)).collect();
    if parts.iter().map(|(_, s)| s.tractogram.n_streamlines()).sum::<usize>() != picked.n_streamlines {
        ui.picked = None;
        return;
    }
    let of_part = |set| picked_of_part(picked, set);
    for (_, set) in &parts {
        for pts in of_part(set) {
            gizmos.linestrip(pts.iter().copied(), Color::WHITE);
        }
    }
    // In each 2D view, the runs of points within the view's slab, on its plane 1 mm towards the eye.
    for (slab, set) in slabs.iter().filter_map(|s| parts.iter().find(|(e, _)| *e == s.set).map(|(_, set)| (s, set))) {
        let Some(a) = (0..3).find(|&a| slab.normal == Vec3::AXES[a]) else { continue };
        let over = slab.offset + fascicle_views::view_axes(a).0[a].signum();
        let inside = |p: &Vec3| (p[a] - slab.offset).abs() <= slab.half_thickness;
        for pts in of_part(set) {
            for run in pts.split(|p| !inside(p)).filter(|r| r.len() > 1) {
                let flat = run.iter().map(|p| {
                    let mut q = *p;
                    q[a] = over;
                    q
                });
                view_gizmos.linestrip(flat, Color::WHITE);
            }
        }
    }
}

/// The points of the picked streamlines that lie in the part `set` of their layer (the first 2,000).
fn picked_of_part<'a>(picked: &'a Picked, set: &'a TractSet) -> impl Iterator<Item = &'a [Vec3]> + 'a {
    let (a, n) = (set.first as u32, set.tractogram.n_streamlines() as u32);
    picked
        .streamlines
        .range(a..a.saturating_add(n))
        .take(2000)
        .map(move |&s| set.tractogram.streamline((s - a) as usize))
}

/// Builds the starting scene from command-line files: scene files replace the scene, data files add layers.
fn initial_scene(files: &[PathBuf]) -> (Scene, Vec<String>) {
    if files.is_empty() {
        return (Scene::default_scene(), vec![]);
    }
    let mut scene = Scene { layers: vec![], camera: CameraSpec::default(), views: Default::default() };
    let mut errors = vec![];
    for f in files {
        if let Err(e) = scene.open_file(f) {
            errors.push(e);
        }
    }
    if !scene.layers.iter().any(|l| matches!(l.kind, LayerKind::Axes { .. })) {
        scene.layers.push(LayerSpec {
            name: "Axes".into(),
            visible: true,
            opacity: 1.0,
            kind: LayerKind::Axes { length_mm: 30.0 },
        });
    }
    (scene, errors)
}

/// `--screenshot`: the window is saved at frame `AUTO_SCREENSHOT_FRAME`, then the viewer exits.
#[derive(Resource)]
struct AutoScreenshot {
    path: PathBuf,
    frame: u32,
}

/// Frames before an automatic screenshot: pipelines compile asynchronously in a window, so this leaves them
/// time (on lavapipe too) rather than capturing the clear colour.
const AUTO_SCREENSHOT_FRAME: u32 = 240;

fn auto_screenshot(mut commands: Commands, mut shot: ResMut<AutoScreenshot>) {
    shot.frame += 1;
    if shot.frame == AUTO_SCREENSHOT_FRAME {
        let path = shot.path.clone();
        commands.spawn(Screenshot::primary_window()).observe(
            move |ev: On<bevy::render::view::screenshot::ScreenshotCaptured>, mut exit: MessageWriter<AppExit>| {
                let result = ev
                    .image
                    .clone()
                    .try_into_dynamic()
                    .map_err(|e| e.to_string())
                    .and_then(|img| img.to_rgb8().save(&path).map_err(|e| e.to_string()));
                match result {
                    Ok(()) => {
                        eprintln!("wrote {}", path.display());
                        exit.write(AppExit::Success);
                    }
                    Err(e) => {
                        eprintln!("error: {}: {e}", path.display());
                        exit.write(AppExit::error());
                    }
                }
            },
        );
    }
}

/// The viewer's frame budget: on when it draws on demand; `FASCICLE_FRAME_BUDGET_MS` (milliseconds, > 0) sets
/// the budget on any adapter instead of [`FrameBudget`]'s defaults (100 ms on a software adapter, 16 ms on a
/// GPU), e.g. 1 to hold the smallest render scale while the view moves.
fn frame_budget(enabled: bool) -> FrameBudget {
    let mut budget = FrameBudget { enabled, ..default() };
    match std::env::var("FASCICLE_FRAME_BUDGET_MS").map(|v| v.trim().parse::<f64>()) {
        Ok(Ok(ms)) if ms > 0.0 && ms.is_finite() => {
            budget.software = std::time::Duration::from_secs_f64(ms / 1e3);
            budget.hardware = budget.software;
        }
        Ok(_) => warn!("FASCICLE_FRAME_BUDGET_MS: not a positive number of milliseconds; the defaults hold"),
        Err(_) => {}
    }
    budget
}

/// `fascicle view` (and `fascicle` alone): the viewer window on `files` (none: the default scene; scene files
/// replace the scene, data files add layers), until it closes; with `screenshot`, the window is saved there as
/// PNG at frame 240 and the viewer exits.
pub fn run(files: Vec<PathBuf>, screenshot: Option<PathBuf>) -> AppExit {
    let (scene, errors) = initial_scene(&files);
    let frame_log = std::env::var_os("FASCICLE_FRAME_LOG").and_then(|p| FrameLog::create(p.into()));
    let orbit = Orbit::from_spec(&scene.camera);
    let mut app = App::new();
    if let Some(log) = frame_log {
        app.insert_resource(log);
    }
    let draw_on_demand = screenshot.is_none();
    if let Some(path) = screenshot {
        app.insert_resource(AutoScreenshot { path, frame: 0 })
            .add_systems(Update, auto_screenshot.run_if(resource_exists::<AutoScreenshot>));
    }
    app.add_plugins(
        fascicle_render::batching::default_plugins()
            .set(WindowPlugin { primary_window: Some(Window { title: "Fascicle".into(), ..default() }), ..default() })
            .set(RenderPlugin { render_creation: fascicle_render::wgpu_settings().into(), ..default() }),
    )
    .add_plugins(EguiPlugin::default())
    .add_plugins((FascicleRenderPlugin, ScenePlugin, HandlesPlugin, DrawOnDemandPlugin, FrameBudgetPlugin))
    .add_plugins(RetainedPicturePlugin);
    // Diagnostics: every pass's CPU and GPU time (timestamp queries), logged each second.
    if std::env::var_os("FASCICLE_PASS_TIMES").is_some() {
        app.add_plugins((
            bevy::render::diagnostic::RenderDiagnosticsPlugin,
            bevy::diagnostic::LogDiagnosticsPlugin::default(),
        ));
    }
    app.init_gizmo_group::<ViewGizmos>()
        .add_systems(PostUpdate, egui_images_outside_picture)
        // A window redraws when something changed (`--screenshot` counts frames, so it draws every frame).
        .insert_resource(DrawOnDemand { enabled: draw_on_demand, ..default() })
        // While the view moves the 3D view draws at the scale the frame budget affords (not with `--screenshot`).
        .insert_resource(frame_budget(draw_on_demand))
        // Line previews while the view moves or a tractogram streams in (not with `--screenshot`, whose frame count
        // stands for a settled scene).
        .insert_resource(fascicle_tracts::TractDetail { enabled: draw_on_demand, ..default() })
        .add_systems(Last, keep_awake_while_working.before(ScheduleNextFrame))
        .add_systems(Last, log_frame.after(ScheduleNextFrame).run_if(resource_exists::<FrameLog>))
        .add_systems(
            PreUpdate,
            drop_repeated_modifier_events
                .after(bevy_egui::EguiPreUpdateSet::ProcessInput)
                .before(bevy_egui::EguiPreUpdateSet::BeginPass),
        )
        .insert_resource(ActiveScene(scene))
        .init_resource::<LayerPanels>()
        .init_resource::<FileDialog>()
        .init_resource::<SceneHistory>()
        .init_resource::<ViewPointer>()
        .insert_resource(RecentFiles::for_user())
        .insert_resource(orbit)
        .insert_resource(UiState {
            message: (!errors.is_empty()).then(|| errors.join("\n")),
            scene_path: "scene.ron".into(),
            selection_path: "selection.trk".into(),
            ..default()
        })
        .add_systems(
            Startup,
            |mut commands: Commands,
             mut egui_settings: ResMut<EguiGlobalSettings>,
             mut gizmo_config: ResMut<GizmoConfigStore>| {
                // The brush's gizmos show in the 2D views, over the images.
                let (config, _) = gizmo_config.config_mut::<ViewGizmos>();
                config.render_layers = RenderLayers::from_layers(&fascicle_views::VIEW_LAYERS);
                config.depth_bias = -1.0;
                // A pointer move that changes nothing puts the last picture back (fascicle_render::retain).
                commands.spawn((view_camera(), Transform::default(), RenderScale::default(), RetainPicture));
                // egui gets its own camera drawn over the 3D view, so the 3D camera can take a viewport.
                egui_settings.auto_create_primary_context = false;
                commands.spawn((
                    PrimaryEguiContext,
                    Camera2d,
                    // egui draws into the camera's unsampled texture: a multisampled one would only be cleared and
                    // resolved over the whole window every frame (lavapipe: about 13 ms a frame of the empty scene).
                    Msaa::Off,
                    RenderLayers::none(),
                    Camera {
                        // Over the 3D view (with its colour bars) and the 2D views.
                        order: 2,
                        output_mode: CameraOutputMode::Write {
                            blend_state: Some(BlendState::ALPHA_BLENDING),
                            clear_color: ClearColorConfig::None,
                        },
                        clear_color: ClearColorConfig::Custom(Color::NONE),
                        ..default()
                    },
                ));
            },
        )
        .add_systems(
            Update,
            (
                view_input.run_if(not(egui_wants_any_pointer_input)),
                orbit_input.after(HandleSystems).run_if(not(egui_wants_any_pointer_input)).run_if(pointer_in_3d_view),
                pick_glyph.run_if(not(egui_wants_any_pointer_input)).run_if(pointer_in_3d_view),
                pick_streamlines.after(view_input).run_if(not(egui_wants_any_pointer_input)),
                draw_picked,
                paint_roi.after(view_input).run_if(not(egui_wants_any_pointer_input)),
                save_painted_masks,
                draw_painted,
                keys.run_if(not(egui_wants_any_keyboard_input)),
                dropped_files,
                file_dialog,
                save_selection,
                undo_keys.run_if(not(egui_wants_any_keyboard_input)),
                apply_orbit.run_if(resource_changed::<Orbit>),
            ),
        )
        // Handles are dragged only when the pointer is over the 3D view and not on the panel.
        .configure_sets(Update, HandleSystems.run_if(not(egui_wants_any_pointer_input)).run_if(pointer_in_3d_view))
        // Undo applies before the layers sync, so the scene it restores shows in the same frame.
        .add_systems(Update, scene_history.before(fascicle_scene::layers::SceneSystems::Sync))
        .add_systems(EguiPrimaryContextPass, panel)
        .run()
}

fn orbit_input(
    buttons: Res<ButtonInput<MouseButton>>,
    keys: Res<ButtonInput<KeyCode>>,
    motion: Res<AccumulatedMouseMotion>,
    scroll: Res<AccumulatedMouseScroll>,
    drag: Res<RoiDrag>,
    mut orbit: ResMut<Orbit>,
    mut interacting: ResMut<fascicle_render::budget::Interacting>,
) {
    // A Ctrl + left drag draws a lasso (pick_streamlines): the view stays.
    let lasso = buttons.pressed(MouseButton::Left) && keys.any_pressed([KeyCode::ControlLeft, KeyCode::ControlRight]);
    if drag.0.is_some() || lasso {
        return;
    }
    // A drag is an interaction from its press (whose frame already draws at the scale the frame budget
    // affords) to its release, frames without motion included.
    let d = motion.delta;
    if buttons.any_pressed([MouseButton::Left, MouseButton::Right]) {
        // Held still, the drag draws nothing new: no frame until the pointer moves or the button is released.
        if d != Vec2::ZERO || scroll.delta.y != 0.0 { interacting.mark() } else { interacting.hold() }
    } else if buttons.any_just_released([MouseButton::Left, MouseButton::Right]) {
        // The drag ended: the view refines now, not after the budget's still time.
        interacting.release();
    }
    if buttons.pressed(MouseButton::Left) && d != Vec2::ZERO {
        orbit.yaw -= d.x * 0.01;
        orbit.pitch = (orbit.pitch + d.y * 0.01).clamp(-1.55, 1.55);
    }
    if buttons.pressed(MouseButton::Right) && d != Vec2::ZERO {
        let fwd = (orbit.target - orbit.eye()).normalize();
        let right = fwd.cross(Vec3::Z).normalize_or_zero();
        let up = right.cross(fwd);
        let k = orbit.distance * 0.0015;
        orbit.target += (-d.x * right + d.y * up) * k;
    }
    if scroll.delta.y != 0.0 {
        orbit.distance = (orbit.distance * (-0.1 * scroll.delta.y).exp()).clamp(1.0, 5000.0);
    }
}

/// The 2D view under the pointer, and the one a drag began in (with its button).
#[derive(Resource, Default, Debug)]
struct ViewPointer {
    hovered: Option<usize>,
    dragging: Option<(usize, MouseButton)>,
}

fn pointer_in_3d_view(pointer: Res<ViewPointer>) -> bool {
    pointer.hovered.is_none() && pointer.dragging.is_none()
}

/// Mouse input in the 2D views: a left click or drag (without Ctrl) moves the crosshair in the view's plane, the wheel steps
/// it one voxel through the plane, a right drag sets the window of the top visible slice layer (horizontal:
/// contrast, vertical: brightness).
#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters are its data dependencies")]
fn view_input(
    buttons: Res<ButtonInput<MouseButton>>,
    keys: Res<ButtonInput<KeyCode>>,
    ui: Res<UiState>,
    motion: Res<AccumulatedMouseMotion>,
    scroll: Res<AccumulatedMouseScroll>,
    window: Single<&Window, With<PrimaryWindow>>,
    views: Query<(&Camera, &GlobalTransform, &OrthoView)>,
    crosshair: Res<Crosshair>,
    sources: Query<(&LayerEntity, &VoxelGrid, &SliceSource)>,
    mut scene: ResMut<ActiveScene>,
    mut pointer: ResMut<ViewPointer>,
) {
    let cursor = window.cursor_position();
    let over = |c: Vec2| {
        views.iter().find(|(cam, _, _)| cam.is_active && cam.logical_viewport_rect().is_some_and(|r| r.contains(c)))
    };
    pointer.hovered = cursor.and_then(over).map(|(.., v)| v.0);
    for b in [MouseButton::Left, MouseButton::Right] {
        if buttons.just_pressed(b) {
            pointer.dragging = pointer.hovered.map(|a| (a, b));
        }
    }
    if !buttons.pressed(MouseButton::Left) && !buttons.pressed(MouseButton::Right) {
        pointer.dragging = None;
    }
    let mut views_edit = scene.0.views;
    let mut at = crosshair.world;
    if let Some(a) = pointer.hovered
        && scroll.delta.y != 0.0
    {
        // One voxel of the first image along its axis nearest the view's.
        let step = sources
            .iter()
            .next()
            .map_or(1.0, |(_, g, _)| g.world_from_voxel.col(g.axis_along(a)).truncate().length() as f32);
        at[a] += step * scroll.delta.y.signum();
        views_edit.crosshair = Some(at.to_array());
    }
    match pointer.dragging {
        // Ctrl + left picks streamlines (pick_streamlines); with the brush on, left paints (paint_roi).
        Some((a, MouseButton::Left))
            if !keys.any_pressed([KeyCode::ControlLeft, KeyCode::ControlRight]) && ui.brush.is_none() =>
        {
            if let Some(c) = cursor
                && let Some((cam, tf, view)) = views.iter().find(|(.., v)| v.0 == a)
                && let Some(p) = pick_in_view(cam, tf, *view, c, at)
            {
                views_edit.crosshair = Some(p.to_array());
            }
        }
        Some((_, MouseButton::Right)) if motion.delta != Vec2::ZERO => {
            if let Some((i, _, source)) = top_slice(&scene.0, &sources)
                && let LayerKind::Slice { window, .. } = &mut scene.0.layers[i].kind
            {
                *window = Some(fascicle_views::window_level(source.window(*window), motion.delta));
            }
        }
        _ => {}
    }
    if views_edit != scene.0.views {
        scene.0.views = views_edit;
    }
}

/// The world ray under the window's cursor through the 3D camera (its viewport beside the panel or in the
/// four-view grid).
fn cursor_ray(window: &Window, (cam, tf): (&Camera, &GlobalTransform)) -> Option<Ray3d> {
    fascicle_views::cursor_ray(cam, tf, window.cursor_position()?)
}

/// A click (press and release without dragging) on an SH glyph toggles its highlight and reports its voxel.
#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters")]
fn pick_glyph(
    mut commands: Commands,
    buttons: Res<ButtonInput<MouseButton>>,
    motion: Res<AccumulatedMouseMotion>,
    mut dragged: Local<f32>,
    window: Single<&Window, With<PrimaryWindow>>,
    camera: Single<(&Camera, &GlobalTransform), With<MainView>>,
    sets: Query<(Entity, &ShGlyphSet, Option<&Highlighted>)>,
    mut ui: ResMut<UiState>,
) {
    if buttons.just_pressed(MouseButton::Left) {
        *dragged = 0.0;
    }
    if buttons.pressed(MouseButton::Left) {
        *dragged += motion.delta.length();
    }
    if !buttons.just_released(MouseButton::Left) || *dragged > 3.0 {
        return;
    }
    let Some(ray) = cursor_ray(&window, *camera) else { return };
    let (o, d) = (ray.origin.as_dvec3(), ray.direction.as_vec3().as_dvec3());
    let best = sets
        .iter()
        .filter_map(|(e, set, lit)| set.pick(o, d).map(|(i, hit)| (e, set, lit, i, hit)))
        .min_by(|a, b| a.4.t.total_cmp(&b.4.t));
    let Some((entity, set, lit, i, hit)) = best else { return };
    let mut lit = lit.cloned().unwrap_or_default();
    lit.toggle(i);
    commands.entity(entity).insert(lit);
    let g = &set.glyphs[i as usize];
    ui.message =
        Some(format!("glyph {i}: voxel {:?}, GFA {:.3}, hit at {:.1?} mm", set.voxel(i), g.gfa, hit.point.to_array()));
}

fn apply_orbit(orbit: Res<Orbit>, mut cam: Query<(&mut Transform, &mut Projection), With<MainView>>) {
    let (tf, proj) = fascicle_scene::layers::camera_from_spec(&orbit.spec());
    for (mut t, mut p) in &mut cam {
        *t = tf;
        *p = proj.clone();
    }
}

fn keys(
    mut commands: Commands,
    input: Res<ButtonInput<KeyCode>>,
    scene: Res<ActiveScene>,
    mut orbit: ResMut<Orbit>,
    mut ui: ResMut<UiState>,
) {
    if input.just_pressed(KeyCode::KeyR) {
        *orbit = Orbit::from_spec(&scene.0.camera);
    }
    if input.just_pressed(KeyCode::F12) {
        let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
        let path = screenshot_path(secs, |p| p.exists());
        ui.screenshots += 1;
        ui.message = Some(format!("saved {}", path.display()));
        commands.spawn(Screenshot::primary_window()).observe(save_to_disk(path));
    }
}

/// Ctrl+Z undoes the last scene edit, Ctrl+Shift+Z (or Ctrl+Y) redoes it.
fn undo_keys(input: Res<ButtonInput<KeyCode>>, mut ui: ResMut<UiState>) {
    let ctrl = input.any_pressed([KeyCode::ControlLeft, KeyCode::ControlRight]);
    let shift = input.any_pressed([KeyCode::ShiftLeft, KeyCode::ShiftRight]);
    if ctrl && input.just_pressed(KeyCode::KeyZ) {
        ui.history_step = Some(!shift);
    } else if ctrl && input.just_pressed(KeyCode::KeyY) {
        ui.history_step = Some(false);
    }
}

/// Records scene edits for undo (a drag with the mouse held is one step) and applies the undo or redo the
/// keys or the panel asked for.
fn scene_history(
    mut history: ResMut<SceneHistory>,
    mut scene: ResMut<ActiveScene>,
    mut ui: ResMut<UiState>,
    buttons: Res<ButtonInput<MouseButton>>,
) {
    if let Some(undo) = ui.history_step.take() {
        let current = scene.0.clone();
        let step = if undo { history.undo(&current) } else { history.redo(&current) };
        match step {
            Some(s) => scene.0 = s,
            None => ui.message = Some(format!("nothing to {}", if undo { "undo" } else { "redo" })),
        }
    }
    if scene.is_changed() {
        history.record(&scene.0, buttons.pressed(MouseButton::Left));
    } else if !buttons.pressed(MouseButton::Left) {
        // A release ends the gesture even when the last frame changed nothing.
        history.record(&scene.0, false);
    }
}

/// `fascicle-YYYYMMDD-HHMMSS.png` (UTC) in the working directory, with `-2`, `-3`, ... if taken: screenshots
/// never overwrite one another, across runs too.
pub fn screenshot_path(unix_secs: u64, exists: impl Fn(&std::path::Path) -> bool) -> PathBuf {
    let [y, m, d] = fascicle_scene::headless::civil_date(unix_secs);
    let rest = unix_secs % 86_400;
    let stem = format!("fascicle-{y:04}{m:02}{d:02}-{:02}{:02}{:02}", rest / 3600, rest % 3600 / 60, rest % 60);
    (1..)
        .map(|k| PathBuf::from(if k == 1 { format!("{stem}.png") } else { format!("{stem}-{k}.png") }))
        .find(|p| !exists(p))
        .unwrap_or_else(|| PathBuf::from(format!("{stem}.png")))
}

fn dropped_files(
    mut events: MessageReader<FileDragAndDrop>,
    mut scene: ResMut<ActiveScene>,
    mut ui: ResMut<UiState>,
    mut orbit: ResMut<Orbit>,
    mut recent: ResMut<RecentFiles>,
) {
    for ev in events.read() {
        if let FileDragAndDrop::DroppedFile { path_buf, .. } = ev {
            open_path(path_buf, &mut scene, &mut ui, &mut orbit, &mut recent);
        }
    }
    if let Some(path) = ui.open_recent.take() {
        open_path(&path, &mut scene, &mut ui, &mut orbit, &mut recent);
    }
}

/// Opens a file as a new layer (or asks what it is, when its content does not tell); the camera frames it.
fn open_path(
    path: &std::path::Path,
    scene: &mut ActiveScene,
    ui: &mut UiState,
    orbit: &mut Orbit,
    recent: &mut RecentFiles,
) {
    if let Ok((first, others)) = Scene::layer_choices(path)
        && !others.is_empty()
    {
        ui.ask = Some((path.to_path_buf(), std::iter::once(first).chain(others).collect()));
        return;
    }
    match scene.0.open_file(path) {
        // The scene's camera frames the new layer: the view follows.
        Ok(()) => {
            *orbit = Orbit::from_spec(&scene.0.camera);
            if let Err(e) = recent.add(path) {
                ui.message = Some(e);
            }
        }
        Err(e) => ui.message = Some(e),
    }
}

/// The system's file dialog, open: it runs on its own thread (the window keeps drawing) and gives the files
/// chosen, or none when cancelled.
#[derive(Resource, Default)]
struct FileDialog(Option<bevy::tasks::Task<Option<Vec<PathBuf>>>>);

/// Draws every [`DrawOnDemand::busy_wait`] while layers are being built, neighbouring slices prefetched or
/// the file dialog is open, so that progress bars move and finished work shows without input; and draws again
/// after egui's textures changed (text with glyphs new to the font atlas is drawn whole in the next frame).
/// A line per frame for `fascicle-bench interact` (the file named by `FASCICLE_FRAME_LOG`): the wall clock
/// (Unix ms) and the frame's time (ms, the real time since the frame before, as the panel's readout), the 3D view's render scale, whether the view moved, when the next frame is
/// due, the window position (logical px) of the first visible tract layer's first ROI or seed sphere, and
/// whether the budget draws coarse ([`BudgetState::coarse`]), and how many ROI selections have been made
/// ([`RoiStats::evaluations`]: a drag's steps that landed).
#[derive(Resource)]
struct FrameLog(std::io::LineWriter<std::fs::File>);

impl FrameLog {
    fn create(path: PathBuf) -> Option<FrameLog> {
        match std::fs::File::create(&path) {
            Ok(f) => Some(FrameLog(std::io::LineWriter::new(f))),
            Err(e) => {
                warn!("FASCICLE_FRAME_LOG {}: {e}", path.display());
                None
            }
        }
    }
}

fn log_frame(
    mut log: ResMut<FrameLog>,
    time: Res<Time<bevy::time::Real>>,
    (budget, next, roi_stats): (Res<BudgetState>, Res<NextFrame>, Res<RoiStats>),
    scene: Res<ActiveScene>,
    camera: Single<(&Camera, &GlobalTransform), With<MainView>>,
) {
    use std::io::Write;
    let roi = scene
        .0
        .layers
        .iter()
        .filter(|l| l.visible)
        .flat_map(|l| fascicle_scene::handles::grips(&l.kind))
        .find_map(|(_, shape)| match shape {
            fascicle_core::roi::RoiShape::Sphere { centre, .. } => {
                camera.0.world_to_viewport(camera.1, Vec3::from(centre)).ok()
            }
            _ => None,
        })
        .unwrap_or(Vec2::NAN);
    let line = format!(
        "{} {:.2} {} {} {:?} {:.0} {:.0} {} {}",
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis()),
        time.delta_secs_f64() * 1e3,
        budget.scale,
        budget.moving,
        *next,
        roi.x,
        roi.y,
        budget.coarse,
        roi_stats.evaluations
    );
    let _ = writeln!(log.0, "{line}");
}

fn keep_awake_while_working(
    jobs: Query<(), With<fascicle_scene::layers::LayerJob>>,
    prefetches: Res<fascicle_scene::layers::Prefetches>,
    dialog: Res<FileDialog>,
    egui_outputs: Query<&bevy_egui::EguiRenderOutput>,
    mut keep: ResMut<KeepAwake>,
) {
    if !jobs.is_empty() || prefetches.running() > 0 || dialog.0.is_some() {
        keep.busy();
    }
    if egui_outputs.iter().any(|o| !o.textures_delta.set.is_empty() || !o.textures_delta.free.is_empty()) {
        keep.redraw();
    }
}

/// bevy_egui 0.42 tells egui the modifier keys' state as an event every frame, and egui repaints at once after
/// any event: the window would never go idle. Only a change of the modifiers is passed on.
fn drop_repeated_modifier_events(
    mut inputs: Query<(Entity, &mut bevy_egui::EguiInput)>,
    mut last: Local<std::collections::HashMap<Entity, egui::Modifiers>>,
) {
    for (entity, mut input) in &mut inputs {
        input.0.events.retain(|e| match e {
            egui::Event::ModifiersChanged(m) => last.insert(entity, *m) != Some(*m),
            _ => true,
        });
    }
}

/// Opens the file dialog when the panel asked, and the files chosen in it when it closes.
fn file_dialog(
    mut dialog: ResMut<FileDialog>,
    mut scene: ResMut<ActiveScene>,
    mut ui: ResMut<UiState>,
    mut orbit: ResMut<Orbit>,
    mut recent: ResMut<RecentFiles>,
) {
    if std::mem::take(&mut ui.open_dialog) && dialog.0.is_none() {
        let pick = rfd::AsyncFileDialog::new()
            .set_title("Open diffusion MRI files")
            .add_filter("images, tractograms, scenes", OPENABLE)
            .add_filter("all files", &["*"])
            .set_directory(std::env::current_dir().unwrap_or_default())
            .pick_files();
        let task = bevy::tasks::IoTaskPool::get()
            .spawn(async move { pick.await.map(|files| files.iter().map(|f| f.path().to_path_buf()).collect()) });
        dialog.0 = Some(task);
    }
    let Some(task) = dialog.0.as_mut() else { return };
    let Some(chosen) = bevy::tasks::futures::check_ready(task) else { return };
    dialog.0 = None;
    // Scene files replace the scene, data files add layers (`Scene::open_file`), as when dropped.
    for path in chosen.unwrap_or_default() {
        open_path(&path, &mut scene, &mut ui, &mut orbit, &mut recent);
    }
}

/// File name endings the open dialog lists (the last part: `.nii.gz` is `gz`).
const OPENABLE: &[&str] = &["nii", "gz", "mif", "trk", "tck", "trx", "ron"];

/// Writes the streamlines that a tract layer's ROIs select to `UiState::selection_path`, when the panel
/// asked: from the layer's tract sets (a layer in parts: its parts in the layer's order), or, when it has none
/// (its data failed to load), selected again from the layer's source (cached), in the source's order.
fn save_selection(
    mut ui: ResMut<UiState>,
    scene: Res<ActiveScene>,
    cache: Res<fascicle_scene::cache::DataCache>,
    sets: Query<(&TractSet, &TractSelection, &LayerEntity)>,
) {
    let Some(layer) = ui.save_selection.take() else { return };
    let path = PathBuf::from(ui.selection_path.trim());
    let mut layer_sets: Vec<_> = sets.iter().filter(|(_, _, le)| le.0 == layer).collect();
    layer_sets.sort_by_key(|(set, ..)| set.first);
    let selected = match &layer_sets[..] {
        [] => match scene.0.layers.get(layer).map(|l| &l.kind) {
            Some(LayerKind::Tracts { source, rois, ends_only, .. }) => {
                fascicle_scene::jobs::tract_data(&cache, source, &Default::default()).map(|d| {
                    let t = &d.tractogram;
                    let mut keep = vec![true; t.n_streamlines()];
                    fascicle_core::roi::Criteria::from_rois(rois, *ends_only).narrow(t, &mut keep);
                    (t.subset(&keep), t.n_streamlines())
                })
            }
            _ => Err(format!("layer {layer} is not a tract layer")),
        },
        [(set, selection, _)] => Ok((selected_tractogram(set, selection), set.tractogram.n_streamlines())),
        parts => {
            let mut all = fascicle_core::io::Tractogram::new();
            for (set, selection, _) in parts {
                for s in (0..set.tractogram.n_streamlines()).filter(|s| selection.0.get(*s) == Some(&true)) {
                    all.push(set.tractogram.streamline(s));
                }
            }
            Ok((all, parts.iter().map(|(set, ..)| set.tractogram.n_streamlines()).sum()))
        }
    };
    ui.message = Some(match selected {
        Ok((t, total)) => match crate::cli::select::write(&path, &t, None) {
            Ok(()) => format!("saved {} of {total} streamlines to {}", t.n_streamlines(), path.display()),
            Err(e) => format!("saving the selection: {e}"),
        },
        Err(e) => format!("saving the selection: {e}"),
    });
}

#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters")]
fn panel(
    mut contexts: EguiContexts,
    mut scene: ResMut<ActiveScene>,
    states: Query<(&LayerEntity, &LayerStatus, Option<&LayerJob>), With<SceneLayer>>,
    mut retries: ResMut<RetryLayers>,
    panels: Res<LayerPanels>,
    layer_data: Res<fascicle_scene::layers::LayerDataMap>,
    mut ui_state: ResMut<UiState>,
    mut orbit: ResMut<Orbit>,
    time: Res<Time>,
    (mut region, crosshair): (ResMut<ViewRegion>, Res<Crosshair>),
    window: Single<&Window, With<PrimaryWindow>>,
    (history, recent): (Res<SceneHistory>, Res<RecentFiles>),
    (draw, next_frame, budget, roi_stats): (Res<DrawOnDemand>, Res<NextFrame>, Res<BudgetState>, Res<RoiStats>),
) -> Result {
    let ctx = contexts.ctx_mut()?;
    trace!("egui repaint causes: {:?}; events {:?}", ctx.repaint_causes(), ctx.input(|i| i.events.clone()));
    // Frames drawn back to back measure what a frame costs; the time since an idle or polling frame does not.
    if *next_frame == NextFrame::Now || !draw.enabled {
        let dt = time.delta_secs() * 1000.0;
        ui_state.frame_ms = if ui_state.frame_ms == 0.0 { dt } else { 0.95 * ui_state.frame_ms + 0.05 * dt };
    }
    let mut edited = scene.0.clone();
    let mut viewport_ui = egui::Ui::new(
        ctx.clone(),
        "viewport".into(),
        egui::UiBuilder::new().layer_id(egui::LayerId::background()).max_rect(ctx.viewport_rect()),
    );
    let panel_width = egui::Panel::left("layers").resizable(true).show(&mut viewport_ui, |ui| {
        ui.heading("Fascicle");
        let drawing = match (draw.enabled, *next_frame) {
            (false, _) => "every frame",
            (true, NextFrame::Poll) => "while working",
            (true, _) => "on demand",
        };
        if roi_stats.pending_layers > 0 {
            ui.label("ROIs: selecting in the background (the layer's index is being built)").on_hover_text(
                "until its index is built, a whole-brain layer's ROI edits are selected on a thread of their own; \
                 the streamlines shown follow when that selection is done",
            );
        }
        let quality = if budget.coarse { ", coarse" } else { "" };
        ui.label(format!("frame {:.1} ms, scale {:.2}{quality}, drawn {drawing}", ui_state.frame_ms, budget.scale))
            .on_hover_text(format!(
                "the cost of a frame drawn back to back; an idle window draws nothing. While the view moves the \
                 3D view draws at the scale (of its side) that holds the frame budget, {} ms, and \"coarse\" when \
                 the smallest scale is still over it (previews of tracts, a coarser volume step); at full \
                 quality once still",
                budget.budget.as_millis()
            ));
        ui.separator();
        ui.heading("Layers");
        let mut remove = None;
        let mut added = Vec::new();
        // The layer list scrolls; scene controls and messages stay visible below it.
        let list_height = (ui.available_height() - 220.0).max(120.0);
        egui::ScrollArea::vertical().max_height(list_height).show(ui, |ui| {
            for (i, layer) in edited.layers.iter_mut().enumerate() {
                ui.horizontal(|ui| {
                    ui.checkbox(&mut layer.visible, &layer.name);
                    if ui.small_button("x").clicked() {
                        remove = Some(i);
                    }
                });
                if let Some((_, status, job)) = states.iter().find(|(le, ..)| le.0 == i) {
                    layer_status(ui, status, job, || retries.0.push(i));
                }
                ui.add(egui::Slider::new(&mut layer.opacity, 0.0..=1.0).text("opacity"));
                if let Some(p) = panels.find(&layer.kind) {
                    let data = layer_data.0.get(&i).cloned().unwrap_or_default();
                    ui.push_id(i, |ui| (p.show)(ui, &mut layer.kind, &data));
                }
                if let Some(tensors) = tensor_source_of(&layer.kind) {
                    ui.push_id(("derive", i), |ui| {
                        ui.horizontal(|ui| {
                            ui.label("from its tensors:");
                            for (label, kind) in derived_layers(&tensors) {
                                if ui.small_button(label).clicked() {
                                    let name = format!("{label} ({})", layer.name);
                                    added.push(LayerSpec { name, visible: true, opacity: 1.0, kind });
                                }
                            }
                        });
                    });
                }
                if let Some(tracts) = tract_source_of(&layer.kind)
                    && ui.push_id(("density", i), |ui| ui.small_button("track density map")).inner.clicked()
                {
                    let name = format!("density ({})", layer.name);
                    let source = fascicle_scene::model::VolumeSource::Density { tracts, voxel_mm: 1.0 };
                    let kind = LayerKind::Slice { source, axis: fascicle_scene::model::SliceAxis::Z, index: None, window: None };
                    added.push(LayerSpec { name, visible: true, opacity: 1.0, kind });
                }
                if let LayerKind::Tracts { deleted, .. } = &mut layer.kind {
                    ui.push_id(("picked", i), |ui| {
                        ui.horizontal(|ui| {
                            let picked = ui_state.picked.clone().filter(|p| p.layer == i && !p.streamlines.is_empty());
                            match &picked {
                                Some(p) => {
                                    ui.label(format!("{} picked", p.streamlines.len()));
                                    if ui.small_button("delete").clicked() {
                                        *deleted = deleted_after(deleted, p, false);
                                        ui_state.picked = None;
                                    }
                                    if ui.small_button("keep only these").clicked() {
                                        *deleted = deleted_after(deleted, p, true);
                                        ui_state.picked = None;
                                    }
                                    if ui.small_button("unpick").clicked() {
                                        ui_state.picked = None;
                                    }
                                }
                                None => {
                                    ui.label("Ctrl + click or Ctrl + drag (a lasso) picks streamlines");
                                }
                            }
                            if !deleted.is_empty() && ui.small_button(format!("restore {} deleted", deleted.len())).clicked() {
                                deleted.clear();
                            }
                        });
                    });
                }
                if matches!(layer.kind, LayerKind::Tracts { .. }) {
                    ui.push_id(("brush", i), |ui| {
                        ui.horizontal(|ui| {
                            let on = ui_state.brush.as_ref().is_some_and(|b| b.layer == i);
                            let hint = "a left drag in a 2D view paints an include ROI on the top image's slice \
                                        (Shift + drag erases); saved as NIfTI after every stroke";
                            if ui.selectable_label(on, "paint ROI").on_hover_text(hint).clicked() {
                                ui_state.brush = (!on).then(|| Brush { layer: i, name: layer.name.clone(), radius_mm: 3.0 });
                            }
                            if let Some(b) = ui_state.brush.as_mut().filter(|b| b.layer == i) {
                                ui.add(egui::Slider::new(&mut b.radius_mm, 0.5..=20.0).text("brush radius (mm)"));
                            }
                        });
                    });
                    ui.push_id(("selection", i), |ui| {
                        ui.horizontal(|ui| {
                            ui.text_edit_singleline(&mut ui_state.selection_path);
                            if ui.button("Save selection").clicked() {
                                ui_state.save_selection = Some(i);
                            }
                        });
                    });
                }
                ui.separator();
            }
        });
        if let Some(i) = remove {
            edited.layers.remove(i);
        }
        edited.layers.append(&mut added);
        ui.separator();
        ui.horizontal(|ui| {
            if ui.button("Open files…").clicked() {
                ui_state.open_dialog = true;
            }
            if ui.button("Reset view (R)").clicked() {
                *orbit = Orbit::from_spec(&edited.camera);
            }
        });
        ui.horizontal(|ui| {
            if ui.add_enabled(history.can_undo(), egui::Button::new("Undo (Ctrl+Z)")).clicked() {
                ui_state.history_step = Some(true);
            }
            if ui.add_enabled(history.can_redo(), egui::Button::new("Redo (Ctrl+Shift+Z)")).clicked() {
                ui_state.history_step = Some(false);
            }
        });
        ui.collapsing("Views", |ui| {
            ui.checkbox(&mut edited.views.ortho, "orthogonal 2D views");
            ui.checkbox(&mut edited.views.follow, "slices follow the crosshair");
            ui.checkbox(&mut edited.views.colour_bars, "colour bars");
            let mut slab = edited.views.slab_mm.unwrap_or(0.0);
            let r = ui.add(egui::Slider::new(&mut slab, 0.0..=20.0).text("streamline slab (mm; 0: one voxel)"));
            if r.changed() {
                edited.views.slab_mm = (slab > 0.0).then_some(slab);
            }
            let mut c = crosshair.world.to_array();
            let changed = ui
                .horizontal(|ui| {
                    ui.label("crosshair (mm)");
                    // Every field is drawn, whichever changed.
                    c.iter_mut().map(|v| ui.add(egui::DragValue::new(v).speed(0.5)).changed()).collect::<Vec<_>>().contains(&true)
                })
                .inner;
            if changed {
                edited.views.crosshair = Some(c);
            }
            ui.label("2D views: click or drag moves the crosshair, the wheel steps through slices, right-drag sets the top slice's window.");
        });
        if !recent.files.is_empty() {
            ui.collapsing("Recent files", |ui| {
                for f in &recent.files {
                    let name = f.file_name().map_or_else(|| f.display().to_string(), |n| n.to_string_lossy().into());
                    if ui.button(name).on_hover_text(f.display().to_string()).clicked() {
                        ui_state.open_recent = Some(f.clone());
                    }
                }
            });
        }
        ui.horizontal(|ui| {
            ui.text_edit_singleline(&mut ui_state.scene_path);
        });
        ui.horizontal(|ui| {
            if ui.button("Save scene").clicked() {
                let mut s = edited.clone();
                s.camera = orbit.spec();
                ui_state.message = Some(match s.save(std::path::Path::new(&ui_state.scene_path)) {
                    Ok(()) => format!("saved {}", ui_state.scene_path),
                    Err(e) => e,
                });
            }
            if ui.button("Load scene").clicked() {
                match Scene::load(std::path::Path::new(&ui_state.scene_path)) {
                    Ok(s) => {
                        *orbit = Orbit::from_spec(&s.camera);
                        edited = s;
                    }
                    Err(e) => ui_state.message = Some(e),
                }
            }
        });
        if let Some(m) = &ui_state.message {
            ui.label(m);
        }
        ui.label("Open or drop NIfTI, .mif, .trk/.tck/.trx or .ron files on the window.");
        ui.allocate_rect(ui.available_rect_before_wrap(), egui::Sense::hover());
    });
    if let Some((path, choices)) = ui_state.ask.clone() {
        let mut open = true;
        let mut chosen = None;
        egui::Window::new("Open as").collapsible(false).open(&mut open).show(ctx, |ui| {
            ui.label(format!("{}: the content does not tell what it holds.", path.display()));
            for (k, c) in choices.iter().enumerate() {
                if ui.button(kind_label(&c.kind)).clicked() {
                    chosen = Some(k);
                }
            }
        });
        if let Some(k) = chosen {
            edited.layers.push(choices[k].clone());
        }
        if chosen.is_some() || !open {
            ui_state.ask = None;
        }
    }
    // The lasso being drawn (Ctrl + drag), over the views.
    if ui_state.lasso.len() > 1 {
        let line: Vec<egui::Pos2> = ui_state.lasso.iter().map(|p| egui::pos2(p.x, p.y)).collect();
        ctx.layer_painter(egui::LayerId::new(egui::Order::Foreground, egui::Id::new("lasso")))
            .add(egui::Shape::closed_line(line, egui::Stroke::new(1.5, egui::Color32::WHITE)));
    }
    let left = (panel_width.response.rect.width() * window.scale_factor()) as u32;
    if region.left != left {
        region.left = left;
    }
    if edited != scene.0 {
        scene.0 = edited;
    }
    Ok(())
}

/// Whether `path` is a `.mif` whose header holds a `dw_scheme`. The panel asks every frame: the header is
/// read again only when the file's modification time changes.
fn has_dw_scheme(path: &std::path::Path) -> bool {
    type Seen = std::collections::HashMap<PathBuf, (Option<std::time::SystemTime>, bool)>;
    static SEEN: std::sync::Mutex<Option<Seen>> = std::sync::Mutex::new(None);
    if !fascicle_core::io::mif::is_mif(path) {
        return false;
    }
    let modified = std::fs::metadata(path).and_then(|m| m.modified()).ok();
    let mut seen = SEEN.lock().unwrap_or_else(|e| e.into_inner());
    let seen = seen.get_or_insert_with(Default::default);
    if let Some((when, has)) = seen.get(path)
        && *when == modified
    {
        return *has;
    }
    let has = fascicle_core::io::mif::read_dw_scheme(path).is_ok_and(|r| !r.is_empty());
    seen.insert(path.to_path_buf(), (modified, has));
    has
}

/// The tensors a layer shows or holds: a DWI slice's (fitted), a tensor glyph or splat layer's.
fn tensor_source_of(kind: &LayerKind) -> Option<fascicle_scene::model::TensorSource> {
    use fascicle_scene::model::{TensorSource, VolumeSource};
    match kind {
        LayerKind::Slice { source: VolumeSource::Nifti { path, .. }, .. } => {
            (fascicle_core::io::classify::gradients_beside(path).is_some() || has_dw_scheme(path))
                .then(|| TensorSource::Dwi { path: path.clone(), bvecs: Default::default() })
        }
        LayerKind::TensorGlyphs { source, .. } | LayerKind::TensorSplats { source, .. }
            if !matches!(source, TensorSource::Spiral { .. }) =>
        {
            Some(source.clone())
        }
        _ => None,
    }
}

/// The streamlines a layer draws, as a tract source (for its density map).
fn tract_source_of(kind: &LayerKind) -> Option<fascicle_scene::model::TractSource> {
    match kind {
        LayerKind::Tracts { source, .. } => Some(source.clone()),
        LayerKind::Tractogram { path } => {
            Some(fascicle_scene::model::TractSource::File { path: path.clone(), tensors: None })
        }
        _ => None,
    }
}

/// Layers made from a tensor source: glyphs, splats and tracking (whole-field grid seeds).
fn derived_layers(tensors: &fascicle_scene::model::TensorSource) -> Vec<(&'static str, LayerKind)> {
    use fascicle_scene::model::{SliceAxis, TractMode, TractSource};
    vec![
        (
            "glyphs",
            LayerKind::TensorGlyphs {
                source: tensors.clone(),
                axis: SliceAxis::Z,
                index: None,
                spacing: 1,
                size: 0.9,
                min_fa: 0.2,
                render: Default::default(),
            },
        ),
        (
            "splats",
            LayerKind::TensorSplats {
                source: tensors.clone(),
                axis: SliceAxis::Z,
                index: None,
                thickness: 1,
                size: 0.5,
                min_fa: 0.0,
                render: Default::default(),
            },
        ),
        (
            "track",
            LayerKind::Tracts {
                source: TractSource::Track {
                    tensors: tensors.clone(),
                    seeds: Default::default(),
                    params: Default::default(),
                },
                mode: TractMode::Tubes,
                render: Default::default(),
                rois: vec![],
                masks: vec![],
                ends_only: false,
                deleted: vec![],
                colouring: Default::default(),
            },
        ),
    ]
}

/// What the "open as" dialog calls a layer kind.
fn kind_label(kind: &LayerKind) -> &'static str {
    match kind {
        LayerKind::ShGlyphs { .. } => "SH coefficients (ODF glyphs)",
        LayerKind::TensorGlyphs { .. } => "diffusion tensors (glyphs)",
        LayerKind::Tracts { .. } => "peaks (lines)",
        LayerKind::Slice { .. } => "volumes (a slice)",
        _ => "other",
    }
}

/// A layer's job (stage, progress bar, cancel) or its error (with retry).
fn layer_status(ui: &mut egui::Ui, status: &LayerStatus, job: Option<&LayerJob>, retry: impl FnOnce()) {
    if let Some(job) = job {
        let (stage, fraction) = job.progress.snapshot();
        ui.horizontal(|ui| {
            let bar = egui::ProgressBar::new(fraction.unwrap_or(0.0)).text(stage).desired_width(160.0);
            ui.add(bar.animate(fraction.is_none()));
            if ui.small_button("cancel").clicked() {
                job.progress.cancel();
            }
        });
    } else if let LayerStatus::Failed(message) = status {
        ui.horizontal_wrapped(|ui| {
            ui.colored_label(egui::Color32::LIGHT_RED, message);
            if ui.small_button("retry").clicked() {
                retry();
            }
        });
    }
}

/// Tells the retained picture which images are egui's (its font atlas grows as new text appears): their
/// changes are not the scene's.
fn egui_images_outside_picture(
    textures: Res<bevy_egui::EguiManagedTextures>,
    outside: Option<ResMut<fascicle_render::retain::ImagesOutsidePicture>>,
) {
    if let Some(mut outside) = outside
        && textures.is_changed()
    {
        outside.0 = textures.values().map(|t| t.handle.id()).collect();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The brush covers the voxels of the slice whose centres lie within its radius in the view's plane: on a
    /// 1 mm grid a radius of 2 mm about a voxel centre is the 13 lattice points of the disk, in the slice the
    /// point lies in, whichever view; on a permuted, flipped 2 mm grid a radius of 4 mm the same 13; clipped at
    /// the grid's edge; nothing outside the grid.
    #[test]
    fn the_brush_paints_the_voxels_of_a_disk_in_the_slice() {
        let grid = VoxelGrid { world_from_voxel: glam::DMat4::IDENTITY, dims: [20, 20, 20] };
        let at = Vec3::new(10.0, 10.0, 7.2);
        let axial = brush_voxels(&grid, 2, at, 2.0);
        assert_eq!(axial.len(), 13);
        assert!(axial.iter().all(|v| v / 400 == 7), "every voxel in slice z = 7");
        assert!(axial.contains(&(12 + 20 * 10 + 400 * 7)) && !axial.contains(&(12 + 20 * 11 + 400 * 7)));
        assert_eq!(brush_voxels(&grid, 0, Vec3::new(10.3, 10.0, 7.0), 2.0).len(), 13);
        // At a corner of the grid: the quarter disk inside (6 of 13).
        assert_eq!(brush_voxels(&grid, 2, Vec3::new(0.0, 0.0, 3.0), 2.0).len(), 6);
        assert!(brush_voxels(&grid, 2, Vec3::new(0.0, 0.0, 30.0), 2.0).is_empty());
        // Voxel x along world -y, y along z, z along x (2 mm): the axial view cuts voxel axis y.
        let m = glam::DMat4::from_cols(
            glam::DVec4::new(0.0, -2.0, 0.0, 0.0),
            glam::DVec4::new(0.0, 0.0, 2.0, 0.0),
            glam::DVec4::new(2.0, 0.0, 0.0, 0.0),
            glam::DVec4::new(-10.0, 20.0, 0.0, 1.0),
        );
        let grid = VoxelGrid { world_from_voxel: m, dims: [30, 40, 10] };
        let centre = m.transform_point3(glam::DVec3::new(8.0, 6.0, 4.0)).as_vec3();
        let v = brush_voxels(&grid, 2, centre, 4.0);
        assert_eq!(v.len(), 13);
        assert!(v.iter().all(|&i| (i as usize / 30) % 40 == 6), "every voxel in voxel slice y = 6");
    }

    /// "Delete" adds the picked to the deleted; "keep only these" deletes every other streamline; both keep
    /// what was deleted before, sorted, once each.
    #[test]
    fn picked_streamlines_are_deleted_or_kept() {
        let picked = Picked { layer: 0, n_streamlines: 6, streamlines: [1, 4].into_iter().collect() };
        assert_eq!(deleted_after(&[4, 5], &picked, false), vec![1, 4, 5]);
        assert_eq!(deleted_after(&[4, 5], &picked, true), vec![0, 2, 3, 4, 5]);
        assert_eq!(deleted_after(&[], &picked, true), vec![0, 2, 3, 5]);
    }

    /// Dropping files: a good one becomes a layer, a bad one an error message; the app keeps running and the
    /// scene keeps what it had.
    #[test]
    fn screenshots_are_named_by_time_and_never_overwrite() {
        // 2026-11-23 21:42:27 UTC.
        let t = 1_795_470_147;
        assert_eq!(super::screenshot_path(t, |_| false), PathBuf::from("fascicle-20261123-214227.png"));
        let taken = [PathBuf::from("fascicle-20261123-214227.png"), PathBuf::from("fascicle-20261123-214227-2.png")];
        assert_eq!(
            super::screenshot_path(t, |p| taken.iter().any(|x| x == p)),
            PathBuf::from("fascicle-20261123-214227-3.png")
        );
        assert_eq!(super::screenshot_path(0, |_| false), PathBuf::from("fascicle-19700101-000000.png"));
        // A leap day.
        assert_eq!(super::screenshot_path(951_782_400, |_| false), PathBuf::from("fascicle-20000229-000000.png"));
    }

    #[test]
    fn dropped_files_add_layers_or_report_errors() {
        let mut app = App::new();
        app.add_plugins(MinimalPlugins)
            .add_message::<FileDragAndDrop>()
            .insert_resource(ActiveScene(Scene::default_scene()))
            .insert_resource(UiState::default())
            .init_resource::<RecentFiles>()
            .insert_resource(Orbit::from_spec(&CameraSpec::default()))
            .add_systems(Update, dropped_files);
        let before = app.world().resource::<ActiveScene>().0.layers.len();
        let data = crate::repo_path("data");
        let window = Entity::PLACEHOLDER;
        app.world_mut()
            .write_message(FileDragAndDrop::DroppedFile { window, path_buf: data.join("tracts/tracks300.trk") });
        app.world_mut()
            .write_message(FileDragAndDrop::DroppedFile { window, path_buf: data.join("no/such/file.nii.gz") });
        app.update();
        let scene = &app.world().resource::<ActiveScene>().0;
        assert_eq!(scene.layers.len(), before + 1);
        assert!(
            matches!(&scene.layers[before].kind, LayerKind::Tractogram { path } if path.ends_with("tracks300.trk"))
        );
        let msg = app.world().resource::<UiState>().message.clone().unwrap_or_default();
        assert!(msg.contains("file.nii.gz"), "{msg}");
        // The camera frames the new streamlines (bounds as `fascicle info` prints them): their centre, with the
        // whole bounding sphere in view.
        let (lo, hi) = (glam::DVec3::new(64.02, 78.36, 61.47), glam::DVec3::new(115.56, 121.13, 91.91));
        let cam = scene.camera;
        let target = glam::Vec3::from(cam.target).as_dvec3();
        assert!((target - (lo + hi) / 2.0).length() < 0.05, "target {target}");
        let distance = (glam::Vec3::from(cam.eye).as_dvec3() - target).length();
        assert!(distance * (cam.fov_y_deg as f64 / 2.0).to_radians().sin() >= (hi - lo).length() / 2.0);
        assert_eq!(*app.world().resource::<Orbit>(), Orbit::from_spec(&cam), "the view follows");
        app.update(); // still running
        // An SH coefficient image becomes a glyph layer (func_coef: 45 coefficients, l_max 8).
        let sh = data.join("sh/func_coef.nii.gz");
        app.world_mut().write_message(FileDragAndDrop::DroppedFile { window, path_buf: sh });
        app.update();
        let scene = &app.world().resource::<ActiveScene>().0;
        assert!(matches!(scene.layers.last().map(|l| &l.kind), Some(LayerKind::ShGlyphs { .. })));
        // Opened files are the recent ones, newest first; the missing one is not.
        let recent = &app.world().resource::<RecentFiles>().files;
        assert!(
            recent.len() == 2 && recent[0].ends_with("sh/func_coef.nii.gz") && recent[1].ends_with("tracks300.trk"),
            "{recent:?}"
        );
    }

    /// A click in a 2D view picks through the set's index what the brute force picks: tracks300 seen along z
    /// through a 4 mm slab at 3 pixels a mm, clicks near points of its streamlines and at random, some
    /// streamlines hidden; and with the index not built yet (brute force, the index started).
    #[test]
    fn a_click_in_a_slab_picks_through_the_index_as_brute_force() {
        use fascicle_core::io::Tractogram;
        use std::sync::Arc;
        let t = Arc::new(Tractogram::read(crate::repo_path("data/tracts/tracks300.trk")).unwrap());
        let set = TractSet {
            tractogram: fascicle_tracts::SetStreamlines::Owned(t.clone()),
            index: fascicle_tracts::LazyIndex::default(),
            selected: Handle::default(),
            first: 0,
        };
        let z0 = t.streamline(0)[t.streamline(0).len() / 2].z;
        let slab =
            fascicle_tracts::TractSlab { set: Entity::PLACEHOLDER, normal: Vec3::Z, offset: z0, half_thickness: 2.0 };
        let (k, origin) = (3.0, Vec2::new(-100.0, 500.0));
        let project = |p: Vec3| ((p.z - z0).abs() <= 2.0).then(|| origin + Vec2::new(p.x, -p.y) * k);
        let brute = |shown: &(dyn Fn(usize) -> bool + Sync), at| {
            fascicle_core::roi::pick_projected(&t, shown, project, at, 4.0)
        };
        let near = |at| click_box(project, at, 4.0, &slab, 2).expect("the slab's plane is seen");
        // Not built yet: every streamline tested.
        let at = project(t.streamline(0)[t.streamline(0).len() / 2]).unwrap();
        assert_eq!(pick_in_slab(&set, |_| true, project, at, 4.0, Some(&near(at))), brute(&|_| true, at));
        set.index.get(&t);
        let mut rng = 7u64;
        let mut next = || {
            rng = rng.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (rng >> 33) as f32 / (1u64 << 31) as f32
        };
        let mut hits = 0;
        for i in 0..200usize {
            let s = (next() * t.n_streamlines() as f32) as usize % t.n_streamlines();
            let pts = t.streamline(s);
            let p = pts[(next() * pts.len() as f32) as usize % pts.len()];
            let at = origin + Vec2::new(p.x, -p.y) * k + Vec2::new(next() - 0.5, next() - 0.5) * 12.0;
            let shown = |s: usize| !i.is_multiple_of(3) || s.is_multiple_of(2);
            let want = brute(&shown, at);
            assert_eq!(pick_in_slab(&set, shown, project, at, 4.0, Some(&near(at))), want, "click {i} at {at}");
            hits += usize::from(want.is_some());
        }
        assert!(hits > 40, "{hits} of 200 clicks pick");
    }

    /// "Save selection" writes what the ROIs select: from a tract set's own selection flags (a layer in parts:
    /// the parts' flags, in the layer's order), or, for a layer without a set (here none is spawned), by
    /// selecting again from the source. A bad path is a message, not a panic.
    #[test]
    fn save_selection_writes_the_selected_streamlines() {
        use fascicle_core::io::Tractogram;
        use fascicle_core::roi::{Roi, RoiMode, RoiShape, SegmentGrid, select};
        use std::sync::Arc;
        let trk = crate::repo_path("data/tracts/tracks300.trk");
        let t = Tractogram::read(&trk).unwrap();
        let tmp_dir = tempfile::Builder::new().prefix("fascicle-save-selection-").tempdir().unwrap();
        let dir = tmp_dir.path().to_path_buf();
        // An include sphere around the middle point of streamline 0.
        let p = t.streamline(0)[t.streamline(0).len() / 2];
        let rois = vec![Roi { shape: RoiShape::Sphere { centre: p.to_array(), radius: 5.0 }, mode: RoiMode::Include }];
        let layer = LayerSpec {
            name: "tracts".into(),
            visible: true,
            opacity: 1.0,
            kind: LayerKind::Tracts {
                source: fascicle_scene::model::TractSource::File { path: trk.clone(), tensors: None },
                mode: fascicle_scene::model::TractMode::Lines,
                render: Default::default(),
                rois: rois.clone(),
                masks: vec![],
                ends_only: false,
                deleted: vec![],
                colouring: Default::default(),
            },
        };
        let mut app = App::new();
        app.add_plugins(MinimalPlugins)
            .insert_resource(ActiveScene(Scene {
                layers: vec![layer],
                camera: CameraSpec::default(),
                views: Default::default(),
            }))
            .insert_resource(UiState::default())
            .init_resource::<fascicle_scene::cache::DataCache>()
            .add_systems(Update, save_selection);
        let save = |app: &mut App, layer: usize, path: &std::path::Path| {
            let mut ui = app.world_mut().resource_mut::<UiState>();
            ui.selection_path = path.display().to_string();
            ui.save_selection = Some(layer);
            app.update();
            app.world().resource::<UiState>().message.clone().unwrap_or_default()
        };

        // No set: selected again from the file.
        let out = dir.join("lines.tck");
        let msg = save(&mut app, 0, &out);
        let grid = SegmentGrid::new(&t.points, &t.offsets, 4.0);
        let keep = select(&t.points, &t.offsets, &grid, &rois);
        let n = keep.iter().filter(|k| **k).count();
        assert!(n > 0 && n < t.n_streamlines(), "{n}");
        assert!(msg.starts_with(&format!("saved {n} of {}", t.n_streamlines())), "{msg}");
        let back = Tractogram::read(&out).unwrap();
        let kept: Vec<usize> = (0..t.n_streamlines()).filter(|s| keep[*s]).collect();
        assert_eq!(back.n_streamlines(), n);
        for (k, s) in kept.iter().enumerate() {
            assert_eq!(back.streamline(k), t.streamline(*s), "streamline {s}");
        }

        // A tract set: its flags are what is saved (every third streamline here).
        let flags: Vec<bool> = (0..t.n_streamlines()).map(|s| s % 3 == 0).collect();
        let set = TractSet {
            tractogram: fascicle_tracts::SetStreamlines::Owned(Arc::new(t.clone())),
            index: fascicle_tracts::LazyIndex::default(),
            selected: Handle::default(),
            first: 0,
        };
        app.world_mut().spawn((set, TractSelection(flags.clone()), LayerEntity(0)));
        let out = dir.join("set.trk");
        let msg = save(&mut app, 0, &out);
        let back = Tractogram::read(&out).unwrap();
        assert_eq!(back.n_streamlines(), t.n_streamlines().div_ceil(3), "{msg}");
        for (k, s) in (0..t.n_streamlines()).step_by(3).enumerate() {
            for (a, b) in back.streamline(k).iter().zip(t.streamline(s)) {
                assert!((*a - *b).abs().max_element() < 1e-3, "streamline {s}: {a} vs {b}");
            }
        }

        // A layer in parts (spawned out of order): each part's flags, the parts in the layer's order.
        let half = t.n_streamlines() / 2;
        let part = |range: std::ops::Range<usize>| {
            Arc::new(t.subset(&(0..t.n_streamlines()).map(|i| range.contains(&i)).collect::<Vec<_>>()))
        };
        for (range, first) in [(half..t.n_streamlines(), half), (0..half, 0)] {
            let set = TractSet {
                tractogram: fascicle_tracts::SetStreamlines::Owned(part(range.clone())),
                index: fascicle_tracts::LazyIndex::default(),
                selected: Handle::default(),
                first,
            };
            let flags = range.map(|s| s % 3 == 0).collect();
            app.world_mut().spawn((set, TractSelection(flags), LayerEntity(1)));
        }
        let msg = save(&mut app, 1, &dir.join("parts.tck"));
        let back = Tractogram::read(dir.join("parts.tck")).unwrap();
        assert!(msg.starts_with(&format!("saved {} of {}", back.n_streamlines(), t.n_streamlines())), "{msg}");
        assert_eq!(back.n_streamlines(), t.n_streamlines().div_ceil(3));
        for (k, s) in (0..t.n_streamlines()).step_by(3).enumerate() {
            for (a, b) in back.streamline(k).iter().zip(t.streamline(s)) {
                assert!((*a - *b).abs().max_element() < 1e-3, "streamline {s}: {a} vs {b}");
            }
        }

        // Bad requests: an unknown extension, a layer that is not a tract layer.
        let msg = save(&mut app, 0, &dir.join("selection.txt"));
        assert!(msg.contains("unknown extension 'txt'"), "{msg}");
        let msg = save(&mut app, 7, &out);
        assert!(msg.contains("layer 7 is not a tract layer"), "{msg}");
        app.update(); // still running
    }
}
