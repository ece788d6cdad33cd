//! Tract lines on the GPU (lavapipe in CI): three straight streamlines along y at x = -6, 0, 6 mm seen from
//! above, each where the pinhole projection puts it (closed form) and in its direction colour (|d| = green);
//! an include sphere around one leaves that one only, by its selection flag, with the same entity and mesh;
//! half opacity blends it over the background.

use std::sync::Arc;

use bevy::prelude::*;
use bevy::render::storage::ShaderBuffer;
use fascicle_core::io::Tractogram;
use fascicle_core::roi::{Roi, RoiMode, RoiShape};
use fascicle_render::headless;
use fascicle_tracts::{RoiStats, TractLineMaterial, TractPlugin, TractRoi, spawn_lines};

const W: u32 = 160;
const H: u32 = 120;
const XS: [f32; 3] = [-6.0, 0.0, 6.0];
const EYE_Z: f32 = 30.0;

fn streamlines() -> Tractogram {
    let mut t = Tractogram::new();
    for x in XS {
        for k in 0..9 {
            t.points.push(Vec3::new(x, -8.0 + 2.0 * k as f32, 0.0));
        }
        t.offsets.push(t.points.len());
    }
    t
}

/// Image column of the line at `x` (camera at (0, 0, EYE_Z) looking down -z, Bevy's default 45° vertical
/// field of view).
fn column(x: f32) -> f32 {
    let half_width = EYE_Z * (std::f32::consts::FRAC_PI_8).tan() * W as f32 / H as f32;
    (x / half_width + 1.0) * 0.5 * W as f32
}

/// Green pixels within 2 columns of each line, over the rows 40..80 (the lines span rows 22-98).
fn lit_per_line(c: &headless::Capture) -> [usize; 3] {
    XS.map(|x| {
        let cx = column(x).floor() as i64;
        let mut n = 0;
        for y in 40..80 {
            for px in (cx - 2)..=(cx + 2) {
                let p = c.pixel(px as u32, y);
                n += usize::from(p[1] > 40 && p[0] < 10 && p[2] < 10);
            }
        }
        n
    })
}

fn render(roi: Option<Roi>, opacity: f32) -> Option<(headless::Capture, usize)> {
    let (mut app, target) = headless::gpu_test_app(W, H)?;
    app.add_plugins(TractPlugin);
    app.add_systems(
        Startup,
        move |mut commands: Commands,
              mut meshes: ResMut<Assets<Mesh>>,
              mut materials: ResMut<Assets<TractLineMaterial>>,
              mut buffers: ResMut<Assets<ShaderBuffer>>| {
            let set =
                spawn_lines(&mut commands, &mut meshes, &mut materials, &mut buffers, Arc::new(streamlines()), opacity);
            if let Some(r) = roi {
                commands.spawn((TractRoi(r), ChildOf(set)));
            }
        },
    );
    headless::spawn_test_camera(&mut app, target.clone(), Vec3::new(0.0, 0.0, EYE_Z), Vec3::ZERO);
    let img = headless::capture(&mut app, target).unwrap_or_else(|e| panic!("{e}"));
    let selected = app.world().resource::<RoiStats>().selected;
    Some((img, selected))
}

#[test]
fn lines_are_drawn_where_projected_and_follow_the_selection() {
    let Some((all, n)) = render(None, 1.0) else { return };
    let per_line = lit_per_line(&all);
    println!("lit pixels per line: {per_line:?} (columns {:?})", XS.map(column));
    assert_eq!(n, 3);
    // One pixel wide, 40 rows: each line lights about 40 pixels near its projected column.
    assert!(per_line.iter().all(|&k| (35..=90).contains(&k)), "{per_line:?}");
    let everywhere = all.rgba.chunks(4).filter(|p| p[1] > 40).count();
    assert!(everywhere <= 3 * 90, "lit pixels away from the lines: {everywhere}");

    let roi = Roi { shape: RoiShape::Sphere { centre: [6.0, 0.0, 0.0], radius: 1.0 }, mode: RoiMode::Include };
    let Some((one, n)) = render(Some(roi), 1.0) else { return };
    let per_line_one = lit_per_line(&one);
    assert_eq!(n, 1);
    assert_eq!(per_line_one[..2], [0, 0], "unselected lines drawn: {per_line_one:?}");
    // The ROI's gizmo outline (a lighter green) crosses the selected line twice.
    assert!(per_line_one[2] + 4 >= per_line[2], "the selected line changed: {per_line_one:?}");

    // Half opacity over black: sRGB(0.5) = 188 instead of 255.
    let Some((half, _)) = render(None, 0.5) else { return };
    let cx = column(6.0).floor() as u32;
    let g = (40..80).flat_map(|y| (cx - 2..=cx + 2).map(move |x| (x, y))).map(|(x, y)| half.pixel(x, y)[1]).max();
    assert!(g.is_some_and(|g| (183..=193).contains(&g)), "half-opacity green {g:?}");
}
