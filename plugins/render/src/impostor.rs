//! A sphere drawn by ray casting on a bounding cube, writing true depth: the reference opaque ray-cast
//! primitive, used by the framework's depth tests and as the template for glyph shaders.
//!
//! Why the prepass is off: with `DepthPrepass` on a camera, the default prepass shader would write the
//! proxy cube's depth, hiding the glyph and everything behind the proxy. A glyph that must appear in the
//! prepass (for volume ray marching that stops at opaque depth) supplies a prepass fragment shader that
//! computes the same depth.

use bevy::pbr::{Material, MaterialPipeline, MaterialPipelineKey};
use bevy::prelude::*;
use bevy::render::render_resource::{AsBindGroup, ShaderType};
use bevy::shader::ShaderRef;

use crate::shaders;

/// GPU parameters. Keep in sync with `ImpostorUniform` in `shaders/sphere_impostor.wgsl`.
#[derive(Clone, Copy, Debug, ShaderType)]
pub struct ImpostorUniform {
    /// Centre (world, mm) and radius (mm).
    pub center_radius: Vec4,
    /// Linear RGB base colour and ambient fraction (0..1).
    pub color_ambient: Vec4,
}

const _: () = assert!(std::mem::size_of::<ImpostorUniform>() == 32);

/// One ray-cast sphere (`shaders/sphere_impostor.wgsl`), drawn on a cube mesh placed by
/// [`SphereImpostorMaterial::proxy_transform`]; no prepass, no shadows, both faces drawn.
#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
pub struct SphereImpostorMaterial {
    /// The sphere and its shading (uniform binding 0).
    #[uniform(0)]
    pub params: ImpostorUniform,
}

impl SphereImpostorMaterial {
    /// A sphere at `center` of `radius`, in linear `color`, with ambient fraction `ambient`.
    pub fn new(center: Vec3, radius: f32, color: LinearRgba, ambient: f32) -> Self {
        Self {
            params: ImpostorUniform {
                center_radius: center.extend(radius),
                color_ambient: Vec4::new(color.red, color.green, color.blue, ambient),
            },
        }
    }

    /// The proxy mesh's transform: a unit cube scaled to the sphere's bounding box.
    pub fn proxy_transform(&self) -> Transform {
        let cr = self.params.center_radius;
        Transform::from_translation(cr.truncate()).with_scale(Vec3::splat(2.0 * cr.w))
    }
}

/// Spawns the child of `parent` that draws a glyph set of `material`: one mesh of a proxy box per glyph
/// ([`crate::meshes::slot_boxes`], placed by the vertex stage `fascicle::proxy`), with `marker`, no frustum
/// culling (the boxes are placed on the GPU), and, for a set of over [`crate::meshes::GLYPH_PREVIEW_MIN`]
/// glyphs, a [`crate::budget::CoarseMesh`] of every other cell of `centres` (the glyphs' centres, in buffer
/// order) drawn while the frame budget is coarse. Nothing for an empty set.
pub fn spawn_glyph_proxies<M: Material>(
    commands: &mut Commands,
    parent: Entity,
    meshes: &mut Assets<Mesh>,
    material: &Handle<M>,
    centres: &[Vec3],
    marker: impl Component,
) {
    if centres.is_empty() {
        return;
    }
    let full = meshes.add(crate::meshes::slot_boxes(centres.len()));
    let mut drawn = commands.spawn((
        marker,
        Mesh3d(full.clone()),
        MeshMaterial3d(material.clone()),
        bevy::camera::visibility::NoFrustumCulling,
        ChildOf(parent),
    ));
    if let Some(slots) = crate::meshes::every_other_cell(centres) {
        let preview = meshes.add(crate::meshes::slot_boxes_of(&slots));
        drawn.insert(crate::budget::CoarseMesh { full, preview });
    }
}

/// Implements `Material` for a proxy-glyph material (SH glyphs, tensor glyphs) whose vertex and fragment stages
/// are both in `$shader`, a `ShaderRef` expression: a set's proxy boxes are one mesh (`meshes::slot_boxes`)
/// placed by the vertex stage (`fascicle::proxy`); no prepass and no shadows (the reason is in this module's
/// docs), and back faces only, so each proxy gives one fragment per pixel (half the work of both faces) and
/// still draws with the camera inside it.
#[macro_export]
macro_rules! proxy_glyph_material {
    ($material:ty, $shader:expr) => {
        impl bevy::pbr::Material for $material {
            fn vertex_shader() -> bevy::shader::ShaderRef {
                $shader
            }
            fn fragment_shader() -> bevy::shader::ShaderRef {
                $shader
            }
            fn enable_prepass() -> bool {
                false
            }
            fn enable_shadows() -> bool {
                false
            }
            fn specialize(
                _pipeline: &bevy::pbr::MaterialPipeline,
                descriptor: &mut bevy::render::render_resource::RenderPipelineDescriptor,
                _layout: &bevy::mesh::MeshVertexBufferLayoutRef,
                _key: bevy::pbr::MaterialPipelineKey<Self>,
            ) -> Result<(), bevy::render::render_resource::SpecializedMeshPipelineError> {
                descriptor.primitive.cull_mode = Some(bevy::render::render_resource::Face::Front);
                Ok(())
            }
        }
    };
}

impl Material for SphereImpostorMaterial {
    fn fragment_shader() -> ShaderRef {
        shaders::sphere_impostor()
    }
    fn enable_prepass() -> bool {
        false
    }
    fn enable_shadows() -> bool {
        false
    }
    fn specialize(
        _pipeline: &MaterialPipeline,
        descriptor: &mut bevy::render::render_resource::RenderPipelineDescriptor,
        _layout: &bevy::mesh::MeshVertexBufferLayoutRef,
        _key: MaterialPipelineKey<Self>,
    ) -> Result<(), bevy::render::render_resource::SpecializedMeshPipelineError> {
        // The ray may enter the proxy from inside (camera within the bounding cube): draw back faces.
        descriptor.primitive.cull_mode = None;
        Ok(())
    }
}
