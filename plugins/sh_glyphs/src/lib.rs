//! Ray-cast spherical-harmonic glyphs (SEEDS.md §4) as a Bevy plugin.
//!
//! # Use
//! Add [`ShGlyphPlugin`] and spawn an entity with [`ShGlyphs`]; nothing else is needed:
//!
//! ```no_run
//! use bevy::prelude::*;
//! use fascicle_sh_glyphs::{Selection, ShGlyphPlugin, ShGlyphs, SliceAxis};
//!
//! fn main() {
//!     App::new().add_plugins((DefaultPlugins, ShGlyphPlugin)).add_systems(Startup, setup).run();
//! }
//!
//! fn setup(mut commands: Commands, assets: Res<AssetServer>) {
//!     // A file written by `fascicle fit csa` (its basis is in the header), loaded off the main thread.
//!     commands.spawn((
//!         ShGlyphs { field: assets.load("csa_l8.nii.gz") },
//!         Selection::Slice { axis: SliceAxis::Z, index: None, spacing: 1 },
//!     ));
//!     commands.spawn((Camera3d::default(), Transform::from_xyz(0.0, 0.0, 120.0).looking_at(Vec3::ZERO, Vec3::Y)));
//! }
//! ```
//!
//! The layer's settings are components on the same entity ([`Selection`], [`GlyphShape`],
//! [`RayCastSettings`]); [`layer`] says what each change costs. [`LayerStatus`] reports loading, ready or
//! the error.
//!
//! # Render integration
//! Bevy's `Material` pipeline serves here: the glyphs are opaque and depth-tested like any mesh. A layer is
//! one [`ShGlyphMaterial`] holding every glyph's centre, bounds and coefficients in GPU storage buffers, and one
//! child entity ([`ShGlyphProxies`]) drawing one mesh of every glyph's proxy box
//! (`fascicle_render::meshes::slot_boxes`: vertices that carry only the glyph's index and the corner): one draw
//! for the set in the main opaque pass (`Opaque3d` phase), whatever its size. The vertex stage
//! (`fascicle::proxy`) places each box at the glyph's tight box (`fascicle_core::sh::exact::glyph_box`) read
//! from the buffers. The fragment shader (`shaders/sh_glyph.wgsl`)
//! finds the view ray's first hit with `r = ψ(u)` ([`GlyphMethod::Exact`]: the glyph's section by the ray's
//! plane, a trigonometric polynomial known from `l_max + 1` values of ψ; or the seed's linear search) and
//! writes true depth (`@builtin(frag_depth)`), so glyphs intersect meshes, tubes and each other; the material
//! disables the prepass, which would write the proxy's depth. The main-world systems run in [`ShGlyphSystems`].
//!
//! The math (basis conversion, sharpening, normalisation, rmax, the ray caster in f64) lives in
//! `fascicle_core::sh::glyph`, which is also the test reference.

#![warn(missing_docs)]

use bevy::asset::RenderAssetUsages;
use bevy::prelude::*;
use bevy::render::render_resource::{AsBindGroup, ShaderType};
use bevy::render::storage::ShaderBuffer;
use fascicle_core::sh::glyph::{Glyph, Lobes};

pub mod layer;
pub mod placed;
pub mod shaders;

pub use fascicle_render::layer::{LayerStatus, Selection, SliceAxis};
pub use layer::{
    GlyphShape, ShField, ShFieldLoader, ShFieldSettings, ShGlyphCounts, ShGlyphSystems, ShGlyphs, field_glyphs,
};
pub use placed::PlacedShGlyphs;

/// Registers the glyph material. Needs `fascicle_render::FascicleRenderPlugin` (the shaders).
pub struct ShGlyphPlugin;

impl Plugin for ShGlyphPlugin {
    fn build(&self, app: &mut App) {
        shaders::register(app);
        fascicle_render::retain::watch_asset::<ShGlyphMaterial>(app);
        fascicle_render::retain::watch_asset::<ShField>(app);
        app.add_plugins(MaterialPlugin::<ShGlyphMaterial>::default());
        layer::build(app);
        placed::build(app);
        app.add_systems(PostUpdate, apply_highlights.in_set(ShGlyphSystems::Highlight));
    }
}

/// How glyphs are coloured.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum GlyphColour {
    /// |direction from the centre| as RGB (red = left-right, green = anterior-posterior, blue = up-down).
    #[default]
    Direction,
    /// The unit normal mapped to RGB (`n / 2 + 1/2`), unlit: for checking normals.
    Normal,
    /// Flat grey, lit.
    Grey,
    /// The glyph's GFA through the viridis colour map.
    Gfa,
}

/// How the fragment shader finds the ray's first hit with a glyph.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum GlyphMethod {
    /// The glyph's section by the ray's plane, a trigonometric polynomial (after Peters et al. 2023): ψ
    /// evaluated `l_max + 1` times per pixel, then certified steps of O(k) each bracket the first root, and
    /// bisection refines it (`fascicle_core::sh::exact`).
    #[default]
    Exact,
    /// The seed's method (SEEDS.md §4): steps of `h · rbound` with ψ evaluated at each, then bisection.
    Linear,
}

/// The ray caster's quality knobs and drawing options: one component of a [`ShGlyphs`] layer, all of it one
/// uniform.
#[derive(Component, Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct RayCastSettings {
    /// How the ray's first hit is found. Defaults to [`GlyphMethod::Exact`].
    pub method: GlyphMethod,
    /// Exact method: the quality knob. Steps along the ray are certified by a Lipschitz bound and at least
    /// `span / (4 samples)`: only a pair of roots closer than that (a lobe tip thinner) can be missed.
    pub samples: u32,
    /// Linear method: search step, in units of the glyph's render bound.
    pub h: f32,
    /// Bisection steps after the bracketing (both methods).
    pub refine: u32,
    /// How negative values of ψ are drawn. Defaults to [`Lobes::Clamp`] (not drawn).
    pub lobes: Lobes,
    /// How glyphs are coloured. Defaults to [`GlyphColour::Direction`].
    pub colour: GlyphColour,
    /// Ambient fraction of the headlight shading.
    pub ambient: f32,
    /// Phong specular weight of the headlight (exponent 32; 0: diffuse only).
    pub specular: f32,
    /// Size factor on every glyph of the layer (1: as packed). A uniform: changing it re-sends nothing else.
    pub size: f32,
}

impl Default for RayCastSettings {
    fn default() -> Self {
        Self {
            method: GlyphMethod::Exact,
            samples: 48,
            h: 0.02,
            refine: 12,
            lobes: Lobes::Clamp,
            colour: GlyphColour::Direction,
            ambient: 0.25,
            specular: 0.3,
            size: 1.0,
        }
    }
}

/// GPU parameters. Keep in sync with `GlyphParams` in `shaders/sh_glyph.wgsl`.
#[derive(Clone, Copy, Debug, ShaderType)]
pub struct ShGlyphUniform {
    /// Maximum (even) SH order of the set's glyphs.
    pub l_max: u32,
    /// f32 coefficients per glyph in the `coeffs` buffer: `(l_max + 1)(l_max + 2) / 2`.
    pub stride: u32,
    /// Bisection steps after the bracketing (at most 32).
    pub refine: u32,
    /// 0: clamp negative lobes, 1: `|ψ|` with negative lobes marked ([`Lobes`]).
    pub lobes: u32,
    /// Linear method: search step, in units of the glyph's render bound (at least 1e-4).
    pub h: f32,
    /// Ambient fraction of the headlight shading.
    pub ambient: f32,
    /// 0: direction RGB, 1: normal as colour, 2: flat grey, 3: GFA through viridis ([`GlyphColour`]).
    pub colour_mode: u32,
    /// Linear method: most search steps per ray, `ceil(2 / h) + 2` (the chord through the bounding sphere
    /// is at most twice the render bound).
    pub max_steps: u32,
    /// Layer-wide size factor: ψ, the render bound and the box are multiplied by it (1 unless finite and
    /// positive).
    pub size: f32,
    /// 0: linear search, 1: exact (polynomial form).
    pub method: u32,
    /// Exact method: the quality knob, [`RayCastSettings::samples`] clamped to 1..=1024.
    pub samples: u32,
    /// Phong specular weight of the headlight (exponent 32; at least 0).
    pub specular: f32,
}

const _: () = assert!(std::mem::size_of::<ShGlyphUniform>() == 48);

impl ShGlyphUniform {
    /// The uniform of a set of order `l_max` drawn with `s`, out-of-range settings clamped (see each
    /// field).
    pub fn new(l_max: usize, s: &RayCastSettings) -> Self {
        let h = s.h.max(1e-4);
        Self {
            l_max: l_max as u32,
            stride: fascicle_core::sh::n_coeffs(l_max) as u32,
            refine: s.refine.min(32),
            lobes: match s.lobes {
                Lobes::Clamp => 0,
                Lobes::Abs => 1,
            },
            h,
            ambient: s.ambient,
            colour_mode: match s.colour {
                GlyphColour::Direction => 0,
                GlyphColour::Normal => 1,
                GlyphColour::Grey => 2,
                GlyphColour::Gfa => 3,
            },
            // The chord is at most 2 rmax: 2 / h steps, plus the last clamped one.
            max_steps: (2.0 / h).ceil() as u32 + 2,
            size: if s.size.is_finite() && s.size > 0.0 { s.size } else { 1.0 },
            method: match s.method {
                GlyphMethod::Linear => 0,
                GlyphMethod::Exact => 1,
            },
            samples: s.samples.clamp(1, 1024),
            specular: s.specular.max(0.0),
        }
    }
}

/// The material of one glyph set.
#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
pub struct ShGlyphMaterial {
    /// The ray caster's parameters (binding 0), from the layer's [`RayCastSettings`].
    #[uniform(0)]
    pub params: ShGlyphUniform,
    /// Three `vec4` per glyph: `(centre, rbound)` (the render bound, `Glyph::rbound`),
    /// `(gfa, highlighted, 0, 0)` and `(half extents of the glyph's box, 0)`.
    #[storage(1, read_only)]
    pub glyphs: Handle<ShaderBuffer>,
    /// `stride` f32 numbers per glyph: its coefficients (in `fascicle_core::sh::glyph::GLYPH_BASIS`) in the
    /// shader's form, `fascicle_core::sh::glyph::chebyshev_form`.
    #[storage(2, read_only)]
    pub coeffs: Handle<ShaderBuffer>,
}

fascicle_render::proxy_glyph_material!(ShGlyphMaterial, shaders::sh_glyph());

/// The entity that draws a glyph set: one mesh of every glyph's proxy box, a child of the set's entity
/// ([`ShGlyphSet`]). It has no frustum culling (the boxes are placed by the vertex shader).
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct ShGlyphProxies;

/// A glyph set: the parent of its [`ShGlyphProxies`] entity, with the CPU copy of its glyphs (for picking and
/// for rewriting the small per-glyph header when highlights change).
#[derive(Component, Clone, Debug)]
pub struct ShGlyphSet {
    /// The material every glyph of the set draws with: the uniform and the glyph buffers.
    pub material: Handle<ShGlyphMaterial>,
    /// Maximum SH order of the set (the largest `Glyph::l_max`); fixes the buffer's per-glyph stride.
    pub l_max: usize,
    /// Number of glyphs.
    pub len: usize,
    /// The CPU copy of the glyphs, in buffer order (centres in RAS+ mm, before the `size` factor).
    pub glyphs: std::sync::Arc<Vec<Glyph>>,
    /// The voxel (`[x, y, z]`, indices into the field's grid) each glyph was built from, in buffer order;
    /// `None` when the glyphs did not come from a volume.
    pub voxels: Option<std::sync::Arc<Vec<[u32; 3]>>>,
    /// How negative lobes are drawn, as in the uniform, so that picking matches the picture.
    pub lobes: Lobes,
    /// The layer-wide size factor the uniform holds ([`RayCastSettings::size`]).
    pub size: f64,
}

/// The glyphs of a set drawn highlighted (the shader tints them): their indices in the set's buffers. A
/// component of the set's entity (the layer); inserting, changing or removing it rewrites the set's small
/// header buffer only (three `vec4` a glyph, no coefficients). A rebuilt set (new data or selection) starts
/// with none.
#[derive(Component, Clone, Debug, Default, PartialEq, Eq, Deref, DerefMut)]
pub struct Highlighted(pub Vec<u32>);

impl Highlighted {
    /// Highlights glyph `i` if it was not, else stops highlighting it; returns whether it is now highlighted.
    pub fn toggle(&mut self, i: u32) -> bool {
        match self.0.iter().position(|&k| k == i) {
            Some(at) => {
                self.0.swap_remove(at);
                false
            }
            None => {
                self.0.push(i);
                true
            }
        }
    }
}

impl ShGlyphSet {
    /// The voxel glyph `i` was built from, when the set came from a volume.
    pub fn voxel(&self, i: u32) -> Option<[u32; 3]> {
        self.voxels.as_ref()?.get(i as usize).copied()
    }

    /// The first glyph of this set the world-space ray hits: its index and the hit.
    pub fn pick(&self, origin: glam::DVec3, dir: glam::DVec3) -> Option<(u32, fascicle_core::sh::glyph::Hit)> {
        let scaled;
        let glyphs = if self.size == 1.0 {
            &self.glyphs[..]
        } else {
            let k = self.size;
            scaled = self
                .glyphs
                .iter()
                .map(|g| Glyph {
                    coeffs: g.coeffs.iter().map(|c| c * k).collect(),
                    rmax: g.rmax * k,
                    rbound: g.rbound * k,
                    half: g.half * k,
                    ..g.clone()
                })
                .collect::<Vec<_>>();
            &scaled[..]
        };
        fascicle_core::sh::glyph::pick(glyphs, origin, dir.normalize(), 0.01, 8, self.lobes).map(|(i, h)| (i as u32, h))
    }
}

/// Rewrites a set's header buffer (three `vec4` per glyph, no coefficients) when its highlights change; a
/// set built in this frame already has a fresh header.
fn apply_highlights(
    changed: Query<(&ShGlyphSet, &Highlighted), Changed<Highlighted>>,
    mut removed: RemovedComponents<Highlighted>,
    sets: Query<Ref<ShGlyphSet>>,
    materials: Res<Assets<ShGlyphMaterial>>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
) {
    let mut rewrite = |set: &ShGlyphSet, flags: &[u32]| {
        let Some(material) = materials.get(&set.material) else { return };
        if let Some(mut buffer) = buffers.get_mut(&material.glyphs) {
            buffer.data = Some(pack_with(&set.glyphs, set.l_max, flags, false).0);
        }
    };
    for (set, lit) in &changed {
        rewrite(set, lit);
    }
    for e in removed.read() {
        if let Ok(set) = sets.get(e)
            && !set.is_added()
        {
            rewrite(&set, &[]);
        }
    }
}

/// Packs glyphs into the two storage buffers' bytes (f32): `vec4(centre, rbound), vec4(gfa, 0, 0, 0),
/// vec4(half, 0)` and the coefficients in the shader's form (`chebyshev_form`).
pub fn pack(glyphs: &[Glyph], l_max: usize) -> (Vec<u8>, Vec<u8>) {
    pack_with(glyphs, l_max, &[], true)
}

/// [`pack`] with the glyphs at `highlighted` flagged (the `y` of their second `vec4`); the coefficients
/// only when `with_coeffs`.
fn pack_with(glyphs: &[Glyph], l_max: usize, highlighted: &[u32], with_coeffs: bool) -> (Vec<u8>, Vec<u8>) {
    let stride = fascicle_core::sh::n_coeffs(l_max);
    let mut head = Vec::with_capacity(glyphs.len() * 48);
    let mut coeffs = Vec::with_capacity(glyphs.len() * stride * 4);
    // The shader's internal form (Chebyshev series per band): one linear map for the set, applied per glyph.
    let form = with_coeffs.then(|| fascicle_core::sh::glyph::ChebyshevForm::new(l_max));
    let (mut padded, mut formed) = (vec![0.0; stride], Vec::with_capacity(stride));
    for (i, g) in glyphs.iter().enumerate() {
        let lit = if highlighted.contains(&(i as u32)) { 1.0 } else { 0.0 };
        let h = g.half;
        for v in [g.centre.x, g.centre.y, g.centre.z, g.rbound, g.gfa, lit, 0.0, 0.0, h.x, h.y, h.z, 0.0] {
            head.extend_from_slice(&(v as f32).to_le_bytes());
        }
        let Some(form) = &form else { continue };
        for (j, v) in padded.iter_mut().enumerate() {
            *v = g.coeffs.get(j).copied().unwrap_or(0.0);
        }
        formed.clear();
        form.apply(&padded, &mut formed);
        for v in &formed {
            coeffs.extend_from_slice(&(*v as f32).to_le_bytes());
        }
    }
    (head, coeffs)
}

/// Spawns a glyph set (all glyphs must share `l_max`, as from one field). Returns the parent entity, which
/// holds the [`ShGlyphSet`] (`voxels[i]`, if given, is glyph i's voxel); an empty set spawns only the parent.
/// (A layer driven by components, [`ShGlyphs`] or [`PlacedShGlyphs`], needs none of this: its plugin spawns the set.)
pub fn spawn_glyph_set(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<ShGlyphMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    glyphs: &[Glyph],
    voxels: Option<&[[u32; 3]]>,
    settings: &RayCastSettings,
) -> Entity {
    let parent = commands.spawn((Transform::default(), Visibility::default())).id();
    let set = fill_glyph_set(commands, parent, meshes, materials, buffers, glyphs, voxels, settings);
    commands.entity(parent).insert(set);
    parent
}

/// The stores a layer's glyph set is built into: what the field-driven and the placed layers' systems
/// (re)build with.
#[derive(bevy::ecs::system::SystemParam)]
pub(crate) struct GlyphStores<'w> {
    meshes: ResMut<'w, Assets<Mesh>>,
    pub(crate) materials: ResMut<'w, Assets<ShGlyphMaterial>>,
    buffers: ResMut<'w, Assets<ShaderBuffer>>,
}

impl GlyphStores<'_> {
    /// Takes away what `layer` draws: its [`ShGlyphProxies`] child, its highlights and `old`'s material.
    pub(crate) fn clear(&mut self, commands: &mut Commands, layer: Entity, old: Option<&ShGlyphSet>) {
        commands.entity(layer).despawn_related::<Children>().try_remove::<Highlighted>();
        if let Some(old) = old {
            self.materials.remove(&old.material);
        }
    }

    /// Replaces what `layer` draws with `glyphs` ([`fill_glyph_set`]); returns the set for `layer`.
    pub(crate) fn refill(
        &mut self,
        commands: &mut Commands,
        layer: Entity,
        old: Option<&ShGlyphSet>,
        (glyphs, voxels): (&[Glyph], Option<&[[u32; 3]]>),
        settings: &RayCastSettings,
    ) -> ShGlyphSet {
        self.clear(commands, layer, old);
        fill_glyph_set(
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

/// Uploads the glyph buffers into a new material and spawns the [`ShGlyphProxies`] child of `parent` that draws
/// them (none for an empty set); returns the [`ShGlyphSet`] for the parent.
#[allow(clippy::too_many_arguments)]
pub(crate) fn fill_glyph_set(
    commands: &mut Commands,
    parent: Entity,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<ShGlyphMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    glyphs: &[Glyph],
    voxels: Option<&[[u32; 3]]>,
    settings: &RayCastSettings,
) -> ShGlyphSet {
    let l_max = glyphs.iter().map(|g| g.l_max).max().unwrap_or(0);
    let (head, coeffs) = pack(glyphs, l_max);
    // Storage buffers must not be empty.
    let buffer = |bytes: Vec<u8>, usage| {
        let bytes = if bytes.is_empty() { vec![0u8; 16] } else { bytes };
        ShaderBuffer::new(&bytes, usage)
    };
    let material = materials.add(ShGlyphMaterial {
        params: ShGlyphUniform::new(l_max, settings),
        // The header is rewritten on highlighting: it stays in the main world too (a render-world-only
        // buffer reached the GPU only on its first rewrite in Bevy 0.19.1; see fascicle-tensors' splats).
        glyphs: buffers.add(buffer(head, RenderAssetUsages::default())),
        coeffs: buffers.add(buffer(coeffs, RenderAssetUsages::RENDER_WORLD)),
    });
    let centres: Vec<Vec3> = glyphs.iter().map(|g| g.centre.as_vec3()).collect();
    fascicle_render::impostor::spawn_glyph_proxies(commands, parent, meshes, &material, &centres, ShGlyphProxies);
    ShGlyphSet {
        material,
        l_max,
        len: glyphs.len(),
        glyphs: std::sync::Arc::new(glyphs.to_vec()),
        voxels: voxels.map(|v| std::sync::Arc::new(v.to_vec())),
        lobes: settings.lobes,
        size: settings.size as f64,
    }
}

/// Changes a set's ray-cast settings in place (one small uniform upload; no buffer is re-sent).
pub(crate) fn update_settings(
    materials: &mut Assets<ShGlyphMaterial>,
    set: &mut ShGlyphSet,
    settings: &RayCastSettings,
) {
    if let Some(mut m) = materials.get_mut(&set.material) {
        m.params = ShGlyphUniform::new(set.l_max, settings);
    }
    set.lobes = settings.lobes;
    set.size = ShGlyphUniform::new(set.l_max, settings).size as f64;
}

/// The mesh baseline: all glyphs as one merged mesh of deformed icospheres of `order` (colour |direction|),
/// drawn by Bevy's standard pipeline. Returns the entity. For side-by-side comparison with ray casting.
pub fn spawn_mesh_glyphs(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<StandardMaterial>,
    glyphs: &[Glyph],
    order: u32,
    lobes: Lobes,
) -> Entity {
    use bevy::mesh::{Indices, PrimitiveTopology};
    let (mut pos, mut nrm, mut col, mut idx) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for g in glyphs {
        let (p, n, f) = fascicle_core::sh::glyph::glyph_mesh(g, order, lobes);
        let base = pos.len() as u32;
        for (p, n) in p.iter().zip(&n) {
            let d = (*p - g.centre).normalize_or_zero().abs();
            pos.push(p.as_vec3().to_array());
            nrm.push(n.as_vec3().to_array());
            col.push([d.x as f32, d.y as f32, d.z as f32, 1.0]);
        }
        idx.extend(f.iter().flat_map(|t| t.map(|i| i + base)));
    }
    let mesh = Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, pos)
        .with_inserted_attribute(Mesh::ATTRIBUTE_NORMAL, nrm)
        .with_inserted_attribute(Mesh::ATTRIBUTE_COLOR, col)
        .with_inserted_indices(Indices::U32(idx));
    let material = materials.add(StandardMaterial { base_color: Color::WHITE, unlit: true, ..default() });
    commands.spawn((Mesh3d(meshes.add(mesh)), MeshMaterial3d(material), Transform::default())).id()
}

#[cfg(test)]
mod tests {
    use super::*;
    use fascicle_core::sh::ShBasis;
    use fascicle_core::sh::glyph::{GlyphStyle, make_glyphs};
    use fascicle_render::budget::CoarseMesh;

    /// A set is one drawing entity whatever its size; a set over `GLYPH_PREVIEW_MIN` glyphs (a 100 x 60 slice)
    /// also gets a coarse preview of every other cell (a quarter), a small one none.
    #[test]
    fn a_set_draws_as_one_entity_with_a_preview_when_large() {
        let mut app = App::new();
        app.add_plugins((MinimalPlugins, bevy::asset::AssetPlugin::default()))
            .init_asset::<Mesh>()
            .init_asset::<ShGlyphMaterial>()
            .init_asset::<ShaderBuffer>();
        let grid: Vec<glam::DVec3> =
            (0..6000).map(|i| glam::DVec3::new((i % 100) as f64 * 2.0, (i / 100) as f64 * 2.0, 5.0)).collect();
        let style = GlyphStyle { scale: 0.9, ..GlyphStyle::default() };
        let glyphs = make_glyphs(grid.iter().map(|c| (*c, &[1.0][..])), ShBasis::default(), style).unwrap().0;
        let spawn = |n: usize| {
            let glyphs = glyphs[..n].to_vec();
            move |mut commands: Commands,
                  mut meshes: ResMut<Assets<Mesh>>,
                  mut materials: ResMut<Assets<ShGlyphMaterial>>,
                  mut buffers: ResMut<Assets<ShaderBuffer>>| {
                let s = RayCastSettings::default();
                spawn_glyph_set(&mut commands, &mut meshes, &mut materials, &mut buffers, &glyphs, None, &s)
            }
        };
        for (n, preview) in [(6000, Some(1500)), (400, None)] {
            let set = bevy::ecs::system::RunSystemOnce::run_system_once(app.world_mut(), spawn(n)).unwrap();
            let world = app.world_mut();
            let drawn: Vec<Entity> = world.get::<Children>(set).expect("children").iter().collect();
            assert_eq!(drawn.len(), 1);
            assert!(world.get::<ShGlyphProxies>(drawn[0]).is_some());
            let vertices = |h: &Handle<Mesh>| world.resource::<Assets<Mesh>>().get(h).unwrap().count_vertices();
            let full = &world.get::<Mesh3d>(drawn[0]).unwrap().0;
            assert_eq!(vertices(full), 8 * n);
            let coarse = world.get::<CoarseMesh>(drawn[0]);
            assert_eq!(coarse.map(|c| vertices(&c.preview) / 8), preview, "{n} glyphs");
        }
    }
}
