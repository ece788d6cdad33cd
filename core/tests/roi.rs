//! ROI selection against brute force: on `tracks300.trk` and on RK4 tracts of the phantom, random sphere, box
//! and plane ROIs in include/exclude combinations select exactly the streamlines a grid-free evaluation of
//! every segment selects; and the segment predicates agree with dense sampling of each segment.

use fascicle_core::io::{Csr, Tractogram};
use fascicle_core::roi::{
    Criteria, MaskRegion, Region, Roi, RoiMode, RoiShape, SegmentGrid, in_polygon, lasso_streamlines, pick_projected,
    pick_streamline, pieces_inside, select, select_ends,
};
use glam::{Vec2, Vec3};
use rand::{RngExt, SeedableRng};

fn data(p: &str) -> std::path::PathBuf {
    std::path::Path::new(&std::env::var("CARGO_MANIFEST_DIR").unwrap_or_else(|_| env!("CARGO_MANIFEST_DIR").into()))
        .join("..")
        .join(p)
}

fn brute(t: &Tractogram, rois: &[Roi]) -> Vec<bool> {
    (0..t.offsets.len() - 1)
        .map(|s| {
            let pts = &t.points[t.offsets[s]..t.offsets[s + 1]];
            // The selection rule written out: a point in a sphere or box, a step across a plane.
            let meets = |r: &Roi| match r.shape {
                RoiShape::Plane { .. } if pts.len() > 1 => pts.windows(2).any(|w| r.shape.meets_segment(w[0], w[1])),
                RoiShape::Plane { .. } => pts.len() == 1 && r.shape.meets_segment(pts[0], pts[0]),
                _ => pts.iter().any(|p| r.shape.contains(*p)),
            };
            rois.iter().filter(|r| r.mode == RoiMode::Include).all(meets)
                && !rois.iter().filter(|r| r.mode == RoiMode::Exclude).any(meets)
        })
        .collect()
}

fn random_roi(rng: &mut rand_pcg::Pcg64, lo: Vec3, hi: Vec3) -> Roi {
    let p = lo + (hi - lo) * Vec3::new(rng.random(), rng.random(), rng.random());
    let size = (hi - lo).length() * (0.03 + 0.12 * rng.random::<f32>());
    let shape = match rng.random_range(0..3) {
        0 => RoiShape::Sphere { centre: p.to_array(), radius: size },
        1 => RoiShape::Box { min: (p - size).to_array(), max: (p + size * Vec3::new(1.0, 0.5, 2.0)).to_array() },
        _ => RoiShape::Plane {
            point: p.to_array(),
            normal: Vec3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5)
                .to_array(),
        },
    };
    let mode = if rng.random::<f32>() < 0.7 { RoiMode::Include } else { RoiMode::Exclude };
    Roi { shape, mode }
}

fn check(t: &Tractogram, seed: u64) -> (usize, usize) {
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for p in &t.points {
        lo = lo.min(*p);
        hi = hi.max(*p);
    }
    let grid = SegmentGrid::new(&t.points, &t.offsets, 4.0);
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    let (mut selected, mut cases, mut ends_selected) = (0, 0, 0);
    for _ in 0..60 {
        let rois: Vec<Roi> = (0..rng.random_range(1..4)).map(|_| random_roi(&mut rng, lo, hi)).collect();
        let got = select(&t.points, &t.offsets, &grid, &rois);
        assert_eq!(got, brute(t, &rois), "{rois:?}");
        // The streaming form (one streamline at a time, as `fascicle select` runs) keeps the same set.
        let criteria = Criteria {
            include: rois.iter().filter(|r| r.mode == RoiMode::Include).map(|r| Region::Shape(r.shape)).collect(),
            exclude: rois.iter().filter(|r| r.mode == RoiMode::Exclude).map(|r| Region::Shape(r.shape)).collect(),
            ends_only: false,
        };
        let streamed: Vec<bool> = t.iter().map(|s| criteria.keeps(s)).collect();
        assert_eq!(streamed, got, "{rois:?}");
        // Ends only (the viewer's live selection, tckedit's -ends_only as `fascicle select` streams it).
        let ends = select_ends(t, &rois);
        let streamed: Vec<bool> = t.iter().map(|s| Criteria { ends_only: true, ..criteria.clone() }.keeps(s)).collect();
        assert_eq!(ends, streamed, "ends only: {rois:?}");
        if rois.iter().all(|r| r.mode == RoiMode::Include && !matches!(r.shape, RoiShape::Plane { .. })) {
            assert!(ends.iter().zip(&got).all(|(e, g)| !e || *g), "an end inside is a point inside");
        }
        ends_selected += ends.iter().filter(|s| **s).count();
        selected += got.iter().filter(|s| **s).count();
        cases += 1;
    }
    assert!(ends_selected > 0 && ends_selected < selected, "ends only selected {ends_selected} of {selected}");
    (selected, cases)
}

#[test]
fn selection_matches_brute_force_on_tracks300() {
    let t = Tractogram::read(data("data/tracts/tracks300.trk")).unwrap();
    let (selected, cases) = check(&t, 1);
    println!("tracks300: {selected} streamlines selected over {cases} ROI sets");
    assert!(selected > 100, "the ROIs must select something: {selected}");
}

#[test]
fn selection_matches_brute_force_on_phantom_tracts() {
    use fascicle_core::tracking::{TensorField, TensorInterpolation, TrackParams, Tracker};
    let ph = fascicle_core::phantom::ring_cross([48, 48, 24]);
    let voxel = glam::DVec3::new(
        ph.world_from_voxel.x_axis.length(),
        ph.world_from_voxel.y_axis.length(),
        ph.world_from_voxel.z_axis.length(),
    );
    let field =
        TensorField::new(ph.dims, voxel, ph.tensors.iter().map(|t| Some(*t)), TensorInterpolation::Componentwise)
            .unwrap();
    let seeds: Vec<glam::DVec3> =
        (0..400).map(|i| glam::DVec3::new(2.0 + (i % 44) as f64, 2.0 + (i / 44) as f64 * 5.0, 12.0)).collect();
    let t = Tracker::new(&field, ph.world_from_voxel, TrackParams::default()).unwrap().run(&seeds).tractogram;
    assert!(t.offsets.len() > 50);
    let (selected, _) = check(&t, 2);
    assert!(selected > 50);
}

#[test]
fn segment_predicates_agree_with_dense_sampling() {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(3);
    let (mut hits, mut misses) = (0, 0);
    for _ in 0..20_000 {
        let roi = random_roi(&mut rng, Vec3::splat(-10.0), Vec3::splat(10.0));
        let a = Vec3::new(rng.random(), rng.random(), rng.random()) * 20.0 - 10.0;
        let b = a + (Vec3::new(rng.random(), rng.random(), rng.random()) - 0.5) * 8.0;
        let exact = roi.shape.meets_segment(a, b);
        let inside = |p: Vec3, grow: f32| match roi.shape {
            RoiShape::Sphere { centre, radius } => (p - Vec3::from(centre)).length() <= radius + grow,
            RoiShape::Box { min, max } => {
                (p - Vec3::from(min)).min_element() >= -grow && (Vec3::from(max) - p).min_element() >= -grow
            }
            RoiShape::Plane { .. } => false,
        };
        if let RoiShape::Plane { point, normal } = roi.shape {
            let s = |p: Vec3| (p - Vec3::from(point)).dot(Vec3::from(normal));
            assert_eq!(exact, s(a) * s(b) <= 0.0);
            continue;
        }
        let n = 512;
        let grow = (b - a).length() / n as f32;
        let sampled = (0..=n).any(|k| inside(a.lerp(b, k as f32 / n as f32), 0.0));
        let near = (0..=n).any(|k| inside(a.lerp(b, k as f32 / n as f32), grow * 1.01));
        // A sampled hit is a hit; an exact hit is within one sample spacing of a sampled one.
        assert!(!sampled || exact, "{roi:?} {a} {b}");
        assert!(!exact || near, "{roi:?} {a} {b}");
        if exact { hits += 1 } else { misses += 1 }
    }
    assert!(hits > 300 && misses > 1000, "{hits} hits, {misses} misses");
}

/// Picking: `ray_hit` on closed forms, and on random rays where its distance is the first point of the
/// region along the ray (dense sampling: no inside point before it, one within a sample of it).
#[test]
fn ray_hits_pick_the_first_point_of_the_region() {
    let sphere = RoiShape::Sphere { centre: [0.0; 3], radius: 2.0 };
    assert_eq!(sphere.ray_hit(Vec3::new(-10.0, 0.0, 0.0), Vec3::X), Some(8.0));
    assert_eq!(sphere.ray_hit(Vec3::ZERO, Vec3::X), Some(0.0));
    assert_eq!(sphere.ray_hit(Vec3::new(-10.0, 3.0, 0.0), Vec3::X), None);
    assert_eq!(sphere.ray_hit(Vec3::new(10.0, 0.0, 0.0), Vec3::X), None, "behind the ray");
    let cube = RoiShape::Box { min: [-1.0; 3], max: [1.0; 3] };
    assert_eq!(cube.ray_hit(Vec3::new(-5.0, 0.5, 0.0), Vec3::X), Some(4.0));
    assert_eq!(cube.ray_hit(Vec3::new(-5.0, 2.0, 0.0), Vec3::X), None);
    let plane = RoiShape::Plane { point: [0.0; 3], normal: [0.0, 0.0, 1.0] };
    assert_eq!(plane.ray_hit(Vec3::new(1.0, 2.0, 10.0), -Vec3::Z), Some(10.0));
    assert_eq!(plane.ray_hit(Vec3::new(40.0, 0.0, 10.0), -Vec3::Z), None, "outside the drawn square");
    assert_eq!(plane.ray_hit(Vec3::new(1.0, 2.0, 10.0), Vec3::X), None, "parallel");

    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let mut hits = 0;
    for _ in 0..5_000 {
        let roi = random_roi(&mut rng, Vec3::splat(-10.0), Vec3::splat(10.0));
        if matches!(roi.shape, RoiShape::Plane { .. }) {
            continue;
        }
        let o = Vec3::new(rng.random(), rng.random(), rng.random()) * 40.0 - 20.0;
        // Aimed near the region, so that about half the rays meet it.
        let aim = roi.shape.anchor() + (Vec3::new(rng.random(), rng.random(), rng.random()) - 0.5) * 12.0;
        let d = (aim - o).normalize_or(Vec3::X);
        let inside = |p: Vec3| match roi.shape {
            RoiShape::Sphere { centre, radius } => (p - Vec3::from(centre)).length() <= radius,
            RoiShape::Box { min, max } => {
                (p - Vec3::from(min)).min_element() >= 0.0 && (Vec3::from(max) - p).min_element() >= 0.0
            }
            RoiShape::Plane { .. } => unreachable!(),
        };
        let (n, len) = (4000, 60.0);
        let first = (0..=n).map(|k| len * k as f32 / n as f32).find(|t| inside(o + d * *t));
        match (roi.shape.ray_hit(o, d), first) {
            (Some(t), Some(s)) => {
                hits += 1;
                assert!(t <= s + 1e-3 && s - t <= len / n as f32 + 1e-3, "{roi:?}: hit {t}, sampled {s}");
            }
            (None, None) => {}
            (Some(t), None) => {
                // Beyond the sampled length, or a grazing chord shorter than the sample spacing: then finer
                // samples just past the hit are inside.
                let fine = (0..=200).any(|k| inside(o + d * (t + k as f32 * 1e-4)));
                assert!(t > len || fine, "{roi:?}: hit {t}, nothing inside there");
            }
            (None, Some(s)) => panic!("{roi:?}: missed, sampled inside at {s}"),
        }
    }
    assert!(hits > 1000, "{hits} hits");
    // Moving: the translated region meets the translated segment exactly when the original meets the original.
    let delta = Vec3::new(3.0, -2.0, 0.5);
    for roi in [sphere, cube, plane] {
        let moved = roi.translated(delta);
        assert_eq!(moved.anchor(), roi.anchor() + delta);
        for (a, b) in [(Vec3::new(-5.0, 0.3, 0.2), Vec3::new(5.0, 0.1, -0.4)), (Vec3::splat(4.0), Vec3::splat(6.0))] {
            assert_eq!(moved.meets_segment(a + delta, b + delta), roi.meets_segment(a, b));
        }
    }
}

/// The grid skips cells whose box does not meet a region: `meets_box` must never say no when part of the box
/// lies in the region (checked by sampling random boxes), and says so on closed forms.
#[test]
fn box_tests_never_miss_a_region() {
    let sphere = RoiShape::Sphere { centre: [0.0; 3], radius: 1.0 };
    assert!(!sphere.meets_box(Vec3::splat(1.5), Vec3::splat(2.0)));
    assert!(sphere.meets_box(Vec3::new(0.5, -1.0, -1.0), Vec3::new(2.0, 1.0, 1.0)));
    let plane = RoiShape::Plane { point: [0.0; 3], normal: [1.0, 1.0, 0.0] };
    assert!(!plane.meets_box(Vec3::new(1.0, 1.0, 0.0), Vec3::new(2.0, 2.0, 1.0)));
    assert!(plane.meets_box(Vec3::new(-1.0, 0.0, 0.0), Vec3::new(0.1, 1.0, 1.0)));
    let cube = RoiShape::Box { min: [0.0; 3], max: [1.0; 3] };
    assert!(!cube.meets_box(Vec3::new(1.1, 0.0, 0.0), Vec3::splat(2.0)));
    assert!(cube.meets_box(Vec3::splat(0.9), Vec3::splat(2.0)));

    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    let (mut met, mut apart) = (0, 0);
    for _ in 0..4_000 {
        let roi = random_roi(&mut rng, Vec3::splat(-10.0), Vec3::splat(10.0));
        let lo = Vec3::new(rng.random(), rng.random(), rng.random()) * 24.0 - 12.0;
        let hi = lo + Vec3::new(rng.random(), rng.random(), rng.random()) * 6.0;
        let inside = |p: Vec3| match roi.shape {
            RoiShape::Sphere { centre, radius } => (p - Vec3::from(centre)).length() <= radius,
            RoiShape::Box { min, max } => {
                (p - Vec3::from(min)).min_element() >= 0.0 && (Vec3::from(max) - p).min_element() >= 0.0
            }
            // A plane is "in" the box when the box has points on both sides.
            RoiShape::Plane { .. } => false,
        };
        let k = 12;
        let samples = (0..=k).flat_map(|i| (0..=k).flat_map(move |j| (0..=k).map(move |l| (i, j, l))));
        let sampled = match roi.shape {
            RoiShape::Plane { point, normal } => {
                let side = |p: Vec3| (p - Vec3::from(point)).dot(Vec3::from(normal));
                let corners: Vec<f32> = (0..8)
                    .map(|c| side(Vec3::new([lo.x, hi.x][c & 1], [lo.y, hi.y][(c >> 1) & 1], [lo.z, hi.z][c >> 2])))
                    .collect();
                corners.iter().any(|v| *v <= 0.0) && corners.iter().any(|v| *v >= 0.0)
            }
            _ => samples
                .into_iter()
                .any(|(i, j, l)| inside(lo + (hi - lo) * Vec3::new(i as f32, j as f32, l as f32) / k as f32)),
        };
        let says = roi.shape.meets_box(lo, hi);
        assert!(!sampled || says, "{roi:?} {lo} {hi}");
        if says { met += 1 } else { apart += 1 }
    }
    assert!(met > 300 && apart > 300, "{met} met, {apart} apart");
}

/// `tckedit`'s rules on a closed case: a point exactly on a sphere counts (`<=`), a step jumping over a small
/// sphere misses it (points, not segments), `--ends-only` tests the two ends only, and a mask is met at the
/// voxel nearest to a point (rounded), nothing outside the image.
#[test]
fn points_not_segments_and_ends_only_as_tckedit() {
    let line: Vec<Vec3> = (0..11).map(|k| Vec3::new(k as f32 * 2.0, 0.0, 0.0)).collect();
    let sphere = |x: f32, r: f32| Region::Shape(RoiShape::Sphere { centre: [x, 0.0, 0.0], radius: r });
    let keeps = |include: Vec<Region>, exclude: Vec<Region>, ends_only: bool| {
        Criteria { include, exclude, ends_only }.keeps(&line)
    };
    assert!(keeps(vec![sphere(4.0, 0.0)], vec![], false), "a point on the sphere (radius 0 at a point)");
    assert!(!keeps(vec![sphere(5.0, 0.9)], vec![], false), "between points 4 and 6: the step jumps over it");
    assert!(keeps(vec![sphere(5.0, 1.0)], vec![], false), "points 4 and 6 lie on its surface");
    assert!(!keeps(vec![sphere(10.0, 1.0)], vec![], true), "a middle point with --ends-only");
    assert!(keeps(vec![sphere(0.0, 1.0), sphere(20.0, 1.0)], vec![], true), "both ends");
    assert!(keeps(vec![sphere(0.0, 1.0)], vec![sphere(4.0, 0.5)], true), "the exclude meets a middle point only");
    assert!(!keeps(vec![sphere(0.0, 1.0)], vec![sphere(4.0, 0.5)], false));
    assert!(!Criteria { include: vec![sphere(0.0, 100.0)], ..Default::default() }.keeps(&[]), "no points");
    assert!(Criteria::default().keeps(&line), "no region keeps everything");

    // A 10x10x10 mask of 2 mm voxels from (-1,-1,-1): voxel (3,0,0) set, centred at x = 5 mm.
    let mut vol = fascicle_core::Volume::<f32>::zeros(
        &[10, 10, 10],
        glam::DMat4::from_translation(glam::DVec3::splat(-1.0)) * glam::DMat4::from_scale(glam::DVec3::splat(2.0)),
    );
    vol.data[3] = 1.0;
    let mask = Region::Mask(std::sync::Arc::new(MaskRegion::new(&vol)));
    let at = |x: f32| Criteria { include: vec![mask.clone()], ..Default::default() }.keeps(&[Vec3::new(x, -1.0, -1.0)]);
    // x = 5 mm is voxel 3.0; rounding takes 2.5..3.5 (x in [4, 6)), with halves away from zero.
    assert!(at(5.0) && at(4.0) && at(5.99) && !at(3.99) && !at(6.0));
    assert!(!Criteria { include: vec![mask], ..Default::default() }.keeps(&[Vec3::new(-4.0, -1.0, -1.0)]));
}

/// A click picks the streamline nearest along the ray within the cone of its tolerance: three parallel lines
/// stacked under the ray, the top one first; a hidden one is skipped; a ray beside them within the cone
/// picks, outside it does not; a one-point streamline is a point; against brute force (each step's densely
/// sampled point nearest the ray) on tracks300.
#[test]
fn a_click_picks_the_nearest_streamline_within_its_cone() {
    let mut points = vec![];
    let mut offsets = vec![0];
    for z in [0.0, 5.0, 10.0] {
        points.extend((0..11).map(|k| Vec3::new(k as f32, 0.0, z)));
        offsets.push(points.len());
    }
    points.push(Vec3::new(20.0, 0.0, 20.0));
    offsets.push(points.len());
    let all = |_: usize| true;
    let down = -Vec3::Z;
    let pick = |o: Vec3, shown: &(dyn Fn(usize) -> bool + Sync), tol: f32| {
        pick_streamline(&Csr(&points, &offsets), shown, o, down, tol)
    };
    assert_eq!(pick(Vec3::new(3.0, 0.0, 100.0), &all, 0.01), Some((2, 90.0)));
    assert_eq!(pick(Vec3::new(3.0, 0.0, 100.0), &|s| s != 2, 0.01), Some((1, 95.0)));
    // 0.5 mm beside the lines: within 0.01 x 90 mm at the top line; 2 mm beside: outside every cone.
    assert_eq!(pick(Vec3::new(3.0, 0.5, 100.0), &all, 0.01).map(|p| p.0), Some(2));
    assert_eq!(pick(Vec3::new(3.0, 2.0, 100.0), &all, 0.01), None);
    // Beyond the lines' ends (x = 10): the step's end is the nearest point.
    assert_eq!(pick(Vec3::new(10.5, 0.0, 100.0), &all, 0.01).map(|p| p.0), Some(2));
    assert_eq!(pick(Vec3::new(12.0, 0.0, 100.0), &all, 0.01), None);
    assert_eq!(pick(Vec3::new(20.0, 0.2, 100.0), &all, 0.01), Some((3, 80.0)));
    // Behind the origin: nothing.
    assert_eq!(pick(Vec3::new(3.0, 0.0, -1.0), &all, 0.01), None);

    // tracks300: rays through points of the streamlines; brute force samples every step densely.
    let t = Tractogram::read(data("data/tracts/tracks300.trk")).unwrap();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
    let tol = 0.004;
    for _ in 0..40 {
        let s = rng.random_range(0..t.n_streamlines());
        let pts = t.streamline(s);
        let target = pts[rng.random_range(0..pts.len())];
        let o = target + Vec3::new(rng.random::<f32>() - 0.5, rng.random::<f32>() - 0.5, 1.0).normalize() * 150.0;
        let d = (target - o).normalize();
        let got = pick_streamline(&t, |_| true, o, d, tol).expect("the ray passes a point");
        // Brute force: per step, its densely sampled point nearest the ray's line; in the cone there, the
        // nearest such along the ray wins.
        let mut best: Option<(usize, f32)> = None;
        for s in 0..t.n_streamlines() {
            for w in t.streamline(s).windows(2) {
                let (dist, along) = (0..=400)
                    .map(|k| {
                        let p = w[0] + (w[1] - w[0]) * (k as f32 / 400.0);
                        let along = (p - o).dot(d);
                        ((o + d * along - p).length(), along)
                    })
                    .min_by(|a, b| a.0.total_cmp(&b.0))
                    .unwrap();
                if along > 0.0 && dist <= tol * along && best.is_none_or(|b| along < b.1) {
                    best = Some((s, along));
                }
            }
        }
        let best = best.expect("brute force finds the target");
        assert!(got.0 == best.0 && (got.1 - best.1).abs() < 0.02, "picked {got:?}, brute force {best:?}");
    }
}

/// A lasso picks the streamlines with a point inside it: short streamlines at the cells of a 10 x 10 grid seen
/// from above, a C-shaped (concave) lasso takes the 41 cells it encloses and none of its notch; hidden
/// streamlines and points that cannot be picked (outside a slab) are left out; against brute force with random
/// triangles (a barycentric test) on tracks300 through an oblique projection.
#[test]
fn a_lasso_picks_the_streamlines_with_a_point_inside() {
    let mut points = vec![];
    let mut offsets = vec![0];
    for s in 0..100 {
        let c = Vec3::new((s % 10) as f32, (s / 10) as f32, 0.0);
        points.extend([c - Vec3::X * 0.1, c + Vec3::X * 0.1]);
        offsets.push(points.len());
    }
    let top = |p: Vec3| Some(p.truncate());
    let c_shape = [(0.5, 0.5), (7.5, 0.5), (7.5, 2.5), (3.5, 2.5), (3.5, 4.5), (7.5, 4.5), (7.5, 7.5), (0.5, 7.5)]
        .map(|(x, y)| Vec2::new(x, y));
    let cell = |s: usize| (s % 10, s / 10);
    let want: Vec<usize> = (0..100)
        .filter(|&s| {
            let (x, y) = cell(s);
            (1..=7).contains(&x) && (1..=7).contains(&y) && !(x >= 4 && (3..=4).contains(&y))
        })
        .collect();
    assert_eq!(want.len(), 41);
    assert_eq!(lasso_streamlines(&Csr(&points, &offsets), |_| true, top, &c_shape), want);
    let without_11: Vec<usize> = want.iter().copied().filter(|&s| s != 11).collect();
    assert_eq!(lasso_streamlines(&Csr(&points, &offsets), |s| s != 11, top, &c_shape), without_11);
    let slab = |p: Vec3| (p.x < 5.5).then_some(p.truncate());
    let left: Vec<usize> = want.iter().copied().filter(|&s| cell(s).0 <= 5).collect();
    assert_eq!(lasso_streamlines(&Csr(&points, &offsets), |_| true, slab, &c_shape), left);
    assert!(lasso_streamlines(&Csr(&points, &offsets), |_| true, top, &c_shape[..2]).is_empty());
    assert!(in_polygon(&c_shape, Vec2::new(2.0, 3.0)) && !in_polygon(&c_shape, Vec2::new(5.0, 3.5)));

    let t = Tractogram::read(data("data/tracts/tracks300.trk")).unwrap();
    let oblique = |p: Vec3| Some(Vec2::new(p.x + 0.3 * p.z, p.y - 0.2 * p.z));
    let (lo, hi) = t.points.iter().fold((Vec2::MAX, Vec2::MIN), |(lo, hi), p| {
        let q = oblique(*p).unwrap();
        (lo.min(q), hi.max(q))
    });
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    let mut picked_some = 0;
    for _ in 0..30 {
        let tri: Vec<Vec2> =
            (0..3).map(|_| lo + (hi - lo) * Vec2::new(rng.random::<f32>(), rng.random::<f32>())).collect();
        let (a, b, c) = (tri[0], tri[1], tri[2]);
        let cross = |u: Vec2, v: Vec2| u.x * v.y - u.y * v.x;
        let area = cross(b - a, c - a);
        let inside = |q: Vec2| {
            let (w0, w1) = (cross(b - q, c - q) / area, cross(c - q, a - q) / area);
            w0 >= 0.0 && w1 >= 0.0 && 1.0 - w0 - w1 >= 0.0
        };
        let brute: Vec<usize> =
            (0..t.n_streamlines()).filter(|&s| t.streamline(s).iter().any(|p| inside(oblique(*p).unwrap()))).collect();
        let got = lasso_streamlines(&t, |_| true, oblique, &tri);
        assert_eq!(got, brute);
        picked_some += usize::from(!got.is_empty() && got.len() < t.n_streamlines());
    }
    assert!(picked_some > 5, "the triangles picked some but not all in {picked_some} of 30 cases");
}

/// A click in a 2D view picks the streamline with the step nearest on screen within the radius: three lines
/// stacked on screen, the nearest wins (the lower index on a tie); past a line's end its last point counts; a
/// one-point streamline is a point; steps outside the slab are left out; against brute force (dense samples of
/// each step) on tracks300.
#[test]
fn a_click_in_a_2d_view_picks_the_nearest_step_on_screen() {
    let mut points = vec![];
    let mut offsets = vec![0];
    for (k, y) in [0.0, 5.0, 10.0].into_iter().enumerate() {
        points.extend((0..11).map(|x| Vec3::new(x as f32, y, k as f32)));
        offsets.push(points.len());
    }
    points.push(Vec3::new(20.0, 20.0, 0.0));
    offsets.push(points.len());
    let top = |p: Vec3| Some(p.truncate());
    let pick =
        |at: (f32, f32), r: f32| pick_projected(&Csr(&points, &offsets), |_| true, top, Vec2::new(at.0, at.1), r);
    assert_eq!(pick((3.0, 1.0), 3.0), Some((0, 1.0)));
    assert_eq!(pick((3.0, 2.6), 3.0), Some((1, 2.4)));
    assert_eq!(pick((3.0, 2.5), 3.0), Some((0, 2.5)));
    assert_eq!(pick((3.0, 2.5), 2.0), None);
    assert_eq!(pick((12.0, 0.0), 3.0), Some((0, 2.0)));
    assert_eq!(pick((20.0, 21.0), 3.0), Some((3, 1.0)));
    let slab = |p: Vec3| (p.z > 0.5).then_some(p.truncate());
    assert_eq!(pick_projected(&Csr(&points, &offsets), |_| true, slab, Vec2::new(3.0, 1.0), 6.0), Some((1, 4.0)));
    assert_eq!(pick_projected(&Csr(&points, &offsets), |s| s != 1, slab, Vec2::new(3.0, 1.0), 6.0), None);

    let t = Tractogram::read(data("data/tracts/tracks300.trk")).unwrap();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
    for _ in 0..20 {
        let s = rng.random_range(0..t.n_streamlines());
        let pts = t.streamline(s);
        let at = pts[rng.random_range(0..pts.len())].truncate() + Vec2::new(rng.random::<f32>(), rng.random::<f32>());
        let got = pick_projected(&t, |_| true, top, at, 1.5).expect("a point within 1.5");
        let mut best = (usize::MAX, f32::MAX);
        for s in 0..t.n_streamlines() {
            for w in t.streamline(s).windows(2) {
                let d = (0..=400)
                    .map(|k| (w[0] + (w[1] - w[0]) * (k as f32 / 400.0)).truncate().distance(at))
                    .fold(f32::MAX, f32::min);
                if d < best.1 {
                    best = (s, d);
                }
            }
        }
        assert!(got.0 == best.0 || (got.1 - best.1).abs() < 1e-3, "picked {got:?}, brute force {best:?}");
        assert!((got.1 - best.1).abs() < 0.01, "picked {got:?}, brute force {best:?}");
    }
}

/// `tckedit -mask`: a streamline is cut where it leaves the union of the masks; the runs of two or more points
/// inside are kept in order, a lone point inside is dropped; wholly inside: the streamline; no masks: the
/// streamline; a plane contains no point.
#[test]
#[allow(clippy::single_range_in_vec_init, reason = "the pieces are ranges: a list of one piece")]
fn masks_cut_streamlines_into_the_runs_inside() {
    let pts: Vec<Vec3> = (0..10).map(|k| Vec3::new(k as f32, 0.0, 0.0)).collect();
    let sphere = |c: f32, r: f32| Region::Shape(RoiShape::Sphere { centre: [c, 0.0, 0.0], radius: r });
    let pieces = pieces_inside(&pts, &[sphere(2.0, 1.0), sphere(6.0, 0.5), sphere(8.5, 0.5)]);
    assert_eq!(pieces, [1..4, 8..10]);
    // Two masks touching make one run.
    assert_eq!(pieces_inside(&pts, &[sphere(2.0, 1.0), sphere(4.5, 0.5)]), [1..6]);
    assert_eq!(pieces_inside(&pts, &[sphere(4.5, 10.0)]), [0..10]);
    assert_eq!(pieces_inside(&pts, &[]), [0..10]);
    assert_eq!(pieces_inside(&pts, &[sphere(0.5, 0.5)]), [0..2]);
    let plane = Region::Shape(RoiShape::Plane { point: [0.0; 3], normal: [0.0, 1.0, 0.0] });
    assert!(pieces_inside(&pts, &[plane]).is_empty());
}
