//! The app outside the workspace, rendered headless on the GPU (lavapipe in CI) and checked against references
//! the renderer does not make: the axial 2D view against the FA read by the core's NIfTI reader (display grey
//! linear in the window, pixel for pixel); the glyphs read from MRtrix3's `.mif` against the glyphs of the same
//! ODFs read from DIPY's NIfTI (other basis, other frame: the same world shapes); the streamlines the include
//! ROI keeps against the core's closed-form sphere test of each streamline; the two colour bars against the
//! grey ramp and the core's f64 viridis.

#[allow(dead_code)]
#[path = "../src/main.rs"]
mod app;

use bevy::prelude::*;
use fascicle_core::sh::{self, glyph::GLYPH_BASIS};
use fascicle_render::example::ExampleApp;
use fascicle_render::headless::{self, Capture};
use fascicle_render::reference::srgb8;
use fascicle_sh_glyphs::ShGlyphSet;
use fascicle_sh_glyphs::layer::{ShFieldSettings, field_glyphs, read_field};
use fascicle_tracts::{TractSelection, TractSet};
use fascicle_views::colourbar::{BAR_W, GRADIENT_ROWS, bar_rect};
use fascicle_views::{OrthoView, cells};
use glam::DVec3;

fn render() -> Option<(ExampleApp, Capture)> {
    if headless::gpu_tests_skipped() {
        eprintln!("FASCICLE_SKIP_GPU=1: GPU test skipped");
        return None;
    }
    let mut ex = app::app(ExampleApp::offscreen(&app::data(), None));
    let capture = ex.render().unwrap_or_else(|e| panic!("{e}"));
    Some((ex, capture))
}

#[test]
fn the_app_shows_its_four_views_exactly() {
    let Some((mut ex, img)) = render() else { return };
    let world = ex.app.world_mut();

    // The axial 2D view: the FA slice through the crosshair, FA 0 black and 1 white.
    let (fa, _) = fascicle_core::io::nifti::read::<f32>(format!("{}/dti/small_64D_fa.nii.gz", app::data())).unwrap();
    let (m, d) = (fa.world_from_voxel, fa.dims3());
    let inv = m.inverse();
    let (cam, at) = world
        .query::<(&Camera, &GlobalTransform, &OrthoView)>()
        .iter(world)
        .find(|(.., v)| v.0 == 2)
        .map(|(c, t, _)| (c.clone(), *t))
        .expect("the axial view");
    let axis = (0..3).max_by(|&i, &j| m.col(i).z.abs().total_cmp(&m.col(j).z.abs())).unwrap();
    let cross = DVec3::from_array(app::CROSSHAIR.map(f64::from));
    let k = inv.transform_point3(cross)[axis].round();
    let (normal, mut on_plane) = (m.col(axis).truncate(), DVec3::ZERO);
    on_plane[axis] = k;
    let on_plane = m.transform_point3(on_plane);
    let cell = cells(URect::new(0, 0, img.width, img.height))[2];
    let (mut checked, mut worst) = (0, 0.0f64);
    for y in cell.min.y + 24..cell.max.y - 24 {
        for x in cell.min.x + 24..cell.max.x - 24 {
            let ray = cam.viewport_to_world(&at, Vec2::new(x as f32 + 0.5, y as f32 + 0.5)).unwrap();
            let (o, dir) = (ray.origin.as_dvec3(), ray.direction.as_dvec3());
            let p = o + dir * (on_plane - o).dot(normal) / dir.dot(normal);
            let v = inv.transform_point3(p);
            let others = (0..3).filter(|&a| a != axis);
            let inside = others.clone().all(|a| v[a] > -0.4 && v[a] < d[a] as f64 - 0.6);
            let clear = others.clone().all(|a| (v[a] - v[a].round()).abs() < 0.35);
            // Away from the crosshair lines and the tracts cropped to the slab (they are drawn over the image).
            if !inside || !clear || (p.x - cross.x).abs() < 1.0 || (p.y - cross.y).abs() < 1.0 {
                continue;
            }
            let idx: [usize; 3] = std::array::from_fn(|a| if a == axis { k as usize } else { v[a].round() as usize });
            let want = (f64::from(fa.data[idx[0] + d[0] * (idx[1] + d[1] * idx[2])]).clamp(0.0, 1.0) * 255.0).round();
            let got = img.pixel(x, y);
            if got[0] != got[1] || got[1] != got[2] {
                continue; // a streamline's colour, not the image's grey
            }
            worst = worst.max((f64::from(got[0]) - want).abs());
            checked += 1;
        }
    }
    assert!(checked > 8_000 && worst <= 1.0, "worst {worst} levels over {checked} pixels");

    // The glyphs from the .mif are those of the same ODFs from DIPY's NIfTI: centres, GFA, shape.
    let set = world.query::<&ShGlyphSet>().single(world).expect("one glyph set").glyphs.clone();
    let bytes = std::fs::read(format!("{}/sh/small_64D_csa_l6.nii.gz", app::data())).unwrap();
    let nifti = read_field(bytes, "small_64D_csa_l6.nii.gz".as_ref(), &ShFieldSettings::default()).unwrap();
    let selection =
        fascicle_sh_glyphs::Selection::Slice { axis: fascicle_sh_glyphs::SliceAxis::Z, index: Some(5), spacing: 1 };
    let (want, _) = field_glyphs(&nifti, &selection, fascicle_sh_glyphs::GlyphShape::default().0).unwrap();
    assert_eq!(set.len(), want.len());
    let dirs = sh::sphere::fibonacci(40);
    for (g, w) in set.iter().zip(&want) {
        assert!((g.centre - w.centre).length() < 1e-6 && (g.gfa - w.gfa).abs() < 1e-5, "{:?} {:?}", g.centre, w.centre);
        for u in &dirs {
            let (a, b) = (sh::eval(GLYPH_BASIS, &g.coeffs, *u).unwrap(), sh::eval(GLYPH_BASIS, &w.coeffs, *u).unwrap());
            assert!((a - b).abs() <= 1e-4 * w.rmax, "radius {a} against {b} mm at {u:?}");
        }
    }

    // The include ROI keeps the streamlines with a point in the sphere or a step through it.
    let (tracts, selection) = world.query::<(&TractSet, &TractSelection)>().single(world).expect("one tract set");
    let t = &tracts.tractogram;
    let kept: Vec<bool> = (0..t.n_streamlines()).map(|i| app::ROI.meets_streamline(t.streamline(i))).collect();
    assert!(kept.iter().any(|k| *k) && kept.iter().any(|k| !*k));
    assert_eq!(selection.0, kept);

    // The bars over the 3D view: the slice's grey ramp (bottom), the glyphs' viridis above it.
    let cell = cells(URect::new(0, 0, img.width, img.height))[3];
    for (i, viridis) in [(0, false), (1, true)] {
        let r = bar_rect(cell.size(), i).expect("the bar fits");
        for x in [0, 60, 130, BAR_W - 1] {
            let got = img.pixel(cell.min.x + r.min.x + x, cell.min.y + r.min.y + GRADIENT_ROWS.start + 3);
            let t = f64::from(x) / f64::from(BAR_W - 1);
            let want = if viridis {
                fascicle_core::dti::splat::viridis(t).to_array().map(srgb8)
            } else {
                [(t * 255.0).round(); 3]
            };
            assert!((0..3).all(|c| (f64::from(got[c]) - want[c]).abs() <= 1.0), "bar {i} at {t}: {got:?} {want:?}");
        }
    }
}
