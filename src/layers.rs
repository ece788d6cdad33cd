//! Turns the active [`Scene`] into entities, for the viewer and the headless renderer alike.
//!
//! Work happens only when the scene changes: a change of visibility or opacity updates the existing
//! entities and materials; a change of what the layers are (sources, slices) respawns them. A layer whose
//! file fails to load becomes an error message in [`LayerErrors`]; the others still show.

use bevy::asset::RenderAssetUsages;
use bevy::image::ImageSampler;
use bevy::mesh::{Indices, PrimitiveTopology};
use bevy::prelude::*;
use bevy::render::render_resource::{Extent3d, TextureDimension, TextureFormat};
use fascicle_core::Volume;
use fascicle_core::io::{Tractogram, nifti};

use bevy::render::storage::ShaderBuffer;
use fascicle_core::sh::glyph::{Glyph, GlyphPlane, GlyphStyle, Sampling, make_glyphs, sample_plane};
use fascicle_core::sh::{self, OdfKind, OdfModel, ShBasis};
use fascicle_sh_glyphs::{
    Selection, ShField, ShGlyphMaterial, ShGlyphPlugin, ShGlyphSet, field_glyphs, spawn_glyph_set, update_settings,
};
use fascicle_tensors::layer::{field_splats, field_tensor_glyphs};
use fascicle_tensors::splat::{SplatMaterial, SplatSet, spawn_splats};
use fascicle_tensors::{
    SplatShape, TensorField, TensorGlyphMaterial, TensorGlyphPlugin, TensorGlyphSet, TensorGlyphShape,
    spawn_tensor_glyphs,
};
use fascicle_tracts::{
    MeshSet, TractMeshMaterial, TractPlugin, TractRoi, TractSet, TubeSet, TubeletMaterial, line_mesh, spawn_lines,
    spawn_polygon_tubes, spawn_tubes,
};
use fascicle_volume::{OpaqueDepth, VolumeMaterial, VolumePlugin, VolumeSet, spawn_volume};

use crate::panels::{LayerData, LayerDataMap, SCATTER_SAMPLES};
use crate::scene::{
    LayerKind, LayerSpec, Scene, ShSource, SliceAxis, TensorSource, TractMode, TractSource, VolumeSource,
};

/// The scene being shown.
#[derive(Resource, Clone, Debug)]
pub struct ActiveScene(pub Scene);

/// Load errors of the current scene's layers, shown by the viewer and returned by the headless renderer.
#[derive(Resource, Default, Debug)]
pub struct LayerErrors(pub Vec<String>);

/// Marks the entities of layer `0` (index into the scene's layers).
#[derive(Component, Clone, Copy)]
pub struct LayerEntity(pub usize);

/// What was spawned, to tell parameter changes from structural ones.
#[derive(Resource, Default)]
struct Spawned(Vec<LayerKind>);

pub struct ScenePlugin;

impl Plugin for ScenePlugin {
    fn build(&self, app: &mut App) {
        if !app.is_plugin_added::<ShGlyphPlugin>() {
            app.add_plugins(ShGlyphPlugin);
        }
        if !app.is_plugin_added::<TensorGlyphPlugin>() {
            app.add_plugins(TensorGlyphPlugin);
        }
        if !app.is_plugin_added::<VolumePlugin>() {
            app.add_plugins(VolumePlugin);
        }
        if !app.is_plugin_added::<TractPlugin>() {
            app.add_plugins(TractPlugin);
        }
        app.init_resource::<LayerErrors>()
            .init_resource::<Spawned>()
            .init_resource::<LayerDataMap>()
            .add_systems(Update, (sync_scene.run_if(resource_exists_and_changed::<ActiveScene>), report_layer_data));
    }
}

/// Refreshes what spawned layers report to their panels when a layer was (re)spawned.
fn report_layer_data(
    added: Query<(), Added<LayerEntity>>,
    sets: Query<(&SplatSet, &LayerEntity)>,
    volumes: Query<(&VolumeSet, &LayerEntity)>,
    mut map: ResMut<LayerDataMap>,
) {
    if added.is_empty() {
        return;
    }
    map.0.clear();
    for (set, le) in &sets {
        let stride = set.len().div_ceil(SCATTER_SAMPLES).max(1);
        let values = set.splats.iter().step_by(stride).map(|s| s.values).collect();
        map.0.insert(le.0, LayerData { eigenvalues: std::sync::Arc::new(values), ..default() });
    }
    for (set, le) in &volumes {
        map.0.insert(le.0, LayerData { histogram: set.histogram.clone(), ..default() });
    }
}

#[expect(clippy::too_many_arguments, reason = "a Bevy system's parameters are its data dependencies")]
fn sync_scene(
    mut commands: Commands,
    scene: Res<ActiveScene>,
    mut spawned: ResMut<Spawned>,
    mut errors: ResMut<LayerErrors>,
    existing: Query<LayerParts, Without<TractRoi>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut images: ResMut<Assets<Image>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    mut glyph_materials: ResMut<Assets<ShGlyphMaterial>>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
    mut glyph_sets: Query<(&mut ShGlyphSet, &LayerEntity)>,
    tensor: TensorAssets,
    volume: VolumeAssets,
    tracts: TractAssets,
) {
    let TensorAssets {
        glyph_materials: mut tensor_materials,
        glyph_sets: tensor_sets,
        mut splat_materials,
        mut splat_sets,
    } = tensor;
    let VolumeAssets { materials: mut volume_materials, sets: volume_sets, depth } = volume;
    let TractAssets {
        materials: mut tube_materials,
        sets: tract_sets,
        rois: roi_entities,
        mesh_sets,
        mut mesh_materials,
    } = tracts;
    let kinds: Vec<LayerKind> = scene.0.layers.iter().map(|l| l.kind.clone()).collect();
    let structure = |k: &[LayerKind]| k.iter().map(LayerKind::structure).collect::<Vec<_>>();
    if structure(&kinds) == structure(&spawned.0) {
        // Draw settings of glyph layers: a uniform update, nothing re-uploaded.
        for (mut set, le) in &mut glyph_sets {
            if let Some(LayerKind::ShGlyphs { render, .. }) = kinds.get(le.0)
                && spawned.0.get(le.0) != kinds.get(le.0)
            {
                update_settings(&mut glyph_materials, &mut set, render);
            }
        }
        for (mut set, le) in &mut splat_sets {
            if let Some(LayerKind::TensorSplats { render, .. }) = kinds.get(le.0)
                && let Some(LayerKind::TensorSplats { render: before, .. }) = spawned.0.get(le.0)
                && render != before
            {
                if render.colouring != before.colouring {
                    // Colour and opacity only: the style buffer, not the geometry or the order.
                    set.restyle(&render.colouring, &splat_materials, &mut buffers);
                }
                if let Some(mut m) = splat_materials.get_mut(&set.material) {
                    m.params = render.into();
                }
            }
        }
        for (set_entity, tubes, le) in &tract_sets {
            if let Some(LayerKind::Tracts { render, rois, .. }) = kinds.get(le.0)
                && spawned.0.get(le.0) != kinds.get(le.0)
            {
                if let Some(tubes) = tubes
                    && let Some(mut m) = tube_materials.get_mut(&tubes.material)
                {
                    m.params = render.into();
                }
                if let Some(LayerKind::Tracts { rois: before, .. }) = spawned.0.get(le.0)
                    && before != rois
                {
                    for (e, rle) in &roi_entities {
                        if rle.0 == le.0 {
                            commands.entity(e).despawn();
                        }
                    }
                    spawn_rois(&mut commands, rois, le.0, set_entity);
                }
            }
        }
        for (set, le) in &volume_sets {
            if let Some(LayerKind::Volume { render, .. }) = kinds.get(le.0)
                && spawned.0.get(le.0) != kinds.get(le.0)
            {
                // The transfer function's table and pre-integration table, and the uniform.
                set.write_style(render, true, &mut volume_materials, &mut buffers);
            }
        }
        for (set, le) in &tensor_sets {
            if let Some(LayerKind::TensorGlyphs { render, .. }) = kinds.get(le.0)
                && spawned.0.get(le.0) != kinds.get(le.0)
                && let Some(mut m) = tensor_materials.get_mut(&set.material)
            {
                m.params = render.into();
            }
        }
        spawned.0 = kinds;
        for (mesh, le) in &mesh_sets {
            let opacity = scene.0.layers.get(le.0).map_or(1.0, |l| l.opacity.clamp(0.0, 1.0));
            if mesh_materials.get(&mesh.material).is_some_and(|m| m.params.opacity != opacity)
                && let Some(mut m) = mesh_materials.get_mut(&mesh.material)
            {
                m.params.opacity = opacity;
            }
        }
        for (e, le, mat) in &existing {
            let Some(spec) = scene.0.layers.get(le.0) else { continue };
            commands.entity(e).insert(if spec.visible { Visibility::Inherited } else { Visibility::Hidden });
            if let Some(mut m) = mat.and_then(|m| materials.get_mut(&m.0)) {
                set_opacity(&mut m, spec.opacity);
            }
        }
        return;
    }
    for (e, _, _) in &existing {
        commands.entity(e).despawn();
    }
    for (e, _) in &roi_entities {
        // ROIs of a tract set were despawned with it.
        commands.entity(e).try_despawn();
    }
    errors.0.clear();
    for (i, spec) in scene.0.layers.iter().enumerate() {
        let vis = if spec.visible { Visibility::Inherited } else { Visibility::Hidden };
        if let LayerKind::ShGlyphs { source, axis, index, spacing, plane, sampling, full_volume, style, render } =
            &spec.kind
        {
            let glyphs = match plane {
                _ if *full_volume => volume_glyphs(source, *spacing, *style),
                Some(p) => free_plane_glyphs(source, p, *sampling, *style),
                None => plane_glyphs(source, *axis, *index, *spacing, *style),
            };
            let set = glyphs.map(|(g, v)| {
                spawn_glyph_set(&mut commands, &mut meshes, &mut glyph_materials, &mut buffers, &g, Some(&v), render)
            });
            place(&mut commands, &mut errors, set, spec, vis, i);
            continue;
        }
        if let LayerKind::TensorSplats { source, axis, index, thickness, size, min_fa, render } = &spec.kind {
            let set = slab_splats(source, *axis, *index, *thickness, *size, *min_fa).map(|mut s| {
                render.colouring.apply(&mut s);
                spawn_splats(&mut commands, &mut meshes, &mut splat_materials, &mut buffers, &s, render)
            });
            place(&mut commands, &mut errors, set, spec, vis, i);
            continue;
        }
        if let LayerKind::Tracts { source, mode, render, rois } = &spec.kind {
            let (t, tensors) = match tract_data(source) {
                Ok((t, tensors)) => (std::sync::Arc::new(t), tensors),
                Err(e) => {
                    errors.0.push(format!("layer '{}': {e}", spec.name));
                    continue;
                }
            };
            let (c, m, b) = (&mut commands, &mut meshes, &mut buffers);
            let set = match mode {
                TractMode::Tubes => spawn_tubes(c, m, &mut tube_materials, b, t, tensors.as_deref(), render),
                TractMode::Polygon => {
                    spawn_polygon_tubes(c, m, &mut mesh_materials, b, t, tensors.as_deref(), render.scale, spec.opacity)
                }
                TractMode::Lines => spawn_lines(c, m, &mut mesh_materials, b, t, spec.opacity),
            };
            place(&mut commands, &mut errors, Ok(set), spec, vis, i);
            spawn_rois(&mut commands, rois, i, set);
            continue;
        }
        if let LayerKind::Volume { source, render } = &spec.kind {
            let set = match (scalar_volume(source), depth.as_deref()) {
                (Ok(vol), Some(depth)) => Ok(spawn_volume(
                    &mut commands,
                    &mut meshes,
                    &mut images,
                    &mut volume_materials,
                    &mut buffers,
                    depth,
                    &vol,
                    render,
                )),
                (Err(e), _) => Err(e),
                (_, None) => Err("the volume plugin has not started".into()),
            };
            place(&mut commands, &mut errors, set, spec, vis, i);
            continue;
        }
        if let LayerKind::TensorGlyphs { source, axis, index, spacing, size, min_fa, render } = &spec.kind {
            let set = slice_tensor_glyphs(source, *axis, *index, *spacing, *size, *min_fa).map(|(g, v)| {
                spawn_tensor_glyphs(
                    &mut commands,
                    &mut meshes,
                    &mut tensor_materials,
                    &mut buffers,
                    &g,
                    Some(&v),
                    render,
                )
            });
            place(&mut commands, &mut errors, set, spec, vis, i);
            continue;
        }
        match spawn_layer(spec, &mut meshes, &mut images, &mut materials) {
            Ok(parts) => {
                for (mesh, mat, tf) in parts {
                    commands.spawn((Mesh3d(mesh), MeshMaterial3d(mat), tf, vis, LayerEntity(i)));
                }
            }
            Err(e) => errors.0.push(format!("layer '{}': {e}", spec.name)),
        }
    }
    spawned.0 = kinds;
}

/// Tags a plugin-spawned layer root with its layer and visibility, or records why it could not be built.
fn place(
    commands: &mut Commands,
    errors: &mut LayerErrors,
    root: Result<Entity, String>,
    spec: &LayerSpec,
    vis: Visibility,
    index: usize,
) {
    match root {
        Ok(e) => {
            commands.entity(e).insert((vis, LayerEntity(index)));
        }
        Err(e) => errors.0.push(format!("layer '{}': {e}", spec.name)),
    }
}

/// A tract layer's ROIs, as children of its set: they act on this layer only and go when it goes.
fn spawn_rois(commands: &mut Commands, rois: &[fascicle_core::roi::Roi], layer: usize, set: Entity) {
    for r in rois {
        commands.spawn((TractRoi(*r), LayerEntity(layer), ChildOf(set)));
    }
}

fn set_opacity(m: &mut StandardMaterial, opacity: f32) {
    let a = opacity.clamp(0.0, 1.0);
    m.base_color.set_alpha(a);
    m.alpha_mode = if a < 1.0 { AlphaMode::Blend } else { AlphaMode::Opaque };
}

type Part = (Handle<Mesh>, Handle<StandardMaterial>, Transform);

fn unlit(opacity: f32) -> StandardMaterial {
    let mut m = StandardMaterial { base_color: Color::WHITE, unlit: true, cull_mode: None, ..default() };
    set_opacity(&mut m, opacity);
    m
}

fn spawn_layer(
    spec: &LayerSpec,
    meshes: &mut Assets<Mesh>,
    images: &mut Assets<Image>,
    materials: &mut Assets<StandardMaterial>,
) -> Result<Vec<Part>, String> {
    match &spec.kind {
        LayerKind::Axes { length_mm } => {
            let (l, w) = (*length_mm, length_mm / 40.0);
            let axes = [
                (Vec3::new(l, w, w), Vec3::X, Color::linear_rgb(1.0, 0.1, 0.1)),
                (Vec3::new(w, l, w), Vec3::Y, Color::linear_rgb(0.1, 1.0, 0.1)),
                (Vec3::new(w, w, l), Vec3::Z, Color::linear_rgb(0.2, 0.3, 1.0)),
            ];
            Ok(axes
                .into_iter()
                .map(|(size, dir, color)| {
                    let mut m = unlit(spec.opacity);
                    m.base_color = color.with_alpha(spec.opacity);
                    (meshes.add(Cuboid::from_size(size)), materials.add(m), Transform::from_translation(dir * l * 0.5))
                })
                .collect())
        }
        LayerKind::Slice { source, axis, index } => {
            let (vol, channel, fixed_window) = match source {
                VolumeSource::PhantomFa => (fascicle_core::phantom::ring_cross(PHANTOM_DIMS).fa(), 0, Some((0.0, 1.0))),
                VolumeSource::Nifti { path, volume } => (read_channel_source(path, *volume)?, *volume, None),
            };
            let (image, corners) = slice_image(&vol, channel, *axis, *index, fixed_window)?;
            let mut m = unlit(spec.opacity);
            m.base_color_texture = Some(images.add(image));
            Ok(vec![(meshes.add(quad(corners)), materials.add(m), Transform::IDENTITY)])
        }
        LayerKind::ShGlyphs { .. }
        | LayerKind::TensorGlyphs { .. }
        | LayerKind::TensorSplats { .. }
        | LayerKind::Volume { .. }
        | LayerKind::Tracts { .. } => Ok(vec![]), // spawned by their plugins
        LayerKind::Tractogram { path } => {
            let t = Tractogram::read(path).map_err(|e| e.to_string())?;
            if t.points.is_empty() {
                return Err("the tractogram holds no points".into());
            }
            Ok(vec![(meshes.add(line_mesh(&t)), materials.add(unlit(spec.opacity)), Transform::IDENTITY)])
        }
    }
}

/// A NIfTI image checked to have a 4th-dimension index `volume`.
fn read_channel_source(path: &std::path::Path, volume: usize) -> Result<Volume<f32>, String> {
    let (v, _) = nifti::read::<f32>(path).map_err(|e| e.to_string())?;
    if volume >= v.n_channels() {
        return Err(format!("volume {volume} requested, the image has {}", v.n_channels()));
    }
    Ok(v)
}

/// One 3D scalar volume of a source (the chosen 4th-dimension index of a NIfTI).
fn scalar_volume(source: &VolumeSource) -> Result<Volume<f32>, String> {
    match source {
        VolumeSource::PhantomFa => Ok(fascicle_core::phantom::ring_cross(PHANTOM_DIMS).fa()),
        VolumeSource::Nifti { path, volume } => {
            let v = read_channel_source(path, *volume)?;
            let d = v.dims3();
            let n = d[0] * d[1] * d[2];
            let mut out = Volume::zeros(&d, v.world_from_voxel);
            out.data.copy_from_slice(&v.data[volume * n..(volume + 1) * n]);
            Ok(out)
        }
    }
}

/// What tensor glyph and splat layers need.
#[derive(bevy::ecs::system::SystemParam)]
struct TensorAssets<'w, 's> {
    glyph_materials: ResMut<'w, Assets<TensorGlyphMaterial>>,
    glyph_sets: Query<'w, 's, (&'static TensorGlyphSet, &'static LayerEntity)>,
    splat_materials: ResMut<'w, Assets<SplatMaterial>>,
    splat_sets: Query<'w, 's, (&'static mut SplatSet, &'static LayerEntity)>,
}

/// The volume plugin's asset stores a volume layer needs.
#[derive(bevy::ecs::system::SystemParam)]
struct VolumeAssets<'w, 's> {
    materials: ResMut<'w, Assets<VolumeMaterial>>,
    sets: Query<'w, 's, (&'static VolumeSet, &'static LayerEntity)>,
    depth: Option<Res<'w, OpaqueDepth>>,
}

/// What a tract layer needs: its material store, its sets and its ROI entities.
#[derive(bevy::ecs::system::SystemParam)]
struct TractAssets<'w, 's> {
    materials: ResMut<'w, Assets<TubeletMaterial>>,
    sets: Query<'w, 's, (Entity, Option<&'static TubeSet>, &'static LayerEntity), With<TractSet>>,
    mesh_sets: Query<'w, 's, (&'static MeshSet, &'static LayerEntity)>,
    mesh_materials: ResMut<'w, Assets<TractMeshMaterial>>,
    rois: Query<'w, 's, (Entity, &'static LayerEntity), With<TractRoi>>,
}

/// A layer's spawned entities (ROIs aside) and their standard material, if any.
type LayerParts = (Entity, &'static LayerEntity, Option<&'static MeshMaterial3d<StandardMaterial>>);

/// Streamlines and, when the source has them, per-point world tensors.
pub type TractData = (Tractogram, Option<Vec<[f32; 6]>>);

/// A tract source's streamlines, with per-point world tensors when it has them.
pub fn tract_data(source: &TractSource) -> Result<TractData, String> {
    match source {
        TractSource::PhantomRk4 { seed_spacing } => {
            use fascicle_core::tracking::{TensorField, TensorInterpolation, TrackParams, Tracker};
            let spacing = (*seed_spacing).max(1);
            let ph = fascicle_core::phantom::ring_cross(PHANTOM_DIMS);
            let a = ph.world_from_voxel;
            let voxel = glam::DVec3::new(a.x_axis.length(), a.y_axis.length(), a.z_axis.length());
            let field = TensorField::new(
                ph.dims,
                voxel,
                ph.tensors.iter().map(|t| Some(*t)),
                TensorInterpolation::Componentwise,
            )
            .map_err(|e| e.to_string())?;
            let z = ph.dims[2] / 2;
            let seeds: Vec<glam::DVec3> = (0..ph.dims[1])
                .step_by(spacing)
                .flat_map(|y| (0..ph.dims[0]).step_by(spacing).map(move |x| [x, y]))
                .filter(|[x, y]| {
                    let t = ph.tensors[x + ph.dims[0] * (y + ph.dims[1] * z)];
                    fascicle_core::dti::eigh(&t).is_some_and(|e| fascicle_core::dti::metrics::fa(&e.values) >= 0.3)
                })
                .map(|[x, y]| glam::DVec3::new(x as f64, y as f64, z as f64))
                .collect();
            let params = TrackParams { step_mm: 1.0, ..TrackParams::default() };
            let tracks = Tracker::new(&field, a, params).map_err(|e| e.to_string())?.run(&seeds);
            Ok((tracks.tractogram, Some(tracks.tensors)))
        }
        TractSource::File { path, tensors } => {
            let t = Tractogram::read(path).map_err(|e| e.to_string())?;
            let Some(source) = tensors else { return Ok((t, None)) };
            use fascicle_core::tracking::{TensorField, TensorInterpolation, tensors_at};
            let f = tensor_field(source)?.tensors;
            let (dims, affine, n) = (f.dims3(), f.world_from_voxel, f.n_voxels());
            let grid: Vec<[f64; 6]> = (0..n).map(|i| std::array::from_fn(|c| f.data[i + n * c] as f64)).collect();
            let voxel = glam::DVec3::new(affine.x_axis.length(), affine.y_axis.length(), affine.z_axis.length());
            let field = TensorField::new(dims, voxel, grid.into_iter().map(Some), TensorInterpolation::Componentwise)
                .map_err(|e| e.to_string())?;
            let sampled = tensors_at(&field, affine, &t.points);
            Ok((t, Some(sampled)))
        }
        TractSource::Peaks { path, length } => Ok((peak_segments(path, *length)?, None)),
    }
}

/// One two-point streamline per peak of a peaks image, through its voxel centre in world coordinates, the
/// voxel's largest peak `length` voxels (of its smallest edge) long and the others in proportion.
pub fn peak_segments(path: &std::path::Path, length: f32) -> Result<Tractogram, String> {
    let img = fascicle_core::io::peaks::read(path).map_err(|e| e.to_string())?;
    let a = img.world_from_voxel;
    let m = fascicle_core::io::peaks::direction_frame(a);
    let edge = min_edge(a);
    let [nx, ny, _] = img.dims;
    let k = img.npeaks;
    let mut t = Tractogram::new();
    for v in 0..img.amplitudes.len() / k {
        let amps = &img.amplitudes[v * k..(v + 1) * k];
        let top = amps.iter().copied().fold(0.0f32, f32::max);
        if top.is_nan() || top <= 0.0 {
            continue;
        }
        let centre =
            a.transform_point3(glam::DVec3::new((v % nx) as f64, ((v / nx) % ny) as f64, (v / (nx * ny)) as f64));
        for (d, amp) in img.dirs[v * k..(v + 1) * k].iter().zip(amps) {
            if *amp > 0.0 {
                let half = m * glam::Vec3::from(*d).as_dvec3() * (0.5 * edge * f64::from(length * amp / top));
                t.points.extend([(centre - half).as_vec3(), (centre + half).as_vec3()]);
                t.offsets.push(t.points.len());
            }
        }
    }
    Ok(t)
}

/// The grid of the scenes' built-in ring/cross phantom.
const PHANTOM_DIMS: [usize; 3] = [48, 48, 24];

/// The SH field (coefficients X,Y,Z,n and their basis, checked by `ShField::new`) of a glyph layer; for the phantom only the voxels of
/// `mask` are fitted.
fn sh_field(source: &ShSource, mask: impl Fn([usize; 3]) -> bool) -> Result<ShField, String> {
    match source {
        ShSource::PhantomCsa { l_max } => {
            let ph = fascicle_core::phantom::ring_cross(PHANTOM_DIMS);
            let (dwi, gtab) = ph.dwi(64, 1000.0).map_err(|e| e.to_string())?;
            let basis = ShBasis::default();
            let model = OdfModel::new(&gtab, OdfKind::Csa, *l_max, 0.006, basis).map_err(|e| e.to_string())?;
            let d = ph.dims;
            let m: Vec<bool> =
                (0..d.iter().product()).map(|v| mask([v % d[0], (v / d[0]) % d[1], v / (d[0] * d[1])])).collect();
            ShField::new(sh::fit_odf_volume(&dwi, &model, Some(&m)).map_err(|e| e.to_string())?, basis)
        }
        ShSource::Nifti { path, basis } => {
            let (v, _) = nifti::read::<f32>(path).map_err(|e| e.to_string())?;
            ShField::new(v, *basis).map_err(|e| format!("{}: {e}", path.display()))
        }
    }
}

/// Glyphs on a free plane of interest (any orientation; nearest or trilinear sampling). For the phantom,
/// only voxels within two voxels of the plane are fitted.
pub fn free_plane_glyphs(
    source: &ShSource,
    plane: &GlyphPlane,
    sampling: Sampling,
    style: GlyphStyle,
) -> Result<(Vec<Glyph>, Vec<[u32; 3]>), String> {
    let near_plane = |affine: glam::DMat4| {
        let (c, n) = (glam::DVec3::from_array(plane.centre), glam::DVec3::from_array(plane.normal).normalize_or_zero());
        move |p: [usize; 3]| {
            let w = affine.transform_point3(glam::DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64));
            (w - c).dot(n).abs() <= 2.0 * affine.x_axis.truncate().length().max(affine.z_axis.truncate().length())
        }
    };
    let affine = fascicle_core::phantom::ring_cross(PHANTOM_DIMS).world_from_voxel;
    let field = sh_field(source, near_plane(affine))?;
    let items = sample_plane(&field.coeffs, plane, sampling).map_err(|e| e.to_string())?;
    let style = style.resolved(plane.spacing);
    let (glyphs, skipped) =
        make_glyphs(items.iter().map(|(p, c, _)| (*p, &c[..])), field.basis, style).map_err(|e| e.to_string())?;
    let voxels = items.iter().enumerate().filter(|(i, _)| !skipped.contains(i)).map(|(_, it)| it.2).collect();
    Ok((glyphs, voxels))
}

/// Tensor glyphs on a slice: one per `spacing`-th voxel with FA >= `min_fa`, tensors rotated into the world
/// frame, largest diameter `size` times the glyph spacing (the plugin's `field_tensor_glyphs`).
pub fn slice_tensor_glyphs(
    source: &TensorSource,
    axis: SliceAxis,
    index: Option<usize>,
    spacing: usize,
    size: f64,
    min_fa: f64,
) -> Result<(Vec<fascicle_core::dti::glyph::TensorGlyph>, Vec<[u32; 3]>), String> {
    if let TensorSource::Spiral { n } = source {
        if spacing == 0 {
            return Err("glyph spacing must be at least 1 voxel".into());
        }
        let (mut glyphs, mut voxels) = (Vec::new(), Vec::new());
        for (i, (centre, t)) in fascicle_core::phantom::spiral(*n).into_iter().enumerate() {
            if let Some(g) = fascicle_core::dti::glyph::tensor_glyph(centre, &t, size * SPIRAL_EDGE / 2.0, 0.1)
                && g.fa >= min_fa
            {
                glyphs.push(g);
                voxels.push([i as u32, 0, 0]);
            }
        }
        return Ok((glyphs, voxels));
    }
    let selection = Selection::Slice { axis, index, spacing };
    field_tensor_glyphs(&tensor_field(source)?, &selection, &TensorGlyphShape { size, min_fa, ..default() })
}

/// Splats of a slab of `thickness` slices centred on a slice: covariance largest standard deviation `size`
/// voxels (colour and opacity unset: apply a `SplatColouring`); the plugin's `field_splats`.
pub fn slab_splats(
    source: &TensorSource,
    axis: SliceAxis,
    index: Option<usize>,
    thickness: usize,
    size: f64,
    min_fa: f64,
) -> Result<Vec<fascicle_core::dti::splat::Splat>, String> {
    if let TensorSource::Spiral { n } = source {
        return Ok(fascicle_core::phantom::spiral(*n)
            .into_iter()
            .filter_map(|(c, t)| {
                fascicle_core::dti::splat::tensor_splat(c, &t, size * SPIRAL_EDGE, glam::DVec3::ONE, 1.0)
            })
            .filter(|s| s.fa() >= min_fa)
            .collect());
    }
    let selection = Selection::Slab { axis, index, thickness };
    field_splats(&tensor_field(source)?, &selection, &SplatShape { size, min_fa })
}

/// The length sizes of spiral glyphs and splats are fractions of (mm): about the spacing of its tensors.
const SPIRAL_EDGE: f64 = 8.0;

fn min_edge(affine: glam::DMat4) -> f64 {
    [affine.x_axis, affine.y_axis, affine.z_axis].iter().map(|c| c.truncate().length()).fold(f64::MAX, f64::min)
}

/// The tensors of a source, as the tensor plugin's asset.
fn tensor_field(source: &TensorSource) -> Result<TensorField, String> {
    match source {
        TensorSource::Phantom => {
            let p = fascicle_core::phantom::ring_cross(PHANTOM_DIMS);
            let data = (0..6).flat_map(|c| p.tensors.iter().map(move |t| t[c] as f32)).collect();
            let shape = vec![p.dims[0], p.dims[1], p.dims[2], 6];
            TensorField::new(Volume { shape, data, world_from_voxel: p.world_from_voxel })
        }
        TensorSource::Spiral { .. } => Err("the spiral is not a voxel grid".into()),
        TensorSource::Nifti { path } => {
            let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
            fascicle_tensors::layer::read_field(bytes, path)
        }
    }
}

/// One glyph per `spacing`-th voxel (along each axis) of the whole field with signal (`c00 > 0`).
pub fn volume_glyphs(
    source: &ShSource,
    spacing: usize,
    style: GlyphStyle,
) -> Result<(Vec<Glyph>, Vec<[u32; 3]>), String> {
    let selection = Selection::Volume { spacing };
    selection.voxels([0; 3])?;
    let field = sh_field(source, |p| p.iter().all(|c| c.is_multiple_of(spacing.max(1))))?;
    field_glyphs(&field, &selection, style)
}

/// One glyph per `spacing`-th voxel of a slice (voxel centres, nearest sampling), skipping voxels with no
/// signal.
pub fn plane_glyphs(
    source: &ShSource,
    axis: SliceAxis,
    index: Option<usize>,
    spacing: usize,
    style: GlyphStyle,
) -> Result<(Vec<Glyph>, Vec<[u32; 3]>), String> {
    Selection::Volume { spacing }.voxels([0; 3])?;
    let ax = axis.index();
    // The phantom's grid is known before fitting (only its slice is fitted); a file's is checked after reading.
    let k = match source {
        ShSource::PhantomCsa { .. } => Some(index.unwrap_or(PHANTOM_DIMS[ax] / 2)),
        ShSource::Nifti { .. } => index,
    };
    let field = sh_field(source, |p| k.is_none_or(|k| p[ax] == k))?;
    field_glyphs(&field, &Selection::Slice { axis, index: k, spacing }, style)
}

/// A grey image of one slice (values mapped from `window` or [min, 99.5th percentile]) and the world
/// positions of its four outer voxel corners, counter-clockwise from voxel (0, 0).
pub fn slice_image(
    vol: &Volume<f32>,
    channel: usize,
    axis: SliceAxis,
    index: Option<usize>,
    window: Option<(f32, f32)>,
) -> Result<(Image, [Vec3; 4]), String> {
    let d = vol.dims3();
    let (ax, u, v) = match axis {
        SliceAxis::X => (0, 1, 2),
        SliceAxis::Y => (1, 0, 2),
        SliceAxis::Z => (2, 0, 1),
    };
    let k = index.unwrap_or(d[ax] / 2);
    if k >= d[ax] {
        return Err(format!("slice {k} is outside the volume's {} slices along {axis:?}", d[ax]));
    }
    let nvox = vol.n_voxels();
    let at = |i: usize, j: usize| {
        let mut p = [0usize; 3];
        p[ax] = k;
        p[u] = i;
        p[v] = j;
        vol.data[p[0] + d[0] * (p[1] + d[1] * p[2]) + nvox * channel]
    };
    let (lo, hi) = window.unwrap_or_else(|| {
        let mut vals: Vec<f32> =
            vol.data[nvox * channel..nvox * (channel + 1)].iter().copied().filter(|x| x.is_finite()).collect();
        vals.sort_by(f32::total_cmp);
        let lo = vals.first().copied().unwrap_or(0.0);
        let hi = vals.get((vals.len().saturating_sub(1)) * 995 / 1000).copied().unwrap_or(1.0);
        (lo, if hi > lo { hi } else { lo + 1.0 })
    });
    let (w, h) = (d[u], d[v]);
    let mut px = Vec::with_capacity(w * h * 4);
    for j in 0..h {
        for i in 0..w {
            let x = at(i, j);
            let g = if x.is_finite() { ((x - lo) / (hi - lo)).clamp(0.0, 1.0) } else { 0.0 };
            let b = (g * 255.0).round() as u8;
            px.extend_from_slice(&[b, b, b, 255]);
        }
    }
    let mut image = Image::new(
        Extent3d { width: w as u32, height: h as u32, depth_or_array_layers: 1 },
        TextureDimension::D2,
        px,
        TextureFormat::Rgba8Unorm,
        RenderAssetUsages::RENDER_WORLD,
    );
    image.sampler = ImageSampler::nearest();
    let corner = |a: f64, b: f64| {
        let mut p = [0f64; 3];
        p[ax] = k as f64;
        p[u] = a;
        p[v] = b;
        vol.world_from_voxel.transform_point3(glam::DVec3::from_array(p)).as_vec3()
    };
    let (a1, b1) = (w as f64 - 0.5, h as f64 - 0.5);
    Ok((image, [corner(-0.5, -0.5), corner(a1, -0.5), corner(a1, b1), corner(-0.5, b1)]))
}

fn quad(c: [Vec3; 4]) -> Mesh {
    let n = (c[1] - c[0]).cross(c[3] - c[0]).normalize_or_zero();
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, c.to_vec())
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, vec![n; 4])
        .with_inserted_attribute(Mesh::ATTRIBUTE_UV_0, vec![[0.0f32, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        .with_inserted_indices(Indices::U32(vec![0, 1, 2, 0, 2, 3]))
}

/// Camera transform and projection for a scene's camera spec.
pub fn camera_from_spec(spec: &crate::scene::CameraSpec) -> (Transform, Projection) {
    let eye = Vec3::from_array(spec.eye);
    let tf = Transform::from_translation(eye).looking_at(Vec3::from_array(spec.target), Vec3::from_array(spec.up));
    let proj = Projection::Perspective(PerspectiveProjection {
        fov: spec.fov_y_deg.to_radians(),
        near: crate::render::NEAR,
        ..default()
    });
    (tf, proj)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Tracts from a file with a tensor field: the phantom's RK4 tracts written to `.tck` and read back with
    /// the phantom's tensors carry the tensors the tracker recorded (to f32 rounding of the points);
    /// without, none; a field that is not a voxel grid is a clear error.
    #[test]
    fn file_tracts_take_tensors_from_a_field() {
        let (t, tracked) = tract_data(&TractSource::PhantomRk4 { seed_spacing: 6 }).unwrap();
        let tracked = tracked.unwrap();
        let path = std::env::temp_dir().join(format!("fascicle-file-tensors-{}.tck", std::process::id()));
        fascicle_core::io::tck::write(&path, &t, &[]).unwrap();
        let file = |tensors| TractSource::File { path: path.clone(), tensors };
        let (back, sampled) = tract_data(&file(Some(TensorSource::Phantom))).unwrap();
        let sampled = sampled.unwrap();
        assert_eq!(back.points.len(), tracked.len());
        let scale = tracked.iter().flatten().fold(0f32, |m, v| m.max(v.abs()));
        let worst = sampled
            .iter()
            .zip(&tracked)
            .flat_map(|(a, b)| a.iter().zip(b).map(|(x, y)| (x - y).abs()))
            .fold(0f32, f32::max);
        assert!(worst <= 1e-4 * scale, "{worst} vs {scale}");
        assert!(tract_data(&file(None)).unwrap().1.is_none());
        let err = tract_data(&file(Some(TensorSource::Spiral { n: 10 }))).unwrap_err();
        assert!(err.contains("not a voxel grid"), "{err}");
        std::fs::remove_file(path).ok();
    }

    /// A peaks file opens as a line layer: one segment per peak, centred on its voxel, along the peak's world
    /// direction, the largest `length` voxels long and the others in proportion to their amplitudes.
    #[test]
    fn peak_files_open_as_segments() {
        use fascicle_core::sh::PeakVolume;
        let dims = [3, 2, 2];
        let n = 12;
        let mut peaks = PeakVolume {
            dims,
            npeaks: 2,
            dirs: vec![[0.0; 3]; n * 2],
            values: vec![0.0; n * 2],
            indices: vec![-1; n * 2],
            gfa: vec![0.0; n],
        };
        // Voxel (1,1,0): a peak along x of amplitude 2 and one along y of amplitude 1.
        let v = 1 + 3;
        peaks.dirs[v * 2] = [1.0, 0.0, 0.0];
        peaks.dirs[v * 2 + 1] = [0.0, 1.0, 0.0];
        peaks.values[v * 2..v * 2 + 2].copy_from_slice(&[2.0, 1.0]);
        peaks.indices[v * 2..v * 2 + 2].copy_from_slice(&[0, 1]);
        // A flipped, scaled affine: x runs right to left, 2 mm voxels.
        let affine = glam::DMat4::from_cols_array(&[
            -2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 10.0, 0.0, 0.0, 1.0,
        ]);
        let dir = std::env::temp_dir().join(format!("fascicle-peak-layer-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("csa_peaks.nii.gz");
        fascicle_core::io::peaks::write_mrtrix(&path, &peaks, affine).unwrap();
        let spec = crate::scene::Scene::layer_for_file(&path).unwrap();
        assert!(
            matches!(
                &spec.kind,
                LayerKind::Tracts { source: TractSource::Peaks { .. }, mode: crate::scene::TractMode::Lines, .. }
            ),
            "{:?}",
            spec.kind
        );
        let t = peak_segments(&path, 0.9).unwrap();
        assert_eq!(t.n_streamlines(), 2);
        let centre = glam::Vec3::new(10.0 - 2.0, 2.0, 0.0);
        let (a, b) = (t.streamline(0), t.streamline(1));
        // The x peak: along world -x (the flip), 0.9 x 2 mm long; the y peak half as long.
        assert!(
            ((a[0] + a[1]) * 0.5 - centre).length() < 1e-5
                && ((a[1] - a[0]).abs() - glam::Vec3::new(1.8, 0.0, 0.0)).length() < 1e-5,
            "{a:?}"
        );
        assert!(((b[1] - b[0]).abs() - glam::Vec3::new(0.0, 0.9, 0.0)).length() < 1e-5, "{b:?}");
        std::fs::remove_dir_all(dir).ok();
    }
}
