//! Tensor splats, at whole-brain scale: a splat set is one entity and one draw. Its static mesh holds N
//! quads whose vertices carry their slot; three storage buffers hold the splats' Gaussians and shapes
//! (written once), their colours and opacities (rewritten alone when the colouring or the barycentric
//! transfer function changes: no re-projection, no re-sort) and the far-to-near order of the slots.
//!
//! The order is sorted on the GPU ([`crate::gpu_sort`]: per view, nothing uploaded) on hardware adapters.
//! With [`SplatSortMode::Cpu`], without compute shaders, or on a software rasteriser (by default),
//! [`sort_splats`] re-sorts a set only when the view
//! direction relative to the set changes (the order of `dot(centre, forward)` does not depend on where the
//! camera is, only where it looks), with the O(n) radix argsort of `fascicle_core::dti::splat::argsort_desc`,
//! and uploads 4 bytes per splat. Quads are
//! rasterised and blended in primitive order, so one draw composites them in that order; the set is drawn
//! in Bevy's transparent phase, after the opaque layers, tested against their depth without writing it.
//!
//! While the frame budget is coarse ([`fascicle_render::budget::CoarseMesh`]), a set of more than
//! [`SPLAT_PREVIEW_MIN`] splats draws every [`SPLAT_PREVIEW_STRIDE`]-th splat (by index: the same splats
//! whatever the view): on a software rasteriser a splat costs its four vertices' footprint, whatever the
//! render scale (the default scene's 3,456 splats: about 35 ms a frame on lavapipe at 1/8 scale). The order
//! buffer holds their far-to-near order after the whole set's ([`preview_len`]); the GPU sort leaves that part
//! in index order, so on a GPU the preview is unsorted.
//!
//! (The first version drew one entity per splat through Bevy's sorted transparent phase: correct, but
//! a draw call and a phase item per splat, and Bevy's batching reorders instances; see `gpu_splats`.)

use std::sync::Arc;
use std::time::Instant;

use crate::shaders;
use crate::sort_order::{GpuSortStats, SplatSortMode, padded_len};
use bevy::asset::RenderAssetUsages;
use bevy::camera::visibility::{NoFrustumCulling, RenderLayers};
use bevy::mesh::MeshVertexBufferLayoutRef;
use bevy::pbr::{Material, MaterialPipeline, MaterialPipelineKey};
use bevy::prelude::*;
use bevy::render::render_resource::{AsBindGroup, RenderPipelineDescriptor, ShaderType, SpecializedMeshPipelineError};
use bevy::render::storage::ShaderBuffer;
use bevy::shader::ShaderRef;
use fascicle_core::dti::splat::{
    ATTENUATION_K, DILATION_PX2, LitTensor, Splat, SplatColouring, SplatRender, argsort_desc, depth_keys,
};

/// Splat drawing options; on a [`crate::TensorSplats`] layer, a change is one uniform write, and a new
/// `colouring` rewrites the colour buffer alone.
#[derive(Component, Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct SplatSettings {
    /// The seed's depth attenuation `exp(-2K sqrt(T'zz))`.
    pub attenuation: bool,
    /// Multiplies every splat's opacity.
    pub opacity: f32,
    /// Lit-tensor shading.
    #[serde(default)]
    pub lit: bool,
    /// Lit-tensor weights and exponent, used when `lit`. Defaults to [`LitTensor::default`] (ambient 0.3,
    /// diffuse 0.7, specular 0.3, shininess 20).
    #[serde(default)]
    pub lighting: LitTensor,
    /// Colour and opacity per splat (a change rewrites the style buffer only).
    #[serde(default)]
    pub colouring: SplatColouring,
}

impl Default for SplatSettings {
    fn default() -> Self {
        Self {
            attenuation: true,
            opacity: 1.0,
            lit: false,
            lighting: LitTensor::default(),
            colouring: SplatColouring::default(),
        }
    }
}

impl SplatSettings {
    /// The knobs the f64 reference compositor shares.
    pub fn reference(&self) -> SplatRender {
        SplatRender { attenuation: self.attenuation, lighting: self.lit.then_some(self.lighting) }
    }
}

/// GPU parameters. Keep in sync with `SplatParams` in `shaders/tensor_splat.wgsl`.
#[derive(Clone, Copy, Debug, ShaderType)]
pub struct SplatUniform {
    /// 1: depth attenuation on ([`SplatSettings::attenuation`]), 0: off.
    pub attenuation: u32,
    /// Depth-attenuation constant `K = -ln 0.25` ([`ATTENUATION_K`]).
    pub k: f32,
    /// Screen-space dilation added to every footprint's covariance, pixels² ([`DILATION_PX2`]).
    pub dilation: f32,
    /// Factor on every splat's opacity ([`SplatSettings::opacity`]).
    pub opacity_scale: f32,
    /// 1: lit-tensor shading ([`SplatSettings::lit`]), 0: the unlit colour.
    pub lit: u32,
    /// Lit tensors: weight of the unlit colour ([`LitTensor::ambient`]).
    pub ambient: f32,
    /// Lit tensors: weight of the diffuse term ([`LitTensor::diffuse`]).
    pub diffuse: f32,
    /// Lit tensors: weight of the white specular term ([`LitTensor::specular`]).
    pub specular: f32,
    /// Lit tensors: Blinn-Phong exponent `N` ([`LitTensor::shininess`]).
    pub shininess: f32,
}

impl From<&SplatSettings> for SplatUniform {
    fn from(s: &SplatSettings) -> Self {
        Self {
            attenuation: u32::from(s.attenuation),
            k: ATTENUATION_K as f32,
            dilation: DILATION_PX2 as f32,
            opacity_scale: s.opacity,
            lit: u32::from(s.lit),
            ambient: s.lighting.ambient as f32,
            diffuse: s.lighting.diffuse as f32,
            specular: s.lighting.specular as f32,
            shininess: s.lighting.shininess as f32,
        }
    }
}

/// The material of one splat set, drawn by `shaders/tensor_splat.wgsl` in the transparent phase with
/// premultiplied alpha, tested against the opaque depth without writing it.
#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
pub struct SplatMaterial {
    /// The splat parameters (binding 0), from the layer's [`SplatSettings`].
    #[uniform(0)]
    pub params: SplatUniform,
    /// Five `vec4` per splat: (centre, cl), (xx, xy, xz, yy), (yz, zz, cp, cs), (e1, 1/s²), (e3, 0).
    #[storage(1, read_only)]
    pub splats: Handle<ShaderBuffer>,
    /// One `vec4` per splat: linear RGB, opacity.
    #[storage(2, read_only)]
    pub styles: Handle<ShaderBuffer>,
    /// One `u32` per slot: the splat drawn there, far to near (padded to [`padded_len`] for the GPU sort),
    /// then the preview's slots ([`preview_len`]).
    #[storage(3, read_only)]
    pub order: Handle<ShaderBuffer>,
}

impl Material for SplatMaterial {
    fn vertex_shader() -> ShaderRef {
        shaders::tensor_splat()
    }
    fn fragment_shader() -> ShaderRef {
        shaders::tensor_splat()
    }
    fn alpha_mode(&self) -> AlphaMode {
        AlphaMode::Premultiplied
    }
    fn enable_prepass() -> bool {
        false
    }
    fn enable_shadows() -> bool {
        false
    }
    fn specialize(
        _pipeline: &MaterialPipeline,
        descriptor: &mut RenderPipelineDescriptor,
        _layout: &MeshVertexBufferLayoutRef,
        _key: MaterialPipelineKey<Self>,
    ) -> Result<(), SpecializedMeshPipelineError> {
        descriptor.primitive.cull_mode = None;
        // Test against the opaque depth, never write it: splats are composited in sorted order, not
        // depth-tested against each other.
        if let Some(ds) = descriptor.depth_stencil.as_mut() {
            ds.depth_write_enabled = Some(false);
        }
        Ok(())
    }
}

/// A splat set: one entity, one draw.
#[derive(Component, Clone, Debug)]
pub struct SplatSet {
    /// The set's material: the uniform and the splat, style and order buffers.
    pub material: Handle<SplatMaterial>,
    /// The splats (colour and opacity as last styled).
    pub splats: Arc<Vec<Splat>>,
    /// The view direction (set frame) the order buffer was sorted for.
    pub sorted_for: Option<Vec3>,
}

impl SplatSet {
    /// Number of splats in the set.
    pub fn len(&self) -> usize {
        self.splats.len()
    }
    /// Whether the set has no splats.
    pub fn is_empty(&self) -> bool {
        self.splats.is_empty()
    }

    /// Recolours the set: rewrites its style buffer (16 bytes per splat) and nothing else.
    pub fn restyle(
        &mut self,
        colouring: &SplatColouring,
        materials: &Assets<SplatMaterial>,
        buffers: &mut Assets<ShaderBuffer>,
    ) {
        let mut splats = (*self.splats).clone();
        colouring.apply(&mut splats);
        if let Some(m) = materials.get(&self.material)
            && let Some(mut b) = buffers.get_mut(&m.styles)
        {
            b.data = Some(pad(pack_styles(&splats)));
        }
        self.splats = Arc::new(splats);
    }
}

/// Costs of the last frames' sorting, for benchmarks and the viewer's status line.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct SplatSortStats {
    /// Sorts done so far, on the CPU and the GPU (the GPU's counted as of the last frame's `PostUpdate`).
    pub sorts: u64,
    /// Of which on the CPU.
    pub cpu_sorts: u64,
    /// Wall time of the last sort (keys, argsort, packing), ms.
    pub last_sort_ms: f64,
    /// Bytes uploaded by the last sort.
    pub last_upload_bytes: usize,
    /// Wall time of the last run of [`sort_splats`], ms (tiny when nothing moved).
    pub last_system_ms: f64,
}

/// Geometry buffer bytes: five `vec4<f32>` per splat.
pub fn pack_geometry(splats: &[Splat]) -> Vec<u8> {
    let mut out = Vec::with_capacity(splats.len() * 80);
    for s in splats {
        let c = s.cov;
        let [cl, cp, cs] = s.shape();
        let vals = [
            s.centre.x,
            s.centre.y,
            s.centre.z,
            cl,
            c.x_axis.x,
            c.x_axis.y,
            c.x_axis.z,
            c.y_axis.y,
            c.y_axis.z,
            c.z_axis.z,
            cp,
            cs,
            s.e1.x,
            s.e1.y,
            s.e1.z,
            1.0 / s.size2,
            s.e3.x,
            s.e3.y,
            s.e3.z,
            0.0,
        ];
        for v in vals {
            out.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
    out
}

/// Style buffer bytes: linear RGB and opacity per splat.
pub fn pack_styles(splats: &[Splat]) -> Vec<u8> {
    splats
        .iter()
        .flat_map(|s| [s.colour.x, s.colour.y, s.colour.z, s.opacity])
        .flat_map(|v| (v as f32).to_le_bytes())
        .collect()
}

/// A storage buffer may not be empty.
fn pad(mut bytes: Vec<u8>) -> Vec<u8> {
    if bytes.is_empty() {
        bytes = vec![0u8; 16];
    }
    bytes
}

/// Sets of more splats than this draw a preview while the frame budget is coarse (default scene: 3,456).
pub const SPLAT_PREVIEW_MIN: usize = 2_000;

/// The preview draws every this-many-th splat.
pub const SPLAT_PREVIEW_STRIDE: usize = 4;

/// The preview's slots, after the whole set's [`padded_len`] slots in the order buffer: the splats whose
/// index is a multiple of [`SPLAT_PREVIEW_STRIDE`] (none for sets of at most [`SPLAT_PREVIEW_MIN`]).
pub fn preview_len(n: usize) -> usize {
    if n > SPLAT_PREVIEW_MIN { n.div_ceil(SPLAT_PREVIEW_STRIDE) } else { 0 }
}

/// The order buffer's contents for `order`, the whole set's far-to-near order: it, the padding slots
/// (naming themselves), then the preview's splats in the same order.
fn order_bytes(order: &[u32]) -> Vec<u8> {
    let n = order.len();
    let preview = order.iter().copied().filter(|i| (*i as usize).is_multiple_of(SPLAT_PREVIEW_STRIDE));
    let slots = order.iter().copied().chain(n as u32..padded_len(n) as u32);
    let all: Vec<u32> = if preview_len(n) > 0 { slots.chain(preview).collect() } else { slots.collect() };
    all.iter().flat_map(|i| i.to_le_bytes()).collect()
}

/// Spawns a splat set with the splats' colours and opacities as given (style them first with
/// `settings.colouring.apply`); returns its entity. The order is filled by [`sort_splats`] before the first
/// frame is drawn.
pub fn spawn_splats(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<SplatMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    splats: &[Splat],
    settings: &SplatSettings,
) -> Entity {
    let splats = splats.to_vec();
    let n = splats.len();
    let material = materials.add(SplatMaterial {
        params: settings.into(),
        splats: buffers.add(ShaderBuffer::new(&pad(pack_geometry(&splats)), RenderAssetUsages::RENDER_WORLD)),
        // The two rewritable buffers stay in the main world too: rewriting a render-world-only buffer
        // reached the GPU once and then never again (Bevy 0.19.1, seen in `gpu_splats`).
        styles: buffers.add(ShaderBuffer::new(&pad(pack_styles(&splats)), RenderAssetUsages::default())),
        // In index order until the first sort (the GPU sort writes the whole set's part only).
        order: buffers
            .add(ShaderBuffer::new(&order_bytes(&(0..n as u32).collect::<Vec<_>>()), RenderAssetUsages::default())),
    });
    let mut e = commands.spawn((
        SplatSet { material: material.clone(), splats: Arc::new(splats), sorted_for: None },
        Transform::default(),
        Visibility::default(),
    ));
    if n > 0 {
        // The quads are placed by the shader: no frustum test on the mesh's bounds.
        let full = meshes.add(fascicle_render::meshes::slot_quads(n));
        e.insert((Mesh3d(full.clone()), MeshMaterial3d(material), NoFrustumCulling));
        let start = padded_len(n) as u32;
        if preview_len(n) > 0 {
            let slots = start..start + preview_len(n) as u32;
            let preview = meshes.add(fascicle_render::meshes::slot_quads_of(slots));
            e.insert(fascicle_render::budget::CoarseMesh { full, preview });
        }
    }
    e.id()
}

/// The CPU sort ([`SplatSortMode::Cpu`], or the GPU's fallback): re-sorts every splat set whose view
/// direction changed since its last sort, for the active 3D camera drawn last among those that see it (their
/// render layers meet the set's): the viewer's or the headless renderer's, not an overlay or another view on
/// other layers.
#[allow(clippy::too_many_arguments, reason = "the sort's inputs, outputs and mode")]
pub fn sort_splats(
    cameras: Query<(&Camera, &GlobalTransform, Option<&RenderLayers>), With<Camera3d>>,
    mut sets: Query<(&mut SplatSet, &GlobalTransform, Option<&RenderLayers>)>,
    materials: Res<Assets<SplatMaterial>>,
    mut buffers: ResMut<Assets<ShaderBuffer>>,
    mut buffer_events: MessageWriter<AssetEvent<ShaderBuffer>>,
    mut stats: ResMut<SplatSortStats>,
    mode: Res<SplatSortMode>,
    gpu: Res<GpuSortStats>,
) {
    let t0 = Instant::now();
    stats.sorts = stats.cpu_sorts + gpu.sorts();
    if gpu.uses_gpu(*mode) {
        stats.last_system_ms = t0.elapsed().as_secs_f64() * 1e3;
        return;
    }
    let default_layers = RenderLayers::default();
    for (mut set, gt, layers) in &mut sets {
        let layers = layers.unwrap_or(&default_layers);
        let Some((_, cam, _)) = cameras
            .iter()
            .filter(|(c, _, l)| c.is_active && l.unwrap_or(&default_layers).intersects(layers))
            .max_by_key(|(c, ..)| c.order)
        else {
            continue;
        };
        let forward = cam.forward().as_vec3();
        // depth = dot(M c + t - eye, f) = dot(c, Mᵀ f) + const.
        let m = gt.affine().matrix3;
        let dir = Vec3::from(m.transpose() * bevy::math::Vec3A::from(forward));
        if set.sorted_for == Some(dir) || set.splats.is_empty() {
            continue;
        }
        let s0 = Instant::now();
        let keys = depth_keys(set.splats.iter().map(|s| s.centre.as_vec3().to_array()), dir.to_array());
        // The slots past the splats (the GPU sort's padding) name themselves; the draw never reads them.
        let bytes = order_bytes(&argsort_desc(&keys));
        stats.last_upload_bytes = bytes.len();
        // Drawn in this frame: the sort runs after the asset events' flush.
        if let Some(mat) = materials.get(&set.material) {
            fascicle_render::modify_now(&mut buffers, &mut buffer_events, &mat.order, |b| b.data = Some(bytes));
        }
        set.sorted_for = Some(dir);
        stats.cpu_sorts += 1;
        stats.sorts += 1;
        stats.last_sort_ms = s0.elapsed().as_secs_f64() * 1e3;
    }
    stats.last_system_ms = t0.elapsed().as_secs_f64() * 1e3;
}
