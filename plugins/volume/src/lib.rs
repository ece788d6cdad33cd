//! Volume context as a Bevy plugin: a scalar volume (T1, FA, MD, any 3D NIfTI) as a 3D texture placed by
//! its affine, drawn by GPU ray casting or by view-aligned 3D-texture slicing with the same transfer
//! function (`shaders/volume.wgsl`, f64 reference `fascicle_core::dvr`). Both are composited in the
//! transparent phase and stop at the opaque layers' depth: [`OpaqueDepth`] is a copy of the camera's depth
//! buffer taken between Bevy's opaque and transparent passes, so glyphs inside the volume hide what lies
//! behind them and are tinted by what lies in front. A new method is one more `VolumeMethod` branch in the
//! shader and one more mesh here.

#![warn(missing_docs)]

use bevy::asset::RenderAssetUsages;
use bevy::camera::visibility::{NoFrustumCulling, RenderLayers};
use bevy::core_pipeline::core_3d::{main_opaque_pass_3d, main_transparent_pass_3d};
use bevy::core_pipeline::schedule::Core3d;
use bevy::image::{ImageSampler, ImageSamplerDescriptor};
use bevy::mesh::{Indices, MeshVertexBufferLayoutRef, PrimitiveTopology};
use bevy::pbr::{Material, MaterialPipeline, MaterialPipelineKey};
use bevy::prelude::*;
use bevy::render::RenderApp;
use bevy::render::camera::ExtractedCamera;
use bevy::render::extract_resource::{ExtractResource, ExtractResourcePlugin};
use bevy::render::render_asset::RenderAssets;
use bevy::render::render_resource::{
    AsBindGroup, CompareFunction, Extent3d, Origin3d, RenderPipelineDescriptor, ShaderType,
    SpecializedMeshPipelineError, TexelCopyTextureInfo, TextureAspect, TextureDimension, TextureFormat, TextureUsages,
};
use bevy::render::renderer::{RenderContext, ViewQuery};
use bevy::render::storage::ShaderBuffer;
use bevy::render::texture::GpuImage;
use bevy::render::view::ViewDepthTexture;
use bevy::shader::ShaderRef;
use fascicle_core::Volume;
use fascicle_core::dvr::{ClipBox, MarchParams, TransferFunction, preintegrate};

pub mod empty_space;
pub mod layer;
pub mod shaders;
pub mod shear_warp;

pub use fascicle_render::layer::LayerStatus;
pub use layer::{ScalarVolume, ScalarVolumeLoader, ScalarVolumeSettings, VolumeCounts, VolumeLayer, VolumeSystems};

/// Pre-integration table size (entries per axis).
pub const TABLE_N: usize = 64;

/// Ambient term of gradient shading.
pub const AMBIENT: f64 = 0.35;

/// How a volume is drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum VolumeMethod {
    /// Image order: a ray per pixel, front to back.
    #[default]
    Raycast,
    /// Object order: view-aligned planes through a 3D texture, back to front.
    Slicing,
    /// Object order, 2D-texture slicing: the voxel planes of the axis nearest the view direction (one of
    /// three stacks, switched as the view turns), back to front, each sampled bilinearly in its plane, opacity
    /// corrected for the distance between planes along each ray.
    Slicing2d,
    /// Object order, voxel splatting (Westover's sheet buffer): every voxel is classified and spread by a
    /// Gaussian kernel ([`VolumeSettings::kernel`]); the footprints of one voxel plane of the axis nearest the
    /// view are summed into a sheet (each voxel weighted by its kernel's line integral along the pixel's ray),
    /// and the sheets are composited back to front, so no footprint pops as the view turns.
    Splatting,
    /// Object order, cell projection: the grid cut into cells of [`VolumeSettings::cell`] voxels, each cell into
    /// six tetrahedra (Kuhn), projected and composited back to front in a visibility order computed per view
    /// (Shirley-Tuchman); each pixel of a tetrahedron integrates the linear field between its exact entry and
    /// exit through the pre-integrated table (Röttger et al.).
    Tetrahedra,
    /// Object order, shear-warp (Lacroute and Levoy): per view, a compute pass composites the voxel planes of
    /// the axis nearest the view into an intermediate image on the front plane (each plane resampled where
    /// the pixel's ray crosses it: the shear), at [`VolumeSettings::intermediate`] pixels per voxel; the
    /// volume's box then warps that image onto the screen ([`shear_warp`]).
    ShearWarp,
}

impl VolumeMethod {
    /// Every method, in the order of their shader codes (`dims.w` 0 to 5).
    pub const ALL: [VolumeMethod; 6] = [
        VolumeMethod::Raycast,
        VolumeMethod::Slicing,
        VolumeMethod::Slicing2d,
        VolumeMethod::Splatting,
        VolumeMethod::Tetrahedra,
        VolumeMethod::ShearWarp,
    ];

    /// Short name (the `method` column of `bench volume`).
    pub fn name(self) -> &'static str {
        match self {
            VolumeMethod::Raycast => "raycast",
            VolumeMethod::Slicing => "slice3d",
            VolumeMethod::Slicing2d => "slice2d",
            VolumeMethod::Splatting => "splat",
            VolumeMethod::Tetrahedra => "tetra",
            VolumeMethod::ShearWarp => "shearwarp",
        }
    }

    /// The code the shader branches on (`dims.w`).
    fn code(self) -> f32 {
        match self {
            VolumeMethod::Raycast => 0.0,
            VolumeMethod::Slicing => 1.0,
            VolumeMethod::Slicing2d => 2.0,
            VolumeMethod::Splatting => 3.0,
            VolumeMethod::Tetrahedra => 4.0,
            VolumeMethod::ShearWarp => 5.0,
        }
    }
}

/// Drawing options of a volume layer (a component of [`VolumeLayer`]; see [`layer`] for what each edit costs).
#[derive(Component, Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(default)]
pub struct VolumeSettings {
    /// How the volume is drawn. Defaults to [`VolumeMethod::Raycast`].
    pub method: VolumeMethod,
    /// Value to linear RGB and opacity per mm. Defaults to [`TransferFunction::default`]: FA as context,
    /// over `[0, 1]`.
    pub tf: TransferFunction,
    /// Step (ray casting) or slice spacing target (slicing), mm.
    pub step: f64,
    /// Early ray termination at this accumulated opacity (> 1: off).
    pub termination: f64,
    /// Dithering against wood-grain artefacts: a jittered ray start (ray casting), or each plane's sample moved
    /// along the ray by a per-pixel fraction of the spacing (slicing: interleaved sampling).
    pub jitter: bool,
    /// Gradient (Lambert headlight) shading.
    pub shading: bool,
    /// Pre-integrated classification (ray casting).
    pub preintegrated: bool,
    /// The part of the volume drawn (fractions of its extent per voxel axis).
    #[serde(default)]
    pub clip: ClipBox,
    /// Splatting: standard deviation of the Gaussian kernel, voxels.
    pub kernel: f64,
    /// Cell projection: edge of a cell, voxels (six tetrahedra per cell).
    pub cell: u32,
    /// Shear-warp: pixels of the intermediate image per voxel.
    pub intermediate: f64,
}

impl Default for VolumeSettings {
    fn default() -> Self {
        Self {
            method: VolumeMethod::Raycast,
            tf: TransferFunction::default(),
            step: 1.0,
            termination: 0.99,
            jitter: true,
            shading: false,
            preintegrated: false,
            clip: ClipBox::default(),
            kernel: 0.6,
            cell: 2,
            intermediate: 1.0,
        }
    }
}

impl VolumeSettings {
    /// The ray-marching knobs of these settings for the f64 reference (`fascicle_core::dvr::march`).
    pub fn march(&self) -> MarchParams {
        MarchParams {
            step: self.step,
            termination: self.termination,
            preintegrated: self.preintegrated,
            clip: self.clip,
            shading: self.shading.then_some(AMBIENT),
            tetrahedra: (self.method == VolumeMethod::Tetrahedra).then_some(self.cell.max(1) as usize),
        }
    }
}

/// GPU parameters. Keep in sync with `VolumeParams` in `shaders/volume.wgsl`.
#[derive(Clone, Copy, Debug, ShaderType)]
pub struct VolumeUniform {
    /// World RAS+ mm to voxel coordinates (the inverse of `world_from_voxel`).
    pub voxel_from_world: Mat4,
    /// Voxel coordinates (integer = voxel centre) to world RAS+ mm.
    pub world_from_voxel: Mat4,
    /// xyz: the volume's dimensions, voxels; w: the method's code (0 ray casting, 1 slicing, 2 2D slicing,
    /// 3 splatting, 4 tetrahedra, 5 shear-warp).
    pub dims: Vec4,
    /// World bounding sphere of the volume's box: centre (xyz) and radius (w), mm.
    pub sphere: Vec4,
    /// The clip box in voxel coordinates (xyz; w unused).
    pub clip_lo: Vec4,
    /// The clip box's upper corner in voxel coordinates (xyz; w unused).
    pub clip_hi: Vec4,
    /// Cell projection: cells per voxel axis (xyz; w unused).
    pub cells: UVec4,
    /// Empty-space skipping: cells per voxel axis (xyz) of [`empty_space::CELL`] voxels (w).
    pub grid: UVec4,
    /// The transfer function's value range `[lo, hi]`, in the volume's units, mapped to the LUT's [0, 1].
    pub range: Vec2,
    /// Ray-casting step or slice spacing target, mm.
    pub step: f32,
    /// Early ray termination at this accumulated opacity (> 1: off).
    pub termination: f32,
    /// 1: dithered ray starts or slice samples, 0: off.
    pub jitter: u32,
    /// 1: gradient (Lambert headlight) shading, 0: off.
    pub shading: u32,
    /// 1: pre-integrated classification (ray casting), 0: post-classification.
    pub preintegrated: u32,
    /// Slicing: view-aligned slices across the bounding sphere, `ceil(2 r / step)` in 1..=4096.
    pub n_slices: u32,
    /// Entries per axis of the pre-integration table ([`TABLE_N`]).
    pub table_n: u32,
    /// Ambient term of gradient shading ([`AMBIENT`]).
    pub ambient: f32,
    /// Splatting: standard deviation of the Gaussian kernel, voxels (clamped to 0.05..=4).
    pub kernel: f32,
    /// Cell projection: edge of a cell, voxels (at least 1).
    pub cell: u32,
}

/// The material of one volume layer, drawn by `shaders/volume.wgsl` in the transparent phase with
/// premultiplied alpha; rays stop at the opaque layers' depth ([`OpaqueDepth`]).
#[derive(Asset, TypePath, AsBindGroup, Debug, Clone)]
#[bind_group_data(VolumeKey)]
pub struct VolumeMaterial {
    /// The drawing parameters (binding 0), from the layer's [`VolumeSettings`] and the volume's grid.
    #[uniform(0)]
    pub params: VolumeUniform,
    /// The scalar volume as an R32Float 3D texture, read unfiltered ([`volume_texture`]).
    #[texture(1, dimension = "3d", sample_type = "float", filterable = false)]
    pub volume: Handle<Image>,
    /// The transfer function's lookup table: 256 `vec4` (linear RGB, opacity per mm) over `params.range`.
    #[storage(2, read_only)]
    pub lut: Handle<ShaderBuffer>,
    /// The pre-integration table: `table_n` x `table_n` premultiplied `vec4` segments (front value major)
    /// for the current step.
    #[storage(3, read_only)]
    pub table: Handle<ShaderBuffer>,
    /// The camera's depth after the opaque pass ([`OpaqueDepth`]), where rays stop.
    #[texture(4, sample_type = "depth")]
    pub opaque_depth: Handle<Image>,
    /// Shear-warp's intermediate image (written by its compute pass; 1x1 for other methods).
    #[texture(5, sample_type = "float", filterable = false)]
    pub intermediate: Handle<Image>,
    /// Where the warp finds that image: axis, base plane, placement (written by the same pass).
    #[storage(6, read_only)]
    pub warp: Handle<ShaderBuffer>,
    /// Empty-space skipping: a `u32` per cell of `params.grid` (x fastest), 0 where no ray can gather
    /// anything with the current transfer function ([`empty_space::occupancy`]).
    #[storage(7, read_only)]
    pub occupancy: Handle<ShaderBuffer>,
}

/// Steps (mm) whose opacity correction the ray caster makes by products and square roots instead of `pow`: the
/// powers of two from a quarter of a millimetre to 16 mm, among them the default step (1 mm). A step and its
/// doubling while the view moves (`fascicle_render::budget`) both belong, up to 8 mm: they share a pipeline. On
/// lavapipe the `pow` of every sample was about a tenth of the default scene's full-scale frame (0.3 of 2.5 s).
/// Keep in sync with `segment_step` in `shaders/volume.wgsl`, which makes the products for these steps.
pub const PRODUCT_STEPS: [f32; 7] = [0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0];

/// The pipeline key of [`VolumeMaterial`]: the shader is compiled for its settings, since lavapipe runs the code
/// of every branch for every pixel whichever way the pixels go (a branch on a setting saves nothing there). The
/// step of a moving view (twice the step) keeps the key of the still one for steps of [`PRODUCT_STEPS`] up to 8
/// mm, so that an interaction compiles no pipeline; a change of method, shading or classification compiles one.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct VolumeKey {
    /// `params.step` is one of [`PRODUCT_STEPS`]: the `PRODUCT_STEPS` shader def.
    pub product_steps: bool,
    /// The material ray casts (`params.dims.w` 0): the `RAY_CAST` def, without the other methods' code.
    pub ray_cast: bool,
    /// Gradient shading (`params.shading` 1): the `SHADING` def.
    pub shading: bool,
    /// Pre-integrated classification (`params.preintegrated` 1): the `PREINTEGRATED` def.
    pub preintegrated: bool,
}

impl From<&VolumeMaterial> for VolumeKey {
    fn from(material: &VolumeMaterial) -> Self {
        let p = &material.params;
        Self {
            product_steps: PRODUCT_STEPS.contains(&p.step),
            ray_cast: p.dims.w == 0.0,
            shading: p.shading == 1,
            preintegrated: p.preintegrated == 1,
        }
    }
}

impl Material for VolumeMaterial {
    fn vertex_shader() -> ShaderRef {
        shaders::volume()
    }
    fn fragment_shader() -> ShaderRef {
        shaders::volume()
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
        key: MaterialPipelineKey<Self>,
    ) -> Result<(), SpecializedMeshPipelineError> {
        let k = key.bind_group_data;
        if let Some(fragment) = descriptor.fragment.as_mut() {
            let defs = [
                (k.product_steps, "PRODUCT_STEPS"),
                (k.ray_cast, "RAY_CAST"),
                (k.shading, "SHADING"),
                (k.preintegrated, "PREINTEGRATED"),
            ];
            fragment.shader_defs.extend(defs.into_iter().filter(|(on, _)| *on).map(|(_, def)| def.into()));
        }
        // Back-face culling: the box is wound inwards, so only its far faces are drawn (one ray per pixel,
        // also with the camera inside); slices are wound to face the camera. The shader tests against the
        // opaque depth itself (the ray stops there), so no depth test or write.
        descriptor.primitive.cull_mode = Some(bevy::render::render_resource::Face::Back);
        if let Some(ds) = descriptor.depth_stencil.as_mut() {
            ds.depth_write_enabled = Some(false);
            ds.depth_compare = Some(CompareFunction::Always);
        }
        Ok(())
    }
}

/// The copy of the main 3D camera's depth buffer after the opaque pass, sampled by volume materials.
#[derive(Resource, Clone, ExtractResource)]
pub struct OpaqueDepth(pub Handle<Image>);

/// A volume layer: one entity.
#[derive(Component, Clone, Debug)]
pub struct VolumeSet {
    /// The layer's material: uniform, 3D texture, transfer-function tables and the depth copy.
    pub material: Handle<VolumeMaterial>,
    /// The volume's dimensions `[X, Y, Z]`, voxels.
    pub dims: [usize; 3],
    /// Voxel coordinates (integer = voxel centre) to world RAS+ mm.
    pub world_from_voxel: glam::DMat4,
    /// The settings the material was last written with (an edit is compared with them to find its cost).
    pub settings: VolumeSettings,
    /// Counts of the volume's values in [`HISTOGRAM_BINS`] bins over the transfer function's range.
    pub histogram: std::sync::Arc<Vec<u32>>,
    /// Per empty-space cell, the values sampling can find there ([`empty_space::cell_value_ranges`]): the
    /// occupancy is made from them whenever the transfer function's tables are written.
    pub cell_ranges: std::sync::Arc<Vec<[f32; 2]>>,
}

impl VolumeSet {
    /// Writes `settings` into the set's material: the uniform, and the transfer function's lookup and
    /// pre-integration tables when `tables` (they depend on the function and the step). The texture and the
    /// mesh are untouched. False when the material is gone.
    pub fn write_style(
        &self,
        settings: &VolumeSettings,
        tables: bool,
        materials: &mut Assets<VolumeMaterial>,
        buffers: &mut Assets<ShaderBuffer>,
    ) -> bool {
        let Some(mut m) = materials.get_mut(&self.material) else { return false };
        if tables {
            let (lut, table, occupancy) = tf_buffers(settings, &self.cell_ranges);
            for (h, bytes) in [(m.lut.clone(), lut), (m.table.clone(), table), (m.occupancy.clone(), occupancy)] {
                if let Some(mut b) = buffers.get_mut(&h) {
                    b.data = Some(bytes);
                }
            }
        }
        m.params = VolumeUniform::new(self.dims, self.world_from_voxel, settings);
        true
    }

    /// Gives the material an intermediate image of the size `settings` need (shear-warp's, or 1x1); false
    /// when it already had it.
    pub fn fit_intermediate(
        &self,
        settings: &VolumeSettings,
        materials: &mut Assets<VolumeMaterial>,
        images: &mut Assets<Image>,
    ) -> bool {
        let edge = shear_warp::image_edge(self.dims, settings.intermediate, settings.method);
        let Some(m) = materials.get(&self.material) else { return false };
        if images.get(&m.intermediate).is_some_and(|img| img.width() == edge) {
            return false;
        }
        let image = images.add(intermediate_image(edge));
        if let Some(mut m) = materials.get_mut(&self.material) {
            m.intermediate = image;
        }
        true
    }
}

/// An `edge`² intermediate image for shear-warp (storage-written, sampled by the warp).
fn intermediate_image(edge: u32) -> Image {
    let mut img = Image::new_uninit(
        Extent3d { width: edge, height: edge, depth_or_array_layers: 1 },
        TextureDimension::D2,
        shear_warp::IMAGE_FORMAT,
        RenderAssetUsages::RENDER_WORLD,
    );
    img.texture_descriptor.usage = TextureUsages::STORAGE_BINDING | TextureUsages::TEXTURE_BINDING;
    img
}

/// Bins of a volume's histogram (for the transfer-function editor).
pub const HISTOGRAM_BINS: usize = 64;

/// Counts of finite values in `bins` equal bins over `[lo, hi]` (values outside are clamped in).
pub fn histogram(values: &[f32], range: [f64; 2], bins: usize) -> Vec<u32> {
    let mut h = vec![0u32; bins];
    let span = range[1] - range[0];
    for v in values.iter().filter(|v| v.is_finite()) {
        let u = if span > 0.0 { ((*v as f64 - range[0]) / span).clamp(0.0, 1.0) } else { 0.0 };
        h[((u * bins as f64) as usize).min(bins - 1)] += 1;
    }
    h
}

/// Registers the volume material and the [`VolumeLayer`] systems, and copies the 3D camera's depth
/// between the opaque and transparent passes ([`OpaqueDepth`]). Cameras that see a volume lose their MSAA.
pub struct VolumePlugin;

impl Plugin for VolumePlugin {
    fn build(&self, app: &mut App) {
        shaders::register(app);
        fascicle_render::retain::watch_asset::<VolumeMaterial>(app);
        fascicle_render::retain::watch_asset::<ScalarVolume>(app);
        fascicle_render::retain::watch::<OpaqueDepth>(app);
        app.add_plugins((MaterialPlugin::<VolumeMaterial>::default(), ExtractResourcePlugin::<OpaqueDepth>::default()))
            .add_systems(Startup, create_opaque_depth)
            .add_systems(PostUpdate, (prepare_cameras, fit_opaque_depth))
            .add_systems(
                PostUpdate,
                coarse_step_while_moving
                    .after(fascicle_render::budget::BudgetSystems)
                    .before(bevy::asset::AssetEventSystems),
            );
        layer::build(app);
        shear_warp::build(app);
        if let Some(render_app) = app.get_sub_app_mut(RenderApp) {
            render_app.add_systems(
                Core3d,
                (copy_opaque_depth, shear_warp::composite)
                    .chain()
                    .after(main_opaque_pass_3d)
                    .before(main_transparent_pass_3d)
                    // A frame that puts a retained picture back skips the main pass's set.
                    .in_set(bevy::core_pipeline::Core3dSystems::MainPass),
            );
        }
    }
}

/// While the frame budget draws at a lower scale (the view moves: [`fascicle_render::budget`]), ray-cast
/// volumes with post-classification march at twice their step (half the samples; opacity is per mm, so the
/// picture keeps its brightness), and at four times it while the budget draws coarse
/// ([`BudgetState::coarse`](fascicle_render::budget::BudgetState::coarse): the smallest scale was over budget);
/// the frame that returns to full scale writes their own step back. A uniform write at each change, nothing
/// else. Pre-integrated volumes keep their step (their table depends on it).
fn coarse_step_while_moving(
    budget: Option<Res<fascicle_render::budget::BudgetState>>,
    sets: Query<&VolumeSet>,
    mut materials: ResMut<Assets<VolumeMaterial>>,
    mut coarse: Local<Option<u32>>,
) {
    let want = budget.map_or(1, |b| step_factor(b.scale < 1.0, b.coarse));
    if coarse.unwrap_or(1) == want {
        return;
    }
    *coarse = Some(want);
    for set in sets.iter().filter(|s| s.settings.method == VolumeMethod::Raycast && !s.settings.preintegrated) {
        if let Some(mut m) = materials.get_mut(&set.material) {
            m.params.step = marched_step(&set.settings, want);
        }
    }
}

/// How many times its own step a post-classified ray-cast volume marches at: 1 at full scale, 2 at a lower
/// scale, 4 while the budget draws coarse.
fn step_factor(scaled: bool, coarse: bool) -> u32 {
    match (scaled, coarse) {
        (_, true) => 4,
        (true, false) => 2,
        (false, false) => 1,
    }
}

/// The step a post-classified ray-cast volume marches at, mm: its own times `factor` ([`step_factor`]).
fn marched_step(settings: &VolumeSettings, factor: u32) -> f32 {
    settings.step as f32 * factor as f32
}

fn depth_image(width: u32, height: u32) -> Image {
    // No initial data: depth textures cannot be written from the CPU. Until the first copy it reads
    // whatever the driver cleared it to; the copy runs before any volume is drawn.
    let mut img = Image::new_uninit(
        Extent3d { width: width.max(1), height: height.max(1), depth_or_array_layers: 1 },
        TextureDimension::D2,
        TextureFormat::Depth32Float,
        RenderAssetUsages::RENDER_WORLD,
    );
    img.texture_descriptor.usage = TextureUsages::TEXTURE_BINDING | TextureUsages::COPY_DST;
    img.sampler = ImageSampler::Descriptor(ImageSamplerDescriptor {
        compare: Some(bevy::image::ImageCompareFunction::Always),
        ..default()
    });
    img
}

fn create_opaque_depth(mut commands: Commands, mut images: ResMut<Assets<Image>>) {
    commands.insert_resource(OpaqueDepth(images.add(depth_image(1, 1))));
}

/// Cameras that see a volume (their render layers meet a volume set's) keep a copyable, single-sampled
/// depth buffer: the volume reads the opaque depth, and a multisampled depth buffer cannot be copied.
/// Other cameras (another view, a UI camera, a minimap on other render layers) keep their MSAA and depth
/// usage. A camera changed here is logged once.
fn prepare_cameras(
    volumes: Query<Option<&RenderLayers>, With<VolumeSet>>,
    mut cameras: Query<(Entity, &mut Camera3d, Option<&Msaa>, Option<&RenderLayers>)>,
    mut commands: Commands,
) {
    if volumes.is_empty() {
        return;
    }
    let default_layers = RenderLayers::default();
    for (e, mut cam, msaa, layers) in &mut cameras {
        let layers = layers.unwrap_or(&default_layers);
        if !volumes.iter().any(|v| v.unwrap_or(&default_layers).intersects(layers)) {
            continue;
        }
        let usage = TextureUsages::from(cam.depth_texture_usages);
        if !usage.contains(TextureUsages::COPY_SRC) {
            cam.depth_texture_usages = (usage | TextureUsages::COPY_SRC).into();
        }
        if msaa != Some(&Msaa::Off) {
            info!("fascicle-volume: camera {e} sees a volume; its MSAA is turned off (the volume reads its depth)");
            commands.entity(e).insert(Msaa::Off);
        }
    }
}

/// Keeps the depth copy the size of the active 3D camera's target.
fn fit_opaque_depth(
    depth: Option<Res<OpaqueDepth>>,
    cameras: Query<&Camera, With<Camera3d>>,
    volumes: Query<(), With<VolumeSet>>,
    mut images: ResMut<Assets<Image>>,
    mut materials: ResMut<Assets<VolumeMaterial>>,
    sets: Query<&VolumeSet>,
) {
    let Some(depth) = depth else { return };
    if volumes.is_empty() {
        return;
    }
    let Some(size) =
        cameras.iter().filter(|c| c.is_active).max_by_key(|c| c.order).and_then(|c| c.physical_target_size())
    else {
        return;
    };
    let Some(img) = images.get(&depth.0) else { return };
    if img.width() == size.x && img.height() == size.y {
        return;
    }
    if let Some(mut img) = images.get_mut(&depth.0) {
        *img = depth_image(size.x, size.y);
    }
    // Rebuild the materials' bind groups around the new texture.
    for set in &sets {
        if let Some(mut m) = materials.get_mut(&set.material) {
            let _: &mut VolumeMaterial = &mut m;
        }
    }
}

fn copy_opaque_depth(
    view: ViewQuery<(&ExtractedCamera, &ViewDepthTexture)>,
    target: Option<Res<OpaqueDepth>>,
    images: Res<RenderAssets<GpuImage>>,
    mut ctx: RenderContext,
) {
    let Some(target) = target else { return };
    let (_, depth) = view.into_inner();
    let Some(dst) = images.get(target.0.id()) else { return };
    let size = depth.texture.size();
    if depth.texture.sample_count() != 1
        || !depth.texture.usage().contains(TextureUsages::COPY_SRC)
        || dst.texture.size() != size
    {
        return;
    }
    ctx.command_encoder().copy_texture_to_texture(
        TexelCopyTextureInfo {
            texture: &depth.texture,
            mip_level: 0,
            origin: Origin3d::ZERO,
            aspect: TextureAspect::DepthOnly,
        },
        TexelCopyTextureInfo {
            texture: &dst.texture,
            mip_level: 0,
            origin: Origin3d::ZERO,
            aspect: TextureAspect::DepthOnly,
        },
        Extent3d { width: size.width, height: size.height, depth_or_array_layers: 1 },
    );
}

/// The volume's bounding box (voxel centres ± 0.5) as 12 triangles in world space, wound inwards.
fn box_mesh(dims: [usize; 3], world_from_voxel: glam::DMat4) -> Mesh {
    let hi = [dims[0] as f64 - 0.5, dims[1] as f64 - 0.5, dims[2] as f64 - 0.5];
    let corner = |i: usize| {
        let p = glam::DVec3::new(
            if i & 1 == 0 { -0.5 } else { hi[0] },
            if i & 2 == 0 { -0.5 } else { hi[1] },
            if i & 4 == 0 { -0.5 } else { hi[2] },
        );
        world_from_voxel.transform_point3(p).as_vec3().to_array()
    };
    let pos: Vec<[f32; 3]> = (0..8).map(corner).collect();
    // Outward counter-clockwise triangles, then reversed so the far faces are the front faces (a mirroring
    // affine reverses them once more).
    let mut idx = fascicle_render::meshes::BOX_TRIANGLES.to_vec();
    if glam::DMat3::from_mat4(world_from_voxel).determinant() > 0.0 {
        for t in idx.chunks_mut(3) {
            t.swap(1, 2);
        }
    }
    Mesh::new(PrimitiveTopology::TriangleList, RenderAssetUsages::RENDER_WORLD)
        .with_inserted_attribute(Mesh::ATTRIBUTE_POSITION, pos)
        .with_inserted_indices(Indices::U32(idx))
}

/// World bounding sphere (centre, radius) of a volume's box.
fn bounding_sphere(dims: [usize; 3], world_from_voxel: glam::DMat4) -> (glam::DVec3, f64) {
    let c = glam::DVec3::new(dims[0] as f64 - 1.0, dims[1] as f64 - 1.0, dims[2] as f64 - 1.0) / 2.0;
    let centre = world_from_voxel.transform_point3(c);
    let r = (0..8)
        .map(|i| {
            let p = glam::DVec3::new(
                if i & 1 == 0 { -0.5 } else { dims[0] as f64 - 0.5 },
                if i & 2 == 0 { -0.5 } else { dims[1] as f64 - 0.5 },
                if i & 4 == 0 { -0.5 } else { dims[2] as f64 - 0.5 },
            );
            (world_from_voxel.transform_point3(p) - centre).length()
        })
        .fold(0.0, f64::max);
    (centre, r)
}

impl VolumeUniform {
    /// The uniform of a `dims` volume placed by `world_from_voxel` (voxel coordinates to RAS+ mm), drawn with `s`.
    pub fn new(dims: [usize; 3], world_from_voxel: glam::DMat4, s: &VolumeSettings) -> Self {
        let (centre, r) = bounding_sphere(dims, world_from_voxel);
        let (lo, hi) = s.clip.voxel_bounds(dims);
        let method = s.method.code();
        let cells = tet_cells(dims, s.cell);
        Self {
            voxel_from_world: world_from_voxel.inverse().as_mat4(),
            world_from_voxel: world_from_voxel.as_mat4(),
            dims: Vec4::new(dims[0] as f32, dims[1] as f32, dims[2] as f32, method),
            sphere: Vec4::new(centre.x as f32, centre.y as f32, centre.z as f32, r as f32),
            clip_lo: lo.as_vec3().extend(0.0),
            clip_hi: hi.as_vec3().extend(0.0),
            cells: UVec4::new(cells[0], cells[1], cells[2], 0),
            grid: UVec4::from((UVec3::from(empty_space::grid(dims)), empty_space::CELL as u32)),
            range: Vec2::new(s.tf.range[0] as f32, s.tf.range[1] as f32),
            step: s.step as f32,
            termination: s.termination as f32,
            jitter: u32::from(s.jitter),
            shading: u32::from(s.shading),
            preintegrated: u32::from(s.preintegrated),
            n_slices: slices(r, s.step),
            table_n: TABLE_N as u32,
            ambient: AMBIENT as f32,
            kernel: s.kernel.clamp(0.05, 4.0) as f32,
            cell: s.cell.max(1),
        }
    }
}

/// Slices covering a bounding sphere of radius `r` at spacing about `step` (at most 4096).
pub fn slices(r: f64, step: f64) -> u32 {
    ((2.0 * r / step.max(1e-3)).ceil() as u32).clamp(1, 4096)
}

/// The transfer function's LUT, pre-integrated table and the empty-space occupancy of cells with values in
/// `cell_ranges` ([`empty_space::cell_value_ranges`]), as buffer bytes.
pub fn tf_buffers(s: &VolumeSettings, cell_ranges: &[[f32; 2]]) -> (Vec<u8>, Vec<u8>, Vec<u8>) {
    let lut = s.tf.lut();
    let table = preintegrate(&lut, TABLE_N, s.step.max(1e-3), 64);
    let occupancy = empty_space::occupancy(cell_ranges, &lut, &table, TABLE_N);
    let tb = table.iter().flat_map(|v| v.to_array()).flat_map(|v| (v as f32).to_le_bytes()).collect();
    (lut.to_bytes(), tb, occupancy.iter().flat_map(|o| o.to_le_bytes()).collect())
}

/// The proxy geometry of a method: the volume's box (ray casting, shear-warp's warp), the view-aligned slices (slicing), the
/// voxel planes (2D slicing, splatting's sheets) or the tetrahedra (cell projection).
pub fn proxy_mesh(dims: [usize; 3], world_from_voxel: glam::DMat4, settings: &VolumeSettings) -> Mesh {
    match settings.method {
        VolumeMethod::Raycast | VolumeMethod::ShearWarp => box_mesh(dims, world_from_voxel),
        VolumeMethod::Slicing => {
            let (_, r) = bounding_sphere(dims, world_from_voxel);
            fascicle_render::meshes::slot_quads(slices(r, settings.step) as usize)
        }
        // One quad per voxel plane of the longest axis; the vertex stage picks the stack and folds the rest.
        VolumeMethod::Slicing2d | VolumeMethod::Splatting => {
            fascicle_render::meshes::slot_quads(dims.into_iter().max().unwrap_or(1))
        }
        // One quad per tetrahedron (six per cell), in drawing order: the vertex stage maps each slot to the
        // tetrahedron that order puts there for the current view, and spans the quad over its projection.
        VolumeMethod::Tetrahedra => {
            let c = tet_cells(dims, settings.cell);
            fascicle_render::meshes::slot_quads(6 * (c[0] * c[1] * c[2]) as usize)
        }
    }
}

/// Cells per voxel axis of the tetrahedral grid at cell edge `cell` voxels: the grid's lattice lines are the
/// voxel centres 0, cell, 2 cell, ..., the last voxel's centre, plus the volume's faces half a voxel beyond
/// the first and last centres (there the field is the edge voxel's value, as the ray caster's clamped
/// sampling), so the cells cover exactly the box the other methods draw.
pub fn tet_cells(dims: [usize; 3], cell: u32) -> [u32; 3] {
    let s = cell.max(1) as usize;
    dims.map(|d| (d.max(1) - 1).div_ceil(s) as u32 + 2)
}

/// Spawns a volume layer (a 3D scalar image) drawn with `settings`; returns its entity.
#[allow(clippy::too_many_arguments, reason = "the asset stores a volume layer writes to")]
pub fn spawn_volume(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    images: &mut Assets<Image>,
    materials: &mut Assets<VolumeMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    depth: &OpaqueDepth,
    vol: &Volume<f32>,
    settings: &VolumeSettings,
) -> Entity {
    let texture = volume_texture(vol);
    spawn_volume_texture(commands, meshes, images, materials, buffers, depth, vol, texture, settings)
}

/// The 3D texture of a volume (R32Float, non-finite values as 0): the costly part of [`spawn_volume`], which
/// can be made on any thread.
pub fn volume_texture(vol: &Volume<f32>) -> Image {
    let d = vol.dims3();
    let n = d[0] * d[1] * d[2];
    let bytes: Vec<u8> =
        vol.data[..n].iter().flat_map(|v| if v.is_finite() { *v } else { 0.0 }.to_le_bytes()).collect();
    let mut tex = Image::new(
        Extent3d { width: d[0] as u32, height: d[1] as u32, depth_or_array_layers: d[2] as u32 },
        TextureDimension::D3,
        bytes,
        TextureFormat::R32Float,
        RenderAssetUsages::RENDER_WORLD,
    );
    tex.sampler = ImageSampler::nearest();
    tex
}

/// [`spawn_volume`] with the volume's texture already made ([`volume_texture`]).
#[allow(clippy::too_many_arguments, reason = "the asset stores a volume layer writes to")]
pub(crate) fn spawn_volume_texture(
    commands: &mut Commands,
    meshes: &mut Assets<Mesh>,
    images: &mut Assets<Image>,
    materials: &mut Assets<VolumeMaterial>,
    buffers: &mut Assets<ShaderBuffer>,
    depth: &OpaqueDepth,
    vol: &Volume<f32>,
    tex: Image,
    settings: &VolumeSettings,
) -> Entity {
    let d = vol.dims3();
    let n = d[0] * d[1] * d[2];
    let cell_ranges = std::sync::Arc::new(empty_space::cell_value_ranges(vol));
    let (lut, table, occupancy) = tf_buffers(settings, &cell_ranges);
    let params = VolumeUniform::new(d, vol.world_from_voxel, settings);
    let material = materials.add(VolumeMaterial {
        params,
        volume: images.add(tex),
        lut: buffers.add(ShaderBuffer::new(&lut, RenderAssetUsages::default())),
        table: buffers.add(ShaderBuffer::new(&table, RenderAssetUsages::default())),
        opaque_depth: depth.0.clone(),
        intermediate: images.add(intermediate_image(shear_warp::image_edge(d, settings.intermediate, settings.method))),
        warp: buffers.add(ShaderBuffer::new(&[0u8; 32], RenderAssetUsages::default())),
        occupancy: buffers.add(ShaderBuffer::new(&occupancy, RenderAssetUsages::default())),
    });
    let mesh = proxy_mesh(d, vol.world_from_voxel, settings);
    commands
        .spawn((
            VolumeSet {
                material: material.clone(),
                dims: d,
                world_from_voxel: vol.world_from_voxel,
                settings: settings.clone(),
                histogram: std::sync::Arc::new(histogram(&vol.data[..n], settings.tf.range, HISTOGRAM_BINS)),
                cell_ranges,
            },
            Mesh3d(meshes.add(mesh)),
            MeshMaterial3d(material),
            Transform::default(),
            Visibility::default(),
            NoFrustumCulling,
        ))
        .id()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The pipeline key of a volume drawn with `s` at `factor` times its step (1 still, 2 moving, 4 coarse).
    fn key(s: &VolumeSettings, factor: u32) -> VolumeKey {
        let mut params = VolumeUniform::new([8, 8, 8], glam::DMat4::IDENTITY, s);
        params.step = marched_step(s, factor);
        let material = VolumeMaterial {
            params,
            volume: Handle::default(),
            lut: Handle::default(),
            table: Handle::default(),
            opaque_depth: Handle::default(),
            intermediate: Handle::default(),
            warp: Handle::default(),
            occupancy: Handle::default(),
        };
        VolumeKey::from(&material)
    }

    /// The shader is compiled per setting, but a moving view (twice the step) keeps the still view's pipeline for
    /// the steps of [`PRODUCT_STEPS`] up to 8 mm and for the others, and a coarse one (four times) up to 4 mm:
    /// an interaction compiles none. The method, shading and pre-integration each change it.
    #[test]
    fn keys_follow_the_settings_not_the_motion() {
        assert_eq!([step_factor(false, false), step_factor(true, false), step_factor(true, true)], [1, 2, 4]);
        for step in [0.25, 0.5, 1.0, 2.0, 4.0, 8.0] {
            let s = VolumeSettings { step, ..default() };
            let still = key(&s, 1);
            assert_eq!(still, key(&s, 2), "step {step}");
            if step <= 4.0 {
                assert_eq!(still, key(&s, 4), "step {step}, coarse");
            }
            assert!(still.product_steps && still.ray_cast && !still.shading && !still.preintegrated, "{still:?}");
        }
        for step in [0.3, 0.7, 1.5, 3.0] {
            let s = VolumeSettings { step, ..default() };
            assert!(!key(&s, 1).product_steps && key(&s, 1) == key(&s, 2) && key(&s, 1) == key(&s, 4), "step {step}");
        }
        let base = key(&VolumeSettings::default(), 1);
        assert!(key(&VolumeSettings { shading: true, ..default() }, 1).shading);
        assert!(key(&VolumeSettings { preintegrated: true, ..default() }, 1).preintegrated);
        for method in [VolumeMethod::Slicing, VolumeMethod::Slicing2d, VolumeMethod::Splatting] {
            assert_ne!(base, key(&VolumeSettings { method, ..default() }, 1), "{method:?}");
            assert!(!key(&VolumeSettings { method, ..default() }, 1).ray_cast);
        }
    }
}
