//! Tensor splats: one entity per splat (a `MeshTag` into one storage buffer) on a shared quad, drawn in
//! Bevy's transparent phase, which sorts them far to near by their centres' depth every frame and tests them
//! against the opaque depth (glyphs, meshes) without writing it. The vertex shader does the EWA projection;
//! the fragment shader the elliptical Gaussian opacity, premultiplied.
//!
//! Splats carry `NoAutomaticBatching`: batched, Bevy's GPU preprocessing compacts the instances of a batch
//! out of order and the far-to-near order is lost (measured: 1 % of pixels off by up to 27 levels). One draw
//! per splat is correct but costs a draw call each; a custom phase item drawing a sorted index buffer in one
//! call is the next step for 1M splats.

use bevy::asset::RenderAssetUsages;
use bevy::camera::visibility::NoFrustumCulling;
use bevy::mesh::{MeshTag, MeshVertexBufferLayoutRef};
use bevy::pbr::{Material, MaterialPipeline, MaterialPipelineKey};
use bevy::prelude::*;
use bevy::render::batching::NoAutomaticBatching;
use bevy::render::render_resource::{AsBindGroup, RenderPipelineDescriptor, ShaderType, SpecializedMeshPipelineError};
use bevy::render::storage::ShaderBuffer;
use bevy::shader::ShaderRef;
use fascicle_core::dti::splat::{ATTENUATION_K, DILATION_PX2, Splat};
use fascicle_render::shaders;

/// Splat drawing options.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SplatSettings {
    /// The seed's depth attenuation `exp(-2K sqrt(T'zz))`.
    pub attenuation: bool,
    /// Multiplies every splat's opacity.
    pub opacity: f32,
}

impl Default for SplatSettings {
    fn default() -> Self {
        Self { attenuation: true, opacity: 1.0 }
    }
}

/// GPU parameters. Keep in sync with `SplatParams` in `shaders/tensor_splat.wgsl`.
#[derive(Clone, Copy, Debug, ShaderType)]
pub struct SplatUniform {
    pub attenuation: u32,
    pub k: f32,
    pub dilation: f32,
    pub opacity_scale: f32,
}

impl From<&SplatSettings> for SplatUniform {
    fn from(s: &SplatSettings) -> Self {
        Self {
            attenuation: u32::from(s.attenuation),
            k: ATTENUATION_K as f32,
            dilation: DILATION_PX2 as f32,
            opacity_scale: s.opacity,
        }
    }
}

#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
pub struct SplatMaterial {
    #[uniform(0)]
    pub params: SplatUniform,
    /// Four `vec4` per splat: (centre, opacity), (xx, xy, xz, yy), (yz, zz, 0, 0), (linear rgb, 0).
    #[storage(1, read_only)]
    pub splats: Handle<ShaderBuffer>,
}

impl Material for SplatMaterial {
    fn vertex_shader() -> ShaderRef {
        ShaderRef::Handle(shaders::TENSOR_SPLAT)
    }
    fn fragment_shader() -> ShaderRef {
        ShaderRef::Handle(shaders::TENSOR_SPLAT)
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

/// A splat set: the parent of its splat entities.
#[derive(Component, Clone, Debug)]
pub struct SplatSet {
    pub material: Handle<SplatMaterial>,
    pub len: usize,
}

/// One splat on screen: its index in the set's buffer.
#[derive(Component, Clone, Copy, Debug, PartialEq, Eq)]
pub struct SplatIndex(pub u32);

/// The storage buffer's bytes.
pub fn pack(splats: &[Splat]) -> Vec<u8> {
    let mut out = Vec::with_capacity(splats.len() * 64);
    for s in splats {
        let c = s.cov;
        let vals = [
            s.centre.x, s.centre.y, s.centre.z, s.opacity, c.x_axis.x, c.x_axis.y, c.x_axis.z, c.y_axis.y, c.y_axis.z,
            c.z_axis.z, 0.0, 0.0, s.colour.x, s.colour.y, s.colour.z, 0.0,
        ];
        for v in vals {
            out.extend_from_slice(&(v as f32).to_le_bytes());
        }
    }
    out
}

/// Spawns a splat set; returns the parent.
pub fn spawn_splats(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    materials: &mut Assets<SplatMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    splats: &[Splat],
    settings: &SplatSettings,
) -> Entity {
    let mut bytes = pack(splats);
    if bytes.is_empty() {
        bytes = vec![0u8; 64];
    }
    let material = materials.add(SplatMaterial {
        params: settings.into(),
        splats: buffers.add(ShaderBuffer::new(&bytes, RenderAssetUsages::RENDER_WORLD)),
    });
    let quad = meshes.add(Rectangle::new(2.0, 2.0));
    let parent = commands
        .spawn((
            SplatSet { material: material.clone(), len: splats.len() },
            Transform::default(),
            Visibility::default(),
        ))
        .id();
    for (i, s) in splats.iter().enumerate() {
        commands.spawn((
            SplatIndex(i as u32),
            Mesh3d(quad.clone()),
            MeshMaterial3d(material.clone()),
            MeshTag(i as u32),
            // The translation is the sort key of the transparent phase; the footprint is placed by the shader.
            Transform::from_translation(s.centre.as_vec3()),
            NoFrustumCulling,
            NoAutomaticBatching,
            ChildOf(parent),
        ));
    }
    parent
}
