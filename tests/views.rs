//! The four-view layout, the crosshair and the colour bars, rendered headless on the GPU (lavapipe in CI) and
//! checked against closed forms: each 2D view shows the phantom's FA (computed here by the core, not read from
//! the renderer) through the crosshair, display grey linear in the window; the crosshair lines cross at the
//! crosshair's screen position; a click moves the crosshair and the slices follow; each colour bar's pixels
//! follow its map (grey ramp, viridis, the volume's transfer function).

use bevy::math::{DMat4, DVec3};
use bevy::prelude::*;
use fascicle_core::Volume;
use fascicle_render::headless::{self, Capture};
use fascicle_scene::jobs::PHANTOM_DIMS;
use fascicle_scene::layers::{ActiveScene, LayerSyncCounts, SceneLayer};
use fascicle_scene::model::{LayerKind, Scene};
use fascicle_views::colourbar::{BAR_W, GRADIENT_ROWS, bar_rect};
use fascicle_views::{OrthoView, ViewSlice, pick_in_view, view_axes};

const W: u32 = 640;
const H: u32 = 480;

/// The 2D views' cells at 640 x 480 (x0, y0, width, height): sagittal, coronal, axial.
const CELLS: [(u32, u32, u32, u32); 3] = [(320, 0, 320, 240), (0, 0, 320, 240), (0, 240, 320, 240)];

fn srgb(c: f64) -> f64 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.0031308 { c * 12.92 } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 }
}

fn close(got: [u8; 4], want: [f64; 3], tol: f64) -> bool {
    (0..3).all(|k| (f64::from(got[k]) - want[k] * 255.0).abs() <= tol)
}

fn fa() -> Volume<f32> {
    fascicle_core::phantom::ring_cross(PHANTOM_DIMS).fa()
}

fn world_box(m: DMat4, dims: [usize; 3]) -> (DVec3, DVec3) {
    let mut lo = DVec3::splat(f64::INFINITY);
    let mut hi = -lo;
    for c in 0..8 {
        let p = DVec3::from_array(std::array::from_fn(|k| if c & (1 << k) == 0 { -0.5 } else { dims[k] as f64 - 0.5 }));
        let w = m.transform_point3(p);
        (lo, hi) = (lo.min(w), hi.max(w));
    }
    (lo, hi)
}

/// Where world point `q` shows in 2D view `a` with crosshair `c`: the view frames the image's box (4 % margin,
/// the larger of its two fits) around the box's centre.
fn screen(a: usize, q: DVec3, c: DVec3, lo: DVec3, hi: DVec3) -> (f64, f64) {
    let (from, up) = view_axes(a);
    let (from, up) = (from.as_dvec3(), up.as_dvec3());
    let right = (-from).cross(up);
    let ext = hi - lo;
    let (w_mm, h_mm) = (ext.dot(right.abs()) * 1.04, ext.dot(up.abs()) * 1.04);
    let (x0, y0, w, h) = CELLS[a];
    let mmpp = (w_mm / f64::from(w)).max(h_mm / f64::from(h));
    let mut centre = (lo + hi) / 2.0;
    centre[a] = c[a];
    let d = q - centre;
    (f64::from(x0) + f64::from(w) / 2.0 + d.dot(right) / mmpp, f64::from(y0) + f64::from(h) / 2.0 - d.dot(up) / mmpp)
}

fn render(scene: &Scene) -> Option<Capture> {
    if headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return None;
    }
    Some(fascicle_scene::headless::render_scene(scene, W, H).unwrap_or_else(|e| panic!("{e}")))
}

/// Checks that 2D view `a` shows the FA slice through crosshair `c` with `window`, away from the crosshair
/// lines; returns how many voxels were checked.
fn check_view(img: &Capture, a: usize, c: DVec3, window: (f64, f64)) -> usize {
    let fa = fa();
    let m = fa.world_from_voxel;
    let dims = fa.dims3();
    let (lo, hi) = world_box(m, dims);
    let v = m.inverse().transform_point3(c);
    let k = v[a].round() as usize;
    let (cx, cy) = screen(a, c, c, lo, hi);
    let mut checked = 0;
    for i in (0..dims[0]).step_by(3) {
        for j in (0..dims[1]).step_by(3) {
            for kk in (0..dims[2]).step_by(3) {
                let mut p = [i, j, kk];
                p[a] = k;
                let q = m.transform_point3(DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
                let (sx, sy) = screen(a, q, c, lo, hi);
                if (sx - cx).abs() < 4.0 || (sy - cy).abs() < 4.0 {
                    continue;
                }
                let value = f64::from(fa.data[p[0] + dims[0] * (p[1] + dims[1] * p[2])]);
                let t = ((value - window.0) / (window.1 - window.0)).clamp(0.0, 1.0);
                let got = img.pixel(sx as u32, sy as u32);
                assert!(
                    close(got, [t; 3], 2.0),
                    "view {a}, voxel {p:?} (FA {value:.3}) at ({sx:.1}, {sy:.1}): {got:?}, want grey {:.1}",
                    t * 255.0
                );
                checked += 1;
            }
        }
    }
    // The crosshair: its vertical line 20 px below the crossing, its horizontal one 20 px right of it.
    let orange = [1.0, srgb(0.6), 0.0];
    for (x, y) in [(cx, cy + 20.0), (cx + 20.0, cy)] {
        let got = img.pixel(x as u32, y as u32);
        assert!(close(got, orange, 3.0), "view {a}: crosshair pixel ({x:.1}, {y:.1}) is {got:?}");
    }
    checked
}

fn ortho_scene(crosshair: [f32; 3]) -> Scene {
    let mut scene = Scene::default_scene();
    scene.views.ortho = true;
    scene.views.crosshair = Some(crosshair);
    scene
}

#[test]
fn the_2d_views_cut_the_image_at_the_crosshair() {
    let m = fa().world_from_voxel;
    for voxel in [DVec3::new(20.3, 14.8, 11.2), DVec3::new(30.0, 26.4, 6.6)] {
        let c = m.transform_point3(voxel);
        let Some(img) = render(&ortho_scene(c.as_vec3().to_array())) else { return };
        for a in 0..3 {
            let n = check_view(&img, a, c, (0.0, 1.0));
            assert!(n > 40, "view {a}: only {n} voxels checked");
        }
    }
}

/// Bar `i`'s gradient: column x shows `want(x / (BAR_W - 1))` (linear RGB), within 2 levels.
fn check_bar(img: &Capture, i: u32, want: impl Fn(f64) -> [f64; 3], size: UVec2) {
    let r = bar_rect(size, i).expect("the bar fits");
    for x in (0..BAR_W).step_by(7).chain([BAR_W - 1]) {
        let t = f64::from(x) / f64::from(BAR_W - 1);
        let got = img.pixel(r.min.x + x, r.min.y + GRADIENT_ROWS.start + 3);
        let w = want(t).map(srgb);
        assert!(close(got, w, 2.0), "bar {i} at t = {t:.3}: {got:?}, want {:?}", w.map(|c| c * 255.0));
    }
}

#[test]
fn colour_bars_follow_their_maps() {
    let scene = Scene::default_scene();
    let Some(img) = render(&scene) else { return };
    // Default scene: the FA slice (grey over 0..1), the splats (FA on viridis), the DVR transfer function.
    let tf = match &scene.layers.iter().find(|l| matches!(l.kind, LayerKind::Volume { .. })).unwrap().kind {
        LayerKind::Volume { render, .. } => render.tf.clone(),
        _ => unreachable!(),
    };
    let size = UVec2::new(W, H);
    let grey = |t: f64| [if t <= 0.04045 { t / 12.92 } else { ((t + 0.055) / 1.055).powf(2.4) }; 3];
    check_bar(&img, 0, grey, size);
    check_bar(&img, 1, |t| fascicle_core::dti::splat::viridis(t).to_array(), size);
    check_bar(
        &img,
        2,
        |t| {
            let c = tf.eval_normalised(t);
            [c[0], c[1], c[2]]
        },
        size,
    );
    // Nothing above the third bar: the background shows there.
    let above = bar_rect(size, 3).unwrap();
    let bg = img.pixel(above.min.x + 100, above.min.y + GRADIENT_ROWS.start + 3);
    assert!(bg[0] < 20 && bg[1] < 20 && bg[2] < 20, "{bg:?}");
}

/// A click in the axial view moves the crosshair there (its height kept); the sagittal and coronal views cut
/// the new voxel, and with "follow" the slice, glyph and splat layers move to it. A window edit re-cuts the
/// slices without a job and the views show the new window.
#[test]
fn a_click_moves_the_crosshair_and_the_slices_follow() {
    if headless::gpu_tests_skipped() {
        return;
    }
    let fa = fa();
    let m = fa.world_from_voxel;
    let dims = fa.dims3();
    let (lo, hi) = world_box(m, dims);
    let start = m.transform_point3(DVec3::new(23.0, 23.0, 12.0));
    let mut scene = ortho_scene(start.as_vec3().to_array());
    scene.views.follow = true;
    let (mut app, target, main) = fascicle_scene::headless::scene_app(&scene, W, H);
    fascicle_scene::layers::settle(&mut app).unwrap();
    // The splats are sorted for the 3D camera, not for a 2D view: only the 3D camera's layers meet theirs. (On
    // the GPU per view that sees them on a hardware adapter; on the CPU, for the last such camera, on lavapipe.)
    let forward = app.world().get::<GlobalTransform>(main).unwrap().forward().as_vec3();
    let gpu = app.world().resource::<fascicle_tensors::gpu_sort::GpuSortStats>().clone();
    let world = app.world_mut();
    let mut q = world.query::<(&fascicle_tensors::splat::SplatSet, &GlobalTransform)>();
    let (set, gt) = q.iter(world).next().expect("the default scene's splats");
    let (sorted_for, want) = match gpu.last_forward() {
        Some(f) => (f, forward),
        None => (
            set.sorted_for.expect("sorted on the CPU"),
            (gt.affine().matrix3.transpose() * bevy::math::Vec3A::from(forward)).into(),
        ),
    };
    assert!(sorted_for.distance(want) < 1e-5, "sorted for {sorted_for}, the 3D camera looks along {want}");

    // The 3D view sits in the bottom-right cell: the window position of that cell's centre looks along the
    // camera's axis (no second subtraction of the viewport's offset).
    let world = app.world_mut();
    let mut q = world.query_filtered::<(&Camera, &GlobalTransform), With<fascicle_views::MainView>>();
    let (cam, tf) = q.single(world).unwrap();
    let ray = fascicle_views::cursor_ray(cam, tf, Vec2::new(480.0, 360.0)).unwrap();
    assert!(ray.direction.as_vec3().angle_between(tf.forward().as_vec3()) < 1e-3, "{ray:?}");

    // 40 px right of and 30 px above the axial view's centre.
    let cursor = Vec2::new(160.0 + 40.0, 240.0 + 120.0 - 30.0);
    let world = app.world_mut();
    let mut q = world.query::<(&Camera, &GlobalTransform, &OrthoView)>();
    let (cam, tf, view) = q.iter(world).find(|(.., v)| v.0 == 2).unwrap();
    let picked = pick_in_view(cam, tf, *view, cursor, start.as_vec3()).expect("inside the axial view");
    let ext = hi - lo;
    let mmpp = (ext.x * 1.04 / 320.0).max(ext.y * 1.04 / 240.0);
    let want = DVec3::new((lo.x + hi.x) / 2.0 + 40.0 * mmpp, (lo.y + hi.y) / 2.0 + 30.0 * mmpp, start.z);
    assert!((picked.as_dvec3() - want).length() < 1e-3, "{picked} vs {want}");
    // Outside every view: nothing.
    assert!(pick_in_view(cam, tf, *view, Vec2::new(500.0, 400.0), start.as_vec3()).is_none());

    app.world_mut().resource_mut::<ActiveScene>().0.views.crosshair = Some(picked.to_array());
    fascicle_scene::layers::settle(&mut app).unwrap();
    for _ in 0..3 {
        app.update();
    }
    fascicle_scene::layers::settle(&mut app).unwrap();
    let v = m.inverse().transform_point3(picked.as_dvec3());
    let voxel = [v.x.round() as usize, v.y.round() as usize, v.z.round() as usize];
    let world = app.world_mut();
    let mut q = world.query::<&ViewSlice>();
    let slices: Vec<ViewSlice> = q.iter(world).cloned().collect();
    assert_eq!(slices.len(), 3, "{slices:?}");
    for s in &slices {
        assert_eq!((s.voxel_axis, s.index), (s.axis, voxel[s.axis]), "{s:?}");
    }
    // Follow: the layers' own slices moved to the crosshair's voxel.
    let scene = app.world().resource::<ActiveScene>().0.clone();
    for l in &scene.layers {
        let (axis, index) = match &l.kind {
            LayerKind::Slice { axis, index, .. }
            | LayerKind::ShGlyphs { axis, index, .. }
            | LayerKind::TensorSplats { axis, index, .. } => (axis.index(), *index),
            _ => continue,
        };
        assert_eq!(index, Some(voxel[axis]), "layer '{}'", l.name);
    }
    let img = headless::capture(&mut app, target.clone()).unwrap();
    for a in 0..2 {
        check_view(&img, a, picked.as_dvec3(), (0.0, 1.0));
    }

    // Window/level: a restyle, no job; the views show the new window.
    let jobs = app.world().resource::<LayerSyncCounts>().jobs;
    {
        let mut s = app.world_mut().resource_mut::<ActiveScene>();
        let i = s.0.layers.iter().position(|l| matches!(l.kind, LayerKind::Slice { .. })).unwrap();
        if let LayerKind::Slice { window, .. } = &mut s.0.layers[i].kind {
            *window = Some((0.2, 0.6));
        }
    }
    for _ in 0..3 {
        app.update();
    }
    assert_eq!(app.world().resource::<LayerSyncCounts>().jobs, jobs, "a window edit started a job");
    let world = app.world_mut();
    let mut q = world.query::<&SceneLayer>();
    assert!(q.iter(world).all(|l| !matches!(l.spec().kind, LayerKind::Slice { window: None, .. })));
    let img = headless::capture(&mut app, target).unwrap();
    for a in 0..3 {
        check_view(&img, a, picked.as_dvec3(), (0.2, 0.6));
    }
}

/// Streamlines in the 2D views, cropped to a slab one voxel thick around each view's plane (closed form): a
/// straight streamline at 60 degrees to z, 8 mm right of and 6 mm in front of the crosshair, shows in the axial
/// view as a segment of length t tan(60°) about where it crosses the axial plane (t the voxel's height), in the
/// sagittal view as a dot where it crosses the sagittal plane, and not at all in the coronal view (its plane is
/// 6 mm away); away from the slab nothing of it is drawn.
#[test]
fn the_2d_views_show_streamlines_cropped_to_a_slab() {
    if headless::gpu_tests_skipped() {
        return;
    }
    let fa = fa();
    let m = fa.world_from_voxel;
    let (lo, hi) = world_box(m, fa.dims3());
    let c = m.transform_point3(DVec3::new(24.0, 24.0, 12.0));
    let theta = 60f64.to_radians();
    let d = DVec3::new(theta.sin(), 0.0, theta.cos());
    let through = c + DVec3::new(8.0, 6.0, 0.0);
    let mut t = fascicle_core::io::Tractogram::new();
    let points: Vec<Vec3> = (-160..=160).map(|k| (through + d * (f64::from(k) * 0.125)).as_vec3()).collect();
    t.push(&points);
    let tmp_path = tempfile::tempdir().unwrap();
    let path = tmp_path.path().join("fascicle-slab.tck");
    fascicle_core::io::tck::write(&path, &t, &[]).unwrap();
    let mut scene = ortho_scene(c.as_vec3().to_array());
    scene.layers.retain(|l| matches!(l.kind, LayerKind::Slice { .. }));
    scene.layers.push(fascicle_scene::model::LayerSpec {
        name: "line".into(),
        visible: true,
        opacity: 1.0,
        kind: LayerKind::Tracts {
            source: fascicle_scene::model::TractSource::File { path: path.clone(), tensors: None },
            mode: fascicle_scene::model::TractMode::Lines,
            render: Default::default(),
            rois: vec![],
            masks: vec![],
            ends_only: false,
            deleted: vec![],
            colouring: Default::default(),
        },
    });
    let Some(img) = render(&scene) else { return };
    std::fs::remove_file(&path).ok();
    let coloured = |x: f64, y: f64| {
        let p = img.pixel(x.round() as u32, y.round() as u32);
        (i32::from(p[0]) - i32::from(p[1])).abs() > 30 && p[2] > 60
    };
    let voxel = |k: usize| m.col(k).truncate().length();
    // Axial (view 2, normal z): the drawn part of the line's row, in pixels, against t tan(theta).
    let (x_mid, y_row) = screen(2, through, c, lo, hi);
    let (x_mm, _) = screen(2, through + DVec3::X, c, lo, hi);
    let px_per_mm = x_mm - x_mid;
    let drawn: Vec<i32> = (-40..=40).filter(|&dx| coloured(x_mid + f64::from(dx), y_row)).collect();
    let want = voxel(2) * theta.tan() * px_per_mm;
    let span = drawn.last().zip(drawn.first()).map_or(0, |(a, b)| a - b + 1);
    println!("axial: drawn {span} px of the line's row, expected {want:.1} px ({drawn:?})");
    assert!((f64::from(span) - want).abs() <= 3.0, "axial crop: {span} px drawn, {want:.1} expected");
    assert!(drawn.iter().all(|dx| f64::from(dx.abs()) <= want / 2.0 + 2.0), "drawn outside the slab: {drawn:?}");
    // Sagittal (view 0, normal x): a dot where the line crosses x = c.x, nothing 5 mm along the line from it.
    let s = (c.x - through.x) / d.x;
    let (sx, sy) = screen(0, through + d * s, c, lo, hi);
    let near = (-2..=2).any(|dy| (-2..=2).any(|dx| coloured(sx + f64::from(dx), sy + f64::from(dy))));
    assert!(near, "sagittal: no streamline pixel near ({sx:.1}, {sy:.1})");
    let (fx, fy) = screen(0, through + d * (s + 5.0), c, lo, hi);
    assert!(!coloured(fx, fy), "sagittal: drawn 5 mm along the line, outside the slab");
    // Coronal (view 1, normal y): the line lies 6 mm in front of the plane: nothing.
    let (x0, y0, w, h) = CELLS[1];
    let any = (y0..y0 + h).step_by(2).any(|y| (x0..x0 + w).step_by(2).any(|x| coloured(f64::from(x), f64::from(y))));
    assert!(!any, "coronal: a streamline 6 mm from the plane was drawn");
}
