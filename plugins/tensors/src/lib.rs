//! Tensor glyphs and tensor splats ([`splat`]) as a Bevy plugin; layers driven by components in [`layer`].
//! Glyphs: ray-cast ellipsoids and Kindlmann superquadrics. A set ([`TensorGlyphSet`], with its
//! [`TensorSample`]s) is one storage buffer and one child entity ([`TensorGlyphProxies`]) drawing one mesh of
//! every glyph's proxy cube (`fascicle_render::meshes::slot_boxes`), placed by the vertex stage: one draw a set.
//! The fragment shader (`shaders/tensor_glyph.wgsl`) intersects the view ray with the glyph (closed form
//! for ellipsoids, search and bisection for superquadrics) and writes true depth. The math and the test
//! references are in `fascicle_core::dti::glyph`.

#![warn(missing_docs)]

use bevy::asset::RenderAssetUsages;
use bevy::prelude::*;
use bevy::render::render_resource::{AsBindGroup, ShaderType};
use bevy::render::storage::ShaderBuffer;
use fascicle_core::dti::glyph::{MIN_EXPONENT, TensorGlyph, TensorShape};

pub mod gpu_sort;
pub mod layer;
pub mod placed;
pub mod shaders;
pub mod sort_order;
pub mod splat;

pub use fascicle_render::layer::{LayerStatus, Selection, SliceAxis};
pub use layer::{
    SplatCounts, SplatShape, TensorField, TensorFieldLoader, TensorFieldSettings, TensorGlyphCounts, TensorGlyphShape,
    TensorGlyphs, TensorSplats, TensorSystems,
};
pub use placed::{PlacedSplats, PlacedTensorGlyphs};
pub use splat::SplatSettings;

/// Tensor glyphs and splats: their materials, the [`TensorField`] asset and its loader, the
/// [`TensorGlyphs`] and [`TensorSplats`] layers and the splat sort (see [`TensorSystems`]).
pub struct TensorGlyphPlugin;

impl Plugin for TensorGlyphPlugin {
    fn build(&self, app: &mut App) {
        shaders::register(app);
        use fascicle_render::retain::{watch, watch_asset};
        watch_asset::<TensorGlyphMaterial>(app);
        watch_asset::<splat::SplatMaterial>(app);
        watch_asset::<TensorField>(app);
        watch::<sort_order::SplatSortMode>(app);
        app.add_plugins((
            MaterialPlugin::<TensorGlyphMaterial>::default(),
            MaterialPlugin::<splat::SplatMaterial>::default(),
        ))
        .init_resource::<splat::SplatSortStats>();
        layer::build(app);
        placed::build(app);
        gpu_sort::build(app);
        app.add_systems(PostUpdate, splat::sort_splats.in_set(TensorSystems::Sort));
        if let Some(render_app) = app.get_sub_app_mut(bevy::render::RenderApp) {
            use bevy::core_pipeline::core_3d::{main_opaque_pass_3d, main_transparent_pass_3d};
            render_app.add_systems(
                bevy::core_pipeline::schedule::Core3d,
                // In the main pass's set: a frame that puts a retained picture back skips it
                // (fascicle_render::retain).
                gpu_sort::sort
                    .after(main_opaque_pass_3d)
                    .before(main_transparent_pass_3d)
                    .in_set(bevy::core_pipeline::Core3dSystems::MainPass),
            );
        }
    }
}

/// How tensor glyphs are coloured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum TensorColour {
    /// |e1| as RGB, weighted by FA (floor 0.2).
    #[default]
    Direction,
    /// FA through viridis.
    Fa,
    /// The unit normal as RGB, unlit (tests).
    Normal,
}

/// Shape and ray-caster knobs; on a [`TensorGlyphs`] layer, a change is one uniform write (a new `shape`
/// repacks: the glyphs' bounds change).
#[derive(Component, Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct TensorGlyphSettings {
    /// Ellipsoid or superquadric. Defaults to Kindlmann's superquadric with γ = 3.
    pub shape: TensorShape,
    /// Superquadric search step in units of the glyph's bound.
    pub h: f32,
    /// Superquadric bisection steps after the search brackets the hit (at most 32). Defaults to 5.
    pub refine: u32,
    /// How glyphs are coloured. Defaults to [`TensorColour::Direction`].
    pub colour: TensorColour,
    /// Ambient fraction of the headlight shading. Defaults to 0.25.
    pub ambient: f32,
}

impl Default for TensorGlyphSettings {
    fn default() -> Self {
        Self { shape: TensorShape::default(), h: 0.02, refine: 5, colour: TensorColour::Direction, ambient: 0.25 }
    }
}

/// GPU parameters. Keep in sync with `TensorParams` in `shaders/tensor_glyph.wgsl`.
#[derive(Clone, Copy, Debug, ShaderType)]
pub struct TensorGlyphUniform {
    /// 0: ellipsoid, 1: superquadric ([`TensorShape`]).
    pub shape: u32,
    /// Superquadric sharpness γ (0 for ellipsoids).
    pub gamma: f32,
    /// Superquadric search step, in units of the glyph's bound (at least 1e-4).
    pub h: f32,
    /// Superquadric bisection steps after the bracketing (at most 32).
    pub refine: u32,
    /// 0: |e1| RGB weighted by FA, 1: FA through viridis, 2: normal as colour ([`TensorColour`]).
    pub colour_mode: u32,
    /// Ambient fraction of the headlight shading.
    pub ambient: f32,
    /// Most superquadric search steps per ray, `ceil(2 / h) + 2` (the chord through the bounding sphere is at
    /// most twice the bound).
    pub max_steps: u32,
    /// Floor of the superquadric exponents α, β (`fascicle_core::dti::glyph::MIN_EXPONENT`, 0.02).
    pub min_exponent: f32,
}

const _: () = assert!(std::mem::size_of::<TensorGlyphUniform>() == 32);

impl From<&TensorGlyphSettings> for TensorGlyphUniform {
    fn from(s: &TensorGlyphSettings) -> Self {
        let h = s.h.max(1e-4);
        let (shape, gamma) = match s.shape {
            TensorShape::Ellipsoid => (0, 0.0),
            TensorShape::Superquadric { gamma } => (1, gamma as f32),
        };
        Self {
            shape,
            gamma,
            h,
            refine: s.refine.min(32),
            colour_mode: match s.colour {
                TensorColour::Direction => 0,
                TensorColour::Fa => 1,
                TensorColour::Normal => 2,
            },
            ambient: s.ambient,
            max_steps: (2.0 / h).ceil() as u32 + 2,
            min_exponent: MIN_EXPONENT as f32,
        }
    }
}

/// The material of one tensor glyph set, drawn on its proxy cubes by `shaders/tensor_glyph.wgsl`.
#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
pub struct TensorGlyphMaterial {
    /// The ray caster's parameters (binding 0), from the layer's [`TensorGlyphSettings`].
    #[uniform(0)]
    pub params: TensorGlyphUniform,
    /// Five `vec4` per glyph: (centre, bound), (e1, r1), (e2, r2), (e3, r3), (cl, cp, fa, 0).
    #[storage(1, read_only)]
    pub glyphs: Handle<ShaderBuffer>,
}

fascicle_render::proxy_glyph_material!(TensorGlyphMaterial, shaders::tensor_glyph());

/// One tensor sample on screen: its index in the set's buffer, its voxel, and what systems select on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TensorSample {
    /// The glyph's index in its set's buffer.
    pub index: u32,
    /// The voxel `[x, y, z]` (indices into the field's grid) it was built from; `None` when not from a volume.
    pub voxel: Option<[u32; 3]>,
    /// The glyph's centre, RAS+ mm.
    pub centre: Vec3,
    /// Fractional anisotropy, in [0, 1].
    pub fa: f32,
    /// Westin linearity `(l1 - l2) / l1`, in [0, 1].
    pub cl: f32,
    /// Westin planarity `(l2 - l3) / l1`, in [0, 1].
    pub cp: f32,
}

/// The entity that draws a tensor glyph set: one mesh of every glyph's proxy cube, a child of the set's
/// entity ([`TensorGlyphSet`]). It has no frustum culling (the cubes are placed by the vertex shader).
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct TensorGlyphProxies;

/// A tensor glyph set: the parent of its [`TensorGlyphProxies`] entity.
#[derive(Component, Clone, Debug)]
pub struct TensorGlyphSet {
    /// The material every glyph of the set draws with: the uniform and the glyph buffer.
    pub material: Handle<TensorGlyphMaterial>,
    /// The shape the buffer was packed for (a glyph's bound depends on it).
    pub shape: TensorShape,
    /// Number of glyphs.
    pub len: usize,
    /// The set's samples, in buffer order.
    pub samples: std::sync::Arc<Vec<TensorSample>>,
}

/// The storage buffer's bytes for `glyphs` drawn as `shape`.
pub fn pack(glyphs: &[TensorGlyph], shape: TensorShape) -> Vec<u8> {
    let mut out = Vec::with_capacity(glyphs.len() * 80);
    for g in glyphs {
        let c = g.centre;
        let [a, b, e] = g.axes;
        let r = g.radii;
        let vals = [
            c.x,
            c.y,
            c.z,
            g.bound(shape),
            a.x,
            a.y,
            a.z,
            r[0],
            b.x,
            b.y,
            b.z,
            r[1],
            e.x,
            e.y,
            e.z,
            r[2],
            g.cl,
            g.cp,
            g.fa,
            0.0,
        ];
        for v in vals {
            out.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
    out
}

/// Spawns a tensor glyph set; returns the parent. `voxels[i]`, if given, is recorded on sample i.
pub fn spawn_tensor_glyphs(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<TensorGlyphMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    glyphs: &[TensorGlyph],
    voxels: Option<&[[u32; 3]]>,
    settings: &TensorGlyphSettings,
) -> Entity {
    let parent = commands.spawn((Transform::default(), Visibility::default())).id();
    let set = fill_tensor_glyphs(commands, parent, meshes, materials, buffers, glyphs, voxels, settings);
    commands.entity(parent).insert(set);
    parent
}

/// The stores a layer's tensor glyph set is built into: what the field-driven and the placed layers' systems
/// (re)build with.
#[derive(bevy::ecs::system::SystemParam)]
pub(crate) struct TensorGlyphStores<'w> {
    meshes: ResMut<'w, Assets<Mesh>>,
    pub(crate) materials: ResMut<'w, Assets<TensorGlyphMaterial>>,
    buffers: ResMut<'w, Assets<ShaderBuffer>>,
}

impl TensorGlyphStores<'_> {
    /// Takes away what `layer` draws: its [`TensorGlyphProxies`] child and `old`'s material.
    pub(crate) fn clear(&mut self, commands: &mut Commands, layer: Entity, old: Option<&TensorGlyphSet>) {
        commands.entity(layer).despawn_related::<Children>();
        if let Some(old) = old {
            self.materials.remove(&old.material);
        }
    }

    /// Replaces what `layer` draws with `glyphs` ([`fill_tensor_glyphs`]); returns the set for `layer`.
    pub(crate) fn refill(
        &mut self,
        commands: &mut Commands,
        layer: Entity,
        old: Option<&TensorGlyphSet>,
        (glyphs, voxels): (&[TensorGlyph], Option<&[[u32; 3]]>),
        settings: &TensorGlyphSettings,
    ) -> TensorGlyphSet {
        self.clear(commands, layer, old);
        fill_tensor_glyphs(
            commands,
            layer,
            &mut self.meshes,
            &mut self.materials,
            &mut self.buffers,
            glyphs,
            voxels,
            settings,
        )
    }
}

/// Uploads the set's buffer into a new material and spawns the [`TensorGlyphProxies`] child of `parent` that
/// draws it (none for an empty set); returns the set's component for `parent`.
#[allow(clippy::too_many_arguments, reason = "the asset stores a glyph set writes to")]
pub(crate) fn fill_tensor_glyphs(
    commands: &mut Commands,
    parent: Entity,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<TensorGlyphMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    glyphs: &[TensorGlyph],
    voxels: Option<&[[u32; 3]]>,
    settings: &TensorGlyphSettings,
) -> TensorGlyphSet {
    let mut bytes = pack(glyphs, settings.shape);
    if bytes.is_empty() {
        bytes = vec![0u8; 80]; // storage buffers must not be empty
    }
    let material = materials.add(TensorGlyphMaterial {
        params: settings.into(),
        glyphs: buffers.add(ShaderBuffer::new(&bytes, RenderAssetUsages::RENDER_WORLD)),
    });
    let centres: Vec<Vec3> = glyphs.iter().map(|g| g.centre.as_vec3()).collect();
    fascicle_render::impostor::spawn_glyph_proxies(commands, parent, meshes, &material, &centres, TensorGlyphProxies);
    let samples = glyphs
        .iter()
        .enumerate()
        .map(|(i, g)| TensorSample {
            index: i as u32,
            voxel: voxels.and_then(|v| v.get(i).copied()),
            centre: g.centre.as_vec3(),
            fa: g.fa as f32,
            cl: g.cl as f32,
            cp: g.cp as f32,
        })
        .collect();
    TensorGlyphSet { material, shape: settings.shape, len: glyphs.len(), samples: std::sync::Arc::new(samples) }
}
