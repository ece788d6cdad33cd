//! Slice layers driven by components: spawn an entity with [`SliceLayer`] (an image: a [`ScalarVolume`],
//! loaded from `.nii`/`.nii.gz` or added from memory, 3D or 4D) and, optionally, [`SliceSettings`]; the plugin
//! shows one slice of it in the 3D view and, with the four views on, its slices through the crosshair in the
//! 2D views. Each edit costs what it changes, for that layer only:
//!
//! | change | cost |
//! |---|---|
//! | the data (handle swapped, asset modified), the channels | the automatic window found again, the slice cut |
//! | axis, index, window | the slice cut again from the image in memory, into the textures it shows |
//! | opacity | a material write |
//!
//! The layer entity carries the image's [`VoxelGrid`] (the crosshair's voxel on it) and, for one channel, the
//! layer's [`ColourBar`] (grey over its window, labelled with its [`Name`]).

use std::sync::Arc;

use bevy::asset::RenderAssetUsages;
use bevy::image::Image;
use bevy::mesh::{Indices, PrimitiveTopology};
use bevy::prelude::*;
use fascicle_core::Volume;
use fascicle_render::layer::{LayerStatus, SliceAxis, changed_assets, despawn_drawn, loaded_or_pending};
use fascicle_volume::ScalarVolume;
use serde::{Deserialize, Serialize};

use crate::VoxelGrid;
use crate::colourbar::{ColourBar, ColourMap, srgb_image};

/// Which volumes of an image a slice shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Channels {
    /// One volume (index along the image's fourth axis), in grey.
    One(usize),
    /// The first three volumes as red, green, blue (one window for all three).
    Rgb,
}

impl Default for Channels {
    fn default() -> Self {
        Channels::One(0)
    }
}

impl Channels {
    fn list(self) -> Vec<usize> {
        match self {
            Channels::One(c) => vec![c],
            Channels::Rgb => vec![0, 1, 2],
        }
    }
}

/// The data component of a slice layer.
#[derive(Component, Clone, Debug, Default)]
#[require(SliceSettings, LayerStatus, Transform, Visibility)]
pub struct SliceLayer {
    /// The image sliced, usually `AssetServer::load("t1.nii.gz")` or `Assets::add` of an image in memory;
    /// every volume of a 4D image can be shown ([`SliceSettings::channels`]).
    pub volume: Handle<ScalarVolume>,
}

/// How a slice layer shows its image. Defaults: the middle axial slice of the first volume, the automatic
/// window, opaque.
#[derive(Component, Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SliceSettings {
    /// The voxel axis the 3D view's slice is cut across; default Z.
    pub axis: SliceAxis,
    /// The 3D view's slice along `axis`; the middle one when `None` (default).
    pub index: Option<usize>,
    /// The values shown black and white (image units); `None` (default): the image's minimum and the 99.5th
    /// percentile of its finite values over the channels shown.
    pub window: Option<(f32, f32)>,
    /// Which volumes are shown; default the first, in grey.
    pub channels: Channels,
    /// Opacity, 0..1 (clamped); below 1 the slice is blended. Default 1.
    pub opacity: f32,
}

impl Default for SliceSettings {
    fn default() -> Self {
        Self { axis: SliceAxis::Z, index: None, window: None, channels: Channels::One(0), opacity: 1.0 }
    }
}

/// What a slice layer's slices are cut from, kept on its entity by the plugin: the image in memory and its
/// automatic window. An app that has the window already (found off the main thread) inserts this with the
/// [`SliceLayer`]; the plugin finds it again only when the image or the channels change.
#[derive(Component, Clone)]
pub struct SliceSource {
    /// The asset the image came from.
    pub asset: AssetId<ScalarVolume>,
    /// The image the slices are cut from.
    pub volume: Arc<Volume<f32>>,
    /// The volumes shown.
    pub channels: Channels,
    /// The window used when the layer sets none ([`auto_window`]).
    pub auto_window: (f32, f32),
}

impl SliceSource {
    /// The source of `channels` of `volume` (asset `asset`), with its automatic window.
    pub fn new(asset: AssetId<ScalarVolume>, volume: Arc<Volume<f32>>, channels: Channels) -> Self {
        let auto_window = auto_window(&volume, channels);
        Self { asset, volume, channels, auto_window }
    }

    /// The window shown: the layer's own, or the automatic one.
    pub fn window(&self, set: Option<(f32, f32)>) -> (f32, f32) {
        set.unwrap_or(self.auto_window)
    }

    /// Slice `index` (the middle one if `None`) along voxel axis `axis` in `window`: its image and world
    /// corners, as [`slice_image`].
    pub fn cut(&self, axis: SliceAxis, index: Option<usize>, window: (f32, f32)) -> Result<(Image, [Vec3; 4]), String> {
        slice_image(&self.volume, self.channels, axis, index, window)
    }
}

/// The window a slice shows when its layer sets none: the image's minimum and 99.5th percentile (of its
/// finite values, over the channels shown); (0, 1) for an image without finite values.
pub fn auto_window(vol: &Volume<f32>, channels: Channels) -> (f32, f32) {
    let nvox = vol.n_voxels();
    let mut vals: Vec<f32> = channels
        .list()
        .into_iter()
        .filter(|&c| c < vol.n_channels())
        .flat_map(|c| vol.data[nvox * c..nvox * (c + 1)].iter().copied())
        .filter(|x| x.is_finite())
        .collect();
    if vals.is_empty() {
        return (0.0, 1.0);
    }
    let k = (vals.len() - 1) * 995 / 1000;
    let (below, &mut hi, _) = vals.select_nth_unstable_by(k, f32::total_cmp);
    let lo = below.iter().copied().fold(hi, f32::min);
    (lo, if hi > lo { hi } else { lo + 1.0 })
}

/// An image of one slice (values mapped linearly from `window` to display black and white, non-finite values
/// black: stored as sRGB, sampled nearest) and the world positions (RAS+ mm) of its four outer voxel corners,
/// counter-clockwise from voxel (0, 0). `index` `None` is the middle slice. Errors name a slice or a volume
/// the image does not have.
pub fn slice_image(
    vol: &Volume<f32>,
    channels: Channels,
    axis: SliceAxis,
    index: Option<usize>,
    window: (f32, f32),
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
    let at = |i: usize, j: usize, channel: usize| {
        let mut p = [0usize; 3];
        p[ax] = k;
        p[u] = i;
        p[v] = j;
        vol.data[p[0] + d[0] * (p[1] + d[1] * p[2]) + nvox * channel]
    };
    if let Some(c) = channels.list().into_iter().find(|&c| c >= vol.n_channels()) {
        return Err(format!("volume {c} requested, the image has {}", vol.n_channels()));
    }
    let (lo, hi) = window;
    let hi = if hi > lo { hi } else { lo + f32::EPSILON.max(lo.abs() * 1e-6) };
    let (w, h) = (d[u], d[v]);
    let level = |x: f32| {
        let g = if x.is_finite() { ((x - lo) / (hi - lo)).clamp(0.0, 1.0) } else { 0.0 };
        (g * 255.0).round() as u8
    };
    let mut px = Vec::with_capacity(w * h * 4);
    for j in 0..h {
        for i in 0..w {
            match channels {
                Channels::One(c) => {
                    let b = level(at(i, j, c));
                    px.extend_from_slice(&[b, b, b, 255]);
                }
                Channels::Rgb => {
                    px.extend_from_slice(&[level(at(i, j, 0)), level(at(i, j, 1)), level(at(i, j, 2)), 255])
                }
            }
        }
    }
    let image = srgb_image(w as u32, h as u32, px);
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

/// The 3D view's slice of a slice layer (its child), and what it was cut with.
#[derive(Component, Clone, Debug, PartialEq)]
pub struct SliceQuad {
    axis: SliceAxis,
    index: Option<usize>,
    window: (f32, f32),
    asset: AssetId<ScalarVolume>,
    channels: Channels,
}

/// The work of the slice layers' stages: `cuts` 3D-view slices cut, `sources` images taken in, `restyles`
/// opacity writes (the 2D views' slices, cut again as the crosshair moves, are not counted).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SliceCounts {
    /// Slices cut from an image in memory (the 3D view's).
    pub cuts: u32,
    /// Images taken in (an automatic window found).
    pub sources: u32,
    /// Opacity edits written to a material.
    pub restyles: u32,
}

type Layer<'a> = (
    Entity,
    &'a SliceLayer,
    Ref<'a, SliceSettings>,
    &'a mut LayerStatus,
    Option<&'a SliceSource>,
    Option<&'a Children>,
    Option<&'a Name>,
    Option<&'a ColourBar>,
    Has<SliceBar>,
);

/// Keeps each slice layer's source, grid, colour bar and 3D-view slice in step with its data and settings.
#[allow(clippy::too_many_arguments, reason = "a Bevy system's parameters are its data dependencies")]
pub(crate) fn sync_slices(
    mut commands: Commands,
    mut layers: Query<Layer>,
    mut quads: Query<(&mut SliceQuad, &Mesh3d, &MeshMaterial3d<StandardMaterial>)>,
    assets: Res<Assets<ScalarVolume>>,
    server: Res<AssetServer>,
    mut events: MessageReader<AssetEvent<ScalarVolume>>,
    mut meshes: ResMut<Assets<Mesh>>,
    mut images: ResMut<Assets<Image>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
    mut counts: ResMut<SliceCounts>,
) {
    let modified = changed_assets(&mut events);
    for (entity, layer, settings, mut status, source, children, name, bar, owns_bar) in &mut layers {
        let Some(volume) = loaded_or_pending(&assets, &server, &layer.volume, &mut status) else { continue };
        let id = layer.volume.id();
        let fresh = source
            .is_none_or(|s| s.asset != id || s.channels != settings.channels || !Arc::ptr_eq(&s.volume, &volume.0))
            || modified.contains(&id);
        let source = if fresh {
            let s = SliceSource::new(id, volume.0.clone(), settings.channels);
            counts.sources += 1;
            commands.entity(entity).insert((s.clone(), VoxelGrid::of(&s.volume)));
            s
        } else {
            source.cloned().expect("a source unless fresh")
        };
        let window = source.window(settings.window);
        let want =
            SliceQuad { axis: settings.axis, index: settings.index, window, asset: id, channels: settings.channels };
        // The grey bar of a one-channel slice, over the window it shows.
        let wanted_bar = matches!(settings.channels, Channels::One(_)).then(|| ColourBar {
            label: name.map_or_else(String::new, |n| n.as_str().to_string()),
            map: ColourMap::Grey,
            range: (f64::from(window.0), f64::from(window.1)),
        });
        // A bar the app put there is left alone unless the plugin has one to show.
        let ours = bar.filter(|_| owns_bar);
        if wanted_bar.as_ref() != ours {
            match wanted_bar {
                Some(b) => commands.entity(entity).insert((b, SliceBar)),
                None => commands.entity(entity).remove::<(ColourBar, SliceBar)>(),
            };
        }
        let quad = children.and_then(|c| c.iter().find(|&c| quads.contains(c)));
        let current = quad.and_then(|q| quads.get(q).ok()).map(|(q, ..)| q.clone());
        if current.as_ref() == Some(&want) && !fresh {
            // Back to the slice shown (after a failed edit): ready again.
            let d = source.volume.dims3();
            let ready = LayerStatus::Ready { items: d.iter().product::<usize>() / d[settings.axis.index()] };
            if *status != ready {
                *status = ready;
            }
            if settings.is_changed()
                && let Some((_, _, material)) = quad.and_then(|q| quads.get(q).ok())
                && let Some(mut m) = materials.get_mut(&material.0)
                && m.base_color.alpha() != settings.opacity.clamp(0.0, 1.0)
            {
                set_opacity(&mut m, settings.opacity);
                counts.restyles += 1;
            }
            continue;
        }
        let (image, corners) = match source.cut(settings.axis, settings.index, window) {
            Ok(cut) => cut,
            Err(message) => {
                *status = LayerStatus::Failed(message);
                continue;
            }
        };
        counts.cuts += 1;
        let items = (image.width() * image.height()) as usize;
        match quad.and_then(|q| quads.get_mut(q).ok()) {
            Some((mut q, mesh, material)) => {
                if let Some(mut m) = meshes.get_mut(&mesh.0) {
                    *m = quad_mesh(corners);
                }
                if let Some(mut m) = materials.get_mut(&material.0) {
                    set_opacity(&mut m, settings.opacity);
                    m.base_color_texture = Some(images.add(image));
                }
                *q = want;
            }
            None => {
                let mut m = unlit(settings.opacity);
                m.base_color_texture = Some(images.add(image));
                commands.spawn((
                    want,
                    Mesh3d(meshes.add(quad_mesh(corners))),
                    MeshMaterial3d(materials.add(m)),
                    ChildOf(entity),
                ));
            }
        }
        let ready = LayerStatus::Ready { items };
        if *status != ready {
            *status = ready;
        }
    }
}

/// Marks a [`ColourBar`] the plugin gave a slice layer (it goes when the layer stops being one; a bar the app
/// put on the entity stays).
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct SliceBar;

/// What the plugin drew under a slice layer.
type Drawn = Or<(With<SliceQuad>, With<crate::ViewSlice>)>;

/// A slice layer that stops being one (its [`SliceLayer`] removed) loses what the plugin gave it: its slices,
/// its source and its bar. Its [`VoxelGrid`] stays (the app may have set it for its next content).
pub(crate) fn forget_slice(
    removed: On<Remove, SliceLayer>,
    mut commands: Commands,
    layers: Query<(Option<&Children>, Has<SliceBar>)>,
    drawn: Query<(), Drawn>,
) {
    let e = removed.entity;
    let Ok((children, bar)) = layers.get(e) else { return };
    despawn_drawn(&mut commands, children, |c| drawn.contains(c));
    commands.entity(e).try_remove::<SliceSource>();
    if bar {
        commands.entity(e).try_remove::<(ColourBar, SliceBar)>();
    }
}

/// Sets a material's alpha to `opacity` (clamped to 0..1), blended below 1.
pub fn set_opacity(m: &mut StandardMaterial, opacity: f32) {
    let a = opacity.clamp(0.0, 1.0);
    m.base_color.set_alpha(a);
    m.alpha_mode = if a < 1.0 { AlphaMode::Blend } else { AlphaMode::Opaque };
}

/// A white, unlit, two-sided material of `opacity` (0..1), for textured quads.
pub fn unlit(opacity: f32) -> StandardMaterial {
    let mut m = StandardMaterial { base_color: Color::WHITE, unlit: true, cull_mode: None, ..default() };
    set_opacity(&mut m, opacity);
    m
}

/// A quad through corners `c` (counter-clockwise), with UVs (0, 0) at `c[0]` to (1, 1) at `c[2]`.
pub fn quad_mesh(c: [Vec3; 4]) -> Mesh {
    let n = (c[1] - c[0]).cross(c[3] - c[0]).normalize_or_zero();
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, c.to_vec())
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, vec![n; 4])
        .with_inserted_attribute(Mesh::ATTRIBUTE_UV_0, vec![[0.0f32, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        .with_inserted_indices(Indices::U32(vec![0, 1, 2, 0, 2, 3]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DMat4;

    fn ramp() -> Volume<f32> {
        // 4 x 3 x 2 voxels of value x + 10 y + 100 z, 2 mm voxels from (-3, 0, 5).
        let data = (0..24).map(|i| (i % 4 + 10 * ((i / 4) % 3) + 100 * (i / 12)) as f32).collect();
        let m = DMat4::from_scale_rotation_translation(
            glam::DVec3::splat(2.0),
            glam::DQuat::IDENTITY,
            glam::DVec3::new(-3.0, 0.0, 5.0),
        );
        Volume { shape: vec![4, 3, 2], data, world_from_voxel: m }
    }

    #[test]
    fn a_slice_maps_its_window_to_black_and_white_and_knows_its_corners() {
        let (img, corners) = slice_image(&ramp(), Channels::One(0), SliceAxis::Z, Some(1), (100.0, 123.0)).unwrap();
        assert_eq!((img.width(), img.height()), (4, 3));
        let px = img.data.as_ref().unwrap();
        let grey = |i: usize, j: usize| px[(j * 4 + i) * 4];
        // Value 100 + i + 10 j over the window (100, 123).
        assert_eq!(grey(0, 0), 0);
        assert_eq!(grey(3, 1), ((13.0 / 23.0) * 255.0f32).round() as u8);
        assert_eq!(grey(3, 2), 255);
        // Voxel (-0.5, -0.5, 1) to (3.5, 2.5, 1), 2 mm voxels from (-3, 0, 5).
        assert_eq!(corners[0], Vec3::new(-4.0, -1.0, 7.0));
        assert_eq!(corners[2], Vec3::new(4.0, 5.0, 7.0));
        assert!(slice_image(&ramp(), Channels::One(0), SliceAxis::Z, Some(2), (0.0, 1.0)).is_err());
        assert!(slice_image(&ramp(), Channels::One(1), SliceAxis::Z, None, (0.0, 1.0)).is_err());
    }

    #[test]
    fn the_automatic_window_runs_from_the_minimum_to_the_995th_percentile() {
        let mut v = ramp();
        v.data[5] = f32::NAN;
        let (lo, hi) = auto_window(&v, Channels::One(0));
        assert_eq!(lo, 0.0);
        // 23 finite values sorted; index (23 - 1) * 995 / 1000 = 21 is the second largest (122).
        assert_eq!(hi, 122.0);
        let flat = Volume { data: vec![3.0; 24], ..ramp() };
        assert_eq!(auto_window(&flat, Channels::One(0)), (3.0, 4.0));
    }
}
