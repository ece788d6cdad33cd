//! Handles in the 3D view, on the scene's layers: Shift + left-drag on a tract layer's ROI, on a tracking
//! layer's seed sphere or on a free ODF glyph plane's handles moves it in the plane facing the camera (the
//! plane's normal handle tilts it; a box ROI's two corner handles resize it, a sphere ROI's radius handle
//! scales it), editing the [`ActiveScene`]: an ROI re-selects, a seed sphere tracks again from its new seeds,
//! a plane places its glyphs again. [`HandlesPlugin`] adds the drag (in [`HandleSystems`],
//! which an app may run only when the pointer is its own) and draws the seed spheres and glyph planes as gizmos
//! (ROIs are drawn by the tracts plugin).

use bevy::prelude::*;
use bevy::window::PrimaryWindow;
use fascicle_core::roi::RoiShape;
use fascicle_views::MainView;

use crate::layers::{ActiveScene, SceneSystems};
use crate::model::{LayerKind, Scene, Seeds, TractSource};

/// The handle drag of [`HandlesPlugin`], in `Update` before the scene's layers sync.
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub struct HandleSystems;

/// Drags ROIs, seed spheres and glyph planes with Shift + left-drag in the view of the [`MainView`] camera, and
/// draws the seed spheres and planes.
pub struct HandlesPlugin;

impl Plugin for HandlesPlugin {
    fn build(&self, app: &mut App) {
        app.init_resource::<RoiDrag>()
            .configure_sets(Update, HandleSystems.before(SceneSystems::Sync))
            .add_systems(Update, drag_roi.in_set(HandleSystems))
            .add_systems(Update, draw_handles.run_if(resource_exists::<bevy::gizmos::config::GizmoConfigStore>));
    }
}

/// What a Shift + left-drag can hold: one of a tract layer's ROIs, the sphere its tracking is seeded from, or
/// the free plane of an ODF glyph layer (its centre handle moves it, its normal handle tilts it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Grip {
    /// A tract layer's ROI, by its index in the layer's list.
    Roi(usize),
    /// A corner handle of a tract layer's box ROI (by its index): 0 the corner of least coordinates, 1 the
    /// greatest. A drag moves that corner; the box keeps at least [`MIN_BOX_SIDE`] a side.
    RoiCorner(usize, usize),
    /// The radius handle of a tract layer's sphere ROI (by its index), on the sphere at +x of its centre: a
    /// drag sets the radius to the handle's distance from the centre (at least [`MIN_BOX_SIDE`]).
    RoiRadius(usize),
    /// A tracking layer's seed sphere.
    Seeds,
    /// A free glyph plane's centre: a drag moves the plane.
    PlaneCentre,
    /// The tip of a free glyph plane's normal: a drag tilts the plane.
    PlaneNormal,
}

/// The glyph plane's two handles: the centre and the tip of the normal, half the plane's half size out.
pub fn plane_handles(p: &fascicle_core::sh::glyph::GlyphPlane) -> [(Grip, RoiShape); 2] {
    let c = glam::DVec3::from(p.centre);
    let n = glam::DVec3::from(p.normal).normalize_or(glam::DVec3::Z);
    let radius = (p.half_size * 0.06).max(1.0) as f32;
    let tip = c + n * (0.5 * p.half_size);
    [
        (Grip::PlaneCentre, RoiShape::Sphere { centre: c.as_vec3().to_array(), radius }),
        (Grip::PlaneNormal, RoiShape::Sphere { centre: tip.as_vec3().to_array(), radius }),
    ]
}

/// The least side of a box ROI, and the least radius of a sphere ROI, that their handles leave (mm): 0.5.
pub const MIN_BOX_SIDE: f32 = 0.5;

/// The resize handles of an ROI (by its index `k`): a box's two corners, a sphere's point at +x; small
/// spheres (a twentieth of the box's diagonal or a sixth of the radius, at least 1 mm).
pub fn roi_handles(k: usize, shape: &RoiShape) -> Vec<(Grip, RoiShape)> {
    match *shape {
        RoiShape::Box { min, max } => {
            let radius = ((Vec3::from(max) - Vec3::from(min)).length() / 20.0).max(1.0);
            vec![
                (Grip::RoiCorner(k, 0), RoiShape::Sphere { centre: min, radius }),
                (Grip::RoiCorner(k, 1), RoiShape::Sphere { centre: max, radius }),
            ]
        }
        RoiShape::Sphere { centre, radius } => {
            let at = (Vec3::from(centre) + Vec3::X * radius).to_array();
            vec![(Grip::RoiRadius(k), RoiShape::Sphere { centre: at, radius: (radius / 6.0).max(1.0) })]
        }
        RoiShape::Plane { .. } => vec![],
    }
}

/// Whether a grip is a resize handle (picked before the shapes, which they sit on).
fn is_handle(grip: Grip) -> bool {
    matches!(grip, Grip::RoiCorner(..) | Grip::RoiRadius(_) | Grip::PlaneCentre | Grip::PlaneNormal)
}

/// The shapes a layer offers to a drag.
pub fn grips(kind: &LayerKind) -> Vec<(Grip, RoiShape)> {
    match kind {
        LayerKind::Tracts { rois, source, .. } => {
            let mut out: Vec<(Grip, RoiShape)> =
                rois.iter().enumerate().map(|(k, r)| (Grip::Roi(k), r.shape)).collect();
            out.extend(rois.iter().enumerate().flat_map(|(k, r)| roi_handles(k, &r.shape)));
            if let TractSource::Track { seeds: Seeds::Sphere { centre, radius, .. }, .. } = source {
                out.push((Grip::Seeds, RoiShape::Sphere { centre: *centre, radius: *radius }));
            }
            out
        }
        LayerKind::ShGlyphs { plane: Some(p), full_volume: false, .. } => plane_handles(p).to_vec(),
        _ => vec![],
    }
}

/// Moves the gripped shape of a layer to `shape` (a plane handle: the plane's centre moves with it, or its
/// normal turns towards it); false when the layer has no such grip.
pub fn set_grip(kind: &mut LayerKind, grip: Grip, shape: RoiShape) -> bool {
    if let LayerKind::ShGlyphs { plane: Some(p), full_volume: false, .. } = kind {
        let RoiShape::Sphere { centre: c, .. } = shape else { return false };
        let c = glam::Vec3::from(c).as_dvec3();
        match grip {
            Grip::PlaneCentre => p.centre = c.to_array(),
            Grip::PlaneNormal => {
                let n = (c - glam::DVec3::from(p.centre)).normalize_or_zero();
                if n == glam::DVec3::ZERO {
                    return false;
                }
                p.normal = n.to_array();
            }
            _ => return false,
        }
        return true;
    }
    let LayerKind::Tracts { rois, source, .. } = kind else { return false };
    match (grip, source, shape) {
        (Grip::Roi(k), _, _) => rois.get_mut(k).map(|r| r.shape = shape).is_some(),
        (Grip::RoiCorner(k, corner), _, RoiShape::Sphere { centre: p, .. }) => {
            let Some(RoiShape::Box { min, max }) = rois.get_mut(k).map(|r| &mut r.shape) else { return false };
            let (p, lo, hi) = (Vec3::from(p), Vec3::from(*min), Vec3::from(*max));
            if corner == 0 {
                *min = p.min(hi - MIN_BOX_SIDE).to_array();
            } else {
                *max = p.max(lo + MIN_BOX_SIDE).to_array();
            }
            true
        }
        (Grip::RoiRadius(k), _, RoiShape::Sphere { centre: p, .. }) => {
            let Some(RoiShape::Sphere { centre, radius }) = rois.get_mut(k).map(|r| &mut r.shape) else {
                return false;
            };
            *radius = (Vec3::from(p) - Vec3::from(*centre)).length().max(MIN_BOX_SIDE);
            true
        }
        (
            Grip::Seeds,
            TractSource::Track { seeds: Seeds::Sphere { centre, radius, .. }, .. },
            RoiShape::Sphere { centre: c, radius: r },
        ) => {
            (*centre, *radius) = (c, r);
            true
        }
        _ => false,
    }
}

/// A shape held by a Shift + left-drag: which one, where the cursor ray first met it, the view direction
/// then, and its shape then. The drag moves it in the plane through that point facing the camera.
#[derive(Clone, Copy, Debug)]
pub struct RoiGrab {
    /// The layer's index in the scene.
    pub layer: usize,
    /// What of the layer is held.
    pub grip: Grip,
    /// Where the cursor ray first met the shape (world mm).
    pub hit: Vec3,
    /// The view direction at the grab: the normal of the plane the drag moves in.
    pub normal: Vec3,
    /// The shape when it was grabbed.
    pub shape: RoiShape,
}

/// The shape a drag holds now, if any (the viewer's orbit waits while one is held).
#[derive(Resource, Default, Debug)]
pub struct RoiDrag(pub Option<RoiGrab>);

/// The ROI or seed sphere of a visible tract layer that a ray meets first: (layer, what, distance). Resize
/// handles, which sit on their shapes, come before any shape.
pub fn pick_roi(scene: &Scene, o: Vec3, d: Vec3) -> Option<(usize, Grip, f32)> {
    scene
        .layers
        .iter()
        .enumerate()
        .filter(|(_, l)| l.visible)
        .flat_map(|(i, l)| grips(&l.kind).into_iter().filter_map(move |(g, s)| s.ray_hit(o, d).map(|t| (i, g, t))))
        .min_by(|a, b| is_handle(b.1).cmp(&is_handle(a.1)).then(a.2.total_cmp(&b.2)))
}

/// The grabbed shape moved by where the cursor ray (`o`, `d`) meets the grab plane; None when the ray runs
/// along the plane or meets it behind the camera.
pub fn dragged_shape(g: &RoiGrab, o: Vec3, d: Vec3) -> Option<RoiShape> {
    let denom = d.dot(g.normal);
    if denom.abs() < 1e-6 {
        return None;
    }
    let t = (g.hit - o).dot(g.normal) / denom;
    (t > 0.0).then(|| g.shape.translated(o + d * t - g.hit))
}

/// Shift + left-drag on an ROI's outline moves it (in the plane facing the camera): the tracts re-select as
/// it moves. On a seed sphere it moves the seeds: the layer tracks again, only from the seeds that are new.
/// Writes the scene only when the shape actually moved.
pub fn drag_roi(
    buttons: Res<ButtonInput<MouseButton>>,
    keys: Res<ButtonInput<KeyCode>>,
    window: Single<&Window, With<PrimaryWindow>>,
    camera: Single<(&Camera, &GlobalTransform), With<MainView>>,
    mut drag: ResMut<RoiDrag>,
    mut scene: ResMut<ActiveScene>,
    interacting: Option<ResMut<fascicle_render::budget::Interacting>>,
) {
    if !buttons.pressed(MouseButton::Left) {
        // A drag that ends refines the view at once (the frame budget's still time is for wheel turns).
        if drag.0.take().is_some()
            && let Some(mut interacting) = interacting
        {
            interacting.release();
        }
        return;
    }
    let Some(ray) = window.cursor_position().and_then(|at| fascicle_views::cursor_ray(camera.0, camera.1, at)) else {
        return;
    };
    let (o, d) = (ray.origin, ray.direction.as_vec3());
    if buttons.just_pressed(MouseButton::Left) && keys.any_pressed([KeyCode::ShiftLeft, KeyCode::ShiftRight]) {
        drag.0 = pick_roi(&scene.0, o, d).and_then(|(layer, grip, t)| {
            let shape = grips(&scene.0.layers[layer].kind).into_iter().find(|(g, _)| *g == grip)?.1;
            Some(RoiGrab { layer, grip, hit: o + d * t, normal: camera.1.forward().as_vec3(), shape })
        });
    }
    let Some(g) = drag.0 else { return };
    let current = scene.0.layers.get(g.layer).and_then(|l| grips(&l.kind).into_iter().find(|(k, _)| *k == g.grip));
    let moved = match (dragged_shape(&g, o, d), current) {
        (Some(shape), Some((_, c))) if c != shape => {
            set_grip(&mut scene.0.layers[g.layer].kind, g.grip, shape);
            true
        }
        _ => false,
    };
    // A drag is an interaction for the frame budget (it moves no camera); held still, it asks for no frame.
    if let Some(mut interacting) = interacting {
        if moved { interacting.mark() } else { interacting.hold() }
    }
}

/// Outlines the seed spheres of visible tracking layers (yellow; ROIs are drawn by the tracts plugin), the ROIs'
/// resize handles (white) and the free planes of glyph layers (cyan: the plane's square, its normal and the two
/// handles).
pub fn draw_handles(mut gizmos: Gizmos, scene: Res<ActiveScene>) {
    for l in scene.0.layers.iter().filter(|l| l.visible) {
        if let LayerKind::ShGlyphs { plane: Some(p), full_volume: false, .. } = &l.kind {
            let colour = Color::linear_rgb(0.1, 0.85, 1.0);
            let c = glam::DVec3::from(p.centre).as_vec3();
            let n = glam::DVec3::from(p.normal).normalize_or(glam::DVec3::Z).as_vec3();
            let (u, v) = n.any_orthonormal_pair();
            let h = p.half_size as f32;
            let corners = [c + (u + v) * h, c + (u - v) * h, c - (u + v) * h, c - (u - v) * h];
            for k in 0..4 {
                gizmos.line(corners[k], corners[(k + 1) % 4], colour);
            }
            let handles = plane_handles(p);
            if let RoiShape::Sphere { centre: tip, .. } = handles[1].1 {
                gizmos.line(c, Vec3::from(tip), colour);
            }
            for (_, shape) in handles {
                if let RoiShape::Sphere { centre, radius } = shape {
                    gizmos.sphere(Isometry3d::from_translation(Vec3::from(centre)), radius, colour);
                }
            }
        }
        for (grip, shape) in grips(&l.kind) {
            let colour = match grip {
                Grip::Seeds => Color::linear_rgb(1.0, 0.85, 0.1),
                // ROI resize handles: white.
                Grip::RoiCorner(..) | Grip::RoiRadius(_) => Color::WHITE,
                _ => continue,
            };
            if let RoiShape::Sphere { centre, radius } = shape {
                gizmos.sphere(Isometry3d::from_translation(Vec3::from(centre)), radius, colour);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{CameraSpec, LayerSpec};

    /// Picking and dragging ROIs: the first ROI along the ray among visible tract layers; a drag moves it by
    /// the cursor's displacement in the plane facing the camera through the grab point.
    #[test]
    fn rois_are_picked_front_first_and_dragged_in_the_view_plane() {
        use fascicle_core::roi::{Roi, RoiMode};
        let tracts = |visible: bool, rois: Vec<RoiShape>| LayerSpec {
            name: "tracts".into(),
            visible,
            opacity: 1.0,
            kind: LayerKind::Tracts {
                source: crate::model::TractSource::PhantomRk4 { seed_spacing: 4 },
                mode: crate::model::TractMode::Tubes,
                render: Default::default(),
                rois: rois.into_iter().map(|shape| Roi { shape, mode: RoiMode::Include }).collect(),
                masks: vec![],
                ends_only: false,
                deleted: vec![],
                colouring: Default::default(),
            },
        };
        let near = RoiShape::Sphere { centre: [0.0, 0.0, 10.0], radius: 2.0 };
        let far = RoiShape::Box { min: [-3.0, -3.0, -3.0], max: [3.0, 3.0, 3.0] };
        let hidden = RoiShape::Sphere { centre: [0.0, 0.0, 20.0], radius: 2.0 };
        let scene = Scene {
            layers: vec![tracts(true, vec![far, near]), tracts(false, vec![hidden])],
            camera: CameraSpec::default(),
            views: Default::default(),
        };
        // Looking down -z from z = 40: the hidden layer's sphere is first along the ray but not pickable.
        let (o, d) = (Vec3::new(0.0, 0.0, 40.0), -Vec3::Z);
        assert_eq!(pick_roi(&scene, o, d), Some((0, Grip::Roi(1), 28.0)));
        assert_eq!(pick_roi(&scene, Vec3::new(2.0, -2.0, 40.0), d), Some((0, Grip::Roi(0), 37.0)));
        assert_eq!(pick_roi(&scene, Vec3::new(10.0, 0.0, 40.0), d), None);

        // Grab the sphere at its top (z = 12) and drag the cursor: a ray from the eye through a point 3 mm
        // to the right and 1 mm up in the grab plane moves the centre by exactly that.
        let g = RoiGrab { layer: 0, grip: Grip::Roi(1), hit: o + d * 28.0, normal: d, shape: near };
        let eye = Vec3::new(0.0, 0.0, 40.0);
        let target = Vec3::new(3.0, 1.0, 12.0);
        let moved = dragged_shape(&g, eye, (target - eye).normalize()).unwrap();
        let RoiShape::Sphere { centre, radius } = moved else { panic!("{moved:?}") };
        assert!((Vec3::from(centre) - Vec3::new(3.0, 1.0, 10.0)).length() < 1e-5 && radius == 2.0, "{centre:?}");
        // A ray along the plane does not move it.
        assert_eq!(dragged_shape(&g, eye, Vec3::X), None);
    }

    /// Resize handles: a box's corner handle is picked before the box it sits on and moves that corner only
    /// (never past the other one); a sphere's radius handle sets the radius to its distance from the centre.
    #[test]
    fn box_corners_and_sphere_radii_are_dragged_by_their_handles() {
        use fascicle_core::roi::{Roi, RoiMode};
        let roi = |shape| Roi { shape, mode: RoiMode::Include };
        let boxed = RoiShape::Box { min: [-10.0, -10.0, -10.0], max: [10.0, 10.0, 10.0] };
        let sphere = RoiShape::Sphere { centre: [40.0, 0.0, 0.0], radius: 6.0 };
        let mut scene = Scene {
            layers: vec![LayerSpec {
                name: "tracts".into(),
                visible: true,
                opacity: 1.0,
                kind: LayerKind::Tracts {
                    source: crate::model::TractSource::PhantomRk4 { seed_spacing: 4 },
                    mode: crate::model::TractMode::Lines,
                    render: Default::default(),
                    rois: vec![roi(boxed), roi(sphere)],
                    masks: vec![],
                    ends_only: false,
                    deleted: vec![],
                    colouring: Default::default(),
                },
            }],
            camera: CameraSpec::default(),
            views: Default::default(),
        };
        let d = -Vec3::Z;
        // Down onto the max corner (10, 10, 10): its handle (radius 1.73 mm), not the box's top face.
        let (layer, grip, t) = pick_roi(&scene, Vec3::new(10.0, 10.0, 40.0), d).unwrap();
        assert_eq!((layer, grip), (0, Grip::RoiCorner(0, 1)));
        assert!((t - (30.0 - 3f32.sqrt())).abs() < 1e-3, "{t}");
        // Elsewhere on the top face: the box itself.
        assert_eq!(pick_roi(&scene, Vec3::new(0.0, 0.0, 40.0), d).map(|p| p.1), Some(Grip::Roi(0)));
        let handle = grips(&scene.layers[0].kind).into_iter().find(|(g, _)| *g == Grip::RoiCorner(0, 1)).unwrap().1;
        let g = RoiGrab {
            layer: 0,
            grip: Grip::RoiCorner(0, 1),
            hit: Vec3::new(10.0, 10.0, 10.0),
            normal: d,
            shape: handle,
        };
        let eye = Vec3::new(10.0, 10.0, 40.0);
        let moved = dragged_shape(&g, eye, (Vec3::new(14.0, 12.0, 10.0) - eye).normalize()).unwrap();
        assert!(set_grip(&mut scene.layers[0].kind, g.grip, moved));
        let LayerKind::Tracts { rois, .. } = &scene.layers[0].kind else { unreachable!() };
        let RoiShape::Box { min, max } = rois[0].shape else { panic!() };
        assert_eq!(min, [-10.0; 3], "the other corner stays");
        assert!((Vec3::from(max) - Vec3::new(14.0, 12.0, 10.0)).length() < 1e-4, "{max:?}");
        // Dragged past the other corner: stopped half a millimetre short of it.
        let past = RoiShape::Sphere { centre: [-20.0, 0.0, 10.0], radius: 1.0 };
        assert!(set_grip(&mut scene.layers[0].kind, Grip::RoiCorner(0, 1), past));
        let LayerKind::Tracts { rois, .. } = &scene.layers[0].kind else { unreachable!() };
        assert_eq!(rois[0].shape, RoiShape::Box { min: [-10.0; 3], max: [-9.5, 0.0, 10.0] });

        // The sphere's radius handle at (46, 0, 0), radius 1 mm: picked, then dragged out to x = 49.
        assert_eq!(pick_roi(&scene, Vec3::new(46.0, 0.0, 40.0), d).map(|p| p.1), Some(Grip::RoiRadius(1)));
        let out = RoiShape::Sphere { centre: [49.0, 0.0, 0.0], radius: 1.0 };
        assert!(set_grip(&mut scene.layers[0].kind, Grip::RoiRadius(1), out));
        let LayerKind::Tracts { rois, .. } = &scene.layers[0].kind else { unreachable!() };
        assert_eq!(rois[1].shape, RoiShape::Sphere { centre: [40.0, 0.0, 0.0], radius: 9.0 });
        // A radius handle on a box, a corner on a sphere: nothing.
        assert!(!set_grip(&mut scene.layers[0].kind, Grip::RoiRadius(0), out));
        assert!(!set_grip(&mut scene.layers[0].kind, Grip::RoiCorner(1, 0), out));
    }

    /// A tracking layer's seed sphere is picked and dragged like an ROI: the drag moves the sphere's centre in
    /// the scene (its radius and seed count stay); grid seeds offer nothing to drag.
    #[test]
    fn seed_spheres_are_picked_and_dragged() {
        use crate::model::TensorSource;
        let track = |seeds: Seeds| LayerSpec {
            name: "tracking".into(),
            visible: true,
            opacity: 1.0,
            kind: LayerKind::Tracts {
                source: TractSource::Track { tensors: TensorSource::Phantom, seeds, params: Default::default() },
                mode: crate::model::TractMode::Tubes,
                render: Default::default(),
                rois: vec![],
                masks: vec![],
                ends_only: false,
                deleted: vec![],
                colouring: Default::default(),
            },
        };
        let sphere = Seeds::Sphere { centre: [28.0, 0.0, 0.0], radius: 6.0, per_voxel: 8 };
        let mut scene = Scene {
            layers: vec![track(Seeds::default()), track(sphere)],
            camera: CameraSpec::default(),
            views: Default::default(),
        };
        assert!(grips(&scene.layers[0].kind).is_empty());
        let (o, d) = (Vec3::new(28.0, 0.0, 40.0), -Vec3::Z);
        assert_eq!(pick_roi(&scene, o, d), Some((1, Grip::Seeds, 34.0)));
        let shape = grips(&scene.layers[1].kind)[0].1;
        let g = RoiGrab { layer: 1, grip: Grip::Seeds, hit: o + d * 34.0, normal: d, shape };
        let target = Vec3::new(30.0, 4.0, 6.0);
        let moved = dragged_shape(&g, o, (target - o).normalize()).unwrap();
        assert!(set_grip(&mut scene.layers[1].kind, Grip::Seeds, moved));
        let LayerKind::Tracts { source: TractSource::Track { seeds, .. }, .. } = &scene.layers[1].kind else {
            unreachable!()
        };
        let Seeds::Sphere { centre, radius, per_voxel } = seeds else { panic!("{seeds:?}") };
        assert!((Vec3::from(*centre) - Vec3::new(30.0, 4.0, 0.0)).length() < 1e-4, "{centre:?}");
        assert_eq!((*radius, *per_voxel), (6.0, 8));
        assert!(!set_grip(&mut scene.layers[0].kind, Grip::Seeds, moved), "grid seeds have no sphere");
    }

    /// A free glyph plane's handles: Shift + drag on the centre moves the plane, on the normal's tip tilts it.
    #[test]
    fn glyph_planes_are_moved_and_tilted_by_their_handles() {
        use fascicle_core::sh::glyph::GlyphPlane;
        let plane = GlyphPlane { centre: [0.0, 0.0, 1.0], normal: [0.0, 0.0, 1.0], half_size: 40.0, spacing: 2.0 };
        let glyphs = |plane| LayerKind::ShGlyphs {
            source: crate::model::ShSource::PhantomCsa { l_max: 4 },
            axis: crate::model::SliceAxis::Z,
            index: None,
            spacing: 1,
            plane,
            sampling: Default::default(),
            full_volume: false,
            style: Default::default(),
            render: Default::default(),
        };
        let mut kind = glyphs(Some(plane));
        let mut scene = Scene {
            layers: vec![LayerSpec { name: "odf".into(), visible: true, opacity: 1.0, kind: kind.clone() }],
            camera: CameraSpec::default(),
            views: Default::default(),
        };
        // From above: the normal's tip (z = 21) comes before the centre (z = 1).
        let (o, d) = (Vec3::new(0.0, 0.0, 60.0), -Vec3::Z);
        let radius = 40.0 * 0.06;
        assert_eq!(pick_roi(&scene, o, d), Some((0, Grip::PlaneNormal, 60.0 - 21.0 - radius)));
        // The centre, seen from the side.
        let (o2, d2) = (Vec3::new(-60.0, 0.0, 1.0), Vec3::X);
        assert_eq!(pick_roi(&scene, o2, d2), Some((0, Grip::PlaneCentre, 60.0 - radius)));
        let centre = grips(&kind)[0].1;
        let g =
            RoiGrab { layer: 0, grip: Grip::PlaneCentre, hit: o2 + d2 * (60.0 - radius), normal: d2, shape: centre };
        // The cursor now points at (y 5, z 9) on the grab plane (through the handle's front, facing the view).
        let moved = dragged_shape(&g, o2, (Vec3::new(-radius, 5.0, 9.0) - o2).normalize()).unwrap();
        assert!(set_grip(&mut kind, Grip::PlaneCentre, moved));
        let LayerKind::ShGlyphs { plane: Some(p), .. } = &kind else { unreachable!() };
        assert!((glam::DVec3::from(p.centre) - glam::DVec3::new(0.0, 5.0, 9.0)).length() < 1e-4, "{p:?}");
        // The tip dragged sideways: the normal turns towards it, the centre stays.
        let tip = RoiShape::Sphere { centre: [20.0, 5.0, 9.0], radius };
        assert!(set_grip(&mut kind, Grip::PlaneNormal, tip));
        let LayerKind::ShGlyphs { plane: Some(p), .. } = &kind else { unreachable!() };
        assert!((glam::DVec3::from(p.normal) - glam::DVec3::X).length() < 1e-9, "{p:?}");
        assert_eq!(p.centre, [0.0, 5.0, 9.0]);
        // A hidden layer's handles are not picked; a slice-placed layer has none.
        scene.layers[0].visible = false;
        assert_eq!(pick_roi(&scene, o, d), None);
        assert!(grips(&glyphs(None)).is_empty());
    }
}
